r"""Residual learning on a scripted policy: the agent's action corrects a base policy's.

A residual agent (Silver et al., "Residual Policy Learning", 2018; Johannink et al., "Residual
Reinforcement Learning for Robot Control", 2019) acts in :math:`[-1, 1]^3` like any agent, but the env
plays

.. math:: a_\mathrm{env} = \mathrm{clip}\big(a_\mathrm{base}(o) + s\,a_\mathrm{agent}(o),\; -1,\; 1\big)

where :math:`a_\mathrm{base}` is a scripted policy's action on the same raw observation :math:`o` and
:math:`s` the residual's scale (``residual_space="action"``, the default). With ``residual_space="split"`` the
correction multiplies the base's shares instead, :math:`\alpha_i \propto \alpha_{\mathrm{base},i}\,
e^{s\,a_{\mathrm{agent},i}}` (its logits shifted by at most s): no action bound clips it, so an exploring agent
moves a base that sits at a corner of the action box (a share at +1, a small share near -1) symmetrically, where
the additive form clips half its draws and drifts (the field task: ``docs/learning.md``). An agent whose action is
zero plays the base policy exactly, so training
starts at the base's level (PPO's action head starts near zero) and keeps what it cannot improve.

``python -m train`` trains one with ``residual: SPEC`` (an :func:`agents.make_policy` spec) and
``residual_scale`` in its settings (``--residual``, ``--residual-scale``): :class:`ResidualVecEnv` sits
between the env and VecNormalize, so the base sees raw observations.

The agent is its correction *and* its base: every model ``.zip`` of a residual run holds, beside SB3's own
entries (which SB3 ignores it among), its :func:`residual_record` (:data:`RECORD_ENTRY`): the base's spec, the
scale, the scenario the base was built for and the base's tuned parameters as trained (:func:`residual_record`
resolves them once, when the run starts; the run's manifest records the same). So the agent loads as the
:class:`ResidualPolicy` it was trained as however it is loaded (a run directory, a checkpoint, a bare model
``.zip``), and its base plays the recorded parameters even after ``python -m eval.tune`` re-tunes the spec.
"""

from __future__ import annotations

import math
import shutil
import warnings
import zipfile
from pathlib import Path

import numpy as np
import yaml
from stable_baselines3.common.vec_env import VecEnvWrapper

__all__ = ["ResidualVecEnv", "ResidualPolicy", "residual_action", "check_scale", "check_space", "RESIDUAL_SPACES",
           "RECORD_ENTRY", "RECORD_KEYS",
           "RECORD_FIX", "residual_record", "write_record", "add_record", "read_record", "check_record", "base_policy"]

#: The entry of a residual agent's model ``.zip`` that holds its :func:`residual_record`.
RECORD_ENTRY = "residual.yml"
#: The fix of a damaged record (it came with the model file).
RECORD_FIX = "the model file is damaged: use the run's own copy, or retrain"
#: What a residual record holds: the run settings (as a run's manifest names them) that make the base policy.
RECORD_KEYS = ("residual", "residual_scale", "scenario", "env_overrides", "residual_params")
#: Where the correction acts (``residual_space``): ``action`` (added to the base's action; the default, which
#: records leave out) or ``split`` (the base's shares' logits).
RESIDUAL_SPACES = ("action", "split")


def check_space(space) -> str:
    """``space`` if it is one of :data:`RESIDUAL_SPACES`; ``ValueError`` naming ``residual_space`` otherwise."""
    if space not in RESIDUAL_SPACES:
        raise ValueError(f"residual_space = {space!r}; use one of {', '.join(RESIDUAL_SPACES)}")
    return space


def check_scale(scale) -> float:
    """``scale`` as a float in (0, 2] (at 2 a correction spans the whole action box); ``ValueError`` naming
    ``residual_scale`` otherwise.
    """
    try:
        s = float(scale)
    except (TypeError, ValueError):
        s = math.nan
    if not (0.0 < s <= 2.0):
        raise ValueError(f"residual_scale = {scale!r}; use a number in (0, 2] (the correction's reach in action "
                         "units, e.g. 0.5)")
    return s


def residual_action(base_action, agent_action, scale: float, space: str = "action") -> np.ndarray:
    """The env's action: ``clip(base_action + scale * agent_action, -1, 1)`` as float32 (``space="action"``), or
    with ``space="split"`` the action of the split whose logits are the base split's plus ``scale * agent_action``
    (:func:`iscc_gym.sim.task.split_to_action`; the base's shares floored at 1e-9); the agent's action clipped to
    [-1, 1] first (as SB3 clips a policy's action to its box). NaN in either is refused.
    """
    base = np.asarray(base_action, dtype=np.float64)
    agent = np.asarray(agent_action, dtype=np.float64)
    if base.shape != agent.shape:
        raise ValueError(f"the agent's action has shape {agent.shape}, the base policy's {base.shape}")
    if not (np.isfinite(base).all() and np.isfinite(agent).all()):
        raise ValueError("residual action: NaN or inf in the base policy's or the agent's action")
    if space == "split":
        from iscc_gym.sim.task import action_to_split, split_to_action

        z = np.log(np.maximum(action_to_split(base), 1e-9)) + scale * np.clip(agent, -1.0, 1.0)
        w = np.exp(z - z.max(axis=-1, keepdims=True))
        return split_to_action(w / w.sum(axis=-1, keepdims=True))
    return np.clip(base + scale * np.clip(agent, -1.0, 1.0), -1.0, 1.0).astype(np.float32)


class ResidualVecEnv(VecEnvWrapper):
    """An SB3 VecEnv whose actions correct ``base``'s (see the module docstring).

    Parameters
    ----------
    venv : VecEnv
        The env, giving raw observations (below any VecNormalize).
    base : a policy (``predict(obs, state, episode_start)`` on raw observations, batched)
    scale : float
        :math:`s`, in (0, 2].
    space : str
        ``residual_space`` (:data:`RESIDUAL_SPACES`).
    world_entries : int
        The observation's last entries the base does not read (the world block an asymmetric critic is shown,
        ``agents.world_critic``; 0: none).
    """

    def __init__(self, venv, base, scale: float, space: str = "action", world_entries: int = 0):
        super().__init__(venv)
        self.base = base
        self.world_entries = int(world_entries)
        self.scale = check_scale(scale)
        self.space = check_space(space)
        self._obs = None
        self._state = None
        self._start = np.ones(self.num_envs, dtype=bool)

    def reset(self):
        self._obs = self.venv.reset()
        self._state = None
        self._start = np.ones(self.num_envs, dtype=bool)
        return self._obs

    def step_async(self, actions) -> None:
        if self._obs is None:
            raise RuntimeError("ResidualVecEnv.step before reset: call reset() first")
        obs = self._obs[:, :-self.world_entries] if self.world_entries else self._obs
        base, self._state = self.base.predict(obs, state=self._state, episode_start=self._start, deterministic=True)
        self.venv.step_async(residual_action(base, np.asarray(actions).reshape(np.shape(base)), self.scale,
                                             self.space))

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        self._obs, self._start = obs, np.asarray(dones, dtype=bool)
        return obs, rewards, dones, infos


class ResidualPolicy:
    """Play a trained residual agent: ``base``'s action corrected by ``agent``'s (the policy protocol,
    on raw observations).

    Parameters
    ----------
    base : a policy (the run's ``residual`` spec, built for its scenario)
    agent : :class:`agents.sb3_policy.SB3Policy`
        The trained correction.
    scale : float
        The run's ``residual_scale``.
    spec : str
        The base's spec (for ``repr``).
    space : str
        The run's ``residual_space``.
    """

    def __init__(self, base, agent, scale: float, spec: str = "base", space: str = "action"):
        self.base, self.agent, self.scale, self.spec = base, agent, check_scale(scale), spec
        self.space = check_space(space)
        self.obs_shape = agent.obs_shape
        self.model = agent.model

    def predict(self, obs, state=None, episode_start=None, deterministic: bool = True):
        """The env action(s) for raw observation(s) (one, or a batch); the state is the pair of the agent's
        (a recurrent agent's LSTM state) and the base's.
        """
        agent_state, base_state = (None, None) if state is None else state
        correction, agent_state = self.agent.predict(obs, state=agent_state, episode_start=episode_start,
                                                     deterministic=deterministic)
        base, base_state = self.base.predict(obs, state=base_state, episode_start=episode_start, deterministic=True)
        return residual_action(base, correction, self.scale, self.space), (agent_state, base_state)

    def __repr__(self) -> str:
        return f"ResidualPolicy(base={self.spec!r}, scale={self.scale}" + (
            f", space={self.space!r})" if self.space != "action" else ")")


def residual_record(spec: str, scale: float, scenario: str = "paper", env_overrides: dict | None = None,
                    space: str = "action") -> dict:
    """The record of a residual agent on base ``spec`` at ``scale``, the base built for preset ``scenario`` with
    ``env_overrides``: :data:`RECORD_KEYS`, ``residual_params`` the tuned parameters the base reads now
    (:func:`agents.tuned_record`'s record; None for a spec that reads none), and ``residual_space`` where it is not
    the default ``action``. Resolved once per run, it is what the base is built from (:func:`base_policy`) in
    training and at every load.
    """
    from iscc_gym.agents import tuned_record
    from iscc_gym.agents.tuned_records import load_tuned

    from iscc_gym import make_scenario

    overrides = dict(env_overrides or {})
    name = tuned_record(spec, make_scenario(scenario, **overrides))
    params = dict(load_tuned(name)["params"]) if name is not None else None
    record = {"residual": str(spec), "residual_scale": check_scale(scale), "scenario": str(scenario),
              "env_overrides": overrides, "residual_params": params}
    if check_space(space) != "action":
        record["residual_space"] = space
    return yaml.safe_load(yaml.safe_dump(record))


def write_record(model_path: str | Path, record: dict) -> None:
    """Add ``record`` to the model ``.zip`` at ``model_path`` as its :data:`RECORD_ENTRY` (call it on the file
    before it is renamed into place, as :func:`train.runs.save_unit` does).
    """
    with zipfile.ZipFile(model_path, "a") as z:
        if RECORD_ENTRY in z.namelist():
            raise ValueError(f"{model_path}: holds a {RECORD_ENTRY} already")
        z.writestr(RECORD_ENTRY, yaml.safe_dump({k: record[k] for k in RECORD_KEYS + ("residual_space",)
                                                 if k in record}, sort_keys=False))


def add_record(model_path: str | Path, record: dict) -> Path:
    """:func:`write_record` into a model ``.zip`` in place, atomically (a copy is written, then renamed onto it):
    a residual agent saved before models held their record. SB3's own entries are left byte for byte.
    """
    from iscc_gym.files import atomic_target

    with atomic_target(model_path) as tmp:
        shutil.copyfile(model_path, tmp)
        write_record(tmp, record)
    return Path(model_path)


def read_record(model_path: str | Path) -> dict | None:
    """The residual record a model ``.zip`` holds (None: not a residual agent's, or one saved before models held
    their record), its fields checked (:func:`check_record`).

    Raises
    ------
    ValueError
        Naming the file and the field: a record that is not valid YAML, not a mapping or with a bad field.
    """
    try:
        with zipfile.ZipFile(model_path) as z:
            if RECORD_ENTRY not in z.namelist():
                return None
            text = z.read(RECORD_ENTRY).decode()
    except (zipfile.BadZipFile, EOFError, OSError, UnicodeDecodeError) as e:
        raise ValueError(f"{model_path}: not a complete SB3 model file (truncated or corrupt: {e})") from None
    where = f"{model_path} (its {RECORD_ENTRY})"
    try:
        record = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise ValueError(f"{where}: not valid YAML ({str(e).splitlines()[0]}); {RECORD_FIX}") from None
    if not isinstance(record, dict) or set(record) - {"residual_space"} != set(RECORD_KEYS):
        raise ValueError(f"{where}: {record!r}; expected the mapping of {', '.join(RECORD_KEYS)}; {RECORD_FIX}")
    check_record(record, where, RECORD_FIX)
    return record


def check_record(run: dict, where: str, fix: str, prefix: str = "") -> None:
    """Check the residual fields of a run's settings (``run``: a record, a manifest's ``run``, a config's
    ``args``): ``ValueError`` ``"{where}: {prefix}FIELD = VALUE; what it must be ({fix})"`` for a bad one.
    """
    from iscc_gym.agents.tuned_records import is_params

    from iscc_gym import SCENARIOS

    def fail(key, want):
        raise ValueError(f"{where}: {prefix}{key} = {run.get(key)!r}; expected {want} ({fix})")

    if not isinstance(run.get("residual"), str) or not run["residual"].strip():
        fail("residual", "the base policy's spec (an agents.make_policy spec, e.g. myopic)")
    try:
        check_scale(run.get("residual_scale"))
    except ValueError:
        fail("residual_scale", "a number in (0, 2]")
    if "scenario" in run and run["scenario"] not in SCENARIOS:
        fail("scenario", f"a preset, one of {sorted(SCENARIOS)}")
    if "env_overrides" in run and not isinstance(run["env_overrides"], dict):
        fail("env_overrides", "a mapping of Scenario fields")
    if run.get("residual_space", "action") not in RESIDUAL_SPACES:
        fail("residual_space", f"one of {', '.join(RESIDUAL_SPACES)}")
    if run.get("residual_params") is not None and not is_params(run["residual_params"]):
        fail("residual_params", "null or the base's tuned parameters, a mapping of names to numbers")


def base_policy(run: dict, where: str = "the run", fix: str = "retrain", prefix: str = "", obs_shape=None):
    """The base policy of a residual run's settings ``run`` (:func:`check_record` first): ``run["residual"]`` built
    for the run's scenario with the recorded ``residual_params`` (a run recorded before they were: the spec's
    tuning record now). A recorded base whose tuning record has been re-tuned since plays the recorded
    parameters, with a warning. ``obs_shape``: the agent's observations, which the scenario's must be.

    Raises
    ------
    ValueError
        ``"{where}: {prefix}FIELD = VALUE; ... ({fix})"`` for a field that does not build a base (or a scenario of
        other observations than ``obs_shape``).
    """
    from iscc_gym.agents import make_policy, tuned_record
    from iscc_gym.agents.tuned_records import TUNED_DIR, load_tuned

    from iscc_gym import make_scenario
    from iscc_gym.sim.schema import obs_size

    check_record(run, where, fix, prefix)
    try:
        scenario = make_scenario(run.get("scenario") or "paper", **(run.get("env_overrides") or {}))
    except (ValueError, TypeError) as e:
        raise ValueError(f"{where}: {prefix}scenario = {run.get('scenario')!r} with env_overrides = "
                         f"{run.get('env_overrides')!r} does not build the base's scenario ({e}) ({fix})") from None
    if obs_shape is not None and (obs_size(scenario),) != tuple(obs_shape):
        raise ValueError(f"{where}: {prefix}scenario = {run.get('scenario')!r} (env_overrides "
                         f"{run.get('env_overrides') or {}}) gives observations of size {obs_size(scenario)}, the "
                         f"agent takes {tuple(obs_shape)} ({fix})")
    field = "residual"
    try:
        name = tuned_record(run["residual"], scenario)
        params = run.get("residual_params")
        if params is not None:
            field = "residual_params"
            now = load_tuned(name)["params"] if name is not None and (TUNED_DIR / f"{name}.yml").exists() else None
            if now is not None and now != params:
                warnings.warn(f"{where}: its base {run['residual']!r} plays the parameters it was trained with "
                              f"({params}), not {TUNED_DIR / name}.yml's {now} (re-tuned since)", UserWarning,
                              stacklevel=3)
        base = make_policy(run["residual"], scenario, tuned=params)
    except (ValueError, TypeError, KeyError, FileNotFoundError) as e:
        raise ValueError(f"{where}: {prefix}{field} = {run.get(field)!r} does not build the base policy "
                         f"({type(e).__name__}: {e}) ({fix})") from None
    return base
