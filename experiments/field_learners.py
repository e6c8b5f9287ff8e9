"""``python -m experiments field-learners``: the field task's learners that use the simulator's knowledge, vs ``bayes``.

``python -m eval`` on ``iscc_gym/ISCC-Field-v0`` (the engine: every policy on the same held-out missions) with the
learners of issue 45 beside the ladder, every difference paired against ``bayes`` (``--focus bayes``), and the share
of the gap ``aware`` - ``myopic`` each closes. The learners are the runs of ``python -m train`` named in
:data:`LEARNERS` (train them first: :data:`NEEDS`).

Example::

    python -m experiments field-learners                                    # the published table (20 missions)
    python -m experiments.field_learners --episodes 2 --max-steps 100       # a smoke run
"""

from __future__ import annotations

import sys

from iscc_gym.commands.docs import RESULTS_PATH, docs_path, write_docs_section
from iscc_gym.commands.options import Parser, check_writable_file, docs_command, run_console

from iscc_gym.tasks import FIELD_ENV_ID

__all__ = ["main", "LEARNERS", "NEEDS", "SECTION"]

PROG = "python -m experiments.field_learners"
SECTION = "field-learners"
#: The learners compared (``--policies`` items) and the command that trains each, beside the shipped agent (``ppo``:
#: the field entry of train/hyperparams.yml, a residual on ``bayes`` with the critic shown the world and the expected
#: reward; ``python -m experiments field-agent``).
_TRAIN = "python -m train --env {env} "
LEARNERS = {
    "ppo-adaptive=runs/field_ppo_adaptive": _TRAIN + "--residual adaptive --critic own --reward sampled "
                                                     "--out runs/field_ppo_adaptive",
    "ppo-bayes=runs/field_res_bayes": _TRAIN + "--critic own --reward sampled --out runs/field_res_bayes",
    "ppo-cw=runs/field_cw_bayes": _TRAIN + "--reward sampled --out runs/field_cw_bayes",
    "estimator:runs/field_est": _TRAIN + "--learner estimator --n-envs 128 --total-timesteps 640000 "
                                         "--out runs/field_est",
    "student:runs/field_dagger": _TRAIN + "--learner dagger --out runs/field_dagger",
}
#: What must exist first (the studies table's ``needs``).
NEEDS = "; ".join(["python -m experiments field-agent", *(cmd.format(env=FIELD_ENV_ID) for cmd in LEARNERS.values())])
#: The ladder beside them.
LADDER = ("ppo", "bayes", "adaptive", "myopic", "aware")


def build_parser(prog: str = PROG) -> Parser:
    ap = Parser(prog=prog, description=__doc__.split("\n\n")[0],
                epilog="Every other flag is python -m eval's (python -m eval --help).")
    ap.add_argument("--write-docs", action="store_true",
                    help=f"write the table into docs/results.md (section {SECTION})")
    return ap


def main(argv: list[str] | None = None, prog: str = PROG) -> dict:
    from iscc_gym.eval.__main__ import main as eval_main
    from iscc_gym.eval.report import markdown_table, oracle_share, oracle_share_sentence

    argv = list(sys.argv[1:] if argv is None else argv)
    args, rest = build_parser(prog).parse_known_args(argv)
    if args.write_docs:
        check_writable_file(docs_path(RESULTS_PATH), "--write-docs")
    policies = ",".join([*LEARNERS, *LADDER])
    res = eval_main(["--env", FIELD_ENV_ID, "--policies", policies, "--focus", "bayes", *rest], prog=prog)
    names = [item.split("=", 1)[0] for item in LEARNERS] + ["ppo", "bayes", "adaptive"]
    shares = {n: oracle_share(res, agent=n, oracle="aware", base="myopic") for n in names}
    sentences = [oracle_share_sentence(sh) for sh in shares.values() if sh is not None]
    for line in sentences:
        print(line)
    if args.write_docs:
        text = markdown_table(res, docs_command(prog, argv)) + "".join(f"\n\n{s}" for s in sentences)
        write_docs_section(RESULTS_PATH, SECTION, "## The field task's learners against bayes (issue 45)\n\n" + text)
    res["oracle_shares"] = {n: sh for n, sh in shares.items() if sh is not None}
    return res


if __name__ == "__main__":
    sys.exit(run_console(main, None, PROG))
