"""The emulated CPU of ``ISCC_TEST_ULP_NUMPY=1`` (tests/ulp_numpy.py, issue 34): numpy's transcendentals one ulp
off for Python callers, compiled code still on libm's."""

import math

import numpy as np
from numba import njit
from ulp_numpy import UlpUfunc, compile_as_the_real_ufuncs


def test_one_ulp_off_numpy_moves_python_calls_and_leaves_compiled_code_on_libm(monkeypatch):
    compile_as_the_real_ufuncs()
    real_exp, real_log = (getattr(f, "ufunc", f) for f in (np.exp, np.log))  # the real ones, also in that mode
    monkeypatch.setattr(np, "exp", UlpUfunc(real_exp))
    monkeypatch.setattr(np, "log", UlpUfunc(real_log))
    assert np.exp(0.5) == np.nextafter(real_exp(0.5), np.inf) and type(np.exp(0.5)) is np.float64
    with np.errstate(all="ignore"):  # exact values, NaN and infinity as they are
        assert np.exp(0.0) == 1.0 and np.log(1.0) == 0.0 and np.isnan(np.log(-1.0)) and np.exp(1e3) == np.inf
    x = np.array([0.5, 2.0], np.float32)
    out = np.empty(2, np.float32)
    assert np.log(x, out=out) is out and out[1] == np.nextafter(real_log(x)[1], np.float32(np.inf))

    @njit
    def compiled(v):
        return np.exp(v) + np.log(v)

    assert compiled(0.5) == math.exp(0.5) + math.log(0.5)  # numba's and math's: both libm's
