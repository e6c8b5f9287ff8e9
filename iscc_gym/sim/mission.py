r"""A mission as the rows the loop state carries: the reference, and with blockage the channel along it.

Each slot's row is the reference ``[position, velocity, acceleration]`` (9 columns,
:data:`REFERENCE_COLUMNS`); with ``Scenario.blockage`` on, :data:`CHANNEL_COLUMNS` follow: the truth
(the realised LoS state and the unit shadowing field at the reference position) and the GBS's map of
it (its LoS probability, its mean of the shadowing field, and the large-scale SNRs it predicts for the
command link and the echo in either state), drawn once per mission by :func:`channel_along`.

The truth is evaluated at the slot's reference position: the drone stays within
``max_tracking_error_m`` of it, and the fields vary over their correlation distances (10-50 m), so this
stands for the field at the drone (``docs/model.md`` Sec. 6). One place has one value within a mission.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import ndtri

from iscc_gym.physics.blockage import (
    draw_field,
    excess_loss_db,
    field_at,
    los_probability,
    map_los_probability,
    shadowing_std_los_db,
    shadowing_std_nlos_db,
)
from iscc_gym.physics.channel import beam_gain, direction_trig, geometry, link_snr
from iscc_gym.physics.sensing import echo_amplitude_sq, sensing_noise_var_w
from iscc_gym.scenario import Scenario
from iscc_gym.sim.effects import task_effects

__all__ = ["REFERENCE_COLUMNS", "CHANNEL_COLUMNS", "MC", "mission_columns", "channel_along", "mission_rows"]

#: Columns of the reference part of a mission row.
REFERENCE_COLUMNS = 9
#: Columns of the channel part (with blockage): ``los`` (1.0 LoS, 0.0 NLoS: the truth), ``shadow_unit`` (the
#: truth's unit shadowing field), ``p_los_map`` (the map's LoS probability), ``shadow_map_unit`` (the map's
#: mean of the unit field), and the large-scale SNRs the map predicts at the reference with its mean shadowing,
#: dB: of the command link in LoS and in NLoS (``snr_los_map_db``, ``snr_nlos_map_db``) and of the echo per
#: element and subcarrier (``echo_los_map_db``, ``echo_nlos_map_db``); ``snr_true_db`` and ``echo_true_db``: the
#: same SNRs in the realised state with the realised shadowing (the oracle's preview, ``preview_source="truth"``).
CHANNEL_COLUMNS = ("los", "shadow_unit", "p_los_map", "shadow_map_unit", "snr_los_map_db", "snr_nlos_map_db",
                   "echo_los_map_db", "echo_nlos_map_db", "snr_true_db", "echo_true_db")
#: Position of each channel column in a mission row.
MC = {name: REFERENCE_COLUMNS + j for j, name in enumerate(CHANNEL_COLUMNS)}


def mission_columns(s: Scenario) -> int:
    """Columns of a mission row: 9, or 9 + len(CHANNEL_COLUMNS) with blockage."""
    return REFERENCE_COLUMNS + (len(CHANNEL_COLUMNS) if task_effects(s).blockage else 0)


def _state_snr_db(s: Scenario, dist, h, gain, los, shadow_unit):
    """Large-scale SNR of the command link and of the echo (dB) in LoS states ``los`` (a bool, or one per slot) and
    unit shadowing.
    """
    sigma = np.where(los, shadowing_std_los_db(s.blockage, h, s.shadowing_a_db, s.shadowing_b_per_m),
                     shadowing_std_nlos_db(s.blockage, h))
    shadow_db = sigma * shadow_unit
    extra = excess_loss_db(s.blockage, los, h, dist, s.carrier_freq_ghz)
    snr = link_snr(s, dist, shadow_db + extra, gain)
    echo = echo_amplitude_sq(s, dist, shadow_db + 2.0 * extra, 1.0) / sensing_noise_var_w(s)
    return 10.0 * np.log10(snr), 10.0 * np.log10(echo)


def channel_along(s: Scenario, ref: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    r"""The channel part of a mission's rows, shape (N+1, len(CHANNEL_COLUMNS)), drawn from ``rng``.

    Four unit fields (:func:`iscc_gym.physics.blockage.draw_field`): the map's and the error's of the LoS
    state (correlation ``los_correlation_m``, kernel ``los_field_kernel``) and of the shadowing
    (``shadowing_decorrelation_m``), in that order. The truth is :math:`\rho\,m + \sigma_e e`
    (``map_error_std`` = :math:`\sigma_e`), LoS where it is below :math:`\Phi^{-1}(P_\mathrm{LoS})` (TR 36.777
    Table B-1 at the reference's height and horizontal distance to the GBS).
    """
    if not task_effects(s).blockage:
        raise ValueError("channel_along needs Scenario.blockage 'uma_av' or 'umi_av'")
    fields = [draw_field(rng, d, kernel=k) for d, k in ((s.los_correlation_m, s.los_field_kernel),
                                                        (s.los_correlation_m, s.los_field_kernel),
                                                        (s.shadowing_decorrelation_m, "exponential"),
                                                        (s.shadowing_decorrelation_m, "exponential"))]
    x, y, h = ref[:, 0], ref[:, 1], ref[:, 2]
    m_los, e_los, m_sh, e_sh = (field_at(f, x, y) for f in fields)
    se = s.map_error_std
    rho = math.sqrt(1.0 - se * se)
    p_los = los_probability(s.blockage, h, np.hypot(x, y))
    with np.errstate(divide="ignore"):
        los = rho * m_los + se * e_los < ndtri(p_los)  # p = 1: +inf, always LoS
    p_map = map_los_probability(p_los, m_los, se)
    shadow_true = rho * m_sh + se * e_sh
    shadow_map = rho * m_sh
    dist, _, _, g = geometry(s, ref[:, :3])
    gain = beam_gain(s, direction_trig(g))
    snr_los, echo_los = _state_snr_db(s, dist, h, gain, True, shadow_map)
    snr_nlos, echo_nlos = _state_snr_db(s, dist, h, gain, False, shadow_map)
    snr_true, echo_true = _state_snr_db(s, dist, h, gain, los, shadow_true)
    return np.column_stack([los.astype(float), shadow_true, p_map, shadow_map, snr_los, snr_nlos, echo_los,
                            echo_nlos, snr_true, echo_true])


def mission_rows(s: Scenario, reference: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A mission's rows (N+1, :func:`mission_columns`): the reference (N+1, 9) as it is without blockage, else
    with :func:`channel_along` drawn from ``rng`` appended.
    """
    if not task_effects(s).blockage:
        return reference
    return np.concatenate([reference, channel_along(s, reference, rng)], axis=1)
