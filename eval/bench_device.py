"""``python -m eval.bench --device cuda`` (or ``standin``): the device env's and the device trainer's figures.

Rows: env-steps/s of :class:`iscc_gym.gpu.vector_env.DeviceVectorEnv` by batch size (paper task; urban and field at
one size), a rollout with a torch MLP policy (2 x 64) on the device reading the env's tensors, PPO end to end
(:mod:`iscc_gym.agents.device_ppo`), the wall time for the paper task's device agent to come within 1 % of
``myopic``'s reward per slot on held-out missions (common random numbers: the same seeds and slots, played on the CPU
env by :func:`iscc_gym.eval.evaluate.run_episodes`), and, from the same run, the CPU kernel's rows for comparison.
"""

from __future__ import annotations

import math
import time

import numpy as np

from iscc_gym.tasks import ENV_ID, TASKS

__all__ = ["run_device", "format_device", "env_rate", "rollout_rate", "time_to_myopic", "device_reward_per_slot",
           "SIZES", "device_env_ids"]

#: Batch sizes of the env rows: on a GPU 1k to 1M envs; on the CPU stand-in small ones.
SIZES = {"cuda": (1024, 16_384, 131_072, 1_048_576), "standin": (64, 1024), "quick": (16,)}


def device_env_ids() -> list[str]:
    """The tasks the device env runs (every single-drone task of the task table, read when asked)."""
    return [env_id for env_id, task in TASKS.items() if not task.fleet]


def _sync(device: str) -> None:
    if device == "cuda":
        import torch

        torch.cuda.synchronize()


def _dev(device: str) -> str:
    return "cuda" if device == "cuda" else "cpu"


def env_rate(device: str, env_id: str, num_envs: int, steps: int, pool_size: int = 1024) -> dict:
    """Env-steps/s of the device env stepping ``steps`` times (after one warm-up step: the kernel's compile), with
    the seconds of its reset (the mission pool, cached per process), of that first step and of the kernels' compile
    (``compile_s``: numba-cuda's, or its load from the cache; None on the stand-in, which numba caches as the CPU env).
    """
    import torch

    from iscc_gym.gpu.vector_env import DeviceVectorEnv

    env = DeviceVectorEnv(env_id, num_envs=num_envs, device=_dev(device), pool_size=min(pool_size, num_envs))
    t = time.perf_counter()
    env.reset(seed=0)  # the mission pool: drawn once per (task, seed) in a process, the later rows' from the cache
    _sync(device)
    reset_s = time.perf_counter() - t
    a = torch.zeros((num_envs, 3), device=env.obs.device)
    t = time.perf_counter()
    env.step(a, check=False)
    _sync(device)
    first = time.perf_counter() - t
    t = time.perf_counter()
    for _ in range(steps):
        env.step(a, check=False)
    _sync(device)
    dt = time.perf_counter() - t
    env.close()
    return {"env_steps_per_s": num_envs * steps / dt, "num_envs": num_envs, "steps": steps, "reset_s": reset_s,
            "first_step_s": first, "compile_s": env.compile_s}


def rollout_rate(device: str, num_envs: int, steps: int) -> dict:
    """Env-steps/s of a rollout: a torch MLP (2 x 64, tanh) on the env's device maps each observation tensor to
    actions written into the env's action buffer, with no copy to the host.
    """
    import torch

    from iscc_gym.gpu.vector_env import DeviceVectorEnv

    env = DeviceVectorEnv(ENV_ID, num_envs=num_envs, device=_dev(device), pool_size=min(1024, num_envs))
    net = torch.nn.Sequential(torch.nn.Linear(env.obs_size, 64), torch.nn.Tanh(), torch.nn.Linear(64, 64),
                              torch.nn.Tanh(), torch.nn.Linear(64, 3)).to(env.obs.device)
    obs, _ = env.reset(seed=0)
    with torch.no_grad():
        env.step(net(obs), check=False)
        _sync(device)
        t = time.perf_counter()
        for _ in range(steps):
            obs, *_ = env.step(net(obs), check=False)
        _sync(device)
    dt = time.perf_counter() - t
    env.close()
    return {"env_steps_per_s": num_envs * steps / dt, "num_envs": num_envs, "steps": steps}


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
    """Train the paper task's device agent (:func:`iscc_gym.agents.device_ppo.paper_config`, ``python -m train
    --device``'s configuration) until its deterministic reward per slot on ``eval_seeds`` held-out missions of
    ``eval_slots`` slots comes within ``within`` (1 %) of ``myopic``'s on the same missions, or ``max_wall_s`` seconds
    of training pass. The agent is checked on the device (:func:`device_reward_per_slot`) after the first update that
    ends ``check_every_s`` seconds of training after the last check (0: after every update); ``myopic`` is played
    once, on the CPU env (common random numbers). The wall time counts training only; the checks' time is reported
    apart and never counted against ``max_wall_s``, so the row runs about ``max_wall_s`` plus its checks.
    """
    from iscc_gym.agents.device_ppo import paper_config, train
    from iscc_gym.agents.myopic import MyopicPolicy
    from iscc_gym.commands.protocol import CALLBACK_EVAL_SEED_START
    from iscc_gym.eval.evaluate import run_episodes

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


def run_device(device: str, quick: bool = False, max_wall_s: float = 120.0, cpu_row=None) -> dict:
    """Every device figure (``quick``: tiny sizes, the tests' smoke run) and, with ``cpu_row(num_envs, steps,
    repeats)`` (:func:`iscc_gym.eval.bench.vector_steps_per_second`), the CPU vector env's row of the same run.
    """
    import torch
    from iscc_gym.agents.device_ppo import DevicePPOConfig, train

    if device == "cuda":
        from iscc_gym.gpu.cuda import cuda_available, simulator

        if not cuda_available() or simulator() or not torch.cuda.is_available():
            raise RuntimeError("--device cuda: no CUDA GPU here (numba-cuda and torch must both see one; the simulator "
                               "does not count); --device standin measures the CPU stand-in")
    sizes = SIZES["quick" if quick else device]
    steps = 3 if quick else (200 if device == "cuda" else 20)
    res = {"device": device, "gpu": torch.cuda.get_device_name(0) if device == "cuda" else None,
           "torch": torch.__version__}
    res["env"] = {str(n): env_rate(device, ENV_ID, n, steps) for n in sizes}
    big = sizes[min(2, len(sizes) - 1)]
    res["tasks"] = {env_id: env_rate(device, env_id, big, steps)  # every other task the device env runs
                    for env_id in device_env_ids() if env_id != ENV_ID}
    res["rollout"] = {str(n): rollout_rate(device, n, steps) for n in sizes[-2:]}
    n_ppo = 16 if quick else (131_072 if device == "cuda" else 1024)
    cfg = DevicePPOConfig(device=_dev(device), n_envs=n_ppo, n_steps=16 if not quick else 4, lr_schedule="kl",
                          total_timesteps=(n_ppo * 16 * 20) if not quick else 128, pool_size=1024, gamma=0.3,
                          gae_lambda=0.8)
    ppo, _ = train(cfg)
    res["ppo"] = {k: ppo[k] for k in ("timesteps", "wall_time_s", "steps_per_s", "rollout_s", "update_s")}
    res["ppo"]["n_envs"] = n_ppo
    res["time_to_myopic"] = time_to_myopic(
        device, max_wall_s=2.0 if quick else max_wall_s, eval_seeds=2 if quick else 8,
        eval_slots=20 if quick else 1000, check_every_s=0.0 if quick else 5.0,
        cfg_overrides={"n_envs": 16, "batch_size": 64, "pool_size": 16} if quick else None)
    if cpu_row is not None:
        res["cpu_kernel"] = {str(n): cpu_row(n, 5 if quick else 50, 1 if quick else 3)
                             for n in ((64,) if quick else (1024,))}
    return res


def format_device(res: dict) -> str:
    """The device figures as a text table."""
    lines = [f"device: {res['device']} ({res['gpu'] or 'CPU stand-in'}), torch {res['torch']}",
             f"{'what':<58} {'env-steps/s':>14}"]
    for n, r in res["env"].items():
        lines.append(f"{'device env, paper, ' + n + ' envs':<58} {r['env_steps_per_s']:>14,.0f}")
    first = next(iter(res["env"].values()))
    if first.get("compile_s") is not None:
        lines.append(f"kernels compiled (or loaded from numba-cuda's cache) in {first['compile_s']:.1f} s; the first "
                     f"reset (mission pool) {first['reset_s']:.1f} s")
    for env_id, r in res["tasks"].items():
        name = f"device env, {env_id.split('/')[-1]}, {r['num_envs']} envs"
        lines.append(f"{name:<58} {r['env_steps_per_s']:>14,.0f}")
    for n, r in res["rollout"].items():
        lines.append(f"{'device env + torch MLP 2x64 policy, ' + n + ' envs':<58} {r['env_steps_per_s']:>14,.0f}")
    p = res["ppo"]
    lines.append(f"{'PPO end to end, ' + str(p['n_envs']) + ' envs':<58} {p['steps_per_s']:>14,.0f}")
    for n, r in res.get("cpu_kernel", {}).items():
        lines.append(f"{'CPU vector env (gymnasium.make_vec), paper, ' + n + ' envs':<58} "
                     f"{r['median_env_steps_per_s']:>14,.0f}")
    t = res["time_to_myopic"]
    if t["reached"]:
        lines.append(f"paper agent within 1 % of myopic ({t['myopic_reward_per_slot']:.4f}/slot): "
                     f"{t['train_wall_s']:.1f} s of training, {t['timesteps']:,} env-steps")
    else:
        best = max((c["reward_per_slot"] for c in t["checks"]), default=float("nan"))
        lines.append(f"paper agent did not reach 1 % of myopic ({t['myopic_reward_per_slot']:.4f}/slot) in "
                     f"{t['max_wall_s']:.0f} s of training (best {best:.4f}/slot)")
    return "\n".join(lines)


def _per_slot(res: dict) -> float:
    """Mean reward per slot over a :func:`iscc_gym.eval.evaluate.run_episodes` result's missions."""
    ep = res["episodes"]
    return float(np.sum(ep["reward"]) / np.sum(ep["length"]))
