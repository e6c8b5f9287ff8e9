"""``python -m eval.tune POLICY``: tune a scripted baseline (margin, sca-per-slot, MODEL_GRIDS) on training seeds.

Tuning seeds (default :data:`TUNE_SEEDS`, 500,000 onwards) are disjoint from every evaluation seed
of the project (the comparison's 10,000-10,999, training's held-out 1,000,000 onwards, RL training's
small integers), so the tuned baseline is evaluated once on seeds it never saw (linkgym's rule).

``margin``: a grid over (m_ctrl, m_comm, sensing_floor), every point played on the same tuning seeds (common random
numbers; all grid points x seeds in one batch of the vector env), then Nelder-Mead
(``scipy.optimize.minimize``) from the best grid point on the same seeds. The record (tuned values,
seeds, the grid's table, the command) goes to ``agents/tuned/margin.yml`` (written atomically),
which ``make_policy("margin")`` reads.

``sca-per-slot``: per-slot SCA's design loss fraction (the slot's fading-averaged loss rate it designs
for, as a fraction of eps*): a grid (:data:`SCA_FRACTION_GRID`) on the tuning seeds, then a bounded
scalar search (``scipy.optimize.minimize_scalar``) between the best grid point's neighbours. The
record goes to ``agents/tuned/sca-per-slot.yml``, which ``SCAPolicy(mode="per_slot")`` reads.

On the urban task (``--scenario urban``; records ``<policy>-urban.yml``, which ``make_policy`` reads for a
scenario with a queue or blockage): ``margin`` as above; ``myopic`` its data weight (the queue's greedy price),
``dpp`` its V, ``mpc`` its deadline margin, holding cost and data weight, each a grid (:data:`MODEL_GRIDS`) on the
tuning seeds, every point on the same missions.

Examples::

    python -m eval.tune margin                       # 40 missions from seed 500000
    python -m eval.tune mpc --scenario urban --episodes 16
    python -m eval.tune margin --episodes 10 --out /tmp/margin.yml
    python -m eval.tune sca-per-slot
"""

from __future__ import annotations

import sys
import time

import numpy as np
from iscc_gym.agents.tuned_records import PER_SLOT_RECORD, record_name, record_task, save_tuned, task_of
from iscc_gym.commands.options import (
    Parser,
    check_writable_file,
    nonneg_int,
    positive_int,
    progress_bar,
    run_console,
    show_progress,
)

# the policies, the rollout loop and scipy's optimisers are imported where they are used, so that the arguments are
# checked before the compiled env loads (issue 43.12)
from iscc_gym.commands.protocol import TUNE_SEED_START, TUNE_SEEDS, check_outside_evaluation, seed_list

from iscc_gym.scenario import make_scenario
from iscc_gym.tasks import TASKS

#: Default grid of ``python -m eval.tune margin``.
MARGIN_GRID = {"m_ctrl": (2.5, 3.0, 3.5, 4.0, 5.0, 6.0, 8.0),
               "m_comm": (1.0, 1.2, 1.4, 1.7, 2.0, 2.5, 3.0, 4.0, 6.0),
               "sensing_floor": (0.01, 0.02, 0.03, 0.05, 0.08, 0.12)}
#: The tuned parameters, in the order of a grid point.
PARAMS = ("m_ctrl", "m_comm", "sensing_floor")
#: Default grid of ``python -m eval.tune sca-per-slot`` (design loss rate as a fraction of eps*).
SCA_FRACTION_GRID = (0.005, 0.01, 0.015, 0.02, 0.03, 0.05, 0.07, 0.1, 0.2)
#: Most bounded-search evaluations of :func:`tune_sca_per_slot`.
MAX_SCALAR_REFINE = 8


def check_tuning_seeds(seeds) -> list[int]:
    """The seeds as ints; ``ValueError`` if any lies in an evaluation range or they are empty."""
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise ValueError("tuning seeds are empty; pass --episodes >= 1")
    for seed in seeds:
        check_outside_evaluation(seed, seed, "tuning seed",
                                 f"tune on seeds outside it (default: from {TUNE_SEED_START})")
    return seeds


#: Largest batch (grid points x seeds) played at once (each loop holds its 5,000-slot reference).
MAX_BATCH = 1024


def n_batches(n_points: int, n_seeds: int) -> int:
    """Batches :func:`margin_rewards` plays ``n_points`` points on ``n_seeds`` seeds in."""
    per = max(1, MAX_BATCH // n_seeds)
    return -(-n_points // per)


def margin_rewards(points, seeds, scenario="paper", progress=None) -> np.ndarray:
    """Mean episode reward over ``seeds`` of each (m_ctrl, m_comm, sensing_floor) in ``points``
    (k, 3), played in batches of up to :data:`MAX_BATCH` loops (common random numbers: every point
    on the same seeds). ``progress(1)``, if given, is called after each batch.
    """
    from iscc_gym.agents.margin import RowMarginPolicy
    from iscc_gym.eval.evaluate import run_episodes

    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    n = len(seeds)
    per = max(1, MAX_BATCH // n)
    out = []
    for i in range(0, len(pts), per):
        rows = np.repeat(pts[i:i + per], n, axis=0)
        run = run_episodes(RowMarginPolicy(rows[:, 0], rows[:, 1], rows[:, 2]), list(seeds) * (len(rows) // n),
                           scenario)
        out.append(run["episodes"]["reward"].reshape(-1, n).mean(axis=1))
        if progress is not None:
            progress(1)
    return np.concatenate(out)


#: The urban task's model-based baselines: their parameters' grids for ``python -m eval.tune <policy> --scenario urban``
#: (every combination played on the tuning seeds).
MODEL_GRIDS = {"myopic": {"rate_weight": (0.1, 0.3, 0.6, 1.0, 2.0, 4.0)},
               "dpp": {"v": (0.3, 1.0, 3.0, 10.0, 30.0, 100.0, 300.0)},
               "mpc": {"deadline_margin": (0.0, 2.0, 4.0), "holding_cost": (0.05, 0.2),
                       "rate_weight": (0.1, 0.3, 1.0)},
               # the field task's adaptive rung: its estimators' memory (python -m eval.tune adaptive --scenario field)
               "adaptive": {"k_window_slots": (10.0, 20.0, 40.0, 80.0), "echo_weight": (0.0, 0.5, 1.0)},
               # the field task's Bayesian rung: its echo likelihood's weight and its prior's correlation distance
               # (python -m eval.tune bayes --scenario field)
               "bayes": {"echo_weight": (0.5, 1.0), "correlation_scale": (0.5, 1.0)}}
#: The task each grid-tuned baseline is tuned on (the preset ``--scenario`` must pose it).
MODEL_TASKS = {policy: task.preset for task in TASKS.values() for policy in task.tuned}  # from each task file


def _grid_policy(policy: str, scenario, params: dict):
    from iscc_gym.agents import DriftPlusPenaltyPolicy, LookaheadPolicy, MyopicPolicy

    if policy == "adaptive":
        from iscc_gym.agents.adaptive import AdaptivePolicy

        return AdaptivePolicy(scenario, **params)
    if policy == "bayes":
        from iscc_gym.agents.bayes import BayesPolicy

        return BayesPolicy(scenario, **params)
    if policy == "myopic":
        return MyopicPolicy(scenario, **params)
    if policy == "dpp":
        return DriftPlusPenaltyPolicy(scenario, **params)
    return LookaheadPolicy(scenario, **params)


def tune_model_grid(policy: str, seeds=TUNE_SEEDS, scenario: str = "urban", log=print, progress=None,
                max_steps: int | None = None, grid: dict | None = None) -> dict:
    """The parameters of ``policy`` on the grid of :data:`MODEL_GRIDS` (every combination), every point on the same
    tuning seeds; returns the tuning record. ``progress(1)`` after each point; ``max_steps`` cuts the missions.
    """
    from iscc_gym.eval.evaluate import run_episodes

    seeds = check_tuning_seeds(seeds)
    grid = MODEL_GRIDS[policy] if grid is None else grid
    names = list(grid)
    points = [dict(zip(names, (float(v) for v in combo), strict=True))
              for combo in np.stack(np.meshgrid(*grid.values(), indexing="ij"), -1).reshape(-1, len(names))]
    s = make_scenario(scenario)
    want = MODEL_TASKS[policy]
    if task_of(s) != want:
        raise ValueError(f"--scenario {scenario!r}: {policy} is tuned on the {want} task (--scenario {want})")
    t0 = time.perf_counter()
    rewards = []
    for params in points:
        run = run_episodes(_grid_policy(policy, s, params), list(seeds), s, max_steps=max_steps)
        rewards.append(float(run["episodes"]["reward"].mean()))
        if progress is not None:
            progress(1)
    best = int(np.argmax(rewards))
    log(f"grid: {len(points)} points x {len(seeds)} missions in {time.perf_counter() - t0:.1f} s; best "
        + ", ".join(f"{k} = {v:g}" for k, v in points[best].items()) + f": {rewards[best]:.1f}")
    return {
        "policy": policy,
        "params": points[best],
        "objective": "mean episode reward on the tuning seeds (common random numbers)",
        "objective_value": round(rewards[best], 3),
        "scenario": scenario,
        "seeds": _seed_text(seeds),
        "n_seeds": len(seeds),
        "columns": [*names, "reward"],
        "grid": [[*p.values(), round(r, 3)] for p, r in zip(points, rewards, strict=True)],
        "wall_time_s": round(time.perf_counter() - t0, 1),
    }


#: Most Nelder-Mead evaluations of :func:`tune_margin`.
MAX_REFINE = 40


def tune_margin(seeds=TUNE_SEEDS, grid=None, scenario: str = "paper", refine: bool = True, log=print,
                progress=None) -> dict:
    """Grid over (m_ctrl, m_comm, sensing_floor), then Nelder-Mead from the best point, on the
    tuning seeds; returns the tuning record (see the module). ``progress(1)``, if given, is called
    after each batch of the grid (:func:`n_batches`) and each Nelder-Mead evaluation.
    """
    from scipy import optimize

    seeds = check_tuning_seeds(seeds)
    grid = grid or MARGIN_GRID
    t0 = time.perf_counter()
    axes = [np.asarray(grid[k], float) for k in PARAMS]
    points = np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")], axis=1)
    rewards = margin_rewards(points, seeds, scenario, progress)
    best = int(np.argmax(rewards))
    log(f"grid: {len(points)} points x {len(seeds)} missions in {time.perf_counter() - t0:.1f} s; best "
        + _fmt(points[best]) + f": {rewards[best]:.1f}")
    x_best, r_best, evals = points[best], float(rewards[best]), []
    if refine:
        def neg(x):
            if np.any(x < 0) or x[2] >= 1:
                return 1e12
            r = float(margin_rewards(x[None], seeds, scenario, progress)[0])
            evals.append([float(v) for v in x] + [r])
            return -r

        simplex = [x_best, x_best * [1.1, 1, 1], x_best * [1, 1.1, 1], x_best * [1, 1, 1.2]]
        res = optimize.minimize(neg, x_best, method="Nelder-Mead",
                                options={"xatol": 0.01, "fatol": 1.0, "maxfev": MAX_REFINE, "initial_simplex": simplex})
        if -res.fun > r_best:
            x_best, r_best = res.x, float(-res.fun)
        log(f"Nelder-Mead: {len(evals)} evaluations; best " + _fmt(x_best) + f": {r_best:.1f}")
    return {
        "policy": "margin",
        "params": {k: round(float(v), 4) for k, v in zip(PARAMS, x_best, strict=True)},
        "objective": "mean episode reward on the tuning seeds (common random numbers)",
        "objective_value": round(r_best, 3),
        "scenario": scenario,
        "seeds": _seed_text(seeds),
        "n_seeds": len(seeds),
        "columns": [*PARAMS, "reward"],
        "grid": [[float(v) for v in p] + [round(float(r), 3)] for p, r in zip(points, rewards, strict=True)],
        "refinement": [[round(v, 4) for v in row[:3]] + [round(row[3], 3)] for row in evals],
        "wall_time_s": round(time.perf_counter() - t0, 1),
    }


def sca_per_slot_reward(fraction: float, seeds, scenario="paper", max_steps: int | None = None) -> float:
    """Mean episode reward over ``seeds`` of per-slot SCA designed at ``fraction`` x eps* (``max_steps`` slots
    per mission, default all).
    """
    from iscc_gym.agents.sca_slot import SCAPolicy
    from iscc_gym.eval.evaluate import run_episodes

    policy = SCAPolicy(make_scenario(scenario), mode="per_slot", loss_design_fraction=float(fraction))
    return float(run_episodes(policy, list(seeds), scenario, max_steps=max_steps)["episodes"]["reward"].mean())


def tune_sca_per_slot(seeds=TUNE_SEEDS, grid=SCA_FRACTION_GRID, scenario: str = "paper", refine: bool = True,
                      log=print, progress=None, max_steps: int | None = None) -> dict:
    """Per-slot SCA's design loss fraction: the grid, then a bounded scalar search between the best
    grid point's neighbours, every point on the same tuning seeds; returns the tuning record.
    ``progress(1)``, if given, is called after each evaluation; ``max_steps`` cuts the missions (tests).
    """
    from scipy import optimize

    seeds = check_tuning_seeds(seeds)
    grid = sorted(float(g) for g in grid)
    if not grid or grid[0] <= 0.0 or grid[-1] > 1.0:
        raise ValueError(f"grid {grid}: design loss fractions must lie in (0, 1]")
    t0 = time.perf_counter()

    def reward(x):
        r = sca_per_slot_reward(x, seeds, scenario, max_steps)
        if progress is not None:
            progress(1)
        return r

    rewards = [reward(g) for g in grid]
    best = int(np.argmax(rewards))
    x_best, r_best, evals = grid[best], rewards[best], []
    log(f"grid: {len(grid)} points x {len(seeds)} missions in {time.perf_counter() - t0:.1f} s; best "
        f"loss_design_fraction = {x_best:.4g}: {r_best:.1f}")
    if refine and len(grid) > 1:
        lo, hi = grid[max(best - 1, 0)], grid[min(best + 1, len(grid) - 1)]

        def neg(x):
            r = reward(x)
            evals.append([float(x), r])
            return -r

        optimize.minimize_scalar(neg, bounds=(lo, hi), method="bounded",
                                 options={"xatol": 1e-3, "maxiter": MAX_SCALAR_REFINE})
        for x, r in evals:
            if r > r_best:
                x_best, r_best = x, r
        log(f"bounded search in [{lo:g}, {hi:g}]: {len(evals)} evaluations; best loss_design_fraction = "
            f"{x_best:.4g}: {r_best:.1f}")
    return {
        "policy": PER_SLOT_RECORD,
        "params": {"loss_design_fraction": round(float(x_best), 5)},
        "objective": "mean episode reward on the tuning seeds (common random numbers)",
        "objective_value": round(r_best, 3),
        "scenario": scenario,
        "seeds": _seed_text(seeds),
        "n_seeds": len(seeds),
        "columns": ["loss_design_fraction", "reward"],
        "grid": [[g, round(r, 3)] for g, r in zip(grid, rewards, strict=True)],
        "refinement": [[round(x, 5), round(r, 3)] for x, r in evals],
        "wall_time_s": round(time.perf_counter() - t0, 1),
    }


def _seed_text(seeds):
    return f"{seeds[0]}-{seeds[-1]}" if seeds == list(range(seeds[0], seeds[-1] + 1)) else seeds


def _fmt(x) -> str:
    return ", ".join(f"{k} = {v:.4g}" for k, v in zip(PARAMS, x, strict=True))


def build_parser(prog: str = "python -m eval.tune") -> Parser:
    ap = Parser(prog=prog, gym_packages=True, description=__doc__.split("\n")[0])
    ap.add_argument("policy", choices=["margin", PER_SLOT_RECORD, *MODEL_GRIDS],
                    help="the baseline to tune (myopic, dpp, mpc: on the urban task, --scenario urban; adaptive, "
                         "bayes: on the field task, --scenario field)")
    ap.add_argument("--episodes", type=positive_int, default=len(TUNE_SEEDS), metavar="N",
                    help=f"tuning missions (default: {len(TUNE_SEEDS)})")
    ap.add_argument("--seed-start", type=nonneg_int, default=TUNE_SEED_START, metavar="SEED",
                    help=f"first tuning seed, outside the evaluation seeds (default: {TUNE_SEED_START})")
    ap.add_argument("--scenario", default="paper", help="scenario preset (default: paper; urban: the urban task, "
                                                        "records <policy>-urban.yml)")
    ap.add_argument("--max-steps", type=positive_int, default=None, metavar="N",
                    help="slots per tuning mission for myopic, dpp and mpc (default: the whole mission; tests)")
    ap.add_argument("--no-refine", action="store_true",
                    help="grid only (no Nelder-Mead for margin, no bounded search for sca-per-slot)")
    ap.add_argument("--out", metavar="PATH",
                    help="where to write the record (default: the package's agents/tuned/<policy>.yml, which "
                         "make_policy reads; checked before the run)")
    ap.add_argument("--quiet", action="store_true",
                    help="no progress bar (there is none either when stderr is not a terminal)")
    return ap


def main(argv: list[str] | None = None, prog: str = "python -m eval.tune") -> dict:
    args = build_parser(prog).parse_args(argv)
    seeds = check_tuning_seeds(seed_list(args.seed_start, args.episodes))
    if args.out:
        check_writable_file(args.out, "--out")
    show = show_progress(args.quiet)
    task = task_of(make_scenario(args.scenario))
    if task == "field" and MODEL_TASKS.get(args.policy) != "field":
        raise ValueError(f"--scenario {args.scenario!r} is the field task, whose {args.policy} is the paper's as "
                         "tuned there (the world it does not know is the task's point): tune it with --scenario "
                         "paper, or tune the field's own rungs (python -m eval.tune adaptive|bayes --scenario field)")
    task = record_task(make_scenario(args.scenario))
    if args.policy in MODEL_GRIDS:
        total = int(np.prod([len(v) for v in MODEL_GRIDS[args.policy].values()]))

        def tune(seeds, scenario, refine, log, progress):
            return tune_model_grid(args.policy, seeds, scenario, log, progress, max_steps=args.max_steps)
    elif args.policy == "margin":
        total = n_batches(int(np.prod([len(v) for v in MARGIN_GRID.values()])), len(seeds))
        total += 0 if args.no_refine else MAX_REFINE
        tune = tune_margin
    else:
        total = len(SCA_FRACTION_GRID) + (0 if args.no_refine else MAX_SCALAR_REFINE)
        tune = tune_sca_per_slot
    with progress_bar(total, "python -m eval.tune", unit="batch", enabled=show) as bar:
        record = tune(seeds, scenario=args.scenario, refine=not args.no_refine,
                      log=bar.write if show else print, progress=bar.update if show else None)
    record["command"] = " ".join(["python -m eval.tune", *[a for a in (argv if argv is not None else sys.argv[1:])
                                                          if a != "--quiet"]])
    path = save_tuned(record_name(args.policy, task), record, args.out)
    print(f"wrote {path}: {record['params']}")
    return record


if __name__ == "__main__":
    sys.exit(run_console(main, None, "python -m eval.tune"))
