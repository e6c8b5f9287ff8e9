"""Static splits: validation of a split (alpha_sen, alpha_ctrl, alpha_comm) and the metrics the
analytic evaluator (:mod:`iscc_gym.analysis`) reports for one.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
from numpy.typing import ArrayLike

from iscc_gym.sim.task import check_split

__all__ = ["AllocationMetrics", "check_alpha"]


@dataclass(frozen=True)
class AllocationMetrics:
    r"""Steady-state figures of static splits, each an array of shape (n,) (or (n, 3) for ``alpha``).

    Attributes
    ----------
    alpha : (n, 3)
        The split (alpha_sen, alpha_ctrl, alpha_comm).
    tracking_error_m :
        Mean tracking error :math:`\mathbb E\|\mathbf p_n - \mathbf p_{\mathrm{ref},n}\|` (inf when
        not mean-square stable).
    tracking_rmse_m :
        :math:`\sqrt{\mathbb E\|\mathbf e_\mathbf p\|^2}` (prob:obj).
    estimation_error_m :
        :math:`\mathbb E\|\hat{\mathbf p}_n - \mathbf p_n\|` of the Kalman estimate.
    peb_m, veb_mps :
        Trajectory-averaged PEB and VEB (large-scale echo, as ``experiments.paper.reproduce``).
    eps_ctrl :
        Trajectory-averaged control packet-loss rate (eq:ctrl_bler over shadowing and fading).
    rho_m :
        Spectral radius of eq:M at ``eps_ctrl``.
    rate_comm_bps :
        Mean data rate (eq:rate_equation over positions, shadowing and fading).
    rate_shortfall :
        Expected normalised shortfall :math:`\mathbb E(R_\min - \mathcal R_{\mathrm{comm},n})^+/R_\min`
        (the env's ``cost_rate``).
    stability_violation :
        Fraction of slots with :math:`\varepsilon_{\mathrm{ctrl},n} > \varepsilon^\star` (the env's
        ``cost_stability``).
    lqg_cost :
        Average LQG cost b (eq:LQG_cost).
    rate_ok :
        ``rate_comm_bps >= rate_min_bps`` (cons:comm_rate on average).
    stable :
        ``eps_ctrl < eps*`` (cons:stability; with ``loss_average="local"`` every position's loss rate).
    trusted :
        Every sampled position's loss rate is at most ``trust_loss_fraction`` x eps*
        (:data:`TRUST_LOSS_FRACTION`): the steady state holds in the env (module docstring).
    feasible :
        ``rate_ok & stable & trusted``.
    objective :
        ``tracking_error_m`` where feasible, else ``max_tracking_error_m`` plus the constraint
        violations (finite, for optimisers; beyond the trust bound the excess loss rate over it).
    expected_reward :
        Steady-state mean per-slot reward of the env: :math:`-\min(\mathbb E\|\mathbf e\|, e_\max)
        - w_\mathrm{rate}\,` ``rate_shortfall`` :math:`- w_\mathrm{stab}\,` ``stability_violation``.
    """

    alpha: np.ndarray
    tracking_error_m: np.ndarray
    tracking_rmse_m: np.ndarray
    estimation_error_m: np.ndarray
    peb_m: np.ndarray
    veb_mps: np.ndarray
    eps_ctrl: np.ndarray
    rho_m: np.ndarray
    rate_comm_bps: np.ndarray
    rate_shortfall: np.ndarray
    stability_violation: np.ndarray
    lqg_cost: np.ndarray
    rate_ok: np.ndarray
    stable: np.ndarray
    trusted: np.ndarray
    feasible: np.ndarray
    objective: np.ndarray
    expected_reward: np.ndarray

    def __getitem__(self, i):
        """Metrics of split(s) ``i`` (an index, slice or mask)."""
        return AllocationMetrics(**{f.name: getattr(self, f.name)[i] for f in fields(self)})

    def as_dict(self, i: int = 0) -> dict:
        """Plain floats (and a list for ``alpha``) of split ``i``, for JSON."""
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)[i]
            out[f.name] = v.tolist() if np.ndim(v) else (bool(v) if v.dtype == bool else float(v))
        return out


def check_alpha(alpha: ArrayLike):
    a = np.asarray(alpha, dtype=float)
    if a.ndim not in (1, 2) or a.shape[-1] != 3:
        raise ValueError(f"alpha must have shape (3,) or (n, 3), got {a.shape}")
    check_split(a)
    return np.maximum(a, 0.0).reshape(-1, 3)
