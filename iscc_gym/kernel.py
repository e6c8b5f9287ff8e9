"""Compiled slot kernel: :func:`iscc_gym.loop.step_reference` and :func:`iscc_gym.loop.observe_reference`
fused into one loop over the batch (numba).

Why it exists: one slot is ~200 small numpy operations on 6 x 6 matrices; at a batch of one, numpy's
per-call overhead (about 1 us each) dominates and the env ran ~20x slower than Pendulum-v1. The
kernel evaluates the same equations one drone at a time, so

* it is a faster evaluation of the documented model, not a second model: every formula here cites the
  numpy function it mirrors, and ``tests/test_kernel.py`` checks the kernel against the numpy
  reference (to ~1e-9 relative) on random states and whole episodes. Only the floating-point
  evaluation differs: the Kalman measurement update takes the whitened rows one at a time
  (:func:`_kf_update`, the same posterior as the batch Joseph form), products use the structure of
  A = [[I, dt I], [0, I]], and the slot and update functions may reassociate sums and fuse
  multiply-adds (``fastmath={"reassoc", "contract"}``: no assumption about NaN or inf);
* each slot draws its own normals from the loop's episode key (:mod:`iscc_gym.noise`), on whichever
  core steps the loop;
* drone i of a batch goes through the same machine code whatever the batch size, so a batch
  reproduces single runs bit for bit (the vector env relies on it).

The numpy modules stay the readable definition of the model; ``docs/model.md`` maps equations to
them. Scenario options the kernel does not cover (``beamforming="broadside"``) fall back to numpy.

Every per-scenario constant is computed once in Python by the same helper functions the numpy path
uses (:func:`kernel_constants`), then passed as one float vector.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .channel import _rician_constants, _snr_constant, matched_gain
from .dynamics import model_matrices
from .fbl import _link_constants, q_inv
from .noise import fill_slot_normals
from .scenario import SPEED_OF_LIGHT_MPS, Scenario, per_scenario
from .schema import ENV_COLUMNS, METRIC_NAMES, N_DRAWS, N_STEP_COLUMNS
from .sensing import _echo_constant, _fim_constants, _index_moments
from .stability import scenario_eps_star

__all__ = ["supported", "kernel_constants", "step_batch", "env_step_batch", "observe_batch", "METRIC_NAMES",
           "ENV_COLUMNS"]


# indices into the constants vector
(_H, _SF_A, _SF_B, _NEG_INV_DECORR, _RIC_LOS, _RIC_SCAT, _SNR_K, _BEAM_G, _ECHO_K, _M_OVER_SIG2,
 _C_TAU, _C_NU, _N_SUB, _ETA_SQ, _SXX, _SYY, _PRIOR, _TWO_OVER_C_SQ, _LAM_HALF_SQ, _K_COMM, _K_CTRL,
 _BITS_PER_HZ, _SQRT_L, _BW, _MAX_ERR, _RATE_MIN, _COVERAGE_R, _N_SLOTS, _ORIENT, _FIM_PRINTED,
 _GNSS, _OPEN_LOOP, _FEEDFORWARD, _EPS_STAR, _Q_BACK, _W_RATE, _W_STAB, _GNSS_EVERY) = range(38)
_N_CONST = 38
# slices of the packed matrices (5, 6, 6): A, B (6 x 3), K (3 x 6), Sigma_w, [chol_w; gnss whitening]
_A, _B, _K, _SIGMA_W, _DIAGS = range(5)
_ORIENTATIONS = {"horizontal": 0.0, "printed": 1.0, "vertical": 2.0}
_LN10_OVER_10 = math.log(10.0) / 10.0


def supported(s: Scenario) -> bool:
    """Whether the kernel covers this scenario (the matched beamformer; broadside uses numpy)."""
    return s.beamforming == "matched"


@per_scenario
def kernel_constants(s: Scenario):
    """``(c, mats)``: the constants vector and the packed matrices of one scenario, from the same
    helpers as the numpy path (read-only, cached)."""
    mm = model_matrices(s)
    eps_star = scenario_eps_star(s)
    c = np.zeros(_N_CONST)
    los, scat = _rician_constants(s)
    m_over_sig2, c_tau, c_nu = _fim_constants(s)
    sxx, syy, eta_sq = _index_moments(s)
    k_comm, k_ctrl, bits_per_hz, sqrt_l = _link_constants(s)
    c[_H] = s.gbs_height_m
    c[_SF_A], c[_SF_B] = s.shadowing_a_db, s.shadowing_b_per_m
    c[_NEG_INV_DECORR] = -1.0 / s.shadowing_decorrelation_m
    c[_RIC_LOS], c[_RIC_SCAT] = los, scat
    c[_SNR_K], c[_BEAM_G] = _snr_constant(s), matched_gain(s)
    c[_ECHO_K], c[_M_OVER_SIG2], c[_C_TAU], c[_C_NU] = _echo_constant(s), m_over_sig2, c_tau, c_nu
    c[_N_SUB], c[_ETA_SQ], c[_SXX], c[_SYY] = s.n_subcarriers, eta_sq, sxx, syy
    c[_PRIOR] = 1.0 / s.sensing_prior_var_m2
    c[_TWO_OVER_C_SQ] = (2.0 / SPEED_OF_LIGHT_MPS) ** 2
    c[_LAM_HALF_SQ] = (0.5 * s.wavelength_m) ** 2
    c[_K_COMM], c[_K_CTRL], c[_BITS_PER_HZ], c[_SQRT_L] = k_comm, k_ctrl, bits_per_hz, sqrt_l
    c[_BW], c[_MAX_ERR], c[_RATE_MIN] = s.bandwidth_hz, s.max_tracking_error_m, s.rate_min_bps
    c[_COVERAGE_R], c[_N_SLOTS] = s.coverage_radius_m, s.n_slots
    c[_ORIENT] = _ORIENTATIONS[s.array_orientation]
    c[_FIM_PRINTED] = float(s.fim_angle_convention == "printed")
    c[_GNSS] = float(s.observation_source == "gnss")
    c[_OPEN_LOOP] = float(s.control_mode == "open_loop")
    c[_FEEDFORWARD] = float(s.reference_feedforward)
    c[_EPS_STAR] = eps_star
    c[_Q_BACK] = float(q_inv(eps_star)) / sqrt_l  # control-share bound of the observation (min_shares)
    c[_W_RATE], c[_W_STAB] = s.w_rate, s.w_stab
    c[_GNSS_EVERY] = s.gnss_update_slots
    mats = np.zeros((5, 6, 6))
    mats[_A], mats[_B, :, :3], mats[_K, :3, :], mats[_SIGMA_W] = mm.a, mm.b, mm.k, mm.sigma_w
    mats[_DIAGS, 0], mats[_DIAGS, 1] = mm.chol_w, np.diag(mm.gnss_whiten)
    c.setflags(write=False)
    mats.setflags(write=False)
    return c, mats


# --- scalar building blocks (each mirrors a numpy function named in its docstring) ----------------

@njit(cache=True, error_model="numpy", inline="always")
def _direction(c, px, py, pz):
    """channel.direction_trig of the LoS vector from the GBS antenna: (dist, g, trig)."""
    rx, ry, rz = px, py, pz - c[_H]
    dist = math.sqrt(rx * rx + ry * ry + rz * rz)
    gx, gy, gz = rx / dist, ry / dist, rz / dist
    cp = math.sqrt(gx * gx + gy * gy)
    zenith = 1.0 if cp < 1e-12 else 0.0
    inv = 1.0 / max(cp, 1e-12)
    return dist, gx, gy, gz, gx * inv + zenith, gy * inv, cp, gz


@njit(cache=True, error_model="numpy", inline="always")
def _large_scale_snr(c, dist, shadow_db):
    """channel.link_snr with the matched beam gain."""
    # = K G l^-2.2 10^(-eps/10), as one exp of a log (pow twice costs more than the rest of the budget)
    return c[_SNR_K] * c[_BEAM_G] * math.exp(-2.2 * math.log(dist) - _LN10_OVER_10 * shadow_db)


@njit(cache=True, error_model="numpy", inline="always")
def _link_terms(snr):
    """fbl.link_terms: log2(1 + snr) and sqrt(V(snr))."""
    g1 = 1.0 + snr
    return math.log2(g1), 1.4426950408889634 * math.sqrt(snr * (2.0 + snr)) / g1


@njit(cache=True, error_model="numpy", inline="always")
def _symlog(x, scale):
    """env._symlog."""
    s = 1.0 if x > 0 else (-1.0 if x < 0 else 0.0)
    return s * math.log1p(abs(x) * (1.0 / scale))


@njit(cache=True, error_model="numpy")
def _observe_one(c, x_hat, p, shadow, n, ref, last_received, last_peb, out):
    """env.observe_reference for one drone (loop.preview + the observation table); returns False where
    an entry could not be evaluated (NaN, written as 0) or the estimate is not finite (env.lost_track)."""
    dist, gx, gy, gz, ct, st, cp, sp = _direction(c, x_hat[0], x_hat[1], x_hat[2])
    shadow_db = c[_SF_A] * math.exp(-c[_SF_B] * x_hat[2]) * shadow
    snr = _large_scale_snr(c, dist, shadow_db)
    cap, sqrt_v = _link_terms(snr)
    bits = c[_BITS_PER_HZ]
    ctrl_min = bits / max(cap - c[_Q_BACK] * sqrt_v, 1e-12 * bits)
    comm_min = (c[_RATE_MIN] / c[_BW]) / max(cap - c[_K_COMM] * sqrt_v, 1e-12)
    for j in range(6):
        out[j] = _symlog(x_hat[j] - ref[n, j], 0.1)
    for j in range(6):
        out[6 + j] = ref[n, 3 + j] * (0.1 if j < 3 else 1.0)
    out[12] = _symlog(math.sqrt(p[0, 0] + p[1, 1] + p[2, 2]), 0.1)
    out[13] = 10.0 * math.log10(snr) * 0.1
    out[14] = dist * (1.0 / c[_COVERAGE_R])
    out[15] = sp
    out[16] = ct
    out[17] = st
    out[18] = 10.0 * ctrl_min
    out[19] = comm_min
    out[20] = last_received
    out[21] = _symlog(last_peb, 0.05)
    out[22] = 1.0 - n * (1.0 / c[_N_SLOTS])
    ok = math.isfinite(shadow)
    for j in range(6):
        ok = ok and math.isfinite(x_hat[j])
        for k in range(6):
            ok = ok and math.isfinite(p[j, k])
    for j in range(23):
        v = out[j]
        if v != v:  # NaN: the model cannot evaluate this entry (a state far outside the region)
            v = 0.0
            ok = False
        out[j] = min(max(v, -10.0), 10.0)
    return ok


@njit(cache=True, error_model="numpy")
def observe_batch(c, x_hat, p, shadow, n, ref, last_received, last_peb, obs):
    """The observation of a batch (env.observe_reference), written into ``obs`` (B, 23) float32."""
    for i in range(x_hat.shape[0]):
        _observe_one(c, x_hat[i], p[i], shadow[i], n[i], ref[i], last_received[i], last_peb[i], obs[i])


@njit(cache=True, error_model="numpy")
def _crlb_local(c, a_sen, dist, ct, st, cp, sp, shadow_db, fading):
    """sensing.crlb_local with the matched beamformer (sensing.matched_signature_terms,
    sensing.fim_terms, sensing.echo_amplitude_sq)."""
    orient = c[_ORIENT]
    if orient == 0.0:  # channel.direction_cosines_trig, horizontal
        tx, ty, qx, qy = -cp * st, cp * ct, -sp * ct, -sp * st
    elif orient == 1.0:  # printed
        tx, ty, qx, qy = ct * cp, ct * sp, -st * sp, st * cp
    else:  # vertical
        tx, ty, qx, qy = cp * ct, 0.0, -sp * st, cp
    sxx, syy = c[_SXX], c[_SYY]
    d_tt = sxx * (tx * tx) + syy * (ty * ty)
    d_pp = sxx * (qx * qx) + syy * (qy * qy)
    d_tp = sxx * (tx * qx) + syy * (ty * qy)
    amp = c[_ECHO_K] * math.exp(-4.4 * math.log(dist) - _LN10_OVER_10 * shadow_db) * fading
    k_sen = a_sen * c[_N_SUB]
    base = amp * c[_M_OVER_SIG2] * k_sen
    common = base * c[_ETA_SQ]
    j_tau = common * c[_C_TAU] * (k_sen * k_sen)
    j_nu = common * c[_C_NU]
    ang = 0.5 * common if c[_FIM_PRINTED] == 1.0 else 2.0 * base
    j_tt, j_pp, j_tp = ang * d_tt, ang * d_pp, ang * d_tp
    prior = c[_PRIOR]
    inv_l = 1.0 / dist
    inv_lc = inv_l / max(cp, 1e-9)
    a = j_tt * inv_lc * inv_lc + prior
    b = j_tp * inv_lc * inv_l
    d = j_pp * inv_l * inv_l + prior
    inv_det = 1.0 / (a * d - b * b)
    m_r = 1.0 / (j_tau * c[_TWO_OVER_C_SQ] + prior)
    lam = c[_LAM_HALF_SQ]
    crlb_vr = lam / (j_nu + lam * prior)
    return m_r, d * inv_det, -b * inv_det, a * inv_det, crlb_vr


@njit(cache=True, error_model="numpy", fastmath={"reassoc", "contract"})
def _kf_update(x, p, y, w, x_post, p_post, h):
    r"""kalman.kf_update with a whitened measurement (unit noise), one row at a time.

    The rows of a whitened measurement have independent unit noise, so processing them one by one
    gives the same posterior as the batch update (Bierman, *Factorization Methods for Discrete
    Sequential Estimation*, 1977, ch. II). Row w with h = P w^T and s = w h + 1:

    .. math::
        \hat{\mathbf x} \leftarrow \hat{\mathbf x} + \mathbf h\,(y - \mathbf w\hat{\mathbf x})/s,\quad
        \mathbf P \leftarrow \mathbf P - \mathbf h\mathbf h^T/s

    (the Joseph form of a scalar update reduces to this), symmetric by construction; no rows: the
    prior is copied (a slot without a measurement). About a third
    of the batch update's arithmetic and no matrix inverse; it agrees with the numpy reference's
    batch Joseph form to rounding (``tests/test_kernel.py``).
    """
    for i in range(6):
        x_post[i] = x[i]
        for j in range(6):
            p_post[i, j] = p[i, j]
    for r in range(w.shape[0]):
        s = 1.0
        innov = y[r]
        for i in range(6):
            acc = 0.0
            for k in range(6):
                acc += p_post[i, k] * w[r, k]
            h[i] = acc
            s += w[r, i] * acc
            innov -= w[r, i] * x_post[i]
        inv_s = 1.0 / s
        gain = innov * inv_s
        for i in range(6):
            x_post[i] += h[i] * gain
            hi = h[i] * inv_s
            for j in range(i, 6):
                v = p_post[i, j] - hi * h[j]
                p_post[i, j] = v
                p_post[j, i] = v


@njit(cache=True, error_model="numpy", fastmath={"reassoc", "contract"})
def _step_one(c, mats, xi, x_hat, p, shadow, ni, ref, a_sen, a_ctrl, a_comm, zi,
              x_next, x_hat_next, p_next, mt, work):
    """loop.step_reference for one drone; writes the next state and the metrics row ``mt``
    (columns :data:`METRIC_NAMES`); returns the next shadowing state."""
    w4, w6, y, x_post, p_post, u, bu, pa, h = work
    px, py, pz = xi[0], xi[1], xi[2]
    # channel (loop.step_reference: geometry, large-scale SNR, fading)
    dist, gx, gy, gz, ct, st, cp, sp = _direction(c, px, py, pz)
    shadow_db = c[_SF_A] * math.exp(-c[_SF_B] * pz) * shadow
    snr_ls = _large_scale_snr(c, dist, shadow_db)
    re = c[_RIC_LOS] + c[_RIC_SCAT] * zi[0]
    im = c[_RIC_SCAT] * zi[1]
    snr = (re * re + im * im) * snr_ls
    re = c[_RIC_LOS] + c[_RIC_SCAT] * zi[2]
    im = c[_RIC_SCAT] * zi[3]
    m_r, m_tt, m_tp, m_pp, crlb_vr = _crlb_local(c, a_sen, dist, ct, st, cp, sp, shadow_db,
                                                 re * re + im * im)
    # measurement, whitened (sensing.whitened_observation_matrix, or GNSS)
    if c[_GNSS] == 1.0:
        w = w6
        for j in range(6):
            w[j, j] = mats[_DIAGS, 1, j]
            y[j] = w[j, j] * xi[j] + zi[4 + j]
    else:
        w = w4
        l11 = math.sqrt(m_tt)
        l21 = m_tp / l11
        inv_l22 = 1.0 / math.sqrt(m_pp - l21 * l21)
        kk = l21 / l11
        inv_sr = 1.0 / math.sqrt(m_r)
        inv_sv = 1.0 / math.sqrt(crlb_vr)
        w[0, 0], w[0, 1], w[0, 2] = gx * inv_sr, gy * inv_sr, gz * inv_sr
        w[1, 0], w[1, 1] = -st / l11, ct / l11
        w[2, 0] = (-sp * ct + kk * st) * inv_l22
        w[2, 1] = (-sp * st - kk * ct) * inv_l22
        w[2, 2] = cp * inv_l22
        w[3, 3], w[3, 4], w[3, 5] = gx * inv_sv, gy * inv_sv, gz * inv_sv
        for j in range(4):
            acc = 0.0
            for k in range(6):
                acc += w[j, k] * xi[k]
            y[j] = acc + zi[4 + j]
    m = w.shape[0]
    if c[_GNSS] == 1.0 and ni % int(c[_GNSS_EVERY]) != 0:  # no GNSS fix this slot: prediction only
        m = 0
    _kf_update(x_hat, p, y[:m], w[:m], x_post, p_post, h)
    # control command and its FBL delivery (fbl.slot_link)
    cap, sqrt_v = _link_terms(snr)
    need = c[_BITS_PER_HZ] / max(a_ctrl, 1e-30)
    eps = 0.5 * math.erfc(c[_SQRT_L] / max(sqrt_v, 1e-150) * (cap - need) * 0.7071067811865476)
    rate_ctrl = a_ctrl * c[_BW] * max(cap - sqrt_v * c[_K_CTRL], 0.0)
    rate_comm = a_comm * c[_BW] * max(cap - sqrt_v * c[_K_COMM], 0.0)
    k_mat = mats[_K]
    if c[_OPEN_LOOP] == 1.0:  # the reference acceleration stored on board
        received = True
        for j in range(3):
            u[j] = ref[ni, 6 + j]
    else:  # delivered with probability 1 - eps: Phi(z) >= eps
        received = eps < 1.0 and 0.5 * math.erfc(-zi[10] * 0.7071067811865476) >= eps
        for j in range(3):
            acc = 0.0
            for k in range(6):
                acc += k_mat[j, k] * (x_post[k] - ref[ni, k])
            u[j] = -acc
            if c[_FEEDFORWARD] == 1.0:
                u[j] += ref[ni, 6 + j]
            if not received:
                u[j] = 0.0
    # drone dynamics and Kalman time update (kalman.kf_predict)
    a_mat, b_mat, sigma_w = mats[_A], mats[_B], mats[_SIGMA_W]
    for j in range(6):
        acc = 0.0
        for k in range(3):
            acc += b_mat[j, k] * u[k]
        bu[j] = acc
    # A x and A P A^T with A = [[I, dt I], [0, I]] (dynamics.system_matrices), blockwise
    dt = a_mat[0, 3]
    for j in range(6):
        ax = xi[j] + dt * xi[j + 3] if j < 3 else xi[j]
        axh = x_post[j] + dt * x_post[j + 3] if j < 3 else x_post[j]
        x_next[j] = ax + bu[j] + mats[_DIAGS, 0, j] * zi[11 + j]
        x_hat_next[j] = axh + bu[j]
    for j in range(3):
        for k in range(3):
            p12 = p_post[j, 3 + k] + dt * p_post[3 + j, 3 + k]
            pa[j, k] = p_post[j, k] + dt * p_post[3 + j, k] + dt * p12
            pa[j, 3 + k] = p12
            pa[3 + j, k] = p_post[3 + j, k] + dt * p_post[3 + j, 3 + k]
            pa[3 + j, 3 + k] = p_post[3 + j, 3 + k]
    for j in range(6):
        for k in range(6):
            p_next[j, k] = 0.5 * ((pa[j, k] + sigma_w[j, k]) + (pa[k, j] + sigma_w[k, j]))
    dx, dy, dz = x_next[0] - px, x_next[1] - py, x_next[2] - pz
    rho = math.exp(math.sqrt(dx * dx + dy * dy + dz * dz) * c[_NEG_INV_DECORR])
    shadow_next = rho * shadow + math.sqrt(1.0 - rho * rho) * zi[17]
    ex = x_next[0] - ref[ni + 1, 0]
    ey = x_next[1] - ref[ni + 1, 1]
    ez = x_next[2] - ref[ni + 1, 2]
    err = math.sqrt(ex * ex + ey * ey + ez * ez)
    dx, dy, dz = x_post[0] - px, x_post[1] - py, x_post[2] - pz
    mt[0] = err
    mt[1] = math.sqrt(dx * dx + dy * dy + dz * dz)
    mt[2] = 10.0 * math.log10(snr)
    mt[3] = 10.0 * math.log10(snr_ls)
    mt[4] = math.sqrt(m_r + m_tt + m_pp)
    mt[5] = math.sqrt(crlb_vr)
    mt[6] = eps
    mt[7] = 1.0 if received else 0.0
    mt[8] = rate_comm
    mt[9] = rate_ctrl
    mt[10] = 0.0 if err <= c[_MAX_ERR] else 1.0
    return shadow_next


@njit(cache=True, error_model="numpy")
def _work():
    """Scratch space of one drone's slot, carved out of one allocation (zeros where only some
    entries are written: the observation matrices)."""
    buf = np.zeros(4 * 36 + 27)
    mats = buf[:4 * 36].reshape(4, 6, 6)
    vec = buf[4 * 36:]
    return (mats[0, :4], mats[1], vec[0:6], vec[6:12], mats[2], vec[12:15], vec[15:21], mats[3], vec[21:27])


@njit(cache=True, error_model="numpy")
def step_batch(c, mats, x, x_hat, p, shadow, n, ref, alpha, z, x_next, x_hat_next, p_next, shadow_next, metrics):
    """loop.step_reference for a batch, written into the output arrays (next x, x_hat, p, shadow and
    the metrics (B, N_METRICS)); outputs are passed in because returning fresh arrays from compiled
    code costs more than the slot itself at small batches."""
    work = _work()
    for i in range(x.shape[0]):
        shadow_next[i] = _step_one(c, mats, x[i], x_hat[i], p[i], shadow[i], n[i], ref[i], alpha[i, 0],
                                   alpha[i, 1], alpha[i, 2], z[i], x_next[i], x_hat_next[i], p_next[i],
                                   metrics[i], work)


N_ENV_COLUMNS = N_STEP_COLUMNS


@njit(cache=True, error_model="numpy")
def _env_rows(c, mats, x, x_hat, p, shadow, n, ref, key, action, z, active, lo, hi,
              x_next, x_hat_next, p_next, shadow_next, out, obs):
    """env_step_batch for rows lo..hi-1, writing into the output arrays."""
    work = _work()
    draw = z.shape[0] == 0
    zbuf = np.empty(N_DRAWS)
    max_err, n_slots = c[_MAX_ERR], c[_N_SLOTS]
    for i in range(lo, hi):
        if not active[i]:
            x_next[i], x_hat_next[i], p_next[i], shadow_next[i] = x[i], x_hat[i], p[i], shadow[i]
            out[i] = 0.0
            obs[i] = 0.0
            continue
        # env.action_to_split
        w0 = (min(max(action[i, 0], -1.0), 1.0) + 1.0) * 0.5
        w1 = (min(max(action[i, 1], -1.0), 1.0) + 1.0) * 0.5
        w2 = (min(max(action[i, 2], -1.0), 1.0) + 1.0) * 0.5
        total = w0 + w1 + w2
        if total <= 1e-12:
            a0 = a1 = a2 = 1.0 / 3.0
        else:
            a0, a1, a2 = w0 / total, w1 / total, w2 / total
        mt = out[i]
        if draw:  # the episode's noise stream (noise.slot_normals), drawn where it is used
            fill_slot_normals(key[i], n[i], zbuf)
            zi = zbuf
        else:
            zi = z[i]
        shadow_next[i] = _step_one(c, mats, x[i], x_hat[i], p[i], shadow[i], n[i], ref[i], a0, a1, a2,
                                   zi, x_next[i], x_hat_next[i], p_next[i], mt, work)
        n_next = n[i] + 1
        evaluable = _observe_one(c, x_hat_next[i], p_next[i], shadow_next[i], n_next, ref[i], mt[7], mt[4],
                                 obs[i])
        # env.reward_and_costs (a rate or loss probability that is NaN counts as a violation)
        err, rate, eps = mt[0], mt[8], mt[6]
        rate_min = c[_RATE_MIN]
        if rate_min <= 0.0:
            cost_rate = 0.0
        elif rate != rate:
            cost_rate = 1.0
        else:
            cost_rate = max(0.0, rate_min - rate) / rate_min
        cost_stab = 1.0 if (eps > c[_EPS_STAR] or eps != eps) else 0.0
        reward = -(err if err <= max_err else max_err) - c[_W_RATE] * cost_rate - c[_W_STAB] * cost_stab
        terminated = mt[10] == 1.0 or not evaluable
        if terminated:
            reward -= max_err * (n_slots - n_next)
        mt[11], mt[12], mt[13] = a0, a1, a2
        mt[14], mt[15], mt[16] = cost_rate, cost_stab, reward
        mt[17] = 1.0 if terminated else 0.0
        mt[18] = 1.0 if (not terminated and n_next >= n_slots) else 0.0


@njit(cache=True, error_model="numpy")
def env_step_batch(c, mats, x, x_hat, p, shadow, n, ref, key, action, z, active,
                   x_next, x_hat_next, p_next, shadow_next, out, obs):
    """One env step of a batch (env.env_step_reference): action -> split (env.action_to_split), slot
    transition, reward and costs (env.reward_and_costs), next observation (env.observe_reference),
    written into the outputs: next x, x_hat, p, shadow, ``out`` (B, N_ENV_COLUMNS) and ``obs``
    (B, 23) float32. ``z`` holds the slot's normals (B, N_DRAWS), or has no rows: then each loop
    draws its own from its episode key (noise.slot_normals(key[i], n[i])). Loops with ``active[i]``
    False are left as they are (state copied, zero outputs)."""
    _env_rows(c, mats, x, x_hat, p, shadow, n, ref, key, action, z, active, 0, x.shape[0],
              x_next, x_hat_next, p_next, shadow_next, out, obs)


@njit(cache=True, error_model="numpy", parallel=True)
def env_step_batch_parallel(c, mats, x, x_hat, p, shadow, n, ref, key, action, z, active,
                            x_next, x_hat_next, p_next, shadow_next, out, obs, chunk):
    """:func:`env_step_batch` with chunks of ``chunk`` rows spread over all cores: each row goes
    through the same compiled :func:`_env_rows`, so results equal the serial kernel's bit for bit
    whatever the chunking."""
    nb = x.shape[0]
    n_chunks = (nb + chunk - 1) // chunk
    for k in prange(n_chunks):
        lo = k * chunk
        _env_rows(c, mats, x, x_hat, p, shadow, n, ref, key, action, z, active, lo, min(lo + chunk, nb),
                  x_next, x_hat_next, p_next, shadow_next, out, obs)


def parallel_chunk(nb: int) -> int:
    """Rows per task: two tasks per thread, at least 32 rows each (measured on 2 cores: 1024 envs
    ~0.9 M env-steps/s with 64-512 rows per task, ~0.5 M with 16)."""
    import numba

    tasks = 2 * numba.get_num_threads()
    return max(32, -(-nb // tasks))


def new_outputs(nb: int, columns: int):
    """Fresh output arrays for the kernels: next x, x_hat, p, shadow, the columns array, and the
    float32 observation."""
    return (np.empty((nb, 6)), np.empty((nb, 6)), np.empty((nb, 6, 6)), np.empty(nb), np.empty((nb, columns)),
            np.empty((nb, 23), np.float32))
