"""Quadrature rules of the analytic evaluator: the expected norm of a Gaussian vector in R^3, the
nodes of the Rician power gain, and the fading-averaged loss rate built on them (the one form the
static model, ``myopic`` and per-slot SCA share).
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numpy.polynomial.legendre import leggauss
from numpy.typing import ArrayLike
from scipy.stats import ncx2

from iscc_gym.physics.fbl import ctrl_bler
from iscc_gym.scenario import Scenario, per_scenario
from iscc_gym.units import db_to_lin

__all__ = ["expected_norm", "rician_power_nodes", "rician_nodes", "mean_ctrl_loss"]


@functools.lru_cache(maxsize=4)
def _sphere_rule(n: int = 6):
    # Gauss-Legendre in t = |u_3| on [0, 1] and in the azimuth on [0, pi/2]: the octant suffices
    # because the integrand depends on u_i^2 only
    t, wt = leggauss(n)
    t = 0.5 * (t + 1.0)
    wt = 0.5 * wt
    ph = 0.25 * np.pi * (t * 2.0)  # same nodes mapped to [0, pi/2]
    wp = wt.copy()
    tt, pp = np.meshgrid(t, ph, indexing="ij")
    w = np.outer(wt, wp).ravel()
    s2 = 1.0 - tt.ravel() ** 2
    u2 = np.stack([s2 * np.cos(pp.ravel()) ** 2, s2 * np.sin(pp.ravel()) ** 2, tt.ravel() ** 2])
    return u2, w / w.sum()


_MEAN_CHI3 = 2.0 * math.sqrt(2.0 / math.pi)


def expected_norm(var_m2: ArrayLike):
    r""":math:`\mathbb E\|\mathbf x\|` of a zero-mean Gaussian vector in R^3 with covariance
    eigenvalues ``var_m2`` (..., 3).

    With :math:`\mathbf x = \Lambda^{1/2} r\mathbf u` (:math:`r\sim\chi_3` independent of the
    uniform direction :math:`\mathbf u`), :math:`\mathbb E\|\mathbf x\| = \mathbb E[\chi_3]\,
    \mathbb E_\mathbf u\sqrt{\sum_i\lambda_i u_i^2}`, :math:`\mathbb E[\chi_3] = 2\sqrt{2/\pi}`;
    the direction average is a 6 x 6 Gauss-Legendre rule on the octant (relative error below 3e-4
    for eigenvalue ratios up to 100, below 1e-3 in the degenerate limits).
    """
    u2, w = _sphere_rule()
    lam = np.asarray(var_m2, dtype=float)
    return _MEAN_CHI3 * (np.sqrt(np.maximum(lam @ u2, 0.0)) @ w)


def rician_power_nodes(k_lin: float):
    r"""Quadrature nodes and weights of the unit-mean Rician power gain :math:`|g|^2`.

    :math:`|g|^2 = \sigma^2\chi'^2_2(2K)` with :math:`\sigma^2 = 1/(2(K+1))` (``channel.rician_gain_one``);
    the nodes are the quantiles at the midpoints of 30 probability bins refined in the lower tail
    (deep fades drive the loss rate), the weights the bins' probabilities.

    Parameters
    ----------
    k_lin : float
        Rician K factor, linear.

    Returns
    -------
    gain, weight : ndarray, shape (30,)
    """
    edges = np.concatenate([[0.0, 1e-6, 1e-5, 1e-4, 3e-4, 1e-3, 3e-3, 0.01, 0.02, 0.04],
                            np.linspace(0.07, 0.97, 19), [0.99, 1.0]])
    mid = 0.5 * (edges[:-1] + edges[1:])
    sigma2 = 0.5 / (k_lin + 1.0)
    return sigma2 * ncx2.ppf(mid, 2, 2.0 * k_lin), np.diff(edges)


@per_scenario
def rician_nodes(s: Scenario):
    """:func:`rician_power_nodes` of the scenario's K factor (``rician_k_db``), read-only, cached."""
    gain, weight = rician_power_nodes(float(db_to_lin(s.rician_k_db)))
    gain.setflags(write=False)
    weight.setflags(write=False)
    return gain, weight


def mean_ctrl_loss(s: Scenario, alpha_ctrl: ArrayLike, snr: ArrayLike, nodes=None):
    r"""The control loss rate eq:ctrl_bler averaged over the slot's unknown gain, by quadrature.

    .. math::
        \bar\varepsilon(\alpha, \bar\gamma) = \sum_k w_k\,
        \varepsilon_\mathrm{ctrl}(\alpha, \bar\gamma\, g_k)

    over gain nodes :math:`(g_k, w_k)`.

    Parameters
    ----------
    alpha_ctrl, snr : array_like, broadcastable
        Control share and large-scale SNR (linear, without the gain of the nodes).
    nodes : (gain, weight), optional
        Gain nodes of shape ``(..., m)`` (broadcast with ``snr[..., None]``) and weights ``(m,)``; the
        Rician fading of :func:`rician_nodes` if omitted (the static model passes shadowing times
        fading nodes per position).

    Returns
    -------
    ndarray
        The broadcast shape of ``alpha_ctrl`` and ``snr``.
    """
    gain, weight = rician_nodes(s) if nodes is None else nodes
    snr_nodes = np.asarray(snr, dtype=float)[..., None] * gain
    return ctrl_bler(s, np.asarray(alpha_ctrl, dtype=float)[..., None], snr_nodes) @ weight
