"""Tests of iscc_gym.physics.blockage against the 3GPP formulas at tabulated points, Monte Carlo and
the stated correlation (statistical tests that can fail)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from iscc_gym.physics import blockage as bl
from iscc_gym.physics.channel import path_loss_db as paper_path_loss_db
from iscc_gym.scenario import Scenario


def _table_b1(model, h, d):
    """TR 36.777 Table B-1 (22.5 < h <= 300 m) and TR 38.901 Table 7.4.2-1 (h <= 22.5 m), written out."""
    if h <= 22.5:
        if d <= 18:
            return 1.0
        if model == "umi_av":
            return 18 / d + math.exp(-d / 36) * (1 - 18 / d)
        c = 0.0 if h <= 13 else ((h - 13) / 10) ** 1.5
        return (18 / d + math.exp(-d / 63) * (1 - 18 / d)) * (1 + c * 5 / 4 * (d / 100) ** 3 * math.exp(-d / 150))
    if model == "uma_av":
        if h > 100:
            return 1.0
        p1, d1 = 4300 * math.log10(h) - 3800, max(460 * math.log10(h) - 700, 18)
    else:
        p1, d1 = 233.98 * math.log10(h) - 0.95, max(294.05 * math.log10(h) - 432.94, 18)
    return 1.0 if d <= d1 else d1 / d + math.exp(-d / p1) * (1 - d1 / d)


@pytest.mark.parametrize("model", ["uma_av", "umi_av"])
@pytest.mark.parametrize("h", [1.5, 10.0, 15.0, 22.5, 23.0, 30.0, 50.0, 80.0, 100.0, 150.0, 300.0])
def test_los_probability_at_table_points(model, h):
    d = np.array([5.0, 18.0, 40.0, 90.0, 250.0, 600.0, 1500.0])
    want = [_table_b1(model, h, x) for x in d]
    np.testing.assert_allclose(bl.los_probability(model, h, d), want, rtol=1e-12, atol=0)


def test_los_probability_hand_values_and_shape():
    # UMi-AV, h = 50 m, d = 500 m: p1 = 396.57, d1 = 66.64 (Table B-1 by hand)
    p1, d1 = 233.98 * 1.6989700043360187 - 0.95, 294.05 * 1.6989700043360187 - 432.94
    assert bl.los_probability("umi_av", 50.0, 500.0) == pytest.approx(d1 / 500 + math.exp(-500 / p1) * (1 - d1 / 500))
    assert 0.35 < bl.los_probability("umi_av", 50.0, 500.0) < 0.40
    assert bl.los_probability("uma_av", 150.0, 900.0) == 1.0  # UMa-AV above 100 m: always LoS
    assert bl.los_probability("none", 30.0, 900.0) == 1.0
    p = bl.los_probability("umi_av", np.array([[30.0], [60.0]]), np.linspace(20.0, 1000.0, 50))
    assert p.shape == (2, 50) and np.all(np.diff(p, axis=1) <= 0) and np.all((p > 0) & (p <= 1))
    with pytest.raises(ValueError, match="blockage model"):
        bl.los_probability("uma", 30.0, 100.0)


@pytest.mark.parametrize("h, d", [(30.0, 60.0), (50.0, 300.0), (90.0, 1200.0), (250.0, 700.0)])
def test_path_loss_table_b2(h, d):
    fc = 2.4
    lf, ld, lh = math.log10(fc), math.log10(d), math.log10(h)
    uma_los = 28.0 + 22.0 * ld + 20.0 * lf
    uma_nlos = -17.5 + (46.0 - 7.0 * lh) * ld + 20.0 * math.log10(40.0 * math.pi * fc / 3.0)
    fspl = 20.0 * math.log10(40.0 * math.pi * d * fc / 3.0)
    umi_los = max(fspl, 30.9 + (22.25 - 0.5 * lh) * ld + 20.0 * lf)
    umi_nlos = max(umi_los, 32.4 + (43.2 - 7.6 * lh) * ld + 20.0 * lf)
    s = Scenario()
    assert bl.path_loss_db("uma_av", True, h, d, fc) == pytest.approx(float(paper_path_loss_db(s, d)), abs=1e-12)
    assert bl.path_loss_db("none", False, h, d, fc) == pytest.approx(uma_los, abs=1e-12)
    assert bl.path_loss_db("uma_av", False, h, d, fc) == pytest.approx(uma_nlos, abs=1e-10)
    assert bl.path_loss_db("umi_av", True, h, d, fc) == pytest.approx(umi_los, abs=1e-10)
    assert bl.path_loss_db("umi_av", False, h, d, fc) == pytest.approx(umi_nlos, abs=1e-10)
    # blockage costs: tens of dB at urban ranges
    assert bl.excess_loss_db("umi_av", False, h, d, fc) > bl.excess_loss_db("umi_av", True, h, d, fc)


def test_nlos_costs_tens_of_db_at_low_altitude():
    ex = bl.excess_loss_db("umi_av", False, 40.0, 300.0, 2.4) - bl.excess_loss_db("umi_av", True, 40.0, 300.0, 2.4)
    assert 15.0 < ex < 35.0


def test_shadowing_std_table_b2():
    h = np.array([30.0, 100.0, 250.0])
    np.testing.assert_allclose(bl.shadowing_std_los_db("uma_av", h), 4.64 * np.exp(-0.0066 * h), rtol=1e-14)
    np.testing.assert_allclose(bl.shadowing_std_los_db("umi_av", h), np.maximum(5 * np.exp(-0.01 * h), 2.0),
                               rtol=1e-14)
    assert bl.shadowing_std_nlos_db("uma_av", 50.0) == 6.0 and bl.shadowing_std_nlos_db("umi_av", 50.0) == 8.0


@pytest.mark.parametrize("kernel, law", [("exponential", lambda u: math.exp(-u)),
                                         ("gaussian", lambda u: math.exp(-u * u))])
def test_field_correlation_matches_the_stated_kernel(kernel, law):
    """Across 600 independent fields the sample correlation at each lag is exp(-lag/d) (exponential) or
    exp(-(lag/d)^2) (gaussian) within 4 standard errors; the marginal is standard normal (KS test)."""
    rng = np.random.default_rng(11)
    d_corr = 50.0
    lags = np.array([0.0, 10.0, 25.0, 50.0, 100.0, 200.0])
    n = 600
    v0, vl = np.empty(n), np.empty((n, len(lags)))
    for i in range(n):
        f = bl.draw_field(rng, d_corr, kernel=kernel)
        ang = rng.uniform(0, 2 * np.pi)
        x0, y0 = rng.uniform(-1000, 1000, 2)
        v0[i] = bl.field_at(f, x0, y0)
        vl[i] = bl.field_at(f, x0 + lags * math.cos(ang), y0 + lags * math.sin(ang))
    for j, lag in enumerate(lags):
        rho = np.corrcoef(v0, vl[:, j])[0, 1] if lag > 0 else 1.0
        want = law(lag / d_corr)
        se = max((1.0 - want * want) / math.sqrt(n), 1e-9)
        assert abs(rho - want) < 4.0 * se, (lag, rho, want)
    assert abs(v0.mean()) < 4.0 / math.sqrt(n) and abs(v0.var() - 1.0) < 4.0 * math.sqrt(2.0 / n)
    assert stats.kstest(v0, "norm").pvalue > 1e-3


def test_field_is_one_value_per_place_and_vectorised():
    f = bl.draw_field(np.random.default_rng(0), 37.0)
    x = np.array([[1.0, 250.0], [-40.0, 7.5]])
    y = np.array([[3.0, -90.0], [12.0, 600.0]])
    v = bl.field_at(f, x, y)
    assert v.shape == (2, 2)
    assert v[1, 0] == bl.field_at(f, -40.0, 12.0) == bl.field_one(f, -40.0, 12.0)
    with pytest.raises(ValueError, match="corr_distance_m"):
        bl.draw_field(np.random.default_rng(0), 0.0)
    with pytest.raises(ValueError, match="kernel"):
        bl.draw_field(np.random.default_rng(0), 37.0, kernel="matern")


@pytest.mark.parametrize("p", [0.2, 0.6])
@pytest.mark.parametrize("se", [0.3, 0.7])
def test_map_los_probability_is_the_posterior(p, se):
    """Monte Carlo of truth = rho m + se e: the LoS frequency given the map's m equals the formula, and its
    mean over maps is the prior."""
    rng = np.random.default_rng(5)
    m, e = rng.standard_normal((2, 400_000))
    rho = math.sqrt(1 - se * se)
    los = rho * m + se * e < stats.norm.ppf(p)
    q = bl.map_los_probability(p, m, se)
    assert q.mean() == pytest.approx(p, abs=4e-3)
    edges = np.quantile(m, np.linspace(0, 1, 9))
    idx = np.clip(np.searchsorted(edges, m) - 1, 0, 7)
    for b in range(8):
        sel = idx == b
        assert los[sel].mean() == pytest.approx(q[sel].mean(), abs=6e-3)
    assert np.all(bl.map_los_probability(p, m[:5], 1.0) == pytest.approx(p))
    assert set(np.unique(bl.map_los_probability(p, m[:100], 0.0))) <= {0.0, 1.0}
    with pytest.raises(ValueError, match="map_error_std"):
        bl.map_los_probability(p, 0.0, 1.5)
