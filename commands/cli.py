"""The console commands' one convention for ending: exit 0 on success; a user's mistake (a bad path, spec
or number) exits 2 with one line naming it, no traceback; Ctrl-C exits 130; SIGTERM (``kill``, ``timeout``, a
scheduler's stop) exits 143 after the same clean-up as Ctrl-C: it raises :class:`Terminated` (a
``KeyboardInterrupt``), so a worker pool ends its processes before the command exits instead of leaving them
running (issue 43.2).

``iscc-eval``, ``iscc-train`` and every ``python -m`` command end through :func:`run`. Set
``ISCC_GYM_TRACEBACK=1`` to see the traceback of an error instead. A package of an extra that is not installed
(torch on the core install) is a user's error too: one line naming the extra. :func:`invoked_prog` names a
command as it was typed (``python -m eval`` in the checkout, ``python -m iscc_gym.eval`` installed).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import zipfile
from collections.abc import Callable

__all__ = ["USER_ERRORS", "EXTRAS", "Terminated", "run", "invoked_prog"]

#: The exceptions that mean "the input was wrong": reported in one line, exit code 2.
USER_ERRORS = (ValueError, TypeError, KeyError, OSError, zipfile.BadZipFile)

#: The packages of pyproject's extras, by import name: a ``ModuleNotFoundError`` for one of them is reported in
#: one line naming the extra, exit code 2 (the core install has none of them).
EXTRAS = {"torch": "train", "stable_baselines3": "train", "sb3_contrib": "train", "tensorboard": "train",
          "optuna": "train", "rich": "train", "pettingzoo": "multi"}


class Terminated(KeyboardInterrupt):
    """SIGTERM received by a command run through :func:`run`. A ``KeyboardInterrupt``, so everything that cleans up
    on Ctrl-C (the worker pools of :mod:`iscc_gym.eval.policies`, ``with`` blocks, temporary files) does so here too.
    """


#: The process that set :func:`_raise_terminated` (a forked worker inherits the handler, not the clean-up duty).
_HANDLER_PID: list[int] = []


def _raise_terminated(signum, frame):
    # a second SIGTERM while the first one's clean-up runs ends the process at once (the signal's default action)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if os.getpid() not in _HANDLER_PID:  # a forked worker, ended by its pool's clean-up: it ends as by default
        os.kill(os.getpid(), signal.SIGTERM)
    raise Terminated(f"signal {signum}")


def invoked_prog(prog: str) -> str:
    """``prog`` (``python -m eval.tune``) as this process was invoked: ``python -m iscc_gym.eval.tune`` when run
    as that module (the installed name), else ``prog`` unchanged (a console script, a test, another module).
    """
    module = prog.split()[2] if prog.startswith("python -m ") and len(prog.split()) == 3 else None
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    name = getattr(spec, "name", None) or ""
    name = name.removesuffix(".__main__")
    if module and name != module and name.endswith("." + module):
        return f"python -m {name}"
    return prog


def _missing_extra(e: ModuleNotFoundError) -> str | None:
    """The one-line error of a missing package of an extra (:data:`EXTRAS`), else None."""
    package = (e.name or "").split(".")[0]
    if package not in EXTRAS:
        return None
    if f"iscc-gym[{EXTRAS[package]}]" in str(e):  # a check's own message, naming the extra already
        return str(e)
    return f"{package} is not installed; it comes with the {EXTRAS[package]} extra: pip install " \
           f"'iscc-gym[{EXTRAS[package]}]'"


def run(main: Callable[[list[str] | None], object], argv: list[str] | None = None, prog: str | None = None) -> int:
    """Call ``main(argv)`` and turn its outcome into an exit code (for ``sys.exit``).

    Returns 0 when ``main`` returns (whatever it returns), 2 after printing ``PROG: error: MESSAGE``
    to stderr for a :data:`USER_ERRORS` exception or a missing package of an extra (:data:`EXTRAS`), 130 on
    Ctrl-C, 143 on SIGTERM (:class:`Terminated`, raised by the handler set for the call). argparse's own exits
    (``--help``, a bad flag) pass through.
    """
    prog = invoked_prog(prog or os.path.basename(sys.argv[0]))
    # SIGTERM as a Ctrl-C (only the main thread may set a handler; a command called from another thread keeps its own)
    handles = threading.current_thread() is threading.main_thread()
    if handles:
        _HANDLER_PID.append(os.getpid())
        previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        main(argv)
    except Terminated:
        print(f"{prog}: terminated", file=sys.stderr)
        return 143
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except ModuleNotFoundError as e:
        msg = _missing_extra(e)
        if msg is None or os.environ.get("ISCC_GYM_TRACEBACK"):
            raise
        print(f"{prog}: error: {msg}", file=sys.stderr)
        return 2
    except USER_ERRORS as e:
        if os.environ.get("ISCC_GYM_TRACEBACK"):
            raise
        msg = str(e) if not isinstance(e, KeyError) else str(e.args[0] if e.args else e)
        print(f"{prog}: error: {msg or type(e).__name__}", file=sys.stderr)
        return 2
    finally:
        if handles:
            signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)
            _HANDLER_PID.pop()
    return 0
