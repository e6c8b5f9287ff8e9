"""On ``PYTHONPATH`` only with ``ISCC_TEST_ULP_NUMPY=1`` (tests/conftest.py): a test's Python subprocesses get the
one-ulp-off numpy of ``tests/ulp_numpy.py`` too."""

import os

if os.environ.get("ISCC_TEST_ULP_NUMPY") == "1":
    import importlib.util

    _path = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "ulp_numpy.py")
    _spec = importlib.util.spec_from_file_location("ulp_numpy", _path)
    _module = importlib.util.module_from_spec(_spec)
    _spec.loader.exec_module(_module)
    _module.install()
