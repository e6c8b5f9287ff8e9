"""Tests of iscc_gym.analysis: the steady-state evaluator of a static allocation.

Oracles: the 6-state Kalman DARE and the vectorised second-moment recursion of iscc_gym.physics.stability,
sensing.crlb_local, finite differences, a seeded Monte Carlo of a Gaussian, and rollouts of the env.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import scipy.linalg
from oracle_loop import rician_power_gain

import iscc_gym  # noqa: F401  (registers the env)
from iscc_gym import SCENARIOS, analysis
from iscc_gym.analysis import averages, quadrature, sensing_share
from iscc_gym.physics import fbl
from iscc_gym.physics.channel import geometry
from iscc_gym.physics.dynamics import model_matrices
from iscc_gym.physics.fbl import ctrl_bler, slot_link
from iscc_gym.physics.kalman import isac_observation_matrix
from iscc_gym.physics.sensing import crlb, crlb_local
from iscc_gym.physics.stability import kalman_steady_state, lqg_cost, steady_state_covariance

S = SCENARIOS["paper"]


@pytest.fixture(scope="module")
def model():
    return analysis.static_model(S)


# --- building blocks ---------------------------------------------------------------------------
def test_local_crlb_matches_sensing_module(model):
    for a in (1e-3, 0.05, 0.2, 0.9):
        ours = sensing_share.local_crlb(model.sensing, a)
        ref = crlb_local(S, a, model.dist_m, model.trig, 0.0)
        for x, y in zip(ours, ref, strict=True):
            np.testing.assert_allclose(x, y, rtol=1e-10)


def test_crlb_trace_derivative_matches_finite_difference(model):
    a, h = 0.17, 1e-6
    tr, dtr = sensing_share.crlb_trace(model.sensing, a)
    trace = sensing_share.crlb_trace
    fd = (trace(model.sensing, a + h)[0] - trace(model.sensing, a - h)[0]) / (2 * h)
    np.testing.assert_allclose(dtr, fd, rtol=1e-5)
    m_r, m_tt, _, m_pp, _ = crlb_local(S, a, model.dist_m, model.trig, 0.0)
    np.testing.assert_allclose(tr, m_r + m_tt + m_pp, rtol=1e-12)
    assert np.all(dtr < 0)  # more sensing, smaller bound


def test_ctrl_goodput_derivative_matches_finite_difference():
    snr = 10.0 ** 1.2
    for a in (0.04, 0.045, 0.1):
        g, dg = fbl.ctrl_goodput_bits(S, a, snr)
        h = 1e-7
        fd = (fbl.ctrl_goodput_bits(S, a + h, snr)[0] - fbl.ctrl_goodput_bits(S, a - h, snr)[0]) / (2 * h)
        assert dg == pytest.approx(fd, rel=1e-4)
        eps, rate, _ = slot_link(S, a, 0.0, snr)
        assert g == pytest.approx((1 - eps) * rate * S.dt_s, rel=1e-12)
    g0, dg0 = fbl.ctrl_goodput_bits(S, 0.045, snr, ignore_loss=True)
    assert g0 == pytest.approx(0.045 * dg0) and g0 > fbl.ctrl_goodput_bits(S, 0.045, snr)[0]


def test_axis_kalman_equals_six_state_dare_in_the_local_frame(model):
    """Rotating to the principal axes of the CRLB splits the 6-state filter into three 2-state ones."""
    mm = model_matrices(S)
    a_sen = 0.05
    p_prior, est, _, _ = model.kalman(a_sen)
    for i in (0, 7, 123):
        cp, cv = crlb(S, a_sen, model.sample.pos_m[i], 0.0)
        los = geometry(S, model.sample.pos_m[i])[3]
        r = scipy.linalg.block_diag(cp, [[cv]])
        p6, est6 = kalman_steady_state(mm.a, isac_observation_matrix(los), mm.sigma_w, r)
        for ours, ref in ((p_prior[0, i], p6), (est[0, i], est6)):
            np.testing.assert_allclose(np.sort(ours[:, 0, 0]), np.linalg.eigvalsh(ref[:3, :3]), rtol=1e-6)
            assert ours[:, 1, 1].sum() == pytest.approx(np.trace(ref[3:, 3:]), rel=1e-6)
            assert ours[:, 0, 1].sum() == pytest.approx(np.trace(ref[:3, 3:]), rel=1e-6)


def test_single_position_evaluation_matches_the_six_state_recursion():
    """One position: tracking covariance Sigma_est + (I - M)^-1 vec(P - Sigma_est) and the LQG cost,
    from the stability module's DARE, vectorised recursion and lqg_cost."""
    pos = np.array([[300.0, -200.0, 180.0]])
    m = analysis.StaticModel(S, averages.TrajectorySample(pos, 1))
    mm = model_matrices(S)
    alpha = np.array([0.01, 0.12, 0.87])
    eps = float(m.eps_ctrl(alpha[1])[0])
    assert 0.0 < eps < 0.2
    cp, cv = crlb(S, alpha[0], pos[0], 0.0)
    los = geometry(S, pos[0])[3]
    p6, est6 = kalman_steady_state(mm.a, isac_observation_matrix(los), mm.sigma_w, scipy.linalg.block_diag(cp, [[cv]]))
    sig_x = est6 + steady_state_covariance(mm.a, mm.b, mm.k, eps, p6 - est6)
    res = m.evaluate(alpha)
    assert res.tracking_rmse_m[0] == pytest.approx(np.sqrt(np.trace(sig_x[:3, :3])), rel=1e-6)
    assert res.tracking_error_m[0] == pytest.approx(
        quadrature.expected_norm(np.linalg.eigvalsh(sig_x[:3, :3])), rel=1e-6)
    assert res.lqg_cost[0] == pytest.approx(lqg_cost(mm.q, mm.r, mm.k, eps, sig_x, est6), rel=1e-6)
    # the paper's recursion: eq:omega_tilde_cov fed to eq:covariance_recursion
    from iscc_gym.physics.stability import equivalent_noise_cov

    sig_p = steady_state_covariance(mm.a, mm.b, mm.k, eps, equivalent_noise_cov(mm.sigma_w, mm.b, mm.k, est6, eps))
    res_p = m.evaluate(alpha, recursion="paper")
    assert res_p.tracking_rmse_m[0] == pytest.approx(np.sqrt(np.trace(sig_p[:3, :3])), rel=1e-6)
    assert res_p.lqg_cost[0] == pytest.approx(lqg_cost(mm.q, mm.r, mm.k, eps, sig_p, est6), rel=1e-6)


def test_expected_norm_against_closed_form_and_monte_carlo():
    assert quadrature.expected_norm(np.array([4.0, 4.0, 4.0])) == pytest.approx(2 * 2 * np.sqrt(2 / np.pi), rel=1e-12)
    z = np.random.default_rng(0).standard_normal((400_000, 3))
    for lam in ([1.0, 0.1, 0.01], [0.04, 0.04, 1e-6], [9.0, 1.0, 1.0]):
        mc = np.linalg.norm(z * np.sqrt(lam), axis=1).mean()
        assert quadrature.expected_norm(np.array(lam)) == pytest.approx(mc, rel=4e-3)


@pytest.mark.parametrize("alpha, snr_db", [(0.05, 10.0), (0.1, 6.0), (0.3, 3.0), (0.03, 20.0)])
def test_mean_ctrl_loss_against_scipy_integral_over_the_rician_density(alpha, snr_db):
    """eq:ctrl_bler averaged over |g|^2 = sigma^2 chi'^2_2(2K) by scipy.integrate.quad (the oracle)."""
    from scipy import integrate, stats

    k = 10.0 ** (S.rician_k_db / 10.0)
    sigma2 = 0.5 / (k + 1.0)
    snr = 10.0 ** (snr_db / 10.0)
    pdf = stats.ncx2(2, 2.0 * k, scale=sigma2).pdf
    want = integrate.quad(lambda x: float(ctrl_bler(S, alpha, snr * x)) * pdf(x), 0.0, 30.0, limit=200,
                          points=[0.5, 1.0, 2.0])[0]
    got = quadrature.mean_ctrl_loss(S, alpha, snr)
    assert 1e-6 < want < 0.9  # a point where the average matters
    assert got == pytest.approx(want, rel=0.04, abs=1e-6)  # the 30-node rule: 2.6 % off at (0.3, 3 dB)
    # broadcast over shares and SNRs, each entry the scalar average
    grid = quadrature.mean_ctrl_loss(S, np.array([[alpha], [2 * alpha]]), np.array([snr, 2 * snr]))
    assert grid.shape == (2, 2) and grid[0, 0] == pytest.approx(got, rel=1e-12)


def test_loss_table_matches_direct_quadrature(model):
    a = np.array([0.03, 0.047, 0.081, 0.13, 0.4])
    direct = np.array([ctrl_bler(S, x, model._node_snr) @ model._node_w for x in a])
    np.testing.assert_allclose(model.eps_ctrl_local(a), direct, atol=2e-3)
    np.testing.assert_allclose(model.eps_ctrl(a), direct.mean(1), atol=3e-4)
    assert np.all(np.diff(model.eps_ctrl(a)) < 0)


def test_fading_and_shadowing_quadrature_against_sampling(model):
    """The node average of eq:ctrl_bler and of the data rate equals sampled slots (same positions)."""
    rng = np.random.default_rng(1)
    pos_idx = rng.integers(0, model.n_positions, 200_000)
    from iscc_gym.physics.channel import large_scale_snr, shadowing_std_db

    pos = model.sample.pos_m[pos_idx]
    sh = shadowing_std_db(S, pos[:, 2]) * rng.standard_normal(len(pos))
    snr = large_scale_snr(S, pos, sh) * rician_power_gain(S, rng.standard_normal(len(pos)),
                                                           rng.standard_normal(len(pos)))
    for a in (0.1, 0.2):
        eps, _, rate = slot_link(S, a, 1.0 - a, snr)
        assert model.eps_ctrl(a)[0] == pytest.approx(eps.mean(), abs=2e-3)
    assert model.rate_comm_per_share_bps == pytest.approx(slot_link(S, 0.0, 1.0, snr)[2].mean(), rel=5e-3)
    r_min = S.rate_min_bps
    short = np.maximum(0.0, r_min - slot_link(S, 0.0, 0.6, snr)[2]).mean() / r_min
    assert model.rate_shortfall(0.6)[0] == pytest.approx(short, abs=5e-3)


def test_evaluate_validates_input(model):
    with pytest.raises(ValueError, match="alpha"):
        model.evaluate([0.5, 0.5, 0.5])
    with pytest.raises(ValueError, match="alpha"):
        model.evaluate([0.5, 0.5])
    with pytest.raises(ValueError, match="recursion"):
        model.evaluate([0.2, 0.2, 0.6], recursion="bogus")
    with pytest.raises(ValueError, match="loss_average"):
        model.evaluate([0.2, 0.2, 0.6], loss_average="bogus")
    with pytest.raises(ValueError, match="control_mode"):
        analysis.StaticModel(S.replace(control_mode="open_loop"), model.sample)
    with pytest.raises(ValueError, match="n_trajectories"):
        averages.sample_positions(S, 0)


def test_feasibility_flags_and_monotone_trends(model):
    res = model.evaluate([[0.2, 0.2, 0.6], [0.2, 0.03, 0.77], [0.3, 0.4, 0.3], [0.05, 0.2, 0.75],
                          [0.01, 0.2, 0.79]])
    assert res.feasible[0] and not res.stable[1] and not res.rate_ok[2]
    assert res.tracking_error_m[1] == np.inf and res.objective[1] >= S.max_tracking_error_m
    assert res.rho_m[1] > 1.0 > res.rho_m[0]
    assert res.eps_ctrl[1] > model.eps_star > res.eps_ctrl[0]
    assert res.peb_m[4] > res.peb_m[3] > res.peb_m[0]  # less sensing, larger PEB ...
    assert res.tracking_error_m[4] > res.tracking_error_m[3] > res.tracking_error_m[0]  # ... larger error
    assert np.all(res.objective[res.feasible] == res.tracking_error_m[res.feasible])
    assert 0.39 < res.tracking_error_m[0] < 0.41  # the LQR floor with process noise is 0.392 m
    d = res.as_dict(0)
    assert isinstance(d["feasible"], bool) and len(d["alpha"]) == 3


def test_trust_bound_and_the_averaged_snr_reading(model):
    """trusted iff every sampled position's loss rate (recomputed here from eq:ctrl_bler by Monte Carlo
    over shadowing and Rician fading, not from the evaluator's table) is at most 0.4 eps*; the
    mean_snr reading is stable exactly above the paper's alpha_ctrl* (stability.alpha_ctrl_star)."""
    from iscc_gym.physics.channel import large_scale_snr, shadowing_std_db
    from iscc_gym.physics.stability import alpha_ctrl_star

    assert analysis.TRUST_LOSS_FRACTION == 0.4
    edge = model.alpha_ctrl_trusted()
    res = model.evaluate([[0.2, edge * 0.98, 0.8 - edge * 0.98], [0.2, edge * 1.02, 0.8 - edge * 1.02]])
    assert list(res.trusted) == [False, True] and list(res.stable) == [True, True]
    assert list(res.feasible) == [False, True] and res.objective[0] > S.max_tracking_error_m
    # independent oracle of the worst position's loss rate at the edge
    rng = np.random.default_rng(3)
    worst = np.argmax(model.eps_ctrl_local(edge)[0])
    pos = model.sample.pos_m[worst]
    sh = rng.standard_normal(200_000) * shadowing_std_db(S, pos[2:3])[0]
    snr = large_scale_snr(S, pos[None], 0.0)[0] * 10 ** (-sh / 10) * rician_power_gain(S, rng.standard_normal(200_000),
                                                                                 rng.standard_normal(200_000))
    mc = float(np.mean(ctrl_bler(S, edge, snr)))
    assert mc == pytest.approx(analysis.TRUST_LOSS_FRACTION * model.eps_star, rel=0.05)
    # the paper's averaged-SNR analysis: stable iff alpha_ctrl > alpha_ctrl*
    a_star = alpha_ctrl_star(S, model.mean_snr, model.eps_star)
    lit = model.evaluate([[0.2, a_star * 0.99, 0.8 - a_star * 0.99], [0.2, a_star * 1.01, 0.8 - a_star * 1.01]],
                         loss_average="mean_snr")
    assert list(lit.stable) == [False, True] and not lit.trusted.any()
    with pytest.raises(ValueError, match="trust_loss_fraction"):
        model.evaluate([0.2, 0.2, 0.6], trust_loss_fraction=0.0)
    assert model.evaluate([0.2, 0.09, 0.71], trust_loss_fraction=1.0).trusted[0]


def test_a_grid_of_splits_evaluates_in_one_call(model):
    g = np.arange(1, 100) / 100
    a_s, a_c = np.meshgrid(g, g, indexing="ij")
    keep = a_s + a_c < 1 - 1e-9
    splits = np.stack([a_s[keep], a_c[keep], 1 - a_s[keep] - a_c[keep]], -1)
    model.evaluate(splits[:5])  # build the lazy tables
    res = model.evaluate(splits)  # its speed: python -m eval.bench, never a timing assert
    assert len(splits) == 4851 and res.objective.shape == (4851,)
    assert np.isfinite(res.objective).all()


# --- the evaluator against rollouts of the env ----------------------------------------------------
def _rollout_mean(split, seeds):
    """Mean per-slot tracking error, data rate and loss rate of full episodes at a fixed split."""
    from iscc_gym.agents import FixedSplitPolicy

    policy = FixedSplitPolicy(split)
    env = gym.make("iscc_gym/ISCC-v0")
    errs, rates, eps = [], [], []
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        done = False
        while not done:
            action, _ = policy.predict(obs)
            obs, _, terminated, truncated, info = env.step(action)
            assert not terminated
            errs.append(info["tracking_error_m"])
            rates.append(info["rate_comm_bps"])
            eps.append(info["eps_ctrl"])
            done = terminated or truncated
    env.close()
    return np.mean(errs), np.mean(rates), np.mean(eps)


def test_analytic_error_agrees_with_monte_carlo_rollouts(model):
    """Two static splits, six full missions each (different trajectories from the model's sample):
    the steady-state mean tracking error within 15 % (the trajectory samples differ), the ordering
    of the two preserved, the exact recursion closer to the rollouts than the paper's
    eq:covariance_recursion."""
    healthy, starved = (0.2, 0.2, 0.6), (0.002, 0.2, 0.798)
    seeds = (11, 12, 13, 14, 15, 16)
    mc_h, rate_h, eps_h = _rollout_mean(healthy, seeds)
    mc_s, _, _ = _rollout_mean(starved, seeds)
    an = model.evaluate([healthy, starved])
    paper = model.evaluate([healthy, starved], recursion="paper")
    assert an.tracking_error_m[0] == pytest.approx(mc_h, rel=0.15)
    assert an.tracking_error_m[1] == pytest.approx(mc_s, rel=0.15)
    assert (an.tracking_error_m[1] - an.tracking_error_m[0]) * (mc_s - mc_h) > 0
    assert mc_s > 1.2 * mc_h  # the two are well separated
    assert abs(an.tracking_error_m[1] - mc_s) < abs(paper.tracking_error_m[1] - mc_s)
    assert an.rate_comm_bps[0] == pytest.approx(rate_h, rel=0.15)
    assert an.eps_ctrl[0] == pytest.approx(eps_h, abs=0.01)
