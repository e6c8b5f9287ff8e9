"""The experiment protocol: which missions train, tune and evaluate, and the studies' shared constants.

A mission is a seed of ``env.reset(seed=...)``. The rules every command follows, written once:

- **Held-out evaluation seeds** lie in :data:`EVAL_SEED_RANGES`: the comparisons of ``python -m eval`` start
  at :data:`EVAL_SEED_START`; the training run's EvalCallback plays :data:`CALLBACK_EVAL_SEED_START` + i;
  each study of ``eval`` draws its missions from its own start inside the upper range (:func:`held_out_seeds`):
  :data:`FADING_SEED_START`, :data:`SENSITIVITY_SEED_START`, :data:`PARETO_SEED_START`,
  :data:`MULTI_SEED_START`, :data:`URBAN_SEED_START`.
- **Training and tuning seeds** stay outside those ranges (checked: :func:`check_outside_evaluation`): PPO
  trains on small integers, the warm start's missions start at :data:`INIT_SEED_START`, the scripted
  baselines are tuned on :data:`TUNE_SEEDS`, the reproduction calibrates on :data:`CALIBRATION_SEED_START` + i.

Used by ``agents``, ``train`` and ``eval``; the core (physics, sim, envs, analysis) never imports it
(``tests/commands/test_imports.py``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["EVAL_SEED_RANGES", "EVAL_SEED_START", "CALLBACK_EVAL_SEED_START", "INIT_SEED_START", "TUNE_SEED_START",
           "TUNE_SEEDS", "CALIBRATION_SEED_START", "FADING_SEED_START", "SENSITIVITY_SEED_START", "PARETO_SEED_START",
           "MULTI_SEED_START", "URBAN_SEED_START", "PARETO_RATE_MIN_BPS", "held_out_seeds", "check_outside_evaluation"]

#: The held-out evaluation seeds, each range [start, stop). Training and tuning seeds must avoid them.
EVAL_SEED_RANGES = ((10_000, 11_000), (1_000_000, 2_000_000))
#: First mission of ``python -m eval`` (and ``experiments.seeds``): the comparisons' held-out missions.
EVAL_SEED_START = 10_000
#: Seeds of the training run's EvalCallback episodes start here (its held-out missions, ``best/``).
CALLBACK_EVAL_SEED_START = 1_000_000
#: The behaviour-cloning warm start's missions: ``INIT_SEED_START + 1000 * seed + i`` (training seeds).
INIT_SEED_START = 200_000
#: First tuning seed (training seeds for the scripted baselines: ``eval.tune``, ``eval.outage``,
#: ``experiments.pareto``).
TUNE_SEED_START = 500_000
#: Default tuning seeds.
TUNE_SEEDS = tuple(range(TUNE_SEED_START, TUNE_SEED_START + 40))
#: The reproduction's calibration missions (``experiments.paper.reproduce``): training seeds.
CALIBRATION_SEED_START = 600_000
#: The held-out missions of the studies, ``start + 1000 * run_seed + i`` inside the upper evaluation range.
FADING_SEED_START = 1_100_000
SENSITIVITY_SEED_START = 1_200_000
PARETO_SEED_START = 1_300_000
MULTI_SEED_START = 1_400_000
URBAN_SEED_START = 1_500_000
#: The Pareto study's data-rate requirement R_min (bit/s): the learned operating points
#: (``experiments.pareto_agents``) are trained and compared (``experiments.pareto``) at this value; at the ``paper``
#: preset's 20 Mbps no split meets a 5 % or 10 % rate-outage target (docs/model.md 4.6).
PARETO_RATE_MIN_BPS = 12e6


def seed_list(start: int, n: int) -> list[int]:
    """``n`` consecutive mission seeds from ``start`` (``start``, ``start + 1``, ...): every command's missions."""
    return list(range(int(start), int(start) + int(n)))


def held_out_seeds(start: int, n: int, seed: int = 0) -> list[int]:
    """``n`` mission seeds for run ``seed`` from ``start``: ``start + 1000 * seed + i``.

    Raises
    ------
    ValueError
        ``seed`` is not an integer >= 0, ``n`` is outside [1, 1000], or a mission leaves the upper evaluation
        range.
    """
    lo_range, hi_range = EVAL_SEED_RANGES[-1]
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed = {seed!r} is invalid: use an integer >= 0")
    if not 1 <= n <= 1000:
        raise ValueError(f"n = {n!r} missions is invalid: use 1 to 1000 per run seed")
    seeds = seed_list(start + 1000 * int(seed), n)
    if seeds[0] < lo_range or seeds[-1] >= hi_range:
        raise ValueError(f"seed = {seed}: missions {seeds[0]}-{seeds[-1]} leave the held-out evaluation range "
                         f"[{lo_range}, {hi_range}); use a seed below {(hi_range - start) // 1000}")
    return seeds


def check_outside_evaluation(lo: int, hi: int, what: str, fix: str) -> None:
    """Refuse training or tuning seeds ``lo``-``hi`` (inclusive) that overlap an evaluation range.

    Raises
    ------
    ValueError
        Naming ``what`` the seeds are, the range they overlap, and ``fix``.
    """
    for start, stop in EVAL_SEED_RANGES:
        if lo < stop and hi >= start:
            span = f"{lo} lies" if lo == hi else f"{lo}-{hi} overlap"
            raise ValueError(f"{what} {span} in the held-out evaluation range [{start}, {stop}); {fix}")
