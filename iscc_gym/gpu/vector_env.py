"""A vector env whose state, missions and outputs live on the GPU: one kernel launch a step, autoreset on the device,
torch tensors shared with the env without copies.

``DeviceVectorEnv("iscc_gym/ISCC-v0", num_envs=131072, device="cuda")`` (the ``gpu`` extra); ``device="cpu"`` is its
stand-in: the same row functions (:mod:`iscc_gym.gpu.kernel`) compiled for one CPU core, torch CPU tensors sharing the
env's numpy buffers. With ``NUMBA_ENABLE_CUDASIM=1`` set before numba is imported, ``device="cuda"`` runs the
kernels in numba-cuda's simulator (the tests' way to run the device path without a GPU).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.vector.utils import batch_space

from iscc_gym.envs.env import check_seed
from iscc_gym.gpu.kernel import (
    MAX_QUEUE_SLOTS,
    THREADS_PER_BLOCK,
    Consts,
    Outs,
    Rows,
    cuda_kernels,
    reset_rows_cpu,
    step_rows_cpu,
)
from iscc_gym.scenario import Scenario, make_scenario
from iscc_gym.sim import loop
from iscc_gym.sim.effects import task_effects
from iscc_gym.sim.functional import observe
from iscc_gym.sim.mission import mission_columns
from iscc_gym.sim.params import slot_params
from iscc_gym.sim.pool import mission_pool
from iscc_gym.sim.schema import OBS_BOUND, STEP_COLUMNS, obs_size
from iscc_gym.tasks import get_task

__all__ = ["DeviceVectorEnv", "DEVICES", "DEFAULT_POOL_SIZE"]

#: Where the env runs: ``cuda`` (numba-cuda kernels on the GPU, or its simulator) or ``cpu`` (the stand-in).
DEVICES = ("cuda", "cpu")
#: Missions in the device pool by default (at most one per env): 0.36 MB each on the paper preset.
DEFAULT_POOL_SIZE = 1024


class DeviceVectorEnv:
    """``num_envs`` loops of a single-drone task stepped by one kernel launch, the state on the device.

    Every row runs the env's own step (:func:`iscc_gym.sim.kernel.env_row_one`, the function the CPU envs run),
    so the same seed gives the same episodes as the CPU vector env (:class:`iscc_gym.envs.vector.ISCCVectorEnv`)
    up to floating-point rounding, for each env's first episode where the pool holds its mission (``i <
    pool_size``): row i flies the mission and initial state that the CPU vector env's sub-env i draws at
    ``reset(seed=seed)``. Later episodes (and rows beyond the pool) are drawn on the device
    (:mod:`iscc_gym.gpu.kernel`: from the seed, the row and its episode count), their missions from the pool.

    Arguments
    ---------
    env_id : str
        A single-drone task of :data:`iscc_gym.tasks.TASKS` (paper, urban, field); the multi-drone task is refused.
    num_envs : int >= 1
    device : ``"cuda"`` or ``"cpu"``
        ``cuda`` needs numba-cuda (``pip install -e ".[gpu]"``) and a GPU (or the simulator); ``cpu`` runs the same
        row functions on one core (tests, machines without a GPU).
    pool_size : int >= 1, optional
        Missions the device holds (default ``min(num_envs, 1024)``); drawn at ``reset(seed=...)`` on the host, each
        as the CPU vector env's sub-env of that index draws it (:func:`iscc_gym.sim.pool.mission_pool`: cached per
        process by scenario, seed and size, drawn over worker processes when large).
    pool_workers : int >= 1, optional
        Processes the pool is drawn over (default :func:`iscc_gym.sim.pool.pool_workers`'s: the cores, one per 256
        missions at most); the pool is the same for any number.
    max_episode_steps : int, optional
        Truncate after this many steps (default the mission's length, the task's registered limit).
    random_start : bool
        Each row's first episode after a reset starts at a slot drawn uniformly from ``[0, max_episode_steps)`` of a
        pool mission (the drone near the reference there; :func:`iscc_gym.gpu.kernel.start_slot`), later episodes at
        slot 0: a trainer's many envs then sample every phase of a mission from its first update, where all rows
        starting at slot 0 together sweep the mission once, in step (rsl_rl's ``init_at_random_ep_len``; the device
        PPO's default, :class:`iscc_gym.train.device_ppo.DevicePPOConfig`). Default False: the first episodes are the
        CPU vector env's.
    scenario : str or Scenario, optional, and ``**overrides``: the task's preset by default, then field overrides.

    Attributes
    ----------
    obs, reward, terminated, truncated : torch.Tensor
        The env's output buffers (``(N, obs_size)`` float32, ``(N,)`` float32, ``(N,)`` bool), on the device, written
        by every step and returned by it: copy what must outlive the next step.
    final_return, final_length : torch.Tensor
        ``(N,)``: the return and length of the episode a row ended in the last step (NaN and 0 where none ended).
    final_obs : torch.Tensor
        ``(N, obs_size)`` float32: the last observation of the episode a row ended in the last step (Gymnasium's
        ``final_obs``; rows where none ended hold an older one: read it where ``terminated | truncated``), what a
        truncated episode's value is bootstrapped from.
    metrics : torch.Tensor
        ``(N, len(STEP_COLUMNS))`` float64: the step's columns (:data:`iscc_gym.sim.schema.STEP_COLUMNS`) per row.

    Notes
    -----
    Same-step autoreset: where an episode ends, the returned observation is the next episode's first; ``terminated``
    and ``truncated`` say which rows ended. Actions are torch tensors ``(N, 3)`` (any float dtype, on the env's
    device), checked finite (one device sync) unless ``step(actions, check=False)``.
    """

    def __init__(self, env_id: str = "iscc_gym/ISCC-v0", num_envs: int = 1024, device: str = "cuda",
                 pool_size: int | None = None, max_episode_steps: int | None = None,
                 scenario: str | Scenario | None = None, pool_workers: int | None = None, random_start: bool = False,
                 **overrides: Any):
        import torch

        task = get_task(env_id)
        if task.fleet:
            raise ValueError(f"env_id {env_id!r}: the multi-drone task has no device env (its K drones share one "
                             "band through a per-base-station split the row kernel does not hold); use "
                             "gymnasium.make_vec for it, or a single-drone task")
        if device not in DEVICES:
            raise ValueError(f"device = {device!r}; expected one of {DEVICES}")
        self.num_envs = _count(num_envs, "num_envs")
        self.pool_size = min(self.num_envs, DEFAULT_POOL_SIZE) if pool_size is None else _count(pool_size, "pool_size")
        self._pool_workers = None if pool_workers is None else _count(pool_workers, "pool_workers")
        self.env_id = env_id
        self.scenario = s = make_scenario(task.preset if scenario is None else scenario, **overrides)
        self.max_steps = s.n_slots if max_episode_steps is None else min(
            _count(max_episode_steps, "max_episode_steps"), s.n_slots)
        if not isinstance(random_start, (bool, np.bool_)):
            raise ValueError(f"random_start = {random_start!r}; expected True or False")
        self.random_start = bool(random_start)
        nq = task_effects(s).queue_deadline_slots
        if nq > MAX_QUEUE_SLOTS:
            raise ValueError(f"queue_deadline_s = {s.queue_deadline_s} is {nq} slots; the device kernel holds at most "
                             f"{MAX_QUEUE_SLOTS} (iscc_gym.gpu.kernel.MAX_QUEUE_SLOTS): a shorter deadline or a "
                             "longer dt_s")
        self._switches = (loop.blocked_switch(s), loop.field_switch(s))
        self.device = device
        need = memory_bytes(s, self.num_envs, self.pool_size)
        self._cuda = None
        if device == "cuda":
            from iscc_gym.gpu.cuda import import_cuda, simulator

            self._cuda = import_cuda()
            self._sim = simulator()
            if not self._sim and not self._cuda.is_available():
                raise RuntimeError("device='cuda' but numba-cuda finds no CUDA GPU (and NUMBA_ENABLE_CUDASIM is not "
                                   "set): run on a machine with one, or use device='cpu' (the stand-in)")
        else:
            self._sim = False
        self._torch_device = torch.device("cuda" if device == "cuda" and not self._sim else "cpu")
        _check_memory(need, self.num_envs, self.pool_size, self._torch_device)
        n, n_obs = self.num_envs, obs_size(s)
        self.obs_size = n_obs
        self.single_action_space = spaces.Box(-1.0, 1.0, (3,), np.float32)
        self.single_observation_space = spaces.Box(-OBS_BOUND, OBS_BOUND, (n_obs,), np.float32)
        self.action_space = batch_space(self.single_action_space, n)
        self.observation_space = batch_space(self.single_observation_space, n)
        # the exposed buffers are torch tensors; the kernels see them through numba views of the same memory
        td = self._torch_device
        self.obs = torch.zeros((n, n_obs), dtype=torch.float32, device=td)
        self.reward = torch.zeros(n, dtype=torch.float32, device=td)
        self.terminated = torch.zeros(n, dtype=torch.bool, device=td)
        self.truncated = torch.zeros(n, dtype=torch.bool, device=td)
        self.final_return = torch.full((n,), float("nan"), dtype=torch.float64, device=td)
        self.final_length = torch.zeros(n, dtype=torch.int64, device=td)
        self.final_obs = torch.zeros((n, n_obs), dtype=torch.float32, device=td)
        self.metrics = torch.zeros((n, len(STEP_COLUMNS)), dtype=torch.float64, device=td)
        self.actions = torch.zeros((n, 3), dtype=torch.float32, device=td)
        # the kernels' views of those tensors (the same memory), made once: the tensors are never reallocated
        self._views = tuple(self._view(t) for t in (self.actions, self.metrics, self.obs, self.reward, self.terminated,
                                                    self.truncated, self.final_return, self.final_length,
                                                    self.final_obs))
        c, mats = slot_params(s)
        self._c, self._mats = self._to_device(np.array(c)), self._to_device(np.array(mats))
        self._std0 = self._to_device(loop.initial_std(s))
        self._state = None
        self._args = None
        self._pool = None
        self._seed_key = None
        self._nq = nq
        #: Seconds the device kernels took to compile (or to load from numba-cuda's cache) in this env, at its first
        #: launch; None before it (and on the CPU stand-in, whose row functions numba caches as the CPU envs').
        self.compile_s = None

    # --- buffers ---------------------------------------------------------------------------------
    def _view(self, t):
        """The kernels' view of tensor ``t`` (the same memory)."""
        if self._torch_device.type == "cuda":
            return self._cuda.as_cuda_array(t)
        return t.numpy()

    def _to_device(self, a: np.ndarray):
        if self._torch_device.type == "cuda":  # on torch's current stream, in order with the kernels
            return self._cuda.to_device(np.ascontiguousarray(a), stream=self._stream())
        return np.ascontiguousarray(a)

    # --- API ---------------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None):
        """Every row starts a new episode; returns ``(obs, info)``, ``obs`` the tensor :attr:`obs`.

        ``seed`` (int >= 0 or None): the pool's missions and the first episodes of rows below the pool's size are
        those the CPU vector env draws at ``reset(seed=seed)`` (sub-env i from ``seed + i``); the rest, and every later
        episode, come from the seed's counter-based streams. None draws a fresh seed.
        """
        import torch

        check_seed(seed, "seed")
        if seed is None:
            seed = int(np.random.SeedSequence().generate_state(1, np.uint32)[0])
        s = self.scenario
        n, pool_n = self.num_envs, self.pool_size
        first = mission_pool(s, seed, pool_n, self._pool_workers)  # cached per (scenario, seed, size): read-only
        self._seed_key = np.uint64(np.random.SeedSequence(seed).generate_state(1, np.uint64)[0])
        host = {"x": np.zeros((n, 6)), "x_hat": np.zeros((n, 6)), "p": np.zeros((n, 6, 6)), "shadow": np.zeros(n),
                "n": np.zeros(n, np.int64), "key": np.zeros(n, np.uint64), "queue": np.zeros((n, self._nq)),
                "mission": np.zeros(n, np.int64), "episode": np.zeros(n, np.int64), "ep_return": np.zeros(n),
                "ep_length": np.zeros(n, np.int64)}
        m = min(n, pool_n)
        for name in ("x", "x_hat", "p", "shadow", "key", "queue"):
            host[name][:m] = getattr(first, name)[:m]
        host["mission"][:m] = np.arange(m)
        self._pool = self._to_device(first.ref) if self._torch_device.type == "cuda" else np.array(first.ref)
        self._state = {k: self._to_device(v) for k, v in host.items()}
        # the kernels' arguments, built once a reset (the buffers never move between resets), not every step
        actions, metrics, obs, reward, terminated, truncated, final_return, final_length, final_obs = self._views
        self._args = (Consts(self._c, self._mats, self._pool, self._std0, self._seed_key, np.int64(self.max_steps),
                             np.int64(self.random_start)),
                      Rows(**self._state), actions,
                      Outs(metrics, obs, reward, terminated, truncated, final_return, final_length, final_obs))
        if self.random_start:  # every row's first episode drawn on the device, at its start slot
            self._launch_reset(np.arange(n, dtype=np.int64))
        else:
            obs0 = observe(s, first.rows(np.arange(m)), np.ones(m), np.zeros(m))  # as the CPU vector env's reset
            self.obs[:m] = torch.from_numpy(obs0).to(self.obs.device)
            if n > m:
                self._launch_reset(np.arange(m, n, dtype=np.int64))
        self.final_return.fill_(float("nan"))
        self.final_length.zero_()
        return self.obs, {}

    def step(self, actions, check: bool = True):
        """One step of every row: ``(obs, reward, terminated, truncated, info)``, the env's own tensors (see the
        class notes); ``info`` holds ``final_return``, ``final_length``, ``final_obs`` and ``metrics``.

        Raises
        ------
        RuntimeError
            Called before :meth:`reset`.
        ValueError
            ``actions`` of another shape than (num_envs, 3), or (with ``check``) NaN or inf in it.
        """
        import torch

        if self._state is None:
            raise RuntimeError("step() called before reset(): call env.reset(seed=...) first")
        a = torch.as_tensor(actions)
        if tuple(a.shape) != (self.num_envs, 3):
            raise ValueError(f"actions must have shape ({self.num_envs}, 3), got {tuple(a.shape)}")
        if a.dtype.is_complex:
            raise TypeError(f"actions have complex dtype {a.dtype}; pass real numbers in [-1, 1]")
        if check and not bool(torch.isfinite(a).all()):
            bad = torch.nonzero(~torch.isfinite(a).all(dim=1)).flatten()[:10].tolist()
            raise ValueError(f"actions of rows {bad} contain NaN or inf; pass finite values in [-1, 1]")
        self.actions.copy_(a)
        if self.device == "cpu":
            step_rows_cpu(*self.kernel_args(), *self._switches)
        else:
            step, _ = self._kernels()
            step[_blocks(self.num_envs), THREADS_PER_BLOCK, self._stream()](*self.kernel_args())
        info = {"final_return": self.final_return, "final_length": self.final_length, "final_obs": self.final_obs,
                "metrics": self.metrics}
        return self.obs, self.reward, self.terminated, self.truncated, info

    def kernel_args(self) -> tuple:
        """The step kernel's arguments (:func:`iscc_gym.gpu.kernel.step_rows_cpu` without the switches):
        :class:`~iscc_gym.gpu.kernel.Consts` (the parameters, the pool, the seed key, the step limit),
        :class:`~iscc_gym.gpu.kernel.Rows` (the state), the action buffer and :class:`~iscc_gym.gpu.kernel.Outs`.
        """
        if self._state is None:
            raise RuntimeError("no state before reset(): call env.reset(seed=...) first")
        return self._args

    @property
    def switches(self) -> tuple:
        """The task's compile-time switches of the slot (``blocked``, ``field``: None or True)."""
        return self._switches

    def reset_args(self, rows: np.ndarray) -> tuple:
        """The reset kernel's arguments (:func:`iscc_gym.gpu.kernel.reset_rows_cpu`'s) that start a new episode in
        each row listed in ``rows`` (int64): :class:`~iscc_gym.gpu.kernel.Consts`, :class:`~iscc_gym.gpu.kernel.Rows`,
        the observation buffer and the rows.
        """
        if self._state is None:
            raise RuntimeError("no state before reset(): call env.reset(seed=...) first")
        consts, state, _, outs = self._args
        return consts, state, outs.obs, self._to_device(np.ascontiguousarray(rows, dtype=np.int64))

    def _launch_reset(self, rows: np.ndarray) -> None:
        args = self.reset_args(rows)
        if self.device == "cpu":
            reset_rows_cpu(*args)
        else:
            _, reset = self._kernels()
            reset[_blocks(rows.size), THREADS_PER_BLOCK, self._stream()](*args)

    def _kernels(self):
        """The task's device kernels (:func:`iscc_gym.gpu.kernel.cuda_kernels`), compiled (or loaded from numba-cuda's
        cache) before the first launch, the seconds it took in :attr:`compile_s`.
        """
        kernels = cuda_kernels(*self._switches, queue_slots=self._nq)
        if self.compile_s is None:
            import time

            import numba

            t0 = time.perf_counter()
            if not self._sim:  # the simulator compiles nothing
                for kernel, args in zip(kernels, (self.kernel_args(), self.reset_args(np.zeros(1, np.int64))),
                                        strict=True):
                    kernel.compile(tuple(numba.typeof(a) for a in args))
            self.compile_s = time.perf_counter() - t0
        return kernels

    def _stream(self):
        """The handle numba gets of torch's current CUDA stream: the kernels run in order with the torch work around
        them (a ``torch.cuda.stream`` context or a graph capture included); 0 (the default stream) in the simulator.
        """
        if self._torch_device.type != "cuda":
            return 0
        import torch

        return self._cuda.external_stream(torch.cuda.current_stream(self._torch_device).cuda_stream)

    def host_state(self) -> dict:
        """Copies of the rows' state on the host: ``x``, ``x_hat``, ``p``, ``shadow``, ``n``, ``key``, ``queue``,
        ``mission`` (pool index), ``episode``, ``ep_return``, ``ep_length`` (for tests and inspection).
        """
        if self._state is None:
            raise RuntimeError("no state before reset()")
        if self._torch_device.type != "cuda":
            return {k: np.array(v) for k, v in self._state.items()}
        stream = self._stream()  # after the kernels queued on torch's current stream
        out = {k: v.copy_to_host(stream=stream) for k, v in self._state.items()}
        stream.synchronize()
        return out

    def close(self) -> None:
        """Free the device buffers."""
        self._state = self._pool = self._args = None


def memory_bytes(s: Scenario, num_envs: int, pool_size: int) -> int:
    """The bytes a :class:`DeviceVectorEnv` of ``num_envs`` rows and ``pool_size`` missions of scenario ``s`` holds:
    its tensors (observation, reward, flags, returns, lengths, metrics, actions), its state rows (the loop's state,
    the data queue, counters) and its mission pool (``n_slots + 1`` mission rows each), the host's copies that
    :meth:`DeviceVectorEnv.reset` draws them into included (once more on a GPU).
    """
    tensors = 2 * obs_size(s) * 4 + 4 + 1 + 1 + 8 + 8 + len(STEP_COLUMNS) * 8 + 3 * 4
    state = (6 + 6 + 36 + 1 + task_effects(s).queue_deadline_slots) * 8 + 7 * 8
    mission = (s.n_slots + 1) * mission_columns(s) * 8
    return int(num_envs) * (tensors + 2 * state) + int(pool_size) * 2 * mission


def _available_bytes(device) -> int | None:
    """Free memory of ``device`` (a torch device): the GPU's free memory, the host's MemAvailable; None if unknown."""
    if device.type == "cuda":
        import torch

        return int(torch.cuda.mem_get_info(device)[0])
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def _check_memory(need: int, num_envs: int, pool_size: int, device) -> None:
    """``ValueError`` naming ``num_envs``, before any buffer is allocated, when the env would not fit in ``device``'s
    free memory (issue 43.10: ``num_envs=10**8`` allocated buffer after buffer, then died on a ``MemoryError`` naming
    its last small array).
    """
    free = _available_bytes(device)
    if free is None or need <= free:
        return
    per_row = need / max(num_envs + pool_size, 1)
    where = "the GPU" if device.type == "cuda" else "this machine"
    fits = max(int(0.8 * free / per_row) - pool_size, 0)  # a margin for the temporaries of reset's draws
    raise ValueError(f"num_envs = {num_envs:,} (pool_size = {pool_size:,}) needs about {need / 2**30:.1f} GiB; "
                     f"{where} has {free / 2**30:.1f} GiB free: use num_envs <= about {fits:,} (or a smaller "
                     "pool_size)")


def _blocks(n: int) -> int:
    return max(1, -(-n // THREADS_PER_BLOCK))


def _count(value, name: str) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} = {value!r}; expected an integer >= 1")
    return int(value)
