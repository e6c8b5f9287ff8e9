"""The device trainer: its GAE and running statistics against SB3's own, a tiny run on the CPU stand-in that saves an
SB3 model python -m eval's loader reads, and python -m train --device's checks."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("stable_baselines3")

from iscc_gym.agents.device_ppo import (  # noqa: E402
    DevicePPOConfig,
    RunningMeanStd,
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
    assert again["curve"] == s["curve"]  # seeded: the same run
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
    assert res["env"]["16"]["env_steps_per_s"] > 0 and res["ppo"]["steps_per_s"] > 0
    assert res["time_to_myopic"]["checks"]  # checked against myopic at least once


def test_the_benchs_paper_config_is_the_yaml_entry_python_m_train_reads():
    from iscc_gym.train.cli import parse_args
    from iscc_gym.train.device import config_from_args

    # if the YAML entry changes, update iscc_gym.agents.device_ppo.paper_config to it
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
    assert rows[0] == "timesteps,wall_s,train_reward_per_step_mean" and [r.split(",")[0] for r in rows[1:]] == [
        "32", "64", "96", "128"]
    assert (out / "learning_curve.png").stat().st_size > 0
