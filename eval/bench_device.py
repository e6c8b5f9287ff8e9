"""``python -m eval.bench --device cuda`` (or ``standin``): the device env's figures.

Rows: env-steps/s of :class:`iscc_gym.gpu.vector_env.DeviceVectorEnv` by batch size (paper task; urban and field at
one size), with the seconds of its first reset (the mission pool) and of the kernels' compile, a rollout with a torch
MLP policy (2 x 64) on the device reading the env's tensors, and, from the same run, the CPU kernel's rows for
comparison. The device trainer's rows (PPO end to end, the time to ``myopic``) are
``python -m experiments.device_ppo``'s (train and eval never import each other).
"""

from __future__ import annotations

import time

from iscc_gym.tasks import ENV_ID, TASKS

__all__ = ["run_device", "format_device", "env_rate", "rollout_rate", "SIZES", "device_env_ids"]

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


def run_device(device: str, quick: bool = False, cpu_row=None) -> dict:
    """Every device env figure (``quick``: tiny sizes, the tests' smoke run) and, with ``cpu_row(num_envs, steps,
    repeats)`` (:func:`iscc_gym.eval.bench.vector_steps_per_second`), the CPU vector env's row of the same run. The
    device PPO's rows (end to end, the time to ``myopic``) are ``python -m experiments.device_ppo``'s.
    """
    import torch

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
    for n, r in res.get("cpu_kernel", {}).items():
        lines.append(f"{'CPU vector env (gymnasium.make_vec), paper, ' + n + ' envs':<58} "
                     f"{r['median_env_steps_per_s']:>14,.0f}")
    return "\n".join(lines)
