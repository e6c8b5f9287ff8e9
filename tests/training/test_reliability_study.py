"""Optuna studies that went wrong without a word (issue 23, defects 8, 9, 10): a journal path that is not a
journal, two studies in one --out, a killed worker's trial left RUNNING on a journal. No training here:
the objectives are tiny fakes, the studies are opened and refused before any trial. The workers that must die or
be capped are forks of the test process (a new interpreter importing iscc_gym took 4-8 s).
"""

from __future__ import annotations

import os
import resource
import signal
import sys
import time
import traceback
from pathlib import Path

import optuna
import pytest
import yaml
from iscc_gym.train import Args, study_io
from iscc_gym.train.cli import cli
from iscc_gym.train.study import StudyArgs, open_study
from iscc_gym.train.study_io import StudyConfigError, make_storage

ROOT = Path(__file__).resolve().parents[2]
#: A budget small enough that a study that is not refused ends in seconds.
TINY = ["--init-policy", "none", "--n-trials", "1", "--n-envs", "2", "--set", "n_steps=32", "--set", "n_epochs=1",
        "--trial-timesteps", "64", "--eval-episodes", "1", "--eval-max-steps", "10", "--no-tensorboard",
        "--n-evaluations", "1"]


def _in_child(fn, *args, timeout: float = 120) -> int:
    """Run ``fn(*args)`` in a forked child (everything already imported) and return its wait status: the exit
    code ``fn`` returns, or minus the signal that killed it. The child never returns into pytest; one still
    running after ``timeout`` s is killed and the test fails."""
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        code = 1
        try:
            code = fn(*args)
        except BaseException:
            traceback.print_exc()
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            return os.waitstatus_to_exitcode(status)
        time.sleep(0.02)
    os.kill(pid, signal.SIGKILL)
    os.waitpid(pid, 0)
    raise AssertionError(f"the child ran longer than {timeout} s")


# --- defect 8: --storage journal:PATH --------------------------------------------------------------------------

def test_journal_on_dev_zero_is_refused_without_reading_it(tmp_path, capfd):
    """/dev/zero was read without end (memory exhausted). Run in a child whose address space may grow by at most
    1.5 GB, so that without the check it dies of MemoryError instead of taking the machine's memory."""
    def child(out):
        pages = int(Path("/proc/self/statm").read_text().split()[0])  # the size the fork starts with
        cap = pages * os.sysconf("SC_PAGE_SIZE") + (1536 << 20)
        resource.setrlimit(resource.RLIMIT_AS, (cap, resource.getrlimit(resource.RLIMIT_AS)[1]))
        try:
            make_storage("journal:/dev/zero", out)
        except StudyConfigError as e:
            print(e)
            return 2
        return 0

    t0 = time.perf_counter()
    code = _in_child(child, str(tmp_path))
    out, err = capfd.readouterr()
    assert code == 2, err[-2000:]
    assert out.startswith("--storage journal:/dev/zero: /dev/zero is not a regular file")
    assert time.perf_counter() - t0 < 60


@pytest.mark.parametrize("content, message", [
    (b"hello, not a journal\n", "is not an Optuna journal"),
    (b"\0" * (2 << 20), "is not an Optuna journal"),  # 2 MB of zeros, no line end: only the first 1 MB is read
    (b'{"a": 1}\n', "is not an Optuna journal"),
    (None, "is a directory"),
], ids=["text", "2MB-of-zeros", "json-not-a-journal", "directory"])
def test_journal_path_that_is_not_a_journal_is_refused_naming_storage(tmp_path, content, message):
    path = tmp_path / "study.log"
    if content is None:
        path.mkdir()
    else:
        path.write_bytes(content)
    with pytest.raises(StudyConfigError, match=rf"^--storage journal:{path}: {path} {message}"):
        make_storage(f"journal:{path}", tmp_path)
    assert content is None or path.read_bytes() == content  # left as it was


def test_new_empty_and_existing_journals_are_accepted(tmp_path):
    new = tmp_path / "new.log"
    storage, _ = make_storage(f"journal:{new}", tmp_path)
    optuna.create_study(storage=storage, study_name="s").optimize(lambda t: t.suggest_float("x", 0, 1), n_trials=1)
    again, _ = make_storage(f"journal:{new}", tmp_path)  # the journal it wrote
    assert len(optuna.load_study(study_name="s", storage=again).trials) == 1
    (tmp_path / "empty.log").write_bytes(b"")
    make_storage(f"journal:{tmp_path / 'empty.log'}", tmp_path)


# --- defect 9: a second study in the same --out ------------------------------------------------------------------

def _open(out: Path, name: str | None):
    return open_study(Args(out=str(out), init_policy="none"), StudyArgs(study_name=name))


def test_second_study_in_the_same_out_is_refused_naming_both(tmp_path):
    """The second study's trial_0 went into the first study's OUT/trial_0 and was recorded as failed."""
    s, shown = _open(tmp_path, "first")
    assert yaml.safe_load((tmp_path / "study.yml").read_text()) == {"study_name": "first", "storage": shown}
    with pytest.raises(StudyConfigError, match=rf"--out {tmp_path}: holds the trials of study 'first' .*study "
                                               r"'second' would overwrite them .*--study-name first"):
        _open(tmp_path, "second")
    assert [x.study_name for x in optuna.get_all_study_summaries(shown)] == ["first"]  # nothing created
    again, _ = _open(tmp_path, "first")  # the same study joins, as a second worker does
    assert again.study_name == "first"


def test_second_study_is_refused_on_the_command_line_before_any_trial(tmp_path, capsys):
    _open(tmp_path, "first")
    with pytest.raises(SystemExit) as exc:
        cli(["--optimize", "--study-name", "second", "--out", str(tmp_path), *TINY])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "holds the trials of study 'first'" in err[0]
    assert not list(tmp_path.glob("trial_*"))


def test_out_with_trials_of_an_earlier_study_and_no_record_is_refused(tmp_path):
    (tmp_path / "trial_0").mkdir()
    with pytest.raises(StudyConfigError, match=r"holds trial directories of an earlier study \(trial_0\)"):
        _open(tmp_path, "fresh")


# --- defect 10: a killed worker's trial on a journal ---------------------------------------------------------

def test_killed_workers_trial_on_a_journal_is_failed_and_retried(tmp_path, monkeypatch):
    """A worker killed mid-trial (SIGKILL: no clean-up) left its trial RUNNING for ever on a journal
    (SQLite's heartbeat recovered it). Now the next worker fails it and runs its parameters again."""
    journal = tmp_path / "study.log"

    def worker():
        storage, _ = make_storage(f"journal:{journal}", tmp_path)
        study = optuna.create_study(storage=storage, study_name="s", direction="maximize")

        def objective(trial):
            trial.suggest_float("x", 0.0, 1.0)
            os.kill(os.getpid(), signal.SIGKILL)

        study.optimize(objective, n_trials=1)
        return 0

    monkeypatch.setattr(study_io, "HEARTBEAT_INTERVAL_S", 0.2)
    monkeypatch.setattr(study_io, "GRACE_PERIOD_S", 0.5)
    assert _in_child(worker) == -signal.SIGKILL
    (dead,) = optuna.load_study(study_name="s", storage=make_storage(f"journal:{journal}", tmp_path)[0]).trials
    assert dead.state == optuna.trial.TrialState.RUNNING

    time.sleep(1.0)  # the dead worker's last heartbeat is now older than the grace period
    storage, _ = make_storage(f"journal:{journal}", tmp_path)
    study = optuna.load_study(study_name="s", storage=storage)
    seen = []
    study.optimize(lambda t: seen.append(t.suggest_float("x", 0.0, 1.0)) or 1.0, n_trials=1)
    trials = sorted(study.trials, key=lambda t: t.number)
    assert [t.state for t in trials] == [optuna.trial.TrialState.FAIL, optuna.trial.TrialState.COMPLETE]
    assert seen == [dead.params["x"]]  # the retry ran the dead trial's parameters
    assert trials[1].system_attrs["failed_trial"] == dead.number


def test_live_trials_keep_beating_and_are_not_failed(tmp_path, monkeypatch):
    """A trial longer than the grace period whose worker is alive is never failed: its heartbeat thread
    writes into the journal every interval."""
    monkeypatch.setattr(study_io, "HEARTBEAT_INTERVAL_S", 0.4)
    monkeypatch.setattr(study_io, "GRACE_PERIOD_S", 1.0)
    storage, _ = make_storage(f"journal:{tmp_path / 'j.log'}", tmp_path)
    study = optuna.create_study(storage=storage, study_name="s")
    other = make_storage(f"journal:{tmp_path / 'j.log'}", tmp_path)[0]  # a second worker's view

    def slow(trial):
        time.sleep(1.8)
        return float(len(other._get_stale_trial_ids(study._study_id)))  # checked while this one runs

    study.optimize(slow, n_trials=1)
    (t,) = study.trials
    assert t.state == optuna.trial.TrialState.COMPLETE and t.value == 0.0
    assert t.system_attrs[study_io.HEARTBEAT_ATTR] > t.datetime_start.timestamp() + 1.0  # beat past the grace
