"""``python -m experiments.urban_figure``: one urban mission, ``myopic`` beside ``mpc``: the path and its blocked
stretches, the queue, and each policy's split over time.

Plays both policies on the same held-out mission (common random numbers) with the single env and writes one PNG:
the plan view of the reference coloured by the realised line of sight (and the map's LoS probability beside
it), the backlog of each policy over time with the blocked slots shaded, and each policy's split over time.

Example::

    python -m experiments.urban_figure --write-docs        # docs/figures/urban_mission.png
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from iscc_gym.agents.shipped import URBAN_AGENT
from iscc_gym.commands.docs import RESULTS_PATH, docs_path, write_section
from iscc_gym.commands.options import PICKLE_WARNING, Parser, check_writable_file, docs_command, nonneg_int, run_console
from iscc_gym.commands.protocol import URBAN_SEED_START, seed_list
from iscc_gym.eval.evaluate import run_episodes
from iscc_gym.eval.figures import new_figure, save_figure
from iscc_gym.eval.policies import build_policy, resolve_specs

from experiments.urban_task import mission_stats
from iscc_gym import URBAN_ENV_ID
from iscc_gym.scenario import make_scenario
from iscc_gym.sim.mission import MC

__all__ = ["play_mission", "mission_policies", "draw", "main", "pick_mission", "FIGURE", "BLOCKED_SHARE"]

#: The figure's file name under docs/figures (``--write-docs``).
FIGURE = "urban_mission.png"
#: The default mission is the first held-out one with at least this share of its flight blocked.
BLOCKED_SHARE = 0.1


def pick_mission(scenario="urban", share: float = BLOCKED_SHARE, tries: int = 200) -> int:
    """The first held-out mission from :data:`iscc_gym.commands.protocol.URBAN_SEED_START` whose flight is blocked
    for at
    least ``share`` of it (a mission that shows what the task is about).
    """
    s = make_scenario(scenario)
    for seed in seed_list(URBAN_SEED_START, tries):
        if mission_stats(s, seed)["los_share"] <= 1.0 - share:
            return seed
    raise ValueError(f"no mission of the first {tries} from {URBAN_SEED_START} is {share:.0%} blocked")


#: What an agent of another env's observations is told here (these commands have no ``--env``).
URBAN_FIX = f"these commands play {URBAN_ENV_ID} only: give --policies an agent trained on it"


def mission_policies(specs: str) -> dict:
    """``{name: policy}`` of a ``--policies`` value (``ppo``: the shipped urban agent), every one built, so checked,
    before any mission is played.
    """
    return dict(build_policy(item, "urban", fix=URBAN_FIX) for item in resolve_specs(specs, URBAN_AGENT))


#: The info keys a mission's figure traces slot by slot (and the slot's reward).
TRACED = ("alpha", "backlog_bits", "bits_dropped", "tracking_error_m", "reward")


def play_mission(policy, seed: int, scenario="urban") -> dict:
    """One mission of ``policy`` (a built one, or a spec: scripted, ``ppo`` for the shipped urban agent or
    ``NAME=PATH``): per slot the split, the backlog, the dropped bits, the tracking error and the reward
    (:data:`TRACED`), and the mission's rows (reference and channel): one mission of
    :func:`~iscc_gym.eval.evaluate.run_episodes`, the one rollout loop (a recurrent agent keeps its memory).
    """
    s = make_scenario(scenario)
    if isinstance(policy, str):
        _, policy = build_policy(resolve_specs(policy, URBAN_AGENT)[0], s, fix=URBAN_FIX)
    res = run_episodes(policy, [int(seed)], s, record=1, trace_info=TRACED)
    out = {k: res["traces"][k][:, 0] for k in TRACED}
    out["slot_reward"] = out.pop("reward")
    return {**out, "rows": res["missions"][0], "dt_s": s.dt_s, "reward": float(res["episodes"]["reward"][0])}


def draw(runs: dict, path: str | Path) -> Path:
    """The figure of :func:`play_mission`'s runs (``{name: run}``, the same mission) at ``path``."""
    first = next(iter(runs.values()))
    rows, dt = first["rows"], first["dt_s"]
    los = rows[:, MC["los"]] == 1.0
    fig = new_figure((11, 2.2 * (2 + len(runs))), dpi=90)
    grid = fig.add_gridspec(2 + len(runs), 2, width_ratios=(1, 2.2))
    ax = fig.add_subplot(grid[:, 0])
    ax.plot(rows[:, 0], rows[:, 1], color="0.8", lw=3, zorder=1)
    sc = ax.scatter(rows[:, 0], rows[:, 1], c=rows[:, MC["p_los_map"]], s=4, cmap="viridis", vmin=0, vmax=1,
                    zorder=2, label="map's LoS probability")
    ax.scatter(rows[~los, 0], rows[~los, 1], s=14, facecolors="none", edgecolors="tab:red", lw=0.6, zorder=3,
               label="blocked (truth)")
    ax.plot([0], [0], "k^", ms=8, label="GBS")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(fontsize=7, loc="best")
    fig.colorbar(sc, ax=ax, fraction=0.04, label="map's LoS probability")
    t_all = np.arange(len(rows)) * dt

    def shade(a):
        a.fill_between(t_all, 0, 1, where=~los, color="tab:red", alpha=0.12, transform=a.get_xaxis_transform(),
                       lw=0)

    ax_q = fig.add_subplot(grid[0, 1])
    ax_e = fig.add_subplot(grid[1, 1], sharex=ax_q)
    for i, (name, run) in enumerate(runs.items()):
        t = np.arange(len(run["backlog_bits"])) * dt
        style = {"ls": ("-", "--", ":")[i % 3], "alpha": 0.85}  # where two policies coincide, both stay visible
        ax_q.plot(t, run["backlog_bits"] * 1e-6, lw=0.9, **style,
                  label=f"{name} (dropped {run['bits_dropped'].sum() * 1e-6:.1f} Mbit)")
        ax_e.plot(t, run["tracking_error_m"], lw=0.8, **style, label=name)
    for a, label in ((ax_q, "backlog (Mbit)"), (ax_e, "tracking error (m)")):
        shade(a)
        a.set_ylabel(label)
        a.legend(fontsize=7, loc="upper right")
    ax_e.set_yscale("log")
    for k, (name, run) in enumerate(runs.items()):
        a = fig.add_subplot(grid[2 + k, 1], sharex=ax_q)
        t = np.arange(len(run["alpha"])) * dt
        a.stackplot(t, run["alpha"].T, labels=("sensing", "control", "data"), alpha=0.85)
        shade(a)
        a.set_ylim(0, 1)
        a.set_ylabel(f"{name}\nsplit")
        a.legend(fontsize=7, loc="upper right", ncol=3)
    fig.axes[-1].set_xlabel("time (s); red: blocked line of sight")
    fig.tight_layout()
    return save_figure(fig, path)


def build_parser(prog: str = "python -m experiments.urban_figure") -> Parser:
    ap = Parser(prog=prog, description=__doc__.split("\n")[0], epilog=PICKLE_WARNING)
    ap.add_argument("--seed", type=nonneg_int, default=None, metavar="SEED",
                    help=f"the held-out mission (default: the first from {URBAN_SEED_START} with at least "
                         f"{BLOCKED_SHARE * 100:.0f}%% of the flight blocked)")  # %%: argparse formats help with %
    ap.add_argument("--policies", default="myopic,mpc", metavar="LIST",
                    help="policies to draw, as in python -m eval (ppo: the shipped urban agent; default: myopic,mpc)")
    ap.add_argument("--out", default="runs/urban_mission.png", metavar="PATH",
                    help="the PNG (default: runs/urban_mission.png)")
    ap.add_argument("--write-docs", action="store_true", help=f"write docs/figures/{FIGURE} instead of --out")
    return ap


def main(argv: list[str] | None = None, prog: str = "python -m experiments.urban_figure") -> Path:
    args = build_parser(prog).parse_args(argv)
    if args.write_docs:
        out = docs_path(Path("docs") / "figures" / FIGURE)
    else:
        out = Path(args.out)
    check_writable_file(out, "--out")
    policies = mission_policies(args.policies)
    seed = pick_mission() if args.seed is None else args.seed
    runs = {name: play_mission(policy, seed) for name, policy in policies.items()}
    print(f"mission {seed}")
    path = draw(runs, out)
    print(f"wrote {path}")
    if args.write_docs:
        lines = [f"Generated by `{docs_command(prog, argv)}`: held-out mission {seed} (the first "
                 f"from {URBAN_SEED_START} with at least {BLOCKED_SHARE:.0%} of its flight blocked), each policy on "
                 "the same draws. Left: the path, coloured by the map's LoS probability, the blocked slots (truth) "
                 "circled in red; right: each policy's backlog, tracking error and split over time, blocked slots "
                 "shaded.", "",
                 f"![one urban mission](figures/{FIGURE})", "",
                 "| policy | episode reward | dropped (Mbit) | mean tracking error (m) |", "|---|--:|--:|--:|"]
        for spec, run in runs.items():
            lines.append(f"| {spec} | {run['reward']:.1f} | {run['bits_dropped'].sum() * 1e-6:.1f} | "
                         f"{run['tracking_error_m'].mean():.3f} |")
        write_section(docs_path(RESULTS_PATH), "urban-figure", "## One urban mission\n\n" + "\n".join(lines))
        print(f"wrote {docs_path(RESULTS_PATH)}")
    return path


if __name__ == "__main__":
    sys.exit(run_console(main, None, "python -m experiments.urban_figure"))
