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


_readme_blocks = []


def pytest_collection_finish(session):
    """tests/commands/test_readme.py runs the README's blocks in an interpreter of their own: start it as soon as the
    tests are known, where a selected test reads it, so that it runs beside the tests before that module's."""
    if session.config.option.collectonly:
        return
    for item in session.items:
        if "ran" in getattr(item, "fixturenames", ()) and hasattr(getattr(item, "module", None), "start_readme_blocks"):
            _readme_blocks.append(item.module)
            item.module.start_readme_blocks()
            return


def pytest_sessionfinish(session):
    for module in _readme_blocks:
        module.stop_readme_blocks()


# ISCC_TEST_ULP_NUMPY=1 python -m pytest tests/test_x.py: the tests run as on a CPU whose numpy transcendentals
# differ from libm's in the last bit (AVX-512), in this process and in the Python subprocesses the tests start
# (tests/ulp_numpy.py): a test comparing numba's or math's results with numpy's bit for bit fails (issue 34)
if os.environ.get("ISCC_TEST_ULP_NUMPY") == "1":
    import ulp_numpy

    ulp_numpy.install()
    site = os.path.join(os.path.dirname(os.path.abspath(__file__)), "ulp_site")
    os.environ["PYTHONPATH"] = os.pathsep.join([site] + [p for p in [os.environ.get("PYTHONPATH")] if p])
