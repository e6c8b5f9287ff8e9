"""Behaviour-cloning warm start (train.pretrain): the actor imitates the scripted policy it watched."""

import numpy as np
import pytest
from iscc_gym.agents import make_policy

from iscc_gym.sim.task import action_to_split


def _ppo(n_envs=4):
    import torch
    from stable_baselines3 import PPO

    torch.set_num_threads(1)
    from iscc_gym.agents.sb3_vec_env import ISCCBatchedVecEnv
    from stable_baselines3.common.vec_env import VecNormalize

    venv = VecNormalize(ISCCBatchedVecEnv(n_envs), gamma=0.95)
    venv.seed(3)
    return PPO("MlpPolicy", venv, n_steps=32, batch_size=64, gamma=0.95, seed=0, device="cpu"), venv


def test_actor_imitates_the_scripted_policy_on_unseen_missions():
    from iscc_gym.train.pretrain import behaviour_clone

    model, venv = _ppo(48)
    margin = make_policy("margin")
    # the fit on minibatches of 128 at a step of 3e-3 (400 steps, 1.6 s) clones as closely as the defaults' 1024
    # at 1e-3 (1500 steps, 18 s under load): median gap 0.034 both
    res = behaviour_clone(model, venv, margin, n_steps=60, grad_steps=400, batch_size=128, learning_rate=3e-3,
                          log_std=-2.0, log=lambda *_: None)
    assert res["samples"] == 2880 and res["critic_mse"] < res["return_var"]
    assert float(model.policy.log_std.detach().mean()) == -2.0
    # unseen missions: the clone's split is the rule's split
    from iscc_gym.envs.vector import ISCCVectorEnv

    env = ISCCVectorEnv(num_envs=8)
    obs, _ = env.reset(seed=list(range(700_000, 700_008)))
    errs = []
    for _ in range(200):
        want = action_to_split(margin.predict(obs)[0])
        got = action_to_split(model.predict(venv.normalize_obs(obs), deterministic=True)[0])
        errs.append(np.abs(got - want).max(axis=1))
        obs, *_ = env.step(margin.predict(obs)[0])
    assert np.median(np.concatenate(errs)) < 0.05  # a fresh policy: > 0.1 (next test)


def test_untrained_actor_is_not_the_rule():
    """The check above can fail: a fresh policy's split is far from the rule's."""
    model, venv = _ppo()
    margin = make_policy("margin")
    obs = venv.reset()
    raw = venv.get_original_obs()
    gap = np.abs(action_to_split(model.predict(obs, deterministic=True)[0]) - action_to_split(margin.predict(raw)[0]))
    assert np.median(gap.max(axis=1)) > 0.1


def test_warm_start_through_train_main(tmp_path):
    from iscc_gym.train import Args, main

    summary = main(Args(total_timesteps=256, n_envs=2, out=str(tmp_path), eval_freq=0, checkpoint_freq=0,
                        tensorboard=False, overrides={"n_steps": 64, "batch_size": 64, "n_epochs": 1},
                        init_policy="margin", init_envs=2, init_steps=50))
    ws = summary["warm_start"]
    assert ws["policy"] == "margin" and ws["samples"] == 100 and summary["wall_time_s"] >= ws["wall_time_s"]
    with pytest.raises(ValueError, match="init_policy"):
        main(Args(algo="sac", total_timesteps=64, n_envs=1, out=str(tmp_path / "sac"), eval_freq=0, checkpoint_freq=0,
                  tensorboard=False, init_policy="margin"))
