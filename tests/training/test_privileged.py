"""The expected one-slot reward (issue 45, a privileged signal at training time): unbiased against the sampled
reward on the field task's own draws, less noisy, and the agent's observation without the world block."""

import numpy as np
import pytest
from iscc_gym.agents.myopic import MyopicPolicy
from iscc_gym.agents.sb3_vec_env import ISCCBatchedVecEnv
from iscc_gym.train.privileged import INFO_KEYS, ExpectedRewardVecEnv, expected_correction

from iscc_gym import make_scenario

FIELD = make_scenario("field")


def _play(steps=150, n=64, seed=3):
    """The sampled rewards, the corrections and the played env's infos of ``myopic`` on the world-shown env."""
    venv = ISCCBatchedVecEnv(n, scenario=FIELD, info_keys=INFO_KEYS, show_world=True)
    venv.seed(seed)
    obs = venv.reset()
    shown = MyopicPolicy(FIELD.replace(show_world=True))
    pol = MyopicPolicy(FIELD)
    from iscc_gym.sim.functional import decode_observation

    rewards, corrs = [], []
    for _ in range(steps):
        k = decode_observation(obs, shown.scenario)["world_k_db"]
        action = pol.predict(obs[:, :-2], deterministic=True)[0]
        obs, r, _, infos = venv.step(action)
        got = {key: np.array([info[key] for info in infos]) for key in INFO_KEYS}
        rewards.append(r)
        corrs.append(expected_correction(shown, k, got["snr_large_scale_db"], got["alpha"], got["cost_rate"],
                                         got["cost_stability"]))
    return np.array(rewards, dtype=float), np.array(corrs)


def test_the_expected_reward_is_unbiased_and_less_noisy():
    rewards, corr = _play()
    c = corr.ravel()
    assert abs(c.mean()) < 3.0 * c.std() / np.sqrt(c.size)  # the sampled indicator minus its probability: mean 0
    expected = rewards + corr
    assert expected.var() < 0.5 * rewards.var()  # the stability term's draws gone


def test_the_wrapper_pays_the_expected_reward_and_hides_the_world():
    inner = ISCCBatchedVecEnv(8, scenario=FIELD, info_keys=INFO_KEYS, show_world=True)
    twin = ISCCBatchedVecEnv(8, scenario=FIELD, info_keys=INFO_KEYS, show_world=True)
    venv = ExpectedRewardVecEnv(inner, FIELD)
    assert venv.observation_space.shape == (25,)
    for v in (venv, twin):
        v.seed(5)
    obs, full = venv.reset(), twin.reset()
    np.testing.assert_array_equal(obs, full[:, :-2])
    shown = MyopicPolicy(FIELD.replace(show_world=True))
    from iscc_gym.sim.functional import decode_observation

    for _ in range(5):
        action = MyopicPolicy(FIELD).predict(obs, deterministic=True)[0]
        k = decode_observation(full, shown.scenario)["world_k_db"]
        obs, r, _, _ = venv.step(action)
        full, r_twin, _, infos = twin.step(action)
        got = {key: np.array([info[key] for info in infos]) for key in INFO_KEYS}
        want = r_twin + expected_correction(shown, k, got["snr_large_scale_db"], got["alpha"], got["cost_rate"],
                                            got["cost_stability"])
        np.testing.assert_allclose(r, want.astype(np.float32), rtol=1e-6)
        assert obs.shape == (8, 25)


def test_the_wrapper_refuses_an_env_without_the_world_shown_or_without_a_field():
    with pytest.raises(ValueError, match="build it with show_world=True"):
        ExpectedRewardVecEnv(ISCCBatchedVecEnv(2, scenario=FIELD, info_keys=INFO_KEYS), FIELD)
    with pytest.raises(ValueError, match="needs the field task's world"):
        ExpectedRewardVecEnv(ISCCBatchedVecEnv(2, scenario="paper", info_keys=INFO_KEYS), "paper")


def test_python_m_train_trains_on_the_expected_reward_and_evaluates_on_the_sampled(tmp_path):
    """``--reward expected`` reaches the trainer: the agent's observation is the task's (25 entries, no world
    block), its run records the reward, its evaluation plays the sampled reward; refused off the field task."""
    import yaml
    from iscc_gym.agents.sb3_policy import SB3Policy
    from iscc_gym.train.cli import cli

    out = tmp_path / "run"
    cli(["--env", "iscc_gym/ISCC-Field-v0", "--reward", "expected", "--total-timesteps", "64", "--n-envs", "4",
         "--set", "n_steps=16", "--set", "batch_size=32", "--eval-freq", "0", "--checkpoint-freq", "0",
         "--no-tensorboard", "--quiet", "--out", str(out)])
    config = yaml.safe_load((out / "config.yml").read_text())
    assert config["args"]["reward"] == "expected"
    assert SB3Policy.load(out, check_env="iscc_gym/ISCC-Field-v0").obs_shape == (25,)
    with pytest.raises(ValueError, match="reward = 'expected' pays the field task's .* use --env iscc_gym/ISCC-Field"):
        cli(["--env", "iscc_gym/ISCC-v0", "--reward", "expected", "--out", str(tmp_path / "paper"), "--quiet"])
    with pytest.raises(ValueError, match="reward = 'mean'; use one of sampled, expected"):
        cli(["--env", "iscc_gym/ISCC-Field-v0", "--reward", "mean", "--out", str(tmp_path / "bad"), "--quiet"])
    assert not (tmp_path / "paper").exists() and not (tmp_path / "bad").exists()
