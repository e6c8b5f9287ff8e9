"""The multi-drone env (issue 16): the 3K-simplex map, per-drone physics, reward, episode end, the
vector env and the PettingZoo view, against independent oracles and the single env.
"""

import gymnasium as gym
import numpy as np
import pytest

import iscc_gym
from iscc_gym.envs.env import ISCCEnv
from iscc_gym.envs.multi import ISCCMultiEnv
from iscc_gym.sim.fleet import drone_budgets, multi_split

M = iscc_gym.SCENARIOS["paper"].max_tracking_error_m


def test_the_action_map_is_the_simplex_over_3k_shares():
    rng = np.random.default_rng(0)
    a = rng.uniform(-1.5, 1.5, (50, 12))
    w = (np.clip(a, -1, 1) + 1) / 2  # oracle: w / sum(w) over all 3K entries
    alpha = multi_split(a, 4)
    np.testing.assert_allclose(alpha.reshape(50, 12), w / w.sum(1, keepdims=True), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(alpha.sum((1, 2)), 1.0, rtol=1e-12)
    np.testing.assert_allclose(drone_budgets(a, 4), alpha.sum(-1), rtol=1e-12)
    np.testing.assert_allclose(multi_split(-np.ones(12), 4), np.full((4, 3), 1 / 12))
    with pytest.raises(ValueError, match="shape"):
        drone_budgets(np.zeros(11), 4)


def test_one_drone_is_the_single_env_bit_for_bit():
    m = ISCCMultiEnv(n_drones=1)
    o1, info = m.reset(seed=5)
    s = ISCCEnv()
    o2, _ = s.reset(seed=info["drone_seeds"][0])
    assert np.array_equal(o1, o2)
    rng = np.random.default_rng(1)
    for _ in range(200):
        a = rng.uniform(-1, 1, 3).astype(np.float32)
        x, y = m.step(a), s.step(a)
        assert np.array_equal(x[0], y[0]) and x[1] == y[1] and x[2:4] == y[2:4]
        assert x[4]["cost"] == y[4]["cost"] and np.allclose(x[4]["alpha"][0], y[4]["alpha"], rtol=1e-15)


def _rollout(env, actions, seed):
    env.reset(seed=seed)
    return [env.step(a) for a in actions]


def test_a_drone_depends_only_on_its_own_shares():
    """Rearranging the other drones' shares, with drone 0's shares fixed, leaves drone 0's flight unchanged."""
    k, steps = 3, 120
    rng = np.random.default_rng(2)
    base = rng.uniform(-1, 1, (steps, 3 * k))
    other = base.copy()
    # swap drones 1 and 2: the total weight, and so drone 0's shares, stay the same
    other[:, 3:6], other[:, 6:9] = base[:, 6:9], base[:, 3:6]
    a, b = _rollout(ISCCMultiEnv(n_drones=k), base, 3), _rollout(ISCCMultiEnv(n_drones=k), other, 3)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_allclose(x[4]["alpha"][0], y[4]["alpha"][0], rtol=1e-14)
        assert x[0][:23].tolist() == pytest.approx(y[0][:23].tolist(), rel=1e-9, abs=1e-9)
        assert x[4]["tracking_error_m"][0] == pytest.approx(y[4]["tracking_error_m"][0], rel=1e-9)
    # more band to drone 0 (the others halved) gives it a higher rate in every slot
    less = base.copy()
    less[:, 3:] = -1 + (base[:, 3:] + 1) / 2
    c = _rollout(ISCCMultiEnv(n_drones=k), less, 3)
    assert all(z[4]["rate_comm_bps"][0] > x[4]["rate_comm_bps"][0] for x, z in zip(a, c, strict=True)
               if x[4]["alpha"][0, 2] > 0)


def test_the_reward_is_the_mean_of_the_drones_single_env_rewards():
    """Issue 23: tracking error and penalties are both per-drone means (the old reward summed the penalties
    over drones but averaged the error, so its maximiser bought rate with the radar)."""
    s = iscc_gym.SCENARIOS["paper"]
    env = ISCCMultiEnv(n_drones=4)
    env.reset(seed=7)
    rng = np.random.default_rng(3)
    differ = 0
    for _ in range(100):
        _, r, term, _, info = env.step(rng.uniform(-1, 1, 12).astype(np.float32))
        err = np.minimum(info["tracking_error_m"], M)
        per_drone = -err - s.w_rate * info["cost_rate"] - s.w_stab * info["cost_stability"]  # the single env's
        assert r == pytest.approx(per_drone.mean(), rel=1e-12, abs=1e-12) and not term
        old = -err.mean() - (s.w_rate * info["cost_rate"] + s.w_stab * info["cost_stability"]).sum()
        differ += r != pytest.approx(old, rel=1e-9)
        assert info["cost"] == pytest.approx(info["cost_rate"].sum() + info["cost_stability"].sum())
        assert info["cost_rate"].shape == (4,) and info["alpha"].shape == (4, 3)
        assert np.all((info["cost_rate"] >= 0) & (info["cost_rate"] <= 1))
    assert differ > 50  # the slots with a penalty tell the mean from the old sum


def test_the_episode_terminates_when_any_drone_loses_track():
    bound = 0.5
    env = ISCCMultiEnv(n_drones=3, max_tracking_error_m=bound)
    env.reset(seed=0)
    for t in range(1, 5001):
        _, r, term, trunc, info = env.step(np.zeros(9, np.float32))
        if term:
            assert (info["tracking_error_m"] > bound).any() and not trunc
            n = env.scenario.n_slots
            assert r < -bound * (n - t) * 0.99  # the loss-of-track penalty for the slots left
            break
        assert (info["tracking_error_m"] <= bound).all()
    else:
        pytest.fail("no drone exceeded a 0.5 m bound in a whole mission")
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(9, np.float32))


def test_api_checkers_and_determinism():
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.make(iscc_gym.MULTI_ENV_ID, n_drones=2)
    check_env(env.unwrapped)
    sb3_check_env(ISCCMultiEnv(n_drones=2))
    assert env.observation_space.shape == (46,) and env.action_space.shape == (6,)
    acts = np.random.default_rng(4).uniform(-1, 1, (30, 6))
    a, b = _rollout(ISCCMultiEnv(n_drones=2), acts, 11), _rollout(ISCCMultiEnv(n_drones=2), acts, 11)
    assert all(np.array_equal(x[0], y[0]) and x[1] == y[1] for x, y in zip(a, b, strict=True))
    c = _rollout(ISCCMultiEnv(n_drones=2), acts, 12)
    assert not np.array_equal(a[-1][0], c[-1][0])


def test_bad_input_is_refused_and_leaves_the_env_unchanged():
    for bad in (0, -1, 2.5, "4", True, 1000):
        with pytest.raises(ValueError, match="n_drones"):
            ISCCMultiEnv(n_drones=bad)
    env = ISCCMultiEnv(n_drones=2)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(6))
    env.reset(seed=0)
    before = env._state.x.copy()
    for action, match in ((np.zeros(5), "shape"), (np.array([0, 0, np.nan, 0, 0, 0]), "NaN")):
        with pytest.raises(ValueError, match=match):
            env.step(action)
    assert np.array_equal(env._state.x, before) and env._state.n[0] == 0


def test_the_vector_env_reproduces_multi_envs_and_autoresets():
    v = gym.make_vec(iscc_gym.MULTI_ENV_ID, num_envs=3, vectorization_mode="vector_entry_point", n_drones=2,
                     max_episode_steps=40)
    assert v.single_action_space.shape == (6,) and v.observation_space.shape == (3, 46)
    envs = [gym.make(iscc_gym.MULTI_ENV_ID, n_drones=2, max_episode_steps=40) for _ in range(3)]
    obs, _ = v.reset(seed=20)
    assert np.array_equal(obs, np.stack([e.reset(seed=20 + i)[0] for i, e in enumerate(envs)]))
    rng = np.random.default_rng(5)
    for _ in range(40):
        acts = rng.uniform(-1, 1, (3, 6)).astype(np.float32)
        obs, rew, term, trunc, info = v.step(acts)
        for i, e in enumerate(envs):
            o, r, te, tr, inf = e.step(acts[i])
            assert np.array_equal(obs[i], o) and rew[i] == r and term[i] == te and trunc[i] == tr
            assert np.array_equal(info["tracking_error_m"][i], inf["tracking_error_m"])
    assert trunc.all() and info["alpha"].shape == (3, 2, 3)
    obs, rew, *_ = v.step(np.zeros((3, 6), np.float32))  # NextStep: the reset step
    assert np.array_equal(rew, np.zeros(3))
    # each sub-env reset from its own generator, as the env's reset() without a seed
    assert np.array_equal(obs, np.stack([e.reset()[0] for e in envs]))
    pos, ref = v.unwrapped.positions()
    assert pos.shape == (3, 2, 3) and ref.shape == (3, 2, 3)
    with pytest.raises(ValueError, match="shape"):
        v.step(np.zeros((3, 3)))


def test_pettingzoo_parallel_api_and_seed_tests_pass_and_rewards_add_up():
    pytest.importorskip("pettingzoo")
    from pettingzoo.test import parallel_api_test, parallel_seed_test

    parallel_api_test(iscc_gym.parallel_env(n_drones=3), num_cycles=60)
    parallel_seed_test(lambda: iscc_gym.parallel_env(n_drones=3), num_cycles=60)
    pz, team = iscc_gym.parallel_env(n_drones=3), ISCCMultiEnv(n_drones=3)
    obs, infos = pz.reset(seed=9)
    o, _ = team.reset(seed=9)
    assert np.array_equal(np.concatenate([obs[a] for a in pz.possible_agents]), o)
    rng = np.random.default_rng(6)
    for _ in range(50):
        acts = {a: rng.uniform(-1, 1, 3).astype(np.float32) for a in pz.agents}
        obs, rew, term, trunc, infos = pz.step(acts)
        _, r, *_ = team.step(np.concatenate([acts[a] for a in pz.possible_agents]))
        assert sum(rew.values()) == pytest.approx(r, rel=1e-12, abs=1e-12)
    slot = pz._env._state.n[0]
    for acts, match in (({a: np.zeros(2) for a in pz.agents}, "shape"),
                        ({pz.agents[0]: np.zeros(3)}, r"no entry for \['drone_1', 'drone_2'\]"),
                        ({**{a: np.zeros(3) for a in pz.agents}, "drone_7": np.zeros(3)}, r"\['drone_7'\].*not live"),
                        ({**{a: np.zeros(3) for a in pz.agents}, "drone_1": np.array([0.0, np.inf, 0.0])},
                         r"actions of \['drone_1'\] contain NaN or inf")):
        with pytest.raises(ValueError, match=match):
            pz.step(acts)
    assert pz._env._state.n[0] == slot  # a refused step leaves the env where it was


def test_each_drone_carries_its_share_of_the_rate_requirement():
    s = iscc_gym.SCENARIOS["paper"]
    assert ISCCMultiEnv(n_drones=4).scenario.rate_min_bps == s.rate_min_bps / 4
    assert ISCCMultiEnv(n_drones=4, rate_min_per_drone_bps=3e6).scenario.rate_min_bps == 3e6
    v = gym.make_vec(iscc_gym.MULTI_ENV_ID, num_envs=2, vectorization_mode="vector_entry_point", n_drones=5)
    assert v.unwrapped.scenario.rate_min_bps == s.rate_min_bps / 5
    for bad in (-1.0, float("nan"), "fast"):
        with pytest.raises(ValueError, match="rate_min_per_drone_bps"):
            ISCCMultiEnv(n_drones=2, rate_min_per_drone_bps=bad)
    env = ISCCMultiEnv(n_drones=2)
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.ones(6, np.float32))
    oracle = np.maximum(0.0, env.scenario.rate_min_bps - info["rate_comm_bps"]) / env.scenario.rate_min_bps
    np.testing.assert_allclose(info["cost_rate"], oracle, rtol=1e-12, atol=1e-15)
