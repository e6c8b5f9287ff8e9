"""``python -m experiments.multi_agents``: train the multi-drone agents (issue 16) shipped in ``agents/trained/multi/``.

One PPO run per number of drones K (default 2, 4 and 8) on ``iscc_gym/ISCC-Multi-v0``: ``python -m
train --env-id iscc_gym/ISCC-Multi-v0 --env-set n_drones=K`` with the configuration of
``train/hyperparams.yml`` (seed 0, the fast batched env), into ``runs/multi/k<K>``; the small artifacts
(weights, VecNormalize statistics, config, summary, learning curve) are copied into
``agents/trained/multi/k<K>``, where ``python -m eval.multi`` finds them. The K = 4 agent is the one
shipped beside the single-drone agent.

``--constrained`` trains the Lagrangian PPO agent instead (``--algo ppo-lag`` with
:data:`MULTI_LAG_LIMITS`: reward minus the mean tracking error, at most 80 % of drone-slots short of
their rate and 1 % with a stability violation) into ``runs/multi/k<K>_lag`` and ships it in
``agents/trained/multi/k<K>_lag``. The rate limit is the rate outage of ``equal-sca`` on 16 training
missions at K = 4 (0.798, seeds 500000-500015), so the constrained agent is compared at that
baseline's outage; the stability limit is the one of the single-drone Pareto runs.

Example::

    python -m experiments.multi_agents                     # K = 2, 4, 8 (a few minutes each on 2 cores)
    python -m experiments.multi_agents --n-drones 4
    python -m experiments.multi_agents --n-drones 4 --constrained
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from iscc_gym.agents.shipped import MULTI_DIR
from iscc_gym.commands.cli import invoked_prog
from iscc_gym.train.config import Args

from iscc_gym import MULTI_ENV_ID

__all__ = ["MULTI_DIR", "K_VALUES", "MULTI_LAG_LIMITS", "K_SETTINGS", "run_args", "train_all", "cli"]

#: Where the multi-drone agents are shipped (``k<K>`` per number of drones).
#: The numbers of drones trained by default.
K_VALUES = (2, 4, 8)
#: Outage limits of the constrained agents (``--constrained``; see the module).
MULTI_LAG_LIMITS = "rate=0.8,stability=0.01"
#: Run settings of one K beside the env's YAML entry (:class:`Args` fields). At K = 8 the control bounds exceed the
#: band, the cloned rule and PPO lose drones in training, and each loss (the penalty of e_max per slot left, up to
#: ~500,000) drove VecNormalize's return statistics to sigma ~2,550 against a slot reward of ~1.6: every slot's reward
#: reached PPO as ~0.0006 and the losses clipped at 10, so the agent shipped before issue 34 lost 4 of 20 missions.
#: Without reward scaling it keeps every drone (docs/learning.md, "Many drones").
K_SETTINGS = {8: {"norm_reward": False}}


def agent_name(n_drones: int, constrained: bool = False) -> str:
    """The directory name of a multi-drone agent: ``k<K>`` or, constrained, ``k<K>_lag``."""
    return f"k{int(n_drones)}" + ("_lag" if constrained else "")


def run_args(n_drones: int, seed: int = 0, total_timesteps: int | None = None, out_root: str = "runs/multi",
             constrained: bool = False) -> Args:
    """The training :class:`Args` of the multi-drone agent for ``n_drones`` drones (``constrained``: the
    Lagrangian PPO agent at :data:`MULTI_LAG_LIMITS`).
    """
    from iscc_gym.sim.fleet import check_n_drones

    k = check_n_drones(n_drones)
    return Args(env_id=MULTI_ENV_ID, env_overrides={"n_drones": k}, seed=seed, total_timesteps=total_timesteps,
                out=f"{out_root}/{agent_name(k, constrained)}", checkpoint_freq=0, tensorboard=False, overwrite=True,
                cost_limit=MULTI_LAG_LIMITS if constrained else None, **K_SETTINGS.get(k, {}))


def train_all(ks=K_VALUES, total_timesteps: int | None = None, dest: Path = MULTI_DIR, out_root: str = "runs/multi",
              quiet: bool = True, constrained: bool = False, **changes) -> dict:
    """Train one agent per K in ``ks`` and copy each into ``dest/k<K>`` (``dest/k<K>_lag`` if
    ``constrained``); ``changes`` replace fields of their :class:`Args` (e.g. a tiny budget in the tests).
    """
    from experiments.ship import ship_all

    ks = [int(k) for k in ks]
    runs = {k: (run_args(k, total_timesteps=total_timesteps, out_root=out_root, constrained=constrained),
                dest / agent_name(k, constrained)) for k in ks}  # every K checked before any run starts
    return ship_all(runs, quiet, **changes)


def cli(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(prog=invoked_prog("python -m experiments.multi_agents"),
                                 description=__doc__.split("\n")[0],
                                 epilog="Model files and vecnormalize.pkl are pickles: load only files you trust.")
    ap.add_argument("--n-drones", default=",".join(map(str, K_VALUES)),
                    help=f"comma-separated numbers of drones (default: {','.join(map(str, K_VALUES))})")
    ap.add_argument("--total-timesteps", type=int, default=None, help="env steps per run (default: the YAML's)")
    ap.add_argument("--constrained", action="store_true",
                    help=f"train the Lagrangian PPO agents (--algo ppo-lag, {MULTI_LAG_LIMITS}) into k<K>_lag")
    ap.add_argument("--quiet", action="store_true", help="no line per run")
    ns = ap.parse_args(argv)
    try:
        ks = [int(x) for x in ns.n_drones.split(",") if x.strip()]
    except ValueError:
        ap.error(f"--n-drones {ns.n_drones!r}: use integers, e.g. --n-drones 2,4,8")
    return train_all(ks, ns.total_timesteps, quiet=ns.quiet, constrained=ns.constrained)


if __name__ == "__main__":
    from iscc_gym.commands.cli import run

    sys.exit(run(cli, None, "python -m experiments.multi_agents"))
