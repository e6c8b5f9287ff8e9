"""Stable-Baselines3 logging without side effects, shared by training and the speed benchmark."""

from __future__ import annotations

__all__ = ["stdout_logger"]


def stdout_logger(verbose: int):
    """An SB3 logger that writes to stdout (``verbose`` >= 1) or nowhere, and creates no folder.

    Without TensorBoard, SB3's own default (``configure(None, ...)``) makes an empty
    ``$TMPDIR/SB3-<date>`` folder per ``learn`` call; a run of this project leaves nothing behind.
    """
    import sys

    from stable_baselines3.common.logger import HumanOutputFormat, Logger

    return Logger(folder=None, output_formats=[HumanOutputFormat(sys.stdout)] if verbose >= 1 else [])
