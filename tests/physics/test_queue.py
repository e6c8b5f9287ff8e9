"""Tests of iscc_gym.physics.queue: bit conservation every slot, FIFO service, the deadline, arrivals."""

from __future__ import annotations

import math

import numpy as np
import pytest

from iscc_gym.physics import queue as qu


def test_conservation_every_slot_on_random_sequences():
    rng = np.random.default_rng(0)
    for d in (1, 3, 10):
        q = np.zeros((16, d))
        for _ in range(200):
            arr = rng.exponential(5.0, 16) * (rng.random(16) < 0.7)
            cap = rng.exponential(4.0, 16) * (rng.random(16) < 0.8)
            q_next, served, dropped = qu.queue_step(q, arr, cap)
            np.testing.assert_allclose(arr, served + dropped + q_next.sum(1) - q.sum(1), atol=1e-9)
            assert np.all(served >= 0) and np.all(dropped >= 0) and np.all(q_next >= 0)
            assert np.all(served <= np.maximum(cap, 0) + 1e-12)
            q = q_next


@pytest.mark.parametrize("d", [1, 4, 10])
def test_deadline_gives_every_bit_d_chances(d):
    """Without service, a burst arriving in slot 0 is dropped at the end of slot d-1, whole."""
    q = np.zeros((1, d))
    drops = []
    for n in range(d + 3):
        q, _, dropped = qu.queue_step(q, 100.0 if n == 0 else 0.0, 0.0)
        drops.append(dropped[0])
    assert drops[d - 1] == 100.0 and sum(drops) == 100.0


def test_fifo_serves_the_oldest_first():
    q = np.zeros((1, 4))
    q, s, x = qu.queue_step(q, 10.0, 0.0)   # 10 bits of age 1 now
    q, s, x = qu.queue_step(q, 20.0, 0.0)   # 20 of age 1, 10 of age 2
    assert q[0].tolist() == [0.0, 20.0, 10.0, 0.0]
    q, s, x = qu.queue_step(q, 5.0, 12.0)   # serves the 10 old bits first, then 2 of the 20
    assert s[0] == 12.0 and x[0] == 0.0
    assert q[0].tolist() == [0.0, 5.0, 18.0, 0.0]
    assert qu.oldest_age_one(q[0]) == 2.0 and qu.oldest_age_one(np.zeros(4)) == 0.0


def test_queue_step_leaves_its_input_alone():
    q = np.array([[1.0, 2.0, 3.0]])
    qu.queue_step(q, 1.0, 1.0)
    assert q.tolist() == [[1.0, 2.0, 3.0]]


def assert_compiled_arrivals_match_numpy(a, a_numpy):
    """The compiled arrivals (``math.exp``: libm's) against numpy's formula, to rounding: on a CPU with AVX-512
    numpy's exp is its own SIMD code, which can differ from libm's in the last bit (issue 34)."""
    np.testing.assert_allclose(a, a_numpy, rtol=1e-13, atol=0)


@pytest.mark.parametrize("cv", [0.0, 0.5, 1.5])
def test_arrivals_have_the_stated_mean_and_burstiness(cv):
    z = np.random.default_rng(2).standard_normal(400_000)
    sig = qu.arrival_sigma(cv)
    a = np.array([qu.arrival_bits_one(1000.0, sig, v) for v in z[:2000]])
    a_all = 1000.0 * np.exp(sig * z - 0.5 * sig * sig)
    assert_compiled_arrivals_match_numpy(a, a_all[:2000])
    assert a_all.mean() == pytest.approx(1000.0, rel=0.02 * max(cv, 0.1))
    assert a_all.std() / a_all.mean() == pytest.approx(cv, abs=0.05 * max(cv, 0.1) + 1e-12)
    with pytest.raises(ValueError, match="queue_arrival_cv"):
        qu.arrival_sigma(-1.0)
    assert math.isfinite(sig)


def test_compiled_arrivals_match_a_numpy_whose_exp_is_one_ulp_off(monkeypatch):
    """Issue 34: on an AVX-512 CPU the arrivals test failed (``412.4911876905254 != 412.49118769052535``) because
    it wanted numba's exp bit-equal to numpy's; here numpy's exp is one ulp off libm's, as there
    (tests/ulp_numpy.py), and the comparison still holds."""
    from ulp_numpy import UlpUfunc

    monkeypatch.setattr(np, "exp", UlpUfunc(np.exp))
    z = np.random.default_rng(2).standard_normal(200)
    sig = qu.arrival_sigma(1.5)
    a = np.array([qu.arrival_bits_one(1000.0, sig, v) for v in z])
    a_numpy = 1000.0 * np.exp(sig * z - 0.5 * sig * sig)
    assert not np.array_equal(a, a_numpy)  # the emulated CPU's numpy differs in the last bit
    assert_compiled_arrivals_match_numpy(a, a_numpy)
