"""Issue 44, point 2: a task added in one file of its own (:mod:`tests.env.toy_task`: a new env id on the
``paper`` preset with one parameter changed, registered at run time through ``--gym-packages``) is played by
``python -m eval``, trained for a tiny budget by ``python -m train``, tuned by ``python -m eval.tune``, and listed
by the benches and the docs site, with no other edit."""

import importlib
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import pytest
import yaml

from iscc_gym.scenario import SCENARIOS
from iscc_gym.tasks import TASKS

ROOT = Path(__file__).resolve().parents[2]
MODULE = "tests.env.toy_task"
TOY = "toy/ISCC-Toy-v0"


@pytest.fixture
def toy():
    """The toy task's module imported by a command's ``--gym-packages``; the registries restored afterwards."""
    sys.modules.pop(MODULE, None)
    yield ["--gym-packages", MODULE]
    TASKS.pop(TOY, None)
    gym.registry.pop(TOY, None)
    SCENARIOS.pop("toy", None)
    sys.modules.pop(MODULE, None)


def test_the_toy_task_is_its_own_preset_and_env_id(toy):
    module = importlib.import_module(MODULE)
    task = module.TASK
    assert TASKS[TOY] is task and SCENARIOS["toy"] == task.scenario
    assert task.scenario.n_slots == 100 and SCENARIOS["paper"].n_slots == 5000  # the paper's preset untouched
    assert gym.spec(TOY).max_episode_steps == 100 and gym.spec(TOY).kwargs == {"scenario": "toy"}
    env = gym.make(TOY)
    assert env.unwrapped.scenario == task.scenario


def test_python_m_eval_plays_the_toy_task(toy):
    from iscc_gym.eval.__main__ import main as eval_main

    res = eval_main([*toy, "--env", TOY, "--episodes", "2", "--workers", "1"])
    assert list(res["policies"]) == ["myopic", "margin", "equal"] and res["reference"] == "myopic"
    assert list(res["policies"]["myopic"]["episodes"]["length"]) == [100, 100]


def test_python_m_train_trains_the_toy_task_with_the_entry_it_names(toy, tmp_path):
    from iscc_gym.train.cli import cli

    out = tmp_path / "run"
    summary = cli([*toy, "--env", TOY, "--total-timesteps", "128", "--n-envs", "2", "--eval-freq", "0",
                   "--checkpoint-freq", "0", "--no-tensorboard", "--quiet", "--out", str(out)])
    assert summary["timesteps"] >= 128 and (out / "model.zip").is_file()
    config = yaml.safe_load((out / "config.yml").read_text())
    assert config["args"]["env_id"] == TOY and config["args"]["scenario"] == "toy"
    assert config["hyperparams"]["gamma"] == 0.3  # the paper task's entry (train_like), no YAML edit


def test_python_m_eval_tune_tunes_a_baseline_on_the_toy_missions(toy, tmp_path):
    from iscc_gym.eval.tune import main as tune_main

    path = tmp_path / "margin-toy.yml"
    record = tune_main(["margin", *toy, "--scenario", "toy", "--episodes", "2", "--no-refine", "--quiet",
                        "--out", str(path)])
    assert record["scenario"] == "toy" and yaml.safe_load(path.read_text())["params"] == record["params"]


def test_the_benches_and_the_docs_list_the_toy_task(toy):
    from iscc_gym.eval.bench import bench_env_ids
    from iscc_gym.eval.bench_device import device_env_ids

    sys.path.insert(0, str(ROOT / "docs" / "site" / "_ext"))
    try:
        import iscc_site
    finally:
        sys.path.remove(str(ROOT / "docs" / "site" / "_ext"))
    assert TOY not in bench_env_ids()
    importlib.import_module(MODULE)
    assert TOY in bench_env_ids() and TOY in device_env_ids()
    rows = iscc_site.task_rows(TOY)
    assert ["task", TASKS[TOY].title] in rows
    index = iscc_site.task_index_rows()
    assert [r[0] for r in index] == list(TASKS) and [TOY, TASKS[TOY].title, "toy", "tasks/paper"] in index


@pytest.mark.slow
def test_the_installed_command_line_plays_the_toy_task_from_its_module():
    r = subprocess.run([sys.executable, "-m", "eval", "--gym-packages", MODULE, "--env", TOY, "--episodes", "1",
                        "--workers", "1", "--policies", "myopic,equal"], cwd=ROOT, capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr
    assert "equal" in r.stdout
    r = subprocess.run([sys.executable, "-m", "eval", "--gym-packages", "no_such_tasks", "--env", TOY],
                       cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 2 and "--gym-packages no_such_tasks: no module named 'no_such_tasks'" in r.stderr
