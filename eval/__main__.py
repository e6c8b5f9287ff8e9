"""``python -m eval``: compare policies on held-out episodes with common random numbers.

Examples::

    python -m eval                                  # shipped PPO agent vs every scripted baseline
    python -m eval --policies ppo,sca,equal         # ppo: the shipped agent
    python -m eval --policies ppo=runs/ppo,sca,equal --episodes 50 --json out.json --plots figs/
    python -m eval --train-steps 300000             # train a fresh PPO agent first, then compare
    python -m eval --env iscc_gym/ISCC-Urban-v0     # the urban task: myopic, margin, dpp, mpc, oracle

Policies are ``NAME=PATH`` (a run directory of ``python -m train`` or a model ``.zip``; a bare ``ppo`` is
the shipped agent) or a spec of :func:`agents.make_policy` (``sca``, ``sca-per-slot``, ``sca-ignore-loss``,
``equal``, ``fixed:0.2,0.2,0.6``, ``grid``, ``evolutionary``, ``margin``, ``margin:4,1.3``, ``myopic``).
Episodes are seeded ``--seed-start``, ``--seed-start + 1``, ... (or ``--seeds``): held out from training
(``python -m train`` trains on seeds below 100 and evaluates on seeds from 1,000,000).

Exit code 0 on success; a user's mistake (a bad path, spec, seed or number) exits 2 with one line, before
any episode is played. A progress bar shows on a terminal (not with ``--quiet`` or a redirected stderr).
Model ``.zip`` files and ``vecnormalize.pkl`` are pickles, which execute code when loaded: load only
files you trust.
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
import time
from pathlib import Path

import numpy as np
from iscc_gym.agents.shipped import PPO_AGENT as SHIPPED_AGENT  # noqa: F401 (a name of this command)
from iscc_gym.agents.tasks import TASK_POLICIES, task_policies
from iscc_gym.commands.cli import invoked_prog, run
from iscc_gym.commands.docs import save_json
from iscc_gym.commands.options import (
    PICKLE_WARNING,
    Parser,
    check_writable_dir,
    check_writable_file,
    env_scenario,
    nonneg_int,
    parse_seeds,
    positive_int,
    progress_bar,
    show_progress,
)
from iscc_gym.commands.protocol import EVAL_SEED_START, seed_list
from iscc_gym.eval.engine import compare, runs_items, worlds
from iscc_gym.eval.policies import (  # noqa: F401
    build_policies,
    build_policy,
    check_specs,
    policy_name,
    resolve_specs,
    run_parallel,
    split_specs,
)
from iscc_gym.eval.training import run_training

from iscc_gym import ENV_ID, URBAN_ENV_ID
from iscc_gym.lazy import lazy_names
from iscc_gym.tasks import TASKS

#: Names this module offers from the engine, the rollout loop and the report, imported on first use
#: (:mod:`iscc_gym.lazy`): the rollout loop loads the compiled env, so a mistake in the arguments is refused before it
#: loads (issue 43.12).
_LAZY = {"evaluate": "iscc_gym.eval.engine", "horizon_slots": "iscc_gym.eval.evaluate",
         "summarize": "iscc_gym.eval.evaluate", **dict.fromkeys(("format_table", "markdown_table", "oracle_share",
                                                                  "oracle_share_sentence"), "iscc_gym.eval.report")}
__getattr__, __dir__ = lazy_names(__name__, _LAZY, globals())


#: The default comparison on the paper's task (each task's: :data:`iscc_gym.agents.tasks.TASK_POLICIES`).
DEFAULT_POLICIES = TASK_POLICIES[ENV_ID].policies
#: The default comparison on the urban task (``--env iscc_gym/ISCC-Urban-v0``).
URBAN_POLICIES = TASK_POLICIES[URBAN_ENV_ID].policies
PROG = "python -m eval"


def save_plots(res: dict, out_dir: str | Path, dt_s: float = 0.1) -> list[str]:
    """Allocation over time, tracking error over time and 3-D trajectories of the first recorded
    episode of every policy, as PNGs.
    """
    from iscc_gym.eval.figures import new_figure, save_figure

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    traces = res["traces"]
    paths = []

    def save(fig, name):
        fig.tight_layout()
        save_figure(fig, out / name)
        paths.append(str(out / name))

    fig = new_figure((9, 2.4 * len(traces)), dpi=90)
    for k, (name, tr) in enumerate(traces.items()):
        ax = fig.add_subplot(len(traces), 1, k + 1)
        alpha = tr["alpha"][:, 0]
        t = np.arange(len(alpha)) * dt_s
        for j, label in enumerate(("sensing", "control", "data")):
            ax.plot(t, alpha[:, j], lw=0.8, label=label)
        ax.set_ylabel(f"{name}\nshare")
        ax.set_ylim(0, 1)
        ax.legend(loc="upper right", fontsize=7, ncol=3)
    fig.axes[-1].set_xlabel("time (s)")
    save(fig, "allocation.png")

    fig = new_figure((9, 3.5), dpi=90)
    ax = fig.add_subplot(1, 1, 1)
    for name, tr in traces.items():
        err = tr["tracking_error_m"][:, 0]
        ax.plot(np.arange(len(err)) * dt_s, err, lw=0.8, label=name)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("tracking error (m)")
    ax.set_yscale("log")
    ax.legend(fontsize=7)
    save(fig, "tracking_error.png")

    fig = new_figure((6, 5), dpi=90)
    ax = fig.add_subplot(1, 1, 1, projection="3d")
    ref = next(iter(traces.values()))["ref_pos"][:, 0]
    ax.plot(ref[:, 0], ref[:, 1], ref[:, 2], "k--", lw=1, label="reference")
    for name, tr in traces.items():
        pos = tr["pos"][:, 0]
        ax.plot(pos[:, 0], pos[:, 1], pos[:, 2], lw=0.8, label=name)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.legend(fontsize=7)
    save(fig, "trajectories.png")
    return paths


def build_parser(prog: str = PROG) -> argparse.ArgumentParser:
    ap = Parser(prog=prog, gym_packages=True, description=__doc__.split("\n")[0], epilog=PICKLE_WARNING)
    single = [e for e, t in TASKS.items() if not t.fleet]
    ap.add_argument("--env", default=ENV_ID, metavar="ID",
                    help=f"env id (default: {ENV_ID}): " + "; ".join(
                        f"{e}: {TASKS[e].title} (preset {TASKS[e].preset!r}, policies {task_policies(e).policies}, "
                        f"reference {task_policies(e).reference})" for e in single)
                    + "; " + ", ".join(e for e, t in TASKS.items() if t.fleet) + " runs python -m eval.multi with the "
                    "other flags (--n-drones K, --k-scan, ...: python -m eval.multi --help)")
    ap.add_argument("--policies", default=None, metavar="LIST",
                    help="comma-separated policies: NAME=PATH (a trained agent: a run directory of python -m train "
                         "or a model .zip; loads that directory's vecnormalize.pkl too, both pickles: only files "
                         "you trust), 'ppo' (the shipped agent), or a scripted spec: sca, sca-per-slot, "
                         "sca-ignore-loss, equal, fixed:A_SEN,A_CTRL,A_COMM, grid, evolutionary, margin, "
                         "margin:M_CTRL,M_COMM, myopic, aware (myopic designed on the world played: the "
                         "model-knowledge bound), on the field task adaptive, and on the urban task dpp, dpp:V, mpc, "
                         "oracle (default: the task's comparison, in --env's help)")
    ap.add_argument("--episodes", type=positive_int, default=20, metavar="N",
                    help="held-out episodes (missions) per policy (default: 20)")
    ap.add_argument("--seed-start", type=nonneg_int, default=EVAL_SEED_START, metavar="SEED",
                    help="seed of the first episode; the others follow (default: 10000)")
    ap.add_argument("--seeds", metavar="LIST",
                    help="explicit comma-separated distinct seeds, instead of --episodes/--seed-start")
    ap.add_argument("--scenario", default=None,
                    help="scenario preset (default: the env's own, in --env's help; a variant of the same task, "
                         "e.g. literal on the paper's)")
    ap.add_argument("--reference", metavar="NAME",
                    help="policy the paired differences are taken against (default: the task's reference, if "
                         f"evaluated: {', '.join(f'{t.reference} on {e}' for e, t in TASK_POLICIES.items())})")
    ap.add_argument("--focus", metavar="NAME",
                    help="policy whose paired differences to every other policy are reported too (default: ppo, "
                         "if evaluated)")
    ap.add_argument("--variants", metavar="LIST",
                    help="play the policies (built for the task's preset) on these variants of the task's missions "
                         "too, one table each: comma-separated names of the task's variants (iscc_gym.tasks), or "
                         "'shifts' (the urban task's: " + ", ".join(TASKS[URBAN_ENV_ID].shifts) + ")")
    ap.add_argument("--runs", metavar="DIR",
                    help="add every seed's agent of python -m train --seeds ... --out DIR (DIR/seed_<s>, named "
                         "seed_<s>) to the policies")
    ap.add_argument("--max-steps", type=positive_int, metavar="N",
                    help="slots per episode, >= 1 (default: the whole mission)")
    ap.add_argument("--json", metavar="PATH", help="write the results as JSON to PATH (checked before the run)")
    ap.add_argument("--plots", metavar="DIR",
                    help="write allocation / error / trajectory plots (PNG) into DIR (checked before the run)")
    ap.add_argument("--train-steps", type=nonneg_int, default=0, metavar="N",
                    help="train a fresh PPO agent for N steps first (into --train-out) and evaluate it as 'ppo' "
                         "(default: 0, no training)")
    ap.add_argument("--train-out", default="runs/ppo_main", metavar="DIR",
                    help="run directory of --train-steps (default: runs/ppo_main)")
    ap.add_argument("--torch-threads", type=positive_int, default=1, metavar="N",
                    help="torch threads of a learned policy's inference (default: 1, the fastest for these batches)")
    ap.add_argument("--workers", type=positive_int, default=min(2, os.cpu_count() or 1), metavar="N",
                    help="processes playing the policies side by side (default: up to 2; 1: all in this process)")
    ap.add_argument("--quiet", action="store_true",
                    help="no progress bar (there is none either when stderr is not a terminal)")
    return ap


def _pick(name: str | None, default: str, names: list[str], flag: str) -> str | None:
    """``name`` if it is one of ``names`` (``ValueError`` if not); without ``name``, ``default`` if present."""
    if name is None:
        return default if default in names else None
    if name not in names:
        raise ValueError(f"{flag} {name!r} is not one of the policies evaluated: {', '.join(names)}")
    return name


def main(argv: list[str] | None = None, prog: str = PROG) -> dict:
    """Run the comparison; returns the results (see :func:`iscc_gym.eval.engine.evaluate`).

    A user's mistake raises ``ValueError``/``OSError`` with one line, before any episode is played (or
    argparse exits with code 2); :func:`console` turns them into exit codes.
    """
    fleet, rest = _multi_argv(sys.argv[1:] if argv is None else list(argv))
    if rest is not None:
        from iscc_gym.eval.multi import main as multi_main

        return multi_main(rest, prog=f"{prog} --env {fleet}")
    args = build_parser(prog).parse_args(argv)
    if task_policies(args.env).fleet:  # ValueError naming the tasks for an unknown one
        raise ValueError(f"--env {args.env!r}: use one of {', '.join(TASKS)}")
    task = task_policies(args.env)
    args.scenario = env_scenario(args.env, args.scenario)  # the env's own, or a variant of its task
    if args.policies is None:
        args.policies = task.policies
    from iscc_gym import make_scenario

    try:
        scenario = make_scenario(args.scenario)
    except (ValueError, KeyError, TypeError) as e:
        raise ValueError(f"--scenario {args.scenario!r}: {e.args[0] if e.args else e}") from None
    seeds = (parse_seeds(args.seeds) if args.seeds is not None
             else seed_list(args.seed_start, args.episodes))
    items = resolve_specs(args.policies, task.agent)
    if args.runs is not None:
        items = resolve_specs(",".join(items + runs_items(args.runs)))  # FileNotFoundError naming the fix
    played = worlds(args.env, args.variants, args.scenario)  # ValueError naming the task's variants
    if args.variants is not None and args.plots:
        raise ValueError("--variants compares on several missions' variants; --plots takes the task's own missions "
                         "(leave --variants out)")
    if args.train_steps > 0:
        items = [it for it in items if policy_name(it) != "ppo"]
        items.insert(0, f"ppo={args.train_out}")
    names = [policy_name(it) for it in items]
    reference = _pick(args.reference, task.reference, names, "--reference")
    focus = _pick(args.focus, task.focus, names, "--focus")
    check_specs([it for it in items if not (args.train_steps > 0 and policy_name(it) == "ppo")], args.scenario)
    # every output is checked before the (long) run
    if args.train_steps > 0:
        out = Path(args.train_out)
        if out.exists() and (not out.is_dir() or any(out.iterdir())):
            raise FileExistsError(f"--train-out {out}: not an empty directory (a previous run?); train into a "
                                  "new --train-out, or evaluate that run with --policies ppo=" + str(out))
        check_writable_dir(out, "--train-out")
    if args.json:
        check_writable_file(args.json, "--json")
    if args.plots:
        check_writable_dir(args.plots, "--plots")
    show = show_progress(args.quiet)
    if args.train_steps > 0:
        summary = run_training(["--env", args.env, "--total-timesteps", args.train_steps, "--scenario", args.scenario],
                               args.train_out, quiet=not show)["summary"]
        print(f"trained PPO: {summary['timesteps']} steps in {summary['wall_time_s']:.0f} s -> {args.train_out}")
    t0 = time.perf_counter()
    record = 1 if args.plots else 0
    from iscc_gym.eval.evaluate import horizon_slots

    # the time left from each policy's own pace (eval.policies.TimeLeft), not tqdm's from the slots done overall
    from iscc_gym.eval.report import format_table, oracle_share, oracle_share_sentence
    bar = progress_bar(len(items) * sum(horizon_slots(w, args.max_steps) for w in played.values()), "evaluating",
                       unit="slot", enabled=show, unit_scale=True,
                       bar_format="{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} [{elapsed}{postfix}]")
    time_left = getattr(bar, "set_time_left", None)
    if time_left is None and hasattr(bar, "set_postfix_str"):  # tqdm on a terminal
        def time_left(s):
            bar.set_postfix_str("" if s is None else f"about {s:.0f} s left", refresh=False)
    try:
        results = compare(args.env, items, seeds, variants=args.variants, scenario=args.scenario, reference=reference,
                          focus=focus, max_steps=args.max_steps, record=record,
                          workers=args.workers if len(items) * len(played) > 1 else 1,
                          torch_threads=args.torch_threads, progress=bar.update if show else None, check=False,
                          time_left=time_left if show else None)
    finally:
        bar.close()
    variants = task.task.variants if args.variants is not None else {}
    for name, res in results.items():
        if variants:
            print(f"\nmissions: {name} ({variants[name].why})")
        print(format_table(res))
        for note in res.get("notes", []):
            print(f"note: {note}")
        # the share of the gap to the bound that each of the task's policies closes (Task.share_of)
        shares = {a: oracle_share(res, agent=a, oracle="oracle" if "oracle" in res["policies"] else "aware",
                                  base="myopic") for a in task.task.share_of}
        shares = {a: sh for a, sh in shares.items() if sh is not None}
        if shares:
            res["oracle_shares"] = shares
            res["oracle_share"] = next(iter(shares.values()))
            for sh in shares.values():
                print(oracle_share_sentence(sh))
    res = next(iter(results.values()))
    print(f"evaluated {len(res['policies'])} policies x {len(seeds)} episodes"
          + (f" x {len(results)} variants" if variants else "") + f" in {time.perf_counter() - t0:.1f} s")
    if args.plots:
        for p in save_plots(res, args.plots, scenario.dt_s):
            print(f"wrote {p}")
        res.pop("traces")
    if variants:
        res = results
    if args.json:
        save_json(args.json, res)
    return res


def _multi_argv(argv: list[str]) -> tuple[str | None, list[str] | None]:
    """``(env id, the other arguments)`` if the arguments ask for a fleet task (:attr:`iscc_gym.tasks.Task.fleet`;
    ``--gym-packages`` imported first), else ``(None, None)``.
    """
    from iscc_gym.commands.options import import_gym_packages

    from iscc_gym.tasks import is_fleet

    import_gym_packages(argv)
    for i, a in enumerate(argv):
        if a == "--env" and i + 1 < len(argv) and is_fleet(argv[i + 1]):
            return argv[i + 1], argv[:i] + argv[i + 2:]
        if a.startswith("--env=") and is_fleet(a.split("=", 1)[1]):
            return a.split("=", 1)[1], argv[:i] + argv[i + 1:]
    return None, None


def console(argv: list[str] | None = None, prog: str | None = None) -> int:
    """The ``iscc-eval`` command: :func:`main`, ending with exit code 0 on success, 2 after a one-line
    error for a user's mistake, 130 on Ctrl-C (:func:`iscc_gym.commands.cli.run`).
    """
    prog = invoked_prog(prog or os.path.basename(sys.argv[0]) or PROG)  # python -m iscc_gym.eval, as typed
    return run(functools.partial(main, prog=prog), argv, prog)


if __name__ == "__main__":
    sys.exit(console(prog=PROG))
