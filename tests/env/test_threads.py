"""iscc_gym.threads: the serial kernel by default, the parallel one on request, the same results either way."""

import importlib

import gymnasium as gym
import numba
import numpy as np
import pytest

import iscc_gym
from iscc_gym import threads
from iscc_gym.sim import kernel


def _rollout(n_envs, steps=12, seed=3):
    venv = gym.make_vec(iscc_gym.ENV_ID, num_envs=n_envs, vectorization_mode="vector_entry_point")
    obs, _ = venv.reset(seed=seed)
    actions = np.random.default_rng(seed).uniform(-1, 1, (steps, n_envs, 3)).astype(np.float32)
    out = [obs]
    for a in actions:
        obs, reward, term, trunc, _ = venv.step(a)
        out += [obs, reward, term, trunc]
    venv.close()
    return out


def test_default_is_serial_and_the_parallel_kernel_is_not_called(monkeypatch):
    assert threads.get_parallel() is False
    assert not threads.use_parallel(4096, 2)

    def boom(*args):
        raise AssertionError("the parallel kernel ran although it is off")

    monkeypatch.setattr(kernel, "env_step_batch_parallel", boom)
    _rollout(threads.PARALLEL_MIN_BATCH + 5, steps=2)


@pytest.mark.skipif(numba.get_num_threads() < 2, reason="one numba thread: the parallel kernel is never used")
def test_parallel_kernel_on_request_gives_the_same_results_bit_for_bit(monkeypatch):
    n = threads.PARALLEL_MIN_BATCH + 7
    serial = _rollout(n)
    calls = []
    original = kernel.env_step_batch_parallel
    monkeypatch.setattr(kernel, "env_step_batch_parallel", lambda *a: calls.append(1) or original(*a))
    threads.set_parallel(True)
    try:
        assert threads.use_parallel(n, 2) and not threads.use_parallel(threads.PARALLEL_MIN_BATCH - 1, 2)
        parallel = _rollout(n)
    finally:
        threads.set_parallel(False)
    assert calls, "the parallel kernel was not used"
    for a, b in zip(serial, parallel, strict=True):
        np.testing.assert_array_equal(a, b)


def test_bad_settings_are_refused_with_the_fix(monkeypatch):
    with pytest.raises(TypeError, match="True or False"):
        threads.set_parallel("yes")
    # ISCC_GYM_PARALLEL is read when iscc_gym.threads is imported (iscc_gym imports it): the module is run
    # again here under each value rather than importing iscc_gym in a new process (~4 s each, more under load)
    before = threads.get_parallel()
    try:
        monkeypatch.setenv("ISCC_GYM_PARALLEL", "sometimes")
        with pytest.raises(ValueError, match=r"ISCC_GYM_PARALLEL='sometimes'; use 1"):
            importlib.reload(threads)
        monkeypatch.setenv("ISCC_GYM_PARALLEL", "1")
        importlib.reload(threads)
        assert threads.get_parallel() is True
        monkeypatch.setenv("ISCC_GYM_PARALLEL", "0")
        importlib.reload(threads)
        assert threads.get_parallel() is False
    finally:
        monkeypatch.delenv("ISCC_GYM_PARALLEL", raising=False)
        importlib.reload(threads)
        threads.set_parallel(before)
