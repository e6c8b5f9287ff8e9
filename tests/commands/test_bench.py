"""The benchmark command in quick mode: every figure present, positive, with its reference. The two runs of the bench
(the quick bench and the PPO training subprocess) are ``slow``: the README's **Slow tests** command runs them."""

import json
from concurrent.futures import ThreadPoolExecutor

import pytest
from iscc_gym.eval import bench


@pytest.fixture(scope="module")
def ppo_figure():
    """The PPO figure of the train configuration (a training subprocess, ~10 s, one core), started in a thread at
    the module's start so that it runs beside the quick bench (in this process) on the second core: its future."""
    with ThreadPoolExecutor(1) as pool:
        yield pool.submit(bench.ppo_shipped_steps_per_second, 256, 1, settings=((1, 1),))


@pytest.mark.slow
def test_bench_quick_reports_every_figure(tmp_path, capsys, ppo_figure):
    path = tmp_path / "bench.json"
    res = bench.main(["--quick", "--steps", "50", "--repeats", "1", "--skip-ppo", "--json", str(path)])
    assert json.loads(path.read_text()) == json.loads(json.dumps(res))
    single = res["single_env"]
    assert single["iscc"]["median_steps_per_s"] > 0
    assert single["reference_pendulum_v1"]["median_steps_per_s"] > 0
    assert set(res["vector_env"]) == {"1", "64"}
    assert all(v["median_env_steps_per_s"] > 0 for v in res["vector_env"].values())
    assert res["eval_static_sca"]["slots"] == 40 and res["eval_static_sca"]["seconds"] > 0
    assert set(res["solvers"]) == {"sca", "grid", "evolutionary"}
    assert all(v["seconds"] > 0 and v["paper_s"] > v["seconds"] for v in res["solvers"].values())
    captured = capsys.readouterr()
    assert "Pendulum-v1 (reference)" in captured.out and "64 envs" in captured.out
    # issue 23: a line per stage on stderr, also without a terminal
    assert "[python -m eval.bench] 0/8 stage (single env)" in captured.err
    assert "[python -m eval.bench] done: 8/8 stage" in captured.err
    urban = res["urban"]  # the urban task's vector env beside the paper's, measured alike
    assert urban["ratio"] > 0 and urban["reset_ms_per_env"] > 0 and "Urban task's vector env" in captured.out
    assert captured.err.count("stage (render)") == 1  # one line a stage, none with a finished stage's name


def test_the_bench_study_needs_the_full_run_and_the_bench_writes_no_docs():
    from experiments.bench import main as bench_study

    with pytest.raises(ValueError, match="--full"):
        bench_study(["--write-docs"])
    with pytest.raises(ValueError, match="drop --device"):
        bench_study(["--full", "--device", "standin", "--write-docs"])
    assert "--write-docs" not in bench.build_parser().format_help()


@pytest.mark.slow
def test_ppo_figure_of_the_train_configuration(ppo_figure):
    """The PPO figure trains python -m train's own configuration (the YAML's env count) per thread setting."""
    from iscc_gym.train.config import Args, resolve_args

    res = ppo_figure.result(timeout=600)
    assert res["n_envs"] == resolve_args(Args())[0].n_envs
    v = res["settings"]["numba1_torch1"]
    assert v["median_env_steps_per_s"] > 0 and (v["numba_threads"], v["torch_threads"]) == (1, 1)


@pytest.mark.slow
def test_the_cold_compile_of_a_task_is_measured_in_a_new_process(capsys):
    """Issue 43.11: the compile note promised "about 10 s once"; its figures now come from python -m eval.bench
    --compile, which builds every kernel from an empty numba cache in a new process."""
    from iscc_gym.eval.bench import compile_times
    from iscc_gym.eval.bench_report import format_compile

    times = compile_times(["iscc_gym/ISCC-v0"])
    assert list(times) == ["import", "iscc_gym/ISCC-v0", "iscc_gym/ISCC-v0 (device stand-in)"]
    assert times["iscc_gym/ISCC-v0"] > 1.0  # compiled, not loaded from this machine's cache (a load is ~0.1 s)
    assert "total" in format_compile(times)
