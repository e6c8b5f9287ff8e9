"""Finite-blocklength rate (Polyanskiy normal approximation) and control-packet drop probability."""

from __future__ import annotations

import math

import numpy as np
from numba import guvectorize, njit, vectorize
from numpy.typing import ArrayLike
from scipy.special import erfc, ndtri

from iscc_gym.scenario import Scenario, per_scenario

__all__ = ["dispersion", "q_func", "q_inv", "link_terms", "fbl_rate_bps", "comm_rate_bps",
           "ctrl_rate_bps", "ctrl_bler", "ctrl_bler_and_slope", "ctrl_goodput_bits", "slot_link", "min_shares",
           "link_constants",
           "link_terms_one", "ctrl_bler_arg_one", "ctrl_bler_one", "ctrl_bler_slope_one", "rate_one", "delivered_one",
           "min_ctrl_share_one", "min_comm_share_one",
           "LINK_PARAMS", "link_params", "ctrl_bler_ufunc"]

_INV_SQRT2 = 1.0 / np.sqrt(2.0)


def q_func(x: ArrayLike):
    r"""Gaussian tail :math:`Q(x) = \tfrac12 \operatorname{erfc}(x/\sqrt2)`.

    For x above about 37 the result is subnormal or 0 (a gradual underflow, not an error).
    """
    with np.errstate(under="ignore"):
        return 0.5 * erfc(np.asarray(x, dtype=float) * _INV_SQRT2)


def q_inv(p: ArrayLike):
    r"""Inverse Gaussian tail :math:`Q^{-1}(p) = -\Phi^{-1}(p)`."""
    return -ndtri(np.asarray(p, dtype=float))


def dispersion(snr: ArrayLike):
    r"""Channel dispersion of the AWGN channel in bits^2 per channel use.

    .. math:: V(\gamma) = (\log_2 e)^2 \left[1 - (1+\gamma)^{-2}\right]

    (the paper, below eq:rate_equation). ``snr`` is linear; the square of the second term of
    :func:`link_terms`.
    """
    return link_terms(snr)[1] ** 2


def link_terms(snr: ArrayLike):
    r"""Capacity :math:`\log_2(1+\gamma)` and :math:`\sqrt{V(\gamma)}` of linear SNRs, the two SNR terms
    every FBL quantity here is built from: :func:`link_terms_one` over arrays.
    """
    return _link_terms_ufunc(np.asarray(snr, dtype=float))


def fbl_rate_bps(alpha: ArrayLike, bandwidth_hz: ArrayLike, snr: ArrayLike, blocklength: ArrayLike, bler: ArrayLike):
    r"""Effective FBL rate of a share ``alpha`` of the band, eq:rate_equation, in bit/s.

    .. math::
        \mathcal R_i = \alpha_i B\left[\log_2(1+\gamma) - \sqrt{\frac{V}{L_i}}\,
        Q^{-1}(\varepsilon_i)\right]

    Clipped at zero (no negative rates at very low SNR). :func:`rate_one` over arrays.
    """
    return _rate_ufunc(alpha, snr, bandwidth_hz, q_inv(bler) / np.sqrt(blocklength))


@per_scenario
def link_constants(s: Scenario):
    """(comm back-off Q^-1(eps)/sqrt(L), ctrl back-off, S / (T_d B), sqrt(L_ctrl))."""
    return (float(q_inv(s.comm_target_bler)) / np.sqrt(s.comm_blocklength),
            float(q_inv(s.ctrl_target_bler)) / np.sqrt(s.ctrl_blocklength),
            s.ctrl_packet_bits / (s.ctrl_deadline_s * s.bandwidth_hz), np.sqrt(s.ctrl_blocklength))


def comm_rate_bps(s: Scenario, alpha_comm: ArrayLike, snr: ArrayLike):
    r"""Data-link FBL rate :math:`\mathcal R_\mathrm{comm}` (L_comm, eps_comm of Table I)."""
    return _rate_ufunc(alpha_comm, snr, s.bandwidth_hz, link_constants(s)[0])


def ctrl_rate_bps(s: Scenario, alpha_ctrl: ArrayLike, snr: ArrayLike):
    r"""Control-link FBL rate :math:`\mathcal R_\mathrm{ctrl}` (L_ctrl, eps_ctrl of Table I)."""
    return _rate_ufunc(alpha_ctrl, snr, s.bandwidth_hz, link_constants(s)[1])


def ctrl_bler(s: Scenario, alpha_ctrl: ArrayLike, snr: ArrayLike):
    r"""Control packet-drop probability under the delivery deadline, eq:ctrl_bler.

    .. math::
        \varepsilon_{\mathrm{ctrl},n} = Q\!\left(\sqrt{\frac{L_\mathrm{ctrl}}{V(\gamma_n)}}
        \left[\log_2(1+\gamma_n) - \frac{S}{T_d\, \alpha_\mathrm{ctrl} B}\right]\right)

    The paper writes :math:`T_d = \Delta t`; here :math:`T_d` is ``ctrl_deadline_s``
    (``docs/model.md``). ``alpha_ctrl = 0`` gives 1 (nothing can be sent). The compiled
    :func:`ctrl_bler_one` over arrays (:func:`ctrl_bler_ufunc`): the env's loss probability, bit for bit.
    """
    _, _, bits_per_hz, sqrt_l = link_constants(s)
    return ctrl_bler_ufunc(alpha_ctrl, snr, sqrt_l, bits_per_hz)


def ctrl_bler_and_slope(s: Scenario, alpha_ctrl: ArrayLike, snr: ArrayLike):
    r"""eq:ctrl_bler and its derivative in ``alpha_ctrl`` (:func:`ctrl_bler_slope_one` over arrays).

    .. math::
        \frac{\partial\varepsilon}{\partial\alpha} = -\phi(x)\sqrt{L_\mathrm{ctrl}/V}\,
        \frac{S}{T_d B\alpha^2},\qquad x = \sqrt{L_\mathrm{ctrl}/V}\left[\log_2(1+\gamma)
        - \frac{S}{T_d B\alpha}\right]
    """
    _, _, bits_per_hz, sqrt_l = link_constants(s)
    return _ctrl_bler_slope_ufunc(alpha_ctrl, snr, sqrt_l, bits_per_hz)


def slot_link(s: Scenario, alpha_ctrl: ArrayLike, alpha_comm: ArrayLike, snr: ArrayLike):
    """The slot's control drop probability (eq:ctrl_bler) and both FBL rates (eq:rate_equation).

    Returns ``(eps_ctrl, rate_ctrl_bps, rate_comm_bps)``. Floors (alpha >= 1e-30,
    sqrt(V) >= 1e-150) keep alpha = 0 and gamma = 0 finite (eps -> 1) without overflow or division
    warnings.
    """
    return ctrl_bler(s, alpha_ctrl, snr), ctrl_rate_bps(s, alpha_ctrl, snr), comm_rate_bps(s, alpha_comm, snr)


def min_shares(s: Scenario, snr: ArrayLike, eps_max: ArrayLike, rate_bps: ArrayLike):
    r"""Smallest control and data shares of a slot at SNR ``snr``.

    The control share with drop probability at most ``eps_max`` and the data share carrying
    ``rate_bps`` (closed forms of eq:ctrl_bler and eq:rate_equation):

    .. math::
        \alpha_\mathrm{ctrl}^\star(\gamma) = \frac{S}{T_d B\left[\log_2(1+\gamma)
        - Q^{-1}(\varepsilon_\max)\sqrt{V(\gamma)/L_\mathrm{ctrl}}\right]},\qquad
        \alpha_\mathrm{comm}^{\min}(\gamma) = \frac{R}{B\left[\log_2(1+\gamma)
        - Q^{-1}(\varepsilon_\mathrm{comm})\sqrt{V(\gamma)/L_\mathrm{comm}}\right]}

    Where a bracket is not positive (unreachable at any share) the result is at least 1e12.
    :func:`min_ctrl_share_one` and :func:`min_comm_share_one` over arrays.
    """
    k_comm, _, bits_per_hz, sqrt_l = link_constants(s)
    q_back = q_inv(eps_max) / sqrt_l
    return (_min_ctrl_share_ufunc(snr, bits_per_hz, q_back),
            _min_comm_share_ufunc(snr, rate_bps, s.bandwidth_hz, k_comm))


def ctrl_goodput_bits(s: Scenario, alpha_ctrl: ArrayLike, snr: ArrayLike, ignore_loss: bool = False):
    r"""Effective control-link supply :math:`g(\alpha_\mathrm{ctrl}) = (1-\varepsilon_\mathrm{ctrl})
    \mathcal R_\mathrm{ctrl}\,\Delta t` in bits per slot, and its derivative in ``alpha_ctrl``.

    :math:`\varepsilon_\mathrm{ctrl}` is eq:ctrl_bler and :math:`\mathcal R_\mathrm{ctrl}` the FBL
    rate eq:rate_equation (target BLER ``ctrl_target_bler``) at the linear SNR ``snr``. The
    left-hand side of cons:rate_cost, per slot so that it compares with L(b) in bits per control
    sample. ``ignore_loss=True`` sets :math:`\varepsilon_\mathrm{ctrl} = 0` (the design that ignores
    packet loss).

    .. math::
        g' = (1-\varepsilon)\mathcal R'\Delta t - \varepsilon'\mathcal R\Delta t,\qquad
        \varepsilon' = -\phi(x)\sqrt{L_\mathrm{ctrl}/V}\,\frac{S}{T_d B\alpha^2}

    Returns
    -------
    g_bits, dg_bits : ndarray
    """
    a = np.maximum(np.asarray(alpha_ctrl, dtype=float), 1e-12)
    per_share = ctrl_rate_bps(s, 1.0, snr) * s.dt_s  # bits per slot and unit share
    if ignore_loss:
        return a * per_share, per_share + 0.0 * a
    eps, deps = ctrl_bler_and_slope(s, a, snr)
    return (1.0 - eps) * a * per_share, (1.0 - eps) * per_share - deps * a * per_share


# --- compiled scalar forms: one drone, composed by the slot kernel (iscc_gym.sim.loop.step_one) ---------
# ``inline="always"``: numba inlines them into the caller's IR, so they compile with the caller's flags.

_INV_SQRT2_F = 0.7071067811865476


@njit(cache=True, error_model="numpy", inline="always")
def link_terms_one(snr):
    """:func:`link_terms` of one SNR: ``(log2(1 + snr), sqrt(V(snr)))``."""
    g1 = 1.0 + snr
    return math.log2(g1), 1.4426950408889634 * math.sqrt(snr * (2.0 + snr)) / g1


@njit(cache=True, error_model="numpy", inline="always")
def ctrl_bler_arg_one(cap, sqrt_v, sqrt_l, bits_per_hz, alpha_ctrl):
    """The argument x of eq:ctrl_bler, eps = Q(x), of one slot from :func:`link_terms_one` (``sqrt_l``,
    ``bits_per_hz`` of :func:`link_constants`); floors alpha >= 1e-30 and sqrt(V) >= 1e-150.
    """
    need = bits_per_hz / max(alpha_ctrl, 1e-30)
    return sqrt_l / max(sqrt_v, 1e-150) * (cap - need)


@njit(cache=True, error_model="numpy", inline="always")
def ctrl_bler_one(cap, sqrt_v, sqrt_l, bits_per_hz, alpha_ctrl):
    """eq:ctrl_bler of one slot: Q of :func:`ctrl_bler_arg_one`."""
    return 0.5 * math.erfc(ctrl_bler_arg_one(cap, sqrt_v, sqrt_l, bits_per_hz, alpha_ctrl) * _INV_SQRT2_F)


@njit(cache=True, error_model="numpy", inline="always")
def ctrl_bler_slope_one(cap, sqrt_v, sqrt_l, bits_per_hz, alpha_ctrl):
    """:func:`ctrl_bler_one` and its derivative in ``alpha_ctrl``, -phi(x) dx/dalpha."""
    x = ctrl_bler_arg_one(cap, sqrt_v, sqrt_l, bits_per_hz, alpha_ctrl)
    a = max(alpha_ctrl, 1e-30)
    dx = sqrt_l / max(sqrt_v, 1e-150) * bits_per_hz / (a * a)
    return 0.5 * math.erfc(x * _INV_SQRT2_F), -math.exp(-0.5 * x * x) * 0.3989422804014327 * dx


@njit(cache=True, error_model="numpy", inline="always")
def rate_one(alpha, bandwidth_hz, cap, sqrt_v, back_off):
    """eq:rate_equation of one slot (``back_off`` = Q^-1(eps)/sqrt(L), :func:`link_constants`), >= 0."""
    return alpha * bandwidth_hz * max(cap - sqrt_v * back_off, 0.0)


@njit(cache=True, error_model="numpy", inline="always")
def delivered_one(eps, z):
    r"""Whether the control packet arrives: :math:`\Phi(z) \ge \varepsilon` for a standard normal z
    (probability 1 - eps; never at eps = 1).
    """
    return eps < 1.0 and 0.5 * math.erfc(-z * _INV_SQRT2_F) >= eps


@njit(cache=True, error_model="numpy", inline="always")
def min_ctrl_share_one(cap, sqrt_v, bits_per_hz, q_back):
    """The control share of :func:`min_shares` (``q_back`` = Q^-1(eps_max)/sqrt(L_ctrl))."""
    return bits_per_hz / max(cap - q_back * sqrt_v, 1e-12 * bits_per_hz)


@njit(cache=True, error_model="numpy", inline="always")
def min_comm_share_one(cap, sqrt_v, rate_bps, bandwidth_hz, k_comm):
    """The data share of :func:`min_shares`."""
    return (rate_bps / bandwidth_hz) / max(cap - k_comm * sqrt_v, 1e-12)


#: The link constants of a scenario the compiled forms read (float64 fields of one record).
LINK_PARAMS = np.dtype([(name, np.float64) for name in (
    "k_comm", "k_ctrl", "bits_per_hz", "sqrt_l",  # link_constants
    "bandwidth_hz",  # bandwidth B, Hz
)], align=True)


@per_scenario
def link_params(s: Scenario):
    """The :data:`LINK_PARAMS` record of a scenario, a read-only structured array of shape (1,)."""
    c = np.zeros(1, LINK_PARAMS)
    r = c[0]
    r["k_comm"], r["k_ctrl"], r["bits_per_hz"], r["sqrt_l"] = link_constants(s)
    r["bandwidth_hz"] = s.bandwidth_hz
    c.setflags(write=False)
    return c


@vectorize(["float64(float64, float64, float64, float64)"], cache=True)
def ctrl_bler_ufunc(alpha_ctrl, snr, sqrt_l, bits_per_hz):
    """eq:ctrl_bler as a numpy ufunc of (alpha_ctrl, linear SNR, sqrt(L_ctrl), S / (T_d B)) from the
    compiled :func:`link_terms_one` and :func:`ctrl_bler_one`: the env's loss probability, bit for bit.
    """
    cap, sqrt_v = link_terms_one(snr)
    return ctrl_bler_one(cap, sqrt_v, sqrt_l, bits_per_hz, alpha_ctrl)


@guvectorize(["void(float64, float64[:], float64[:])"], "()->(),()", cache=True)
def _link_terms_ufunc(snr, cap, sqrt_v):
    cap[0], sqrt_v[0] = link_terms_one(snr)


@vectorize(["float64(float64, float64, float64, float64)"], cache=True)
def _rate_ufunc(alpha, snr, bandwidth_hz, back_off):
    cap, sqrt_v = link_terms_one(snr)
    return rate_one(alpha, bandwidth_hz, cap, sqrt_v, back_off)


@guvectorize(["void(float64, float64, float64, float64, float64[:], float64[:])"], "(),(),(),()->(),()",
             cache=True)
def _ctrl_bler_slope_ufunc(alpha_ctrl, snr, sqrt_l, bits_per_hz, eps, deps):
    cap, sqrt_v = link_terms_one(snr)
    eps[0], deps[0] = ctrl_bler_slope_one(cap, sqrt_v, sqrt_l, bits_per_hz, alpha_ctrl)


@vectorize(["float64(float64, float64, float64)"], cache=True)
def _min_ctrl_share_ufunc(snr, bits_per_hz, q_back):
    cap, sqrt_v = link_terms_one(snr)
    return min_ctrl_share_one(cap, sqrt_v, bits_per_hz, q_back)


@vectorize(["float64(float64, float64, float64, float64)"], cache=True)
def _min_comm_share_ufunc(snr, rate_bps, bandwidth_hz, k_comm):
    cap, sqrt_v = link_terms_one(snr)
    return min_comm_share_one(cap, sqrt_v, rate_bps, bandwidth_hz, k_comm)
