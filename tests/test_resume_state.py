"""Issue 23 item 6 (defects 1-6): a checkpoint holds everything a resume needs (learning curve and wall
time, multipliers and their history, best score, evaluation schedule), best/ is replaced as a unit, and a
resume with other constraints is refused. Kills are simulated by raising inside a callback or a save; tiny
runs (256-512 steps on 2 envs)."""

import csv
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from iscc_gym.agents.sb3_policy import SB3Policy, read_manifest, write_manifest
from iscc_gym.train import main
from iscc_gym.train import train as T
from iscc_gym.train.lagrangian import load_lagrange
from iscc_gym.train.runs import RESUME_FILE, recover_unit, replace_unit
from stable_baselines3 import PPO
from stable_baselines3.common import evaluation
from stable_baselines3.common.callbacks import BaseCallback
from tiny_runs import TINY
from tiny_runs import tiny_args as _args

LAG = {"cost_limit": "rate=0.05,stability=0.0", "lagrange_lr": 0.5}


class Killed(BaseException):
    """A kill (not an Exception: nothing in train may catch it)."""


def _kill_at(step):
    class KillAt(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps >= step:
                raise Killed(step)
            return True

    return KillAt()


def _killed_run(monkeypatch, out, step, **kw):
    """A run killed at ``step`` (a callback raises after the others ran at that step)."""
    monkeypatch.setattr(T, "_steps_callback", lambda say, total: _kill_at(step))
    with pytest.raises(Killed):
        main(_args(out, **kw))
    monkeypatch.undo()


def _rows(out):
    with open(Path(out) / "learning_curve.csv", newline="") as f:
        return [r for r in csv.DictReader(f) if r["wall_s"]]


def _rewrite(unit: Path, name: str, edit):
    """Change a file of a unit and write its manifest anew (a damaged file the manifest cannot catch)."""
    if name.endswith(".yml"):
        doc = yaml.safe_load((unit / name).read_text())
        (unit / name).write_text(yaml.safe_dump(edit(doc)))
    else:
        edit(unit / name)
    m = yaml.safe_load((unit / "manifest.yml").read_text())
    files = list(m.pop("files"))
    write_manifest(unit, files, **m)


@pytest.fixture(scope="module")
def lag_256(tmp_path_factory):
    """A finished constrained run: checkpoints at 128 and 256, multipliers updated at 128 and 256."""
    out = tmp_path_factory.mktemp("lag") / "run"
    main(_args(out, quiet=True, **LAG))
    return out


@pytest.fixture(scope="module")
def run_256(tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "run"
    main(_args(out, quiet=True))
    return out


def _copy(run, tmp_path) -> Path:
    dst = tmp_path / "run"
    shutil.copytree(run, dst)
    return dst


# --- 1. the learning curve -------------------------------------------------------------------------------

def test_resume_keeps_learning_curve(tmp_path, monkeypatch):
    """Killed at step 320 (checkpoint 256): learning_curve.csv is already on disk, and the resumed run keeps
    its rows and goes on with the wall time (it was written only at the end, and restarted at 0)."""
    out = tmp_path / "run"
    _killed_run(monkeypatch, out, 320, total_timesteps=512)
    before = _rows(out)
    assert [int(r["timesteps"]) for r in before] == [128, 256]
    assert all(r["eval_reward_mean"] for r in before)  # the evaluations at 128 and 256 beside them
    main(_args(out, total_timesteps=512, resume=True, quiet=True))
    rows = _rows(out)
    assert [int(r["timesteps"]) for r in rows] == [128, 256, 384, 512]
    assert rows[:2] == before
    walls = [float(r["wall_s"]) for r in rows]
    assert walls == sorted(walls) and walls[2] > walls[1]
    state = yaml.safe_load((out / "checkpoints" / "step_512" / RESUME_FILE).read_text())
    assert [r["timesteps"] for r in state["curve"]] == [128, 256, 384, 512] and state["wall_s"] >= walls[-1]


# --- 2. and 3. the multipliers ------------------------------------------------------------------------------

def test_resume_of_a_finished_run_keeps_the_multipliers_history(lag_256, tmp_path):
    out = _copy(lag_256, tmp_path)
    before = load_lagrange(out)["history"]
    assert [h["timesteps"] for h in before] == [128, 256]
    main(_args(out, total_timesteps=512, resume=True, quiet=True, **LAG))
    after = load_lagrange(out)["history"]
    assert [h["timesteps"] for h in after] == [128, 256, 384, 512] and after[:2] == before


def test_resume_takes_the_multipliers_from_the_checkpoint(lag_256, tmp_path):
    """Without lagrange.yml the multipliers still come back (from the checkpoint), not 0."""
    out = _copy(lag_256, tmp_path)
    saved = yaml.safe_load((out / "checkpoints" / "step_256" / RESUME_FILE).read_text())["lagrange"]
    assert saved["lambdas"]["rate"] > 0.0 and [h["timesteps"] for h in saved["history"]] == [128, 256]
    (out / "lagrange.yml").unlink()
    summary = main(_args(out, total_timesteps=256, resume=True, quiet=True, **LAG))
    assert summary["lagrange"]["lambdas"] == saved["lambdas"]
    assert load_lagrange(out)["history"] == saved["history"]


@pytest.mark.parametrize("value, message", [
    (-1.0, r"lambdas\.rate = -1\.0; a multiplier file holds finite numbers >= 0"),
    (float("nan"), r"lambdas\.rate = nan"),
    ("abc", r"lambdas\.rate = 'abc'"),
])
def test_invalid_multipliers_in_the_checkpoint_are_refused(lag_256, tmp_path, value, message):
    out = _copy(lag_256, tmp_path)

    def edit(doc):
        doc["lagrange"]["lambdas"]["rate"] = value
        return doc

    _rewrite(out / "checkpoints" / "step_256", RESUME_FILE, edit)
    with pytest.raises(ValueError, match=r"step_256/resume\.yml: lagrange: " + message):
        main(_args(out, total_timesteps=384, resume=True, quiet=True, **LAG))


@pytest.mark.parametrize("text, message", [
    ("lambdas: {rate: -0.5}\n", r"lagrange\.yml: lambdas\.rate = -0\.5; .* >= 0"),
    ("lambdas: {rate: .nan}\n", r"lagrange\.yml: lambdas\.rate = nan"),
    ("lambdas: [rate\n", r"lagrange\.yml: not valid YAML"),
    ("- 1\n", r"lagrange\.yml: not a multipliers record"),
])
def test_invalid_lagrange_yml_is_refused_naming_the_file_and_field(tmp_path, text, message):
    (tmp_path / "lagrange.yml").write_text(text)
    with pytest.raises(ValueError, match=message):
        load_lagrange(tmp_path)


def test_a_checkpoint_without_multipliers_and_no_lagrange_yml_is_refused(lag_256, tmp_path):
    """A checkpoint of an older python -m train (no resume.yml) of a constrained run: without lagrange.yml the
    multipliers would silently restart at 0."""
    out = _copy(lag_256, tmp_path)
    for step in (128, 256):
        unit = out / "checkpoints" / f"step_{step}"
        (unit / RESUME_FILE).unlink()
        m = yaml.safe_load((unit / "manifest.yml").read_text())
        files = [f for f in m.pop("files") if f != RESUME_FILE]
        write_manifest(unit, files, **m)
    (out / "lagrange.yml").unlink()
    with pytest.raises(FileNotFoundError, match=r"lagrange\.yml is missing .* would restart at 0"):
        main(_args(out, total_timesteps=384, resume=True, quiet=True, **LAG))


# --- 4. the constraints are part of the run -------------------------------------------------------------

@pytest.mark.parametrize("change, message", [
    ({"cost_limit": "rate=0.1,stability=0.0"},
     r"cost_limit \{'rate': 0\.05, 'stability': 0\.0\} -> \{'rate': 0\.1, 'stability': 0\.0\}"),
    ({"cost_limit": "rate=0.05"}, r"cost_limit \{'rate': 0\.05, 'stability': 0\.0\} -> \{'rate': 0\.05\}"),
    ({"cost_limit": None, "env_overrides": {"w_rate": 0.0, "w_stab": 0.0}},
     r"cost_limit \{'rate': 0\.05, 'stability': 0\.0\} -> None"),
    ({"lagrange_lr": 0.1}, r"lagrange_lr 0\.5 -> 0\.1"),
])
def test_resume_refuses_changed_constraints(lag_256, tmp_path, change, message):
    out = _copy(lag_256, tmp_path)
    with pytest.raises(ValueError, match=r"resume: .* was trained with other settings \(.*" + message):
        main(_args(out, total_timesteps=384, resume=True, quiet=True, **{**LAG, **change}))


def test_resume_refuses_constraints_added_to_a_plain_run(run_256, tmp_path):
    out = _copy(run_256, tmp_path)
    with pytest.raises(ValueError, match=r"cost_limit None -> \{'rate': 0\.05, 'stability': 0\.0\}"):
        main(_args(out, total_timesteps=384, resume=True, quiet=True, **LAG))


# --- 5. the best model ------------------------------------------------------------------------------------

def _scores(monkeypatch, means):
    """evaluate_policy returning the given mean rewards in turn (two episodes each)."""
    it = iter(means)

    def fake(model, env, n_eval_episodes=2, **kw):
        m = next(it)
        return [m] * n_eval_episodes, [50] * n_eval_episodes

    monkeypatch.setattr(evaluation, "evaluate_policy", fake)


def test_a_kill_during_a_best_model_save_keeps_the_previous_best_and_its_score(tmp_path, monkeypatch):
    """Held-out rewards -100 (step 128) then -50 (step 256): the kill comes while best/ is being replaced.
    The previous best stays whole (it was overwritten file by file), and the resumed run keeps its score
    (it was reset to -inf): a worse evaluation (-200) does not replace it."""
    out = tmp_path / "run"
    _scores(monkeypatch, [-100.0, -50.0])
    real_save, calls = PPO.save, []

    def save(self, path, *a, **kw):
        if "best_model" in Path(path).name:
            calls.append(path)
            if len(calls) == 2:
                Path(path).write_bytes(b"PK\x03\x04 half a zip")
                raise Killed("during the best model's save")
        return real_save(self, path, *a, **kw)

    monkeypatch.setattr(PPO, "save", save)
    with pytest.raises(Killed):
        main(_args(out, total_timesteps=512, quiet=True))
    monkeypatch.undo()
    manifest = read_manifest(out / "best")
    assert (manifest["timesteps"], manifest["mean_reward"]) == (128, -100.0)
    assert SB3Policy.load(out, best=True).vecnormalize is not None
    assert not [p.name for p in out.iterdir() if p.name.startswith(".best")]  # no half-written unit left
    _scores(monkeypatch, [-200.0] * 3)
    summary = main(_args(out, total_timesteps=512, resume=True, quiet=True))
    assert [t for t, _ in summary["evaluations"]] == [128, 256, 384, 512]
    assert summary["best"] == {"mean_reward": -100.0, "timesteps": 128}
    assert read_manifest(out / "best")["timesteps"] == 128


def test_a_kill_between_the_renames_of_a_best_save_is_recovered(tmp_path):
    class Model:
        def __init__(self, tag):
            self.tag = tag

        def save(self, path):
            Path(path).write_bytes(self.tag)

    best = tmp_path / "best"
    replace_unit(best, Model(b"old"), model_name="best_model.zip", timesteps=128, mean_reward=-100.0)
    replace_unit(best, Model(b"new"), model_name="best_model.zip", timesteps=256, mean_reward=-50.0)
    assert (best / "best_model.zip").read_bytes() == b"new" and len(list(tmp_path.iterdir())) == 1
    # the kill: the old unit moved aside, the new one complete but not yet renamed into place
    replace_unit(tmp_path / "new", Model(b"newer"), model_name="best_model.zip", timesteps=384, mean_reward=-10.0)
    best.rename(tmp_path / ".best.1.a.old")
    (tmp_path / "new").rename(tmp_path / ".best.1.a.tmp")
    note = recover_unit(best)
    assert "restored from .best.1.a.tmp" in note
    assert read_manifest(best)["timesteps"] == 384 and [p.name for p in tmp_path.iterdir()] == ["best"]


# --- 6. the evaluation schedule -----------------------------------------------------------------------------

def test_an_evaluation_cut_off_by_a_kill_is_redone_on_resume(tmp_path, monkeypatch):
    out = tmp_path / "run"
    real, calls = evaluation.evaluate_policy, []

    def evaluate(*a, **kw):
        calls.append(1)
        if len(calls) == 2:
            raise Killed("during the evaluation at step 256")
        return real(*a, **kw)

    monkeypatch.setattr(evaluation, "evaluate_policy", evaluate)
    with pytest.raises(Killed):
        main(_args(out, total_timesteps=384, quiet=True))
    monkeypatch.undo()
    with np.load(out / "eval" / "evaluations.npz") as d:
        assert d["timesteps"].tolist() == [128]
    summary = main(_args(out, total_timesteps=384, resume=True, quiet=True))
    assert [t for t, _ in summary["evaluations"]] == [128, 256, 384]


def test_the_evaluation_schedule_goes_on_across_a_resume(tmp_path, monkeypatch):
    """Checkpoints every 192 steps, evaluations every 128: resumed from step 192, the evaluations stay at
    256, 384, 512 (the schedule restarted at the resume: 320, 448)."""
    out = tmp_path / "run"
    kw = dict(total_timesteps=512, checkpoint_freq=192, overrides={**TINY, "n_steps": 32})
    _killed_run(monkeypatch, out, 250, **kw)
    assert (out / "checkpoints" / "step_192").is_dir() and not (out / "checkpoints" / "step_256").exists()
    summary = main(_args(out, resume=True, quiet=True, **kw))
    assert summary["resumed_from"].endswith("step_192")
    assert [t for t, _ in summary["evaluations"]] == [128, 256, 384, 512]


def test_a_due_evaluation_is_done_at_the_start_of_a_resume(run_256, tmp_path):
    """A checkpoint whose schedule says the evaluation at its own step is due (never completed)."""
    out = _copy(run_256, tmp_path)

    def edit(doc):
        doc["evaluations"] = {k: v[:1] for k, v in doc["evaluations"].items()}
        doc["schedule"].update(last=128, next=256)
        return doc

    _rewrite(out / "checkpoints" / "step_256", RESUME_FILE, edit)
    summary = main(_args(out, total_timesteps=384, resume=True, quiet=True))
    assert [t for t, _ in summary["evaluations"]] == [128, 256, 384]
    state = yaml.safe_load((out / "checkpoints" / "step_384" / RESUME_FILE).read_text())
    assert state["schedule"] == {"every": 128, "last": 384, "next": 512}
