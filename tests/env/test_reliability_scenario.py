"""Scenario values that passed validation and then broke a reset or a step (issue 23, defects 11 and 16):
refused when the Scenario is made, or, for LQG weights without a feedback gain, when the env is made,
with the field names and the fix.
"""

from __future__ import annotations

import time

import gymnasium as gym
import numpy as np
import pytest

import iscc_gym  # noqa: F401  (registers the env ids)
from iscc_gym import Scenario
from iscc_gym.scenario_checks import MAX_WAYPOINTS
from iscc_gym.trajectory import coverage_volume_km3, sample_reference


@pytest.mark.parametrize("n", [17, 50])
def test_min_waypoints_a_reset_cannot_draw_is_refused_at_construction(n):
    """At 50 every reset ran 1-2 minutes, then raised: the spline through that many waypoints leaves the
    altitude band in every draw."""
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=rf"Scenario\.min_waypoints = {n} is invalid: must be an integer in \[2, 16\] "
                                         r"\(a reset redraws the waypoints"):
        Scenario(min_waypoints=n)
    assert time.perf_counter() - t0 < 1.0


@pytest.mark.parametrize("overrides", [
    {"min_waypoints": MAX_WAYPOINTS},
    {"min_waypoints": MAX_WAYPOINTS, "altitude_min_m": 100.0, "altitude_max_m": 105.0},  # a thin band: worst case
    {"waypoint_intensity_per_km3": MAX_WAYPOINTS / coverage_volume_km3(Scenario())},  # the expected count at the cap
], ids=["min", "min-thin-band", "mean"])
def test_waypoint_counts_at_the_bound_reset_quickly(overrides):
    """The bound is one a reset meets: at it, references are found in well under a second each."""
    s = Scenario(**overrides)
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    refs = [sample_reference(s, rng) for _ in range(5)]
    assert all(len(r.waypoints_m) >= s.min_waypoints for r in refs)
    assert time.perf_counter() - t0 < 10.0


@pytest.mark.parametrize("bad", [1e-300, 1e-3, 0.49, 100.5, 1e3])
def test_carrier_frequency_outside_the_channel_models_range_is_refused(bad):
    """1e-300 GHz passed validation (the range was (0, 1000]), then the wavelength overflowed in a step."""
    with pytest.raises(ValueError, match=r"Scenario\.carrier_freq_ghz = .* must be in \[0\.5, 100\] \(.*38\.901"):
        Scenario(carrier_freq_ghz=bad)


@pytest.mark.parametrize("f", [0.5, 100.0])
def test_carrier_frequencies_at_the_ends_of_the_range_step_finite(f):
    env = gym.make("iscc_gym/ISCC-v0", carrier_freq_ghz=f, max_episode_steps=3)
    obs, _ = env.reset(seed=0)
    for _ in range(3):
        obs, reward, *_ = env.step(env.action_space.sample())
        assert np.all(np.isfinite(obs)) and np.isfinite(reward)
    env.close()


@pytest.mark.parametrize("weights, why", [
    ({"lqg_q_pos": 1e-300, "lqg_q_vel": 1.0, "lqg_r": 1e-300}, "the DARE has no solution"),
    ({"lqg_q_pos": 1e-3, "lqg_q_vel": 1e-12, "lqg_r": 1e12}, "the DARE has no solution"),
    ({"lqg_q_pos": 1e-300, "lqg_q_vel": 1e-3, "lqg_r": 1e12}, "the LQ gain does not stabilise the loop"),
])
def test_lqg_weights_without_a_feedback_gain_name_the_fields(weights, why):
    """These weights passed validation, then the env raised numpy's LinAlgError ("Failed to find a finite
    solution"), or scipy's reordering ValueError, naming no field; or ran an unstable loop."""
    s = Scenario(**weights)
    with pytest.raises(ValueError, match=r"Scenario\.lqg_q_pos = .*, lqg_q_vel = .*, lqg_r = .* give no LQG feedback "
                                         r"gain: " + why + r".*Table I"):
        gym.make("iscc_gym/ISCC-v0", scenario=s).reset(seed=0)
