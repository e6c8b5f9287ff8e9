"""The task on top of the closed loop, in numpy: the action map, the observation, the reward and costs,
and the env step they make (:func:`env_step_reference`).

The readable definition of what :mod:`iscc_gym.kernel` compiles; :mod:`iscc_gym.env` re-exports these
names and uses them where the compiled step does not cover a scenario (``beamforming="broadside"``).
The reward itself is written once, :func:`iscc_gym.kernel.reward_one`; :func:`reward_and_costs` is its
numpy API.
"""

from __future__ import annotations

import numpy as np

from . import kernel, loop
from .scenario import Scenario
from .schema import (
    CTRL_SHARE_SCALE,
    ERR_SCALE,
    METRIC_NAMES,
    OBS_BOUND,
    OBS_NAMES,
    PEB_SCALE,
    REF_ACC_SCALE,
    REF_VEL_SCALE,
    SNR_SCALE,
)
from .stability import scenario_eps_star

__all__ = ["action_to_split", "split_to_action", "observe_reference", "reward_and_costs", "env_step_reference"]


def action_to_split(action):
    """Map an action in [-1, 1]^3 onto the simplex (alpha_sen, alpha_ctrl, alpha_comm).

    .. math:: w_i = (\\mathrm{clip}(a_i, -1, 1) + 1)/2,\\qquad \\alpha_i = w_i / \\textstyle\\sum_j w_j

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


def split_to_action(alpha):
    """Inverse of :func:`action_to_split`: the action whose split is ``alpha`` (largest share at +1).

    ``alpha`` must be non-negative and sum to 1 along the last axis.
    """
    a = np.asarray(alpha, dtype=float)
    if np.any(~np.isfinite(a)) or np.any(a < 0) or not np.allclose(a.sum(axis=-1), 1.0, atol=1e-9):
        raise ValueError(f"alpha = {alpha!r} is not a split: shares must be >= 0 and sum to 1")
    return (2.0 * a / a.max(axis=-1, keepdims=True) - 1.0).astype(np.float32)


def _symlog(x, scale):
    return np.sign(x) * np.log1p(np.abs(x) * (1.0 / scale))


#: Per-entry scale of the linear part of the observation (entries 6-11: reference motion).
_REF_SCALE = np.array([REF_VEL_SCALE] * 3 + [REF_ACC_SCALE] * 3)


def observe_reference(s: Scenario, state: loop.LoopState, last_received, last_peb_m):
    """:func:`observe` in numpy (one loop or a batch): the readable definition of the observation."""
    return _observe_and_check(s, state, last_received, last_peb_m)[0]


def _observe_and_check(s: Scenario, state: loop.LoopState, last_received, last_peb_m):
    """``(obs, evaluable)``: :func:`observe_reference`, and where the observation could be evaluated
    (no NaN entry, a finite estimate); where not, the episode ends (:func:`reward_and_costs`)."""
    pv = loop.preview(s, state, scenario_eps_star(s))
    ref = loop.reference_at(state)
    cos_az, sin_az, _, sin_el = pv["trig"]
    p = state.p
    obs = np.empty(state.x.shape[:-1] + (len(OBS_NAMES),))
    obs[..., 0:6] = _symlog(state.x_hat - ref[..., :6], ERR_SCALE)
    obs[..., 6:12] = ref[..., 3:9] * _REF_SCALE
    obs[..., 12] = _symlog(np.sqrt(p[..., 0, 0] + p[..., 1, 1] + p[..., 2, 2]), ERR_SCALE)
    obs[..., 13] = pv["snr_db"] * SNR_SCALE
    obs[..., 14] = pv["dist_m"] * (1.0 / s.coverage_radius_m)
    obs[..., 15] = sin_el
    obs[..., 16] = cos_az
    obs[..., 17] = sin_az
    obs[..., 18] = CTRL_SHARE_SCALE * pv["alpha_ctrl_min"]
    obs[..., 19] = pv["alpha_comm_min"]
    obs[..., 20] = last_received
    obs[..., 21] = _symlog(last_peb_m, PEB_SCALE)
    obs[..., 22] = 1.0 - state.n * (1.0 / s.n_slots)
    # every entry is finite in the region the model describes (floors in min_shares, prior in the
    # CRLB); far outside it (an estimate below ground, a diverged filter) an entry can be NaN: it reads
    # 0 and the episode ends (loss of track). The clip keeps divergent states inside the box.
    nan = np.isnan(obs)
    evaluable = ~nan.any(axis=-1) & np.isfinite(state.shadow) & np.isfinite(state.x_hat).all(axis=-1) \
        & np.isfinite(p).all(axis=(-2, -1))
    if nan.any():
        obs = np.where(nan, 0.0, obs)
    return np.minimum(np.maximum(obs, -OBS_BOUND), OBS_BOUND).astype(np.float32), evaluable


def reward_and_costs(s: Scenario, metrics: dict, n_next, evaluable=True):
    """Costs, reward and episode end of a slot from :func:`iscc_gym.loop.step`'s metrics (numpy,
    any batch shape): ``(cost_rate, cost_stability, reward, terminated, truncated)``. The reward is
    :func:`iscc_gym.kernel.reward_one` (written once, also what the compiled env step uses).

    Reward and penalty as in :class:`ISCCEnv`'s docstring; ``n_next`` is the slot index after the step.
    ``evaluable`` is False where the next observation could not be evaluated (see
    :func:`observe_reference`): loss of track, like a tracking error above the bound. A rate or a loss
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


def env_step_reference(s: Scenario, state: loop.LoopState, actions, z):
    """:func:`env_step` in numpy from pre-drawn normals ``z`` (B, N_DRAWS): the readable definition."""
    alpha = action_to_split(actions)
    new, m = loop.step_reference(s, state, alpha, None, z=z)
    cols = [np.asarray(m[k], dtype=float) for k in METRIC_NAMES]
    obs, evaluable = _observe_and_check(s, new, cols[7], cols[4])
    costs = reward_and_costs(s, m, new.n, evaluable)
    cols += [alpha[:, 0], alpha[:, 1], alpha[:, 2]] + [np.asarray(v, dtype=float) for v in costs]
    out = np.stack(cols, axis=-1)
    return new, out, obs
