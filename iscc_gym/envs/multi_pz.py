r"""PettingZoo view of the multi-drone env: one agent per drone proposing its demand.

``iscc_gym.parallel_env(n_drones=K)`` or this module's :func:`parallel_env` (needs ``pip install pettingzoo``,
the ``multi`` extra).

Agents ``drone_0`` ... ``drone_{K-1}``. Each agent's action is ``Box(-1, 1, (3,))``: its proposed
sensing, control and data weights. **The GBS's normalisation rule**: it maps the K proposals onto the
shared budget exactly as the centralised env maps its 3K-vector (:func:`iscc_gym.sim.fleet.multi_split`):
:math:`w_{k,f} = (a_{k,f} + 1)/2`, :math:`\alpha_{k,f} = w_{k,f} / \sum_{j,f} w_{j,f}`, so a drone's
band grows with its total demand against everyone else's (proportional sharing). Each agent observes
its own drone (the single env's 23 entries). Rewards are per drone, its single-env reward over K,
:math:`(-\min(e_k, e_\max) - w_\mathrm{rate} c^\mathrm{rate}_k - w_\mathrm{stab} c^\mathrm{stab}_k)/K`
(minus the loss-of-track penalty shared out 1/K per drone; :func:`iscc_gym.sim.fleet.drone_rewards`), so
the agents' rewards sum to the centralised env's team reward, the mean over drones.
Every agent terminates when any drone loses track and truncates at the mission's end. Infos carry the
single env's keys for the agent's drone (costs ``cost_rate``, ``cost_stability``, ``cost``, tracking error, SNRs,
PEB, rates, ``packet_received``, its shares ``alpha``, the slot) and the drone's seed (``drone_seed``), with the
same keys at reset as at every step (TorchRL's ``PettingZooWrapper`` builds its specs from the reset infos): at
reset the initial tracking error, zero costs, equal shares 1/(3K) and NaN slot outcomes. Actions must be real:
complex numbers raise ``TypeError``.
"""

from __future__ import annotations

import functools

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from iscc_gym.envs.env import real_array
from iscc_gym.envs.multi import ISCCMultiEnv
from iscc_gym.sim.fleet import N_DRONES, drone_rewards
from iscc_gym.sim.functional import INFO_COLUMNS
from iscc_gym.sim.schema import OBS_BOUND, OBS_NAMES

__all__ = ["ISCCParallelEnv"]


class ISCCParallelEnv(ParallelEnv):
    """One agent per drone of :class:`iscc_gym.envs.multi.ISCCMultiEnv` (module docstring: the rule)."""

    metadata = {"render_modes": [], "name": "iscc_multi_v0", "is_parallelizable": True}

    def __init__(self, n_drones: int = N_DRONES, scenario="paper", render_mode=None, **overrides):
        self._seeds: list[int] = []
        self._env = ISCCMultiEnv(n_drones=n_drones, scenario=scenario, render_mode=render_mode, **overrides)
        self.render_mode = None
        self.possible_agents = [f"drone_{k}" for k in range(self._env.n_drones)]
        self.agents: list[str] = []

    @functools.cache  # noqa: B019  (PettingZoo's documented pattern: one space per agent)
    def observation_space(self, agent):
        return spaces.Box(-OBS_BOUND, OBS_BOUND, (len(OBS_NAMES),), np.float32)

    @functools.cache  # noqa: B019
    def action_space(self, agent):
        return spaces.Box(-1.0, 1.0, (3,), np.float32)

    @property
    def scenario(self):
        return self._env.scenario

    def _split(self, obs):
        return {a: obs[k * len(OBS_NAMES):(k + 1) * len(OBS_NAMES)] for k, a in enumerate(self.possible_agents)}

    def reset(self, seed=None, options=None):
        obs, info = self._env.reset(seed=seed, options=options)
        self.agents = list(self.possible_agents)
        self._seeds = list(info["drone_seeds"])
        return self._split(obs), self._infos(self.agents, info)

    def _infos(self, agents, team: dict) -> dict:
        """Each agent's info from the team env's (:func:`iscc_gym.sim.functional.step_info`, per drone): its
        drone's entries of :data:`~iscc_gym.sim.functional.INFO_COLUMNS`, ``packet_received``, ``cost`` (its rate
        plus stability cost), ``alpha`` (its shares), ``slot`` and ``drone_seed``; the same keys at reset and at
        every step.
        """
        out = {}
        for i, a in enumerate(agents):
            info = {key: float(team[key][i]) for key in INFO_COLUMNS}
            info["packet_received"] = bool(team["packet_received"][i])
            info["cost"] = info["cost_rate"] + info["cost_stability"]
            info["alpha"] = np.array(team["alpha"][i], dtype=np.float64)
            info["slot"] = int(team["slot"])
            info["drone_seed"] = self._seeds[i]
            out[a] = info
        return out

    def step(self, actions):
        if not self.agents:
            raise RuntimeError("step() called with no live agents: call reset() first")
        missing = [a for a in self.agents if a not in actions]
        if missing:
            raise ValueError(f"actions has no entry for {missing}; pass one (3,) action per agent")
        unknown = [a for a in actions if a not in self.agents]
        if unknown:
            raise ValueError(f"actions names {unknown}, which are not live agents {self.agents}; pass one (3,) "
                             "action per live agent")
        bad = {a: np.shape(actions[a]) for a in self.agents if np.shape(actions[a]) != (3,)}
        if bad:
            raise ValueError(f"each agent's action must have shape (3,); got {bad}")
        real = {a: real_array(actions[a], f"actions[{a!r}]") for a in self.agents}
        nonfinite = [a for a in self.agents if not np.all(np.isfinite(real[a]))]
        if nonfinite:
            raise ValueError(f"actions of {nonfinite} contain NaN or inf; pass finite values in [-1, 1]")
        vec = np.concatenate([real[a] for a in self.possible_agents])
        obs, _, term, trunc, info = self._env.step(vec)
        s, k = self.scenario, len(self.possible_agents)
        out_err, c_rate, c_stab = info["tracking_error_m"], info["cost_rate"], info["cost_stability"]
        per = drone_rewards(s, out_err, c_rate, c_stab, term, info["slot"]) / k
        agents = self.agents
        infos = self._infos(agents, info)
        result = (self._split(obs), {a: float(per[i]) for i, a in enumerate(agents)},
                  {a: bool(term) for a in agents}, {a: bool(trunc) for a in agents}, infos)
        if term or trunc:
            self.agents = []
        return result

    def close(self):
        self._env.close()


def parallel_env(n_drones: int = N_DRONES, **kwargs) -> ISCCParallelEnv:
    """The PettingZoo ``ParallelEnv`` of the multi-drone env (PettingZoo's convention: a module's
    ``parallel_env``); ``kwargs`` as :class:`ISCCParallelEnv` (``scenario``, ``render_mode``, Scenario fields).
    """
    return ISCCParallelEnv(n_drones=n_drones, **kwargs)
