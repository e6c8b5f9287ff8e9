"""Validation of a :class:`iscc_gym.scenario.Scenario`: the allowed choices and range of every field,
and the checks that keep every quantity of a slot finite and every array small.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from iscc_gym.trajectory import (
    coverage_box_fraction,
    coverage_volume_km3,
    in_coverage,
    order_waypoints,
    sample_waypoints,
    spline_reference,
)

if TYPE_CHECKING:  # pragma: no cover
    from iscc_gym.scenario import Scenario

__all__ = ["validate", "reference_share", "CHOICES", "MAX_SLOTS", "MAX_WAYPOINTS", "MAX_MEAN_WAYPOINTS",
           "MIN_BOX_FRACTION"]

#: The shortest correlation distance of a spatially consistent field (the LoS state's, the K-factor's), m: a
#: centimetre, a wavelength at 30 GHz; large-scale parameters are not defined below the wavelength (TR 38.901's
#: distances are 10-50 m). At about 1e-305 m the field's wave numbers overflowed and every value was NaN.
MIN_CORRELATION_M = 0.01

CHOICES: dict[str, tuple[str, ...]] = {
    "process_noise_reading": ("variance", "std"),
    "snr_convention": ("total_power", "per_subcarrier_power"),
    "sensing_noise_convention": ("full_band", "per_subcarrier"),
    "array_orientation": ("printed", "vertical", "horizontal"),
    "beamforming": ("matched", "broadside"),
    "fim_angle_convention": ("definition", "printed"),
    "observation_source": ("isac", "gnss"),
    "control_mode": ("lqg", "open_loop"),
    "rate_cost_determinant": ("pseudo", "printed"),
    "blockage": ("none", "uma_av", "umi_av"),
    "preview_source": ("map", "truth"),
    "los_field_kernel": ("exponential", "gaussian"),
    "rician_k_blockage": ("none", "uma_av", "umi_av"),
}


#: The fields that are True or False.
_FLAGS = ("reference_feedforward", "show_world")


def _fail(name: str, value: Any, allowed: str) -> None:
    raise ValueError(f"Scenario.{name} = {value!r} is invalid: must be {allowed}")


#: Allowed range of every numeric field: (low, high, low_open), i.e. (low, high] or [low, high]. The
#: upper bounds are generous physical limits that keep every quantity of a slot finite and every
#: array small; the lower bounds are what the model needs (a positive frequency, a non-negative std).
#: The carrier frequency is held to 0.5-100 GHz, the range of 3GPP TR 38.901's channel models, whose
#: UMa line-of-sight path loss (TR 36.777's aerial one, iscc_gym.physics.channel) and Rician K-factor the model
#: uses; far outside it the wavelength over- or underflows (1e-300 GHz: a 3e299 m wavelength).
_RANGES: dict[str, tuple[float, float, bool]] = {
    "carrier_freq_ghz": (0.5, 100.0, False),
    "bandwidth_hz": (0.0, 1e11, True),
    "tx_power_dbm": (-100.0, 100.0, False),
    "gbs_height_m": (0.0, 1e5, False),
    "n_x": (1, 1024, False),
    "n_y": (1, 1024, False),
    "antenna_spacing_wavelengths": (0.0, 100.0, True),
    "coverage_radius_m": (0.0, 1e5, True),
    "altitude_min_m": (0.0, 1e5, False),
    "shadowing_a_db": (0.0, 100.0, False),
    "shadowing_b_per_m": (0.0, 10.0, False),
    "shadowing_decorrelation_m": (0.0, 1e6, True),
    "rician_k_db": (-100.0, 100.0, False),
    "rcs_m2": (0.0, 1e6, True),
    "noise_psd_dbm_hz": (-300.0, 100.0, False),
    "comm_snr_offset_db": (-300.0, 300.0, False),
    "sensing_snr_offset_db": (-300.0, 300.0, False),
    "sensing_prior_var_m2": (0.0, 1e20, True),
    "n_symbols": (1, 10**6, False),
    "n_subcarriers": (1, 10**6, False),
    "subcarrier_spacing_hz": (0.0, 1e9, True),
    "symbol_duration_s": (0.0, 1.0, True),
    "mission_duration_s": (0.0, 1e6, True),
    "dt_s": (0.0, 1e4, True),
    "lqg_q_pos": (0.0, 1e12, False),
    "lqg_q_vel": (0.0, 1e12, False),
    "lqg_r": (0.0, 1e12, True),
    "process_noise_pos": (0.0, 1e6, False),
    "process_noise_vel": (0.0, 1e6, False),
    "ctrl_packet_bits": (1, 10**9, False),
    "ctrl_blocklength": (1, 10**9, False),
    "comm_blocklength": (1, 10**9, False),
    "ctrl_deadline_s": (0.0, 1e4, True),
    "rate_min_bps": (0.0, 1e12, False),
    "lqg_cost_target": (0.0, 1e15, True),
    "w_rate": (0.0, 1e6, False),
    "w_stab": (0.0, 1e6, False),
    "max_tracking_error_m": (0.0, 1e15, True),
    "waypoint_intensity_per_km3": (0.0, 1e6, True),
    "min_waypoints": (2, 16, False),  # MAX_WAYPOINTS
    "initial_pos_std_m": (0.0, 1e4, False),
    "initial_vel_std_mps": (0.0, 1e3, False),
    "gnss_pos_std_m": (0.0, 1e6, True),
    "gnss_vel_std_mps": (0.0, 1e4, True),
    "gnss_update_period_s": (0.0, 1e6, True),
    "los_correlation_m": (MIN_CORRELATION_M, 1e5, False),
    "map_error_std": (0.0, 1.0, False),
    "queue_deadline_s": (0.0, 1e4, False),
    "queue_arrival_bps": (0.0, 1e12, False),
    "queue_arrival_cv": (0.0, 10.0, False),
    "preview_slots": (0, 256, False),
    "preview_stride_slots": (1, 10**4, False),
    "rician_k_std_db": (0.0, 20.0, False),
    "rician_k_correlation_m": (MIN_CORRELATION_M, 1e5, False),
    "rcs_std_db": (0.0, 20.0, False),
    "rician_k_nlos_db": (-100.0, 100.0, False),
}
#: At most this many slots per mission (the reference alone takes 72 bytes a slot per loop).
MAX_SLOTS = 1_000_000
#: At most this many waypoints required per mission (``min_waypoints``), and expected (intensity x
#: coverage volume) without a check of the region. A reset redraws the waypoints until the cubic spline
#: through them stays inside the coverage region, and gives up after 1000 draws
#: (``trajectory.sample_reference``); the more waypoints, the more often the spline overshoots the
#: altitude band. Measured share of draws that stay inside with n waypoints, in the thinnest bands (the
#: worst case: in a band much thinner than the region is wide, the share depends on n alone): n = 4:
#: 0.61, 8: 0.25, 12: 0.10, 16: 0.045, 20: 0.02, 25: < 0.01 (paper preset: 0.63, 0.29, 0.13, 0.068,
#: 0.025, 0.013). At 16 a reset needs ~22 draws on average and fails with probability ~1e-20; at 50
#: (accepted before) every reset ran 1-2 minutes, then failed.
MAX_WAYPOINTS = 16
#: At most this many waypoints expected per mission in any region (the thickest regions keep ~2 % of
#: their draws at 100 waypoints: a whole hemisphere 0.02, a 30-900 m band 0.0).
MAX_MEAN_WAYPOINTS = 100.0
#: Beyond ``MAX_WAYPOINTS`` expected, the share of references that stay in the region is estimated on
#: this many draws (seeded, once per region) and must be at least ``MIN_REFERENCE_SHARE``: a reset then
#: fails with probability below 1e-22 (thicker regions keep more: a 30-900 m band keeps 0.18 at 30).
REFERENCE_SHARE_DRAWS = 64
MIN_REFERENCE_SHARE = 0.05
_reference_shares: dict[tuple, float] = {}


def reference_share(s: Scenario) -> float:
    """Share of :data:`REFERENCE_SHARE_DRAWS` seeded reference draws of ``s`` whose spline stays in the
    coverage region (what ``trajectory.sample_reference`` accepts); cached per region and waypoint law.
    """
    key = (s.coverage_radius_m, s.altitude_min_m, s.altitude_max_m, s.waypoint_intensity_per_km3, s.min_waypoints,
           s.mission_duration_s, s.dt_s)
    if key not in _reference_shares:
        rng = np.random.default_rng(0)
        kept = sum(bool(np.all(in_coverage(s, spline_reference(s, order_waypoints(sample_waypoints(s, rng))).pos_m)))
                   for _ in range(REFERENCE_SHARE_DRAWS))
        if len(_reference_shares) >= 256:
            _reference_shares.clear()
        _reference_shares[key] = kept / REFERENCE_SHARE_DRAWS
    return _reference_shares[key]


_SHORT_FIELD = ("a spatially consistent field's correlation distance: below a centimetre (a wavelength at 30 GHz) it "
                "is no large-scale field, and the field's wave numbers (1/distance) overflow")
#: Why a range is what it is, said after it where the bound is not plain physics.
_WHY = {
    "los_correlation_m": _SHORT_FIELD,
    "rician_k_correlation_m": _SHORT_FIELD,
    "carrier_freq_ghz": "the 0.5-100 GHz range of the 3GPP TR 38.901 channel models the path loss and K-factor "
                        "come from",
    "min_waypoints": f"a reset redraws the waypoints until the spline through them stays in the coverage region and "
                     f"gives up after 1000 draws; through more than {MAX_WAYPOINTS} waypoints the spline leaves a thin "
                     f"altitude band in over 95 % of draws",
}
#: The coverage region must fill at least this share of its bounding box (waypoints are drawn by
#: rejection from the box).
MIN_BOX_FRACTION = 1e-3


def _range_text(lo: float, hi: float, lo_open: bool) -> str:
    return f"in {'(' if lo_open else '['}{lo:g}, {hi:g}]"


def validate(s: Scenario) -> None:
    integer = ["n_x", "n_y", "n_symbols", "n_subcarriers", "ctrl_packet_bits", "ctrl_blocklength",
               "comm_blocklength", "min_waypoints", "preview_slots", "preview_stride_slots"]
    for f in dataclasses.fields(s):
        v = getattr(s, f.name)
        if f.name in CHOICES or f.name in _FLAGS:
            continue
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)):
            _fail(f.name, v, "a real number (not a bool or a string)")
        if not math.isfinite(float(v)):
            _fail(f.name, v, "a finite number")
    for name in integer:
        v = getattr(s, name)
        if not isinstance(v, (int, np.integer)):
            lo, hi, _ = _RANGES[name]
            _fail(name, v, f"an integer in [{lo}, {hi}]")
    for name, (lo, hi, lo_open) in _RANGES.items():
        v = float(getattr(s, name))
        if not ((v > lo if lo_open else v >= lo) and v <= hi):
            what = "an integer " if name in integer else ""
            why = f" ({_WHY[name]})" if name in _WHY else ""
            _fail(name, getattr(s, name), what + _range_text(lo, hi, lo_open) + why)
    for name, choices in CHOICES.items():
        if getattr(s, name) not in choices:
            _fail(name, getattr(s, name), f"one of {list(choices)}")
    for name in _FLAGS:
        if not isinstance(getattr(s, name), (bool, np.bool_)):
            _fail(name, getattr(s, name), "True or False")
    if s.show_world and s.rician_k_std_db == 0.0 and s.rcs_std_db == 0.0:
        _fail("show_world", s.show_world, "False where the world is the model (rician_k_std_db and rcs_std_db "
              "both 0: there is nothing hidden to show); set one of them > 0")
    for name in ("ctrl_target_bler", "comm_target_bler"):
        v = getattr(s, name)
        if not 0.0 < v < 0.5:
            _fail(name, v, "in (0, 0.5)")
    if not 0.0 <= s.altitude_min_m < s.altitude_max_m:
        _fail("altitude_min_m", s.altitude_min_m, f"in [0, altitude_max_m = {s.altitude_max_m})")
    if s.altitude_max_m >= s.coverage_radius_m:
        _fail("altitude_max_m", s.altitude_max_m, f"< coverage_radius_m = {s.coverage_radius_m}")
    if s.gbs_height_m >= s.altitude_min_m:
        _fail("gbs_height_m", s.gbs_height_m, f"< altitude_min_m = {s.altitude_min_m}")
    if s.subcarrier_spacing_hz * s.n_subcarriers > s.bandwidth_hz * (1 + 1e-9):
        _fail(
            "n_subcarriers", s.n_subcarriers,
            f"<= bandwidth_hz / subcarrier_spacing_hz = {s.bandwidth_hz / s.subcarrier_spacing_hz:g}",
        )
    if s.symbol_duration_s * (1 + 1e-9) < 1.0 / s.subcarrier_spacing_hz:
        _fail(
            "symbol_duration_s", s.symbol_duration_s,
            f">= 1 / subcarrier_spacing_hz = {1.0 / s.subcarrier_spacing_hz:g} s (T_S = T + T_CP)",
        )
    if s.ctrl_deadline_s > s.dt_s * (1 + 1e-12):
        _fail("ctrl_deadline_s", s.ctrl_deadline_s, f"<= dt_s = {s.dt_s} (one slot)")
    n = s.mission_duration_s / s.dt_s
    if abs(n - round(n)) > 1e-6 or round(n) < 2:
        _fail("dt_s", s.dt_s, "a divisor of mission_duration_s giving at least 2 slots")
    if round(n) > MAX_SLOTS:
        _fail("mission_duration_s", s.mission_duration_s,
              f"at most {MAX_SLOTS:,} slots of dt_s = {s.dt_s} s (it gives {round(n):,}); shorten the mission or "
              f"lengthen dt_s")
    # what a reset can achieve: a bounded number of waypoints, drawn by rejection from the bounding box
    mean = s.waypoint_intensity_per_km3 * coverage_volume_km3(s)
    if mean > MAX_MEAN_WAYPOINTS:
        _fail("waypoint_intensity_per_km3", s.waypoint_intensity_per_km3,
              f"at most {MAX_MEAN_WAYPOINTS:g} expected waypoints per mission (this coverage region of "
              f"{coverage_volume_km3(s):.4g} km^3 expects {mean:.4g}: the spline through more leaves any region "
              f"in almost every draw); lower it or coverage_radius_m")
    frac = coverage_box_fraction(s)
    if frac < MIN_BOX_FRACTION:
        _fail("altitude_min_m", s.altitude_min_m,
              f"low enough below coverage_radius_m = {s.coverage_radius_m} for the coverage region to fill at "
              f"least {MIN_BOX_FRACTION:g} of its bounding box (it fills {frac:.3g}): lower altitude_min_m or "
              f"altitude_max_m, or enlarge coverage_radius_m")
    if mean > MAX_WAYPOINTS and (share := reference_share(s)) < MIN_REFERENCE_SHARE:
        _fail("waypoint_intensity_per_km3", s.waypoint_intensity_per_km3,
              f"low enough for a reset to find a reference: this coverage region expects {mean:.4g} waypoints, "
              f"and the spline through them stays in the region in {round(share * REFERENCE_SHARE_DRAWS)} of "
              f"{REFERENCE_SHARE_DRAWS} seeded draws (a share of at least {MIN_REFERENCE_SHARE:g} needed; a reset "
              f"gives up after 1000 draws); lower it, "
              f"or widen the altitude band (altitude_min_m, altitude_max_m)")
    if s.blockage != "none" and not (22.5 < s.altitude_min_m and s.altitude_max_m <= 300.0):
        _fail("altitude_min_m" if s.altitude_min_m <= 22.5 else "altitude_max_m",
              s.altitude_min_m if s.altitude_min_m <= 22.5 else s.altitude_max_m,
              f"within (22.5, 300] m with blockage = {s.blockage!r} (the heights of TR 36.777 Table B-2's aerial path "
              f"loss); raise altitude_min_m or lower altitude_max_m, or set blockage = 'none'")
    if s.rician_k_blockage != "none":
        if s.rician_k_std_db == 0.0:
            _fail("rician_k_blockage", s.rician_k_blockage, "'none' without the K-factor's field (it switches the "
                  "field's K to rician_k_nlos_db in NLoS); set rician_k_std_db > 0 (the field task)")
        if not (22.5 < s.altitude_min_m and s.altitude_max_m <= 300.0):
            _fail("rician_k_blockage", s.rician_k_blockage, "'none' unless the altitude band lies within (22.5, "
                  "300] m (TR 36.777 Table B-1's aerial LoS probability); move the band or set it to 'none'")
    if s.queue_deadline_s > 0.0 and s.queue_deadline_s < 0.5 * s.dt_s:
        _fail("queue_deadline_s", s.queue_deadline_s, f"0 (no queue) or at least half a slot (dt_s = {s.dt_s} s)")
    if s.queue_deadline_s > 1000.0 * s.dt_s:
        _fail("queue_deadline_s", s.queue_deadline_s, f"at most 1000 slots of dt_s = {s.dt_s} s")
    if s.preview_slots > 0 and s.blockage == "none":
        _fail("preview_slots", s.preview_slots, "0 with blockage = 'none' (the preview reads the blockage map); "
              "set blockage to 'uma_av' or 'umi_av'")
    if s.lqg_q_pos == 0.0:
        # (A, Q^{1/2}) must be detectable for the LQG gain to stabilise: position weight > 0.
        _fail("lqg_q_pos", s.lqg_q_pos, "> 0 (with zero position weight the LQR leaves the "
              "position undetectable and the DARE has no stabilising solution)")
