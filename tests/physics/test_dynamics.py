"""Tests of iscc_gym.physics.dynamics against closed forms and scipy's DARE solver (paper, Sec. III-A)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
from hypothesis import given, settings
from hypothesis import strategies as st

from iscc_gym import SCENARIOS, Scenario
from iscc_gym.physics.dynamics import (
    lqg_weights,
    lqr_gain,
    model_matrices,
    process_noise_cov,
    system_matrices,
)

finite = st.floats(min_value=-1e3, max_value=1e3, allow_nan=False, allow_infinity=False)


def _spectral_radius(m):
    return float(np.max(np.abs(np.linalg.eigvals(m))))


def _scipy_lqr(a, b, q, r):
    """Oracle: P from scipy's DARE, K = (R + B'PB)^{-1} B'PA (eq:LQG_control_input)."""
    p = scipy.linalg.solve_discrete_are(a, b, q, r)
    k = np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a)
    return k, p


# --- eq:AB_matrices ---------------------------------------------------------------------------


@pytest.mark.parametrize("dt", [0.1, 0.05, 1.0, 0.37])
def test_system_matrices_block_structure(dt):
    a, b = system_matrices(dt)
    assert a.shape == (6, 6) and b.shape == (6, 3)
    i3 = np.eye(3)
    np.testing.assert_array_equal(a[:3, :3], i3)
    np.testing.assert_allclose(a[:3, 3:], dt * i3, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(a[3:, :3], np.zeros((3, 3)))
    np.testing.assert_array_equal(a[3:, 3:], i3)
    np.testing.assert_allclose(b[:3], 0.5 * dt * dt * i3, rtol=0, atol=1e-15)
    np.testing.assert_allclose(b[3:], dt * i3, rtol=0, atol=1e-15)


@settings(max_examples=40, deadline=None)
@given(px=finite, py=finite, pz=finite, v=finite, acc=finite,
       dt=st.floats(min_value=1e-3, max_value=2.0))
def test_newton_example_of_the_paper(px, py, pz, v, acc, dt):
    """Paper: x = [px, py, pz, v, 0, 0], u = [a, 0, 0]
    -> x+ = [px + v dt + a dt^2 / 2, py, pz, v + a dt, 0, 0]."""
    a, b = system_matrices(dt)
    x = np.array([px, py, pz, v, 0.0, 0.0])
    u = np.array([acc, 0.0, 0.0])
    expected = np.array([px + v * dt + 0.5 * acc * dt * dt, py, pz, v + acc * dt, 0.0, 0.0])
    np.testing.assert_allclose(a @ x + b @ u, expected, rtol=1e-12, atol=1e-9)


def test_system_matrices_is_exact_zoh_of_double_integrator():
    """A = expm(Ac dt), B = int_0^dt expm(Ac s) ds Bc for the continuous double integrator."""
    dt = 0.1
    ac = np.zeros((6, 6))
    ac[:3, 3:] = np.eye(3)
    bc = np.vstack([np.zeros((3, 3)), np.eye(3)])
    big = np.zeros((9, 9))
    big[:6, :6] = ac
    big[:6, 6:] = bc
    e = scipy.linalg.expm(big * dt)
    a, b = system_matrices(dt)
    np.testing.assert_allclose(a, e[:6, :6], atol=1e-14)
    np.testing.assert_allclose(b, e[:6, 6:], atol=1e-14)


# --- LQR gain ---------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["paper", "literal"])
def test_lqr_gain_matches_scipy_dare(name):
    s = SCENARIOS[name]
    a, b = system_matrices(s.dt_s)
    q, r = lqg_weights(s)
    k, p = lqr_gain(a, b, q, r)
    k_ref, p_ref = _scipy_lqr(a, b, q, r)
    assert k.shape == (3, 6) and p.shape == (6, 6)
    np.testing.assert_allclose(p, p_ref, rtol=1e-8, atol=1e-8 * np.abs(p_ref).max())
    np.testing.assert_allclose(k, k_ref, rtol=1e-8, atol=1e-8 * np.abs(k_ref).max())
    # and P solves the DARE as printed below eq:LQG_control_input
    resid = (a.T @ p @ a
             - a.T @ p @ b @ np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a) + q - p)
    assert np.abs(resid).max() <= 1e-8 * np.abs(p).max()


@pytest.mark.parametrize("q_pos,q_vel,r_w,dt", [(1e4, 1e2, 0.01, 0.1), (1.0, 0.0, 1.0, 0.1),
                                               (10.0, 3.0, 0.5, 0.5), (1e2, 1.0, 1e-3, 0.02)])
def test_lqr_gain_other_weights(q_pos, q_vel, r_w, dt):
    a, b = system_matrices(dt)
    q = np.diag([q_pos] * 3 + [q_vel] * 3)
    r = r_w * np.eye(3)
    k, p = lqr_gain(a, b, q, r)
    k_ref, p_ref = _scipy_lqr(a, b, q, r)
    np.testing.assert_allclose(k, k_ref, rtol=1e-7, atol=1e-9 * np.abs(k_ref).max())
    np.testing.assert_allclose(p, p_ref, rtol=1e-7, atol=1e-9 * np.abs(p_ref).max())
    assert _spectral_radius(a - b @ k) < 1.0


def test_lqg_weights_table_one():
    q, r = lqg_weights(Scenario())
    np.testing.assert_array_equal(q, np.diag([1e4] * 3 + [1e2] * 3))
    np.testing.assert_array_equal(r, 0.01 * np.eye(3))


def test_closed_loop_schur_stable_and_rho_squared():
    """rho(A - BK)^2 = rho(M(eps = 0)) ~ 0.109 for Table I weights.

    The paper reports rho(M) saturating "around 0.1" at large alpha_ctrl (Fig. subfig3); with
    eps -> 0, M -> (A-BK) kron (A-BK), whose spectral radius is rho(A-BK)^2.
    """
    s = Scenario()
    a, b = system_matrices(s.dt_s)
    q, r = lqg_weights(s)
    k_ref, _ = _scipy_lqr(a, b, q, r)
    mm = model_matrices(s)
    rho = _spectral_radius(a - b @ k_ref)
    assert rho < 1.0
    assert rho**2 == pytest.approx(0.109, abs=1e-3)
    assert _spectral_radius(mm.a_cl) ** 2 == pytest.approx(rho**2, rel=1e-9)
    m0 = np.kron(mm.a_cl, mm.a_cl)
    assert _spectral_radius(m0) == pytest.approx(0.109, abs=1e-3)


# --- process noise ------------------------------------------------------------------------------


@pytest.mark.parametrize("reading,pos_var,vel_var", [("variance", 0.2, 0.002),
                                                     ("std", 0.04, 4e-6)])
def test_process_noise_cov(reading, pos_var, vel_var):
    s = Scenario(process_noise_reading=reading)
    cov = process_noise_cov(s)
    expected = np.diag([pos_var] * 3 + [vel_var] * 3)
    np.testing.assert_allclose(cov, expected, rtol=1e-12, atol=0)
    assert s.process_noise_var_pos_m2 == pytest.approx(pos_var, rel=1e-12)
    assert s.process_noise_var_vel_m2s2 == pytest.approx(vel_var, rel=1e-12)


def test_process_noise_presets():
    np.testing.assert_allclose(np.diag(process_noise_cov(SCENARIOS["literal"])),
                               [0.2] * 3 + [0.002] * 3, rtol=1e-12)
    np.testing.assert_allclose(np.diag(process_noise_cov(SCENARIOS["paper"])),
                               [0.04] * 3 + [4e-6] * 3, rtol=1e-12)


# --- model_matrices -----------------------------------------------------------------------------


def test_model_matrices_cached_and_consistent():
    s = Scenario()
    mm = model_matrices(s)
    assert model_matrices(Scenario()) is mm  # equal frozen scenarios hit the cache
    assert model_matrices(s.replace(lqg_r=0.02)) is not mm
    a, b = system_matrices(s.dt_s)
    k_ref, p_ref = _scipy_lqr(a, b, *lqg_weights(s))
    np.testing.assert_array_equal(mm.a, a)
    np.testing.assert_array_equal(mm.b, b)
    np.testing.assert_allclose(mm.k, k_ref, rtol=1e-8)
    np.testing.assert_allclose(mm.p, p_ref, rtol=1e-8)
    np.testing.assert_allclose(mm.a_cl, a - b @ mm.k, atol=1e-14)
    np.testing.assert_allclose(mm.chol_w**2, np.diag(mm.sigma_w), rtol=1e-14)
    np.testing.assert_allclose(mm.sigma_w, process_noise_cov(s), rtol=0)


def test_model_matrices_read_only():
    mm = model_matrices(Scenario())
    for name in ("a", "b", "k", "p", "q", "r", "sigma_w", "a_cl", "chol_w"):
        arr = getattr(mm, name)
        assert not arr.flags.writeable, name
        with pytest.raises(ValueError):
            arr[0] = 1.0
    # the cached object must not accept new attributes either (__slots__)
    with pytest.raises(AttributeError):
        mm.extra = 1


def test_axis_matrices_are_one_axis_of_the_system_matrices():
    """A1, B1 written once (dynamics.axis_matrices); A, B are their Kronecker products with I3."""
    from iscc_gym.physics.dynamics import axis_matrices, system_matrices

    dt = 0.1
    a1, b1 = axis_matrices(dt)
    np.testing.assert_array_equal(a1, [[1.0, dt], [0.0, 1.0]])
    np.testing.assert_array_equal(b1, [[0.5 * dt**2], [dt]])
    a, b = system_matrices(dt)
    for ax in range(3):
        idx = [ax, ax + 3]
        np.testing.assert_array_equal(a[np.ix_(idx, idx)], a1)
        np.testing.assert_array_equal(b[idx, ax:ax + 1], b1)
