"""Tests of agents.myopic: the expected one-slot reward against independent oracles (Monte Carlo over
the env's own fading draws, scipy's non-central chi-square, the static evaluator, the generic
steady-state solver), the search against a brute-force grid, the policy protocol and validation."""

from __future__ import annotations

import numpy as np
import pytest
from iscc_gym.agents import make_policy
from iscc_gym.agents.myopic import LocalTrackingModel, MyopicPolicy, rician_power_cdf
from oracle_loop import rician_power_gain
from scipy.stats import ncx2

import iscc_gym  # noqa: F401  (registers the env)
from iscc_gym import SCENARIOS
from iscc_gym.analysis import StaticModel
from iscc_gym.analysis.averages import TrajectorySample
from iscc_gym.analysis.kalman_steady import axis_kalman_steady_state
from iscc_gym.analysis.quadrature import expected_norm
from iscc_gym.analysis.sensing_share import local_crlb
from iscc_gym.envs.vector import ISCCVectorEnv
from iscc_gym.physics.channel import geometry, link_snr, matched_gain
from iscc_gym.physics.dynamics import model_matrices, system_matrices
from iscc_gym.physics.fbl import min_shares, slot_link
from iscc_gym.physics.stability import scenario_eps_star, steady_state_covariance
from iscc_gym.sim.schema import OBS_NAMES
from iscc_gym.sim.task import action_to_split, split_to_action

S = SCENARIOS["paper"]
EPS_STAR = scenario_eps_star(S)


@pytest.fixture(scope="module")
def policy():
    return MyopicPolicy(S)


@pytest.fixture(scope="module")
def observations():
    """Env observations (4 episodes at a fixed split, every 100 slots), then three constructed ones:
    close to the GBS (SNR ~ 30 dB), mid-range, and far in a shadowed spot (R_min out of reach)."""
    venv = ISCCVectorEnv(num_envs=4, scenario=S)
    obs, _ = venv.reset(seed=[1, 2, 3, 4])
    a = np.tile(split_to_action([0.2, 0.2, 0.6]), (4, 1))
    out = []
    for t in range(400):
        obs, *_ = venv.step(a)
        if t % 100 == 99:
            out.append(obs)
    made = [obs_at([60.0, 40.0, 90.0]), obs_at([300.0, -200.0, 110.0]), obs_at([950.0, -500.0, 60.0], 6.0)]
    return np.concatenate(out + [np.array(made)])


@pytest.fixture(scope="module")
def fading():
    """The env's small-scale fading: rician_power_gain of standard normal pairs (400k draws)."""
    z = np.random.default_rng(0).standard_normal((2, 400_000))
    return rician_power_gain(S, z[0], z[1])


def obs_at(pos_m, shadow_db=0.0):
    """An observation (float32) whose geometry, SNR and minimum shares are those of a position
    ``pos_m`` (the estimate there) with shadowing ``shadow_db``; the other entries 0."""
    dist, az, el, _ = geometry(S, np.asarray(pos_m, dtype=float))
    snr = link_snr(S, dist, shadow_db, matched_gain(S))
    o = np.zeros(len(OBS_NAMES), np.float32)
    o[13] = np.log10(snr)
    ctrl_min, comm_min = min_shares(S, snr, EPS_STAR, S.rate_min_bps)
    o[18], o[19] = 10.0 * ctrl_min, comm_min
    o[14], o[15], o[16], o[17] = dist / S.coverage_radius_m, np.sin(el), np.cos(az), np.sin(az)
    return o


# --- the fading model --------------------------------------------------------------------------
def test_rician_cdf_matches_env_draws_and_scipy(fading):
    k = 10.0 ** (S.rician_k_db / 10.0)
    x = np.array([0.01, 0.05, 0.2, 0.5, 1.0, 1.5, 2.5])
    cdf = rician_power_cdf(S, x)
    emp = (fading[:, None] <= x).mean(0)
    assert np.all(np.abs(cdf - emp) <= 4.0 * np.sqrt(emp * (1.0 - emp) / fading.size) + 1e-4)
    # scipy's frozen distribution, scale form: |g|^2 = sigma^2 chi'^2_2(2K)
    np.testing.assert_allclose(cdf, ncx2(2, 2.0 * k, scale=0.5 / (k + 1.0)).cdf(x), rtol=1e-10)


def test_stability_probability_matches_monte_carlo(policy, observations, fading):
    obs = observations[[0, 5, 10, -3, -2, -1]]
    ctx = policy.slot_context(obs)
    for i in range(len(obs)):
        snr = ctx.snr[i]
        a_star = obs[i, 18] / 10.0  # eps* share at the mean SNR: probe around it
        c = np.minimum(a_star * np.array([0.9, 1.1, 1.5, 2.0, 3.0]), 1.0)
        _, p_viol = policy.ctrl_terms(ctx, np.tile(c, (len(obs), 1)))
        eps = slot_link(S, c[:, None], 0.0, fading * snr)[0]
        mc = (eps > EPS_STAR).mean(1)
        se = np.sqrt(np.maximum(mc * (1.0 - mc), 1e-6) / fading.size)
        assert np.all(np.abs(p_viol[i] - mc) <= 4.0 * se + 2e-4), (i, p_viol[i], mc)
        assert np.all(np.diff(p_viol[i]) <= 0.0)  # more control share, fewer violations


def test_loss_rate_and_rate_shortfall_match_monte_carlo(policy, observations, fading):
    obs = observations[[1, 14, -3, -2, -1]]
    ctx = policy.slot_context(obs)
    c = np.array([0.05, 0.08, 0.12, 0.2])
    d = np.array([0.3, 0.5, 0.7, 0.9])
    eps_bar, _ = policy.ctrl_terms(ctx, np.tile(c, (len(obs), 1)))
    short = policy.rate_shortfall(ctx, np.tile(d, (len(obs), 1)))
    for i in range(len(obs)):
        snr = fading * ctx.snr[i]
        mc_eps = slot_link(S, c[:, None], 0.0, snr)[0].mean(1)
        mc_short = np.maximum(S.rate_min_bps - slot_link(S, 0.0, d[:, None], snr)[2], 0.0).mean(1) / S.rate_min_bps
        np.testing.assert_allclose(eps_bar[i], mc_eps, atol=3e-3)
        np.testing.assert_allclose(short[i], mc_short, atol=2e-3)


# --- the tracking term ----------------------------------------------------------------------------
@pytest.mark.parametrize("pos", [[250.0, 120.0, 90.0], [-700.0, 500.0, 150.0]])
def test_tracking_term_matches_static_evaluator(policy, pos):
    """At a command share with no loss, T equals StaticModel's steady-state error at that position."""
    sen = np.array([0.005, 0.03, 0.2])
    split = np.stack([sen, np.full(3, 0.5), 0.5 - sen], -1)
    ours = policy.expected_terms(obs_at(pos), split)["tracking_error_m"][0]
    ref = StaticModel(S, TrajectorySample(np.array([pos]), 1)).evaluate(split).tracking_error_m
    np.testing.assert_allclose(ours, ref, rtol=1e-3)


def test_tracking_term_loss_rate_matches_generic_steady_state(policy):
    """Per-axis variances against the Kalman steady state at the exact CRLB and the generic
    solver of eq:covariance_recursion (stability.steady_state_covariance), no tables."""
    ctx = policy.slot_context(obs_at([600.0, -300.0, 120.0], shadow_db=2.0))
    coef = ctx.coef
    mm = model_matrices(S)
    a, b = system_matrices(S.dt_s)
    ax = [0, 3]
    a1, b1, k1 = a[np.ix_(ax, ax)], b[ax][:, :1], mm.k[:1, ax]
    model = policy.tracking
    for sen in (0.01, 0.1):
        m_r, m_tt, m_tp, m_pp, vr = local_crlb(coef, sen)
        cross = np.linalg.eigvalsh(np.array([[m_tt[0], m_tp[0]], [m_tp[0], m_pp[0]]]))[::-1]
        for eps in (0.0, 0.1, 0.3, 0.45):
            lam = []
            for r_p, r_v in ((m_r[0], vr[0]), (cross[0], None), (cross[1], None)):
                p_prior, est = axis_kalman_steady_state(S.dt_s, S.process_noise_var_pos_m2,
                                                        S.process_noise_var_vel_m2s2, r_p, r_v)
                sig = steady_state_covariance(a1, b1, k1, eps, p_prior - est)
                lam.append(sig[0, 0] + est[0, 0])
            ours = model.axis_variances(coef, sen, eps)[0]
            np.testing.assert_allclose(ours, lam, rtol=2e-3)
            np.testing.assert_allclose(model.tracking_error(coef, sen, eps)[0], expected_norm(np.array(lam)),
                                       rtol=2e-3)
    # no steady state at or beyond eps*: the cap, as the env's reward clips the error
    assert model.tracking_error(coef, 0.1, EPS_STAR)[0] == S.max_tracking_error_m
    t = model.tracking_error(coef, 0.1, np.array([0.0, 0.2, 0.4, 0.49]))
    assert np.all(np.diff(t) > 0.0)


# --- the search -----------------------------------------------------------------------------------
def test_split_on_simplex_with_floors(policy, observations):
    split, state = policy.split_batch(observations)
    assert state is None
    assert np.allclose(split.sum(1), 1.0)
    assert np.all(split[:, 0] >= policy.sensing_floor - 1e-12)
    assert np.all(split[:, 1] >= policy.ctrl_floor - 1e-12)
    assert np.all(split[:, 2] >= 0.0)
    action, _ = policy.predict(observations)
    assert action.shape == (len(observations), 3) and action.dtype == np.float32
    assert np.all(np.abs(action) <= 1.0)
    np.testing.assert_allclose(action_to_split(action), split, atol=1e-6)
    one, _ = policy.predict(observations[0])
    assert one.shape == (3,)
    np.testing.assert_allclose(one, action[0], atol=1e-7)


def test_split_maximises_objective_on_a_fine_grid(policy, observations):
    obs = observations[[0, 6, 14, -3, -2, -1]]
    c = np.geomspace(policy.ctrl_floor, 1.0, 220)
    d = np.linspace(0.0, 1.0, 220)
    cc, dd = (g.ravel() for g in np.meshgrid(c, d, indexing="ij"))
    keep = 1.0 - cc - dd >= policy.sensing_floor
    grid = np.stack([1.0 - cc[keep] - dd[keep], cc[keep], dd[keep]], -1)
    brute = policy.expected_reward(obs, grid).max(1)
    split, _ = policy.split_batch(obs)
    chosen = policy.expected_reward(obs, split[:, None, :])[:, 0]
    assert np.all(chosen >= brute - 2e-3), (chosen, brute)
    # and at least as good, in its own objective, as static SCA's split and the equal split
    others = np.stack([make_policy("sca", S).split, np.full(3, 1.0 / 3.0)])
    assert np.all(chosen[:, None] >= policy.expected_reward(obs, others) - 1e-12)
    # the terms add up to the objective
    terms = policy.expected_terms(obs, split[:, None, :])
    total = -terms["tracking_error_m"] - S.w_rate * terms["rate_shortfall"] - S.w_stab * terms["stability_violation"]
    np.testing.assert_allclose(terms["reward"], total, rtol=1e-12)


def test_rate_weight_trades_rate_for_sensing(observations):
    """A smaller rate weight gives the data link less and sensing more."""
    obs = observations[[2, 9, -2]]
    base, _ = MyopicPolicy(S).split_batch(obs)
    low, _ = MyopicPolicy(S, rate_weight=0.05).split_batch(obs)
    assert np.all(low[:, 2] < base[:, 2]) and np.all(low[:, 0] > base[:, 0])


def test_rollout_runs_and_is_deterministic(policy):
    def run():
        venv = ISCCVectorEnv(num_envs=2, scenario=S)
        obs, _ = venv.reset(seed=[11, 12])
        actions, rewards = [], []
        state = None
        with np.errstate(over="raise", invalid="raise", divide="raise"):
            for _ in range(200):
                a, state = policy.predict(obs, state=state)
                obs, r, term, trunc, _ = venv.step(a)
                actions.append(a)
                rewards.append(r)
        assert not np.any(term)
        return np.array(actions), np.array(rewards)

    a1, r1 = run()
    a2, r2 = run()
    np.testing.assert_array_equal(a1, a2)
    np.testing.assert_array_equal(r1, r2)
    assert np.all(np.isfinite(r1))


# --- validation -------------------------------------------------------------------------------------
def test_bad_observations_raise(policy):
    with pytest.raises(ValueError, match="obs must have shape"):
        policy.predict(np.zeros(22))
    with pytest.raises(ValueError, match="obs must have shape"):
        policy.predict(np.zeros((2, 3, 23)))
    bad = np.zeros((2, 23))
    bad[1, 13] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        policy.predict(bad)
    with pytest.raises(ValueError, match="split = .* is not a split"):
        policy.expected_reward(np.zeros(23), [[0.5, 0.5, 0.5]])


@pytest.mark.parametrize("kwargs, field", [
    ({"rate_weight": -1.0}, "rate_weight"),
    ({"stability_weight": float("nan")}, "stability_weight"),
    ({"sensing_floor": 0.6}, "sensing_floor"),
    ({"ctrl_floor": 0.0}, "ctrl_floor"),
    ({"n_coarse": 2}, "n_coarse"),
    ({"n_refine": -1}, "n_refine"),
    ({"refine_points": 4}, "refine_points"),
    ({"refine_factor": 1.0}, "refine_factor"),
    ({"scenario": 3}, "scenario"),
    ({"scenario": S.replace(observation_source="gnss")}, "observation_source"),
])
def test_bad_parameters_raise(kwargs, field):
    kw = {"scenario": S, **kwargs}
    with pytest.raises(ValueError, match=field):
        MyopicPolicy(**kw)


def test_local_tracking_model_is_scenario_bound():
    m = LocalTrackingModel(S)
    assert m.eps_star == EPS_STAR
    np.testing.assert_array_equal(m.loss_weights(np.array([EPS_STAR, 0.7])), 0.0)
