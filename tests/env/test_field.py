"""The field task's world (issue 36): the K-factor along the path and the drone's RCS, in the compiled slot and the
observation; each effect off is the paper's slot, the hidden values reach only the aware bound's observation."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import iscc_gym
from iscc_gym.scenario import make_scenario
from iscc_gym.sim import loop
from iscc_gym.sim.functional import decode_observation
from iscc_gym.sim.mission import REFERENCE_COLUMNS, WORLD_COLUMNS, mission_columns, world_along, world_column
from iscc_gym.sim.schema import METRIC_NAMES, obs_names
from iscc_gym.tasks import FIELD_ENV_ID


def _field_state(s, k_db, rcs_db, seed=0):
    """A paper mission's loop state with the world's columns set by hand (one loop)."""
    paper = make_scenario("paper")
    rng = np.random.default_rng(seed)
    st = loop.init_mission(paper, rng)
    ref = st.ref[0]
    world = np.column_stack([np.full(len(ref), k_db), np.full(len(ref), rcs_db)])
    return loop.init_state(s, np.concatenate([ref, world], axis=1)[None], [np.random.default_rng(seed)]), st


def _step_both(k_db, rcs_db, steps=40):
    s = make_scenario("field")
    fst, pst = _field_state(s, k_db, rcs_db)
    paper = make_scenario("paper")
    pst = loop.init_state(paper, pst.ref, [np.random.default_rng(0)])
    alpha = np.array([[0.1, 0.2, 0.7]])
    out_f, out_p = [], []
    for t in range(steps):  # the same Generator seed: the same normals for both
        fst, mf = loop.step(s, fst, alpha, np.random.default_rng(100 + t))
        pst, mp = loop.step(paper, pst, alpha, np.random.default_rng(100 + t))
        out_f.append([mf[k][0] for k in METRIC_NAMES])
        out_p.append([mp[k][0] for k in METRIC_NAMES])
    return np.array(out_f, float), np.array(out_p, float)


def test_the_world_at_the_models_values_is_the_papers_slot():
    """K = rician_k_db and no RCS offset in the rows: the field branch gives the paper branch's slot (to rounding:
    its Rician constants are computed in the slot, the paper's once)."""
    s = make_scenario("field")
    f, p = _step_both(s.rician_k_db, 0.0)
    np.testing.assert_allclose(f, p, rtol=1e-9, atol=1e-9)
    assert np.all(np.isfinite(f))


def test_an_rcs_offset_is_a_gain_on_the_echo_alone():
    """+6 dB of RCS: the echo's SNR 6 dB higher on the same draws, the command link's SNR unchanged."""
    base, _ = _step_both(9.0, 0.0, steps=1)
    up, _ = _step_both(9.0, 6.0, steps=1)
    col = {k: j for j, k in enumerate(METRIC_NAMES)}
    assert up[0, col["echo_snr_db"]] - base[0, col["echo_snr_db"]] == pytest.approx(6.0, abs=1e-9)
    assert up[0, col["snr_db"]] == base[0, col["snr_db"]]
    assert up[0, col["peb_m"]] < base[0, col["peb_m"]]


def test_a_lower_k_factor_fades_deeper_on_the_same_draws():
    """The same normals under K = -10 dB spread the link's fading gain wider than under 20 dB."""
    col = {k: j for j, k in enumerate(METRIC_NAMES)}
    lo, _ = _step_both(-10.0, 0.0, steps=60)
    hi, _ = _step_both(20.0, 0.0, steps=60)
    fade = lambda m: m[:, col["snr_db"]] - m[:, col["snr_large_scale_db"]]  # noqa: E731
    assert np.std(fade(lo)) > 3.0 * np.std(fade(hi))


def test_world_rows_follow_their_sources_spreads_and_share_draws_across_spreads():
    s = make_scenario("field")
    ref = np.zeros((3, 9))
    ref[:, 0] = [0.0, 1e4, 2e4]  # far apart: independent points of the field
    cols = np.array([world_along(s, ref, np.random.default_rng(i)) for i in range(400)])
    k = cols[:, :, 0].ravel()
    assert abs(k.mean() - s.rician_k_db) < 0.6 and abs(k.std() - s.rician_k_std_db) < 0.6
    rcs = cols[:, :, 1]
    assert np.all(rcs == rcs[:, :1])  # one RCS per mission
    assert abs(rcs[:, 0].std() - s.rcs_std_db) < 0.4
    wide = make_scenario("field", rician_k_std_db=8.0, rcs_std_db=6.0)
    w = world_along(wide, ref, np.random.default_rng(3))
    n = world_along(s, ref, np.random.default_rng(3))
    np.testing.assert_allclose((w[:, 0] - 9.0) / 8.0, (n[:, 0] - 9.0) / 5.0, rtol=1e-12)
    np.testing.assert_allclose(w[:, 1] / 6.0, n[:, 1] / 3.74, rtol=1e-12)


def test_abrupt_line_of_sight_drops_k_where_blocked_and_leaves_every_other_draw():
    from iscc_gym.physics.blockage import los_probability

    s = make_scenario("field")
    blocked = s.replace(rician_k_blockage="umi_av", los_field_kernel="gaussian", rician_k_nlos_db=-15.0)
    a, b = loop.init_mission(s, np.random.default_rng(5)), loop.init_mission(blocked, np.random.default_rng(5))
    for name in a._fields:  # the initial state, the reference, the RCS: the same draws
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray) and name != "ref":
            np.testing.assert_array_equal(x, y)
    k = world_column(s)
    np.testing.assert_array_equal(np.delete(a.ref, k, axis=2), np.delete(b.ref, k, axis=2))
    nlos = b.ref[0, :, k] != a.ref[0, :, k]
    assert np.all(b.ref[0, nlos, k] == -15.0)
    # blocked in stretches, as often as TR 36.777's UMi-AV probability says along this path (a field is one draw:
    # pooled over missions)
    frac, expect, switches = [], [], []
    for seed in range(12):
        st = loop.init_mission(blocked, np.random.default_rng(seed))
        un = loop.init_mission(s, np.random.default_rng(seed))
        off = st.ref[0, :, k] != un.ref[0, :, k]
        ref = st.ref[0]
        frac.append(off.mean())
        expect.append(1.0 - los_probability("umi_av", ref[:, 2], np.hypot(ref[:, 0], ref[:, 1])).mean())
        switches.append(np.sum(off[1:] != off[:-1]))
    assert abs(np.mean(frac) - np.mean(expect)) < 0.12 and 0.1 < np.mean(frac) < 0.7
    assert 2 < np.mean(switches) < 200
    with pytest.raises(ValueError, match=r"Scenario\.rician_k_blockage = 'umi_av' is invalid.*rician_k_std_db"):
        make_scenario("paper", rician_k_blockage="umi_av")
    with pytest.raises(ValueError, match=r"Scenario\.rician_k_blockage = 'uma' is invalid.*one of"):
        s.replace(rician_k_blockage="uma")
    with pytest.raises(ValueError, match=r"Scenario\.rician_k_blockage = 'umi_av' is invalid.*altitude"):
        s.replace(rician_k_blockage="umi_av", altitude_max_m=350.0, coverage_radius_m=2000.0,
                  waypoint_intensity_per_km3=0.5)


def test_layout_without_the_field_is_the_papers():
    paper = make_scenario("paper")
    field = make_scenario("field")
    assert mission_columns(paper) == REFERENCE_COLUMNS and world_column(paper) == -1
    assert mission_columns(field) == REFERENCE_COLUMNS + len(WORLD_COLUMNS) == world_column(field) + 2
    names = obs_names(field)
    assert names[:len(obs_names(paper))] == obs_names(paper)
    assert names[-2:] == ("last_fade_db", "last_echo_snr_db")
    assert obs_names(field.replace(show_world=True))[-2:] == ("world_k_db", "world_rcs_offset_db")


def test_show_world_needs_a_hidden_world():
    with pytest.raises(ValueError, match=r"Scenario\.show_world = True is invalid.*rician_k_std_db"):
        make_scenario("paper", show_world=True)
    with pytest.raises(ValueError, match=r"Scenario\.rician_k_std_db"):
        make_scenario("paper", rician_k_std_db=-1.0)


def test_the_env_measures_what_the_slot_did_and_shows_the_world_only_when_asked():
    s = make_scenario("field")
    env = gym.make(FIELD_ENV_ID)
    shown = iscc_gym.ISCCEnv(scenario=s.replace(show_world=True))
    obs, _ = env.reset(seed=4)
    obs_w, _ = shown.reset(seed=4)
    assert obs.shape == (25,) and obs_w.shape == (27,)
    np.testing.assert_array_equal(obs_w[:25], obs)
    d = decode_observation(obs, s)
    assert d["last_fade_db"] == 0.0 and d["last_echo_snr_db"] == 0.0  # 0 at reset
    for _ in range(5):
        a = np.array([0.2, -0.3, 0.5], np.float32)
        obs, _, _, _, info = env.step(a)
        obs_w, _, _, _, info_w = shown.step(a)
        assert info_w["tracking_error_m"] == info["tracking_error_m"]  # the same missions and draws
        d = decode_observation(obs, s)
        assert d["last_fade_db"] == pytest.approx(info["snr_db"] - info["snr_large_scale_db"], abs=1e-5)
        assert d["last_echo_snr_db"] == pytest.approx(info["echo_snr_db"], abs=1e-4)
    rows = shown.unwrapped._state.ref[0]
    n = int(shown.unwrapped._state.n[0])
    dw = decode_observation(obs_w, s.replace(show_world=True))
    w = world_column(s)
    assert dw["world_k_db"] == pytest.approx(rows[n, w], abs=1e-5)
    assert dw["world_rcs_offset_db"] == pytest.approx(rows[n, w + 1], abs=1e-5)


def test_both_checkers_pass_on_the_field_env_without_warnings():
    import warnings

    from gymnasium.utils.env_checker import check_env as gym_check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gym_check_env(gym.make(FIELD_ENV_ID).unwrapped)
        sb3_check_env(gym.make(FIELD_ENV_ID), warn=True)
        sb3_check_env(gym.make(FIELD_ENV_ID, show_world=True).unwrapped, warn=True)
    assert [str(w.message) for w in caught] == []


@pytest.mark.parametrize("name", ["rician_k_correlation_m", "los_correlation_m"])
@pytest.mark.parametrize("value", [1e-305, 1e-310, 0.005])
def test_a_correlation_distance_too_short_for_a_field_is_refused_by_name(name, value):
    """Issue 43.6: ``rician_k_correlation_m`` of about 1e-305 passed the validator, overflowed the field's wave numbers
    and made every K NaN (the episode ended after one slot with the loss-of-track penalty)."""
    with pytest.raises(ValueError, match=rf"{name} = .*centimetre"):
        make_scenario("field", **{name: value})


def test_the_shortest_correlation_distance_accepted_flies_a_finite_mission():
    from iscc_gym.physics.blockage import draw_field

    env = gym.make(FIELD_ENV_ID, rician_k_correlation_m=0.01)
    env.reset(seed=3)
    for _ in range(20):
        obs, reward, terminated, truncated, info = env.step(np.array([0.0, 0.3, 0.5], np.float32))
        assert np.all(np.isfinite(obs)) and np.isfinite(reward) and not terminated
    with pytest.raises(ValueError, match="too short"):
        draw_field(np.random.default_rng(0), 1e-305)
