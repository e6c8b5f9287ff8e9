"""Robustness and API tests of the Gymnasium environment ``iscc_gym/ISCC-v0``.

Covers the "Robustness checklist" of ``../shared/DESIGN.md`` (issue 3, item 9): the Gymnasium and
SB3 env checkers, registration and ``gymnasium.make`` arguments, the action map, invalid actions,
API order, seeding, divergence, the observation box, costs and the Safety-Gymnasium wrapper, info
keys, pickle / deepcopy, vector envs, the comparison schemes, rendering, saving an agent, and a
hypothesis test over random action sequences. Everything goes through the public API
(``gymnasium.make``) except where a test must look at the env's internal state
(``env.unwrapped._state``, its generator) to show that nothing changed.
"""

from __future__ import annotations

import copy
import math
import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from oracle_loop import preview

import iscc_gym
from iscc_gym import ENV_ID, SCENARIOS, Scenario, action_to_split, split_to_action
from iscc_gym.envs.env import ISCCEnv
from iscc_gym.envs.wrappers import SafetyCostWrapper

# any warning inside a test is a failure (the env promises to run warning-free)
pytestmark = pytest.mark.filterwarnings("error")

INFO_KEYS = ("tracking_error_m", "cost_rate", "cost_stability", "cost", "snr_db", "peb_m", "veb_mps",
             "eps_ctrl", "packet_received", "rate_comm_bps", "rate_ctrl_bps", "estimation_error_m",
             "alpha")
#: info entries that are finite real numbers
NUMERIC_INFO = tuple(k for k in INFO_KEYS if k not in ("packet_received", "alpha"))
HEALTHY = (0.2, 0.2, 0.6)  # tracks to ~0.5 m for a whole mission
UNSTABLE = (0.98, 0.0, 0.02)  # no control share: every command is lost, the drone drifts away
N_SLOTS = 5000  # T_m / dt = 500 s / 0.1 s
ACTION_SPACE = gym.spaces.Box(-1.0, 1.0, (3,), np.float32)  # the documented space (checked below)


# --- helpers --------------------------------------------------------------------------------------


def make(**kwargs):
    return gym.make(ENV_ID, **kwargs)


def actions(seed, n, low=-1.0, high=1.0):
    """n actions drawn in advance, float32 like ``action_space.sample()``."""
    return np.random.default_rng(seed).uniform(low, high, (n, 3)).astype(np.float32)


def assert_valid_split(alpha, atol=1e-12):
    alpha = np.asarray(alpha)
    assert alpha.shape[-1] == 3
    assert np.all(np.isfinite(alpha))
    assert np.all(alpha >= 0.0), alpha
    np.testing.assert_allclose(alpha.sum(axis=-1), 1.0, rtol=0, atol=atol)


def assert_obs_ok(env, obs):
    space = env.observation_space
    assert isinstance(obs, np.ndarray)
    assert obs.dtype == np.float32
    assert obs.shape == space.shape == (23,)
    assert np.all(np.isfinite(obs)), obs
    assert space.contains(obs), obs


def assert_info_ok(env, info):
    missing = set(INFO_KEYS) - set(info)
    assert not missing, f"info lacks {sorted(missing)}"
    for k in NUMERIC_INFO:
        v = info[k]
        assert isinstance(v, (float, int, np.floating, np.integer)) and not isinstance(v, bool), (k, v)
        assert math.isfinite(v), (k, v)
    assert isinstance(info["packet_received"], (bool, np.bool_))
    assert_valid_split(info["alpha"])
    assert info["alpha"].shape == (3,)
    for k in ("cost_rate", "cost_stability", "cost", "tracking_error_m", "peb_m", "veb_mps",
              "estimation_error_m", "rate_comm_bps", "rate_ctrl_bps"):
        assert info[k] >= 0.0, (k, info[k])
    assert 0.0 <= info["eps_ctrl"] <= 1.0
    assert 0.0 <= info["cost_rate"] <= 1.0
    assert info["cost_stability"] in (0.0, 1.0)
    assert info["cost"] == info["cost_rate"] + info["cost_stability"]
    # the stability cost is the indicator of eps_ctrl above the scenario's eps*
    assert info["cost_stability"] == float(info["eps_ctrl"] > env.unwrapped.eps_star)


def assert_info_equal(a, b, skip=()):
    assert set(a) - set(skip) == set(b) - set(skip)
    for k in set(a) - set(skip):
        va, vb = a[k], b[k]
        if isinstance(va, np.ndarray) or isinstance(vb, np.ndarray):
            np.testing.assert_array_equal(va, vb, err_msg=k)
            assert np.asarray(va).dtype == np.asarray(vb).dtype, k
        elif isinstance(va, dict):
            assert_info_equal(va, vb)
        else:
            same = va == vb or (isinstance(va, float) and math.isnan(va) and math.isnan(vb))  # reset: NaN outcomes
            assert type(va) is type(vb) and same, (k, va, vb)


def assert_same_step(r1, r2, skip_info=()):
    o1, rew1, te1, tr1, i1 = r1
    o2, rew2, te2, tr2, i2 = r2
    np.testing.assert_array_equal(o1, o2)
    assert o1.dtype == o2.dtype
    assert rew1 == rew2
    assert (te1, tr1) == (te2, tr2)
    assert_info_equal(i1, i2, skip=skip_info)


def time_limit(env):
    e = env
    while not isinstance(e, gym.wrappers.TimeLimit):
        e = e.env
    return e


def snapshot(env):
    """Copies of everything a step may change: loop state, last outcome, generator, step counts."""
    u = env.unwrapped
    snap = {name: np.array(getattr(u._state, name), copy=True) for name in u._state._fields}
    snap["last_received"] = copy.deepcopy(u._last_received)
    snap["last_peb"] = copy.deepcopy(u._last_peb)
    snap["rng"] = copy.deepcopy(u.np_random.bit_generator.state)
    snap["elapsed"] = time_limit(env)._elapsed_steps
    return snap


def assert_snapshot_equal(a, b):
    assert a.keys() == b.keys()
    for k in a:
        if isinstance(a[k], np.ndarray):
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)
        else:
            assert a[k] == b[k], k


def run_held_split(env, split, seed, check=True):
    """Hold ``split`` until the episode ends; return the last step and the number of steps."""
    env.reset(seed=seed)
    a = split_to_action(split)
    for n in range(1, N_SLOTS + 1):
        out = env.step(a)
        obs, reward, terminated, truncated, info = out
        if check:
            assert_obs_ok(env, obs)
            assert math.isfinite(reward)
            assert_info_ok(env, info)
        if terminated or truncated:
            return out, n
    raise AssertionError("the episode neither terminated nor truncated within the mission")


# --- env checkers ---------------------------------------------------------------------------------


@pytest.mark.parametrize("render_mode", [None, "rgb_array", "human"])
def test_gymnasium_check_env_passes_without_warnings(render_mode):
    env = make(render_mode=render_mode)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gym_check_env(env.unwrapped, skip_render_check=render_mode is None)
    assert [str(w.message) for w in caught] == []


def test_sb3_check_env_passes_without_warnings():
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sb3_check_env(make(), warn=True)
        sb3_check_env(make().unwrapped, warn=True)
        sb3_check_env(make(scenario="literal", observation_source="gnss"), warn=True)
    assert [str(w.message) for w in caught] == []


# --- registration and make ------------------------------------------------------------------------


def test_registered_with_mission_horizon():
    assert iscc_gym.ENV_ID == "iscc_gym/ISCC-v0"
    assert gym.spec(ENV_ID).max_episode_steps == N_SLOTS == SCENARIOS["paper"].n_slots
    env = make()
    assert env.spec.max_episode_steps == N_SLOTS
    assert time_limit(env)._max_episode_steps == N_SLOTS
    assert isinstance(env.unwrapped, ISCCEnv)


@pytest.mark.parametrize("name", ["paper", "literal"])
def test_make_preset_by_name(name):
    assert make(scenario=name).unwrapped.scenario == SCENARIOS[name]


def test_make_default_is_paper():
    assert make().unwrapped.scenario == SCENARIOS["paper"] == Scenario()


def test_make_scenario_instance_and_overrides():
    custom = SCENARIOS["literal"].replace(w_rate=3.0)
    assert make(scenario=custom).unwrapped.scenario == custom
    s = make(scenario=custom, w_stab=7.0, observation_source="gnss").unwrapped.scenario
    assert s == custom.replace(w_stab=7.0, observation_source="gnss")
    assert (s.w_rate, s.w_stab, s.observation_source) == (3.0, 7.0, "gnss")
    s = make(scenario="paper", control_mode="open_loop", reference_feedforward=True).unwrapped.scenario
    assert s == SCENARIOS["paper"].replace(control_mode="open_loop", reference_feedforward=True)


def test_make_unknown_keyword_raises():
    with pytest.raises(TypeError, match="not_a_field"):
        make(not_a_field=1.0)
    with pytest.raises(TypeError, match="sceanrio"):
        make(sceanrio="paper")  # a typo of a real argument is not silently ignored


def test_make_unknown_preset_raises():
    with pytest.raises(ValueError, match="bogus"):
        make(scenario="bogus")


@pytest.mark.parametrize("field, bad", [
    ("gnss_pos_std_m", -3.0),        # negative standard deviation
    ("process_noise_pos", -1e-4),    # negative variance
    ("ctrl_target_bler", 1.5),       # probability outside [0, 1]
    ("ctrl_blocklength", 0),         # zero blocklength
    ("lqg_q_pos", 0.0),              # undetectable position: no stabilising LQG gain
])
def test_make_bad_scenario_raises_naming_the_field(field, bad):
    with pytest.raises(ValueError, match=field):
        make(**{field: bad})


def test_time_limit_of_an_overridden_mission_length():
    """gymnasium.make applies the registered TimeLimit (5000); a longer mission warns and tells the fix,
    and the fix (max_episode_steps) truncates at the mission's end."""
    with pytest.warns(UserWarning, match="max_episode_steps=6000"):
        env = make(mission_duration_s=600.0)
    assert env.spec.max_episode_steps == 5000
    with pytest.warns(UserWarning, match="max_episode_steps=6000"):
        env = gym.make(ENV_ID, mission_duration_s=600.0, max_episode_steps=6000)
    assert env.unwrapped.scenario.n_slots == 6000 and env.spec.max_episode_steps == 6000


# --- action map -----------------------------------------------------------------------------------


def test_any_in_space_action_gives_a_valid_split():
    space = make().action_space
    assert space == ACTION_SPACE
    space.seed(0)
    corners = np.array(np.meshgrid(*[[-1.0, 0.0, 1.0]] * 3)).reshape(3, -1).T.astype(np.float32)
    batch = np.concatenate([np.stack([space.sample() for _ in range(2000)]), corners])
    alpha = action_to_split(batch)
    assert alpha.shape == batch.shape
    assert_valid_split(alpha)
    # one action at a time agrees with the batch
    for a, al in zip(batch[::50], alpha[::50], strict=True):
        np.testing.assert_array_equal(action_to_split(a), al)
    # all weights zero: the documented equal split
    np.testing.assert_allclose(action_to_split(np.full(3, -1.0, np.float32)), np.full(3, 1 / 3), rtol=1e-15)


@st.composite
def splits(draw):
    """A split (non-negative, sums to 1) with exact zero shares and tiny shares included."""
    share = st.one_of(st.just(0.0), st.floats(1e-12, 1.0), st.floats(0.0, 1e-6), st.just(1.0))
    w = np.array([draw(share) for _ in range(3)])
    if w.sum() == 0.0:
        w[draw(st.integers(0, 2))] = 1.0
    return w / w.sum()


@settings(max_examples=300, deadline=None)
@given(splits())
def test_split_to_action_round_trip(alpha):
    assert_valid_split(alpha)
    action = split_to_action(alpha)
    assert action.shape == (3,) and action.dtype == np.float32
    assert ACTION_SPACE.contains(action), action
    back = action_to_split(action)
    assert_valid_split(back)
    np.testing.assert_allclose(back, alpha, rtol=0, atol=1e-6)
    assert np.all(back[alpha == 0.0] == 0.0)  # zero shares are reachable exactly
    assert action.max() == 1.0


def test_split_to_action_batched_and_rejects_non_splits():
    alphas = np.array([[1.0, 0.0, 0.0], [0.0, 0.5, 0.5], [0.2, 0.2, 0.6], HEALTHY, UNSTABLE])
    np.testing.assert_allclose(action_to_split(split_to_action(alphas)), alphas, atol=1e-7)
    for bad in ([0.5, 0.5, 0.5], [-0.1, 0.6, 0.5], [np.nan, 0.5, 0.5], [0.0, 0.0, 0.0]):
        with pytest.raises(ValueError):
            split_to_action(bad)


def test_info_alpha_is_the_applied_split():
    env = make()
    env.reset(seed=0)
    for a in np.concatenate([actions(1, 20), [split_to_action(HEALTHY), split_to_action(UNSTABLE)]]):
        info = env.step(a)[4]
        np.testing.assert_array_equal(info["alpha"], action_to_split(a))
    np.testing.assert_allclose(info["alpha"], UNSTABLE, atol=1e-7)


# --- invalid actions ------------------------------------------------------------------------------


BAD_VALUES = {
    "nan": [np.nan, 0.0, 0.0],
    "inf": [0.0, np.inf, 0.0],
    "-inf": [0.0, 0.0, -np.inf],
    "all-nan": [np.nan, np.nan, np.nan],
    "nan-out-of-range": [5.0, np.nan, -5.0],
}


@pytest.mark.parametrize("warmup", [0, 7])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("bad", list(BAD_VALUES), ids=list(BAD_VALUES))
def test_non_finite_action_raises_and_leaves_env_unchanged(bad, dtype, warmup):
    env, twin = make(), make()
    acts = actions(3, warmup + 5)
    for e in (env, twin):
        e.reset(seed=42)
        for a in acts[:warmup]:
            e.step(a)
    before = snapshot(env)
    with pytest.raises(ValueError, match=r"(?i)action.*(nan|inf)"):
        env.step(np.array(BAD_VALUES[bad], dtype=dtype))
    assert_snapshot_equal(snapshot(env), before)
    # and the episode continues exactly as if the bad call never happened
    for a in acts[warmup:]:
        assert_same_step(env.step(a), twin.step(a))


@pytest.mark.parametrize("shape", [(), (2,), (4,), (1, 3), (3, 1), (2, 3), (0,)])
def test_wrong_shape_action_raises_and_leaves_env_unchanged(shape):
    env, twin = make(), make()
    for e in (env, twin):
        e.reset(seed=1)
        e.step(np.zeros(3, np.float32))
    before = snapshot(env)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(shape, np.float32))
    assert_snapshot_equal(snapshot(env), before)
    for a in actions(1, 5):
        assert_same_step(env.step(a), twin.step(a))


@pytest.mark.parametrize("low, high", [(-5.0, 5.0), (-1e30, 1e30), (1.0, 3.0), (-3.0, -1.0)])
def test_out_of_range_action_behaves_like_the_clipped_one(low, high):
    raw = actions(4, 15, low, high)
    raw[0] = [1.0 + 1e-6, -1.0 - 1e-6, 0.5]  # just outside the box
    raw[1] = [-7.0, -7.0, -7.0]  # clipped to all -1: the equal split
    env, clipped = make(), make()
    env.reset(seed=9)
    clipped.reset(seed=9)
    for a in raw:
        r_raw = env.step(a)
        r_clip = clipped.step(np.clip(a, -1.0, 1.0))
        # info["action"] (if present) echoes the action as passed; everything else must agree
        assert_same_step(r_raw, r_clip, skip_info=("action",))
        assert_valid_split(r_raw[4]["alpha"])
        np.testing.assert_array_equal(r_raw[4]["alpha"], action_to_split(a))  # the public map clips too
    assert_snapshot_equal(snapshot(env), snapshot(clipped))


def test_list_and_float64_actions_accepted():
    env, twin = make(), make()
    env.reset(seed=2)
    twin.reset(seed=2)
    assert_same_step(env.step([0.5, -0.25, 1.0]), twin.step(np.array([0.5, -0.25, 1.0], np.float32)))
    assert_same_step(env.step(np.array([0.1, 0.2, 0.3])), twin.step([0.1, 0.2, 0.3]))
    assert_same_step(env.step((1, 0, -1)), twin.step(np.array([1.0, 0.0, -1.0], np.float32)))


# --- API order ------------------------------------------------------------------------------------


def test_step_before_reset_raises_clear_error():
    with pytest.raises(RuntimeError, match="reset"):
        ISCCEnv().step(np.zeros(3, np.float32))
    with pytest.raises((RuntimeError, gym.error.ResetNeeded), match="reset"):
        make().step(np.zeros(3, np.float32))


@pytest.fixture(scope="module")
def full_episode():
    """One whole mission with random actions through make + SafetyCostWrapper (the only full run
    on a healthy allocation; several tests read it)."""
    env = SafetyCostWrapper(make())
    out = env.reset(seed=2024)
    assert len(out) == 2
    obs0, info0 = out
    acts = actions(2024, N_SLOTS + 1)
    steps = []
    for a in acts[:N_SLOTS]:
        r = env.step(a)
        steps.append(r)
        if r[3] or r[4]:
            break
    return {"env": env, "obs0": obs0, "info0": info0, "steps": steps, "next_action": acts[-1]}


def test_full_episode_truncates_at_the_horizon(full_episode):
    steps = full_episode["steps"]
    assert len(steps) == N_SLOTS
    assert not any(r[3] for r in steps), "a healthy random allocation lost track"
    assert [r[4] for r in steps] == [False] * (N_SLOTS - 1) + [True]
    assert steps[-1][5]["slot"] == N_SLOTS
    assert steps[-1][0][-1] == 0.0  # no time left
    assert full_episode["obs0"][-1] == 1.0


def test_step_after_truncation_without_reset_raises(full_episode):
    env = full_episode["env"]
    before = snapshot(env)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(full_episode["next_action"])
    assert_snapshot_equal(snapshot(env), before)
    obs, _ = env.reset(seed=1)  # reset revives it
    assert_obs_ok(env, obs)
    assert len(env.step(full_episode["next_action"])) == 6


def test_full_episode_observations_in_space(full_episode):
    env = full_episode["env"]
    assert_obs_ok(env, full_episode["obs0"])
    obs = np.stack([r[0] for r in full_episode["steps"]])
    assert obs.dtype == np.float32 and obs.shape == (N_SLOTS, 23)
    assert np.all(np.isfinite(obs))
    assert np.all(obs >= env.observation_space.low) and np.all(obs <= env.observation_space.high)
    for o in obs[::97]:
        assert env.observation_space.contains(o)


def test_full_episode_costs_and_six_tuple(full_episode):
    env = full_episode["env"]
    w_rate, w_stab = env.unwrapped.scenario.w_rate, env.unwrapped.scenario.w_stab
    costs = []
    for r in full_episode["steps"]:
        assert len(r) == 6
        obs, reward, cost, terminated, truncated, info = r
        assert isinstance(cost, float) and cost == info["cost"]
        assert math.isfinite(cost) and cost >= 0.0
        assert_info_ok(env, info)
        # documented reward: -(tracking error) - w_rate * shortfall - w_stab * violation
        assert reward == pytest.approx(-info["tracking_error_m"] - w_rate * info["cost_rate"]
                                       - w_stab * info["cost_stability"], rel=1e-12, abs=1e-12)
        costs.append(cost)
    costs = np.array(costs)
    parts = np.array([[r[5]["cost_rate"], r[5]["cost_stability"]] for r in full_episode["steps"]])
    assert math.fsum(costs) == pytest.approx(math.fsum(parts.ravel()), rel=1e-12)
    assert 0 < np.count_nonzero(parts[:, 0]) < N_SLOTS  # random splits: some shortfall, not always
    assert np.count_nonzero(parts[:, 1]) > 0


def test_safety_wrapper_reset_and_episode_cost_with_termination():
    env = SafetyCostWrapper(make())
    obs, info = env.reset(seed=4)
    assert_obs_ok(env, obs)
    total, parts = 0.0, 0.0
    a = split_to_action(UNSTABLE)
    for _ in range(N_SLOTS):
        obs, reward, cost, terminated, truncated, info = env.step(a)
        total += cost
        parts += info["cost_rate"] + info["cost_stability"]
        assert 0.0 <= cost <= 2.0  # the termination penalty goes to the reward, not the cost
        if terminated or truncated:
            break
    assert terminated and not truncated
    assert total == pytest.approx(parts, rel=1e-12) and total > 0


# --- seeding --------------------------------------------------------------------------------------


def test_reset_with_seed_is_bit_reproducible():
    env, other = make(), make()
    obs1, info1 = env.reset(seed=123)
    s1 = snapshot(env)
    for a in actions(0, 5):
        env.step(a)
    obs2, info2 = env.reset(seed=123)
    obs3, info3 = other.reset(seed=123)
    for obs, info in ((obs2, info2), (obs3, info3)):
        np.testing.assert_array_equal(obs, obs1)
        assert_info_equal(info, info1)
    s2, s3 = snapshot(env), snapshot(other)
    for s in (s1, s2, s3):
        s.pop("elapsed")
    assert_snapshot_equal(s2, s1)
    assert_snapshot_equal(s3, s1)
    # the reseeded env continues exactly like a fresh one (no leftover draws from before)
    for a in actions(1, 30):
        assert_same_step(env.step(a), other.step(a))


def test_same_seed_same_actions_equal_for_1000_steps():
    env_a, env_b = make(), make()
    r_a, r_b = env_a.reset(seed=77), env_b.reset(seed=77)
    np.testing.assert_array_equal(r_a[0], r_b[0])
    assert_info_equal(r_a[1], r_b[1])
    for k, a in enumerate(actions(77, 1000)):
        # all randomness from the env's generator: the global numpy RNG does not matter
        np.random.seed(k)  # noqa: NPY002
        r_a = env_a.step(a)
        np.random.seed(10_000 + k)  # noqa: NPY002
        r_b = env_b.step(a)
        assert_same_step(r_a, r_b)
        assert set(INFO_KEYS) <= set(r_a[4])
        if r_a[2] or r_a[3]:
            r_a, r_b = env_a.reset(), env_b.reset()
            np.testing.assert_array_equal(r_a[0], r_b[0])
    assert_snapshot_equal(snapshot(env_a), snapshot(env_b))


def test_different_seed_gives_different_draws():
    env_a, env_b = make(), make()
    obs_a, _ = env_a.reset(seed=0)
    obs_b, _ = env_b.reset(seed=1)
    assert not np.array_equal(obs_a, obs_b)
    a = split_to_action(HEALTHY)
    for _ in range(10):
        ra, rb = env_a.step(a), env_b.step(a)
        assert not np.array_equal(ra[0], rb[0])
        assert ra[4]["tracking_error_m"] != rb[4]["tracking_error_m"]
        assert ra[4]["snr_db"] != rb[4]["snr_db"]


def test_each_reset_draws_a_new_trajectory():
    env = make()
    obs, refs = [], []
    obs.append(env.reset(seed=5)[0])
    refs.append(env.unwrapped._state.ref.copy())
    for _ in range(3):
        env.step(split_to_action(HEALTHY))
        obs.append(env.reset()[0])
        refs.append(env.unwrapped._state.ref.copy())
    for i in range(len(refs)):
        for j in range(i):
            assert not np.array_equal(refs[i], refs[j]), (i, j)
            assert not np.array_equal(obs[i], obs[j]), (i, j)
    # ...and the sequence of trajectories is itself reproducible from the first seed
    twin = make()
    twin.reset(seed=5)
    twin.step(split_to_action(HEALTHY))
    np.testing.assert_array_equal(twin.reset()[0], obs[1])
    np.testing.assert_array_equal(twin.unwrapped._state.ref, refs[1])


# --- divergence -----------------------------------------------------------------------------------


@pytest.mark.parametrize("scenario, split", [
    ("paper", UNSTABLE),
    ("paper", (1.0, 0.0, 0.0)),
    ("paper", (0.0, 0.0, 1.0)),
    ("literal", (1 / 3, 1 / 3, 1 / 3)),  # the literal radar sees almost nothing: the estimate drifts
], ids=["paper-0.98-0-0.02", "paper-sense-only", "paper-data-only", "literal-equal"])
def test_unstable_split_terminates_with_finite_values(scenario, split):
    env = make(scenario=scenario)
    s = env.unwrapped.scenario
    with np.errstate(all="raise"), warnings.catch_warnings():
        warnings.simplefilter("error")
        (obs, reward, terminated, truncated, info), n = run_held_split(env, split, seed=3)
    assert terminated is True and truncated is False, "divergence must terminate, not truncate"
    assert n < N_SLOTS
    assert info["tracking_error_m"] > s.max_tracking_error_m
    assert_obs_ok(env, obs)
    assert math.isfinite(reward)
    # documented penalty: the bound for every remaining slot, on top of the capped slot error
    expected = (-s.max_tracking_error_m - s.w_rate * info["cost_rate"] - s.w_stab * info["cost_stability"]
                - s.max_tracking_error_m * (s.n_slots - n))
    assert reward == pytest.approx(expected, rel=1e-12)
    if scenario == "paper":  # a good estimate sees the divergence: error entries far out, in the box
        assert np.max(np.abs(obs[:3])) > 5.0


def test_unstable_split_terminates_with_finite_values_numpy_path():
    env = make(scenario="literal", beamforming="broadside")
    s = env.unwrapped.scenario
    with np.errstate(all="raise"), warnings.catch_warnings():
        warnings.simplefilter("error")
        (obs, reward, terminated, truncated, info), n = run_held_split(env, (1 / 3, 1 / 3, 1 / 3), seed=1)
    assert terminated is True and truncated is False
    assert info["tracking_error_m"] > s.max_tracking_error_m
    assert_obs_ok(env, obs)
    assert math.isfinite(reward)


def _below_ground(env, z=-1592.0, shadow=-1.0):
    """Put the drone and its estimate ``-z`` m below the ground with a negative shadowing state: the
    shadowing std a exp(-b z) there is ~1.7e5 dB, so the SNR overflows (issue 12's NaN observation)."""
    st = env.unwrapped._state
    x, x_hat = st.x.copy(), st.x_hat.copy()
    x[0, 2] = x_hat[0, 2] = z
    env.unwrapped._state = st._replace(x=x, x_hat=x_hat, shadow=np.full_like(st.shadow, shadow))


@pytest.mark.parametrize("beamforming", ["matched", "broadside"], ids=["kernel", "numpy"])
def test_state_the_model_cannot_evaluate_ends_the_episode_with_finite_values(beamforming):
    """Far outside the region (lifted loss-of-track bound, drone 1.6 km below ground) the SNR
    overflows and the filter's update is NaN: the observation is still finite and in the box (NaN
    entries read 0), the reward finite, and the episode ends as a loss of track."""
    env = make(max_tracking_error_m=1e12, beamforming=beamforming)
    s = env.unwrapped.scenario
    env.reset(seed=0)
    _below_ground(env)
    with np.errstate(all="ignore"):  # the numpy path meets the overflow itself
        obs, reward, terminated, truncated, info = env.step(np.zeros(3, np.float32))
    assert_obs_ok(env, obs)
    assert math.isfinite(reward)
    assert terminated is True and truncated is False
    # the tracking error is below the lifted bound: the episode ends because the estimate is lost
    assert info["tracking_error_m"] < s.max_tracking_error_m
    # a NaN rate and loss probability count as violations; the loss-of-track penalty applies
    assert info["cost_rate"] == 1.0 and info["cost_stability"] == 1.0
    expected = (-info["tracking_error_m"] - s.w_rate - s.w_stab - s.max_tracking_error_m * (s.n_slots - 1))
    assert reward == pytest.approx(expected, rel=1e-12)


def test_largest_initial_velocity_error_stays_finite_at_the_terminal_step():
    env = make(initial_vel_std_mps=1e3, mission_duration_s=1.0)  # the validator's upper bound
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        assert_obs_ok(env, obs)
        done = False
        while not done:
            obs, reward, terminated, truncated, _ = env.step(env.action_space.sample())
            assert_obs_ok(env, obs)
            assert math.isfinite(reward)
            done = terminated or truncated


def test_step_after_termination_without_reset_raises():
    """Issue 12: a terminated episode must not keep going (and charge the penalty again)."""
    env = make()
    (_, reward, terminated, _, _), n = run_held_split(env, UNSTABLE, seed=3)
    assert terminated and n < N_SLOTS
    before = snapshot(env)
    for _ in range(2):
        with pytest.raises(RuntimeError, match="terminated.*reset"):
            env.step(split_to_action(HEALTHY))
    assert_snapshot_equal(snapshot(env), before)
    obs, _ = env.reset(seed=3)  # reset revives it
    assert_obs_ok(env, obs)
    assert len(env.step(split_to_action(HEALTHY))) == 5


@pytest.mark.parametrize("bad,error", [
    (1.5, TypeError), ("7", TypeError), (True, TypeError), ([7], TypeError), (-1, ValueError),
])
def test_reset_rejects_bad_seeds_and_leaves_env_unchanged(bad, error):
    env = make()
    env.reset(seed=0)
    env.step(split_to_action(HEALTHY))
    before = snapshot(env)
    with pytest.raises(error, match="seed"):
        env.reset(seed=bad)
    after = snapshot(env)
    # (Gymnasium's TimeLimit zeroes its step count before it calls the env's reset: not the env's state)
    before.pop("elapsed"), after.pop("elapsed")
    assert_snapshot_equal(after, before)
    assert len(env.step(split_to_action(HEALTHY))) == 5  # the episode goes on
    a, _ = env.reset(seed=np.int64(4))  # numpy integers are seeds too
    b, _ = make().reset(seed=4)
    assert np.array_equal(a, b)


def test_reset_returns_for_scenarios_with_a_rare_waypoint_condition():
    """Issue 12: these passed validation and reset never returned (an unbounded Poisson redraw)."""
    import signal

    def fail(*_):
        raise TimeoutError("reset did not return within 20 s")

    old = signal.signal(signal.SIGALRM, fail)
    signal.setitimer(signal.ITIMER_REAL, 20.0)
    try:
        for overrides in ({"waypoint_intensity_per_km3": 0.01}, {"altitude_max_m": 100.001}):
            env = make(**overrides)
            obs, _ = env.reset(seed=0)
            assert_obs_ok(env, obs)
            assert len(env.unwrapped._state.ref[0]) == env.unwrapped.scenario.n_slots + 1
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def test_max_episode_steps_shortens_the_episode_not_the_flight():
    """Issue 12 item 9: ``mission_duration_s`` sets the length of the flight (the whole tour in T_m,
    so a shorter mission flies faster); ``max_episode_steps`` ends the episode early on the same flight."""
    full, short = make(), make(max_episode_steps=20)
    o1, _ = full.reset(seed=5)
    o2, _ = short.reset(seed=5)
    np.testing.assert_array_equal(full.unwrapped._state.ref, short.unwrapped._state.ref)
    a = split_to_action(HEALTHY)
    for k in range(20):
        r1, r2 = full.step(a), short.step(a)
        np.testing.assert_array_equal(r1[0], r2[0])
        assert r2[3] == (k == 19) and not r1[3]
    # the squeezed mission: same waypoints, a tenth of the time: ten times the speed
    fast = make(mission_duration_s=50.0)
    fast.reset(seed=5)
    speed = [np.linalg.norm(e.unwrapped._state.ref[0, :, 3:6], axis=1).mean() for e in (full, fast)]
    assert speed[1] / speed[0] == pytest.approx(10.0, rel=0.05)


# --- info -----------------------------------------------------------------------------------------


def test_info_carries_the_documented_keys():
    env = make()
    _, info = env.reset(seed=0)
    assert_valid_split(info["alpha"])
    for a in actions(6, 30):
        obs, reward, terminated, truncated, info = env.step(a)
        assert_info_ok(env, info)
        assert isinstance(reward, float) and isinstance(terminated, bool) and isinstance(truncated, bool)


# --- pickle / deepcopy ----------------------------------------------------------------------------


COPIERS = {"pickle": lambda e: pickle.loads(pickle.dumps(e)), "deepcopy": copy.deepcopy}


@pytest.mark.parametrize("unwrapped", [False, True], ids=["made", "unwrapped"])
@pytest.mark.parametrize("how", list(COPIERS))
def test_copy_mid_episode_continues_identically(how, unwrapped):
    env = make()
    env.reset(seed=31)
    acts = actions(31, 70)
    for a in acts[:20]:
        env.step(a)
    if unwrapped:
        env = env.unwrapped
    clone = COPIERS[how](env)
    assert clone is not env and clone.unwrapped._state is not env.unwrapped._state
    # interleaved: a shared generator or shared arrays would make the two runs drift apart
    for a in acts[20:]:
        assert_same_step(env.step(a), clone.step(a))


# --- vector envs ----------------------------------------------------------------------------------


def test_dummy_and_subproc_vec_env_agree():
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    fns = [make, lambda: make(scenario="literal", observation_source="gnss")]
    dummy = DummyVecEnv(fns)
    sub = SubprocVecEnv(fns, start_method="fork")
    single = make()
    try:
        dummy.seed(17)
        sub.seed(17)
        obs_d, obs_s = dummy.reset(), sub.reset()
        np.testing.assert_array_equal(obs_d, obs_s)
        np.testing.assert_array_equal(obs_d[0], single.reset(seed=17)[0])
        acts = np.stack([actions(17, 30), actions(18, 30)], axis=1)
        for a in acts:
            od, rd, dd, id_ = dummy.step(a)
            os_, rs, ds, is_ = sub.step(a)
            np.testing.assert_array_equal(od, os_)
            assert od.dtype == os_.dtype == np.float32
            # DummyVecEnv keeps rewards in a float32 buffer, SubprocVecEnv stacks python floats
            np.testing.assert_array_equal(rd, np.asarray(rs, dtype=rd.dtype))
            np.testing.assert_array_equal(dd, ds)
            for i_d, i_s in zip(id_, is_, strict=True):
                assert_info_equal(i_d, i_s)
            # and the vector env reproduces the plain env
            o1, r1, _, _, info1 = single.step(a[0])
            np.testing.assert_array_equal(od[0], o1)
            assert rd[0] == np.float32(r1)
            assert_info_equal(id_[0], info1, skip=("TimeLimit.truncated",))
    finally:
        sub.close()
        dummy.close()


# --- comparison schemes ---------------------------------------------------------------------------


def _rollout(n, seed, split=HEALTHY, **overrides):
    env = make(**overrides)
    env.reset(seed=seed)
    a = split_to_action(split)
    infos = []
    for _ in range(n):
        obs, reward, terminated, truncated, info = env.step(a)
        assert_obs_ok(env, obs)
        assert math.isfinite(reward)
        assert_info_ok(env, info)
        assert not terminated and not truncated
        infos.append(info)
    return infos


@pytest.mark.parametrize("overrides", [
    {"observation_source": "gnss"},
    {"control_mode": "open_loop"},
    {"observation_source": "gnss", "control_mode": "open_loop"},
    {"scenario": "literal", "observation_source": "gnss"},
], ids=["gnss", "open_loop", "gnss+open_loop", "literal+gnss"])
def test_schemes_run_with_finite_values(overrides):
    infos = _rollout(200, 8, **overrides)
    assert max(i["tracking_error_m"] for i in infos) < 50.0


def test_gnss_estimate_is_worse_than_isac():
    isac = _rollout(200, 8)
    gnss = _rollout(200, 8, observation_source="gnss")
    err_isac = np.mean([i["estimation_error_m"] for i in isac])
    err_gnss = np.mean([i["estimation_error_m"] for i in gnss])
    assert err_gnss > 3.0 * err_isac  # 3 m GNSS fixes vs ~0.1 m radar


def test_open_loop_ignores_the_link():
    a = _rollout(100, 8, split=(0.2, 0.2, 0.6), control_mode="open_loop")
    b = _rollout(100, 8, split=(0.9, 0.0, 0.1), control_mode="open_loop")
    assert all(i["packet_received"] for i in a + b)
    # nothing is sent, so the trajectory does not depend on the control share
    np.testing.assert_allclose([i["tracking_error_m"] for i in a], [i["tracking_error_m"] for i in b],
                               rtol=1e-9)


# --- rendering ------------------------------------------------------------------------------------


def test_render_rgb_array():
    env = make(render_mode="rgb_array")
    env.reset(seed=0)
    for a in actions(0, 5):
        env.step(a)
    img = env.render()
    assert isinstance(img, np.ndarray) and img.dtype == np.uint8
    assert img.ndim == 3 and img.shape[2] == 3 and img.shape[0] > 50 and img.shape[1] > 50
    assert img.std() > 0  # not a blank canvas
    env.close()


def test_render_none_and_before_reset():
    assert ISCCEnv().render() is None
    with pytest.raises(RuntimeError, match="reset"):
        ISCCEnv(render_mode="rgb_array").render()


@pytest.mark.parametrize("mode", ["rgb", "ansi", "", "RGB_ARRAY", "HUMAN"])
def test_invalid_render_mode_raises(mode):
    with pytest.raises(ValueError, match="render_mode"):
        ISCCEnv(render_mode=mode)
    if mode == "human":  # gymnasium.make itself maps "human" onto rgb_array + HumanRendering
        return
    with pytest.warns(UserWarning, match="render_modes"), pytest.raises(ValueError, match="render_mode"):
        make(render_mode=mode)


# --- saving an agent ------------------------------------------------------------------------------


def test_saved_agent_and_vecnormalize_reload_identically(tmp_path):
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    venv = VecNormalize(DummyVecEnv([make]))
    venv.seed(0)
    model = PPO("MlpPolicy", venv, n_steps=32, batch_size=32, n_epochs=1, seed=0, device="cpu",
                policy_kwargs={"net_arch": [16]})
    model.learn(64)
    model.save(tmp_path / "agent")
    venv.save(tmp_path / "vecnormalize.pkl")
    model2 = PPO.load(tmp_path / "agent", device="cpu")
    venv2 = VecNormalize.load(tmp_path / "vecnormalize.pkl", DummyVecEnv([make]))
    for attr in ("mean", "var", "count"):
        np.testing.assert_array_equal(getattr(venv2.obs_rms, attr), getattr(venv.obs_rms, attr))
        np.testing.assert_array_equal(getattr(venv2.ret_rms, attr), getattr(venv.ret_rms, attr))
    assert venv.obs_rms.count > 1  # the statistics were actually updated
    raw = np.random.default_rng(1).uniform(-3, 3, (32, 23)).astype(np.float32)
    np.testing.assert_array_equal(venv2.normalize_obs(raw), venv.normalize_obs(raw))
    obs = venv.normalize_obs(raw)
    np.testing.assert_array_equal(model2.predict(obs, deterministic=True)[0],
                                  model.predict(obs, deterministic=True)[0])


# --- property test over random action sequences ---------------------------------------------------


_action_element = st.one_of(
    st.floats(-1.0, 1.0, width=32),
    st.sampled_from([-1.0, 0.0, 1.0]),
    st.floats(-1e3, 1e3, width=32),  # finite but out of range: clipped
)


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), acts=hnp.arrays(np.float32, (20, 3), elements=_action_element),
       scenario=st.sampled_from(["paper", "literal"]))
def test_random_action_sequences(seed, acts, scenario):
    env = make(scenario=scenario)
    obs, info = env.reset(seed=seed)
    assert_obs_ok(env, obs)
    for a in acts:
        obs, reward, terminated, truncated, info = env.step(a)
        assert_obs_ok(env, obs)
        assert isinstance(reward, float) and math.isfinite(reward)
        assert_info_ok(env, info)
        np.testing.assert_array_equal(info["alpha"], action_to_split(a))
        np.testing.assert_array_equal(action_to_split(a), action_to_split(np.clip(a, -1.0, 1.0)))
        # the filter's covariance stays symmetric positive semi-definite
        p = np.asarray(env.unwrapped._state.p).reshape(-1, 6, 6)
        np.testing.assert_array_equal(p, np.swapaxes(p, -1, -2))
        assert np.all(np.linalg.eigvalsh(p) >= -1e-12 * np.abs(p).max())
        if terminated or truncated:
            break


def test_decode_observation_inverts_the_scalings():
    """decode_observation gives the physical values the observation was built from (issue 14)."""
    from iscc_gym.physics.stability import scenario_eps_star
    from iscc_gym.sim import loop
    from iscc_gym.sim.functional import decode_observation

    env = gym.make(iscc_gym.ENV_ID)
    obs, _ = env.reset(seed=3)
    for _ in range(20):
        obs, *_ = env.step(np.array([0.2, 0.5, -0.1], np.float32))
    inner = env.unwrapped
    s, state = inner.scenario, inner._state
    d = decode_observation(obs, s)
    ref = loop.reference_at(state)[0]
    pv = preview(s, state, scenario_eps_star(s))
    np.testing.assert_allclose(d["pos_err_m"], state.x_hat[0, :3] - ref[:3], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(d["ref_vel_mps"], ref[3:6], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(d["range_m"], pv["dist_m"][0], rtol=1e-5)
    np.testing.assert_allclose(d["snr_db"], pv["snr_db"][0], rtol=1e-5)
    np.testing.assert_allclose(d["alpha_ctrl_min"], pv["alpha_ctrl_min"][0], rtol=1e-5)
    np.testing.assert_allclose(d["last_peb_m"], inner._last_peb, rtol=1e-5)
    assert d["slot"] == pytest.approx(20.0, abs=1e-3)
    assert d["last_packet_received"] == inner._last_received
    batch = decode_observation(np.stack([obs, obs]), s)
    assert batch["pos_err_m"].shape == (2, 3) and batch["snr_db"].shape == (2,)


@pytest.mark.parametrize("overrides", [{}, {"rate_min_bps": 0.0}])
def test_reward_and_costs_match_the_numpy_oracle(overrides):
    """The reward written once (kernel.reward_one) against its formula in numpy, NaN and ends included."""
    import oracle_env

    from iscc_gym.sim.task import reward_and_costs

    s = iscc_gym.make_scenario("paper", **overrides)
    rng = np.random.default_rng(4)
    shape = (5, 40)
    m = {"tracking_error_m": rng.uniform(0, 2 * s.max_tracking_error_m, shape),
         "rate_comm_bps": rng.uniform(0, 2 * max(s.rate_min_bps, 1.0), shape),
         "eps_ctrl": rng.uniform(0, 2 * 0.05, shape)}
    m["rate_comm_bps"][0, :5] = np.nan
    m["eps_ctrl"][1, :5] = np.nan
    m["diverged"] = m["tracking_error_m"] > s.max_tracking_error_m
    n_next = rng.integers(1, s.n_slots + 1, shape)
    evaluable = rng.uniform(size=shape) > 0.1
    got = reward_and_costs(s, m, n_next, evaluable)
    want = oracle_env.reward_and_costs(s, m, n_next, evaluable)
    for g, w in zip(got, want, strict=True):
        assert g.shape == shape
        np.testing.assert_array_equal(g, w)


def test_action_to_split_matches_the_numpy_oracle_bit_for_bit():
    """The action map written once (kernel.split_one) against its numpy formula, inf/NaN included."""
    import oracle_env

    rng = np.random.default_rng(0)
    a = rng.uniform(-1.5, 1.5, (4, 500, 3))
    a[:, ::7, 0] = -1.0
    a[:, ::11] = -3.0
    a[:, ::13, 1] = np.inf
    a[:, ::17, 2] = -np.inf
    a[0, 5] = [np.nan, 0.0, 0.0]
    got, want = action_to_split(a), oracle_env.action_to_split(a)
    assert got.shape == a.shape
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(action_to_split(a[1, 3]), oracle_env.action_to_split(a[1, 3]))
    with pytest.raises(ValueError, match="shape"):
        action_to_split(np.zeros(4))


# --- issue 23: the clients' API (item 4) and defect 14 ---------------------------------------------


@pytest.mark.parametrize("env_id", [ENV_ID, iscc_gym.MULTI_ENV_ID])
def test_unknown_keyword_has_pythons_own_typeerror_wording(env_id):
    """TorchRL's GymEnv passes frameskip=1 and retries without it only on Python's standard wording."""
    cls = "ISCCEnv" if env_id == ENV_ID else "ISCCMultiEnv"
    with pytest.raises(TypeError, match=rf"^{cls}\.__init__\(\) got an unexpected keyword argument 'frameskip'; "
                                        r"it takes .*Scenario fields"):
        gym.make(env_id, frameskip=1)
    with pytest.raises(TypeError, match=r"unexpected keyword argument 'sceanrio' \(did you mean 'scenario'\?\)"):
        gym.make(env_id, sceanrio="paper")


def test_reset_info_carries_the_step_info_keys():
    """Reset and step infos have the same keys and types (TorchRL and others build specs from the reset
    info): the initial tracking error, zero costs, NaN slot outcomes, no action yet."""
    env = make()
    _, info = env.reset(seed=3)
    _, _, _, _, step_info = env.step(np.zeros(3, np.float32))
    assert set(info) == set(step_info)
    for key, val in info.items():
        assert type(val) is type(step_info[key]), key
        assert np.shape(val) == np.shape(step_info[key]) and np.asarray(val).dtype == np.asarray(step_info[key]).dtype
    st = env.unwrapped._state
    assert info["slot"] == 0 and info["cost"] == info["cost_rate"] == info["cost_stability"] == 0.0
    assert info["packet_received"] is True
    # the true initial error, recomputed from the env's state after a fresh reset with the same seed
    env.reset(seed=3)
    st = env.unwrapped._state
    assert info["tracking_error_m"] == float(np.linalg.norm(st.x[0, :3] - st.ref[0, 0, :3]))
    for key in ("snr_db", "snr_large_scale_db", "peb_m", "veb_mps", "eps_ctrl", "rate_comm_bps", "rate_ctrl_bps",
                "estimation_error_m"):
        assert math.isnan(info[key]), key
    assert np.isnan(info["action"]).all()


def test_multi_env_reset_info_carries_the_step_info_keys():
    env = gym.make(iscc_gym.MULTI_ENV_ID, n_drones=3)
    _, info = env.reset(seed=1)
    _, _, _, _, step_info = env.step(np.zeros(9, np.float32))
    assert set(info) - {"drone_seeds"} == set(step_info)
    for key in step_info:
        assert np.shape(info[key]) == np.shape(step_info[key]), key
    assert info["cost"] == 0.0 and info["slot"] == 0 and info["tracking_error_m"].shape == (3,)
    assert info["mean_tracking_error_m"] == pytest.approx(info["tracking_error_m"].mean())


@pytest.mark.parametrize("env_id", [ENV_ID, iscc_gym.MULTI_ENV_ID])
@pytest.mark.parametrize("bad", ["complex", "complex_list", "complex64"])
def test_complex_action_is_refused_and_changes_nothing(env_id, bad):
    """Defect 14: numpy dropped the imaginary part of a complex action (with only a ComplexWarning)."""
    env = gym.make(env_id).unwrapped
    env.reset(seed=0)
    n = env.action_space.shape[0]
    action = {"complex": np.full(n, 0.2 + 0.1j), "complex_list": [0.5j] + [0.0] * (n - 1),
              "complex64": np.zeros(n, np.complex64)}[bad]
    before = env._state
    with pytest.raises(TypeError, match="action has complex dtype complex"):
        env.step(action)
    assert env._state is before
    env.step(np.zeros(n, np.float32))  # and the env steps on


def test_human_render_mode_prints_a_status_line_headless(capsys):
    """rl_zoo3.enjoy renders in "human" mode: a status line at reset, once per simulated second, at the
    episode's end, and at most once per slot however often render() is called."""
    env = make(render_mode="human", max_episode_steps=25)
    env.reset(seed=0)
    env.render()  # the reset line is already printed
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 1 and lines[0].startswith("ISCC t=    0.0 s  slot     0  tracking error")
    for _ in range(25):
        env.step(np.zeros(3, np.float32))
    lines = capsys.readouterr().out.splitlines()
    assert [ln.split()[5] for ln in lines] == ["10", "20"]  # slots 10 and 20 (TimeLimit ends at 25)
    env.render()
    env.render()
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 1 and " slot    25 " in lines[0] and "PEB" in lines[0]
    assert env.render() is None
