"""The env step as pure functions of a batch of loop states: the faces (:mod:`iscc_gym.envs`) are thin
stateful shells around them.

:func:`env_step` (action map, slot transition, reward, costs and the next observation, one compiled call),
:func:`observe` and :func:`decode_observation` (the observation and its physical values), and the one builder
of what a step reports, :func:`step_info` (and :func:`reset_info_arrays` for the same keys at reset), used by the
single env, the vector env, the multi-drone env and its PettingZoo view.
"""

from __future__ import annotations

import operator
from typing import Any

import numba
import numpy as np
from numpy.typing import ArrayLike

from iscc_gym import threads
from iscc_gym.scenario import Scenario, per_scenario
from iscc_gym.sim import kernel, loop
from iscc_gym.sim.effects import task_effects
from iscc_gym.sim.params import slot_params
from iscc_gym.sim.schema import (
    COL,
    N_DRAWS,
    STEP_COLUMNS,
    ObsEntry,
    n_draws,
    obs_entries,
    obs_size,
)

__all__ = ["env_step", "observe", "decode_observation", "step_info", "reset_info_arrays", "INFO_COLUMNS", "INFO_KEYS",
           "SLOT_OUTCOME_KEYS", "PARALLEL_MIN_BATCH"]


def observe(s: Scenario, state: loop.LoopState, last_received: ArrayLike, last_peb_m: ArrayLike):
    """The observation of :class:`ISCCEnv` (table in its docstring), shape (B, obs_size(s)), float32.

    A pure function of a batch of loop states and the last slot's outcome (arrays of shape (B,)),
    so the single env and any vector env build it the same way (:func:`iscc_gym.sim.kernel.observe_one`;
    an unbatched state gives shape (23,)).
    """
    if state.x.ndim == 1:
        return observe(s, loop.LoopState(*(f[None] for f in state)), last_received, last_peb_m)[0]
    nb = state.x.shape[0]
    obs = np.empty((nb, _output_sizes(s)[0]), np.float32)
    kernel.observe_batch(slot_params(s)[0], tuple(state),
                         np.broadcast_to(np.asarray(last_received, dtype=float), (nb,)),
                         np.broadcast_to(np.asarray(last_peb_m, dtype=float), (nb,)), obs)
    return obs


def decode_observation(obs: ArrayLike, s: Scenario) -> dict:
    """Named physical values of observations (any leading batch shape), inverting the scalings of
    :data:`iscc_gym.sim.schema.OBS_BLOCKS` (:func:`iscc_gym.sim.schema.observation_table`).

    Entries at the clip bound (+-``OBS_BOUND``) decode to the bound's value, not the true one.

    Returns
    -------
    dict of ndarray
        Keyed by each entry's ``decoded`` name (:class:`iscc_gym.sim.schema.ObsEntry`): ``pos_err_m``,
        ``vel_err_mps`` (predicted estimate minus reference), ``ref_vel_mps``, ``ref_acc_mps2`` (shape (..., 3));
        ``est_pos_std_m``, ``snr_db`` (predicted large-scale SNR), ``range_m``, ``sin_elevation``, ``cos_azimuth``,
        ``sin_azimuth``, ``alpha_ctrl_min``, ``alpha_comm_min``, ``last_packet_received`` (bool), ``last_peb_m``,
        ``slot`` (the slot index n, float) (shape (...)); with a queue ``backlog_bits``, ``oldest_age_slots``; with
        blockage ``echo_snr_db``; with a preview ``p_los_ahead``, ``snr_los_ahead_db``, ``snr_nlos_ahead_db``,
        ``echo_los_ahead_db``, ``echo_nlos_ahead_db`` (shape (..., H), point k at k - 1).
    """
    o = np.asarray(obs, dtype=float)
    if o.shape[-1] != obs_size(s):
        raise ValueError(f"obs must have {obs_size(s)} entries along the last axis for this scenario, got shape "
                         f"{o.shape}")
    groups: dict[str, list] = {}
    stacked = set()
    for j, (_, e, k) in enumerate(obs_entries(s)):
        groups.setdefault(e.decoded, []).append(_decode_entry(e, o[..., j], s))
        if k:
            stacked.add(e.decoded)
    return {key: (np.stack(vals, -1) if len(vals) > 1 or key in stacked else vals[0]) for key, vals in groups.items()}


def _decode_entry(e: ObsEntry, y: np.ndarray, s: Scenario):
    """The physical value of entry ``e`` from its observed values ``y`` (:class:`iscc_gym.sim.schema.ObsEntry`)."""
    if e.scaling == "symlog":
        return np.sign(y) * e.scale * np.expm1(np.abs(y))
    if e.scaling == "linear":
        return y / e.scale
    if e.scaling == "flag":
        return y > 0.5
    if e.scaling == "range":
        return y * s.coverage_radius_m
    if e.scaling == "time_left":  # 1 - n / n_slots
        return (1.0 - y) * s.n_slots
    if e.scaling == "log_arrivals":  # ln(1 + B / A)
        return np.expm1(y) * s.queue_arrival_bps * s.dt_s
    if e.scaling == "per_deadline":  # age / D
        return y * s.queue_deadline_slots
    raise ValueError(f"unknown scaling {e.scaling!r} of observation entry {e.name!r}")


#: Smaller batches are always stepped serially; larger ones on all cores only when the parallel kernel
#: is switched on (:mod:`iscc_gym.threads`; the same results bit for bit).
PARALLEL_MIN_BATCH = threads.PARALLEL_MIN_BATCH


def env_step(s: Scenario, state: loop.LoopState, actions: ArrayLike, normals: ArrayLike = None,
             active: ArrayLike = None, budget: ArrayLike = None):
    """One env step of a batch of loops: action map, slot transition, reward, costs, next observation.

    The single env (a batch of one) and the vector env both call it, so drone i of a batch
    reproduces the single env seeded alike bit for bit.

    Parameters
    ----------
    state : LoopState (batched, B loops)
    actions : ndarray (B, 3), finite
    normals : ndarray (B, N_DRAWS), or (B, N_DRAWS + 1) with a queue, optional
        The slot's standard normals; default: each loop's episode stream
        (:func:`iscc_gym.sim.noise.slot_normals` of its key and slot, drawn inside the kernel).
    active : ndarray (B,) bool, optional
        Loops to step (default all); the others keep their state, slot index and zero outputs.
    budget : ndarray (B,), optional
        Each loop's share of the band, which scales its split (the multi-drone env,
        :mod:`iscc_gym.envs.multi`); default the whole band.

    Returns
    -------
    state : LoopState
    out : ndarray (B, len(STEP_COLUMNS))
        :data:`STEP_COLUMNS`: the loop metrics, the applied split, ``cost_rate``,
        ``cost_stability``, ``reward``, ``terminated`` and ``truncated`` (0/1).
    obs : ndarray (B, obs_size(s)) float32
    """
    nb = state.x.shape[0]
    all_active = active is None
    if all_active:
        active = _all_active(nb)
    c, mats = slot_params(s)
    n_obs, deadline_slots, blocked = _output_sizes(s)
    x, x_hat, p, shadow, queue, out, obs = outputs = kernel.new_outputs(nb, len(STEP_COLUMNS), n_obs, deadline_slots)
    if normals is None:
        z = _NO_NORMALS
    else:
        z = normals
        draws = n_draws(s)
        if z.shape != (nb, draws):
            raise ValueError(f"normals must have shape ({nb}, {draws}) (the slot's draws"
                             f"{', and the queue arrivals' if draws > N_DRAWS else ''}), got {z.shape}")
    b = _WHOLE_BAND if budget is None else budget
    # plain tuples: a named one costs the compiled function's dispatcher about a microsecond
    args = (c, mats, tuple(state), (actions, b, z, active), outputs)
    # numba.get_num_threads() costs ~0.5 us: asked only for a batch the parallel kernel could take
    if nb >= PARALLEL_MIN_BATCH and threads.use_parallel(nb, numba.get_num_threads()):
        kernel.env_step_batch_parallel(*args, kernel.parallel_chunk(nb), *blocked)
    else:
        kernel.env_step_batch(*args, *blocked)
    n = state.n + 1 if all_active else state.n + active
    return state._replace(x=x, x_hat=x_hat, p=p, shadow=shadow, n=n, queue=queue), out, obs


@per_scenario
def _output_sizes(s: Scenario) -> tuple[int, int, tuple]:
    """The observation's length, the queue's slots and the compiled step's trailing switch arguments of a
    scenario (cached: asked at every step; :func:`iscc_gym.sim.loop.slot_switches`: for the paper none, the kernel's
    defaults compile the paper's slot).
    """
    fx = task_effects(s)
    return obs_size(s), fx.queue_deadline_slots, loop.slot_switches(s)


_ALL_ACTIVE: dict[int, np.ndarray] = {}


_NO_NORMALS = np.empty((0, N_DRAWS))  # the kernel's "draw from the keys" signal


_WHOLE_BAND = np.empty(0)  # the kernel's "every loop has the whole band" signal


def _all_active(nb: int) -> np.ndarray:
    """An all-True mask of length nb (cached: built once per batch size). Writable like the masks the vector
    env passes at an autoreset, so the compiled step has one signature (a read-only array is another type to
    numba: a second compile of the kernel, ~4 s on a fresh install); nothing writes it.
    """
    mask = _ALL_ACTIVE.get(nb)
    if mask is None:
        mask = np.ones(nb, dtype=bool)
        _ALL_ACTIVE[nb] = mask
    return mask


#: Info keys of a step whose values are outcomes of a slot (its fading, measurement and links): NaN in the
#: info of ``reset``, before any slot has run (:func:`reset_info_arrays`).
SLOT_OUTCOME_KEYS = ("snr_db", "snr_large_scale_db", "peb_m", "veb_mps", "eps_ctrl", "rate_comm_bps", "rate_ctrl_bps",
                     "estimation_error_m", "echo_snr_db")


def reset_info_arrays(state: loop.LoopState) -> dict:
    """The values of a step's info keys at reset, per loop of a batch (arrays of shape (B,), ``alpha``
    (B, 3)), so ``reset`` and ``step`` infos carry the same keys (libraries such as TorchRL build their
    specs from the reset info).

    ``tracking_error_m``: the initial state's true error ||p_0 - p_ref,0||; ``cost_rate``,
    ``cost_stability``, ``cost``: 0 (no slot, no violation); ``packet_received``: True and ``alpha``:
    equal thirds (as the observation's entry 20 at reset); ``slot``: 0; the slot outcomes of
    :data:`SLOT_OUTCOME_KEYS` (SNRs, PEB, VEB, loss probability, rates, estimation error): NaN.
    """
    nb = state.x.shape[0]
    zeros = np.zeros(nb)
    info = {"tracking_error_m": np.linalg.norm(state.x[:, :3] - state.ref[np.arange(nb), state.n, :3], axis=1),
            "cost_rate": zeros, "cost_stability": zeros.copy()}
    info.update({key: np.full(nb, np.nan) for key in SLOT_OUTCOME_KEYS})
    for key in ("bits_arrived", "bits_served", "bits_dropped"):
        info[key] = zeros.copy()
    info["backlog_bits"] = state.queue.sum(axis=1)  # zeros without a queue (an empty last axis)
    info["cost"] = zeros.copy()
    info["packet_received"] = np.ones(nb, dtype=bool)
    info["alpha"] = np.full((nb, 3), 1.0 / 3.0)
    info["slot"] = state.n.copy()
    return info


#: The output columns a step's info reports as they are, per loop.
INFO_COLUMNS = ("tracking_error_m", "cost_rate", "cost_stability", "snr_db", "snr_large_scale_db", "peb_m", "veb_mps",
                "eps_ctrl", "rate_comm_bps", "rate_ctrl_bps", "estimation_error_m", "bits_arrived", "bits_served",
                "bits_dropped", "backlog_bits", "echo_snr_db")
#: The keys of a step's info (:func:`step_info`): :data:`INFO_COLUMNS`, ``cost`` (rate plus stability cost,
#: Safety-Gymnasium's key), ``packet_received`` (bool), ``alpha`` (the applied split) and ``slot``. The single
#: env adds ``action``; the multi-drone env sums ``cost`` over its drones and adds ``mean_tracking_error_m``.
INFO_KEYS = (*INFO_COLUMNS, "cost", "packet_received", "alpha", "slot")
_INFO_COLUMNS = tuple((key, COL[key]) for key in INFO_COLUMNS)
_read_columns = operator.itemgetter(*(COL[key] for key in INFO_COLUMNS))
_RECEIVED = COL["packet_received"]
_ALPHA = slice(COL["alpha_sen"], COL["alpha_comm"] + 1)


def step_info(out: np.ndarray | list, slot: Any, fleet: bool = False) -> dict:
    """What a step reports (:data:`INFO_KEYS`), built from its output rows: the one builder of every face.

    Parameters
    ----------
    out : ndarray (..., len(STEP_COLUMNS)) or list
        :func:`env_step`'s rows: one loop's row as a list (``out[0].tolist()``, the single env) gives Python
        floats and bools; a batch (B, C) or (N, K, C) gives arrays, views into ``out`` (the vector envs; ``out``
        is new at every step).
    slot : int or ndarray
        The slot index after the step (the env's or each sub-env's).
    fleet : bool
        The last batch axis holds the K drones of one base station (the multi-drone env): ``cost`` is summed
        over them and ``mean_tracking_error_m`` added.

    Returns
    -------
    dict
    """
    if isinstance(out, list):
        info: dict[str, Any] = dict(zip(INFO_COLUMNS, _read_columns(out), strict=True))
        info["packet_received"] = out[_RECEIVED] == 1.0
        info["alpha"] = np.array(out[_ALPHA])
    else:
        info = {key: out[..., j] for key, j in _INFO_COLUMNS}
        info["packet_received"] = out[..., _RECEIVED] == 1.0
        info["alpha"] = out[..., _ALPHA]
    info["cost"] = info["cost_rate"] + info["cost_stability"]
    if fleet:
        info["cost"] = info["cost"].sum(axis=-1)
        info["mean_tracking_error_m"] = info["tracking_error_m"].mean(axis=-1)
    info["slot"] = slot
    return info
