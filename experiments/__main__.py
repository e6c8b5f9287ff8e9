"""``python -m experiments``: the studies behind this repository's docs, one table (:mod:`experiments.studies`).

Usage::

    python -m experiments                        # list the studies
    python -m experiments NAME [FLAGS ...]       # run one as published; FLAGS: more of its module's flags
    python -m experiments index                  # write the list "docs section -> command" (experiments/README.md)
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

from iscc_gym.commands import options
from iscc_gym.commands.cli import run
from iscc_gym.commands.docs import write_section

from experiments.studies import STUDIES, get_study, section_index

PROG = "python -m experiments"
#: The list of every generated section and its command, in this file.
INDEX = Path(__file__).with_name("README.md")


def table() -> str:
    """The studies as aligned text (``python -m experiments``)."""
    width = max(len(n) for n in STUDIES)
    lines = [f"{'study':<{width}}  kind        what (sections written)"]
    for s in STUDIES.values():
        sections = ", ".join(w.split("#")[1] for w in s.sections)
        lines.append(f"{s.name:<{width}}  {'comparison' if s.comparison else 'script':<10}  {s.what} ({sections})"
                     + (f"; first: {s.needs}" if s.needs else ""))
    lines.append(f"\n{PROG} NAME runs one as published (its module and arguments: {PROG} NAME --help); {PROG} index "
                 f"writes the list of sections and commands into {INDEX.parent.name}/{INDEX.name}.")
    return "\n".join(lines)


def run_study(name: str, extra: list[str] | None = None):
    """Run study ``name`` (:data:`~experiments.studies.STUDIES`) with its published arguments and ``extra`` ones;
    the docs it writes quote ``python -m experiments NAME`` (and ``extra``). Returns its module's result.
    """
    study = get_study(name)
    prog = f"{PROG} {name}"
    argv = [*study.argv, *(extra or [])]
    module = importlib.import_module(study.module)
    options.STUDY.append((prog, list(study.argv)))
    try:
        if "--help" in (extra or []) or "-h" in (extra or []):
            print(f"{prog}: {study.what}; runs {study.module} with: {' '.join(study.argv) or '(no arguments)'}\n")
        return module.main(argv, prog=prog)
    finally:
        options.STUDY.pop()


def main(argv: list[str] | None = None) -> object:
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help", "list"):
        print(table())
        return STUDIES
    if args[0] == "index":
        write_section(INDEX, "studies", section_index())
        print(f"wrote {INDEX}")
        return INDEX
    return run_study(args[0], args[1:])


if __name__ == "__main__":
    sys.exit(run(main, None, PROG))
