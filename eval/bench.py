"""Benchmarks: steps per second of the ISCC env beside a reference measured the same way.

Usage::

    python -m eval.bench [--steps N] [--repeats R] [--json PATH]

Single-env throughput is measured through ``gymnasium.make`` (with its default wrappers) and
actions drawn in advance, so ``Box.sample()`` (about 16 us) is not timed; Gymnasium's Pendulum-v1
is measured in the same process, in the same way, as the reference. Each figure is the median
over ``repeats`` runs.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time

import gymnasium as gym
import numpy as np

import iscc_gym


def env_steps_per_second(env_id: str, n_steps: int, repeats: int, seed: int = 0, **kwargs) -> dict:
    """Median steps/s of ``env.step`` over ``repeats`` runs of ``n_steps`` pre-drawn actions."""
    env = gym.make(env_id, **kwargs)
    env.action_space.seed(seed)
    actions = [env.action_space.sample() for _ in range(n_steps)]
    rates = []
    for r in range(repeats):
        env.reset(seed=seed + r)
        t0 = time.perf_counter()
        for a in actions:
            _, _, terminated, truncated, _ = env.step(a)
            if terminated or truncated:
                env.reset()
        rates.append(n_steps / (time.perf_counter() - t0))
    env.close()
    return {"median_steps_per_s": statistics.median(rates), "runs": rates, "n_steps": n_steps}


def run(n_steps: int = 5000, repeats: int = 5) -> dict:
    """All benchmark figures as a JSON-able dict."""
    return {
        "machine": {"python": platform.python_version(), "numpy": np.__version__,
                    "gymnasium": gym.__version__, "processor": platform.processor() or "unknown"},
        "single_env": {
            "iscc": env_steps_per_second(iscc_gym.ENV_ID, n_steps, repeats),
            "reference_pendulum_v1": env_steps_per_second("Pendulum-v1", n_steps, repeats),
        },
    }


def format_report(res: dict) -> str:
    se = res["single_env"]
    ours, ref = se["iscc"]["median_steps_per_s"], se["reference_pendulum_v1"]["median_steps_per_s"]
    return "\n".join([
        "Single env through gymnasium.make, actions drawn in advance (median of runs):",
        f"  {iscc_gym.ENV_ID:<22} {ours:10,.0f} steps/s  ({1e6 / ours:6.1f} us/step)",
        f"  {'Pendulum-v1 (reference)':<22} {ref:10,.0f} steps/s  ({1e6 / ref:6.1f} us/step)",
        f"  ratio ISCC / Pendulum: {ours / ref:.3f}",
    ])


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(prog="python -m eval.bench", description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=int, default=5000, help="steps per run")
    ap.add_argument("--repeats", type=int, default=5, help="runs per figure (median reported)")
    ap.add_argument("--json", metavar="PATH", help="write the figures as JSON to PATH")
    args = ap.parse_args(argv)
    res = run(args.steps, args.repeats)
    print(format_report(res))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(res, f, indent=2)
        print(f"wrote {args.json}")
    return res


if __name__ == "__main__":
    main(sys.argv[1:])
