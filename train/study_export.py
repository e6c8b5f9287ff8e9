"""A study's best trial as a hyperparameter entry: :func:`best_trial` (the best completed trial),
:func:`best_entry` (its ``hyperparams.yml`` entry in rl-zoo3's layout) and :func:`export_best` (written atomically,
with the command that trains it).
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import yaml

from iscc_gym.files import write_atomic

if TYPE_CHECKING:  # pragma: no cover
    import optuna

__all__ = ["best_trial", "best_entry", "export_best"]


def best_trial(s: optuna.Study) -> optuna.trial.FrozenTrial | None:
    """The completed trial of highest value that :func:`make_objective` ran (None if there is none yet)."""
    import optuna

    done = [t for t in s.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))
            if "hyperparams" in t.user_attrs and t.value is not None]
    return max(done, key=lambda t: t.value, default=None)


def best_entry(trial: optuna.trial.FrozenTrial, env_id: str, algo: str) -> dict:
    """The hyperparams.yml content of a completed trial, in rl-zoo3's layout.

    Parameters
    ----------
    trial : optuna.trial.FrozenTrial
        A trial run by :func:`make_objective` (its user attributes hold the configuration).
    env_id, algo : str
        The env id of the entry and the algorithm (named under ``iscc_gym.train.algo``).

    Returns
    -------
    dict
        ``{env_id: entry, "iscc_gym.train": {"algo": algo, "settings": {env_id: ...}}}``: the entry holds
        ``n_timesteps``, ``n_envs``,
        ``normalize`` (read by :func:`iscc_gym.train.train.resolve_args` and by rl-zoo3) and the
        algorithm's keyword arguments, ``policy_kwargs`` as rl-zoo3's ``dict(...)`` string; ``settings`` the
        trial's run settings in use (a warm start, a residual base, randomised missions), where it recorded any.
    """
    from iscc_gym.train.config import OWN_SECTION, format_policy_kwargs

    attrs = trial.user_attrs
    hp = dict(attrs["hyperparams"])
    if hp.get("policy_kwargs"):
        hp["policy_kwargs"] = format_policy_kwargs(hp["policy_kwargs"])
    entry = {"n_timesteps": int(attrs["n_timesteps"]), "n_envs": int(attrs["n_envs"]),
             "normalize": bool(attrs["normalize"]), **hp}
    flags = attrs.get("run") or {}  # what the trial played beside its hyperparameters (older trials recorded none)
    if flags.get("env_overrides"):  # rl-zoo3's env_kwargs, which python -m train reads as Scenario overrides
        entry["env_kwargs"] = dict(flags["env_overrides"])
    own: dict = {"algo": algo}
    if attrs.get("settings"):  # the trial's warm start / residual / randomisation (older trials recorded none)
        own["settings"] = {env_id: dict(attrs["settings"])}
    return {env_id: entry, OWN_SECTION: own}


def export_best(s: optuna.Study, env_id: str, algo: str, path: str | os.PathLike) -> str:
    """Write the best trial as a hyperparams.yml entry to ``path`` (temporary name, then rename), under a
    header saying how to train it: ``python -m train``, and rl-zoo3 only for a trial without run settings
    (rl-zoo3 ignores a residual base, a warm start or randomised missions and trains a plain agent).

    Parameters
    ----------
    s : optuna.Study
        A study with at least one completed trial run by :func:`make_objective` (:func:`best_trial`).
    env_id, algo : str
        The keys of the entry.
    path : path-like
        Destination, e.g. ``OUT/best_hyperparams.yml``.

    Returns
    -------
    str
        The YAML text written.
    """
    from iscc_gym.train.config import OWN_SECTION

    best = best_trial(s)
    if best is None:
        raise ValueError(f"study {s.study_name!r} has no completed trial to export yet")
    entry = best_entry(best, env_id, algo)
    flags = best.user_attrs.get("run") or {}
    extra = "".join(f" --{k.replace('_', '-')} {v}" for k, v in flags.items() if k != "env_overrides")
    header = (f"# Best trial #{best.number} of Optuna study {s.study_name!r}: final held-out mean episode reward "
              f"{best.value:.4f}\n# ({len(s.trials)} trials in the study when exported). Train it with:\n"
              f"#   python -m train --algo {algo} --env {env_id}{extra} --hyperparams {path}\n")
    settings = entry[OWN_SECTION].get("settings", {}).get(env_id)
    if extra:  # the trial's scenario and constraints are flags (issue 43.15: the export left them out)
        header += (f"# (the trial played{extra}: give them as above; env_kwargs holds its Scenario overrides)\n")
    if settings or extra:  # rl-zoo3 reads the entry alone: it would train a plain agent, not the trial's
        shown = ", ".join([*(f"{k}={v}" for k, v in (settings or {}).items()), *(f"{k}={v}" for k, v in flags.items()
                                                                                 if k != "env_overrides")])
        header += (f"# (python -m train only: rl-zoo3 ignores the run settings under {OWN_SECTION}.settings and "
                   f"the flags, {shown},\n# and would train a plain {algo} agent instead)\n")
    else:
        header += (f"# or rl-zoo3 (its layout): python -m rl_zoo3.train --algo {algo} --env {env_id} "
                   f"--gym-packages iscc_gym -conf {path}\n")
    text = header + yaml.safe_dump(entry, sort_keys=False)
    write_atomic(path, text)
    return text
