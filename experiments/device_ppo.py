"""``python -m experiments.device_ppo``: the device trainer's figures: PPO end to end on the device env, and the wall
time for the paper task's device agent to come within 1 % of ``myopic``'s reward per slot on held-out missions, for
each learning-rate schedule asked (``--schedules kl,linear``: rsl_rl's KL-adaptive rate and CleanRL's annealed one,
:mod:`iscc_gym.train.device_ppo`).

The agent is checked on the device env (:func:`device_reward_per_slot`: the CPU env's missions and noise for the same
seeds, so the figure is the CPU evaluation's up to rounding, common random numbers with ``myopic`` played once on the
CPU), after the update that ends each ``--check-every-s`` seconds of training; the time counts training only.

Example::

    python -m experiments.device_ppo --device cuda                        # on a GPU: the published rows
    python -m experiments.device_ppo --device standin --max-wall-s 300    # the same logic on the CPU stand-in
    python -m experiments.device_ppo --device standin --quick             # a smoke run (the tests')
"""

from __future__ import annotations

import json
import math
import sys
import time

import numpy as np
from iscc_gym.commands.options import Parser, check_writable_file, run_console

from iscc_gym.tasks import ENV_ID

__all__ = ["main", "ppo_rate", "time_to_myopic", "device_reward_per_slot", "format_rows"]

PROG = "python -m experiments.device_ppo"


def _dev(device: str) -> str:
    return "cuda" if device == "cuda" else "cpu"


def ppo_rate(device: str, quick: bool = False, lr_schedule: str = "kl") -> dict:
    """PPO end to end on the paper task's device env: env-steps/s over 20 updates of 131,072 envs x 16 steps on a GPU
    (1,024 envs on the stand-in; ``quick``: 16 envs x 4 steps, two updates).
    """
    from iscc_gym.train.device_ppo import DevicePPOConfig, train

    n_ppo = 16 if quick else (131_072 if device == "cuda" else 1024)
    cfg = DevicePPOConfig(device=_dev(device), n_envs=n_ppo, n_steps=16 if not quick else 4, lr_schedule=lr_schedule,
                          total_timesteps=(n_ppo * 16 * 20) if not quick else 128, pool_size=1024, gamma=0.3,
                          gae_lambda=0.8)
    ppo, _ = train(cfg)
    res = {k: ppo[k] for k in ("timesteps", "wall_time_s", "steps_per_s", "rollout_s", "update_s")}
    res["n_envs"] = n_ppo
    return res


class _DeviceAgent:
    """``predict`` of a device trainer's policy and observation statistics (SB3's deterministic action, clipped): the
    agent played on the CPU env (the tests' oracle of :func:`device_reward_per_slot`).
    """

    def __init__(self, pol, obs_rms, clip_obs: float):
        self.pol, self.obs_rms, self.clip = pol, obs_rms, clip_obs

    def predict(self, obs, state=None, episode_start=None, deterministic: bool = True):
        import torch

        dev = self.obs_rms.mean.device
        o = torch.as_tensor(np.asarray(obs), dtype=torch.float64, device=dev)
        o = ((o - self.obs_rms.mean) / torch.sqrt(self.obs_rms.var + 1e-8)).clamp(-self.clip, self.clip).float()
        with torch.no_grad():
            a = self.pol._predict(o, deterministic=deterministic)
        return np.clip(a.cpu().numpy(), -1.0, 1.0), None


def device_reward_per_slot(pol, obs_rms, cfg, seeds: list[int], slots: int) -> float:
    """The deterministic reward per slot of a device trainer's policy on the paper task's missions ``seeds`` (each
    ``slots`` long), played on the device env: row i flies the mission and noise of seed ``seeds[0] + i`` as the CPU
    env does (the device env's first episodes are the CPU vector env's), so it is compared with a CPU-played policy
    on common random numbers; observations normalised by ``obs_rms`` as in training, actions clipped as SB3's
    ``predict`` clips them.
    """
    import torch

    from iscc_gym.gpu.vector_env import DeviceVectorEnv

    if list(seeds) != list(range(seeds[0], seeds[0] + len(seeds))):
        raise ValueError("seeds must be consecutive (row i of the device env flies seed seeds[0] + i)")
    env = DeviceVectorEnv(ENV_ID, num_envs=len(seeds), device=cfg.device, pool_size=len(seeds), scenario="paper",
                          max_episode_steps=slots)
    obs, _ = env.reset(seed=seeds[0])
    alive = torch.ones(len(seeds), dtype=torch.bool, device=obs.device)
    total = torch.zeros((), dtype=torch.float64, device=obs.device)
    length = torch.zeros((), dtype=torch.int64, device=obs.device)
    with torch.no_grad():
        for _ in range(slots):
            o = ((obs.double() - obs_rms.mean) / torch.sqrt(obs_rms.var + 1e-8)).clamp(-cfg.clip_obs, cfg.clip_obs)
            a = pol._predict(o.float(), deterministic=True).clamp(-1.0, 1.0)
            obs, reward, term, trunc, _ = env.step(a, check=False)
            total += torch.where(alive, reward.double(), 0.0).sum()
            length += alive.sum()
            alive &= ~(term | trunc)
            if not bool(alive.any()):
                break
    env.close()
    return float(total) / max(int(length), 1)


def time_to_myopic(device: str, max_wall_s: float, eval_seeds: int = 8, eval_slots: int = 1000,
                   check_every_s: float = 5.0, cfg_overrides: dict | None = None, within: float = 0.01) -> dict:
    """Train the paper task's device agent (:func:`iscc_gym.train.device_ppo.paper_config`, ``python -m train
    --device``'s configuration) until its deterministic reward per slot on ``eval_seeds`` held-out missions of
    ``eval_slots`` slots comes within ``within`` (1 %) of ``myopic``'s on the same missions, or ``max_wall_s`` seconds
    of training pass. The agent is checked on the device (:func:`device_reward_per_slot`) after the first update that
    ends ``check_every_s`` seconds of training after the last check (0: after every update); ``myopic`` is played
    once, on the CPU env (common random numbers). The wall time counts training only; the checks' time is reported
    apart and never counted against ``max_wall_s``, so the row runs about ``max_wall_s`` plus its checks.
    """
    from iscc_gym.agents.myopic import MyopicPolicy
    from iscc_gym.commands.protocol import CALLBACK_EVAL_SEED_START
    from iscc_gym.eval.evaluate import run_episodes
    from iscc_gym.train.device_ppo import paper_config, train

    seeds = list(range(CALLBACK_EVAL_SEED_START, CALLBACK_EVAL_SEED_START + eval_seeds))
    t = time.perf_counter()
    ref = run_episodes(MyopicPolicy("paper"), seeds, "paper", eval_slots)
    myopic = _per_slot(ref)
    myopic_s = time.perf_counter() - t
    target = myopic - within * abs(myopic)
    cfg = paper_config(device, **{**(cfg_overrides or {}), "total_timesteps": 10**12})
    checks, check_s, last = [], [0.0], [-math.inf]

    def callback(summary, pol, obs_rms):
        train_s = summary["wall_time_s"] - check_s[0]
        if train_s - last[0] < check_every_s:
            return train_s > max_wall_s
        last[0] = train_s
        t0 = time.perf_counter()
        value = device_reward_per_slot(pol, obs_rms, cfg, seeds, eval_slots)
        check_s[0] += time.perf_counter() - t0
        checks.append({"timesteps": summary["timesteps"], "train_wall_s": train_s, "reward_per_slot": value})
        return value >= target or train_s > max_wall_s

    summary, _ = train(cfg, callback=callback)
    reached = [c for c in checks if c["reward_per_slot"] >= target]
    return {"myopic_reward_per_slot": myopic, "target_reward_per_slot": target, "myopic_eval_s": myopic_s,
            "reached": bool(reached), "train_wall_s": reached[0]["train_wall_s"] if reached else None,
            "timesteps": reached[0]["timesteps"] if reached else summary["timesteps"], "checks": checks,
            "check_s": check_s[0], "max_wall_s": max_wall_s, "eval_seeds": eval_seeds, "eval_slots": eval_slots,
            "config": {k: summary["config"][k] for k in ("n_envs", "n_steps", "batch_size", "n_epochs",
                                                          "learning_rate", "lr_schedule", "gamma")}}




def _per_slot(res: dict) -> float:
    """Mean reward per slot over a :func:`iscc_gym.eval.evaluate.run_episodes` result's missions."""
    ep = res["episodes"]
    return float(np.sum(ep["reward"]) / np.sum(ep["length"]))


def format_rows(res: dict) -> str:
    """The figures as text lines."""
    p = res["ppo"]
    lines = [f"device: {res['device']}",
             f"PPO end to end, {p['n_envs']:,} envs: {p['steps_per_s']:,.0f} env-steps/s "
             f"(rollouts {p['rollout_s']:.1f} s, updates {p['update_s']:.1f} s)"]
    for schedule, t in res["time_to_myopic"].items():
        if t["reached"]:
            lines.append(f"lr_schedule {schedule}: within 1 % of myopic ({t['myopic_reward_per_slot']:.4f}/slot) in "
                         f"{t['train_wall_s']:.1f} s of training, {t['timesteps']:,} env-steps")
        else:
            best = max((c["reward_per_slot"] for c in t["checks"]), default=float("nan"))
            lines.append(f"lr_schedule {schedule}: not within 1 % of myopic ({t['myopic_reward_per_slot']:.4f}/slot) "
                         f"in {t['max_wall_s']:.0f} s of training (best {best:.4f}/slot, {len(t['checks'])} checks)")
    return "\n".join(lines)


def main(argv: list[str] | None = None, prog: str = PROG) -> dict:
    import torch

    ap = Parser(prog=prog, description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", choices=("cuda", "standin"), default="cuda",
                    help="cuda: a GPU (the gpu extra); standin: the device env's CPU stand-in")
    ap.add_argument("--schedules", default="kl,linear,constant",
                    help="learning-rate schedules to time to myopic, comma-separated (constant, kl, linear)")
    ap.add_argument("--max-wall-s", type=float, default=120.0, metavar="S",
                    help="training time allowed to each schedule's paper agent (default: 120)")
    ap.add_argument("--check-every-s", type=float, default=5.0, metavar="S",
                    help="seconds of training between checks against myopic (default: 5)")
    ap.add_argument("--quick", action="store_true", help="tiny sizes (a smoke run, for the tests)")
    ap.add_argument("--json", metavar="PATH", help="write the figures as JSON to PATH (checked before the run)")
    args = ap.parse_args(argv)
    from iscc_gym.train.device_ppo import LR_SCHEDULES

    schedules = [s.strip() for s in args.schedules.split(",") if s.strip()]
    bad = [s for s in schedules if s not in LR_SCHEDULES]
    if not schedules or bad:
        raise ValueError(f"--schedules {args.schedules!r}; use a comma-separated list of {', '.join(LR_SCHEDULES)}")
    if not (math.isfinite(args.max_wall_s) and args.max_wall_s > 0):
        raise ValueError(f"--max-wall-s {args.max_wall_s}; use a number of seconds > 0")
    if args.json:
        check_writable_file(args.json, "--json")
    if args.device == "cuda":
        from iscc_gym.gpu.cuda import cuda_available, simulator

        if not cuda_available() or simulator() or not torch.cuda.is_available():
            raise RuntimeError("--device cuda: no CUDA GPU here (numba-cuda and torch must both see one); --device "
                               "standin runs the same logic on the CPU stand-in")
    res = {"device": args.device, "ppo": ppo_rate(args.device, args.quick)}
    overrides = {"n_envs": 16, "batch_size": 64, "pool_size": 16} if args.quick else None
    res["time_to_myopic"] = {s: time_to_myopic(args.device, max_wall_s=2.0 if args.quick else args.max_wall_s,
                                               eval_seeds=2 if args.quick else 8, eval_slots=20 if args.quick else 1000,
                                               check_every_s=0.0 if args.quick else args.check_every_s,
                                               cfg_overrides={**(overrides or {}), "lr_schedule": s})
                             for s in schedules}
    print(format_rows(res))
    if args.json:
        from iscc_gym.files import write_atomic

        write_atomic(args.json, json.dumps(res, indent=1, default=float))
    return res


if __name__ == "__main__":
    sys.exit(run_console(main, None, PROG))
