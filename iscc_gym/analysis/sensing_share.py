"""The CRLB as an explicit function of the sensing share alpha_sen (the SCA objective f_sen of
Sec. IV-B and the analytic evaluator's measurement noise), from the closed-form FIM of
:mod:`iscc_gym.physics.sensing` at alpha_sen = 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import guvectorize, njit
from numpy.typing import ArrayLike

from iscc_gym.physics.sensing import crlb_from_info, crlb_from_info_one, position_info
from iscc_gym.scenario import Scenario

__all__ = ["SensingCoefficients", "sensing_coefficients", "local_crlb", "crlb_trace", "crlb_trace_one"]


@dataclass(frozen=True)
class SensingCoefficients:
    r"""Position-domain Fisher information of the ISAC measurement at ``alpha_sen = 1``.

    The closed-form FIM (eq:FIM_tau -- eq:FIM_zero) scales as :math:`\alpha_\mathrm{sen}^3` in the
    range (delay) entry and as :math:`\alpha_\mathrm{sen}` in the angle and Doppler entries, so the
    CRLB at any share follows from these coefficients (:func:`local_crlb`). Frame: range direction
    :math:`\mathbf g`, azimuth direction :math:`\mathbf e_\theta`, elevation direction
    :math:`\mathbf e_\varphi` (:func:`iscc_gym.physics.sensing.local_frame`).

    Attributes
    ----------
    info_range : ndarray, m^-2
        :math:`(2/c)^2 J_{\tau\tau}` at :math:`\alpha_\mathrm{sen}=1`.
    info_az, info_cross, info_el : ndarray, m^-2
        Entries of :math:`\mathbf D\mathbf J_{\theta\varphi}\mathbf D` (azimuth, cross, elevation).
    info_vr : ndarray, (m/s)^-2
        :math:`J_{\nu\nu}/(\lambda/2)^2`.
    prior : float, m^-2
        ``1 / sensing_prior_var_m2`` (added to every diagonal entry, as in ``sensing.crlb_local``).
    """

    info_range: np.ndarray
    info_az: np.ndarray
    info_cross: np.ndarray
    info_el: np.ndarray
    info_vr: np.ndarray
    prior: float


def sensing_coefficients(s: Scenario, dist_m: ArrayLike, trig: tuple[ArrayLike, ArrayLike, ArrayLike, ArrayLike],
                         shadow_db: ArrayLike = 0.0, fading_gain: ArrayLike = 1.0) -> SensingCoefficients:
    """:class:`SensingCoefficients` at ranges ``dist_m`` and directions ``trig`` (the output of
    :func:`iscc_gym.physics.channel.direction_trig`), for the given shadowing (dB) and fading gain: the compiled
    :func:`iscc_gym.physics.sensing.position_info` at ``alpha_sen = 1``.
    """
    info_range, info_az, info_cross, info_el, j_nu = position_info(s, 1.0, dist_m, trig, shadow_db, fading_gain)
    lam_half_sq = (0.5 * s.wavelength_m) ** 2
    return SensingCoefficients(
        info_range=info_range,
        info_az=info_az,
        info_cross=info_cross,
        info_el=info_el,
        info_vr=np.asarray(j_nu / lam_half_sq, dtype=float),
        prior=1.0 / s.sensing_prior_var_m2,
    )


def local_crlb(coef: SensingCoefficients, alpha_sen: ArrayLike):
    """Local-frame CRLB at sensing share ``alpha_sen`` (equal to :func:`iscc_gym.physics.sensing.crlb_local`).

    Returns
    -------
    m_r, m_tt, m_tp, m_pp : ndarray, m^2
        Range variance and the azimuth/elevation 2 x 2 block of the position CRLB (eq:CRLB_pos).
    crlb_vr : ndarray, (m/s)^2
    """
    a_s = np.asarray(alpha_sen, dtype=float)
    return crlb_from_info(a_s**3 * coef.info_range, a_s * coef.info_az, a_s * coef.info_cross, a_s * coef.info_el,
                          a_s * coef.info_vr, coef.prior, 1.0)


def crlb_trace(coef: SensingCoefficients, alpha_sen: ArrayLike):
    r""":math:`f_\mathrm{sen}(\alpha_\mathrm{sen}) = \operatorname{Tr}\mathrm{CRLB}_\mathbf p`
    (PEB squared, m^2) and its derivative in ``alpha_sen`` (the SCA objective, Sec. IV-B).

    Returns
    -------
    trace_m2, dtrace : ndarray
    """
    return _crlb_trace_ufunc(coef.info_range, coef.info_az, coef.info_cross, coef.info_el, coef.prior,
                             np.asarray(alpha_sen, dtype=float))


@njit(cache=True, error_model="numpy")
def crlb_trace_one(info_range, info_az, info_cross, info_el, prior, alpha_sen):
    r""":func:`crlb_trace` of one position (scalars of :class:`SensingCoefficients`): ``(trace, dtrace)``.

    The CRLB is :func:`iscc_gym.physics.sensing.crlb_from_info_one`; its derivative is
    :math:`\partial\mathbf M/\partial\alpha = -\mathbf M\,(\partial\mathbf J/\partial\alpha)\,
    \mathbf M`, with
    :math:`\partial\mathbf J/\partial\alpha` the information at alpha_sen = 1 (3 alpha^2 of it in range).
    """
    a = alpha_sen
    m_r, m_tt, m_tp, m_pp, _ = crlb_from_info_one(a * a * a * info_range, a * info_az, a * info_cross,
                                                  a * info_el, 0.0, prior, 1.0)
    trace = m_r + m_tt + m_pp
    dtrace = (-3.0 * a * a * info_range * m_r * m_r
              - (info_az * (m_tt * m_tt + m_tp * m_tp) + 2.0 * info_cross * m_tp * (m_tt + m_pp)
                 + info_el * (m_tp * m_tp + m_pp * m_pp)))
    return trace, dtrace


@guvectorize(["void(float64, float64, float64, float64, float64, float64, float64[:], float64[:])"],
             "(),(),(),(),(),()->(),()", cache=True)
def _crlb_trace_ufunc(info_range, info_az, info_cross, info_el, prior, alpha_sen, trace, dtrace):
    trace[0], dtrace[0] = crlb_trace_one(info_range, info_az, info_cross, info_el, prior, alpha_sen)
