"""Test oracles of the sensing model: the FIM from its definition (the echo's derivatives), the
printed eq:CRLB_pos through the Jacobian, and the position information in the global frame.

Independent numpy paths kept out of the library (issue 14): the tests check :mod:`iscc_gym.physics.sensing`'s
closed forms against them.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from iscc_gym.physics.channel import array_response, geometry
from iscc_gym.scenario import SPEED_OF_LIGHT_MPS, Scenario


def position_jacobian(s: Scenario, pos_m):
    """Jacobian :math:`\\Upsilon_\\mathbf p = \\partial\\mathbf p/\\partial\\boldsymbol\\xi_\\mathbf p`,
    eq:Jacobian, shape (..., 3, 3), columns :math:`(\\tau_S, \\theta, \\varphi)`."""
    dist, th, ph, _ = geometry(s, pos_m)
    tau = 2.0 * dist / SPEED_OF_LIGHT_MPS
    st, ct, sp, cp = np.sin(th), np.cos(th), np.sin(ph), np.cos(ph)
    zero = np.zeros_like(st)
    rows = [
        np.stack([cp * ct, -tau * cp * st, -tau * sp * ct], -1),
        np.stack([cp * st, tau * cp * ct, -tau * sp * st], -1),
        np.stack([sp, zero, tau * cp], -1),
    ]
    return 0.5 * SPEED_OF_LIGHT_MPS * np.stack(rows, -2)


def position_information(s: Scenario, pos_m, j_tau, j_ang):
    """Position-domain Fisher information :math:`\\Upsilon^{-T}\\mathbf J_\\mathbf p\\Upsilon^{-1}`, (..., 3, 3).

    Written with :math:`\\partial\\boldsymbol\\xi_\\mathbf p/\\partial\\mathbf p` in closed form
    (:math:`\\partial\\tau/\\partial\\mathbf p = 2\\mathbf g/c`,
    :math:`\\partial\\theta/\\partial\\mathbf p = [-\\sin\\theta, \\cos\\theta, 0]/(l\\cos\\varphi)`,
    :math:`\\partial\\varphi/\\partial\\mathbf p = [-\\sin\\varphi\\cos\\theta, -\\sin\\varphi\\sin\\theta,
    \\cos\\varphi]/l`), so it stays finite where :math:`\\mathbf J_\\mathbf p` is singular.
    """
    dist, th, ph, los = geometry(s, pos_m)
    st, ct, sp, cp = np.sin(th), np.cos(th), np.sin(ph), np.cos(ph)
    cp_safe = np.maximum(cp, 1e-9)
    zero = np.zeros_like(st)
    d_th = np.stack([-st, ct, zero], -1) / (dist * cp_safe)[..., None]
    d_ph = np.stack([-sp * ct, -sp * st, cp], -1) / dist[..., None]
    t = np.stack([d_th, d_ph], -2)  # (..., 2, 3)
    g = 2.0 / SPEED_OF_LIGHT_MPS * los
    return (np.asarray(j_tau)[..., None, None] * g[..., :, None] * g[..., None, :]
            + np.einsum("...ai,...ab,...bj->...ij", t, j_ang, t))


def crlb_position_from_jacobian(s: Scenario, pos_m, j_tau, j_ang):
    """eq:CRLB_pos exactly as printed, :math:`\\Upsilon_\\mathbf p\\mathbf J_\\mathbf p^{-1}
    \\Upsilon_\\mathbf p^T` (no prior); an independent path used by the tests."""
    jp = np.zeros(np.shape(j_tau) + (3, 3))
    jp[..., 0, 0] = j_tau
    jp[..., 1:, 1:] = j_ang
    ups = position_jacobian(s, pos_m)
    return ups @ np.linalg.inv(jp) @ np.swapaxes(ups, -1, -2)


def echo_mean(s: Scenario, xi, n_sen_subcarriers: int, w, amp_sq: float):
    """Noise-free echo :math:`\\mu_{m,k}` of eq:sensing_vector_model for one target, shape (M, K_sen, N).

    .. math::
        \\boldsymbol\\mu_{m,k} = \\sqrt{P_k\\beta_S}\\, g_S\\, \\boldsymbol\\eta(\\theta,\\varphi)\\,
        e^{-jA_k\\tau_S} e^{jB_m\\nu_S},\\quad A_k = 2\\pi k\\Delta f,\\ B_m = 2\\pi m T_S

    with :math:`d_{m,k}=1`, :math:`k = 0..K_\\mathrm{sen}-1`, :math:`m = 0..\\mathcal M-1`,
    :math:`\\boldsymbol\\eta = \\mathbf a(\\mathbf a^H \\mathbf w)` and ``amp_sq`` =
    :math:`P_k\\beta_S|g_S|^2`. Used to evaluate the FIM from its definition.

    Parameters
    ----------
    xi : sequence of 4 floats
        :math:`(\\tau_S, \\theta, \\varphi, \\nu_S)`.
    w : ndarray, shape (N,)
        Beamformer, held fixed.
    """
    tau, th, ph, nu = (float(v) for v in xi)
    a, _, _ = array_response(s, th, ph)
    eta = a * np.vdot(a, w)
    k = np.arange(n_sen_subcarriers)
    m = np.arange(s.n_symbols)
    phase = (np.exp(-2j * np.pi * k * s.subcarrier_spacing_hz * tau)[None, :]
             * np.exp(2j * np.pi * m * s.symbol_duration_s * nu)[:, None])
    return np.sqrt(amp_sq) * phase[:, :, None] * eta[None, None, :]


def fim_from_definition(dmu, noise_var_w: float):
    """FIM from its definition, :math:`[\\mathbf J]_{ij} = \\frac{2}{\\sigma^2}\\sum_{m,k}
    \\Re\\{\\partial_i\\boldsymbol\\mu_{m,k}^H\\partial_j\\boldsymbol\\mu_{m,k}\\}`.

    Parameters
    ----------
    dmu : sequence of ndarray
        Derivatives of :func:`echo_mean` with respect to each parameter (any common shape).
    """
    flat = np.stack([np.ravel(d) for d in dmu])
    return 2.0 / noise_var_w * np.real(np.conj(flat) @ flat.T)


def crlb_local(s: Scenario, alpha_sen, dist_m, trig, shadow_db, fading_gain=1.0):
    """Numpy oracle of :func:`iscc_gym.physics.sensing.crlb_local` (the compiled one): the printed FIM
    (eq:FIM_tau -- eq:FIM_zero, angle entries per ``fim_angle_convention``) with the signature summed over
    the array response (:func:`iscc_gym.physics.signature.signature_derivatives` with an explicit beamformer), the
    echo power from the radar path loss in dB, the prior added and the angle block inverted by
    ``numpy.linalg.inv``. Returns ``(m_r, m_tt, m_tp, m_pp, crlb_vr)``.
    """
    from iscc_gym.physics.channel import beamformer
    from iscc_gym.physics.sensing import sensing_noise_var_w, sensing_path_loss_db
    from iscc_gym.physics.signature import signature_derivatives
    from iscc_gym.units import dbm_to_w

    ct, st, cp, sp = (np.asarray(v, dtype=float) for v in trig)
    az, el = np.arctan2(st, ct), np.arctan2(sp, cp)
    eta_sq, d_tt, d_pp, d_tp = signature_derivatives(s, az, el, w=beamformer(s, az, el))
    dist = np.asarray(dist_m, dtype=float)
    amp = (float(dbm_to_w(s.tx_power_dbm)) / s.n_subcarriers
           * 10.0 ** (-(sensing_path_loss_db(s, dist) + shadow_db - s.sensing_snr_offset_db) / 10.0) * fading_gain)
    k_sen = np.asarray(alpha_sen, dtype=float) * s.n_subcarriers
    m, sig2 = s.n_symbols, sensing_noise_var_w(s)
    j_tau = 8.0 * (np.pi * s.subcarrier_spacing_hz) ** 2 * amp * eta_sq * m * k_sen**3 / (3.0 * sig2)
    j_nu = 8.0 * (np.pi * s.symbol_duration_s) ** 2 * amp * eta_sq * k_sen * m**3 / (3.0 * sig2)
    ang = 2.0 * amp * m * k_sen / sig2
    if s.fim_angle_convention == "printed":
        ang = ang * eta_sq / 4.0
    prior = 1.0 / s.sensing_prior_var_m2
    d_az, d_el = 1.0 / (dist * np.maximum(cp, 1e-9)), 1.0 / dist
    block = np.stack([np.stack([ang * d_tt * d_az**2 + prior, ang * d_tp * d_az * d_el], -1),
                      np.stack([ang * d_tp * d_az * d_el, ang * d_pp * d_el**2 + prior], -1)], -2)
    inv = np.linalg.inv(block)
    lam_half_sq = (0.5 * s.wavelength_m) ** 2
    m_r = 1.0 / ((2.0 / SPEED_OF_LIGHT_MPS) ** 2 * j_tau + prior)
    return m_r, inv[..., 0, 0], inv[..., 0, 1], inv[..., 1, 1], lam_half_sq / (j_nu + lam_half_sq * prior)


def whitened_observation_matrix(los_unit: ArrayLike, trig: tuple[ArrayLike, ArrayLike, ArrayLike, ArrayLike],
                                m_r: ArrayLike, m_tt: ArrayLike, m_tp: ArrayLike, m_pp: ArrayLike,
                                crlb_vr: ArrayLike):
    r"""Observation matrix of the whitened ISAC measurement, shape (..., 4, 6).

    With :math:`\Sigma_\upsilon = \mathrm{blkdiag}(\mathbf U\mathbf M\mathbf U^T, \mathrm{CRLB}_{v_r})`,
    :math:`\mathbf M = \mathbf L\mathbf L^T` (Cholesky, closed form) and
    :math:`\mathbf W = \mathrm{blkdiag}(\mathbf L^{-1}\mathbf U^T, \mathrm{CRLB}_{v_r}^{-1/2})`,
    the measurement :math:`\mathbf W\mathbf y_n = \mathbf W\mathbf C_n\mathbf x_n +
    \mathbf z_n`, :math:`\mathbf z_n\sim\mathcal N(\mathbf 0, \mathbf I_4)`, carries the same
    information as eq:observation_model (the Kalman posterior is unchanged). Returns
    :math:`\mathbf W\mathbf C_n`; rows: :math:`\mathbf g^T/\sqrt{m_r}`,
    :math:`\mathbf e_\theta^T/l_{11}`, :math:`(\mathbf e_\varphi - (l_{21}/l_{11})\mathbf e_\theta)^T/l_{22}`
    on the position, :math:`\mathbf g^T/\sqrt{\mathrm{CRLB}_{v_r}}` on the velocity.
    Arguments as returned by :func:`crlb_local` and :func:`iscc_gym.physics.channel.direction_trig`.
    """
    ct, st, cp, sp = trig
    l11 = np.sqrt(m_tt)
    l21 = m_tp / l11
    inv_l22 = 1.0 / np.sqrt(m_pp - l21 * l21)
    k = l21 / l11
    w = np.zeros(np.shape(m_r) + (4, 6))
    w[..., 0, :3] = los_unit * (1.0 / np.sqrt(m_r))[..., None]
    w[..., 1, 0] = -st / l11
    w[..., 1, 1] = ct / l11
    w[..., 2, 0] = (-sp * ct + k * st) * inv_l22
    w[..., 2, 1] = (-sp * st - k * ct) * inv_l22
    w[..., 2, 2] = cp * inv_l22
    w[..., 3, 3:] = los_unit * (1.0 / np.sqrt(crlb_vr))[..., None]
    return w
