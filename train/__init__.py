"""Training SB3 agents on the ISCC envs: ``python -m train`` (the repository's ``train/`` folder, installed as
``iscc_gym.train``).

``config`` (:class:`Args`, the hyperparameter file), ``train`` (the training loop, :func:`main`), ``cli`` (the
command line above it), ``runs`` (run directories, checkpoints, resume), ``lagrangian`` (PPO-Lagrangian),
``pretrain`` (behaviour-cloning warm start), ``study``/``study_io``/``multi_seed`` (Optuna studies and seeds).
The runs that produce this repository's shipped agents (``experiments.ship``, ``experiments.multi_agents``,
``experiments.pareto_agents``) are the checkout's ``experiments/``, not installed.
"""

import importlib as _importlib

from iscc_gym.train.config import Args, load_hyperparams

#: Imported on first use (PEP 562): the training loop loads torch and SB3, and the command checks its arguments
#: before (issue 43.12).
_LAZY = {"cli": "cli", "console": "cli", "parse_args": "cli", "main": "train"}


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(_importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

__all__ = ["Args", "main", "cli", "console", "parse_args", "load_hyperparams"]
