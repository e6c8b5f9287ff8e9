"""The device vector env on its CPU stand-in: the same episodes as the CPU vector env, autoreset by the documented
formula (checked against a numpy oracle of it), reproducibility, tensors shared without copies, and clear errors."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

torch = pytest.importorskip("torch")

import iscc_gym  # noqa: E402,F401
from iscc_gym.gpu.kernel import N_INIT_DRAWS  # noqa: E402
from iscc_gym.gpu.vector_env import DeviceVectorEnv  # noqa: E402
from iscc_gym.scenario import make_scenario  # noqa: E402
from iscc_gym.sim.noise import slot_normals  # noqa: E402
from iscc_gym.sim.schema import COL  # noqa: E402

_REWARD = COL["reward"]


def _play_both(env_id, n, steps, limit, seed=3):
    d = DeviceVectorEnv(env_id, num_envs=n, device="cpu", pool_size=n, max_episode_steps=limit)
    v = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", max_episode_steps=limit)
    o1, _ = d.reset(seed=seed)
    o2, _ = v.reset(seed=seed)
    np.testing.assert_array_equal(o1.numpy(), o2)
    rng = np.random.default_rng(0)
    for k in range(steps):
        a = rng.uniform(-1.2, 1.2, (n, 3)).astype(np.float32)
        o1, r1, t1, u1, info = d.step(torch.from_numpy(a))
        o2, r2, t2, u2, _ = v.step(a.astype(np.float64))
        np.testing.assert_allclose(info["metrics"][:, _REWARD].numpy(), r2, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(r1.numpy(), r2, rtol=1e-6)
        np.testing.assert_array_equal(t1.numpy(), t2)
        np.testing.assert_array_equal(u1.numpy(), u2)
        if k < steps - 1 or not (t2 | u2).any():
            np.testing.assert_allclose(o1.numpy(), o2, rtol=1e-6, atol=1e-6)
        ended = t2 | u2  # the CPU env autoresets in the next step: its observation now is the episode's last
        np.testing.assert_allclose(info["final_obs"].numpy()[ended], o2[ended], rtol=1e-6, atol=1e-6)
    return d


@pytest.mark.parametrize("env_id", ["iscc_gym/ISCC-v0", pytest.param("iscc_gym/ISCC-Urban-v0", marks=pytest.mark.slow),
                                    pytest.param("iscc_gym/ISCC-Field-v0", marks=pytest.mark.slow)])
def test_first_episodes_are_the_cpu_vector_envs(env_id):
    d = _play_both(env_id, 3, 12, 12)
    assert (d.final_length.numpy() == 12).all()  # every episode truncated at the limit in the last step
    assert np.isfinite(d.final_return.numpy()).all()


_M64 = (1 << 64) - 1
_G = 0x9E3779B97F4A7C15


def _mix64(z):
    """SplitMix64's output function in Python integers (an oracle independent of the compiled one)."""
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _M64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _M64
    return z ^ (z >> 31)


def _oracle_reset(s, pool, seed_key, row, episode):
    """The new episode of ``row`` by the formula documented in iscc_gym.gpu.kernel, in Python integers: the key
    SplitMix64 of the row's stream stepped by the episode count, the mission its top 53 bits modulo the pool, the
    initial normals slot 0 of the salted key's stream.
    """
    stream = _mix64((int(seed_key) + (row + 1) * _G) & _M64)
    k = _mix64((stream + (episode + 1) * _G) & _M64)
    j = (k >> 11) % pool.shape[0]
    z = slot_normals(np.uint64(_mix64(k ^ 0x5851F42D4C957F2D)), 0, N_INIT_DRAWS)
    std0 = np.array([s.initial_pos_std_m] * 3 + [s.initial_vel_std_mps] * 3)
    return k, j, pool[j, 0, :6] + std0 * z[:6], z[6]


def test_autoreset_and_rows_beyond_the_pool_follow_the_documented_draws():
    s = make_scenario("paper")
    d = DeviceVectorEnv(num_envs=5, device="cpu", pool_size=2, max_episode_steps=4)
    d.reset(seed=11)
    pool = d._pool
    st = d.host_state()
    for row in (2, 3, 4):  # beyond the pool: episode 0 drawn on the device
        k, j, x, shadow = _oracle_reset(s, pool, d._seed_key, row, 0)
        assert st["key"][row] == k and st["mission"][row] == j
        np.testing.assert_allclose(st["x"][row], x, rtol=1e-12)
        np.testing.assert_allclose(st["x_hat"][row], pool[j, 0, :6])
        assert st["shadow"][row] == pytest.approx(shadow, rel=1e-12)
    a = torch.zeros((5, 3))
    for _ in range(4):
        obs, _, term, trunc, info = d.step(a)
    assert trunc.all() and not term.any()
    st = d.host_state()
    assert (st["episode"] == 1).all() and (st["n"] == 0).all() and (info["final_length"].numpy() == 4).all()
    for row in range(5):
        k, j, x, shadow = _oracle_reset(s, pool, d._seed_key, row, 1)
        assert st["key"][row] == k and st["mission"][row] == j
        np.testing.assert_allclose(st["x"][row], x, rtol=1e-12)
    # the returned observation is the new episode's first (same-step autoreset)
    from iscc_gym.sim import loop
    from iscc_gym.sim.functional import observe

    state = loop.LoopState(x=st["x"], x_hat=st["x_hat"], p=st["p"], shadow=st["shadow"], n=st["n"],
                           ref=pool[st["mission"]], key=st["key"], queue=st["queue"])
    np.testing.assert_array_equal(obs.numpy(), observe(s, state, np.ones(5), np.zeros(5)))


def test_random_start_spreads_first_episodes_over_the_mission_and_later_ones_start_at_zero():
    from iscc_gym.sim import loop
    from iscc_gym.sim.functional import observe

    s = make_scenario("paper")
    n, limit = 64, 40
    d = DeviceVectorEnv(num_envs=n, device="cpu", pool_size=8, max_episode_steps=limit, random_start=True)
    obs, _ = d.reset(seed=2)
    pool, st = d._pool, d.host_state()
    assert (st["episode"] == 0).all() and 0 <= st["n"].min() and st["n"].max() < limit
    assert len(np.unique(st["n"])) > n // 3  # spread, not in step
    for row in (0, 7, 63):  # the documented draws: the start slot from the salted key, the drone near ref there
        k, j, _, shadow = _oracle_reset(s, pool, d._seed_key, row, 0)
        start = (_mix64(k ^ 0x2545F4914F6CDD1D) >> 11) % limit
        assert st["key"][row] == k and st["mission"][row] == j and st["n"][row] == start
        z = slot_normals(np.uint64(_mix64(k ^ 0x5851F42D4C957F2D)), 0, N_INIT_DRAWS)
        std0 = np.array([s.initial_pos_std_m] * 3 + [s.initial_vel_std_mps] * 3)
        np.testing.assert_allclose(st["x"][row], pool[j, start, :6] + std0 * z[:6], rtol=1e-12)
        np.testing.assert_allclose(st["x_hat"][row], pool[j, start, :6])
    state = loop.LoopState(x=st["x"], x_hat=st["x_hat"], p=st["p"], shadow=st["shadow"], n=st["n"],
                           ref=pool[st["mission"]], key=st["key"], queue=st["queue"])
    np.testing.assert_array_equal(obs.numpy(), observe(s, state, np.ones(n), np.zeros(n)))
    ends = np.zeros(n, np.int64)
    for step in range(limit):
        _, _, term, trunc, info = d.step(torch.zeros((n, 3)))
        done = (term | trunc).numpy()
        ends[done & (ends == 0)] = step + 1
    assert (ends == limit - st["n"]).all()  # each first episode truncated at the limit slot
    after = d.host_state()
    assert (after["episode"] == 1).all() and (after["n"] == limit - ends).all()  # the second ones from slot 0
    with pytest.raises(ValueError, match="random_start = 1; expected True or False"):
        DeviceVectorEnv(num_envs=2, device="cpu", random_start=1)


def test_same_seed_same_run_and_tensors_are_shared():
    runs = []
    for _ in range(2):
        d = DeviceVectorEnv(num_envs=4, device="cpu", pool_size=2, max_episode_steps=3)
        obs, _ = d.reset(seed=5)
        assert obs is d.obs
        g = torch.Generator().manual_seed(0)
        rewards = []
        for _ in range(7):
            o, r, *_ = d.step(torch.rand((4, 3), generator=g) * 2 - 1)
            assert o is d.obs and r is d.reward  # the env's buffers, no copies
            rewards.append(r.clone())
        runs.append(torch.stack(rewards))
    assert torch.equal(runs[0], runs[1])
    assert d.obs.numpy().base is not None  # a view the kernel writes through
    assert d.actions.dtype == torch.float32


def test_errors_name_the_field_and_leave_the_env_usable():
    with pytest.raises(ValueError, match="multi-drone"):
        DeviceVectorEnv("iscc_gym/ISCC-Multi-v0", num_envs=2, device="cpu")
    with pytest.raises(ValueError, match="device"):
        DeviceVectorEnv(num_envs=2, device="tpu")
    with pytest.raises(ValueError, match="num_envs"):
        DeviceVectorEnv(num_envs=0, device="cpu")
    with pytest.raises(ValueError, match="pool_size"):
        DeviceVectorEnv(num_envs=2, device="cpu", pool_size=1.5)
    d = DeviceVectorEnv(num_envs=2, device="cpu", pool_size=2)
    with pytest.raises(RuntimeError, match="reset"):
        d.step(torch.zeros((2, 3)))
    d.reset(seed=0)
    before = d.host_state()
    with pytest.raises(ValueError, match=r"rows \[1\]"):
        d.step(torch.tensor([[0.0, 0.0, 0.0], [float("nan"), 0.0, 0.0]]))
    with pytest.raises(ValueError, match="shape"):
        d.step(torch.zeros((3, 3)))
    with pytest.raises(TypeError, match="seed"):
        d.reset(seed=1.5)
    after = d.host_state()
    for k in before:
        np.testing.assert_array_equal(before[k], after[k])
    d.step(torch.zeros((2, 3)))


def test_cuda_without_a_gpu_says_so():
    from iscc_gym.gpu.cuda import cuda_available, simulator

    pytest.importorskip("numba.cuda")
    if cuda_available() or simulator():
        pytest.skip("this machine has a CUDA GPU (or runs the simulator)")
    with pytest.raises(RuntimeError, match="no CUDA GPU"):
        DeviceVectorEnv(num_envs=2, device="cuda")


def test_an_env_too_large_for_the_memory_is_refused_up_front_with_what_it_needs(monkeypatch):
    """Issue 43.10: ``DeviceVectorEnv(num_envs=10**8)`` allocated buffer after buffer and died on a MemoryError naming
    its last small array (or the OOM killer). Refused before any allocation, naming the memory and a count that fits;
    the estimate is of the buffers the env holds (checked against a small env's arrays)."""
    import torch

    from iscc_gym.gpu import vector_env

    allocated = []
    monkeypatch.setattr(torch, "zeros", lambda *a, **k: allocated.append(a) or pytest.fail("allocated"))
    with pytest.raises(ValueError, match=r"num_envs = 100,000,000 .*needs about \d+\.\d GiB; this machine has "
                                         r"\d+\.\d GiB free: use num_envs <= about [\d,]+"):
        DeviceVectorEnv("iscc_gym/ISCC-v0", num_envs=10**8, device="cpu")
    assert not allocated
    monkeypatch.undo()
    env = DeviceVectorEnv("iscc_gym/ISCC-Field-v0", num_envs=64, device="cpu", pool_size=8)
    env.reset(seed=0)
    held = sum(t.numel() * t.element_size() for t in (env.obs, env.reward, env.terminated, env.truncated,
                                                          env.final_return, env.final_length, env.metrics, env.actions,
                                                          env.final_obs))
    held += sum(a.nbytes for a in env._state.values()) + env._pool.nbytes
    estimate = vector_env.memory_bytes(env.scenario, 64, 8)
    assert held <= estimate <= 2.5 * held  # the host copies reset draws into are counted once more
