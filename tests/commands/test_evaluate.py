"""The common-random-number evaluator: pairing, agreement with single-env rollouts, statistics."""

import json
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from iscc_gym.agents.base import EqualSplitPolicy, FixedSplitPolicy
from iscc_gym.eval.engine import evaluate
from iscc_gym.eval.evaluate import Entry, run_episodes
from iscc_gym.eval.report import format_table, mean_ci
from scipy import stats

import iscc_gym  # noqa: F401
from iscc_gym.sim.task import split_to_action


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
    assert "equal vs a" in format_table(res)


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
    from iscc_gym.eval.__main__ import main, split_specs

    assert split_specs("sca,fixed:0.2,0.2,0.6,equal") == ["sca", "fixed:0.2,0.2,0.6", "equal"]
    path = tmp_path / "out.json"
    res = main(["--policies", "sca,equal,fixed:0.3,0.2,0.5", "--episodes", "2", "--seed-start", "50", "--workers", "1",
                "--max-steps", "40", "--json", str(path), "--plots", str(tmp_path / "figs")])
    saved = json.loads(path.read_text())
    assert saved["seeds"] == [50, 51]
    for name in ("sca", "equal", "fixed:0.3,0.2,0.5"):
        assert {"reward_mean", "reward_ci95", "tracking_error_m_mean", "violation_mean"} <= set(saved["policies"][name])
    pair = saved["paired"]["equal_vs_sca"]
    assert pair["ci95"] == pair["reward_diff_ci95"] and len(pair["ci95"]) == 2
    for png in ("allocation.png", "tracking_error.png", "trajectories.png"):
        assert (tmp_path / "figs" / png).stat().st_size > 1000
    assert "Paired differences against sca" in capsys.readouterr().out
    assert res["reference"] == "sca"


def fake_checkout(root):
    """A project checkout at ``root`` (pyproject, README with a comparison block, docs/results.md); returns
    the ``PACKAGE_DIR`` of its ``iscc_gym/``."""
    (root / "iscc_gym").mkdir(parents=True)
    (root / "docs").mkdir()
    (root / "pyproject.toml").write_text('[project]\nname = "iscc-gym"\n')
    (root / "docs" / "results.md").write_text("# Results\n\n<!-- bench:start -->\nkeep me\n<!-- bench:end -->\n")
    (root / "README.md").write_text("intro\n<!-- comparison:start -->\nold\n<!-- comparison:end -->\noutro\n")
    return root / "iscc_gym"


def test_the_comparison_study_owns_only_its_sections_of_the_checkout(tmp_path, monkeypatch):
    """``python -m experiments comparison`` writes the checkout's README and docs (found from the package), not the
    working directory's, quoting itself as the command that regenerates them (issue 44: ``python -m eval``, an
    installed command, writes no docs)."""
    from iscc_gym.commands import docs

    from experiments.__main__ import main

    repo = tmp_path / "repo"
    monkeypatch.setattr(docs, "PACKAGE_DIR", fake_checkout(repo))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    main(["comparison", "--policies", "sca,equal", "--episodes", "2", "--max-steps", "20", "--workers", "1",
          "--quiet"])
    assert list(elsewhere.iterdir()) == []
    results = (repo / "docs" / "results.md").read_text()
    readme = (repo / "README.md").read_text()
    assert "keep me" in results and "| equal vs sca |" in results
    assert readme.startswith("intro\n") and readme.endswith("outro\n") and "old" not in readme
    assert "`python -m experiments comparison --policies sca,equal --episodes 2 --max-steps 20 --workers 1`" in readme
    from iscc_gym.eval.__main__ import build_parser

    assert "--write-docs" not in build_parser().format_help()


class FakeBar:
    """Stands in for the tqdm bar: records the progress reported."""

    def __init__(self, total, *args, **kwargs):
        self.total, self.n = total, 0
        FakeBar.last = self

    def update(self, n=1):
        self.n += n

    def close(self):
        pass


@pytest.mark.slow
def test_python_m_eval_in_worker_processes_gives_the_serial_results(monkeypatch, tmp_path):
    """``python -m eval --workers 2`` runs as ``__main__`` (its spawned workers must import what they run from
    a module): every per-episode figure equals the serial in-process run's, and the progress it reports
    through the workers' queue (lines on stderr without a terminal) adds up to every slot played, as the
    serial run's bar does on a terminal."""
    import iscc_gym.eval.__main__ as cli

    monkeypatch.setattr(cli, "show_progress", lambda quiet: True)
    monkeypatch.setattr(cli, "progress_bar", FakeBar)
    argv = ["--policies", "equal,margin,sca", "--episodes", "3", "--seed-start", "60", "--max-steps", "30"]
    serial = cli.main([*argv, "--workers", "1"])
    assert FakeBar.last.total == FakeBar.last.n == 3 * 30
    root = Path(__file__).resolve().parents[2]
    out = subprocess.run([sys.executable, "-m", "eval", *argv, "--workers", "2", "--json", str(tmp_path / "p.json")],
                         cwd=root, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert "Paired differences against sca" in out.stdout
    assert "done: 90/90 slot" in out.stderr.splitlines()[-1]
    parallel = json.loads((tmp_path / "p.json").read_text())
    assert list(parallel["policies"]) == ["equal", "margin", "sca"]
    for name in serial["policies"]:
        assert parallel["policies"][name]["episodes"] == json.loads(json.dumps(serial["policies"][name]["episodes"]))
    pair = "margin_vs_sca"
    assert parallel["paired"][pair]["reward_diff_mean"] == serial["paired"][pair]["reward_diff_mean"]


def test_focus_pairs_one_policy_against_every_other():
    pols = {"a": EqualSplitPolicy(), "b": FixedSplitPolicy([0.1, 0.3, 0.6]), "c": FixedSplitPolicy([0.05, 0.25, 0.7])}
    res = evaluate(pols, seeds=[3, 4, 5], reference="a", focus="b", max_steps=30)
    assert set(res["focus_paired"]) == {"b_vs_a", "b_vs_c"}
    rb = np.asarray(res["policies"]["b"]["episodes"]["reward"])
    rc = np.asarray(res["policies"]["c"]["episodes"]["reward"])
    assert res["focus_paired"]["b_vs_c"]["reward_diff_mean"] == pytest.approx((rb - rc).mean())
    assert res["focus_paired"]["b_vs_a"]["reward_diff_ci95"] == res["paired"]["b_vs_a"]["reward_diff_ci95"]


def test_confidence_intervals_are_clamped_to_each_metric_range():
    """A fraction's CI stays inside [0, 1], a non-negative metric's above 0, a difference of fractions inside
    [-1, 1]; the reward's is the plain t interval."""
    from iscc_gym.eval.evaluate import METRIC_RANGES, summarize

    assert mean_ci([0, 0, 0, 1], bounds=(0, 1))[1][0] == 0.0 and mean_ci([0, 0, 0, 1])[1][0] < 0
    assert mean_ci([1, 1, 1, 0], bounds=(0, 1))[1][1] == 1.0 and mean_ci([1, 1, 1, 0])[1][1] > 1
    few = {m: np.array([0.0, 0.0, 0.0, 1.0]) for m in METRIC_RANGES}
    many = {m: np.array([1.0, 1.0, 1.0, 0.0]) for m in METRIC_RANGES}
    for eps in (few, many):
        eps["reward"] = np.array([-10.0, -12.0, -9.0, -30.0])
    run = {"wall_time_s": 0.0, "slots": 4}
    res = summarize({"a": {**run, "episodes": few}, "b": {**run, "episodes": many}}, [1, 2, 3, 4], reference="a")
    for name in ("a", "b"):
        p = res["policies"][name]
        for metric, (low, high) in METRIC_RANGES.items():
            lo, hi = p[f"{metric}_ci95"]
            assert low <= lo <= p[f"{metric}_mean"] <= hi <= high, (name, metric)
        assert p["reward_ci95"] == mean_ci(p["episodes"]["reward"])[1]
    d = res["paired"]["b_vs_a"]
    assert d["violation_diff_ci95"][1] == 1.0 and d["violation_diff_ci95"][0] >= -1.0


def _result_of(n_policies=6):
    """A comparison result from synthetic episodes (no env): the shape of python -m eval's."""
    from iscc_gym.eval.evaluate import METRIC_RANGES, summarize

    rng = np.random.default_rng(0)
    names = ["ppo", "sca", "sca-per-slot", "margin", "myopic", "equal"][:n_policies]
    runs = {}
    for k, name in enumerate(names):
        eps = {m: rng.uniform(0.0, 0.4, 20) for m in METRIC_RANGES}
        eps["terminated"] = np.zeros(20)
        eps["stability_violation"] = np.r_[np.zeros(19), 0.01]  # its t interval reaches below 0
        eps["reward"] = rng.normal(-2600.0 - 100 * k, 300.0, 20)
        runs[name] = {"episodes": eps, "wall_time_s": 1.0, "slots": 100}
    return summarize(runs, list(range(10_000, 10_020)), reference="sca", focus="ppo")


def test_comparison_markdown_fits_120_columns_and_says_what_is_better():
    from iscc_gym.eval.report import markdown_table

    text = markdown_table(_result_of(), "python -m eval")
    lines = text.splitlines()
    assert max(map(len, lines)) <= 120, max(lines, key=len)
    header = next(line for line in lines if line.startswith("| policy |"))
    assert "episode reward ↑" in header and "tracking error (m) ↓" in header and "PEB (m) ↓" in header
    for line in lines:
        if line.startswith("| policy |") or line.startswith("| pair |"):
            titles = [t.strip() for t in line.strip("|").split("|")][1:]
            assert all(t.endswith(("↑", "↓")) or t.startswith("mean split") for t in titles), line
    note = " ".join(lines[lines.index(header) + 9:lines.index(header) + 13])
    assert "PEB: position error bound, the Cramér–Rao bound" in note and "(m)" in note
    assert "| ppo | " in text and " ±" in text and "| ppo vs sca |" in text
    # the stability violations of every policy: 0.0005 [0.0000, 0.0015] (cut at 0), never a negative bound
    row = next(line for line in lines if line.startswith("| sca |") and "/" in line)
    assert "[0.0000, " in row and "-0.0" not in row


def test_comparison_text_table_fits_a_terminal():
    text = format_table(_result_of())
    assert max(map(len, text.splitlines())) <= 120
    assert "↑" in text and "↓" in text


def test_reading_sentences_say_what_the_paired_table_says():
    """Issue 23: the comparison's prose is generated from the paired differences, so it cannot go stale."""
    from iscc_gym.eval.evaluate import _paired
    from iscc_gym.eval.report import reading_sentences

    def d(diffs):
        return _paired({"reward": np.asarray(diffs, float)}, {"reward": np.zeros(len(diffs))})

    res = {"reference": "sca", "paired": {"ppo_vs_sca": d([440, 450, 460]), "equal_vs_sca": d([-20, 5, 0])},
           "focus": "ppo", "focus_paired": {"ppo_vs_sca": d([440, 450, 460]), "ppo_vs_myopic": d([-30, -35, -38])}}
    text = reading_sentences(res)
    assert "ppo is ahead of sca by 450.0 ±24.8 (the interval excludes zero)" in text
    assert "equal is behind sca by 5.0 ±" in text and "(the interval includes zero)" in text
    assert "ppo is behind myopic by 34.3 ±" in text
    assert text.count("ppo is ahead of sca") == 1  # the pair against the reference is not repeated
    assert reading_sentences({"reference": None}) == ""


def test_the_share_of_the_oracles_gain_is_a_ratio_of_paired_means():
    from iscc_gym.eval.report import oracle_share, oracle_share_sentence

    def run(*r):
        return {"episodes": {"reward": list(r)}}

    res = {"policies": {"myopic": run(-10.0, -20.0, -30.0), "ppo": run(-9.0, -19.0, -28.0),
                        "oracle": run(-6.0, -16.0, -26.0)}}
    share = oracle_share(res)
    assert share["agent_gain"][0] == pytest.approx(4.0 / 3.0) and share["oracle_gain"][0] == pytest.approx(4.0)
    assert share["share"] == pytest.approx(1.0 / 3.0)  # (4/3) / 4, by hand
    # issue 43.11: 3 missions give no resampled interval (2 gave "0.37 [0.37, 0.38]"), and the sentence says why
    assert share["share_ci95"] is None and share["missions"] == 3
    assert "= 0.33 [n/a: 3 missions, an interval needs 10]." in oracle_share_sentence(share)
    res = {"policies": {k: run(*(v["episodes"]["reward"] * 4)) for k, v in res["policies"].items()}}  # 12 missions
    share = oracle_share(res)
    lo, hi = share["share_ci95"]  # the missions resampled (seeded): an interval around the ratio
    assert lo <= share["share"] <= hi and lo < hi
    assert f"= 0.33 [{lo:.2f}, {hi:.2f}] (missions resampled)." in oracle_share_sentence(share)  # measured: +4 always
    res["policies"]["oracle"] = run(*[-6.0, -24.0, -30.0] * 4)  # gains +4, -4, 0: not distinguishable from zero
    assert "measures nothing" in oracle_share_sentence(oracle_share(res))
    del res["policies"]["oracle"]
    assert oracle_share(res) is None


def test_one_mission_gives_no_interval_and_no_verdict():
    """Issue 34 item 9: with one mission the tables printed a zero-width "95 % interval" and the sentences said it
    excluded zero; mean_ci gives no interval, every command writes "n/a: 1 mission" through one function
    (ci_bounds) and draws no conclusion (ci_side)."""
    from iscc_gym.eval.evaluate import summarize
    from iscc_gym.eval.report import ci_bounds, markdown_table, oracle_share, oracle_share_sentence

    from experiments import urban_levers, urban_shift

    m, ci = mean_ci([3.0], bounds=(0.0, 1.0))
    assert m == 3.0 and ci is None and ci_bounds(ci) == "[n/a: 1 mission]"  # JSON null, equal across processes
    eps = {"reward": np.array([-10.0]), "tracking_error_m": np.array([0.5]), "violation": np.array([0.1]),
           "terminated": np.zeros(1), "peb_m": np.array([0.06]), "rate_comm_mbps": np.array([20.0]),
           "rate_violation": np.array([0.1]), "stability_violation": np.zeros(1), "alpha_sen": np.array([0.2]),
           "alpha_ctrl": np.array([0.2]), "alpha_comm": np.array([0.6])}
    runs = {name: {"episodes": {**eps, "reward": eps["reward"] + d}, "wall_time_s": 0.0, "slots": 3}
            for name, d in (("myopic", 0.0), ("ppo", 2.0), ("oracle", 5.0))}
    res = summarize(runs, [10_000], reference="myopic", focus="ppo")
    text = format_table(res) + markdown_table(res, "python -m eval")
    assert "-10.0 [n/a: 1 mission]" in text and "±0.0" not in text and "nan" not in text
    assert "ppo is ahead of myopic by 2.0 on one mission (no interval)" in text
    assert "zero" not in text and "95 % intervals" not in text
    share = oracle_share_sentence(oracle_share(res))
    assert "+2.0 [n/a: 1 mission] / +5.0 [n/a: 1 mission]" in share and "no interval from one mission" in share
    # the urban commands' tables and verdicts
    row = {"name": "smooth", "nlos_share": 0.3, "stretch_s_median": 1.0, "stretch_s_p90": 2.0, "myopic": -10.0,
           "parts": {"tracking": 5.0, "stability": 3.0, "dropped": 2.0, "lost_track": 0.0}, "seeds": [1, 1],
           "tune_seeds": [2, 2], "lost_track": {}, "myopic_dropped_mbit": 0.0, "mpc_dropped_mbit": 0.0,
           "oracle_dropped_mbit": 0.0, **{k: mean_ci([1.5]) for k in ("mpc", "oracle", "preview", "knowledge")}}
    levers = urban_levers.markdown([row], "python -m experiments.urban_levers")
    assert "+1.5 [n/a: 1 mission]" in levers and "interval" not in levers.split("Variants:")[1].replace(
        "no interval from one mission", "")
    shifted = urban_shift.markdown({next(iter(urban_shift.SHIFTS)): res}, "ppo", "python -m experiments.urban_shift")
    assert "-10.0; +2.0 [n/a: 1 mission]" in shifted and "interval below zero" not in shifted


def test_the_time_left_follows_each_jobs_own_pace_on_the_workers():
    """Issue 43.11: the main job's estimate ran 5x high mid-run (the slow policies' pace applied to every slot left).
    Two slow jobs (0.01 and 0.006 s a slot) and four fast ones (0.0002 s a slot) of 1,000 slots on 2 workers, the
    slow ones first, as the engine orders them: the estimate is when the pool ends."""
    from iscc_gym.eval.policies import TimeLeft

    now = [0.0]
    clock = TimeLeft([1000] * 6, [True, True, False, False, False, False], workers=2, clock=lambda: now[0])
    assert clock.seconds() is None
    clock.report(0, 0)
    clock.report(1, 0)
    now[0] = 3.0
    clock.report(0, 300)  # 0.01 s a slot: 7 s left
    clock.report(1, 500)  # 0.006 s a slot: 3 s left, then the four fast jobs (not measured: negligible)
    assert clock.seconds() == pytest.approx(7.0)
    now[0] = 6.0
    clock.report(1, 1000)  # job 1 done; its worker starts the fast ones
    clock.report(0, 600)
    clock.report(2, 0)
    now[0] = 6.1
    clock.report(2, 500)  # 0.0002 s a slot: the three fast ones left take 0.2 s each, 0.7 s in all on worker 2
    assert clock.seconds() == pytest.approx(4.0)  # job 0 still rules: 0.01 x 400
    now[0] = 9.5
    clock.report(0, 950)  # 0.5 s left
    assert clock.seconds() == pytest.approx(0.7)  # then the fast ones share the two workers: 0.1 + 0.2 + 0.2, 0.5 + 0.2
    now[0] = 0.0
    serial = TimeLeft([100, 100], [True, False], workers=1, clock=lambda: now[0])
    serial.report(0, 0)
    now[0] = 1.0
    serial.report(0, 50)  # 0.02 s a slot, the fast one not measured
    assert serial.seconds() == pytest.approx(1.0)
