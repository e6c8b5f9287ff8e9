"""``python -m eval.outage``: scripted policies at a rate-outage target (issue 15 item 2).

Each scripted family has one knob that trades rate outage (the fraction of slots whose data rate is
below ``rate_min_bps``) for tracking error:

* ``sca``: static SCA designed for ``knob`` x R_min (a rate design margin; the env still charges
  R_min). A larger knob gives data more and sensing less.
* ``margin``: the tuned margin rule with the data multiple ``m_comm = knob`` (data gets ``knob``
  times the share the GBS predicts it needs; a larger knob gives data more).
* ``myopic``: the myopic optimiser with the price of a rate shortfall ``rate_weight = knob`` (a
  larger price gives data more).

The command finds, on training seeds (500,000 onwards, common random numbers, never an evaluation
seed), the knob value whose mean rate-outage fraction meets a target: bisection on the knob, the
outage being monotone in it. Example::

    python -m eval.outage margin --target 0.10 --episodes 8
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable

import numpy as np
from iscc_gym.commands.options import Parser, Stages, nonneg_int, positive_int, run_console
from iscc_gym.commands.protocol import seed_list
from iscc_gym.eval.evaluate import run_episodes
from iscc_gym.eval.tune import TUNE_SEED_START, check_tuning_seeds

from iscc_gym.scenario import Scenario, make_scenario

__all__ = ["FAMILIES", "build", "outage", "find_knob", "main"]

#: family -> (knob name, low, high, outage falls as the knob rises?)
FAMILIES = {
    "sca": ("rate design margin (x R_min)", 0.5, 4.0, True),
    "margin": ("data multiple m_comm", 0.5, 30.0, True),
    "myopic": ("rate_weight", 0.0, 100.0, True),
}


def build(family: str, knob: float, scenario: Scenario):
    """The policy of ``family`` at knob value ``knob`` (see the module docstring)."""
    if family == "sca":
        from iscc_gym.agents.sca_slot import SCAPolicy

        return SCAPolicy(scenario.replace(rate_min_bps=scenario.rate_min_bps * float(knob)))
    if family == "margin":
        from iscc_gym.agents.margin import MarginPolicy
        from iscc_gym.agents.tuned_records import load_tuned

        p = load_tuned("margin")["params"]
        return MarginPolicy(p["m_ctrl"], float(knob), sensing_floor=p["sensing_floor"])
    if family == "myopic":
        from iscc_gym.agents.myopic import MyopicPolicy

        return MyopicPolicy(scenario, rate_weight=float(knob))
    raise ValueError(f"family = {family!r}; use one of {sorted(FAMILIES)}")


def outage(family: str, knob: float, seeds, scenario: Scenario, max_steps: int | None = None) -> dict:
    """Mean rate-outage fraction and tracking error of ``family`` at ``knob`` on ``seeds``."""
    ep = run_episodes(build(family, knob, scenario), seeds, scenario, max_steps=max_steps)["episodes"]
    return {"knob": float(knob), "rate_outage": float(np.mean(ep["rate_violation"])),
            "tracking_error_m": float(np.mean(ep["tracking_error_m"])),
            "rms_error_m": float(np.sqrt(np.mean(ep["mse_m2"]))), "lost": int(np.sum(ep["terminated"]))}


def find_knob(family: str, target: float, seeds, scenario: Scenario, max_steps: int | None = None,
              iterations: int = 8, on_step: Callable[[str], None] | None = None) -> dict:
    """The knob value of ``family`` whose rate outage on ``seeds`` is at most ``target``, closest to it
    (bisection between the family's bounds, geometric for a positive knob); ``met`` is False if even the
    bound cannot reach it. ``on_step(label)`` is called before each evaluation (progress).
    """
    if not 0.0 <= target <= 1.0:
        raise ValueError(f"target = {target!r}: a rate-outage target is a fraction in [0, 1]")
    _, lo, hi, falls = FAMILIES[family]
    # the knob end with the smallest outage
    safe, risky = (hi, lo) if falls else (lo, hi)
    step = on_step or (lambda label: None)
    step(f"knob {safe:.4g} (the safe bound)")
    tried = [outage(family, safe, seeds, scenario, max_steps)]
    if tried[-1]["rate_outage"] > target:
        return {"family": family, "target": target, "met": False, "best": tried[-1], "tried": tried}
    best = tried[-1]
    for _ in range(iterations):
        # geometric where the knob is a positive multiple, so a wide range is searched evenly
        mid = math.sqrt(safe * risky) if min(safe, risky) > 0 else 0.5 * (safe + risky)
        step(f"knob {mid:.4g}, last outage {tried[-1]['rate_outage']:.3f}")
        r = outage(family, mid, seeds, scenario, max_steps)
        tried.append(r)
        if r["rate_outage"] <= target:
            safe, best = mid, r
        else:
            risky = mid
    return {"family": family, "target": target, "met": True, "best": best, "tried": tried}


def build_parser(prog: str = "python -m eval.outage") -> Parser:
    ap = Parser(prog=prog, description=__doc__.split("\n\n")[0])
    ap.add_argument("family", choices=sorted(FAMILIES), help="scripted policy family")
    ap.add_argument("--target", type=float, default=0.1, help="rate-outage target, a fraction (default: 0.1)")
    ap.add_argument("--episodes", type=positive_int, default=8, help="training missions (default: 8)")
    ap.add_argument("--seed-start", type=nonneg_int, default=TUNE_SEED_START,
                    help=f"first training seed (default: {TUNE_SEED_START})")
    ap.add_argument("--max-steps", type=positive_int, default=None, help="slots per mission (default: all)")
    ap.add_argument("--iterations", type=positive_int, default=8, help="bisection steps (default: 8)")
    ap.add_argument("--scenario", default="paper", help="scenario preset (default: paper)")
    ap.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    ap.add_argument("--rate-min-mbps", type=float, default=None,
                    help="the rate requirement R_min in Mbps (default: the scenario's; python -m experiments.pareto "
                         "uses 12)")
    return ap


def main(argv: list[str] | None = None, prog: str = "python -m eval.outage") -> dict:
    args = build_parser(prog).parse_args(argv)
    if not (math.isfinite(args.target) and 0.0 <= args.target <= 1.0):
        raise ValueError(f"--target {args.target}: use a fraction in [0, 1], e.g. --target 0.05")
    seeds = seed_list(args.seed_start, args.episodes)
    check_tuning_seeds(seeds)
    over = {} if args.rate_min_mbps is None else {"rate_min_bps": args.rate_min_mbps * 1e6}
    with Stages(args.iterations + 1, prog, enabled=not args.quiet) as st:
        res = find_knob(args.family, args.target, seeds, make_scenario(args.scenario, **over), args.max_steps,
                        args.iterations, on_step=st.next)
    b = res["best"]
    name = FAMILIES[args.family][0]
    print(f"{args.family}: {name} = {b['knob']:.4g} -> rate outage {b['rate_outage']:.3f} "
          f"(target {args.target}{'' if res['met'] else ', NOT met'}), tracking error {b['tracking_error_m']:.4f} m "
          f"(RMS {b['rms_error_m']:.4f}), {b['lost']} of {len(seeds)} missions lost")
    return res


def console(argv: list[str] | None = None, prog: str = "python -m eval.outage") -> int:
    return run_console(main, argv, prog)


if __name__ == "__main__":
    sys.exit(console())
