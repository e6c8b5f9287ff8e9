"""The console commands' one convention for ending: exit 0 on success; a user's mistake (a bad path, spec
or number) exits 2 with one line naming it, no traceback; Ctrl-C exits 130.

``iscc-eval``, ``iscc-train`` and every ``python -m`` command end through :func:`run`. Set
``ISCC_GYM_TRACEBACK=1`` to see the traceback of an error instead.
"""

from __future__ import annotations

import os
import sys
import zipfile
from collections.abc import Callable

__all__ = ["USER_ERRORS", "run"]

#: The exceptions that mean "the input was wrong": reported in one line, exit code 2.
USER_ERRORS = (ValueError, TypeError, KeyError, OSError, zipfile.BadZipFile)


def run(main: Callable[[list[str] | None], object], argv: list[str] | None = None, prog: str | None = None) -> int:
    """Call ``main(argv)`` and turn its outcome into an exit code (for ``sys.exit``).

    Returns 0 when ``main`` returns (whatever it returns), 2 after printing ``PROG: error: MESSAGE``
    to stderr for a :data:`USER_ERRORS` exception, 130 on Ctrl-C. argparse's own exits (``--help``,
    a bad flag) pass through.
    """
    prog = prog or os.path.basename(sys.argv[0])
    try:
        main(argv)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except USER_ERRORS as e:
        if os.environ.get("ISCC_GYM_TRACEBACK"):
            raise
        msg = str(e) if not isinstance(e, KeyError) else str(e.args[0] if e.args else e)
        print(f"{prog}: error: {msg or type(e).__name__}", file=sys.stderr)
        return 2
    return 0
