"""The device env's step and reset of one env row, written once as ``@njit`` functions: numba compiles them for the
CPU (:func:`step_rows_cpu`, :func:`reset_rows_cpu`: the CPU stand-in) and numba-cuda for the GPU
(:func:`cuda_kernels`: one thread per env, scratch in per-thread local memory).

A row's step is the env's own (:func:`iscc_gym.sim.kernel.env_row_one`: the slot transition, data queue, observation,
reward and costs), then the device env's autoreset in the same call: an env whose episode ends starts its next one at
once (Gymnasium's same-step autoreset; the returned observation is the new episode's, the ended episode's return and
length are reported). A new episode draws everything from counter-based streams (:mod:`iscc_gym.sim.noise`): its key
from the run's seed key, the env's index and its episode count (:func:`episode_key`), its mission from the device
pool by that key (:func:`mission_index`), its initial state from the key's own stream. So a run is a function of the
seed, the pool and the actions only: the same on any device, any batch split, the CPU stand-in or a GPU (up to the
last bits of ``exp``/``log``).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numba import njit

from iscc_gym.sim.kernel import LastSlot, env_row_one, observe_one, split_one
from iscc_gym.sim.loop import WORK_MATS, WORK_VEC, LoopState, init_row_one, next_row, slot_draws_one, work_from
from iscc_gym.sim.noise import GOLDEN_GAMMA as _GAMMA
from iscc_gym.sim.noise import fill_slot_normals
from iscc_gym.sim.noise import mix64 as _mix64
from iscc_gym.sim.schema import COL, N_DRAWS

__all__ = ["Consts", "Rows", "Outs", "Scratch", "MAX_QUEUE_SLOTS", "N_INIT_DRAWS", "episode_key", "mission_index",
           "start_slot", "init_normals_key", "step_rows_cpu", "reset_rows_cpu", "cuda_kernels", "THREADS_PER_BLOCK",
           "PTX_LIMITS", "kernel_ptx", "ptxas_usage"]

#: The data queue's longest buffer the device kernel holds per thread (its local memory is sized at compile time).
MAX_QUEUE_SLOTS = 64
#: Normals of a new episode's initial state: six of the state, one of the shadowing
#: (:func:`iscc_gym.sim.loop.init_state`).
N_INIT_DRAWS = 7
#: Threads per block of the device kernels (the measurement of ``../shared/notes/gpu.md``: 128 best).
THREADS_PER_BLOCK = 128

_REWARD, _TERM, _TRUNC = COL["reward"], COL["terminated"], COL["truncated"]
_N_Z = N_DRAWS + 1  # a slot's draws with the queue's arrival (a constant: local arrays are sized at compile time)
_INIT_SALT = np.uint64(0x5851F42D4C957F2D)  # separates a key's initial-state stream from its slots' streams
_START_SALT = np.uint64(0x2545F4914F6CDD1D)  # and its start slot's draw (random_start)
_ONE = np.uint64(1)
_SHIFT = np.uint64(11)


@njit(cache=True, error_model="numpy", inline="always")
def episode_key(seed_key, env, episode):
    """The noise key of episode ``episode`` (0, 1, ...) of env row ``env`` in a run seeded with ``seed_key``
    (uint64): SplitMix64 of the row's stream, stepped by the episode count.
    """
    row = _mix64(seed_key + (np.uint64(env) + _ONE) * _GAMMA)
    return _mix64(row + (np.uint64(episode) + _ONE) * _GAMMA)


@njit(cache=True, error_model="numpy", inline="always")
def mission_index(key, pool_size):
    """The pool mission an episode with ``key`` flies: the key's top 53 bits, modulo the pool's size."""
    return np.int64(key >> _SHIFT) % pool_size


@njit(cache=True, error_model="numpy", inline="always")
def start_slot(key, max_steps):
    """The slot a first episode with ``key`` starts at under ``random_start``: uniform over ``[0, max_steps)`` (the
    salted key's top 53 bits, modulo ``max_steps``).
    """
    return np.int64(_mix64(key ^ _START_SALT) >> _SHIFT) % max_steps


@njit(cache=True, error_model="numpy", inline="always")
def init_normals_key(key):
    """The stream of an episode's initial-state normals (slot 0 of it): the key, salted."""
    return _mix64(key ^ _INIT_SALT)


class Consts(NamedTuple):
    """What every row of a run reads: the slot's record and matrices (:func:`iscc_gym.sim.params.slot_params`), the
    mission pool ``(P, N + 1, C)``, the initial state's deviations (6,), the run's seed key (uint64), the step
    limit (int64), and ``random_start`` (int64 1: a row's first episode starts at :func:`start_slot`; 0: at slot 0).
    """

    cp: Any
    mats: Any
    pool: Any
    std0: Any
    seed_key: Any
    max_steps: Any
    random_start: Any


class Rows(NamedTuple):
    """The state of every row: the loop's (``x``, ``x_hat``, ``p``, ``shadow``, ``n``, ``key``, ``queue``) and the
    episode's (``mission``: its pool index, ``episode``: the count, ``ep_return``, ``ep_length``).
    """

    x: Any
    x_hat: Any
    p: Any
    shadow: Any
    n: Any
    key: Any
    queue: Any
    mission: Any
    episode: Any
    ep_return: Any
    ep_length: Any


class Outs(NamedTuple):
    """What a step writes per row: the env's columns (``out``), the observation, reward and done flags, and the ended
    episode's return, length and last observation.
    """

    out: Any
    obs: Any
    reward: Any
    terminated: Any
    truncated: Any
    final_return: Any
    final_length: Any
    final_obs: Any


class Scratch(NamedTuple):
    """A thread's work space: local copies of the row's state (``xl``, ``xhl``, ``pl``, ``ql``), the slot's
    matrices and vectors (``mbuf``, ``vbuf``: :func:`iscc_gym.sim.loop.work_from`) and the draws (``zbuf``).
    """

    xl: Any
    xhl: Any
    pl: Any
    ql: Any
    mbuf: Any
    vbuf: Any
    zbuf: Any


@njit(cache=True, error_model="numpy")
def reset_row(i, c, k, st, obs, zbuf):
    """Start episode ``st.episode[i]`` of row ``i`` (``c``: the slot's record, ``k``: :class:`Consts`, ``st``:
    :class:`Rows`): its key, mission, initial state (:func:`iscc_gym.sim.loop.init_row_one`, as the CPU envs': the
    drone near the reference's start, the estimate at it, ``P_0`` diagonal, the shadowing a standard normal), an empty
    queue, and its first observation into ``obs[i]``. With ``k.random_start`` a row's first episode (``episode`` 0)
    starts at :func:`start_slot` of its key instead of slot 0: the drone near the reference there.
    """
    key = episode_key(k.seed_key, i, st.episode[i])
    st.key[i] = key
    j = mission_index(key, k.pool.shape[0])
    st.mission[i] = j
    ref = k.pool[j]
    z = zbuf[:N_INIT_DRAWS]
    fill_slot_normals(init_normals_key(key), 0, z)
    n0 = np.int64(0)
    if k.random_start != 0 and st.episode[i] == 0:
        n0 = start_slot(key, k.max_steps)
    st.shadow[i] = init_row_one(ref[n0], k.std0, z, st.x[i], st.x_hat[i], st.p[i])
    st.n[i] = n0
    for a in range(st.queue.shape[1]):
        st.queue[i, a] = 0.0
    st.ep_return[i] = 0.0
    st.ep_length[i] = 0
    observe_one(c, LoopState(st.x[i], st.x_hat[i], st.p[i], st.shadow[i], n0, ref, key, st.queue[i]),
                LastSlot(1.0, 0.0, 0.0, 0.0), obs[i])


@njit(cache=True, error_model="numpy")
def step_row(i, k, st, action, o, w, blocked, field):
    """One step of row ``i`` in place (``k``: :class:`Consts`, ``st``: :class:`Rows`, ``action``: (N, 3), ``o``:
    :class:`Outs`, ``w``: the caller's :class:`Scratch`): the env's step (:func:`iscc_gym.sim.kernel.env_row_one`,
    from local copies of the row's state), its outputs (``o.out[i]``: the env's columns; the observation, reward and
    done flags), then, where the episode ended (terminated, the mission's end, or ``k.max_steps`` slots), the ended
    episode's return and length into ``o.final_return[i]``, ``o.final_length[i]`` (NaN and 0 otherwise), its last
    observation into ``o.final_obs[i]`` (a truncated episode's value is bootstrapped from it; left as it was where
    none ended) and the next episode (:func:`reset_row`).
    """
    c = k.cp[0]
    nq = st.queue.shape[1]
    for a in range(6):
        w.xl[a] = st.x[i, a]
        w.xhl[a] = st.x_hat[i, a]
        for b in range(6):
            w.pl[a, b] = st.p[i, a, b]
    for a in range(nq):
        w.ql[a] = st.queue[i, a]
    a0, a1, a2 = split_one(action[i, 0], action[i, 1], action[i, 2])
    zi = w.zbuf[:slot_draws_one(c)]
    ni = st.n[i]
    fill_slot_normals(st.key[i], ni, zi)
    ref = k.pool[st.mission[i]]
    mt = o.out[i]
    now = LoopState(w.xl, w.xhl, w.pl, st.shadow[i], ni, ref, st.key[i], w.ql[:nq])
    st.shadow[i] = env_row_one(c, k.mats, now, (a0, a1, a2), zi, next_row(st, i), mt, o.obs[i],
                               work_from(w.mbuf, w.vbuf), blocked, field)
    st.n[i] = ni + 1
    r = mt[_REWARD]
    term = mt[_TERM] == 1.0
    trunc = (not term) and (mt[_TRUNC] == 1.0 or ni + 1 >= k.max_steps)
    mt[_TRUNC] = 1.0 if trunc else 0.0
    o.reward[i] = r
    o.terminated[i] = term
    o.truncated[i] = trunc
    st.ep_return[i] += r
    st.ep_length[i] += 1
    if term or trunc:
        o.final_return[i] = st.ep_return[i]
        o.final_length[i] = st.ep_length[i]
        for a in range(o.obs.shape[1]):
            o.final_obs[i, a] = o.obs[i, a]
        st.episode[i] += 1
        reset_row(i, c, k, st, o.obs, w.zbuf)
    else:
        o.final_return[i] = math.nan
        o.final_length[i] = 0


@njit(cache=True, error_model="numpy")
def step_rows_cpu(k, st, action, o, blocked=None, field=None):
    """:func:`step_row` over every row on one CPU core (the CPU stand-in of the device kernel; the arguments are the
    step kernel's, :meth:`iscc_gym.gpu.vector_env.DeviceVectorEnv.kernel_args`), its scratch one set of buffers for
    the batch.
    """
    w = Scratch(np.empty(6), np.empty(6), np.empty((6, 6)), np.empty(MAX_QUEUE_SLOTS), np.empty(WORK_MATS),
                np.empty(WORK_VEC), np.empty(_N_Z))
    for i in range(st.x.shape[0]):
        step_row(i, k, st, action, o, w, blocked, field)


@njit(cache=True, error_model="numpy")
def reset_rows_cpu(k, st, obs, rows):
    """:func:`reset_row` of the rows listed in ``rows`` (the CPU stand-in of the device reset kernel)."""
    c = k.cp[0]
    zbuf = np.empty(_N_Z)
    for j in range(rows.shape[0]):
        reset_row(rows[j], c, k, st, obs, zbuf)


@njit(cache=True, inline="always")
def _same(a):
    return a


def _simulated_array(a):
    """The numpy array inside one of numba-cuda's simulated device arrays."""
    return getattr(a, "_ary", a)


_KERNELS: dict = {}
cuda = None  # numba.cuda once cuda_kernels has imported it


def cuda_kernels(blocked=None, field=None, queue_slots=MAX_QUEUE_SLOTS):
    """``(step, reset)``: the device kernels of a task's compile-time switches (``blocked``, ``field``:
    :func:`iscc_gym.sim.loop.slot_switches`) and data queue (``queue_slots``: its buffer's length, 0 without a queue),
    one thread per env row, built once per process and key. ``step`` takes :func:`step_rows_cpu`'s arguments without
    the switches; ``reset`` takes :func:`reset_rows_cpu`'s. The scratch is per-thread local memory (no device-heap
    allocation), the queue's sized for the task (``max(queue_slots, 1)`` floats: the paper task carries none of
    :data:`MAX_QUEUE_SLOTS`). Compiled with ``cache=True``: numba-cuda keeps each compiled kernel on disk (keyed by
    its source, the closure's values and the argument types), so a later process loads it instead of compiling.
    """
    if not 0 <= int(queue_slots) <= MAX_QUEUE_SLOTS:
        raise ValueError(f"queue_slots = {queue_slots}; the device kernel holds 0 to {MAX_QUEUE_SLOTS} "
                         "(iscc_gym.gpu.kernel.MAX_QUEUE_SLOTS)")
    got = _KERNELS.get((blocked, field, int(queue_slots)))
    if got is not None:
        return got
    from numba import float64

    from iscc_gym.gpu.cuda import import_cuda, simulator

    global cuda  # a module global: numba-cuda's simulator swaps the module where the kernels' globals hold it
    cuda = import_cuda()
    # the simulator runs the kernels as Python and hands them its wrappers of the array arguments (not of the arrays
    # inside the tuples), which the @njit row functions (compiled for the CPU there) do not take: it passes them the
    # arrays inside; on a GPU an identity, inlined
    host = _simulated_array if simulator() else _same
    nql = max(int(queue_slots), 1)  # a compile-time constant of the closure: the local array's length

    @cuda.jit(cache=True)
    def step(k, st, action, o):
        i = cuda.grid(1)
        if i >= st.x.shape[0]:
            return
        w = Scratch(cuda.local.array(6, float64), cuda.local.array(6, float64), cuda.local.array((6, 6), float64),
                    cuda.local.array(nql, float64), cuda.local.array(WORK_MATS, float64),
                    cuda.local.array(WORK_VEC, float64), cuda.local.array(_N_Z, float64))
        step_row(i, k, st, host(action), o, w, blocked, field)

    @cuda.jit(cache=True)
    def reset(k, st, obs, rows):
        j = cuda.grid(1)
        if j >= rows.shape[0]:
            return
        reset_row(host(rows)[j], k.cp[0], k, st, host(obs), cuda.local.array(_N_Z, float64))

    _KERNELS[(blocked, field, int(queue_slots))] = step, reset
    return step, reset


#: What the PTX test holds each kernel to (``ptxas -v`` for sm_90, :func:`ptxas_usage`), for every single-drone task:
#: no register spills, at most this many registers a thread (an SM's 64K registers hold two blocks of 128 threads
#: at up to 255 each; fewer registers, more resident blocks) and at most this many bytes of stack a thread (the
#: per-thread local arrays: the slot's work space, the draws, the queue). Measured at issue 46 (numba-cuda 0.30,
#: CUDA 12 ptxas): the step 234-242 registers and 1,568 B (paper, field) to 1,648 B (urban: its queue) of stack, no
#: spills (2,080 B with the queue's 64 slots on every task, 1,040 byte-wise loads of the record before it was
#: aligned); the reset 70 registers and 40 B.
PTX_LIMITS = {"step": {"registers": 248, "stack_bytes": 1700, "spill_bytes": 0},
              "reset": {"registers": 96, "stack_bytes": 64, "spill_bytes": 0}}


def kernel_ptx(which: str, args, switches=(None, None), queue_slots=MAX_QUEUE_SLOTS, cc=(9, 0)) -> str:
    """Device kernel ``which`` (``"step"`` or ``"reset"``) compiled to PTX for compute capability ``cc`` (default
    sm_90, the H100) for the argument values ``args`` (their numba types: the signature the env launches,
    :meth:`iscc_gym.gpu.vector_env.DeviceVectorEnv.kernel_args`, ``reset_args``), without a GPU: needs the CUDA
    toolkit's libNVVM and NVRTC (:func:`iscc_gym.gpu.cuda.toolkit_for_ptx` says what is missing).

    numba-cuda (0.30) asks the current device for its capability when it compiles the device functions a kernel
    calls, which a machine without a GPU cannot answer: for the compile, that question gets ``cc``'s answer.
    """
    from unittest import mock

    import numba

    if which not in ("step", "reset"):
        raise ValueError(f"which = {which!r}; use 'step' or 'reset'")
    kernels = dict(zip(("step", "reset"), cuda_kernels(*switches, queue_slots=queue_slots), strict=True))
    sig = tuple(numba.typeof(a) for a in args)

    class _Device:
        compute_capability = tuple(cc)

    from numba.cuda import dispatcher

    with mock.patch.object(dispatcher, "get_current_device", lambda: _Device()):
        ptx, _ = cuda.compile_ptx(kernels[which].py_func, sig, cc=tuple(cc))
    return ptx


def ptxas_usage(ptx: str, cc=(9, 0)) -> dict:
    """``{"registers", "stack_bytes", "spill_bytes", "seconds"}`` of the kernel in ``ptx`` as ``ptxas -v`` assembles it
    for ``sm_<cc>`` (the CUDA toolkit's ``ptxas`` on the PATH or under ``CUDA_HOME``); the entry's figures (ptxas
    also lists the device functions it keeps, such as libdevice's slow paths).

    Raises
    ------
    RuntimeError
        No ``ptxas``, or it rejects the PTX (its message).
    """
    import os
    import re
    import shutil
    import subprocess
    import tempfile
    import time

    exe = shutil.which("ptxas") or (os.path.join(os.environ["CUDA_HOME"], "bin", "ptxas")
                                    if os.environ.get("CUDA_HOME") else None)
    if exe is None or not os.path.exists(exe):
        raise RuntimeError("no ptxas: put the CUDA toolkit's bin on the PATH or set CUDA_HOME")
    entry = re.search(r"\.entry\s+(\S+?)\s*\(", ptx)
    with tempfile.TemporaryDirectory() as tmp:
        src = os.path.join(tmp, "kernel.ptx")
        with open(src, "w") as f:
            f.write(ptx)
        t0 = time.perf_counter()
        r = subprocess.run([exe, "-v", f"-arch=sm_{cc[0]}{cc[1]}", src, "-o", os.path.join(tmp, "kernel.cubin")],
                           capture_output=True, text=True, timeout=600)
        seconds = time.perf_counter() - t0
    if r.returncode != 0:
        raise RuntimeError(f"ptxas failed: {r.stderr.strip()[-2000:]}")
    text = r.stderr
    # the entry's block: "Compiling entry function '<name>'" then its properties and usage lines
    at = text.find(f"'{entry.group(1)}'") if entry else -1
    block = text[at:] if at >= 0 else text
    regs = re.search(r"Used (\d+) registers", block)
    frame = re.search(r"(\d+) bytes stack frame, (\d+) bytes spill stores, (\d+) bytes spill loads", block)
    if regs is None or frame is None:
        raise RuntimeError(f"ptxas -v gave no usage for the kernel: {text[-2000:]}")
    return {"registers": int(regs.group(1)), "stack_bytes": int(frame.group(1)),
            "spill_bytes": int(frame.group(2)) + int(frame.group(3)), "seconds": seconds}
