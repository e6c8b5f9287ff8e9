"""numba-cuda, imported once with what it needs, and what this machine can do with it.

numba-cuda (pinned ``numba-cuda>=0.30.4,<0.31`` in the ``gpu`` extra) uses ``np.row_stack``, which NumPy 2.5 removed:
:func:`import_cuda` sets it to ``np.vstack`` (the same function) before the import where it is missing. The
simulator (``NUMBA_ENABLE_CUDASIM=1`` in the environment before numba is imported) runs kernels as Python on the
CPU: the tests use it on tiny batches.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np

__all__ = ["import_cuda", "simulator", "cuda_available", "toolkit_for_ptx", "INSTALL_HINT"]

INSTALL_HINT = 'pip install -e ".[gpu]" (numba-cuda; install CPU torch first, see the README)'


def import_cuda():
    """``numba.cuda``, with NumPy >= 2.5's missing ``row_stack`` restored first.

    Raises
    ------
    ImportError
        numba-cuda is not installed (naming the extra that installs it).
    """
    if not hasattr(np, "row_stack"):  # NumPy >= 2.5 removed it; numba-cuda <= 0.30.4 still calls it
        # setattr, not an assignment: ruff's NumPy-2 fix (NPY201) rewrites ``np.row_stack`` to ``np.vstack``
        setattr(np, "row_stack", np.vstack)  # noqa: B010
    try:
        from numba import cuda
    except ImportError as e:  # pragma: no cover - depends on the install
        raise ImportError(f"the GPU path needs numba-cuda: {INSTALL_HINT} ({e})") from None
    if not hasattr(cuda, "jit"):  # a stub without numba-cuda
        raise ImportError(f"the GPU path needs numba-cuda: {INSTALL_HINT}")
    return cuda


def simulator() -> bool:
    """True where numba runs CUDA kernels in its simulator (``NUMBA_ENABLE_CUDASIM=1``)."""
    from numba import config

    return bool(config.ENABLE_CUDASIM)


def cuda_available() -> bool:
    """True where kernels can run: a CUDA GPU with its driver, or the simulator."""
    try:
        cuda = import_cuda()
    except ImportError:
        return False
    return simulator() or bool(cuda.is_available())


def toolkit_for_ptx() -> str | None:
    """Why a PTX compile cannot run here (None where it can): libNVVM from the CUDA toolkit (``CUDA_HOME``, or
    ``nvcc`` on the PATH) and NVRTC (the ``nvidia-cuda-nvrtc`` wheel or the toolkit's) are needed, not a GPU.
    """
    try:
        import_cuda()
    except ImportError as e:
        return str(e)
    if simulator():
        return "NUMBA_ENABLE_CUDASIM=1: the simulator compiles nothing"
    home = _toolkit_home()
    if home is None:
        return ("no CUDA toolkit found (libNVVM and libdevice): set CUDA_HOME to the toolkit's folder (the one holding "
                "nvvm/libdevice)")
    os.environ.setdefault("CUDA_HOME", home)
    try:
        from cuda.pathfinder import load_nvidia_dynamic_lib

        load_nvidia_dynamic_lib("nvrtc")
    except Exception as e:  # noqa: BLE001 - any failure to find the library is the same answer
        return f"no NVRTC library ({type(e).__name__}): pip install nvidia-cuda-nvrtc"
    return None


def _toolkit_home() -> str | None:
    """The first CUDA toolkit folder holding ``nvvm/libdevice``: ``CUDA_HOME``, ``CUDA_PATH``, ``/usr/local/cuda``, then
    the folder above the ``bin`` of ``nvcc`` on the PATH.
    """
    nvcc = shutil.which("nvcc")
    candidates = [os.environ.get("CUDA_HOME"), os.environ.get("CUDA_PATH"), "/usr/local/cuda",
                  str(Path(nvcc).resolve().parent.parent) if nvcc else None]
    for home in candidates:
        if home and (Path(home) / "nvvm" / "libdevice").is_dir():
            return home
    return None
