"""One slot of the ISCC closed loop as a pure, batched transition.

``step(scenario, state, alpha, rng) -> (state, metrics)`` advances a batch of B independent
drones by one slot: sense (CRLB-limited ISAC or GNSS) -> Kalman update -> LQG command ->
finite-blocklength delivery (Bernoulli drop) -> drone dynamics -> Kalman prediction, and with a data queue
the slot's arrivals served by its data share (:mod:`iscc_gym.physics.queue`). The compiled slot
(:func:`step_one`, then the data queue's :func:`queue_slot_one`) is the whole transition: :func:`step` and the
env's kernel (:mod:`iscc_gym.sim.kernel`) both run it, so neither advances any part of the state the other does
not; nothing here keeps state between calls.

Randomness: each slot uses exactly :func:`iscc_gym.sim.schema.n_draws` standard normals per drone
(:data:`N_DRAWS`, one more with a queue: the arrivals). By default they are
the episode's stream (:func:`iscc_gym.sim.noise.slot_normals` of the key the state carries, drawn at
:func:`init_state`), so the transition is a pure function of the state; or they are drawn from a
Generator passed in (one shared, or one per drone: then drone i's draws depend only on its own
Generator, so a batch reproduces single runs bit for bit).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

from iscc_gym.physics.blockage import excess_loss_db_one, shadowing_std_db_one
from iscc_gym.physics.channel import (
    beam_gain_one,
    direction_one,
    link_snr_one,
    rician_gain_one,
    shadowing_db_one,
    shadowing_step_one,
)
from iscc_gym.physics.dynamics import input_one, lqg_command_one, propagate_one
from iscc_gym.physics.fbl import ctrl_bler_one, delivered_one, link_terms_one, rate_one
from iscc_gym.physics.kalman import kf_predict_one, kf_update_whitened_one
from iscc_gym.physics.queue import arrival_bits_one, queue_step_one
from iscc_gym.physics.sensing import crlb_amp_one, echo_amplitude_one, whitened_rows_one
from iscc_gym.scenario import Scenario
from iscc_gym.sim.effects import task_effects
from iscc_gym.sim.mission import MC, mission_columns, mission_rows
from iscc_gym.sim.noise import draw_keys, slot_normals, standard_normals
from iscc_gym.sim.params import MATS, slot_params
from iscc_gym.sim.schema import (
    COL,
    METRIC_NAMES,
    N_DRAWS,
    N_METRICS,
    N_OBS,
    Z_ARRIVAL,
    Z_DROP,
    Z_FADE_COMM,
    Z_FADE_SEN,
    Z_MEAS,
    Z_PROC,
    Z_SHADOW,
    n_draws,
)
from iscc_gym.trajectory import Reference, sample_reference

__all__ = ["LoopState", "N_DRAWS", "init_state", "step", "reference_at", "work_from", "WORK_MATS", "WORK_VEC",
           "standard_normals", "stack_references", "reference_array", "slot_noise", "step_one", "reference_rows",
           "vector_norm", "check_step", "channel_state_one", "init_mission", "blocked_switch", "field_switch",
           "slot_switches",
           "step_batch", "new_outputs", "queue_slot_one", "RowNext", "StepOutputs", "state_row", "next_row"]


class LoopState(NamedTuple):
    r"""State of a batch of B closed loops at the start of slot n (before allocation); an immutable
    named tuple (cheap to build on the env's hot path).

    Attributes
    ----------
    x : (B, 6)
        True drone state [p, v] in m, m/s.
    x_hat : (B, 6)
        Predicted estimate :math:`\hat{\mathbf x}_{n|n-1}`.
    p : (B, 6, 6)
        Predicted error covariance :math:`\mathbf P_{n|n-1}`.
    shadow : (B,)
        Unit-variance shadowing state (shadowing in dB is sigma_SF(h) * shadow).
    n : (B,) int
        Slot index.
    ref : (B, N+1, C)
        The mission's rows (:mod:`iscc_gym.sim.mission`): the reference [position, velocity, acceleration]
        at every slot (C = 9), and with blockage the channel along it (the truth and the GBS's map).
    key : (B,) uint64
        The episode's noise key: slot n's normals are :func:`iscc_gym.sim.noise.slot_normals` (key, n).
    queue : (B, D)
        The data queue's bits by the slots they have waited (:mod:`iscc_gym.physics.queue`); D = 0
        without a queue.
    """

    x: np.ndarray
    x_hat: np.ndarray
    p: np.ndarray
    shadow: np.ndarray
    n: np.ndarray
    ref: np.ndarray
    key: np.ndarray
    queue: np.ndarray

    def rows(self, idx) -> LoopState:
        """The loops ``idx`` of a batch (copies)."""
        return LoopState(*(field[idx] for field in self))

    def with_rows(self, idx, sub: LoopState) -> LoopState:
        """A copy of this batch with loops ``idx`` replaced by ``sub``. The per-slot arrays are
        copied; the (large, constant per episode) reference array is updated in place.
        """
        fields = {}
        for name in ("x", "x_hat", "p", "shadow", "n", "key", "queue"):
            arr = getattr(self, name).copy()
            arr[idx] = getattr(sub, name)
            fields[name] = arr
        self.ref[idx] = sub.ref
        return LoopState(ref=self.ref, **fields)

    @property
    def batch_size(self) -> int | None:
        """B for a batch of loops, None for a single (unbatched) loop."""
        return None if self.x.ndim == 1 else self.x.shape[0]


class RowNext(NamedTuple):
    """Where one loop's slot writes its next state: ``x`` (6,), ``x_hat`` (6,), ``p`` (6, 6) and the queue (D,); arrays
    that must not alias the current state's (a row of :class:`StepOutputs`, :func:`next_row`).
    """

    x: np.ndarray
    x_hat: np.ndarray
    p: np.ndarray
    queue: np.ndarray


class StepOutputs(NamedTuple):
    """The compiled batch step's outputs (:func:`new_outputs`): the next ``x``, ``x_hat``, ``p``, ``shadow``, ``queue``,
    the columns ``out`` (B, columns) and the float32 observation ``obs`` (B, obs_size). The compiled functions take
    them as a plain tuple (a named one costs the dispatcher about a microsecond a call) and name them inside.
    """

    x: np.ndarray
    x_hat: np.ndarray
    p: np.ndarray
    shadow: np.ndarray
    queue: np.ndarray
    out: np.ndarray
    obs: np.ndarray


@njit(cache=True, inline="always")
def state_row(st, i):
    """Row ``i`` of a batch's :class:`LoopState` as an unbatched one (views, and the row's scalars)."""
    return LoopState(st.x[i], st.x_hat[i], st.p[i], st.shadow[i], st.n[i], st.ref[i], st.key[i], st.queue[i])


@njit(cache=True, inline="always")
def next_row(o, i):
    """Row ``i`` of :class:`StepOutputs` (or of any batch with ``x``, ``x_hat``, ``p`` and ``queue``: the device's
    rows) as the :class:`RowNext` a slot writes into.
    """
    return RowNext(o.x[i], o.x_hat[i], o.p[i], o.queue[i])


def slot_noise(state: LoopState, rng: np.random.Generator = None, k: int = N_DRAWS) -> np.ndarray:
    """The slot's ``k`` standard normals, (k,) or (B, k): the episode stream of the state's key at its slot
    (``rng`` None), else drawn from ``rng`` (:func:`standard_normals`). ``k``: :data:`N_DRAWS`, or a scenario's
    :func:`iscc_gym.sim.schema.n_draws` (one more with a queue; the first N_DRAWS are the same either way).
    """
    if rng is None:
        return slot_normals(state.key, state.n, k)
    return standard_normals(rng, state.batch_size, k)


def stack_references(refs: Sequence[Reference]):
    """Stack references into the (B, N+1, 9) array the loop state carries."""
    return np.stack([reference_array(r) for r in refs])


def reference_array(ref: Reference):
    """One reference as the (N+1, 9) array [position, velocity, acceleration] the state carries."""
    return np.concatenate([ref.pos_m, ref.vel_mps, ref.acc_mps2], -1)


def init_state(s: Scenario, refs: ArrayLike, rng: np.random.Generator) -> LoopState:
    r"""Initial state at slot 0: drone near the reference start, estimate at the reference start.

    .. math::
        \mathbf x_0 = \mathbf x_{\mathrm{ref},0} + \mathcal N(\mathbf 0, \mathbf P_0),\quad
        \hat{\mathbf x}_{0|-1} = \mathbf x_{\mathrm{ref},0},\quad
        \mathbf P_0 = \mathrm{blkdiag}(\sigma_{p0}^2\mathbf I_3, \sigma_{v0}^2\mathbf I_3)

    Parameters
    ----------
    refs : Reference or ndarray (N+1, C)
        One mission: an unbatched loop (state arrays without a batch axis; ``rng`` one
        Generator). Or a sequence of B References / an ndarray (B, N+1, C): a batch of B loops
        (``rng`` one Generator or a sequence of B Generators). C = 9 (the reference), or with blockage
        :func:`iscc_gym.sim.mission.mission_columns` (the rows of :func:`iscc_gym.sim.mission.mission_rows`).
    rng : Generator or sequence of Generators
        Per drone: 7 normals (initial state and shadowing), then the episode's noise key
        (:func:`iscc_gym.sim.noise.draw_keys`).
    """
    if isinstance(refs, Reference):
        ref = reference_array(refs)
    elif isinstance(refs, np.ndarray):
        ref = np.asarray(refs, dtype=float)
    else:
        ref = stack_references(refs)
    cols = mission_columns(s)
    if ref.ndim not in (2, 3) or ref.shape[-2] != s.n_slots + 1 or ref.shape[-1] != cols:
        raise ValueError(f"refs must have shape ({s.n_slots + 1}, {cols}) or (B, {s.n_slots + 1}, {cols}), "
                         f"got {ref.shape}" + (" (a mission with blockage: iscc_gym.sim.mission.mission_rows)"
                                               if cols > 9 else ""))
    batch = None if ref.ndim == 2 else ref.shape[0]
    shape = () if batch is None else (batch,)
    z = standard_normals(rng, batch, 7)
    key = draw_keys(rng, batch)
    std0 = initial_std(s)
    rows = ref.reshape(-1, *ref.shape[-2:])
    zs = np.ascontiguousarray(z, dtype=float).reshape(-1, 7)
    x, x_hat, p0, shadow = np.empty((len(rows), 6)), np.empty((len(rows), 6)), np.empty((len(rows), 6, 6)), \
        np.empty(len(rows))
    for b in range(len(rows)):  # the device's reset runs the same row function (iscc_gym.gpu.kernel.reset_row)
        shadow[b] = init_row_one(rows[b, 0], std0, zs[b], x[b], x_hat[b], p0[b])
    return LoopState(x=x.reshape(shape + (6,)), x_hat=x_hat.reshape(shape + (6,)), p=p0.reshape(shape + (6, 6)),
                     shadow=shadow.reshape(shape), n=np.zeros(shape, dtype=np.int64), ref=ref, key=key,
                     queue=np.zeros(shape + (task_effects(s).queue_deadline_slots,)))


def initial_std(s: Scenario) -> np.ndarray:
    r"""The initial state's standard deviations :math:`(\sigma_{p0} \mathbf 1_3, \sigma_{v0} \mathbf 1_3)` (6,)."""
    return np.array([s.initial_pos_std_m] * 3 + [s.initial_vel_std_mps] * 3)


@njit(cache=True, error_model="numpy", inline="always")
def init_row_one(ref0, std0, z, x, x_hat, p):
    r"""One loop's initial state (:func:`init_state`), in place: :math:`\mathbf x_0 = \mathbf x_{\mathrm{ref},0} +
    \boldsymbol\sigma_0 \odot \mathbf z_{0:6}`, :math:`\hat{\mathbf x}_{0|-1} = \mathbf x_{\mathrm{ref},0}`,
    :math:`\mathbf P_0 = \mathrm{diag}(\boldsymbol\sigma_0^2)`; returns the shadowing state :math:`z_6`. The
    one source of the CPU envs' and the device env's initial states (``ref0``: the mission's first row, ``std0``:
    :func:`initial_std`, ``z``: 7 standard normals).
    """
    for a in range(6):
        x[a] = ref0[a] + std0[a] * z[a]
        x_hat[a] = ref0[a]
        for b in range(6):
            p[a, b] = std0[a] * std0[a] if a == b else 0.0
    return z[6]


@njit(cache=True, inline="always")
def slot_draws_one(c):
    """Standard normals a slot draws per loop (:func:`iscc_gym.sim.schema.n_draws` of the compiled slot's record
    ``c``): :data:`iscc_gym.sim.schema.N_DRAWS`, one more (the queue's arrival) with a queue.
    """
    return N_DRAWS + (1 if c.queue == 1.0 else 0)


def blocked_switch(s: Scenario):
    """The compiled slot's ``blocked`` argument for a scenario: None without blockage (the paper's machine code),
    True with (:func:`step_one`).
    """
    return True if task_effects(s).blockage else None


def field_switch(s: Scenario):
    """The compiled slot's ``field`` argument for a scenario: None without the field task's world (the paper's
    machine code), True with (:func:`step_one`).
    """
    return True if task_effects(s).field else None


def slot_switches(s: Scenario) -> tuple:
    """The compiled slot's trailing switch arguments (``blocked``, ``field``) of a scenario, as short as the defaults
    allow: () for the paper (the kernel's defaults, None, compile the paper's slot), (True,) with blockage alone.
    """
    blocked, field = blocked_switch(s), field_switch(s)
    if field is not None:
        return blocked, field
    return () if blocked is None else (blocked,)


def init_mission(s: Scenario, rng: np.random.Generator) -> LoopState:
    """A new mission for one loop, as a batch of one: its reference (:func:`iscc_gym.trajectory.sample_reference`),
    with blockage the channel along it (:func:`iscc_gym.sim.mission.mission_rows`), then :func:`init_state`, all
    drawn from ``rng`` in that order (the paper's missions draw exactly what they drew before).
    """
    ref = mission_rows(s, reference_array(sample_reference(s, rng)), rng)
    return init_state(s, ref[None], [rng])


def reference_rows(ref, n):
    """Rows ``n`` of the reference: ref[n] unbatched, ref[b, n_b] batched."""
    if n.ndim == 0:
        return ref[n]
    return ref[np.arange(n.shape[0]), n]


def reference_at(state: LoopState):
    """The reference row [p, v, a] of each loop's current slot, shape (9,) or (B, 9)."""
    return reference_rows(state.ref, state.n)


def vector_norm(v):
    """Euclidean norm over the last axis of (..., 3) vectors (a stacked product: bit-stable)."""
    return np.sqrt((v[..., None, :] @ v[..., :, None])[..., 0, 0])


def step(s: Scenario, state: LoopState, alpha: ArrayLike, rng: np.random.Generator = None):
    """Advance every loop by one slot.

    Parameters
    ----------
    s : Scenario
    state : LoopState
        One loop (arrays without a batch axis) or a batch of B loops, at slot n < N.
    alpha : array_like, shape (3,) or (B, 3)
        Applied split (alpha_sen, alpha_ctrl, alpha_comm), non-negative, summing to 1.
    rng : Generator, or a sequence of B Generators for a batch, optional
        Draw the slot's normals from it; default: the episode stream of the state's key
        (:func:`slot_noise`).

    Returns
    -------
    state : LoopState
        At slot n + 1.
    metrics : dict of ndarray, shape () or (B,)
        :data:`iscc_gym.sim.schema.METRIC_NAMES`: ``tracking_error_m`` (||p_{n+1} - p_ref,n+1||),
        ``estimation_error_m`` (||p_hat_n - p_n||), ``snr_db`` (the slot's SNR with fading),
        ``snr_large_scale_db``, ``peb_m``, ``veb_mps``, ``eps_ctrl``, ``packet_received`` (bool),
        ``rate_comm_bps``, ``rate_ctrl_bps``, ``diverged`` (bool: tracking error above
        ``max_tracking_error_m`` or non-finite); the data queue's ``bits_arrived``, ``bits_served``,
        ``bits_dropped`` and ``backlog_bits`` (after the slot; all 0 without a queue).

    Notes
    -----
    Evaluated by the compiled slot (:func:`step_batch`: :func:`step_one`, :func:`queue_slot_one`) one drone at a
    time, so drone i of a batch reproduces the unbatched loop bit for bit, and the env's step (which runs the
    same pair) from the same state, split and normals bit for bit. ``tests/oracle_loop.py`` holds the same
    transition in numpy (``step_reference``), the test oracle it is checked against.
    """
    alpha = np.asarray(alpha, dtype=float)
    x = state.x
    batch = None if x.ndim == 1 else x.shape[0]
    check_step(s, state, alpha)
    z = slot_noise(state, rng, n_draws(s))
    nb = 1 if batch is None else batch
    outputs = new_outputs(nb, N_METRICS, 0, task_effects(s).queue_deadline_slots)
    x_n, xh_n, p_n, sh_n, q_n, met, _ = outputs
    switches = slot_switches(s)
    if batch is None:  # a batch of one, squeezed back
        step_batch(*slot_params(s), tuple(f[None] for f in state), alpha[None], z[None], outputs, *switches)
        x_n, xh_n, p_n, sh_n, q_n, met = x_n[0], xh_n[0], p_n[0], sh_n[0], q_n[0], met[0]
    else:
        step_batch(*slot_params(s), tuple(state), alpha, z, outputs, *switches)
    metrics = dict(zip(METRIC_NAMES, met.T, strict=True))
    metrics["packet_received"] = metrics["packet_received"] > 0.5
    metrics["diverged"] = metrics["diverged"] > 0.5
    return state._replace(x=x_n, x_hat=xh_n, p=p_n, shadow=sh_n, n=state.n + 1, queue=q_n), metrics


def check_step(s: Scenario, state: LoopState, alpha: np.ndarray) -> None:
    if alpha.shape != state.x.shape[:-1] + (3,):
        raise ValueError(f"alpha must have shape {state.x.shape[:-1] + (3,)}, got {alpha.shape}")
    if state.n.max() >= s.n_slots:
        raise ValueError("a loop is past the last slot of the mission; reset it first")


# --- the compiled slot: step_reference's equations composed from the physics modules' scalar forms ---
# Evaluated one drone at a time (a slot is ~200 small numpy operations on 6 x 6 matrices; at a batch of
# one numpy's per-call overhead dominates). Only the floating-point evaluation differs from
# step_reference: the Kalman measurement update takes the whitened rows one at a time
# (kalman.kf_update_whitened_one), products use the structure of A = [[I, dt I], [0, I]], and the slot
# may reassociate sums and fuse multiply-adds (fastmath {"reassoc", "contract"}: no assumption about
# NaN or inf). Drone i of a batch goes through the same machine code whatever the batch size, so a
# batch reproduces single runs bit for bit.

_A, _B, _K, _SIGMA_W, _DIAGS = MATS["a"], MATS["b"], MATS["k"], MATS["sigma_w"], MATS["diags"]
_MC_LOS, _MC_SHADOW = MC["los"], MC["shadow_unit"]
(_ERR, _EST, _SNR, _SNR_LS, _PEB, _VEB, _EPS, _RX, _RATE_COMM, _RATE_CTRL, _DIVERGED,
 _ARRIVED, _SERVED, _DROPPED, _BACKLOG, _ECHO) = (COL[name] for name in METRIC_NAMES)
_LN10_OVER_10 = math.log(10.0) / 10.0


@njit(cache=True, error_model="numpy", inline="always")
def blocked_state_one(c, row, h_m, dist_m):
    """With blockage, the slot's shadowing and excess path loss in dB, ``(shadow_db, extra_db)``, at height ``h_m``
    and range ``dist_m``: the mission row's LoS state and unit shadowing field
    (:data:`iscc_gym.sim.mission.CHANNEL_COLUMNS`) times the state's std, and the excess of
    :func:`iscc_gym.physics.blockage.excess_loss_db_one` (the link pays it once, the echo twice).
    """
    los = row[_MC_LOS] == 1.0
    sigma = shadowing_std_db_one(c.blockage, los, h_m, c.sf_a, c.sf_b)
    return sigma * row[_MC_SHADOW], excess_loss_db_one(c.blockage, los, h_m, dist_m, c.carrier_freq_ghz)


@njit(cache=True, error_model="numpy", inline="always")
def channel_state_one(c, row, h_m, dist_m, shadow):
    """``(shadow_db, extra_db)`` of a slot: the paper's AR(1) shadowing state ``shadow`` (extra 0) without blockage,
    else :func:`blocked_state_one`.
    """
    if c.blockage == 0.0:
        return shadowing_db_one(c.sf_a, c.sf_b, h_m, shadow), 0.0
    return blocked_state_one(c, row, h_m, dist_m)


@njit(cache=True, error_model="numpy")
def queue_slot_one(c, q, zi, mt, q_next):
    """The data queue's part of a slot (:mod:`iscc_gym.physics.queue`), run right after :func:`step_one` (which
    writes the slot's data rate into ``mt``): the slot's arrivals (:func:`iscc_gym.physics.queue.arrival_bits_one`
    of the draw ``zi[Z_ARRIVAL]``) join ``q`` and the data share serves ``rate_comm_bps`` x dt bits (none at a NaN
    rate); writes the next buffer into ``q_next`` (``q`` unchanged) and the queue's metrics columns of ``mt`` (0
    without a queue).

    The slot transition is :func:`step_one` then this function: :func:`step_batch` (``loop.step``) and the env's
    kernel (:func:`iscc_gym.sim.kernel.env_step_batch`) both run the pair. It is a function of its own, called
    from those callers without fastmath, so its arithmetic stays as written: called from inside the fastmath
    :func:`step_one` the compiler may fuse its multiply-adds (the urban task's bits would change), and a wrapper
    around the pair costs the paper's kernel 7-14 % (measured: call and reference-count overhead per loop).
    """
    for j in range(q.shape[0]):
        q_next[j] = q[j]
    if c.queue == 1.0:
        arrived = arrival_bits_one(c.arrival_mean_bits, c.arrival_sigma, zi[Z_ARRIVAL])
        capacity = mt[_RATE_COMM] * c.dt_s
        served, dropped = queue_step_one(q_next, arrived, capacity if capacity == capacity else 0.0)
        backlog = 0.0
        for j in range(q_next.shape[0]):
            backlog += q_next[j]
    else:
        arrived = served = dropped = backlog = 0.0
    mt[_ARRIVED], mt[_SERVED], mt[_DROPPED], mt[_BACKLOG] = arrived, served, dropped, backlog


@njit(cache=True, error_model="numpy", fastmath={"reassoc", "contract"})
def step_one(c, mats, now, alpha, zi, nxt, mt, work, blocked=None, field=None):
    """The closed loop's part of one slot of one loop (``tests/oracle_loop.py``'s ``step_reference``; ``c``,
    ``mats``: :func:`iscc_gym.sim.params.slot_params`); the slot transition is this, then the data queue
    (:func:`queue_slot_one`). ``now``: the loop's state, an unbatched :class:`LoopState` (:func:`state_row`);
    ``alpha``: the split ``(a_sen, a_ctrl, a_comm)``. Writes the next state into ``nxt`` (:class:`RowNext`: x, x_hat,
    p) and the metrics row ``mt`` (:data:`iscc_gym.sim.schema.METRIC_NAMES`; a row of the env's columns fits too:
    they start with them); returns the next shadowing state. ``zi``: the slot's normals
    (:func:`iscc_gym.sim.schema.n_draws`); ``work``:
    :func:`work_space`, scratch reused from loop to loop (the slot allocates nothing). ``blocked``: None
    without blockage (the default), True with (a compile-time switch: see the comment in the body). ``field``:
    None without the field task's world (the default), True with: the slot's K-factor (both links) and the drone's
    RCS offset are the mission row's :data:`iscc_gym.sim.mission.WORLD_COLUMNS` instead of the scenario's constants.
    """
    w4, w6, y, x_post, p_post, u, bu, pa, h = work
    xi, x_hat, p, shadow, ni, ref = now.x, now.x_hat, now.p, now.shadow, now.n, now.ref
    a_sen, a_ctrl, a_comm = alpha
    x_next, x_hat_next, p_next = nxt.x, nxt.x_hat, nxt.p
    px, py, pz = xi[0], xi[1], xi[2]
    # channel: geometry, large-scale SNR, fading
    dist, gx, gy, gz, ct, st, cp, sp = direction_one(c.gbs_height_m, px, py, pz)
    # ``blocked`` None (the paper) prunes the other branch when the kernel compiles: the paper's slot is the same
    # machine code as before blockage existed (bit for bit under fastmath, tests/env/test_golden.py)
    if blocked is None:
        shadow_db = shadowing_db_one(c.sf_a, c.sf_b, pz, shadow)
        snr_ls = link_snr_one(c.snr_k, beam_gain_one(c, ct, st, cp, sp), dist, shadow_db)
        shadow_echo = shadow_db
    else:  # the excess loss: once on the link, on both ways of the echo
        shadow_db, extra_db = blocked_state_one(c, ref[ni], pz, dist)
        snr_ls = link_snr_one(c.snr_k, beam_gain_one(c, ct, st, cp, sp), dist, shadow_db + extra_db)
        shadow_echo = shadow_db + 2.0 * extra_db
    if field is None:  # the paper's constants (pruned at compile time, as ``blocked``)
        ric_los, ric_scat = c.ric_los, c.ric_scat
    else:  # the world's K-factor here, and the drone's RCS (a gain on the echo: a negative loss)
        wk = int(c.world_at)
        k_lin = math.exp(_LN10_OVER_10 * ref[ni, wk])
        ric_los, ric_scat = math.sqrt(k_lin / (k_lin + 1.0)), math.sqrt(0.5 / (k_lin + 1.0))
        shadow_echo -= ref[ni, wk + 1]
    snr = rician_gain_one(ric_los, ric_scat, zi[Z_FADE_COMM], zi[Z_FADE_COMM + 1]) * snr_ls
    g_sen = rician_gain_one(ric_los, ric_scat, zi[Z_FADE_SEN], zi[Z_FADE_SEN + 1])
    echo = echo_amplitude_one(c, dist, shadow_echo, g_sen)  # the CRLB's echo power, and the slot's echo_snr_db
    m_r, m_tt, m_tp, m_pp, crlb_vr = crlb_amp_one(c, a_sen, echo, dist, ct, st, cp, sp)
    # measurement, whitened (ISAC or GNSS), and the Kalman measurement update
    if c.gnss == 1.0:
        w = w6
        for j in range(6):
            w[j, j] = mats[_DIAGS, 1, j]
            y[j] = w[j, j] * xi[j] + zi[Z_MEAS + j]
    else:
        w = w4
        whitened_rows_one(gx, gy, gz, ct, st, cp, sp, m_r, m_tt, m_tp, m_pp, crlb_vr, w)
        for j in range(4):
            acc = 0.0
            for k in range(6):
                acc += w[j, k] * xi[k]
            y[j] = acc + zi[Z_MEAS + j]
    m = w.shape[0]
    if c.gnss == 1.0 and ni % int(c.gnss_every) != 0:  # no GNSS fix this slot: prediction only
        m = 0
    kf_update_whitened_one(x_hat, p, y[:m], w[:m], x_post, p_post, h)
    # control command and its FBL delivery
    cap, sqrt_v = link_terms_one(snr)
    eps = ctrl_bler_one(cap, sqrt_v, c.sqrt_l, c.bits_per_hz, a_ctrl)
    rate_ctrl = rate_one(a_ctrl, c.bandwidth_hz, cap, sqrt_v, c.k_ctrl)
    rate_comm = rate_one(a_comm, c.bandwidth_hz, cap, sqrt_v, c.k_comm)
    if c.open_loop == 1.0:  # the reference acceleration stored on board
        received = True
        for j in range(3):
            u[j] = ref[ni, 6 + j]
    else:
        received = delivered_one(eps, zi[Z_DROP])
        lqg_command_one(mats[_K], x_post, ref[ni], c.feedforward == 1.0, u)
        if not received:  # a lost command applies nothing
            for j in range(3):
                u[j] = 0.0
    # drone dynamics, Kalman time update, shadowing
    input_one(mats[_B], u, bu)
    dt = mats[_A, 0, 3]
    propagate_one(dt, xi, bu, mats[_DIAGS, 0], zi, Z_PROC, x_next)
    kf_predict_one(dt, x_post, p_post, bu, mats[_SIGMA_W], x_hat_next, p_next, pa)
    dx, dy, dz = x_next[0] - px, x_next[1] - py, x_next[2] - pz
    if blocked is None:
        shadow_next = shadowing_step_one(c.neg_inv_decorr, shadow, math.sqrt(dx * dx + dy * dy + dz * dz),
                                         zi[Z_SHADOW])
    else:  # the shadowing is a field over the plane (the mission rows); the AR(1) state rests
        shadow_next = shadow
    ex = x_next[0] - ref[ni + 1, 0]
    ey = x_next[1] - ref[ni + 1, 1]
    ez = x_next[2] - ref[ni + 1, 2]
    err = math.sqrt(ex * ex + ey * ey + ez * ez)
    dx, dy, dz = x_post[0] - px, x_post[1] - py, x_post[2] - pz
    mt[_ERR] = err
    mt[_EST] = math.sqrt(dx * dx + dy * dy + dz * dz)
    mt[_SNR] = 10.0 * math.log10(snr)
    mt[_SNR_LS] = 10.0 * math.log10(snr_ls)
    mt[_PEB] = math.sqrt(m_r + m_tt + m_pp)
    mt[_VEB] = math.sqrt(crlb_vr)
    mt[_EPS] = eps
    mt[_RX] = 1.0 if received else 0.0
    mt[_RATE_COMM] = rate_comm
    mt[_RATE_CTRL] = rate_ctrl
    mt[_DIVERGED] = 0.0 if err <= c.max_tracking_error_m else 1.0
    mt[_ECHO] = 10.0 * math.log10(echo / c.sen_noise_w)
    return shadow_next


#: The sizes of a slot's scratch (:func:`work_from`): four 6 x 6 matrices and 27 numbers.
WORK_MATS, WORK_VEC = (4, 6, 6), 27


@njit(cache=True, error_model="numpy", inline="always")
def work_from(mbuf, vbuf):
    """Scratch space of one drone's slot (:func:`step_one`'s ``work``) carved out of buffers the caller owns:
    ``mbuf`` (:data:`WORK_MATS`) and ``vbuf`` (:data:`WORK_VEC`), zeroed here (the observation matrices are only
    partly written). Allocates nothing: the device kernel passes per-thread local arrays.
    """
    for a in range(mbuf.shape[0]):
        for j in range(6):
            for k in range(6):
                mbuf[a, j, k] = 0.0
    for j in range(vbuf.shape[0]):
        vbuf[j] = 0.0
    return (mbuf[0, :4], mbuf[1], vbuf[0:6], vbuf[6:12], mbuf[2], vbuf[12:15], vbuf[15:21], mbuf[3], vbuf[21:27])


@njit(cache=True, error_model="numpy")
def work_space():
    """Scratch space of one drone's slot: :func:`work_from` of new buffers (the CPU batch's one allocation)."""
    return work_from(np.empty(WORK_MATS), np.empty(WORK_VEC))


@njit(cache=True, error_model="numpy")
def step_batch(cp, mats, state, alpha, z, outputs, blocked=None, field=None):
    """The slot transition (:func:`step_one`, then :func:`queue_slot_one`) over a batch (``state``: a
    :class:`LoopState`'s fields as a plain tuple; ``alpha`` (B, 3); ``z`` the slot's normals (B, draws)), written into
    ``outputs`` (:class:`StepOutputs`' fields as a plain tuple, ``out`` the metrics (B, N_METRICS), ``obs`` unused);
    outputs are passed in because returning fresh arrays from compiled code costs more than the slot itself at small
    batches. ``cp``: the parameter record array (1,).
    """
    c = cp[0]
    st, o = LoopState(*state), StepOutputs(*outputs)
    work = work_space()
    for i in range(st.x.shape[0]):
        o.shadow[i] = step_one(c, mats, state_row(st, i), (alpha[i, 0], alpha[i, 1], alpha[i, 2]), z[i],
                               next_row(o, i), o.out[i], work, blocked, field)
        queue_slot_one(c, st.queue[i], z[i], o.out[i], o.queue[i])


def new_outputs(nb: int, columns: int, n_obs: int = N_OBS, queue_deadline_slots: int = 0):
    """Fresh output arrays for the compiled batch functions: next x, x_hat, p, shadow, the queue's buffer
    (nb, queue_deadline_slots), the columns array, and the float32 observation (nb, n_obs).
    """
    return (np.empty((nb, 6)), np.empty((nb, 6)), np.empty((nb, 6, 6)), np.empty(nb),
            np.empty((nb, queue_deadline_slots)), np.empty((nb, columns)), np.empty((nb, n_obs), np.float32))
