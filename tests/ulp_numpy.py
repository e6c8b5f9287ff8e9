"""A CPU whose numpy transcendentals differ from libm in the last bit, emulated (``ISCC_TEST_ULP_NUMPY=1``).

On a CPU with AVX-512 numpy evaluates float64 exp and log (and, built with SVML, sin, cos, tan, arctan2, power,
log1p, expm1, log10, ...) with its own SIMD code, whose results can differ in the last bit from libm's, what
``math`` and numba-compiled code call; on other CPUs numpy calls libm too. A test that wants numba's or math's
result bit-equal to numpy's therefore passes on one CPU and fails on the other (issue 34).
``ISCC_TEST_ULP_NUMPY=1 python -m pytest tests/test_x.py`` runs tests as on such a CPU: every Python-level call of
the ufuncs in :data:`ULP_UFUNCS` returns its floating results one ulp towards +inf (integers, infinities and NaNs
as they are: a SIMD routine gets exp(0) and log(1) exact), while numba-compiled code that names ``np.exp`` still
compiles to libm's (the wrapper types as the ufunc it wraps). ``tests/conftest.py`` installs it in the test
process and, through ``tests/ulp_site/sitecustomize.py`` on ``PYTHONPATH``, in every Python subprocess the tests
start (their workers see the same numpy as the test). Not covered: ``a ** b`` on arrays, which reaches numpy's
power without the module attribute. Golden digests belong to a processor, and this is another one
(``tests/env/test_golden.py`` skips).
"""

from __future__ import annotations

import numpy as np

ULP_UFUNCS = ("exp", "exp2", "expm1", "log", "log2", "log10", "log1p", "sin", "cos", "tan", "arcsin", "arccos",
              "arctan", "arctan2", "sinh", "cosh", "tanh", "arcsinh", "arccosh", "arctanh", "power", "cbrt")


def one_ulp_up(r):
    """``r`` (a ufunc's result: array, numpy scalar or ``out=`` array, changed in place) with its non-integer finite
    floating values moved one ulp towards +inf."""
    arr = np.asarray(r)
    if arr.dtype.kind != "f":
        return r
    with np.errstate(all="ignore"):  # a subnormal's step is no underflow of the caller's
        moved = np.where(np.isfinite(arr) & (arr != np.round(arr)), np.nextafter(arr, np.inf, dtype=arr.dtype), arr)
    if isinstance(r, np.ndarray):
        np.copyto(r, moved)
        return r
    return arr.dtype.type(moved)


class UlpUfunc:
    """``ufunc`` whose results :func:`one_ulp_up` moves; every attribute (nin, reduce, types, ...) the ufunc's."""

    def __init__(self, ufunc: np.ufunc):
        self.ufunc = ufunc
        self.__name__ = ufunc.__name__

    def __getattr__(self, name):
        return getattr(self.ufunc, name)

    def __repr__(self):
        return f"<{self.ufunc.__name__} one ulp off>"

    def __call__(self, *args, **kwargs):
        return one_ulp_up(self.ufunc(*args, **kwargs))


def compile_as_the_real_ufuncs() -> None:
    """Make numba type a :class:`UlpUfunc` as the ufunc it wraps, so that compiled code naming it calls libm's."""
    from numba.core.registry import cpu_target
    from numba.extending import typeof_impl

    if UlpUfunc in typeof_impl.registry:
        return
    # numba keys its typing and lowering of ufuncs by the objects it finds on numpy when it first loads them
    cpu_target.typing_context.refresh()
    cpu_target.target_context.refresh()

    @typeof_impl.register(UlpUfunc)
    def _typeof_ulp_ufunc(val, c):
        return cpu_target.typing_context.resolve_value_type(val.ufunc)


def install() -> None:
    """Replace numpy's :data:`ULP_UFUNCS` by :class:`UlpUfunc` wrappers, numba still compiling the real ones."""
    compile_as_the_real_ufuncs()
    for name in ULP_UFUNCS:
        if not isinstance(getattr(np, name), UlpUfunc):
            setattr(np, name, UlpUfunc(getattr(np, name)))
