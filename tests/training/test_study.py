"""Optuna studies and multi-seed runs of ``python -m train`` (train/study.py), with tiny budgets.

Trials train 256 env steps on 4 envs (n_steps 32) and evaluate 2 held-out episodes of 50 slots.
"""

import importlib
import os
import signal
import socket
import sys
import threading
import time
import traceback
from pathlib import Path

import numpy as np
import optuna
import pytest
import yaml
from iscc_gym.train import Args, load_hyperparams, main
from iscc_gym.train.cli import cli, console
from iscc_gym.train.config import resolve_args
from iscc_gym.train.study import (
    PPO_SPACE,
    StudyArgs,
    export_best,
    make_objective,
    make_sampler,
    sample_ppo_params,
)

ROOT = Path(__file__).resolve().parents[2]
ENV_ID = "iscc_gym/ISCC-v0"
TINY = ["--init-policy", "none", "--n-envs", "4", "--set", "n_steps=32", "--set", "n_epochs=1",
        "--trial-timesteps", "256",
        "--eval-episodes", "2", "--eval-max-steps", "50", "--no-tensorboard", "--n-evaluations", "2"]


def _worker(argv: list[str], out: Path, err: Path) -> int:
    """Fork a worker running ``python -m train argv`` as the console runs it (everything already imported: a new
    interpreter spends 4-8 s importing torch, SB3 and Optuna), its stdout and stderr in ``out`` and ``err``;
    returns its pid. The child never returns into pytest."""
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        code = 1
        try:
            with open(out, "w") as fo, open(err, "w") as fe:
                os.dup2(fo.fileno(), 1)
                os.dup2(fe.fileno(), 2)
                sys.stdout, sys.stderr = open(1, "w", closefd=False), open(2, "w", closefd=False)
                try:
                    code = console(argv, "python -m train")
                except BaseException:
                    traceback.print_exc()
                finally:
                    sys.stdout.flush()
                    sys.stderr.flush()
        finally:
            os._exit(code)
    return pid


def _wait(pids: list[int], timeout: float) -> list[int]:
    """The exit codes of the children ``pids`` (minus the signal that killed one); any still running after
    ``timeout`` s is killed and the test fails (nothing hangs)."""
    codes = {}
    deadline = time.monotonic() + timeout
    while len(codes) < len(pids) and time.monotonic() < deadline:
        for pid in pids:
            if pid not in codes:
                done, status = os.waitpid(pid, os.WNOHANG)
                if done:
                    codes[pid] = os.waitstatus_to_exitcode(status)
        time.sleep(0.02)
    for pid in set(pids) - set(codes):
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
    assert len(codes) == len(pids), f"a worker ran longer than {timeout} s"
    return [codes[pid] for pid in pids]


#: What a study worker imports on its way (torch's compiler front end, loaded by the first optimiser; SB3;
#: TensorBoard's writer; Optuna's SQL storage): 7.6 s of a 10 s worker, imported once before the workers fork.
WORKER_IMPORTS = ("torch._dynamo", "stable_baselines3", "torch.utils.tensorboard", "sqlalchemy", "alembic.migration")


@pytest.fixture(scope="module")
def shared_study(tmp_path_factory):
    """Two worker processes started together on one SQLite storage, one trial each, one run directory (forks of
    the test process, each in its own process as separate workers are)."""
    for name in WORKER_IMPORTS:
        importlib.import_module(name)
    root = tmp_path_factory.mktemp("shared")
    storage = f"sqlite:///{root / 'shared.db'}"
    argv = ["--optimize", "--n-trials", "1", "--storage", storage, "--study-name", "shared", "--out",
            str(root / "run"), *TINY]
    logs = [(root / f"worker{i}.out", root / f"worker{i}.err") for i in range(2)]
    pids = [_worker(argv, *log) for log in logs]
    codes = _wait(pids, timeout=180)
    outputs = [(o.read_text(), e.read_text()) for o, e in logs]
    for code, (out, err) in zip(codes, outputs, strict=True):
        assert code == 0, f"worker failed ({code}):\n{out}\n{err}"
    study = optuna.load_study(study_name="shared", storage=storage)
    return root, study, outputs


def test_two_workers_share_one_sqlite_study(shared_study):
    root, study, outputs = shared_study
    trials = study.get_trials()
    assert sorted(t.number for t in trials) == [0, 1]
    assert {t.state for t in trials} <= {optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED}
    assert len({t.user_attrs["worker"] for t in trials}) == 2  # one trial per process
    for t in trials:
        assert (root / "run" / f"trial_{t.number}" / "config.yml").exists()
        assert len(t.intermediate_values) >= 1 and all(np.isfinite(list(t.intermediate_values.values())))
        assert "n_envs" not in t.params and "n_steps" not in t.params  # fixed by --n-envs / --set
        assert t.user_attrs["hyperparams"]["n_steps"] == 32 and t.user_attrs["n_envs"] == 4
    # the sampler of trial n is seeded from (--seed, n): two workers with one --seed draw different trials
    assert trials[0].params != trials[1].params
    assert any("held-out reward" in out for out, _ in outputs)


def test_best_entry_loads_with_resolve_args_and_trains(shared_study, tmp_path):
    root, study, _ = shared_study
    path = root / "run" / "best_hyperparams.yml"
    complete = [t for t in study.get_trials() if t.state == optuna.trial.TrialState.COMPLETE]
    assert complete, "no trial completed (the median pruner waits for 5 trials, so both should)"
    text = export_best(study, ENV_ID, "ppo", tmp_path / "again.yml")  # what the last worker wrote, re-exported
    assert yaml.safe_load(text) == yaml.safe_load(path.read_text())
    best = study.best_trial
    hp = load_hyperparams(path, ENV_ID, "ppo")
    assert hp["n_envs"] == 4 and hp["n_timesteps"] == 256 and hp["normalize"] is True
    assert (4 * hp["n_steps"]) % hp["batch_size"] == 0 and hp["batch_size"] > 1
    args, kwargs = resolve_args(Args(hyperparams=str(path)))
    assert args.n_envs == 4 and args.total_timesteps == 256 and args.normalize is True
    assert kwargs == best.user_attrs["hyperparams"]
    assert kwargs["learning_rate"] == best.params["learning_rate"]
    assert kwargs["policy_kwargs"]["net_arch"] == [best.params["net_width"]] * best.params["net_depth"]
    assert kwargs["policy_kwargs"]["activation_fn"] == "tanh"  # the YAML's policy_kwargs are kept
    summary = main(Args(hyperparams=str(path), out=str(tmp_path / "retrain"), eval_freq=0, checkpoint_freq=0,
                        tensorboard=False))
    assert summary["timesteps"] == 256


def _minimize_study(tmp_path) -> str:
    storage = f"sqlite:///{tmp_path / 'min.db'}"
    optuna.create_study(storage=storage, study_name="lower-is-better", direction="minimize")
    return storage


@pytest.mark.parametrize("flags, message", [
    (["--optimize", "--sampler", "grid"], r"--sampler 'grid': use one of tpe, random"),
    (["--optimize", "--pruner", "hyperband"], r"--pruner 'hyperband': use one of median, none"),
    (["--optimize", "--n-trials", "0"], r"--n-trials 0: use an integer >= 1"),
    (["--optimize", "--trial-timesteps", "0"], r"--trial-timesteps 0: use an integer >= 1"),
    (["--optimize", "--algo", "sac"], r"--algo sac: the study's search space is PPO's"),
    (["--optimize", "--storage", "postgresql://nohost/optuna"], r"--storage postgresql://nohost/optuna: cannot"),
    (["--optimize", "--storage", "postgresql://u:pw@127.0.0.1:1/optuna"], r"--storage postgresql://u:\*\*\*@"),
    (["--optimize", "--storage", "nosuchdialect://host/db"], r"unknown database dialect 'nosuchdialect'"),
    (["--optimize", "--storage", "study.db"], r"--storage 'study.db': not a storage URL; use sqlite:///PATH"),
    (["--optimize", "--storage", "journal:"], r"--storage journal:: name the journal file"),
    (["--optimize", "--storage", "MIN", "--study-name", "lower-is-better"],
     r"--study-name lower-is-better: .* has direction minimize; .* choose another --study-name"),
    (["--seeds", "0,x"], r"--seeds '0,x': give comma-separated integers"),
    (["--seeds", "1,1"], r"--seeds: seed 1 is given twice"),
    (["--seeds", "-1"], r"--seeds: seed -1 is negative"),
    (["--seeds", "0", "--optimize"], r"--optimize and --seeds: use one"),
])
def test_bad_input_exits_with_one_line_naming_the_flag(flags, message, tmp_path, capsys):
    import re

    flags = [_minimize_study(tmp_path) if f == "MIN" else f for f in flags]
    t0 = time.perf_counter()
    with pytest.raises(SystemExit) as exc:
        cli([*flags, "--out", str(tmp_path / "out")])
    assert exc.value.code == 2
    assert time.perf_counter() - t0 < 15  # an unreachable database fails fast
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("python -m train: error: ") and re.search(message, err[0]), err
    assert ":pw@" not in err[0]  # passwords are never printed
    assert not (tmp_path / "out" / "trial_0").exists()


def test_a_server_that_is_not_the_database_fails_with_a_storage_error(tmp_path, capsys):
    """Host and port answer (a TCP server that hangs up), so the probe passes: the driver (missing, or
    refused by the server) still yields one line naming --storage, in well under the connect timeout."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen()
    port = server.getsockname()[1]

    def hang_up():
        for _ in range(3):
            try:
                conn, _ = server.accept()
                conn.close()
            except OSError:
                return

    threading.Thread(target=hang_up, daemon=True).start()
    try:
        with pytest.raises(SystemExit):
            cli(["--optimize", "--storage", f"postgresql://u@127.0.0.1:{port}/db", "--out", str(tmp_path)])
    finally:
        server.close()
    err = capsys.readouterr().err
    assert err.startswith(f"python -m train: error: --storage postgresql://u@127.0.0.1:{port}/db: ")
    assert "driver is not installed" in err or "cannot open the database" in err


def _sampled(seed: int, n_trials: int, sampler: str = "tpe", workers: int = 1) -> list[dict]:
    """Params of trials 0..n-1 of an in-memory study with ``workers`` samplers taking turns (no training)."""
    storage = optuna.storages.InMemoryStorage()
    studies = [optuna.create_study(storage=storage, study_name="s", direction="maximize", load_if_exists=True,
                                   sampler=make_sampler(sampler, seed, n_startup_trials=3)) for _ in range(workers)]
    base = load_hyperparams(ROOT / "train" / "hyperparams.yml", ENV_ID, "ppo")

    def objective(trial):
        n_envs, hp = sample_ppo_params(trial, base, fixed={})
        assert n_envs in PPO_SPACE["n_envs"] and hp["n_steps"] in PPO_SPACE["n_steps"]
        assert (n_envs * hp["n_steps"]) % hp["batch_size"] == 0 and hp["batch_size"] > 1
        assert hp["policy_kwargs"]["activation_fn"] == "tanh" and len(hp["policy_kwargs"]["net_arch"]) >= 1
        return -abs(np.log10(hp["learning_rate"]) + 3.5) - hp["ent_coef"]

    for i in range(n_trials):
        studies[i % workers].optimize(objective, n_trials=1)
    return [t.params for t in sorted(studies[0].trials, key=lambda t: t.number)]


def test_sampler_is_reproducible_given_the_seed_and_trial_number():
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    a, b, c = _sampled(0, 6), _sampled(0, 6), _sampled(1, 6)
    assert a == b  # TPE after 3 random start-up trials: same seed, same trials
    assert a != c and a[0] != c[0]
    assert len({tuple(sorted(p.items())) for p in a}) == 6
    # random sampler: trial n's draw depends on (seed, n) only, not on which worker ran it
    assert _sampled(7, 4, "random", workers=2) == _sampled(7, 4, "random", workers=1)


def test_fixed_overrides_are_not_sampled():
    fixed = {"n_envs": 4, "n_steps": 32, "batch_size": 64, "gamma": 0.9, "policy_kwargs.net_arch": [8]}
    trial = optuna.create_study(direction="maximize").ask()
    n_envs, hp = sample_ppo_params(trial, {"policy_kwargs": {"activation_fn": "relu"}}, fixed)
    assert n_envs == 4 and hp["n_steps"] == 32 and hp["batch_size"] == 64 and hp["gamma"] == 0.9
    assert hp["policy_kwargs"]["net_arch"] == [8] and hp["policy_kwargs"]["activation_fn"] == "relu"
    assert not {"n_envs", "n_steps", "n_minibatches", "gamma", "net_width", "net_depth"} & set(trial.params)


def test_pruned_trial_stops_training_and_is_recorded_as_pruned(tmp_path):
    """A pruner that prunes every report: the first evaluation is reported, training stops early and the
    trial ends PRUNED (optuna.TrialPruned), without a final evaluation."""
    args = Args(n_envs=4, overrides={"n_steps": 32, "n_epochs": 1}, eval_episodes=2, eval_max_steps=50,
                tensorboard=False, out=str(tmp_path), init_policy="none")
    study = optuna.create_study(direction="maximize", sampler=make_sampler("random", 0),
                                pruner=optuna.pruners.ThresholdPruner(lower=1e9))
    study.optimize(make_objective(args, StudyArgs(trial_timesteps=512, n_evaluations=4)), n_trials=1)
    (trial,) = study.trials
    assert trial.state == optuna.trial.TrialState.PRUNED
    assert list(trial.intermediate_values) == [1]
    assert trial.user_attrs["timesteps"] < 512
    assert (tmp_path / "trial_0" / "model.zip").exists()


def test_seeds_trains_each_seed_and_writes_the_summary(tmp_path, capsys):
    result = cli(["--seeds", "0,1", "--init-policy", "none",
                  "--total-timesteps", "256", "--n-envs", "4", "--set", "n_steps=32",
                  "--set", "batch_size=32", "--set", "n_epochs=1", "--eval-freq", "128", "--eval-episodes", "2",
                  "--eval-max-steps", "50", "--no-tensorboard", "--out", str(tmp_path)])
    summary = yaml.safe_load((tmp_path / "seeds.yml").read_text())
    assert [r["seed"] for r in summary["runs"]] == [0, 1]
    for r in summary["runs"]:
        run = tmp_path / f"seed_{r['seed']}"
        assert (run / "model.zip").exists() and r["out"] == str(run)
        assert yaml.safe_load((run / "config.yml").read_text())["args"]["seed"] == r["seed"]
        assert np.isfinite(r["final_reward_mean"]) and r["wall_time_s"] > 0 and r["timesteps"] == 256
    finals = [r["final_reward_mean"] for r in summary["runs"]]
    assert summary["final_reward_mean"] == pytest.approx(np.mean(finals))
    assert summary["hyperparams"]["batch_size"] == 32 and summary["n_envs"] == 4
    assert result["path"] == str(tmp_path / "seeds.yml")
    assert not list(tmp_path.glob(".seeds.yml.*"))  # the temporary file was renamed
    table = capsys.readouterr().out
    assert "final held-out reward" in table and str(tmp_path / "seed_1") in table


def test_seeds_with_a_held_out_seed_are_refused_before_any_run(tmp_path):
    """--seeds 0,10000: seed 10000 is an evaluation seed; refused before seed 0 trains (it trained first)."""
    with pytest.raises(SystemExit) as e:
        cli(["--seeds", "0,10000", "--init-policy", "none", "--total-timesteps", "256", "--n-envs", "4", "--set",
             "n_steps=32", "--set", "batch_size=32", "--no-tensorboard", "--out", str(tmp_path)])
    assert e.value.code == 2
    assert not (tmp_path / "seed_0").exists()


def test_the_exported_entry_keeps_the_trials_run_settings(tmp_path):
    """A trial of a residual run (the urban entry's settings) exports them, so the exported file trains the same
    kind of agent; a trial that recorded none (older studies) exports the entry alone."""
    from types import SimpleNamespace

    from iscc_gym.train.config import run_settings
    from iscc_gym.train.study_export import best_entry

    from iscc_gym import URBAN_ENV_ID

    resolved, kwargs = resolve_args(Args(env_id=URBAN_ENV_ID))
    settings = run_settings(resolved)
    assert settings == {"residual": "myopic", "residual_scale": 0.5}  # the urban entry's, and nothing unused
    attrs = {"n_timesteps": 1000, "n_envs": 8, "normalize": True, "hyperparams": {"gamma": 0.9},
             "settings": settings}
    path = tmp_path / "best.yml"
    path.write_text(yaml.safe_dump(best_entry(SimpleNamespace(user_attrs=attrs), URBAN_ENV_ID, "ppo")))
    args, hp = resolve_args(Args(env_id=URBAN_ENV_ID, hyperparams=str(path)))
    assert (args.residual, args.residual_scale, args.n_envs, hp) == ("myopic", 0.5, 8, {"gamma": 0.9})
    del attrs["settings"]
    assert set(best_entry(SimpleNamespace(user_attrs=attrs), URBAN_ENV_ID, "ppo")["iscc_gym.train"]) == {"algo"}


def test_the_exported_header_names_rl_zoo3_only_for_a_trial_it_can_train(tmp_path):
    """A residual trial's export says python -m train (with its env) trains it and rl-zoo3 does not (it would
    train a plain PPO agent); a trial without run settings names both."""
    from iscc_gym import URBAN_ENV_ID

    s = optuna.create_study(direction="maximize")
    attrs = {"n_timesteps": 1000, "n_envs": 8, "normalize": True, "hyperparams": {"gamma": 0.9},
             "settings": {"residual": "myopic", "residual_scale": 0.5}}
    s.add_trial(optuna.trial.create_trial(value=1.0, user_attrs=attrs))
    path = tmp_path / "best.yml"
    header = [line for line in export_best(s, URBAN_ENV_ID, "ppo", path).splitlines() if line.startswith("#")]
    assert not any("python -m rl_zoo3" in line for line in header)
    assert f"#   python -m train --algo ppo --env {URBAN_ENV_ID} --hyperparams {path}" in header
    assert any("rl-zoo3 ignores" in line and "residual=myopic" in line for line in header)
    del attrs["settings"]
    s.add_trial(optuna.trial.create_trial(value=2.0, user_attrs=attrs))
    assert "python -m rl_zoo3.train --algo ppo" in export_best(s, URBAN_ENV_ID, "ppo", path)


def test_seeds_score_a_recurrent_run(tmp_path):
    """--algo ppo_lstm --seeds: each seed's run is scored by its own algorithm (RecurrentPPO; seed 0 trained,
    then its scoring failed with ``error: ppo_lstm``). One rollout of 2 x 8 slots, one held-out episode of 5."""
    pytest.importorskip("sb3_contrib")
    from iscc_gym.train.multi_seed import run_seeds

    from iscc_gym import URBAN_ENV_ID

    args = Args(env_id=URBAN_ENV_ID, algo="ppo_lstm", total_timesteps=16, n_envs=2, eval_freq=0, checkpoint_freq=0,
                eval_episodes=1, eval_max_steps=5, tensorboard=False, quiet=True, out=str(tmp_path),
                overrides={"n_steps": 8, "batch_size": 16, "n_epochs": 1})
    result = run_seeds(args, [0])
    assert [r["seed"] for r in result["runs"]] == [0] and np.isfinite(result["final_reward_mean"])


def test_a_trials_scenario_overrides_and_constraints_are_exported(tmp_path):
    """Issue 43.15: a study run with --cost-limit, --env-set or --scenario exported its best trial without them. The
    Scenario overrides go into the entry (rl-zoo3's env_kwargs, which python -m train reads); the scenario and the
    constraints into the command the header gives, and rl-zoo3 is not offered."""
    from iscc_gym.train.config import run_flags

    resolved, _ = resolve_args(Args(scenario="literal", env_overrides={"w_rate": 2.0}, cost_limit="rate=0.05",
                                    lagrange_lr=0.1))
    flags = run_flags(resolved)
    assert flags == {"scenario": "literal", "env_overrides": {"w_rate": 2.0}, "cost_limit": "rate=0.05",
                     "lagrange_lr": 0.1}
    assert run_flags(resolve_args(Args())[0]) == {}
    s = optuna.create_study(direction="maximize")
    attrs = {"n_timesteps": 1000, "n_envs": 8, "normalize": True, "hyperparams": {"gamma": 0.9}, "run": flags}
    s.add_trial(optuna.trial.create_trial(value=1.0, user_attrs=attrs))
    path = tmp_path / "best.yml"
    text = export_best(s, "iscc_gym/ISCC-v0", "ppo", path)
    assert ("#   python -m train --algo ppo --env iscc_gym/ISCC-v0 --scenario literal --cost-limit rate=0.05 "
            f"--lagrange-lr 0.1 --hyperparams {path}") in text
    assert "python -m rl_zoo3" not in text
    args, hp = resolve_args(Args(hyperparams=str(path), scenario="literal"))
    assert args.env_overrides == {"w_rate": 2.0} and hp == {"gamma": 0.9}
