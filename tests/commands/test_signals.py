"""Issue 43.2: SIGTERM (``kill PID``, ``timeout``, a scheduler's stop) on a pooled command ends its workers too.

Before the fix ``python -m eval`` died at once on SIGTERM and its two spawned workers and the resource tracker
ran on (60 s later). :func:`iscc_gym.commands.cli.run` now turns SIGTERM into
:class:`iscc_gym.commands.cli.Terminated` (a
``KeyboardInterrupt``), so the pool's clean-up ends its processes, and the command exits 143.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _children(pid: int) -> set[int]:
    """Every living descendant of ``pid`` (read from ``/proc``)."""
    parents = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            fields = stat.rsplit(")", 1)[1].split()
            if fields[0] != "Z":  # a zombie is ended, waiting for its parent to reap it
                parents[int(entry.name)] = int(fields[1])
    out, frontier = set(), {pid}
    while frontier:
        frontier = {c for c, p in parents.items() if p in frontier} - out
        out |= frontier
    return out


def _alive(pids) -> set[int]:
    alive = set()
    for pid in pids:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z":
            alive.add(pid)
    return alive


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads the process tree from /proc")
def test_sigterm_on_a_pooled_command_leaves_no_child(tmp_path):
    cmd = [sys.executable, "-m", "eval", "--policies", "myopic,margin,equal", "--episodes", "20", "--workers", "2",
           "--quiet"]
    env = {k: v for k, v in os.environ.items() if k not in ("ISCC_GYM_TRACEBACK",)}
    # output to files, not pipes: an orphaned worker holding a pipe open would keep communicate() waiting
    with open(tmp_path / "out", "w") as out, open(tmp_path / "err", "w") as err:
        proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=out, stderr=err, text=True)
    try:
        # the pool is up when the parent has its two workers and the resource tracker; then the workers play a while
        deadline, seen = time.monotonic() + 240, set()
        while time.monotonic() < deadline and proc.poll() is None:
            seen |= _children(proc.pid)
            if len(_alive(seen)) >= 3:
                break
            time.sleep(0.2)
        assert proc.poll() is None and len(_alive(seen)) >= 3, ("the pool never started", proc.poll(), seen)
        time.sleep(3.0)
        seen |= _children(proc.pid)
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    err = (tmp_path / "err").read_text()
    assert proc.returncode == 143, (proc.returncode, err)
    assert err.strip().endswith("terminated"), err
    deadline = time.monotonic() + 10
    while _alive(seen) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = _alive(seen)
    for pid in left:  # not left behind by the test either
        os.kill(pid, signal.SIGKILL)
    assert not left, f"left running after SIGTERM: {sorted(left)}"


def test_sigterm_raises_terminated_in_a_command_and_exits_143(capsys):
    """In process: the handler :func:`iscc_gym.commands.cli.run` sets for the call turns SIGTERM into ``Terminated`` (so
    ``except BaseException`` clean-ups run), the exit code is 143, and the previous handler is back afterwards."""
    from iscc_gym.commands.cli import Terminated, run

    seen = []

    def main(argv):
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)  # the handler raises before this ends
        except BaseException as e:
            seen.append(type(e))
            raise

    before = signal.getsignal(signal.SIGTERM)
    start = time.monotonic()
    assert run(main, [], prog="cmd") == 143
    assert time.monotonic() - start < 4
    assert seen == [Terminated] and issubclass(Terminated, KeyboardInterrupt)
    assert capsys.readouterr().err == "cmd: terminated\n"
    assert signal.getsignal(signal.SIGTERM) is before
