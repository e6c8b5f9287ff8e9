"""Common-random-number evaluation of policies and schemes on the batched env.

Every policy plays the same list of seeds: sub-env k of the native vector env is reset with seed
s_k, so every policy faces the same trajectories, shadowing, fading, measurement noise, process
noise and packet-drop draws (the env draws the same normals whatever the action). Differences
between policies are therefore paired per episode, and their confidence intervals are tight.

``evaluate({"sca": policy, "equal": other}, seeds=range(101, 121))`` returns, per policy, the
per-episode metrics, their mean and 95 % CI (Student t), and paired differences against a reference
policy. A policy may come with Scenario overrides (a *scheme*: ``observation_source="gnss"``,
``control_mode="open_loop"``), so one evaluator scores everything.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from iscc_gym.envs.vector import ISCCVectorEnv
from iscc_gym.scenario import Scenario, make_scenario

from .report import mean_ci

__all__ = ["Entry", "summarize", "run_episodes", "Actor", "EPISODE_METRICS", "METRIC_RANGES", "horizon_slots"]

#: Per-episode metrics (means over the episode's slots unless stated).
EPISODE_METRICS = {
    "reward": "episode reward (sum)",
    "tracking_error_m": "mean tracking error (m)",
    "mse_m2": "mean squared tracking error (m^2; the RMS error is its square root)",
    "rate_violation": "fraction of slots with data rate below R_min (with a queue: slots that drop bits)",
    "stability_violation": "fraction of slots with eps_ctrl above eps*",
    "violation": "fraction of slots with either violation",
    "cost": "episode cost (sum of cost_rate + cost_stability)",
    "peb_m": "mean PEB (m)",
    "peb_median_m": "median PEB over the episode's slots (and drones) (m): a few slots of a lost radar lift the mean",
    "rate_comm_mbps": "mean data rate (Mbit/s)",
    "eps_ctrl": "mean control packet-loss probability",
    "packet_loss": "fraction of control packets lost",
    "terminated": "episode ended by loss of track (0/1)",
    "length": "slots played",
    "alpha_sen": "mean sensing share",
    "alpha_ctrl": "mean control share",
    "alpha_comm": "mean data share",
    "dropped_mbit": "data dropped at its deadline (Mbit, sum; 0 without a queue)",
}

_FRACTION = (0.0, 1.0)
_NONNEG = (0.0, math.inf)
#: The range of every per-episode metric: a confidence interval is clamped to it (a fraction's CI stays
#: inside [0, 1], an error's or a count's above 0). Metrics not listed (the reward) are unbounded.
METRIC_RANGES = {
    "tracking_error_m": _NONNEG, "mse_m2": _NONNEG, "rate_violation": _FRACTION, "stability_violation": _FRACTION,
    "violation": _FRACTION, "cost": _NONNEG, "peb_m": _NONNEG, "peb_median_m": _NONNEG, "rate_comm_mbps": _NONNEG,
    "eps_ctrl": _FRACTION,
    "packet_loss": _FRACTION, "terminated": _FRACTION, "length": _NONNEG, "alpha_sen": _FRACTION,
    "alpha_ctrl": _FRACTION, "alpha_comm": _FRACTION, "dropped_mbit": _NONNEG,
}

#: How often (in slots) :func:`run_episodes` reports progress.
PROGRESS_EVERY = 100


@dataclass
class Entry:
    """A policy to evaluate and the Scenario overrides of its scheme (empty: the plain env)."""

    policy: Any
    overrides: dict = field(default_factory=dict)


def horizon_slots(scenario: str | Scenario = "paper", max_steps: int | None = None, **overrides) -> int:
    """The slots :func:`run_episodes` plays at most per episode: the mission's, or ``max_steps`` if fewer."""
    s = make_scenario(scenario, **overrides)
    return s.n_slots if max_steps is None else min(int(max_steps), s.n_slots)


class Actor:
    """A policy's deterministic actions along ``n_envs`` episodes played from their first slot together: the
    recurrent state (a ``ppo_lstm`` agent's memory, per-slot SCA's warm start) is carried from slot to slot and
    ``episode_start`` is True on the first slot only, as SB3's own rollouts call ``predict``. The step of every
    rollout of the evaluator (:func:`run_episodes`, :func:`experiments.urban_figure.play_mission`), so they
    play the same policy.
    """

    def __init__(self, policy, n_envs: int):
        self.policy = policy
        self.state = None
        self.episode_start = np.ones(int(n_envs), dtype=bool)

    def __call__(self, obs) -> np.ndarray:
        """The action(s) for ``obs`` (a batch of ``n_envs``, or one observation when ``n_envs`` is 1)."""
        action, self.state = self.policy.predict(obs, state=self.state, episode_start=self.episode_start,
                                                 deterministic=True)
        self.episode_start = np.zeros_like(self.episode_start)
        return action


#: The Scenario fields a policy's ``scenario_overrides`` may set (the oracle's view of the same missions).
SHOWN_OVERRIDES = frozenset({"preview_source", "show_world"})


def run_episodes(policy, seeds: Sequence[int], scenario: str | Scenario = "paper", max_steps: int | None = None,
                 record: int = 0, progress: Callable[[int], None] | None = None, n_drones: int | None = None,
                 trace_info: Sequence[str] = (), **overrides) -> dict:
    """Play one episode per seed, all at once on the batched env, with ``policy.predict``
    (deterministic). Returns per-episode metric arrays (:data:`EPISODE_METRICS`), the wall time,
    and, if ``record`` > 0, the slot-by-slot traces of the first ``record`` episodes.

    ``progress(n)``, if given, is called every :data:`PROGRESS_EVERY` slots with the slots played since
    its last call; the calls add up to :func:`horizon_slots` (the rest is reported when every episode
    ended early). A policy's ``scenario_overrides`` attribute (the ``oracle``'s ``preview_source="truth"``)
    is applied to the scenario: only fields of :data:`SHOWN_OVERRIDES`, which change what the env shows, not
    the missions or their draws (common random numbers hold).

    ``trace_info``: info keys (any of the env's, and ``"reward"``) traced slot by slot too for the first ``record``
    episodes; with ``record``, ``missions`` holds those episodes' mission rows (the vector env's ``missions``).
    """
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise ValueError("seeds is empty; pass at least one seed")
    if max_steps is not None and int(max_steps) < 1:
        raise ValueError(f"max_steps = {max_steps}: play at least one slot (or None: the whole mission)")
    rate_drone = overrides.pop("rate_min_per_drone_bps", None)
    shown = dict(getattr(policy, "scenario_overrides", None) or {})
    if set(shown) - SHOWN_OVERRIDES:
        raise ValueError(f"a policy's scenario_overrides may change only what the env shows "
                         f"({sorted(SHOWN_OVERRIDES)}), never the missions; got {sorted(shown)}")
    s = make_scenario(scenario, **{**overrides, **shown})
    k = len(seeds)
    venv = ISCCVectorEnv(num_envs=k, scenario=s, n_drones=n_drones, rate_min_per_drone_bps=rate_drone)
    drones = (lambda x: np.mean(x, axis=-1)) if n_drones else (lambda x: x)
    horizon = s.n_slots if max_steps is None else min(int(max_steps), s.n_slots)
    reported = 0
    t0 = time.perf_counter()
    obs, _ = venv.reset(seed=seeds)
    missions = venv.missions(record) if record else None
    alive = np.ones(k, dtype=bool)
    sums = {key: np.zeros(k) for key in ("reward", "tracking_error_m", "mse_m2", "rate_violation",
                                         "stability_violation", "violation", "cost", "peb_m", "rate_comm_mbps",
                                         "eps_ctrl", "packet_loss", "alpha_sen", "alpha_ctrl", "alpha_comm",
                                         "dropped_mbit")}
    length = np.zeros(k)
    terminated_any = np.zeros(k, dtype=bool)
    traces: dict[str, list] = {"alpha": [], "tracking_error_m": [], "pos": [], "ref_pos": []}
    extra = [key for key in dict.fromkeys(trace_info) if key not in traces]  # the others are traced anyway
    traces.update({key: [] for key in extra})
    pebs = []  # each slot's PEB (k, drones), NaN once an episode ended: the median's samples
    act = Actor(policy, k)
    for t in range(horizon):
        if progress is not None and t - reported >= PROGRESS_EVERY:
            progress(t - reported)
            reported = t
        action = act(obs)
        obs, reward, term, trunc, info = venv.step(np.asarray(action, dtype=np.float32).reshape(k, -1))
        a = alive.astype(float)
        cr, cs, err = info["cost_rate"], info["cost_stability"], info["tracking_error_m"]
        sums["reward"] += a * reward
        sums["tracking_error_m"] += a * drones(err)
        sums["mse_m2"] += a * drones(err * err)
        sums["rate_violation"] += a * drones(cr > 0)
        sums["stability_violation"] += a * drones(cs > 0)
        sums["violation"] += a * drones((cr > 0) | (cs > 0))
        sums["cost"] += a * (drones(cr + cs) * (n_drones or 1))
        sums["peb_m"] += a * drones(info["peb_m"])
        pebs.append(np.where(alive[:, None], np.asarray(info["peb_m"], dtype=float).reshape(k, -1), np.nan))
        sums["rate_comm_mbps"] += a * drones(info["rate_comm_bps"]) * 1e-6
        sums["eps_ctrl"] += a * drones(info["eps_ctrl"])
        sums["packet_loss"] += a * drones(~info["packet_received"])
        sums["dropped_mbit"] += a * drones(info["bits_dropped"]) * 1e-6
        alpha = info["alpha"].sum(axis=-2) if n_drones else info["alpha"]
        for j, name in enumerate(("alpha_sen", "alpha_ctrl", "alpha_comm")):
            sums[name] += a * alpha[:, j]
        length += a
        if record:
            traces["alpha"].append(alpha[:record].copy())
            traces["tracking_error_m"].append(np.where(alive[:record], drones(err)[:record], np.nan))
            pos, ref_pos = venv.positions(record)
            traces["pos"].append(pos)
            traces["ref_pos"].append(ref_pos)
            for key in extra:
                traces[key].append(np.array(reward if key == "reward" else info[key])[:record])
        terminated_any |= term & alive
        alive &= ~(term | trunc)
        if not alive.any():
            break
    wall = time.perf_counter() - t0
    if progress is not None and horizon > reported:
        progress(horizon - reported)
    out = {key: (val if key in ("reward", "cost", "dropped_mbit") else val / np.maximum(length, 1))
           for key, val in sums.items()}
    out["peb_median_m"] = np.nanmedian(np.stack(pebs, axis=1).reshape(k, -1), axis=1)
    out["terminated"] = terminated_any.astype(float)
    out["length"] = length
    res = {"episodes": out, "seeds": seeds, "wall_time_s": wall, "slots": int(length.sum())}
    if record:
        res["traces"] = {key: np.array(v) for key, v in traces.items()}
        res["missions"] = missions
    return res


def summarize(runs: Mapping[str, dict], seeds: Sequence[int], reference: str | None = None,
              focus: str | None = None) -> dict:
    """The result of :func:`evaluate` from the :func:`run_episodes` results of every policy (played on
    ``seeds``, e.g. in separate processes). With ``focus`` (a policy name), ``focus_paired`` holds
    its paired differences against every other policy (``<focus>_vs_<name>``).
    """
    if reference is not None and reference not in runs:
        raise ValueError(f"reference = {reference!r} is not one of the policies {list(runs)}")
    traces = {name: run["traces"] for name, run in runs.items() if "traces" in run}
    res: dict[str, Any] = {"seeds": [int(s) for s in seeds], "reference": reference, "policies": {}, "paired": {}}
    for name, run in runs.items():
        summary: dict[str, Any] = {"wall_time_s": run["wall_time_s"], "slots": run["slots"]}
        for metric, vals in run["episodes"].items():
            summary[f"{metric}_mean"], summary[f"{metric}_ci95"] = mean_ci(vals, bounds=METRIC_RANGES.get(metric))
        summary["episodes"] = {m: np.asarray(v).tolist() for m, v in run["episodes"].items()}
        res["policies"][name] = summary
    if reference is not None:
        for name, run in runs.items():
            if name != reference:
                res["paired"][f"{name}_vs_{reference}"] = _paired(run["episodes"], runs[reference]["episodes"])
    if focus is not None and focus in runs:
        res["focus"] = focus
        res["focus_paired"] = {f"{focus}_vs_{name}": _paired(runs[focus]["episodes"], run["episodes"])
                               for name, run in runs.items() if name != focus}
    if traces:
        res["traces"] = traces
    return res


def _paired(episodes: Mapping, ref: Mapping) -> dict:
    """Per-metric mean and 95 % CI of ``episodes - ref`` (per episode), clamped to the range a difference
    of the metric can take (a difference of fractions inside [-1, 1]); ``ci95`` is the reward's.
    """
    pair = {}
    for metric, vals in episodes.items():
        low, high = METRIC_RANGES.get(metric, (-math.inf, math.inf))
        pair[f"{metric}_diff_mean"], pair[f"{metric}_diff_ci95"] = mean_ci(
            np.asarray(vals) - np.asarray(ref[metric]), bounds=(low - high, high - low))
    pair["ci95"] = pair["reward_diff_ci95"]  # the headline: episode reward
    return pair
