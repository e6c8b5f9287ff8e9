"""Test-session settings: caches and logs that libraries put in $TMPDIR go under pytest's own temporary
directory (removed by pytest's retention policy), so a test run leaves no stray folders behind."""

import os

import pytest


@pytest.fixture(scope="session", autouse=True)
def _library_folders_in_pytest_tmp(tmp_path_factory):
    base = tmp_path_factory.mktemp("library-folders")
    names = {"TORCHINDUCTOR_CACHE_DIR": base / "torchinductor", "SB3_LOGDIR": base / "sb3"}
    old = {k: os.environ.get(k) for k in names}
    os.environ.update({k: str(v) for k, v in names.items()})  # inherited by the tests' subprocesses too
    yield
    for k, v in old.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v
