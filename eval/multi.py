"""``python -m eval.multi``: the multi-drone env's baselines and trained agent on held-out missions.

Every policy plays the same held-out missions of ``iscc_gym/ISCC-Multi-v0`` with K drones (common random
numbers; seeds from :data:`SEED_START`): the scripted baselines of :mod:`iscc_gym.agents.multi`
(``equal-sca``: 1/K of the band per drone with per-slot Algorithm 1 inside; ``joint-sca``: Algorithm 1's
problem over all drones; ``margin``: the tuned rule per drone, renormalised; ``margin-starved``:
``margin`` with a tenth of its sensing, the rest to data) and the trained agent of
``agents/trained/multi/k<K>`` (``python -m experiments.multi_agents``) or ``--agent PATH``. The table gives mean and
95 % CI per policy and paired differences against ``joint-sca`` and of the agent against every other
policy. ``--k-scan 2,4,8`` repeats the comparison per K, with a summary of every policy's reward,
tracking error and PEB against K, and reports how the agent's advantage changes with it. ``python -m
eval --env iscc_gym/ISCC-Multi-v0 ...`` runs this command.

Example::

    python -m eval.multi --n-drones 4 --episodes 20
    python -m eval.multi --k-scan 2,4,8 --episodes 20          # python -m experiments multi-scan: into the docs
"""

from __future__ import annotations

import sys
from pathlib import Path

from iscc_gym.agents.sb3_policy import LAGRANGE_FILE
from iscc_gym.agents.tasks import TASK_POLICIES
from iscc_gym.commands.options import (
    PICKLE_WARNING,
    Parser,
    nonneg_int,
    positive_int,
    progress_bar,
    run_console,
    show_progress,
)
from iscc_gym.commands.protocol import MULTI_SEED_START as SEED_START
from iscc_gym.commands.protocol import held_out_seeds
from iscc_gym.eval.engine import compare as engine_compare
from iscc_gym.eval.evaluate import horizon_slots
from iscc_gym.eval.report import ci_bounds, ci_cell, format_table, markdown_table

from iscc_gym import MULTI_ENV_ID
from iscc_gym.sim.fleet import N_DRONES, check_n_drones

__all__ = ["SEED_START", "DEFAULT_POLICIES", "agent_dir", "compare", "scan_table", "main"]

#: First held-out mission of this command (inside the evaluation range, apart from the others).
#: The scripted baselines played by default (``margin-starved``: ``margin`` with a tenth of its sensing,
#: the rest to data, the policy that buys rate with the radar; issue 23).
DEFAULT_POLICIES = TASK_POLICIES[MULTI_ENV_ID].policies
#: The columns of the K-scan's summary (:func:`scan_table`): metric, title, format.
#: The median PEB stands beside the mean: a few slots of a lost radar lift a mission's mean PEB (issue 34).
SCAN_COLUMNS = (("reward", "episode reward ↑", "{:.1f}"), ("tracking_error_m", "tracking error (m) ↓", "{:.4f}"),
                ("peb_m", "PEB (m) ↓", "{:.4f}"), ("peb_median_m", "median PEB (m) ↓", "{:.4f}"),
                ("alpha_sen", "sensing share", "{:.3f}"))
#: The reference of the paired differences.
REFERENCE = TASK_POLICIES[MULTI_ENV_ID].reference


def agent_dir(n_drones: int) -> Path:
    """Where ``python -m experiments.multi_agents`` ships the agent for ``n_drones`` drones."""
    return TASK_POLICIES[MULTI_ENV_ID].shipped_agent(n_drones)


def agent_label(path) -> str:
    """How an agent is reported: ``ppo-lag`` for a constrained run (its ``lagrange.yml``), else ``ppo``."""
    return "ppo-lag" if (Path(path) / LAGRANGE_FILE).is_file() else "ppo"


def compare(n_drones: int, seeds, policies: str = DEFAULT_POLICIES, agent: str | None = None, scenario="paper",
            max_steps: int | None = None, progress=None) -> dict:
    """The engine's comparison of the fleet task (:func:`iscc_gym.eval.engine.compare`) for ``n_drones`` drones
    (``agent``: a run directory, played first as :func:`agent_label`, the focus; the reference ``joint-sca`` where
    it is played). ``progress(n)``: called with the slots played.
    """
    label = agent_label(agent) if agent is not None else None
    items = ([f"{label}={agent}"] if agent is not None else []) + [p.strip() for p in policies.split(",") if p.strip()]
    return engine_compare(MULTI_ENV_ID, items, seeds, scenario=scenario, focus=label, max_steps=max_steps,
                          progress=progress, n_drones=n_drones)[scenario]


def _advantage_cells(res: dict) -> str:
    fp = res.get("focus_paired") or {}
    cells = []
    for pair, d in fp.items():
        other = pair.split("_vs_", 1)[1]
        cells.append(f"vs {other}: error {d['tracking_error_m_diff_mean']:+.4f} m "
                     f"{ci_bounds(d['tracking_error_m_diff_ci95'], '{:+.4f}')}, reward "
                     f"{d['reward_diff_mean']:+.1f} {ci_bounds(d['reward_diff_ci95'], '{:+.1f}')}")
    return "; ".join(cells)


def _render(titles: list[str], rows: list[list[str]], markdown: bool, align: str) -> str:
    """A table as markdown (``align``: ``l``/``r`` per column) or as aligned plain text for a terminal."""
    if markdown:
        rule = "|" + "|".join("---" if a == "l" else "--:" for a in align) + "|"
        return "\n".join(["| " + " | ".join(titles) + " |", rule] + ["| " + " | ".join(r) + " |" for r in rows])
    widths = [max(len(x) for x in col) for col in zip(titles, *rows, strict=True)]

    def line(cells):
        return "  ".join(c.ljust(w) if a == "l" else c.rjust(w)
                         for c, w, a in zip(cells, widths, align, strict=True)).rstrip()

    head = line(titles)
    return "\n".join([head, "-" * len(head)] + [line(r) for r in rows])


def scan_table(out: dict, markdown: bool = True) -> str:
    """The K-scan's summary: every policy's episode reward, tracking error, mean and median PEB and mean
    sensing share per K (``out``: the comparison of each K, :func:`compare`), mean ±half-width of the 95 % CI;
    markdown for the docs, else aligned text for a terminal.
    """
    rows = [[str(k), name] + [ci_cell(p[f"{m}_mean"], p[f"{m}_ci95"], fmt) for m, _, fmt in SCAN_COLUMNS]
            for k, res in out.items() for name, p in res["policies"].items()]
    titles = ["K", "policy"] + [title for _, title, _ in SCAN_COLUMNS]
    return _render(titles, rows, markdown, "rl" + "r" * len(SCAN_COLUMNS))


def build_parser(prog: str = "python -m eval.multi") -> Parser:
    ap = Parser(prog=prog, description=__doc__.split("\n\n")[0], epilog=PICKLE_WARNING)
    ap.add_argument("--n-drones", type=positive_int, default=N_DRONES, help=f"drones per env (default: {N_DRONES})")
    ap.add_argument("--k-scan", default=None, metavar="K1,K2,...",
                    help="repeat the comparison for these numbers of drones (each with its shipped agent)")
    ap.add_argument("--episodes", type=positive_int, default=20, help="held-out missions (default: 20)")
    ap.add_argument("--seed", type=nonneg_int, default=0, help="run seed: missions from 1,400,000 + 1000 x seed")
    ap.add_argument("--policies", default=DEFAULT_POLICIES, help=f"scripted baselines (default: {DEFAULT_POLICIES})")
    ap.add_argument("--agent", default=None, metavar="PATH",
                    help="a trained run directory (default: agents/trained/multi/k<K> if it exists; none: no agent)")
    ap.add_argument("--scenario", default="paper", help="scenario preset (default: paper)")
    ap.add_argument("--max-steps", type=positive_int, default=None, help="slots per mission (default: all)")
    ap.add_argument("--quiet", action="store_true", help="no progress (bar on a terminal, else lines on stderr)")
    return ap


def main(argv: list[str] | None = None, prog: str = "python -m eval.multi", command: str | None = None) -> dict:
    """The comparison (one K, or a scan of K); returns the results and their Markdown sections (``sections``, under
    ``section``: its name and title; ``python -m experiments multi`` writes them into the docs), each quoting
    ``command`` (default: this command line).
    """
    from iscc_gym.agents.multi import MULTI_POLICY_SPECS
    from iscc_gym.commands.options import docs_command

    args = build_parser(prog).parse_args(argv)
    try:
        ks = [int(x) for x in args.k_scan.split(",") if x.strip()] if args.k_scan else [args.n_drones]
    except ValueError:
        raise ValueError(f"--k-scan {args.k_scan!r}: use integers, e.g. --k-scan 2,4,8") from None
    for k in ks:
        check_n_drones(k)
    bad = [p for p in args.policies.split(",") if p.strip() and p.strip() not in MULTI_POLICY_SPECS]
    if bad:
        raise ValueError(f"--policies {args.policies!r}: unknown {bad}; use some of {', '.join(MULTI_POLICY_SPECS)}")
    agents = {}
    for k in ks:
        if args.agent == "none":
            agents[k] = None
        elif args.agent is not None:
            if not (Path(args.agent) / "model.zip").is_file() and not Path(args.agent).is_file():
                raise ValueError(f"--agent {args.agent}: no model.zip there; give a run directory of python -m train "
                                 "(or --agent none)")
            agents[k] = args.agent
        else:
            agents[k] = str(agent_dir(k)) if (agent_dir(k) / "model.zip").is_file() else None
    seeds = held_out_seeds(SEED_START, args.episodes, args.seed)
    command = command or docs_command(prog, argv)
    out, sections = {}, []
    n_baselines = len([p for p in args.policies.split(",") if p.strip()])
    n_runs = sum(n_baselines + (1 if agents[k] else 0) for k in ks)
    # a run plays its missions side by side: its progress counts the slots of one mission (as python -m eval's)
    bar = progress_bar(n_runs * horizon_slots(args.scenario, args.max_steps), prog, unit="slot",
                       enabled=show_progress(args.quiet), unit_scale=True)
    for k in ks:
        res = compare(k, seeds, args.policies, agents[k], args.scenario, args.max_steps, progress=bar.update)
        out[k] = res
        sections.append(f"### {k} drones\n\n" + markdown_table(res, command))
        print(f"\n{k} drones{' (agent: ' + agents[k] + ')' if agents[k] else ''}:\n{format_table(res)}")
    bar.close()
    if len(ks) > 1:
        print("\nReward, tracking error and PEB against K:\n" + scan_table(out, markdown=False))
        sections.insert(0, "### Reward, tracking error and PEB against K\n\n" + scan_table(out))
    if len(ks) > 1 and any(agents.values()):
        titles = ["K", "trained agent minus each baseline (paired, 95 % CI)"]
        rows = [[str(k), _advantage_cells(out[k])] for k in ks if agents[k]]
        print("\n" + _render(titles, rows, False, "rl"))
        sections.append("### The agent's advantage against K\n\n" + _render(titles, rows, True, "ll"))
    if len(ks) > 1:
        section = ("multi_scan", "Many drones, one base station")
    else:
        label = f"agent `{Path(agents[ks[0]]).as_posix()}`" if agents[ks[0]] else "the baselines"
        section = ("multi", f"Many drones: {label} at K = {ks[0]}")
    return {"results": {str(k): v for k, v in out.items()}, "seeds": [seeds[0], seeds[-1]],
            "agents": {str(k): v for k, v in agents.items()}, "section": section, "sections": sections}


def console(argv: list[str] | None = None, prog: str = "python -m eval.multi") -> int:
    return run_console(main, argv, prog)


if __name__ == "__main__":
    sys.exit(console())

