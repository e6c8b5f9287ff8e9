"""The RL libraries users bring (issue 23 item 4), each running the README's snippet of "Use with other
libraries" for a few steps: a CleanRL-style torch loop, TorchRL (GymEnv by id, GymWrapper on the native
vector env, PettingZooWrapper on the multi-drone view), Tianshou (vector envs + Collector), SuperSuit + SB3
on the PettingZoo view, rl-zoo3 (train and enjoy) and Ray RLlib on the PettingZoo view.

The light libraries are the ``clients`` extra (in ``test``, so CI runs them); rl-zoo3 and Ray RLlib are
heavy and their tests skip unless installed (README: how they were run). The first tests need no optional
library: they pin our side of the API the clients rely on.
"""

from __future__ import annotations

import multiprocessing
import os
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest

import iscc_gym
from iscc_gym import ENV_ID

#: the id form that needs no ``import iscc_gym`` (Gymnasium imports the module before the lookup)
PREFIXED_ID = "iscc_gym:" + ENV_ID
SAME_STEP = gym.vector.AutoresetMode.SAME_STEP


@pytest.fixture(autouse=True)
def _keep_the_multiprocessing_start_method():
    """Importing torchrl sets the global start method to "spawn", which would make every later test that
    starts worker processes (eval's, AsyncVectorEnv's) re-import the project in each worker: put it back."""
    before = multiprocessing.get_start_method(allow_none=True)
    yield
    multiprocessing.set_start_method(before, force=True)


@pytest.fixture(scope="module", autouse=True)
def prefixed_id_launch():
    """A new interpreter that never imports iscc_gym itself makes the env by its prefixed id (a CleanRL-style
    script), started at the module's start so that its imports (~4 s, one core) run beside the tests in this
    process; :func:`test_env_id_with_module_prefix_needs_no_import`, last, reads it: its Popen."""
    code = ("import sys, gymnasium as gym\n"
            "try:\n    gym.make('iscc_gym/ISCC-v0')\n"
            "except gym.error.Error as e:\n    print('bare id:', type(e).__name__)\n"
            "assert 'iscc_gym' not in sys.modules\n"
            f"env = gym.make({PREFIXED_ID!r}, max_episode_steps=3)\nenv.reset(seed=0)\n"
            "venv = gym.make_vec(" + repr(PREFIXED_ID) + ", num_envs=2)\n"
            "print(type(env.unwrapped).__name__, type(venv).__name__)\n")
    with subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                          env={**os.environ, "ISCC_GYM_QUIET": "1"}) as proc:
        yield proc
        if proc.poll() is None:
            proc.kill()


def _pz(n_drones=2):
    return iscc_gym.parallel_env(n_drones=n_drones)


# --- our side: what the clients rely on ------------------------------------------------------------


def test_pettingzoo_view_reset_infos_carry_the_step_keys():
    """TorchRL's PettingZooWrapper builds its specs from the reset infos (regression: they held only
    ``drone_seed``); every agent's reset info has the step's keys and types."""
    pz = _pz(3)
    _, infos = pz.reset(seed=4)
    _, _, _, _, step_infos = pz.step({a: pz.action_space(a).sample() for a in pz.agents})
    for a in pz.possible_agents:
        assert set(infos[a]) == set(step_infos[a]), a
        for key, val in infos[a].items():
            assert type(val) is type(step_infos[a][key]), key
            assert np.shape(val) == np.shape(step_infos[a][key]), key
        assert infos[a]["cost"] == infos[a]["cost_rate"] == infos[a]["cost_stability"] == 0.0
        assert infos[a]["slot"] == 0 and step_infos[a]["slot"] == 1
        assert 0.0 < infos[a]["tracking_error_m"] < 10.0  # the drone's initial error
        np.testing.assert_allclose(infos[a]["alpha"], 1.0 / 9.0)
        assert infos[a]["drone_seed"] == step_infos[a]["drone_seed"]


def test_pettingzoo_view_passes_pettingzoos_parallel_api_test():
    from pettingzoo.test import parallel_api_test

    parallel_api_test(_pz(2), num_cycles=20)


def test_pettingzoo_view_refuses_complex_actions():
    pz = _pz(2)
    pz.reset(seed=0)
    before = pz._env._state.x.copy()
    actions = {a: np.zeros(3) for a in pz.agents}
    actions["drone_1"] = np.array([0.5 + 0.5j, 0.0, 0.0])
    with pytest.raises(TypeError, match=r"actions\['drone_1'\] has complex dtype"):
        pz.step(actions)
    np.testing.assert_array_equal(pz._env._state.x, before)


# --- CleanRL-style: gym.make_vec and your own torch loop -------------------------------------------


def test_cleanrl_style_torch_loop():
    """CleanRL's continuous PPO pattern, in miniature: the prefixed id, the native vector env with
    Gymnasium's vector RecordEpisodeStatistics, a Gaussian torch policy, a few clipped-objective updates."""
    torch = pytest.importorskip("torch")
    torch.manual_seed(0)
    envs = gym.wrappers.vector.RecordEpisodeStatistics(
        gym.make_vec(PREFIXED_ID, num_envs=4, vectorization_mode="vector_entry_point", max_episode_steps=12))
    obs_dim, act_dim = envs.single_observation_space.shape[0], envs.single_action_space.shape[0]
    mean = torch.nn.Sequential(torch.nn.Linear(obs_dim, 16), torch.nn.Tanh(), torch.nn.Linear(16, act_dim))
    log_std = torch.nn.Parameter(torch.full((act_dim,), -0.5))
    opt = torch.optim.Adam([*mean.parameters(), log_std], lr=3e-3)
    start = [p.detach().clone() for p in mean.parameters()]
    obs, _ = envs.reset(seed=1)
    returns = []
    for _ in range(3):  # iterations of 8 steps x 4 envs
        batch_obs, batch_act, batch_logp, batch_rew = [], [], [], []
        for _ in range(8):
            o = torch.as_tensor(obs)
            with torch.no_grad():
                dist = torch.distributions.Normal(mean(o), log_std.exp())
                act = dist.sample()
            obs, rew, term, trunc, info = envs.step(act.numpy())
            batch_obs.append(o), batch_act.append(act), batch_logp.append(dist.log_prob(act).sum(-1))
            batch_rew.append(torch.as_tensor(rew, dtype=torch.float32))
            if "episode" in info:
                returns += list(info["episode"]["r"][info["_episode"]])
        o, a, old_logp = torch.cat(batch_obs), torch.cat(batch_act), torch.cat(batch_logp)
        adv = torch.cat(batch_rew)
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        for _ in range(2):
            ratio = (torch.distributions.Normal(mean(o), log_std.exp()).log_prob(a).sum(-1) - old_logp).exp()
            loss = -torch.min(ratio * adv, ratio.clamp(0.8, 1.2) * adv).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
    assert torch.isfinite(loss)
    assert any(not torch.equal(p, q) for p, q in zip(mean.parameters(), start, strict=True))
    assert len(returns) >= 4 and np.all(np.isfinite(returns))  # every sub-env finished a 12-step episode


# --- TorchRL -------------------------------------------------------------------------------------


def test_torchrl_gymenv_by_id():
    """GymEnv passes frameskip=1 and retries without it only on Python's own TypeError wording."""
    pytest.importorskip("torchrl")
    from torchrl.envs import GymEnv

    env = GymEnv(ENV_ID, max_episode_steps=6)
    td = env.rollout(10, break_when_any_done=False)  # crosses the end of a 6-step episode
    assert td["next", "observation"].shape == (10, 23)
    assert td["next", "truncated"].squeeze(-1).tolist() == [False] * 5 + [True] + [False] * 4
    env.close()


def test_torchrl_gymwrapper_on_the_native_vector_env_same_step():
    """TorchRL's GymWrapper takes a vector env only with same-step autoreset."""
    pytest.importorskip("torchrl")
    from torchrl.envs import GymWrapper

    env = GymWrapper(gym.make_vec(ENV_ID, num_envs=2, max_episode_steps=3, autoreset_mode=SAME_STEP))
    td = env.rollout(7, break_when_any_done=False)
    assert td.batch_size == (2, 7)
    done = td["next", "done"].squeeze(-1)
    assert done.tolist() == [[False, False, True] * 2 + [False]] * 2
    assert td["next", "reward"].abs().sum() > 0


def test_torchrl_pettingzoo_wrapper_on_the_multi_drone_view():
    pytest.importorskip("torchrl")
    from torchrl.envs.libs.pettingzoo import PettingZooWrapper

    env = PettingZooWrapper(_pz(2), use_mask=True)
    td = env.rollout(5)
    assert td["next", "drone", "reward"].shape == (5, 2, 1)
    assert td["next", "drone", "info", "tracking_error_m"].shape == (5, 2)
    assert td["next", "drone", "info", "cost"].isfinite().all()
    env.close()


# --- Tianshou ------------------------------------------------------------------------------------


def test_tianshou_vector_env_and_collector(monkeypatch):
    pytest.importorskip("tianshou")
    from tianshou.algorithm.algorithm_base import Policy, RandomActionPolicy
    from tianshou.data import Collector, VectorReplayBuffer
    from tianshou.data.buffer.manager import ReplayBufferManager
    from tianshou.env import DummyVectorEnv  # SubprocVectorEnv alike (slower to start: each worker imports)

    # Tianshou compiles its numba helpers (returns, buffer indices; uncached) ahead of time in every process on
    # building a policy or a vector buffer, 7-16 s; the warm-ups are skipped here: a helper collection calls
    # still compiles on its first call
    monkeypatch.setattr(Policy, "_compile", staticmethod(lambda: None))
    monkeypatch.setattr(ReplayBufferManager, "_compile", lambda self: None)
    envs = DummyVectorEnv([lambda: gym.make(PREFIXED_ID, max_episode_steps=10)] * 2)
    try:
        envs.seed(0)
        collector = Collector(RandomActionPolicy(envs.action_space[0]), envs, VectorReplayBuffer(100, 2))
        collector.reset()
        stats = collector.collect(n_step=40)
        assert stats.n_collected_steps == 40 and stats.n_collected_episodes == 4
        assert np.all(np.isfinite(stats.returns))
        assert np.all(np.isfinite(collector.buffer.info["cost"][:40]))
    finally:
        envs.close()


# --- SuperSuit + SB3 on the PettingZoo view -------------------------------------------------------


def test_supersuit_sb3_ppo_on_the_pettingzoo_view():
    ss = pytest.importorskip("supersuit")
    pytest.importorskip("stable_baselines3")
    import torch
    from stable_baselines3 import PPO

    torch.manual_seed(0)
    venv = ss.pettingzoo_env_to_vec_env_v1(_pz(2))  # one SB3 env per drone, shared policy
    venv = ss.concat_vec_envs_v1(venv, 2, num_cpus=0, base_class="stable_baselines3")
    assert venv.num_envs == 4
    model = PPO("MlpPolicy", venv, n_steps=16, batch_size=32, n_epochs=1, verbose=0)  # no seed=: ConcatVecEnv
    model.learn(128)
    assert model.num_timesteps == 128
    action, _ = model.predict(venv.reset(), deterministic=True)
    assert action.shape == (4, 3)
    venv.close()


def test_env_id_with_module_prefix_needs_no_import(prefixed_id_launch):
    """A CleanRL-style script calls ``gym.make(args.env_id)`` and never imports iscc_gym. Gymnasium 1.x has
    no plugin entry points (1.0 removed them), so the bare id is unknown in a fresh interpreter; the
    ``iscc_gym:`` prefix makes Gymnasium import the registering module itself (:func:`prefixed_id_launch`)."""
    out, err = prefixed_id_launch.communicate(timeout=300)
    assert prefixed_id_launch.returncode == 0, err
    assert out.split("\n")[:2] == ["bare id: NamespaceNotFound", "ISCCEnv ISCCVectorEnv"]


# --- heavy clients: skipped unless installed (README: how they were run) ---------------------------


def test_rl_zoo3_train_and_enjoy(tmp_path):
    """``python -m rl_zoo3.train`` with the project's hyperparameters for a few hundred steps, then
    ``python -m rl_zoo3.enjoy`` without ``--no-render``: the env's headless ``human`` mode prints its
    status line."""
    pytest.importorskip("rl_zoo3")
    common = ["--algo", "ppo", "--env", ENV_ID, "--gym-packages", "iscc_gym", "-f", str(tmp_path),
              "--env-kwargs", "max_episode_steps:20"]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "ISCC_GYM_QUIET": "1"}
    train = subprocess.run([sys.executable, "-m", "rl_zoo3.train", *common, "-conf", _hyperparams(), "-n", "256",
                            "--hyperparams", "n_envs:2", "--eval-freq", "-1", "--seed", "0"],
                           capture_output=True, text=True, timeout=600, env=env)
    assert train.returncode == 0, train.stderr[-3000:]
    assert (tmp_path / "ppo" / "iscc_gym-ISCC-v0_1" / "iscc_gym-ISCC-v0" / "vecnormalize.pkl").is_file()
    enjoy = subprocess.run([sys.executable, "-m", "rl_zoo3.enjoy", *common, "--exp-id", "1", "-n", "25"],
                           capture_output=True, text=True, timeout=600, env=env)
    assert enjoy.returncode == 0, enjoy.stderr[-3000:]
    lines = [ln for ln in enjoy.stdout.splitlines() if ln.startswith("ISCC t=")]
    assert len(lines) >= 25 and "tracking error" in lines[-1]


def _hyperparams() -> str:
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    return os.path.join(root, "train", "hyperparams.yml")


def test_ray_rllib_ppo_on_the_pettingzoo_view():
    pytest.importorskip("ray.rllib")
    import ray
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv
    from ray.tune.registry import register_env

    register_env("iscc_multi", lambda cfg: ParallelPettingZooEnv(_pz(2)))
    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False)
    try:
        config = (PPOConfig().environment("iscc_multi")
                  .multi_agent(policies={"shared"}, policy_mapping_fn=lambda agent_id, *a, **k: "shared")
                  .env_runners(num_env_runners=0)
                  .training(train_batch_size=128, minibatch_size=64, num_epochs=1))
        algo = config.build_algo()
        result = algo.train()
        assert result["env_runners"]["num_env_steps_sampled_lifetime"] >= 128
        algo.stop()
    finally:
        ray.shutdown()
