"""Tests of iscc_gym.sim.loop: the batched one-slot transition of the ISCC closed loop."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import scipy.stats

from iscc_gym import SCENARIOS, Scenario, make_scenario
from iscc_gym.sim.loop import N_DRAWS, LoopState, init_state, stack_references, step
from iscc_gym.trajectory import sample_reference

S = Scenario()
HEALTHY = (0.2, 0.2, 0.6)
METRIC_KEYS = {"tracking_error_m", "estimation_error_m", "snr_db", "snr_large_scale_db", "peb_m",
               "veb_mps", "eps_ctrl", "packet_received", "rate_comm_bps", "rate_ctrl_bps",
               "diverged", "bits_arrived", "bits_served", "bits_dropped", "backlog_bits",
               "echo_snr_db"}  # the queue's: 0 without
STATE_FIELDS = ("x", "x_hat", "p", "shadow", "n", "ref")

# model written out from eq:AB_matrices and Table I (independent of iscc_gym.physics.dynamics)
_DT = 0.1
_A = np.block([[np.eye(3), _DT * np.eye(3)], [np.zeros((3, 3)), np.eye(3)]])
_B = np.vstack([0.5 * _DT**2 * np.eye(3), _DT * np.eye(3)])
_Q = np.diag([1e4] * 3 + [1e2] * 3)
_R = 0.01 * np.eye(3)
_P = scipy.linalg.solve_discrete_are(_A, _B, _Q, _R)
_K = np.linalg.solve(_R + _B.T @ _P @ _B, _B.T @ _P @ _A)


@pytest.fixture(scope="module")
def refs():
    return [sample_reference(S, np.random.default_rng(100 + i)) for i in range(3)]


def _alpha(batch, split=HEALTHY):
    return np.tile(np.asarray(split, dtype=float), (batch, 1))


def _rollout(s, refs_, n_steps, alpha, init_rng, step_rng):
    state = init_state(s, refs_, init_rng)
    states, metrics = [state], []
    for _ in range(n_steps):
        state, m = step(s, state, alpha, step_rng)
        states.append(state)
        metrics.append(m)
    return states, metrics


# --- shapes -------------------------------------------------------------------------------------


@pytest.mark.parametrize("batch", [1, 3])
def test_init_state_and_step_shapes(refs, batch):
    state = init_state(S, refs[:batch], np.random.default_rng(0))
    assert isinstance(state, LoopState)
    assert state.batch_size == batch
    assert state.x.shape == (batch, 6) and state.x_hat.shape == (batch, 6)
    assert state.p.shape == (batch, 6, 6)
    assert state.shadow.shape == (batch,)
    assert state.n.shape == (batch,) and np.issubdtype(state.n.dtype, np.integer)
    assert np.all(state.n == 0)
    assert state.ref.shape == (batch, S.n_slots + 1, 9)
    for i in range(batch):  # the stacked reference is [pos, vel, acc]
        np.testing.assert_array_equal(state.ref[i, :, :3], refs[i].pos_m)
        np.testing.assert_array_equal(state.ref[i, :, 3:6], refs[i].vel_mps)
        np.testing.assert_array_equal(state.ref[i, :, 6:], refs[i].acc_mps2)
    new, metrics = step(S, state, _alpha(batch), np.random.default_rng(1))
    for name in STATE_FIELDS:
        assert getattr(new, name).shape == getattr(state, name).shape, name
    assert np.all(new.n == 1)
    assert set(metrics) == METRIC_KEYS
    for k, v in metrics.items():
        assert np.shape(v) == (batch,), k
        assert np.all(np.isfinite(np.asarray(v, dtype=float))), k
    assert metrics["packet_received"].dtype == bool
    assert metrics["diverged"].dtype == bool


def test_init_state_accepts_stacked_array_and_rejects_bad_shapes(refs):
    arr = stack_references(refs)
    assert arr.shape == (3, 5001, 9)
    s1 = init_state(S, arr, np.random.default_rng(0))
    s2 = init_state(S, refs, np.random.default_rng(0))
    np.testing.assert_array_equal(s1.x, s2.x)
    with pytest.raises(ValueError):
        init_state(S, arr[:, :-1], np.random.default_rng(0))
    with pytest.raises(ValueError):
        init_state(S, arr[..., :6], np.random.default_rng(0))
    with pytest.raises(ValueError):
        init_state(S, arr[0, :-1], np.random.default_rng(0))
    with pytest.raises(ValueError):
        init_state(S, arr[0][None, None], np.random.default_rng(0))
    # a single (N+1, 9) reference is an unbatched loop
    single = init_state(S, arr[0], np.random.default_rng(0))
    assert single.x.shape == (6,) and single.p.shape == (6, 6) and single.n.shape == ()


def test_init_state_distribution(refs):
    """x_0 = x_ref,0 + N(0, P_0), x_hat = x_ref,0, P_0 = blkdiag(0.5^2 I, 0.1^2 I)
    (sample statistics over 4000 drones)."""
    batch = 4000
    ref = np.broadcast_to(stack_references(refs[:1]), (batch, S.n_slots + 1, 9))
    state = init_state(S, ref, np.random.default_rng(5))
    x_ref0 = refs[0].state[0]
    np.testing.assert_array_equal(state.x_hat, np.broadcast_to(x_ref0, (batch, 6)))
    np.testing.assert_allclose(state.p, np.broadcast_to(np.diag([0.25] * 3 + [0.01] * 3),
                                                        (batch, 6, 6)))
    dev = state.x - x_ref0
    std = dev.std(axis=0)
    np.testing.assert_allclose(std, [0.5] * 3 + [0.1] * 3, rtol=0.06)
    np.testing.assert_allclose(dev.mean(axis=0) / np.array([0.5] * 3 + [0.1] * 3), 0.0,
                               atol=4 / np.sqrt(batch))
    assert abs(state.shadow.std() - 1.0) < 0.06


# --- determinism --------------------------------------------------------------------------------


def test_same_seeds_bit_identical_rollouts(refs):
    a = _alpha(3)
    s1, m1 = _rollout(S, refs, 200, a, np.random.default_rng(7), np.random.default_rng(8))
    s2, m2 = _rollout(S, refs, 200, a, np.random.default_rng(7), np.random.default_rng(8))
    for st1, st2 in zip(s1, s2, strict=True):
        for name in STATE_FIELDS:
            assert np.array_equal(getattr(st1, name), getattr(st2, name)), name
    for d1, d2 in zip(m1, m2, strict=True):
        for k in METRIC_KEYS:
            assert np.array_equal(d1[k], d2[k]), k
    s3, _ = _rollout(S, refs, 5, a, np.random.default_rng(7), np.random.default_rng(9))
    assert not np.array_equal(s3[-1].x, s1[5].x)


def _batch_and_singles(refs, n_steps):
    alpha = np.array([[0.2, 0.2, 0.6], [0.1, 0.05, 0.85], [0.3, 0.1, 0.6]])
    batch_states, batch_metrics = _rollout(
        S, refs, n_steps, alpha, [np.random.default_rng(10 + i) for i in range(3)],
        [np.random.default_rng(20 + i) for i in range(3)])
    singles = []
    for i in range(3):
        singles.append(_rollout(S, refs[i:i + 1], n_steps, alpha[i:i + 1],
                                [np.random.default_rng(10 + i)], [np.random.default_rng(20 + i)]))
    return batch_states, batch_metrics, singles


def test_batch_equals_single_runs_bit_for_bit(refs):
    batch_states, batch_metrics, singles = _batch_and_singles(refs, 200)
    for i, (states, metrics) in enumerate(singles):
        for n, (sb, ss) in enumerate(zip(batch_states, states, strict=True)):
            for name in STATE_FIELDS:
                assert np.array_equal(getattr(sb, name)[i], getattr(ss, name)[0]), (i, n, name)
        for mb, ms in zip(batch_metrics, metrics, strict=True):
            for k in METRIC_KEYS:
                assert np.array_equal(mb[k][i], ms[k][0]), (i, k)


def test_batch_equals_single_runs_to_rounding(refs):
    """Same as above up to floating-point rounding: the per-drone Generators fully decouple the
    drones' random draws."""
    batch_states, batch_metrics, singles = _batch_and_singles(refs, 200)
    for i, (states, metrics) in enumerate(singles):
        for sb, ss in zip(batch_states, states, strict=True):
            np.testing.assert_allclose(sb.x[i], ss.x[0], rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(sb.x_hat[i], ss.x_hat[0], rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(sb.p[i], ss.p[0], rtol=1e-9, atol=1e-15)
            np.testing.assert_allclose(sb.shadow[i], ss.shadow[0], rtol=1e-9, atol=1e-12)
            assert sb.n[i] == ss.n[0]
        for mb, ms in zip(batch_metrics, metrics, strict=True):
            assert mb["packet_received"][i] == ms["packet_received"][0]
            np.testing.assert_allclose(mb["tracking_error_m"][i], ms["tracking_error_m"][0],
                                       rtol=1e-9, atol=1e-9)


def test_rng_sequence_length_must_match_batch(refs):
    state = init_state(S, refs, np.random.default_rng(0))
    with pytest.raises(TypeError):
        step(S, state, _alpha(3), [np.random.default_rng(0)] * 2)
    assert N_DRAWS == 18


# --- closed-loop behaviour ----------------------------------------------------------------------


def test_no_control_share_means_no_packets_and_drift(refs):
    states, metrics = _rollout(S, refs, 400, _alpha(3, (0.2, 0.0, 0.8)),
                               np.random.default_rng(1), np.random.default_rng(2))
    received = np.array([m["packet_received"] for m in metrics])
    eps = np.array([m["eps_ctrl"] for m in metrics])
    err = np.array([m["tracking_error_m"] for m in metrics])
    assert not received.any()
    np.testing.assert_array_equal(eps, 1.0)
    # without commands the drone does not follow the (accelerating) reference: drift grows
    assert np.all(err[-50:].mean(axis=0) > 10.0)
    assert np.all(err[-50:].mean(axis=0) > 5 * err[:20].mean(axis=0))
    # and the true state evolves with u = 0: velocity changes only by process noise
    dv = np.diff(np.stack([s.x[:, 3:] for s in states]), axis=0)
    assert np.abs(dv).max() < 6 * 0.002  # sigma_v = 0.002 m/s per slot ("std" reading)


def test_healthy_split_tracks_the_reference(refs):
    _, metrics = _rollout(S, refs, 1000, _alpha(3), np.random.default_rng(3),
                          np.random.default_rng(4))
    err = np.array([m["tracking_error_m"] for m in metrics])
    assert np.all(err.mean(axis=0) < 2.0)
    assert not np.array([m["diverged"] for m in metrics]).any()
    assert np.array([m["packet_received"] for m in metrics]).mean() > 0.99


def test_diverged_flag_matches_threshold(refs):
    _, metrics = _rollout(S, refs, 400, _alpha(3, (0.2, 0.0, 0.8)), np.random.default_rng(1),
                          np.random.default_rng(2))
    for m in metrics:
        np.testing.assert_array_equal(m["diverged"], m["tracking_error_m"] > 100.0)
    assert np.array([m["diverged"] for m in metrics]).any()


def test_drop_frequency_matches_eps_ctrl(refs):
    """delta_n ~ Bernoulli(1 - eps_n): the fraction of received packets matches mean(1 - eps) within
    the Bernoulli standard error. A one-symbol control block flattens eq:ctrl_bler so eps is
    spread over (0, 1); alpha_ctrl is set so eps ~ 0.25 at the median large-scale SNR."""
    s = S.replace(ctrl_blocklength=1)
    probe = init_state(s, refs, np.random.default_rng(0))
    _, m0 = step(s, probe, _alpha(3), np.random.default_rng(0))
    snr = 10 ** (np.median(m0["snr_large_scale_db"]) / 10)
    v = np.log2(np.e) ** 2 * (1 - (1 + snr) ** -2)
    need = np.log2(1 + snr) - np.sqrt(v) * scipy.stats.norm.isf(0.25)
    a_ctrl = min(0.5, s.ctrl_packet_bits / (s.ctrl_deadline_s * s.bandwidth_hz * need))
    _, metrics = _rollout(s, refs, 600, _alpha(3, (0.2, a_ctrl, 0.8 - a_ctrl)),
                          np.random.default_rng(1), np.random.default_rng(2))
    eps = np.array([m["eps_ctrl"] for m in metrics]).ravel()
    rec = np.array([m["packet_received"] for m in metrics]).ravel()
    assert np.mean((eps > 0.02) & (eps < 0.98)) > 0.3  # precondition: eps is actually random
    se = np.sqrt(np.sum(eps * (1 - eps))) / eps.size
    assert abs(rec.mean() - (1 - eps.mean())) < 4 * se + 1e-3


def test_lqg_command_is_minus_k_times_estimate_error(refs):
    """With no process noise the applied command is recoverable from the state change,
    B u = x_{n+1} - A x_n, and the filtered estimate from the prediction,
    x_hat_{n+1|n} = A x_hat_n + B u; the command must be -K (x_hat_n - x_ref,n)
    (eq:LQG_control_input)."""
    s = S.replace(process_noise_pos=0.0, process_noise_vel=0.0)
    state = init_state(s, refs, np.random.default_rng(0))
    rng = np.random.default_rng(1)
    checked = 0
    for n in range(30):
        new, m = step(s, state, _alpha(3), rng)
        bu = new.x - state.x @ _A.T
        u = np.linalg.lstsq(_B, bu.T, rcond=None)[0].T
        np.testing.assert_allclose(u @ _B.T, bu, atol=1e-9)  # B u explains the whole change
        x_post = np.linalg.solve(_A, (new.x_hat - bu).T).T
        expected = -(x_post - state.ref[:, n, :6]) @ _K.T
        rec = m["packet_received"]
        np.testing.assert_allclose(u[rec], expected[rec], rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(u[~rec], 0.0, atol=1e-9)
        checked += rec.sum()
        state = new
    assert checked > 0


def test_open_loop_applies_reference_acceleration(refs):
    s = S.replace(control_mode="open_loop", process_noise_pos=0.0, process_noise_vel=0.0)
    for split in (HEALTHY, (0.2, 0.0, 0.8)):
        state = init_state(s, refs, np.random.default_rng(0))
        rng = np.random.default_rng(1)
        for n in range(50):
            new, m = step(s, state, _alpha(3, split), rng)
            assert m["packet_received"].all()  # nothing is sent, nothing is dropped
            expected = state.x @ _A.T + state.ref[:, n, 6:] @ _B.T
            np.testing.assert_allclose(new.x, expected, rtol=1e-12, atol=1e-9)
            state = new


def test_open_loop_never_drops_with_noise(refs):
    s = S.replace(control_mode="open_loop")
    _, metrics = _rollout(s, refs, 100, _alpha(3, (0.5, 0.0, 0.5)), np.random.default_rng(0),
                          np.random.default_rng(1))
    assert all(m["packet_received"].all() for m in metrics)


def test_gnss_observation_runs(refs):
    s = S.replace(observation_source="gnss")
    _, metrics = _rollout(s, refs, 200, _alpha(3, (0.0, 0.2, 0.8)), np.random.default_rng(0),
                          np.random.default_rng(1))
    for m in metrics:
        for k in METRIC_KEYS:
            assert np.all(np.isfinite(np.asarray(m[k], dtype=float))), k
    est = np.array([m["estimation_error_m"] for m in metrics])
    err = np.array([m["tracking_error_m"] for m in metrics])
    # a 3 m-per-axis GNSS fix filtered by the KF: error well below the raw 3 sqrt(3) m, not zero
    assert 0.05 < est[50:].mean() < 3 * np.sqrt(3)
    assert err.mean() < 10.0


def test_literal_preset_runs(refs):
    s = SCENARIOS["literal"]
    _, metrics = _rollout(s, refs, 50, _alpha(3), np.random.default_rng(0),
                          np.random.default_rng(1))
    for m in metrics:
        for k in METRIC_KEYS:
            assert np.all(np.isfinite(np.asarray(m[k], dtype=float))), k


# --- errors -------------------------------------------------------------------------------------


def test_step_rejects_bad_alpha_shape(refs):
    state = init_state(S, refs, np.random.default_rng(0))
    for bad in (np.array(HEALTHY), _alpha(2), _alpha(3)[:, :2], _alpha(3)[None]):
        with pytest.raises(ValueError):
            step(S, state, bad, np.random.default_rng(0))
    single = init_state(S, refs[:1], np.random.default_rng(0))
    with pytest.raises(ValueError):
        step(S, single, np.array(HEALTHY), np.random.default_rng(0))


def test_step_rejects_past_last_slot(refs):
    state = init_state(S, refs, np.random.default_rng(0))
    last = state._replace(n=np.full(3, S.n_slots - 1))
    end, _ = step(S, last, _alpha(3), np.random.default_rng(0))  # the last slot is fine
    assert np.all(end.n == S.n_slots)
    with pytest.raises(ValueError):
        step(S, end, _alpha(3), np.random.default_rng(0))
    mixed = state._replace(n=np.array([0, S.n_slots, 3]))
    with pytest.raises(ValueError):
        step(S, mixed, _alpha(3), np.random.default_rng(0))


def test_no_floating_point_warnings_at_healthy_split(refs):
    with np.errstate(all="raise"):
        _, metrics = _rollout(S, refs, 300, _alpha(3), np.random.default_rng(0),
                              np.random.default_rng(1))
    assert np.all(np.isfinite([m["tracking_error_m"] for m in metrics]))


def test_unbatched_loop_equals_batch_member(refs):
    """A single (unbatched) loop with Generator i follows drone i of a batch stepped with a list of
    Generators: same random draws, same decisions, values equal to rounding (numpy scalars and
    2-D matrix products may round differently from their batched forms in the last bit)."""
    alpha = np.array([[0.2, 0.2, 0.6], [0.1, 0.05, 0.85], [0.3, 0.04, 0.66]])
    gens = [np.random.default_rng(40 + i) for i in range(3)]
    batch = init_state(S, refs, gens)
    singles_rng = [np.random.default_rng(40 + i) for i in range(3)]
    singles = [init_state(S, refs[i], singles_rng[i]) for i in range(3)]
    for _ in range(300):
        batch, mb = step(S, batch, alpha, gens)
        for i in range(3):
            singles[i], ms = step(S, singles[i], alpha[i], singles_rng[i])
            assert mb["packet_received"][i] == ms["packet_received"]
            np.testing.assert_allclose(batch.x[i], singles[i].x, rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(batch.p[i], singles[i].p, rtol=1e-9, atol=1e-15)
            for k in METRIC_KEYS:
                np.testing.assert_allclose(mb[k][i], ms[k], rtol=1e-9, atol=1e-12)



def test_gnss_fix_every_k_slots_and_prediction_in_between():
    """With a GNSS fix every 3rd slot, the covariance between fixes follows the prediction alone,
    P <- A P A^T + Sigma_w (an independent recursion), and a fix shrinks it."""
    from iscc_gym.physics.dynamics import model_matrices as _mm

    s = make_scenario("paper", observation_source="gnss", gnss_update_period_s=0.3)
    mm = _mm(s)
    rng = np.random.default_rng(0)
    state = init_state(s, [sample_reference(s, rng)], [rng])
    for n in range(9):
        p_before = state.p[0].copy()
        state, _ = step(s, state, np.array([[0.0, 0.2, 0.8]]), [rng])
        predicted = mm.a @ p_before @ mm.a.T + mm.sigma_w
        if n % 3 == 0:
            assert np.trace(state.p[0][:3, :3]) < np.trace(predicted[:3, :3]) - 1e-6
        else:
            np.testing.assert_allclose(state.p[0], predicted, rtol=1e-12, atol=1e-15)
