"""The device trainer: its GAE and running statistics against SB3's own, a tiny run on the CPU stand-in that saves an
SB3 model python -m eval's loader reads, and python -m train --device's checks."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("stable_baselines3")

from iscc_gym.train.device_ppo import (  # noqa: E402
    LR_BOUNDS,
    N_MINIBATCHES,
    DevicePPOConfig,
    RunningMeanStd,
    adapt_lr,
    default_n_envs,
    gae,
    paper_config,
    to_sb3,
    train,
)


def test_gae_equals_sb3s_rollout_buffer():
    from gymnasium import spaces
    from stable_baselines3.common.buffers import RolloutBuffer

    t_len, n = 7, 5
    rng = np.random.default_rng(0)
    rewards, values = rng.normal(size=(t_len, n)), rng.normal(size=(t_len, n))
    dones = (rng.random((t_len, n)) < 0.2).astype(float)
    last_value = rng.normal(size=n)
    buf = RolloutBuffer(t_len, spaces.Box(-1, 1, (2,)), spaces.Box(-1, 1, (3,)), n_envs=n, gamma=0.7, gae_lambda=0.9)
    # SB3 stores episode_starts[t] = done[t - 1] and takes the done of the last step apart
    starts = np.vstack([np.zeros((1, n)), dones[:-1]])
    for t in range(t_len):
        buf.add(np.zeros((n, 2)), np.zeros((n, 3)), rewards[t], starts[t], torch.tensor(values[t]),
                torch.zeros(n))
    buf.compute_returns_and_advantage(torch.tensor(last_value), dones[-1])
    adv, ret = gae(*(torch.tensor(a) for a in (rewards, values, dones, last_value)), 0.7, 0.9)
    # SB3's buffer holds float32
    np.testing.assert_allclose(adv.numpy(), buf.advantages, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(ret.numpy(), buf.returns, rtol=1e-6, atol=1e-6)


def test_running_statistics_equal_sb3s():
    from stable_baselines3.common.running_mean_std import RunningMeanStd as SB3RMS

    rng = np.random.default_rng(1)
    ours, theirs = RunningMeanStd((3,), "cpu"), SB3RMS(shape=(3,))
    for _ in range(4):
        x = rng.normal(2.0, 3.0, (11, 3))
        ours.update(torch.tensor(x))
        theirs.update(x)
    np.testing.assert_allclose(ours.mean.numpy(), theirs.mean, rtol=1e-12)
    np.testing.assert_allclose(ours.var.numpy(), theirs.var, rtol=1e-12)


def test_a_tiny_run_is_seeded_and_its_sb3_model_predicts_as_trained():
    cfg = DevicePPOConfig(device="cpu", n_envs=8, n_steps=4, batch_size=16, n_epochs=1, total_timesteps=64,
                          pool_size=4, net_arch=[8, 8], gamma=0.3)
    s, trained = train(cfg)
    assert s["timesteps"] == 64 and s["iterations"] == 2 and len(s["curve"]) == 2
    again, _ = train(cfg)
    untimed = [[c[:2] + c[3:] for c in run["curve"]] for run in (s, again)]  # (steps, reward, wall s, lr, kl)
    assert untimed[0] == untimed[1]  # seeded: the same run
    model, vn = to_sb3(cfg, trained, s["timesteps"])
    obs = np.random.default_rng(0).normal(size=(5, vn.observation_space.shape[0])).astype(np.float32)
    rms = trained.obs_rms  # the trainer's own statistics, as it normalised
    normed = ((torch.as_tensor(obs, dtype=torch.float64) - rms.mean) / torch.sqrt(rms.var + 1e-8)).clamp(-10, 10)
    with torch.no_grad():
        ours = trained.policy._predict(normed.float(), deterministic=True).numpy()
    theirs, _ = model.predict(vn.normalize_obs(obs), deterministic=True)
    np.testing.assert_allclose(theirs, np.clip(ours, -1, 1), rtol=1e-6)


def test_train_cli_device_checks(tmp_path):
    from iscc_gym.train.cli import cli

    with pytest.raises(SystemExit):
        cli(["--device", "standin", "--optimize", "--out", str(tmp_path / "a")])
    with pytest.raises(ValueError, match="residual"):  # the urban entry trains a residual
        cli(["--device", "standin", "--env", "iscc_gym/ISCC-Urban-v0", "--out", str(tmp_path / "b")])
    with pytest.raises(ValueError, match="--device"):
        cli(["--device", "standin", "--algo", "sac", "--out", str(tmp_path / "c")])
    with pytest.raises(ValueError, match="--resume"):
        cli(["--device", "standin", "--resume", "--out", str(tmp_path / "e")])
    s = cli(["--device", "standin", "--n-envs", "8", "--total-timesteps", "128", "--set", "batch_size=64",
             "--out", str(tmp_path / "d"), "--quiet"])
    assert s["timesteps"] == 128
    from iscc_gym.agents.sb3_policy import SB3Policy

    pol = SB3Policy.load(tmp_path / "d")  # a unit of python -m train: manifest, model, statistics
    assert pol.vecnormalize is not None
    a, _ = pol.predict(np.zeros((3, pol.obs_shape[0]), np.float32))
    assert a.shape == (3, 3) and np.all(np.abs(a) <= 1)
    (tmp_path / "f").mkdir()
    (tmp_path / "f" / "mine.txt").write_text("not a run")
    with pytest.raises(FileExistsError):  # a folder that is not a run is never written into
        cli(["--device", "standin", "--n-envs", "8", "--total-timesteps", "64", "--out", str(tmp_path / "f")])
    assert (tmp_path / "f" / "mine.txt").read_text() == "not a run"


@pytest.mark.slow
def test_device_bench_quick_runs_on_the_stand_in(tmp_path):
    from iscc_gym.eval.bench import main

    res = main(["--device", "standin", "--quick", "--quiet", "--json", str(tmp_path / "b.json")])
    assert res["env"]["16"]["env_steps_per_s"] > 0 and res["env"]["16"]["reset_s"] > 0


@pytest.mark.slow
def test_device_ppo_experiment_quick_runs_on_the_stand_in(tmp_path):
    from experiments.device_ppo import main

    res = main(["--device", "standin", "--quick", "--schedules", "kl,linear", "--json", str(tmp_path / "p.json")])
    assert res["ppo"]["steps_per_s"] > 0
    assert set(res["time_to_myopic"]) == {"kl", "linear"}
    assert all(t["checks"] for t in res["time_to_myopic"].values())  # checked against myopic at least once
    assert (tmp_path / "p.json").exists()
    with pytest.raises(ValueError, match="--schedules 'cosine'"):
        main(["--device", "standin", "--schedules", "cosine"])


def test_the_benchs_paper_config_is_the_yaml_entry_python_m_train_reads():
    from iscc_gym.train.cli import parse_args
    from iscc_gym.train.device import config_from_args

    # if the YAML entry changes, update iscc_gym.train.device_ppo.paper_config to it
    assert config_from_args(parse_args(["--out", "x"]), "standin") == paper_config("standin")


def test_train_device_plays_and_records_the_scenario_asked(tmp_path, monkeypatch):
    """Issue 43.5: ``python -m train --device standin --scenario literal`` trained the env id's preset and recorded
    ``scenario: paper``; a scenario of another task is refused as by an SB3 run."""
    import yaml
    from iscc_gym.train.cli import cli

    from iscc_gym.gpu import vector_env

    played = []
    init = vector_env.DeviceVectorEnv.__init__

    def spy(self, *a, **k):
        init(self, *a, **k)
        played.append(self.scenario)

    monkeypatch.setattr(vector_env.DeviceVectorEnv, "__init__", spy)
    cli(["--device", "standin", "--scenario", "literal", "--n-envs", "8", "--total-timesteps", "64", "--set",
         "batch_size=64", "--out", str(tmp_path / "lit"), "--quiet"])
    from iscc_gym.scenario import make_scenario

    assert played == [make_scenario("literal")]
    config = yaml.safe_load((tmp_path / "lit" / "config.yml").read_text())
    assert config["args"]["scenario"] == "literal"
    with pytest.raises(ValueError, match="'urban' is the urban task, but iscc_gym/ISCC-v0 is the paper task"):
        cli(["--device", "standin", "--scenario", "urban", "--out", str(tmp_path / "u"), "--quiet"])
    assert not (tmp_path / "u").exists()


@pytest.mark.parametrize("leftover", [".config.yml.4242.0123abcd.tmp", ".model.zip.7.deadbeef.tmp"])
def test_overwrite_recovers_a_folder_left_by_a_kill_inside_the_first_save(tmp_path, leftover):
    """Issue 43.8: after a kill inside a run's first save (``train --device``: before config.yml was in place) the
    folder held only temporary files; a rerun said "pass --resume or --overwrite", --resume "keeps no checkpoints",
    --overwrite "holds no run". Now --overwrite recognises what the killed save left and starts afresh; a folder that
    holds anything else is still never written into."""
    from iscc_gym.train.cli import cli

    out = tmp_path / "run"
    out.mkdir()
    (out / leftover).write_bytes(b"half a file")
    argv = ["--device", "standin", "--n-envs", "8", "--total-timesteps", "64", "--set", "batch_size=64", "--out",
            str(out), "--quiet"]
    with pytest.raises(FileExistsError, match="--overwrite to start afresh"):
        cli(argv)
    cli([*argv, "--overwrite"])
    assert not (out / leftover).exists() and (out / "model.zip").is_file()
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / leftover).write_bytes(b"half a file")
    (mine / "notes.txt").write_text("mine")
    with pytest.raises(FileExistsError, match="holds no run"):
        cli([*argv[:-2], str(mine), "--quiet", "--overwrite"])
    assert (mine / "notes.txt").read_text() == "mine" and (mine / leftover).exists()


def test_train_device_says_its_budget_and_progress_and_writes_summary_and_curve(tmp_path, capsys):
    """Issue 43.11: ``--device standin --total-timesteps 2000`` trained 65,536 steps without a word, printed no
    progress and wrote no summary.yml or learning curve, though --help promises them."""
    import yaml
    from iscc_gym.train.cli import cli

    out = tmp_path / "d"
    cli(["--device", "standin", "--n-envs", "8", "--total-timesteps", "100", "--set", "n_steps=4", "--set",
         "batch_size=32", "--out", str(out)])
    err = capsys.readouterr().err
    assert ("--total-timesteps 100 rounds up to 128: the device PPO trains whole rollouts of 8 envs x 4 steps = 32"
            in err)
    assert "step 32/128" in err and "step 128/128" in err and "ETA" in err
    summary = yaml.safe_load((out / "summary.yml").read_text())
    assert summary["timesteps"] == 128 and summary["device"] == "standin"
    rows = (out / "learning_curve.csv").read_text().splitlines()
    assert rows[0] == "timesteps,wall_s,train_reward_per_step_mean,learning_rate,approx_kl"
    assert [r.split(",")[0] for r in rows[1:]] == ["32", "64", "96", "128"]
    assert (out / "learning_curve.png").stat().st_size > 0


def test_the_device_run_is_scaled_to_its_batch():
    """Issue 46: a rollout cut into N_MINIBATCHES minibatches by default, the rate adapted to a KL target (rsl_rl's
    rule, within its bounds) or annealed to zero (CleanRL's), the statistics updated once a rollout."""
    cfg = DevicePPOConfig(device="cpu", n_envs=8, n_steps=4)
    assert cfg.batch_size == 8 * 4 // N_MINIBATCHES
    assert default_n_envs("standin") == 4096 and paper_config("standin").lr_schedule == "kl"
    assert adapt_lr(1e-3, 0.05, 0.01) == pytest.approx(1e-3 / 1.5)
    assert adapt_lr(1e-3, 0.001, 0.01) == pytest.approx(1.5e-3)
    assert adapt_lr(1e-3, 0.01, 0.01) == 1e-3
    assert adapt_lr(LR_BOUNDS[1], 0.0, 0.01) == LR_BOUNDS[1] and adapt_lr(LR_BOUNDS[0], 1.0, 0.01) == LR_BOUNDS[0]
    with pytest.raises(ValueError, match="lr_schedule = 'cosine'; use one of constant, kl, linear"):
        DevicePPOConfig(device="cpu", lr_schedule="cosine")
    with pytest.raises(ValueError, match="desired_kl = 0"):
        DevicePPOConfig(device="cpu", desired_kl=0)
    base = dict(device="cpu", n_envs=8, n_steps=4, n_epochs=2, total_timesteps=96, pool_size=4, net_arch=[8, 8],
                gamma=0.3, learning_rate=1e-3)
    kl, _ = train(DevicePPOConfig(**base, lr_schedule="kl", desired_kl=1e-12))  # every KL above: the rate falls
    rates = [c[3] for c in kl["curve"]]
    assert max(rates) < 1e-3 and min(rates) >= LR_BOUNDS[0] and min(rates) <= 1.5 * LR_BOUNDS[0]  # to the floor
    lin, trained = train(DevicePPOConfig(**base, lr_schedule="linear"))
    assert [c[3] for c in lin["curve"]] == pytest.approx([1e-3, 1e-3 * (1 - 32 / 96), 1e-3 * (1 - 64 / 96)])
    assert trained.obs_rms.count == pytest.approx(1e-4 + 8 + 3 * 32)  # the reset's rows, then each rollout's once


def test_truncations_are_bootstrapped_with_the_value_of_the_final_observation(monkeypatch):
    """SB3's rule: a truncated (not terminated) episode's last reward gains gamma V(its last observation), read from
    the device env's final_obs; a constant value function makes the term gamma * V exactly."""
    from iscc_gym.train import device_ppo

    seen = {}
    real_gae = device_ppo.gae

    def spy(rewards, values, dones, last_value, gamma, lam):
        seen["rewards"], seen["dones"] = rewards.clone(), dones.clone()
        return real_gae(rewards, values, dones, last_value, gamma, lam)

    monkeypatch.setattr(device_ppo, "gae", spy)
    cfg = DevicePPOConfig(device="cpu", n_envs=4, n_steps=3, n_epochs=1, total_timesteps=12, pool_size=4,
                          net_arch=[8, 8], gamma=0.5, normalize=False, env_overrides={},
                          random_start=False)
    # episodes of 2 slots: step 1 of the rollout truncates every row
    monkeypatch.setattr(device_ppo, "_policy", _constant_value_policy(device_ppo._policy, 7.0))
    from iscc_gym.gpu import vector_env

    init = vector_env.DeviceVectorEnv.__init__
    monkeypatch.setattr(vector_env.DeviceVectorEnv, "__init__",
                        lambda self, *a, **k: init(self, *a, **{**k, "max_episode_steps": 2}))
    train(cfg)
    assert seen["dones"][1].tolist() == [1.0] * 4 and seen["dones"][0].tolist() == [0.0] * 4
    raw = torch.tensor(np.array(_rewards_of_a_run(cfg, 2)))
    np.testing.assert_allclose(seen["rewards"][0].numpy(), raw[0].numpy(), rtol=1e-6)
    np.testing.assert_allclose(seen["rewards"][1].numpy(), raw[1].numpy() + 0.5 * 7.0, rtol=1e-6)


def _constant_value_policy(make, value):
    def policy(cfg, env, device):
        pol = make(cfg, env, device)
        with torch.no_grad():
            pol.value_net.weight.zero_()
            pol.value_net.bias.fill_(value)
        for p in pol.value_net.parameters():
            p.requires_grad_(False)
        return pol

    return policy


def _rewards_of_a_run(cfg, limit):
    """The rewards of the first two steps of cfg's rollout, replayed on the device env with the same seeded policy."""
    from iscc_gym.train import device_ppo

    from iscc_gym.gpu.vector_env import DeviceVectorEnv

    torch.manual_seed(cfg.seed)
    env = DeviceVectorEnv(cfg.env_id, num_envs=cfg.n_envs, device="cpu", pool_size=cfg.pool_size,
                          max_episode_steps=limit)
    pol = device_ppo._policy(cfg, env, env.obs.device)
    obs, _ = env.reset(seed=cfg.seed)
    out = []
    with torch.no_grad():
        for _ in range(2):
            actions, _, _ = pol(obs)
            obs, reward, *_ = env.step(actions, check=False)
            out.append(reward.numpy().copy())
    return out


def test_the_device_evaluation_is_the_cpu_envs_on_common_random_numbers():
    """time_to_myopic checks the agent on the device env (bench_device.device_reward_per_slot): the same missions and
    noise as the CPU env plays for the same seeds, so its figure is the CPU evaluation's up to rounding."""
    from iscc_gym.eval.evaluate import run_episodes

    from experiments.device_ppo import _DeviceAgent, _per_slot, device_reward_per_slot

    cfg = DevicePPOConfig(device="cpu", n_envs=8, n_steps=4, n_epochs=1, total_timesteps=64, pool_size=4,
                          net_arch=[8, 8], gamma=0.3, log_std_init=-1.0)
    _, trained = train(cfg)
    seeds = [1_000_000, 1_000_001, 1_000_002]
    ours = device_reward_per_slot(trained.policy, trained.obs_rms, cfg, seeds, 30)
    cpu = _per_slot(run_episodes(_DeviceAgent(trained.policy, trained.obs_rms, cfg.clip_obs), seeds, "paper", 30))
    assert ours == pytest.approx(cpu, rel=1e-6)
    with pytest.raises(ValueError, match="consecutive"):
        device_reward_per_slot(trained.policy, trained.obs_rms, cfg, [1, 3], 5)


def test_the_trainer_starts_its_rows_spread_over_the_mission_by_default(monkeypatch):
    from iscc_gym.gpu import vector_env

    assert DevicePPOConfig(device="cpu").random_start is True
    with pytest.raises(ValueError, match="random_start = 'yes'; expected True or False"):
        DevicePPOConfig(device="cpu", random_start="yes")
    starts = {}
    reset = vector_env.DeviceVectorEnv.reset

    def spy(self, **kw):
        out = reset(self, **kw)
        starts["random_start"], starts["n"] = self.random_start, self.host_state()["n"].copy()
        return out

    monkeypatch.setattr(vector_env.DeviceVectorEnv, "reset", spy)
    train(DevicePPOConfig(device="cpu", n_envs=16, n_steps=2, n_epochs=1, total_timesteps=32, pool_size=4,
                          net_arch=[8, 8]))
    assert starts["random_start"] and len(set(starts["n"].tolist())) > 4
