"""``python -m experiments.probes``: what a learner could find beyond the per-slot optimum.

Is there anything beyond the per-slot optimum for a learner to find?

Plays variants of the scripted baselines that use what a non-myopic (learned) policy could exploit,
each against its base rule on the same tuning missions (common random numbers, seeds from 500,000,
disjoint from every evaluation seed), and reports the paired difference of episode reward:

* burst sensing: the tuned ``margin`` rule, but sensing ``burst`` every k-th slot and ``floor``
  otherwise (the range Fisher information grows as alpha_sen^3, so concentrated sensing gives more
  information on average);
* reacting to the loop's state: the control multiple raised after a lost command (obs 20) or with the
  predicted position error (obs 0-2);
* the myopic optimiser with other weights than the env's (is its model of a slot calibrated?).

Example::

    python -m experiments.probes --episodes 16 --write-docs
"""

from __future__ import annotations

import sys

import numpy as np
from iscc_gym.agents import MarginPolicy, MyopicPolicy
from iscc_gym.agents.base import SplitPolicy
from iscc_gym.agents.margin import margin_split, predicted_needs
from iscc_gym.commands.options import (
    Parser,
    docs_command,
    nonneg_int,
    positive_int,
    progress_bar,
    run_console,
    show_progress,
)
from iscc_gym.commands.protocol import seed_list
from iscc_gym.eval.engine import evaluate
from iscc_gym.eval.report import ci_bounds
from iscc_gym.eval.tune import TUNE_SEED_START, check_tuning_seeds

from iscc_gym.sim.schema import OBS_NAMES

_TIME_LEFT = OBS_NAMES.index("time_left")
_RECEIVED = OBS_NAMES.index("last_packet_received")


class MarginVariant(SplitPolicy):
    """The margin rule with burst sensing and/or a state-dependent control multiple."""

    def __init__(self, base: MarginPolicy, n_slots: int, burst_every: int = 1, burst: float | None = None,
                 floor: float | None = None, lost_boost: float = 1.0, error_gain: float = 0.0):
        self.base, self.n_slots = base, n_slots
        self.every, self.burst = burst_every, base.sensing_floor if burst is None else burst
        self.floor = base.sensing_floor if floor is None else floor
        self.lost_boost, self.error_gain = lost_boost, error_gain

    def split_batch(self, obs, state=None, episode_start=None):
        o = np.asarray(obs, dtype=float)
        slot = np.rint((1.0 - o[:, _TIME_LEFT]) * self.n_slots).astype(int)
        floor = np.where(slot % self.every == 0, self.burst, self.floor)
        m_ctrl = self.base.m_ctrl * np.where(o[:, _RECEIVED] < 0.5, self.lost_boost, 1.0) \
            * (1.0 + self.error_gain * np.abs(o[:, 0:3]).max(axis=1))
        return margin_split(*predicted_needs(o), m_ctrl, self.base.m_comm, floor), state


#: Policies :func:`probes` plays: without and with the myopic probes.
N_PROBES = (15, 20)


def probes(seeds, scenario: str = "paper", myopic: bool = True, progress=None) -> list[dict]:
    """Every probe's mean episode reward and paired difference to its base (see the module).
    ``progress(1)``, if given, is called after each policy played (:data:`N_PROBES`).
    """
    from iscc_gym.scenario import make_scenario

    s = make_scenario(scenario)
    margin = MarginPolicy.tuned()
    tick = progress or (lambda n: None)
    # every probe beside its base, each group one comparison of the engine (common random numbers, paired)
    groups = {"margin": {"margin (tuned)": margin}}
    for k in (2, 3, 5):
        for burst in (0.05, 0.08, 0.12):
            groups["margin"][f"burst sensing: {burst:.0%} every {k} slots, 1% between"] = MarginVariant(
                margin, s.n_slots, k, burst, 0.01)
    for boost in (1.5, 2.0, 3.0):
        groups["margin"][f"control x{boost:g} after a lost command"] = MarginVariant(margin, s.n_slots,
                                                                                     lost_boost=boost)
    for gain in (0.1, 0.3):
        groups["margin"][f"control x(1 + {gain:g} x largest predicted position error, symlog)"] = MarginVariant(
            margin, s.n_slots, error_gain=gain)
    if myopic:
        groups["myopic"] = {"myopic (env weights)": MyopicPolicy(s)}
        for kw in ({"stability_weight": 5.0}, {"stability_weight": 20.0}, {"rate_weight": 0.7},
                   {"rate_weight": 1.5}):
            (key, value), = kw.items()
            groups["myopic"][f"myopic, {key} = {value:g}"] = MyopicPolicy(s, **kw)
    rows = []
    for base_name, policies in groups.items():
        base = next(iter(policies))
        res = evaluate(policies, seeds, s, reference=base, done=lambda name: tick(1))
        for name, p in res["policies"].items():
            pair = res["paired"].get(f"{name}_vs_{base}")
            rows.append({"probe": name, "base": "-" if pair is None else base_name, "reward": p["reward_mean"],
                         "diff": 0.0 if pair is None else pair["reward_diff_mean"],
                         "ci95": [0.0, 0.0] if pair is None else pair["reward_diff_ci95"]})
    return rows


def markdown(rows: list[dict], command: str, seeds) -> str:
    lines = [f"Generated by `{command}`: {len(seeds)} tuning missions (seeds {seeds[0]}-{seeds[-1]}), common "
             "random numbers; episode reward and the paired difference to the base rule, mean [95 % CI].", "",
             "| probe | episode reward | minus base | base |", "|---|---|---|---|"]
    for r in rows:
        diff = "" if r["base"] == "-" else f"{r['diff']:+.1f} {ci_bounds(r['ci95'], '{:+.1f}')}"
        lines.append(f"| {r['probe']} | {r['reward']:.1f} | {diff} | {r['base']} |")
    return "\n".join(lines)


def build_parser(prog: str = "python -m experiments.probes") -> Parser:
    ap = Parser(prog=prog, description=__doc__.split("\n")[0])
    ap.add_argument("--episodes", type=positive_int, default=16, metavar="N",
                    help="tuning missions, >= 2 (default: 16)")
    ap.add_argument("--seed-start", type=nonneg_int, default=TUNE_SEED_START, metavar="SEED",
                    help=f"first tuning seed, outside the evaluation seeds (default: {TUNE_SEED_START})")
    ap.add_argument("--no-myopic", action="store_true", help="skip the myopic probes (the slow ones)")
    ap.add_argument("--write-docs", action="store_true",
                    help="write the table into the project's docs/results.md (section probes; needs a source "
                         "checkout)")
    ap.add_argument("--quiet", action="store_true",
                    help="no progress bar (there is none either when stderr is not a terminal)")
    return ap


def main(argv: list[str] | None = None, prog: str = "python -m experiments.probes") -> list[dict]:
    args = build_parser(prog).parse_args(argv)
    if args.episodes < 2:
        raise ValueError(f"--episodes {args.episodes}: use at least 2 (a confidence interval needs two missions)")
    seeds = check_tuning_seeds(seed_list(args.seed_start, args.episodes))
    if args.write_docs:
        from iscc_gym.commands.docs import RESULTS_PATH, docs_path
        from iscc_gym.commands.options import check_writable_file

        check_writable_file(docs_path(RESULTS_PATH), "--write-docs")
    show = show_progress(args.quiet)
    with progress_bar(N_PROBES[not args.no_myopic], "python -m experiments.probes", unit="policy", enabled=show) as bar:
        rows = probes(seeds, myopic=not args.no_myopic, progress=bar.update if show else None)
    cmd = docs_command("python -m experiments.probes", argv)
    table = markdown(rows, cmd, seeds)
    print(table)
    if args.write_docs:
        from iscc_gym.commands.docs import write_section

        write_section(docs_path(RESULTS_PATH), "probes", "## Non-myopic probes of the scripted rules\n\n" + table)
        print(f"wrote {docs_path(RESULTS_PATH)}")
    return rows


if __name__ == "__main__":
    sys.exit(run_console(main, None, "python -m experiments.probes"))
