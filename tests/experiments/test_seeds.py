"""experiments.seeds: per-seed paired differences of trained agents against the scripted baselines."""

import numpy as np
import pytest
from iscc_gym.eval.engine import evaluate
from iscc_gym.eval.report import mean_ci
from iscc_gym.train import Args, main

from experiments import seeds as eval_seeds


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    root = tmp_path_factory.mktemp("seeds")
    for s in (0, 1):
        main(Args(total_timesteps=128, n_envs=2, seed=s, out=str(root / f"seed_{s}"), eval_freq=0, checkpoint_freq=0,
                  tensorboard=False, overrides={"n_steps": 64, "batch_size": 64, "n_epochs": 1}, init_policy="none"))
    (root / "seed_9").mkdir()  # no model: ignored
    return root


def test_per_seed_differences_are_paired_against_an_independent_evaluation(root):
    from iscc_gym.agents import make_policy
    from iscc_gym.agents.sb3_policy import SB3Policy

    seeds = [10_000, 10_001, 10_002]
    res = eval_seeds.compare_seeds(root, seeds, scripted=("sca", "margin"), max_steps=40)
    assert [r["seed"] for r in res["runs"]] == [0, 1]
    ref = evaluate({"a": SB3Policy.load(root / "seed_1"), "sca": make_policy("sca"), "margin": make_policy("margin")},
                   seeds, max_steps=40)
    eps = {k: np.asarray(v["episodes"]["reward"]) for k, v in ref["policies"].items()}
    best = max(("sca", "margin"), key=lambda k: eps[k].mean())
    assert res["best_scripted"] == best
    row = res["runs"][1]
    assert row["vs_sca"] == pytest.approx(mean_ci(eps["a"] - eps["sca"])[0])
    assert row["vs_best_ci95"] == pytest.approx(mean_ci(eps["a"] - eps[best])[1])
    assert "| 1 |" in eval_seeds.markdown(res, "python -m experiments.seeds X")


def test_missing_runs_are_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="python -m train --seeds"):
        eval_seeds.seed_runs(tmp_path)
    with pytest.raises(FileNotFoundError, match="is not a directory"):
        eval_seeds.main([str(tmp_path / "nope")])
    assert eval_seeds.main.__module__ and eval_seeds.build_parser().parse_args(["x"]).quiet is False


def test_command_writes_json_and_checks_its_outputs_first(root, tmp_path, capsys):
    import json

    path = tmp_path / "seeds.json"
    res = eval_seeds.main([str(root), "--episodes", "2", "--max-steps", "5", "--quiet", "--json", str(path)])
    assert json.loads(path.read_text())["runs"] == json.loads(json.dumps(res["runs"]))
    assert "| 0 |" in capsys.readouterr().out
    with pytest.raises(OSError, match="--json"):
        eval_seeds.main([str(root), "--episodes", "2", "--max-steps", "5", "--json", str(path / "x.json")])


def test_the_run_folder_is_listed_once(tmp_path, monkeypatch):
    """Issue 43.15 (left from earlier notes): experiments.seeds listed the seed runs' folder twice (seed_runs, then
    runs_items, then again in compare_seeds)."""
    from iscc_gym.eval import engine

    from experiments import seeds

    for s in (0, 1):
        (tmp_path / f"seed_{s}").mkdir()
        (tmp_path / f"seed_{s}" / "model.zip").write_bytes(b"")
    listed = []
    real = engine.seed_runs

    def spy(root):
        listed.append(root)
        return real(root)

    monkeypatch.setattr(seeds, "seed_runs", spy)
    monkeypatch.setattr(engine, "seed_runs", spy)
    class Played(Exception):
        pass

    def play(*a, runs=None, **k):
        assert runs is not None  # the listing passed on
        raise Played

    monkeypatch.setattr(seeds, "compare_seeds", play)
    with pytest.raises(Played):
        seeds.main([str(tmp_path), "--episodes", "2", "--quiet"])
    assert len(listed) == 1, listed
