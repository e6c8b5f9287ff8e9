"""Dryden low-altitude turbulence (iscc_gym.physics.wind) at the points MIL-F-8785C's formulas fix, and the gust
process's variance and correlation against Monte Carlo."""

import math

import numpy as np
import pytest

from iscc_gym.physics.wind import (
    FT_M,
    KNOT_MPS,
    W20_MPS,
    dryden_low_altitude,
    gust_phi,
    gust_step,
    gust_step_one,
)


def test_at_1000_ft_the_scale_lengths_are_1000_ft_and_the_intensities_equal():
    d = dryden_low_altitude(1000 * FT_M, W20_MPS["moderate"])
    for key in ("L_u_m", "L_v_m", "L_w_m"):
        assert d[key] == pytest.approx(304.8, rel=1e-12)
    sigma = 0.1 * 30 * KNOT_MPS  # 1.543 m/s: a tenth of 30 knots
    for key in ("sigma_u_mps", "sigma_v_mps", "sigma_w_mps"):
        assert d[key] == pytest.approx(sigma, rel=1e-12)


def test_low_altitude_values_by_hand():
    # h = 100 ft: 0.177 + 0.0823 = 0.2593; L_u = 100 / 0.2593^1.2 ft, sigma_u / sigma_w = 0.2593^-0.4
    d = dryden_low_altitude(100 * FT_M, W20_MPS["light"])
    assert d["L_w_m"] == pytest.approx(30.48)
    assert d["L_u_m"] == pytest.approx(100 / 0.2593 ** 1.2 * FT_M, rel=1e-12)  # 0.2593^1.2 = 0.1979: 505.2 ft
    assert d["L_u_m"] == pytest.approx(153.98, abs=0.01)
    assert d["sigma_u_mps"] / d["sigma_w_mps"] == pytest.approx(0.2593 ** -0.4, rel=1e-12)  # 1.716
    assert d["sigma_w_mps"] == pytest.approx(0.1 * 15 * 1852 / 3600)
    # the intensity ratio falls and the scale length grows towards 1000 ft
    h = np.array([20, 50, 200, 500, 999]) * FT_M
    many = dryden_low_altitude(h, 10.0)
    assert np.all(np.diff(many["sigma_u_mps"]) < 0) and np.all(np.diff(many["L_u_m"]) > 0)


@pytest.mark.parametrize("bad", [dict(altitude_m=1.0, w20_mps=5.0), dict(altitude_m=400.0, w20_mps=5.0),
                                 dict(altitude_m=50.0, w20_mps=-1.0), dict(altitude_m=50.0, w20_mps=math.nan)])
def test_out_of_range_inputs_are_named(bad):
    with pytest.raises(ValueError, match="altitude_m|w20_mps"):
        dryden_low_altitude(**bad)
    with pytest.raises(ValueError, match="scale_length_m"):
        gust_phi(10.0, 0.1, 0.0)


def test_the_gust_process_is_stationary_with_the_dryden_variance_and_correlation():
    d = dryden_low_altitude(50.0, W20_MPS["severe"])
    sigma, phi = float(d["sigma_u_mps"]), float(gust_phi(10.0, 0.1, d["L_u_m"]))
    assert phi == pytest.approx(math.exp(-10.0 * 0.1 / float(d["L_u_m"])))
    rng = np.random.default_rng(0)
    n_paths, n_steps = 4000, 400
    g = sigma * rng.standard_normal(n_paths)  # start in the stationary law
    g0 = g.copy()
    for _ in range(n_steps):
        g = gust_step(g, phi, sigma, rng.standard_normal(n_paths))
    assert np.var(g) == pytest.approx(sigma ** 2, rel=0.08)  # stationary variance
    assert np.corrcoef(g0, g)[0, 1] == pytest.approx(phi ** n_steps, abs=0.05)  # lag-400 correlation
    # the compiled scalar form is the array form
    z = rng.standard_normal(5)
    scalar = [gust_step_one(0.3, phi, sigma, zi) for zi in z]
    np.testing.assert_allclose(scalar, gust_step(0.3, phi, sigma, z), rtol=1e-15)
