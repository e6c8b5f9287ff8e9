"""``python -m experiments.urban_levers``: what makes looking ahead pay on the urban task (issue 25, point 3).

For each named variant of the ``urban`` preset (a change of the blockage statistics, the data's deadline, rate or
weight, the map's error: :data:`VARIANTS`, each within the range its source states), on training missions only:

1. ``myopic``'s data weight and the planner's (``rate_weight``; its other parameters those of its record,
   ``agents/tuned/mpc-urban.yml``) are tuned for the variant (:data:`RATE_WEIGHT_GRID` times the variant's
   ``w_rate``) on :data:`TUNE_MISSIONS` tuning missions (from :data:`iscc_gym.commands.protocol.TUNE_SEED_START`), so
   that
   both are as strong on the variant as on the preset;
2. ``myopic``, ``mpc``, ``mpc-hold`` (the planner blind to the preview) and ``oracle`` (the planner shown the truth
   ahead), the last two with ``mpc``'s parameters, play the next ``--missions`` training missions (``--skip`` more
   later for a replication), common random numbers;
3. the table reports ``myopic``'s episode reward and what it is made of (tracking error, stability violations,
   dropped data: what the split can change lies in the last two and in the tracking error's part above its floor),
   the blocked share of the flight, and the paired differences ``mpc`` - ``myopic``, ``oracle`` - ``myopic``,
   ``mpc`` - ``mpc-hold`` (what the preview is worth to the planner) and ``oracle`` - ``mpc`` (the truth's worth
   over the map's) with their 95 % intervals.

The held-out missions are never played here: a variant chosen from this table is evaluated afterwards by
``python -m eval --env iscc_gym/ISCC-Urban-v0``.

Example::

    python -m experiments.urban_levers --missions 16 --write-docs
    python -m experiments.urban_levers --missions 16 --jobs 2 --write-docs    # two variants at a time
"""

from __future__ import annotations

import functools
import sys
import time

import numpy as np
from iscc_gym.agents.tuned_records import load_tuned, record_name
from iscc_gym.commands.options import Parser, docs_command, nonneg_int, parse_names, positive_int, run_console
from iscc_gym.commands.protocol import TUNE_SEED_START, seed_list
from iscc_gym.eval.engine import compare
from iscc_gym.eval.policies import pool_map
from iscc_gym.eval.report import ci_bounds, ci_side, mean_ci

from experiments.urban_task import task_stats
from iscc_gym.scenario import make_scenario
from iscc_gym.tasks import TASKS, URBAN_ENV_ID, variant_scenario

__all__ = ["VARIANTS", "RATE_WEIGHT_GRID", "TUNE_MISSIONS", "lever_row", "markdown", "main"]

#: The variants of ``urban`` played here, by name: the urban task's variants (:data:`iscc_gym.tasks.TASKS`).
LEVERS = ("urban", "smooth", "smooth w_rate=5", "smooth deadline=3s", "smooth 15Mbps", "w_rate=5", "map_error=0.8",
          "smooth 40Mbps deadline=5s", "calm smooth 20Mbps deadline=3s", "umi_av")
#: name -> (Scenario overrides, why the value is physical).
VARIANTS: dict[str, tuple[dict, str]] = {name: (dict(TASKS[URBAN_ENV_ID].variants[name].overrides),
                                                TASKS[URBAN_ENV_ID].variants[name].why) for name in LEVERS}

#: ``myopic``'s data weight is tuned among these multiples of the variant's ``w_rate``.
RATE_WEIGHT_GRID = (0.1, 0.3, 1.0, 3.0)
#: Tuning missions per variant (seeds from TUNE_SEED_START); the evaluation's follow them.
TUNE_MISSIONS = 8


def lever_row(name: str, overrides: dict | None, missions: int, tune_missions: int = TUNE_MISSIONS,
              max_steps: int | None = None, log=print, skip: int = 0) -> dict:
    """One variant of the urban task: the engine (:func:`iscc_gym.eval.engine.compare`) retunes ``myopic``'s and the
    planner's data weights on ``tune_missions`` training missions of the variant, then plays ``myopic``, ``mpc``,
    ``mpc-hold`` and ``oracle``, each designed on the variant (``@world``), on ``missions`` more, ``skip`` missions
    after the tuning ones (a replication on other missions: ``--skip``; see the module docstring). Returns the
    figures of the table's row. ``overrides``: the variant's (None: the task's variant of that name).
    """
    s = make_scenario("urban", **(VARIANTS[name][0] if overrides is None else overrides))
    if s != variant_scenario(URBAN_ENV_ID, name):
        raise ValueError(f"{name!r}: overrides {overrides} are not the urban task's variant of that name")
    tune_seeds = seed_list(TUNE_SEED_START, tune_missions)
    first = TUNE_SEED_START + tune_missions + skip
    seeds = seed_list(first, missions)
    t0 = time.perf_counter()

    def weights(world):  # the data weight's grid: multiples of the variant's w_rate
        return {"rate_weight": tuple(w * world.w_rate for w in RATE_WEIGHT_GRID)}

    # the planner's data weight likewise (its other parameters the record's); mpc-hold and oracle take mpc's
    params = dict(load_tuned(record_name("mpc", "urban"))["params"])
    items = {"myopic": "myopic@world", "mpc": "mpc@world", "mpc-hold": "mpc-hold@world", "oracle": "oracle@world"}
    res = compare(URBAN_ENV_ID, list(items.values()), seeds, variants=[name], max_steps=max_steps, check=False,
                  tune_seeds=tune_seeds,
                  retune={items["myopic"]: weights,
                          items["mpc"]: lambda w: {**{k: (v,) for k, v in params.items() if k != "rate_weight"},
                                                   **weights(w)},
                          items["mpc-hold"]: items["mpc"], items["oracle"]: items["mpc"]})[name]
    eps = {k: {m: np.asarray(v) for m, v in res["policies"][it]["episodes"].items()} for k, it in items.items()}
    weight, plan = res["tuned"][items["myopic"]]["rate_weight"], res["tuned"][items["mpc"]]
    m = eps["myopic"]
    slots = m["length"]
    mean_arrival_mbit = s.queue_arrival_bps * s.dt_s * 1e-6
    parts = {"tracking": float(np.mean(m["tracking_error_m"] * slots)),
             "stability": float(np.mean(s.w_stab * m["stability_violation"] * slots)),
             "dropped": float(np.mean(s.w_rate * m["dropped_mbit"] / mean_arrival_mbit))}
    parts["lost_track"] = -float(m["reward"].mean()) - sum(parts.values())  # the loss-of-track penalty
    st = task_stats(s, seeds)
    row = {"name": name, "overrides": overrides, "rate_weight": weight, "mpc_rate_weight": plan["rate_weight"],
           "myopic": float(m["reward"].mean()),
           "parts": parts, "lost_track": {k: float(e["terminated"].mean()) for k, e in eps.items()},
           "nlos_share": 1.0 - st["los_share_mean"], "stretch_s_median": st["stretch_s_median"],
           "stretch_s_p90": st["stretch_s_p90"], "seeds": [seeds[0], seeds[-1]], "tune_seeds": [tune_seeds[0],
                                                                                              tune_seeds[-1]]}
    for k in ("mpc", "oracle"):
        row[k] = mean_ci(eps[k]["reward"] - m["reward"])
        row[f"{k}_dropped_mbit"] = float(eps[k]["dropped_mbit"].mean())
    row["preview"] = mean_ci(eps["mpc"]["reward"] - eps["mpc-hold"]["reward"])  # what the preview is worth to mpc
    row["knowledge"] = mean_ci(eps["oracle"]["reward"] - eps["mpc"]["reward"])  # the truth's over the map's
    row["myopic_dropped_mbit"] = float(m["dropped_mbit"].mean())
    log(f"{name}: myopic {row['myopic']:.1f} (rate_weight {weight:g}, mpc's {plan['rate_weight']:g}); mpc "
        f"{_ci(row['mpc'])}; oracle {_ci(row['oracle'])}; mpc - mpc-hold {_ci(row['preview'])}; oracle - mpc "
        f"{_ci(row['knowledge'])} ({time.perf_counter() - t0:.0f} s)")
    return row


def _ci(x) -> str:
    mean, ci = x
    return f"{mean:+.1f} {ci_bounds(ci, '{:+.1f}')}"


def markdown(rows: list[dict], command: str) -> str:
    r = rows[0]
    lines = [
        f"Generated by `{command}`: training missions only (`myopic`'s and `mpc`'s data weights tuned per variant on "
        "seeds "
        f"{r['tune_seeds'][0]}-{r['tune_seeds'][1]}, then every policy on seeds {r['seeds'][0]}-{r['seeds'][1]}, "
        "common random numbers). `myopic`'s episode reward is split into its tracking error, stability violations "
        "and dropped data (each as the reward charges it); `mpc` and `oracle` are the paired differences against "
        "`myopic`, mean [95 % interval]; `mpc` - `mpc-hold` is what the preview is worth to the planner (the same "
        "planner blind to it, the slot's channel held over the horizon), `oracle` - `mpc` what the truth ahead is "
        "worth over the map.", "",
        "| variant | NLoS share | stretch median / p90 (s) | myopic reward = tracking + stability + dropped | "
        "mpc - myopic | oracle - myopic | mpc - mpc-hold | oracle - mpc | dropped Mbit: myopic / mpc / oracle |",
        "|---|--:|--:|--:|--:|--:|--:|--:|--:|"]
    for r in rows:
        p = r["parts"]
        lines.append(
            f"| {r['name']} | {r['nlos_share']:.3f} | {r['stretch_s_median']:.1f} / {r['stretch_s_p90']:.1f} | "
            f"{r['myopic']:.1f} = -{p['tracking']:.1f} - {p['stability']:.1f} - {p['dropped']:.1f}"
            + (f" - {p['lost_track']:.1f} (lost track)" if p["lost_track"] > 0.05 else "") + f" | {_ci(r['mpc'])} | "
            f"{_ci(r['oracle'])} | {_ci(r['preview'])} | {_ci(r['knowledge'])} | "
            f"{r['myopic_dropped_mbit']:.1f} / {r['mpc_dropped_mbit']:.1f} / "
            f"{r['oracle_dropped_mbit']:.1f} |")
    lines += ["", "Variants: " + "; ".join(f"**{r['name']}**: {VARIANTS[r['name']][1]}" if r["name"] in VARIANTS
                                           else r["name"] for r in rows) + "."]
    for k in ("mpc", "oracle", "preview"):
        above = [r["name"] for r in rows if ci_side(r[k][1]) == 1]
        below = [r["name"] for r in rows if ci_side(r[k][1]) == -1]
        pair = "`mpc` over `mpc-hold`" if k == "preview" else f"`{k}` over `myopic`"
        if all(ci_side(r[k][1]) is None for r in rows):
            lines.append(f"{pair}: no interval from one mission.")
            continue
        lines.append(f"{pair}, interval above zero: "
                     f"{', '.join(above) if above else 'no variant'}; interval below zero: "
                     f"{', '.join(below) if below else 'no variant'}.")
    lost = [r for r in rows if any(v > 0 for v in r["lost_track"].values())]
    if lost:
        lines.append("Missions that lost track: " + "; ".join(
            f"{r['name']}: " + ", ".join(f"{k} {100 * v:.0f} %" for k, v in r["lost_track"].items()) for r in lost)
            + ".")
    return "\n".join(lines)


def build_parser(prog: str = "python -m experiments.urban_levers") -> Parser:
    ap = Parser(prog=prog, description=__doc__.split("\n")[0])
    ap.add_argument("--variants", default=",".join(VARIANTS), metavar="LIST",
                    help=f"comma-separated variant names (default: all of {', '.join(VARIANTS)})")
    ap.add_argument("--missions", type=positive_int, default=16, metavar="N",
                    help="training missions each policy plays per variant (default: 16)")
    ap.add_argument("--tune-missions", type=positive_int, default=TUNE_MISSIONS, metavar="N",
                    help=f"missions myopic's data weight is tuned on per variant (default: {TUNE_MISSIONS})")
    ap.add_argument("--skip", type=nonneg_int, default=0, metavar="N",
                    help="play the missions N after the tuning ones (default 0): a replication on other training "
                         "missions, e.g. --skip 16 after a --missions 16 table")
    ap.add_argument("--jobs", type=positive_int, default=1, metavar="N",
                    help="variants run at once in N processes (default: 1; each single-threaded, so at most the "
                         "machine's cores)")
    ap.add_argument("--max-steps", type=positive_int, default=None, metavar="N",
                    help="cut every mission after N slots (smoke runs)")
    ap.add_argument("--write-docs", action="store_true",
                    help="write the table into the project's docs/results.md (section urban-levers)")
    return ap


def main(argv: list[str] | None = None, prog: str = "python -m experiments.urban_levers") -> list[dict]:
    args = build_parser(prog).parse_args(argv)
    names = parse_names(args.variants, "--variants", list(VARIANTS))
    if args.write_docs:
        from iscc_gym.commands.docs import RESULTS_PATH, docs_path
        from iscc_gym.commands.options import check_writable_file

        check_writable_file(docs_path(RESULTS_PATH), "--write-docs")
    row = functools.partial(lever_row, missions=args.missions, tune_missions=args.tune_missions,
                            max_steps=args.max_steps, skip=args.skip)
    overrides = [VARIANTS[n][0] for n in names]
    if args.jobs > 1:  # one variant per process; each row is seeded, so the table is the same as with one
        rows = pool_map(row, names, overrides, workers=min(args.jobs, len(names)))  # Ctrl-C stops the workers
    else:
        rows = list(map(row, names, overrides))
    table = markdown(rows, docs_command(prog, argv))
    print(table)
    if args.write_docs:
        from iscc_gym.commands.docs import RESULTS_PATH, docs_path, write_section

        write_section(docs_path(RESULTS_PATH), "urban-levers", "## What makes looking ahead pay\n\n" + table)
        print(f"wrote {docs_path(RESULTS_PATH)}")
    return rows


if __name__ == "__main__":
    sys.exit(run_console(main, None, "python -m experiments.urban_levers"))
