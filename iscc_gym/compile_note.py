"""One line on stderr when the compiled kernels are built rather than loaded from numba's cache.

The env's slot and step are numba functions cached on disk (``cache=True``): the first use of each task after an
install or an upgrade compiles its specialisation (``python -m eval.bench --compile``, a cold cache on 2 idle cores:
about 15 s for the first task, 5 s for each further one, 4-6 s for the device env's stand-in; several times that
beside busy processes), and every later process loads them in a fraction of a second. So that a first run does not
look hung, the first real compilation of one of this package's functions prints one note to stderr (numba's
``numba:compile`` event fires on a cache miss only, never on a cache hit). ``ISCC_GYM_QUIET=1`` in the environment
silences it.

Once per run, not per process: the first process importing the package names a marker file in the environment
(:data:`RUN_ENV`), which its worker processes inherit (spawned, forked, forkserver); the process that prints the
note creates the marker, and one that finds it there already prints nothing. The first process removes it at exit.
"""

from __future__ import annotations

import atexit
import os
import sys
import tempfile
import uuid

from numba.core import event

__all__ = ["NOTE", "RUN_ENV", "CompileNote"]

#: The line printed once per run.
NOTE = ("iscc_gym: building the compiled env kernels, once per task after an install or upgrade (on 2 idle cores "
        "about 15 s for the first task, 5 s for another, 5 s for the device env; longer on a busy machine; "
        "python -m eval.bench --compile measures it); cached for later runs")
#: The environment variable naming the run's marker file (set by the run's first process, inherited by its workers).
RUN_ENV = "ISCC_GYM_COMPILE_NOTE"


class CompileNote(event.Listener):
    """Prints :data:`NOTE` to ``stream`` (default stderr) at the first compilation of a function of the package
    ``package`` (default ``iscc_gym``); with ``per_run``, only if no other process of the run printed it (the
    marker file named by :data:`RUN_ENV`, if set).
    """

    def __init__(self, stream=None, package: str = "iscc_gym", per_run: bool = False):
        self.stream = stream
        self.package = package
        self.per_run = per_run
        self.noted = False

    def on_start(self, ev):
        if self.noted or os.environ.get("ISCC_GYM_QUIET"):
            return
        dispatcher = (ev.data or {}).get("dispatcher")
        module = getattr(getattr(dispatcher, "py_func", None), "__module__", "") or ""
        if module.split(".")[0] == self.package:
            self.noted = True
            if not self.per_run or _first_in_run():
                print(NOTE, file=self.stream or sys.stderr, flush=True)

    def on_end(self, ev):
        pass


def _first_in_run() -> bool:
    """Whether this process is the first of its run to claim the note (creates the run's marker file)."""
    path = os.environ.get(RUN_ENV)
    if not path:
        return True
    try:
        os.close(os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
    except FileExistsError:
        return False
    except OSError:  # no marker can be written: every process notes for itself
        pass
    return True


def _remove_marker(path: str, owner: int) -> None:
    if os.getpid() == owner:  # not in a forked child that inherited the exit hook
        try:
            os.remove(path)
        except OSError:
            pass


if RUN_ENV not in os.environ:  # the run's first process: its workers inherit the marker's name
    _marker = os.path.join(tempfile.gettempdir(), f"iscc_gym-compile-note-{os.getpid()}-{uuid.uuid4().hex[:8]}")
    os.environ[RUN_ENV] = _marker
    atexit.register(_remove_marker, _marker, os.getpid())

LISTENER = CompileNote(per_run=True)
event.register("numba:compile", LISTENER)
