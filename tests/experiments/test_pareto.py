"""Pareto fronts (issue 15 item 3): dominance, the per-target winner, and the command on tiny budgets."""

import time

import numpy as np
import pytest

from experiments import pareto as P


def _pt(fam, knob, outage, err, per):
    return {"family": fam, "knob": knob, "rate_outage": outage, "tracking_error_m": err,
            "per_mission_error_m": per}


def test_dominance_and_the_front():
    pts = [_pt("a", 1, 0.10, 0.40, [0.40, 0.40]), _pt("a", 2, 0.20, 0.39, [0.39, 0.39]),
           _pt("b", 1, 0.15, 0.41, [0.41, 0.41]), _pt("b", 2, 0.05, 0.45, [0.44, 0.46])]
    assert P.non_dominated(pts) == [True, True, False, True]  # b1 is worse than a1 on both axes
    assert P.dominated_by(pts[2], pts) == [pts[0]]
    assert P.learned_family("ppo-lag/0.05") == ("ppo-lag", "0.05") and P.learned_family("ppo") == ("ppo", "ppo")


def test_operating_points_are_chosen_on_training_seeds_then_played_held_out(tmp_path, capsys, monkeypatch):
    # two of static SCA's six knob points (each builds the analytic model of its own rate requirement, ~0.9 s)
    monkeypatch.setitem(P.KNOBS, "sca", (1.0, 3.5))
    res = P.main(["--episodes", "2", "--max-steps", "60", "--families", "sca", "--learned",
                  "ppo/shipped=agents/trained/ppo_iscc", "--targets", "0.95", "--train-episodes", "2",
                  "--iterations", "1", "--figure", str(tmp_path / "p.png")])
    fams = [p["family"] for p in res["points"]]
    assert fams.count("sca") == len(P.KNOBS["sca"]) and fams.count("ppo") == 1
    assert all(0.0 <= p["rate_outage"] <= 1.0 and np.isfinite(p["tracking_error_m"]) for p in res["points"])
    assert res["rate_min_bps"] == P.RATE_MIN_BPS
    r = res["targets"]["0.95"]
    assert set(r["best"]) <= {"sca", "ppo"} and r["best"]
    for p in r["best"].values():
        assert p["train"]["rate_outage"] <= 0.95  # chosen on the training missions
        assert len(p["per_mission_error_m"]) == 2  # played on the held-out ones
    other = [f for f in r["best"] if f != r["winner"]]
    for f in other:
        d = np.subtract(r["best"][f]["per_mission_error_m"], r["best"][r["winner"]]["per_mission_error_m"]).mean()
        assert r["paired_vs_winner"][f][0] == pytest.approx(d) and d >= 0.0
    assert (tmp_path / "p.png").stat().st_size > 1000
    captured = capsys.readouterr()
    out = captured.out
    assert "non-dominated" in out and "At 95 % outage" in out and "Learned points against the scripted ones" in out
    # issue 23 item 5: a line per point and per target stage on stderr, also without a terminal
    n = len(P.KNOBS["sca"]) + 1 + 2
    assert f"[python -m experiments.pareto] 0/{n} stage (sca " in captured.err
    assert "stage (ppo/shipped)" in captured.err and "stage (target 0.95: held out)" in captured.err
    assert f"done: {n}/{n} stage" in captured.err


def test_selection_refuses_evaluation_seeds():
    with pytest.raises(ValueError, match="seed"):
        P.select(0.1, [10_000, 10_001], families=("sca",), max_steps=10)


def test_bad_input_is_refused_before_any_run():
    for argv, match in ((["--families", "nope"], "unknown"), (["--learned", "x=/no/such/dir"], "run directory"),
                        (["--targets", "2"], "fractions"), (["--targets", "a"], "fractions"),
                        (["--rate-min-mbps", "-1"], "rate-min-mbps")):
        with pytest.raises(ValueError, match=match):
            P.main(argv)


# --- issue 23 defect 18: refused before the work --------------------------------------------------------------

TINY = ["--episodes", "1", "--max-steps", "5", "--train-episodes", "1", "--iterations", "1", "--targets", "0.5"]


def test_no_points_are_refused_before_any_work(tmp_path):
    """--families none --learned none played the training missions, then failed drawing an empty figure."""
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=r"--families 'none' and --learned none: no point to compare"):
        P.main(["--families", "none", "--learned", "none", "--figure", str(tmp_path / "p.png"), *TINY])
    assert time.perf_counter() - t0 < 2.0 and not (tmp_path / "p.png").exists()


@pytest.mark.parametrize("names", [("ppo/a", "ppo/a"), ("ppo", "ppo/ppo")], ids=["same", "same-point"])
def test_duplicate_learned_names_are_refused_naming_the_duplicate(names):
    """Two --learned of one name kept the last silently (a dict); "ppo" is the point "ppo/ppo" too."""
    argv = ["--families", "none", *TINY]
    for n in names:
        argv += ["--learned", f"{n}=agents/trained/ppo_iscc"]
    with pytest.raises(ValueError, match=rf"--learned '{names[1]}=agents/trained/ppo_iscc': the name '{names[1]}' "
                                         rf"is given twice \({names[0]}="):
        P.main(argv)
