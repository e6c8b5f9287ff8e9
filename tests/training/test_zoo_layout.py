"""Models trained elsewhere: rl-zoo3's run layout and bare SB3 models load with their VecNormalize statistics,
or are refused / warned about, never silently evaluated on unnormalised observations."""

from collections import OrderedDict

import gymnasium as gym
import numpy as np
import pytest
import yaml

import iscc_gym  # noqa: F401

pytest.importorskip("stable_baselines3")
from iscc_gym.agents.sb3_policy import SB3Policy, find_vecnormalize  # noqa: E402
from stable_baselines3 import PPO  # noqa: E402
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize  # noqa: E402

ENV = "iscc_gym/ISCC-v0"


@pytest.fixture(scope="module")
def zoo_run(tmp_path_factory):
    """A run folder as rl-zoo3 writes it: <run>/<env>.zip, <run>/best_model.zip, <run>/<env>/{vecnormalize.pkl,
    config.yml} (config.yml a yaml.dump of an OrderedDict, rl-zoo3's ExperimentManager)."""
    run = tmp_path_factory.mktemp("logs") / "ppo" / "iscc_gym-ISCC-v0_1"
    stats_dir = run / "iscc_gym-ISCC-v0"
    stats_dir.mkdir(parents=True)
    venv = VecNormalize(DummyVecEnv([lambda: gym.make(ENV)]), norm_reward=False)
    model = PPO("MlpPolicy", venv, n_steps=64, batch_size=32, n_epochs=1, seed=0, device="cpu")
    model.learn(128)
    model.save(run / "iscc_gym-ISCC-v0.zip")
    model.save(run / "best_model.zip")
    venv.save(stats_dir / "vecnormalize.pkl")
    (stats_dir / "config.yml").write_text(yaml.dump(OrderedDict([("n_steps", 64), ("normalize", True),
                                                                 ("policy", "MlpPolicy")])))
    return run, venv


def test_rl_zoo3_statistics_are_found_in_the_env_folder(zoo_run):
    run, venv = zoo_run
    for name in ("iscc_gym-ISCC-v0.zip", "best_model.zip"):
        pol = SB3Policy.load(run / name)
        assert pol.vecnormalize is not None, name
        np.testing.assert_array_equal(pol.vecnormalize.obs_rms.mean, venv.obs_rms.mean)
    assert find_vecnormalize(run / "best_model.zip") == (run / "iscc_gym-ISCC-v0" / "vecnormalize.pkl", True)


def test_rl_zoo3_run_trained_with_normalisation_but_no_statistics_is_refused(zoo_run, tmp_path):
    run, _ = zoo_run
    copy = tmp_path / "run"
    (copy / "iscc_gym-ISCC-v0").mkdir(parents=True)
    (copy / "best_model.zip").write_bytes((run / "best_model.zip").read_bytes())
    (copy / "iscc_gym-ISCC-v0" / "config.yml").write_text((run / "iscc_gym-ISCC-v0" / "config.yml").read_text())
    with pytest.raises(ValueError, match="trained with VecNormalize.*no vecnormalize.pkl"):
        SB3Policy.load(copy / "best_model.zip")


def test_bare_model_without_statistics_or_config_warns(zoo_run, tmp_path):
    run, _ = zoo_run
    (tmp_path / "m.zip").write_bytes((run / "best_model.zip").read_bytes())
    with pytest.warns(UserWarning, match="no vecnormalize.pkl"):
        pol = SB3Policy.load(tmp_path / "m.zip")
    assert pol.vecnormalize is None


def test_two_rl_zoo3_folders_beside_a_model_are_refused(zoo_run, tmp_path):
    run, _ = zoo_run
    (tmp_path / "m.zip").write_bytes((run / "best_model.zip").read_bytes())
    for d in ("a", "b"):
        (tmp_path / d).mkdir()
        (tmp_path / d / "vecnormalize.pkl").write_bytes((run / "iscc_gym-ISCC-v0" / "vecnormalize.pkl").read_bytes())
    with pytest.raises(ValueError, match="several rl-zoo3 run folders"):
        SB3Policy.load(tmp_path / "m.zip")


def test_statistics_beside_the_model_win_over_several_sub_folders(zoo_run, tmp_path):
    """An older run directory (no manifest) holds best/ and other folders with statistics: the model's own
    vecnormalize.pkl beside it is meant, nothing is ambiguous."""
    run, _ = zoo_run
    (tmp_path / "m.zip").write_bytes((run / "best_model.zip").read_bytes())
    pkl = (run / "iscc_gym-ISCC-v0" / "vecnormalize.pkl").read_bytes()
    (tmp_path / "vecnormalize.pkl").write_bytes(pkl)
    for d in ("best", "other"):
        (tmp_path / d).mkdir()
        (tmp_path / d / "vecnormalize.pkl").write_bytes(pkl)
    assert find_vecnormalize(tmp_path / "m.zip") == (tmp_path / "vecnormalize.pkl", None)
