"""The task's numpy API: the action map and the reward and costs, for arrays of any batch shape.

Each is written once, compiled (:func:`iscc_gym.sim.kernel.split_one`, :func:`iscc_gym.sim.kernel.reward_one`,
what the env step applies); these functions evaluate the same code on numpy arrays.
:mod:`iscc_gym.envs.env` re-exports them. The independent numpy formulas are test oracles
(``tests/oracle_env.py``, ``tests/oracle_loop.py``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from iscc_gym.scenario import Scenario
from iscc_gym.sim import kernel
from iscc_gym.sim.params import slot_params

__all__ = ["action_to_split", "split_to_action", "check_split", "SPLIT_TOLERANCE", "reward_and_costs"]

#: How far a split's shares may sum from 1, and dip below 0: the rounding of a computed split (an optimiser's
#: or a float32 action's), never a real error. Every "is this a split?" of the project is :func:`check_split`.
SPLIT_TOLERANCE = 1e-6


def check_split(alpha: ArrayLike, name: str = "alpha", over: str = "") -> np.ndarray:
    """``alpha`` as a float array if it holds splits along its last axis: finite shares, each at least
    ``-SPLIT_TOLERANCE``, summing to 1 within :data:`SPLIT_TOLERANCE`. ``over`` names what the shares split
    in the error (e.g. " over drones and functions").

    Raises
    ------
    ValueError
        Naming ``name``, its value (shortened) and the rule.
    """
    a = np.asarray(alpha, dtype=float)
    if a.ndim == 0 or a.shape[-1] == 0:
        raise ValueError(f"{name} must hold shares along its last axis, got shape {a.shape}")
    if (not np.isfinite(a).all() or (a < -SPLIT_TOLERANCE).any()
            or (np.abs(a.sum(axis=-1) - 1.0) > SPLIT_TOLERANCE).any()):
        shown = np.array2string(a, threshold=12, edgeitems=2, precision=6)
        raise ValueError(f"{name} = {shown} is not a split: shares must be finite, >= 0 and sum to 1{over}")
    return a


def action_to_split(action: ArrayLike):
    r"""Map an action in [-1, 1]^3 onto the simplex (alpha_sen, alpha_ctrl, alpha_comm).

    .. math:: w_i = (\mathrm{clip}(a_i, -1, 1) + 1)/2,\qquad \alpha_i = w_i / \textstyle\sum_j w_j

    and the equal split where every w_i = 0. Every split is reachable (see :func:`split_to_action`),
    including zero shares: there is no minimum share. Broadcasts over leading axes (shape (..., 3)).
    Evaluated by :func:`iscc_gym.sim.kernel.split_one`, the map the compiled env step applies.
    """
    a = np.asarray(action, dtype=float)
    if a.ndim == 0 or a.shape[-1] != 3:
        raise ValueError(f"action must have shape (..., 3), got {a.shape}")
    out = np.empty(a.shape)
    kernel.split_batch(np.ascontiguousarray(a).reshape(-1, 3), out.reshape(-1, 3))
    return out


def split_to_action(alpha: ArrayLike):
    """Inverse of :func:`action_to_split`: the action whose split is ``alpha`` (largest share at +1).

    ``alpha`` (..., n) must hold splits along the last axis (:func:`check_split`); n = 3 for the env's
    (alpha_sen, alpha_ctrl, alpha_comm), 3 K for the multi-drone env's shares over (drone, function).
    """
    a = check_split(alpha)
    return (2.0 * a / a.max(axis=-1, keepdims=True) - 1.0).astype(np.float32)


def reward_and_costs(s: Scenario, metrics: dict, n_next: ArrayLike, evaluable: ArrayLike = True):
    """Costs, reward and episode end of a slot from :func:`iscc_gym.sim.loop.step`'s metrics (numpy,
    any batch shape): ``(cost_rate, cost_stability, reward, terminated, truncated)``; with a queue,
    ``metrics["bits_dropped"]`` gives the data term (the env step's column of that name). The reward is
    :func:`iscc_gym.sim.kernel.reward_one` (written once, also what the compiled env step uses).

    Reward and penalty as in :class:`iscc_gym.envs.env.ISCCEnv`'s docstring; ``n_next`` is the slot index
    after the step. ``evaluable`` is False where the next observation could not be evaluated (see
    :func:`iscc_gym.sim.kernel.observe_one`): loss of track, like a tracking error above the bound. A rate or a loss
    probability that is NaN (an SNR overflowing far outside the region) counts as a violation, so the
    reward stays finite.
    """
    terminated = np.asarray(metrics["diverged"], dtype=bool) | ~np.asarray(evaluable, dtype=bool)
    dropped = np.asarray(metrics.get("bits_dropped", 0.0), dtype=float)
    err, rate, eps, drop, term, n1 = np.broadcast_arrays(*(np.asarray(metrics[k], dtype=float) for k in (
        "tracking_error_m", "rate_comm_bps", "eps_ctrl")), dropped, terminated, np.asarray(n_next, dtype=np.int64))
    cost_rate, cost_stab, reward = (np.empty(err.shape) for _ in range(3))
    kernel.reward_batch(slot_params(s)[0], err.ravel(), rate.ravel(), eps.ravel(), np.ascontiguousarray(drop).ravel(),
                        term.ravel(), n1.ravel(), cost_rate.reshape(-1), cost_stab.reshape(-1), reward.reshape(-1))
    terminated = term.copy()
    truncated = ~terminated & (n1 >= s.n_slots)
    return cost_rate, cost_stab, reward, terminated, truncated
