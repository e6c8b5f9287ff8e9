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

import numpy as np
from numba import njit

from iscc_gym.sim.kernel import env_row_one, observe_one, split_one
from iscc_gym.sim.loop import WORK_MATS, WORK_VEC, work_from
from iscc_gym.sim.noise import GOLDEN_GAMMA as _GAMMA
from iscc_gym.sim.noise import fill_slot_normals
from iscc_gym.sim.noise import mix64 as _mix64
from iscc_gym.sim.schema import COL, N_DRAWS

__all__ = ["MAX_QUEUE_SLOTS", "N_INIT_DRAWS", "episode_key", "mission_index", "init_normals_key", "step_rows_cpu",
           "reset_rows_cpu", "cuda_kernels", "THREADS_PER_BLOCK"]

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
def init_normals_key(key):
    """The stream of an episode's initial-state normals (slot 0 of it): the key, salted."""
    return _mix64(key ^ _INIT_SALT)


@njit(cache=True, error_model="numpy")
def reset_row(i, c, x, x_hat, p, shadow, n, key, queue, mission, episode, ep_return, ep_length, pool, std0, seed_key,
              obs, zbuf):
    """Start episode ``episode[i]`` of row ``i``: its key, mission, initial state (as
    :func:`iscc_gym.sim.loop.init_state`: the drone near the reference's start, the estimate at it, ``P_0`` diagonal,
    the shadowing a standard normal), an empty queue, and its first observation into ``obs[i]``.
    """
    k = episode_key(seed_key, i, episode[i])
    key[i] = k
    j = mission_index(k, pool.shape[0])
    mission[i] = j
    ref = pool[j]
    z = zbuf[:N_INIT_DRAWS]
    fill_slot_normals(init_normals_key(k), 0, z)
    for a in range(6):
        x[i, a] = ref[0, a] + std0[a] * z[a]
        x_hat[i, a] = ref[0, a]
        for b in range(6):
            p[i, a, b] = std0[a] * std0[a] if a == b else 0.0
    shadow[i] = z[6]
    n[i] = 0
    for a in range(queue.shape[1]):
        queue[i, a] = 0.0
    ep_return[i] = 0.0
    ep_length[i] = 0
    observe_one(c, x_hat[i], p[i], shadow[i], 0, ref, queue[i], 1.0, 0.0, obs[i], 0.0, 0.0)


@njit(cache=True, error_model="numpy")
def step_row(i, cp, mats, x, x_hat, p, shadow, n, key, queue, mission, episode, ep_return, ep_length, pool, std0,
             seed_key, max_steps, action, out, obs, reward, terminated, truncated, final_return, final_length,
             xl, xhl, pl, ql, mbuf, vbuf, zbuf, blocked, field):
    """One step of row ``i`` in place: the env's step (:func:`iscc_gym.sim.kernel.env_row_one`, from local copies of
    the row's state), its outputs (``out[i]``: the env's columns; ``obs[i]``, ``reward[i]``, the done flags), then,
    where the episode ended (terminated, the mission's end, or ``max_steps`` slots), the ended episode's return and
    length into ``final_return[i]``, ``final_length[i]`` (NaN and 0 otherwise) and the next episode
    (:func:`reset_row`). ``xl``, ``xhl``, ``pl``, ``ql``, ``mbuf``, ``vbuf``, ``zbuf``: the caller's scratch.
    """
    c = cp[0]
    nq = queue.shape[1]
    for a in range(6):
        xl[a] = x[i, a]
        xhl[a] = x_hat[i, a]
        for b in range(6):
            pl[a, b] = p[i, a, b]
    for a in range(nq):
        ql[a] = queue[i, a]
    a0, a1, a2 = split_one(action[i, 0], action[i, 1], action[i, 2])
    zi = zbuf[:N_DRAWS + (1 if c.queue == 1.0 else 0)]
    ni = n[i]
    fill_slot_normals(key[i], ni, zi)
    ref = pool[mission[i]]
    mt = out[i]
    shadow[i] = env_row_one(c, mats, xl, xhl, pl, shadow[i], ni, ref, ql[:nq], a0, a1, a2, zi, x[i], x_hat[i], p[i],
                            queue[i], mt, obs[i], work_from(mbuf, vbuf), blocked, field)
    n[i] = ni + 1
    r = mt[_REWARD]
    term = mt[_TERM] == 1.0
    trunc = (not term) and (mt[_TRUNC] == 1.0 or ni + 1 >= max_steps)
    mt[_TRUNC] = 1.0 if trunc else 0.0
    reward[i] = r
    terminated[i] = term
    truncated[i] = trunc
    ep_return[i] += r
    ep_length[i] += 1
    if term or trunc:
        final_return[i] = ep_return[i]
        final_length[i] = ep_length[i]
        episode[i] += 1
        reset_row(i, c, x, x_hat, p, shadow, n, key, queue, mission, episode, ep_return, ep_length, pool, std0,
                  seed_key, obs, zbuf)
    else:
        final_return[i] = math.nan
        final_length[i] = 0


@njit(cache=True, error_model="numpy")
def step_rows_cpu(cp, mats, x, x_hat, p, shadow, n, key, queue, mission, episode, ep_return, ep_length, pool, std0,
                  seed_key, max_steps, action, out, obs, reward, terminated, truncated, final_return, final_length,
                  blocked=None, field=None):
    """:func:`step_row` over every row on one CPU core (the CPU stand-in of the device kernel), its scratch one set
    of buffers for the batch.
    """
    xl, xhl, pl, ql = np.empty(6), np.empty(6), np.empty((6, 6)), np.empty(MAX_QUEUE_SLOTS)
    mbuf, vbuf, zbuf = np.empty(WORK_MATS), np.empty(WORK_VEC), np.empty(_N_Z)
    for i in range(x.shape[0]):
        step_row(i, cp, mats, x, x_hat, p, shadow, n, key, queue, mission, episode, ep_return, ep_length, pool, std0,
                 seed_key, max_steps, action, out, obs, reward, terminated, truncated, final_return, final_length,
                 xl, xhl, pl, ql, mbuf, vbuf, zbuf, blocked, field)


@njit(cache=True, error_model="numpy")
def reset_rows_cpu(cp, x, x_hat, p, shadow, n, key, queue, mission, episode, ep_return, ep_length, pool, std0,
                   seed_key, obs, rows):
    """:func:`reset_row` of the rows listed in ``rows`` (the CPU stand-in of the device reset kernel)."""
    c = cp[0]
    zbuf = np.empty(_N_Z)
    for k in range(rows.shape[0]):
        reset_row(rows[k], c, x, x_hat, p, shadow, n, key, queue, mission, episode, ep_return, ep_length, pool, std0,
                  seed_key, obs, zbuf)


@njit(cache=True, inline="always")
def _same(a):
    return a


def _simulated_array(a):
    """The numpy array inside one of numba-cuda's simulated device arrays."""
    return getattr(a, "_ary", a)


_KERNELS: dict = {}
cuda = None  # numba.cuda once cuda_kernels has imported it


def cuda_kernels(blocked=None, field=None):
    """``(step, reset)``: the device kernels of a task's compile-time switches (``blocked``, ``field``:
    :func:`iscc_gym.sim.loop.slot_switches`), one thread per env row, built once per switch pair. ``step`` takes
    :func:`step_rows_cpu`'s arguments without the switches; ``reset`` takes :func:`reset_rows_cpu`'s. The scratch is
    per-thread local memory (no device-heap allocation).
    """
    got = _KERNELS.get((blocked, field))
    if got is not None:
        return got
    from numba import float64

    from iscc_gym.gpu.cuda import import_cuda, simulator

    global cuda  # a module global: numba-cuda's simulator swaps the module where the kernels' globals hold it
    cuda = import_cuda()
    # the simulator runs the kernels as Python and hands them its array wrappers, which the @njit row functions
    # (compiled for the CPU there) do not take: it passes them the arrays inside; on a GPU an identity, inlined
    host = _simulated_array if simulator() else _same

    @cuda.jit
    def step(cp, mats, x, x_hat, p, shadow, n, key, queue, mission, episode, ep_return, ep_length, pool, std0,
             seed_key, max_steps, action, out, obs, reward, terminated, truncated, final_return, final_length):
        i = cuda.grid(1)
        if i >= x.shape[0]:
            return
        xl = cuda.local.array(6, float64)
        xhl = cuda.local.array(6, float64)
        pl = cuda.local.array((6, 6), float64)
        ql = cuda.local.array(MAX_QUEUE_SLOTS, float64)
        mbuf = cuda.local.array(WORK_MATS, float64)
        vbuf = cuda.local.array(WORK_VEC, float64)
        zbuf = cuda.local.array(_N_Z, float64)
        h = host
        step_row(i, h(cp), h(mats), h(x), h(x_hat), h(p), h(shadow), h(n), h(key), h(queue), h(mission), h(episode),
                 h(ep_return), h(ep_length), h(pool), h(std0), seed_key, max_steps, h(action), h(out), h(obs),
                 h(reward), h(terminated), h(truncated), h(final_return), h(final_length), xl, xhl, pl, ql, mbuf, vbuf,
                 zbuf, blocked, field)

    @cuda.jit
    def reset(cp, x, x_hat, p, shadow, n, key, queue, mission, episode, ep_return, ep_length, pool, std0, seed_key,
              obs, rows):
        k = cuda.grid(1)
        if k >= rows.shape[0]:
            return
        zbuf = cuda.local.array(_N_Z, float64)
        h = host
        reset_row(rows[k], h(cp)[0], h(x), h(x_hat), h(p), h(shadow), h(n), h(key), h(queue), h(mission), h(episode),
                  h(ep_return), h(ep_length), h(pool), h(std0), seed_key, h(obs), zbuf)

    _KERNELS[(blocked, field)] = step, reset
    return step, reset


def step_ptx(args, switches=(None, None), cc=(9, 0)) -> str:
    """The device step kernel compiled to PTX for compute capability ``cc`` (default sm_90, the H100) for the
    argument values ``args`` (their numba types; :meth:`iscc_gym.gpu.vector_env.DeviceVectorEnv.kernel_args`), without
    a GPU: needs the CUDA toolkit's libNVVM and NVRTC (:func:`iscc_gym.gpu.cuda.toolkit_for_ptx` says what is missing).

    numba-cuda (0.30) asks the current device for its capability when it compiles the device functions a kernel
    calls, which a machine without a GPU cannot answer: for the compile, that question gets ``cc``'s answer.
    """
    from unittest import mock

    import numba

    step, _ = cuda_kernels(*switches)
    sig = tuple(numba.typeof(a) for a in args)

    class _Device:
        compute_capability = tuple(cc)

    from numba.cuda import dispatcher

    with mock.patch.object(dispatcher, "get_current_device", lambda: _Device()):
        ptx, _ = cuda.compile_ptx(step.py_func, sig, cc=tuple(cc))
    return ptx
