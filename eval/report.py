"""The comparison's report, written once: the Student-t interval of a mean (:func:`mean_ci`), interval cells
(:func:`ci_cell`, :func:`ci_bounds`, :func:`ci_side`), the share of a gap closed (:func:`oracle_share`), and the
console and Markdown tables and reading sentences of a comparison's result (:func:`format_table`,
:func:`markdown_table`, :func:`reading_sentences`). Every command and study that prints or publishes a comparison
formats it here.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy import stats

__all__ = ["mean_ci", "format_table", "markdown_table", "ci_cell", "ci_bounds", "ci_side", "share_bounds",
           "oracle_share", "oracle_share_sentence", "reading_sentences", "detail_columns", "MAIN_COLUMNS",
           "DETAIL_COLUMNS", "PAIR_COLUMNS", "DROPPED_COLUMN", "SPLIT_TITLE", "PEB_NOTE"]


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
    """The comparison as markdown (tables under 120 columns): the command that generated it (``command``, quoted as
    given), the main metrics per policy, a line explaining the columns, the violations split and the mean
    allocation, then the paired differences; mean ±half-width of the 95 % CI, ↑/↓ marking the better direction.
    """
    import textwrap

    n = len(res["seeds"])
    wrap = functools.partial(textwrap.fill, width=118, break_on_hyphens=False)
    lines = [wrap(f"Generated by `{command}`: {n} held-out missions (seeds {res['seeds'][0]}-"
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
