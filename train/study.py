"""Hyperparameter studies on Optuna and multi-seed runs: ``python -m train --optimize`` / ``--seeds``.

Usage::

    # one machine: the study lives in OUT/study.db (SQLite)
    python -m train --optimize --n-trials 20 --trial-timesteps 200000 --out runs/study
    # many machines: the same command with one shared storage URL joins the same study
    python -m train --optimize --n-trials 4 --storage postgresql://USER:PASS@HOST/DB --study-name ppo-a --out runs/study
    # one configuration (the YAML's, with --set overrides) trained with several seeds
    python -m train --seeds 0,1,2,3,4 --out runs/seeds

Each trial samples PPO hyperparameters (:func:`sample_ppo_params`), trains with
:func:`iscc_gym.train.train.main` into ``OUT/trial_<n>`` and reports every held-out evaluation of the
EvalCallback (mean episode reward on the seeds from :data:`iscc_gym.commands.protocol.CALLBACK_EVAL_SEED_START`) to
Optuna,
which may prune it. The objective, maximised, is the final model's mean reward on the same held-out
episodes. The best trial is exported as a ``hyperparams.yml`` entry, ``OUT/best_hyperparams.yml``,
which ``python -m train --hyperparams OUT/best_hyperparams.yml`` trains directly.

Storage (``--storage``): omitted, ``sqlite:///OUT/study.db``; otherwise any SQLAlchemy URL Optuna's
``RDBStorage`` takes (``sqlite:///PATH``, ``postgresql://USER:PASS@HOST[:PORT]/DB``,
``mysql+pymysql://USER:PASS@HOST/DB``; the driver must be installed) or ``journal:PATH``, an Optuna
journal file (``JournalFileBackend``) on a filesystem every worker mounts (NFS: no database server;
SQLite files on NFS are not safe); a journal path must be a regular file holding an Optuna journal, or
absent or empty. Workers that run the same command with the same ``--storage`` and ``--study-name``
share one study (``load_if_exists``); each worker runs ``--n-trials`` trials.

A killed worker: every storage records a heartbeat of each running trial (every 60 s; on a journal
file, in the journal); the next worker that starts a trial marks FAIL any RUNNING trial without a
heartbeat for 180 s and queues it once more with the same hyperparameters, as a new trial number
(``train.study_io.HEARTBEAT_INTERVAL_S``, ``GRACE_PERIOD_S``, ``MAX_RETRY``). On a journal the ages
are read on the workers' clocks, which must agree within those 180 s.

One study per ``--out``: ``OUT/study.yml`` names it, and a study of another name is refused there
(its ``trial_<n>`` directories and ``best_hyperparams.yml`` would overwrite the first study's); give
each study its own ``--out``, or the same ``--study-name`` to add trials to it.

Reproducibility: the sampler of trial ``n`` is seeded from ``(--seed, n)``, so a single worker's study
is reproducible given ``--seed``, and parallel workers with the same ``--seed`` never draw the same
random start-up configurations.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import socket
import time
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml
from iscc_gym.train.config import Args, load_hyperparams, resolve_args, run_flags, run_settings

if TYPE_CHECKING:  # pragma: no cover
    import optuna

from iscc_gym.commands.options import parse_seeds

from .multi_seed import check_run_config, evaluate_run, run_seeds
from .study_export import best_trial, export_best
from .study_io import (
    PRUNERS,
    SAMPLERS,
    StudyConfigError,
    claim_out,
    make_pruner,
    make_sampler,
    make_storage,
)

#: The PPO search space: name -> choices (a list) or ``(low, high, "log" | "linear")``. ``n_minibatches``
#: sets ``batch_size = n_envs * n_steps / n_minibatches`` (always a divisor of the rollout);
#: ``net_width`` x ``net_depth`` is ``policy_kwargs.net_arch``; ``log_std_init`` goes into
#: ``policy_kwargs``. A name fixed by ``--n-envs`` or ``--set`` is not sampled.
PPO_SPACE: dict[str, Any] = {
    "n_envs": [32, 64, 128, 256],
    "n_steps": [16, 32, 64, 128, 256],
    "n_minibatches": [1, 2, 4, 8, 16, 32],
    "n_epochs": [1, 3, 5, 10, 20],
    "learning_rate": (1e-5, 3e-3, "log"),
    # low discounts too: an allocation acts mostly within the slot (docs/learning.md)
    "gamma": [0.3, 0.5, 0.7, 0.8, 0.9, 0.95, 0.98, 0.99],
    "gae_lambda": [0.8, 0.9, 0.92, 0.95, 0.98, 0.99, 1.0],
    "clip_range": [0.1, 0.2, 0.3, 0.4],
    "ent_coef": (1e-8, 1e-1, "log"),  # the low end is ~0: no entropy bonus
    "net_width": [32, 64, 128, 256],
    "net_depth": [1, 2, 3],
    "log_std_init": (-4.0, 0.5, "linear"),
}

@dataclass
class StudyArgs:
    """Settings of a study (``python -m train --optimize``), beside the training :class:`~train.train.Args`.

    Attributes
    ----------
    n_trials : int
        Trials this worker runs (>= 1); every worker of a shared study runs its own ``n_trials``.
    storage : str or None
        Optuna storage URL (``sqlite:///PATH``, ``postgresql://...``, ``mysql+pymysql://...``) or
        ``journal:PATH``; None: ``sqlite:///OUT/study.db``.
    study_name : str or None
        Name of the study in the storage; None: ``<env name>-<algo>``, e.g. ``ISCC-v0-ppo``.
    sampler : str
        ``tpe`` (Optuna's TPESampler, random for the first ``n_startup_trials``) or ``random``.
    pruner : str
        ``median`` (MedianPruner) or ``none``.
    n_startup_trials : int
        Random trials before TPE models the results, and trials before the median pruner prunes.
    trial_timesteps : int or None
        Env steps per trial; None: ``--total-timesteps``, else the YAML's ``n_timesteps``, else 200k.
    n_evaluations : int
        Held-out evaluations reported to Optuna per trial (every ``trial_timesteps / n_evaluations``
        env steps); the median pruner waits for ``max(1, n_evaluations // 3)`` of them.
    """

    n_trials: int = 10
    storage: str | None = None
    study_name: str | None = None
    sampler: str = "tpe"
    pruner: str = "median"
    n_startup_trials: int = 5
    trial_timesteps: int | None = None
    n_evaluations: int = 4


_STUDY_HELP = {
    "n_trials": "trials this worker runs (each worker of a shared study runs its own)",
    "storage": "Optuna storage: sqlite:///PATH, postgresql://USER:PASS@HOST/DB, mysql+pymysql://..., or "
               "journal:PATH (an Optuna journal file, or a new one, on a shared filesystem); default "
               "sqlite:///OUT/study.db. On every storage a killed worker's trial is marked failed after 180 s "
               "without a heartbeat and run once more",
    "study_name": "study name in the storage (default <env>-<algo>); workers with the same name share it. One "
                  "study per --out (OUT/study.yml names it): another study's --out is refused, so trial_<n> "
                  "and best_hyperparams.yml of two studies never collide",
    "sampler": "tpe | random (seeded from --seed and the trial number)",
    "pruner": "median | none",
    "n_startup_trials": "random trials before TPE, and trials before the median pruner prunes",
    "trial_timesteps": "env steps per trial (default --total-timesteps, else the YAML's n_timesteps)",
    "n_evaluations": "held-out evaluations reported to Optuna per trial",
}


def add_study_arguments(ap: argparse.ArgumentParser) -> None:
    """Add ``--optimize``, ``--seeds`` and the :class:`StudyArgs` flags to the ``python -m train`` parser.

    Parameters
    ----------
    ap : argparse.ArgumentParser
        The parser of :func:`iscc_gym.train.train.build_parser`.
    """
    group = ap.add_argument_group("hyperparameter studies (Optuna) and multi-seed runs")
    group.add_argument("--optimize", action="store_true",
                       help="run a study: each trial samples PPO hyperparameters and trains into OUT/trial_<n> "
                            "(one study per --out)")
    group.add_argument("--seeds", default=None, metavar="S0,S1,...",
                       help="train the configuration once per seed into OUT/seed_<s>; summary in OUT/seeds.yml")
    defaults = StudyArgs()
    for f in dataclasses.fields(StudyArgs):
        default = getattr(defaults, f.name)
        kind = int if f.name in ("trial_timesteps",) or isinstance(default, int) else str
        group.add_argument("--" + f.name.replace("_", "-"), type=kind, default=default, help=_STUDY_HELP[f.name])


def study_args_from_namespace(ns: argparse.Namespace) -> StudyArgs:
    """The :class:`StudyArgs` of a namespace parsed by a parser with :func:`add_study_arguments`."""
    return StudyArgs(**{f.name: getattr(ns, f.name) for f in dataclasses.fields(StudyArgs)})


def study_seeds(text: str) -> list[int]:
    """``--seeds`` of a seeds run (:func:`iscc_gym.commands.options.parse_seeds`), as a :class:`StudyConfigError`."""
    try:
        return parse_seeds(text, "--seeds")
    except ValueError as e:
        raise StudyConfigError(str(e)) from None


def run_cli(ap: argparse.ArgumentParser, ns: argparse.Namespace, args: Args) -> dict:
    """``python -m train --optimize`` / ``--seeds``: run, print, and turn bad input into a one-line error.

    Parameters
    ----------
    ap : argparse.ArgumentParser
        The parser (for its program name and ``exit``).
    ns : argparse.Namespace
        The parsed flags.
    args : Args
        The training arguments of the same command line.

    Returns
    -------
    dict
        The study summary (:func:`optimize`) or the multi-seed summary (:func:`run_seeds`).
    """
    try:
        if ns.optimize and ns.seeds is not None:
            raise StudyConfigError("--optimize and --seeds: use one (a study, or one configuration over seeds)")
        if ns.optimize:
            result = optimize(args, study_args_from_namespace(ns))
            print(result["report"])
            return result
        return run_seeds(args, study_seeds(ns.seeds))
    except StudyConfigError as e:
        ap.exit(2, f"{ap.prog}: error: {e}\n")


# --- validation -----------------------------------------------------------------------------------------

def _check_study(args: Args, study: StudyArgs) -> None:
    if args.algo != "ppo":
        raise StudyConfigError(f"--algo {args.algo}: the study's search space is PPO's; use --algo ppo "
                               "(--seeds runs a fixed configuration of any algorithm)")
    if study.sampler not in SAMPLERS:
        raise StudyConfigError(f"--sampler {study.sampler!r}: use one of {', '.join(SAMPLERS)}")
    if study.pruner not in PRUNERS:
        raise StudyConfigError(f"--pruner {study.pruner!r}: use one of {', '.join(PRUNERS)}")
    for name in ("n_trials", "n_evaluations", "trial_timesteps"):
        value = getattr(study, name)
        if value is not None and value < 1:
            raise StudyConfigError(f"--{name.replace('_', '-')} {value}: use an integer >= 1")
    if study.n_startup_trials < 0:
        raise StudyConfigError(f"--n-startup-trials {study.n_startup_trials}: use an integer >= 0")
    if args.resume:
        raise StudyConfigError("--resume: a study starts every trial afresh; drop --resume")
    _, hp = check_run_config(args)


# --- the search space and the trial -----------------------------------------------------------------------

def _minibatch_size(rollout: int, n_minibatches: int) -> int:
    """The largest minibatch size ``rollout / k`` with ``k <= n_minibatches`` dividing the rollout, >= 2."""
    k = max(1, min(n_minibatches, rollout // 2))
    while rollout % k:
        k -= 1
    return rollout // k


def sample_ppo_params(trial: optuna.Trial, base: Mapping[str, Any], fixed: Mapping[str, Any]) -> tuple[int, dict]:
    """Sample one PPO configuration from :data:`PPO_SPACE`.

    Parameters
    ----------
    trial : optuna.Trial
        The trial that records the draws.
    base : mapping
        The YAML entry with the ``--set`` overrides (its ``policy_kwargs``, e.g. ``activation_fn``, are kept).
    fixed : mapping
        Values not to sample: ``n_envs``, any PPO keyword (``n_steps``, ``batch_size``...) and
        ``policy_kwargs.<key>`` (``policy_kwargs.net_arch``, ``policy_kwargs.log_std_init``).

    Returns
    -------
    n_envs : int
        Parallel envs.
    overrides : dict
        PPO keyword arguments for :attr:`Args.overrides` (``batch_size`` divides ``n_envs * n_steps``).
    """

    def pick(name: str) -> Any:
        if name in fixed:
            return fixed[name]
        space = PPO_SPACE[name]
        if isinstance(space, list):
            return trial.suggest_categorical(name, space)
        low, high, scale = space
        return trial.suggest_float(name, low, high, log=scale == "log")

    n_envs = int(pick("n_envs"))
    hp: dict[str, Any] = {"n_steps": int(pick("n_steps"))}
    rollout = n_envs * hp["n_steps"]
    hp["batch_size"] = int(fixed["batch_size"]) if "batch_size" in fixed else _minibatch_size(rollout,
                                                                                            pick("n_minibatches"))
    for name in ("n_epochs", "learning_rate", "gamma", "gae_lambda", "clip_range", "ent_coef"):
        hp[name] = pick(name)
    pk = dict(base.get("policy_kwargs") or {})
    if "policy_kwargs.net_arch" in fixed:
        pk["net_arch"] = fixed["policy_kwargs.net_arch"]
    else:
        pk["net_arch"] = [int(pick("net_width"))] * int(pick("net_depth"))
    key = "policy_kwargs.log_std_init"
    pk["log_std_init"] = float(fixed[key] if key in fixed else pick("log_std_init"))
    hp["policy_kwargs"] = pk
    return n_envs, hp


def _fixed_values(args: Args) -> dict:
    fixed = dict(args.overrides)
    for key, value in (args.overrides.get("policy_kwargs") or {}).items():
        fixed[f"policy_kwargs.{key}"] = value
    if args.n_envs is not None:
        fixed["n_envs"] = args.n_envs
    return fixed


def _trial_callback(trial: optuna.Trial):
    """An EvalCallback ``callback_after_eval`` that reports each held-out evaluation to ``trial``.

    Reports ``parent.last_mean_reward`` at step ``k`` (the k-th evaluation, so trials of different
    ``n_envs`` are compared at the same point of their budget; every evaluation plays the same
    held-out episodes, :func:`iscc_gym.train.train.main` re-seeds them) and stops training, setting
    ``pruned``, when the pruner says so.
    """
    from stable_baselines3.common.callbacks import BaseCallback

    class TrialEvalCallback(BaseCallback):
        def __init__(self):
            super().__init__()
            self.trial = trial
            self.evaluations: list[tuple[int, float]] = []
            self.pruned = False

        def _on_step(self) -> bool:
            value = float(self.parent.last_mean_reward)
            self.evaluations.append((int(self.parent.num_timesteps), value))
            self.trial.report(value, len(self.evaluations))
            if self.trial.should_prune():
                self.pruned = True
                return False
            return True

    return TrialEvalCallback()


def _budget(args: Args, study: StudyArgs) -> int:
    if study.trial_timesteps is not None:
        return study.trial_timesteps
    return int(args.total_timesteps if args.total_timesteps is not None else resolve_args(args)[0].total_timesteps)


def make_objective(args: Args, study: StudyArgs) -> Callable[[optuna.Trial], float]:
    """The objective: sample, train into ``OUT/trial_<n>`` reporting evaluations, return the final reward.

    Parameters
    ----------
    args : Args
        Training arguments shared by every trial (env, ``--set`` overrides, eval settings, seed).
    study : StudyArgs
        The study settings (budget and evaluations per trial).

    Returns
    -------
    callable
        ``objective(trial) -> float``; raises ``optuna.TrialPruned`` when the pruner stops a trial.
    """
    import optuna

    base = load_hyperparams(args.hyperparams, args.env_id, args.algo, args.overrides)
    fixed = _fixed_values(args)
    budget = _budget(args, study)

    def objective(trial: optuna.Trial) -> float:
        n_envs, hp = sample_ppo_params(trial, base, fixed)
        run = dataclasses.replace(args, n_envs=n_envs, total_timesteps=budget, overrides={**args.overrides, **hp},
                                  out=str(Path(args.out) / f"trial_{trial.number}"),
                                  eval_freq=max(n_envs, budget // study.n_evaluations))
        resolved, kwargs = resolve_args(run)
        trial.set_user_attr("n_envs", n_envs)
        trial.set_user_attr("n_timesteps", budget)
        trial.set_user_attr("normalize", bool(resolved.normalize))
        trial.set_user_attr("settings", run_settings(resolved))  # warm start, residual, randomisation
        trial.set_user_attr("run", run_flags(resolved))  # scenario, env overrides, constraints (issue 43.15)
        trial.set_user_attr("hyperparams", kwargs)
        trial.set_user_attr("out", str(Path(run.out).resolve()))
        trial.set_user_attr("worker", f"{socket.gethostname()}:{os.getpid()}")
        callback = _trial_callback(trial)
        t0 = time.perf_counter()
        from iscc_gym.train.train import main

        summary = main(run, callback_after_eval=callback)
        trial.set_user_attr("wall_time_s", time.perf_counter() - t0)
        trial.set_user_attr("timesteps", summary["timesteps"])
        if callback.pruned:
            raise optuna.TrialPruned(f"evaluation {len(callback.evaluations)}: {callback.evaluations[-1][1]:.1f} "
                                     f"at {callback.evaluations[-1][0]} steps")
        mean, std = evaluate_run(run)
        trial.set_user_attr("final_reward_std", std)
        if not math.isfinite(mean):
            raise FloatingPointError(f"final held-out reward {mean}")
        return mean

    return objective


def open_study(args: Args, study: StudyArgs):
    """Create or join (``load_if_exists``) the study of ``study.storage`` / ``study.study_name``.

    Parameters
    ----------
    args : Args
        Training arguments (``out`` holds the default storage, ``seed`` seeds the sampler).
    study : StudyArgs
        The study settings.

    Returns
    -------
    study : optuna.Study
        Direction ``maximize``.
    shown : str
        The storage URL as printed (no password).

    Raises
    ------
    StudyConfigError
        Bad flags, an unusable storage, an existing study of that name that minimizes, or an ``--out``
        holding another study's trials (``OUT/study.yml`` names the study of an ``--out``).
    """
    import optuna

    _check_study(args, study)
    name = study.study_name or f"{args.env_id.split('/')[-1]}-{args.algo}"
    claim_out(args.out, name)  # another study's OUT is refused before anything is created
    storage, shown = make_storage(study.storage, args.out)
    sampler = make_sampler(study.sampler, args.seed, study.n_startup_trials)
    pruner = make_pruner(study.pruner, study.n_startup_trials, study.n_evaluations)
    s = optuna.create_study(storage=storage, study_name=name, direction="maximize", sampler=sampler, pruner=pruner,
                            load_if_exists=True)
    if s.directions != [optuna.study.StudyDirection.MAXIMIZE]:
        found = " and ".join(d.name.lower() for d in s.directions)
        raise StudyConfigError(f"--study-name {name}: the study of that name in {shown} has direction {found}; this "
                               "objective (held-out reward) is maximized: choose another --study-name")
    claim_out(args.out, name, shown, has_trials=bool(s.get_trials(deepcopy=False)))
    return s, shown


def optimize(args: Args, study: StudyArgs) -> dict:
    """Run ``study.n_trials`` trials of a (possibly shared) study and export its best trial.

    Parameters
    ----------
    args : Args
        Training arguments shared by every trial.
    study : StudyArgs
        The study settings.

    Returns
    -------
    dict
        ``study`` (the ``optuna.Study``), ``best_path`` (``OUT/best_hyperparams.yml``, None before a trial
        completes), ``best`` (the exported entry) and ``report`` (the printed text).

    Notes
    -----
    Every trial trains with the same ``args.seed`` (trials are compared on paired training draws). A
    trial that raises ``ValueError`` (e.g. torch rejecting NaN action means after a diverged update)
    or ``FloatingPointError`` is recorded as failed and the worker goes on; any other exception
    stops the worker.
    """
    import optuna
    from iscc_gym.train.callbacks import progress_bar_on

    s, shown = open_study(args, study)
    bar = progress_bar_on(args)  # trials done / total (each trial's own bar is off)
    if args.quiet:
        optuna.logging.set_verbosity(optuna.logging.WARNING)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        s.optimize(make_objective(dataclasses.replace(args, progress_bar=False), study), n_trials=study.n_trials,
                   catch=(ValueError, FloatingPointError), gc_after_trial=True, show_progress_bar=bar)
    states = [t.state for t in s.get_trials(deepcopy=False)]
    counts = ", ".join(f"{sum(x == st for x in states)} {st.name.lower()}" for st in
                       (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED,
                        optuna.trial.TrialState.FAIL, optuna.trial.TrialState.RUNNING))
    lines = [f"study {s.study_name!r} in {shown}: {len(states)} trials ({counts})"]
    result: dict[str, Any] = {"study": s, "best_path": None, "best": None}
    best = best_trial(s)
    if best is not None:
        path = Path(args.out) / "best_hyperparams.yml"
        text = export_best(s, args.env_id, args.algo, path)
        result.update(best_path=str(path), best=yaml.safe_load(text))
        lines += [f"best trial #{best.number}: held-out reward {best.value:.2f} -> {path}", text.rstrip()]
    else:
        lines.append("no completed trial yet: nothing exported")
    result["report"] = "\n".join(lines)
    return result
