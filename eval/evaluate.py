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

import functools
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from iscc_gym.envs.vector import ISCCVectorEnv
from iscc_gym.scenario import Scenario, make_scenario

__all__ = ["Entry", "evaluate", "summarize", "run_episodes", "Actor", "mean_ci", "format_table", "markdown_table",
           "EPISODE_METRICS", "METRIC_RANGES", "PEB_NOTE", "ci_cell", "ci_bounds", "ci_side", "horizon_slots"]

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


def mean_ci(x, confidence: float = 0.95,
            bounds: tuple[float, float] | None = None) -> tuple[float, list[float] | None]:
    """Mean and the Student-t confidence interval of the mean of samples ``x``, clamped to ``bounds``
    (``(low, high)``: the metric's range, e.g. ``(0, 1)`` for a fraction; the t interval of a fraction
    near 0 would otherwise reach below 0). Fewer than two samples give no interval: None (JSON null;
    :func:`ci_bounds` writes ``n/a``, :func:`ci_side` draws no conclusion from it).
    """
    x = np.asarray(x, dtype=float)
    m = float(x.mean())
    if x.size < 2:
        return m, None
    half = float(stats.t.ppf(0.5 + confidence / 2, x.size - 1) * x.std(ddof=1) / np.sqrt(x.size))
    lo, hi = m - half, m + half
    if bounds is not None:
        low, high = bounds
        lo, hi = min(max(lo, low), high), min(max(hi, low), high)
    return m, [lo, hi]


def evaluate(policies: Mapping[str, Any], seeds: Sequence[int], scenario: str | Scenario = "paper",
             reference: str | None = None, max_steps: int | None = None, record: int = 0,
             focus: str | None = None, progress: Callable[[int], None] | None = None) -> dict:
    """Evaluate every policy (or :class:`Entry`) on the same seeds; paired differences vs ``reference``.

    Returns a JSON-able dict: ``policies.<name>`` with ``<metric>_mean``, ``<metric>_ci95`` per
    metric of :data:`EPISODE_METRICS` (``reward_mean``, ``reward_ci95``, ...), ``episodes`` (the
    per-episode values) and ``wall_time_s``; ``paired.<name>_vs_<reference>`` with
    ``<metric>_diff_mean`` and ``<metric>_diff_ci95`` (name minus reference, per episode). Every
    interval is clamped to its metric's range (:data:`METRIC_RANGES`). ``progress(n)``: as in
    :func:`run_episodes`, for every policy in turn.
    """
    if not policies:
        raise ValueError("policies is empty; pass at least one policy")
    if reference is not None and reference not in policies:
        raise ValueError(f"reference = {reference!r} is not one of the policies {list(policies)}")
    runs = {}
    for name, entry in policies.items():
        entry = entry if isinstance(entry, Entry) else Entry(entry)
        runs[name] = run_episodes(entry.policy, seeds, scenario, max_steps, record, progress=progress,
                                  **entry.overrides)
    return summarize(runs, seeds, reference, focus)


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


#: Columns of the comparison tables: (metric, title, number format, which direction is better: "↑" higher, "↓" lower).
MAIN_COLUMNS = (("reward", "episode reward", "{:.1f}", "↑"), ("tracking_error_m", "tracking error (m)", "{:.4f}", "↓"),
                ("violation", "violations", "{:.3f}", "↓"), ("terminated", "lost track", "{:.2f}", "↓"),
                ("peb_m", "PEB (m)", "{:.4f}", "↓"), ("rate_comm_mbps", "data rate (Mbit/s)", "{:.2f}", "↑"))
DETAIL_COLUMNS = (("rate_violation", "rate violations", "{:.3f}", "↓"),
                  ("stability_violation", "stability violations", "{:.4f}", "↓"))
PAIR_COLUMNS = (("reward", "Δ episode reward", "{:+.1f}", "↑"),
                ("tracking_error_m", "Δ tracking error (m)", "{:+.4f}", "↓"),
                ("violation", "Δ violations", "{:+.3f}", "↓"))
SPLIT_TITLE = "mean split: sensing / control / data"
#: The detail column of a task with a data queue (shown when some policy dropped bits).
DROPPED_COLUMN = ("dropped_mbit", "dropped (Mbit)", "{:.1f}", "↓")


def detail_columns(res: dict) -> tuple:
    """:data:`DETAIL_COLUMNS`, and :data:`DROPPED_COLUMN` where a policy of the comparison dropped data (a queue)."""
    dropped = any(p.get("dropped_mbit_mean", 0.0) > 0.0 for p in res["policies"].values())
    return DETAIL_COLUMNS + ((DROPPED_COLUMN,) if dropped else ())

#: The line under the comparison explaining its columns.
PEB_NOTE = ("PEB: position error bound, the Cramér–Rao bound on the error of the radar's position estimate (m), "
            "mean over the mission's slots. Violations: fraction of slots with the data rate below R_min or the "
            "control packet-loss rate above eps* (split into rate and stability violations below); lost track: "
            "fraction of missions ended by loss of track. ↑: higher is better, ↓: lower is better.")


#: What the tables and sentences say for an interval of one mission (:func:`mean_ci` gives none).
NO_CI = "n/a: 1 mission"


def ci_bounds(ci, fmt: str = "{:.3f}") -> str:
    """``[low, high]`` of a confidence interval, ``[n/a: 1 mission]`` where there is none (:func:`mean_ci` of one
    sample): every command's interval goes through this.
    """
    if ci_side(ci) is None:
        return f"[{NO_CI}]"
    return f"[{fmt.format(ci[0])}, {fmt.format(ci[1])}]"


def ci_side(ci) -> int | None:
    """Where a confidence interval ``(low, high)`` lies: 1 above zero, -1 below, 0 around it; None where there is
    no interval (None: :func:`mean_ci` of one sample), so that no conclusion is drawn from it.
    """
    if ci is None:
        return None
    lo, hi = ci
    return 1 if lo > 0 else -1 if hi < 0 else 0


def ci_cell(mean: float, ci, fmt: str = "{:.3f}") -> str:
    """``mean ±half-width`` of a symmetric interval, ``mean [low, high]`` of one clamped to its metric's range,
    ``mean [n/a: 1 mission]`` without one (:func:`ci_bounds`).
    """
    if ci is None:
        return f"{fmt.format(mean)} {ci_bounds(ci)}"
    lo, hi = ci
    below, above = mean - lo, hi - mean
    if abs(below - above) <= 1e-9 * max(1.0, abs(hi - lo)):
        return f"{fmt.format(mean)} ±{fmt.replace('+', '').format(abs(above))}"
    return f"{fmt.format(mean)} {ci_bounds(ci, fmt)}"


def _split(p: dict) -> str:
    return " / ".join(f"{p[f'alpha_{k}_mean']:.3f}" for k in ("sen", "ctrl", "comm"))


def _pair_groups(res: dict) -> list[tuple[str, dict]]:
    groups = []
    if res.get("paired"):
        groups.append((f"Paired differences against {res['reference']} (the policy minus {res['reference']}, "
                       "per mission)", res["paired"]))
    if res.get("focus_paired"):
        groups.append((f"Paired differences of {res['focus']} against every other policy ({res['focus']} minus "
                       "the other, per mission)", res["focus_paired"]))
    return groups


def _pair_name(pair: str) -> str:
    return pair.replace("_vs_", " vs ", 1)


def format_table(res: dict) -> str:
    """The comparison as a text table for a terminal (about 110 columns): mean ±half-width of the 95 % CI
    per policy, ↑/↓ marking the better direction, then the paired differences.
    """
    n = len(res["seeds"])
    names = list(res["policies"])
    w0 = max([len("policy"), *map(len, names)]) + 2
    lines = [f"{n} held-out episodes per policy, common random numbers; mean ±half-width of the 95% CI",
             "(↑ higher is better, ↓ lower is better; PEB: the Cramér–Rao position error bound of the radar)"]
    for cols, extra in ((MAIN_COLUMNS, False), (detail_columns(res), True)):
        cells = {name: [ci_cell(p[f"{m}_mean"], p[f"{m}_ci95"], fmt) for m, _, fmt, _ in cols]
                 for name, p in res["policies"].items()}
        titles = [f"{title} {better}" for _, title, _, better in cols]
        if extra:
            titles.append(SPLIT_TITLE)
            for name, p in res["policies"].items():
                cells[name].append(_split(p))
        widths = [max(len(t), *(len(c[j]) for c in cells.values())) + 2 for j, t in enumerate(titles)]
        header = "policy".ljust(w0) + "".join(t.rjust(w) for t, w in zip(titles, widths, strict=True))
        lines += ["", header, "-" * len(header)]
        lines += [name.ljust(w0) + "".join(c.rjust(w) for c, w in zip(cells[name], widths, strict=True))
                  for name in names]
    for title, pairs in _pair_groups(res):
        w = max(len(_pair_name(k)) for k in pairs) + 2
        rows = {k: [ci_cell(d[f"{m}_diff_mean"], d[f"{m}_diff_ci95"], fmt) for m, _, fmt, _ in PAIR_COLUMNS]
                for k, d in pairs.items()}
        titles = [f"{t} {b}" for _, t, _, b in PAIR_COLUMNS]
        widths = [max(len(t), *(len(r[j]) for r in rows.values())) + 2 for j, t in enumerate(titles)]
        lines += ["", f"{title}:", "pair".ljust(w) + "".join(t.rjust(x) for t, x in zip(titles, widths, strict=True))]
        lines += [_pair_name(k).ljust(w) + "".join(c.rjust(x) for c, x in zip(r, widths, strict=True))
                  for k, r in rows.items()]
    return "\n".join(lines)


#: The fewest missions a share's resampled interval is given for: with fewer, the resamplings take so few distinct
#: values (2 missions: 3 means) that the percentile interval is no interval (issue 43.11: ``0.37 [0.37, 0.38]`` from
#: 2 missions). Below it the interval is None and :func:`share_bounds` says why.
MIN_BOOTSTRAP_MISSIONS = 10


def share_bounds(share: dict, fmt: str = "{:.2f}") -> str:
    """``[low, high]`` of :func:`oracle_share`'s ``share_ci95``, or why there is none (too few missions)."""
    if share.get("share_ci95") is None:
        return f"[n/a: {share['missions']} missions, an interval needs {MIN_BOOTSTRAP_MISSIONS}]"
    return ci_bounds(share["share_ci95"], fmt)


def oracle_share(res: dict, agent: str = "ppo", oracle: str = "oracle", base: str = "myopic") -> dict | None:
    """The share of the oracle's gain an agent recovers, ``(agent - base) / (oracle - base)`` in mean episode
    reward on the same missions, with both gains' paired means and 95 % intervals, and the share's 95 % interval
    (``share_ci95``: the percentile interval of the ratio over 10,000 resamplings of the missions, seeded; the
    missions are resampled whole, so both gains keep their pairing; None from fewer than
    :data:`MIN_BOOTSTRAP_MISSIONS` missions, :func:`share_bounds` saying so); None unless all three played.
    The share is a ratio of means: where the oracle's interval includes zero it is not a measured fraction.
    """
    pol = res["policies"]
    if not all(k in pol for k in (agent, oracle, base)):
        return None
    ref = np.asarray(pol[base]["episodes"]["reward"], dtype=float)
    gain = np.asarray(pol[agent]["episodes"]["reward"], dtype=float) - ref
    best = np.asarray(pol[oracle]["episodes"]["reward"], dtype=float) - ref
    out = {"agent": agent, "oracle": oracle, "base": base, "agent_gain": mean_ci(gain), "oracle_gain": mean_ci(best),
           "missions": len(ref)}
    out["share"] = float(gain.mean() / best.mean()) if best.mean() != 0.0 else math.nan
    out["share_ci95"] = None
    if len(ref) >= MIN_BOOTSTRAP_MISSIONS:
        idx = np.random.default_rng(0).integers(0, len(ref), (10_000, len(ref)))
        with np.errstate(divide="ignore", invalid="ignore"):
            ratios = gain[idx].mean(axis=1) / best[idx].mean(axis=1)
        ratios = ratios[np.isfinite(ratios)]
        out["share_ci95"] = ((float(np.percentile(ratios, 2.5)), float(np.percentile(ratios, 97.5)))
                             if ratios.size else (math.nan, math.nan))
    return out


def oracle_share_sentence(share: dict) -> str:
    """One sentence of :func:`oracle_share`."""
    (g, gci), (o, oci) = share["agent_gain"], share["oracle_gain"]
    a, b, base = share["agent"], share["oracle"], share["base"]
    side = ci_side(oci)
    why = (f"the {b}'s gain has no interval from one mission" if side is None else
           f"the {b}'s gain is not distinguishable from zero on these missions")
    return (f"Share of the {b}'s gain over {base} that {a} recovers, ({a} - {base}) / ({b} - {base}): "
            f"{g:+.1f} {ci_bounds(gci, '{:+.1f}')} / {o:+.1f} {ci_bounds(oci, '{:+.1f}')} = "
            f"{share['share']:.2f}" + (f" {share_bounds(share)}" + (" (missions resampled)."
                                                                     if share.get("share_ci95") else ".")
                                       if side == 1 and "missions" in share
                                       else "." if side == 1 else f" ({why}, so the ratio measures nothing)."))


def markdown_table(res: dict, command: str) -> str:
    """The comparison as markdown (tables under 120 columns): the main metrics per policy, a line
    explaining the columns, the violations split and the mean allocation, then the paired differences;
    mean ±half-width of the 95 % CI, ↑/↓ marking the better direction.
    """
    import textwrap

    n = len(res["seeds"])
    wrap = functools.partial(textwrap.fill, width=118, break_on_hyphens=False)
    lines = [wrap(f"Generated by `{command} --write-docs`: {n} held-out missions (seeds {res['seeds'][0]}-"
                  f"{res['seeds'][-1]}), the same for every policy (common random numbers); mean ±half-width of "
                  "the 95 % confidence interval (mean [low, high] where the interval is cut at the metric's "
                  "range, e.g. a fraction's at 0)."), ""]

    def table(cols, extra=None):
        titles = [f"{title} {better}" for _, title, _, better in cols] + ([extra[0]] if extra else [])
        out = ["| policy | " + " | ".join(titles) + " |", "|---|" + "--:|" * len(titles)]
        for name, p in res["policies"].items():
            cells = [ci_cell(p[f"{m}_mean"], p[f"{m}_ci95"], fmt) for m, _, fmt, _ in cols]
            cells += [extra[1](p)] if extra else []
            out.append(f"| {name} | " + " | ".join(cells) + " |")
        return out

    lines += table(MAIN_COLUMNS)
    lines += ["", wrap(PEB_NOTE), ""]
    lines += table(detail_columns(res), (SPLIT_TITLE, _split))
    for title, pairs in _pair_groups(res):
        lines += ["", f"{title}:", "", "| pair | " + " | ".join(f"{t} {b}" for _, t, _, b in PAIR_COLUMNS) + " |",
                  "|---|" + "--:|" * len(PAIR_COLUMNS)]
        for pair, d in pairs.items():
            cells = [ci_cell(d[f"{m}_diff_mean"], d[f"{m}_diff_ci95"], fmt) for m, _, fmt, _ in PAIR_COLUMNS]
            lines.append(f"| {_pair_name(pair)} | " + " | ".join(cells) + " |")
    reading = reading_sentences(res)
    if reading:
        lines += ["", wrap(reading)]
    return "\n".join(lines)


def _verdict(pair: str, d: dict, metric: str = "reward") -> str:
    """``A is ahead of B by X ±h`` (or behind) for the pair ``A_vs_B`` (``h`` the half-width of the paired 95 %
    interval ``(low, high)``), with whether the interval excludes zero; of one mission, no interval.
    """
    a, b = _pair_name(pair).split(" vs ", 1)
    m, ci = d[f"{metric}_diff_mean"], d[f"{metric}_diff_ci95"]
    side = ci_side(ci)
    if side is None:
        return f"{a} is {'ahead of' if m > 0 else 'behind'} {b} by {abs(m):.1f} on one mission (no interval)"
    lo, hi = ci
    return (f"{a} is {'ahead of' if m > 0 else 'behind'} {b} by {abs(m):.1f} ±{(hi - lo) / 2:.1f} "
            f"(the interval {'includes' if side == 0 else 'excludes'} zero)")


def reading_sentences(res: dict) -> str:
    """The comparison's figures in words, generated with the tables so prose and table cannot disagree: each
    policy's paired reward difference against the reference and, for the focus policy, against every other.
    """
    pairs = dict(res.get("paired") or {})
    pairs.update({p: d for p, d in (res.get("focus_paired") or {}).items()
                  if _pair_name(p).split(" vs ", 1)[1] != res.get("reference")})
    if not pairs:
        return ""
    one = all(ci_side(d["reward_diff_ci95"]) is None for d in pairs.values())
    out = ["In episode reward" + (" (one mission: no intervals):" if one else " per mission (paired 95 % intervals):")]
    out.append("; ".join(_verdict(p, d) for p, d in pairs.items()) + ".")
    return " ".join(out)
