"""The env's step, compiled: action map, slot, reward and costs, next observation, as one loop over
the batch (numba), composed of the compiled slot (:func:`iscc_gym.sim.loop.step_one`, then the data queue's
:func:`iscc_gym.sim.loop.queue_slot_one`) and the physics
modules' scalar forms.

Every equation of the slot is written once, in the module that owns it (``channel.*_one``,
``fbl.*_one``, ``sensing.*_one``, ``kalman.*_one``, ``dynamics.*_one``, ``queue.*_one``), and composed by
:func:`iscc_gym.sim.loop.step_one` and :func:`iscc_gym.sim.loop.queue_slot_one` (the whole slot transition,
which :func:`iscc_gym.sim.loop.step` runs too);
this module adds the env's own pieces, also written once: the action
map (:func:`split_one`), the reward and costs (:func:`reward_one`) and the observation
(:func:`observe_one`). ``tests/physics/test_kernel.py`` checks it against the numpy oracle
(``tests/oracle_loop.py``, to ~1e-9 relative) on random states and whole episodes. Each slot draws
its own normals from the loop's episode key (:mod:`iscc_gym.sim.noise`), on whichever core steps the
loop; drone i of a batch goes through the same machine code whatever the batch size, so a batch
reproduces single runs bit for bit (the vector env relies on it).

Every per-scenario constant is computed once in Python (:func:`iscc_gym.sim.params.slot_params`) and
passed as one typed record.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit, prange, vectorize

from iscc_gym.physics.channel import beam_gain_one, direction_one, link_snr_one
from iscc_gym.physics.fbl import link_terms_one, min_comm_share_one, min_ctrl_share_one
from iscc_gym.physics.queue import oldest_age_one
from iscc_gym.physics.sensing import echo_amplitude_one
from iscc_gym.sim.loop import (
    LoopState,
    StepOutputs,
    channel_state_one,
    new_outputs,
    next_row,
    queue_slot_one,
    slot_draws_one,
    state_row,
    step_one,
    work_space,
)
from iscc_gym.sim.mission import MC
from iscc_gym.sim.noise import fill_slot_normals
from iscc_gym.sim.schema import (
    COL,
    CTRL_SHARE_SCALE,
    ENV_COLUMNS,
    ERR_SCALE,
    METRIC_NAMES,
    N_PREVIEW_OBS,
    N_STEP_COLUMNS,
    O_BACKLOG,
    O_ECHO_LOS_AHEAD,
    O_ECHO_NLOS_AHEAD,
    O_OLDEST_AGE,
    O_P_LOS_AHEAD,
    O_SNR_LOS_AHEAD,
    O_SNR_NLOS_AHEAD,
    OBS,
    OBS_BOUND,
    PEB_SCALE,
    REF_ACC_SCALE,
    REF_VEL_SCALE,
    SNR_SCALE,
)

__all__ = ["env_step_batch", "env_row_one", "env_step_batch_parallel", "observe_batch",
           "observe_one", "reward_one", "reward_batch", "split_one", "split_batch", "parallel_chunk", "new_outputs",
           "METRIC_NAMES", "ENV_COLUMNS", "LastSlot", "StepInputs"]

N_ENV_COLUMNS = N_STEP_COLUMNS


class LastSlot(NamedTuple):
    """What the observation reports of the last slot: the command's delivery (1.0 or 0.0), the PEB (m), and the
    field's measured block (the command link's fading gain and the echo SNR, dB); at reset ``(1.0, 0.0, 0.0, 0.0)``.
    """

    received: float
    peb_m: float
    fade_db: float
    echo_db: float


class StepInputs(NamedTuple):
    """The batch step's inputs beside the state: ``action`` (B, 3), ``budget`` (B,) or no rows (the whole band), ``z``
    the slot's normals (B, draws) or no rows (each loop draws its own), ``active`` (B,) bool. Passed to the compiled
    functions as a plain tuple (see :class:`iscc_gym.sim.loop.StepOutputs`).
    """

    action: np.ndarray
    budget: np.ndarray
    z: np.ndarray
    active: np.ndarray

_ERR, _PEB, _EPS, _RX, _RATE_COMM, _DIVERGED = (COL[k] for k in ("tracking_error_m", "peb_m", "eps_ctrl",
                                                                "packet_received", "rate_comm_bps", "diverged"))
_ALPHA, _COST_RATE, _COST_STAB, _REWARD, _TERM, _TRUNC = (COL[k] for k in ("alpha_sen", "cost_rate", "cost_stability",
                                                                          "reward", "terminated", "truncated"))
_O_POS, _O_REF, _O_STD, _O_SNR, _O_RANGE = OBS["pos_err_x"], OBS["ref_vel_x"], OBS["est_pos_std"], OBS["snr_db"], \
    OBS["range"]
_O_SIN_EL, _O_COS_AZ, _O_SIN_AZ = OBS["sin_elevation"], OBS["cos_azimuth"], OBS["sin_azimuth"]
_O_CTRL, _O_COMM, _O_RX, _O_PEB, _O_TIME = (OBS[k] for k in ("alpha_ctrl_min", "alpha_comm_min", "last_packet_received",
                                                           "last_peb", "time_left"))
_DROPPED = COL["bits_dropped"]
_SNR, _SNR_LS, _ECHO = COL["snr_db"], COL["snr_large_scale_db"], COL["echo_snr_db"]
_MC_P, _MC_LOS, _MC_SNR_TRUE, _MC_ECHO_TRUE = MC["p_los_map"], MC["los"], MC["snr_true_db"], MC["echo_true_db"]
_N_PREVIEW_DB = 4  # the preview point's dB columns, after p_los_map's shadow_map_unit (sim.mission.CHANNEL_COLUMNS)
_MC_DB = MC["snr_los_map_db"]
# the map's four dB columns are the preview point's four dB entries, in the same order
assert tuple(MC[k] - _MC_DB for k in ("snr_los_map_db", "snr_nlos_map_db", "echo_los_map_db",
                                      "echo_nlos_map_db")) == (0, 1, 2, 3)
assert (O_SNR_NLOS_AHEAD, O_ECHO_LOS_AHEAD, O_ECHO_NLOS_AHEAD) == tuple(O_SNR_LOS_AHEAD + m for m in (1, 2, 3))


@njit(cache=True, error_model="numpy", inline="always")
def _symlog(x, scale):
    """sign(x) ln(1 + |x| / scale) (the observation's scaling, :data:`iscc_gym.sim.schema.OBS_SCALING`)."""
    s = 1.0 if x > 0 else (-1.0 if x < 0 else 0.0)
    return s * math.log1p(abs(x) * (1.0 / scale))


@njit(cache=True, error_model="numpy")
def observe_one(c, now, last, out):
    """The observation of one loop (the entries, scalings and layout of :data:`iscc_gym.sim.schema.OBS_BLOCKS`,
    :func:`iscc_gym.sim.schema.observation_table`), written into ``out`` (:func:`iscc_gym.sim.schema.obs_size`
    entries: the optional blocks at :func:`iscc_gym.sim.schema.obs_offsets`, passed in the record); returns False
    where an entry could not be evaluated (NaN, written as 0) or the estimate is not finite. ``now``: the loop's
    state (an unbatched :class:`iscc_gym.sim.loop.LoopState`; ``x`` unread); ``last``: :class:`LastSlot`.
    """
    x_hat, p, shadow, n, ref, q = now.x_hat, now.p, now.shadow, now.n, now.ref, now.queue
    last_received, last_peb, last_fade_db, last_echo_db = last
    dist, gx, gy, gz, ct, st, cp, sp = direction_one(c.gbs_height_m, x_hat[0], x_hat[1], x_hat[2])
    shadow_db, extra_db = channel_state_one(c, ref[n], x_hat[2], dist, shadow)
    # with blockage the slot's channel state is measured (the map tells only of the slots ahead)
    shadow_comm = shadow_db if c.blockage == 0.0 else shadow_db + extra_db
    snr = link_snr_one(c.snr_k, beam_gain_one(c, ct, st, cp, sp), dist, shadow_comm)
    cap, sqrt_v = link_terms_one(snr)
    ctrl_min = min_ctrl_share_one(cap, sqrt_v, c.bits_per_hz, c.q_back)
    if c.queue == 1.0:  # the share that would clear the backlog and a slot's mean arrivals
        backlog = 0.0
        for j in range(q.shape[0]):
            backlog += q[j]
        rate_need = (backlog + c.arrival_mean_bits) / c.dt_s
    else:
        backlog = 0.0
        rate_need = c.rate_min_bps
    comm_min = min_comm_share_one(cap, sqrt_v, rate_need, c.bandwidth_hz, c.k_comm)
    for j in range(6):
        out[_O_POS + j] = _symlog(x_hat[j] - ref[n, j], ERR_SCALE)
    for j in range(6):
        out[_O_REF + j] = ref[n, 3 + j] * (REF_VEL_SCALE if j < 3 else REF_ACC_SCALE)
    out[_O_STD] = _symlog(math.sqrt(p[0, 0] + p[1, 1] + p[2, 2]), ERR_SCALE)
    out[_O_SNR] = 10.0 * math.log10(snr) * SNR_SCALE
    out[_O_RANGE] = dist * (1.0 / c.coverage_radius_m)
    out[_O_SIN_EL] = sp
    out[_O_COS_AZ] = ct
    out[_O_SIN_AZ] = st
    out[_O_CTRL] = CTRL_SHARE_SCALE * ctrl_min
    out[_O_COMM] = comm_min
    out[_O_RX] = last_received
    out[_O_PEB] = _symlog(last_peb, PEB_SCALE)
    out[_O_TIME] = 1.0 - n * (1.0 / c.n_slots)
    # the optional blocks where the schema lays them out (schema.obs_offsets, via the record; -1: absent)
    if c.obs_queue_at >= 0.0:
        k = int(c.obs_queue_at)
        out[k + O_BACKLOG] = math.log1p(backlog / max(c.arrival_mean_bits, 1e-300))
        out[k + O_OLDEST_AGE] = oldest_age_one(q) / c.queue_deadline_slots
    if c.obs_echo_at >= 0.0:
        echo = echo_amplitude_one(c, dist, shadow_db + 2.0 * extra_db, 1.0) / c.sen_noise_w
        out[int(c.obs_echo_at)] = 10.0 * math.log10(echo) * SNR_SCALE
    if c.obs_measured_at >= 0.0:
        k = int(c.obs_measured_at)
        out[k] = last_fade_db * SNR_SCALE
        out[k + 1] = last_echo_db * SNR_SCALE
    if c.obs_world_at >= 0.0:  # the hidden world of the slot about to be allocated (the aware bound's)
        k, w = int(c.obs_world_at), int(c.world_at)
        out[k] = ref[n, w] * SNR_SCALE
        out[k + 1] = ref[n, w + 1] * SNR_SCALE
    last = int(c.n_slots)
    stride = int(c.preview_stride_slots)
    k = int(c.obs_preview_at)
    for j in range(1, int(c.preview_slots) + 1):
        r = min(n + j * stride, last)
        if c.preview_truth == 1.0:  # the oracle's preview: the realised state, both states' entries its SNRs
            out[k + O_P_LOS_AHEAD] = ref[r, _MC_LOS]
            out[k + O_SNR_LOS_AHEAD] = out[k + O_SNR_NLOS_AHEAD] = ref[r, _MC_SNR_TRUE] * SNR_SCALE
            out[k + O_ECHO_LOS_AHEAD] = out[k + O_ECHO_NLOS_AHEAD] = ref[r, _MC_ECHO_TRUE] * SNR_SCALE
        else:
            out[k + O_P_LOS_AHEAD] = ref[r, _MC_P]
            for m in range(_N_PREVIEW_DB):
                out[k + O_SNR_LOS_AHEAD + m] = ref[r, _MC_DB + m] * SNR_SCALE
        k += N_PREVIEW_OBS
    ok = math.isfinite(shadow)
    for j in range(6):
        ok = ok and math.isfinite(x_hat[j])
        for k in range(6):
            ok = ok and math.isfinite(p[j, k])
    for j in range(out.shape[0]):
        v = out[j]
        if v != v:  # NaN: the model cannot evaluate this entry (a state far outside the region)
            v = 0.0
            ok = False
        out[j] = min(max(v, -OBS_BOUND), OBS_BOUND)
    return ok


@njit(cache=True, error_model="numpy")
def observe_batch(cp, state, last_received, last_peb, obs):
    """The observation of a batch (:func:`observe_one`; ``state``: a :class:`iscc_gym.sim.loop.LoopState`'s fields as
    a plain tuple, the last slot's delivery and PEB (B,) each; no measured block), written into ``obs`` (B, obs_size)
    float32.
    """
    c = cp[0]
    st = LoopState(*state)
    for i in range(st.x_hat.shape[0]):
        observe_one(c, state_row(st, i), LastSlot(last_received[i], last_peb[i], 0.0, 0.0), obs[i])


@njit(cache=True, error_model="numpy", inline="always")
def split_one(a0, a1, a2):
    """:func:`iscc_gym.sim.task.action_to_split` of one action."""
    w0 = (min(max(a0, -1.0), 1.0) + 1.0) * 0.5
    w1 = (min(max(a1, -1.0), 1.0) + 1.0) * 0.5
    w2 = (min(max(a2, -1.0), 1.0) + 1.0) * 0.5
    total = w0 + w1 + w2
    if total <= 1e-12:
        return 1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0
    return w0 / total, w1 / total, w2 / total


@njit(cache=True, error_model="numpy")
def split_batch(action, alpha):
    """:func:`split_one` over the rows of ``action`` (n, 3) into ``alpha`` (n, 3) (the numpy API
    :func:`iscc_gym.sim.task.action_to_split`).
    """
    for i in range(action.shape[0]):
        alpha[i, 0], alpha[i, 1], alpha[i, 2] = split_one(action[i, 0], action[i, 1], action[i, 2])


@njit(cache=True, error_model="numpy", inline="always")
def reward_from_costs_one(max_err, w_rate, w_stab, err, cost_rate, cost_stab):
    """The reward of a slot from its tracking error and costs (:class:`iscc_gym.envs.env.ISCCEnv`, Rewards):
    ``-min(err, max_err) - w_rate cost_rate - w_stab cost_stab`` (also of expected costs: the
    analytic evaluator's expected reward).
    """
    return -(err if err <= max_err else max_err) - w_rate * cost_rate - w_stab * cost_stab


@vectorize(["float64(float64, float64, float64, float64, float64, float64)"], cache=True)
def reward_from_costs(max_err, w_rate, w_stab, err, cost_rate, cost_stab):
    """:func:`reward_from_costs_one` over arrays."""
    return reward_from_costs_one(max_err, w_rate, w_stab, err, cost_rate, cost_stab)


@njit(cache=True, error_model="numpy", inline="always")
def terminal_penalty_one(max_err, n_slots, n_next):
    """The loss-of-track penalty: ``max_err`` for each slot left after ``n_next`` (as if the error
    stayed at the bound for the rest of the mission).
    """
    return max_err * (n_slots - n_next)


@vectorize(["float64(float64, int64, int64)"], cache=True)
def terminal_penalty(max_err, n_slots, n_next):
    """:func:`terminal_penalty_one` over arrays."""
    return terminal_penalty_one(max_err, n_slots, n_next)


@njit(cache=True, error_model="numpy", inline="always")
def reward_one(c, err, rate, eps, dropped, terminated, n_next):
    """The slot's ``(cost_rate, cost_stability, reward)`` (:class:`iscc_gym.envs.env.ISCCEnv`, Rewards): a
    rate or loss probability that is NaN counts as a violation; an episode that terminates pays
    ``max_tracking_error_m`` for each remaining slot. With a queue the data term is the dropped bits over a
    slot's mean arrivals, and ``cost_rate`` 1 where bits were dropped (``rate`` unused); without, ``dropped``
    is unused and the term is the normalised shortfall below ``rate_min_bps``.
    """
    max_err = c.max_tracking_error_m
    rate_min = c.rate_min_bps
    if c.queue == 1.0:
        cost_rate = 1.0 if (dropped > 0.0 or dropped != dropped) else 0.0
        rate_term = dropped / max(c.arrival_mean_bits, 1e-300)
    else:
        if rate_min <= 0.0:
            cost_rate = 0.0
        elif rate != rate:
            cost_rate = 1.0
        else:
            cost_rate = max(0.0, rate_min - rate) / rate_min
        rate_term = cost_rate
    cost_stab = 1.0 if (eps > c.eps_star or eps != eps) else 0.0
    reward = reward_from_costs_one(max_err, c.w_rate, c.w_stab, err, rate_term, cost_stab)
    if terminated:
        reward -= terminal_penalty_one(max_err, c.n_slots, n_next)
    return cost_rate, cost_stab, reward


@njit(cache=True, error_model="numpy")
def reward_batch(cp, err, rate, eps, dropped, terminated, n_next, cost_rate, cost_stab, reward):
    """:func:`reward_one` over flat arrays (the numpy API :func:`iscc_gym.sim.task.reward_and_costs`)."""
    c = cp[0]
    for i in range(err.shape[0]):
        cost_rate[i], cost_stab[i], reward[i] = reward_one(c, err[i], rate[i], eps[i], dropped[i], terminated[i],
                                                           n_next[i])


@njit(cache=True, error_model="numpy", inline="always")
def env_row_one(c, mats, now, alpha, zi, nxt, mt, ob, work, blocked, field):
    """One env step of one loop (``now``: an unbatched :class:`iscc_gym.sim.loop.LoopState`) from its split ``alpha``
    ``(a0, a1, a2)`` and the slot's normals ``zi``, its next state into ``nxt`` (:class:`iscc_gym.sim.loop.RowNext`):
    the slot transition
    (:func:`iscc_gym.sim.loop.step_one`, then the data queue's :func:`iscc_gym.sim.loop.queue_slot_one`), the next
    observation (:func:`observe_one`, into ``ob``), reward and costs (:func:`reward_one`) and the done flags, written
    into the row ``mt`` (:data:`ENV_COLUMNS`); returns the next shadowing state.

    The one step source of every face: the CPU batch (:func:`env_step_batch`, :func:`env_step_batch_parallel`) and
    the device kernel (:mod:`iscc_gym.gpu.kernel`, compiled by numba-cuda) call it. It allocates nothing: ``work``
    (:func:`iscc_gym.sim.loop.work_from`) is scratch the caller owns (a buffer per batch on the CPU, per-thread local
    memory on the GPU); the next state goes to arrays that must not alias the current one. Inlined into its caller
    (no call overhead; compiled under the caller's flags, as the code it replaced).
    """
    shadow_next = step_one(c, mats, now, alpha, zi, nxt, mt, work, blocked, field)
    queue_slot_one(c, now.queue, zi, mt, nxt.queue)
    n_next = now.n + 1
    evaluable = observe_one(c, LoopState(nxt.x, nxt.x_hat, nxt.p, shadow_next, n_next, now.ref, now.key, nxt.queue),
                            LastSlot(mt[_RX], mt[_PEB], mt[_SNR] - mt[_SNR_LS], mt[_ECHO]), ob)
    terminated = mt[_DIVERGED] == 1.0 or not evaluable
    cost_rate, cost_stab, reward = reward_one(c, mt[_ERR], mt[_RATE_COMM], mt[_EPS], mt[_DROPPED], terminated, n_next)
    mt[_ALPHA], mt[_ALPHA + 1], mt[_ALPHA + 2] = alpha
    mt[_COST_RATE], mt[_COST_STAB], mt[_REWARD] = cost_rate, cost_stab, reward
    mt[_TERM] = 1.0 if terminated else 0.0
    mt[_TRUNC] = 1.0 if (not terminated and n_next >= c.n_slots) else 0.0
    return shadow_next


@njit(cache=True, error_model="numpy")
def _env_rows(cp, mats, state, inputs, outputs, lo, hi, blocked=None, field=None):
    """env_step_batch for rows lo..hi-1, writing into the output arrays (scratch: one work space and one draw
    buffer for the rows, :func:`env_row_one`).
    """
    c = cp[0]
    st, ins, o = LoopState(*state), StepInputs(*inputs), StepOutputs(*outputs)
    work = work_space()
    draw = ins.z.shape[0] == 0
    whole = ins.budget.shape[0] == 0
    zbuf = np.empty(slot_draws_one(c))
    for i in range(lo, hi):
        if not ins.active[i]:
            o.x[i], o.x_hat[i], o.p[i], o.shadow[i] = st.x[i], st.x_hat[i], st.p[i], st.shadow[i]
            o.queue[i] = st.queue[i]
            o.out[i] = 0.0
            o.obs[i] = 0.0
            continue
        a0, a1, a2 = split_one(ins.action[i, 0], ins.action[i, 1], ins.action[i, 2])
        if not whole:  # the loop's share of the band (iscc_gym.envs.multi): its split scaled by it
            b = ins.budget[i]
            a0, a1, a2 = a0 * b, a1 * b, a2 * b
        if draw:  # the episode's noise stream (noise.slot_normals), drawn where it is used
            fill_slot_normals(st.key[i], st.n[i], zbuf)
            zi = zbuf
        else:
            zi = ins.z[i]
        o.shadow[i] = env_row_one(c, mats, state_row(st, i), (a0, a1, a2), zi, next_row(o, i), o.out[i], o.obs[i],
                                  work, blocked, field)


@njit(cache=True, error_model="numpy")
def env_step_batch(c, mats, state, inputs, outputs, blocked=None, field=None):
    """One env step of a batch: action -> split (:func:`split_one`), slot transition
    (:func:`iscc_gym.sim.loop.step_one`, then the data queue's :func:`iscc_gym.sim.loop.queue_slot_one`), reward and
    costs (:func:`reward_one`), next observation (:func:`observe_one`). ``state``: a
    :class:`iscc_gym.sim.loop.LoopState`'s fields, ``inputs``: :class:`StepInputs`', ``outputs``:
    :class:`iscc_gym.sim.loop.StepOutputs`' (:func:`new_outputs`), each a plain tuple; written into the outputs: next
    x, x_hat, p, shadow, queue, ``out`` (B, N_ENV_COLUMNS) and ``obs`` (B, obs_size) float32. ``budget`` (B,) scales
    loop i's split to its share of the band (the multi-drone env, :mod:`iscc_gym.envs.multi`), or has no rows: the
    whole band (the single env). ``z`` holds the slot's normals (B, n_draws), or has no rows: then each loop draws its
    own from its episode key (noise.slot_normals(key[i], n[i])). Loops with ``active[i]`` False are left as they are
    (state copied, zero outputs). ``blocked``, ``field``: None without blockage, without the field's world (the
    defaults), True with (:func:`iscc_gym.sim.loop.step_one`'s compile-time switches).
    """
    _env_rows(c, mats, state, inputs, outputs, 0, state[0].shape[0], blocked, field)


@njit(cache=True, error_model="numpy", parallel=True)
def env_step_batch_parallel(c, mats, state, inputs, outputs, chunk, blocked=None, field=None):
    """:func:`env_step_batch` with chunks of ``chunk`` rows spread over all cores: each row goes
    through the same compiled :func:`_env_rows`, so results equal the serial kernel's bit for bit
    whatever the chunking.
    """
    nb = state[0].shape[0]
    n_chunks = (nb + chunk - 1) // chunk
    for k in prange(n_chunks):
        lo = k * chunk
        _env_rows(c, mats, state, inputs, outputs, lo, min(lo + chunk, nb), blocked, field)


def parallel_chunk(nb: int) -> int:
    """Rows per task: two tasks per thread, at least 32 rows each (measured on 2 cores: 1024 envs
    ~0.9 M env-steps/s with 64-512 rows per task, ~0.5 M with 16).
    """
    import numba

    tasks = 2 * numba.get_num_threads()
    return max(32, -(-nb // tasks))
