r"""What only the simulator knows, used at training time only (issue 45): the expected one-slot reward.

The field task's room above its model-based rungs is some 0.03 reward a slot against a per-slot noise of 1.18, most
of it the stability term's indicator (``w_stab`` = 10 when a fade pushes the command's loss above
:math:`\varepsilon^\star`). The simulator knows the slot's true K-factor, so it can pay the learner the reward's
expectation over the slot's fading instead of its draw:

.. math::
    \tilde r = r + w_\mathrm{rate}\,(c_\mathrm{rate} - \mathbb E_g[c_\mathrm{rate}])
             + w_\mathrm{stab}\,(c_\mathrm{stab} - P_g(\varepsilon_\mathrm{ctrl} > \varepsilon^\star)),

the tracking error and any loss-of-track penalty as drawn; the expectations are over the command link's fading gain
:math:`g` at the slot's true K (the Rician power law), given the slot's large-scale SNR and the shares played
(``agents.myopic.MyopicPolicy``'s terms, designed on the world: ``aware``'s model). Unbiased: its mean is the
sampled reward's (``tests/training/test_privileged.py``). :class:`ExpectedRewardVecEnv` wraps a batched env built
with the world shown and hands the agent the observation without the world block: the deployed policy never reads
it, and evaluation always plays the sampled reward.
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces
from iscc_gym.agents.myopic import MyopicPolicy, SlotContext, rician_nodes_at
from stable_baselines3.common.vec_env import VecEnvWrapper

from iscc_gym.physics.fbl import comm_rate_bps
from iscc_gym.scenario import Scenario, make_scenario
from iscc_gym.sim.effects import task_effects
from iscc_gym.sim.functional import decode_observation
from iscc_gym.units import db_to_lin

__all__ = ["ExpectedRewardVecEnv", "INFO_KEYS", "expected_correction", "world_entries"]

#: The info keys the wrapped env must report (``ISCCBatchedVecEnv(info_keys=...)``).
INFO_KEYS = ("alpha", "snr_large_scale_db", "cost_rate", "cost_stability")


def world_entries(scenario: Scenario) -> int:
    """How many entries the world block adds to the observation (the last ones, with ``show_world``)."""
    s = make_scenario(scenario)
    from iscc_gym.sim.schema import obs_size

    return obs_size(s.replace(show_world=True)) - obs_size(s.replace(show_world=False))


def expected_correction(model: MyopicPolicy, k_db, snr_ls_db, alpha, cost_rate, cost_stab) -> np.ndarray:
    r"""The term that turns the sampled reward into the expected one (see the module docstring), arrays (n,) and
    ``alpha`` (n, 3): :math:`w_\mathrm{rate}(c_\mathrm{rate} - \mathbb E c_\mathrm{rate}) + w_\mathrm{stab}
    (c_\mathrm{stab} - P(\varepsilon > \varepsilon^\star))` at the slot's true K-factor ``k_db``.
    """
    s = model.scenario
    snr = db_to_lin(np.asarray(snr_ls_db, dtype=float))
    k_db = np.asarray(k_db, dtype=float)
    fade = rician_nodes_at(k_db)
    rate = comm_rate_bps(s, 1.0, snr[:, None] * fade) / max(s.rate_min_bps, 1e-300)
    ctx = SlotContext(snr=snr, coef=None, rate_per_share=rate, k_lin=db_to_lin(k_db), fade=fade)
    alpha = np.asarray(alpha, dtype=float)
    _, p_viol = model.ctrl_terms(ctx, alpha[:, 1])
    shortfall = model.rate_shortfall(ctx, alpha[:, 2])
    return s.w_rate * (np.asarray(cost_rate, dtype=float) - shortfall) + \
        s.w_stab * (np.asarray(cost_stab, dtype=float) - p_viol)


class ExpectedRewardVecEnv(VecEnvWrapper):
    """The expected one-slot reward in place of the sampled one, and the observation without the world block.

    ``venv``: an SB3 VecEnv of the field task built with ``show_world=True`` and :data:`INFO_KEYS` reported
    (``agents.sb3_vec_env.ISCCBatchedVecEnv``); ``scenario``: its Scenario (the world's law: the slot's K is read from
    the world block of the observation the slot was played from); ``keep_world``: hand the observation on with its
    world block (for a critic shown the world, ``agents.world_critic``; the actor hides it).
    """

    def __init__(self, venv, scenario: Scenario | str, keep_world: bool = False):
        s = make_scenario(scenario)
        if not task_effects(s).field:
            raise ValueError("the expected reward needs the field task's world (rician_k_std_db or rcs_std_db > 0)")
        self.shown = s.replace(show_world=True)
        self.n_world = world_entries(s)
        space = venv.observation_space
        if space.shape[-1] != self.model_size():
            raise ValueError(f"the wrapped env's observations have {space.shape[-1]} entries, the world-shown "
                             f"field env's {self.model_size()}: build it with show_world=True")
        self.keep = slice(None) if keep_world else slice(0, space.shape[-1] - self.n_world)
        obs_space = spaces.Box(space.low[self.keep], space.high[self.keep], dtype=space.dtype)
        super().__init__(venv, observation_space=obs_space)
        self.model = MyopicPolicy(self.shown)
        self._k_db = None

    def model_size(self) -> int:
        from iscc_gym.sim.schema import obs_size

        return obs_size(self.shown)

    def _world_k(self, obs) -> np.ndarray:
        return np.asarray(decode_observation(np.asarray(obs, dtype=float), self.shown)["world_k_db"], dtype=float)

    def reset(self):
        obs = self.venv.reset()
        self._k_db = self._world_k(obs)
        return obs[:, self.keep]

    def step_async(self, actions) -> None:
        self.venv.step_async(actions)

    def step_wait(self):
        obs, reward, dones, infos = self.venv.step_wait()
        got = np.array([[info[k] if np.ndim(info[k]) == 0 else np.nan for k in INFO_KEYS[1:]] for info in infos])
        alpha = np.stack([np.asarray(info["alpha"], dtype=float) for info in infos])
        corr = expected_correction(self.model, self._k_db, got[:, 0], alpha, got[:, 1], got[:, 2])
        self._k_db = self._world_k(obs)  # the next slot's (a new mission's first, where one ended)
        for info in infos:
            if "terminal_observation" in info:
                info["terminal_observation"] = info["terminal_observation"][self.keep]
        return obs[:, self.keep], (reward + corr).astype(np.float32), dones, infos
