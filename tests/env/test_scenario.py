"""Tests of iscc_gym.scenario: validation of every field, presets, immutability, derived values.

The field categories below are written out from the Scenario docstring (units and meaning), not
imported from the validator, and a completeness test checks that they cover every field.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from iscc_gym import SCENARIOS, Scenario, make_scenario
from iscc_gym.scenario import LITERAL_OVERRIDES

POSITIVE = [  # must be > 0
    "carrier_freq_ghz", "bandwidth_hz", "antenna_spacing_wavelengths", "coverage_radius_m",
    "shadowing_decorrelation_m", "rcs_m2", "subcarrier_spacing_hz", "symbol_duration_s",
    "mission_duration_s", "dt_s", "lqg_r", "ctrl_deadline_s", "lqg_cost_target",
    "max_tracking_error_m", "waypoint_intensity_per_km3", "sensing_prior_var_m2",
    "gnss_pos_std_m", "gnss_vel_std_mps", "los_correlation_m", "rician_k_correlation_m",
]
NON_NEGATIVE = [  # must be >= 0
    "gbs_height_m", "shadowing_a_db", "shadowing_b_per_m", "lqg_q_vel", "process_noise_pos",
    "process_noise_vel", "rate_min_bps", "w_rate", "w_stab", "initial_pos_std_m",
    "initial_vel_std_mps", "altitude_min_m", "map_error_std", "queue_deadline_s", "queue_arrival_bps",
    "queue_arrival_cv", "rician_k_std_db", "rcs_std_db",
]
POSITIVE_INT = ["n_x", "n_y", "n_symbols", "n_subcarriers", "ctrl_packet_bits",
                "ctrl_blocklength", "comm_blocklength", "min_waypoints"]
BLER = ["ctrl_target_bler", "comm_target_bler"]  # in (0, 0.5)
ANY_FINITE = ["tx_power_dbm", "noise_psd_dbm_hz", "comm_snr_offset_db", "sensing_snr_offset_db",
              "rician_k_db", "rician_k_nlos_db", "altitude_max_m"]
URBAN_INT = ["preview_slots", "preview_stride_slots"]  # integers >= 0 and >= 1; previews need blockage
SPECIAL = ["lqg_q_pos", "gnss_update_period_s"]  # > 0 (and: zero position weight; a multiple of dt_s)
CHOICES = {
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
BOOLS = ["reference_feedforward", "show_world"]
NUMERIC = POSITIVE + NON_NEGATIVE + POSITIVE_INT + BLER + ANY_FINITE + SPECIAL + URBAN_INT


def _msg(name):
    return rf"Scenario\.{name} = "


def test_field_categories_cover_every_field():
    names = [f.name for f in dataclasses.fields(Scenario)]
    listed = NUMERIC + list(CHOICES) + BOOLS
    assert sorted(listed) == sorted(names)
    assert len(set(listed)) == len(listed)


# --- numeric fields -----------------------------------------------------------------------------


@pytest.mark.parametrize("name", NUMERIC)
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf], ids=["nan", "inf", "-inf"])
def test_non_finite_rejected(name, bad):
    with pytest.raises(ValueError, match=_msg(name)):
        Scenario().replace(**{name: bad})


@pytest.mark.parametrize("name", POSITIVE + SPECIAL)
@pytest.mark.parametrize("bad", [0.0, -1.0, -1e-12])
def test_positive_fields_reject_zero_and_negative(name, bad):
    with pytest.raises(ValueError, match=_msg(name)):
        Scenario().replace(**{name: bad})


@pytest.mark.parametrize("name", NON_NEGATIVE)
@pytest.mark.parametrize("bad", [-1.0, -1e-9])
def test_non_negative_fields_reject_negative(name, bad):
    with pytest.raises(ValueError, match=_msg(name)):
        Scenario().replace(**{name: bad})


@pytest.mark.parametrize("name", [n for n in NON_NEGATIVE if n not in ("altitude_min_m",
                                                                       "gbs_height_m")])
def test_non_negative_fields_accept_zero(name):
    assert getattr(Scenario().replace(**{name: 0.0}), name) == 0.0


def test_gbs_height_zero_accepted_and_altitude_min_zero_needs_lower_gbs():
    assert Scenario(gbs_height_m=0.0).gbs_height_m == 0.0
    # altitude_min_m >= 0 is allowed by itself, but the GBS must stay strictly below it
    with pytest.raises(ValueError, match=_msg("gbs_height_m")):
        Scenario(altitude_min_m=0.0, gbs_height_m=0.0)


@pytest.mark.parametrize("name", [n for n in POSITIVE_INT if n != "min_waypoints"])
@pytest.mark.parametrize("bad", [0, -3, 2.0, 2.5, True, "4"],
                         ids=["zero", "neg", "float", "frac", "bool", "str"])
def test_positive_int_fields(name, bad):
    with pytest.raises(ValueError, match=_msg(name)):
        Scenario().replace(**{name: bad})


def test_positive_int_fields_accept_numpy_integers():
    s = Scenario(n_x=np.int64(2), n_symbols=np.int32(32))
    assert s.n_antennas == 8


@pytest.mark.parametrize("bad", [1, 0, 17, 50, 4.0, True])
def test_min_waypoints(bad):
    with pytest.raises(ValueError, match=_msg("min_waypoints")):
        Scenario(min_waypoints=bad)
    assert Scenario(min_waypoints=2).min_waypoints == 2
    assert Scenario(min_waypoints=16).min_waypoints == 16


@pytest.mark.parametrize("bad", [-1, 2.0, 257, True])
def test_preview_slots(bad):
    urban = SCENARIOS["urban"]
    with pytest.raises(ValueError, match=_msg("preview_slots")):
        urban.replace(preview_slots=bad)
    assert urban.replace(preview_slots=0).preview_slots == 0
    with pytest.raises(ValueError, match=_msg("preview_stride_slots")):
        urban.replace(preview_stride_slots=0)
    with pytest.raises(ValueError, match=_msg("preview_slots") + r"4 is invalid: must be 0 with blockage = 'none'"):
        Scenario(preview_slots=4)


def test_urban_fields_ranges_and_cross_checks():
    with pytest.raises(ValueError, match=_msg("map_error_std")):
        Scenario(map_error_std=1.5)
    with pytest.raises(ValueError, match=_msg("queue_deadline_s") + r".*at least half a slot"):
        Scenario(queue_deadline_s=0.01)
    with pytest.raises(ValueError, match=_msg("altitude_min_m") + r".*TR 36.777 Table B-2"):
        SCENARIOS["urban"].replace(altitude_min_m=20.0, gbs_height_m=10.0)
    assert Scenario().queue_deadline_slots == 0 and SCENARIOS["urban"].queue_deadline_slots == 10
    assert Scenario(queue_deadline_s=0.26).queue_deadline_slots == 3


@pytest.mark.parametrize("name", BLER)
@pytest.mark.parametrize("bad", [0.0, -1e-3, 0.5, 0.7, 1.0])
def test_bler_fields(name, bad):
    with pytest.raises(ValueError, match=_msg(name)):
        Scenario().replace(**{name: bad})


@pytest.mark.parametrize("name", ANY_FINITE[:-1])
def test_unrestricted_fields_accept_negative_values(name):
    assert getattr(Scenario().replace(**{name: -7.5}), name) == -7.5


# --- choice and bool fields ---------------------------------------------------------------------


@pytest.mark.parametrize("name", list(CHOICES))
def test_choice_fields(name):
    base = SCENARIOS["field"] if name == "rician_k_blockage" else Scenario()  # it switches the field's K
    for ok in CHOICES[name]:
        assert getattr(base.replace(**{name: ok}), name) == ok
    for bad in ("bogus", CHOICES[name][0].upper(), "", None, 1):
        with pytest.raises(ValueError, match=_msg(name)):
            base.replace(**{name: bad})


@pytest.mark.parametrize("bad", [0, 1, "yes", None, 1.0])
def test_bool_field_rejects_non_bools(bad):
    with pytest.raises(ValueError, match=_msg("reference_feedforward")):
        Scenario(reference_feedforward=bad)


def test_bool_field_accepts_bools():
    assert Scenario(reference_feedforward=True).reference_feedforward is True
    assert bool(Scenario(reference_feedforward=np.bool_(True)).reference_feedforward)


# --- cross-field checks -------------------------------------------------------------------------


@pytest.mark.parametrize("overrides,field", [
    ({"altitude_min_m": 300.0}, "altitude_min_m"),
    ({"altitude_min_m": 350.0}, "altitude_min_m"),
    ({"altitude_max_m": 100.0}, "altitude_min_m"),
    ({"altitude_max_m": 1000.0}, "altitude_max_m"),
    ({"coverage_radius_m": 300.0}, "altitude_max_m"),
    ({"gbs_height_m": 100.0}, "gbs_height_m"),
    ({"gbs_height_m": 150.0}, "gbs_height_m"),
    ({"n_subcarriers": 101}, "n_subcarriers"),
    ({"subcarrier_spacing_hz": 120e3}, "n_subcarriers"),
    ({"bandwidth_hz": 9e6}, "n_subcarriers"),
    ({"symbol_duration_s": 9.9e-6}, "symbol_duration_s"),
    ({"ctrl_deadline_s": 0.2}, "ctrl_deadline_s"),
    ({"ctrl_deadline_s": 0.1000001}, "ctrl_deadline_s"),
    ({"dt_s": 0.3}, "dt_s"),
    ({"dt_s": 0.15}, "dt_s"),
    ({"dt_s": 500.0}, "dt_s"),  # a single slot
    ({"mission_duration_s": 500.05}, "dt_s"),
    ({"lqg_q_pos": 0.0}, "lqg_q_pos"),
])
def test_cross_field_checks(overrides, field):
    with pytest.raises(ValueError, match=_msg(field)):
        Scenario().replace(**overrides)


@pytest.mark.parametrize("overrides", [
    {"ctrl_deadline_s": 0.1},                      # exactly one slot (the literal preset)
    {"symbol_duration_s": 1e-5},                   # no cyclic prefix
    {"n_subcarriers": 100, "bandwidth_hz": 10e6},  # K * df = B exactly
    {"dt_s": 250.0, "ctrl_deadline_s": 1e-3},      # two slots
    {"dt_s": 0.05},
    {"altitude_max_m": 999.0},
    {"gbs_height_m": 99.0},
])
def test_cross_field_boundaries_accepted(overrides):
    s = Scenario().replace(**overrides)
    for k, v in overrides.items():
        assert getattr(s, k) == v


# --- replace / make_scenario ----------------------------------------------------------------------


def test_unknown_field_raises_type_error():
    with pytest.raises(TypeError, match="dt"):
        Scenario().replace(dt=0.1)
    with pytest.raises(TypeError):
        make_scenario("paper", not_a_field=1)
    with pytest.raises(TypeError):
        Scenario(not_a_field=1)


def test_make_scenario():
    assert make_scenario() == Scenario()
    assert make_scenario("paper") is SCENARIOS["paper"]
    assert make_scenario("literal") == SCENARIOS["literal"]
    s = make_scenario("literal", lqg_r=0.5)
    assert s.lqg_r == 0.5 and s.process_noise_reading == "variance"
    with pytest.raises(ValueError, match=_msg("ctrl_deadline_s")):
        make_scenario("literal", dt_s=0.05)  # literal deadline 0.1 s exceeds the slot
    base = Scenario(lqg_r=0.5)
    assert make_scenario(base) is base
    assert make_scenario(base, lqg_q_vel=3.0) == Scenario(lqg_r=0.5, lqg_q_vel=3.0)
    with pytest.raises(ValueError, match="nope"):
        make_scenario("nope")
    with pytest.raises(ValueError, match=_msg("dt_s")):
        make_scenario("paper", dt_s=-0.1)
    with pytest.raises(TypeError):
        make_scenario(3)


def test_replace_revalidates_and_does_not_mutate():
    s = Scenario()
    t = s.replace(lqg_r=1.0)
    assert s.lqg_r == 0.01 and t.lqg_r == 1.0
    with pytest.raises(ValueError):
        s.replace(lqg_r=0.0)


def test_frozen_and_hashable():
    s = Scenario()
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.dt_s = 0.2
    with pytest.raises(dataclasses.FrozenInstanceError):
        del s.lqg_r
    assert hash(s) == hash(Scenario())
    assert s == Scenario() and s is not Scenario()
    d = {s: 1, SCENARIOS["literal"]: 2}
    assert d[Scenario()] == 1 and len(d) == 2
    assert len({s, Scenario(), s.replace(lqg_r=s.lqg_r)}) == 1
    assert s.replace(lqg_r=0.02) != s


# --- presets and derived quantities --------------------------------------------------------------

# The literal preset, as documented in the module docstring: process noise read as variances,
# total-power SNR, no calibration offsets, full-band echo noise, the printed array response and
# angle FIM, a one-slot control deadline and the printed rate-cost determinant.
DOCUMENTED_LITERAL = {
    "process_noise_reading": "variance",
    "snr_convention": "total_power",
    "comm_snr_offset_db": 0.0,
    "sensing_snr_offset_db": 0.0,
    "sensing_noise_convention": "full_band",
    "array_orientation": "printed",
    "fim_angle_convention": "printed",
    "ctrl_deadline_s": 0.1,
    "rate_cost_determinant": "printed",
    "gnss_update_period_s": 0.1,
}


def test_literal_differs_from_paper_exactly_in_documented_fields():
    paper, literal = SCENARIOS["paper"], SCENARIOS["literal"]
    assert paper == Scenario()
    diff = {f.name for f in dataclasses.fields(Scenario)
            if getattr(paper, f.name) != getattr(literal, f.name)}
    assert diff == set(DOCUMENTED_LITERAL) == set(LITERAL_OVERRIDES)
    for k, v in DOCUMENTED_LITERAL.items():
        assert getattr(literal, k) == v
        assert LITERAL_OVERRIDES[k] == v
    assert literal == paper.replace(**DOCUMENTED_LITERAL)


@pytest.mark.parametrize("name", ["paper", "literal"])
def test_presets_hold_table_one(name):
    s = SCENARIOS[name]
    table = {
        "carrier_freq_ghz": 2.4, "bandwidth_hz": 10e6, "tx_power_dbm": 42.0, "gbs_height_m": 25.0,
        "n_x": 2, "n_y": 4, "coverage_radius_m": 1000.0, "altitude_min_m": 100.0,
        "altitude_max_m": 300.0, "shadowing_a_db": 4.64, "shadowing_b_per_m": 0.0066,
        "rcs_m2": 0.01, "noise_psd_dbm_hz": -150.0, "n_symbols": 64, "n_subcarriers": 100,
        "subcarrier_spacing_hz": 100e3, "symbol_duration_s": 12.5e-6, "mission_duration_s": 500.0,
        "dt_s": 0.1, "lqg_q_pos": 1e4, "lqg_q_vel": 1e2, "lqg_r": 0.01, "ctrl_packet_bits": 256,
        "ctrl_blocklength": 50, "comm_blocklength": 8000, "ctrl_target_bler": 1e-5,
        "comm_target_bler": 1e-3, "process_noise_pos": 0.2, "process_noise_vel": 0.002,
    }
    for k, v in table.items():
        assert getattr(s, k) == v, k


def test_derived_quantities():
    s = Scenario()
    assert s.wavelength_m == pytest.approx(0.1249, abs=1e-4)
    assert s.wavelength_m == pytest.approx(299_792_458.0 / 2.4e9, rel=1e-12)
    assert s.n_slots == 5000
    assert s.n_antennas == 8
    assert Scenario(dt_s=0.05).n_slots == 10_000
    assert Scenario(carrier_freq_ghz=3.5).wavelength_m == pytest.approx(0.0856549880, rel=1e-9)
    assert Scenario(n_x=4, n_y=4).n_antennas == 16
    assert SCENARIOS["literal"].process_noise_var_pos_m2 == pytest.approx(0.2)
    assert SCENARIOS["paper"].process_noise_var_pos_m2 == pytest.approx(0.04)
    assert SCENARIOS["paper"].process_noise_var_vel_m2s2 == pytest.approx(4e-6)


# --- validation gaps --------------------------------------------------------------------------


def test_bool_in_float_field_rejected():
    with pytest.raises(ValueError, match=_msg("dt_s")):
        Scenario(dt_s=True, ctrl_deadline_s=1e-4)


def test_string_in_float_field_rejected():
    with pytest.raises(ValueError, match=_msg("tx_power_dbm")):
        Scenario(tx_power_dbm="42")


def test_gnss_update_period_in_slots():
    assert Scenario(gnss_update_period_s=0.3).gnss_update_slots == 3
    assert Scenario(gnss_update_period_s=0.26).gnss_update_slots == 3  # rounded to whole slots
    assert Scenario(gnss_update_period_s=0.01).gnss_update_slots == 1  # at least every slot
    assert SCENARIOS["paper"].gnss_update_slots == 10 and SCENARIOS["literal"].gnss_update_slots == 1


# --- upper bounds and what a reset can achieve (issue 12) -----------------------------------------


@pytest.mark.parametrize("name,bad", [
    ("tx_power_dbm", 1e15), ("noise_psd_dbm_hz", -1e15), ("comm_snr_offset_db", 1e15),
    ("sensing_snr_offset_db", -1e15), ("rician_k_db", 1e15), ("shadowing_a_db", 1e15),
    ("n_x", 2**63), ("n_y", 2**40), ("n_symbols", 2**63), ("ctrl_packet_bits", 2**63),
    ("ctrl_blocklength", 2**63), ("comm_blocklength", 2**63), ("carrier_freq_ghz", 1e300),
    ("bandwidth_hz", 1e300), ("initial_vel_std_mps", 1e6), ("initial_pos_std_m", 1e9),
    ("w_rate", 1e300), ("w_stab", 1e300), ("max_tracking_error_m", 1e300), ("lqg_q_pos", 1e300),
    ("lqg_r", 1e300), ("coverage_radius_m", 1e300), ("gnss_pos_std_m", 1e300),
    ("sensing_prior_var_m2", 1e300), ("rate_min_bps", 1e300), ("waypoint_intensity_per_km3", 1e300),
])
def test_values_beyond_the_physical_range_rejected_naming_the_range(name, bad):
    with pytest.raises(ValueError, match=_msg(name) + r".*must be (an integer )?in [\[(]"):
        Scenario().replace(**{name: bad})


def test_mission_too_long_for_memory_rejected():
    # 1e6 s at 1e-3 s: 1e9 slots, 72 GB of reference per loop
    with pytest.raises(ValueError, match=_msg("mission_duration_s") + ".*slots"):
        Scenario(mission_duration_s=1e6, dt_s=1e-3, ctrl_deadline_s=1e-4)
    assert Scenario(mission_duration_s=1e5, dt_s=0.1).n_slots == 1_000_000  # the cap itself is allowed


def test_expected_waypoint_count_bounded():
    # the default region (0.6 km^3) at 1e4 per km^3 expects ~6,000 waypoints, at 1000 ~600
    for bad in (1e4, 1000.0):
        with pytest.raises(ValueError, match=_msg("waypoint_intensity_per_km3") + ".*expected waypoints"):
            Scenario(waypoint_intensity_per_km3=bad)
    # ~36: within the cap, but the spline through them leaves the 100-300 m band in every draw
    with pytest.raises(ValueError, match=_msg("waypoint_intensity_per_km3") + ".*stays in the region in 0 of 64"):
        Scenario(waypoint_intensity_per_km3=60.0)
    assert Scenario(waypoint_intensity_per_km3=26.0).waypoint_intensity_per_km3 == 26.0  # ~15.6


def test_coverage_region_must_fill_part_of_its_box():
    # a 0.1 mm band just below the top of the hemisphere fills ~1e-7 of its bounding box
    with pytest.raises(ValueError, match=_msg("altitude_min_m") + ".*bounding box"):
        Scenario(altitude_min_m=999.9998, altitude_max_m=999.9999)


@pytest.mark.parametrize("name", [n for n in NUMERIC if n not in ("altitude_max_m",)])
def test_presets_inside_every_range(name):
    from iscc_gym.scenario_checks import _RANGES

    for preset in SCENARIOS.values():
        v = getattr(preset, name)
        if name in _RANGES:
            lo, hi, _ = _RANGES[name]
            assert lo <= v <= hi
