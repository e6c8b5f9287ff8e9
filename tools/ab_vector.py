"""A/B of the native vector env's speed between revisions of this repository, in fresh processes.

Each revision (two or more: a bisection's candidates in one run) is checked out into a temporary git worktree; every
round runs one fresh process per revision, in alternating order, each importing ``iscc_gym`` from its worktree
(``PYTHONPATH``) with one numba thread, warming the compiled kernels (numba caches them in each worktree: the first
round of a revision compiles), then timing the best of ``--repeats`` runs of ``--steps`` batched steps of
``gym.make_vec(ENV, num_envs=N, vectorization_mode="vector_entry_point")``. The median over rounds of each
revision's best is reported, with every round's figures, so one noisy round does not decide. Run it on a quiet machine::

    python tools/ab_vector.py 5852000 HEAD --rounds 7

Issue 43.14 (the paper task's vector env measured 6.6e5 env-steps/s at the urban task's landing, 4.4e5 later, on a
busy machine) is settled with it.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: One timed process: the env-steps/s of the best run, as a JSON line.
TIMED = """
import json, sys, time
import numba
numba.set_num_threads(1)
import gymnasium as gym, numpy as np
import iscc_gym
assert iscc_gym.__file__.startswith(sys.argv[1]), iscc_gym.__file__
env_id, n, steps, repeats = sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5])
venv = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point")
venv.reset(seed=0)
actions = np.random.default_rng(0).uniform(-1, 1, (steps, n, 3)).astype(np.float32)
for a in actions[:5]:
    venv.step(a)
best = 0.0
for _ in range(repeats):
    t0 = time.perf_counter()
    for a in actions:
        venv.step(a)
    best = max(best, steps * n / (time.perf_counter() - t0))
print(json.dumps(best))
"""


def _run(tree: Path, args) -> float:
    env = {**os.environ, "PYTHONPATH": str(tree), "ISCC_GYM_QUIET": "1", "NUMBA_NUM_THREADS": "1"}
    r = subprocess.run([sys.executable, "-c", TIMED, str(tree), args.env, str(args.num_envs), str(args.steps),
                        str(args.repeats)], capture_output=True, text=True, env=env, cwd=tree, timeout=1800)
    if r.returncode != 0:
        raise SystemExit(f"ab_vector: the run in {tree} failed: {r.stderr.strip().splitlines()[-1:]}")
    return float(r.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(prog="python tools/ab_vector.py", description=__doc__.split("\n")[0])
    ap.add_argument("revs", nargs="+", metavar="REV",
                    help="revisions (commits, tags or branches), two or more; ratios against the first")
    ap.add_argument("--env", default="iscc_gym/ISCC-v0", help="env id (default: iscc_gym/ISCC-v0)")
    ap.add_argument("--num-envs", type=int, default=1024, help="vector env size (default: 1024)")
    ap.add_argument("--steps", type=int, default=50, help="batched steps per timed run (default: 50)")
    ap.add_argument("--repeats", type=int, default=5, help="timed runs per process, the best kept (default: 5)")
    ap.add_argument("--rounds", type=int, default=7, help="fresh processes per revision, alternating (default: 7)")
    args = ap.parse_args(argv)
    if len(args.revs) < 2 or len(set(args.revs)) < len(args.revs):
        ap.error("give two or more distinct revisions")
    with tempfile.TemporaryDirectory(prefix="iscc_gym-ab-") as tmp:
        trees = {}
        for name in args.revs:
            tree = Path(tmp) / name.replace("/", "_")
            subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-q", str(tree), name], check=True)
            trees[name] = tree
        try:
            for tree in trees.values():  # compile each tree's kernels into its own numba cache, untimed
                _run(tree, argparse.Namespace(**{**vars(args), "steps": 2, "repeats": 1}))
            rounds: dict[str, list[float]] = {name: [] for name in trees}
            for i in range(args.rounds):
                order = list(trees) if i % 2 == 0 else list(trees)[::-1]
                for name in order:
                    rounds[name].append(_run(trees[name], args))
                print(f"round {i + 1}: " + ", ".join(f"{n} {rounds[n][-1]:,.0f}" for n in trees), flush=True)
        finally:
            for tree in trees.values():
                subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)], check=False)
    med = {name: statistics.median(r) for name, r in rounds.items()}
    print(f"{args.env}, {args.num_envs} envs, one numba thread, best of {args.repeats} x {args.steps} steps, "
          f"median of {args.rounds} rounds (env-steps/s): " + ", ".join(f"{n} {m:,.0f}" for n, m in med.items())
          + "; against " + args.revs[0] + ": "
          + ", ".join(f"{n} {med[n] / med[args.revs[0]]:.3f}" for n in args.revs[1:]))
    out = {"median": med, "rounds": rounds}
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    main()
