r"""Many drones, one base station: the Gymnasium face ``iscc_gym/ISCC-Multi-v0`` of the fleet step
(:mod:`iscc_gym.sim.fleet`: K drones, each the single-drone loop, sharing one OFDM budget). Its vector env is
:class:`iscc_gym.envs.vector.ISCCMultiVectorEnv`, its PettingZoo view :mod:`iscc_gym.envs.multi_pz`.
docs/model.md, section 5, states the modelling choices.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from iscc_gym.envs.env import TimeLimitCheck, check_keywords, check_seed, real_array
from iscc_gym.scenario import Scenario, make_scenario
from iscc_gym.sim import loop
from iscc_gym.sim.fleet import (
    N_DRONES,
    check_n_drones,
    drone_scenario,
    drone_seeds,
    multi_reset_info,
    multi_step,
    reset_drones,
)
from iscc_gym.sim.functional import observe, step_info
from iscc_gym.sim.schema import COL, OBS_BOUND, OBS_NAMES
from iscc_gym.tasks import MULTI_ENV_ID

__all__ = ["ISCCMultiEnv", "MULTI_ENV_ID"]



class ISCCMultiEnv(TimeLimitCheck, gym.Env):
    r"""Split one base station's time-frequency budget across K drones, every slot.

    ## Description

    K drones (``n_drones``, default 4), each the ISCC loop of :class:`iscc_gym.envs.env.ISCCEnv` (its own
    reference, Kalman filter, LQG loop, links, fading, shadowing and noise), share one OFDM budget:
    every slot the agent gives each drone a sensing, a control and a data share, 3K shares summing to
    1. Drone k's CRLB, drop probability and rate follow from its own shares exactly as in the single
    env (per-subcarrier SNR independent of the share, orthogonal subcarriers: no interference).
    Each step runs the compiled single-drone step on a batch of K loops.

    ## Action Space

    ``Box(-1, 1, (3K,), float32)``: entries 3k, 3k+1, 3k+2 are drone k's sensing, control and data
    weights. Mapped onto the 3K-simplex: :math:`w = (a + 1)/2`, :math:`\alpha_{k,f} = w_{k,f} /
    \sum w` (equal shares 1/(3K) if every w = 0; :func:`iscc_gym.sim.fleet.multi_split`). ``info["alpha"]`` (K, 3) holds
    the applied shares. NaN/inf or a wrong shape raise ``ValueError`` and leave the env unchanged.

    ## Observation Space

    ``Box(-10, 10, (23K,), float32)``: drone k's single-env observation (the table of
    :class:`iscc_gym.envs.env.ISCCEnv`) at entries 23k to 23k+22. Its ``alpha_ctrl_min`` and
    ``alpha_comm_min`` are shares of the whole band, as here (``alpha_comm_min`` for the drone's
    own rate requirement).

    ## Rewards

    .. math::
        r_n = \frac1K \sum_k \Bigl(-\min(e_{k,n}, e_\max) - w_\mathrm{rate}\, c^\mathrm{rate}_{k,n}
        - w_\mathrm{stab}\, c^\mathrm{stab}_{k,n}\Bigr)

    the mean over drones of each drone's single-env reward: its tracking error (clipped at
    ``max_tracking_error_m``) and its rate and stability penalties (the single env's costs;
    :func:`iscc_gym.sim.fleet.multi_reward`, :func:`iscc_gym.sim.fleet.drone_rewards`). Error and penalties
    are both per-drone means, so a drone's tracking weighs against its costs as in the single env at every K
    (summing the penalties over an averaged error would make the penalties K times heavier, and losing the radar
    pay).
    Per-drone costs are in ``info["cost_rate"]``, ``info["cost_stability"]`` (K,); ``info["cost"]`` is
    their total, for safe-RL libraries. Loss of track adds the single env's penalty,
    ``max_tracking_error_m`` per remaining slot. With K = 1 reward and costs are the single env's.

    ## Starting State

    ``reset(seed=s)`` seeds the env's generator, draws one seed per drone from it
    (``info["drone_seeds"]``) and resets drone k exactly as :class:`iscc_gym.envs.env.ISCCEnv` reset with
    its seed: drones fly independent references from independent noise streams.

    ## Episode End

    * Termination: **any** drone loses track (its tracking error above ``max_tracking_error_m`` or
      its state outside the evaluable range, as in the single env): the team's mission failed.
    * Truncation: after ``n_slots`` slots (5000), the mission's end for every drone.

    ## Arguments

    ``gymnasium.make("iscc_gym/ISCC-Multi-v0", n_drones=4, scenario="paper",
    rate_min_per_drone_bps=None, **overrides)``: ``scenario`` and ``overrides`` as in
    :class:`iscc_gym.envs.env.ISCCEnv`, shared by every drone; each drone's data link must carry
    ``rate_min_per_drone_bps``, by default the scenario's ``rate_min_bps`` / K (the base station's
    requirement split evenly; :func:`iscc_gym.sim.fleet.drone_scenario`). ``env.scenario`` is the per-drone scenario.
    ``gymnasium.make_vec(..., vectorization_mode="vector_entry_point")`` gives the native batched
    env (:class:`iscc_gym.envs.vector.ISCCVectorEnv` with ``n_drones``).

    ## Version History

    * v0: initial version.

    ## Example

    >>> import gymnasium as gym, iscc_gym
    >>> env = gym.make("iscc_gym/ISCC-Multi-v0", n_drones=4)
    >>> obs, info = env.reset(seed=0)
    >>> obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    """

    metadata = {"render_modes": []}

    def __init__(self, n_drones: int = N_DRONES, scenario: str | Scenario = "paper", render_mode: str | None = None,
                 rate_min_per_drone_bps: float | None = None, **overrides: Any):
        check_keywords(type(self).__name__, overrides,
                       ("n_drones", "scenario", "render_mode", "rate_min_per_drone_bps"))
        self.n_drones = check_n_drones(n_drones)
        self.scenario = drone_scenario(make_scenario(scenario, **overrides), self.n_drones, rate_min_per_drone_bps)
        if render_mode is not None:
            raise ValueError(f"render_mode={render_mode!r}; the multi-drone env has no renderer (use None)")
        self.render_mode = None
        k = self.n_drones
        self.action_space = spaces.Box(-1.0, 1.0, (3 * k,), np.float32)
        self.observation_space = spaces.Box(-OBS_BOUND, OBS_BOUND, (k * len(OBS_NAMES),), np.float32)
        self._state: loop.LoopState | None = None
        self._ended = False
        self._last_rx = np.ones(k)
        self._last_peb = np.zeros(k)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        seed = check_seed(seed, "seed")
        super().reset(seed=seed)
        self._state, self._ended = None, False
        seeds = drone_seeds(self.np_random, self.n_drones)
        self._state = reset_drones(self.scenario, seeds)
        self._last_rx, self._last_peb = np.ones(self.n_drones), np.zeros(self.n_drones)
        obs = observe(self.scenario, self._state, self._last_rx, self._last_peb).reshape(-1)
        info = {key: (val[0].item() if val.ndim == 1 else val[0]) for key, val in
                multi_reset_info(self._state, self.n_drones).items()}  # a step's keys (NaN: no slot yet)
        info["action"] = np.full(3 * self.n_drones, np.nan, np.float32)
        info["drone_seeds"] = seeds
        return obs, info

    def step(self, action):
        if self._state is None:
            raise RuntimeError("step() called before reset(): call env.reset(seed=...) first")
        a = real_array(action, "action")
        if a.shape != (3 * self.n_drones,):
            raise ValueError(f"action must have shape ({3 * self.n_drones},) for {self.n_drones} drones, got {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError(f"action entries {np.flatnonzero(~np.isfinite(a)).tolist()} are NaN or inf; pass "
                             "finite values in [-1, 1]")
        if self._ended:
            raise RuntimeError("the episode has ended (a drone lost track); call reset() before step()")
        if self._state.n[0] >= self.scenario.n_slots:
            raise RuntimeError("the mission is over (truncated); call reset() before step()")
        self._state, out, obs, reward, term, trunc = multi_step(self.scenario, self._state, a[None], self.n_drones)
        out = out[0]
        self._ended = bool(term[0])
        self._last_rx = out[:, COL["packet_received"]].copy()
        self._last_peb = out[:, COL["peb_m"]].copy()
        info = step_info(out, int(self._state.n[0]), fleet=True)
        info["action"] = a.astype(np.float32)
        info["slot"] = int(self._state.n[0])
        return obs[0], float(reward[0]), bool(term[0]), bool(trunc[0]), info

