"""A pool of missions drawn once: the device env's missions (:class:`iscc_gym.gpu.vector_env.DeviceVectorEnv`), cached
by (scenario, seed) and drawn in parallel processes where the pool is large.

Mission ``j`` of a pool seeded ``seed`` is :func:`iscc_gym.sim.loop.init_mission` on ``np_random(seed + j)``: the
mission and initial state the CPU vector env's sub-env ``j`` draws at ``reset(seed=seed)``. Each mission has its own
generator, so a pool drawn over any number of worker processes is the serial one bit for bit.

Drawing costs some 7 ms a mission of the field task on one core of this machine (its K-factor field evaluated along
the path, the reference's splines): 1024 missions take 7-12 s serially. The draw is done once per process for a
(scenario, seed) (:data:`CACHE_POOLS` pools kept, the newest; a smaller pool is the larger's prefix), so the device
bench's rows and a trainer's evaluation envs share it; with :data:`PARALLEL_MIN_POOL` missions or more it is split
over worker processes (``workers``: by default ``ISCC_GYM_POOL_WORKERS``, else the machine's cores, at most one per
:data:`PARALLEL_MIN_POOL` missions), each drawing a contiguous block of seeds.
"""

from __future__ import annotations

import os
import sys
from collections import OrderedDict

import numpy as np
from gymnasium.utils import seeding

from iscc_gym.scenario import Scenario
from iscc_gym.sim import loop

__all__ = ["mission_pool", "pool_workers", "clear_pool_cache", "PARALLEL_MIN_POOL", "CACHE_POOLS"]

#: Pools of at least this many missions are drawn over worker processes (a worker's start, some 2 s of imports,
#: costs the draw of a few hundred missions).
PARALLEL_MIN_POOL = 256
#: Pools kept per process, one per (scenario, seed) (the newest; a field pool of 1024 missions holds about 350 MB).
CACHE_POOLS = 2

_CACHE: OrderedDict = OrderedDict()


def pool_workers(size: int, workers: int | None = None) -> int:
    """The worker processes a pool of ``size`` missions is drawn over: ``workers`` if given (at most one a mission),
    else ``ISCC_GYM_POOL_WORKERS`` or the cores this process may use, at most one per :data:`PARALLEL_MIN_POOL`
    missions (1: drawn here, serially).
    """
    if workers is not None:
        if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
            raise ValueError(f"workers = {workers!r}; use an integer >= 1 (1: draw serially)")
        return int(max(1, min(int(workers), size)))
    if workers is None:
        env = os.environ.get("ISCC_GYM_POOL_WORKERS", "").strip()
        if env:
            try:
                workers = int(env)
            except ValueError:
                raise ValueError(f"ISCC_GYM_POOL_WORKERS={env!r}; use an integer >= 1 (1: draw serially)") from None
        else:
            workers = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
        raise ValueError(f"workers = {workers!r}; use an integer >= 1 (1: draw serially)")
    return int(max(1, min(int(workers), size // PARALLEL_MIN_POOL)))


def _draw(s: Scenario, seeds: range) -> loop.LoopState:
    parts = [loop.init_mission(s, seeding.np_random(j)[0]) for j in seeds]
    return loop.LoopState(*(np.concatenate(f) for f in zip(*parts, strict=True)))


def mission_pool(s: Scenario, seed: int, size: int, workers: int | None = None) -> loop.LoopState:
    """The ``size`` missions (and initial states) of sub-envs ``0 .. size - 1`` of a CPU vector env reset with
    ``seed``, as one batched :class:`iscc_gym.sim.loop.LoopState`; read-only arrays, cached per process (copy
    what you write to).

    The cache is kept per (scenario, seed): a smaller pool is a prefix of a larger one (views of its arrays), a
    larger one draws only the missions the cached one lacks. ``workers``: processes to draw over
    (:func:`pool_workers`); any number gives the same pool bit for bit.
    """
    key, seed, size = (s, int(seed)), int(seed), int(size)
    have = _CACHE.get(key)
    if have is not None:
        _CACHE.move_to_end(key)
        if len(have.n) >= size:
            return have if len(have.n) == size else loop.LoopState(*(a[:size] for a in have))
    start = 0 if have is None else len(have.n)
    todo = size - start
    n_workers = pool_workers(todo, workers)
    if n_workers == 1:
        parts = [_draw(s, range(seed + start, seed + size))]
    else:
        bounds = start + np.linspace(0, todo, n_workers + 1).astype(int)
        parts = _draw_in_processes(s, [range(seed + a, seed + b) for a, b in zip(bounds[:-1], bounds[1:], strict=True)])
    if have is not None:
        parts.insert(0, have)
    pool = parts[0] if len(parts) == 1 else loop.LoopState(*(np.concatenate(f) for f in zip(*parts, strict=True)))
    for a in pool:
        a.setflags(write=False)
    _CACHE[key] = pool
    while len(_CACHE) > CACHE_POOLS:
        _CACHE.popitem(last=False)
    return pool


def _draw_in_processes(s: Scenario, blocks: list[range]) -> list[loop.LoopState]:
    """:func:`_draw` of each block of seeds in a process of its own (``python -m iscc_gym.sim.pool``: a fresh
    interpreter, so neither a fork of this process's threads nor a re-import of its ``__main__`` is involved); the
    scenario goes to them and the missions come back through files in a temporary folder.
    """
    import pickle
    import subprocess
    import tempfile

    with tempfile.TemporaryDirectory(prefix="iscc_gym_pool_") as tmp:
        src = os.path.join(tmp, "scenario.pkl")
        with open(src, "wb") as f:
            pickle.dump(s, f)
        procs = [subprocess.Popen([sys.executable, "-m", "iscc_gym.sim.pool", src, os.path.join(tmp, f"{k}.npz"),
                                   str(b.start), str(b.stop), str(os.getpid())], stdout=subprocess.DEVNULL,
                                  stderr=subprocess.PIPE, env={**os.environ, "ISCC_GYM_POOL_WORKERS": "1"})
                 for k, b in enumerate(blocks)]
        try:
            errors = [p.communicate()[1] for p in procs]
        finally:  # interrupted (Ctrl-C, an error): no worker outlives the draw
            for p in procs:
                if p.poll() is None:
                    p.kill()
                    p.wait()
        for k, (p, err) in enumerate(zip(procs, errors, strict=True)):
            if p.returncode != 0:
                why = err.decode(errors="replace").strip()[-2000:]
                raise RuntimeError(f"a mission pool worker (seeds {blocks[k].start} to {blocks[k].stop - 1}) failed: "
                                   f"{why}; ISCC_GYM_POOL_WORKERS=1 draws here")
        parts = []
        for k in range(len(blocks)):
            with np.load(os.path.join(tmp, f"{k}.npz")) as z:
                parts.append(loop.LoopState(*(z[f] for f in loop.LoopState._fields)))
    return parts


def _worker(argv: list[str]) -> None:
    """``python -m iscc_gym.sim.pool SCENARIO.pkl OUT.npz START STOP PARENT``: the missions of seeds START .. STOP - 1,
    for the process PARENT; on Linux the worker is sent SIGTERM when its parent dies (a parent killed by a plain
    SIGTERM, which runs no cleanup, leaves no worker behind).
    """
    import pickle

    src, out, start, stop, parent = argv
    if sys.platform.startswith("linux"):
        import ctypes
        import signal

        ctypes.CDLL(None).prctl(1, int(signal.SIGTERM))  # PR_SET_PDEATHSIG
    if os.getppid() != int(parent):  # the parent died before the line above
        sys.exit(1)
    with open(src, "rb") as f:
        s = pickle.load(f)  # the parent's own temporary file
    pool = _draw(s, range(int(start), int(stop)))
    np.savez(out, **pool._asdict())


def clear_pool_cache() -> None:
    """Forget every cached pool (the memory goes back once no env holds it)."""
    _CACHE.clear()


if __name__ == "__main__":
    _worker(sys.argv[1:])
