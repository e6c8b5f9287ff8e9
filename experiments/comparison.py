"""A task's comparison written into the docs (``python -m experiments comparison``, ``urban-comparison``,
``field-comparison``): ``python -m eval`` (the engine: every policy of the task's comparison on the same held-out
missions) with its flags, then the Markdown table and the share of the gap closed into ``docs/results.md``'s section
of the task (:attr:`iscc_gym.tasks.Task.results_section`) and, for the task whose table is the README's
(:attr:`~iscc_gym.tasks.Task.readme`), into the README too. ``python -m eval`` itself writes only where told
(``--json``, ``--plots``).

Example::

    python -m experiments comparison                       # the published table of the paper task
    python -m experiments.comparison --env iscc_gym/ISCC-Urban-v0 --episodes 2 --max-steps 50   # a smoke run
"""

from __future__ import annotations

import sys

from iscc_gym.agents.tasks import task_policies
from iscc_gym.commands.docs import README_PATH, RESULTS_PATH, docs_path, publish, write_docs_section
from iscc_gym.commands.options import Parser, check_writable_file, docs_command, env_scenario, run_console

from iscc_gym import ENV_ID

PROG = "python -m experiments.comparison"


def build_parser(prog: str = PROG) -> Parser:
    ap = Parser(prog=prog, description=__doc__.split("\n\n")[0],
                epilog="Every other flag is python -m eval's (python -m eval --help).")
    ap.add_argument("--env", default=ENV_ID, help=f"the task (default: {ENV_ID})")
    ap.add_argument("--scenario", default=None, help="the task's own preset only (the docs sections are of it)")
    ap.add_argument("--write-docs", action="store_true",
                    help="write the table into docs/results.md (and the README's for the paper task)")
    return ap


def main(argv: list[str] | None = None, prog: str = PROG) -> dict:
    from iscc_gym.eval.__main__ import main as eval_main
    from iscc_gym.eval.report import markdown_table, oracle_share_sentence

    argv = list(sys.argv[1:] if argv is None else argv)
    args, rest = build_parser(prog).parse_known_args(argv)
    task = task_policies(args.env)
    if task.fleet:
        raise ValueError(f"--env {args.env}: the fleet task's tables are python -m experiments multi and multi-scan")
    scenario = env_scenario(args.env, args.scenario, args.write_docs)
    if args.write_docs:
        bad = [f for f in ("--variants", "--plots", "--train-steps") if any(a.split("=")[0] == f for a in rest)]
        if bad:
            raise ValueError(f"{bad[0]} with --write-docs: the docs table is the task's own missions and agents "
                             "(the shifted-mission study writes its own: python -m experiments urban-shift)")
        for rel in (RESULTS_PATH, README_PATH):
            check_writable_file(docs_path(rel), "--write-docs")
    res = eval_main(["--env", args.env, "--scenario", scenario, *rest], prog=prog)
    if args.write_docs:
        shares = res.get("oracle_shares", {})
        text = markdown_table(res, docs_command(prog, argv)) + "".join(
            f"\n\n{oracle_share_sentence(sh)}" for sh in shares.values())
        if task.readme:
            publish(task.results_section, task.results_title, text)
        else:
            write_docs_section(RESULTS_PATH, task.results_section, f"## {task.results_title}\n\n" + text)
    return res


if __name__ == "__main__":
    sys.exit(run_console(main, None, PROG))
