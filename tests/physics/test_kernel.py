"""The compiled slot kernel against the numpy reference (the readable model), and batch invariance."""

import numpy as np
import oracle_loop
import pytest

from iscc_gym.scenario import make_scenario
from iscc_gym.sim import functional as E
from iscc_gym.sim import kernel, loop, noise
from iscc_gym.sim.params import slot_params
from iscc_gym.sim.schema import OBS_BOUND, STEP_COLUMNS
from iscc_gym.trajectory import sample_reference

VARIANTS = [
    ("paper", {}),
    ("literal", {}),
    ("paper", {"observation_source": "gnss"}),
    ("paper", {"observation_source": "gnss", "gnss_update_period_s": 0.1}),
    ("paper", {"control_mode": "open_loop"}),
    ("paper", {"reference_feedforward": True, "array_orientation": "printed",
               "fim_angle_convention": "printed"}),
    ("paper", {"array_orientation": "vertical", "rate_min_bps": 0.0}),
    ("paper", {"beamforming": "broadside"}),
    ("literal", {"beamforming": "broadside", "array_orientation": "printed"}),
    ("paper", {"beamforming": "broadside", "array_orientation": "vertical"}),
]


def _batch(s, b, seed=1):
    rng = np.random.default_rng(seed)
    refs = [sample_reference(s, rng) for _ in range(b)]
    return loop.init_state(s, refs, [np.random.default_rng(seed + 10 + i) for i in range(b)])


@pytest.mark.parametrize("name,overrides", VARIANTS)
def test_env_step_kernel_matches_numpy_reference(name, overrides):
    """Same state, same normals: every output column and the observation agree with the numpy
    reference (action map, loop.step_reference, reward_and_costs, observe_reference)."""
    s = make_scenario(name, **overrides)
    b = 6
    state = _batch(s, b)
    rngs = [np.random.default_rng(100 + i) for i in range(b)]
    acts = np.random.default_rng(5).uniform(-1.3, 1.3, (150, b, 3))
    acts[::7, 0] = [-1.0, 1.0, -1.0]  # zero sensing share
    acts[::11, 1] = [1.0, -1.0, 1.0]  # zero control share
    acts[::13, 2] = -5.0  # every weight zero: equal split
    c, mats = slot_params(s)
    for t in range(150):
        z = loop.standard_normals(rngs, b)
        x, x_hat, p, shadow, _, out, obs = outputs = kernel.new_outputs(b, len(STEP_COLUMNS))
        kernel.env_step_batch(c, mats, tuple(state), (acts[t], np.empty(0), z, np.ones(b, dtype=bool)), outputs)
        ref_state, ref_out, ref_obs = oracle_loop.env_step_reference(s, state, acts[t], z)
        np.testing.assert_allclose(out, ref_out, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(obs, ref_obs, rtol=1e-6, atol=1e-6)
        assert obs.dtype == np.float32
        np.testing.assert_allclose(x, ref_state.x, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(x_hat, ref_state.x_hat, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(p, ref_state.p, rtol=1e-9, atol=1e-15)
        np.testing.assert_allclose(shadow, ref_state.shadow, rtol=1e-12, atol=1e-12)
        state = ref_state


def test_loop_step_kernel_rollout_tracks_numpy_rollout():
    """Independent 500-slot rollouts (kernel vs numpy) stay together: rounding does not grow."""
    s = make_scenario("paper")
    b = 4
    sk = sr = _batch(s, b, seed=3)
    rk = [np.random.default_rng(50 + i) for i in range(b)]
    rr = [np.random.default_rng(50 + i) for i in range(b)]
    alpha = np.tile([0.2, 0.2, 0.6], (b, 1))
    for _ in range(500):
        sk, mk = loop.step(s, sk, alpha, rk)
        sr, mr = oracle_loop.step_reference(s, sr, alpha, rr)
        assert np.array_equal(mk["packet_received"], mr["packet_received"])
        for key in ("tracking_error_m", "peb_m", "snr_db", "eps_ctrl", "rate_comm_bps"):
            np.testing.assert_allclose(mk[key], mr[key], rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(sk.x, sr.x, rtol=0, atol=1e-8)


def test_batch_reproduces_single_loops_bit_for_bit():
    """Drone i of a batch equals the batch of one and the unbatched loop with its own Generator."""
    s = make_scenario("paper")
    b = 5
    rng = np.random.default_rng(1)
    refs = [sample_reference(s, rng) for _ in range(b)]
    alpha = np.random.default_rng(3).dirichlet([1, 1, 1], size=(200, b))
    batch = loop.init_state(s, refs, [np.random.default_rng(i) for i in range(b)])
    rb = [np.random.default_rng(100 + i) for i in range(b)]
    for t in range(200):
        batch, _ = loop.step(s, batch, alpha[t], rb)
    for i in range(b):
        one = loop.init_state(s, [refs[i]], [np.random.default_rng(i)])
        flat = loop.init_state(s, refs[i], np.random.default_rng(i))
        r1, r2 = [np.random.default_rng(100 + i)], np.random.default_rng(100 + i)
        for t in range(200):
            one, _ = loop.step(s, one, alpha[t, i:i + 1], r1)
            flat, _ = loop.step(s, flat, alpha[t, i], r2)
        for field in ("x", "x_hat", "p", "shadow"):
            assert np.array_equal(getattr(one, field)[0], getattr(batch, field)[i])
            assert np.array_equal(getattr(flat, field), getattr(batch, field)[i])


def test_env_step_batch_equals_single_env_steps_bit_for_bit():
    s = make_scenario("paper")
    b = 4
    acts = np.random.default_rng(9).uniform(-1, 1, (120, b, 3))
    batch = _batch(s, b, seed=7)
    rb = [np.random.default_rng(200 + i) for i in range(b)]
    outs, obss = [], []
    for t in range(120):
        batch, out, obs = E.env_step(s, batch, acts[t], loop.standard_normals(rb, b))
        outs.append(out)
        obss.append(obs)
    full = _batch(s, b, seed=7)
    for i in range(b):
        one = full.rows(slice(i, i + 1))
        r = [np.random.default_rng(200 + i)]
        for t in range(120):
            one, out, obs = E.env_step(s, one, acts[t, i:i + 1], loop.standard_normals(r, 1))
            assert np.array_equal(out[0], outs[t][i])
            assert np.array_equal(obs[0], obss[t][i])


def test_observation_kernel_matches_reference_on_extreme_states():
    """Near divergence and right above the GBS the observation is finite, in the box, and equal to
    the numpy reference."""
    s = make_scenario("paper")
    state = _batch(s, 3)
    x_hat = state.x_hat.copy()
    x_hat[0, :3] += 5e4  # far outside the coverage region
    x_hat[1, :3] = [0.0, 0.0, 200.0]  # zenith of the GBS
    x_hat[2, 3:] = -1e6
    state = state._replace(x_hat=x_hat)
    last_rx, last_peb = np.array([0.0, 1.0, 1.0]), np.array([1e9, 0.0, 0.01])
    obs = E.observe(s, state, last_rx, last_peb)
    ref = oracle_loop.observe_reference(s, state, last_rx, last_peb)
    assert np.all(np.isfinite(obs)) and np.all(np.abs(obs) <= OBS_BOUND)
    np.testing.assert_allclose(obs, ref, rtol=1e-6, atol=1e-6)


def test_kernel_draws_the_episode_stream_of_each_key():
    """With no normals passed, the kernel draws loop i's slot normals from its key and slot: the
    same outputs as passing noise.slot_normals(key, n), on the serial and the parallel kernel,
    whatever the rows' slots (rows at different slots, some inactive)."""
    s = make_scenario("paper")
    b = E.PARALLEL_MIN_BATCH + 9
    state = _batch(s, b, seed=4)
    state = state._replace(n=np.arange(b, dtype=np.int64) * 37 % s.n_slots)
    acts = np.random.default_rng(1).uniform(-1, 1, (b, 3))
    active = np.random.default_rng(2).random(b) < 0.8
    c, mats = slot_params(s)
    st = tuple(state)
    given = kernel.new_outputs(b, len(STEP_COLUMNS))
    kernel.env_step_batch(c, mats, st, (acts, np.empty(0), noise.slot_normals(state.key, state.n), active), given)
    drawn = kernel.new_outputs(b, len(STEP_COLUMNS))
    kernel.env_step_batch(c, mats, st, (acts, np.empty(0), np.empty((0, noise.N_DRAWS)), active), drawn)
    par = kernel.new_outputs(b, len(STEP_COLUMNS))
    kernel.env_step_batch_parallel(c, mats, st, (acts, np.empty(0), np.empty((0, noise.N_DRAWS)), active), par, 16)
    for g, d, q in zip(given, drawn, par, strict=True):
        assert np.array_equal(g, d) and np.array_equal(g, q)
    new, out, obs = E.env_step(s, state, acts, active=active)
    assert np.array_equal(out, given[5]) and np.array_equal(new.key, state.key)


def test_loop_step_defaults_to_the_state_key_stream():
    """loop.step and loop.step_reference without a Generator use noise.slot_normals(key, n)."""
    s = make_scenario("paper")
    state = _batch(s, 3, seed=6)
    alpha = np.tile([0.2, 0.2, 0.6], (3, 1))
    a, ma = loop.step(s, state, alpha)
    b, mb = oracle_loop.step_reference(s, state, alpha, z=noise.slot_normals(state.key, state.n))
    c, mc = oracle_loop.step_reference(s, state, alpha)
    np.testing.assert_allclose(a.x, b.x, rtol=1e-12, atol=1e-9)
    assert np.array_equal(b.x, c.x) and np.array_equal(a.key, state.key)


def test_sequential_update_keeps_covariance_symmetric_psd_at_extreme_precision():
    """All-sensing slots near the GBS (the most precise measurements) with bursts of lost packets:
    the kernel's row-by-row update keeps P exactly symmetric and positive definite and follows the
    numpy reference's batch Joseph form."""
    s = make_scenario("paper")
    state = _batch(s, 3, seed=8)
    x = state.x.copy()
    x[:, :3] = [[30.0, 10.0, 110.0], [-5.0, 2.0, 100.5], [400.0, -300.0, 250.0]]
    state = state._replace(x=x, x_hat=x.copy())
    acts = np.tile([1.0, -1.0, -1.0], (3, 1))  # all sensing: no control share, every packet lost
    acts[:, 1] = np.where(np.arange(3) == 0, 0.0, -1.0)
    ref_state = state
    for _ in range(300):
        z = noise.slot_normals(state.key, state.n)
        state, _, _ = E.env_step(s, state, acts, z)
        ref_state, _, _ = oracle_loop.env_step_reference(s, ref_state, acts, z)
        np.testing.assert_allclose(state.p, ref_state.p, rtol=1e-7, atol=1e-12)
        assert np.array_equal(state.p, state.p.transpose(0, 2, 1))
        assert np.all(np.linalg.eigvalsh(state.p) > 0)
        ref_state = state  # step both from the kernel's state: compare one slot at a time


def test_kernel_matches_reference_where_the_model_cannot_evaluate_the_state():
    """Estimate below ground with an overflowing SNR, a NaN estimate, a healthy drone: both paths
    give the same finite observation (NaN entries read 0), the same costs, reward and termination."""
    s = make_scenario("paper", max_tracking_error_m=1e12)
    state = _batch(s, 3)
    x, x_hat, shadow = state.x.copy(), state.x_hat.copy(), state.shadow.copy()
    x[0, 2] = x_hat[0, 2] = -1592.0
    shadow[0] = -1.0
    x_hat[1, 0] = np.nan
    state = state._replace(x=x, x_hat=x_hat, shadow=shadow)
    z = loop.standard_normals([np.random.default_rng(i) for i in range(3)], 3)
    acts = np.zeros((3, 3))
    with np.errstate(all="ignore"):
        _, ref_out, ref_obs = oracle_loop.env_step_reference(s, state, acts, z)
        _, out, obs = E.env_step(s, state, acts, z)
    col = {name: j for j, name in enumerate(STEP_COLUMNS)}
    assert np.all(np.isfinite(obs)) and np.all(np.abs(obs) <= OBS_BOUND)
    assert np.all(np.isfinite(out[:, col["reward"]]))
    assert list(out[:, col["terminated"]]) == [1.0, 1.0, 0.0]
    np.testing.assert_array_equal(out[:, col["terminated"]], ref_out[:, col["terminated"]])
    for name in ("cost_rate", "cost_stability", "reward", "truncated"):
        np.testing.assert_allclose(out[:, col[name]], ref_out[:, col[name]], rtol=1e-9)
    np.testing.assert_allclose(obs, ref_obs, rtol=1e-6, atol=1e-6)
    # and the observation of such a state alone (reset / observe) is finite on both paths too
    for fn in (E.observe, oracle_loop.observe_reference):
        with np.errstate(all="ignore"):
            o = fn(s, state, np.ones(3), np.zeros(3))
        assert np.all(np.isfinite(o))
