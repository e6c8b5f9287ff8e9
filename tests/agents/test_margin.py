"""The ``margin`` rule (agents.margin) and its tuning command (eval.tune)."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from iscc_gym.agents import MarginPolicy, make_policy
from iscc_gym.agents.margin import margin_split
from iscc_gym.agents.tuned_records import load_tuned
from iscc_gym.eval import tune
from oracle_loop import preview

from iscc_gym import SCENARIOS
from iscc_gym.envs.vector import ISCCVectorEnv
from iscc_gym.physics.stability import scenario_eps_star
from iscc_gym.sim.schema import OBS_NAMES
from iscc_gym.sim.task import action_to_split

S = SCENARIOS["paper"]


def test_split_is_the_rule_where_it_fits():
    a = margin_split(np.array([0.02]), np.array([0.5]), 4.0, 1.2, 0.01)[0]
    np.testing.assert_allclose(a, [1 - 0.08 - 0.6, 0.08, 0.6], atol=1e-15)


def test_control_first_then_data_then_the_sensing_floor():
    # control alone overflows: it gets all but the floor, data nothing
    a = margin_split(np.array([0.5]), np.array([0.5]), 4.0, 1.2, 0.05)[0]
    np.testing.assert_allclose(a, [0.05, 0.95, 0.0], atol=1e-15)
    # data overflows: it gets what control leaves above the floor
    a = margin_split(np.array([0.1]), np.array([0.9]), 2.0, 1.5, 0.02)[0]
    np.testing.assert_allclose(a, [0.02, 0.2, 0.78], atol=1e-15)


def test_splits_on_the_simplex_for_any_need():
    rng = np.random.default_rng(1)
    need = rng.exponential(0.5, size=(2, 1000))
    a = margin_split(need[0], need[1], 5.0, 1.3, 0.01)
    assert np.all(a >= -1e-15) and np.all(a[:, 0] >= 0.01 - 1e-12)
    np.testing.assert_allclose(a.sum(axis=1), 1.0, atol=1e-12)


def test_policy_reads_the_predicted_needs_from_the_env():
    """The shares applied by the env are the multiples of the needs the GBS predicted (loop.preview)."""
    env = ISCCVectorEnv(num_envs=3, scenario=S)
    obs, _ = env.reset(seed=[7, 8, 9])
    pv = preview(S, env._state, scenario_eps_star(S))
    pol = MarginPolicy(3.0, 1.1, 0.0)
    action, _ = pol.predict(obs)
    alpha = action_to_split(action)
    np.testing.assert_allclose(alpha[:, 1], np.minimum(3.0 * pv["alpha_ctrl_min"], 1.0), rtol=1e-5)
    want_comm = np.minimum(1.1 * pv["alpha_comm_min"], 1.0 - alpha[:, 1])
    np.testing.assert_allclose(alpha[:, 2], want_comm, rtol=1e-5, atol=1e-7)
    assert OBS_NAMES[18] == "alpha_ctrl_min" and OBS_NAMES[19] == "alpha_comm_min"


@pytest.mark.parametrize("kw, field", [({"m_ctrl": -1.0}, "m_ctrl"), ({"m_comm": float("nan")}, "m_comm"),
                                       ({"sensing_floor": 1.0}, "sensing_floor")])
def test_bad_parameters_name_the_field(kw, field):
    args = {"m_ctrl": 4.0, "m_comm": 1.2, "sensing_floor": 0.01, **kw}
    with pytest.raises(ValueError, match=field):
        MarginPolicy(**args)


def test_specs():
    p = make_policy("margin:4,1.3")
    assert (p.m_ctrl, p.m_comm) == (4.0, 1.3)
    tuned = make_policy("margin")
    rec = load_tuned("margin")
    assert tuned.m_ctrl == rec["params"]["m_ctrl"] and tuned.m_comm == rec["params"]["m_comm"]
    with pytest.raises(ValueError, match="two numbers"):
        make_policy("margin:4")


def test_stored_record_was_tuned_on_seeds_disjoint_from_evaluation():
    rec = load_tuned("margin")
    lo, hi = (int(x) for x in str(rec["seeds"]).split("-"))
    tune.check_tuning_seeds(range(lo, hi + 1))  # raises if any evaluation seed was used
    assert rec["n_seeds"] == hi - lo + 1 and rec["command"].startswith("python -m eval.tune margin")
    best = max(rec["grid"] + rec["refinement"], key=lambda row: row[3])
    assert rec["objective_value"] == pytest.approx(best[3])


def test_tuning_seeds_in_an_evaluation_range_are_refused():
    with pytest.raises(ValueError, match="evaluation range"):
        tune.check_tuning_seeds([10_005])
    with pytest.raises(ValueError, match="empty"):
        tune.check_tuning_seeds([])


def test_tune_command_picks_the_grid_maximum(tmp_path):
    """A tiny tuning run: the record's point is the grid's best, each grid reward is the mean over the
    seeds of the same policy played alone (an independent rollout), and the file is a valid record."""
    out = tmp_path / "margin.yml"
    grid = {"m_ctrl": (2.0, 6.0), "m_comm": (1.0, 1.4), "sensing_floor": (0.02,)}
    seeds = [500_123, 500_124]
    rec = tune.tune_margin(seeds, grid=grid, refine=False, log=lambda *_: None, scenario="paper")
    rewards = {(a, b): r for a, b, _, r in rec["grid"]}
    assert (rec["params"]["m_ctrl"], rec["params"]["m_comm"]) == max(rewards, key=rewards.get)
    from iscc_gym.eval.evaluate import run_episodes

    alone = run_episodes(MarginPolicy(6.0, 1.4, 0.02), seeds, "paper")["episodes"]["reward"].mean()
    assert rewards[(6.0, 1.4)] == pytest.approx(alone, abs=1e-3)  # the record keeps 3 decimals
    tune.save_tuned("margin", rec, out)
    assert yaml.safe_load(out.read_text())["params"] == rec["params"]
    assert not list(tmp_path.glob(".margin.yml.*"))  # no temporary file left behind
