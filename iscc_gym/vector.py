"""Native batched vector env: N ISCC loops stepped as one call of the same transition as the single env.

``gymnasium.make_vec("iscc_gym/ISCC-v0", num_envs=N, vectorization_mode="vector_entry_point")``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from . import loop
from .env import (
    OBS_BOUND,
    OBS_NAMES,
    REGISTERED_MAX_EPISODE_STEPS,
    STEP_COLUMNS,
    env_step,
    observe,
    warn_time_limit,
)
from .scenario import Scenario, make_scenario
from .trajectory import sample_reference

__all__ = ["ISCCVectorEnv"]

_COL = {name: j for j, name in enumerate(STEP_COLUMNS)}
#: info keys of a step, from the columns of :func:`iscc_gym.env.env_step` (``alpha`` and ``cost`` added).
INFO_KEYS = ("tracking_error_m", "cost_rate", "cost_stability", "cost", "snr_db", "snr_large_scale_db",
             "peb_m", "veb_mps", "eps_ctrl", "packet_received", "rate_comm_bps", "rate_ctrl_bps",
             "estimation_error_m", "alpha", "slot")


class ISCCVectorEnv(VectorEnv):
    """``num_envs`` independent ISCC loops (:class:`iscc_gym.env.ISCCEnv`) stepped as one batch.

    Every sub-env runs exactly the single env's pipeline (:func:`iscc_gym.env.env_step` on a batch),
    so sub-env i reset with seed s_i reproduces ``ISCCEnv`` reset with seed s_i bit for bit:
    observations, rewards, terminations and info, over whole episodes.

    Spaces are the single env's, batched: actions ``(num_envs, 3)`` in [-1, 1], observations
    ``(num_envs, 23)``. ``info`` holds one array per key of the single env's info (``alpha`` is
    ``(num_envs, 3)``), each with Gymnasium's ``_key`` mask of the sub-envs it is valid for.

    Arguments
    ---------
    num_envs : int
    scenario : str or Scenario, and ``**overrides``: as :class:`iscc_gym.env.ISCCEnv`
    autoreset_mode : ``"NextStep"`` (default, Gymnasium's) or ``"SameStep"``
        NextStep: the step after an episode ends resets that sub-env (reward 0, not done).
        SameStep: it is reset in the step that ends it; the last observation and info go to
        ``info["final_obs"]`` / ``info["final_info"]`` (masks ``_final_obs``, ``_final_info``).
    max_episode_steps : int, optional
        Truncate after this many steps (``make_vec`` passes the registered 5000).

    ``reset(seed=s)`` seeds sub-env i with ``s + i``; ``reset(seed=[s_0, ...])`` with ``s_i``;
    ``reset(options={"reset_mask": mask})`` resets only the masked sub-envs.
    """

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, scenario: str | Scenario = "paper",
                 autoreset_mode: str | AutoresetMode = AutoresetMode.NEXT_STEP,
                 max_episode_steps: int | None = None, **overrides: Any):
        if not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs = {num_envs!r}; use an integer >= 1")
        try:
            mode = AutoresetMode(autoreset_mode)
        except ValueError:
            raise ValueError(f"autoreset_mode = {autoreset_mode!r}; use 'NextStep' or 'SameStep'") from None
        if mode == AutoresetMode.DISABLED:
            raise ValueError("autoreset_mode = 'Disabled' is not supported; use 'NextStep' or 'SameStep'")
        if max_episode_steps is not None and max_episode_steps < 1:
            raise ValueError(f"max_episode_steps = {max_episode_steps}; use an integer >= 1 or None")
        self.scenario = make_scenario(scenario, **overrides)
        if max_episode_steps == REGISTERED_MAX_EPISODE_STEPS:
            warn_time_limit(self.scenario)
        self.num_envs = int(num_envs)
        self.render_mode = None
        self.metadata = {**self.metadata, "autoreset_mode": mode}
        self.autoreset_mode = mode
        s = self.scenario
        self.max_steps = s.n_slots if max_episode_steps is None else min(int(max_episode_steps), s.n_slots)
        self.single_action_space = spaces.Box(-1.0, 1.0, (3,), np.float32)
        self.single_observation_space = spaces.Box(-OBS_BOUND, OBS_BOUND, (len(OBS_NAMES),), np.float32)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._rngs: list[np.random.Generator] | None = None
        self._state: loop.LoopState | None = None
        self._last_rx = np.ones(self.num_envs)
        self._last_peb = np.zeros(self.num_envs)
        self._done = np.zeros(self.num_envs, dtype=bool)

    # --- Gymnasium VectorEnv API ------------------------------------------------------------------
    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        n = self.num_envs
        mask = np.ones(n, dtype=bool)
        if options and "reset_mask" in options:
            mask = np.asarray(options["reset_mask"], dtype=bool)
            if mask.shape != (n,):
                raise ValueError(f"options['reset_mask'] must have shape ({n},), got {mask.shape}")
            if self._state is None and not mask.all():
                raise RuntimeError("the first reset() must reset every sub-env (no reset_mask)")
        if seed is None:
            seeds: list[int | None] = [None] * n
        elif isinstance(seed, (int, np.integer)):
            seeds = [int(seed) + i for i in range(n)]
        else:
            seeds = list(seed)
            if len(seeds) != n:
                raise ValueError(f"seed must be an int, None or a list of {n} seeds, got {len(seeds)}")
        if self._rngs is None:
            self._rngs = [seeding.np_random(sd)[0] for sd in seeds]
        else:
            for i in np.flatnonzero(mask):
                if seeds[i] is not None:
                    self._rngs[i] = seeding.np_random(seeds[i])[0]
        self._reset_rows(np.flatnonzero(mask))
        self._done[mask] = False
        obs = observe(self.scenario, self._state, self._last_rx, self._last_peb)
        return obs, {"slot": self._state.n.copy(), "_slot": mask.copy()}

    def step(self, actions):
        if self._state is None:
            raise RuntimeError("step() called before reset(): call env.reset(seed=...) first")
        a = np.asarray(actions, dtype=np.float64)
        if a.shape != (self.num_envs, 3):
            raise ValueError(f"actions must have shape ({self.num_envs}, 3), got {a.shape}")
        if not np.isfinite(a).all():
            bad = np.flatnonzero(~np.isfinite(a).all(axis=1)).tolist()
            raise ValueError(f"actions of sub-envs {bad} contain NaN or inf; pass finite values in [-1, 1]")
        s = self.scenario
        restart = self._done.copy()  # NextStep: these sub-envs reset now instead of stepping
        active = ~restart if restart.any() else None
        self._state, out, obs = env_step(s, self._state, a, active=active)
        valid = np.ones(self.num_envs, dtype=bool) if active is None else active
        if active is not None:
            self._last_rx = np.where(active, out[:, _COL["packet_received"]], self._last_rx)
            self._last_peb = np.where(active, out[:, _COL["peb_m"]], self._last_peb)
            self._reset_rows(np.flatnonzero(restart))
            obs[restart] = observe(s, self._state.rows(restart), self._last_rx[restart],
                                   self._last_peb[restart])
        else:
            self._last_rx = out[:, _COL["packet_received"]].copy()
            self._last_peb = out[:, _COL["peb_m"]].copy()
        terminated = (out[:, _COL["terminated"]] == 1.0) & valid
        truncated = ((out[:, _COL["truncated"]] == 1.0) | (self._state.n >= self.max_steps)) & valid & ~terminated
        reward = out[:, _COL["reward"]].copy()  # 0 where a sub-env was reset instead of stepped
        info = _info(out, self._state.n, valid)
        done = terminated | truncated
        if self.autoreset_mode == AutoresetMode.SAME_STEP and done.any():
            idx = np.flatnonzero(done)
            final_obs = np.empty(self.num_envs, dtype=object)
            for i in idx:
                final_obs[i] = obs[i].copy()
            info["final_obs"], info["_final_obs"] = final_obs, done.copy()
            info["final_info"] = {k: (v & done if k.startswith("_") else v) for k, v in info.items()
                                  if not k.startswith(("final", "_final"))}
            info["_final_info"] = done.copy()
            self._reset_rows(idx)
            obs[idx] = observe(s, self._state.rows(idx), self._last_rx[idx], self._last_peb[idx])
            self._done = np.zeros(self.num_envs, dtype=bool)
        else:
            self._done = done
        return obs, reward, terminated, truncated, info

    # --- helpers ---------------------------------------------------------------------------------
    def _reset_rows(self, idx: np.ndarray) -> None:
        """New episodes for sub-envs ``idx``: exactly :meth:`ISCCEnv.reset`'s draws, per sub-env."""
        if idx.size == 0:
            return
        s = self.scenario
        refs = [sample_reference(s, self._rngs[i]) for i in idx]
        parts = [loop.init_state(s, [r], [self._rngs[i]]) for r, i in zip(refs, idx, strict=True)]
        new = loop.LoopState(*(np.concatenate(fields) for fields in zip(*parts, strict=True)))
        if self._state is None or idx.size == self.num_envs:
            self._state = new
        else:
            self._state = self._state.with_rows(idx, new)
        self._last_rx[idx] = 1.0
        self._last_peb[idx] = 0.0


def _info(out: np.ndarray, n: np.ndarray, valid: np.ndarray) -> dict:
    """Vector info: views into this step's fresh ``out`` array, one ``_key`` mask per key."""
    info: dict[str, Any] = {}
    for key in INFO_KEYS:
        if key == "cost":
            val = out[:, _COL["cost_rate"]] + out[:, _COL["cost_stability"]]
        elif key == "alpha":
            val = out[:, _COL["alpha_sen"]:_COL["alpha_comm"] + 1]
        elif key == "packet_received":
            val = out[:, _COL["packet_received"]] == 1.0
        elif key == "slot":
            val = n.copy()
        else:
            val = out[:, _COL[key]]
        info[key] = val
        info["_" + key] = valid
    return info
