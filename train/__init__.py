"""Training SB3 agents on the ISCC envs: ``python -m train`` (the repository's ``train/`` folder, installed as
``iscc_gym.train``).

``config`` (:class:`Args`, the hyperparameter file), ``train`` (the training loop, :func:`main`), ``cli`` (the
command line above it), ``runs`` (run directories, checkpoints, resume), ``lagrangian`` (PPO-Lagrangian),
``pretrain`` (behaviour-cloning warm start), ``study``/``study_io``/``multi_seed`` (Optuna studies and seeds).
The runs that produce this repository's shipped agents (``experiments.ship``, ``experiments.multi_agents``,
``experiments.pareto_agents``) are the checkout's ``experiments/``, not installed.
"""

from iscc_gym.train.config import Args, load_hyperparams

from iscc_gym.lazy import lazy_names as _lazy_names

#: Imported on first use (:mod:`iscc_gym.lazy`): the training loop loads torch and SB3, and the command checks its
#: arguments before (issue 43.12).
__getattr__, __dir__ = _lazy_names(__name__, {"cli": ".cli", "console": ".cli", "parse_args": ".cli",
                                              "main": ".train"}, globals())

__all__ = ["Args", "main", "cli", "console", "parse_args", "load_hyperparams"]
