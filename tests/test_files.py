"""iscc_gym.files.write_atomic: a failed write leaves the old file whole and no temporary file."""

import pytest

from iscc_gym.files import write_atomic


def test_write_replaces_and_creates_parents(tmp_path):
    p = tmp_path / "a" / "b.yml"
    assert write_atomic(p, "one") == p and p.read_text() == "one"
    write_atomic(p, "two")
    assert p.read_text() == "two" and [q.name for q in p.parent.iterdir()] == ["b.yml"]


def test_failed_write_keeps_the_old_file(tmp_path, monkeypatch):
    """Interrupted after the temporary file is written, before the rename: the old file stays whole."""
    import os

    p = tmp_path / "b.yml"
    p.write_text("old")

    def killed(*args):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", killed)
    with pytest.raises(KeyboardInterrupt):
        write_atomic(p, "new")
    assert p.read_text() == "old" and [q.name for q in tmp_path.iterdir()] == ["b.yml"]
