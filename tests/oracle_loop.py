"""Test oracle of the closed loop and the env step in numpy: the transition (``step_reference``), the
observation (``observe_reference``) and the env step (``env_step_reference``), written with the numpy
physics functions (``channel``, ``fbl``, ``sensing``, ``kalman``) independently of the compiled slot
(:func:`iscc_gym.sim.loop.step_one`, :mod:`iscc_gym.sim.kernel`), which ``tests/physics/test_kernel.py`` checks
against them (issue 14: the library computes each equation once, the numpy path lives here).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from oracle_env import action_to_split, reward_and_costs
from oracle_kalman import kf_predict, kf_update
from oracle_sensing import crlb_local, whitened_observation_matrix

from iscc_gym.physics.channel import (
    beam_gain,
    direction_trig,
    link_snr,
    rician_constants,
    shadowing_std_db,
)
from iscc_gym.physics.dynamics import model_matrices
from iscc_gym.physics.fbl import min_shares, q_func, slot_link
from iscc_gym.physics.queue import arrival_sigma, queue_step
from iscc_gym.physics.sensing import echo_amplitude_sq, sensing_noise_var_w
from iscc_gym.physics.stability import scenario_eps_star
from iscc_gym.scenario import Scenario
from iscc_gym.sim import loop
from iscc_gym.sim.loop import LoopState, check_step, reference_rows, slot_noise, vector_norm
from iscc_gym.sim.schema import (
    COL,
    CTRL_SHARE_SCALE,
    ERR_SCALE,
    METRIC_NAMES,
    OBS_BOUND,
    OBS_NAMES,
    PEB_SCALE,
    REF_ACC_SCALE,
    REF_VEL_SCALE,
    SNR_SCALE,
    Z_ARRIVAL,
    Z_DROP,
    Z_FADE_COMM,
    Z_FADE_SEN,
    Z_MEAS,
    Z_PROC,
    Z_SHADOW,
    n_draws,
)

_MEAS, _DROP, _PROC, _SHAD = slice(Z_MEAS, Z_MEAS + 6), Z_DROP, slice(Z_PROC, Z_PROC + 6), Z_SHADOW


def step_reference(s: Scenario, state: LoopState, alpha, rng=None, z=None):
    """Advance every loop by one slot, in numpy: the readable definition of the transition.

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
    z : ndarray (n_draws(s),) or (B, n_draws(s)), optional
        The slot's standard normals, drawn already (then ``rng`` is not used).

    Returns
    -------
    state : LoopState
        At slot n + 1.
    metrics : dict of ndarray, shape () or (B,)
        ``tracking_error_m`` (||p_{n+1} - p_ref,n+1||), ``estimation_error_m`` (||p_hat_n - p_n||),
        ``snr_db`` (the slot's SNR with fading), ``snr_large_scale_db``, ``peb_m``, ``veb_mps``,
        ``eps_ctrl``, ``packet_received`` (bool), ``rate_comm_bps``, ``rate_ctrl_bps``,
        ``diverged`` (bool: tracking error above ``max_tracking_error_m`` or non-finite).

    Notes
    -----
    Every elementwise operation is the same for a batch and a single loop and every matrix
    product is a stacked product, so drone i of a batch reproduces the unbatched loop bit for bit
    (with its own key's stream, or stepped with Generator i against that Generator).
    """
    mm = model_matrices(s)
    alpha = np.asarray(alpha, dtype=float)
    x = state.x
    check_step(s, state, alpha)
    n = state.n
    if z is None:
        z = slot_noise(state, rng, n_draws(s))
    ref_n = reference_rows(state.ref, n)
    pos = x[..., :3]
    a_sen, a_ctrl, a_comm = alpha[..., 0], alpha[..., 1], alpha[..., 2]

    # --- channel: geometry, large-scale SNR (path loss, beam gain, shadowing), this slot's fading
    rel = pos - mm.gbs_pos
    dist = vector_norm(rel)
    los = rel / dist[..., None]
    trig = direction_trig(los)
    shadow_db = shadowing_std_db(s, pos[..., 2]) * state.shadow
    snr_ls = link_snr(s, dist, shadow_db, beam_gain(s, trig))
    snr = rician_power_gain(s, z[..., Z_FADE_COMM], z[..., Z_FADE_COMM + 1]) * snr_ls

    # --- sensing (CRLB in the local range/azimuth/elevation frame) and Kalman measurement update
    g_sen = rician_power_gain(s, z[..., Z_FADE_SEN], z[..., Z_FADE_SEN + 1])
    m_r, m_tt, m_tp, m_pp, crlb_vr = crlb_local(s, a_sen, dist, trig, shadow_db, g_sen)
    if s.observation_source == "isac":
        # eq:observation_model, whitened: W y = W C x + z with W C from the CRLBs, z ~ N(0, I4)
        c = whitened_observation_matrix(los, trig, m_r, m_tt, m_tp, m_pp, crlb_vr)
        y = (c @ x[..., None])[..., 0] + z[..., Z_MEAS:Z_MEAS + 4]
    else:  # GNSS: position and velocity with independent Gaussian errors, whitened likewise
        c = mm.gnss_whiten
        y = (c @ x[..., None])[..., 0] + z[..., _MEAS]
    x_post, p_post, _ = kf_update(state.x_hat, state.p, y, c, None)
    if s.observation_source == "gnss" and s.gnss_update_slots > 1:  # a fix every k-th slot only
        fix = (n % s.gnss_update_slots) == 0
        x_post = np.where(fix[..., None], x_post, state.x_hat)
        p_post = np.where(fix[..., None, None], p_post, state.p)

    # --- control command and its finite-blocklength delivery
    eps, rate_ctrl, rate_comm = slot_link(s, a_ctrl, a_comm, snr)
    if s.control_mode == "lqg":
        u_cmd = -(mm.k @ (x_post - ref_n[..., :6])[..., None])[..., 0]
        if s.reference_feedforward:
            u_cmd = u_cmd + ref_n[..., 6:]
        received = (eps < 1.0) & (q_func(-z[..., _DROP]) >= eps)  # Phi(z) >= eps: P = 1 - eps
        u_applied = np.where(np.asarray(received)[..., None], u_cmd, 0.0)  # a lost command applies nothing
    else:  # open loop: the reference acceleration is stored on board, no link involved
        received = np.ones(x.shape[:-1], dtype=bool)
        u_applied = ref_n[..., 6:]

    # --- drone dynamics and Kalman time update
    bu = (mm.b @ u_applied[..., None])[..., 0]
    x_next = (mm.a @ x[..., None])[..., 0] + bu + mm.chol_w * z[..., _PROC]
    x_hat_next, p_next = kf_predict(x_post, p_post, mm.a, bu, mm.sigma_w)
    shadow_next = shadowing_step(s, state.shadow, vector_norm(x_next[..., :3] - pos), z[..., _SHAD])

    n_next = n + 1
    err = vector_norm(x_next[..., :3] - reference_rows(state.ref, n_next)[..., :3])
    metrics = {
        "tracking_error_m": err,
        "estimation_error_m": vector_norm(x_post[..., :3] - pos),
        "snr_db": 10.0 * np.log10(snr),
        "snr_large_scale_db": 10.0 * np.log10(snr_ls),
        "peb_m": np.sqrt(m_r + m_tt + m_pp),
        "veb_mps": np.sqrt(crlb_vr),
        "eps_ctrl": eps,
        "packet_received": received,
        "rate_comm_bps": rate_comm,
        "rate_ctrl_bps": rate_ctrl,
        "diverged": ~(err <= s.max_tracking_error_m),  # also catches NaN
    }
    # --- the data queue: the slot's arrivals, served by the data share (physics.queue)
    q_next = state.queue
    zero = np.zeros(x.shape[:-1])
    arrived = served = dropped = backlog = zero
    if s.queue_deadline_slots > 0:
        sigma = arrival_sigma(s.queue_arrival_cv)
        arrived = s.queue_arrival_bps * s.dt_s * np.exp(sigma * z[..., Z_ARRIVAL] - 0.5 * sigma * sigma)
        capacity = np.where(np.isnan(rate_comm), 0.0, rate_comm * s.dt_s)
        q_next, served, dropped = queue_step(state.queue.reshape(-1, s.queue_deadline_slots), arrived, capacity)
        q_next, served, dropped = q_next.reshape(state.queue.shape), served.reshape(zero.shape), \
            dropped.reshape(zero.shape)
        backlog = q_next.sum(axis=-1)
    metrics.update(bits_arrived=arrived, bits_served=served, bits_dropped=dropped, backlog_bits=backlog,
                   echo_snr_db=10.0 * np.log10(echo_amplitude_sq(s, dist, shadow_db, g_sen) / sensing_noise_var_w(s)))
    new_state = state._replace(x=x_next, x_hat=x_hat_next, p=p_next, shadow=shadow_next, n=n_next, queue=q_next)
    return new_state, metrics


def _symlog(x, scale):
    return np.sign(x) * np.log1p(np.abs(x) * (1.0 / scale))


#: Per-entry scale of the linear part of the observation (entries 6-11: reference motion).
_REF_SCALE = np.array([REF_VEL_SCALE] * 3 + [REF_ACC_SCALE] * 3)


def observe_reference(s: Scenario, state: loop.LoopState, last_received, last_peb_m):
    """:func:`observe` in numpy (one loop or a batch): the readable definition of the observation."""
    return _observe_and_check(s, state, last_received, last_peb_m)[0]


def _observe_and_check(s: Scenario, state: loop.LoopState, last_received, last_peb_m):
    """``(obs, evaluable)``: :func:`observe_reference`, and where the observation could be evaluated
    (no NaN entry, a finite estimate); where not, the episode ends (:func:`reward_and_costs`)."""
    pv = preview(s, state, scenario_eps_star(s))
    ref = loop.reference_at(state)
    cos_az, sin_az, _, sin_el = pv["trig"]
    p = state.p
    obs = np.empty(state.x.shape[:-1] + (len(OBS_NAMES),))
    obs[..., 0:6] = _symlog(state.x_hat - ref[..., :6], ERR_SCALE)
    obs[..., 6:12] = ref[..., 3:9] * _REF_SCALE
    obs[..., 12] = _symlog(np.sqrt(p[..., 0, 0] + p[..., 1, 1] + p[..., 2, 2]), ERR_SCALE)
    obs[..., 13] = pv["snr_db"] * SNR_SCALE
    obs[..., 14] = pv["dist_m"] * (1.0 / s.coverage_radius_m)
    obs[..., 15] = sin_el
    obs[..., 16] = cos_az
    obs[..., 17] = sin_az
    obs[..., 18] = CTRL_SHARE_SCALE * pv["alpha_ctrl_min"]
    obs[..., 19] = pv["alpha_comm_min"]
    obs[..., 20] = last_received
    obs[..., 21] = _symlog(last_peb_m, PEB_SCALE)
    obs[..., 22] = 1.0 - state.n * (1.0 / s.n_slots)
    # every entry is finite in the region the model describes (floors in min_shares, prior in the
    # CRLB); far outside it (an estimate below ground, a diverged filter) an entry can be NaN: it reads
    # 0 and the episode ends (loss of track). The clip keeps divergent states inside the box.
    nan = np.isnan(obs)
    evaluable = ~nan.any(axis=-1) & np.isfinite(state.shadow) & np.isfinite(state.x_hat).all(axis=-1) \
        & np.isfinite(p).all(axis=(-2, -1))
    if nan.any():
        obs = np.where(nan, 0.0, obs)
    return np.minimum(np.maximum(obs, -OBS_BOUND), OBS_BOUND).astype(np.float32), evaluable


def env_step_reference(s: Scenario, state: loop.LoopState, actions, z):
    """:func:`env_step` in numpy from pre-drawn normals ``z`` (B, N_DRAWS): the readable definition."""
    alpha = action_to_split(actions)
    new, m = step_reference(s, state, alpha, None, z=z)
    cols = [np.asarray(m[k], dtype=float) for k in METRIC_NAMES]
    obs, evaluable = _observe_and_check(s, new, cols[COL["packet_received"]], cols[COL["peb_m"]])
    costs = reward_and_costs(s, m, new.n, evaluable)
    cols += [alpha[:, 0], alpha[:, 1], alpha[:, 2]] + [np.asarray(v, dtype=float) for v in costs]
    out = np.stack(cols, axis=-1)
    return new, out, obs


def preview(s: Scenario, state: LoopState, eps_max: float) -> dict:
    """What the GBS can predict about slot n before allocating it, from its estimate x_hat_{n|n-1}.

    Returns a dict: ``dist_m`` and ``trig`` (range and (cos, sin) of azimuth and elevation of the
    predicted position, see :func:`iscc_gym.physics.channel.direction_trig`), ``snr_db`` (large-scale SNR
    there: path loss, beam gain and the current shadowing; the slot's small-scale fading is not
    known yet), ``alpha_ctrl_min`` (control share at which eq:ctrl_bler gives ``eps_max`` at that
    SNR) and ``alpha_comm_min`` (data share carrying ``rate_min_bps``), see
    :func:`iscc_gym.physics.fbl.min_shares`.
    """
    pos = state.x_hat[..., :3]
    rel = pos - model_matrices(s).gbs_pos
    dist = vector_norm(rel)
    los = rel / dist[..., None]
    trig = direction_trig(los)
    snr = link_snr(s, dist, shadowing_std_db(s, pos[..., 2]) * state.shadow, beam_gain(s, trig))
    ctrl_min, comm_min = min_shares(s, snr, eps_max, s.rate_min_bps)
    return {"dist_m": dist, "trig": trig, "snr_db": 10.0 * np.log10(snr),
            "alpha_ctrl_min": ctrl_min, "alpha_comm_min": comm_min}


def shadowing_step(s: Scenario, shadow_norm: ArrayLike, moved_m: ArrayLike, z: ArrayLike):
    r"""Advance the unit-variance shadowing process by a travelled distance (Gudmundson AR(1)).

    .. math:: s_{n+1} = \rho s_n + \sqrt{1-\rho^2}\, z_n,\quad \rho = e^{-d_n / d_\mathrm{corr}}

    The shadowing in dB is :math:`\varepsilon_n = \sigma_\mathrm{SF}(h_n)\, s_n`
    (:func:`shadowing_std_db`). The paper gives :math:`\varepsilon\sim\mathcal N(0,\sigma_{SF}^2)`
    but not its correlation; see ``docs/model.md``.

    Parameters
    ----------
    shadow_norm : ndarray, shape (...)
        Current unit-variance shadowing state.
    moved_m : ndarray, shape (...)
        Distance travelled since the last slot in m.
    z : ndarray, shape (...)
        Standard normal innovation.
    """
    rho = np.exp(moved_m * (-1.0 / s.shadowing_decorrelation_m))
    return rho * shadow_norm + np.sqrt(1.0 - rho * rho) * z


def rician_power_gain(s: Scenario, z_re: ArrayLike, z_im: ArrayLike):
    r"""Small-scale power gain :math:`|g|^2` of a unit-mean-power Rician coefficient.

    .. math::
        g = \sqrt{\tfrac{K}{K+1}} + \sqrt{\tfrac{1}{2(K+1)}}\,(z_\mathrm{re} + j z_\mathrm{im}),
        \quad \mathbb{E}|g|^2 = 1

    i.e. :math:`g \sim \mathcal{CN}(\mu, \sigma^2)` with :math:`|\mu|^2/\sigma^2 = K`
    (``rician_k_db``), the paper's :math:`g_{C,m,k}` and :math:`g_{S,m,k}`, one draw per slot.
    ``z_re`` and ``z_im`` are standard normal draws.
    """
    los, scat = rician_constants(s)
    re = los + scat * z_re
    im = scat * z_im
    return re * re + im * im
