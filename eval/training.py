"""Training from the eval commands, through ``python -m iscc_gym.train``'s command line only.

``eval`` and ``train`` are siblings (``docs/model.md``, the import directions): neither imports the
other. An eval command that needs a trained agent (``python -m eval --train-steps``) or a training
speed (``python -m eval.bench``) runs the training command in a subprocess and reads the files it
writes into its run directory (``summary.yml``, ``config.yml``).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import yaml

__all__ = ["run_training"]


def run_training(argv: list[str], out: str | Path, quiet: bool = True, env: dict | None = None) -> dict:
    """Run ``python -m iscc_gym.train ARGV --out OUT`` and return ``{"summary": ..., "config": ...}``
    (its ``summary.yml`` and ``config.yml``). ``env``: environment variables set for the run (e.g.
    ``ISCC_GYM_PARALLEL``).

    Raises
    ------
    RuntimeError
        The training command failed (its exit code and last error line are in the message).
    """
    cmd = [sys.executable, "-m", "iscc_gym.train", *map(str, argv), "--out", str(out)]
    if quiet:
        cmd.append("--quiet")
    proc = subprocess.run(cmd, stdout=subprocess.PIPE if quiet else None, stderr=subprocess.PIPE, text=True,
                          env={**os.environ, **(env or {})})
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise RuntimeError(f"python -m iscc_gym.train exited with {proc.returncode}: {last}")
    out = Path(out)
    return {"summary": yaml.safe_load((out / "summary.yml").read_text()),
            "config": yaml.safe_load((out / "config.yml").read_text())}
