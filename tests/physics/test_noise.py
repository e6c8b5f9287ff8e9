"""The per-episode noise streams against scipy's normal distribution (the oracle)."""

import math

import numpy as np
import pytest
from scipy import stats

from iscc_gym.sim import noise

SLOTS = 100_000  # 1.8 M normals per key


@pytest.fixture(scope="module")
def draws():
    return noise.slot_normals(np.uint64(0x1234_5678_9ABC_DEF0), np.arange(SLOTS))


def test_ziggurat_layers_have_equal_area():
    """Every layer box [0, x_i] x [f(x_i), f(x_{i-1})] and the base strip (rectangle plus tail) has
    the area V; the outer edge is R."""
    k, w, f = noise._ZIG_K, noise._ZIG_W, noise._ZIG_F
    x = w * 2.0**52
    r = noise.ZIGGURAT_R
    v = r * math.exp(-0.5 * r * r) + math.sqrt(math.pi / 2) * math.erfc(r / math.sqrt(2))
    assert x[-1] == pytest.approx(r, rel=1e-15)
    assert x[0] * f[-1] == pytest.approx(v, rel=1e-12)  # base strip, tail included
    areas = x[1:] * (f[:-1] - f[1:])
    np.testing.assert_allclose(areas[1:], v, rtol=1e-9)
    assert areas[0] == pytest.approx(v, rel=1e-3)  # the top layer closes the curve at x = 0
    np.testing.assert_allclose(f[1:], np.exp(-0.5 * x[1:] ** 2), rtol=1e-14)
    assert k[1] == 0 and np.all(k[2:].astype(float) / 2.0**52 < 1.0)


def test_draws_are_standard_normal(draws):
    z = draws.ravel()
    assert stats.kstest(z, "norm").pvalue > 1e-3
    se = 1 / math.sqrt(z.size)
    assert abs(z.mean()) < 4 * se
    assert abs(z.var() - 1) < 4 * math.sqrt(2) * se
    assert abs(stats.skew(z)) < 4 * math.sqrt(6) * se
    assert abs(stats.kurtosis(z)) < 4 * math.sqrt(24) * se
    # chi-square over 64 equiprobable bins: the layers' edges leave no step in the density
    edges = stats.norm.ppf(np.linspace(0, 1, 65))
    counts = np.histogram(z, edges)[0]
    assert stats.chisquare(counts).pvalue > 1e-3


def test_tails_match_the_normal(draws):
    """The tail algorithm (beyond R) and the outer layers give the normal's tail mass."""
    z = draws.ravel()
    for t in (2.5, noise.ZIGGURAT_R, 4.2):
        p = 2 * stats.norm.sf(t)
        observed = np.mean(np.abs(z) > t)
        assert abs(observed - p) < 5 * math.sqrt(p * (1 - p) / z.size), t
    assert np.mean(z > noise.ZIGGURAT_R) > 0 and np.mean(z < -noise.ZIGGURAT_R) > 0


def test_draws_are_uncorrelated_across_columns_slots_and_keys(draws):
    tol = 5 / math.sqrt(SLOTS)
    corr = np.corrcoef(draws, rowvar=False)
    assert np.max(np.abs(corr - np.eye(noise.N_DRAWS))) < tol
    lag = np.corrcoef(draws[:-1].ravel(), draws[1:].ravel())[0, 1]
    assert abs(lag) < 5 / math.sqrt(draws.size)
    keys = np.arange(1, SLOTS + 1, dtype=np.uint64)  # neighbouring keys, same slot
    other = noise.slot_normals(keys, 0)
    assert np.max(np.abs(np.corrcoef(other, rowvar=False) - np.eye(noise.N_DRAWS))) < tol
    assert abs(np.corrcoef(other[:-1].ravel(), other[1:].ravel())[0, 1]) < 5 / math.sqrt(other.size)


def test_pure_function_of_key_and_slot():
    keys = np.array([3, 2**64 - 1, 17], dtype=np.uint64)
    n = np.array([0, 4999, 12])
    a = noise.slot_normals(keys, n)
    assert a.shape == (3, noise.N_DRAWS)
    for i in range(3):
        assert np.array_equal(noise.slot_normals(keys[i], n[i]), a[i])
    assert noise.slot_normals(keys[0], 1).shape == (noise.N_DRAWS,)
    assert not np.array_equal(noise.slot_normals(keys[0], 1), noise.slot_normals(keys[0], 0))
    assert not np.array_equal(noise.slot_normals(keys[0] + np.uint64(1), 0), a[0])
    assert noise.slot_normals(keys, 7, k=5).shape == (3, 5)


def test_bad_keys_and_slots_are_refused():
    with pytest.raises(TypeError, match="uint64"):
        noise.slot_normals(np.int64(3), 0)
    with pytest.raises(ValueError, match="slot index"):
        noise.slot_normals(np.uint64(3), -1)
    with pytest.raises(TypeError, match="Generator"):
        noise.draw_keys(None, None)
    with pytest.raises(TypeError, match="one Generator per drone"):
        noise.draw_keys([np.random.default_rng(0)], 2)


def test_draw_keys_per_generator_equals_single_draws():
    gens = [np.random.default_rng(i) for i in range(3)]
    keys = noise.draw_keys(gens, 3)
    assert keys.dtype == np.uint64
    for i in range(3):
        assert keys[i] == noise.draw_keys(np.random.default_rng(i), None)
    assert noise.draw_keys(np.random.default_rng(0), 4).shape == (4,)
    assert len(set(noise.draw_keys(np.random.default_rng(1), 1000).tolist())) == 1000
