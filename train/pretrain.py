"""Behaviour-cloning warm start: a PPO policy initialised to imitate a scripted policy, then trained.

``python -m train`` with ``init_policy: myopic`` in the YAML entry (or ``--init-policy SPEC``, any
:func:`agents.make_policy` spec) first plays the scripted policy on ``init_envs`` envs of its own for
``init_steps`` steps each (whole missions by default, so every phase of a mission is seen; seeds
from :data:`iscc_gym.commands.protocol.INIT_SEED_START`, training seeds disjoint from every evaluation seed),
gathering VecNormalize statistics on the way (they become the training env's). It then fits the
actor's mean action to the scripted actions and the critic to the discounted (normalised) returns
of those steps, both by Adam on mean-squared error, and sets the action noise to ``init_log_std``.
PPO then improves on the scripted policy's level instead of starting from a random policy. The
warm start is reported with the agent (docs/results.md says the agent starts from the imitated
baseline).
"""

from __future__ import annotations

import time

import numpy as np

__all__ = ["collect", "behaviour_clone"]


def collect(venv, policy, n_steps: int) -> dict:
    """Play ``policy`` (a scripted policy's ``predict`` on raw observations) for ``n_steps`` steps of
    every env of ``venv`` (an SB3 VecNormalize, in training mode: its statistics are updated).

    Returns raw observations (T, n, obs), actions (T, n, 3), raw rewards (T, n) and the episode
    ends (T, n).
    """
    venv.reset()
    raw = venv.get_original_obs()
    obs_buf, act_buf, rew_buf, done_buf = [], [], [], []
    state, start = None, np.ones(venv.num_envs, dtype=bool)
    for _ in range(n_steps):
        action, state = policy.predict(raw, state=state, episode_start=start, deterministic=True)
        action = np.asarray(action, dtype=np.float32).reshape(venv.num_envs, -1)
        obs_buf.append(raw.copy())
        act_buf.append(action)
        _, _, done, _ = venv.step(action)
        rew_buf.append(np.asarray(venv.get_original_reward(), dtype=np.float64))
        done_buf.append(np.asarray(done, dtype=bool))
        start = done
        raw = venv.get_original_obs()
    return {"obs": np.array(obs_buf), "actions": np.array(act_buf), "rewards": np.array(rew_buf),
            "dones": np.array(done_buf)}


def _returns(rewards, dones, gamma: float) -> np.ndarray:
    """Discounted returns of each step within its episode (zero after the last collected step)."""
    out = np.zeros_like(rewards)
    acc = np.zeros(rewards.shape[1])
    for t in range(len(rewards) - 1, -1, -1):
        acc = rewards[t] + gamma * acc * ~dones[t]
        out[t] = acc
    return out


def behaviour_clone(model, venv, policy, n_steps: int, collect_env=None, grad_steps: int | None = None,
                    batch_size: int = 1024, learning_rate: float = 1e-3, log_std: float | None = None,
                    seed: int = 0, log=print) -> dict:
    """Fit ``model``'s actor (mean action) and critic to ``policy`` played on ``venv`` (see the module).

    Parameters
    ----------
    model : stable_baselines3 PPO (an ``ActorCriticPolicy``)
    venv : stable_baselines3 VecNormalize in training mode
        The training env; its normalisation statistics are replaced by ``collect_env``'s.
    policy : a scripted policy (``predict`` on raw observations)
    n_steps : int
        Steps per env to collect.
    collect_env : stable_baselines3 VecNormalize, optional
        Where the scripted policy plays (default ``venv``), wrapping the same env as ``venv``.
    grad_steps, batch_size, learning_rate :
        Of the supervised fit (Adam on random minibatches); ``grad_steps`` defaults to about 40
        passes over the samples, between 200 and 3,000 steps.
    log_std : float, optional
        Set the policy's log standard deviation to this after the fit (None: keep it).

    Returns
    -------
    dict
        Samples, the actor's and critic's final mean-squared errors, wall time.
    """
    import torch
    from stable_baselines3.common.vec_env import VecNormalize

    if not isinstance(venv, VecNormalize):
        raise ValueError("behaviour cloning needs the VecNormalize env (normalize: true); "
                         "its observation statistics are gathered while the scripted policy plays")
    if n_steps < 1:
        raise ValueError(f"init_steps = {n_steps}; use an integer >= 1")
    t0 = time.perf_counter()
    collect_env = venv if collect_env is None else collect_env
    data = collect(collect_env, policy, n_steps)
    if collect_env is not venv:
        venv.obs_rms, venv.ret_rms = collect_env.obs_rms.copy(), collect_env.ret_rms.copy()
    gamma = float(model.gamma)
    # returns of the rewards as PPO will see them: normalised with the final statistics
    returns = _returns(venv.normalize_reward(data["rewards"]), data["dones"], gamma)
    # the last ~5 horizons have truncated returns: the critic is fitted on the steps before them
    keep = max(1, n_steps - int(5.0 / max(1e-6, 1.0 - gamma)))
    obs = venv.normalize_obs(data["obs"].reshape(-1, data["obs"].shape[-1])).astype(np.float32)
    act = data["actions"].reshape(-1, data["actions"].shape[-1])
    ret = returns[:keep].reshape(-1)
    pol = model.policy
    pol.set_training_mode(True)
    x, y, r = torch.as_tensor(obs), torch.as_tensor(act), torch.as_tensor(ret, dtype=torch.float32)
    n_val = keep * collect_env.num_envs
    opt = torch.optim.Adam(pol.parameters(), lr=learning_rate)
    gen = torch.Generator().manual_seed(seed)
    if grad_steps is None:
        grad_steps = int(min(3000, max(200, 40 * len(x) // batch_size)))
    for _ in range(grad_steps):
        idx = torch.randint(0, len(x), (batch_size,), generator=gen)
        vidx = torch.randint(0, n_val, (batch_size,), generator=gen)
        latent_pi, _ = pol.mlp_extractor(pol.extract_features(x[idx]))
        _, latent_vf = pol.mlp_extractor(pol.extract_features(x[vidx]))
        loss = ((pol.action_net(latent_pi) - y[idx]) ** 2).mean() \
            + 0.5 * ((pol.value_net(latent_vf).squeeze(-1) - r[vidx]) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        latent_pi, latent_vf = pol.mlp_extractor(pol.extract_features(x))
        actor_mse = float(((pol.action_net(latent_pi) - y) ** 2).mean())
        critic_mse = float(((pol.value_net(latent_vf[:n_val]).squeeze(-1) - r) ** 2).mean())
        if log_std is not None:
            pol.log_std.fill_(float(log_std))
    pol.set_training_mode(False)
    out = {"samples": int(len(x)), "actor_mse": actor_mse, "critic_mse": critic_mse,
           "return_var": float(r.var()), "wall_time_s": time.perf_counter() - t0}
    log(f"behaviour cloning: {out['samples']:,} samples, actor MSE {actor_mse:.4g}, critic MSE {critic_mse:.4g} "
        f"(return variance {out['return_var']:.4g}), {out['wall_time_s']:.1f} s")
    return out
