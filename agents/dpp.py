r"""Lyapunov drift-plus-penalty on the data queue (the urban task): ``dpp``.

Each slot, for every env of a batch, the split that maximises

.. math::
    V\,\mathbb E\big[r^{\setminus\mathrm{data}}_n(\boldsymbol\alpha)\big]
    + \frac{B_n}{A}\,\frac{\mathbb E\big[\min(\mathcal R_\mathrm{comm}(\alpha_\mathrm{comm}, g\bar\gamma_n)\Delta t,
    B_n + A)\big]}{A}

(Neely, *Stochastic Network Optimization with Application to Communication and Queueing Systems*, 2010,
Ch. 3: the min-drift-plus-penalty rule): :math:`r^{\setminus\mathrm{data}}` is the env's one-slot reward
without its data term (the tracking error the split maintains and the stability violation, in expectation
over the slot's fading, as :class:`iscc_gym.agents.MyopicPolicy` evaluates them), :math:`B_n` the backlog, A a
slot's mean arrivals, the served bits capped at what the buffer will hold. The backlog prices the data share:
an empty buffer gets none beyond what tracking leaves, a growing one more, and V (``v``) sets how much
tracking is worth against the queue. V is tuned on training seeds.

The rule reads the queue only through the backlog (the observation's ``backlog``); it does not see when the
bits expire, nor the preview: a per-slot policy, the queue's standard one.
"""

from __future__ import annotations

import math

import numpy as np

from iscc_gym.scenario import Scenario

from .myopic import MyopicPolicy, SlotContext, lead_axes

__all__ = ["DriftPlusPenaltyPolicy"]


class DriftPlusPenaltyPolicy(MyopicPolicy):
    """Drift-plus-penalty on the data queue (see the module docstring); the search of :class:`MyopicPolicy`.

    Parameters
    ----------
    scenario : Scenario or str
        A scenario with a data queue (``queue_deadline_s`` > 0).
    v : float
        The penalty weight V > 0 (larger: tracking first, the queue later).
    **kwargs
        :class:`MyopicPolicy`'s search parameters (``stability_weight``, floors, lattice).

    Raises
    ------
    ValueError
        A scenario without a queue, or V not a finite number > 0.
    """

    def __init__(self, scenario: Scenario | str = "urban", v: float = 1.0, **kwargs):
        super().__init__(scenario, rate_weight=1.0, **kwargs)
        if self.scenario.queue_deadline_slots == 0:
            raise ValueError("DriftPlusPenaltyPolicy needs a data queue: the scenario's queue_deadline_s must be > 0 "
                             "(e.g. the 'urban' preset)")
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not (
                math.isfinite(float(v)) and float(v) > 0.0):
            raise ValueError(f"v = {v!r} is invalid: must be a finite number > 0")
        self.v = float(v)
        self.name = "dpp"

    def rate_shortfall(self, ctx: SlotContext, alpha_comm):
        r"""The data term as the objective charges it: :math:`-(B/A)\,\mathbb E[\min(\mathcal R\Delta t, B + A)]/(A V)`
        (the drift's bonus, divided by V so that the rest of the objective is the reward's).
        """
        d = np.asarray(alpha_comm, dtype=float)
        rate = ctx.rate_per_share.reshape(ctx.rate_per_share.shape[:1] + (1,) * (d.ndim - 1) + (-1,))
        need = lead_axes(ctx.need, d.ndim + 1)
        served = np.minimum(d[..., None] * rate, need) @ self.fade_w
        return -lead_axes(ctx.backlog, d.ndim) * served / self.v

    def __repr__(self) -> str:
        return f"DriftPlusPenaltyPolicy(v={self.v:g}, stability_weight={self.stability_weight:g})"
