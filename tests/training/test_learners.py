"""The field task's learners that use what only the simulator knows at training time (issue 45): the learned
estimator of the world (RMA-style), the DAgger student of ``aware`` and the critic shown the world. Each is trained
by ``python -m train`` in a tiny budget, plays through ``agents.make_policy`` / ``python -m eval``'s loader, and never
reads the world block when deployed."""

import math

import numpy as np
import pytest
import torch
from iscc_gym.agents import make_policy
from iscc_gym.agents.bayes import ESTIMATOR_INPUTS, BayesPolicy, estimator_inputs
from iscc_gym.agents.estimator import FILE, WorldEstimator, load_estimator, save_estimator
from iscc_gym.agents.sb3_vec_env import ISCCBatchedVecEnv
from iscc_gym.train.cli import cli
from iscc_gym.train.estimator import fit, two_hot

from iscc_gym import make_scenario

FIELD = make_scenario("field")
TINY = ["--env", "iscc_gym/ISCC-Field-v0", "--n-envs", "4", "--quiet"]


def test_estimator_inputs_are_the_filters_measurements_bounded():
    x = estimator_inputs(np.array([True, False, False]), np.array([5.0, 1e-9, 10.0]),
                         np.array([3.0, np.nan, -200.0]), np.array([np.nan, 0.5, 9.0]))
    assert x.shape == (3, len(ESTIMATOR_INPUTS)) and x.dtype == np.float32
    np.testing.assert_array_equal(x[0], [1, 0, 0, 0, 0, 0, 0])  # a new mission: nothing measured yet
    np.testing.assert_allclose(x[1], [0, -6, 1e-6, 0, 0, 0, 0.5], rtol=1e-5)  # the deepest fade clipped, no echo
    np.testing.assert_allclose(x[2], [0, 1, 10, -6, 1e-6, 1, 5], rtol=1e-5)


def test_two_hot_puts_the_mass_that_reproduces_the_value():
    grid = np.linspace(-4.0, 12.0, 41)
    y = np.array([-9.0, -4.0, 0.13, 7.77, 12.0, 30.0])
    i, w = two_hot(y, grid)
    np.testing.assert_allclose((1 - w) * grid[i] + w * grid[i + 1], np.clip(y, -4, 12), atol=1e-12)


def test_the_estimator_fit_learns_a_world_it_can_see():
    """An oracle: the K-factor is written in the fade input, the RCS is constant; the fit's cross-entropy falls far
    below the uniform law's and its mean error to a fraction of the grid's width."""
    rng = np.random.default_rng(0)
    k_grid, rcs_grid = np.linspace(0.0, 10.0, 11), np.linspace(-2.0, 2.0, 5)
    k = rng.uniform(0.0, 10.0, (60, 16))
    x = np.zeros((60, 16, len(ESTIMATOR_INPUTS)), np.float32)
    x[0, :, 0] = 1.0
    x[:, :, 1] = (k - 5.0) / 5.0
    data = {"x": x, "k": k, "rcs": np.full((60, 16), 1.0), "k_grid": k_grid, "rcs_grid": rcs_grid,
            "bayes_ce": np.zeros((60, 16)), "bayes_mean": k}
    _, report = fit(data, hidden=16, epochs=60, chunk=10, learning_rate=3e-2, held_out=0.25, seed=0)
    assert report["k_cross_entropy"] < 0.5 * math.log(len(k_grid))
    assert report["rcs_cross_entropy"] < 0.5 * math.log(len(rcs_grid))
    assert report["k_mean_abs_error_db"] < 1.0


def _hidden_obs(n=3, steps=4, seed=9):
    venv = ISCCBatchedVecEnv(n, scenario=FIELD, show_world=True)
    venv.seed(seed)
    obs = venv.reset()
    out = [obs]
    for _ in range(steps):
        obs, _, _, _ = venv.step(np.zeros((n, 3), np.float32))
        out.append(obs)
    return out


def test_the_estimator_policy_designs_on_its_law_and_never_reads_the_world(tmp_path):
    bayes = BayesPolicy(FIELD)
    torch.manual_seed(0)
    save_estimator(tmp_path / FILE, WorldEstimator(len(bayes.k_grid), len(bayes.rcs_grid), 8),
                   {"kind": "estimator", "inputs": len(ESTIMATOR_INPUTS), "hidden": 8, "scenario": "field",
                    "k_grid": bayes.k_grid.tolist(), "rcs_grid": bayes.rcs_grid.tolist()})
    policy = make_policy(f"estimator:{tmp_path}", FIELD)
    for obs in _hidden_obs():
        action, _ = policy.predict(obs[:, :-2])
        assert action.shape == (3, 3) and np.all(np.abs(action) <= 1)
        np.testing.assert_allclose(policy.posterior.sum(axis=(1, 2)), 1.0)
    with pytest.raises(ValueError, match="obs|observation"):
        policy.predict(obs)  # the world-shown observation: not the deployed policy's
    # another grid, a missing file, a damaged one: one line naming the path and the fix
    save_estimator(tmp_path / "other.pt", WorldEstimator(5, 31, 8), {"kind": "estimator",
                   "inputs": len(ESTIMATOR_INPUTS), "hidden": 8, "scenario": "x", "k_grid": list(range(5)),
                   "rcs_grid": bayes.rcs_grid.tolist()})
    with pytest.raises(ValueError, match="trained on another"):
        make_policy(f"estimator:{tmp_path / 'other.pt'}", FIELD)
    with pytest.raises(FileNotFoundError, match="--learner estimator"):
        make_policy(f"estimator:{tmp_path / 'none'}", FIELD)
    (tmp_path / "bad.pt").write_bytes(b"not a file torch wrote")
    with pytest.raises(ValueError, match="retrain"):
        load_estimator(tmp_path / "bad.pt")


def test_python_m_train_trains_the_estimator_and_the_student(tmp_path):
    """``--learner estimator`` and ``--learner dagger`` end to end in a tiny budget: each writes its file, summary
    and config, and plays through make_policy on the task's observation; mistakes refused before any play."""
    import yaml

    est = cli([*TINY, "--learner", "estimator", "--total-timesteps", "120", "--set", "epochs=1", "--set", "chunk=10",
               "--set", "worlds=2", "--out", str(tmp_path / "est")])
    assert len(yaml.safe_load((tmp_path / "est" / "config.yml").read_text())["worlds"]) == 2
    summary = yaml.safe_load((tmp_path / "est" / "summary.yml").read_text())
    assert est["timesteps"] == 120 and summary["held_out"]["held_out_envs"] == 1
    assert {"k_cross_entropy", "bayes_k_cross_entropy", "k_mean_abs_error_db"} <= set(summary["held_out"])
    dag = cli([*TINY, "--learner", "dagger", "--total-timesteps", "80", "--set", "rounds=2", "--set", "epochs=1",
               "--set", "chunk=10", "--out", str(tmp_path / "dag")])
    assert dag["timesteps"] == 160
    rounds = yaml.safe_load((tmp_path / "dag" / "summary.yml").read_text())["rounds"]
    assert [r["beta"] for r in rounds] == [1.0, 0.5] and rounds[0]["student_share"] == 0.0
    assert 0.0 < rounds[1]["student_share"] < 1.0
    obs = _hidden_obs(n=2, steps=2)
    for spec in (f"estimator:{tmp_path / 'est'}", f"student:{tmp_path / 'dag'}"):
        policy = make_policy(spec, FIELD)
        for o in obs:
            split, _ = policy.split_batch(o[:, :-2])
            np.testing.assert_allclose(split.sum(axis=1), 1.0)
    with pytest.raises(ValueError, match="StudentPolicy filters the field task.s world"):
        make_policy(f"student:{tmp_path / 'dag'}", "paper")
    with pytest.raises(ValueError, match="needs the field task's hidden world"):
        cli(["--env", "iscc_gym/ISCC-v0", "--learner", "estimator", "--quiet", "--out", str(tmp_path / "p")])
    with pytest.raises(ValueError, match="--set depth: this learner's settings are hidden"):
        cli([*TINY, "--learner", "dagger", "--set", "depth=3", "--out", str(tmp_path / "q")])
    with pytest.raises(ValueError, match="--set beta=2"):
        cli([*TINY, "--learner", "dagger", "--set", "beta=2", "--out", str(tmp_path / "q")])
    with pytest.raises(ValueError, match="not empty.*--overwrite"):
        cli([*TINY, "--learner", "estimator", "--out", str(tmp_path / "est")])
    assert not (tmp_path / "p").exists() and not (tmp_path / "q").exists()


def test_the_world_critic_sees_the_world_and_the_actor_does_not(tmp_path):
    """``--critic world``: the value depends on the world block, the action does not (scrambled); the deployed agent
    reads the task's observation (25 entries) and loads as python -m eval loads it; refused off the field task."""
    from iscc_gym.agents.sb3_policy import SB3Policy
    from iscc_gym.agents.world_critic import WorldCriticPolicy

    out = tmp_path / "run"
    cli([*TINY, "--critic", "world", "--residual", "bayes", "--total-timesteps", "64", "--set", "n_steps=16",
         "--set", "batch_size=32", "--eval-freq", "0", "--checkpoint-freq", "0", "--no-tensorboard", "--out", str(out)])
    agent = SB3Policy.load(out, check_env="iscc_gym/ISCC-Field-v0")
    assert agent.obs_shape == (25,)
    sb3 = agent.agent if hasattr(agent, "agent") else agent
    policy = sb3.model.policy
    assert isinstance(policy, WorldCriticPolicy) and policy.world_entries == 2
    with torch.no_grad():  # the actor's layers after training: perturb only the world block
        policy.value_net.weight.normal_()  # a critic whose value surely reads its whole input
        for layer in policy.mlp_extractor.value_net:
            if isinstance(layer, torch.nn.Linear):
                layer.weight.normal_()
        obs = torch.randn(6, 27)
        other = obs.clone()
        other[:, -2:] = torch.randn(6, 2) * 10
        act, _ = policy.predict(obs.numpy(), deterministic=True)
        act2, _ = policy.predict(other.numpy(), deterministic=True)
        np.testing.assert_array_equal(act, act2)
        assert not torch.allclose(policy.predict_values(obs), policy.predict_values(other))
    first = _hidden_obs(n=2, steps=0)[0][:, :-2]
    action, _ = agent.predict(first)
    assert action.shape == (2, 3)
    with pytest.raises(ValueError, match="critic = 'world' shows PPO's critic"):
        cli(["--env", "iscc_gym/ISCC-v0", "--critic", "world", "--quiet", "--out", str(tmp_path / "p")])
    with pytest.raises(ValueError, match="critic = 'oracle'; use one of own, world"):
        cli([*TINY, "--critic", "oracle", "--out", str(tmp_path / "p")])
    assert not (tmp_path / "p").exists()


def test_randomised_worlds_are_drawn_inside_their_ranges_and_reproduce():
    from iscc_gym.tasks.field import FIELD_VARIANTS, FIELD_WORLD_RANGES, draw_worlds

    assert draw_worlds(1, 0) == [{}]
    worlds = draw_worlds(64, 3)
    assert worlds == draw_worlds(64, 3) and worlds != draw_worlds(64, 4)
    for key, (lo, hi) in FIELD_WORLD_RANGES.items():
        values = np.array([w[key] for w in worlds])
        assert lo <= values.min() and values.max() <= hi and values.std() > 0.1 * (hi - lo)
        # the preset and every test world lie inside the ranges the learner is trained over
        assert lo <= getattr(FIELD, key) <= hi
        for variant in FIELD_VARIANTS.values():
            assert lo <= variant.overrides.get(key, getattr(FIELD, key)) <= hi
