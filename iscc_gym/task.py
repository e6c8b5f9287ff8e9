"""The task's numpy API: the action map and the reward and costs, for arrays of any batch shape.

Each is written once, compiled (:func:`iscc_gym.kernel.split_one`, :func:`iscc_gym.kernel.reward_one`,
what the env step applies); these functions evaluate the same code on numpy arrays.
:mod:`iscc_gym.env` re-exports them. The independent numpy formulas are test oracles
(``tests/oracle_env.py``, ``tests/oracle_loop.py``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from . import kernel
from .scenario import Scenario

__all__ = ["action_to_split", "split_to_action", "reward_and_costs"]


def action_to_split(action: ArrayLike):
    r"""Map an action in [-1, 1]^3 onto the simplex (alpha_sen, alpha_ctrl, alpha_comm).

    .. math:: w_i = (\mathrm{clip}(a_i, -1, 1) + 1)/2,\qquad \alpha_i = w_i / \textstyle\sum_j w_j

    and the equal split where every w_i = 0. Every split is reachable (see :func:`split_to_action`),
    including zero shares: there is no minimum share. Broadcasts over leading axes (shape (..., 3)).
    Evaluated by :func:`iscc_gym.kernel.split_one`, the map the compiled env step applies.
    """
    a = np.asarray(action, dtype=float)
    if a.ndim == 0 or a.shape[-1] != 3:
        raise ValueError(f"action must have shape (..., 3), got {a.shape}")
    out = np.empty(a.shape)
    kernel.split_batch(np.ascontiguousarray(a).reshape(-1, 3), out.reshape(-1, 3))
    return out


def split_to_action(alpha: ArrayLike):
    """Inverse of :func:`action_to_split`: the action whose split is ``alpha`` (largest share at +1).

    ``alpha`` must be non-negative and sum to 1 along the last axis.
    """
    a = np.asarray(alpha, dtype=float)
    if np.any(~np.isfinite(a)) or np.any(a < 0) or not np.allclose(a.sum(axis=-1), 1.0, atol=1e-9):
        raise ValueError(f"alpha = {alpha!r} is not a split: shares must be >= 0 and sum to 1")
    return (2.0 * a / a.max(axis=-1, keepdims=True) - 1.0).astype(np.float32)


def reward_and_costs(s: Scenario, metrics: dict, n_next: ArrayLike, evaluable: ArrayLike = True):
    """Costs, reward and episode end of a slot from :func:`iscc_gym.loop.step`'s metrics (numpy,
    any batch shape): ``(cost_rate, cost_stability, reward, terminated, truncated)``. The reward is
    :func:`iscc_gym.kernel.reward_one` (written once, also what the compiled env step uses).

    Reward and penalty as in :class:`iscc_gym.env.ISCCEnv`'s docstring; ``n_next`` is the slot index
    after the step. ``evaluable`` is False where the next observation could not be evaluated (see
    :func:`iscc_gym.kernel.observe_one`): loss of track, like a tracking error above the bound. A rate or a loss
    probability that is NaN (an SNR overflowing far outside the region) counts as a violation, so the
    reward stays finite.
    """
    terminated = np.asarray(metrics["diverged"], dtype=bool) | ~np.asarray(evaluable, dtype=bool)
    err, rate, eps, term, n1 = np.broadcast_arrays(*(np.asarray(metrics[k], dtype=float) for k in (
        "tracking_error_m", "rate_comm_bps", "eps_ctrl")), terminated, np.asarray(n_next, dtype=np.int64))
    cost_rate, cost_stab, reward = (np.empty(err.shape) for _ in range(3))
    kernel.reward_batch(kernel.kernel_constants(s)[0], err.ravel(), rate.ravel(), eps.ravel(), term.ravel(),
                        n1.ravel(), cost_rate.reshape(-1), cost_stab.reshape(-1), reward.reshape(-1))
    terminated = term.copy()
    truncated = ~terminated & (n1 >= s.n_slots)
    return cost_rate, cost_stab, reward, terminated, truncated
