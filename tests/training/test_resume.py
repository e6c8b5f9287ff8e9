"""Resuming a training run (issue 23 items 5 and 6): a checkpoint holds everything a resume needs (learning curve
and wall time, multipliers and their history, best score, evaluation schedule), best/ is replaced as a unit, a
resume with other settings or constraints is refused, damaged run files are named, settings are checked before
any work (hyperparameter ranges, frequencies, training seeds against the held-out seeds), and progress lines go
to stderr without a terminal. Kills are simulated by raising inside a callback or a save; tiny runs (256-512
steps on 2 envs) share one module-scoped run."""

import csv
import pickle
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from iscc_gym.agents.sb3_policy import SB3Policy, read_manifest, write_manifest
from iscc_gym.commands.protocol import EVAL_SEED_RANGES
from iscc_gym.train import Args, main
from iscc_gym.train import train as T
from iscc_gym.train.cli import console
from iscc_gym.train.lagrangian import load_lagrange
from iscc_gym.train.runs import RESUME_FILE, latest_checkpoint, recover_unit, replace_unit
from stable_baselines3 import PPO
from stable_baselines3.common import evaluation
from stable_baselines3.common.callbacks import BaseCallback
from tiny_runs import TINY
from tiny_runs import tiny_args as _args

TINY_FLAGS = ["--total-timesteps", "64", "--n-envs", "2", "--set", "n_steps=32", "--set", "batch_size=64",
              "--set", "n_epochs=1", "--no-tensorboard", "--init-policy", "none"]


@pytest.fixture(scope="module")
def run_256(tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "run"
    main(_args(out, quiet=True))
    return out


def _copy(run, tmp_path):
    dst = tmp_path / "run"
    shutil.copytree(run, dst)
    return dst


def _relist(unit, drop=()):
    """Write a unit's manifest anew for its files as they are now (a damage its manifest cannot catch)."""
    m = yaml.safe_load((unit / "manifest.yml").read_text())
    files = [f for f in m.pop("files") if f not in drop]
    write_manifest(unit, files, **m)


# --- 17. hyperparameter and setting ranges, checked before any work ----------------------------------------

@pytest.mark.parametrize("flags, message", [
    (["--set", "n_steps=0"], r"n_steps = 0 is out of range; use a value >= 1"),
    (["--set", "gamma=2"], r"gamma = 2 is out of range; use a value in \[0, 1\]"),
    (["--set", "clip_range=-1"], r"clip_range = -1 is out of range; use a value > 0"),
    (["--set", "learning_rate=.nan"], r"learning_rate = nan is out of range; use a value >= 0"),
    (["--set", "batch_size=1"], r"batch_size = 1 is out of range; use a value >= 2"),
    (["--set", "gae_lambda=1.5"], r"gae_lambda = 1.5 is out of range"),
    (["--set", "target_kl=abc"], r"target_kl = 'abc'; use a number > 0"),
    (["--set", "policy_kwargs={log_std_init: .inf}"], r"policy_kwargs.log_std_init = inf; use a finite number"),
    (["--eval-freq", "-1"], r"eval_freq = -1; use an integer >= 0 \(0: none\)"),
    (["--checkpoint-freq", "-5"], r"checkpoint_freq = -5; use an integer >= 0"),
    (["--init-log-std", "nan"], r"init_log_std = nan; use a finite number"),
    (["--init-steps", "0"], r"init_steps = 0; use an integer >= 1"),
    (["--seed", "-1"], r"seed = -1; use an integer in \[0, 2\*\*32\)"),
    (["--n-envs", "1", "--set", "n_steps=1"], r"PPO needs a rollout of at least 2 steps"),
])
def test_out_of_range_settings_are_refused_before_any_work(tmp_path, capsys, flags, message):
    code = console([*TINY_FLAGS, *flags, "--out", str(tmp_path / "out")], prog="iscc-train")
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("iscc-train: error: "), err
    assert re.search(message, err[0]), err[0]
    assert not (tmp_path / "out").exists()


def test_sac_ranges(tmp_path):
    for hp, message in (({"tau": 0.0}, r"tau = 0.0 is out of range; use a value in \(0, 1\]"),
                        ({"gradient_steps": 0}, r"gradient_steps = 0 is out of range; use a value >= 1, or -1"),
                        ({"buffer_size": 0}, r"buffer_size = 0 is out of range")):
        with pytest.raises(ValueError, match=message):
            main(_args(tmp_path / "out", algo="sac", overrides=hp))
    assert not (tmp_path / "out").exists()


# --- 21. training seeds against the held-out evaluation seeds --------------------------------------------

def test_the_protocol_puts_every_default_where_it_belongs():
    """Evaluation defaults inside the held-out ranges, training and tuning defaults outside (one protocol)."""
    from iscc_gym.commands import protocol as P
    from iscc_gym.eval.__main__ import build_parser

    def held_out(seed):
        return any(lo <= seed < hi for lo, hi in EVAL_SEED_RANGES)

    assert held_out(build_parser().parse_args([]).seed_start) and held_out(P.CALLBACK_EVAL_SEED_START)
    for start in (P.FADING_SEED_START, P.SENSITIVITY_SEED_START, P.PARETO_SEED_START, P.MULTI_SEED_START):
        assert all(map(held_out, P.held_out_seeds(start, 1000, 99)))
    assert not any(map(held_out, [*P.TUNE_SEEDS, P.INIT_SEED_START, P.CALIBRATION_SEED_START]))


@pytest.mark.parametrize("kw, message", [
    ({"seed": 10_000}, r"seed = 10000: the training envs' seeds 10000-10001 overlap in the held-out evaluation "
                       r"range \[10000, 11000\)"),
    ({"seed": 9_999}, r"seeds 9999-10000 overlap in the held-out evaluation range \[10000, 11000\)"),
    ({"seed": 1_500_000}, r"seeds 1500000-1500001 overlap in the held-out evaluation range \[1000000, 2000000\)"),
    ({"seed": 800, "init_policy": "margin", "init_envs": 4},
     r"seed = 800: the warm start's seeds 1000000-1000003 overlap in the held-out evaluation range "
     r"\[1000000, 2000000\)"),
])
def test_training_seeds_inside_the_evaluation_seeds_are_refused(tmp_path, kw, message):
    with pytest.raises(ValueError, match=message):
        main(_args(tmp_path / "out", **kw))
    assert not (tmp_path / "out").exists()


def test_training_seeds_next_to_the_evaluation_seeds_are_accepted():
    from iscc_gym.train.config import check_resolved

    check_resolved(Args(seed=9_998, n_envs=2, init_policy="none"), {"n_steps": 64})
    check_resolved(Args(seed=799, n_envs=2, init_policy="margin", init_envs=16, init_steps=10), {"n_steps": 64})


# --- 19. damaged run files name the file --------------------------------------------------------------------

@pytest.mark.parametrize("text, message", [
    ("files: {}\ntimesteps: 256\n", r"step_256/manifest\.yml: files = \{\}; not a manifest .* \(empty or damaged"),
    ("files: [model.zip]\n", r"step_256/manifest\.yml: files = \['model\.zip'\]; not a manifest"),
    ("files: {model.zip: null}\n", r"step_256/manifest\.yml: files = \{'model\.zip': None\}"),
    ("files: {a: [\n", r"step_256/manifest\.yml: not valid YAML"),
    ("", r"step_256/manifest\.yml: files = None"),
])
def test_a_damaged_or_empty_manifest_is_named_and_skipped(run_256, tmp_path, text, message):
    out = _copy(run_256, tmp_path)
    (out / "checkpoints" / "step_256" / "manifest.yml").write_text(text)
    ckpt, manifest, skipped = latest_checkpoint(out / "checkpoints")
    assert ckpt.name == "step_128" and len(skipped) == 1 and re.search(message, skipped[0]), skipped


def test_a_manifest_without_the_checkpoints_own_files_is_skipped(run_256, tmp_path):
    out = _copy(run_256, tmp_path)
    unit = out / "checkpoints" / "step_256"
    _relist(unit, drop=("vecnormalize.pkl",))
    ckpt, _, skipped = latest_checkpoint(out / "checkpoints")
    assert ckpt.name == "step_128" and "step_256/manifest.yml: lists no vecnormalize.pkl" in skipped[0]


@pytest.mark.parametrize("edit, message", [
    (lambda d: {**d, "curve": 5}, r"step_256/resume\.yml: curve = 5; expected a list of rows"),
    (lambda d: {**d, "wall_s": -1.0}, r"step_256/resume\.yml: wall_s = -1\.0; expected seconds >= 0"),
    (lambda d: {**d, "timesteps": 128}, r"step_256/resume\.yml: timesteps = 128; expected the checkpoint's 256"),
    (lambda d: {**d, "evaluations": {"timesteps": [1]}}, r"step_256/resume\.yml: evaluations = "),
    (lambda d: {**d, "schedule": {"next": "soon"}}, r"step_256/resume\.yml: schedule = "),
    (lambda d: {**d, "best": {"mean_reward": "high"}}, r"step_256/resume\.yml: best = "),
    (lambda d: [d], r"step_256/resume\.yml: the document = "),
])
def test_a_damaged_resume_file_is_named_with_its_field(run_256, tmp_path, edit, message):
    out = _copy(run_256, tmp_path)
    unit = out / "checkpoints" / "step_256"
    (unit / RESUME_FILE).write_text(yaml.safe_dump(edit(yaml.safe_load((unit / RESUME_FILE).read_text()))))
    _relist(unit)
    with pytest.raises(ValueError, match=message):
        main(_args(out, total_timesteps=384, resume=True, quiet=True))


def test_damaged_files_of_an_older_checkpoint_are_named(run_256, tmp_path):
    """A checkpoint without resume.yml (an older python -m train) takes the history from the run's files."""
    out = _copy(run_256, tmp_path)
    for step in (128, 256):
        unit = out / "checkpoints" / f"step_{step}"
        (unit / RESUME_FILE).unlink()
        _relist(unit, drop=(RESUME_FILE,))
    (out / "eval" / "evaluations.npz").write_bytes(b"not an npz")
    with pytest.raises(ValueError, match=r"eval/evaluations\.npz: not an evaluations\.npz of python -m train"):
        main(_args(out, total_timesteps=384, resume=True, quiet=True))
    (out / "eval" / "evaluations.npz").unlink()
    (out / "learning_curve.csv").write_text("timesteps,wall_s\n128,abc\n")
    with pytest.raises(ValueError, match=r"learning_curve\.csv: not a learning_curve\.csv of python -m train"):
        main(_args(out, total_timesteps=384, resume=True, quiet=True))
    (out / "learning_curve.csv").unlink()
    assert main(_args(out, total_timesteps=384, resume=True, quiet=True))["timesteps"] == 384


# --- 20. a vecnormalize.pkl that is not a VecNormalize ----------------------------------------------------

def test_a_vecnormalize_pkl_that_is_not_a_vecnormalize_is_named(run_256, tmp_path):
    out = _copy(run_256, tmp_path)
    for unit in (out / "checkpoints" / "step_256", out):
        (unit / "vecnormalize.pkl").write_bytes(pickle.dumps({"obs_rms": None}))
        _relist(unit)
    with pytest.raises(ValueError, match=r"step_256/vecnormalize\.pkl: holds a builtins\.dict, not SB3's VecNormalize"):
        main(_args(out, total_timesteps=384, resume=True, quiet=True))
    with pytest.raises(ValueError, match=r"run/vecnormalize\.pkl: holds a builtins\.dict, not SB3's VecNormalize"):
        SB3Policy.load(out)


# --- item 5: progress without a terminal ----------------------------------------------------------------------

def test_progress_lines_on_stderr_without_a_terminal_and_none_with_quiet(tmp_path, capsys, monkeypatch):
    from iscc_gym.train import callbacks

    monkeypatch.setattr(callbacks, "PROGRESS_EVERY_S", 0.0)  # a line at every step of this tiny run
    main(_args(tmp_path / "a"))
    err = capsys.readouterr().err.splitlines()
    assert err and all(line.startswith("train: ") for line in err), err
    text = "\n".join(err)
    for want in (r"setting up ppo on iscc_gym/ISCC-v0 .*: 256 steps on 2 envs", r"evaluation at step 128: mean reward",
                 r"checkpoint at step 128 -> ", r"step 200/256, [\d,]+ steps/s, elapsed 0:00:\d\d, ETA 0:00:\d\d",
                 r"done: 256 steps in"):
        assert re.search(want, text), (want, text)
    main(_args(tmp_path / "b", quiet=True))
    assert capsys.readouterr().err == ""


def test_progress_names_the_warm_start_and_the_resume(run_256, tmp_path, capsys):
    out = _copy(run_256, tmp_path)
    main(_args(out, total_timesteps=384, resume=True))
    assert re.search(r"train: resuming .* from .*step_256 \(step 256\)", capsys.readouterr().err)
    main(_args(tmp_path / "ws", total_timesteps=128, eval_freq=0, checkpoint_freq=0, init_policy="margin",
               init_envs=2, init_steps=20))
    err = capsys.readouterr().err
    assert "train: warm start: cloning margin played on 2 envs x 20 steps" in err and "warm start done in" in err


# --- the state a checkpoint holds -------------------------------------------------------------------------------------
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
    monkeypatch.setattr(T, "steps_callback", lambda say, total: _kill_at(step))
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


def test_resume_refuses_another_reward_scaling(run_256, tmp_path):
    """Issue 43.15: norm_reward was not part of a run's identity: a resume with it changed went on silently with the
    checkpoint's VecNormalize (scaling the rewards or not as the first part did)."""
    out = _copy(run_256, tmp_path)
    with pytest.raises(ValueError, match=r"norm_reward True -> False"):
        main(_args(out, total_timesteps=384, resume=True, quiet=True, norm_reward=False))
    ckpt, manifest, _ = latest_checkpoint(out / "checkpoints")
    assert manifest["run"]["norm_reward"] is True


def test_resume_of_a_checkpoint_that_recorded_no_reward_scaling_goes_on(run_256, tmp_path):
    out = _copy(run_256, tmp_path)
    for unit in (out / "checkpoints").iterdir():  # as an older python -m train wrote them
        m = yaml.safe_load((unit / "manifest.yml").read_text())
        m["run"].pop("norm_reward")
        files = m.pop("files")
        write_manifest(unit, files, **m)
    main(_args(out, total_timesteps=384, resume=True, quiet=True))


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
