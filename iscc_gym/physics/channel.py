"""Air-to-ground channel: geometry, 3GPP UMa-AV LoS path loss, shadowing, Rician fading, UPA, SNR.

All functions broadcast over leading batch axes: positions have shape ``(..., 3)``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import guvectorize, njit, vectorize
from numpy.typing import ArrayLike

from iscc_gym.scenario import Scenario, per_scenario
from iscc_gym.units import db_to_lin, dbm_to_w

__all__ = [
    "geometry",
    "direction_trig",
    "direction_cosines_trig",
    "matched_gain",
    "beam_gain",
    "link_snr",
    "path_loss_db",
    "shadowing_std_db",
    "direction_cosines",
    "array_response",
    "beamformer",
    "beamforming_gain",
    "noise_power_w",
    "large_scale_snr",
    "rician_constants",
    "snr_constant",
    "ORIENTATIONS",
    "trig_one",
    "direction_one",
    "shadowing_db_one",
    "link_snr_one",
    "rician_gain_one",
    "shadowing_step_one",
    "upa_terms_one",
    "broadside_sums_one",
    "beam_gain_one",
]


def geometry(s: Scenario, pos_m: ArrayLike):
    r"""Range, azimuth, elevation and LoS unit vector of the drone seen from the GBS antenna.

    .. math::
        \mathbf{r} = \mathbf{p} - [0, 0, h_\mathrm{GBS}]^T,\quad l = \|\mathbf{r}\|_2,\quad
        \theta = \operatorname{atan2}(r_y, r_x),\quad \varphi = \arcsin(r_z / l),\quad
        \mathbf{g} = \mathbf{r} / l

    Parameters
    ----------
    s : Scenario
    pos_m : array_like, shape (..., 3)
        Drone position in m (ground origin below the GBS mast).

    Returns
    -------
    dist_m, azimuth_rad, elevation_rad : ndarray, shape (...)
    los_unit : ndarray, shape (..., 3)
        The unit LoS direction g_n used to project velocity on the radial direction.
    """
    rel = np.asarray(pos_m, dtype=float) - np.array([0.0, 0.0, s.gbs_height_m])
    dist = np.sqrt(np.einsum("...i,...i->...", rel, rel))
    dist = np.maximum(dist, 1e-9)
    los = rel / dist[..., None]
    az = np.arctan2(rel[..., 1], rel[..., 0])
    el = np.arcsin(np.clip(los[..., 2], -1.0, 1.0))
    return dist, az, el, los


def path_loss_db(s: Scenario, dist_m: ArrayLike):
    r"""3GPP TR 36.777 UMa-AV LoS path loss in dB.

    .. math:: \mathcal{L}(l) = 28.0 + 22\log_{10}(l) + 20\log_{10}(f_c)

    with :math:`l` in m and :math:`f_c` in GHz (the paper, Sec. II-B).
    """
    return 28.0 + 22.0 * np.log10(dist_m) + 20.0 * np.log10(s.carrier_freq_ghz)


def shadowing_std_db(s: Scenario, altitude_m: ArrayLike):
    r"""Shadowing standard deviation :math:`\sigma_\mathrm{SF}(h) = 4.64 e^{-0.0066 h}` dB (Table I).

    ``altitude_m`` is the drone height above ground in m.
    """
    return s.shadowing_a_db * np.exp(-s.shadowing_b_per_m * altitude_m)


@per_scenario
def rician_constants(s: Scenario):
    r"""``(los, scat)``: :math:`\sqrt{K/(K+1)}` and :math:`\sqrt{1/(2(K+1))}` of :func:`rician_gain_one`."""
    k = float(db_to_lin(s.rician_k_db))
    return float(np.sqrt(k / (k + 1.0))), float(np.sqrt(0.5 / (k + 1.0)))


def _element_indices(s: Scenario):
    # Phase reference at the array centre; element order a_x (kron) a_y.
    ix = np.arange(s.n_x) - 0.5 * (s.n_x - 1)
    iy = np.arange(s.n_y) - 0.5 * (s.n_y - 1)
    return np.repeat(ix, s.n_y), np.tile(iy, s.n_x)


def direction_trig(los_unit: ArrayLike):
    r"""Sines and cosines of the azimuth and elevation of a unit LoS vector, without trigonometry.

    .. math::
        \cos\varphi = \sqrt{g_x^2 + g_y^2},\ \sin\varphi = g_z,\
        \cos\theta = g_x/\cos\varphi,\ \sin\theta = g_y/\cos\varphi

    (azimuth 0 at the zenith, where it is undefined). Returns ``(cos_az, sin_az, cos_el, sin_el)``;
    the array form of the compiled :func:`trig_one`.
    """
    g = np.asarray(los_unit, dtype=float)
    return tuple(v[()] for v in _trig_ufunc(g[..., 0], g[..., 1], g[..., 2]))


def direction_cosines(s: Scenario, azimuth_rad: ArrayLike, elevation_rad: ArrayLike):
    r"""The two phase-progression terms (u_x, u_y) of the UPA and their angle derivatives.

    ``array_orientation`` selects the response (see :class:`Scenario`):

    * ``"printed"``: :math:`u_x = \sin\theta\cos\varphi,\ u_y = \sin\theta\sin\varphi`
      (the paper's :math:`\mathbf a_x, \mathbf a_y` as printed);
    * ``"vertical"``: :math:`u_x = \cos\varphi\sin\theta,\ u_y = \sin\varphi`;
    * ``"horizontal"``: :math:`u_x = \cos\varphi\cos\theta,\ u_y = \cos\varphi\sin\theta`.

    Returns
    -------
    u : ndarray, shape (..., 2)
    du_dtheta, du_dphi : ndarray, shape (..., 2)
    """
    th = np.asarray(azimuth_rad, dtype=float)
    ph = np.asarray(elevation_rad, dtype=float)
    u, dth, dph = direction_cosines_trig(s, np.cos(th), np.sin(th), np.cos(ph), np.sin(ph))
    return np.stack(u, -1), np.stack(dth, -1), np.stack(dph, -1)


def direction_cosines_trig(s: Scenario, ct: ArrayLike, st: ArrayLike, cp: ArrayLike, sp: ArrayLike):
    """:func:`direction_cosines` from the angles' cosines and sines; returns three (x, y) tuples (the
    array form of the compiled :func:`upa_terms_one`).
    """
    ux, uy, tx, ty, qx, qy = (v[()] for v in _upa_ufunc(ORIENTATIONS[s.array_orientation], ct, st, cp, sp))
    return (ux, uy), (tx, ty), (qx, qy)


def array_response(s: Scenario, azimuth_rad: ArrayLike, elevation_rad: ArrayLike):
    r"""UPA response :math:`\mathbf a(\theta,\varphi) = \mathbf a_x \otimes \mathbf a_y` and derivatives.

    .. math::
        [\mathbf a]_{(i,j)} = \exp\big(j 2\pi \tfrac{d_\lambda}{\lambda}
        (i\, u_x + j\, u_y)\big)

    with centred element indices (phase reference at the array centre) and (u_x, u_y) from
    :func:`direction_cosines`.

    Returns
    -------
    a, da_dtheta, da_dphi : ndarray, complex, shape (..., n_x n_y)
    """
    ix, iy = _element_indices(s)
    u, dth, dph = direction_cosines(s, azimuth_rad, elevation_rad)
    k = 2.0 * np.pi * s.antenna_spacing_wavelengths
    phase = k * (u[..., :1] * ix + u[..., 1:] * iy)
    a = np.exp(1j * phase)
    dphase_th = k * (dth[..., :1] * ix + dth[..., 1:] * iy)
    dphase_ph = k * (dph[..., :1] * ix + dph[..., 1:] * iy)
    return a, 1j * dphase_th * a, 1j * dphase_ph * a


def beamformer(s: Scenario, azimuth_rad: ArrayLike, elevation_rad: ArrayLike):
    r"""Unit-norm transmit beamformer w, shape (..., N).

    ``"matched"``: :math:`\mathbf w = \mathbf a(\theta,\varphi)/\sqrt N` (steered at the given
    direction, :math:`G = N`); ``"broadside"``: :math:`\mathbf w = \mathbf 1/\sqrt N`.
    """
    n = s.n_antennas
    if s.beamforming == "matched":
        a, _, _ = array_response(s, azimuth_rad, elevation_rad)
        return a / np.sqrt(n)
    shape = np.broadcast(np.asarray(azimuth_rad), np.asarray(elevation_rad)).shape
    return np.full(shape + (n,), 1.0 / np.sqrt(n), dtype=complex)


def beamforming_gain(a: ArrayLike, w: ArrayLike):
    r"""Beamforming gain :math:`G(\theta,\varphi) = |\mathbf a^H \mathbf w|^2` (Sec. II-B)."""
    return np.abs(np.einsum("...i,...i->...", np.conj(a), w)) ** 2


def noise_power_w(s: Scenario):
    """Receiver noise power :math:`N_0 B` in W."""
    return float(dbm_to_w(s.noise_psd_dbm_hz) * s.bandwidth_hz)


def large_scale_snr(s: Scenario, pos_m: ArrayLike, shadow_db: ArrayLike, gain: ArrayLike = None):
    r"""Link SNR without small-scale fading (:math:`|g|^2 = 1`), linear.

    .. math::
        \bar\gamma = \frac{P\, \beta_C\, G(\theta,\varphi)}{N_0 B},\qquad
        \sqrt{\beta_C} = 10^{-(\mathcal L + \varepsilon)/20}

    with :math:`P = P_t` (``snr_convention="total_power"``, the printed eq. of :math:`\gamma`) or
    :math:`P = P_k = P_t/\mathcal K` (``"per_subcarrier_power"``), times the calibration
    ``comm_snr_offset_db``. The slot's SNR is :math:`\gamma = |g_C|^2 \bar\gamma`.

    Parameters
    ----------
    pos_m : array_like, shape (..., 3)
    shadow_db : array_like, shape (...)
        Shadowing :math:`\varepsilon` in dB.
    gain : array_like, optional
        Beamforming gain; the scenario's beamformer steered at the drone if omitted (for
        ``"matched"`` this is exactly :math:`G = N`).
    """
    dist, az, el, _ = geometry(s, pos_m)
    if gain is None:
        gain = matched_gain(s) if s.beamforming == "matched" else None
    if gain is None:
        a, _, _ = array_response(s, az, el)
        gain = beamforming_gain(a, beamformer(s, az, el))
    return link_snr(s, dist, shadow_db, gain)


def matched_gain(s: Scenario) -> float:
    r"""Gain of the matched beamformer, :math:`|\mathbf a^H \mathbf a|^2/N = N`."""
    return float(s.n_antennas)


def beam_gain(s: Scenario, trig: tuple[ArrayLike, ArrayLike, ArrayLike, ArrayLike]):
    """Beamforming gain towards a direction given by :func:`direction_trig`'s output (matched: N)."""
    if s.beamforming == "matched":
        return matched_gain(s)
    ct, st, cp, sp = trig
    az, el = np.arctan2(st, ct), np.arctan2(sp, cp)
    a, _, _ = array_response(s, az, el)
    return beamforming_gain(a, beamformer(s, az, el))


def link_snr(s: Scenario, dist_m: ArrayLike, shadow_db: ArrayLike, gain: ArrayLike):
    r""":func:`large_scale_snr` from the range, the shadowing and the beamforming gain.

    The dB budget :math:`P - \mathcal L(l) - \varepsilon + \Delta - N_0B` in linear form,
    :math:`\kappa\, G\, l^{-2.2}\, 10^{-\varepsilon/10}`, with the constant :math:`\kappa` cached;
    the array form of the compiled :func:`link_snr_one`.
    """
    return _link_snr_ufunc(snr_constant(s), gain, dist_m, shadow_db)[()]


@per_scenario
def snr_constant(s: Scenario) -> float:
    r"""The range-independent factor :math:`\kappa` of :func:`link_snr` (transmit power over noise,
    path loss at 1 m and the carrier, calibration offset).
    """
    p_w = float(dbm_to_w(s.tx_power_dbm))
    if s.snr_convention == "per_subcarrier_power":
        p_w /= s.n_subcarriers
    # path_loss_db(l) = 28 + 20 log10 f_c + 22 log10 l: the l-independent part goes here
    fixed_db = float(path_loss_db(s, 1.0)) - s.comm_snr_offset_db
    return p_w / noise_power_w(s) * 10.0 ** (-0.1 * fixed_db)


# --- compiled scalar forms: one drone, composed by the slot kernel (iscc_gym.sim.loop.step_one) ---------
# ``inline="always"``: numba inlines them into the caller's IR, so they compile with the caller's flags.

_LN10_OVER_10 = math.log(10.0) / 10.0


@njit(cache=True, error_model="numpy", inline="always")
def trig_one(gx, gy, gz):
    """:func:`direction_trig` of one unit LoS vector, ``(cos_az, sin_az, cos_el, sin_el)``."""
    cp = math.sqrt(gx * gx + gy * gy)
    zenith = 1.0 if cp < 1e-12 else 0.0  # azimuth undefined: take theta = 0
    inv = 1.0 / max(cp, 1e-12)
    return gx * inv + zenith, gy * inv, cp, gz


@njit(cache=True, error_model="numpy", inline="always")
def direction_one(h_gbs, px, py, pz):
    """:func:`geometry` and :func:`direction_trig` of one position: ``(dist, gx, gy, gz, cos_az, sin_az,
    cos_el, sin_el)`` (range in m, LoS unit vector, cosines and sines of azimuth and elevation).
    """
    rx, ry, rz = px, py, pz - h_gbs
    dist = math.sqrt(rx * rx + ry * ry + rz * rz)
    gx, gy, gz = rx / dist, ry / dist, rz / dist
    ct, st, cp, sp = trig_one(gx, gy, gz)
    return dist, gx, gy, gz, ct, st, cp, sp


@njit(cache=True, error_model="numpy", inline="always")
def shadowing_db_one(sf_a, sf_b, altitude_m, shadow_norm):
    """Shadowing in dB, :func:`shadowing_std_db` times the unit-variance state."""
    return sf_a * math.exp(-sf_b * altitude_m) * shadow_norm


@njit(cache=True, error_model="numpy", inline="always")
def link_snr_one(snr_k, gain, dist_m, shadow_db):
    r""":func:`link_snr`, :math:`\kappa G l^{-2.2} 10^{-\varepsilon/10}`, as one exp of a log (two
    powers cost more than the rest of the slot).
    """
    return snr_k * gain * math.exp(-2.2 * math.log(dist_m) - _LN10_OVER_10 * shadow_db)


@njit(cache=True, error_model="numpy", inline="always")
def rician_gain_one(los, scat, z_re, z_im):
    """:func:`rician_gain_one` of one draw (``los``, ``scat`` from :func:`rician_constants`)."""
    re = los + scat * z_re
    im = scat * z_im
    return re * re + im * im


@njit(cache=True, error_model="numpy", inline="always")
def shadowing_step_one(neg_inv_decorr, shadow_norm, moved_m, z):
    """:func:`shadowing_step` of one loop (``neg_inv_decorr`` = -1 / shadowing_decorrelation_m)."""
    rho = math.exp(moved_m * neg_inv_decorr)
    return rho * shadow_norm + math.sqrt(1.0 - rho * rho) * z


@njit(cache=True, error_model="numpy", inline="always")
def upa_terms_one(orient, ct, st, cp, sp):
    """:func:`direction_cosines_trig` of one direction, ``(ux, uy, dux_dth, duy_dth, dux_dph, duy_dph)``;
    ``orient`` from :data:`ORIENTATIONS` (``Scenario.array_orientation``).
    """
    if orient == 0.0:
        return cp * ct, cp * st, -cp * st, cp * ct, -sp * ct, -sp * st
    if orient == 1.0:
        return st * cp, st * sp, ct * cp, ct * sp, -st * sp, st * cp
    return cp * st, sp, cp * ct, 0.0, -sp * st, cp


@njit(cache=True, error_model="numpy")
def broadside_sums_one(kd, n_x, n_y, ux, uy, tx, ty, qx, qy):
    r"""Sums over the UPA of the broadside beamformer in one direction.

    The beamformer is :math:`\mathbf w = \mathbf 1/\sqrt N` (element phases
    :math:`\phi_i = k(i_x u_x + i_y u_y)` on the centred grid, ``kd`` = :math:`k = 2\pi d/\lambda`,
    ``(tx, ty)``, ``(qx, qy)`` the derivatives of (u_x, u_y) in azimuth and elevation).
    Returns ``(t, d_th, d_ph, s_tt, s_pp, s_tp)``:

    .. math::
        t = \mathbf a^H\mathbf w = \tfrac{1}{\sqrt N}\sum_i\cos\phi_i,\quad
        \partial_a\mathbf a^H\mathbf w = -\tfrac{1}{\sqrt N}\sum_i\psi_{a,i}\sin\phi_i,\quad
        s_{ab} = \sum_i\psi_{a,i}\psi_{b,i}

    with :math:`\psi_{a,i} = \partial_a\phi_i`; the grid's point symmetry makes t and the derivatives
    real (the sine sums of t and the cosine sums of its derivatives vanish).
    """
    t = d_th = d_ph = s_tt = s_pp = s_tp = 0.0
    cx, cy = 0.5 * (n_x - 1), 0.5 * (n_y - 1)
    for i in range(n_x):
        ix = i - cx
        for j in range(n_y):
            iy = j - cy
            phi = kd * (ix * ux + iy * uy)
            c, s = math.cos(phi), math.sin(phi)
            p_th = kd * (ix * tx + iy * ty)
            p_ph = kd * (ix * qx + iy * qy)
            t += c
            d_th += p_th * s
            d_ph += p_ph * s
            s_tt += p_th * p_th
            s_pp += p_ph * p_ph
            s_tp += p_th * p_ph
    inv = 1.0 / math.sqrt(n_x * n_y)
    return t * inv, -d_th * inv, -d_ph * inv, s_tt, s_pp, s_tp


@njit(cache=True, error_model="numpy", inline="always")
def beam_gain_one(c, ct, st, cp, sp):
    r""":func:`beam_gain` of one direction: ``c.beam_g`` (= N) for the matched beamformer, else the
    broadside gain :math:`|\mathbf a^H\mathbf w|^2` (:func:`broadside_sums_one`). ``c``: a record with
    ``broadside``, ``beam_g``, ``orient``, ``kd``, ``n_x``, ``n_y`` (:data:`iscc_gym.sim.params.SLOT_PARAMS`).
    """
    if c.broadside == 0.0:
        return c.beam_g
    ux, uy, tx, ty, qx, qy = upa_terms_one(c.orient, ct, st, cp, sp)
    t = broadside_sums_one(c.kd, int(c.n_x), int(c.n_y), ux, uy, tx, ty, qx, qy)[0]
    return t * t


# --- array forms of the compiled scalar functions (the numpy API above calls these) ---------------------

#: ``Scenario.array_orientation`` as the code :func:`upa_terms_one` reads.
ORIENTATIONS = {"horizontal": 0.0, "printed": 1.0, "vertical": 2.0}


@vectorize(["float64(float64, float64, float64, float64)"], cache=True)
def _link_snr_ufunc(snr_k, gain, dist_m, shadow_db):
    return link_snr_one(snr_k, gain, dist_m, shadow_db)


@guvectorize(["void(float64, float64, float64, float64[:], float64[:], float64[:], float64[:])"],
             "(),(),()->(),(),(),()", cache=True)
def _trig_ufunc(gx, gy, gz, ct, st, cp, sp):
    ct[0], st[0], cp[0], sp[0] = trig_one(gx, gy, gz)


@guvectorize(["void(float64, float64, float64, float64, float64, float64[:], float64[:], float64[:], float64[:], "
              "float64[:], float64[:])"], "(),(),(),(),()->(),(),(),(),(),()", cache=True)
def _upa_ufunc(orient, ct, st, cp, sp, ux, uy, tx, ty, qx, qy):
    ux[0], uy[0], tx[0], ty[0], qx[0], qy[0] = upa_terms_one(orient, ct, st, cp, sp)
