r"""Residual learning on a scripted policy: the agent's action corrects a base policy's.

A residual agent (Silver et al., "Residual Policy Learning", 2018; Johannink et al., "Residual
Reinforcement Learning for Robot Control", 2019) acts in :math:`[-1, 1]^3` like any agent, but the env
plays

.. math:: a_\mathrm{env} = \mathrm{clip}\big(a_\mathrm{base}(o) + s\,a_\mathrm{agent}(o),\; -1,\; 1\big)

where :math:`a_\mathrm{base}` is a scripted policy's action on the same raw observation :math:`o` and
:math:`s` the residual's scale. An agent whose action is zero plays the base policy exactly, so training
starts at the base's level (PPO's action head starts near zero) and keeps what it cannot improve.

``python -m train`` trains one with ``residual: SPEC`` (an :func:`agents.make_policy` spec) and
``residual_scale`` in its settings (``--residual``, ``--residual-scale``): :class:`ResidualVecEnv` sits
between the env and VecNormalize, so the base sees raw observations. The run's manifest records both,
so :meth:`agents.sb3_policy.SB3Policy.load` returns the :class:`ResidualPolicy` that plays it.
"""

from __future__ import annotations

import math

import numpy as np
from stable_baselines3.common.vec_env import VecEnvWrapper

__all__ = ["ResidualVecEnv", "ResidualPolicy", "residual_action", "check_scale"]


def check_scale(scale) -> float:
    """``scale`` as a float in (0, 2] (at 2 a correction spans the whole action box); ``ValueError`` naming
    ``residual_scale`` otherwise.
    """
    try:
        s = float(scale)
    except (TypeError, ValueError):
        s = math.nan
    if not (0.0 < s <= 2.0):
        raise ValueError(f"residual_scale = {scale!r}; use a number in (0, 2] (the correction's reach in action "
                         "units, e.g. 0.5)")
    return s


def residual_action(base_action, agent_action, scale: float) -> np.ndarray:
    """The env's action: ``clip(base_action + scale * agent_action, -1, 1)`` as float32, the agent's action
    clipped to [-1, 1] first (as SB3 clips a policy's action to its box). NaN in either is refused.
    """
    base = np.asarray(base_action, dtype=np.float64)
    agent = np.asarray(agent_action, dtype=np.float64)
    if base.shape != agent.shape:
        raise ValueError(f"the agent's action has shape {agent.shape}, the base policy's {base.shape}")
    if not (np.isfinite(base).all() and np.isfinite(agent).all()):
        raise ValueError("residual action: NaN or inf in the base policy's or the agent's action")
    return np.clip(base + scale * np.clip(agent, -1.0, 1.0), -1.0, 1.0).astype(np.float32)


class ResidualVecEnv(VecEnvWrapper):
    """An SB3 VecEnv whose actions correct ``base``'s (see the module docstring).

    Parameters
    ----------
    venv : VecEnv
        The env, giving raw observations (below any VecNormalize).
    base : a policy (``predict(obs, state, episode_start)`` on raw observations, batched)
    scale : float
        :math:`s`, in (0, 2].
    """

    def __init__(self, venv, base, scale: float):
        super().__init__(venv)
        self.base = base
        self.scale = check_scale(scale)
        self._obs = None
        self._state = None
        self._start = np.ones(self.num_envs, dtype=bool)

    def reset(self):
        self._obs = self.venv.reset()
        self._state = None
        self._start = np.ones(self.num_envs, dtype=bool)
        return self._obs

    def step_async(self, actions) -> None:
        if self._obs is None:
            raise RuntimeError("ResidualVecEnv.step before reset: call reset() first")
        base, self._state = self.base.predict(self._obs, state=self._state, episode_start=self._start,
                                              deterministic=True)
        self.venv.step_async(residual_action(base, np.asarray(actions).reshape(np.shape(base)), self.scale))

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        self._obs, self._start = obs, np.asarray(dones, dtype=bool)
        return obs, rewards, dones, infos


class ResidualPolicy:
    """Play a trained residual agent: ``base``'s action corrected by ``agent``'s (the policy protocol,
    on raw observations).

    Parameters
    ----------
    base : a policy (the run's ``residual`` spec, built for its scenario)
    agent : :class:`agents.sb3_policy.SB3Policy`
        The trained correction.
    scale : float
        The run's ``residual_scale``.
    spec : str
        The base's spec (for ``repr``).
    """

    def __init__(self, base, agent, scale: float, spec: str = "base"):
        self.base, self.agent, self.scale, self.spec = base, agent, check_scale(scale), spec
        self.obs_shape = agent.obs_shape
        self.model = agent.model

    def predict(self, obs, state=None, episode_start=None, deterministic: bool = True):
        """The env action(s) for raw observation(s) (one, or a batch); the state is the pair of the agent's
        (a recurrent agent's LSTM state) and the base's.
        """
        agent_state, base_state = (None, None) if state is None else state
        correction, agent_state = self.agent.predict(obs, state=agent_state, episode_start=episode_start,
                                                     deterministic=deterministic)
        base, base_state = self.base.predict(obs, state=base_state, episode_start=episode_start, deterministic=True)
        return residual_action(base, correction, self.scale), (agent_state, base_state)

    def __repr__(self) -> str:
        return f"ResidualPolicy(base={self.spec!r}, scale={self.scale})"
