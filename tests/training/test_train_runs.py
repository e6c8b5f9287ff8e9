"""Reliability of python -m train's run directories (issue 12): atomic units, resume, history, clear errors,
exit codes, progress, and the rl-zoo3 layout of train/hyperparams.yml. Tiny budgets (256 steps on 2 envs)."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from iscc_gym.agents.sb3_policy import SB3Policy, read_manifest, write_manifest
from iscc_gym.train import Args, main
from iscc_gym.train.callbacks import progress_bar_on
from iscc_gym.train.cli import build_parser, console
from iscc_gym.train.config import HYPERPARAMS, format_policy_kwargs, load_hyperparams, parse_policy_kwargs, resolve_args
from iscc_gym.train.runs import latest_checkpoint, save_unit
from tiny_runs import TINY
from tiny_runs import tiny_args as _args

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = ROOT / "agents" / "trained" / "ppo_iscc"


@pytest.fixture(scope="module")
def run_256(tmp_path_factory):
    """One finished run (checkpoints at 128 and 256, evaluations at 128 and 256), copied by each test."""
    out = tmp_path_factory.mktemp("run") / "run"
    main(_args(out))
    return out


def _copy(run, tmp_path) -> Path:
    dst = tmp_path / "run"
    shutil.copytree(run, dst)
    return dst


# --- checkpoints: atomic units, resume from the newest complete one ---------------------------------------

@pytest.mark.parametrize("damage", ["truncate_model", "drop_statistics", "drop_manifest"])
def test_resume_skips_an_incomplete_newest_checkpoint(run_256, tmp_path, damage, capsys):
    """A kill or a full disk during the zip write (truncated model), between the model and the statistics
    (no vecnormalize.pkl) or before the manifest: the newest checkpoint is incomplete, resume takes the one
    before it (with its own statistics) instead of crashing or starting from fresh normalisation."""
    out = _copy(run_256, tmp_path)
    newest = out / "checkpoints" / "step_256"
    if damage == "truncate_model":
        data = (newest / "model.zip").read_bytes()
        (newest / "model.zip").write_bytes(data[: len(data) // 2])
    elif damage == "drop_statistics":
        (newest / "vecnormalize.pkl").unlink()
    else:
        (newest / "manifest.yml").unlink()
    ckpt, manifest, skipped = latest_checkpoint(out / "checkpoints")
    assert ckpt.name == "step_128" and manifest["timesteps"] == 128 and len(skipped) == 1
    summary = main(_args(out, total_timesteps=384, resume=True))
    assert summary["resumed_from"].endswith("step_128") and summary["timesteps"] == 384
    assert "resume skipped an incomplete checkpoint" in capsys.readouterr().err


def test_an_interrupted_save_leaves_no_partial_file_and_the_old_unit_whole(run_256, tmp_path):
    """A model whose save fails half-way (a full disk): no model.zip of the new unit, no manifest, and the
    existing unit it would have replaced still loads."""
    out = _copy(run_256, tmp_path)
    before = (out / "model.zip").read_bytes()

    class FullDisk:
        def save(self, path):
            Path(path).write_bytes(b"PK\x03\x04 half a zip")
            raise OSError(28, "No space left on device")

    with pytest.raises(OSError, match="No space"):
        save_unit(out / "checkpoints" / "step_999", FullDisk(), None, timesteps=999)
    assert not list((out / "checkpoints" / "step_999").iterdir())  # nothing left, not even the temporary file
    with pytest.raises(OSError):
        save_unit(out, FullDisk(), None, timesteps=999)
    assert (out / "model.zip").read_bytes() == before and read_manifest(out)
    assert not [p for p in out.iterdir() if p.name.endswith(".tmp")]
    SB3Policy.load(out)


def test_sac_checkpoints_hold_the_replay_buffer_and_resume_loads_it(tmp_path):
    kw = dict(algo="sac", n_envs=2, total_timesteps=64, eval_freq=0, checkpoint_freq=32,
              overrides={"learning_starts": 16, "batch_size": 16, "buffer_size": 1000})
    main(_args(tmp_path, **kw))
    manifest = read_manifest(tmp_path / "checkpoints" / "step_64")
    assert "replay_buffer.pkl" in manifest["files"]
    main(_args(tmp_path, **{**kw, "total_timesteps": 96}, resume=True))
    from stable_baselines3.common.save_util import load_from_pkl

    buffer = load_from_pkl(tmp_path / "checkpoints" / "step_96" / "replay_buffer.pkl")
    assert buffer.pos == 48  # 96 steps / 2 envs: the resumed run went on filling the saved buffer


# --- resume keeps history; one run per --out ----------------------------------------------------------------

def test_resume_keeps_evaluations_curve_and_the_best_model_unless_beaten(run_256, tmp_path):
    out = _copy(run_256, tmp_path)
    # pretend the first session's best was excellent: no later evaluation beats it
    manifest = yaml.safe_load((out / "best" / "manifest.yml").read_text())
    manifest["mean_reward"] = 1e9
    (out / "best" / "manifest.yml").write_text(yaml.safe_dump(manifest))
    best_before = (out / "best" / "best_model.zip").read_bytes()
    rows_before = (out / "learning_curve.csv").read_text().splitlines()[1:]
    summary = main(_args(out, total_timesteps=512, resume=True))
    with np.load(out / "eval" / "evaluations.npz") as d:
        assert d["timesteps"].tolist() == [128, 256, 384, 512] and d["results"].shape == (4, 2)
    assert [t for t, _ in summary["evaluations"]] == [128, 256, 384, 512]
    assert (out / "best" / "best_model.zip").read_bytes() == best_before
    rows = (out / "learning_curve.csv").read_text().splitlines()[1:]
    assert rows[: len(rows_before)] == rows_before and len(rows) > len(rows_before)
    assert read_manifest(out / "best")["mean_reward"] == 1e9


def test_the_best_model_comes_with_its_own_statistics(run_256):
    best = SB3Policy.load(run_256, best=True)
    final = SB3Policy.load(run_256)
    assert best.vecnormalize is not None
    assert read_manifest(run_256 / "best")["files"].keys() == {"vecnormalize.pkl", "best_model.zip"}
    # statistics of the evaluation that chose it, not the end of training
    t_best = read_manifest(run_256 / "best")["timesteps"]
    assert t_best in (128, 256)
    if t_best == 128:
        assert best.vecnormalize.obs_rms.count < final.vecnormalize.obs_rms.count


def test_a_non_empty_out_is_refused_without_resume_or_overwrite(run_256, tmp_path):
    out = _copy(run_256, tmp_path)
    with pytest.raises(FileExistsError, match="not empty.*--resume.*--overwrite"):
        main(_args(out))
    with pytest.raises(ValueError, match="use one"):
        main(_args(out, resume=True, overwrite=True))
    # --overwrite starts afresh: no checkpoint of the old run, no stale statistics after --no-normalize, no
    # best/ left aside by a kill during its replacement
    (out / ".best.1.a.tmp").mkdir()
    main(_args(out, normalize=False, overwrite=True, checkpoint_freq=0, eval_freq=0))
    assert not (out / "vecnormalize.pkl").exists() and not (out / "checkpoints").exists()
    assert not (out / ".best.1.a.tmp").exists()
    assert not (out / "best").exists() and SB3Policy.load(out).vecnormalize is None
    # a directory that is not a run is never emptied (e.g. --out . in the repository)
    other = tmp_path / "project"
    (other / "eval").mkdir(parents=True)
    (other / "eval" / "code.py").write_text("x = 1")
    with pytest.raises(FileExistsError, match=r"holds no run of python -m train \(.*\); nothing deleted"):
        main(_args(other, overwrite=True))
    assert (other / "eval" / "code.py").exists()


@pytest.mark.parametrize("change, message", [
    ({"normalize": False}, r"normalize True -> False"),
    ({"env_overrides": {"mission_duration_s": 10.0}}, r"env_overrides \{\} -> \{'mission_duration_s': 10.0\}"),
    ({"algo": "td3", "overrides": {"learning_starts": 16, "batch_size": 16}}, r"algo 'ppo' -> 'td3'"),
    # a resumed model keeps its checkpoint's hyperparameters: a --set that changes one is refused, not ignored
    ({"overrides": {**TINY, "learning_rate": 1e-3}}, r"learning_rate 0\.000228\d* -> 0\.001\)"),
    ({"overrides": {**TINY, "n_epochs": 2}}, r"n_epochs 1 -> 2\)"),
])
def test_resume_with_other_settings_is_a_clear_error(run_256, tmp_path, change, message):
    out = _copy(run_256, tmp_path)
    with pytest.raises(ValueError, match=r"resume: .* was trained with other settings \(" + message):
        main(_args(out, total_timesteps=512, resume=True, **change))


def test_resume_of_a_checkpoint_without_hyperparameters_in_its_manifest(run_256, tmp_path):
    """Checkpoints of an older python -m train carry no hyperparameters: nothing to compare, resume goes on."""
    import yaml

    out = _copy(run_256, tmp_path)
    for manifest in (out / "checkpoints").glob("*/manifest.yml"):
        data = yaml.safe_load(manifest.read_text())
        assert "hyperparams" in data["run"]
        del data["run"]["hyperparams"]
        manifest.write_text(yaml.safe_dump(data))
    assert main(_args(out, total_timesteps=384, resume=True))["timesteps"] == 384


# --- clear errors -----------------------------------------------------------------------------------------

@pytest.mark.parametrize("flags, message", [
    (["--set", "n_steps=abc"], r"n_steps = 'abc'; use a number"),
    (["--set", "n_steps=6.5"], r"n_steps = 6.5; use an integer"),
    (["--set", "n_step=64"], r"'n_step' is not an argument of PPO; did you mean n_steps"),
    (["--set", "policy_kwargs=__import__('os').system('true')"], r"evaluates nothing else"),
    (["--hyperparams", "/nonexistent/hp.yml"], r"No such file"),
    (["--algo", "a2c"], r"algo = 'a2c'; use one of ppo, sac, td3, ppo_lstm, ppo-lag$"),  # issue 34: ppo-lag too
    # issue 34: an unknown env id is named as such, with the ids (not a --vec-env or a YAML entry to change)
    (["--env", "iscc_gym/ISCC-v9"], r"env_id 'iscc_gym/ISCC-v9' is not a registered env id; use one of "
                                    r"iscc_gym/ISCC-v0, iscc_gym/ISCC-Urban-v0, iscc_gym/ISCC-Multi-v0"),
    (["--n-envs", "0"], r"n_envs = 0; use an integer >= 1"),
])
def test_console_exits_2_with_one_line_for_a_user_mistake(flags, message, tmp_path, capsys):
    import re

    code = console([*flags, "--out", str(tmp_path / "out"), "--total-timesteps", "64"], prog="iscc-train")
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("iscc-train: error: "), err
    assert re.search(message, err[0]), err[0]
    assert not (tmp_path / "out").exists()  # nothing was started


def test_console_exits_0_on_success_and_on_a_non_tty_shows_no_progress_bar(tmp_path, capsys):
    code = console(["--out", str(tmp_path), "--total-timesteps", "128", "--n-envs", "2", "--set", "n_steps=64",
                    "--set", "batch_size=64", "--set", "n_epochs=1", "--eval-freq", "0", "--checkpoint-freq", "0",
                    "--no-tensorboard", "--init-policy", "none"])
    out = capsys.readouterr()
    assert code == 0 and "trained 128 steps" in out.out and "%" not in out.err
    assert console(["--out", str(tmp_path), "--total-timesteps", "128"]) == 2  # now non-empty
    assert "not empty" in capsys.readouterr().err


def test_torch_threads_hold_when_numbas_pool_starts_in_a_fork(tmp_path, monkeypatch):
    """In a forked process (the study workers of tests/training/test_study.py) numba's first start of its OpenMP pool
    sets torch's thread count to numba's (measured: torch 1 -> 2 on 2 cores), so --torch-threads set before the numba
    threads was lost (PPO's updates 5-10x slower beside a busy process). Emulated here in process: the numba
    setting also sets torch's count, as that first start does; the run must end on --torch-threads."""
    import torch
    from iscc_gym.train import train as loop

    def numba_then_its_pool(n):
        original(n)
        torch.set_num_threads(2)  # what the pool's first start in a fork does to torch

    original = loop.set_numba_threads
    monkeypatch.setattr(loop, "set_numba_threads", numba_then_its_pool)
    before = torch.get_num_threads()
    try:
        main(_args(tmp_path / "r", total_timesteps=64, eval_freq=0, checkpoint_freq=0, torch_threads=1,
                   overrides={**TINY, "n_steps": 32}))
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)


def test_python_m_train_exits_0(tmp_path, monkeypatch, capfd):
    """The module entry point returns 0 (it used to exit 1, printing the summary dict to stderr). Its
    ``__main__`` (train/__main__.py, which ``python -m train`` runs in the checkout) is run here in process as
    the interpreter runs it: ``sys.exit``'s code is the exit status (a new interpreter took 10-20 s of imports).
    """
    import runpy

    monkeypatch.setattr(sys, "argv", ["python -m train", "--out", str(tmp_path / "r"), "--total-timesteps", "64",
                                      "--n-envs", "2", "--set", "n_steps=32", "--set", "batch_size=64", "--set",
                                      "n_epochs=1", "--eval-freq", "0", "--checkpoint-freq", "0", "--no-tensorboard",
                                      "--init-policy", "none", "--quiet"])
    capfd.readouterr()
    with pytest.raises(SystemExit) as exc:
        runpy.run_module("iscc_gym.train", run_name="__main__", alter_sys=True)
    out, err = capfd.readouterr()
    assert exc.value.code == 0, err  # sys.exit(0): status 0; sys.exit(summary) exited 1
    assert (tmp_path / "r" / "summary.yml").is_file()
    assert out == "" and "{" not in err  # --quiet: no closing line
    assert "train:" not in err  # nor progress lines


def test_truncated_model_and_unknown_algo_and_other_env_are_clear_errors(tmp_path):
    d = tmp_path / "trunc"
    d.mkdir()
    data = (SHIPPED / "model.zip").read_bytes()
    (d / "model.zip").write_bytes(data[: len(data) // 3])
    with pytest.raises(ValueError, match="not a complete SB3 model file"):
        SB3Policy.load(d)
    d = tmp_path / "algo"
    d.mkdir()
    shutil.copy(SHIPPED / "model.zip", d / "model.zip")
    cfg = yaml.safe_load((SHIPPED / "config.yml").read_text())
    cfg["args"]["algo"] = "a2c"
    (d / "config.yml").write_text(yaml.safe_dump(cfg))
    with pytest.raises(ValueError, match=r"config.yml: args.algo = 'a2c'; expected one of"):
        SB3Policy.load(d)
    from stable_baselines3 import PPO

    PPO("MlpPolicy", "Pendulum-v1", n_steps=16, batch_size=16, device="cpu").save(tmp_path / "pendulum.zip")
    with pytest.raises(ValueError, match=r"observations of shape \(3,\), iscc_gym/ISCC-v0 gives \(23,\)"):
        SB3Policy.load(tmp_path / "pendulum.zip")
    policy = SB3Policy.load(SHIPPED)
    with pytest.raises(ValueError, match=r"observation of shape \(22,\)"):
        policy.predict(np.zeros(22, dtype=np.float32))


def test_info_keys_typo_is_a_clear_error():
    from iscc_gym.agents.sb3_vec_env import ISCCBatchedVecEnv

    with pytest.raises(ValueError, match=r"unknown 'tracking_eror_m' \(did you mean 'tracking_error_m'\?\)"):
        ISCCBatchedVecEnv(1, info_keys=("tracking_eror_m",))
    with pytest.raises(ValueError, match="sequence of keys"):
        ISCCBatchedVecEnv(1, info_keys="cost")
    env = ISCCBatchedVecEnv(2, info_keys=("cost",))
    env.reset()
    _, _, _, infos = env.step(np.zeros((2, 3), dtype=np.float32))
    assert all("cost" in i for i in infos)


# --- progress and help ----------------------------------------------------------------------------------------

def test_progress_bar_on_a_terminal_unless_quiet(monkeypatch):
    monkeypatch.setattr(sys.stdout, "isatty", lambda: True, raising=False)
    assert progress_bar_on(Args()) is True
    assert progress_bar_on(Args(quiet=True)) is False
    assert progress_bar_on(Args(progress_bar=False)) is False
    monkeypatch.setattr(sys.stdout, "isatty", lambda: False, raising=False)
    assert progress_bar_on(Args()) is False
    assert progress_bar_on(Args(progress_bar=True)) is True


def test_every_flag_has_help_and_the_help_warns_about_pickles():
    ap = build_parser()
    missing = [a.option_strings for a in ap._actions if a.option_strings != ["-h", "--help"] and not a.help]
    assert not missing
    text = " ".join(ap.format_help().split())
    assert "pickles" in text and "load only files you trust" in text.lower()
    for flag in ("--quiet", "--progress-bar", "--overwrite", "--resume"):
        assert flag in text


# --- train/hyperparams.yml: rl-zoo3's layout, read by both ------------------------------------------------------

def test_the_yaml_is_rl_zoo3s_layout_and_trains_the_shipped_configuration():
    """rl-zoo3 reads table[env id] as the PPO keyword arguments (plus its own keys): nothing else may be there.
    python -m train reads the same entry and the shipped agent's configuration is unchanged."""
    table = yaml.safe_load(HYPERPARAMS.read_text())
    zoo_keys = {"n_envs", "n_timesteps", "normalize", "policy", "policy_kwargs", "env_kwargs"}
    import inspect

    from stable_baselines3 import PPO

    ppo = set(inspect.signature(PPO.__init__).parameters)
    for env_id in ("iscc_gym/ISCC-v0", "Pendulum-v1"):
        assert set(table[env_id]) <= zoo_keys | ppo, set(table[env_id]) - zoo_keys - ppo
        assert "n_timesteps" in table[env_id]  # rl-zoo3 requires it
    assert isinstance(table["iscc_gym/ISCC-v0"]["policy_kwargs"], str)  # rl-zoo3 eval's it; a dict would not map
    shipped = yaml.safe_load((SHIPPED / "config.yml").read_text())
    args, hp = resolve_args(Args())
    assert hp == shipped["hyperparams"]
    for key in ("total_timesteps", "n_envs", "normalize", "init_policy", "init_envs", "init_steps", "init_log_std"):
        assert getattr(args, key) == shipped["args"][key], key
    sac = load_hyperparams(HYPERPARAMS, "iscc_gym/ISCC-v0", "sac")
    assert sac["buffer_size"] == 200000 and sac["policy_kwargs"] == {"net_arch": [64, 64]}


def test_policy_kwargs_are_read_without_eval():
    pk = parse_policy_kwargs("dict(net_arch=dict(pi=[64, 64], vf=[32]), activation_fn=nn.ReLU, ortho_init=False)")
    assert pk == {"net_arch": {"pi": [64, 64], "vf": [32]}, "activation_fn": "relu", "ortho_init": False}
    assert parse_policy_kwargs(format_policy_kwargs(pk)) == pk
    for bad in ("dict(x=os.system('true'))", "__import__('os')", "dict(activation_fn=nn.Module)", "[1, 2]"):
        with pytest.raises(ValueError, match="policy_kwargs"):
            parse_policy_kwargs(bad)


def test_older_layout_and_project_settings(tmp_path):
    hp = tmp_path / "old.yml"
    hp.write_text("iscc_gym/ISCC-v0:\n  ppo:\n    policy: MlpPolicy\n    n_steps: 32\n    init_policy: margin\n"
                  "  sac:\n    policy: MlpPolicy\n")
    args, kw = resolve_args(Args(hyperparams=str(hp)))
    assert kw == {"policy": "MlpPolicy", "n_steps": 32} and args.init_policy == "margin"
    zoo = tmp_path / "zoo.yml"
    zoo.write_text("iscc_gym/ISCC-v0:\n  policy: MlpPolicy\n  n_timesteps: 1000\n  env_kwargs:\n"
                   "    mission_duration_s: 10.0\niscc_gym.train:\n  algo: ppo\n")
    args, kw = resolve_args(Args(hyperparams=str(zoo)))
    assert args.total_timesteps == 1000 and args.env_overrides == {"mission_duration_s": 10.0}
    with pytest.raises(ValueError, match="its entries are ppo's"):
        resolve_args(Args(hyperparams=str(zoo), algo="sac"))


def test_rl_zoo3_trains_from_the_yaml(tmp_path):
    """python -m rl_zoo3.train reads train/hyperparams.yml (tiny budget; skipped without rl_zoo3)."""
    pytest.importorskip("rl_zoo3")
    env = {**os.environ, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-m", "rl_zoo3.train", "--algo", "ppo", "--env", "iscc_gym/ISCC-v0",
                           "--gym-packages", "iscc_gym", "-conf", str(HYPERPARAMS), "-n", "64",
                           "--hyperparams", "n_envs:2", "n_steps:32", "batch_size:64", "--eval-freq", "-1",
                           "--vec-env", "dummy", "--device", "cpu", "--log-folder", str(tmp_path)],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=180)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "'gamma', 0.3" in proc.stdout  # the shipped configuration's discount
    assert list(tmp_path.glob("ppo/*/*.zip")) and list(tmp_path.glob("ppo/*/*/vecnormalize.pkl"))


def test_ship_copies_a_unit(tmp_path, monkeypatch):
    from experiments.ship import ARTIFACTS, ship

    monkeypatch.chdir(tmp_path)
    args = _args(tmp_path / "ship_run", eval_freq=0, checkpoint_freq=0, total_timesteps=128, overwrite=True)
    (tmp_path / "ship_run").mkdir()
    (tmp_path / "ship_run" / "model.zip").write_text("a previous ship run")
    (tmp_path / "ship_run" / "config.yml").write_text("args: {}\n")
    ship(args, dest=tmp_path / "dest", write_docs=False)
    assert {p.name for p in (tmp_path / "dest").iterdir()} == set(ARTIFACTS)
    assert SB3Policy.load(tmp_path / "dest").vecnormalize is not None and read_manifest(tmp_path / "dest")


def test_a_ship_killed_while_copying_leaves_the_old_agent_whole(run_256, tmp_path, monkeypatch):
    """A kill after the new statistics are copied, before the model: the shipped folder is still the old agent
    (it loads, every file its own), never new statistics beside the old model; the next ship swaps the new one
    in whole and clears what a killed one left beside it."""
    from experiments.ship import publish

    dest = tmp_path / "agent"
    publish(_args(run_256), {}, dest, write_docs=False)
    old = {p.name: p.read_bytes() for p in dest.iterdir()}
    new = _copy(run_256, tmp_path)  # another agent: the step-128 checkpoint's model and statistics
    meta = read_manifest(new)
    for name in ("model.zip", "vecnormalize.pkl"):
        shutil.copy2(new / "checkpoints" / "step_128" / name, new / name)
    write_manifest(new, list(meta.pop("files")), **{**meta, "timesteps": 128})
    copy2, copied = shutil.copy2, []

    def killed(src, dst):
        if copied:
            raise KeyboardInterrupt
        copied.append(copy2(src, dst))

    monkeypatch.setattr(shutil, "copy2", killed)
    with pytest.raises(KeyboardInterrupt):
        publish(_args(new), {}, dest, write_docs=False)
    monkeypatch.undo()
    assert {p.name: p.read_bytes() for p in dest.iterdir()} == old and sorted(tmp_path.iterdir()) == [dest, new]
    SB3Policy.load(dest)
    (tmp_path / ".agent.1.dead.tmp").mkdir()  # what a SIGKILL mid-copy leaves
    publish(_args(new), {}, dest, write_docs=False)
    assert (dest / "model.zip").read_bytes() == (new / "model.zip").read_bytes()
    assert read_manifest(dest)["timesteps"] == 128 and sorted(tmp_path.iterdir()) == [dest, new]
    SB3Policy.load(dest)


def test_a_run_leaves_nothing_in_the_temporary_directory(tmp_path, monkeypatch):
    """SB3's default logger makes an empty $TMPDIR/SB3-<date> folder per learn() without TensorBoard."""
    import tempfile

    tmp = tmp_path / "tmpdir"
    tmp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    monkeypatch.delenv("SB3_LOGDIR", raising=False)
    main(_args(tmp_path / "run", total_timesteps=128, eval_freq=0, checkpoint_freq=0))
    assert (tmp_path / "run" / "model.zip").is_file()
    assert sorted(p.name for p in tmp.iterdir() if not p.name.startswith("torchinductor")) == []
