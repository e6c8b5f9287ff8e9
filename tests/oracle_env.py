"""Test oracles of the env's task in plain numpy: the reward (:class:`iscc_gym.envs.env.ISCCEnv`, Rewards) and
the action map.

The library computes each once (:func:`iscc_gym.sim.kernel.reward_one`, :func:`iscc_gym.sim.kernel.split_one`,
also behind :func:`iscc_gym.sim.task.reward_and_costs` and :func:`iscc_gym.sim.task.action_to_split`); these
independent paths check them.
"""

from __future__ import annotations

import numpy as np

from iscc_gym.physics.stability import scenario_eps_star
from iscc_gym.scenario import Scenario


def reward_and_costs(s: Scenario, metrics: dict, n_next, evaluable=True):
    """``(cost_rate, cost_stability, reward, terminated, truncated)`` of a slot's metrics."""
    err, rate, eps = metrics["tracking_error_m"], metrics["rate_comm_bps"], metrics["eps_ctrl"]
    if s.rate_min_bps > 0:
        cost_rate = np.maximum(0.0, s.rate_min_bps - rate) / s.rate_min_bps
        cost_rate = np.where(np.isnan(rate), 1.0, cost_rate)
    else:
        cost_rate = np.zeros_like(rate)
    cost_stab = ((eps > scenario_eps_star(s)) | np.isnan(eps)).astype(float)
    terminated = np.asarray(metrics["diverged"], dtype=bool) | ~np.asarray(evaluable, dtype=bool)
    reward = -np.where(err <= s.max_tracking_error_m, err, s.max_tracking_error_m) \
        - s.w_rate * cost_rate - s.w_stab * cost_stab
    reward = reward - np.where(terminated, s.max_tracking_error_m * (s.n_slots - n_next), 0.0)
    truncated = ~terminated & (n_next >= s.n_slots)
    return cost_rate, cost_stab, reward, terminated, truncated


def action_to_split(action):
    """w_i = (clip(a_i, -1, 1) + 1) / 2, alpha = w / sum(w); the equal split where every w_i = 0."""
    w = (np.minimum(np.maximum(np.asarray(action, dtype=float), -1.0), 1.0) + 1.0) * 0.5
    total = w.sum(axis=-1, keepdims=True)
    empty = total <= 1e-12
    return np.where(empty, 1.0 / 3.0, w / np.where(empty, 1.0, total)) if empty.any() else w / total
