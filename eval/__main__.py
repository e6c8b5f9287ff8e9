"""``python -m eval``: compare policies on held-out episodes with common random numbers.

Examples::

    python -m eval                                  # shipped PPO agent vs every scripted baseline
    python -m eval --policies ppo=runs/ppo,sca,equal --episodes 50 --json out.json --plots figs/
    python -m eval --train-steps 300000             # train a fresh PPO agent first, then compare

Policies are ``NAME=PATH`` (a run directory of ``python -m train`` or a model ``.zip``) or a spec of
:func:`agents.make_policy` (``sca``, ``sca-per-slot``, ``sca-ignore-loss``, ``equal``,
``fixed:0.2,0.2,0.6``, ``grid``, ``evolutionary``, ``margin``, ``margin:4,1.3``, ``myopic``).
Episodes are seeded ``--seed-start``,
``--seed-start + 1``, ... (or ``--seeds``): held out from training (``python -m train`` trains on
seeds below 100 and evaluates on seeds from 1,000,000).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from eval.docs import publish, save_json
from eval.evaluate import evaluate, format_table, run_episodes, summarize

#: The trained PPO agent shipped in the repository (produced by ``python -m eval.ship``).
SHIPPED_AGENT = Path(__file__).resolve().parent.parent / "agents" / "trained" / "ppo_iscc"
DEFAULT_POLICIES = f"ppo={SHIPPED_AGENT},sca,sca-per-slot,margin,myopic,equal"


def build_policy(item: str, scenario: str = "paper"):
    """``(name, policy)`` of one ``NAME=PATH`` (a trained agent) or :func:`agents.make_policy` spec."""
    from agents import make_policy

    if "=" in item:
        name, path = item.split("=", 1)
        from agents.sb3_policy import SB3Policy

        return name, SB3Policy.load(path)
    return item, make_policy(item, scenario)


def build_policies(specs: str, scenario: str = "paper") -> dict:
    """``{name: policy}`` from a comma-separated list of ``NAME=PATH`` or make_policy specs."""
    items = _items(specs)
    return dict(build_policy(item, scenario) for item in items)


def _items(specs: str) -> list[str]:
    items = [p.strip() for p in _split_specs(specs) if p.strip()]
    if not items:
        raise ValueError("--policies is empty; e.g. --policies sca,equal")
    return items


#: Specs whose evaluation takes longest (an optimisation every slot): started first by the workers.
SLOW_SPECS = ("sca-per-slot", "myopic", "grid", "evolutionary")


def _worker_init(torch_threads: int) -> None:
    """A worker process: one numba thread (the workers already use the cores) and ``torch_threads``."""
    import numba

    numba.set_num_threads(1)
    if torch_threads:
        import torch

        torch.set_num_threads(torch_threads)


def _run_item(item: str, seeds, scenario: str, max_steps, record: int):
    name, policy = build_policy(item, scenario)
    return name, run_episodes(policy, seeds, scenario, max_steps, record)


def run_parallel(specs: str, seeds, scenario: str = "paper", max_steps=None, record: int = 0, workers: int = 2,
                 torch_threads: int = 1) -> dict:
    """``{name: run_episodes result}`` of every policy of ``specs``, in ``workers`` processes (spawned,
    one numba thread each); every policy plays the same seeds, so the results are those of one process."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    items = _items(specs)
    order = sorted(range(len(items)), key=lambda i: items[i].split("=")[0] not in SLOW_SPECS)
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init,
                             initargs=(torch_threads,)) as pool:
        futures = {i: pool.submit(_run_item, items[i], list(seeds), scenario, max_steps, record) for i in order}
        results = [futures[i].result() for i in range(len(items))]
    names = [n for n, _ in results]
    if len(set(names)) != len(names):
        raise ValueError(f"--policies names a policy twice: {names}")
    return dict(results)


def _split_specs(specs: str) -> list[str]:
    """Split on commas, except inside ``fixed:a,b,c`` and ``margin:a,b``."""
    out, parts = [], specs.split(",")
    i = 0
    while i < len(parts):
        p = parts[i]
        width = 3 if p.strip().startswith("fixed:") else 2 if p.strip().startswith("margin:") else 1
        out.append(",".join(parts[i:i + width]))
        i += width
    return out


def save_plots(res: dict, out_dir: str | Path, dt_s: float = 0.1) -> list[str]:
    """Allocation over time, tracking error over time and 3-D trajectories of the first recorded
    episode of every policy, as PNGs."""
    from eval.figures import new_figure

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    traces = res["traces"]
    paths = []

    def save(fig, name):
        fig.tight_layout()
        fig.savefig(out / name)
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


def markdown_table(res: dict, command: str) -> str:
    """The comparison as markdown: per policy mean [95 % CI], then the paired differences."""
    cols = [("reward", "episode reward", "{:.1f}"), ("tracking_error_m", "tracking error (m)", "{:.4f}"),
            ("violation", "violation fraction", "{:.3f}"), ("rate_violation", "rate viol.", "{:.3f}"),
            ("stability_violation", "stability viol.", "{:.3f}"), ("peb_m", "mean PEB (m)", "{:.3g}"),
            ("rate_comm_mbps", "rate (Mbit/s)", "{:.2f}"), ("terminated", "lost track", "{:.2f}")]
    n = len(res["seeds"])
    split_title = "mean split (sen / ctrl / comm)"
    lines = [f"Generated by `{command} --write-docs`: {n} held-out missions (seeds {res['seeds'][0]}-"
             f"{res['seeds'][-1]}), the same for every policy (common random numbers); mean [95 % CI].", "",
             "| policy | " + " | ".join(title for _, title, _ in cols) + f" | {split_title} |",
             "|---|" + "---|" * (len(cols) + 1)]
    for name, p in res["policies"].items():
        cells = []
        for metric, _, fmt in cols:
            lo, hi = p[f"{metric}_ci95"]
            cells.append(f"{fmt.format(p[metric + '_mean'])} [{fmt.format(lo)}, {fmt.format(hi)}]")
        split = " / ".join(f"{p[f'alpha_{k}_mean']:.3f}" for k in ("sen", "ctrl", "comm"))
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {split} |")
    if res["paired"]:
        lines += ["", f"Paired differences against {res['reference']} (policy minus {res['reference']}, per mission), "
                  "mean [95 % CI]:", "", "| pair | episode reward | tracking error (m) | violation fraction |",
                  "|---|---|---|---|"]
        for pair, d in res["paired"].items():
            cells = [f"{d[m + '_diff_mean']:+.4g} [{d[m + '_diff_ci95'][0]:+.4g}, {d[m + '_diff_ci95'][1]:+.4g}]"
                     for m in ("reward", "tracking_error_m", "violation")]
            lines.append(f"| {pair} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(prog="python -m eval", description=__doc__.split("\n")[0])
    ap.add_argument("--policies", default=DEFAULT_POLICIES,
                    help="comma-separated NAME=PATH or specs (default: the shipped PPO agent, sca, "
                         "sca-per-slot, margin, myopic, equal)")
    ap.add_argument("--episodes", type=int, default=20, help="held-out episodes per policy")
    ap.add_argument("--seed-start", type=int, default=10_000, help="seed of the first episode")
    ap.add_argument("--seeds", help="explicit comma-separated seeds (instead of --episodes/--seed-start)")
    ap.add_argument("--scenario", default="paper", help="scenario preset")
    ap.add_argument("--reference", default="sca", help="policy the paired differences are taken against")
    ap.add_argument("--max-steps", type=int, help="slots per episode (default: the whole mission)")
    ap.add_argument("--json", metavar="PATH", help="write the results as JSON")
    ap.add_argument("--plots", metavar="DIR", help="write allocation / error / trajectory plots here")
    ap.add_argument("--train-steps", type=int, default=0,
                    help="train a fresh PPO agent for this many steps first (into --train-out) and "
                         "evaluate it as 'ppo'")
    ap.add_argument("--train-out", default="runs/ppo_main", help="run directory of --train-steps")
    ap.add_argument("--torch-threads", type=int, default=1,
                    help="torch threads of a learned policy's inference (1: fastest for the batch sizes here)")
    ap.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1),
                    help="processes playing the policies side by side (default: up to 2; 1: all in this process)")
    ap.add_argument("--write-docs", action="store_true",
                    help="write the comparison into docs/results.md and the README (comparison block)")
    args = ap.parse_args(argv)
    if args.workers < 1:
        ap.error(f"--workers {args.workers}: use an integer >= 1")
    specs = args.policies
    if args.train_steps > 0:
        from train import Args
        from train import main as train_main

        summary = train_main(Args(total_timesteps=args.train_steps, out=args.train_out, scenario=args.scenario,
                                  progress_bar=True))
        print(f"trained PPO: {summary['timesteps']} steps in {summary['wall_time_s']:.0f} s -> {args.train_out}")
        specs = ",".join(f"ppo={args.train_out}" if s.startswith("ppo=") else s for s in _split_specs(specs))
        if "ppo=" not in specs:
            specs = f"ppo={args.train_out}," + specs
    seeds = ([int(s) for s in args.seeds.split(",")] if args.seeds
             else list(range(args.seed_start, args.seed_start + args.episodes)))
    if args.torch_threads < 1:
        ap.error(f"--torch-threads {args.torch_threads}: use an integer >= 1")
    if any("=" in p for p in _split_specs(specs)):
        import torch

        torch.set_num_threads(args.torch_threads)
    t0 = time.perf_counter()
    record = 1 if args.plots else 0
    if args.workers > 1 and len(_items(specs)) > 1:
        runs = run_parallel(specs, seeds, args.scenario, args.max_steps, record, args.workers, args.torch_threads)
        reference = args.reference if args.reference in runs else None
        res = summarize(runs, seeds, reference)
    else:
        policies = build_policies(specs, args.scenario)
        reference = args.reference if args.reference in policies else None
        res = evaluate(policies, seeds, scenario=args.scenario, reference=reference, max_steps=args.max_steps,
                       record=record)
    print(format_table(res))
    print(f"evaluated {len(res['policies'])} policies x {len(seeds)} episodes in {time.perf_counter() - t0:.1f} s")
    if args.plots:
        from iscc_gym import make_scenario

        for p in save_plots(res, args.plots, make_scenario(args.scenario).dt_s):
            print(f"wrote {p}")
        res.pop("traces")
    if args.write_docs:
        rest = [a for a in (argv or []) if a != "--write-docs"]
        cmd = " ".join(["python -m eval", *rest])
        publish("comparison", "Learned vs scripted allocation", markdown_table(res, cmd))
    if args.json:
        save_json(args.json, res)
    return res


if __name__ == "__main__":
    main(sys.argv[1:])
