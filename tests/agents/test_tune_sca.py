"""Per-slot SCA's design loss fraction: tuned by ``python -m eval.tune sca-per-slot`` on training seeds."""

import pytest
import yaml
from iscc_gym.agents import make_policy
from iscc_gym.agents.sca_slot import SCAPolicy, per_slot_loss_design_fraction
from iscc_gym.agents.tuned_records import load_tuned
from iscc_gym.eval import tune
from iscc_gym.eval.evaluate import run_episodes

from iscc_gym.scenario import make_scenario


def test_stored_record_was_tuned_on_seeds_disjoint_from_evaluation():
    rec = load_tuned("sca-per-slot")
    lo, hi = (int(x) for x in str(rec["seeds"]).split("-"))
    tune.check_tuning_seeds(range(lo, hi + 1))  # raises if any evaluation seed was used
    assert rec["n_seeds"] == hi - lo + 1 and rec["command"].startswith("python -m eval.tune sca-per-slot")
    rows = rec["grid"] + rec["refinement"]
    best = max(rows, key=lambda row: row[1])
    assert rec["objective_value"] == pytest.approx(best[1])
    assert rec["params"]["loss_design_fraction"] == pytest.approx(best[0], abs=1e-5)


def test_per_slot_policy_reads_the_record():
    frac = load_tuned("sca-per-slot")["params"]["loss_design_fraction"]
    assert per_slot_loss_design_fraction() == frac
    assert make_policy("sca-per-slot").loss_design_fraction == frac
    assert make_policy("sca").loss_design_fraction == 0.1  # the static design keeps its own default


def test_missing_record_names_the_command(tmp_path):
    with pytest.raises(FileNotFoundError, match="python -m eval.tune sca-per-slot"):
        per_slot_loss_design_fraction(tmp_path / "none.yml")


def test_tune_picks_the_best_point_and_writes_a_record(tmp_path):
    """A tiny run: the record's fraction is the best of the grid and the bounded search, each grid
    reward is the policy played alone on the same seeds, and the record is written atomically."""
    seeds = [500_201, 500_202]
    rec = tune.tune_sca_per_slot(seeds, grid=(0.01, 0.1), refine=True, log=lambda *_: None, max_steps=100)
    rows = rec["grid"] + rec["refinement"]
    assert len(rec["refinement"]) >= 1
    assert all(0.01 <= x <= 0.1 for x, _ in rec["refinement"])  # searched between the grid's neighbours
    best = max(rows, key=lambda row: row[1])
    assert rec["params"]["loss_design_fraction"] == pytest.approx(best[0], abs=1e-5)
    alone = run_episodes(SCAPolicy(make_scenario("paper"), mode="per_slot", loss_design_fraction=0.1), seeds,
                         "paper", max_steps=100)["episodes"]["reward"].mean()
    assert dict(map(tuple, rec["grid"]))[0.1] == pytest.approx(alone, abs=1e-3)
    out = tmp_path / "sca.yml"
    tune.save_tuned("sca-per-slot", rec, out)
    assert yaml.safe_load(out.read_text())["params"] == rec["params"]
    assert not list(tmp_path.glob(".sca.yml.*"))


@pytest.mark.parametrize("grid", [(), (0.0, 0.1), (0.1, 1.5)])
def test_bad_grid_is_refused(grid):
    with pytest.raises(ValueError, match="grid"):
        tune.tune_sca_per_slot([500_000], grid=grid, log=lambda *_: None)


def test_evaluation_seeds_are_refused():
    with pytest.raises(ValueError, match="evaluation range"):
        tune.tune_sca_per_slot([10_003], grid=(0.02,), log=lambda *_: None)
