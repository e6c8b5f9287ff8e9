r"""The local tracking model of a model-based policy: the steady-state tracking error of the closed loop at one
geometry, for any sensing share and control-packet loss rate (:class:`LocalTrackingModel`), and the CDF of the
Rician fading power (:func:`rician_power_cdf`, that of :func:`iscc_gym.physics.channel.rician_gain_one`). Built of
the Kalman steady state (:func:`iscc_gym.analysis.kalman_steady.axis_kalman_steady_state`), the second-moment
recursion under packet loss (:func:`iscc_gym.physics.stability.stability_matrix`) and the mean error norm
(:func:`iscc_gym.analysis.quadrature.expected_norm`); the per-slot policies (``iscc_gym.agents``) design on it.
"""

from __future__ import annotations

import numpy as np
from scipy.special import chndtr

from iscc_gym.analysis.kalman_steady import axis_kalman_steady_state
from iscc_gym.analysis.quadrature import expected_norm
from iscc_gym.analysis.sensing_share import SensingCoefficients, local_crlb
from iscc_gym.physics.dynamics import axis_gain, axis_matrices
from iscc_gym.physics.stability import scenario_eps_star, stability_matrix
from iscc_gym.scenario import Scenario, per_scenario
from iscc_gym.units import db_to_lin

__all__ = ["LocalTrackingModel", "local_tracking_model", "rician_power_cdf"]


def rician_power_cdf(s: Scenario, x, k_lin=None):
    r"""CDF :math:`P(|g|^2 \le x)` of the unit-mean Rician power gain of
    :func:`iscc_gym.physics.channel.rician_gain_one`.

    :math:`|g|^2 = \sigma^2\chi'^2_2(2K)` with :math:`\sigma^2 = 1/(2(K+1))` and K = ``rician_k_db``
    (linear), the distribution whose quantiles :func:`iscc_gym.analysis.quadrature.rician_power_nodes` takes.

    Parameters
    ----------
    s : Scenario
    x : array_like
        Power gain (linear, >= 0).
    k_lin : array_like, optional
        The K-factor (linear), broadcast with ``x``; default the scenario's ``rician_k_db``.

    Returns
    -------
    ndarray
        Same shape as ``x``.
    """
    k = float(db_to_lin(s.rician_k_db)) if k_lin is None else np.asarray(k_lin, dtype=float)
    return chndtr(np.asarray(x, dtype=float) * (2.0 * (k + 1.0)), 2.0, 2.0 * k)  # scipy.stats.ncx2.cdf


class LocalTrackingModel:
    r"""Steady-state mean tracking error at one geometry for a sensing share and a loss rate.

    The model of :mod:`iscc_gym.analysis` (frozen geometry, exact closed-loop recursion) at a
    single position: the local CRLB (:func:`iscc_gym.analysis.sensing_share.local_crlb`) splits the filter into
    three 2-state axes (range: position and radial velocity measured; the two principal cross-range
    axes: position only). On each axis, with the Kalman steady state :math:`\mathbf P_{n|n-1}`,
    :math:`\Sigma_\mathrm{est}` (:func:`iscc_gym.analysis.kalman_steady.axis_kalman_steady_state`) and the loss rate
    :math:`\varepsilon`,

    .. math::
        \mathrm{vec}\,\Sigma_{\hat z} = (\mathbf I - \mathbf M_1(\varepsilon))^{-1}
        \mathrm{vec}(\mathbf P_{n|n-1} - \Sigma_\mathrm{est}),\qquad
        \lambda = [\Sigma_{\hat z}]_{pp} + [\Sigma_\mathrm{est}]_{pp},\qquad
        T = \mathbb E\|\mathbf e_\mathbf p\| = \texttt{expected\_norm}(\lambda_r, \lambda_1, \lambda_2)

    with :math:`\mathbf M_1` the per-axis eq:M (:func:`iscc_gym.physics.stability.stability_matrix`). The
    Kalman steady state is tabulated once on a grid of measurement variances (0.05 decade steps,
    bilinear in the logarithms; clamped outside :math:`[10^{-10}, 10^{6.5}]` m^2 and
    :math:`[10^{-14}, 10^{6.5}]` (m/s)^2, where it no longer changes); :math:`\varepsilon \ge
    \varepsilon^\star` (no steady state) gives ``max_tracking_error_m``, and T is capped there as
    the env's reward is.

    Parameters
    ----------
    s : Scenario
    """

    _LOG_POS = (-10.0, 6.5)
    _LOG_VEL = (-14.0, 6.5)
    _STEP = 0.05

    def __init__(self, s: Scenario):
        self.scenario = s
        self.eps_star = scenario_eps_star(s)
        self.e_max = float(s.max_tracking_error_m)
        self._lp = np.arange(self._LOG_POS[0], self._LOG_POS[1] + 1e-9, self._STEP)
        self._lv = np.arange(self._LOG_VEL[0], self._LOG_VEL[1] + 1e-9, self._STEP)
        qp, qv = s.process_noise_var_pos_m2, s.process_noise_var_vel_m2s2
        rp, rv = np.meshgrid(10.0 ** self._lp, 10.0 ** self._lv, indexing="ij")
        self._range_tab = self._pack(*axis_kalman_steady_state(s.dt_s, qp, qv, rp, rv))  # (n_pos, n_vel, 4)
        self._cross_tab = self._pack(*axis_kalman_steady_state(s.dt_s, qp, qv, 10.0 ** self._lp))  # (n_pos, 4)
        a1, b1 = axis_matrices(s.dt_s)  # one axis (position, velocity) of the isotropic A, B, K
        k1 = axis_gain(s)
        self._m_ok = stability_matrix(a1, b1, k1, 0.0)
        self._m_lost = stability_matrix(a1, b1, k1, 1.0)  # eq:M is affine in eps

    @staticmethod
    def _pack(p_prior, est):
        """(P_prior - est)_pp, _pv, _vv and est_pp: what the position variance needs."""
        n = p_prior - est
        return np.stack([n[..., 0, 0], n[..., 0, 1], n[..., 1, 1], est[..., 0, 0]], -1)

    def _index(self, var, grid):
        u = (np.log10(np.maximum(var, 1e-300)) - grid[0]) * (1.0 / self._STEP)
        u = np.clip(u, 0.0, len(grid) - 1 - 1e-9)
        i = u.astype(np.intp)
        return i, (u - i)[..., None]

    def _range_axis(self, pos_var, vel_var):
        i, ti = self._index(pos_var, self._lp)
        j, tj = self._index(vel_var, self._lv)
        t = self._range_tab
        return ((1.0 - ti) * ((1.0 - tj) * t[i, j] + tj * t[i, j + 1])
                + ti * ((1.0 - tj) * t[i + 1, j] + tj * t[i + 1, j + 1]))

    def _cross_axis(self, pos_var):
        i, ti = self._index(pos_var, self._lp)
        return (1.0 - ti) * self._cross_tab[i] + ti * self._cross_tab[i + 1]

    def loss_weights(self, eps):
        r"""Row of :math:`(\mathbf I - \mathbf M_1(\varepsilon))^{-1}` giving
        :math:`[\Sigma_{\hat z}]_{pp}` from (N_pp, N_pv, N_vv), shape ``eps.shape + (3,)``;
        zeros where :math:`\varepsilon \ge \varepsilon^\star`.
        """
        e = np.asarray(eps, dtype=float)
        stable = e < self.eps_star
        ee = np.where(stable, e, 0.0)[..., None, None]
        row = np.linalg.inv(np.eye(4) - ((1.0 - ee) * self._m_ok + ee * self._m_lost))[..., 0, :]
        w = np.stack([row[..., 0], row[..., 1] + row[..., 2], row[..., 3]], -1)  # vec order (00, 10, 01, 11)
        return np.where(stable[..., None], w, 0.0)

    def axis_variances(self, coef: SensingCoefficients, alpha_sen, eps=None, weights=None):
        """Steady-state position variances (m^2) on the range and the two cross-range axes,
        shape ``broadcast(coef, alpha_sen, eps) + (3,)``; ``weights`` (:meth:`loss_weights` of
        ``eps``) may be passed instead of ``eps``.
        """
        if weights is None:
            weights = self.loss_weights(0.0 if eps is None else eps)
        m_r, m_tt, m_tp, m_pp, vr = local_crlb(coef, alpha_sen)
        half = 0.5 * (m_tt + m_pp)
        disc = np.sqrt(0.25 * (m_tt - m_pp) ** 2 + m_tp * m_tp)  # principal axes of the angle block
        lam = [(q[..., :3] * weights).sum(-1) + q[..., 3]
               for q in (self._range_axis(m_r, vr), self._cross_axis(half + disc), self._cross_axis(half - disc))]
        return np.stack(lam, -1)

    def tracking_error(self, coef: SensingCoefficients, alpha_sen, eps):
        r""":math:`\min(\mathbb E\|\mathbf e_\mathbf p\|, e_\max)` in m (``max_tracking_error_m``
        where ``eps`` >= eps*); broadcasts ``coef``'s arrays, ``alpha_sen`` and ``eps``.
        """
        eps = np.asarray(eps, dtype=float)
        return self._error(self.axis_variances(coef, alpha_sen, weights=self.loss_weights(eps)), eps)

    def _error(self, lam, eps):
        bad = (eps >= self.eps_star) | np.any(~(lam >= 0.0), -1)
        t = expected_norm(np.where(bad[..., None], 0.0, lam))
        return np.where(bad, self.e_max, np.minimum(t, self.e_max))


@per_scenario
def local_tracking_model(s: Scenario) -> LocalTrackingModel:
    """:class:`LocalTrackingModel` of a scenario, built once (its Kalman tables take ~0.3 s; it keeps no state that
    changes, so the policies of a scenario share it).
    """
    return LocalTrackingModel(s)
