"""Monostatic OFDM ISAC sensing: radar path loss, Fisher information, CRLB of position and radial
velocity, PEB and VEB (the paper, Sec. II-C).

Every function broadcasts over leading batch axes.
"""

from __future__ import annotations

import numpy as np

from .channel import array_response, beamformer, geometry, path_loss_db
from .scenario import SPEED_OF_LIGHT_MPS, Scenario
from .units import dbm_to_w

__all__ = [
    "sensing_path_loss_db",
    "sensing_noise_var_w",
    "echo_amplitude_sq",
    "signature_derivatives",
    "fim",
    "position_information",
    "crlb",
    "crlb_position_from_jacobian",
    "position_jacobian",
    "peb",
    "veb",
    "echo_mean",
    "fim_from_definition",
]


def sensing_path_loss_db(s: Scenario, dist_m):
    """Two-way radar path loss in dB (Sec. II-C).

    .. math::
        \\mathcal L_S = 2\\mathcal L(l) - 10\\log_{10}\\sigma_\\mathrm{RCS}
        + 10\\log_{10}\\frac{\\lambda^2}{4\\pi}
    """
    lam = s.wavelength_m
    return (2.0 * path_loss_db(s, dist_m) - 10.0 * np.log10(s.rcs_m2)
            + 10.0 * np.log10(lam * lam / (4.0 * np.pi)))


def sensing_noise_var_w(s: Scenario) -> float:
    """Echo noise variance :math:`\\sigma^2` per complex dimension, in W.

    The paper never gives it. ``"full_band"``: :math:`N_0 B` (its per-subcarrier communication noise
    :math:`n_C \\sim \\mathcal{CN}(0, N_0 B)`); ``"per_subcarrier"``: :math:`N_0\\Delta f`.
    """
    bw = s.bandwidth_hz if s.sensing_noise_convention == "full_band" else s.subcarrier_spacing_hz
    return float(dbm_to_w(s.noise_psd_dbm_hz) * bw)


def echo_amplitude_sq(s: Scenario, dist_m, shadow_db, fading_gain):
    """Received echo power per element and subcarrier before array gain,
    :math:`P_k \\beta_S |g_S|^2`, in W (with :math:`P_k = P_t/\\mathcal K`), times the calibration
    ``sensing_snr_offset_db``."""
    p_k = float(dbm_to_w(s.tx_power_dbm)) / s.n_subcarriers
    loss_db = sensing_path_loss_db(s, dist_m) + shadow_db - s.sensing_snr_offset_db
    return p_k * 10.0 ** (-loss_db / 10.0) * fading_gain


def signature_derivatives(s: Scenario, azimuth_rad, elevation_rad, w=None):
    """Two-way spatial signature and its angle derivatives, with the beamformer held fixed.

    .. math::
        \\boldsymbol\\eta = \\mathbf a\\,(\\mathbf a^H \\mathbf w),\\qquad
        \\partial_\\theta \\boldsymbol\\eta = \\partial_\\theta\\mathbf a\\,(\\mathbf a^H\\mathbf w)
        + \\mathbf a\\,(\\partial_\\theta \\mathbf a^H \\mathbf w)

    The paper writes :math:`\\mathbf a^T\\mathbf w`; we use the conjugate :math:`\\mathbf a^H\\mathbf w`
    so that one beamformer has the same gain :math:`|\\mathbf a^H\\mathbf w|^2` on the
    communication and sensing links (``docs/model.md``).

    Returns
    -------
    eta_sq : ndarray, shape (...)
        :math:`\\|\\boldsymbol\\eta\\|^2`.
    d_tt, d_pp, d_tp : ndarray, shape (...)
        :math:`\\|\\partial_\\theta\\boldsymbol\\eta\\|^2`, :math:`\\|\\partial_\\varphi\\boldsymbol\\eta\\|^2`,
        :math:`\\Re\\{\\partial_\\theta\\boldsymbol\\eta^H\\partial_\\varphi\\boldsymbol\\eta\\}`.
    """
    a, da_t, da_p = array_response(s, azimuth_rad, elevation_rad)
    if w is None:
        w = beamformer(s, azimuth_rad, elevation_rad)
    t = np.einsum("...i,...i->...", np.conj(a), w)[..., None]
    dt_ = np.einsum("...i,...i->...", np.conj(da_t), w)[..., None]
    dp_ = np.einsum("...i,...i->...", np.conj(da_p), w)[..., None]
    deta_t = da_t * t + a * dt_
    deta_p = da_p * t + a * dp_
    eta_sq = np.sum(np.abs(a) ** 2, -1) * np.abs(t[..., 0]) ** 2
    d_tt = np.sum(np.abs(deta_t) ** 2, -1)
    d_pp = np.sum(np.abs(deta_p) ** 2, -1)
    d_tp = np.real(np.sum(np.conj(deta_t) * deta_p, -1))
    return eta_sq, d_tt, d_pp, d_tp


def fim(s: Scenario, alpha_sen, pos_m, shadow_db, fading_gain=1.0):
    """Closed-form Fisher information of :math:`\\boldsymbol\\xi = [\\tau_S, \\theta, \\varphi, \\nu_S]`,
    eq:FIM_tau -- eq:FIM_zero.

    .. math::
        J_{\\tau\\tau} &= \\frac{8(\\pi\\Delta f)^2 P_k\\beta_S\\|\\boldsymbol\\eta\\|^2\\mathcal M
        (\\alpha_\\mathrm{sen}\\mathcal K)^3}{3\\sigma^2},\\qquad
        J_{\\nu\\nu} = \\frac{8(\\pi T_S)^2 P_k\\beta_S\\|\\boldsymbol\\eta\\|^2
        \\alpha_\\mathrm{sen}\\mathcal K \\mathcal M^3}{3\\sigma^2},\\\\
        J_{ab} &= \\frac{2 P_k\\beta_S \\mathcal M\\alpha_\\mathrm{sen}\\mathcal K}{\\sigma^2}
        \\Re\\{\\partial_a\\boldsymbol\\eta^H\\partial_b\\boldsymbol\\eta\\},\\quad a,b\\in\\{\\theta,\\varphi\\}

    (angle entries from the FIM definition; with ``fim_angle_convention="printed"`` they carry the
    printed factor :math:`\\|\\boldsymbol\\eta\\|^2/4` on top). :math:`J_{\\tau\\theta} =
    J_{\\tau\\varphi} = 0` and :math:`\\nu_S` is decoupled, as in the paper.

    Parameters
    ----------
    alpha_sen : array_like, shape (...)
        Sensing share of the subcarriers, in [0, 1].
    pos_m : array_like, shape (..., 3)
    shadow_db : array_like, shape (...)
    fading_gain : array_like, shape (...)
        :math:`|g_S|^2` of the slot (1 for the large-scale average).

    Returns
    -------
    j_tau, j_nu : ndarray, shape (...)
        In s^-2 and Hz^-2.
    j_ang : ndarray, shape (..., 2, 2)
        Angle block (theta, phi) in rad^-2.
    """
    dist, az, el, _ = geometry(s, pos_m)
    amp = echo_amplitude_sq(s, dist, shadow_db, fading_gain)
    eta_sq, d_tt, d_pp, d_tp = signature_derivatives(s, az, el)
    sig2 = sensing_noise_var_w(s)
    k_sen = np.asarray(alpha_sen, dtype=float) * s.n_subcarriers
    m = s.n_symbols
    common = amp * eta_sq * m * k_sen / sig2
    j_tau = common * 8.0 * (np.pi * s.subcarrier_spacing_hz) ** 2 * k_sen**2 / 3.0
    j_nu = common * 8.0 * (np.pi * s.symbol_duration_s) ** 2 * m**2 / 3.0
    if s.fim_angle_convention == "printed":
        ang = common / 2.0
    else:
        ang = 2.0 * amp * m * k_sen / sig2
    j_ang = np.stack([np.stack([ang * d_tt, ang * d_tp], -1),
                      np.stack([ang * d_tp, ang * d_pp], -1)], -2)
    return j_tau, j_nu, j_ang


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


def crlb(s: Scenario, alpha_sen, pos_m, shadow_db, fading_gain=1.0):
    """Observation-noise covariances of the ISAC measurement, eq:CRLB_pos and CRLB_vr.

    .. math::
        \\mathrm{CRLB}_\\mathbf p = \\big(\\Upsilon_\\mathbf p^{-T}\\mathbf J_\\mathbf p
        \\Upsilon_\\mathbf p^{-1} + \\sigma_0^{-2}\\mathbf I_3\\big)^{-1},\\qquad
        \\mathrm{CRLB}_{v_r} = \\left(\\frac{\\lambda}{2}\\right)^2 J_{\\nu\\nu}^{-1}

    where :math:`\\sigma_0^2` is ``sensing_prior_var_m2`` (a weak prior that only matters where the
    angle information vanishes; without it this is :math:`\\Upsilon\\mathbf J^{-1}\\Upsilon^T`).
    ``alpha_sen = 0`` gives the prior alone for position and an infinite-like velocity variance
    (``sensing_prior_var_m2`` in (m/s)^2).

    Returns
    -------
    crlb_p : ndarray, shape (..., 3, 3), m^2
    crlb_vr : ndarray, shape (...), (m/s)^2
    """
    j_tau, j_nu, j_ang = fim(s, alpha_sen, pos_m, shadow_db, fading_gain)
    info = position_information(s, pos_m, j_tau, j_ang)
    info = info + np.eye(3) / s.sensing_prior_var_m2
    crlb_p = np.linalg.inv(info)
    crlb_p = 0.5 * (crlb_p + np.swapaxes(crlb_p, -1, -2))
    lam_half = 0.5 * s.wavelength_m
    crlb_vr = lam_half**2 / (np.asarray(j_nu) + lam_half**2 / s.sensing_prior_var_m2)
    return crlb_p, crlb_vr


def crlb_position_from_jacobian(s: Scenario, pos_m, j_tau, j_ang):
    """eq:CRLB_pos exactly as printed, :math:`\\Upsilon_\\mathbf p\\mathbf J_\\mathbf p^{-1}
    \\Upsilon_\\mathbf p^T` (no prior); an independent path used by the tests."""
    jp = np.zeros(np.shape(j_tau) + (3, 3))
    jp[..., 0, 0] = j_tau
    jp[..., 1:, 1:] = j_ang
    ups = position_jacobian(s, pos_m)
    return ups @ np.linalg.inv(jp) @ np.swapaxes(ups, -1, -2)


def peb(crlb_p):
    """Position error bound :math:`\\mathrm{PEB} = \\sqrt{\\operatorname{Tr}\\,\\mathrm{CRLB}_\\mathbf p}` in m."""
    return np.sqrt(np.trace(crlb_p, axis1=-2, axis2=-1))


def veb(crlb_vr):
    """Velocity error bound :math:`\\mathrm{VEB} = \\sqrt{\\mathrm{CRLB}_{v_r}}` in m/s."""
    return np.sqrt(crlb_vr)


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
