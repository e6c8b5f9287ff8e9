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

__all__ = ["REFERENCE_COLUMNS", "CHANNEL_COLUMNS", "MC", "WORLD_COLUMNS", "mission_columns", "world_column",
           "channel_along", "world_along", "los_along", "mission_rows"]

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


#: Columns of the world's part (the field task, after the channel's): ``k_db``, the Rician K-factor of the command
#: link and of the echo at the slot's reference position (dB), and ``rcs_offset_db``, the drone's radar cross
#: section over ``rcs_m2`` (dB, one value per mission): what the designer's model does not know.
WORLD_COLUMNS = ("k_db", "rcs_offset_db")


def world_column(s: Scenario) -> int:
    """Where a mission row's :data:`WORLD_COLUMNS` start; -1 without the field."""
    fx = task_effects(s)
    return REFERENCE_COLUMNS + (len(CHANNEL_COLUMNS) if fx.blockage else 0) if fx.field else -1


def mission_columns(s: Scenario) -> int:
    """Columns of a mission row: 9, + len(CHANNEL_COLUMNS) with blockage, + len(WORLD_COLUMNS) with the field."""
    fx = task_effects(s)
    return REFERENCE_COLUMNS + (len(CHANNEL_COLUMNS) if fx.blockage else 0) + (len(WORLD_COLUMNS) if fx.field else 0)


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


def world_along(s: Scenario, ref: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    r"""The world's part of a mission's rows, shape (N+1, len(WORLD_COLUMNS)), drawn from ``rng``: one unit field
    (:func:`iscc_gym.physics.blockage.draw_field`, exponential correlation ``rician_k_correlation_m``, 3GPP TR
    38.901 Sec. 7.6.3's spatially consistent large-scale parameters) and one standard normal, in that order,
    whatever the spreads (so worlds of other spreads share a mission's draws: common random numbers).

    .. math::
        K_\mathrm{dB}(\mathbf p) = \mu_K + \sigma_K\, f(\mathbf p),\qquad
        \Delta\sigma_\mathrm{RCS,dB} = \sigma_\mathrm{RCS}\, z

    (:math:`\mu_K` = ``rician_k_db``, :math:`\sigma_K` = ``rician_k_std_db``, :math:`\sigma_\mathrm{RCS}` =
    ``rcs_std_db``; the field at the slot's reference position, as the blockage's channel is). With
    ``rician_k_blockage`` on, :func:`los_along` drawn from a stream jumped ahead of ``rng``'s (``rng`` is left as
    it is, so every other draw of the mission is the world's without it): where it is NLoS, :math:`K_\mathrm{dB}`
    is ``rician_k_nlos_db``.
    """
    if not task_effects(s).field:
        raise ValueError("world_along needs Scenario.rician_k_std_db or rcs_std_db > 0")
    field = draw_field(rng, s.rician_k_correlation_m, kernel="exponential")
    z = rng.standard_normal()
    k_db = s.rician_k_db + s.rician_k_std_db * field_at(field, ref[:, 0], ref[:, 1])
    if s.rician_k_blockage != "none":
        # from a stream jumped ahead of rng's, which leaves rng as it is: the mission's later draws (the initial
        # state's) are those of the world without the blockage (common random numbers)
        los = los_along(s, s.rician_k_blockage, ref, np.random.Generator(rng.bit_generator.jumped()))
        k_db = np.where(los, k_db, s.rician_k_nlos_db)
    return np.column_stack([k_db, np.full(len(ref), s.rcs_std_db * z)])


def los_along(s: Scenario, model: str, ref: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    r"""A LoS state along the reference, (N+1,) bool, drawn from ``rng`` (one unit field): LoS where the field
    (correlation ``los_correlation_m``, kernel ``los_field_kernel``) is below :math:`\Phi^{-1}(P_\mathrm{LoS})`,
    TR 36.777 Table B-1's probability under ``model`` at the reference's height and horizontal distance to the
    GBS (the urban task's truth with a perfect map: ``map_error_std`` 0). For ``rician_k_blockage``.
    """
    x, y, h = ref[:, 0], ref[:, 1], ref[:, 2]
    f = field_at(draw_field(rng, s.los_correlation_m, kernel=s.los_field_kernel), x, y)
    with np.errstate(divide="ignore"):
        return f < ndtri(los_probability(model, h, np.hypot(x, y)))


def mission_rows(s: Scenario, reference: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A mission's rows (N+1, :func:`mission_columns`): the reference (N+1, 9) as it is without blockage or the
    field; with blockage :func:`channel_along`, then with the field :func:`world_along`, drawn from ``rng`` in that
    order, appended.
    """
    fx = task_effects(s)
    if not (fx.blockage or fx.field):
        return reference
    parts = [reference]
    if fx.blockage:
        parts.append(channel_along(s, reference, rng))
    if fx.field:
        parts.append(world_along(s, reference, rng))
    return np.concatenate(parts, axis=1)
