"""What the base station predicts about the coming slot from an observation, written once for the policies.

The observation carries the predicted range, direction and large-scale SNR of the drone
(:func:`iscc_gym.sim.functional.decode_observation`); the scripted policies that solve the slot (``myopic``,
per-slot SCA, the multi-drone SCA variants) turn them into the geometry and the sensing coefficients of the
CRLB the same way, here.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from iscc_gym.analysis.sensing_share import SensingCoefficients, sensing_coefficients
from iscc_gym.physics.channel import beam_gain, link_snr
from iscc_gym.physics.sensing import echo_amplitude_sq, sensing_noise_var_w
from iscc_gym.scenario import Scenario

__all__ = ["predicted_geometry", "predicted_sensing"]


def predicted_geometry(s: Scenario, snr_db: ArrayLike, range_m: ArrayLike, sin_el: ArrayLike, cos_az: ArrayLike,
                       sin_az: ArrayLike, gain: ArrayLike | None = None):
    """The predicted range, direction and shadowing of slots with these decoded observation entries.

    The range is floored at 1 m, the elevation's sine clipped to [-1, 1] and the azimuth's cosine and sine
    renormalised (the observation rounds them); the shadowing is what the predicted large-scale SNR implies
    at that range and beam gain (:func:`iscc_gym.physics.channel.link_snr` without shadowing, minus ``snr_db``).

    Parameters
    ----------
    gain : array_like, optional
        The beamforming gain (the matched beam's constant); default :func:`iscc_gym.physics.channel.beam_gain`
        of the direction.

    Returns
    -------
    dist_m : ndarray
    trig : tuple of ndarray
        ``(cos_az, sin_az, cos_el, sin_el)``.
    shadow_db : ndarray
    """
    dist = np.maximum(range_m, 1.0)
    sin_el = np.clip(sin_el, -1.0, 1.0)
    norm = np.hypot(cos_az, sin_az)
    norm = np.where(norm > 0.0, norm, 1.0)
    trig = (cos_az / norm, sin_az / norm, np.sqrt(np.maximum(0.0, 1.0 - sin_el * sin_el)), sin_el)
    gain = gain if gain is not None else beam_gain(s, trig)
    shadow_db = 10.0 * np.log10(link_snr(s, dist, 0.0, gain)) - snr_db
    return dist, trig, shadow_db


def predicted_sensing(s: Scenario, snr_db: ArrayLike, range_m: ArrayLike, sin_el: ArrayLike, cos_az: ArrayLike,
                      sin_az: ArrayLike, gain: ArrayLike | None = None,
                      echo_snr_db: ArrayLike | None = None,
                      rcs_offset_db: ArrayLike | None = None) -> SensingCoefficients:
    """The coefficients of the slot's CRLB as a function of the sensing share
    (:func:`iscc_gym.analysis.sensing_share.sensing_coefficients`) at :func:`predicted_geometry`.

    ``echo_snr_db`` (the urban task's measured echo SNR, :func:`iscc_gym.sim.functional.decode_observation`):
    the echo's loss is what it implies (:func:`iscc_gym.physics.sensing.echo_amplitude_sq` without loss, minus it),
    which carries a blocked line of sight's two-way excess; without it, the link's shadowing stands for the echo's.
    ``rcs_offset_db`` (the field task's drone RCS over ``rcs_m2``, known or estimated): a gain on the echo.
    """
    dist, trig, shadow_db = predicted_geometry(s, snr_db, range_m, sin_el, cos_az, sin_az, gain)
    if echo_snr_db is not None:
        free = echo_amplitude_sq(s, dist, 0.0, 1.0) / sensing_noise_var_w(s)
        shadow_db = 10.0 * np.log10(free) - echo_snr_db
    elif rcs_offset_db is not None:
        shadow_db = shadow_db - np.asarray(rcs_offset_db, dtype=float)
    return sensing_coefficients(s, dist, trig, shadow_db)
