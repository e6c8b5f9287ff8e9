"""``python -m experiments.pareto``: tracking error against rate outage for every policy family (issue 15 item 3).

Every scripted family is played over its knob (:data:`iscc_gym.eval.outage.FAMILIES`: static SCA's
rate design margin, ``margin``'s data multiple, ``myopic``'s ``rate_weight``) and every learned run
(by default the six of ``agents/trained/pareto/``, trained by ``python -m experiments.pareto_agents``: PPO at three
``w_rate``, PPO-Lagrangian at three rate-outage limits) as one point, all on the same held-out
missions (common random numbers) at the rate requirement :data:`RATE_MIN_BPS`. Each point is the
mean rate-outage fraction and the mean and RMS tracking error with 95 % CIs over missions; the table
marks the non-dominated points (no other point has both a lower outage and a lower error).

At each outage target, every family's operating point is chosen on **training** seeds (500,000
onwards, never an evaluation seed): the scripted knob by :func:`iscc_gym.eval.outage.find_knob`,
the learned run with the lowest training error among those whose training outage meets the target.
The chosen points are then played on the held-out missions, where the table gives their outage,
their error and the paired CI of each error against the lowest one.

Example::

    python -m experiments.pareto --episodes 20 --write-docs
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from iscc_gym.agents.shipped import PARETO_DIR
from iscc_gym.commands.docs import RESULTS_PATH, docs_path, write_section
from iscc_gym.commands.options import Parser, Stages, check_writable_file, nonneg_int, positive_int, run_console
from iscc_gym.commands.protocol import PARETO_RATE_MIN_BPS, TUNE_SEED_START, held_out_seeds, seed_list
from iscc_gym.commands.protocol import PARETO_SEED_START as SEED_START
from iscc_gym.eval.evaluate import run_episodes
from iscc_gym.eval.outage import build, find_knob
from iscc_gym.eval.report import ci_bounds, mean_ci
from iscc_gym.eval.tune import check_tuning_seeds

from iscc_gym.scenario import make_scenario

__all__ = ["KNOBS", "RATE_MIN_BPS", "points", "non_dominated", "select", "at_target", "markdown", "main"]

#: Knob grid per scripted family (at :data:`RATE_MIN_BPS`).
KNOBS = {"sca": (1.0, 1.5, 2.0, 2.5, 3.0, 3.5), "margin": (1.0, 2.0, 3.0, 5.0, 10.0, 30.0),
         "myopic": (0.5, 2.0, 5.0, 20.0, 50.0)}
#: First held-out mission of this command (inside the evaluation range, apart from the others).
#: The rate requirement of the Pareto comparison (bps): 12 Mbps, not the ``paper`` preset's 20 Mbps,
#: at which no split meets a 5 % or 10 % outage target (docs/model.md 4.6).
RATE_MIN_BPS = PARETO_RATE_MIN_BPS


def scenario_at(rate_min_bps: float = RATE_MIN_BPS, scenario="paper"):
    """The comparison's scenario: ``scenario`` with the rate requirement ``rate_min_bps``."""
    return make_scenario(scenario, rate_min_bps=float(rate_min_bps))


def _point(family: str, knob, episodes: dict, label: str | None = None) -> dict:
    out = np.asarray(episodes["rate_violation"], dtype=float)
    err = np.asarray(episodes["tracking_error_m"], dtype=float)
    mse = np.asarray(episodes["mse_m2"], dtype=float)
    m_out, ci_out = mean_ci(out, bounds=(0.0, 1.0))
    m_err, ci_err = mean_ci(err, bounds=(0.0, np.inf))
    return {"family": family, "knob": knob, "label": f"{knob:g}" if label is None else label,
            "rate_outage": m_out, "rate_outage_ci95": ci_out, "tracking_error_m": m_err,
            "tracking_error_ci95": ci_err, "rms_error_m": float(np.sqrt(mse.mean())),
            "stability_violation": float(np.mean(episodes["stability_violation"])),
            "lost": int(np.sum(episodes["terminated"])), "per_mission_error_m": err.tolist()}


def learned_family(name: str) -> tuple[str, str]:
    """``"ppo-lag/0.05"`` -> ``("ppo-lag", "0.05")``; a name without ``/`` is its own family."""
    fam, _, label = name.partition("/")
    return fam, label or fam


def _play_learned(path, seeds, s, max_steps) -> dict:
    from iscc_gym.agents.sb3_policy import SB3Policy

    return run_episodes(SB3Policy.load(path), seeds, s, max_steps=max_steps)["episodes"]


def points(seeds, scenario=None, families=tuple(KNOBS), knobs: dict | None = None, learned: dict | None = None,
           max_steps: int | None = None, on_step=None) -> list[dict]:
    """Every family over its knob grid and every learned run (``name -> run directory``, the name
    ``family/label``), on ``seeds`` (common random numbers), at ``scenario`` (default
    :func:`scenario_at`). ``on_step(label)`` is called before each point (progress).
    """
    s = scenario_at() if scenario is None else make_scenario(scenario)
    knobs = {**KNOBS, **(knobs or {})}
    step = on_step or (lambda label: None)
    out = []
    for fam in families:
        for k in knobs[fam]:
            step(f"{fam} {float(k):.4g}")
            out.append(_point(fam, float(k), run_episodes(build(fam, k, s), seeds, s, max_steps=max_steps)["episodes"]))
    for name, path in (learned or {}).items():
        fam, label = learned_family(name)
        step(name)
        out.append({**_point(fam, None, _play_learned(path, seeds, s, max_steps), label), "path": str(path)})
    return out


def non_dominated(pts: list[dict]) -> list[bool]:
    """Whether each point is on the front: no other point has outage and error both at most its own,
    one of them strictly lower.
    """
    return [not dominated_by(p, pts) for p in pts]


def dominated_by(p: dict, pts: list[dict]) -> list[dict]:
    """The points of ``pts`` with outage and error both at most ``p``'s, one strictly lower."""
    return [q for q in pts if q is not p and q["rate_outage"] <= p["rate_outage"]
            and q["tracking_error_m"] <= p["tracking_error_m"]
            and (q["rate_outage"] < p["rate_outage"] or q["tracking_error_m"] < p["tracking_error_m"])]


def select(target: float, train_seeds, scenario=None, families=tuple(KNOBS), learned: dict | None = None,
           max_steps: int | None = None, iterations: int = 6, cache: dict | None = None) -> dict:
    """Per family, the operating point for an outage ``target`` chosen on ``train_seeds``: ``family ->
    {"knob" or "path", "label", "train": the training outage and error}`` (None where the family cannot
    meet the target on the training seeds). ``cache`` (a dict, optional) keeps the learned runs'
    training results between targets.
    """
    s = scenario_at() if scenario is None else make_scenario(scenario)
    check_tuning_seeds(train_seeds)
    chosen: dict[str, dict | None] = {}
    for fam in families:
        r = find_knob(fam, target, train_seeds, s, max_steps=max_steps, iterations=iterations)
        b = r["best"]
        chosen[fam] = {"knob": b["knob"], "label": f"{b['knob']:.4g}", "train": b} if r["met"] else None
    for name, path in (learned or {}).items():
        fam, label = learned_family(name)
        if (tr := (cache or {}).get(path)) is None:
            ep = _play_learned(path, train_seeds, s, max_steps)
            tr = {"rate_outage": float(np.mean(ep["rate_violation"])),
                  "tracking_error_m": float(np.mean(ep["tracking_error_m"]))}
            if cache is not None:
                cache[path] = tr
        cur = chosen.get(fam)
        if tr["rate_outage"] <= target and (cur is None or tr["tracking_error_m"] < cur["train"]["tracking_error_m"]):
            chosen[fam] = {"path": str(path), "label": label, "train": tr}
        else:
            chosen.setdefault(fam, None)
    return chosen


def at_target(target: float, chosen: dict, seeds, pts: list[dict], scenario=None,
              max_steps: int | None = None) -> dict:
    """The held-out points of the operating points ``chosen`` (:func:`select`) at ``target``: each
    family's point, the family with the lowest held-out error (``winner``) and every other family's
    paired error difference against it (mean, 95 % CI).
    """
    s = scenario_at() if scenario is None else make_scenario(scenario)
    best: dict[str, dict] = {}
    for fam, c in chosen.items():
        if c is None:
            continue
        if "path" in c:
            p = next(q for q in pts if q.get("path") == c["path"])
        else:
            ep = run_episodes(build(fam, c["knob"], s), seeds, s, max_steps=max_steps)["episodes"]
            p = _point(fam, c["knob"], ep, c["label"])
        best[fam] = {**p, "train": c["train"], "meets_held_out": p["rate_outage"] <= target}
    res = {"target": target, "best": best, "unmet": sorted(f for f, c in chosen.items() if c is None)}
    if best:
        winner = min(best, key=lambda f: best[f]["tracking_error_m"])
        res["winner"] = winner
        res["paired_vs_winner"] = {
            f: mean_ci(np.asarray(p["per_mission_error_m"]) - np.asarray(best[winner]["per_mission_error_m"]))
            for f, p in best.items() if f != winner}
    return res


def _error_bar(value: float, ci) -> list[float]:
    """The error bar ``[below, above]`` of a confidence interval; NaN (no bar drawn) without one (one mission)."""
    return [np.nan, np.nan] if ci is None else [value - ci[0], ci[1] - value]


def markdown(pts: list[dict], results: list[dict], command: str, seeds, train_seeds, rate_min_bps: float) -> str:
    front = non_dominated(pts)
    lines = [f"Generated by `{command}`: R_min = {rate_min_bps / 1e6:g} Mbps; {len(seeds)} held-out missions (seeds "
             f"{seeds[0]}-{seeds[-1]}), common random numbers; rate outage = fraction of slots with the data rate "
             "below R_min; mean [95 % CI]; knob: static SCA's rate design margin (x R_min), `margin`'s data "
             "multiple m_comm, `myopic`'s rate_weight, the learned runs' w_rate or rate-outage limit.", "",
             "| family | knob | rate outage | tracking error (m) | RMS error (m) | stability violations | lost | "
             "non-dominated |", "|---|---|---|---|---|---|---|---|"]
    for p, f in zip(pts, front, strict=True):
        lines.append(f"| {p['family']} | {p['label']} | {p['rate_outage']:.3f} {ci_bounds(p['rate_outage_ci95'])} | "
                     f"{p['tracking_error_m']:.4f} {ci_bounds(p['tracking_error_ci95'], '{:.4f}')} | "
                     f"{p['rms_error_m']:.4f} | "
                     f"{p['stability_violation']:.4f} | {p['lost']} | {'yes' if f else ''} |")
    learned = [p for p in pts if "path" in p]
    if learned:
        lines += ["", "Learned points against the scripted ones:", ""]
        scripted = [p for p in pts if "path" not in p]
        for p in learned:
            dom = dominated_by(p, scripted)
            beats = [q for q in scripted if dominated_by(q, [p])]
            lines.append(f"- {p['family']} {p['label']}: "
                         + (f"dominated by {', '.join(q['family'] + ' ' + q['label'] for q in dom)}" if dom
                            else "not dominated by any scripted point")
                         + f"; dominates {len(beats)} of {len(scripted)} scripted points.")
    for r in results:
        t = r["target"]
        lines += ["", f"**At {100 * t:g} % outage** (operating points chosen on {len(train_seeds)} training missions, "
                      f"seeds {train_seeds[0]}-{train_seeds[-1]}; then played on the held-out missions):", ""]
        if not r["best"]:
            lines.append("no family meets the target on the training missions.")
            continue
        lines += ["| family | knob | training outage | held-out outage | meets it held out | tracking error (m) | "
                  "minus the lowest (paired) |", "|---|---|---|---|---|---|---|"]
        for fam, p in sorted(r["best"].items(), key=lambda kv: kv[1]["tracking_error_m"]):
            d = r["paired_vs_winner"].get(fam)
            diff = "lowest" if d is None else f"{d[0]:+.4f} {ci_bounds(d[1], '{:+.4f}')}"
            lines.append(f"| {fam} | {p['label']} | {p['train']['rate_outage']:.3f} | {p['rate_outage']:.3f} "
                         f"{ci_bounds(p['rate_outage_ci95'])} | {'yes' if p['meets_held_out'] else 'no'} | "
                         f"{p['tracking_error_m']:.4f} {ci_bounds(p['tracking_error_ci95'], '{:.4f}')} | {diff} |")
        if r["unmet"]:
            lines += ["", f"Not met on the training missions by: {', '.join(r['unmet'])}."]
    return "\n".join(lines)


def draw(pts: list[dict], path, targets=()) -> str:
    """Tracking error (mean, and RMS) against rate outage per family, with 95 % CIs; points far above
    the rest (e.g. static SCA past its feasible design margin) are marked at the top edge with their
    value; dashed lines at the outage ``targets``.
    """
    from iscc_gym.eval.figures import new_figure, save_figure

    fig = new_figure((11, 4.4))
    for ax, key, label in zip(fig.subplots(1, 2), ("tracking_error_m", "rms_error_m"),
                              ("mean tracking error (m)", "RMS tracking error (m)"), strict=True):
        ys = np.array([p[key] for p in pts])
        top = min(ys.max(), np.median(ys) * 1.12) * 1.01
        for fam in dict.fromkeys(p["family"] for p in pts):
            q = sorted((p for p in pts if p["family"] == fam), key=lambda p: p["rate_outage"])
            x = np.array([p["rate_outage"] for p in q])
            y = np.array([p[key] for p in q])
            xerr = np.array([_error_bar(p["rate_outage"], p["rate_outage_ci95"]) for p in q]).T
            yerr = None
            if key == "tracking_error_m":
                yerr = np.array([_error_bar(p[key], p["tracking_error_ci95"]) for p in q]).T
            inside = y <= top
            line = ax.errorbar(x[inside], y[inside], xerr=xerr[:, inside],
                               yerr=None if yerr is None else yerr[:, inside], marker="o", ms=4, capsize=2, lw=1,
                               label=fam)
            for xi, yi in zip(x[~inside], y[~inside], strict=True):
                ax.annotate(f"{fam} {yi:.2f} m", (xi, top), xytext=(xi, top * 0.995), fontsize=6, ha="left",
                            va="top", color=line[0].get_color(), arrowprops={"arrowstyle": "-|>", "lw": 0.6})
        for t in targets:
            ax.axvline(t, color="0.5", ls="--", lw=0.7)
        ax.set_ylim(top=top)
        ax.set(xlabel="rate outage (fraction of slots below R_min)", ylabel=label)
        ax.legend(fontsize=7)
    fig.suptitle("Tracking error against rate outage (held-out missions, common random numbers; dashed: targets)",
                 fontsize=9)
    return str(save_figure(fig, path))


def default_learned() -> dict:
    """``name -> directory`` of the shipped Pareto runs (``agents/trained/pareto/<family>/<label>``)."""
    from iscc_gym.agents.sb3_policy import SB3Policy  # noqa: F401  (fails clearly without the train extra)

    root = PARETO_DIR
    return {f"{d.parent.name}/{d.name}": str(d) for d in sorted(root.glob("*/*")) if (d / "model.zip").is_file()}


def build_parser(prog: str = "python -m experiments.pareto") -> Parser:
    ap = Parser(prog=prog, description=__doc__.split("\n\n")[0])
    ap.add_argument("--episodes", type=positive_int, default=20, help="held-out missions (default: 20)")
    ap.add_argument("--seed", type=nonneg_int, default=0, help="run seed: missions from 1,300,000 + 1000 x seed")
    ap.add_argument("--train-episodes", type=positive_int, default=16,
                    help="training missions (seeds from 500,000) on which each family's operating point at a "
                         "target is chosen (default: 16)")
    ap.add_argument("--iterations", type=positive_int, default=6, help="bisection steps per scripted knob (default: 6)")
    ap.add_argument("--rate-min-mbps", type=float, default=RATE_MIN_BPS / 1e6,
                    help=f"the rate requirement R_min in Mbps (default: {RATE_MIN_BPS / 1e6:g}; the learned runs "
                         "were trained at the default)")
    ap.add_argument("--families", default=",".join(KNOBS), help=f"scripted families (default: {','.join(KNOBS)})")
    ap.add_argument("--learned", action="append", default=None, metavar="NAME=PATH",
                    help="a trained run as one point, NAME = family/label, e.g. --learned ppo-lag/0.3=runs/ppo_lag "
                         "(repeatable, each NAME once; default: the runs of agents/trained/pareto/; none: --learned "
                         "none, which with --families none leaves nothing and is refused; pickles: only runs you "
                         "trust)")
    ap.add_argument("--targets", default="0.05,0.1", help="outage targets (default: 0.05,0.1)")
    ap.add_argument("--max-steps", type=positive_int, default=None, help="slots per mission (default: all)")
    ap.add_argument("--figure", default=None, help="write the figure to this PNG")
    ap.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    ap.add_argument("--write-docs", action="store_true", help="write the table into docs/results.md and the figure "
                                                               "into docs/figures/pareto.png")
    return ap


def _learned(items) -> dict:
    if items is None:
        return default_learned()
    learned: dict[str, str] = {}
    for item in items:
        if item == "none":
            continue
        name, sep, path = item.partition("=")
        if not sep or not name or not (Path(path) / "model.zip").is_file():
            raise ValueError(f"--learned {item!r}: give NAME=PATH with PATH a run directory holding model.zip "
                             "(or --learned none)")
        same = [n for n in learned if learned_family(n) == learned_family(name)]
        if same:
            fam, label = learned_family(name)
            raise ValueError(f"--learned {item!r}: the name {name!r} is given twice ({same[0]}={learned[same[0]]} "
                             f"is the point {fam} {label} too); give each run its own NAME = family/label")
        learned[name] = path
    return learned


def main(argv: list[str] | None = None, prog: str = "python -m experiments.pareto") -> dict:
    from iscc_gym.commands.options import docs_command

    args = build_parser(prog).parse_args(argv)
    families = [f.strip() for f in args.families.split(",") if f.strip() and f.strip() != "none"]
    bad = [f for f in families if f not in KNOBS]
    if bad:
        raise ValueError(f"--families {args.families!r}: unknown {bad}; use some of {','.join(KNOBS)} (or none)")
    try:
        targets = [float(t) for t in args.targets.split(",") if t.strip()]
    except ValueError:
        targets = [-1.0]
    if any(not 0.0 <= t <= 1.0 for t in targets):
        raise ValueError(f"--targets {args.targets!r}: use fractions in [0, 1], e.g. --targets 0.05,0.1")
    if not (np.isfinite(args.rate_min_mbps) and args.rate_min_mbps > 0):
        raise ValueError(f"--rate-min-mbps {args.rate_min_mbps}: use a positive number of Mbps, e.g. 12")
    learned = _learned(args.learned)
    if not families and not learned:
        raise ValueError(f"--families {args.families!r} and --learned {' '.join(args.learned or ['(default)'])}: no "
                         "point to compare (no scripted family, no trained run); name a family, e.g. --families sca, "
                         "or a run, --learned NAME=PATH")
    if args.figure:
        check_writable_file(args.figure, "--figure")
    s = scenario_at(args.rate_min_mbps * 1e6)
    seeds = held_out_seeds(SEED_START, args.episodes, args.seed)
    train_seeds = seed_list(TUNE_SEED_START, args.train_episodes)
    check_tuning_seeds(train_seeds)
    n_points = sum(len(KNOBS[f]) for f in families) + len(learned)
    with Stages(n_points + 2 * len(targets), prog, enabled=not args.quiet) as st:
        pts = points(seeds, s, families=families, learned=learned, max_steps=args.max_steps, on_step=st.next)
        cache: dict = {}
        results = []
        for t in targets:
            st.next(f"target {t:g}: operating points on the training missions")
            chosen = select(t, train_seeds, s, families, learned, args.max_steps, args.iterations, cache)
            st.next(f"target {t:g}: held out")
            results.append(at_target(t, chosen, seeds, pts, s, args.max_steps))
    table = markdown(pts, results, docs_command(prog, argv), seeds, train_seeds, s.rate_min_bps)
    print(table)
    res = {"points": pts, "targets": {str(r["target"]): r for r in results}, "seeds": [seeds[0], seeds[-1]],
           "rate_min_bps": s.rate_min_bps}
    if args.figure:
        res["figure"] = draw(pts, args.figure, targets)
    if args.write_docs:
        res["figure"] = draw(pts, docs_path("docs/figures/pareto.png"), targets)
        write_section(docs_path(RESULTS_PATH), "pareto", "## Pareto fronts: tracking error against rate outage\n\n"
                      + table + "\n\n![pareto](figures/pareto.png)")
    return res


def console(argv: list[str] | None = None, prog: str = "python -m experiments.pareto") -> int:
    return run_console(main, argv, prog)


if __name__ == "__main__":
    sys.exit(console())
