"""Writing files so that an interrupted write never leaves a truncated one: the only place it is done."""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["write_atomic", "atomic_target"]


@contextmanager
def atomic_target(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary name beside ``path`` to write to (by any writer: ``np.savez``, an SB3 ``save``,
    a pickle); on leaving the block without an error it is renamed onto ``path``, else removed.

    ``with atomic_target("run/model.zip") as tmp: model.save(tmp)``: a kill or a full disk during the
    write leaves the old ``path`` (or none), never a truncated one. Parent directories are created.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to a unique temporary name beside ``path``, then rename it onto ``path``.

    A kill mid-write leaves the old file (or none) and at most a hidden ``.NAME.*.tmp`` beside it,
    never a truncated ``path``. Parent directories are created. Returns the path.
    """
    with atomic_target(path) as tmp:
        tmp.write_text(text)
    return Path(path)
