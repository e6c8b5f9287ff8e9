"""The fleet task's tables written into the docs (``python -m experiments multi``, ``multi-scan``): ``python -m
eval.multi`` with its flags, then its sections into ``docs/results.md`` (``multi``: one K; ``multi_scan``: a scan
of K). ``python -m eval.multi`` itself writes only where told.
"""

from __future__ import annotations

import sys

from iscc_gym.commands.docs import RESULTS_PATH, docs_path, write_docs_section
from iscc_gym.commands.options import Parser, check_writable_file, docs_command, run_console

PROG = "python -m experiments.multi"


def main(argv: list[str] | None = None, prog: str = PROG) -> dict:
    from iscc_gym.eval.multi import main as multi_main

    argv = list(sys.argv[1:] if argv is None else argv)
    ap = Parser(prog=prog, description=__doc__.split("\n\n")[0],
                epilog="Every other flag is python -m eval.multi's (python -m eval.multi --help).")
    ap.add_argument("--write-docs", action="store_true", help="write the tables into docs/results.md")
    args, rest = ap.parse_known_args(argv)
    if args.write_docs:
        check_writable_file(docs_path(RESULTS_PATH), "--write-docs")
    res = multi_main(rest, prog=prog, command=docs_command(prog, argv))
    if args.write_docs:
        name, title = res["section"]
        write_docs_section(RESULTS_PATH, name, f"## {title}\n\n" + "\n\n".join(res["sections"]))
    return res


if __name__ == "__main__":
    sys.exit(run_console(main, None, PROG))
