"""Writing files so that an interrupted write never leaves a truncated one: the only place it is done."""

from __future__ import annotations

import os
import uuid
from pathlib import Path

__all__ = ["write_atomic"]


def write_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to a unique temporary name beside ``path``, then rename it onto ``path``.

    A kill mid-write leaves the old file (or none) and at most a hidden ``.NAME.*.tmp`` beside it,
    never a truncated ``path``. Parent directories are created. Returns the path.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path
