"""Finite-blocklength rate (Polyanskiy normal approximation) and control-packet drop probability."""

from __future__ import annotations

import numpy as np
from scipy.special import erfc, ndtri

from .scenario import Scenario

__all__ = ["dispersion", "q_func", "q_inv", "fbl_rate_bps", "comm_rate_bps", "ctrl_rate_bps",
           "ctrl_bler", "min_ctrl_share", "min_comm_share"]

_LOG2E_SQ = np.log2(np.e) ** 2
_INV_SQRT2 = 1.0 / np.sqrt(2.0)


def q_func(x):
    """Gaussian tail :math:`Q(x) = \\tfrac12 \\operatorname{erfc}(x/\\sqrt2)`."""
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
    snr = np.asarray(snr, dtype=float)
    r = np.log2(1.0 + snr) - np.sqrt(dispersion(snr) / blocklength) * q_inv(bler)
    return np.asarray(alpha, dtype=float) * bandwidth_hz * np.maximum(r, 0.0)


def comm_rate_bps(s: Scenario, alpha_comm, snr):
    """Data-link FBL rate :math:`\\mathcal R_\\mathrm{comm}` (L_comm, eps_comm of Table I)."""
    return fbl_rate_bps(alpha_comm, s.bandwidth_hz, snr, s.comm_blocklength, s.comm_target_bler)


def ctrl_rate_bps(s: Scenario, alpha_ctrl, snr):
    """Control-link FBL rate :math:`\\mathcal R_\\mathrm{ctrl}` (L_ctrl, eps_ctrl of Table I)."""
    return fbl_rate_bps(alpha_ctrl, s.bandwidth_hz, snr, s.ctrl_blocklength, s.ctrl_target_bler)


def ctrl_bler(s: Scenario, alpha_ctrl, snr):
    """Control packet-drop probability under the delivery deadline, eq:ctrl_bler.

    .. math::
        \\varepsilon_{\\mathrm{ctrl},n} = Q\\!\\left(\\sqrt{\\frac{L_\\mathrm{ctrl}}{V(\\gamma_n)}}
        \\left[\\log_2(1+\\gamma_n) - \\frac{S}{T_d\\, \\alpha_\\mathrm{ctrl} B}\\right]\\right)

    The paper writes :math:`T_d = \\Delta t`; here :math:`T_d` is ``ctrl_deadline_s``
    (``docs/model.md``). ``alpha_ctrl = 0`` gives 1 (nothing can be sent).
    """
    snr = np.asarray(snr, dtype=float)
    # alpha -> 1e-30 and V -> 1e-300 floors keep alpha = 0 and gamma = 0 finite (Q -> 1) without
    # overflow or division warnings
    need = (s.ctrl_packet_bits / (s.ctrl_deadline_s * s.bandwidth_hz)) / np.maximum(alpha_ctrl, 1e-30)
    scale = np.sqrt(s.ctrl_blocklength / np.maximum(dispersion(snr), 1e-300))
    return q_func(scale * (np.log2(1.0 + snr) - need))


def min_ctrl_share(s: Scenario, snr, eps_max):
    """Smallest control share whose drop probability (eq:ctrl_bler) is at most ``eps_max``.

    Closed form of :math:`\\varepsilon_\\mathrm{ctrl}(\\alpha, \\gamma) = \\varepsilon_\\max`:

    .. math::
        \\alpha^\\star(\\gamma) = \\frac{S}{T_d B\\left[\\log_2(1+\\gamma)
        - Q^{-1}(\\varepsilon_\\max)\\sqrt{V(\\gamma)/L_\\mathrm{ctrl}}\\right]}

    Returns ``inf`` where no share reaches ``eps_max`` (the bracket is not positive); values above 1
    mean even the whole band is not enough.
    """
    snr = np.asarray(snr, dtype=float)
    cap = np.log2(1.0 + snr) - q_inv(eps_max) * np.sqrt(dispersion(snr) / s.ctrl_blocklength)
    with np.errstate(divide="ignore"):
        return np.where(cap > 0.0, s.ctrl_packet_bits / (s.ctrl_deadline_s * s.bandwidth_hz
                                                         * np.where(cap > 0.0, cap, 1.0)), np.inf)


def min_comm_share(s: Scenario, snr, rate_bps):
    """Smallest data share whose FBL rate (eq:rate_equation) reaches ``rate_bps``; ``inf`` if none."""
    per_hz = fbl_rate_bps(1.0, 1.0, snr, s.comm_blocklength, s.comm_target_bler)
    with np.errstate(divide="ignore"):
        return np.where(per_hz > 0.0, rate_bps / (s.bandwidth_hz * np.where(per_hz > 0, per_hz, 1.0)),
                        np.inf)
