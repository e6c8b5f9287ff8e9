"""Which compiled kernel steps a batch: the serial one (the default), or the parallel one on numba's threads.

Both give the same results bit for bit (each row goes through the same compiled code), so the choice
is about speed only, and the fastest depends on what else runs on the machine. Measured on the 2-core
machine (``python -m eval.bench``, rows "vector env ... kernel"): on a quiet machine two threads step
1024 envs about twice as fast as one; but as soon as another process keeps one core busy, every
fork-join step waits for a descheduled (or spinning) OpenMP thread, and the parallel kernel falls to
~0.05-0.2 M env-steps/s against ~0.9-1 M serially. An adaptive choice (timing both kernels and
playing the faster) lost to both fixed choices: switching kernels wakes and spins the OpenMP pool.

So the default is serial, which never collapses; in training the env is a few per cent of the time,
so it costs nothing there. On a machine you know to be quiet, large batches gain from the parallel
kernel: :func:`set_parallel(True) <set_parallel>` or ``ISCC_GYM_PARALLEL=1``.
"""

from __future__ import annotations

import os

__all__ = ["PARALLEL_MIN_BATCH", "get_parallel", "set_parallel", "use_parallel"]

#: Smaller batches are stepped serially even with the parallel kernel on (its launch costs more).
PARALLEL_MIN_BATCH = 64

_TRUE, _FALSE = ("1", "true", "yes", "on"), ("", "0", "false", "no", "off")


def _from_environment() -> bool:
    value = os.environ.get("ISCC_GYM_PARALLEL", "").strip().lower()
    if value not in _TRUE + _FALSE:
        raise ValueError(f"ISCC_GYM_PARALLEL={value!r}; use 1 (parallel kernel on all numba threads) or 0 (serial)")
    return value in _TRUE


_parallel = _from_environment()


def set_parallel(on: bool) -> None:
    """Step batches of at least :data:`PARALLEL_MIN_BATCH` loops on all of numba's threads (``True``) or
    serially (``False``, the default). Results are identical either way.
    """
    global _parallel
    if not isinstance(on, bool):
        raise TypeError(f"set_parallel(on={on!r}): use True or False")
    _parallel = on


def get_parallel() -> bool:
    """Whether the parallel kernel is on (:func:`set_parallel`, ``ISCC_GYM_PARALLEL``)."""
    return _parallel


def use_parallel(nb: int, threads: int) -> bool:
    """True to step a batch of ``nb`` loops with the parallel kernel on ``threads`` numba threads."""
    return _parallel and nb >= PARALLEL_MIN_BATCH and threads >= 2
