"""PPO on the device env (:class:`iscc_gym.gpu.vector_env.DeviceVectorEnv`): rollouts, normalisation, GAE and updates
all on one torch device, the env's tensors read without copies. ``python -m train --device cuda`` runs it
(:mod:`iscc_gym.train.device`).

The smallest clear PPO the project can own, written to SB3's PPO step for step (clipped surrogate, unclipped value
loss, per-minibatch advantage normalisation, Adam with eps 1e-5, gradient norm clip, VecNormalize's running
observation and return statistics) with SB3's own network (:class:`stable_baselines3.common.policies.
ActorCriticPolicy`), so a run saves as an SB3 ``model.zip`` with its ``vecnormalize.pkl``: ``python -m eval`` and
:class:`iscc_gym.agents.sb3_policy.SB3Policy` load it like every other agent and compare it on the CPU with common
random numbers. Why not a library (docs/gpu.md): rsl-rl-lib, skrl and TorchRL each want their own env wrapper and
policy classes (TensorDict observations, their checkpoints), none of which ``predict`` loads.

Scaled to its batch (issue 46): a GPU rollout holds some 100k envs x 16 steps, where SB3 on a CPU holds 4,096
samples; at SB3's constant rate and minibatch size, PPO took one optimizer step per 5,461 samples. The device run
splits each rollout into :data:`N_MINIBATCHES` minibatches (rsl_rl's and CleanRL's GPU variants: 4 and 2-4) and
can adapt the rate to a KL target as rsl_rl does (``lr_schedule="kl"``: the rate is divided by 1.5
after a minibatch whose KL exceeds twice ``desired_kl``, multiplied by 1.5 after one below half of it, kept within
[:data:`LR_BOUNDS`]; the device default, :data:`DEVICE_DEFAULTS`: on the CPU stand-in the fastest of the three,
docs/gpu.md); ``"linear"`` anneals it to zero over the run (CleanRL's), ``"constant"`` keeps SB3's.

Rows start spread over the mission (``random_start``, the default; :class:`iscc_gym.gpu.vector_env.DeviceVectorEnv`):
with thousands of envs and 16-step rollouts a run lasts about one mission per env, and rows that all start at slot 0
sweep the mission in step, every update's samples from one phase of it (the policy forgets the early slots while it
trains on the late ones: on the stand-in it got worse as it trained, docs/gpu.md); rsl_rl starts its envs at random
episode lengths for the same reason.

Differences from SB3, stated: the normalisation statistics (VecNormalize's observation and return statistics) are
updated once a rollout, from all its samples, not after every step (the rollout is normalised by the statistics it
started with, its rewards scaled by those it ended with); a truncated episode's last reward is bootstrapped with the
value of its last observation (the env's ``final_obs``), as SB3 does; the rollout's episodes are the device's.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

__all__ = ["DevicePPOConfig", "RunningMeanStd", "Trained", "gae", "train", "to_sb3", "paper_config", "DEVICE_DEFAULTS",
           "LR_SCHEDULES", "LR_BOUNDS", "N_MINIBATCHES", "default_n_envs", "adapt_lr"]

#: Settings of a device run where the task's YAML entry (sized for SB3 on a CPU) does not fit a GPU: many envs
#: (:func:`default_n_envs` on a GPU), a rollout of 16 steps cut into :data:`N_MINIBATCHES` minibatches, the rate
#: adapted to a KL target as rsl_rl's (on the CPU stand-in the paper agent came within 1 % of ``myopic`` in 31 s of
#: training with it; ``constant`` and ``linear`` not in 120 s, docs/gpu.md).
DEVICE_DEFAULTS = {"n_envs": 4096, "n_steps": 16, "pool_size": 1024, "lr_schedule": "kl", "desired_kl": 0.01}
#: Minibatches a rollout is cut into by default (``batch_size`` = ``n_envs * n_steps / N_MINIBATCHES``).
N_MINIBATCHES = 4
#: ``lr_schedule``: ``constant`` (SB3's), ``kl`` (rsl_rl's KL-adaptive rate), ``linear`` (annealed to 0, CleanRL's).
LR_SCHEDULES = ("constant", "kl", "linear")
#: The KL-adaptive rate stays within these bounds (rsl_rl's).
LR_BOUNDS = (1e-5, 1e-2)
#: Resident threads an SM holds at the step kernel's register use (~240 a thread: two blocks of 128), times four
#: waves: :func:`default_n_envs` on a GPU.
_ENVS_PER_SM = 1024


def default_n_envs(device: str) -> int:
    """Envs of a device run when none is asked: on a GPU enough to fill it (its SMs x 1,024: four waves of the step
    kernel's resident blocks; 135,168 on an H100 or H200), on the CPU stand-in :data:`DEVICE_DEFAULTS`'s 4,096.
    """
    if device != "cuda":
        return DEVICE_DEFAULTS["n_envs"]
    try:
        import torch

        return int(torch.cuda.get_device_properties(0).multi_processor_count) * _ENVS_PER_SM
    except Exception:  # noqa: BLE001 - no GPU here: the env says so when it is built
        return DEVICE_DEFAULTS["n_envs"]


def adapt_lr(lr: float, kl: float, desired_kl: float) -> float:
    """rsl_rl's KL-adaptive rate: ``lr / 1.5`` after a minibatch whose KL is above ``2 * desired_kl``, ``lr * 1.5``
    below ``desired_kl / 2``, within :data:`LR_BOUNDS`.
    """
    if kl > 2.0 * desired_kl:
        lr = lr / 1.5
    elif kl < 0.5 * desired_kl:
        lr = lr * 1.5
    return min(max(lr, LR_BOUNDS[0]), LR_BOUNDS[1])


@dataclass
class DevicePPOConfig:
    """A device PPO run (SB3's PPO names and defaults where they exist)."""

    env_id: str = "iscc_gym/ISCC-v0"
    scenario: str | None = None  # the Scenario preset; None: the one env_id is registered with
    device: str = "cuda"
    total_timesteps: int = 20_000_000
    n_envs: int = 4096
    n_steps: int = 16
    batch_size: int | None = None  # None: a rollout cut into N_MINIBATCHES minibatches
    n_epochs: int = 3
    learning_rate: float = 3e-4
    lr_schedule: str = "constant"
    desired_kl: float = 0.01
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_range: float = 0.2
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    net_arch: list = field(default_factory=lambda: [64, 64])
    activation: str = "Tanh"
    log_std_init: float = 0.0
    normalize: bool = True
    norm_reward: bool = True
    clip_obs: float = 10.0
    clip_reward: float = 10.0
    pool_size: int = 1024
    random_start: bool = True  # each row's first episode at a random slot (DeviceVectorEnv's random_start)
    seed: int = 0
    env_overrides: dict = field(default_factory=dict)

    def __post_init__(self):
        sized = all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in (self.n_envs, self.n_steps))
        if self.batch_size is None and sized:
            self.batch_size = max(1, int(self.n_envs) * int(self.n_steps) // N_MINIBATCHES)
        if not isinstance(self.random_start, (bool, np.bool_)):
            raise ValueError(f"random_start = {self.random_start!r}; expected True or False")
        if self.lr_schedule not in LR_SCHEDULES:
            raise ValueError(f"lr_schedule = {self.lr_schedule!r}; use one of {', '.join(LR_SCHEDULES)}")
        if not (isinstance(self.desired_kl, (int, float)) and 0.0 < self.desired_kl < math.inf):
            raise ValueError(f"desired_kl = {self.desired_kl!r}; expected a number > 0")
        for name in ("total_timesteps", "n_envs", "n_steps", "batch_size", "n_epochs", "pool_size"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{name} = {v!r}; expected an integer >= 1")
        for name, lo, hi in (("gamma", 0.0, 1.0), ("gae_lambda", 0.0, 1.0), ("clip_range", 0.0, math.inf),
                             ("learning_rate", 0.0, math.inf)):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and lo < v <= hi) or not math.isfinite(v):
                raise ValueError(f"{name} = {v!r}; expected a number in ({lo}, {hi}]")


class RunningMeanStd:
    """SB3's ``RunningMeanStd`` (the parallel-variance update of Chan et al.) on torch tensors, in float64."""

    def __init__(self, shape, device, epsilon: float = 1e-4):
        import torch

        self.mean = torch.zeros(shape, dtype=torch.float64, device=device)
        self.var = torch.ones(shape, dtype=torch.float64, device=device)
        self.count = epsilon

    def update(self, x) -> None:
        import torch

        x = x.to(torch.float64)
        b_mean, b_var, b_count = x.mean(0), x.var(0, unbiased=False), x.shape[0]
        delta = b_mean - self.mean
        tot = self.count + b_count
        self.mean = self.mean + delta * b_count / tot
        m2 = self.var * self.count + b_var * b_count + delta.square() * self.count * b_count / tot
        self.var = m2 / tot
        self.count = tot


def gae(rewards, values, dones, last_value, gamma: float, lam: float):
    """Generalised advantage estimates and returns of a rollout (T, N) as SB3's ``RolloutBuffer``
    (``compute_returns_and_advantage``): ``dones[t]`` marks that the episode ended at step t (no bootstrap from t + 1).
    """
    import torch

    adv = torch.zeros_like(rewards)
    last = torch.zeros_like(last_value)
    n = rewards.shape[0]
    for t in range(n - 1, -1, -1):
        next_value = last_value if t == n - 1 else values[t + 1]
        live = 1.0 - dones[t]
        delta = rewards[t] + gamma * next_value * live - values[t]
        last = delta + gamma * lam * live * last
        adv[t] = last
    return adv, adv + values


def _policy(cfg: DevicePPOConfig, env, device):
    import torch
    from stable_baselines3.common.policies import ActorCriticPolicy

    act = getattr(torch.nn, cfg.activation)
    pol = ActorCriticPolicy(env.single_observation_space, env.single_action_space, lambda _: cfg.learning_rate,
                            net_arch=list(cfg.net_arch), activation_fn=act, log_std_init=cfg.log_std_init)
    return pol.to(device)


@dataclass
class Trained:
    """What a device run learned: SB3's policy network (on the run's device) and the running observation and return
    statistics (:func:`to_sb3` turns them into an SB3 model and its VecNormalize).
    """

    policy: Any
    obs_rms: RunningMeanStd
    ret_rms: RunningMeanStd


def train(cfg: DevicePPOConfig, callback=None, quiet: bool = True) -> tuple[dict, Trained]:
    """Train a PPO agent on the device env; returns the summary (steps, wall time, throughput, the learning curve as
    (steps, mean reward per step of the update's rollout)) and the :class:`Trained` agent.
    ``callback(summary_so_far, policy, obs_rms)`` after each update may return True to stop (the bench's
    time-to-level).
    """
    import torch

    from iscc_gym.gpu.vector_env import DeviceVectorEnv

    torch.manual_seed(cfg.seed)
    env = DeviceVectorEnv(cfg.env_id, num_envs=cfg.n_envs, device=cfg.device, pool_size=min(cfg.pool_size, cfg.n_envs),
                          scenario=cfg.scenario, random_start=cfg.random_start, **cfg.env_overrides)
    dev = env.obs.device
    pol = _policy(cfg, env, dev)
    opt = torch.optim.Adam(pol.parameters(), lr=cfg.learning_rate, eps=1e-5)
    n, t_len, d_obs = cfg.n_envs, cfg.n_steps, env.obs_size
    obs_buf = torch.zeros((t_len, n, d_obs), device=dev)
    act_buf = torch.zeros((t_len, n, 3), device=dev)
    logp_buf = torch.zeros((t_len, n), device=dev)
    rew_buf = torch.zeros((t_len, n), device=dev)
    done_buf = torch.zeros((t_len, n), device=dev)
    val_buf = torch.zeros((t_len, n), device=dev)
    obs_rms = RunningMeanStd((d_obs,), dev)
    ret_rms = RunningMeanStd((), dev)
    ret = torch.zeros(n, dtype=torch.float64, device=dev)

    def norm(o):
        if not cfg.normalize:
            return o
        return ((o.double() - obs_rms.mean) / torch.sqrt(obs_rms.var + 1e-8)).clamp(-cfg.clip_obs, cfg.clip_obs).float()

    raw_buf = torch.zeros((t_len, n, d_obs), device=dev)  # the rollout's raw observations: the statistics' update
    ret_buf = torch.zeros((t_len, n), dtype=torch.float64, device=dev)  # discounted returns: the reward scaling
    boot_buf = torch.zeros((t_len, n), device=dev)  # gamma V(final obs) of truncated rows, added to the scaled reward
    raw, _ = env.reset(seed=cfg.seed)
    if cfg.normalize:
        obs_rms.update(raw)
    obs = norm(raw)
    steps, iters, t0 = 0, 0, time.perf_counter()
    curve, rollout_s, update_s = [], 0.0, 0.0
    batch = n * t_len
    mb = min(cfg.batch_size, batch)
    lr = float(cfg.learning_rate)
    stop = False
    while steps < cfg.total_timesteps and not stop:
        ta = time.perf_counter()
        rsum = 0.0
        with torch.no_grad():
            for t in range(t_len):
                actions, values, logp = pol(obs)
                obs_buf[t], act_buf[t], logp_buf[t], val_buf[t] = obs, actions, logp, values.flatten()
                raw, reward, term, trunc, info = env.step(actions, check=False)
                done = term | trunc
                r = reward.double()
                rsum = rsum + r.sum()  # on the device: read once an update
                rew_buf[t] = r.float()
                ret = ret * cfg.gamma + r
                ret_buf[t] = ret
                ret = torch.where(done, torch.zeros_like(ret), ret)
                # SB3's bootstrap of a truncation: gamma V(the episode's last observation), normalised as the rollout
                cut = trunc & ~term
                boot_buf[t] = torch.where(cut, cfg.gamma * pol.predict_values(norm(info["final_obs"])).flatten(),
                                          torch.zeros_like(boot_buf[t]))
                done_buf[t] = done.float()
                raw_buf[t] = raw
                obs = norm(raw)
            last_value = pol.predict_values(obs).flatten()
            if cfg.normalize:  # the statistics once a rollout, from all its samples
                obs_rms.update(raw_buf.reshape(batch, d_obs))
                if cfg.norm_reward:  # VecNormalize's reward scaling, by the return statistics the rollout ends with
                    ret_rms.update(ret_buf.reshape(batch))
                    rew_buf.copy_((rew_buf.double() / torch.sqrt(ret_rms.var + 1e-8))
                                  .clamp(-cfg.clip_reward, cfg.clip_reward).float())
            rew_buf.add_(boot_buf)
            adv, returns = gae(rew_buf, val_buf, done_buf, last_value, cfg.gamma, cfg.gae_lambda)
            obs = norm(raw)  # the next rollout's first observation, by the statistics it will use
        if dev.type == "cuda":
            torch.cuda.synchronize()
        tb = time.perf_counter()
        rollout_s += tb - ta
        if cfg.lr_schedule == "linear":  # CleanRL's annealing: from the rate to 0 over the run
            lr = float(cfg.learning_rate) * max(1.0 - steps / cfg.total_timesteps, 0.0)
        b_obs, b_act = obs_buf.reshape(batch, d_obs), act_buf.reshape(batch, 3)
        b_logp, b_adv, b_ret = logp_buf.reshape(batch), adv.reshape(batch), returns.reshape(batch)
        kls = []
        for _ in range(cfg.n_epochs):
            perm = torch.randperm(batch, device=dev)
            for k in range(0, batch, mb):
                idx = perm[k:k + mb]
                values, logp, entropy = pol.evaluate_actions(b_obs[idx], b_act[idx])
                a = b_adv[idx]
                if a.numel() > 1:
                    a = (a - a.mean()) / (a.std() + 1e-8)
                log_ratio = logp - b_logp[idx]
                ratio = torch.exp(log_ratio)
                pg = -torch.min(a * ratio, a * ratio.clamp(1 - cfg.clip_range, 1 + cfg.clip_range)).mean()
                vf = torch.nn.functional.mse_loss(b_ret[idx], values.flatten())
                ent = -torch.mean(-logp) if entropy is None else -torch.mean(entropy)
                loss = pg + cfg.ent_coef * ent + cfg.vf_coef * vf
                kl = ((ratio - 1.0) - log_ratio).mean().detach()  # SB3's approx_kl (Schulman's k3 estimator)
                kls.append(kl)
                if cfg.lr_schedule == "kl":  # rsl_rl: the rate of this step from the KL of the last one
                    lr = adapt_lr(lr, float(kl), cfg.desired_kl) if len(kls) > 1 else lr
                for g in opt.param_groups:
                    g["lr"] = lr
                opt.zero_grad()
                loss.backward()
                torch.nn.utils.clip_grad_norm_(pol.parameters(), cfg.max_grad_norm)
                opt.step()
        if dev.type == "cuda":
            torch.cuda.synchronize()
        update_s += time.perf_counter() - tb
        steps += batch
        iters += 1
        wall = time.perf_counter() - t0
        curve.append((steps, float(rsum) / batch, wall, lr, float(torch.stack(kls).mean())))
        summary = {"timesteps": steps, "iterations": iters, "wall_time_s": wall, "rollout_s": rollout_s,
                   "update_s": update_s, "curve": curve}
        if not quiet and iters % 20 == 0:
            print(f"  {steps:>12,d} steps  {steps / summary['wall_time_s'] / 1e6:6.2f}M steps/s  "
                  f"reward/step {curve[-1][1]:8.3f}", flush=True)
        if callback is not None and callback(summary, pol, obs_rms):
            stop = True
    wall = time.perf_counter() - t0
    summary = {"timesteps": steps, "iterations": iters, "wall_time_s": wall, "rollout_s": rollout_s,
               "update_s": update_s, "steps_per_s": steps / wall, "curve": curve, "config": asdict(cfg),
               "device": str(dev)}
    env.close()
    return summary, Trained(pol, obs_rms, ret_rms)


def to_sb3(cfg: DevicePPOConfig, trained: Trained, timesteps: int):
    """``(model, vecnormalize)``: the trained agent as an SB3 PPO model on the CPU (the run's settings and SB3's
    network with the trained weights) and a VecNormalize holding its observation and return statistics (None without
    normalisation), what ``python -m train`` saves (:func:`iscc_gym.train.runs.save_unit`) and
    :class:`iscc_gym.agents.sb3_policy.SB3Policy` loads.
    """
    import gymnasium as gym
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    import iscc_gym  # noqa: F401  (the env ids)

    scenario = {} if cfg.scenario is None else {"scenario": cfg.scenario}
    venv = DummyVecEnv([lambda: gym.make(cfg.env_id, **scenario, **cfg.env_overrides)])
    with warnings.catch_warnings():  # SB3 warns that a batch exceeds its (unused) one-env rollout buffer
        warnings.simplefilter("ignore", UserWarning)
        model = PPO("MlpPolicy", venv, learning_rate=cfg.learning_rate, n_steps=cfg.n_steps, batch_size=cfg.batch_size,
                    n_epochs=cfg.n_epochs, gamma=cfg.gamma, gae_lambda=cfg.gae_lambda, clip_range=cfg.clip_range,
                    ent_coef=cfg.ent_coef, vf_coef=cfg.vf_coef, max_grad_norm=cfg.max_grad_norm, device="cpu",
                    policy_kwargs={"net_arch": list(cfg.net_arch), "activation_fn": getattr(torch.nn, cfg.activation),
                                   "log_std_init": cfg.log_std_init})
    model.policy.load_state_dict({k: v.detach().cpu() for k, v in trained.policy.state_dict().items()})
    model.num_timesteps = int(timesteps)
    if not cfg.normalize:
        return model, None
    vn = VecNormalize(venv, gamma=cfg.gamma, clip_obs=cfg.clip_obs, clip_reward=cfg.clip_reward,
                      norm_reward=cfg.norm_reward)
    vn.obs_rms.mean = trained.obs_rms.mean.cpu().numpy().copy()
    vn.obs_rms.var = trained.obs_rms.var.cpu().numpy().copy()
    vn.obs_rms.count = float(trained.obs_rms.count)
    vn.ret_rms.mean, vn.ret_rms.var = float(trained.ret_rms.mean), float(trained.ret_rms.var)
    vn.ret_rms.count = float(trained.ret_rms.count)
    return model, vn


def paper_config(device: str = "cuda", **changes) -> DevicePPOConfig:
    """The paper task's device run: its YAML entry's learning settings (``train/hyperparams.yml``, the entry
    ``python -m train --device`` reads; ``tests/gpu/test_device_ppo.py`` checks the two agree) on the device's batch
    sizes and rate schedule (:data:`DEVICE_DEFAULTS`, :func:`default_n_envs`), with ``changes``.
    """
    kw = dict(env_id="iscc_gym/ISCC-v0", scenario="paper", device="cuda" if device == "cuda" else "cpu",
              total_timesteps=4_000_000,
              n_epochs=3, learning_rate=0.00022829724408019228, gamma=0.3, gae_lambda=0.8, clip_range=0.3,
              ent_coef=0.014029585467490158, net_arch=[32, 32], activation="Tanh", log_std_init=-0.7903302449680623,
              normalize=True, norm_reward=True, **{**DEVICE_DEFAULTS, "n_envs": default_n_envs(device)})
    kw.update(changes)
    return DevicePPOConfig(**kw)
