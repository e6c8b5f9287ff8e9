"""Search baselines over static allocations: grid search and differential evolution.

Both minimise :attr:`iscc_gym.analysis.allocation.AllocationMetrics.objective` (the steady-state mean tracking
error where the split is feasible, a finite penalty elsewhere) of
:class:`iscc_gym.analysis.StaticModel`, the same evaluator that scores the SCA allocation: the
paper's Table II compares SCA with a grid search and a genetic algorithm on the tracking error.

Neither can pick a split the env cannot hold: a split is ``feasible`` only where the evaluator is
trusted (every sampled position's control loss rate at most
:data:`iscc_gym.analysis.TRUST_LOSS_FRACTION` of eps*; ``docs/model.md`` 3.1), and the objective
penalises the excess loss rate beyond that bound. ``trust_loss_fraction=1.0`` (an evaluate keyword)
leaves only the stability bound.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import LinearConstraint, differential_evolution

from iscc_gym.analysis import StaticModel, static_model
from iscc_gym.scenario import Scenario

from .base import FixedSplitPolicy
from .sca import MIN_SHARE

__all__ = ["SearchResult", "grid_search", "evolutionary_search", "grid_splits"]


@dataclass
class SearchResult:
    """Outcome of a search over static splits.

    Attributes
    ----------
    method : str
        ``"grid"`` or ``"evolutionary"``.
    alpha : ndarray (3,)
        Best split (alpha_sen, alpha_ctrl, alpha_comm).
    objective : float
        Its objective (mean tracking error in m if feasible).
    metrics : dict
        :meth:`iscc_gym.analysis.allocation.AllocationMetrics.as_dict` of the best split.
    n_evaluations : int
        Splits evaluated.
    wall_time_s : float
        Time of the search (the per-scenario model, shared with SCA, is built beforehand).
    policy : FixedSplitPolicy
        Plays ``alpha``.
    """

    method: str
    alpha: np.ndarray
    objective: float
    metrics: dict
    n_evaluations: int
    wall_time_s: float
    policy: FixedSplitPolicy


def grid_splits(step: float) -> np.ndarray:
    """All splits on the lattice of spacing ``step`` with every share at least ``step``, (n, 3).

    Raises
    ------
    ValueError
        ``step`` not in (0, 1/3].
    """
    if not 0.0 < step <= 1.0 / 3.0:
        raise ValueError(f"step = {step!r} is invalid: must be in (0, 1/3]")
    m = int(round(1.0 / step))
    if abs(m * step - 1.0) > 1e-9:
        raise ValueError(f"step = {step!r} is invalid: 1/step must be an integer")
    i, j = np.meshgrid(np.arange(1, m), np.arange(1, m), indexing="ij")
    keep = (i + j) <= m - 1
    a_s, a_c = i[keep] / m, j[keep] / m
    return np.stack([a_s, a_c, 1.0 - a_s - a_c], -1)


def _model(s: Scenario, model: StaticModel | None) -> StaticModel:
    if model is None:
        if not isinstance(s, Scenario):
            raise ValueError(f"scenario must be a Scenario, got {type(s).__name__}")
        return static_model(s)
    return model


def grid_search(scenario: Scenario, step: float = 0.01, model: StaticModel | None = None,
                **evaluate_kwargs) -> SearchResult:
    """Exhaustive search on the lattice :func:`grid_splits` (``step = 0.01``: 4,851 splits).

    Parameters
    ----------
    scenario : Scenario
    step : float
        Lattice spacing (1/step an integer).
    model : StaticModel, optional
        Default: the cached :func:`iscc_gym.analysis.static_model` of ``scenario``.
    **evaluate_kwargs
        Passed to :meth:`StaticModel.evaluate` (``recursion``, ``loss_average``, ``trust_loss_fraction``).

    Returns
    -------
    SearchResult
    """
    m = _model(scenario, model)
    t0 = time.perf_counter()
    splits = grid_splits(step)
    met = m.evaluate(splits, **evaluate_kwargs)
    i = int(np.argmin(met.objective))
    wall = time.perf_counter() - t0
    alpha = splits[i]
    return SearchResult("grid", alpha, float(met.objective[i]), met.as_dict(i), len(splits), wall,
                        FixedSplitPolicy(alpha, name="grid"))


def evolutionary_search(scenario: Scenario, seed: int = 0, model: StaticModel | None = None,
                        popsize: int = 15, maxiter: int = 200, tol: float = 1e-8,
                        **evaluate_kwargs) -> SearchResult:
    """Differential evolution (``scipy.optimize.differential_evolution``) over (alpha_sen, alpha_ctrl).

    ``alpha_comm = 1 - alpha_sen - alpha_ctrl``; bounds ``[MIN_SHARE, 1 - MIN_SHARE]`` and the
    linear constraint ``alpha_sen + alpha_ctrl <= 1 - MIN_SHARE``; infeasible splits (rate,
    stability) carry the evaluator's finite penalty. The population is evaluated as one vectorised
    batch per generation; no gradient polish.

    Parameters
    ----------
    scenario : Scenario
    seed : int
        Seed of the evolution (deterministic for a given seed).
    model : StaticModel, optional
    popsize, maxiter, tol :
        As ``differential_evolution``.
    **evaluate_kwargs
        Passed to :meth:`StaticModel.evaluate`.

    Returns
    -------
    SearchResult
    """
    m = _model(scenario, model)
    t0 = time.perf_counter()
    count = [0]

    def objective(x):
        x = np.atleast_2d(np.asarray(x, dtype=float).T)  # (S, 2) from DE's (2, S)
        alpha = np.column_stack([x, 1.0 - x.sum(1)])
        bad = alpha[:, 2] < 0.0
        alpha[bad, 2] = 0.0
        alpha /= alpha.sum(1, keepdims=True)
        count[0] += len(alpha)
        out = m.evaluate(alpha, **evaluate_kwargs).objective
        return np.where(bad, 1e6, out)

    res = differential_evolution(
        objective, bounds=[(MIN_SHARE, 1.0 - MIN_SHARE)] * 2,
        constraints=LinearConstraint(np.ones((1, 2)), -np.inf, 1.0 - MIN_SHARE),
        seed=seed, popsize=popsize, maxiter=maxiter, tol=tol, polish=False, vectorized=True,
        updating="deferred")
    alpha = np.array([res.x[0], res.x[1], 1.0 - res.x[0] - res.x[1]])
    met = m.evaluate(alpha, **evaluate_kwargs)
    wall = time.perf_counter() - t0
    return SearchResult("evolutionary", alpha, float(met.objective[0]), met.as_dict(0), count[0], wall,
                        FixedSplitPolicy(alpha, name="evolutionary"))
