"""Wrappers for constrained-RL libraries."""

from __future__ import annotations

import gymnasium as gym

__all__ = ["SafetyCostWrapper"]


class SafetyCostWrapper(gym.Wrapper):
    """Return Safety-Gymnasium's 6-tuple ``(obs, reward, cost, terminated, truncated, info)``.

    ``cost`` is ``info["cost"]``: the normalised data-rate shortfall plus the stability-violation
    indicator of the slot (both also in ``info`` separately). ``reset`` is unchanged.
    """

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, float(info["cost"]), terminated, truncated, info
