"""The env on a GPU: the project's step source compiled by numba-cuda as one kernel (:mod:`iscc_gym.gpu.kernel`),
a device-resident vector env with torch tensors shared without copies (:mod:`iscc_gym.gpu.vector_env`), and a CPU
stand-in of it that runs the same row function through numba's CPU compiler (tests, machines without a GPU).

The extra ``pip install -e ".[gpu]"`` adds numba-cuda (the CPU stand-in needs only the core install and torch);
``docs/gpu.md`` holds the design notes (the pin, the NumPy shim, numba-cuda's maintenance status).
"""

from iscc_gym.lazy import lazy_names as _lazy_names

# a submodule on first use (iscc_gym.gpu.<module> after import iscc_gym, as when iscc_gym imported the env eagerly)
__getattr__, __dir__ = _lazy_names(__name__, {}, globals())
