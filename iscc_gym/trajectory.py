"""Reference trajectories: Poisson waypoints in the coverage region and a cubic spline through them
(the paper, Sec. V-A)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from .scenario import Scenario

__all__ = ["coverage_volume_km3", "in_coverage", "sample_waypoints", "order_waypoints",
           "Reference", "spline_reference", "sample_reference"]


def coverage_volume_km3(s: Scenario) -> float:
    """Volume of the coverage region :math:`\\{\\|\\mathbf p\\| \\le R,\\ h_\\min < p_z \\le h_\\max\\}` in km^3.

    .. math:: V = \\int_{h_\\min}^{h_\\max} \\pi (R^2 - z^2)\\,dz
    """
    r, lo, hi = s.coverage_radius_m, s.altitude_min_m, s.altitude_max_m
    return float(np.pi * (r * r * (hi - lo) - (hi**3 - lo**3) / 3.0)) * 1e-9


def in_coverage(s: Scenario, pos_m):
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
    while n < s.min_waypoints:
        n = int(rng.poisson(mean))
    r = s.coverage_radius_m
    lo = np.array([-r, -r, s.altitude_min_m])
    hi = np.array([r, r, s.altitude_max_m])
    pts = np.empty((0, 3))
    while len(pts) < n:
        cand = rng.uniform(lo, hi, size=(2 * n, 3))
        cand = cand[in_coverage(s, cand)]
        pts = np.vstack([pts, cand])
    return pts[:n]


def order_waypoints(points):
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
        """Reference state :math:`\\mathbf x_{\\mathrm{ref},n} = [\\mathbf p^T, \\mathbf v^T]^T`, (N+1, 6)."""
        return np.concatenate([self.pos_m, self.vel_mps], axis=-1)


def spline_reference(s: Scenario, waypoints):
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
    the region (altitude band or radius) between waypoints is rejected and redrawn.
    """
    for _ in range(max_tries):
        ref = spline_reference(s, order_waypoints(sample_waypoints(s, rng)))
        if np.all(in_coverage(s, ref.pos_m)):
            return ref
    raise RuntimeError(f"no in-coverage spline in {max_tries} draws; check the coverage fields")
