"""The common-random-number evaluator: pairing, agreement with single-env rollouts, statistics."""

import gymnasium as gym
import numpy as np
import pytest
from iscc_gym.agents.base import EqualSplitPolicy, FixedSplitPolicy
from iscc_gym.eval.evaluate import Entry, evaluate, format_table, mean_ci, run_episodes
from scipy import stats

import iscc_gym  # noqa: F401
from iscc_gym.env import split_to_action


def test_episode_metrics_equal_single_env_rollouts():
    """The batched evaluator's per-episode sums equal a plain gymnasium.make rollout per seed."""
    split = [0.3, 0.2, 0.5]
    res = run_episodes(FixedSplitPolicy(split), seeds=[7, 8], max_steps=150)
    for k, seed in enumerate([7, 8]):
        env = gym.make("iscc_gym/ISCC-v0")
        env.reset(seed=seed)
        rewards, errors, costs = [], [], []
        for _ in range(150):
            _, r, te, tr, info = env.step(split_to_action(split))
            rewards.append(r)
            errors.append(info["tracking_error_m"])
            costs.append(info["cost"])
        assert res["episodes"]["reward"][k] == pytest.approx(sum(rewards), rel=1e-12)
        assert res["episodes"]["tracking_error_m"][k] == pytest.approx(np.mean(errors), rel=1e-12)
        assert res["episodes"]["cost"][k] == pytest.approx(sum(costs), rel=1e-12)
        assert res["episodes"]["length"][k] == 150


def test_identical_policies_pair_to_exactly_zero_and_schemes_differ():
    res = evaluate({"a": FixedSplitPolicy([0.2, 0.2, 0.6]), "b": FixedSplitPolicy([0.2, 0.2, 0.6]),
                    "gnss": Entry(FixedSplitPolicy([0.2, 0.2, 0.6]), {"observation_source": "gnss"}),
                    "equal": EqualSplitPolicy()},
                   seeds=[1, 2, 3], reference="a", max_steps=600)
    pair = res["paired"]["b_vs_a"]
    assert pair["reward_diff_mean"] == 0.0 and pair["reward_diff_ci95"] == [0.0, 0.0]
    # GNSS feedback (3 m) tracks worse than ISAC at this split, on every paired episode
    assert res["paired"]["gnss_vs_a"]["tracking_error_m_diff_ci95"][0] > 0
    assert set(res["policies"]) == {"a", "b", "gnss", "equal"}
    assert "equal_vs_a" in format_table(res)


def test_mean_ci_matches_scipy_t_interval():
    x = np.random.default_rng(0).normal(3.0, 2.0, 17)
    m, (lo, hi) = mean_ci(x)
    ref = stats.t.interval(0.95, 16, loc=x.mean(), scale=stats.sem(x))
    assert m == pytest.approx(x.mean()) and lo == pytest.approx(ref[0]) and hi == pytest.approx(ref[1])


def test_termination_is_counted_and_stops_accumulating():
    res = run_episodes(FixedSplitPolicy([0.98, 0.0, 0.02]), seeds=[4], max_steps=2000)
    assert res["episodes"]["terminated"][0] == 1.0
    assert res["episodes"]["length"][0] < 2000


def test_bad_arguments():
    with pytest.raises(ValueError, match="seeds"):
        run_episodes(EqualSplitPolicy(), seeds=[])
    with pytest.raises(ValueError, match="reference"):
        evaluate({"a": EqualSplitPolicy()}, seeds=[1], reference="sca")


def test_eval_cli_writes_json_and_plots(tmp_path, capsys):
    from iscc_gym.eval.__main__ import _split_specs, main

    assert _split_specs("sca,fixed:0.2,0.2,0.6,equal") == ["sca", "fixed:0.2,0.2,0.6", "equal"]
    path = tmp_path / "out.json"
    res = main(["--policies", "sca,equal,fixed:0.3,0.2,0.5", "--episodes", "2", "--seed-start", "50",
                "--max-steps", "40", "--json", str(path), "--plots", str(tmp_path / "figs")])
    import json

    saved = json.loads(path.read_text())
    assert saved["seeds"] == [50, 51]
    for name in ("sca", "equal", "fixed:0.3,0.2,0.5"):
        assert {"reward_mean", "reward_ci95", "tracking_error_m_mean", "violation_mean"} <= set(saved["policies"][name])
    pair = saved["paired"]["equal_vs_sca"]
    assert pair["ci95"] == pair["reward_diff_ci95"] and len(pair["ci95"]) == 2
    for png in ("allocation.png", "tracking_error.png", "trajectories.png"):
        assert (tmp_path / "figs" / png).stat().st_size > 1000
    assert "paired differences vs sca" in capsys.readouterr().out
    assert res["reference"] == "sca"


def test_eval_write_docs_owns_only_its_sections(tmp_path, monkeypatch):
    from iscc_gym.eval.__main__ import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "results.md").write_text("# Results\n\n<!-- bench:start -->\nkeep me\n<!-- bench:end -->\n")
    (tmp_path / "README.md").write_text("intro\n<!-- comparison:start -->\nold\n<!-- comparison:end -->\noutro\n")
    main(["--policies", "sca,equal", "--episodes", "2", "--max-steps", "20", "--write-docs"])
    results = (tmp_path / "docs" / "results.md").read_text()
    readme = (tmp_path / "README.md").read_text()
    assert "keep me" in results and "| equal_vs_sca |" in results
    assert readme.startswith("intro\n") and readme.endswith("outro\n") and "old" not in readme
    assert "`python -m eval --policies sca,equal --episodes 2 --max-steps 20 --write-docs`" in readme


def test_eval_cli_in_worker_processes_gives_the_same_results():
    """Policies played in two spawned processes: every per-episode figure equals the serial run's."""
    from iscc_gym.eval.__main__ import main

    argv = ["--policies", "equal,margin,sca", "--episodes", "3", "--seed-start", "60", "--max-steps", "30"]
    serial = main([*argv, "--workers", "1"])
    parallel = main([*argv, "--workers", "2"])
    assert list(parallel["policies"]) == ["equal", "margin", "sca"]
    for name in serial["policies"]:
        assert parallel["policies"][name]["episodes"] == serial["policies"][name]["episodes"]
    pair = "margin_vs_sca"
    assert parallel["paired"][pair]["reward_diff_mean"] == serial["paired"][pair]["reward_diff_mean"]


def test_python_m_eval_with_workers_runs_as_a_command():
    """``python -m eval`` runs as ``__main__``: its workers must import what they run from a module."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, "-m", "eval", "--policies", "equal,sca", "--episodes", "2", "--max-steps",
                          "10", "--workers", "2"], cwd=root, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert "paired differences vs sca" in out.stdout


def test_focus_pairs_one_policy_against_every_other():
    pols = {"a": EqualSplitPolicy(), "b": FixedSplitPolicy([0.1, 0.3, 0.6]), "c": FixedSplitPolicy([0.05, 0.25, 0.7])}
    res = evaluate(pols, seeds=[3, 4, 5], reference="a", focus="b", max_steps=30)
    assert set(res["focus_paired"]) == {"b_vs_a", "b_vs_c"}
    rb = np.asarray(res["policies"]["b"]["episodes"]["reward"])
    rc = np.asarray(res["policies"]["c"]["episodes"]["reward"])
    assert res["focus_paired"]["b_vs_c"]["reward_diff_mean"] == pytest.approx((rb - rc).mean())
    assert res["focus_paired"]["b_vs_a"]["reward_diff_ci95"] == res["paired"]["b_vs_a"]["reward_diff_ci95"]
