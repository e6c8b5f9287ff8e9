"""SafetyCostWrapper (issue 15 item 4): the 6-tuple on the single env and the native vector env, in
any order with Gymnasium's wrappers, and the cost equal to the env's own ``info["cost"]``."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.wrappers import ClipAction, RecordEpisodeStatistics, TimeLimit

import iscc_gym
from iscc_gym.envs.wrappers import SafetyCostVectorWrapper, SafetyCostWrapper


def _actions(n, shape, seed=0):
    return np.random.default_rng(seed).uniform(-1, 1, (n, *shape)).astype(np.float32)


def _plain_costs(n=30):
    env = gym.make(iscc_gym.ENV_ID)
    env.reset(seed=3)
    return [env.step(a)[4]["cost"] for a in _actions(n, (3,))]


@pytest.mark.parametrize("stack", ["safe", "safe(rec)", "rec(safe)", "safe(rec(safe))", "clip(time(safe))",
                                   "safe(clip(time))"])
def test_single_env_in_any_order(stack):
    """Outermost SafetyCostWrapper: a 6-tuple with cost = info["cost"] (= the plain env's cost);
    inside Gymnasium wrappers it passes their 5-tuple through, and those wrappers keep working."""
    def build():
        e = gym.make(iscc_gym.ENV_ID)
        return {"safe": lambda: SafetyCostWrapper(e),
                "safe(rec)": lambda: SafetyCostWrapper(RecordEpisodeStatistics(e)),
                "rec(safe)": lambda: RecordEpisodeStatistics(SafetyCostWrapper(e)),
                "safe(rec(safe))": lambda: SafetyCostWrapper(RecordEpisodeStatistics(SafetyCostWrapper(e))),
                "clip(time(safe))": lambda: ClipAction(TimeLimit(SafetyCostWrapper(e), 10)),
                "safe(clip(time))": lambda: SafetyCostWrapper(ClipAction(TimeLimit(e, 10)))}[stack]()

    env = build()
    env.reset(seed=3)
    want = _plain_costs()
    outer_safe = stack.startswith("safe")
    for i, a in enumerate(_actions(12, (3,))):
        out = env.step(a)
        assert len(out) == (6 if outer_safe else 5)
        info = out[-1]
        assert info["cost"] == pytest.approx(want[i], abs=0.0)
        if outer_safe:
            assert out[2] == info["cost"] and isinstance(out[2], float)
        if out[-2] or out[-3]:  # truncated by the 10-step TimeLimit
            assert i == 9
            break


def test_record_episode_statistics_sees_the_episode_through_the_cost_wrapper():
    env = RecordEpisodeStatistics(SafetyCostWrapper(gym.make(iscc_gym.ENV_ID, max_episode_steps=5)))
    env.reset(seed=0)
    for a in _actions(5, (3,)):
        *_, info = env.step(a)
    assert info["episode"]["l"] == 5


def test_vector_env_gets_a_cost_vector():
    venv = gym.make_vec(iscc_gym.ENV_ID, num_envs=3, vectorization_mode="vector_entry_point")
    plain = gym.make_vec(iscc_gym.ENV_ID, num_envs=3, vectorization_mode="vector_entry_point")
    safe = SafetyCostWrapper(venv)
    assert isinstance(safe, SafetyCostVectorWrapper)
    safe.reset(seed=[1, 2, 3])
    plain.reset(seed=[1, 2, 3])
    for a in _actions(8, (3, 3)):
        obs, rew, cost, term, trunc, info = safe.step(a)
        *_, pinfo = plain.step(a)
        assert cost.shape == (3,) and cost.dtype == np.float64
        np.testing.assert_array_equal(cost, pinfo["cost"])


def test_vector_env_in_any_order_with_gymnasium_vector_wrappers():
    from gymnasium.wrappers.vector import RecordEpisodeStatistics as VecRecord

    def make():
        return gym.make_vec(iscc_gym.ENV_ID, num_envs=2, vectorization_mode="vector_entry_point",
                            max_episode_steps=4)

    inner = VecRecord(SafetyCostWrapper(make()))
    outer = SafetyCostWrapper(VecRecord(make()))
    inner.reset(seed=[5, 6])
    outer.reset(seed=[5, 6])
    for a in _actions(4, (2, 3)):
        a_out, b_out = inner.step(a), outer.step(a)
        assert len(a_out) == 5 and len(b_out) == 6
        np.testing.assert_array_equal(b_out[2], a_out[-1]["cost"])
    assert "episode" in a_out[-1] and "episode" in b_out[-1]


def test_bad_input_is_a_clear_error():
    with pytest.raises(TypeError, match="gymnasium.Env or VectorEnv"):
        SafetyCostWrapper(object())


# --- issue 23 defects 12 and 13 ---------------------------------------------------------------------


@pytest.mark.parametrize("how", ["deepcopy", "pickle"])
def test_wrapper_can_be_deep_copied_and_pickled(how):
    """Defect 12: ``__new__(cls, env)`` needed ``env``, which copy and pickle do not pass."""
    import copy
    import pickle

    env = SafetyCostWrapper(gym.make(iscc_gym.ENV_ID))
    env.reset(seed=2)
    env.step(np.zeros(3, np.float32))
    clone = copy.deepcopy(env) if how == "deepcopy" else pickle.loads(pickle.dumps(env))
    assert type(clone) is SafetyCostWrapper
    for a in _actions(3, (3,)):
        out, out_clone = env.step(a), clone.step(a)
        assert len(out_clone) == 6
        assert out_clone[1] == out[1] and out_clone[2] == out[2]  # the copy continues the same episode
        np.testing.assert_array_equal(out_clone[0], out[0])


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_wrapper_inside_gymnasium_vector_envs(mode):
    """Defect 13: as a sub-env of SyncVectorEnv / AsyncVectorEnv it returned the 6-tuple ("too many values
    to unpack"); they get the 5-tuple, and SafetyCostWrapper around the vector env gives the cost array."""
    venv = gym.make_vec(iscc_gym.ENV_ID, num_envs=2, vectorization_mode=mode, wrappers=[SafetyCostWrapper])
    try:
        venv.reset(seed=[1, 2])
        plain = gym.make_vec(iscc_gym.ENV_ID, num_envs=2, vectorization_mode="vector_entry_point")
        plain.reset(seed=[1, 2])
        safe = SafetyCostWrapper(venv)
        for a in _actions(3, (2, 3)):
            obs, rew, cost, term, trunc, info = safe.step(a)
            pobs, prew, *_, pinfo = plain.step(a)
            np.testing.assert_array_equal(cost, pinfo["cost"])
            np.testing.assert_array_equal(obs, pobs)
        out = venv.step(_actions(1, (2, 3))[0])
        assert len(out) == 5
    finally:
        venv.close()


def test_wrapper_inside_sb3_dummy_vec_env():
    """SB3's DummyVecEnv steps its sub-envs expecting Gymnasium's 5-tuple (the cost stays in info)."""
    vec_env = pytest.importorskip("stable_baselines3.common.vec_env")
    venv = vec_env.DummyVecEnv([lambda: SafetyCostWrapper(gym.make(iscc_gym.ENV_ID))] * 2)
    venv.seed(0)
    venv.reset()
    for a in _actions(3, (2, 3)):
        obs, rew, done, infos = venv.step(a)
        assert obs.shape == (2, 23) and all("cost" in i for i in infos)


def test_vector_cost_of_a_same_step_reset_is_the_ended_steps():
    """Issue 34 item 11: with SameStep autoreset the top-level info of a reset sub-env is the reset's (cost 0); the
    cost returned with the ending step's reward is that step's, as the single env's."""
    venv = SafetyCostWrapper(gym.make_vec(iscc_gym.ENV_ID, num_envs=2, vectorization_mode="vector_entry_point",
                                          max_episode_steps=3, autoreset_mode="SameStep"))
    single = gym.make(iscc_gym.ENV_ID, max_episode_steps=3)
    venv.reset(seed=[7, 8])
    single.reset(seed=7)
    for a in _actions(3, (2, 3)):
        _, _, cost, _, trunc, info = venv.step(a)
        *_, sinfo = single.step(a[0])
        assert cost[0] == sinfo["cost"]
    assert trunc.all() and info["cost"][0] == 0.0 and cost[0] > 0.0
