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

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from iscc_gym.scenario import Scenario, make_scenario
from iscc_gym.vector import ISCCVectorEnv

__all__ = ["Entry", "evaluate", "summarize", "run_episodes", "mean_ci", "format_table", "EPISODE_METRICS"]

#: Per-episode metrics (means over the episode's slots unless stated).
EPISODE_METRICS = {
    "reward": "episode reward (sum)",
    "tracking_error_m": "mean tracking error (m)",
    "rate_violation": "fraction of slots with data rate below R_min",
    "stability_violation": "fraction of slots with eps_ctrl above eps*",
    "violation": "fraction of slots with either violation",
    "cost": "episode cost (sum of cost_rate + cost_stability)",
    "peb_m": "mean PEB (m)",
    "rate_comm_mbps": "mean data rate (Mbit/s)",
    "eps_ctrl": "mean control packet-loss probability",
    "packet_loss": "fraction of control packets lost",
    "terminated": "episode ended by loss of track (0/1)",
    "length": "slots played",
    "alpha_sen": "mean sensing share",
    "alpha_ctrl": "mean control share",
    "alpha_comm": "mean data share",
}


@dataclass
class Entry:
    """A policy to evaluate and the Scenario overrides of its scheme (empty: the plain env)."""

    policy: Any
    overrides: dict = field(default_factory=dict)


def run_episodes(policy, seeds: Sequence[int], scenario: str | Scenario = "paper", max_steps: int | None = None,
                 record: int = 0, **overrides) -> dict:
    """Play one episode per seed, all at once on the batched env, with ``policy.predict``
    (deterministic). Returns per-episode metric arrays (:data:`EPISODE_METRICS`), the wall time,
    and, if ``record`` > 0, the slot-by-slot traces of the first ``record`` episodes."""
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise ValueError("seeds is empty; pass at least one seed")
    s = make_scenario(scenario, **overrides)
    k = len(seeds)
    venv = ISCCVectorEnv(num_envs=k, scenario=s)
    horizon = s.n_slots if max_steps is None else min(int(max_steps), s.n_slots)
    t0 = time.perf_counter()
    obs, _ = venv.reset(seed=seeds)
    alive = np.ones(k, dtype=bool)
    sums = {key: np.zeros(k) for key in ("reward", "tracking_error_m", "rate_violation", "stability_violation",
                                         "violation", "cost", "peb_m", "rate_comm_mbps", "eps_ctrl",
                                         "packet_loss", "alpha_sen", "alpha_ctrl", "alpha_comm")}
    length = np.zeros(k)
    terminated_any = np.zeros(k, dtype=bool)
    traces: dict[str, list] = {"alpha": [], "tracking_error_m": [], "pos": [], "ref_pos": []}
    state = None
    episode_start = np.ones(k, dtype=bool)
    for _ in range(horizon):
        action, state = policy.predict(obs, state=state, episode_start=episode_start, deterministic=True)
        episode_start = np.zeros(k, dtype=bool)
        obs, reward, term, trunc, info = venv.step(np.asarray(action, dtype=np.float32).reshape(k, 3))
        a = alive.astype(float)
        cr, cs = info["cost_rate"], info["cost_stability"]
        sums["reward"] += a * reward
        sums["tracking_error_m"] += a * info["tracking_error_m"]
        sums["rate_violation"] += a * (cr > 0)
        sums["stability_violation"] += a * (cs > 0)
        sums["violation"] += a * ((cr > 0) | (cs > 0))
        sums["cost"] += a * (cr + cs)
        sums["peb_m"] += a * info["peb_m"]
        sums["rate_comm_mbps"] += a * info["rate_comm_bps"] * 1e-6
        sums["eps_ctrl"] += a * info["eps_ctrl"]
        sums["packet_loss"] += a * ~info["packet_received"]
        for j, name in enumerate(("alpha_sen", "alpha_ctrl", "alpha_comm")):
            sums[name] += a * info["alpha"][:, j]
        length += a
        if record:
            traces["alpha"].append(info["alpha"][:record].copy())
            traces["tracking_error_m"].append(np.where(alive[:record], info["tracking_error_m"][:record], np.nan))
            traces["pos"].append(venv._state.x[:record, :3].copy())
            traces["ref_pos"].append(venv._state.ref[np.arange(min(record, k)), venv._state.n[:record], :3].copy())
        terminated_any |= term & alive
        alive &= ~(term | trunc)
        if not alive.any():
            break
    wall = time.perf_counter() - t0
    out = {key: (val if key in ("reward", "cost") else val / np.maximum(length, 1)) for key, val in sums.items()}
    out["terminated"] = terminated_any.astype(float)
    out["length"] = length
    res = {"episodes": out, "seeds": seeds, "wall_time_s": wall, "slots": int(length.sum())}
    if record:
        res["traces"] = {key: np.array(v) for key, v in traces.items()}
    return res


def mean_ci(x, confidence: float = 0.95) -> tuple[float, list[float]]:
    """Mean and the Student-t confidence interval of the mean of samples ``x``."""
    x = np.asarray(x, dtype=float)
    m = float(x.mean())
    if x.size < 2:
        return m, [m, m]
    half = float(stats.t.ppf(0.5 + confidence / 2, x.size - 1) * x.std(ddof=1) / np.sqrt(x.size))
    return m, [m - half, m + half]


def evaluate(policies: Mapping[str, Any], seeds: Sequence[int], scenario: str | Scenario = "paper",
             reference: str | None = None, max_steps: int | None = None, record: int = 0,
             focus: str | None = None) -> dict:
    """Evaluate every policy (or :class:`Entry`) on the same seeds; paired differences vs ``reference``.

    Returns a JSON-able dict: ``policies.<name>`` with ``<metric>_mean``, ``<metric>_ci95`` per
    metric of :data:`EPISODE_METRICS` (``reward_mean``, ``reward_ci95``, ...), ``episodes`` (the
    per-episode values) and ``wall_time_s``; ``paired.<name>_vs_<reference>`` with
    ``<metric>_diff_mean`` and ``<metric>_diff_ci95`` (name minus reference, per episode).
    """
    if not policies:
        raise ValueError("policies is empty; pass at least one policy")
    if reference is not None and reference not in policies:
        raise ValueError(f"reference = {reference!r} is not one of the policies {list(policies)}")
    runs = {}
    for name, entry in policies.items():
        entry = entry if isinstance(entry, Entry) else Entry(entry)
        runs[name] = run_episodes(entry.policy, seeds, scenario, max_steps, record, **entry.overrides)
    return summarize(runs, seeds, reference, focus)


def summarize(runs: Mapping[str, dict], seeds: Sequence[int], reference: str | None = None,
              focus: str | None = None) -> dict:
    """The result of :func:`evaluate` from the :func:`run_episodes` results of every policy (played on
    ``seeds``, e.g. in separate processes). With ``focus`` (a policy name), ``focus_paired`` holds
    its paired differences against every other policy (``<focus>_vs_<name>``)."""
    if reference is not None and reference not in runs:
        raise ValueError(f"reference = {reference!r} is not one of the policies {list(runs)}")
    traces = {name: run["traces"] for name, run in runs.items() if "traces" in run}
    res: dict[str, Any] = {"seeds": [int(s) for s in seeds], "reference": reference, "policies": {}, "paired": {}}
    for name, run in runs.items():
        summary: dict[str, Any] = {"wall_time_s": run["wall_time_s"], "slots": run["slots"]}
        for metric, vals in run["episodes"].items():
            summary[f"{metric}_mean"], summary[f"{metric}_ci95"] = mean_ci(vals)
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
    """Per-metric mean and 95 % CI of ``episodes - ref`` (per episode); ``ci95`` is the reward's."""
    pair = {}
    for metric, vals in episodes.items():
        pair[f"{metric}_diff_mean"], pair[f"{metric}_diff_ci95"] = mean_ci(np.asarray(vals) - np.asarray(ref[metric]))
    pair["ci95"] = pair["reward_diff_ci95"]  # the headline: episode reward
    return pair


def format_table(res: dict) -> str:
    """The comparison as a text table: mean [95 % CI] per policy, then paired differences."""
    cols = [("reward", "episode reward", "{:.1f}"), ("tracking_error_m", "track err (m)", "{:.4f}"),
            ("violation", "viol. frac", "{:.4f}"), ("peb_m", "PEB (m)", "{:.4f}"),
            ("rate_comm_mbps", "rate (Mbps)", "{:.2f}"), ("terminated", "lost track", "{:.2f}")]
    n = len(res["seeds"])
    lines = [f"{n} held-out episodes per policy, common random numbers; mean [95% CI]"]
    header = f"{'policy':<16}" + "".join(f"{title:>30}" for _, title, _ in cols)
    lines += [header, "-" * len(header)]
    for name, p in res["policies"].items():
        row = f"{name:<16}"
        for metric, _, fmt in cols:
            lo, hi = p[f"{metric}_ci95"]
            row += f"{fmt.format(p[metric + '_mean']) + ' [' + fmt.format(lo) + ', ' + fmt.format(hi) + ']':>30}"
        lines.append(row)
    groups = []
    if res["paired"]:
        groups.append((f"paired differences vs {res['reference']} (policy minus reference), mean [95% CI]:",
                       res["paired"]))
    if res.get("focus_paired"):
        groups.append((f"paired differences of {res['focus']} against every other policy, mean [95% CI]:",
                       res["focus_paired"]))
    for title, pairs in groups:
        lines.append(title)
        for pair, d in pairs.items():
            row = f"{pair:<28}"
            for metric in ("reward", "tracking_error_m", "violation"):
                lo, hi = d[f"{metric}_diff_ci95"]
                row += f"  {metric}: {d[metric + '_diff_mean']:+.4g} [{lo:+.4g}, {hi:+.4g}]"
            lines.append(row)
    return "\n".join(lines)
