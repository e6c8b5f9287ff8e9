"""Steady states of the Kalman filter: one axis of the double integrator (batched, by the doubling
algorithm) and the GNSS-fed LQG loop of the paper's Fig. 9 comparison.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike

from iscc_gym.physics.dynamics import axis_gain, axis_matrices
from iscc_gym.scenario import Scenario

__all__ = ["axis_kalman_steady_state", "gnss_steady_error_m"]


def _mul(x, y):
    """Product of 2 x 2 matrices stored as (m00, m01, m10, m11) tuples of arrays."""
    x00, x01, x10, x11 = x
    y00, y01, y10, y11 = y
    return (x00 * y00 + x01 * y10, x00 * y01 + x01 * y11, x10 * y00 + x11 * y10, x10 * y01 + x11 * y11)


def _tr(x):
    return (x[0], x[2], x[1], x[3])


def _inv(x):
    x00, x01, x10, x11 = x
    inv_det = 1.0 / (x00 * x11 - x01 * x10)
    return (x11 * inv_det, -x01 * inv_det, -x10 * inv_det, x00 * inv_det)


def _congruence(m, s):
    r""":math:`\mathbf M\mathbf S\mathbf M^T` for symmetric S (both as 4-tuples); symmetric result."""
    m00, m01, m10, m11 = m
    s00, s01, _, s11 = s
    t00, t01 = m00 * s00 + m01 * s01, m00 * s01 + m01 * s11  # first row of M S
    t10, t11 = m10 * s00 + m11 * s01, m10 * s01 + m11 * s11
    r01 = t00 * m10 + t01 * m11
    return (t00 * m00 + t01 * m01, r01, r01, t10 * m10 + t11 * m11)


def _add_sym(x, y):
    return (x[0] + y[0], x[1] + y[1], x[2] + y[2], x[3] + y[3])


def _sym(x):
    off = 0.5 * (x[1] + x[2])
    return (x[0], off, off, x[3])


def axis_kalman_steady_state(dt_s: float, var_pos_m2: float, var_vel_m2s2: float, meas_pos_var_m2: ArrayLike,
                             meas_vel_var_m2s2: ArrayLike = None, tol: float = 1e-12, max_iter: int = 60):
    r"""Steady-state Kalman covariances of one axis of the double integrator, batched.

    State (p, v), :math:`\mathbf A_1 = [[1, \Delta t], [0, 1]]`, process noise
    :math:`\mathrm{diag}(\sigma_p^2, \sigma_v^2)`, measurement of p with variance
    ``meas_pos_var_m2`` and (optionally) of v with variance ``meas_vel_var_m2s2``. The filtering DARE
    :math:`\mathbf X = \mathbf A_1\mathbf X(\mathbf I + \mathbf G\mathbf X)^{-1}\mathbf A_1^T
    + \mathbf W`, :math:`\mathbf G = \mathbf C^T\mathbf R^{-1}\mathbf C`, is solved by the
    structure-preserving doubling algorithm (Chu, Fan and Lin, 2005; quadratic convergence), written
    out entry by entry so that it vectorises over any number of filters.

    Parameters
    ----------
    dt_s : float
        Slot duration.
    var_pos_m2, var_vel_m2s2 : float
        Process-noise variances per axis.
    meas_pos_var_m2 : array_like, shape (...)
        Position measurement variance (> 0).
    meas_vel_var_m2s2 : array_like, shape (...), optional
        ``None`` or ``inf``: velocity not measured on this axis.

    Returns
    -------
    p_prior : ndarray, shape (..., 2, 2)
        :math:`\mathbf P_{n|n-1}`.
    sigma_est : ndarray, shape (..., 2, 2)
        :math:`\Sigma_\mathrm{est} = \mathbf X(\mathbf I + \mathbf G\mathbf X)^{-1}`.
    """
    rp = np.asarray(meas_pos_var_m2, dtype=float)
    rv = np.full(rp.shape, np.inf) if meas_vel_var_m2s2 is None else np.broadcast_to(
        np.asarray(meas_vel_var_m2s2, dtype=float), rp.shape)
    zero = np.zeros(rp.shape)
    g0 = (1.0 / rp, zero, zero, 1.0 / rv)
    g = g0
    a = tuple(zero + v for v in axis_matrices(dt_s)[0].T.ravel())  # A_1^T, entry by entry (row-major)
    h = (zero + var_pos_m2, zero, zero, zero + var_vel_m2s2)
    for _ in range(max_iter):
        gh = _mul(g, h)
        w_inv = _inv((1.0 + gh[0], gh[1], gh[2], 1.0 + gh[3]))
        h_new = _add_sym(h, _congruence(_tr(a), _sym(_mul(h, w_inv))))  # H + A^T (H W^-1) A
        g = _add_sym(g, _congruence(a, _sym(_mul(w_inv, g))))  # G + A (W^-1 G) A^T
        a = _mul(_mul(a, w_inv), a)
        change = max(float(np.max(np.abs(h_new[0] - h[0]) / np.maximum(h_new[0], 1e-300), initial=0.0)),
                     float(np.max(np.abs(h_new[3] - h[3]) / np.maximum(h_new[3], 1e-300), initial=0.0)))
        h = h_new
        if change <= tol:
            break
    gh = _mul(g0, h)
    est = _sym(_mul(h, _inv((1.0 + gh[0], gh[1], gh[2], 1.0 + gh[3]))))
    return _stack2(h), _stack2(est)


def _stack2(x):
    return np.stack([np.stack([x[0], x[1]], -1), np.stack([x[2], x[3]], -1)], -2)


def gnss_steady_error_m(s: Scenario, eps: float = 0.0, period_slots: int = 1, raw: bool = False) -> float:
    """Mean tracking error E||p - p_ref|| of the GNSS-fed LQG loop at steady state (exact second
    moments of the linear-Gaussian loop, per axis; the reference's lag is neglected).

    Per axis the state is (x, x_hat_{n|n-1}) with x = (p, v) relative to the reference. A GNSS fix
    (noise std ``gnss_pos_std_m``, ``gnss_vel_std_mps``) arrives every ``period_slots`` slots; the
    Kalman filter (at its periodic steady state) updates on fixes and predicts otherwise; the command
    u = -K x_hat is lost with probability ``eps`` (the GBS learns the loss, as in the env).
    ``raw=True`` feeds the fix to the LQ gain unfiltered (x_hat = y, every slot). The second moments
    are the fixed point of the period's linear map (Bernoulli loss averaged); the error is averaged
    over the phases of the period. ``period_slots = 1`` is the env's GNSS scheme.
    """
    if period_slots < 1:
        raise ValueError(f"period_slots = {period_slots!r} is invalid: must be an integer >= 1")
    a, b = axis_matrices(s.dt_s)
    bk = b @ axis_gain(s)
    w = np.diag([s.process_noise_var_pos_m2, s.process_noise_var_vel_m2s2])
    r = np.diag([s.gnss_pos_std_m**2, s.gnss_vel_std_mps**2])
    eye = np.eye(2)
    if raw:
        period_slots, fix_gain = 1, eye
    else:
        a_p = np.linalg.matrix_power(a, period_slots)
        w_p = sum(np.linalg.matrix_power(a, i) @ w @ np.linalg.matrix_power(a, i).T for i in range(period_slots))
        p_prior = scipy.linalg.solve_discrete_are(a_p.T, eye, w_p, r)  # prior covariance at a fix
        fix_gain = p_prior @ np.linalg.inv(p_prior + r)
    noise = np.zeros((4, 4))
    noise[:2, :2] = w
    maps = []  # per phase: vec(Sigma_next) = m @ vec(Sigma) + c
    for phase in range(period_slots):
        gain = fix_gain if phase == 0 else np.zeros((2, 2))
        m, c = np.zeros((16, 16)), noise.copy()
        for delta, prob in ((1.0, 1.0 - eps), (0.0, eps)):
            acl = a - delta * bk
            f = np.block([[a - delta * bk @ gain, -delta * bk @ (eye - gain)], [acl @ gain, acl @ (eye - gain)]])
            g = np.vstack([-delta * bk @ gain, acl @ gain])
            m += prob * np.kron(f, f)
            c += prob * (g @ r @ g.T)
        maps.append((m, c.ravel()))
    m_tot, c_tot = np.eye(16), np.zeros(16)
    for m, c in maps:
        m_tot, c_tot = m @ m_tot, m @ c_tot + c
    if np.max(np.abs(np.linalg.eigvals(m_tot))) >= 1.0:
        return float("inf")
    sig = np.linalg.solve(np.eye(16) - m_tot, c_tot)
    errs = []
    for m, c in maps:
        sig = m @ sig + c
        errs.append(math.sqrt(8.0 / math.pi) * math.sqrt(max(sig[0], 0.0)))
    return float(np.mean(errs))
