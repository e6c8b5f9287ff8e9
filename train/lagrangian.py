r"""Constrained training: SB3 on the reward minus Lagrange multipliers times the constraint costs.

``python -m train --cost-limit rate=0.05,stability=0.0`` trains on

.. math::
    r'_n = r_n - \sum_k \lambda_k\, c_{k,n},\qquad
    c_{\mathrm{rate},n} = 1[\texttt{info["cost\_rate"]} > 0],\quad
    c_{\mathrm{stability},n} = 1[\texttt{info["cost\_stability"]} > 0],

the costs read from the env's ``info`` (no reward re-derivation), as **outage indicators**: the limit
of a cost is the fraction of slots allowed to violate it, the way a link designer states a rate
requirement ("met in 95 % of the slots"). The multipliers follow **projected dual ascent** (plain, not
PID-Lagrangian), once per rollout:

.. math:: \lambda_k \leftarrow \max\bigl(0,\ \lambda_k + \eta\,(\bar c_k - d_k)\bigr)

with :math:`\bar c_k` the rollout's outage fraction, :math:`d_k` the limit and :math:`\eta` the
multiplier learning rate (``--lagrange-lr``). Unless the run sets them, the env's own fixed penalty
weights ``w_rate`` and ``w_stab`` are set to 0 for a constrained run, so the reward is minus the
tracking error and the multipliers alone price the costs. The multipliers and outage fractions are
logged to TensorBoard (``lagrange/``), saved in the run's ``lagrange.yml`` and its ``summary.yml``,
and with their history in every checkpoint (``--resume`` continues them from there; a multiplier that
is negative, NaN or not a number is refused, naming the file and the field).

On the multi-drone env (``iscc_gym/ISCC-Multi-v0``) ``info`` carries one cost per drone; a slot's
indicator is the share of its drones in violation, so the limit is the fraction of drone-slots allowed
to violate (the team reward's penalties are summed over drones, so one drone's violation costs the
same whichever drone it is).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import yaml
from iscc_gym.agents.sb3_policy import LAGRANGE_FILE
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnvWrapper

from iscc_gym.files import write_atomic

__all__ = ["COSTS", "parse_cost_limits", "LagrangianVecEnv", "LagrangeCallback", "LAGRANGE_FILE", "check_lagrange",
           "load_lambdas"]

#: Constraint name -> the ``info`` key whose positive value marks a violating slot.
COSTS = {"rate": "cost_rate", "stability": "cost_stability"}
#: ``lagrange.yml`` is rewritten at most this often during training (its history grows by one entry per
#: rollout; every checkpoint holds the whole record, and the run's end writes it).
SAVE_EVERY_S = 30.0
#: libyaml's dumper where PyYAML has it (the history of a long run is ~1,000 entries).
_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)


def parse_cost_limits(text: str) -> dict[str, float]:
    """``"rate=0.05,stability=0.0"`` -> ``{"rate": 0.05, "stability": 0.0}``; a clear ``ValueError`` naming
    the flag and the fix on a bad name or value (a limit is an outage fraction in [0, 1]).
    """
    limits: dict[str, float] = {}
    for part in str(text).split(","):
        name, sep, value = (x.strip() for x in part.partition("="))
        if not sep or name not in COSTS:
            raise ValueError(f"--cost-limit {text!r}: use NAME=FRACTION pairs with NAME in {sorted(COSTS)}, "
                             "e.g. --cost-limit rate=0.05,stability=0.0")
        try:
            v = float(value)
        except ValueError:
            raise ValueError(f"--cost-limit {text!r}: {name}={value!r} is not a number; use a fraction in [0, 1]") \
                from None
        if not 0.0 <= v <= 1.0:
            raise ValueError(f"--cost-limit {text!r}: {name}={v} is outside [0, 1]; a limit is the fraction of "
                             "slots allowed to violate the constraint")
        if name in limits:
            raise ValueError(f"--cost-limit {text!r}: {name} is given twice")
        limits[name] = v
    return limits


class LagrangianVecEnv(VecEnvWrapper):
    """Rewards minus ``lambdas . outage indicators``; counts the indicators for the dual update.

    Parameters
    ----------
    venv : VecEnv
        Whose ``infos`` carry the keys of :data:`COSTS` (the batched env: pass them in ``info_keys``).
    limits : dict
        Constraint name -> outage-fraction limit (:func:`parse_cost_limits`).
    lambdas : dict, optional
        Starting multipliers (default 0).
    """

    def __init__(self, venv, limits: dict[str, float], lambdas: dict[str, float] | None = None):
        super().__init__(venv)
        self.names = list(limits)
        self.limits = np.array([limits[k] for k in self.names], dtype=np.float64)
        lam = lambdas or {}
        self.lambdas = np.array([float(lam.get(k, 0.0)) for k in self.names], dtype=np.float64)
        self.reset_counts()

    def reset_counts(self) -> None:
        self.count = np.zeros(len(self.names))
        self.slots = 0

    def reset(self):
        return self.venv.reset()

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        ind = np.zeros((len(infos), len(self.names)))
        for i, info in enumerate(infos):
            for j, name in enumerate(self.names):
                key = COSTS[name]
                if key not in info:
                    raise KeyError(f"info has no {key!r}: a constrained run needs the env's costs in info "
                                   f"(ISCCBatchedVecEnv(info_keys=({key!r}, ...)))")
                ind[i, j] = np.mean(np.asarray(info[key]) > 0.0)  # multi-drone env: the share of drones
        self.count += ind.sum(axis=0)
        self.slots += len(infos)
        return obs, rewards - ind @ self.lambdas, dones, infos

    def as_dict(self) -> dict:
        return {"lambdas": dict(zip(self.names, self.lambdas.tolist(), strict=True)),
                "limits": dict(zip(self.names, self.limits.tolist(), strict=True))}


class LagrangeCallback(BaseCallback):
    """Projected dual ascent of :class:`LagrangianVecEnv`'s multipliers at every rollout end; logs
    ``lagrange/lambda_<name>`` and ``lagrange/outage_<name>`` and writes ``out/lagrange.yml`` (at most
    every :data:`SAVE_EVERY_S` seconds, and by :meth:`save` at the end).
    """

    def __init__(self, wrapper: LagrangianVecEnv, lr: float, out: str | Path | None = None,
                 history: list[dict] | None = None):
        super().__init__()
        if not (lr > 0.0 and np.isfinite(lr)):
            raise ValueError(f"lagrange_lr = {lr!r}; use a positive number, e.g. 0.05")
        self.wrapper, self.lr, self.out = wrapper, float(lr), out
        self.history: list[dict] = list(history or [])  # of the run it resumes, continued
        self.saved_at = -np.inf

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        w = self.wrapper
        if w.slots == 0:
            return
        outage = w.count / w.slots
        w.lambdas = np.maximum(0.0, w.lambdas + self.lr * (outage - w.limits))
        for j, name in enumerate(w.names):
            self.logger.record(f"lagrange/lambda_{name}", float(w.lambdas[j]))
            self.logger.record(f"lagrange/outage_{name}", float(outage[j]))
        self.history.append({"timesteps": int(self.num_timesteps),
                             "outage": dict(zip(w.names, outage.tolist(), strict=True)),
                             "lambdas": dict(zip(w.names, w.lambdas.tolist(), strict=True))})
        w.reset_counts()
        if time.perf_counter() - self.saved_at >= SAVE_EVERY_S:
            self.save()

    def state(self) -> dict:
        """The multipliers, limits, step and whole history (``lagrange.yml``, and a checkpoint's)."""
        return {**self.wrapper.as_dict(), "lr": self.lr, "history": list(self.history)}

    def save(self) -> None:
        if self.out is not None:
            write_atomic(Path(self.out) / LAGRANGE_FILE, yaml.dump(self.state(), Dumper=_DUMPER, sort_keys=False))
            self.saved_at = time.perf_counter()


def _number(value, where: str, minimum: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value) or (
            minimum is not None and value < minimum):
        bound = f" >= {minimum:g}" if minimum is not None else ""
        raise ValueError(f"{where} = {value!r}; a multiplier file holds finite numbers{bound}")
    return float(value)


def check_lagrange(doc, where: str, names: list[str] | None = None) -> dict:
    """A multipliers record (``lagrange.yml``, or a checkpoint's ``lagrange`` entry) checked: ``lambdas``
    a mapping of constraint name -> finite number >= 0 (``names``, if given, exactly those), ``history``
    a list of ``{timesteps, outage, lambdas}``. Returns it with ``lambdas`` as floats.

    Raises
    ------
    ValueError
        Naming ``where`` (the file) and the field: a negative, NaN or non-numeric multiplier, a missing
        or unknown constraint, a malformed history.
    """
    if not isinstance(doc, dict):
        raise ValueError(f"{where}: not a multipliers record (a mapping with lambdas and history)")
    lam = doc.get("lambdas")
    if not isinstance(lam, dict) or not lam:
        raise ValueError(f"{where}: lambdas = {lam!r}; expected a mapping of constraint name -> multiplier")
    if names is not None and sorted(lam) != sorted(names):
        raise ValueError(f"{where}: lambdas are of the constraints {sorted(lam)}, the run's are {sorted(names)}")
    out = dict(doc)
    out["lambdas"] = {k: _number(v, f"{where}: lambdas.{k}", 0.0) for k, v in lam.items()}
    history = doc.get("history") or []
    if not isinstance(history, list):
        raise ValueError(f"{where}: history = {history!r}; expected a list")
    for i, h in enumerate(history):
        if not (isinstance(h, dict) and isinstance(h.get("timesteps"), int) and isinstance(h.get("lambdas"), dict)
                and isinstance(h.get("outage"), dict)):
            raise ValueError(f"{where}: history[{i}] = {h!r}; expected {{timesteps, outage, lambdas}}")
        for k, v in h["lambdas"].items():
            _number(v, f"{where}: history[{i}].lambdas.{k}", 0.0)
        for k, v in h["outage"].items():
            _number(v, f"{where}: history[{i}].outage.{k}", 0.0)
    out["history"] = list(history)
    return out


def load_lagrange(out: str | Path, names: list[str] | None = None) -> dict | None:
    """The checked multipliers record (:func:`check_lagrange`) of a run directory's ``lagrange.yml``, or None
    if there is none; a ``ValueError`` naming the file for one that is not valid YAML or not valid.
    """
    p = Path(out) / LAGRANGE_FILE
    if not p.is_file():
        return None
    try:
        doc = yaml.safe_load(p.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as e:
        raise ValueError(f"{p}: not valid YAML ({str(e).splitlines()[0]})") from None
    return check_lagrange(doc, str(p), names)


def load_lambdas(out: str | Path) -> dict[str, float] | None:
    """The multipliers saved in a run directory's ``lagrange.yml``, or None (checked: :func:`load_lagrange`)."""
    doc = load_lagrange(out)
    return None if doc is None else doc["lambdas"]
