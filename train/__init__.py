"""Training SB3 agents on the ISCC env: ``python -m train`` (see :mod:`train.train`)."""

from .train import Args, cli, console, load_hyperparams, main, parse_args

__all__ = ["Args", "main", "cli", "console", "parse_args", "load_hyperparams"]
