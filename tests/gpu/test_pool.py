"""The device env's mission pool (:mod:`iscc_gym.sim.pool`): the CPU vector env's missions, the same drawn over
worker processes, cached per (scenario, seed, size), never written through."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium.utils import seeding

from iscc_gym.scenario import make_scenario
from iscc_gym.sim import loop
from iscc_gym.sim.pool import PARALLEL_MIN_POOL, clear_pool_cache, mission_pool, pool_workers


def test_the_pool_is_the_vector_envs_missions_in_any_number_of_processes():
    s = make_scenario("field")
    clear_pool_cache()
    serial = mission_pool(s, 5, 3, workers=1)
    for j in range(3):  # sub-env j of a vector env reset with seed 5 draws from np_random(5 + j)
        one = loop.init_mission(s, seeding.np_random(5 + j)[0])
        for a, b in zip(serial, one, strict=True):
            np.testing.assert_array_equal(a[j], b[0])
    clear_pool_cache()
    parallel = mission_pool(s, 5, 3, workers=2)  # two spawned processes: 2 missions and 1
    assert parallel is not serial
    for a, b in zip(parallel, serial, strict=True):
        np.testing.assert_array_equal(a, b)
    assert mission_pool(s, 5, 3) is parallel  # cached: the same arrays
    assert np.shares_memory(mission_pool(s, 5, 2).ref, parallel.ref)  # a smaller pool: the prefix
    grown = mission_pool(s, 5, 4, workers=1)  # a larger one: the missing mission drawn
    np.testing.assert_array_equal(grown.ref[:3], parallel.ref)
    np.testing.assert_array_equal(grown.ref[3], loop.init_mission(s, seeding.np_random(8)[0]).ref[0])
    assert mission_pool(s, 6, 3, workers=1) is not grown  # another seed, another pool
    with pytest.raises(ValueError, match="assignment destination is read-only"):
        grown.ref[0, 0, 0] = 1.0


def test_pool_workers_defaults_and_errors(monkeypatch):
    monkeypatch.delenv("ISCC_GYM_POOL_WORKERS", raising=False)
    assert pool_workers(PARALLEL_MIN_POOL - 1) == 1  # small pools: drawn here
    assert pool_workers(10, workers=4) == 4 and pool_workers(3, workers=8) == 3
    monkeypatch.setenv("ISCC_GYM_POOL_WORKERS", "1")
    assert pool_workers(100 * PARALLEL_MIN_POOL) == 1
    monkeypatch.setenv("ISCC_GYM_POOL_WORKERS", "many")
    with pytest.raises(ValueError, match="ISCC_GYM_POOL_WORKERS='many'"):
        pool_workers(1000)
    with pytest.raises(ValueError, match="workers = 0"):
        pool_workers(10, workers=0)
