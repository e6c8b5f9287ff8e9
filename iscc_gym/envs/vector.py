"""Native batched vector env: N ISCC loops stepped as one call of the same transition as the single env.

``gymnasium.make_vec("iscc_gym/ISCC-v0", num_envs=N, vectorization_mode="vector_entry_point")``.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

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
from iscc_gym.sim.functional import env_step, observe, reset_info_arrays, step_info
from iscc_gym.sim.schema import COL as _COL
from iscc_gym.sim.schema import OBS_BOUND, obs_size

__all__ = ["ISCCVectorEnv", "ISCCMultiVectorEnv", "check_memory", "reset_bytes", "available_memory_bytes"]



class ISCCVectorEnv(TimeLimitCheck, VectorEnv):
    """``num_envs`` independent ISCC loops (:class:`iscc_gym.envs.env.ISCCEnv`) stepped as one batch.

    Every sub-env runs exactly the single env's pipeline (:func:`iscc_gym.sim.functional.env_step` on a batch),
    so sub-env i reset with seed s_i reproduces ``ISCCEnv`` reset with seed s_i bit for bit:
    observations, rewards, terminations and info, over whole episodes.

    Spaces are the single env's, batched: actions ``(num_envs, 3)`` in [-1, 1], observations
    ``(num_envs, 23)``. ``info`` holds one array per key of the single env's info (``alpha`` is
    ``(num_envs, 3)``), each with Gymnasium's ``_key`` mask of the sub-envs it is valid for.

    Arguments
    ---------
    num_envs : int
    scenario : str or Scenario, and ``**overrides``: as :class:`iscc_gym.envs.env.ISCCEnv`
    autoreset_mode : ``AutoresetMode.NEXT_STEP`` (default, Gymnasium's) or ``AutoresetMode.SAME_STEP``
        (or their values ``"NextStep"``, ``"SameStep"``, or names ``"NEXT_STEP"``, ``"SAME_STEP"``).
        NextStep: the step after an episode ends resets that sub-env (reward 0, not done).
        SameStep: it is reset in the step that ends it; the last observation and info go to
        ``info["final_obs"]`` / ``info["final_info"]`` (masks ``_final_obs``, ``_final_info``) and the top-level
        info holds the new episode's reset info, as in Gymnasium's ``SyncVectorEnv`` (a sum over steps of
        ``info[key]`` counts no slot twice); TorchRL's ``GymWrapper`` needs it. Through ``gymnasium.make_vec``
        it is a keyword, ``gym.make_vec(id, num_envs=N, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)``: Gymnasium
        (1.1 to 1.4) refuses ``vector_kwargs`` for a vector entry point before calling it ("Custom
        vector environment can be passed arguments only through kwargs"); ``vector_kwargs=
        {"autoreset_mode": ...}`` is the form of ``vectorization_mode="sync"`` / ``"async"``
        (Gymnasium's own vector envs around the single env).
    max_episode_steps : int >= 1, optional
        Truncate after this many steps (``make_vec`` passes the env id's registered limit, 5000 or 1200 for
        ``iscc_gym/ISCC-Urban-v0``, and a warning names the fix where that cuts a longer mission short); a
        non-integer (2.5, ``'10'``, NaN, True) is a ``TypeError`` naming it.

    n_drones : int, optional
        K drones per sub-env: each sub-env is the multi-drone env :class:`iscc_gym.envs.multi.ISCCMultiEnv`
        (``gymnasium.make_vec("iscc_gym/ISCC-Multi-v0", num_envs=N, n_drones=K,
        vectorization_mode="vector_entry_point")``): actions ``(num_envs, 3K)``, observations
        ``(num_envs, 23K)``, per-drone info arrays ``(num_envs, K)`` (``alpha`` ``(num_envs, K, 3)``),
        N x K loops stepped as one batch; sub-env i reproduces the multi-drone env seeded alike bit
        for bit. None (default): the single-drone env.
    rate_min_per_drone_bps : float, optional
        With ``n_drones``: each drone's rate requirement (default the scenario's ``rate_min_bps`` / K;
        :func:`iscc_gym.sim.fleet.drone_scenario`).

    Notes
    -----
    ``reset(seed=s)`` seeds sub-env i with ``s + i``; ``reset(seed=[s_0, ...])`` with ``s_i``;
    ``reset(options={"reset_mask": mask})`` resets only the masked sub-envs. The reset ``info`` carries
    the keys of a step's info (the single env's reset values: initial tracking error, zero costs, NaN
    slot outcomes; :func:`iscc_gym.sim.functional.reset_info_arrays`), masked to the sub-envs reset. Complex
    actions raise ``TypeError``, NaN/inf or a wrong shape ``ValueError``.
    """

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, scenario: str | Scenario = "paper",
                 autoreset_mode: str | AutoresetMode = AutoresetMode.NEXT_STEP,
                 max_episode_steps: int | None = None, n_drones: int | None = None,
                 rate_min_per_drone_bps: float | None = None, **overrides: Any):
        check_keywords(type(self).__name__, overrides, ("num_envs", "scenario", "autoreset_mode", "max_episode_steps",
                                                        "n_drones", "rate_min_per_drone_bps"))
        num_envs = _check_count(num_envs, "num_envs")
        mode = _autoreset_mode(autoreset_mode)
        if max_episode_steps is not None:
            max_episode_steps = _check_count(max_episode_steps, "max_episode_steps", none_ok=True)
        self.n_drones = None if n_drones is None else check_n_drones(n_drones)
        k = self._k = 1 if n_drones is None else self.n_drones
        self.scenario = make_scenario(scenario, **overrides)
        if n_drones is not None:
            self.scenario = drone_scenario(self.scenario, k, rate_min_per_drone_bps)
        elif rate_min_per_drone_bps is not None:
            raise ValueError("rate_min_per_drone_bps needs n_drones (the multi-drone env); set rate_min_bps instead")
        check_memory(self.scenario, int(num_envs) * k)
        self._time_limit_given = max_episode_steps  # make_vec passes the id's registered one: TimeLimitCheck
        self.num_envs = int(num_envs)
        self.render_mode = None
        self.metadata = {**self.metadata, "autoreset_mode": mode}
        self.autoreset_mode = mode
        s = self.scenario
        self.max_steps = s.n_slots if max_episode_steps is None else min(int(max_episode_steps), s.n_slots)
        self.single_action_space = spaces.Box(-1.0, 1.0, (3 * k,), np.float32)
        self.single_observation_space = spaces.Box(-OBS_BOUND, OBS_BOUND, (k * obs_size(s),), np.float32)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._rngs: list[np.random.Generator] | None = None
        self._state: loop.LoopState | None = None
        self._last_rx = np.ones(self.num_envs * k)  # per loop
        self._last_peb = np.zeros(self.num_envs * k)
        self._done = np.zeros(self.num_envs, dtype=bool)

    # --- Gymnasium VectorEnv API ------------------------------------------------------------------
    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        # every argument is checked before any state changes: a rejected call leaves the env as it was
        mask = self._check_reset_mask(options)
        seeds = self._check_seeds(seed)
        if self._rngs is None:
            self._rngs = [seeding.np_random(sd)[0] for sd in seeds]
        else:
            for i in np.flatnonzero(mask):
                if seeds[i] is not None:
                    self._rngs[i] = seeding.np_random(seeds[i])[0]
        self._reset_rows(np.flatnonzero(mask))
        self._done[mask] = False
        obs = observe(self.scenario, self._state, self._last_rx, self._last_peb)
        return obs.reshape(self.num_envs, -1), self._reset_info(mask)

    def step(self, actions):
        if self._state is None:
            raise RuntimeError("step() called before reset(): call env.reset(seed=...) first")
        a = real_array(actions, "actions")
        if a.shape != (self.num_envs, 3 * self._k):
            raise ValueError(f"actions must have shape ({self.num_envs}, {3 * self._k}), got {a.shape}")
        if not np.isfinite(a).all():
            bad = np.flatnonzero(~np.isfinite(a).all(axis=1)).tolist()
            raise ValueError(f"actions of sub-envs {bad} contain NaN or inf; pass finite values in [-1, 1]")
        s = self.scenario
        restart = self._done.copy()  # NextStep: these sub-envs reset now instead of stepping
        active = ~restart if restart.any() else None
        if self.n_drones is None:
            self._state, out, obs = env_step(s, self._state, a, active=active)
            reward = out[:, _COL["reward"]].copy()  # 0 where a sub-env was reset instead of stepped
            term_, trunc_ = out[:, _COL["terminated"]] == 1.0, out[:, _COL["truncated"]] == 1.0
            loop_out = out
        else:
            self._state, out, obs, reward, term_, trunc_ = multi_step(s, self._state, a, self._k, active=active)
            loop_out = out.reshape(self.num_envs * self._k, -1)
        valid = np.ones(self.num_envs, dtype=bool) if active is None else active
        if active is not None:
            loops = np.repeat(active, self._k)
            self._last_rx = np.where(loops, loop_out[:, _COL["packet_received"]], self._last_rx)
            self._last_peb = np.where(loops, loop_out[:, _COL["peb_m"]], self._last_peb)
            self._reset_rows(np.flatnonzero(restart))
            obs[restart] = self._observe(np.flatnonzero(restart))
        else:
            self._last_rx = loop_out[:, _COL["packet_received"]].copy()
            self._last_peb = loop_out[:, _COL["peb_m"]].copy()
        slots = self._slots()
        terminated = term_ & valid
        truncated = (trunc_ | (slots >= self.max_steps)) & valid & ~terminated
        info = _masked(step_info(out, slots, fleet=self.n_drones is not None), valid)
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
            obs[idx] = self._observe(idx)
            # as Gymnasium's SyncVectorEnv: a sub-env reset in this step reports its reset's info at the top level
            # (new arrays: final_info keeps the ended step's)
            new = self._reset_info(done)
            for key in new:
                if not key.startswith("_"):
                    info[key] = np.where(done.reshape(-1, *(1,) * (np.ndim(info[key]) - 1)), new[key], info[key])
            self._done = np.zeros(self.num_envs, dtype=bool)
        else:
            self._done = done
        return obs, reward, terminated, truncated, info

    # --- helpers ---------------------------------------------------------------------------------
    def positions(self, rows: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The drones' true positions and their reference positions (m) at each loop's current slot,
        for the first ``rows`` sub-envs (all by default): two copies of shape (rows, 3), or (rows, K, 3)
        with ``n_drones``. For plots and evaluation traces; the policy sees only the observation.

        Raises
        ------
        RuntimeError
            Before the first ``reset``.
        """
        m = self._first_loops(rows, "positions")
        st = self._state
        pos, ref = st.x[:m, :3].copy(), st.ref[np.arange(m), st.n[:m], :3].copy()
        if self.n_drones is None:
            return pos, ref
        return pos.reshape(-1, self._k, 3), ref.reshape(-1, self._k, 3)

    def missions(self, rows: int | None = None) -> np.ndarray:
        """The missions being flown by the first ``rows`` sub-envs (all by default): a copy of each loop's
        per-slot rows (reference position, velocity, acceleration, then the channel's columns of
        :data:`iscc_gym.sim.mission.CHANNEL_COLUMNS` where the task has them), shape (rows, slots, columns), or
        (rows, K, slots, columns) with ``n_drones``. For figures; the policy sees only the observation.

        Raises
        ------
        RuntimeError
            Before the first ``reset``.
        """
        m = self._first_loops(rows, "missions")
        ref = self._state.ref[:m].copy()
        return ref if self.n_drones is None else ref.reshape(-1, self._k, *ref.shape[1:])

    def _first_loops(self, rows: int | None, what: str) -> int:
        """The loops of the first ``rows`` sub-envs (all by default; K per sub-env with ``n_drones``);
        ``RuntimeError`` naming ``what`` before the first ``reset``.
        """
        if self._state is None:
            raise RuntimeError(f"call reset() before {what}()")
        return (self.num_envs if rows is None else max(0, min(int(rows), self.num_envs))) * self._k

    def _reset_info(self, mask: np.ndarray) -> dict:
        """A step's info keys at reset (:func:`iscc_gym.sim.functional.reset_info_arrays`), masked to the sub-envs
        reset.
        """
        if self.n_drones is None:
            info = reset_info_arrays(self._state)
        else:
            info = multi_reset_info(self._state, self._k)
        for key in list(info):
            info["_" + key] = mask.copy()
        return info

    def _slots(self) -> np.ndarray:
        """Each sub-env's slot index (its drones share it)."""
        return self._state.n[::self._k].copy()

    def _loops(self, idx: np.ndarray) -> np.ndarray:
        """The loop rows of sub-envs ``idx`` (drone j of sub-env i at row i K + j)."""
        return (np.asarray(idx)[:, None] * self._k + np.arange(self._k)).reshape(-1)

    def _observe(self, idx: np.ndarray) -> np.ndarray:
        """The observations of sub-envs ``idx``, (len(idx), 23 K)."""
        rows = self._loops(idx)
        obs = observe(self.scenario, self._state.rows(rows), self._last_rx[rows], self._last_peb[rows])
        return obs.reshape(len(idx), -1)

    def _check_reset_mask(self, options) -> np.ndarray:
        n = self.num_envs
        if options is None:
            return np.ones(n, dtype=bool)
        if not isinstance(options, dict):
            raise TypeError(f"options = {options!r}: pass a dict (e.g. {{'reset_mask': mask}}) or None")
        if "reset_mask" not in options:
            return np.ones(n, dtype=bool)
        raw = options["reset_mask"]
        mask = np.asarray(raw)
        if mask.dtype != np.bool_:
            raise TypeError(f"options['reset_mask'] must be a boolean array of shape ({n},) (True: reset that "
                            f"sub-env), got {type(raw).__name__} of dtype {mask.dtype}")
        if mask.shape != (n,):
            raise ValueError(f"options['reset_mask'] must have shape ({n},) (one flag per sub-env), got {mask.shape}")
        if self._state is None and not mask.all():
            raise RuntimeError("the first reset() must reset every sub-env (no reset_mask)")
        return mask.copy()

    def _check_seeds(self, seed) -> list[int | None]:
        n = self.num_envs
        if seed is None:
            return [None] * n
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, (bool, np.bool_)):
            check_seed(seed, "seed")
            return [int(seed) + i for i in range(n)]
        if isinstance(seed, (str, bytes, dict, set)) or not hasattr(seed, "__len__"):
            raise TypeError(f"seed = {seed!r} ({type(seed).__name__}): pass an integer >= 0 (sub-env i gets "
                            f"seed + i), None, or a list of {n} seeds (integers >= 0 or None)")
        seeds = list(seed)
        if len(seeds) != n:
            raise ValueError(f"seed must be an int, None or a list of {n} seeds (one per sub-env), got {len(seeds)}")
        return [check_seed(sd, f"seed[{i}]") for i, sd in enumerate(seeds)]

    def _reset_rows(self, idx: np.ndarray) -> None:
        """New episodes for sub-envs ``idx``: exactly :meth:`ISCCEnv.reset`'s draws, per sub-env."""
        if idx.size == 0:
            return
        s = self.scenario
        if self.n_drones is None:
            parts = [loop.init_mission(s, self._rngs[i]) for i in idx]
        else:  # each sub-env exactly ISCCMultiEnv's reset from its generator
            parts = [reset_drones(s, drone_seeds(self._rngs[i], self._k)) for i in idx]
        new = loop.LoopState(*(np.concatenate(fields) for fields in zip(*parts, strict=True)))
        rows = self._loops(idx)
        if self._state is None or idx.size == self.num_envs:
            self._state = new
        else:
            self._state = self._state.with_rows(rows, new)
        self._last_rx[rows] = 1.0
        self._last_peb[rows] = 0.0


class ISCCMultiVectorEnv(ISCCVectorEnv):
    """The vector entry point of ``iscc_gym/ISCC-Multi-v0``: :class:`ISCCVectorEnv` with ``n_drones``
    (default :data:`iscc_gym.sim.fleet.N_DRONES`) drones per sub-env.
    """

    def __init__(self, num_envs: int = 1, n_drones: int = N_DRONES, **kwargs: Any):
        super().__init__(num_envs, n_drones=n_drones, **kwargs)


def _check_count(value, name: str, none_ok: bool = False) -> int:
    """``value`` as an int >= 1, or an error naming ``name``: a bool, a float (2.5, NaN), a string is a
    ``TypeError``, an integer below 1 a ``ValueError``.
    """
    alt = " or None" if none_ok else ""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} = {value!r} ({type(value).__name__}); use an integer >= 1{alt}")
    if value < 1:
        raise ValueError(f"{name} = {value!r}; use an integer >= 1{alt}")
    return int(value)


def _autoreset_mode(value) -> AutoresetMode:
    """``value`` (an :class:`AutoresetMode`, its value ``"SameStep"`` or its name ``"SAME_STEP"``) as the
    mode, or a ``ValueError`` naming ``autoreset_mode``.
    """
    mode = value if isinstance(value, AutoresetMode) else None
    if mode is None and isinstance(value, str):
        mode = {m.value: m for m in AutoresetMode}.get(value) or AutoresetMode.__members__.get(value.upper())
    if mode is None or mode == AutoresetMode.DISABLED:
        raise ValueError(f"autoreset_mode = {value!r} is not supported; use gymnasium.vector.AutoresetMode.NEXT_STEP "
                         "(default) or AutoresetMode.SAME_STEP (or 'NextStep', 'SameStep')")
    return mode


def reset_bytes(s: Scenario) -> int:
    """Peak memory of one sub-env in bytes while all are reset, about 304 bytes a slot (1.5 MB at 5,000
    slots, measured 1.49): the episode's reference kept in the state (72 bytes a slot), and during a
    reset the sampled :class:`iscc_gym.trajectory.Reference` (80), its (N+1, 9) array and the batch's
    copy of it (72 each) beside the previous episode's; plus the small per-slot state. With blockage the
    mission rows carry 10 more columns (three copies of 80 bytes a slot) and the draw of the channel along
    the path about 35 temporary arrays of a slot's float (280): 824 bytes a slot (estimated, not measured).
    """
    return (304 if s.blockage == "none" else 824) * (s.n_slots + 1) + 16384 + 8 * s.queue_deadline_slots


def available_memory_bytes() -> int | None:
    """Memory the system can give this process now: ``MemAvailable`` of ``/proc/meminfo`` (Linux), else
    free physical pages x page size; None where neither is known.
    """
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_AVPHYS_PAGES"))
    except (AttributeError, ValueError, OSError):
        return None


def check_memory(s: Scenario, num_envs: int) -> None:
    """Raise ``ValueError`` naming ``num_envs`` when its episodes would not fit in the available memory
    (:func:`reset_bytes` per sub-env against :func:`available_memory_bytes`).
    """
    need = num_envs * reset_bytes(s)
    have = available_memory_bytes()
    if have is not None and need > have:
        fit = max(1, have // reset_bytes(s))
        raise ValueError(
            f"num_envs = {num_envs} needs about {need / 2**30:.3g} GiB for its episodes ({reset_bytes(s) / 2**20:.2g} "
            f"MiB per sub-env at {s.n_slots} slots), more than the {have / 2**30:.3g} GiB available: use at most "
            f"num_envs = {fit} on this machine, or a shorter mission (mission_duration_s)")


def _masked(info: dict, valid: np.ndarray) -> dict:
    """Gymnasium's vector info: each key's ``_key`` mask of the sub-envs it is valid for."""
    for key in list(info):
        info["_" + key] = valid
    return info
