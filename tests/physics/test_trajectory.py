"""Tests of iscc_gym.trajectory (paper Sec. V-A): Poisson waypoints in the coverage region and the
clamped cubic-spline reference, against Monte Carlo volumes, Poisson statistics, exact volume
fractions, scipy's CubicSpline with independently derived knot times and finite differences."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats
from scipy.interpolate import CubicSpline

from iscc_gym import Scenario
from iscc_gym.trajectory import (
    coverage_volume_km3,
    in_coverage,
    order_waypoints,
    sample_reference,
    sample_waypoints,
    spline_reference,
)

S = Scenario()
N_DRAWS = 2000


def _slab_volume_m3(radius, lo, hi):
    """Volume of {|p| <= radius, lo < z <= hi} (hemisphere slab), by the disc-area integral."""
    return np.pi * (radius**2 * (hi - lo) - (hi**3 - lo**3) / 3.0)


def _mc_volume_km3(s, n, rng):
    r = s.coverage_radius_m
    lo = np.array([-r, -r, s.altitude_min_m])
    hi = np.array([r, r, s.altitude_max_m])
    pts = rng.uniform(lo, hi, size=(n, 3))
    inside = ((np.sqrt(np.sum(pts**2, axis=1)) <= r)
              & (pts[:, 2] > s.altitude_min_m) & (pts[:, 2] <= s.altitude_max_m))
    box = np.prod(hi - lo) * 1e-9
    frac = inside.mean()
    return box * frac, box * np.sqrt(frac * (1 - frac) / n)


@pytest.fixture(scope="module")
def waypoint_draws():
    rng = np.random.default_rng(2024)
    return [sample_waypoints(S, rng) for _ in range(N_DRAWS)]


# --- coverage region ----------------------------------------------------------------------------


@pytest.mark.parametrize("overrides", [{}, {"altitude_min_m": 30.0, "altitude_max_m": 900.0},
                                       {"coverage_radius_m": 500.0, "altitude_max_m": 450.0}])
def test_coverage_volume_matches_monte_carlo(overrides):
    s = S.replace(**overrides)
    vol = coverage_volume_km3(s)
    mc, se = _mc_volume_km3(s, 400_000, np.random.default_rng(7))
    assert abs(vol - mc) < 5 * se
    assert vol == pytest.approx(mc, rel=0.01)


def test_coverage_volume_table_one():
    # pi (R^2 (h1 - h0) - (h1^3 - h0^3) / 3) with R = 1 km, (h0, h1] = (0.1, 0.3] km
    assert coverage_volume_km3(S) == pytest.approx(np.pi * (0.2 - (0.027 - 0.001) / 3), rel=1e-12)


def test_in_coverage_boundaries():
    pts = np.array([
        [0.0, 0.0, 200.0],        # inside
        [0.0, 0.0, 100.0],        # altitude_min is open: excluded
        [0.0, 0.0, 300.0],        # altitude_max is closed: included
        [0.0, 0.0, 300.0001],     # above the band
        [0.0, 0.0, 99.999],       # below the band
        [990.0, 0.0, 150.0],      # |p| = 1001.2 > 1000
        [900.0, 400.0, 150.0],    # |p| = 996.2 <= 1000
    ])
    expected = [True, False, True, False, False, False, True]
    assert in_coverage(S, pts).tolist() == expected
    assert in_coverage(S, pts.reshape(7, 1, 3)).shape == (7, 1)


# --- Poisson waypoints --------------------------------------------------------------------------


def test_waypoints_in_coverage_and_count(waypoint_draws):
    for wp in waypoint_draws:
        assert wp.ndim == 2 and wp.shape[1] == 3
        assert len(wp) >= S.min_waypoints
        assert np.all(in_coverage(S, wp))


def test_waypoint_count_is_conditioned_poisson(waypoint_draws):
    """Count ~ Poisson(intensity * volume) conditioned on >= min_waypoints (mean ~9.02)."""
    mu = S.waypoint_intensity_per_km3 * _slab_volume_m3(1000.0, 100.0, 300.0) * 1e-9
    assert mu == pytest.approx(9.0164, abs=1e-3)
    k = np.arange(S.min_waypoints)
    p_low = stats.poisson.pmf(k, mu)
    cond_mean = (mu - np.sum(k * p_low)) / (1 - p_low.sum())
    counts = np.array([len(w) for w in waypoint_draws])
    se = counts.std() / np.sqrt(len(counts))
    assert abs(counts.mean() - cond_mean) < 4 * se
    assert abs(counts.mean() - mu) < 0.35  # conditioning barely matters at mu ~ 9
    # and the variance is Poisson-like (conditional variance ~ mu)
    assert counts.var() == pytest.approx(mu, rel=0.15)
    assert counts.min() >= S.min_waypoints


def test_waypoint_count_respects_min_waypoints_at_low_intensity():
    s = S.replace(waypoint_intensity_per_km3=1.0, min_waypoints=5)  # mean 0.6 points
    rng = np.random.default_rng(3)
    counts = [len(sample_waypoints(s, rng)) for _ in range(200)]
    assert min(counts) >= 5
    # P(N = 5 | N >= 5) for Poisson(0.6) is ~0.88
    assert np.mean(np.asarray(counts) == 5) > 0.75


def test_waypoints_uniform_in_region(waypoint_draws):
    pts = np.concatenate(waypoint_draws)
    n = len(pts)
    total = _slab_volume_m3(1000.0, 100.0, 300.0)
    # lower half of the altitude band
    p_low = _slab_volume_m3(1000.0, 100.0, 200.0) / total
    frac = np.mean(pts[:, 2] <= 200.0)
    assert abs(frac - p_low) < 4 * np.sqrt(p_low * (1 - p_low) / n)
    # inner ball of radius 700 m
    p_in = _slab_volume_m3(700.0, 100.0, 300.0) / total
    frac = np.mean(np.linalg.norm(pts, axis=1) <= 700.0)
    assert abs(frac - p_in) < 4 * np.sqrt(p_in * (1 - p_in) / n)
    # horizontal isotropy: the four azimuth quadrants are equally likely
    quad = (pts[:, 0] > 0).astype(int) * 2 + (pts[:, 1] > 0).astype(int)
    observed = np.bincount(quad, minlength=4)
    assert stats.chisquare(observed).pvalue > 1e-4


# --- waypoint order ----------------------------------------------------------------------------


def test_order_waypoints_greedy_nearest_neighbour():
    pts = np.array([[0.0, 0, 0], [10, 0, 0], [1, 0, 0], [5, 0, 0], [2, 0, 0]])
    np.testing.assert_array_equal(order_waypoints(pts),
                                  pts[[0, 2, 4, 3, 1]])


# --- spline reference ---------------------------------------------------------------------------

# chord lengths 100, 200, 100 -> knot times 0, 125, 375, 500 s = slots 0, 1250, 3750, 5000
GRID_WP = np.array([[0.0, 0.0, 150.0], [100.0, 0.0, 150.0], [100.0, 200.0, 150.0],
                    [100.0, 200.0, 250.0]])
GRID_SLOTS = [0, 1250, 3750, 5000]


def test_spline_passes_through_waypoints_at_knot_times():
    ref = spline_reference(S, GRID_WP)
    assert ref.pos_m.shape == (S.n_slots + 1, 3)
    np.testing.assert_allclose(ref.t_s, np.arange(S.n_slots + 1) * 0.1, atol=1e-9)
    for wp, n in zip(GRID_WP, GRID_SLOTS, strict=True):
        np.testing.assert_allclose(ref.pos_m[n], wp, atol=1e-8)
    # between knots the spline is not at a waypoint
    assert np.min(np.linalg.norm(ref.pos_m[625] - GRID_WP, axis=1)) > 1.0


def test_spline_matches_scipy_clamped_spline():
    ref = spline_reference(S, GRID_WP)
    cs = CubicSpline([0.0, 125.0, 375.0, 500.0], GRID_WP, bc_type="clamped")
    t = np.arange(5001) * 0.1
    np.testing.assert_allclose(ref.pos_m, cs(t), atol=1e-8)
    np.testing.assert_allclose(ref.vel_mps, cs(t, 1), atol=1e-9)
    np.testing.assert_allclose(ref.acc_mps2, cs(t, 2), atol=1e-9)
    np.testing.assert_allclose(ref.state, np.concatenate([cs(t), cs(t, 1)], axis=1), atol=1e-8)


def test_spline_drops_repeated_waypoints():
    dup = np.insert(GRID_WP, 2, GRID_WP[1], axis=0)
    ref = spline_reference(S, dup)
    np.testing.assert_allclose(ref.pos_m, spline_reference(S, GRID_WP).pos_m, atol=1e-9)
    assert len(ref.waypoints_m) == 4


def _knot_times(wp, total):
    chord = np.linalg.norm(np.diff(wp, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(chord)]) / chord.sum() * total


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_reference_interpolates_and_finite_differences(seed):
    ref = sample_reference(S, np.random.default_rng(seed))
    dt = S.dt_s
    p, v, a = ref.pos_m, ref.vel_mps, ref.acc_mps2
    knots = _knot_times(ref.waypoints_m, S.mission_duration_s)
    # passes through every (ordered) waypoint at its chord-length knot time
    cs = CubicSpline(knots, ref.waypoints_m, bc_type="clamped")
    np.testing.assert_allclose(p, cs(ref.t_s), atol=1e-7)
    np.testing.assert_allclose(cs(knots), ref.waypoints_m, atol=1e-7)
    # clamped end conditions
    np.testing.assert_allclose(v[0], 0.0, atol=1e-10)
    np.testing.assert_allclose(v[-1], 0.0, atol=1e-10)
    np.testing.assert_allclose(p[0], ref.waypoints_m[0], atol=1e-8)
    np.testing.assert_allclose(p[-1], ref.waypoints_m[-1], atol=1e-8)
    # away from knots the spline is one cubic on [t-dt, t+dt]: central differences are exact
    t = ref.t_s[1:-1]
    smooth = np.all(np.abs(t[:, None] - knots[None, :]) > 1.01 * dt, axis=1)
    assert smooth.mean() > 0.99
    cd_v = (p[2:] - p[:-2]) / (2 * dt)
    jerk = (a[2:] - a[:-2]) / (2 * dt)
    np.testing.assert_allclose((cd_v - dt**2 / 6 * jerk)[smooth], v[1:-1][smooth], atol=1e-7)
    np.testing.assert_allclose(((v[2:] - v[:-2]) / (2 * dt))[smooth], a[1:-1][smooth], atol=1e-7)
    np.testing.assert_allclose(((p[2:] - 2 * p[1:-1] + p[:-2]) / dt**2)[smooth],
                               a[1:-1][smooth], atol=1e-6)
    # everywhere (including across knots) to first order
    assert np.abs(cd_v - v[1:-1]).max() < 1e-2 * max(1.0, np.abs(v).max())
    assert np.abs((v[2:] - v[:-2]) / (2 * dt) - a[1:-1]).max() < 2e-2 * max(1.0, np.abs(a).max())


# --- sample_reference ---------------------------------------------------------------------------


def test_sample_reference_shape_and_coverage():
    for seed in range(10):
        ref = sample_reference(S, np.random.default_rng(seed))
        assert S.n_slots == 5000
        for arr in (ref.pos_m, ref.vel_mps, ref.acc_mps2):
            assert arr.shape == (5001, 3)
        assert ref.state.shape == (5001, 6)
        assert ref.t_s.shape == (5001,)
        assert np.all(in_coverage(S, ref.pos_m))
        assert len(ref.waypoints_m) >= S.min_waypoints
        assert np.all(in_coverage(S, ref.waypoints_m))


def test_sample_reference_seed_determinism():
    r1 = sample_reference(S, np.random.default_rng(42))
    r2 = sample_reference(S, np.random.default_rng(42))
    r3 = sample_reference(S, np.random.default_rng(43))
    for name in ("t_s", "pos_m", "vel_mps", "acc_mps2", "waypoints_m"):
        np.testing.assert_array_equal(getattr(r1, name), getattr(r2, name))
    assert not np.array_equal(r1.pos_m, r3.pos_m)



# --- scenarios whose condition is rare: bounded redraws (issue 12) -------------------------------


class _Deadline:
    """Fail (instead of hanging) when the body runs longer than ``seconds`` (SIGALRM, main thread)."""

    def __init__(self, seconds):
        self.seconds = seconds

    def __enter__(self):
        import signal

        def fail(*_):
            raise TimeoutError(f"did not return within {self.seconds} s")

        self._old = signal.signal(signal.SIGALRM, fail)
        signal.setitimer(signal.ITIMER_REAL, self.seconds)

    def __exit__(self, *exc):
        import signal

        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, self._old)


@pytest.mark.parametrize("overrides", [
    {"min_waypoints": 16, "waypoint_intensity_per_km3": 0.1},   # P(N >= 16) ~ 1e-33 at mean 0.06
    {"waypoint_intensity_per_km3": 0.01},                        # mean 0.006 points, at least 4
    {"altitude_min_m": 100.0, "altitude_max_m": 100.001},        # a 1 mm band: mean 5e-5 points
], ids=["min16", "sparse", "1mm-band"])
def test_rare_waypoint_condition_returns_the_conditioned_count(overrides):
    s = S.replace(**overrides)
    mu = s.waypoint_intensity_per_km3 * coverage_volume_km3(s)
    assert stats.poisson.sf(s.min_waypoints - 1, mu) < 1e-9  # the plain redraw loop: hours or more
    rng = np.random.default_rng(5)
    with _Deadline(5.0):
        draws = [sample_waypoints(s, rng) for _ in range(5)]
    for pts in draws:
        assert len(pts) >= s.min_waypoints
        if mu < 0.01:  # the law conditioned on N >= m puts all but mu / m of its mass on m itself
            assert len(pts) == s.min_waypoints
        assert np.all(in_coverage(s, pts))


def test_an_uncommon_condition_draws_the_conditioned_count_at_once():
    """p = 4e-4 (below HOPELESS_TAIL): the count comes from the conditioned law, as the redraws would sample it."""
    s = S.replace(waypoint_intensity_per_km3=1.0, min_waypoints=5)
    mu = coverage_volume_km3(s)
    rng = np.random.default_rng(3)
    counts = np.array([len(sample_waypoints(s, rng)) for _ in range(1000)])
    assert counts.min() >= 5
    expected = stats.poisson.pmf(5, mu) / stats.poisson.sf(4, mu)  # 0.91
    assert abs(np.mean(counts == 5) - expected) < 4 * np.sqrt(expected * (1 - expected) / len(counts))


def test_conditioned_count_follows_the_truncated_poisson_law():
    from iscc_gym.trajectory import _conditioned_poisson

    mu, m = 6.0, 8
    rng = np.random.default_rng(11)
    counts = np.array([_conditioned_poisson(mu, m, rng) for _ in range(4000)])
    assert counts.min() >= m
    ks = np.arange(m, m + 6)
    expected = stats.poisson.pmf(ks, mu) / stats.poisson.sf(m - 1, mu)
    observed = np.array([np.mean(counts == k) for k in ks])
    assert np.all(np.abs(observed - expected) < 4 * np.sqrt(expected * (1 - expected) / len(counts)) + 1e-3)


def test_default_waypoint_draws_are_those_of_the_plain_redraw_loop():
    """The bound changes nothing where the condition is common: same draws as the unbounded loop."""

    def plain(s, rng):  # the algorithm of the paper's Sec. V-A as first written
        mean = s.waypoint_intensity_per_km3 * coverage_volume_km3(s)
        n = 0
        while n < s.min_waypoints:
            n = int(rng.poisson(mean))
        r = s.coverage_radius_m
        lo, hi = np.array([-r, -r, s.altitude_min_m]), np.array([r, r, s.altitude_max_m])
        pts = np.empty((0, 3))
        while len(pts) < n:
            cand = rng.uniform(lo, hi, size=(2 * n, 3))
            pts = np.vstack([pts, cand[in_coverage(s, cand)]])
        return pts[:n]

    from iscc_gym.trajectory import HOPELESS_TAIL, _poisson_tail

    rare = S.replace(waypoint_intensity_per_km3=3.0, min_waypoints=5)  # the condition holds with p = 0.037
    assert _poisson_tail(3.0 * coverage_volume_km3(S), 5) > HOPELESS_TAIL
    for s in (S, rare):
        a, b = np.random.default_rng(9), np.random.default_rng(9)
        for _ in range(50):
            np.testing.assert_array_equal(sample_waypoints(s, a), plain(s, b))


def test_sample_reference_gives_up_with_an_error_naming_the_fields():
    with pytest.raises(ValueError, match="altitude_min_m.*altitude_max_m.*coverage_radius_m.*min_waypoints"):
        sample_reference(S, np.random.default_rng(0), max_tries=0)
