"""Scripted policies at a rate-outage target (issue 15 item 2): knobs and the bisection."""

import numpy as np
import pytest
from iscc_gym.eval import outage as O

from iscc_gym import SCENARIOS

S = SCENARIOS["paper"]
SEEDS = [500000, 500001]


@pytest.mark.parametrize("family", sorted(O.FAMILIES))
def test_every_family_builds_a_policy_at_both_ends_of_its_knob(family):
    import gymnasium as gym

    import iscc_gym

    env = gym.make(iscc_gym.ENV_ID)
    obs, _ = env.reset(seed=0)
    _, lo, hi, _ = O.FAMILIES[family]
    for knob in (lo, hi):
        action, _ = O.build(family, knob, S).predict(obs[None], deterministic=True)
        assert action.shape == (1, 3) and np.all(np.isfinite(action))


def test_the_knob_trades_outage_and_the_search_meets_the_target():
    lo_end = O.outage("margin", 0.5, SEEDS, S, max_steps=200)
    hi_end = O.outage("margin", 30.0, SEEDS, S, max_steps=200)
    assert hi_end["rate_outage"] < lo_end["rate_outage"]  # a larger data multiple, less outage
    target = 0.5 * (lo_end["rate_outage"] + hi_end["rate_outage"])
    res = O.find_knob("margin", target, SEEDS, S, max_steps=200, iterations=4)
    assert res["met"] and res["best"]["rate_outage"] <= target
    assert any(r["rate_outage"] > target for r in res["tried"])  # the bisection crossed the target
    assert 0.5 <= res["best"]["knob"] <= 30.0


def test_an_unreachable_target_is_reported_not_met_and_bad_targets_refused():
    res = O.find_knob("margin", 0.0, SEEDS, S, max_steps=50, iterations=1)
    assert not res["met"]
    with pytest.raises(ValueError, match="fraction"):
        O.find_knob("margin", 1.5, SEEDS, S)


def test_evaluation_seeds_are_refused(capsys):
    assert O.console(["margin", "--seed-start", "10000", "--episodes", "2"]) == 2
    assert "seed" in capsys.readouterr().err


def test_outage_command_reports_each_bisection_step_on_stderr(capsys):
    """Issue 23 item 5: a line per evaluated knob value, also without a terminal; --quiet silences them."""
    from iscc_gym.eval import outage as cmd

    argv = ["margin", "--episodes", "1", "--max-steps", "5", "--iterations", "2", "--target", "1"]
    cmd.main(argv)
    err = capsys.readouterr().err
    assert err.count("[python -m eval.outage] ") == 4 and "0/3 stage (knob" in err and "done: 3/3 stage" in err
    cmd.main([*argv, "--quiet"])
    assert capsys.readouterr().err == ""
