"""Issue 23 item 6 (defects 17, 19, 20, 21) and item 5: settings checked before any work (hyperparameter
ranges, frequencies, training seeds against the held-out seeds), damaged run files named on resume, and
progress lines on stderr without a terminal. Tiny runs (256 steps on 2 envs)."""

import pickle
import re
import shutil

import pytest
import yaml
from iscc_gym.agents.sb3_policy import SB3Policy, write_manifest
from iscc_gym.train import Args, main
from iscc_gym.train import train as T
from iscc_gym.train.cli import console
from iscc_gym.train.runs import RESUME_FILE, latest_checkpoint
from tiny_runs import tiny_args as _args

from iscc_gym.protocol import EVAL_SEED_RANGES

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
    from iscc_gym.eval.__main__ import build_parser

    from iscc_gym import protocol as P

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
    monkeypatch.setattr(T, "PROGRESS_EVERY_S", 0.0)  # a line at every step of this tiny run
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
