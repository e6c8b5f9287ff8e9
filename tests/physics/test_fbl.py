"""Tests of iscc_gym.physics.fbl: dispersion, Q / Q^-1, the FBL rate (eq:rate_equation) and the control
packet-drop probability (eq:ctrl_bler).

Oracles: the paper's formulas written out with math / numpy and scipy.stats.norm (sf, isf).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import norm

from iscc_gym.physics import fbl
from iscc_gym.scenario import SCENARIOS, Scenario

S = Scenario()
LOG2E = 1.0 / math.log(2.0)
SNRS = np.array([0.0, 1e-6, 1e-3, 0.1, 0.5, 1.0, 3.0, 10.0, 100.0, 1e4, 1e7])

# Hypothesis: deterministic and few examples so the suite stays fast.
FAST = settings(max_examples=60, deadline=None, derandomize=True)


def _v(g):
    """Channel dispersion (log2 e)^2 [1 - (1 + g)^-2], the paper below eq:rate_equation.

    Written as g (2 + g) / (1 + g)^2, which is algebraically identical but free of the
    cancellation of 1 - (1 + g)^-2 at small g.
    """
    return LOG2E**2 * g * (2.0 + g) / (1.0 + g) ** 2


def _rate(alpha, b, g, blocklength, eps):
    """eq:rate_equation with scipy's Q^-1 = norm.isf (unclipped)."""
    return alpha * b * (math.log2(1.0 + g) - math.sqrt(_v(g) / blocklength) * norm.isf(eps))


# --------------------------------------------------------------------------------------------------
# dispersion, Q, Q^-1
# --------------------------------------------------------------------------------------------------
def test_dispersion_formula():
    expected = [_v(float(g)) for g in SNRS]
    # the printed form 1 - (1+g)^-2 loses ~eps/(2g) relative accuracy to cancellation:
    # 5e-11 at g = 1e-6, hence rtol 1e-9 (1e-12 for g >= 1e-3)
    np.testing.assert_allclose(fbl.dispersion(SNRS), expected, rtol=1e-9, atol=1e-300)
    np.testing.assert_allclose(fbl.dispersion(SNRS[2:]), expected[2:], rtol=1e-12)
    assert fbl.dispersion(0.0) == 0.0
    # high-SNR limit (log2 e)^2 = 2.0814
    assert fbl.dispersion(1e12) == pytest.approx(LOG2E**2, rel=1e-12)
    # gamma = 1: (log2 e)^2 * 3/4
    assert fbl.dispersion(1.0) == pytest.approx(0.75 * LOG2E**2, rel=1e-14)


def test_dispersion_broadcasts():
    g = np.array([[0.5, 2.0], [9.0, 99.0]])
    np.testing.assert_allclose(fbl.dispersion(g), _v(g), rtol=1e-13)


def test_q_func_vs_scipy():
    x = np.array([-8.0, -3.0, -1.0, -0.1, 0.0, 0.3, 1.0, 2.5, 4.26, 6.0, 10.0, 20.0, 37.0])
    np.testing.assert_allclose(fbl.q_func(x), norm.sf(x), rtol=1e-12, atol=0.0)
    assert fbl.q_func(0.0) == 0.5
    assert fbl.q_func(np.inf) == 0.0
    assert fbl.q_func(-np.inf) == 1.0


def test_q_inv_vs_scipy():
    p = np.array([1e-300, 1e-12, 1e-5, 1e-3, 0.01, 0.2, 0.5, 0.7, 0.99, 1 - 1e-9])
    np.testing.assert_allclose(fbl.q_inv(p), norm.isf(p), rtol=1e-9, atol=1e-12)
    # Table I BLER targets
    assert fbl.q_inv(1e-5) == pytest.approx(4.264890793922825, rel=1e-12)
    assert fbl.q_inv(1e-3) == pytest.approx(3.090232306167813, rel=1e-12)


@FAST
@given(st.floats(min_value=1e-12, max_value=0.5 - 1e-9))
def test_q_inv_inverts_q(p):
    assert fbl.q_func(fbl.q_inv(p)) == pytest.approx(p, rel=1e-9)


# --------------------------------------------------------------------------------------------------
# FBL rate, eq:rate_equation
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("blocklength, eps", [(50, 1e-5), (8000, 1e-3), (200, 0.1)])
@pytest.mark.parametrize("snr", [0.5, 3.0, 31.6, 1000.0])
def test_fbl_rate_formula(blocklength, eps, snr):
    expected = _rate(0.3, 10e6, snr, blocklength, eps)
    if snr > 1.0:
        assert expected > 0  # the grid is not only clipped values
    got = fbl.fbl_rate_bps(0.3, 10e6, snr, blocklength, eps)
    expected = max(expected, 0.0)
    assert got == pytest.approx(expected, rel=1e-11)
    # below Shannon capacity
    assert got < 0.3 * 10e6 * math.log2(1 + snr)


@FAST
@given(alpha=st.floats(0.0, 1.0), snr=st.floats(1e-2, 1e5),
       blocklength=st.integers(10, 10000), eps=st.floats(1e-9, 0.4))
def test_fbl_rate_formula_property(alpha, snr, blocklength, eps):
    expected = max(_rate(alpha, 1e7, snr, blocklength, eps), 0.0)
    got = float(fbl.fbl_rate_bps(alpha, 1e7, snr, blocklength, eps))
    assert got == pytest.approx(expected, rel=1e-9, abs=1e-6)


def test_fbl_rate_clipped_at_zero_at_low_snr():
    # at gamma = 1e-4 the dispersion penalty exceeds the capacity term for L = 50, eps = 1e-5
    assert _rate(1.0, 1e7, 1e-4, 50, 1e-5) < 0.0
    assert fbl.fbl_rate_bps(1.0, 1e7, 1e-4, 50, 1e-5) == 0.0
    r = fbl.fbl_rate_bps(1.0, 1e7, np.array([0.0, 1e-6, 1e-4, 1e-3]), 50, 1e-5)
    np.testing.assert_array_equal(r, 0.0)


def test_fbl_rate_linear_in_alpha():
    alphas = np.linspace(0.0, 1.0, 11)
    r = fbl.fbl_rate_bps(alphas, 1e7, 20.0, 8000, 1e-3)
    per_unit = _rate(1.0, 1e7, 20.0, 8000, 1e-3)
    np.testing.assert_allclose(r, alphas * per_unit, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(np.diff(r), per_unit / 10, rtol=1e-9)


def test_fbl_rate_broadcast_shapes():
    alpha = np.array([0.1, 0.5])[:, None]
    snr = np.array([1.0, 10.0, 100.0])[None, :]
    r = fbl.fbl_rate_bps(alpha, 1e7, snr, 50, 1e-5)
    assert r.shape == (2, 3)
    for i in range(2):
        for j in range(3):
            assert r[i, j] == pytest.approx(
                _rate(alpha[i, 0], 1e7, snr[0, j], 50, 1e-5), rel=1e-11)


def test_comm_and_ctrl_rates_use_table_i_links():
    g = 50.0
    assert fbl.comm_rate_bps(S, 0.7, g) == pytest.approx(_rate(0.7, 10e6, g, 8000, 1e-3), rel=1e-11)
    assert fbl.ctrl_rate_bps(S, 0.05, g) == pytest.approx(_rate(0.05, 10e6, g, 50, 1e-5), rel=1e-11)
    # the short control packet pays a larger FBL penalty than the long data packet
    assert fbl.ctrl_rate_bps(S, 1.0, g) < fbl.comm_rate_bps(S, 1.0, g)


# --------------------------------------------------------------------------------------------------
# control packet drop, eq:ctrl_bler
# --------------------------------------------------------------------------------------------------
def _ctrl_bler(s, alpha, g):
    """eq:ctrl_bler with T_d = ctrl_deadline_s, evaluated with scipy.stats.norm.sf."""
    need = s.ctrl_packet_bits / (s.ctrl_deadline_s * alpha * s.bandwidth_hz)
    arg = math.sqrt(s.ctrl_blocklength / _v(g)) * (math.log2(1.0 + g) - need)
    return norm.sf(arg)


@pytest.mark.parametrize("scenario", [Scenario(), SCENARIOS["literal"]], ids=["paper", "literal"])
def test_ctrl_bler_direct_formula(scenario):
    checked_interior = 0
    for alpha in [0.005, 0.02, 0.0403, 0.06, 0.1, 0.5]:
        for g in [0.05, 1.0, 5.0, 12.0, 20.0, 40.0, 100.0, 1e3]:
            expected = _ctrl_bler(scenario, alpha, g)
            got = float(fbl.ctrl_bler(scenario, alpha, g))
            assert got == pytest.approx(expected, rel=1e-9, abs=1e-300)
            checked_interior += 1e-12 < expected < 1 - 1e-12
    assert checked_interior >= 5  # the grid exercises the transition, not only 0 and 1


def test_ctrl_bler_known_point():
    # S = 256 bit, T_d = 1.8e-4 s, B = 10 MHz, alpha = 0.05 -> 256 / 90 = 2.8444 bit/use needed
    s = S.replace(ctrl_packet_bits=256, ctrl_deadline_s=1.8e-4, bandwidth_hz=10e6,
                  ctrl_blocklength=50)
    need = 256 / 90
    g = 2.0**need * 1.2 - 1.0  # capacity exceeds the need by log2(1.2) bit
    arg = math.sqrt(50 / _v(g)) * math.log2(1.2)
    assert float(fbl.ctrl_bler(s, 0.05, g)) == pytest.approx(norm.sf(arg), rel=1e-10)
    # exactly at capacity = need the argument is 0 and the drop probability is 1/2
    assert float(fbl.ctrl_bler(s, 0.05, 2.0**need - 1.0)) == pytest.approx(0.5, abs=1e-9)


def test_ctrl_bler_alpha_zero_is_one():
    g = np.array([0.0, 1e-3, 1.0, 100.0, 1e6])
    np.testing.assert_array_equal(fbl.ctrl_bler(S, 0.0, g), 1.0)
    np.testing.assert_array_equal(fbl.ctrl_bler(S, np.zeros(5), g), 1.0)


def test_ctrl_bler_zero_snr_is_one():
    np.testing.assert_array_equal(fbl.ctrl_bler(S, np.array([0.01, 0.5, 1.0]), 0.0), 1.0)


def test_ctrl_bler_monotone_in_alpha():
    alpha = np.linspace(0.0, 1.0, 2001)
    for g in [5.0, 20.0, 100.0]:
        e = fbl.ctrl_bler(S, alpha, g)
        assert np.all(np.diff(e) <= 0.0)
        inner = (e[:-1] < 1.0) & (e[1:] > 1e-250)
        assert np.all(np.diff(e)[inner] < 0.0)  # strict where not saturated
        assert e[0] == 1.0 and e[-1] < 1e-6


def test_ctrl_bler_monotone_in_snr():
    g = np.logspace(-4, 5, 3000)
    for alpha in [0.02, 0.0403, 0.1]:
        e = fbl.ctrl_bler(S, alpha, g)
        assert np.all(np.diff(e) <= 0.0)
        assert e[0] == pytest.approx(1.0) and e[-1] < 1e-12


# Tiny positive alpha (~1e-300) with SNR 0 overflows inside ctrl_bler (RuntimeWarning, outside its
# np.errstate); the returned value is still the correct 1.0, which is what this test checks.
@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
@FAST
@given(alpha=st.floats(0.0, 1.0), snr=st.floats(0.0, 1e6))
def test_ctrl_bler_is_a_probability(alpha, snr):
    for s in (S, SCENARIOS["literal"]):
        e = float(fbl.ctrl_bler(s, alpha, snr))
        assert 0.0 <= e <= 1.0
        assert not math.isnan(e)


def test_ctrl_bler_deadline_reading():
    # the literal T_d = dt = 0.1 s needs far fewer bits per channel use than the calibrated T_d
    lit = SCENARIOS["literal"]
    assert S.ctrl_deadline_s < lit.ctrl_deadline_s
    assert lit.ctrl_deadline_s == 0.1
    e_lit = float(fbl.ctrl_bler(lit, 0.0403, 10.0))
    e_cal = float(fbl.ctrl_bler(S, 0.0403, 10.0))
    assert e_lit == pytest.approx(_ctrl_bler(lit, 0.0403, 10.0), rel=1e-9, abs=1e-300)
    assert e_lit < e_cal
