"""Pareto fronts (issue 15 item 3): dominance, the per-target winner, and the command on tiny budgets."""

import numpy as np
import pytest
from iscc_gym.eval import pareto as P


def _pt(fam, knob, outage, err, per):
    return {"family": fam, "knob": knob, "rate_outage": outage, "tracking_error_m": err,
            "per_mission_error_m": per}


def test_dominance_and_the_winner_at_a_target():
    pts = [_pt("a", 1, 0.10, 0.40, [0.40, 0.40]), _pt("a", 2, 0.20, 0.39, [0.39, 0.39]),
           _pt("b", 1, 0.15, 0.41, [0.41, 0.41]), _pt("b", 2, 0.05, 0.45, [0.44, 0.46])]
    assert P.non_dominated(pts) == [True, True, False, True]  # b1 is worse than a1 on both axes
    r = P.at_target(pts, 0.12)
    assert r["winner"] == "a" and r["best"]["a"]["knob"] == 1 and r["best"]["b"]["knob"] == 2
    m, ci = r["paired_vs_winner"]["b"]
    assert m == pytest.approx(0.05) and ci[0] <= 0.05 <= ci[1]
    assert P.at_target(pts, 0.01)["best"] == {} and P.at_target(pts, 0.01)["unmet"] == ["a", "b"]


def test_the_command_plays_a_family_and_a_learned_run_on_the_same_missions(tmp_path, capsys):
    res = P.main(["--episodes", "2", "--max-steps", "60", "--families", "margin", "--learned",
                  "ppo=agents/trained/ppo_iscc", "--targets", "0.9", "--figure", str(tmp_path / "p.png")])
    fams = [p["family"] for p in res["points"]]
    assert fams.count("margin") == len(P.KNOBS["margin"]) and fams.count("ppo") == 1
    assert all(0.0 <= p["rate_outage"] <= 1.0 and np.isfinite(p["tracking_error_m"]) for p in res["points"])
    assert (tmp_path / "p.png").stat().st_size > 1000
    assert "non-dominated" in capsys.readouterr().out


def test_bad_input_is_refused_before_any_run():
    for argv, match in ((["--families", "nope"], "unknown"), (["--learned", "x=/no/such/dir"], "run directory"),
                        (["--targets", "2"], "fractions")):
        with pytest.raises(ValueError, match=match):
            P.main(argv)
