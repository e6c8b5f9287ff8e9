"""Tuning records of the scripted baselines: ``agents/tuned/<name>.yml``, written by ``python -m eval.tune``.

A record holds the tuned values (``params``), the training seeds they were tuned on (disjoint from every
evaluation seed), the objective and the command; the policies read their defaults from it.
"""

from __future__ import annotations

from pathlib import Path

from iscc_gym.agents.shipped import TUNED_DIR

from iscc_gym.files import write_atomic

__all__ = ["TUNED_DIR", "load_tuned", "save_tuned"]



def load_tuned(name: str, path: str | Path | None = None) -> dict:
    """The tuning record of baseline ``name`` (``agents/tuned/<name>.yml`` unless ``path``).

    Raises
    ------
    FileNotFoundError
        No record: run ``python -m eval.tune <name>``.
    """
    import yaml

    p = Path(path) if path is not None else TUNED_DIR / f"{name}.yml"
    if not p.exists():
        raise FileNotFoundError(f"no tuned parameters for {name!r} at {p}; run `python -m eval.tune {name}`")
    with open(p) as f:
        record = yaml.safe_load(f)
    if not isinstance(record, dict) or "params" not in record:
        raise ValueError(f"{p} is not a tuning record (no 'params' mapping); rerun `python -m eval.tune {name}`")
    return record


def save_tuned(name: str, record: dict, path: str | Path | None = None) -> Path:
    """Write a tuning record atomically (temporary file in the same directory, then rename)."""
    import yaml

    return write_atomic(Path(path) if path is not None else TUNED_DIR / f"{name}.yml",
                        yaml.safe_dump(record, sort_keys=False))
