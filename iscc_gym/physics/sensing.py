"""Monostatic OFDM ISAC sensing: radar path loss, Fisher information, CRLB of position and radial
velocity, PEB and VEB (the paper, Sec. II-C).

Every function broadcasts over leading batch axes.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, vectorize
from numpy.typing import ArrayLike

from iscc_gym.physics.channel import (
    direction_trig,
    geometry,
    path_loss_db,
)
from iscc_gym.physics.signature import SIGNATURE_PARAMS, signature_derivatives, signature_one, signature_params
from iscc_gym.scenario import SPEED_OF_LIGHT_MPS, Scenario, per_scenario
from iscc_gym.units import dbm_to_w

__all__ = [
    "sensing_path_loss_db",
    "sensing_noise_var_w",
    "echo_amplitude_sq",
    "fim",
    "fim_terms",
    "crlb",
    "crlb_local",
    "local_frame",
    "peb",
    "veb",
    "echo_constant",
    "fim_constants",
    "position_info",
    "echo_amplitude_one",
    "fim_terms_one",
    "position_info_one",
    "crlb_local_one",
    "crlb_amp_one",
    "crlb_from_info_one",
    "crlb_from_info",
    "whitened_rows_one",
    "SENSING_PARAMS",
    "sensing_params",
]


def sensing_path_loss_db(s: Scenario, dist_m: ArrayLike):
    r"""Two-way radar path loss in dB (Sec. II-C).

    .. math::
        \mathcal L_S = 2\mathcal L(l) - 10\log_{10}\sigma_\mathrm{RCS}
        + 10\log_{10}\frac{\lambda^2}{4\pi}
    """
    lam = s.wavelength_m
    return (2.0 * path_loss_db(s, dist_m) - 10.0 * np.log10(s.rcs_m2)
            + 10.0 * np.log10(lam * lam / (4.0 * np.pi)))


def sensing_noise_var_w(s: Scenario) -> float:
    r"""Echo noise variance :math:`\sigma^2` per complex dimension, in W.

    The paper never gives it. ``"full_band"``: :math:`N_0 B` (its per-subcarrier communication noise
    :math:`n_C \sim \mathcal{CN}(0, N_0 B)`); ``"per_subcarrier"``: :math:`N_0\Delta f`.
    """
    bw = s.bandwidth_hz if s.sensing_noise_convention == "full_band" else s.subcarrier_spacing_hz
    return float(dbm_to_w(s.noise_psd_dbm_hz) * bw)


def echo_amplitude_sq(s: Scenario, dist_m: ArrayLike, shadow_db: ArrayLike, fading_gain: ArrayLike):
    r"""Received echo power per element and subcarrier before array gain,
    :math:`P_k \beta_S |g_S|^2`, in W (with :math:`P_k = P_t/\mathcal K`), times the calibration
    ``sensing_snr_offset_db``: the compiled :func:`echo_amplitude_one` over arrays.
    """
    return _over_arrays(_echo_loop, s, 1, dist_m, shadow_db, fading_gain)[0]


@per_scenario
def echo_constant(s: Scenario) -> float:
    """The range-independent factor of :func:`echo_amplitude_sq` (power per subcarrier, radar path
    loss at 1 m, calibration offset).
    """
    p_k = float(dbm_to_w(s.tx_power_dbm)) / s.n_subcarriers
    return p_k * 10.0 ** (-0.1 * (float(sensing_path_loss_db(s, 1.0)) - s.sensing_snr_offset_db))


def fim(s: Scenario, alpha_sen: ArrayLike, pos_m: ArrayLike, shadow_db: ArrayLike, fading_gain: ArrayLike = 1.0):
    r"""Closed-form Fisher information of :math:`\boldsymbol\xi = [\tau_S, \theta, \varphi, \nu_S]`,
    eq:FIM_tau -- eq:FIM_zero.

    .. math::
        J_{\tau\tau} &= \frac{8(\pi\Delta f)^2 P_k\beta_S\|\boldsymbol\eta\|^2\mathcal M
        (\alpha_\mathrm{sen}\mathcal K)^3}{3\sigma^2},\qquad
        J_{\nu\nu} = \frac{8(\pi T_S)^2 P_k\beta_S\|\boldsymbol\eta\|^2
        \alpha_\mathrm{sen}\mathcal K \mathcal M^3}{3\sigma^2},\\
        J_{ab} &= \frac{2 P_k\beta_S \mathcal M\alpha_\mathrm{sen}\mathcal K}{\sigma^2}
        \Re\{\partial_a\boldsymbol\eta^H\partial_b\boldsymbol\eta\},\quad a,b\in\{\theta,\varphi\}

    (angle entries from the FIM definition; with ``fim_angle_convention="printed"`` they carry the
    printed factor :math:`\|\boldsymbol\eta\|^2/4` on top). :math:`J_{\tau\theta} =
    J_{\tau\varphi} = 0` and :math:`\nu_S` is decoupled, as in the paper.

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
    j_tau, j_nu, j_tt, j_pp, j_tp = fim_terms(s, np.asarray(alpha_sen, dtype=float), dist,
                                              shadow_db, fading_gain, signature_derivatives(s, az, el))
    j_ang = np.stack([np.stack([j_tt, j_tp], -1), np.stack([j_tp, j_pp], -1)], -2)
    return j_tau, j_nu, j_ang


@per_scenario
def fim_constants(s: Scenario):
    """``(M / sigma^2, 8 (pi Delta f)^2 / 3, 8 (pi T_S)^2 M^2 / 3)``: the factors of :func:`fim_terms`."""
    m = s.n_symbols
    return (m / sensing_noise_var_w(s), (8.0 / 3.0) * (np.pi * s.subcarrier_spacing_hz) ** 2,
            (8.0 / 3.0) * (np.pi * s.symbol_duration_s) ** 2 * m * m)


def fim_terms(s: Scenario, alpha_sen: ArrayLike, dist_m: ArrayLike, shadow_db: ArrayLike, fading_gain: ArrayLike,
              signature: tuple[ArrayLike, ...]):
    """Core of :func:`fim` from the range and :func:`signature_derivatives`' output: the compiled
    :func:`echo_amplitude_one` and :func:`fim_terms_one` over arrays.

    Returns ``(j_tau, j_nu, j_thth, j_phph, j_thph)``.
    """
    return _over_arrays(_fim_loop, s, 5, alpha_sen, dist_m, shadow_db, fading_gain, *signature)


def crlb(s: Scenario, alpha_sen: ArrayLike, pos_m: ArrayLike, shadow_db: ArrayLike, fading_gain: ArrayLike = 1.0):
    r"""Observation-noise covariances of the ISAC measurement, eq:CRLB_pos and CRLB_vr.

    .. math::
        \mathrm{CRLB}_\mathbf p = \big(\Upsilon_\mathbf p^{-T}\mathbf J_\mathbf p
        \Upsilon_\mathbf p^{-1} + \sigma_0^{-2}\mathbf I_3\big)^{-1},\qquad
        \mathrm{CRLB}_{v_r} = \left(\frac{\lambda}{2}\right)^2 J_{\nu\nu}^{-1}

    where :math:`\sigma_0^2` is ``sensing_prior_var_m2`` (a weak prior that only matters where the
    angle information vanishes; without it this is :math:`\Upsilon\mathbf J^{-1}\Upsilon^T`).
    Computed in the local frame of :func:`crlb_local` and rotated back,
    :math:`\mathrm{CRLB}_\mathbf p = \mathbf U\mathbf M\mathbf U^T`.
    ``alpha_sen = 0`` gives the prior alone (also ``sensing_prior_var_m2`` in (m/s)^2 for v_r).

    Returns
    -------
    crlb_p : ndarray, shape (..., 3, 3), m^2
    crlb_vr : ndarray, shape (...), (m/s)^2
    """
    dist, _, _, los = geometry(s, pos_m)
    trig = direction_trig(los)
    m_r, m_tt, m_tp, m_pp, crlb_vr = crlb_local(s, alpha_sen, dist, trig, shadow_db, fading_gain)
    u = local_frame(los, trig)
    zero = np.zeros_like(m_r)
    m = np.stack([np.stack([m_r, zero, zero], -1), np.stack([zero, m_tt, m_tp], -1),
                  np.stack([zero, m_tp, m_pp], -1)], -2)
    return u @ m @ np.swapaxes(u, -1, -2), crlb_vr


def local_frame(los_unit: ArrayLike, trig: tuple[ArrayLike, ArrayLike, ArrayLike, ArrayLike]):
    r"""Orthonormal frame :math:`\mathbf U = [\mathbf g, \mathbf e_\theta, \mathbf e_\varphi]`
    (columns) of range, azimuth and elevation directions, shape (..., 3, 3):
    :math:`\mathbf e_\theta = [-\sin\theta, \cos\theta, 0]`,
    :math:`\mathbf e_\varphi = [-\sin\varphi\cos\theta, -\sin\varphi\sin\theta,
    \cos\varphi]`.
    """
    ct, st, cp, sp = trig
    u = np.empty(np.shape(ct) + (3, 3))
    u[..., :, 0] = los_unit
    u[..., 0, 1], u[..., 1, 1], u[..., 2, 1] = -st, ct, 0.0
    u[..., 0, 2], u[..., 1, 2], u[..., 2, 2] = -sp * ct, -sp * st, cp
    return u


def crlb_local(s: Scenario, alpha_sen: ArrayLike, dist_m: ArrayLike, trig: tuple[ArrayLike, ArrayLike, ArrayLike,
               ArrayLike], shadow_db: ArrayLike, fading_gain: ArrayLike = 1.0):
    r"""Position CRLB in the local frame :func:`local_frame` and the radial-velocity CRLB.

    The position information :math:`\Upsilon^{-T}\mathbf J_\mathbf p\Upsilon^{-1}` is, in the
    frame :math:`(\mathbf g, \mathbf e_\theta, \mathbf e_\varphi)`,
    :math:`\mathrm{blkdiag}\big((2/c)^2 J_{\tau\tau},\ \mathbf D\mathbf J_{\theta\varphi}
    \mathbf D\big)` with :math:`\mathbf D = \mathrm{diag}(1/(l\cos\varphi), 1/l)`
    (:math:`\partial\theta/\partial\mathbf p = \mathbf e_\theta/(l\cos\varphi)`,
    :math:`\partial\varphi/\partial\mathbf p = \mathbf e_\varphi/l`), so adding the prior and
    inverting takes a scalar and a 2 x 2 closed form. The compiled :func:`crlb_local_one` (the
    env's CRLB, bit for bit) over arrays of any broadcastable shapes.

    Returns
    -------
    m_r, m_tt, m_tp, m_pp : ndarray, shape (...)
        Range, azimuth-direction, cross and elevation-direction entries of M in m^2.
    crlb_vr : ndarray, shape (...)
    """
    return _over_arrays(_crlb_local_loop, s, 5, alpha_sen, dist_m, *trig, shadow_db, fading_gain)


def position_info(s: Scenario, alpha_sen: ArrayLike, dist_m: ArrayLike, trig: tuple[ArrayLike, ArrayLike, ArrayLike,
                  ArrayLike], shadow_db: ArrayLike = 0.0, fading_gain: ArrayLike = 1.0):
    r"""Position-domain Fisher information in the local frame before the prior, and :math:`J_{\nu\nu}`:
    the compiled :func:`position_info_one` of :func:`fim_terms_one` over arrays.

    Returns
    -------
    info_range, info_az, info_cross, info_el : ndarray, m^-2
        :math:`(2/c)^2 J_{\tau\tau}` and the entries of :math:`\mathbf D\mathbf J_{\theta\varphi}\mathbf D`.
    j_nu : ndarray, Hz^-2
    """
    return _over_arrays(_info_loop, s, 5, alpha_sen, dist_m, *trig, shadow_db, fading_gain)


def peb(crlb_p: ArrayLike):
    r"""Position error bound :math:`\mathrm{PEB} = \sqrt{\operatorname{Tr}\,\mathrm{CRLB}_\mathbf p}` in m."""
    return np.sqrt(np.trace(crlb_p, axis1=-2, axis2=-1))


def veb(crlb_vr: ArrayLike):
    r"""Velocity error bound :math:`\mathrm{VEB} = \sqrt{\mathrm{CRLB}_{v_r}}` in m/s."""
    return np.sqrt(crlb_vr)


# --- compiled scalar forms: one drone, composed by the slot kernel (iscc_gym.sim.loop.step_one) ---------

_LN10_OVER_10 = math.log(10.0) / 10.0


@njit(cache=True, error_model="numpy", inline="always")
def echo_amplitude_one(c, dist, shadow_db, fading):
    """:func:`echo_amplitude_sq` of one slot: ``echo_constant * dist^-4.4 * 10^(-shadow_db / 10) * fading``."""
    return c.echo_k * math.exp(-4.4 * math.log(dist) - _LN10_OVER_10 * shadow_db) * fading


@njit(cache=True, error_model="numpy", inline="always")
def fim_terms_one(c, a_sen, amp, eta_sq, d_tt, d_pp, d_tp):
    """eq:FIM_tau -- eq:FIM_zero of one slot (:func:`fim`) from the echo power ``amp`` and the signature
    terms: ``(j_tau, j_nu, j_thth, j_phph, j_thph)``.
    """
    k_sen = a_sen * c.n_sub
    base = amp * c.m_over_sig2 * k_sen
    common = base * eta_sq
    j_tau = common * c.c_tau * (k_sen * k_sen)
    j_nu = common * c.c_nu
    ang = 0.5 * common if c.fim_printed == 1.0 else 2.0 * base
    return j_tau, j_nu, ang * d_tt, ang * d_pp, ang * d_tp


@njit(cache=True, error_model="numpy", inline="always")
def position_info_one(c, dist, cp, j_tau, j_tt, j_pp, j_tp):
    r"""The position-domain information of :func:`crlb_local` in the local frame,
    ``(info_range, info_az, info_cross, info_el)`` = :math:`(2/c)^2 J_{\tau\tau}` and
    :math:`\mathbf D\mathbf J_{\theta\varphi}\mathbf D`, :math:`\mathbf D = \mathrm{diag}(1/(l\cos\varphi), 1/l)`.
    """
    inv_l = 1.0 / dist
    inv_lc = inv_l / max(cp, 1e-9)
    return j_tau * c.two_over_c_sq, j_tt * inv_lc * inv_lc, j_tp * inv_lc * inv_l, j_pp * inv_l * inv_l


@njit(cache=True, error_model="numpy", inline="always")
def _info_one(c, a_sen, dist, ct, st, cp, sp, shadow_db, fading):
    return _info_amp_one(c, a_sen, echo_amplitude_one(c, dist, shadow_db, fading), dist, ct, st, cp, sp)


@njit(cache=True, error_model="numpy", inline="always")
def _info_amp_one(c, a_sen, amp, dist, ct, st, cp, sp):
    eta_sq, d_tt, d_pp, d_tp = signature_one(c, ct, st, cp, sp)
    j_tau, j_nu, j_tt, j_pp, j_tp = fim_terms_one(c, a_sen, amp, eta_sq, d_tt, d_pp, d_tp)
    i_r, i_az, i_x, i_el = position_info_one(c, dist, cp, j_tau, j_tt, j_pp, j_tp)
    return i_r, i_az, i_x, i_el, j_nu


@njit(cache=True, error_model="numpy", inline="always")
def crlb_amp_one(c, a_sen, amp, dist, ct, st, cp, sp):
    """:func:`crlb_local_one` from the slot's echo power ``amp`` (:func:`echo_amplitude_one`), for a caller that
    reports it too (the slot's ``echo_snr_db``: computed once, not twice, issue 43.14). ``(m_r, m_tt, m_tp, m_pp,
    crlb_vr)``.
    """
    i_r, i_az, i_x, i_el, j_nu = _info_amp_one(c, a_sen, amp, dist, ct, st, cp, sp)
    return crlb_from_info_one(i_r, i_az, i_x, i_el, j_nu, c.prior, c.lam_half_sq)


@njit(cache=True, error_model="numpy")
def crlb_local_one(c, a_sen, dist, ct, st, cp, sp, shadow_db, fading):
    """:func:`crlb_local` of one drone, returning ``(m_r, m_tt, m_tp, m_pp, crlb_vr)``: :func:`signature_one`,
    :func:`echo_amplitude_one`, :func:`fim_terms_one`, :func:`position_info_one` and the inversion
    :func:`crlb_from_info_one`.

    ``c``: a record with the fields of :data:`SENSING_PARAMS` (:func:`sensing_params`, or the slot's
    :data:`iscc_gym.sim.params.SLOT_PARAMS`, which holds them too).
    """
    i_r, i_az, i_x, i_el, j_nu = _info_one(c, a_sen, dist, ct, st, cp, sp, shadow_db, fading)
    return crlb_from_info_one(i_r, i_az, i_x, i_el, j_nu, c.prior, c.lam_half_sq)


@njit(cache=True, error_model="numpy", inline="always")
def crlb_from_info_one(info_range, info_az, info_cross, info_el, j_nu, prior, lam_half_sq):
    r"""eq:CRLB_pos in the local frame from the position-domain Fisher information: the one place the
    CRLB is inverted.

    .. math::
        m_r = \frac{1}{(2/c)^2 J_{\tau\tau} + p},\qquad
        \begin{bmatrix}m_{\theta\theta} & m_{\theta\varphi}\\ m_{\theta\varphi} & m_{\varphi\varphi}
        \end{bmatrix} = \begin{bmatrix}a & b\\ b & d\end{bmatrix}^{-1},\qquad
        \mathrm{CRLB}_{v_r} = \frac{(\lambda/2)^2}{J_{\nu\nu} + (\lambda/2)^2 p}

    with :math:`a` = ``info_az`` + p, :math:`b` = ``info_cross``, :math:`d` = ``info_el`` + p (the
    entries of :math:`\mathbf D\mathbf J_{\theta\varphi}\mathbf D`), ``info_range`` =
    :math:`(2/c)^2 J_{\tau\tau}` and p the prior information ``1 / sensing_prior_var_m2``.
    Returns ``(m_r, m_tt, m_tp, m_pp, crlb_vr)``.
    """
    a = info_az + prior
    b = info_cross
    d = info_el + prior
    inv_det = 1.0 / (a * d - b * b)
    m_r = 1.0 / (info_range + prior)
    crlb_vr = lam_half_sq / (j_nu + lam_half_sq * prior)
    return m_r, d * inv_det, -b * inv_det, a * inv_det, crlb_vr


@vectorize(["float64(float64, float64, float64, float64, float64, float64, float64, int64)"], cache=True)
def _crlb_from_info_ufunc(info_range, info_az, info_cross, info_el, j_nu, prior, lam_half_sq, which):
    return crlb_from_info_one(info_range, info_az, info_cross, info_el, j_nu, prior, lam_half_sq)[which]


def crlb_from_info(info_range: ArrayLike, info_az: ArrayLike, info_cross: ArrayLike, info_el: ArrayLike,
                   j_nu: ArrayLike, prior: ArrayLike, lam_half_sq: ArrayLike):
    """:func:`crlb_from_info_one` over arrays: ``(m_r, m_tt, m_tp, m_pp, crlb_vr)``."""
    return tuple(_crlb_from_info_ufunc(info_range, info_az, info_cross, info_el, j_nu, prior, lam_half_sq, k)
                 for k in range(5))


@njit(cache=True, error_model="numpy", inline="always")
def whitened_rows_one(gx, gy, gz, ct, st, cp, sp, m_r, m_tt, m_tp, m_pp, crlb_vr, w):
    """:func:`whitened_observation_matrix` of one drone, written into the non-zero entries of ``w``
    (4, 6) (the others must be zero).
    """
    l11 = math.sqrt(m_tt)
    l21 = m_tp / l11
    inv_l22 = 1.0 / math.sqrt(m_pp - l21 * l21)
    kk = l21 / l11
    inv_sr = 1.0 / math.sqrt(m_r)
    inv_sv = 1.0 / math.sqrt(crlb_vr)
    w[0, 0], w[0, 1], w[0, 2] = gx * inv_sr, gy * inv_sr, gz * inv_sr
    w[1, 0], w[1, 1] = -st / l11, ct / l11
    w[2, 0] = (-sp * ct + kk * st) * inv_l22
    w[2, 1] = (-sp * st - kk * ct) * inv_l22
    w[2, 2] = cp * inv_l22
    w[3, 3], w[3, 4], w[3, 5] = gx * inv_sv, gy * inv_sv, gz * inv_sv


#: The sensing constants of a scenario :func:`crlb_local_one` reads (float64 fields of one record).
SENSING_PARAMS = np.dtype([(name, np.float64) for name in SIGNATURE_PARAMS.names + (
    "echo_k",                            # echo_constant
    "m_over_sig2", "c_tau", "c_nu",      # fim_constants
    "n_sub",          # subcarriers K
    "fim_printed",    # 1.0 with fim_angle_convention="printed"
    "prior",          # 1 / sensing_prior_var_m2
    "two_over_c_sq",  # (2 / c)^2
    "lam_half_sq",    # (lambda / 2)^2
)], align=True)


@per_scenario
def sensing_params(s: Scenario):
    """The :data:`SENSING_PARAMS` record of a scenario, a read-only structured array of shape (1,)."""
    c = np.zeros(1, SENSING_PARAMS)
    r = c[0]
    sig = signature_params(s)[0]
    for name in SIGNATURE_PARAMS.names:
        r[name] = sig[name]
    r["echo_k"] = echo_constant(s)
    r["m_over_sig2"], r["c_tau"], r["c_nu"] = fim_constants(s)
    r["n_sub"] = s.n_subcarriers
    r["fim_printed"] = float(s.fim_angle_convention == "printed")
    r["prior"] = 1.0 / s.sensing_prior_var_m2
    r["two_over_c_sq"] = (2.0 / SPEED_OF_LIGHT_MPS) ** 2
    r["lam_half_sq"] = (0.5 * s.wavelength_m) ** 2
    c.setflags(write=False)
    return c


# --- array forms: the compiled scalar functions over flattened, broadcast numpy arrays ----------------

def _over_arrays(loop, s: Scenario, n_out: int, *arrays):
    """Broadcast ``arrays``, run ``loop(sensing_params(s), *flat, out)`` over them and return the ``n_out``
    outputs in the broadcast shape.
    """
    args = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in arrays))
    shape = args[0].shape
    out = np.empty((n_out, args[0].size))
    # copies: a view of broadcast_arrays warns when numba reads its writeable flag
    loop(sensing_params(s), *(np.array(a, order="C").reshape(-1) for a in args), out)
    return tuple(o.reshape(shape) for o in out)


@njit(cache=True, error_model="numpy")
def _crlb_local_loop(cp, a_sen, dist, ct, st, cp_, sp, shadow_db, fading, out):
    c = cp[0]
    for i in range(a_sen.shape[0]):
        out[0, i], out[1, i], out[2, i], out[3, i], out[4, i] = crlb_local_one(
            c, a_sen[i], dist[i], ct[i], st[i], cp_[i], sp[i], shadow_db[i], fading[i])


@njit(cache=True, error_model="numpy")
def _info_loop(cp, a_sen, dist, ct, st, cp_, sp, shadow_db, fading, out):
    c = cp[0]
    for i in range(a_sen.shape[0]):
        out[0, i], out[1, i], out[2, i], out[3, i], out[4, i] = _info_one(
            c, a_sen[i], dist[i], ct[i], st[i], cp_[i], sp[i], shadow_db[i], fading[i])


@njit(cache=True, error_model="numpy")
def _fim_loop(cp, a_sen, dist, shadow_db, fading, eta_sq, d_tt, d_pp, d_tp, out):
    c = cp[0]
    for i in range(a_sen.shape[0]):
        amp = echo_amplitude_one(c, dist[i], shadow_db[i], fading[i])
        out[0, i], out[1, i], out[2, i], out[3, i], out[4, i] = fim_terms_one(
            c, a_sen[i], amp, eta_sq[i], d_tt[i], d_pp[i], d_tp[i])


@njit(cache=True, error_model="numpy")
def _echo_loop(cp, dist, shadow_db, fading, out):
    c = cp[0]
    for i in range(dist.shape[0]):
        out[0, i] = echo_amplitude_one(c, dist[i], shadow_db[i], fading[i])
