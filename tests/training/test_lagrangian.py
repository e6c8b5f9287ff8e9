"""Constrained training (issue 15 item 1): outage limits, the Lagrangian reward and the dual ascent."""

import numpy as np
import pytest
import yaml
from iscc_gym.train import Args, main
from iscc_gym.train.lagrangian import LagrangeCallback, LagrangianVecEnv, load_lambdas, parse_cost_limits
from stable_baselines3.common.vec_env import VecEnv


def test_cost_limits_parse_and_refuse_bad_input():
    assert parse_cost_limits("rate=0.05,stability=0.0") == {"rate": 0.05, "stability": 0.0}
    assert parse_cost_limits(" rate = 0.1") == {"rate": 0.1}
    for bad, match in (("speed=0.1", "NAME=FRACTION"), ("rate=abc", "not a number"), ("rate=1.5", "outside"),
                       ("rate=0.1,rate=0.2", "twice"), ("rate", "NAME=FRACTION")):
        with pytest.raises(ValueError, match=match):
            parse_cost_limits(bad)


class _Fake(VecEnv):
    """Two envs whose infos carry given costs; reward 1 each step."""

    def __init__(self, costs):
        import gymnasium as gym

        super().__init__(2, gym.spaces.Box(-1, 1, (1,)), gym.spaces.Box(-1, 1, (1,)))
        self.costs, self.t = costs, 0

    def reset(self):
        return np.zeros((2, 1), np.float32)

    def step_async(self, actions):
        pass

    def step_wait(self):
        c = self.costs[self.t % len(self.costs)]
        self.t += 1
        infos = [{"cost_rate": c[i][0], "cost_stability": c[i][1]} for i in range(2)]
        return np.zeros((2, 1), np.float32), np.ones(2), np.zeros(2, bool), infos

    def close(self): pass
    def get_attr(self, name, indices=None): return [None, None]
    def set_attr(self, name, value, indices=None): pass
    def env_method(self, name, *a, indices=None, **k): return [None, None]
    def env_is_wrapped(self, cls, indices=None): return [False, False]
    def seed(self, seed=None): return [None, None]


def test_reward_minus_lambda_times_outage_and_projected_dual_ascent():
    # env 0 violates the rate (0.3 shortfall) every step, env 1 the stability every other step
    costs = [[(0.3, 0.0), (0.0, 1.0)], [(0.3, 0.0), (0.0, 0.0)]]
    w = LagrangianVecEnv(_Fake(costs), {"rate": 0.25, "stability": 0.5}, {"rate": 2.0, "stability": 1.0})
    w.reset()
    w.step_async(None)
    _, r, _, _ = w.step_wait()
    np.testing.assert_allclose(r, [1.0 - 2.0, 1.0 - 1.0])  # an indicator, not the shortfall size
    for _ in range(3):
        w.step_async(None)
        w.step_wait()
    cb = LagrangeCallback(w, lr=0.4)
    cb.init_callback(type("M", (), {"num_timesteps": 8, "get_env": lambda self: None,
                                    "logger": __import__("stable_baselines3.common.logger",
                                                         fromlist=["Logger"]).Logger(None, [])})())
    cb.on_rollout_end()
    # 8 slots: rate outage 4/8 = 0.5 (limit 0.25) -> 2 + 0.4 * 0.25; stability 2/8 (limit 0.5) -> 1 - 0.1
    np.testing.assert_allclose(w.lambdas, [2.1, 0.9])
    assert w.slots == 0
    w2 = LagrangianVecEnv(_Fake([[(0.0, 0.0), (0.0, 0.0)]]), {"rate": 0.1}, {"rate": 0.01})
    w2.step_async(None)
    w2.step_wait()
    LagrangeCallback.__init__(cb, w2, lr=1.0)
    cb._on_rollout_end()
    assert w2.lambdas[0] == 0.0  # projected onto lambda >= 0


def test_a_constrained_run_raises_the_multiplier_of_a_violated_limit_and_saves_it(tmp_path):
    out = tmp_path / "run"
    summary = main(Args(total_timesteps=8192, n_envs=32, overrides={"n_steps": 64}, eval_freq=4096, eval_episodes=2,
                        eval_max_steps=50, checkpoint_freq=0,
                        tensorboard=False, quiet=True, cost_limit="rate=0.05,stability=0.0", lagrange_lr=0.5,
                        out=str(out)))
    lam = load_lambdas(out)
    assert lam["rate"] > 0.0  # an untrained policy misses the rate in far more than 5 % of the slots
    assert summary["lagrange"]["lambdas"] == pytest.approx(lam)
    assert len(summary["evaluations"]) == 2  # held-out evaluations run beside the Lagrangian wrapper
    cfg = yaml.safe_load((out / "config.yml").read_text())
    assert cfg["args"]["env_overrides"] == {"w_rate": 0.0, "w_stab": 0.0}


def test_multi_drone_costs_count_the_share_of_drones_in_violation():
    """Per-drone costs (the multi-drone env's info): a slot's indicator is the share of drones violating."""
    costs = [[(np.array([0.3, 0.0, 0.0, 0.2]), np.zeros(4)), (np.zeros(4), np.array([0.0, 1.0, 0.0, 0.0]))]]
    w = LagrangianVecEnv(_Fake(costs), {"rate": 0.1, "stability": 0.1}, {"rate": 2.0, "stability": 4.0})
    w.step_async(None)
    _, r, _, _ = w.step_wait()
    np.testing.assert_allclose(r, [1.0 - 2.0 * 0.5, 1.0 - 4.0 * 0.25])
    np.testing.assert_allclose(w.count, [0.5, 0.25])


def test_a_constrained_multi_drone_run_reads_the_per_drone_costs(tmp_path):
    out = tmp_path / "run"
    main(Args(env_id="iscc_gym/ISCC-Multi-v0", env_overrides={"n_drones": 2}, total_timesteps=2048, n_envs=8,
              overrides={"n_steps": 64, "batch_size": 64}, eval_freq=0, checkpoint_freq=0, tensorboard=False,
              quiet=True, init_policy="none", cost_limit="rate=0.05", lagrange_lr=0.5, out=str(out)))
    rec = yaml.safe_load((out / "lagrange.yml").read_text())
    outage = [h["outage"]["rate"] for h in rec["history"]]
    assert all(0.0 <= o <= 1.0 for o in outage) and rec["lambdas"]["rate"] > 0.0
    # a rollout is 8 x 64 = 512 slots of 2 drones: a slot with one drone short counts 1/2, so some outage
    # fraction is an odd number of 1/1024 (whole-slot indicators would give multiples of 1/512 only)
    assert any(round(o * 1024) % 2 == 1 for o in outage)


def test_bad_limits_fail_before_training(tmp_path):
    with pytest.raises(ValueError, match="--cost-limit"):
        main(Args(total_timesteps=64, cost_limit="rate=2", out=str(tmp_path / "x"), quiet=True))
    assert not (tmp_path / "x").exists()


def test_algo_ppo_lag_is_ppo_with_the_lagrangian():
    from iscc_gym.train.cli import parse_args
    from iscc_gym.train.config import PPO_LAG_LIMITS

    a = parse_args(["--algo", "ppo-lag"])
    assert a.algo == "ppo" and a.cost_limit == PPO_LAG_LIMITS == "rate=0.05,stability=0.0"
    b = parse_args(["--algo", "ppo-lag", "--cost-limit", "rate=0.2"])
    assert b.algo == "ppo" and b.cost_limit == "rate=0.2"
    assert parse_args(["--algo", "ppo"]).cost_limit is None


def test_the_pareto_runs_train_at_the_comparisons_rate_and_ship_their_multipliers(tmp_path, monkeypatch):
    from iscc_gym.commands.protocol import PARETO_RATE_MIN_BPS as RATE_MIN_BPS

    from experiments import pareto_agents as TP

    a = TP.run_args("ppo-lag/0.10")
    assert a.algo == "ppo-lag" and a.cost_limit.startswith("rate=0.1,") and a.env_overrides == {"rate_min_bps":
                                                                                                RATE_MIN_BPS}
    assert TP.run_args("ppo/w3").env_overrides == {"rate_min_bps": RATE_MIN_BPS, "w_rate": 3.0}
    with pytest.raises(ValueError, match="not a Pareto run"):
        TP.run_args("ppo/w7")
    monkeypatch.chdir(tmp_path)
    TP.train_all(["ppo-lag/0.05"], total_timesteps=256, dest=tmp_path / "dest", out_root=str(tmp_path / "runs"),
                 n_envs=4, overrides={"n_steps": 32, "batch_size": 64}, eval_freq=0)
    shipped = tmp_path / "dest" / "ppo-lag" / "0.05"
    assert (shipped / "model.zip").is_file() and (shipped / "lagrange.yml").is_file()
    assert yaml.safe_load((shipped / "lagrange.yml").read_text())["limits"]["rate"] == 0.05
