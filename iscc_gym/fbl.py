"""Finite-blocklength rate (Polyanskiy normal approximation) and control-packet drop probability."""

from __future__ import annotations

import math

import numpy as np
from numba import njit, vectorize
from scipy.special import erfc, ndtri

from .scenario import Scenario, per_scenario

__all__ = ["dispersion", "q_func", "q_inv", "link_terms", "fbl_rate_bps", "comm_rate_bps",
           "ctrl_rate_bps", "ctrl_bler", "slot_link", "min_shares", "min_ctrl_share", "link_constants",
           "link_terms_one", "ctrl_bler_one", "rate_one", "delivered_one", "min_ctrl_share_one", "min_comm_share_one",
           "LINK_PARAMS", "link_params", "ctrl_bler_ufunc", "ctrl_bler_compiled"]

_LOG2E = float(np.log2(np.e))
_LOG2E_SQ = _LOG2E**2
_INV_SQRT2 = 1.0 / np.sqrt(2.0)


def q_func(x):
    """Gaussian tail :math:`Q(x) = \\tfrac12 \\operatorname{erfc}(x/\\sqrt2)`.

    For x above about 37 the result is subnormal or 0 (a gradual underflow, not an error)."""
    with np.errstate(under="ignore"):
        return 0.5 * erfc(np.asarray(x, dtype=float) * _INV_SQRT2)


def q_inv(p):
    """Inverse Gaussian tail :math:`Q^{-1}(p) = -\\Phi^{-1}(p)`."""
    return -ndtri(np.asarray(p, dtype=float))


def dispersion(snr):
    """Channel dispersion of the AWGN channel in bits^2 per channel use.

    .. math:: V(\\gamma) = (\\log_2 e)^2 \\left[1 - (1+\\gamma)^{-2}\\right]

    (the paper, below eq:rate_equation). ``snr`` is linear.
    """
    g = np.asarray(snr, dtype=float)
    return _LOG2E_SQ * g * (2.0 + g) / ((1.0 + g) * (1.0 + g))  # = 1 - (1+g)^-2, exact at small g


def fbl_rate_bps(alpha, bandwidth_hz, snr, blocklength, bler):
    """Effective FBL rate of a share ``alpha`` of the band, eq:rate_equation, in bit/s.

    .. math::
        \\mathcal R_i = \\alpha_i B\\left[\\log_2(1+\\gamma) - \\sqrt{\\frac{V}{L_i}}\\,
        Q^{-1}(\\varepsilon_i)\\right]

    Clipped at zero (no negative rates at very low SNR).
    """
    cap, sqrt_v = link_terms(np.asarray(snr, dtype=float))
    return _rate(alpha, bandwidth_hz, cap, sqrt_v, q_inv(bler) / np.sqrt(blocklength))


def link_terms(snr):
    """Capacity :math:`\\log_2(1+\\gamma)` and :math:`\\sqrt{V(\\gamma)}`, the two SNR terms every
    FBL quantity here is built from (computed once per slot)."""
    g1 = 1.0 + snr
    return np.log2(g1), _LOG2E * np.sqrt(snr * (2.0 + snr)) / g1


def _rate(alpha, bandwidth_hz, cap, sqrt_v, back_off):
    return alpha * bandwidth_hz * np.maximum(cap - sqrt_v * back_off, 0.0)


@per_scenario
def link_constants(s: Scenario):
    """(comm back-off Q^-1(eps)/sqrt(L), ctrl back-off, S / (T_d B), sqrt(L_ctrl))."""
    return (float(q_inv(s.comm_target_bler)) / np.sqrt(s.comm_blocklength),
            float(q_inv(s.ctrl_target_bler)) / np.sqrt(s.ctrl_blocklength),
            s.ctrl_packet_bits / (s.ctrl_deadline_s * s.bandwidth_hz), np.sqrt(s.ctrl_blocklength))


def comm_rate_bps(s: Scenario, alpha_comm, snr):
    """Data-link FBL rate :math:`\\mathcal R_\\mathrm{comm}` (L_comm, eps_comm of Table I)."""
    return slot_link(s, 0.0, alpha_comm, snr)[2]


def ctrl_rate_bps(s: Scenario, alpha_ctrl, snr):
    """Control-link FBL rate :math:`\\mathcal R_\\mathrm{ctrl}` (L_ctrl, eps_ctrl of Table I)."""
    return slot_link(s, alpha_ctrl, 0.0, snr)[1]


def ctrl_bler(s: Scenario, alpha_ctrl, snr):
    """Control packet-drop probability under the delivery deadline, eq:ctrl_bler.

    .. math::
        \\varepsilon_{\\mathrm{ctrl},n} = Q\\!\\left(\\sqrt{\\frac{L_\\mathrm{ctrl}}{V(\\gamma_n)}}
        \\left[\\log_2(1+\\gamma_n) - \\frac{S}{T_d\\, \\alpha_\\mathrm{ctrl} B}\\right]\\right)

    The paper writes :math:`T_d = \\Delta t`; here :math:`T_d` is ``ctrl_deadline_s``
    (``docs/model.md``). ``alpha_ctrl = 0`` gives 1 (nothing can be sent).
    """
    return slot_link(s, alpha_ctrl, 0.0, snr)[0]


def slot_link(s: Scenario, alpha_ctrl, alpha_comm, snr):
    """The slot's control drop probability (eq:ctrl_bler) and both FBL rates (eq:rate_equation).

    Returns ``(eps_ctrl, rate_ctrl_bps, rate_comm_bps)``, sharing the SNR terms of
    :func:`link_terms`. Floors (alpha >= 1e-30, sqrt(V) >= 1e-150) keep alpha = 0 and
    gamma = 0 finite (eps -> 1) without overflow or division warnings.
    """
    k_comm, k_ctrl, bits_per_hz, sqrt_l = link_constants(s)
    cap, sqrt_v = link_terms(np.asarray(snr, dtype=float))
    need = bits_per_hz / np.maximum(alpha_ctrl, 1e-30)
    eps = q_func(sqrt_l / np.maximum(sqrt_v, 1e-150) * (cap - need))
    return (eps, _rate(alpha_ctrl, s.bandwidth_hz, cap, sqrt_v, k_ctrl),
            _rate(alpha_comm, s.bandwidth_hz, cap, sqrt_v, k_comm))


def min_shares(s: Scenario, snr, eps_max, rate_bps):
    """Smallest control share with drop probability at most ``eps_max`` and smallest data share
    carrying ``rate_bps``, at SNR ``snr`` (closed forms of eq:ctrl_bler and eq:rate_equation):

    .. math::
        \\alpha_\\mathrm{ctrl}^\\star(\\gamma) = \\frac{S}{T_d B\\left[\\log_2(1+\\gamma)
        - Q^{-1}(\\varepsilon_\\max)\\sqrt{V(\\gamma)/L_\\mathrm{ctrl}}\\right]},\\qquad
        \\alpha_\\mathrm{comm}^{\\min}(\\gamma) = \\frac{R}{B\\left[\\log_2(1+\\gamma)
        - Q^{-1}(\\varepsilon_\\mathrm{comm})\\sqrt{V(\\gamma)/L_\\mathrm{comm}}\\right]}

    Where a bracket is not positive (unreachable at any share) the result is at least 1e12.
    """
    k_comm, _, bits_per_hz, sqrt_l = link_constants(s)
    cap, sqrt_v = link_terms(np.asarray(snr, dtype=float))
    ctrl = bits_per_hz / np.maximum(cap - float(q_inv(eps_max)) / sqrt_l * sqrt_v, 1e-12 * bits_per_hz)
    comm = (rate_bps / s.bandwidth_hz) / np.maximum(cap - k_comm * sqrt_v, 1e-12)
    return ctrl, comm


def min_ctrl_share(s: Scenario, snr, eps_max):
    """The control share of :func:`min_shares` (kept for ``agents/myopic.py``)."""
    return min_shares(s, snr, eps_max, 0.0)[0]


# --- compiled scalar forms: one drone, composed by the slot kernel (iscc_gym.loop.step_one) ---------
# ``inline="always"``: numba inlines them into the caller's IR, so they compile with the caller's flags.

_INV_SQRT2_F = 0.7071067811865476


@njit(cache=True, error_model="numpy", inline="always")
def link_terms_one(snr):
    """:func:`link_terms` of one SNR: ``(log2(1 + snr), sqrt(V(snr)))``."""
    g1 = 1.0 + snr
    return math.log2(g1), 1.4426950408889634 * math.sqrt(snr * (2.0 + snr)) / g1


@njit(cache=True, error_model="numpy", inline="always")
def ctrl_bler_one(cap, sqrt_v, sqrt_l, bits_per_hz, alpha_ctrl):
    """eq:ctrl_bler of one slot from :func:`link_terms_one` (``sqrt_l``, ``bits_per_hz`` of
    :func:`link_constants`); the floors of :func:`slot_link`."""
    need = bits_per_hz / max(alpha_ctrl, 1e-30)
    return 0.5 * math.erfc(sqrt_l / max(sqrt_v, 1e-150) * (cap - need) * _INV_SQRT2_F)


@njit(cache=True, error_model="numpy", inline="always")
def rate_one(alpha, bandwidth_hz, cap, sqrt_v, back_off):
    """eq:rate_equation of one slot (``back_off`` = Q^-1(eps)/sqrt(L), :func:`link_constants`), >= 0."""
    return alpha * bandwidth_hz * max(cap - sqrt_v * back_off, 0.0)


@njit(cache=True, error_model="numpy", inline="always")
def delivered_one(eps, z):
    """Whether the control packet arrives: :math:`\\Phi(z) \\ge \\varepsilon` for a standard normal z
    (probability 1 - eps; never at eps = 1)."""
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
    "bw",  # bandwidth B, Hz
)])


@per_scenario
def link_params(s: Scenario):
    """The :data:`LINK_PARAMS` record of a scenario, a read-only structured array of shape (1,)."""
    c = np.zeros(1, LINK_PARAMS)
    r = c[0]
    r["k_comm"], r["k_ctrl"], r["bits_per_hz"], r["sqrt_l"] = link_constants(s)
    r["bw"] = s.bandwidth_hz
    c.setflags(write=False)
    return c


@vectorize(["float64(float64, float64, float64, float64)"], cache=True)
def ctrl_bler_ufunc(alpha_ctrl, snr, sqrt_l, bits_per_hz):
    """eq:ctrl_bler as a numpy ufunc of (alpha_ctrl, linear SNR, sqrt(L_ctrl), S / (T_d B)) from the
    compiled :func:`link_terms_one` and :func:`ctrl_bler_one`: the env's loss probability, bit for bit."""
    cap, sqrt_v = link_terms_one(snr)
    return ctrl_bler_one(cap, sqrt_v, sqrt_l, bits_per_hz, alpha_ctrl)


def ctrl_bler_compiled(s: Scenario, alpha_ctrl, snr):
    """:func:`ctrl_bler` by the compiled scalar form (:func:`ctrl_bler_ufunc`), for arrays of any
    broadcastable shapes. Agrees with :func:`ctrl_bler` to rounding (libm's erfc, not scipy's)."""
    r = link_params(s)[0]
    return ctrl_bler_ufunc(alpha_ctrl, snr, r["sqrt_l"], r["bits_per_hz"])
