"""The device kernels without a GPU: run in numba-cuda's simulator on tiny batches (equal to the CPU stand-in, the
same row functions, and so to the CPU vector env), and compiled to PTX for an H100 (sm_90) where the CUDA toolkit is
here, with no device-heap allocation."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest

pytest.importorskip("numba_cuda", reason="numba-cuda is not installed (the gpu or test extra installs it)")

_SIM = textwrap.dedent("""
    import json, sys
    import numpy as np, torch
    from iscc_gym.gpu.vector_env import DeviceVectorEnv
    env_id = sys.argv[1]
    out = {}
    envs = {dev: DeviceVectorEnv(env_id, num_envs=4, device=dev, pool_size=2, max_episode_steps=3)
            for dev in ("cuda", "cpu")}
    obs = {dev: e.reset(seed=7)[0].numpy().copy() for dev, e in envs.items()}
    out["reset"] = float(np.abs(obs["cuda"] - obs["cpu"]).max())
    g = np.random.default_rng(1)
    worst = {"reward": 0.0, "obs": 0.0, "metrics": 0.0, "done": 0}
    for k in range(5):
        a = torch.from_numpy(g.uniform(-1, 1, (4, 3)).astype(np.float32))
        res = {dev: e.step(a) for dev, e in envs.items()}
        (o1, r1, t1, u1, i1), (o2, r2, t2, u2, i2) = res["cuda"], res["cpu"]
        worst["obs"] = max(worst["obs"], float(np.abs(o1.numpy() - o2.numpy()).max()))
        m1, m2 = i1["metrics"].numpy(), i2["metrics"].numpy()
        worst["metrics"] = max(worst["metrics"], float(np.nanmax(np.abs(m1 - m2) / (1e-12 + np.abs(m2)))))
        worst["done"] += int((t1.numpy() != t2.numpy()).sum() + (u1.numpy() != u2.numpy()).sum())
    out.update(worst)
    out["sim"] = envs["cuda"]._sim
    out["episodes"] = envs["cuda"].host_state()["episode"].tolist()
    print(json.dumps(out))
""")


@pytest.mark.parametrize("env_id", ["iscc_gym/ISCC-v0",
                                    pytest.param("iscc_gym/ISCC-Urban-v0", marks=pytest.mark.slow)])
def test_the_kernels_in_the_simulator_equal_the_cpu_stand_in(env_id, tmp_path):
    env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1"}
    r = subprocess.run([sys.executable, "-c", _SIM, env_id], env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    res = json.loads(r.stdout.strip().splitlines()[-1])
    assert res["sim"] is True
    assert res["reset"] == 0.0 and res["done"] == 0
    assert res["metrics"] < 1e-9 and res["obs"] < 1e-6
    assert res["episodes"] == [1, 1, 1, 1]  # every row autoreset on the device once (3-slot episodes, 5 steps)


def _ptx(env_id, which="step"):
    from iscc_gym.gpu.cuda import toolkit_for_ptx

    why = toolkit_for_ptx()
    if why is not None:
        pytest.skip(f"no PTX compile here: {why}")
    import numpy as np

    from iscc_gym.gpu import kernel
    from iscc_gym.gpu.vector_env import DeviceVectorEnv

    d = DeviceVectorEnv(env_id, num_envs=2, device="cpu", pool_size=2)
    d.reset(seed=0)
    # the signatures the env launches: its own arguments (types as on the GPU: C-contiguous arrays, uint64, int64)
    args = d.kernel_args() if which == "step" else d.reset_args(np.zeros(1, np.int64))
    return kernel.kernel_ptx(which, args, d.switches, queue_slots=d._nq, cc=(9, 0))


@pytest.mark.slow  # 10-17 s a task (NVVM compiles the whole inlined step): the README's slow run, in CI
@pytest.mark.parametrize("which", ["step", "reset"])
@pytest.mark.parametrize("env_id", ["iscc_gym/ISCC-v0", "iscc_gym/ISCC-Urban-v0", "iscc_gym/ISCC-Field-v0"])
def test_the_kernels_compile_to_ptx_for_sm_90_within_their_stated_limits(env_id, which):
    """No device heap (the scratch is per-thread local memory), the parameter record read in 8-byte words (an aligned
    record: no byte-wise loads), and ``ptxas -v``'s registers, stack and spills within
    :data:`iscc_gym.gpu.kernel.PTX_LIMITS`."""
    from iscc_gym.gpu.kernel import PTX_LIMITS, ptxas_usage

    ptx = _ptx(env_id, which)
    assert ".target sm_90" in ptx
    assert ".entry" in ptx
    low = ptx.lower()
    assert "malloc" not in low and "nrt_" not in low
    assert "ld.global.u8" not in ptx  # an unaligned record is loaded a byte at a time
    usage = ptxas_usage(ptx)
    for name, limit in PTX_LIMITS[which].items():
        assert usage[name] <= limit, (name, usage)


def test_the_queue_s_local_array_is_sized_per_task():
    """The paper task has no queue: its kernels are built without the queue's 64 local slots (a key of their own);
    a queue longer than the kernel can hold is refused."""
    from iscc_gym.gpu import kernel
    from iscc_gym.gpu.vector_env import DeviceVectorEnv

    pytest.importorskip("numba_cuda")
    assert DeviceVectorEnv("iscc_gym/ISCC-v0", num_envs=1, device="cpu")._nq == 0
    assert DeviceVectorEnv("iscc_gym/ISCC-Urban-v0", num_envs=1, device="cpu")._nq > 0
    with pytest.raises(ValueError, match="queue_slots = 65"):
        kernel.cuda_kernels(queue_slots=kernel.MAX_QUEUE_SLOTS + 1)


def test_import_cuda_restores_numpys_row_stack(monkeypatch):
    import numpy as np

    from iscc_gym.gpu.cuda import import_cuda

    monkeypatch.delattr(np, "row_stack", raising=False)  # as NumPy >= 2.5
    import_cuda()
    assert getattr(np, "row_stack") is np.vstack  # noqa: B009 (getattr: ruff's NPY201 would rewrite the name)
