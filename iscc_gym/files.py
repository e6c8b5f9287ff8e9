"""Writing files so that an interrupted write never leaves a truncated one: the only place it is done.

Every output of the project (``--json``, figures, run files, tuned records) goes through
:func:`atomic_target` (or :func:`write_atomic`), which writes what the destination is:

- a regular file, or no file yet: a temporary name beside it, renamed onto it at the end;
- a symbolic link: the same, beside the link's target (resolved), so the link stays a link;
- an open descriptor of this process (``/dev/stdout``, ``/dev/stderr``, ``/dev/fd/N``,
  ``/proc/self/fd/N``): the bytes are written into that descriptor, at its position, after Python's
  own buffers are flushed, so ``--json /dev/stdout > out.txt`` keeps the printed lines and the JSON;
- any other file that is not a regular one (a device such as ``/dev/null``, a FIFO): opened and
  written into, never replaced (a FIFO waits for its reader, as a shell redirection does).

In the last two cases the writer still writes to a temporary file first, so a failing writer sends
nothing. A directory is refused (``IsADirectoryError``).

A directory written as one unit (a saved agent, ``best/``) goes through :func:`atomic_dir`: filled
under a temporary name beside it, then swapped in whole.
"""

from __future__ import annotations

import errno
import os
import re
import shutil
import stat
import sys
import tempfile
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["write_atomic", "atomic_target", "atomic_dir", "destination", "create_exclusive"]

#: A path naming an open descriptor of a process: ``/proc/self/fd/N``, ``/proc/<pid>/fd/N``,
#: ``/proc/thread-self/fd/N`` or ``/proc/<pid>/task/<tid>/fd/N``.
_FD_PATH = re.compile(r"/proc/(?:self|thread-self|(\d+)(?:/task/\d+)?)/fd/(\d+)")
_MAX_LINKS = 40  # as the kernel's limit on symbolic links followed in one lookup


def _descriptor(path: str | os.PathLike) -> int | None:
    """The descriptor number if ``path`` names an open descriptor of this process (directly or through
    symbolic links: ``/dev/stdout`` -> ``/proc/self/fd/1``), else None.
    """
    p = os.path.abspath(path)
    for _ in range(_MAX_LINKS):
        parent, name = os.path.split(p)
        p = os.path.join(os.path.realpath(parent), name)
        m = _FD_PATH.fullmatch(p)
        if m is not None and m.group(1) in (None, str(os.getpid())):
            return int(m.group(2))
        if not os.path.islink(p):
            return None
        p = os.path.join(os.path.dirname(p), os.readlink(p))
    return None


def destination(path: str | os.PathLike) -> tuple[str, Path | int]:
    """How :func:`atomic_target` writes ``path``.

    Returns
    -------
    kind : str
        ``"file"`` (a temporary file renamed onto ``target``), ``"descriptor"`` (written into the
        open descriptor ``target``) or ``"stream"`` (``target`` exists and is not a regular file: a
        device or a FIFO, opened and written into).
    target : Path or int
        The file to create or replace (a symbolic link's target, resolved), the descriptor number, or
        the path to open.

    Raises
    ------
    IsADirectoryError
        ``path`` is a directory (or a link to one).
    """
    fd = _descriptor(path)
    if fd is not None:
        return "descriptor", fd
    try:
        mode = os.stat(path).st_mode  # follows links
    except (FileNotFoundError, NotADirectoryError):  # nothing there yet (or a file where a parent should be)
        mode = None
    if mode is not None and stat.S_ISDIR(mode):
        raise IsADirectoryError(f"{path}: is a directory; give a file name")
    if mode is not None and not stat.S_ISREG(mode):
        return "stream", Path(path)
    # a regular file, a link to one, a dangling link (its target is created) or nothing yet
    return "file", Path(os.path.realpath(path)) if os.path.islink(path) else Path(path)


def _send(kind: str, target: Path | int, tmp: Path) -> None:
    """Copy the finished temporary file ``tmp`` into a descriptor or a non-regular file."""
    with open(tmp, "rb") as src:
        if kind == "descriptor":
            for stream in (sys.stdout, sys.stderr):  # what Python printed before comes first
                try:
                    stream.flush()
                except (AttributeError, ValueError, OSError):
                    pass
            with os.fdopen(os.dup(int(target)), "wb") as dst:
                shutil.copyfileobj(src, dst)
        else:
            with open(target, "wb") as dst:
                shutil.copyfileobj(src, dst)


@contextmanager
def atomic_target(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary name to write to (by any writer: ``np.savez``, an SB3 ``save``, a pickle); on leaving
    the block without an error it becomes ``path``, else it is removed.

    ``with atomic_target("run/model.zip") as tmp: model.save(tmp)``: a kill or a full disk during the
    write leaves the old ``path`` (or none), never a truncated one. Parent directories are created. A
    symbolic link stays a link (its target is replaced), and a destination that is not a regular file
    (``/dev/stdout``, a device, a FIFO) is written into, never replaced (see the module docstring).

    Raises
    ------
    IsADirectoryError
        ``path`` is a directory.
    """
    kind, target = destination(path)
    if kind != "file":
        with tempfile.TemporaryDirectory(prefix="iscc_gym-") as d:
            tmp = Path(d) / f"{Path(path).name}.tmp"
            yield tmp
            _send(kind, target, tmp)
        return
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_name(f".{target.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        yield tmp
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)


def _exchange(a: Path, b: Path) -> bool:
    """Swap the two existing paths ``a`` and ``b`` in one step (Linux ``renameat2(RENAME_EXCHANGE)``);
    False where the system or the file system cannot.
    """
    if not sys.platform.startswith("linux"):
        return False
    import ctypes

    try:
        renameat2 = ctypes.CDLL(None, use_errno=True).renameat2
    except AttributeError:  # a C library older than glibc 2.28
        return False
    renameat2.argtypes = (ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint)
    at_fdcwd, rename_exchange = -100, 2
    if renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.EPERM):
        return False
    raise OSError(err, os.strerror(err), str(b))


def _remove(p: Path) -> None:
    """Delete a directory tree, or a file or link, where one is."""
    if p.is_dir() and not p.is_symlink():
        shutil.rmtree(p, ignore_errors=True)
    else:
        p.unlink(missing_ok=True)


@contextmanager
def atomic_dir(path: str | os.PathLike) -> Iterator[Path]:
    """A new, empty directory beside ``path`` (``.NAME.<pid>.<tag>.tmp``) to fill; on leaving the block
    without an error it takes ``path``'s place whole, else it is deleted and ``path`` is left as it was.

    ``with atomic_dir("agents/trained/ppo_iscc") as tmp: copy files into tmp``: a kill or a full disk while
    filling leaves the old directory untouched (and at most the hidden temporary one beside it). The swap
    is one exchange of the two names on Linux, so ``path`` is at every instant the old directory or the
    new one; where the file system cannot exchange, two renames (the old one aside as ``.NAME.<pid>.<tag>
    .old``, the new one into place), and a kill between them leaves both whole beside ``path``
    (:func:`iscc_gym.train.runs.recover_unit` puts one back). The old directory is then deleted.
    """
    d = Path(path)
    d.parent.mkdir(parents=True, exist_ok=True)
    tag = f"{os.getpid()}.{uuid.uuid4().hex[:8]}"
    tmp = d.with_name(f".{d.name}.{tag}.tmp")
    tmp.mkdir()
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if not (d.exists() or d.is_symlink()):
        os.rename(tmp, d)
    elif _exchange(tmp, d):
        _remove(tmp)  # the old directory, under the temporary name now
    else:
        old = d.with_name(f".{d.name}.{tag}.old")
        os.rename(d, old)
        os.rename(tmp, d)
        _remove(old)


def write_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to a unique temporary name beside ``path``, then rename it onto ``path``.

    A kill mid-write leaves the old file (or none) and at most a hidden ``.NAME.*.tmp`` beside it,
    never a truncated ``path``. Parent directories are created. A symbolic link keeps pointing at its
    (replaced) target; ``/dev/stdout``, a device or a FIFO is written into (:func:`atomic_target`).
    Returns the path.
    """
    with atomic_target(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def create_exclusive(path: str | os.PathLike, text: str) -> bool:
    """Create ``path`` holding ``text`` unless it exists, atomically: whole or not at all, and of two
    processes creating it at once exactly one succeeds (a hard link of a finished temporary file).

    Returns
    -------
    bool
        True if this call created it, False if ``path`` existed (it is left as it was).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        tmp.write_text(text)
        os.link(tmp, path)
        return True
    except FileExistsError:
        return False
    finally:
        tmp.unlink(missing_ok=True)
