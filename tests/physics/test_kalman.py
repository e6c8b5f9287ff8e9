"""Tests of the Kalman filter against the textbook one (eq:observation_model, eq:KF_update): the numpy
oracle (tests/oracle_kalman.py) and the compiled per-drone forms of iscc_gym.physics.kalman."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from numba import njit
from oracle_kalman import kf_predict, kf_update, symmetrize

from iscc_gym import Scenario
from iscc_gym.physics.dynamics import model_matrices
from iscc_gym.physics.kalman import isac_observation_matrix, kf_predict_one, kf_update_whitened_one


def _random_spd(rng, n, log_lo=-2.0, log_hi=2.0):
    q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    ev = 10.0 ** rng.uniform(log_lo, log_hi, n)
    m = q @ np.diag(ev) @ q.T
    return 0.5 * (m + m.T)


def _unit(rng, shape=()):
    g = rng.standard_normal(shape + (3,))
    return g / np.linalg.norm(g, axis=-1, keepdims=True)


def _textbook_update(x, p, y, c, r):
    """Oracle: L = P C'(C P C' + R)^-1, x+ = x + L (y - C x), P+ = (I - L C) P (non-Joseph)."""
    s = c @ p @ c.T + r
    gain = p @ c.T @ np.linalg.inv(s)
    x_post = x + gain @ (y - c @ x)
    p_post = (np.eye(p.shape[0]) - gain @ c) @ p
    return x_post, p_post, gain


# --- observation matrix -------------------------------------------------------------------------


def test_isac_observation_matrix_structure():
    rng = np.random.default_rng(0)
    g = _unit(rng)
    c = isac_observation_matrix(g)
    assert c.shape == (4, 6)
    np.testing.assert_array_equal(c[:3, :3], np.eye(3))
    np.testing.assert_array_equal(c[:3, 3:], np.zeros((3, 3)))
    np.testing.assert_array_equal(c[3, :3], np.zeros(3))
    np.testing.assert_array_equal(c[3, 3:], g)
    x = rng.standard_normal(6)
    np.testing.assert_allclose(c @ x, np.concatenate([x[:3], [g @ x[3:]]]), atol=1e-14)


def test_isac_observation_matrix_batched():
    rng = np.random.default_rng(1)
    g = _unit(rng, (2, 5))
    c = isac_observation_matrix(g)
    assert c.shape == (2, 5, 4, 6)
    for i in range(2):
        for j in range(5):
            expected = np.zeros((4, 6))
            expected[:3, :3] = np.eye(3)
            expected[3, 3:] = g[i, j]
            np.testing.assert_array_equal(c[i, j], expected)


def test_symmetrize():
    rng = np.random.default_rng(2)
    m = rng.standard_normal((4, 6, 6))
    out = symmetrize(m)
    np.testing.assert_array_equal(out, np.swapaxes(out, -1, -2))
    np.testing.assert_allclose(out[1], 0.5 * (m[1] + m[1].T), atol=0)


# --- update and predict -------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(8))
def test_kf_update_matches_textbook(seed):
    rng = np.random.default_rng(seed)
    p = _random_spd(rng, 6)
    r = _random_spd(rng, 4)
    c = isac_observation_matrix(_unit(rng))
    x = rng.standard_normal(6) * 10
    y = rng.standard_normal(4) * 10
    x_post, p_post, gain = kf_update(x, p, y, c, r)
    x_ref, p_ref, gain_ref = _textbook_update(x, p, y, c, r)
    np.testing.assert_allclose(gain, gain_ref, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(x_post, x_ref, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(p_post, p_ref, rtol=1e-9, atol=1e-9)


def test_kf_update_general_observation_matrix():
    """Non-ISAC C (e.g. the full-state GNSS model, and a random 2 x 6 C)."""
    rng = np.random.default_rng(11)
    for c in (np.eye(6), rng.standard_normal((2, 6))):
        m = c.shape[0]
        p = _random_spd(rng, 6)
        r = _random_spd(rng, m)
        x, y = rng.standard_normal(6), rng.standard_normal(m)
        out = kf_update(x, p, y, c, r)
        for got, ref in zip(out, _textbook_update(x, p, y, c, r), strict=True):
            np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-9)


def test_kf_update_information_form():
    """Posterior information = prior information + C' R^-1 C (an independent identity)."""
    rng = np.random.default_rng(3)
    p = _random_spd(rng, 6)
    r = _random_spd(rng, 4)
    c = isac_observation_matrix(_unit(rng))
    _, p_post, _ = kf_update(np.zeros(6), p, np.zeros(4), c, r)
    info = np.linalg.inv(p) + c.T @ np.linalg.inv(r) @ c
    np.testing.assert_allclose(np.linalg.inv(p_post), info, rtol=1e-8,
                               atol=1e-8 * np.abs(info).max())


def test_kf_predict():
    rng = np.random.default_rng(4)
    s = Scenario()
    mm = model_matrices(s)
    p = _random_spd(rng, 6)
    x = rng.standard_normal(6)
    bu = mm.b @ rng.standard_normal(3)
    x_new, p_new = kf_predict(x, p, mm.a, bu, mm.sigma_w)
    np.testing.assert_allclose(x_new, mm.a @ x + bu, atol=1e-12)
    np.testing.assert_allclose(p_new, mm.a @ p @ mm.a.T + mm.sigma_w, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(p_new, p_new.T)


def test_batched_update_and_predict_equal_per_item():
    rng = np.random.default_rng(5)
    mm = model_matrices(Scenario())
    shape = (2, 3)
    p = np.stack([_random_spd(rng, 6) for _ in range(6)]).reshape(shape + (6, 6))
    r = np.stack([_random_spd(rng, 4, -6, 3) for _ in range(6)]).reshape(shape + (4, 4))
    c = isac_observation_matrix(_unit(rng, shape))
    x = rng.standard_normal(shape + (6,))
    y = rng.standard_normal(shape + (4,))
    xb, pb, gb = kf_update(x, p, y, c, r)
    bu = rng.standard_normal(shape + (3,)) @ mm.b.T
    xpb, ppb = kf_predict(xb, pb, mm.a, bu, mm.sigma_w)
    assert xb.shape == shape + (6,) and pb.shape == shape + (6, 6) and gb.shape == shape + (6, 4)
    for i in range(shape[0]):
        for j in range(shape[1]):
            xi, pi, gi = kf_update(x[i, j], p[i, j], y[i, j], c[i, j], r[i, j])
            np.testing.assert_allclose(xb[i, j], xi, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(pb[i, j], pi, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(gb[i, j], gi, rtol=1e-12, atol=1e-12)
            xpi, ppi = kf_predict(xi, pi, mm.a, bu[i, j], mm.sigma_w)
            np.testing.assert_allclose(xpb[i, j], xpi, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(ppb[i, j], ppi, rtol=1e-12, atol=1e-12)


# --- property: symmetric PSD under arbitrary drop / noise sequences ------------------------------


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**32 - 1),
    received=st.lists(st.booleans(), min_size=50, max_size=200),
    log_lo=st.floats(-9.0, 0.0),
    log_span=st.floats(0.0, 15.0),
    reading=st.sampled_from(["std", "variance"]),
)
def test_covariance_stays_symmetric_psd(seed, received, log_lo, log_span, reading):
    """Random CRLB-like SPD measurement covariances (eigenvalues spanning up to 15 decades), random
    unit LoS vectors, random received/dropped commands: P stays exactly symmetric and PSD."""
    rng = np.random.default_rng(seed)
    mm = model_matrices(Scenario(process_noise_reading=reading))
    log_hi = min(log_lo + log_span, 6.0)
    x = np.zeros(6)
    p = np.diag([0.25] * 3 + [0.01] * 3)

    def check(mat):
        assert np.all(np.isfinite(mat))
        assert np.array_equal(mat, mat.T)
        ev = np.linalg.eigvalsh(mat)
        assert ev[0] >= -1e-9 * ev[-1]

    for got in received:
        r = np.zeros((4, 4))
        r[:3, :3] = _random_spd(rng, 3, log_lo, log_hi)
        r[3, 3] = 10.0 ** rng.uniform(log_lo, log_hi)
        c = isac_observation_matrix(_unit(rng))
        y = c @ x + rng.standard_normal(4) * 5.0
        x, p, _ = kf_update(x, p, y, c, r)
        check(p)
        bu = mm.b @ (rng.standard_normal(3) * 3.0) if got else np.zeros(6)
        x, p = kf_predict(x, p, mm.a, bu, mm.sigma_w)
        check(p)


@pytest.mark.parametrize("seed", range(5))
def test_compiled_whitened_update_is_the_joseph_form(seed):
    """kalman.kf_update_whitened_one (rows one at a time) equals the batch Joseph form with unit noise."""
    rng = np.random.default_rng(seed)
    p = _random_spd(rng, 6)
    x, w = rng.standard_normal(6), rng.standard_normal((4, 6))
    y = rng.standard_normal(4)
    x_ref, p_ref, _ = kf_update(x, p, y, w, None)
    x_post, p_post, h = np.empty(6), np.empty((6, 6)), np.empty(6)
    kf_update_whitened_one(x, p, y, w, x_post, p_post, h)
    np.testing.assert_allclose(x_post, x_ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(p_post, p_ref, rtol=1e-9, atol=1e-12)
    assert np.array_equal(p_post, p_post.T)
    kf_update_whitened_one(x, p, y[:0], w[:0], x_post, p_post, h)  # no rows: the prior
    assert np.array_equal(x_post, x) and np.array_equal(p_post, p)


def test_compiled_time_update_is_the_dense_one():
    """kalman.kf_predict_one (blockwise A) equals A P A' + Sigma_w, symmetrised, and A x + B u."""
    s = Scenario()
    mm = model_matrices(s)
    rng = np.random.default_rng(3)
    p = _random_spd(rng, 6)
    x, bu = rng.standard_normal(6), rng.standard_normal(6)
    x_ref, p_ref = kf_predict(x, p, mm.a, bu, mm.sigma_w)
    x_next, p_next, pa = np.empty(6), np.empty((6, 6)), np.empty((6, 6))
    _predict(s.dt_s, x, p, bu, mm.sigma_w, x_next, p_next, pa)
    np.testing.assert_allclose(x_next, x_ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(p_next, p_ref, rtol=1e-12, atol=1e-12)
    assert np.array_equal(p_next, p_next.T)


@njit
def _predict(dt, x, p, bu, sigma_w, x_next, p_next, pa):
    kf_predict_one(dt, x, p, bu, sigma_w, x_next, p_next, pa)
