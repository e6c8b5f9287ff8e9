"""Reference trajectories: Poisson waypoints in the coverage region and a cubic spline through them
(the paper, Sec. V-A).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike
from scipy.interpolate import CubicSpline

if TYPE_CHECKING:  # annotations only: the scenario's checks (scenario_checks) draw references with this module
    from iscc_gym.scenario import Scenario

__all__ = ["coverage_volume_km3", "coverage_box_fraction", "in_coverage", "sample_waypoints", "order_waypoints",
           "Reference", "spline_reference", "sample_reference"]


def coverage_volume_km3(s: Scenario) -> float:
    r"""Volume of the coverage region :math:`\{\|\mathbf p\| \le R,\ h_\min < p_z \le h_\max\}` in km^3.

    .. math:: V = \int_{h_\min}^{h_\max} \pi (R^2 - z^2)\,dz
    """
    r, lo, hi = s.coverage_radius_m, s.altitude_min_m, s.altitude_max_m
    return float(np.pi * (r * r * (hi - lo) - (hi**3 - lo**3) / 3.0)) * 1e-9


def in_coverage(s: Scenario, pos_m: ArrayLike):
    """True where a point lies in the coverage region (upper hemisphere, altitude band)."""
    p = np.asarray(pos_m, dtype=float)
    return ((np.linalg.norm(p, axis=-1) <= s.coverage_radius_m)
            & (p[..., 2] > s.altitude_min_m) & (p[..., 2] <= s.altitude_max_m))


def sample_waypoints(s: Scenario, rng: np.random.Generator):
    """Waypoints of a homogeneous 3-D Poisson point process in the coverage region.

    The count is Poisson with mean ``waypoint_intensity_per_km3`` times the region's volume,
    conditioned on at least ``min_waypoints``; given the count, points are i.i.d. uniform in the
    region (drawn by rejection from its bounding box).

    Returns
    -------
    ndarray, shape (n, 3), in m
    """
    mean = s.waypoint_intensity_per_km3 * coverage_volume_km3(s)
    n = 0
    # where the redraws would take long (1/p on average), skip them: the conditioned law is the same law
    redraws = POISSON_REDRAWS if _poisson_tail(mean, s.min_waypoints) >= HOPELESS_TAIL else 0
    for _ in range(redraws):
        n = int(rng.poisson(mean))
        if n >= s.min_waypoints:
            break
    else:  # the condition is rare at this mean: draw from the conditioned law directly
        n = _conditioned_poisson(mean, s.min_waypoints, rng)
    r = s.coverage_radius_m
    lo = np.array([-r, -r, s.altitude_min_m])
    hi = np.array([r, r, s.altitude_max_m])
    pts = np.empty((0, 3))
    for _ in range(POINT_REDRAWS):
        if len(pts) >= n:
            return pts[:n]
        cand = rng.uniform(lo, hi, size=(2 * n, 3))
        cand = cand[in_coverage(s, cand)]
        pts = np.vstack([pts, cand])
    if len(pts) >= n:
        return pts[:n]
    raise ValueError(  # unreachable for a validated Scenario (it bounds the region's share of its box)
        f"the coverage region fills only {coverage_box_fraction(s):.2e} of its bounding box: no {n} waypoints in "
        f"{POINT_REDRAWS} rounds of rejection sampling; widen the altitude band (altitude_min_m, altitude_max_m) "
        f"below coverage_radius_m")


#: Poisson counts drawn (and rejected below ``min_waypoints``) before :func:`sample_waypoints` draws the
#: count from the conditioned law itself (about 0.1 s of redraws). The ``paper`` preset (mean 9.1, at
#: least 4) fails a draw with probability 0.02, so it never gets there: its draws, and those of any
#: scenario whose condition holds with probability above ~1e-3, are those of the plain rejection loop.
POISSON_REDRAWS = 100_000
#: Below this probability p of the condition (at least ``min_waypoints``), the redraws are skipped and the count is
#: drawn from the conditioned law (the law the redraws sample, so only the draws differ): the plain loop takes 1/p
#: redraws on average, and at p = 1e-4 to 1e-9 it spent up to ~0.2 s a reset on them. Every preset's p is above
#: 0.7 (the ``paper``'s 0.98, ``urban``'s 0.73), so their draws are the plain loop's.
HOPELESS_TAIL = 1e-2
#: Rounds of rejection sampling of the waypoint positions (each proposes 2n points in the bounding box).
POINT_REDRAWS = 10_000


def _poisson_tail(mean: float, n_min: int) -> float:
    """P(N >= n_min) for N ~ Poisson(mean), as 1 - P(N < n_min) (exact enough down to ~1e-15)."""
    if mean <= 0.0:
        return 1.0 if n_min <= 0 else 0.0
    below = sum(math.exp(-mean + i * math.log(mean) - math.lgamma(i + 1.0)) for i in range(max(0, n_min)))
    return max(0.0, 1.0 - below)


def _conditioned_poisson(mean: float, n_min: int, rng: np.random.Generator) -> int:
    """One draw of a Poisson(mean) count conditioned on at least ``n_min``, by inversion of its pmf
    (computed in logs from ``n_min`` up to where the tail is below 1e-17 of the mass).
    """
    if mean <= 0.0:
        return n_min
    hi = n_min + int(mean + 40.0 * math.sqrt(mean) + 60.0)
    k = np.arange(n_min, hi + 1)
    log_p = k * math.log(mean) - np.array([math.lgamma(i + 1.0) for i in k])
    p = np.exp(log_p - log_p.max())
    cdf = np.cumsum(p)
    return int(k[min(int(np.searchsorted(cdf, rng.uniform() * cdf[-1], side="right")), len(k) - 1)])


def coverage_box_fraction(s: Scenario) -> float:
    """Share of the bounding box [-R, R]^2 x [h_min, h_max] that the coverage region fills (the acceptance
    rate of :func:`sample_waypoints`' rejection sampling).
    """
    r = s.coverage_radius_m
    return coverage_volume_km3(s) * 1e9 / (4.0 * r * r * (s.altitude_max_m - s.altitude_min_m))


def order_waypoints(points: ArrayLike):
    """Visit order: a greedy nearest-neighbour tour from the first point (the paper gives none)."""
    pts = np.asarray(points, dtype=float)
    left = list(range(1, len(pts)))
    order = [0]
    while left:
        d = np.linalg.norm(pts[left] - pts[order[-1]], axis=1)
        order.append(left.pop(int(np.argmin(d))))
    return pts[order]


@dataclass(frozen=True)
class Reference:
    """Sampled reference: position, velocity, acceleration at t_n = n dt, n = 0..N (N+1 rows)."""

    t_s: np.ndarray
    pos_m: np.ndarray
    vel_mps: np.ndarray
    acc_mps2: np.ndarray
    waypoints_m: np.ndarray

    @property
    def state(self):
        r"""Reference state :math:`\mathbf x_{\mathrm{ref},n} = [\mathbf p^T, \mathbf v^T]^T`, (N+1, 6)."""
        return np.concatenate([self.pos_m, self.vel_mps], axis=-1)


def spline_reference(s: Scenario, waypoints: ArrayLike):
    """Cubic spline through ordered waypoints over the mission, sampled every dt.

    Knot times are proportional to the cumulative chord length (near-constant speed) and span
    [0, T_m]; the end conditions are clamped (the drone starts and ends at rest).
    """
    wp = np.asarray(waypoints, dtype=float)
    seg = np.linalg.norm(np.diff(wp, axis=0), axis=1)
    keep = np.concatenate([[True], seg > 1e-6])  # drop repeated points
    wp = wp[keep]
    seg = np.linalg.norm(np.diff(wp, axis=0), axis=1)
    knots = np.concatenate([[0.0], np.cumsum(seg)])
    knots = knots / knots[-1] * s.mission_duration_s
    spline = CubicSpline(knots, wp, bc_type="clamped")
    t = np.arange(s.n_slots + 1) * s.dt_s
    return Reference(t, spline(t), spline(t, 1), spline(t, 2), wp)


def sample_reference(s: Scenario, rng: np.random.Generator, max_tries: int = 1000) -> Reference:
    """Draw Poisson waypoints, order them, and return the sampled spline reference.

    The paper assumes the drone stays in coverage throughout the flight; a spline that overshoots
    the region (altitude band or radius) between waypoints is rejected and redrawn, at most
    ``max_tries`` times.

    Raises
    ------
    ValueError
        No draw stayed in the region: the scenario's region is too thin for a spline through its
        waypoints (a narrow altitude band, many waypoints); the message names the fields.
    """
    for _ in range(max_tries):
        ref = spline_reference(s, order_waypoints(sample_waypoints(s, rng)))
        if np.all(in_coverage(s, ref.pos_m)):
            return ref
    raise ValueError(
        f"no reference trajectory stayed in the coverage region in {max_tries} draws: the spline through "
        f"the waypoints overshoots the altitude band (altitude_min_m = {s.altitude_min_m}, altitude_max_m = "
        f"{s.altitude_max_m}) or coverage_radius_m = {s.coverage_radius_m}; widen the band or lower "
        f"min_waypoints = {s.min_waypoints} / waypoint_intensity_per_km3 = {s.waypoint_intensity_per_km3}")
