"""The two-way spatial signature of the UPA and its angle derivatives: the array side of the sensing
Fisher information (:mod:`iscc_gym.physics.sensing`), for the matched and the broadside beamformer.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

from iscc_gym.physics.channel import ORIENTATIONS, array_response, broadside_sums_one, upa_terms_one
from iscc_gym.scenario import Scenario, per_scenario

__all__ = ["signature_derivatives", "index_moments", "signature_terms", "signature_one", "SIGNATURE_PARAMS",
           "signature_params"]


def signature_derivatives(s: Scenario, azimuth_rad: ArrayLike, elevation_rad: ArrayLike, w: ArrayLike = None):
    r"""Two-way spatial signature and its angle derivatives, with the beamformer held fixed.

    .. math::
        \boldsymbol\eta = \mathbf a\,(\mathbf a^H \mathbf w),\qquad
        \partial_\theta \boldsymbol\eta = \partial_\theta\mathbf a\,(\mathbf a^H\mathbf w)
        + \mathbf a\,(\partial_\theta \mathbf a^H \mathbf w)

    The paper writes :math:`\mathbf a^T\mathbf w`; we use the conjugate :math:`\mathbf a^H\mathbf w`
    so that one beamformer has the same gain :math:`|\mathbf a^H\mathbf w|^2` on the
    communication and sensing links (``docs/model.md``).

    ``w=None`` (the scenario's beamformer) is the closed form :func:`signature_terms`; an explicit
    ``w`` sums over the elements of :func:`iscc_gym.physics.channel.array_response`.

    Returns
    -------
    eta_sq : ndarray, shape (...)
        :math:`\|\boldsymbol\eta\|^2`.
    d_tt, d_pp, d_tp : ndarray, shape (...)
        :math:`\|\partial_\theta\boldsymbol\eta\|^2`, :math:`\|\partial_\varphi\boldsymbol\eta\|^2`,
        :math:`\Re\{\partial_\theta\boldsymbol\eta^H\partial_\varphi\boldsymbol\eta\}`.
    """
    if w is None:
        th = np.asarray(azimuth_rad, dtype=float)
        ph = np.asarray(elevation_rad, dtype=float)
        return signature_terms(s, np.cos(th), np.sin(th), np.cos(ph), np.sin(ph))
    a, da_t, da_p = array_response(s, azimuth_rad, elevation_rad)
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


@per_scenario
def index_moments(s: Scenario):
    """``(sxx, syy, eta_sq)`` of the matched beamformer in :func:`signature_terms`."""
    # N k^2 times the sums over the grid of the squared centred element indices along each axis,
    # and ||eta||^2 = N^2 of the matched beamformer
    ix = np.arange(s.n_x) - 0.5 * (s.n_x - 1)
    iy = np.arange(s.n_y) - 0.5 * (s.n_y - 1)
    n = s.n_antennas
    c = n * (2.0 * np.pi * s.antenna_spacing_wavelengths) ** 2
    return c * s.n_y * float(ix @ ix), c * s.n_x * float(iy @ iy), float(n * n)


def signature_terms(s: Scenario, ct: ArrayLike, st: ArrayLike, cp: ArrayLike, sp: ArrayLike):
    r""":func:`signature_derivatives` of the scenario's beamformer in closed form, from cos/sin of
    azimuth and elevation: the compiled :func:`signature_one` over arrays.

    For the matched beamformer, with :math:`\mathbf w = \mathbf a/\sqrt N` and the phase reference at
    the array centre, :math:`\mathbf a^H\mathbf w = \sqrt N` and :math:`\partial\mathbf a^H\mathbf w = 0`, so

    .. math::
        \|\boldsymbol\eta\|^2 = N^2,\qquad
        \Re\{\partial_a\boldsymbol\eta^H\partial_b\boldsymbol\eta\} = N k^2 \left(
        \partial_a u_x\,\partial_b u_x \sum i^2 + \partial_a u_y\,\partial_b u_y \sum j^2\right)

    with :math:`k = 2\pi d_\lambda/\lambda` and the sums over the centred element grid
    (:math:`\sum ij = 0`, :func:`index_moments`). The broadside beamformer's sums are
    :func:`iscc_gym.physics.channel.broadside_sums_one`.

    Returns ``(eta_sq, d_tt, d_pp, d_tp)`` as :func:`signature_derivatives`.
    """
    args = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (ct, st, cp, sp)))
    out = np.empty((4, args[0].size))
    _signature_loop(signature_params(s), *(np.ascontiguousarray(a).reshape(-1) for a in args), out)
    return tuple(o.reshape(args[0].shape) for o in out)


#: The array constants :func:`signature_one` reads (float64 fields of one record).
SIGNATURE_PARAMS = np.dtype([(name, np.float64) for name in (
    "orient",         # array orientation: 0 horizontal, 1 printed, 2 vertical
    "broadside",      # 1.0 with beamforming="broadside", 0.0 matched
    "kd", "n_x", "n_y",                  # 2 pi d / lambda, UPA size
    "sxx", "syy", "eta_sq",              # index_moments
)], align=True)  # aligned: the device loads each field whole (issue 46)


@per_scenario
def signature_params(s: Scenario):
    """The :data:`SIGNATURE_PARAMS` record of a scenario, a read-only structured array of shape (1,)."""
    c = np.zeros(1, SIGNATURE_PARAMS)
    r = c[0]
    r["orient"] = ORIENTATIONS[s.array_orientation]
    r["broadside"] = float(s.beamforming == "broadside")
    r["kd"], r["n_x"], r["n_y"] = 2.0 * np.pi * s.antenna_spacing_wavelengths, s.n_x, s.n_y
    r["sxx"], r["syy"], r["eta_sq"] = index_moments(s)
    c.setflags(write=False)
    return c


# --- compiled scalar form and its array loop -------------------------------------------------------

@njit(cache=True, error_model="numpy", inline="always")
def signature_one(c, ct, st, cp, sp):
    """:func:`signature_terms` of one direction, ``(eta_sq, d_tt, d_pp, d_tp)``: the matched beamformer
    from :func:`index_moments`, or the broadside beamformer by :func:`iscc_gym.physics.channel.broadside_sums_one`
    (``c``: a record with the fields of :data:`SIGNATURE_PARAMS`, e.g. :data:`iscc_gym.physics.sensing.SENSING_PARAMS`).
    """
    if c.broadside == 0.0:  # the matched beamformer (index_moments)
        _, _, tx, ty, qx, qy = upa_terms_one(c.orient, ct, st, cp, sp)
        sxx, syy = c.sxx, c.syy
        d_tt = sxx * (tx * tx) + syy * (ty * ty)
        d_pp = sxx * (qx * qx) + syy * (qy * qy)
        d_tp = sxx * (tx * qx) + syy * (ty * qy)
        eta_sq = c.eta_sq
    else:  # signature_derivatives of the broadside beamformer (eta = a t, d eta = da t + a dt, t real)
        ux, uy, tx, ty, qx, qy = upa_terms_one(c.orient, ct, st, cp, sp)
        t, d_th, d_ph, s_tt, s_pp, s_tp = broadside_sums_one(c.kd, int(c.n_x), int(c.n_y), ux, uy, tx, ty, qx, qy)
        n_ant = c.n_x * c.n_y
        t2 = t * t
        eta_sq = n_ant * t2
        d_tt = t2 * s_tt + n_ant * (d_th * d_th)
        d_pp = t2 * s_pp + n_ant * (d_ph * d_ph)
        d_tp = t2 * s_tp + n_ant * (d_th * d_ph)
    return eta_sq, d_tt, d_pp, d_tp


@njit(cache=True, error_model="numpy")
def _signature_loop(cp, ct, st, cp_, sp, out):
    c = cp[0]
    for i in range(ct.shape[0]):
        out[0, i], out[1, i], out[2, i], out[3, i] = signature_one(c, ct[i], st[i], cp_[i], sp[i])
