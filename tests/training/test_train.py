"""Training CLI smoke runs with tiny budgets: train, resume, save/load, config parsing."""

import numpy as np
import pytest
import yaml
from iscc_gym.agents.sb3_policy import SB3Policy
from iscc_gym.train import Args, load_hyperparams, main, parse_args
from tiny_runs import TINY
from tiny_runs import tiny_args as _args


def test_train_writes_every_artifact_and_resume_continues(tmp_path):
    summary = main(_args(tmp_path))
    assert summary["timesteps"] == 256
    for name in ("model.zip", "vecnormalize.pkl", "manifest.yml", "config.yml", "learning_curve.csv",
                 "learning_curve.png", "best/best_model.zip", "best/vecnormalize.pkl", "best/manifest.yml",
                 "checkpoints/step_256/model.zip", "checkpoints/step_256/vecnormalize.pkl",
                 "checkpoints/step_128/manifest.yml", "eval/evaluations.npz", "summary.yml"):
        assert (tmp_path / name).exists(), name
    cfg = yaml.safe_load((tmp_path / "config.yml").read_text())
    assert cfg["hyperparams"]["n_steps"] == 64 and cfg["args"]["algo"] == "ppo"
    assert len(summary["evaluations"]) == 2
    resumed = main(_args(tmp_path, total_timesteps=512, resume=True))
    assert resumed["resumed_from"].endswith("step_256")
    assert resumed["timesteps"] == 512


def test_saved_agent_loads_with_identical_actions_and_statistics(tmp_path):
    main(_args(tmp_path, vec_env="dummy", eval_freq=0))
    a = SB3Policy.load(tmp_path)
    b = SB3Policy.load(tmp_path / "model.zip")
    obs = np.random.default_rng(0).uniform(-2, 2, (16, 23)).astype(np.float32)
    act_a, _ = a.predict(obs)
    act_b, _ = b.predict(obs)
    assert np.array_equal(act_a, act_b) and act_a.shape == (16, 3)
    assert np.array_equal(a.vecnormalize.obs_rms.mean, b.vecnormalize.obs_rms.mean)
    assert a.vecnormalize.obs_rms.count > 256  # statistics of the training run, not a fresh tracker


def test_resume_without_checkpoint_and_bad_args(tmp_path):
    with pytest.raises(FileNotFoundError, match="checkpoint"):
        main(_args(tmp_path, resume=True))
    with pytest.raises(ValueError, match="algo"):
        main(_args(tmp_path, algo="a2c"))
    with pytest.raises(ValueError, match="vec_env"):
        main(_args(tmp_path, vec_env="ray"))
    with pytest.raises(ValueError, match="no entry"):
        load_hyperparams("train/hyperparams.yml", "CartPole-v1", "ppo")


def test_cli_parsing():
    args = parse_args(["--algo", "sac", "--n-envs", "3", "--no-normalize", "--set", "learning_rate=0.001",
                       "--env-set", "observation_source=gnss"])
    assert args.algo == "sac" and args.n_envs == 3 and args.normalize is False
    assert args.overrides == {"learning_rate": 0.001}
    assert args.env_overrides == {"observation_source": "gnss"}


def test_sac_runs_on_the_batched_env(tmp_path):
    summary = main(_args(tmp_path, algo="sac", total_timesteps=64, eval_freq=0, checkpoint_freq=0,
                         overrides={"learning_starts": 16, "batch_size": 16}))
    assert summary["timesteps"] >= 64


def test_ppo_learns_bit_identically_on_the_batched_env_and_on_single_envs(tmp_path):
    """Same seed, same budget: PPO on the batched env ends with exactly the parameters and VecNormalize
    statistics of PPO on DummyVecEnv of gymnasium.make envs (SubprocVecEnv equals DummyVecEnv,
    tests/env/test_env.py), through episode ends (20 s missions) and autoresets."""
    import torch
    from stable_baselines3 import PPO

    params, stats = {}, {}
    for vec in ("dummy", "batched"):
        out = tmp_path / vec
        main(_args(out, vec_env=vec, total_timesteps=512, eval_freq=0, checkpoint_freq=0, seed=5,
                   env_overrides={"mission_duration_s": 10.0}))
        model = PPO.load(out / "model.zip", device="cpu")
        params[vec] = torch.cat([p.detach().flatten() for p in model.policy.parameters()])
        stats[vec] = SB3Policy.load(out).vecnormalize
    assert torch.equal(params["dummy"], params["batched"])
    assert np.array_equal(stats["dummy"].obs_rms.mean, stats["batched"].obs_rms.mean)
    assert np.array_equal(stats["dummy"].ret_rms.var, stats["batched"].ret_rms.var)


def test_shipped_agent_loads_and_acts():
    import gymnasium as gym
    from iscc_gym.eval.__main__ import SHIPPED_AGENT
    from iscc_gym.train.config import resolve_args

    import iscc_gym  # noqa: F401
    from experiments.ship import SHIP_ARGS

    policy = SB3Policy.load(SHIPPED_AGENT)
    cfg = yaml.safe_load((SHIPPED_AGENT / "config.yml").read_text())
    shipped, _ = resolve_args(SHIP_ARGS)
    assert cfg["args"]["seed"] == SHIP_ARGS.seed and cfg["args"]["total_timesteps"] == shipped.total_timesteps
    assert cfg["args"]["n_envs"] == shipped.n_envs and cfg["args"]["init_policy"] == shipped.init_policy
    env = gym.make("iscc_gym/ISCC-v0")
    obs, _ = env.reset(seed=10_000)
    for _ in range(20):
        action, _ = policy.predict(obs)
        assert env.action_space.contains(action.astype(np.float32))
        obs, reward, terminated, truncated, info = env.step(action)
        assert np.isfinite(reward) and not terminated
    batch, _ = policy.predict(np.stack([obs, obs]))
    assert batch.shape == (2, 3) and np.allclose(batch[0], batch[1], atol=1e-6)  # torch batching: last ulp


def test_every_evaluation_plays_the_same_held_out_missions(tmp_path):
    """With a frozen policy (learning rate 0, no normalisation) every held-out evaluation gives the
    same reward: the eval env is re-seeded before each one (a VecEnv forgets its seeds on reset)."""
    summary = main(_args(tmp_path, total_timesteps=384, eval_freq=128, checkpoint_freq=0, normalize=False,
                         overrides={**TINY, "learning_rate": 0.0}))
    rewards = [r for _, r in summary["evaluations"]]
    assert len(rewards) == 3 and rewards[0] == rewards[1] == rewards[2]


def test_run_settings_come_from_the_yaml_unless_flags_set_them(tmp_path):
    from iscc_gym.train.config import resolve_args

    hp = tmp_path / "hp.yml"
    hp.write_text("iscc_gym/ISCC-v0:\n  ppo:\n    policy: MlpPolicy\n    n_envs: 16\n    n_timesteps: 2.0e+5\n"
                  "    normalize: false\n    n_steps: 32\n")
    args, kw = resolve_args(Args(hyperparams=str(hp)))
    assert (args.n_envs, args.total_timesteps, args.normalize) == (16, 200_000, False)
    assert "n_envs" not in kw and "n_timesteps" not in kw and kw["n_steps"] == 32
    args, _ = resolve_args(parse_args(["--hyperparams", str(hp), "--n-envs", "3", "--normalize"]))
    assert (args.n_envs, args.total_timesteps, args.normalize) == (3, 200_000, True)


def test_set_reads_numbers_in_exponent_notation():
    args = parse_args(["--set", "learning_rate=5e-5", "--set", "n_steps=64", "--set", "policy=MlpPolicy",
                       "--env-set", "rate_min_bps=1e6"])
    assert args.overrides == {"learning_rate": 5e-5, "n_steps": 64, "policy": "MlpPolicy"}
    assert args.env_overrides == {"rate_min_bps": 1e6}


def test_linear_schedule_as_rl_zoo3_writes_it(tmp_path):
    from iscc_gym.train.config import linear_schedule

    f = linear_schedule("lin_3e-4")
    assert f(1.0) == pytest.approx(3e-4) and f(0.5) == pytest.approx(1.5e-4) and f(0.0) == 0.0
    with pytest.raises(ValueError, match="lin_<number>"):
        linear_schedule("exp_3e-4")
    with pytest.raises(ValueError, match="learning_rate"):
        linear_schedule("lin_-1")
    summary = main(_args(tmp_path, total_timesteps=256, eval_freq=0, checkpoint_freq=0,
                         overrides={**TINY, "learning_rate": "lin_1e-3"}))
    assert summary["timesteps"] == 256


def test_td3_with_rl_zoo3_noise_keys(tmp_path):
    from iscc_gym.train.config import action_noise
    from stable_baselines3.common.noise import VectorizedActionNoise

    kw = action_noise({"noise_type": "normal", "noise_std": 0.2, "batch_size": 64}, 3, 3)
    assert isinstance(kw["action_noise"], VectorizedActionNoise) and "noise_std" not in kw
    assert kw["action_noise"]().shape == (3, 3)
    with pytest.raises(ValueError, match="noise_type"):
        action_noise({"noise_type": "pink"}, 1, 3)
    with pytest.raises(ValueError, match="noise_type"):
        action_noise({"noise_std": 0.1}, 1, 3)
    summary = main(_args(tmp_path, algo="td3", total_timesteps=64, eval_freq=0, checkpoint_freq=0,
                         overrides={"learning_starts": 16, "batch_size": 16, "noise_type": "normal",
                                    "noise_std": 0.1}))
    assert summary["timesteps"] == 64


def test_subproc_workers_import_iscc_gym_to_make_their_envs(monkeypatch):
    """SB3's subproc workers start by forkserver with gymnasium's registry alone (every iscc_gym id failed
    there): the env factory a worker unpickles imports an iscc_gym module, whose import registers the ids, and
    makes the run's env."""
    import io
    import pickle

    import cloudpickle
    from iscc_gym.train.config import resolve_args
    from iscc_gym.train.train import make_train_env
    from stable_baselines3.common import vec_env

    class Workers:  # SubprocVecEnv without its processes: the env factories it would send them
        def __init__(self, env_fns, start_method=None):
            self.env_fns = env_fns

        def seed(self, seed=None):
            pass

    class Worker(pickle.Unpickler):  # what a worker imports to unpickle its factory (cloudpickle.loads)
        def find_class(self, module, name):
            imported.append(module)
            return super().find_class(module, name)

    monkeypatch.setattr(vec_env, "SubprocVecEnv", Workers)
    args, _ = resolve_args(_args("unused", vec_env="subproc", env_overrides={"rate_min_bps": 2e6}))
    imported = []
    make = Worker(io.BytesIO(cloudpickle.dumps(make_train_env(args).env_fns[1]))).load()
    assert any(m.split(".")[0] == "iscc_gym" for m in imported), imported
    env = make()
    assert env.spec.id == "iscc_gym/ISCC-v0" and env.unwrapped.scenario.rate_min_bps == 2e6
    env.close()


def test_a_scenario_of_another_task_than_the_env_is_refused(tmp_path, monkeypatch):
    """Issue 34 item 8: ``python -m train --env iscc_gym/ISCC-Urban-v0 --scenario paper`` trained a paper agent
    under the urban task's hyperparameters and name; now refused before any work, naming both and the fix. A
    variant of the env's own task (``literal`` on ISCC-v0) passes."""
    from iscc_gym.train import train as loop
    from iscc_gym.train.cli import cli
    from iscc_gym.train.config import check_args

    def work(*a, **k):
        raise AssertionError("the run started before the mistake was reported")

    monkeypatch.setattr(loop, "prepare_out", work)
    out = tmp_path / "run"
    with pytest.raises(ValueError, match=r"scenario = 'paper' is the paper task, but iscc_gym/ISCC-Urban-v0 is the "
                                         r"urban task .*use --env iscc_gym/ISCC-v0 for 'paper', or drop --scenario"):
        cli(["--env", "iscc_gym/ISCC-Urban-v0", "--scenario", "paper", "--out", str(out), "--quiet"])
    assert not out.exists()
    with pytest.raises(ValueError, match="'urban' is the urban task, but iscc_gym/ISCC-v0 is the paper task"):
        check_args(Args(scenario="urban"))
    check_args(Args(scenario="literal"))
    with pytest.raises(ValueError, match="'field' is the field task, but iscc_gym/ISCC-v0 is the paper task.*use "
                                         "--env iscc_gym/ISCC-Field-v0"):  # issue 43.4
        check_args(Args(scenario="field"))
    with pytest.raises(ValueError, match="'paper' is the paper task, but iscc_gym/ISCC-Field-v0 is the field task"):
        check_args(Args(env_id="iscc_gym/ISCC-Field-v0", scenario="paper"))


@pytest.mark.parametrize("device", ["cpu", "standin"])
def test_a_run_whose_policy_would_observe_the_hidden_world_is_refused_before_any_work(device, tmp_path):
    """Issue 43.9: ``--env-set show_world=true`` trained an agent on the hidden world's observation without a word;
    python -m eval then refused it as trained on another env. Refused up front, naming the setting."""
    from iscc_gym.train.cli import cli

    out = tmp_path / "run"
    with pytest.raises(ValueError, match="show_world = True: the policy would observe the hidden world"):
        cli(["--env", "iscc_gym/ISCC-Field-v0", "--env-set", "show_world=true", "--device", device,
             "--total-timesteps", "64", "--out", str(out), "--quiet"])
    assert not out.exists()


def test_a_budget_that_is_not_whole_rollouts_is_rounded_up_and_said(tmp_path, capsys):
    """Issue 43.11: ``--total-timesteps 2000`` printed ``step 2,560/2,000 ... ETA -1:59:58`` and trained 4,096 without
    a word. The run says it rounds up to whole rollouts and counts its progress against what it trains."""
    from iscc_gym.train.callbacks import clock
    from iscc_gym.train.cli import cli

    s = cli(["--total-timesteps", "100", "--n-envs", "2", "--set", "n_steps=32", "--set", "batch_size=64",
             "--eval-freq", "0", "--checkpoint-freq", "0", "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert s["timesteps"] == 128
    assert "--total-timesteps 100 rounds up to 128: ppo trains whole rollouts of 2 envs x 32 steps = 64" in err
    assert "training from step 0 to 128" in err
    assert clock(-5.0) == "0:00:00"
