r"""K drones of one base station sharing its band: the fleet's step as pure functions of a batch of loops.

Each drone is exactly the single-drone loop (its own reference trajectory, Kalman filter, LQG loop, links,
fading and noise streams); the 3K shares :math:`\alpha_{k,f}` (drone k, function f in sensing, control, data)
sum to 1. The per-subcarrier SNR does not depend on the share (the paper's footnote) and the subcarriers are
orthogonal (no inter-drone interference), so the compiled single-drone step runs on a batch of K loops, each
with its split scaled by its share of the band (:func:`iscc_gym.sim.functional.env_step`'s ``budget``).

Everything here composes the single env's functions: the action map (:func:`multi_split`, built on
:func:`iscc_gym.sim.task.action_to_split`), the reward (:func:`multi_reward`, from
:func:`iscc_gym.sim.kernel.reward_from_costs`), the reset (each drone a single env's reset with its own seed,
:func:`reset_drones`) and the info (:func:`iscc_gym.sim.functional.step_info`). The faces are
:class:`iscc_gym.envs.multi.ISCCMultiEnv`, its vector env and its PettingZoo view; docs/model.md, section 5,
states the modelling choices.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.utils import seeding
from numpy.typing import ArrayLike

from iscc_gym.scenario import Scenario
from iscc_gym.sim import kernel, loop
from iscc_gym.sim.effects import task_effects
from iscc_gym.sim.functional import INFO_COLUMNS, env_step, reset_info_arrays
from iscc_gym.sim.schema import COL, OBS_NAMES
from iscc_gym.sim.task import action_to_split, check_split, split_to_action

#: Drones per base station by default.
N_DRONES = 4


#: The largest supported number of drones (memory and observation size grow with it).
MAX_DRONES = 64


def check_n_drones(n_drones) -> int:
    """``n_drones`` as an int in [1, :data:`MAX_DRONES`], or a ``ValueError`` naming it."""
    if isinstance(n_drones, bool) or not isinstance(n_drones, (int, np.integer)) \
            or not 1 <= n_drones <= MAX_DRONES:
        raise ValueError(f"n_drones = {n_drones!r}; use an integer from 1 to {MAX_DRONES}")
    return int(n_drones)


def drone_scenario(s: Scenario, n_drones: int, rate_min_per_drone_bps: float | None = None) -> Scenario:
    """The scenario each of K drones flies: ``s`` with the per-drone rate requirement
    ``rate_min_per_drone_bps``, by default ``s.rate_min_bps / K`` (the base station's data requirement
    split evenly: at the ``paper`` preset's 20 Mbps for each drone, K >= 2 drones would need more than
    the whole band; docs/model.md, section 5).
    """
    k = check_n_drones(n_drones)
    fx = task_effects(s)
    if fx.blockage or fx.queue:
        raise ValueError(f"the multi-drone env flies the paper's task only (blockage = 'none', queue_deadline_s = 0), "
                         f"got blockage = {s.blockage!r}, queue_deadline_s = {s.queue_deadline_s!r}: use the single or "
                         f"vector env for the urban task")
    rate = s.rate_min_bps / k if rate_min_per_drone_bps is None else rate_min_per_drone_bps
    try:
        rate = float(rate)
    except (TypeError, ValueError):
        raise ValueError(f"rate_min_per_drone_bps = {rate_min_per_drone_bps!r}; use a number of bps >= 0 "
                         "or None (the scenario's rate_min_bps / n_drones)") from None
    if not (np.isfinite(rate) and rate >= 0.0):
        raise ValueError(f"rate_min_per_drone_bps = {rate_min_per_drone_bps!r}; use a number of bps >= 0 "
                         "or None (the scenario's rate_min_bps / n_drones)")
    return s.replace(rate_min_bps=rate)


def _weights(actions: np.ndarray, k: int) -> np.ndarray:
    a = np.asarray(actions, dtype=float)
    if a.ndim == 0 or a.shape[-1] != 3 * k:
        raise ValueError(f"actions must have shape (..., {3 * k}) for {k} drones (3 shares each), got {a.shape}")
    return ((np.clip(a, -1.0, 1.0) + 1.0) * 0.5).reshape(a.shape[:-1] + (k, 3))


def drone_budgets(actions: ArrayLike, n_drones: int) -> np.ndarray:
    r"""Each drone's share of the band for actions in [-1, 1]^{3K}, shape (..., K).

    .. math::
        w_{k,f} = (\mathrm{clip}(a_{3k+f}, -1, 1) + 1)/2,\qquad
        b_k = \textstyle\sum_f w_{k,f} \big/ \sum_{j,f} w_{j,f}

    (:math:`b_k = 1/K` where every :math:`w = 0`). With the drone's own split
    :func:`iscc_gym.sim.task.action_to_split` of its three actions, :math:`\alpha_{k,f} = b_k\,
    w_{k,f}/\sum_f w_{k,f} = w_{k,f}/\sum_{j,f} w_{j,f}`: the single env's map onto the simplex, over
    3K shares.
    """
    k = check_n_drones(n_drones)
    w = _weights(actions, k)
    per = w.sum(axis=-1)
    total = per.sum(axis=-1, keepdims=True)
    ok = total > 1e-12
    return np.where(ok, per / np.where(ok, total, 1.0), 1.0 / k)


def multi_split(actions: ArrayLike, n_drones: int) -> np.ndarray:
    """The applied shares ``alpha[..., k, f]`` of actions (..., 3K): each drone's budget
    (:func:`drone_budgets`) times its own split (:func:`iscc_gym.sim.task.action_to_split`), as the
    compiled step applies them; they sum to 1 over (k, f).
    """
    k = check_n_drones(n_drones)
    a = np.asarray(actions, dtype=float)
    b = drone_budgets(a, k)
    return b[..., None] * action_to_split(a.reshape(a.shape[:-1] + (k, 3)))


def shares_to_action(alpha: ArrayLike) -> np.ndarray:
    """Inverse of :func:`multi_split`: the action (..., 3K) float32 whose shares are ``alpha`` (..., K, 3)
    (largest share at +1), for shares >= 0 summing to 1 over (k, f).
    """
    a = np.asarray(alpha, dtype=float)
    if a.ndim < 2 or a.shape[-1] != 3:
        raise ValueError(f"alpha must have shape (..., K, 3), got {a.shape}")
    flat = check_split(a.reshape(a.shape[:-2] + (-1,)), "alpha", " over drones and functions")
    return split_to_action(flat)


def drone_rewards(s: Scenario, err: ArrayLike, cost_rate: ArrayLike, cost_stability: ArrayLike,
                  terminated: ArrayLike, n_next: ArrayLike) -> np.ndarray:
    r"""Each drone's reward of a step, shape (..., K): the single env's reward of that drone.

    .. math::
        r_{k,n} = -\min(e_{k,n}, e_\max) - w_\mathrm{rate}\, c^\mathrm{rate}_{k,n}
        - w_\mathrm{stab}\, c^\mathrm{stab}_{k,n} - [\text{lost}_n]\, e_\max (N - n')

    (:func:`iscc_gym.sim.kernel.reward_from_costs` and :func:`iscc_gym.sim.kernel.terminal_penalty`), where
    ``err``, ``cost_rate`` and ``cost_stability`` are (..., K), ``terminated`` (...,) is True where
    **any** drone lost track (the mission ends for every drone, so every drone pays the penalty for the
    slots left) and ``n_next`` (...,) is the slot index after the step, :math:`n'`.
    """
    r = kernel.reward_from_costs(s.max_tracking_error_m, s.w_rate, s.w_stab, np.asarray(err, dtype=float),
                                 np.asarray(cost_rate, dtype=float), np.asarray(cost_stability, dtype=float))
    pen = kernel.terminal_penalty(s.max_tracking_error_m, s.n_slots, np.asarray(n_next, dtype=np.int64))
    return r - np.where(np.asarray(terminated, dtype=bool), pen, 0.0)[..., None]


def multi_reward(s: Scenario, out: np.ndarray, n_next: ArrayLike) -> np.ndarray:
    r"""The team reward of a step from the per-drone step outputs ``out`` (..., K, columns).

    The mean over drones of each drone's single-env reward (:func:`drone_rewards`):

    .. math::
        r_n = \frac1K \sum_k \Bigl(-\min(e_{k,n}, e_\max) - w_\mathrm{rate}\, c^\mathrm{rate}_{k,n}
        - w_\mathrm{stab}\, c^\mathrm{stab}_{k,n}\Bigr)

    minus the single env's loss-of-track penalty :math:`e_\max` per remaining slot when any drone
    loses track. Tracking error and penalties are both per-drone means, so the reward's trade-off
    between a drone's tracking and its costs is the single env's at every K (docs/model.md, section
    5). With K = 1 it is the single env's reward bit for bit.
    """
    err, c_rate, c_stab = (out[..., COL[name]] for name in ("tracking_error_m", "cost_rate", "cost_stability"))
    term = (out[..., COL["terminated"]] == 1.0).any(axis=-1)
    return drone_rewards(s, err, c_rate, c_stab, term, n_next).mean(axis=-1)


def drone_seeds(rng: np.random.Generator, n_drones: int) -> list[int]:
    """K seeds drawn from an env's generator, one per drone (each drone is a single env reset with
    its seed: :func:`reset_drones`).
    """
    return [int(x) for x in rng.integers(0, 2**63 - 1, size=check_n_drones(n_drones), dtype=np.int64)]


def reset_drones(s: Scenario, seeds) -> loop.LoopState:
    """The initial state of K drones (a batch of K loops), drone k exactly the single env
    (:class:`iscc_gym.envs.env.ISCCEnv`) reset with ``seeds[k]``: its reference, initial state and noise key.
    """
    rngs = [seeding.np_random(int(sd))[0] for sd in seeds]
    parts = [loop.init_mission(s, r) for r in rngs]
    return loop.LoopState(*(np.concatenate(fields) for fields in zip(*parts, strict=True)))


def multi_step(s: Scenario, state: loop.LoopState, actions: np.ndarray, n_drones: int,
               active: ArrayLike = None):
    """One step of N multi-drone envs (N x K loops, drone k of env i at row i K + k).

    Returns ``(state, out, obs, reward, terminated, truncated)``: ``out`` (N, K, columns) the per-drone
    step outputs (:data:`iscc_gym.sim.schema.STEP_COLUMNS`), ``obs`` (N, 23 K) the drones' observations
    concatenated, ``reward`` (N,) :func:`multi_reward`, ``terminated`` (N,) when any drone loses
    track, ``truncated`` (N,) at the mission's end. ``active`` (N,) bool: envs to step (the others
    keep their state, zero outputs).
    """
    k = n_drones
    a = np.asarray(actions, dtype=np.float64)
    nenv = a.shape[0]
    budget = drone_budgets(a, k).reshape(-1)
    rows = a.reshape(nenv * k, 3)
    act = None if active is None else np.repeat(np.asarray(active, dtype=bool), k)
    state, out, obs = env_step(s, state, rows, active=act, budget=budget)
    out = out.reshape(nenv, k, -1)
    n_next = state.n.reshape(nenv, k)[:, 0]
    reward = multi_reward(s, out, n_next)
    terminated = (out[..., COL["terminated"]] == 1.0).any(axis=-1)
    truncated = ~terminated & (out[..., COL["truncated"]] == 1.0).any(axis=-1)
    if active is not None:
        reward = np.where(active, reward, 0.0)
    return state, out, obs.reshape(nenv, k * len(OBS_NAMES)), reward, terminated, truncated


def multi_reset_info(state: loop.LoopState, n_drones: int) -> dict:
    """The keys of :func:`iscc_gym.sim.functional.step_info` (``fleet=True``) at reset, for N envs of K drones
    (``state`` of N K loops): per-drone arrays (N, K) (``alpha`` (N, K, 3), equal shares 1/(3K)), ``cost`` 0 and
    ``mean_tracking_error_m`` (N,), ``slot`` (N,); the per-drone values of
    :func:`iscc_gym.sim.functional.reset_info_arrays` (the initial tracking error, zero costs, NaN slot outcomes).
    """
    k = n_drones
    per = reset_info_arrays(state)
    nenv = state.x.shape[0] // k
    info: dict[str, Any] = {key: per[key].reshape(nenv, k) for key in INFO_COLUMNS}
    info["packet_received"] = per["packet_received"].reshape(nenv, k)
    info["alpha"] = np.full((nenv, k, 3), 1.0 / (3 * k))
    info["cost"] = np.zeros(nenv)
    info["mean_tracking_error_m"] = info["tracking_error_m"].mean(axis=-1)
    info["slot"] = per["slot"][::k].copy()
    return info
