"""The field task's baseline ladder (issue 36): the fading law at any K, the adaptive rung's estimators against Monte
Carlo, and the aware bound reading the world the env shows it."""

from __future__ import annotations

import numpy as np
import pytest
from iscc_gym.agents import make_policy
from iscc_gym.agents.adaptive import AdaptivePolicy, greenstein_k, mean_log_gain_db
from iscc_gym.agents.myopic import MyopicPolicy, rician_nodes_at

from iscc_gym.analysis.quadrature import rician_power_nodes
from iscc_gym.envs.vector import ISCCVectorEnv
from iscc_gym.scenario import make_scenario
from iscc_gym.sim.effects import task_effects
from iscc_gym.units import db_to_lin


def _rician_power(k_db, n, rng):
    k = db_to_lin(k_db)
    los, scat = np.sqrt(k / (k + 1.0)), np.sqrt(0.5 / (k + 1.0))
    z = rng.standard_normal((2, n))
    return (los + scat * z[0]) ** 2 + (scat * z[1]) ** 2


@pytest.mark.parametrize("k_db", [-7.3, 2.61, 9.0, 17.9])
def test_nodes_at_any_k_are_the_exact_quadratures(k_db):
    exact = rician_power_nodes(float(db_to_lin(k_db)))[0]
    np.testing.assert_allclose(rician_nodes_at(np.array([k_db]))[0], exact, rtol=2e-3, atol=1e-9)


@pytest.mark.parametrize("k_db", [0.0, 6.0, 12.0])
def test_greenstein_estimate_and_mean_log_gain_against_monte_carlo(k_db):
    g = _rician_power(k_db, 400_000, np.random.default_rng(1))
    k_hat = 10.0 * np.log10(greenstein_k(g.mean(), (g * g).mean()))
    assert k_hat == pytest.approx(k_db, abs=0.3)
    assert mean_log_gain_db(np.array([k_db]))[0] == pytest.approx(np.mean(10.0 * np.log10(g)), abs=0.05)


def test_greenstein_clamps_where_the_moments_are_not_rician():
    lo, hi = greenstein_k(np.array([1.0, 1.0]), np.array([3.5, 1.0]))  # gamma >= 1: Rayleigh's end; 0: no fading
    assert 10.0 * np.log10(lo) == pytest.approx(-20.0) and 10.0 * np.log10(hi) == pytest.approx(40.0)


def test_aware_at_the_models_world_is_myopic():
    """The world block at the model's values (K 9 dB, RCS offset 0): aware designs the slot as myopic does."""
    s = make_scenario("field")
    venv = ISCCVectorEnv(num_envs=3, scenario=s)
    obs, _ = venv.reset(seed=[1, 2, 3])
    world = np.tile(np.array([9.0 * 0.1, 0.0], np.float32), (3, 1))
    aware = MyopicPolicy(s.replace(show_world=True))
    assert aware.scenario_overrides == {"show_world": True}
    np.testing.assert_allclose(aware.split_batch(np.hstack([obs, world]))[0], MyopicPolicy(s).split_batch(obs)[0],
                               atol=1e-12)
    low_k = np.tile(np.array([-3.0 * 0.1, 0.0], np.float32), (3, 1))
    assert np.all(aware.split_batch(np.hstack([obs, low_k]))[0][:, 1] > MyopicPolicy(s).split_batch(obs)[0][:, 1])


def test_adaptive_learns_a_constant_world_from_the_measured_block():
    """Fed the env's missions with a low K and a large RCS everywhere, its estimates move from the model's to them."""
    s = make_scenario("field", rician_k_db=2.0, rician_k_std_db=1e-9, rcs_std_db=1e-9)
    truth = make_scenario("field", rician_k_db=2.0, rician_k_std_db=1e-9, rcs_std_db=1e-9)
    venv = ISCCVectorEnv(num_envs=8, scenario=truth)
    obs, _ = venv.reset(seed=list(range(8)))
    # the designer's model: K 9 dB; the world 2 dB. The RCS offset: a world of rcs_m2 10x the model's
    model = make_scenario("field")
    pol = AdaptivePolicy(model, k_window_slots=100.0, rcs_prior_slots=1.0)
    venv_rcs = ISCCVectorEnv(num_envs=8, scenario=truth.replace(rcs_m2=10.0 * model.rcs_m2))
    obs, _ = venv_rcs.reset(seed=list(range(8)))
    assert task_effects(s).field
    for _ in range(300):
        action, _ = pol.predict(obs)
        obs, *_ = venv_rcs.step(action)
    k_db, rcs_db = pol._k_db, pol._rcs_sum / (pol._rcs_n + 1.0)
    assert np.all(np.abs(k_db - 2.0) < 2.5), k_db
    assert np.all(np.abs(rcs_db - 10.0) < 1.5), rcs_db
    # a new mission (slot 0) starts afresh at the model's values
    obs, _ = venv_rcs.reset(seed=list(range(8)))
    pol.predict(obs)
    np.testing.assert_allclose(pol._k_db, 9.0, atol=1e-9)


def test_adaptive_needs_the_field_and_is_causal():
    with pytest.raises(ValueError, match="rician_k_std_db or rcs_std_db"):
        AdaptivePolicy("paper")
    with pytest.raises(ValueError, match="show_world"):
        AdaptivePolicy(make_scenario("field", show_world=True))
    with pytest.raises(ValueError, match="k_window_slots"):
        AdaptivePolicy("field", k_window_slots=0.5)
    assert make_policy("adaptive", "field").name == "adaptive"


def test_tuning_a_paper_baseline_on_the_field_task_is_refused_before_its_record_is_overwritten(tmp_path):
    """Issue 43.4: with the field task the paper task to ``task_of``, ``python -m eval.tune margin --scenario field``
    wrote the paper's ``margin`` record from field missions. The field's baselines read the paper's records."""
    from iscc_gym.eval import tune

    out = tmp_path / "margin.yml"
    with pytest.raises(ValueError, match="'field' is the field task, whose margin is the paper's as tuned there"):
        tune.main(["margin", "--scenario", "field", "--episodes", "1", "--out", str(out), "--quiet"])
    assert not out.exists()
    with pytest.raises(ValueError, match="adaptive is tuned on the field task"):
        tune.tune_model_grid("adaptive", scenario="paper", max_steps=1)


def test_a_world_designed_spec_that_reads_no_world_plays_the_field_task_on_the_worlds_law():
    """Issue 43.7: ``sca@world`` (and ``sca-per-slot@world``) failed mid-run on the field task, after the other
    policies had played, with an observation-shape message: they were built for the shown world's observation. Only
    ``myopic@world`` (``aware``) reads the slot's world; the others are designed on the world's law."""
    from iscc_gym.eval.engine import compare
    from iscc_gym.eval.policies import build_policy

    from iscc_gym.tasks import FIELD_ENV_ID, variant_scenario

    res = compare(FIELD_ENV_ID, "myopic,sca@world,sca-per-slot@world,aware", [10000], variants=["K mean 4 dB"],
                  max_steps=2, reference="myopic")
    played = res["K mean 4 dB"]["policies"]
    assert set(played) == {"myopic", "sca@world", "sca-per-slot@world", "aware"}
    assert all(np.all(np.isfinite(p["episodes"]["reward"])) for p in played.values())
    world = variant_scenario(FIELD_ENV_ID, "K mean 4 dB")
    _, sca = build_policy("sca@world", "field", world=world)
    assert getattr(sca, "scenario_overrides", None) is None
    _, aware = build_policy("aware", "field", world=world)
    assert aware.scenario_overrides == {"show_world": True}


def test_the_loaders_shape_check_knows_every_single_drone_task():
    """Issue 44: agents/sb3_policy.py's observation-shape check knew the paper and urban envs only (the field agent
    passed unchecked against its env); it reads each task's preset from its task file."""
    pytest.importorskip("stable_baselines3")
    from iscc_gym.agents.sb3_policy import SB3Policy
    from iscc_gym.agents.shipped import FIELD_AGENT

    from iscc_gym.tasks import FIELD_ENV_ID

    assert SB3Policy.load(FIELD_AGENT, check_env=FIELD_ENV_ID).obs_shape == (25,)
    with pytest.raises(ValueError, match="iscc_gym/ISCC-v0 gives \\(23,\\): it was trained on another env"):
        SB3Policy.load(FIELD_AGENT, check_env="iscc_gym/ISCC-v0")
