"""The batched vector env against the single env, autoreset semantics, and input validation."""

import gymnasium as gym
import numpy as np
import pytest

import iscc_gym  # noqa: F401  (registers the env)
from iscc_gym.envs.vector import ISCCVectorEnv
from iscc_gym.scenario import make_scenario
from iscc_gym.sim import functional as E
from iscc_gym.sim import kernel, loop
from iscc_gym.sim.params import slot_params
from iscc_gym.sim.schema import OBS_BOUND, STEP_COLUMNS
from iscc_gym.sim.task import split_to_action
from iscc_gym.trajectory import sample_reference

UNSTABLE = split_to_action([0.98, 0.0, 0.02])  # no control share: every command lost


def _make_vec(n, **kw):
    return gym.make_vec("iscc_gym/ISCC-v0", num_envs=n, vectorization_mode="vector_entry_point", **kw)


def _record(venv, actions):
    recs = []
    for a in actions:
        o, r, te, tr, info = venv.step(a)
        recs.append((o.copy(), r.copy(), te.copy(), tr.copy(),
                     {k: np.copy(v) for k, v in info.items() if not k.startswith(("final", "_final"))},
                     info))
    return recs


def test_make_vec_uses_the_native_vector_env():
    venv = _make_vec(2)
    assert isinstance(venv, ISCCVectorEnv)
    assert venv.max_steps == 5000
    obs, info = venv.reset(seed=0)
    assert obs.shape == (2, 23) and obs.dtype == np.float32 and venv.observation_space.contains(obs)
    assert venv.action_space.shape == (2, 3)


def test_sub_envs_reproduce_single_envs_over_whole_episodes_with_terminations():
    """NextStep autoreset: sub-env i seeded s_i equals the single env seeded s_i (reset without a
    seed after each episode), step for step, through a full 5000-slot mission and through
    repeated loss-of-track terminations."""
    n, steps = 3, 5100
    acts = np.random.default_rng(0).uniform(-1, 1, (steps, n, 3)).astype(np.float32)
    acts[:, 1] = UNSTABLE
    venv = _make_vec(n)
    obs0, _ = venv.reset(seed=[11, 12, 13])
    recs = _record(venv, acts)
    for i in range(n):
        env = gym.make("iscc_gym/ISCC-v0")
        o, _ = env.reset(seed=11 + i)
        assert np.array_equal(o, obs0[i])
        done, resets, truncations = False, 0, 0
        for t in range(steps):
            ro, rr, rte, rtr, rinfo, _ = recs[t]
            if done:  # the vector env resets this sub-env in this step
                o, _ = env.reset()
                assert np.array_equal(o, ro[i]) and rr[i] == 0.0 and not rte[i] and not rtr[i]
                assert not rinfo["_tracking_error_m"][i]
                done, resets = False, resets + 1
                continue
            o, r, te, tr, info = env.step(acts[t, i])
            assert np.array_equal(o, ro[i]), (i, t)
            assert (r, te, tr) == (rr[i], rte[i], rtr[i]), (i, t)
            for key in ("tracking_error_m", "peb_m", "eps_ctrl", "rate_comm_bps", "cost", "slot"):
                assert info[key] == rinfo[key][i], (key, i, t)
            assert np.array_equal(info["alpha"], rinfo["alpha"][i])
            assert info["packet_received"] == rinfo["packet_received"][i]
            truncations += tr
            done = te or tr
        if i == 1:
            assert resets >= 3  # the unstable sub-env lost track repeatedly
        else:
            assert truncations == 1 and resets == 1  # a whole mission, then a new episode


def test_same_step_autoreset_reports_final_observation():
    n = 2
    venv = _make_vec(n, autoreset_mode="SameStep")
    single = gym.make("iscc_gym/ISCC-v0")
    venv.reset(seed=[5, 6])
    o_single, _ = single.reset(seed=6)
    acts = np.zeros((400, n, 3), np.float32)
    acts[:, 1] = UNSTABLE
    for t in range(400):
        o, r, te, tr, info = venv.step(acts[t])
        so, sr, ste, str_, _ = single.step(acts[t, 1])
        assert sr == r[1] and ste == te[1]
        if te[1]:
            assert info["_final_obs"][1] and not info["_final_obs"][0]
            assert np.array_equal(info["final_obs"][1], so)
            assert info["final_info"]["_tracking_error_m"][1]
            so, _ = single.reset()
            assert np.array_equal(o[1], so)  # already the new episode's first observation
            return
        assert np.array_equal(o[1], so)
    pytest.fail("the unstable sub-env never terminated")


def test_reset_mask_resets_only_masked_sub_envs():
    venv = _make_vec(3)
    obs, _ = venv.reset(seed=0)
    for _ in range(10):
        obs, *_ = venv.step(np.zeros((3, 3), np.float32))
    x_before = venv._state.x.copy()
    obs2, info = venv.reset(seed=[None, 42, None], options={"reset_mask": [False, True, False]})
    assert np.array_equal(venv._state.x[[0, 2]], x_before[[0, 2]])
    assert list(venv._state.n) == [10, 0, 10]
    single = gym.make("iscc_gym/ISCC-v0")
    o, _ = single.reset(seed=42)
    assert np.array_equal(obs2[1], o)
    assert list(info["_slot"]) == [False, True, False]


@pytest.mark.parametrize("bad,match", [
    (np.full((2, 3), np.nan), "NaN or inf"),
    (np.zeros((3, 3)), "shape"),
    (np.zeros(3), "shape"),
])
def test_bad_actions_raise_and_leave_state_unchanged(bad, match):
    venv = _make_vec(2)
    venv.reset(seed=1)
    venv.step(np.zeros((2, 3), np.float32))
    x, n = venv._state.x.copy(), venv._state.n.copy()
    rng_states = [r.bit_generator.state for r in venv._rngs]
    with pytest.raises(ValueError, match=match):
        venv.step(bad)
    assert np.array_equal(venv._state.x, x) and np.array_equal(venv._state.n, n)
    assert [r.bit_generator.state for r in venv._rngs] == rng_states


def test_invalid_construction_and_step_before_reset():
    with pytest.raises(ValueError, match="num_envs"):
        ISCCVectorEnv(num_envs=0)
    with pytest.raises(ValueError, match="autoreset_mode"):
        ISCCVectorEnv(num_envs=2, autoreset_mode="Sometimes")
    with pytest.raises(TypeError):
        ISCCVectorEnv(num_envs=2, not_a_field=1)
    with pytest.raises(RuntimeError, match="reset"):
        ISCCVectorEnv(num_envs=2).step(np.zeros((2, 3)))


def test_parallel_kernel_equals_serial_kernel_bit_for_bit():
    s = make_scenario("paper")
    b = E.PARALLEL_MIN_BATCH + 45
    rng = np.random.default_rng(2)
    ref = loop.reference_array(sample_reference(s, rng))
    refs = np.ascontiguousarray(np.broadcast_to(ref, (b,) + ref.shape))
    state = loop.init_state(s, refs, rng)
    c, mats = slot_params(s)
    args = (c, mats, tuple(state), (rng.uniform(-1, 1, (b, 3)), rng.uniform(0, 1, b),
                                    rng.standard_normal((b, loop.N_DRAWS)), rng.random(b) < 0.9))
    serial = kernel.new_outputs(b, len(STEP_COLUMNS))
    kernel.env_step_batch(*args, serial)
    for chunk in (16, 37, kernel.parallel_chunk(b)):
        parallel = kernel.new_outputs(b, len(STEP_COLUMNS))
        kernel.env_step_batch_parallel(*args, parallel, chunk)
        for a, b_ in zip(serial, parallel, strict=True):
            assert np.array_equal(a, b_)


def test_a_sub_env_the_model_cannot_evaluate_ends_alone_with_finite_values():
    venv = ISCCVectorEnv(3, max_tracking_error_m=1e12)
    venv.reset(seed=0)
    st = venv._state
    x, x_hat, shadow = st.x.copy(), st.x_hat.copy(), st.shadow.copy()
    x[1, 2] = x_hat[1, 2] = -1592.0  # 1.6 km below ground: the SNR overflows
    shadow[1] = -1.0
    venv._state = st._replace(x=x, x_hat=x_hat, shadow=shadow)
    obs, reward, terminated, truncated, _ = venv.step(np.zeros((3, 3), np.float32))
    assert np.all(np.isfinite(obs)) and np.all(np.abs(obs) <= OBS_BOUND)
    assert np.all(np.isfinite(reward))
    assert list(terminated) == [False, True, False] and not truncated.any()
    obs, reward, terminated, truncated, _ = venv.step(np.zeros((3, 3), np.float32))  # NextStep: 1 resets
    assert reward[1] == 0.0 and venv._state.n[1] == 0 and np.all(np.isfinite(obs))


@pytest.mark.parametrize("kwargs,error,match", [
    ({"seed": [7, -1]}, ValueError, r"seed\[1\] = -1"),
    ({"seed": [7, 1.5]}, TypeError, r"seed\[1\]"),
    ({"seed": 1.5}, TypeError, "seed = 1.5"),
    ({"seed": "12"}, TypeError, "seed = '12'"),
    ({"seed": -3}, ValueError, "seed = -3"),
    ({"seed": [1, 2, 3]}, ValueError, "list of 2 seeds"),
    ({"options": {"reset_mask": "ab"}}, TypeError, "reset_mask"),
    ({"options": {"reset_mask": [1, 0]}}, TypeError, "reset_mask"),
    ({"options": {"reset_mask": [True, False, True]}}, ValueError, r"reset_mask.*shape \(2,\)"),
    ({"seed": [7, -1], "options": {"reset_mask": [True, False]}}, ValueError, r"seed\[1\]"),
])
def test_rejected_reset_leaves_every_sub_env_untouched(kwargs, error, match):
    """Issue 12: reset(seed=[7, -1]) had reseeded sub-env 0 before rejecting seed 1."""
    venv = ISCCVectorEnv(2)
    venv.reset(seed=0)
    venv.step(np.zeros((2, 3), np.float32))
    x, n = venv._state.x.copy(), venv._state.n.copy()
    rng_states = [r.bit_generator.state for r in venv._rngs]
    with pytest.raises(error, match=match):
        venv.reset(**kwargs)
    assert np.array_equal(venv._state.x, x) and np.array_equal(venv._state.n, n)
    assert [r.bit_generator.state for r in venv._rngs] == rng_states


def test_too_many_sub_envs_for_the_memory_rejected_up_front():
    with pytest.raises(ValueError, match="num_envs = 10000000 needs about"):
        ISCCVectorEnv(num_envs=10_000_000)  # ~15 TB of episodes


def test_terminated_sub_env_is_reset_not_charged_again():
    """A sub-env that lost track is reset by the next step (NextStep autoreset): reward 0, slot 0; it
    never keeps flying (and paying the loss-of-track penalty) without a reset."""
    venv = ISCCVectorEnv(2)
    venv.reset(seed=[3, 4])
    acts = np.stack([UNSTABLE, split_to_action([0.2, 0.2, 0.6])])
    for _ in range(5000):
        _, reward, terminated, _, _ = venv.step(acts)
        if terminated[0]:
            break
    assert terminated[0] and reward[0] < -1000.0
    _, reward, terminated, truncated, info = venv.step(acts)
    assert reward[0] == 0.0 and not terminated[0] and not truncated[0] and info["slot"][0] == 0
    assert not info["_tracking_error_m"][0]


def test_positions_are_the_true_and_reference_positions_behind_the_tracking_error():
    """``positions()`` (the evaluator's traces) returns the state the tracking error is measured on."""
    import pytest

    from iscc_gym.envs.vector import ISCCVectorEnv

    venv = ISCCVectorEnv(num_envs=3)
    with pytest.raises(RuntimeError, match="reset"):
        venv.positions()
    venv.reset(seed=[4, 5, 6])
    for _ in range(20):
        _, _, _, _, info = venv.step(np.full((3, 3), 0.1, dtype=np.float32))
    pos, ref = venv.positions()
    assert pos.shape == ref.shape == (3, 3)
    np.testing.assert_allclose(np.linalg.norm(pos - ref, axis=1), info["tracking_error_m"], rtol=1e-9)
    assert venv.positions(2)[0].shape == (2, 3)


# --- issue 23: the clients' API (item 4) and defects 14, 15 -----------------------------------------


@pytest.mark.parametrize("n_drones", [None, 2])
def test_reset_info_carries_the_step_info_keys(n_drones):
    kw = {} if n_drones is None else {"n_drones": n_drones}
    venv = ISCCVectorEnv(num_envs=3, **kw)
    _, info = venv.reset(seed=5)
    k = 3 * (n_drones or 1)
    _, _, _, _, step_info = venv.step(np.zeros((3, k), np.float32))
    assert set(info) == set(step_info)
    for key, val in info.items():
        assert np.shape(val) == np.shape(step_info[key]), key
        assert np.asarray(val).dtype.kind == np.asarray(step_info[key]).dtype.kind, key
        if key.startswith("_"):
            assert val.all(), key
    assert (info["slot"] == 0).all() and (info["cost"] == 0.0).all() and np.isnan(info["peb_m"]).all()
    assert np.all(info["tracking_error_m"] > 0.0)
    if n_drones is None:  # sub-env i: the single env's reset info with seed 5 + i
        for i in range(3):
            _, single = gym.make("iscc_gym/ISCC-v0").reset(seed=5 + i)
            assert info["tracking_error_m"][i] == single["tracking_error_m"]
    # a partial reset: values for the reset sub-env only, the others masked off
    _, info = venv.reset(options={"reset_mask": np.array([False, True, False])})
    assert info["_tracking_error_m"].tolist() == [False, True, False] and info["slot"][1] == 0


@pytest.mark.parametrize("n_drones", [None, 2])
def test_complex_actions_are_refused(n_drones):
    kw = {} if n_drones is None else {"n_drones": n_drones}
    venv = ISCCVectorEnv(num_envs=2, **kw)
    venv.reset(seed=0)
    before = venv._state
    a = np.zeros((2, 3 * (n_drones or 1)), np.complex128)
    with pytest.raises(TypeError, match="actions has complex dtype complex128"):
        venv.step(a)
    assert venv._state is before


@pytest.mark.parametrize("kwargs, error, match", [
    ({"max_episode_steps": 2.5}, TypeError, r"max_episode_steps = 2.5 \(float\); use an integer >= 1 or None"),
    ({"max_episode_steps": "10"}, TypeError, r"max_episode_steps = '10' \(str\)"),
    ({"max_episode_steps": float("nan")}, TypeError, r"max_episode_steps = nan \(float\)"),
    ({"max_episode_steps": True}, TypeError, r"max_episode_steps = True \(bool\)"),
    ({"max_episode_steps": 0}, ValueError, r"max_episode_steps = 0; use an integer >= 1"),
    ({"num_envs": True}, TypeError, r"num_envs = True \(bool\); use an integer >= 1"),
    ({"num_envs": 2.0}, TypeError, r"num_envs = 2.0 \(float\)"),
    ({"num_envs": 0}, ValueError, r"num_envs = 0; use an integer >= 1"),
])
def test_counts_are_validated_with_errors_naming_them(kwargs, error, match):
    """Defect 15: max_episode_steps=2.5 became 2, '10' and NaN gave unclear errors, num_envs=True was 1."""
    with pytest.raises(error, match=match):
        ISCCVectorEnv(**{"num_envs": 2, **kwargs})
    if "max_episode_steps" in kwargs:  # the same through gymnasium.make_vec
        with pytest.raises(error, match=match):
            _make_vec(2, **kwargs)
    assert ISCCVectorEnv(num_envs=np.int64(2), max_episode_steps=np.int32(7)).max_steps == 7


def test_unknown_keyword_has_pythons_own_typeerror_wording():
    with pytest.raises(TypeError, match=r"^ISCCVectorEnv\.__init__\(\) got an unexpected keyword argument "
                                        r"'frameskip'; it takes num_envs, "):
        ISCCVectorEnv(num_envs=2, frameskip=1)


@pytest.mark.parametrize("mode", [gym.vector.AutoresetMode.SAME_STEP, "SameStep", "SAME_STEP", "same_step"])
def test_autoreset_mode_as_gymnasium_passes_it(mode):
    """A keyword of make_vec for the vector entry point; Gymnasium's own sync/async vector envs take it in
    vector_kwargs. Gymnasium (1.1-1.4) refuses vector_kwargs for a vector entry point itself: if a
    later Gymnasium passes them on, the env must honour them."""
    venv = _make_vec(2, autoreset_mode=mode)
    assert venv.autoreset_mode == venv.metadata["autoreset_mode"] == gym.vector.AutoresetMode.SAME_STEP
    sync = gym.make_vec("iscc_gym/ISCC-v0", num_envs=2, vectorization_mode="sync",
                        vector_kwargs={"autoreset_mode": gym.vector.AutoresetMode.SAME_STEP})
    assert sync.metadata["autoreset_mode"] == gym.vector.AutoresetMode.SAME_STEP
    try:
        venv = gym.make_vec("iscc_gym/ISCC-v0", num_envs=2, vectorization_mode="vector_entry_point",
                            vector_kwargs={"autoreset_mode": gym.vector.AutoresetMode.SAME_STEP})
    except gym.error.Error as e:
        assert "vector_kwargs" in str(e)  # Gymnasium's refusal, before our entry point is called
    else:
        assert venv.autoreset_mode == gym.vector.AutoresetMode.SAME_STEP


def test_same_step_autoreset_ends_and_restarts_in_one_step():
    venv = _make_vec(2, autoreset_mode="SAME_STEP", max_episode_steps=3)
    venv.reset(seed=0)
    for _ in range(3):
        obs, _, term, trunc, info = venv.step(np.zeros((2, 3), np.float32))
    assert trunc.all() and info["_final_obs"].all() and (venv._slots() == 0).all()


# --- issue 34 -----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("env_id", [iscc_gym.ENV_ID, iscc_gym.MULTI_ENV_ID])
def test_same_step_autoreset_info_is_gymnasiums_sync_vector_envs(env_id):
    """Item 11: SameStep puts a reset sub-env's reset info at the top level and the ended step's under
    final_info, as Gymnasium's SyncVectorEnv over the single env (the oracle) does: a consumer summing
    info["bits_arrived"] counted each episode's last slot twice."""
    same = gym.vector.AutoresetMode.SAME_STEP
    kw = {"max_episode_steps": 3, **({"n_drones": 2} if env_id == iscc_gym.MULTI_ENV_ID else {})}
    sync = gym.make_vec(env_id, num_envs=2, vectorization_mode="sync", vector_kwargs={"autoreset_mode": same}, **kw)
    venv = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", autoreset_mode=same, **kw)
    for env in (sync, venv):
        env.reset(seed=[3, 4])
        env.step(np.zeros(env.action_space.shape, np.float32))
        env.reset(options={"reset_mask": np.array([True, False])})  # sub-env 0 ends a step after sub-env 1
    acts = np.random.default_rng(0).uniform(-1, 1, (6, *venv.action_space.shape)).astype(np.float32)
    ends = 0
    for a in acts:
        (o, r, te, tr, info), (so, sr, ste, str_, sinfo) = venv.step(a), sync.step(a)
        assert np.array_equal(o, so) and np.array_equal(r, sr) and np.array_equal(te | tr, ste | str_)
        for top, ref in ((info, sinfo), (info.get("final_info"), sinfo.get("final_info"))):
            if ref is None:
                assert top is None
                continue
            for key in (k for k in top if not k.startswith(("_", "final"))):
                assert np.array_equal(top["_" + key], ref["_" + key]), key
                m = ref["_" + key]
                assert np.array_equal(top[key][m], ref[key][m], equal_nan=True), key
        if "final_obs" in sinfo:
            assert np.array_equal(info["_final_obs"], sinfo["_final_obs"])
            for i in np.flatnonzero(sinfo["_final_obs"]):
                assert np.array_equal(info["final_obs"][i], sinfo["final_obs"][i])
        ends += int((te | tr).sum())
    assert ends == 4  # each sub-env ended twice, at different steps


def test_sb3_batched_env_reports_an_ended_episodes_last_step_as_dummy_vec_env():
    """Item 11: the SB3 face keeps SB3's convention (an ended episode's info is its last step's) now that the
    vector env's top-level info holds the reset's."""
    from iscc_gym.agents.sb3_vec_env import ISCCBatchedVecEnv
    from stable_baselines3.common.vec_env import DummyVecEnv

    keys = ("cost", "slot", "tracking_error_m")
    ours = ISCCBatchedVecEnv(2, info_keys=keys, max_episode_steps=3)
    dummy = DummyVecEnv([lambda: gym.make(iscc_gym.ENV_ID, max_episode_steps=3)] * 2)
    for v in (ours, dummy):
        v.seed(5)
        v.reset()
    ended = 0
    for a in np.random.default_rng(1).uniform(-1, 1, (4, 2, 3)).astype(np.float32):
        (o, r, d, infos), (so, sr, sd, sinfos) = ours.step(a), dummy.step(a)
        assert np.array_equal(o, so) and np.array_equal(r, sr) and np.array_equal(d, sd)
        for i, si in zip(infos, sinfos, strict=True):
            assert {k: i[k] for k in keys} == {k: si[k] for k in keys}
        ended += int(d.sum())
    assert ended == 2  # both episodes ended at step 3, and their last slot is reported: slot 3
