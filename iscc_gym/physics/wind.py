r"""Low-altitude wind turbulence: the Dryden model's intensities and scale lengths, and gusts as a coloured process.

The paper's drone sees white process noise of known variance (Table I). Real air near the ground is turbulent:
the gust velocity is a coloured random process whose intensity and correlation grow with the wind and the altitude.
This module holds the Dryden model of MIL-F-8785C (the military specification's low-altitude form, below 1000 ft,
also MIL-HDBK-1797) as functions; the compiled slot does not call it yet (issue 36: a world richer than the
designer's model).

**Intensities and scale lengths** (MIL-F-8785C, low altitude, :math:`h` in feet, :math:`W_{20}` the wind speed at
20 ft):

.. math::

    L_w = h, \qquad L_u = L_v = \frac{h}{(0.177 + 0.000823\,h)^{1.2}}, \qquad
    \sigma_w = 0.1\,W_{20}, \qquad \frac{\sigma_u}{\sigma_w} = \frac{\sigma_v}{\sigma_w}
    = \frac{1}{(0.177 + 0.000823\,h)^{0.4}}.

At :math:`h` = 1000 ft the three scale lengths are 1000 ft and the three intensities equal. The specification's
:math:`W_{20}` for light, moderate and severe turbulence is 15, 30 and 45 knots (:data:`W20_MPS`).

**Gusts over time.** A drone at airspeed :math:`V` through a frozen turbulence field sees the longitudinal Dryden
spectrum, the output of :math:`H_u(s) = \sigma_u\sqrt{2L_u/(\pi V)}\,/\,(1 + (L_u/V)s)` driven by unit white noise: a
first-order Gauss-Markov process of correlation time :math:`L/V`. Sampled every :math:`\Delta t` exactly:

.. math::

    g_{k+1} = \phi\, g_k + \sigma\sqrt{1 - \phi^2}\; z_k, \qquad \phi = e^{-V\Delta t / L},
    \qquad z_k \sim \mathcal N(0, 1),

stationary with variance :math:`\sigma^2` and lag-:math:`k` correlation :math:`\phi^k`. **Choice:** the lateral and
vertical components (second-order Dryden forms) take the same first-order form with their own :math:`L` and
:math:`\sigma`: the same variance and correlation time, a different spectral shape at high frequency, which a
0.1 s slot does not resolve at low airspeed.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

__all__ = ["FT_M", "KNOT_MPS", "W20_MPS", "dryden_low_altitude", "gust_step_one", "gust_step", "gust_phi"]

#: Metres per foot and metres per second per knot (exact, by definition).
FT_M = 0.3048
KNOT_MPS = 1852.0 / 3600.0
#: MIL-F-8785C's wind speed at 20 ft for light, moderate and severe low-altitude turbulence (15, 30, 45 knots).
W20_MPS = {"light": 15.0 * KNOT_MPS, "moderate": 30.0 * KNOT_MPS, "severe": 45.0 * KNOT_MPS}
#: The low-altitude model's altitude range in metres (10 ft, where the specification's tables start, to 1000 ft).
ALTITUDE_RANGE_M = (10.0 * FT_M, 1000.0 * FT_M)


def dryden_low_altitude(altitude_m: ArrayLike, w20_mps: float) -> dict[str, np.ndarray]:
    r"""Dryden scale lengths (m) and intensities (m/s) below 1000 ft (MIL-F-8785C's low-altitude model).

    Parameters
    ----------
    altitude_m : array_like
        Altitude above ground, m, within :data:`ALTITUDE_RANGE_M` (3.048 to 304.8 m).
    w20_mps : float
        Wind speed at 20 ft (6.1 m), m/s, >= 0 (:data:`W20_MPS`: 7.7, 15.4, 23.2 m/s).

    Returns
    -------
    dict
        ``L_u_m``, ``L_v_m``, ``L_w_m`` and ``sigma_u_mps``, ``sigma_v_mps``, ``sigma_w_mps``, each of the
        shape of ``altitude_m``.

    Raises
    ------
    ValueError
        An altitude outside the low-altitude range or a negative or non-finite wind speed.
    """
    h_m = np.asarray(altitude_m, dtype=float)
    lo, hi = ALTITUDE_RANGE_M
    if not np.all((h_m >= lo) & (h_m <= hi)):
        raise ValueError(f"altitude_m = {altitude_m!r} is outside the Dryden low-altitude model's range "
                         f"[{lo:g}, {hi:g}] m (10 to 1000 ft)")
    if not (math.isfinite(w20_mps) and w20_mps >= 0.0):
        raise ValueError(f"w20_mps = {w20_mps!r} is invalid: a wind speed at 20 ft >= 0 m/s")
    h_ft = h_m / FT_M
    base = 0.177 + 0.000823 * h_ft
    l_uv = h_ft / base ** 1.2 * FT_M
    sigma_w = np.full_like(h_m, 0.1 * w20_mps)
    sigma_uv = sigma_w / base ** 0.4
    return {"L_u_m": l_uv, "L_v_m": l_uv.copy(), "L_w_m": h_m.copy(), "sigma_u_mps": sigma_uv,
            "sigma_v_mps": sigma_uv.copy(), "sigma_w_mps": sigma_w}


def gust_phi(airspeed_mps: ArrayLike, dt_s: float, scale_length_m: ArrayLike) -> np.ndarray:
    r"""The gust's one-step correlation :math:`\phi = e^{-V\Delta t/L}` (``ValueError`` for a non-positive L)."""
    length = np.asarray(scale_length_m, dtype=float)
    if not np.all(length > 0.0):
        raise ValueError(f"scale_length_m = {scale_length_m!r} must be > 0")
    return np.exp(-np.abs(np.asarray(airspeed_mps, dtype=float)) * float(dt_s) / length)


@njit(cache=True, error_model="numpy", inline="always")
def gust_step_one(g, phi, sigma, z):
    r"""One slot of a gust component, :math:`\phi g + \sigma\sqrt{1-\phi^2}\,z` (compiled, scalar)."""
    return phi * g + sigma * math.sqrt(max(0.0, 1.0 - phi * phi)) * z


def gust_step(g: ArrayLike, phi: ArrayLike, sigma: ArrayLike, z: ArrayLike) -> np.ndarray:
    """:func:`gust_step_one` over arrays (broadcast)."""
    phi = np.asarray(phi, dtype=float)
    return np.asarray(g, dtype=float) * phi + np.asarray(sigma, dtype=float) * np.sqrt(
        np.maximum(0.0, 1.0 - phi * phi)) * np.asarray(z, dtype=float)
