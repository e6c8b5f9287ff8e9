"""Golden episodes: refactors must keep the env's behaviour bit for bit (issue 14).

Three seeded 5000-slot episodes of the single env under seeded random actions, and the vector env
with the same seeds. The digests recorded before the issue-14 refactor (equal to those of commit
69ce7bd) held through every refactor step; they were re-recorded once, on purpose, when the
``paper`` preset's ``sensing_snr_offset_db`` moved from 103.8 to 103.23 dB (issue 13: the PEB is
calibrated to Table II's 0.0635 m), a physics change, not a refactor. A change that moves the last
bit of any observation or reward changes a digest; if such a change is intended, say so, regenerate
every figure and table, and record the new digests here.

Bit for bit holds on one machine: the compiled kernels are built for the host CPU (numba compiles for its
instruction set, and numpy picks SIMD kernels by CPU), so a digest belongs to the processor it was recorded on
(:func:`platform_key`: architecture, CPU model, vector extensions). Issue 23: on a new machine (AMD EPYC, AVX2)
the code of c41e22e, whose golden test had passed on the earlier machine, gave other digests, the same with
numba 0.68.0/0.68.1, numpy 2.3.5/2.4.6, scipy 1.16.3/1.17.1 and gymnasium 1.3.0/1.4.0, while every generated
comparison table came out identical. ``tests/env/golden.json`` lists the recorded processors; one not in it is
skipped with a message, and ``python tests/env/test_golden.py --record`` adds it, run on the code whose behaviour
is the reference. A library release that moves a bit on a recorded processor fails the test, as it should.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import re
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import iscc_gym

GOLDEN = Path(__file__).with_name("golden.json")


def platform_key() -> str:
    """The processor a digest belongs to: architecture, CPU model and vector extensions."""
    cpu, flags = platform.processor() or platform.machine(), ""
    try:
        info = Path("/proc/cpuinfo").read_text()
        cpu = re.search(r"model name\s*:\s*(.*)", info).group(1).strip()
        flags = " ".join(sorted(f for f in re.search(r"flags\s*:\s*(.*)", info).group(1).split()
                                if f.startswith(("avx", "fma", "sse4", "f16c", "amx"))))
    except (OSError, AttributeError):
        pass
    if os.environ.get("ISCC_TEST_ULP_NUMPY") == "1":  # tests/ulp_numpy.py: numpy as on another processor
        flags += " | numpy one ulp off"
    return f"{platform.machine()} | {cpu} | {flags}"


def single_digest() -> str:
    h = hashlib.sha256()
    for seed in (0, 1, 2):
        env = gym.make(iscc_gym.ENV_ID)
        obs, _ = env.reset(seed=seed)
        rng = np.random.default_rng(100 + seed)
        h.update(obs.tobytes())
        for _ in range(5000):
            obs, reward, terminated, truncated, _ = env.step(rng.uniform(-1, 1, 3).astype(np.float32))
            h.update(obs.tobytes())
            h.update(np.float64(reward).tobytes())
            if terminated or truncated:
                break
    return h.hexdigest()


def vector_digest() -> str:
    venv = gym.make_vec(iscc_gym.ENV_ID, num_envs=3, vectorization_mode="vector_entry_point")
    obs, _ = venv.reset(seed=[0, 1, 2])
    h = hashlib.sha256(obs.tobytes())
    rng = np.random.default_rng(7)
    for _ in range(5000):
        obs, reward, _, _, _ = venv.step(rng.uniform(-1, 1, (3, 3)).astype(np.float32))
        h.update(obs.tobytes())
        h.update(np.asarray(reward, np.float64).tobytes())
    return h.hexdigest()


def _recorded() -> dict:
    entry = json.loads(GOLDEN.read_text())["platforms"].get(platform_key())
    if entry is None:
        pytest.skip(f"no golden digests recorded for this platform ({platform_key()}); record them on the reference "
                    "code with `python tests/env/test_golden.py --record`")
    return entry


def test_single_env_episodes_are_bit_for_bit_the_recorded_ones():
    assert single_digest() == _recorded()["single"]


def test_vector_env_episodes_are_bit_for_bit_the_recorded_ones():
    assert vector_digest() == _recorded()["vector"]


def test_this_machine_has_recorded_digests_or_says_how_to_record_them():
    """The recorded platforms are well formed; the first one is the digests of issues 13-14 (platform unknown)."""
    platforms = json.loads(GOLDEN.read_text())["platforms"]
    assert platforms and all(set(v) >= {"single", "vector", "commit"} for v in platforms.values())
    assert all(re.fullmatch(r"[0-9a-f]{64}", v[k]) for v in platforms.values() for k in ("single", "vector"))


if __name__ == "__main__":
    if sys.argv[1:] != ["--record"]:
        raise SystemExit("usage: python tests/env/test_golden.py --record  (adds this platform's digests to "
                         "golden.json)")
    import subprocess

    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=GOLDEN.parent).stdout.strip()
    data = json.loads(GOLDEN.read_text())
    data["platforms"][platform_key()] = {"single": single_digest(), "vector": vector_digest(), "commit": commit}
    tmp = GOLDEN.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(data, indent=1) + "\n")
    tmp.replace(GOLDEN)
    print(f"recorded {platform_key()} -> {GOLDEN}")
