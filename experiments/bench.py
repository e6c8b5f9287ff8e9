"""The speed table written into the docs (``python -m experiments bench``): ``python -m eval.bench --full`` with its
flags, then its table into ``docs/results.md`` and the README's ``bench`` block. ``python -m eval.bench`` itself
writes only where told (``--json``).
"""

from __future__ import annotations

import sys

from iscc_gym.commands.docs import README_PATH, RESULTS_PATH, docs_path, publish
from iscc_gym.commands.options import Parser, check_writable_file, docs_command, run_console

PROG = "python -m experiments.bench"


def main(argv: list[str] | None = None, prog: str = PROG) -> dict:
    from iscc_gym.eval.bench import main as bench_main
    from iscc_gym.eval.bench_report import markdown

    argv = list(sys.argv[1:] if argv is None else argv)
    ap = Parser(prog=prog, description=__doc__.split("\n\n")[0],
                epilog="Every other flag is python -m eval.bench's (python -m eval.bench --help).")
    ap.add_argument("--write-docs", action="store_true",
                    help="write the table into docs/results.md and the README (needs --full)")
    args, rest = ap.parse_known_args(argv)
    if args.write_docs:
        if "--full" not in rest:
            raise ValueError("--write-docs writes the README's full table: add --full")
        if any(a.split("=")[0] in ("--device", "--compile", "--quick") for a in rest):
            raise ValueError("--write-docs writes the CPU table of a full run: drop --device, --compile and --quick")
        for rel in (RESULTS_PATH, README_PATH):
            check_writable_file(docs_path(rel), "--write-docs")
    res = bench_main(rest, prog=prog)
    if args.write_docs:
        publish("bench", "Speed", markdown(res, docs_command(prog, argv)))
    return res


if __name__ == "__main__":
    sys.exit(run_console(main, None, PROG))
