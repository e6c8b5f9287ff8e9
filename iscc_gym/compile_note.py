"""One line on stderr when the compiled kernels are built rather than loaded from numba's cache.

The env's slot and step are numba functions cached on disk (``cache=True``): the first use after an install or
an upgrade compiles them, about ten seconds on a 2-core machine, and every later process loads them in a
fraction of a second. So that a first run does not look hung, the first real compilation of one of this
package's functions in a process prints one note to stderr (numba's ``numba:compile`` event fires on a cache
miss only, never on a cache hit). ``ISCC_GYM_QUIET=1`` in the environment silences it.
"""

from __future__ import annotations

import os
import sys

from numba.core import event

__all__ = ["NOTE", "CompileNote"]

#: The line printed once per process.
NOTE = ("iscc_gym: building the compiled env kernels on first use (about 10 s once after an install or upgrade; "
        "cached for later runs)")


class CompileNote(event.Listener):
    """Prints :data:`NOTE` to ``stream`` (default stderr) at the first compilation of a function of the package
    ``package`` (default ``iscc_gym``).
    """

    def __init__(self, stream=None, package: str = "iscc_gym"):
        self.stream = stream
        self.package = package
        self.noted = False

    def on_start(self, ev):
        if self.noted or os.environ.get("ISCC_GYM_QUIET"):
            return
        dispatcher = (ev.data or {}).get("dispatcher")
        module = getattr(getattr(dispatcher, "py_func", None), "__module__", "") or ""
        if module.split(".")[0] == self.package:
            self.noted = True
            print(NOTE, file=self.stream or sys.stderr, flush=True)

    def on_end(self, ev):
        pass


LISTENER = CompileNote()
event.register("numba:compile", LISTENER)
