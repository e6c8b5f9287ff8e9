"""``python -m experiments.pareto_agents``: train the learned points of the Pareto fronts (issue 15 item 3).

Six PPO runs on ``iscc_gym/ISCC-v0`` at the Pareto comparison's rate requirement
(:data:`iscc_gym.commands.protocol.PARETO_RATE_MIN_BPS`), each ``python -m train`` with the configuration of
``train/hyperparams.yml`` (seed 0) plus the flags of :data:`RUNS`:

* ``ppo/w<x>``: the fixed-weight reward with the rate-shortfall weight ``w_rate = x``;
* ``ppo-lag/<d>``: PPO-Lagrangian (``--algo ppo-lag``, train/lagrangian.py) with the rate-outage
  limit ``d`` and the stability-violation limit :data:`STABILITY_LIMIT`.

Each run trains into ``runs/pareto/<name>`` and its small artifacts (weights, VecNormalize
statistics, config, summary, learning curve, multipliers) are copied into
``agents/trained/pareto/<name>``, where ``python -m experiments.pareto`` finds them.

Example::

    python -m experiments.pareto_agents               # all six (about 2 minutes each on 2 cores)
    python -m experiments.pareto_agents --only ppo/w1  # one
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from iscc_gym.agents.shipped import PARETO_DIR
from iscc_gym.commands.cli import invoked_prog
from iscc_gym.commands.protocol import PARETO_RATE_MIN_BPS
from iscc_gym.train.config import Args

__all__ = ["RUNS", "PARETO_DIR", "STABILITY_LIMIT", "run_args", "train_all", "cli"]

#: Where the trained Pareto points are shipped (one directory per run, named as in :data:`RUNS`).
#: The stability-violation limit of every PPO-Lagrangian run (fraction of slots).
STABILITY_LIMIT = 0.01
#: name -> (algo, env overrides beside the rate requirement, cost limit or None).
RUNS = {
    "ppo/w0.3": ("ppo", {"w_rate": 0.3}, None),
    "ppo/w1": ("ppo", {"w_rate": 1.0}, None),
    "ppo/w3": ("ppo", {"w_rate": 3.0}, None),
    "ppo-lag/0.05": ("ppo-lag", {}, f"rate=0.05,stability={STABILITY_LIMIT}"),
    "ppo-lag/0.10": ("ppo-lag", {}, f"rate=0.1,stability={STABILITY_LIMIT}"),
    "ppo-lag/0.20": ("ppo-lag", {}, f"rate=0.2,stability={STABILITY_LIMIT}"),
}


def run_args(name: str, seed: int = 0, total_timesteps: int | None = None, out_root: str = "runs/pareto") -> Args:
    """The training :class:`Args` of the Pareto run ``name`` (a key of :data:`RUNS`)."""
    if name not in RUNS:
        raise ValueError(f"run {name!r} is not a Pareto run; use one of {', '.join(RUNS)}")
    algo, env, limit = RUNS[name]
    return Args(algo=algo, cost_limit=limit, env_overrides={"rate_min_bps": PARETO_RATE_MIN_BPS, **env}, seed=seed,
                total_timesteps=total_timesteps, out=f"{out_root}/{name}", checkpoint_freq=0, tensorboard=False,
                overwrite=True)


def train_all(names=None, total_timesteps: int | None = None, dest: Path = PARETO_DIR, out_root: str = "runs/pareto",
              quiet: bool = True, **changes) -> dict:
    """Train the runs ``names`` (default all of :data:`RUNS`) and copy each into ``dest/<name>``;
    ``changes`` replace fields of their :class:`Args` (e.g. a tiny budget in the tests).
    """
    from experiments.ship import ship_all

    names = list(RUNS) if names is None else list(names)
    runs = {n: (run_args(n, total_timesteps=total_timesteps, out_root=out_root), dest / n)
            for n in names}  # every name checked before any run starts
    return ship_all(runs, quiet, **changes)


def cli(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(prog=invoked_prog("python -m experiments.pareto_agents"),
                                 description=__doc__.split("\n")[0],
                                 epilog="Model files and vecnormalize.pkl are pickles: load only files you trust.")
    ap.add_argument("--only", default=None, help=f"comma-separated runs (default: all of {', '.join(RUNS)})")
    ap.add_argument("--total-timesteps", type=int, default=None, help="env steps per run (default: the YAML's)")
    ap.add_argument("--quiet", action="store_true", help="no line per run")
    ns = ap.parse_args(argv)
    names = None if ns.only is None else [x.strip() for x in ns.only.split(",") if x.strip()]
    return train_all(names, ns.total_timesteps, quiet=ns.quiet)


if __name__ == "__main__":
    from iscc_gym.commands.cli import run

    sys.exit(run(cli, None, "python -m experiments.pareto_agents"))
