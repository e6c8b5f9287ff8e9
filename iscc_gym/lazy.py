"""Names a package imports on first use (PEP 562), so that importing it loads only what its light names need.

``import iscc_gym`` registers the env ids and ``import iscc_gym.agents`` gives the task tables without loading the
compiled env, the policies or torch; a command checks its arguments before any of them load (issue 43.12). The
names listed are imported from their module the first time they are read, then kept in the package's namespace.
"""

from __future__ import annotations

import importlib
import importlib.util
from collections.abc import Callable, Mapping

__all__ = ["lazy_names"]


def lazy_names(package: str, table: Mapping[str, str], namespace: dict) -> tuple[Callable, Callable]:
    """``(__getattr__, __dir__)`` for package ``package``: each name of ``table`` imported on first use from its
    module (absolute, or relative to ``package`` with a leading dot) and stored in ``namespace`` (the package's
    ``globals()``); a submodule's name imports it (``iscc_gym.envs`` after ``import iscc_gym``, as when the package
    imported it itself); any other name an ``AttributeError``.
    """
    def __getattr__(name: str):
        if name in table:
            value = getattr(importlib.import_module(table[name], package), name)
            namespace[name] = value
            return value
        if not name.startswith("_") and importlib.util.find_spec(f"{package}.{name}") is not None:
            return importlib.import_module(f"{package}.{name}")  # a submodule, as an eager package gave it
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__():
        return sorted([*namespace, *table])

    return __getattr__, __dir__
