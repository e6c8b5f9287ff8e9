"""iscc_gym.files.write_atomic: a failed write leaves the old file whole and no temporary file."""

import os
import stat
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from iscc_gym.files import atomic_dir, atomic_target, create_exclusive, destination, write_atomic

ROOT = Path(__file__).resolve().parents[2]


def test_write_replaces_and_creates_parents(tmp_path):
    p = tmp_path / "a" / "b.yml"
    assert write_atomic(p, "one") == p and p.read_text() == "one"
    write_atomic(p, "two")
    assert p.read_text() == "two" and [q.name for q in p.parent.iterdir()] == ["b.yml"]


def test_failed_write_keeps_the_old_file(tmp_path, monkeypatch):
    """Interrupted after the temporary file is written, before the rename: the old file stays whole."""
    p = tmp_path / "b.yml"
    p.write_text("old")

    def killed(*args):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", killed)
    with pytest.raises(KeyboardInterrupt):
        write_atomic(p, "new")
    assert p.read_text() == "old" and [q.name for q in tmp_path.iterdir()] == ["b.yml"]


# --- destinations that are not regular files are written through, never replaced (issue 23, defect 7) -----

def test_write_through_symlink_keeps_link(tmp_path):
    target = tmp_path / "results" / "a.json"
    target.parent.mkdir()
    target.write_text("old")
    link = tmp_path / "latest.json"
    link.symlink_to(Path("results") / "a.json")  # relative, as `ln -s` makes them
    write_atomic(link, "new")
    assert link.is_symlink() and os.readlink(link) == str(Path("results") / "a.json")
    assert target.read_text() == "new"
    assert sorted(p.name for p in target.parent.iterdir()) == ["a.json"]  # no temporary file left
    assert sorted(p.name for p in tmp_path.iterdir()) == ["latest.json", "results"]


def test_write_through_dangling_symlink_creates_its_target(tmp_path):
    link = tmp_path / "out.json"
    link.symlink_to(tmp_path / "new" / "made.json")
    write_atomic(link, "x")
    assert link.is_symlink() and (tmp_path / "new" / "made.json").read_text() == "x"


def test_write_into_fifo_keeps_the_fifo(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_text()), daemon=True)
    reader.start()
    write_atomic(fifo, "through the pipe")
    reader.join(timeout=10)
    assert got == ["through the pipe"]
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() != 0, reason="making a device node needs root")
def test_write_into_device_keeps_the_device(tmp_path):
    """As root a rename would replace a device node by a regular file: a copy of /dev/null here."""
    null = tmp_path / "null"
    os.mknod(null, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    write_atomic(null, "discarded")
    with atomic_target(null) as tmp:
        tmp.write_bytes(b"\0" * 10)
    assert stat.S_ISCHR(os.lstat(null).st_mode) and os.lstat(null).st_rdev == os.makedev(1, 3)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["null"]


@pytest.mark.parametrize("how", ["link to /dev/stdout", "/dev/fd/1", "/proc/self/fd/1"])
def test_write_to_stdout_keeps_printed_lines_in_order(tmp_path, how):
    """``--json /dev/stdout > out.txt``: the JSON lands in the redirected stdout after what was printed
    before it (Python's buffer is flushed first) and before what is printed after, and the shell's
    file is not replaced (a rename would leave the printed lines in a deleted file)."""
    if how == "link to /dev/stdout":
        dest = tmp_path / "stdout.json"
        dest.symlink_to("/dev/stdout")
    else:
        dest = Path(how)
    code = ("import importlib.util, sys\n"  # iscc_gym/files.py alone: the package's import takes seconds
            "spec = importlib.util.spec_from_file_location('files', sys.argv[2])\n"
            "files = importlib.util.module_from_spec(spec)\nspec.loader.exec_module(files)\n"
            "print('printed before')\n"
            "files.write_atomic(sys.argv[1], '{\"json\": 1}\\n')\nprint('printed after')\n")
    out = tmp_path / "out.txt"
    with open(out, "w") as f:
        r = subprocess.run([sys.executable, "-c", code, str(dest), str(ROOT / "iscc_gym" / "files.py")], stdout=f,
                           stderr=subprocess.PIPE, text=True, cwd=tmp_path, timeout=60)
    assert r.returncode == 0, r.stderr
    assert out.read_text() == 'printed before\n{"json": 1}\nprinted after\n'
    if how == "link to /dev/stdout":
        assert dest.is_symlink()


def test_failed_writer_sends_nothing_to_a_stream():
    r, w = os.pipe()
    try:
        with pytest.raises(RuntimeError, match="writer failed"), atomic_target(f"/proc/self/fd/{w}") as tmp:
            tmp.write_text("half")
            raise RuntimeError("writer failed")
        os.close(w)
        w = -1
        assert os.read(r, 100) == b""  # end of file: nothing was sent
    finally:
        os.close(r)
        if w >= 0:
            os.close(w)


def test_directory_is_refused_naming_it(tmp_path):
    with pytest.raises(IsADirectoryError, match=f"{tmp_path}: is a directory"):
        write_atomic(tmp_path, "x")
    assert destination(tmp_path / "missing.yml") == ("file", tmp_path / "missing.yml")
    (tmp_path / "a.txt").write_text("")
    assert destination(tmp_path / "a.txt" / "b.yml") == ("file", tmp_path / "a.txt" / "b.yml")  # fails on writing


def test_writable_check_accepts_what_is_written_through(tmp_path):
    """``--json /dev/stdout`` passes the commands' check before the run (it probed /dev for a new file,
    which only root may create) and a link is checked where its target is written."""
    from iscc_gym.commands.options import check_writable_file

    assert check_writable_file("/dev/stdout", "--json") == Path("/dev/stdout")
    assert check_writable_file("/dev/null", "--json") == Path("/dev/null")
    (tmp_path / "ro").mkdir()
    link = tmp_path / "ro" / "out.json"
    link.symlink_to(tmp_path / "elsewhere" / "out.json")
    assert check_writable_file(link, "--json") == link


def test_create_exclusive_creates_once_whole(tmp_path):
    p = tmp_path / "d" / "study.yml"
    assert create_exclusive(p, "first") is True
    assert create_exclusive(p, "second") is False
    assert p.read_text() == "first" and sorted(q.name for q in p.parent.iterdir()) == ["study.yml"]


@pytest.mark.parametrize("exchange", [True, False])
def test_atomic_dir_swaps_a_folder_in_whole_or_leaves_the_old_one(tmp_path, monkeypatch, exchange):
    """Filled then swapped in (one exchange, or two renames where the file system has none); a failure while
    filling leaves the old folder as it was and nothing beside it."""
    import iscc_gym.files as files

    if not exchange:
        monkeypatch.setattr(files, "_exchange", lambda a, b: False)
    d = tmp_path / "agent"
    for text in ("old", "new"):
        with atomic_dir(d) as tmp:
            (tmp / "a").write_text(text)
            (tmp / text).write_text(text)
    assert sorted(p.name for p in d.iterdir()) == ["a", "new"] and (d / "a").read_text() == "new"
    with pytest.raises(KeyboardInterrupt), atomic_dir(d) as tmp:
        (tmp / "a").write_text("newer")
        raise KeyboardInterrupt
    assert (d / "a").read_text() == "new" and [p.name for p in tmp_path.iterdir()] == ["agent"]
