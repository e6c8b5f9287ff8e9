"""The ``margin`` rule: control and data get fixed multiples of the shares the GBS predicts they need.

The observation carries, for the coming slot, the control share at which the predicted large-scale
SNR gives the drop probability eps* (``alpha_ctrl_min``) and the data share that
carries ``rate_min_bps`` (``alpha_comm_min``), both without the slot's fading (drawn after
the allocation). A design margin covers the fading: control gets ``m_ctrl`` times its need, data
``m_comm`` times its need, sensing the rest (at least ``sensing_floor``). Where the three do not fit
in the slot, control comes first (a stability violation costs ``w_stab`` = 10, a rate shortfall at
most ``w_rate`` = 1), data gets what is left above the sensing floor.

The two multiples are tuned by ``python -m eval.tune margin`` on training seeds disjoint from every
evaluation seed; the tuned values, the seeds and the command's output live in
``agents/tuned/margin.yml`` (:func:`load_tuned`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from iscc_gym.sim.schema import OBS, OBS_SCALING

from .base import SplitPolicy
from .tuned_records import load_tuned

__all__ = ["MarginPolicy", "margin_split", "predicted_needs"]


def predicted_needs(obs) -> tuple[np.ndarray, np.ndarray]:
    """The control and data shares the GBS predicts the slot needs, read from observations (n, 23):
    ``alpha_ctrl_min`` and ``alpha_comm_min`` (both scaled linearly, :data:`iscc_gym.sim.schema.OBS_SCALING`).
    """
    o = np.asarray(obs, dtype=float)
    return tuple(o[:, OBS[name]] / OBS_SCALING[name][1] for name in ("alpha_ctrl_min", "alpha_comm_min"))


def margin_split(ctrl_need, comm_need, m_ctrl: float, m_comm: float, sensing_floor: float):
    r"""The rule's split for predicted needs ``ctrl_need``, ``comm_need`` (arrays (n,)), shape (n, 3).

    .. math::
        \alpha_\mathrm{ctrl} = \min(m_\mathrm{ctrl}\,\alpha_\mathrm{ctrl}^\star, 1 - f),\quad
        \alpha_\mathrm{comm} = \min(m_\mathrm{comm}\,\alpha_\mathrm{comm}^{\min},
        1 - f - \alpha_\mathrm{ctrl}),\quad
        \alpha_\mathrm{sen} = 1 - \alpha_\mathrm{ctrl} - \alpha_\mathrm{comm}

    with the sensing floor :math:`f`.
    """
    room = 1.0 - sensing_floor
    ctrl = np.minimum(m_ctrl * np.maximum(ctrl_need, 0.0), room)
    comm = np.minimum(m_comm * np.maximum(comm_need, 0.0), room - ctrl)
    return np.stack([1.0 - ctrl - comm, ctrl, comm], axis=-1)


class MarginPolicy(SplitPolicy):
    """Per-slot rule: fixed multiples of the predicted control and data needs, sensing the rest.

    Parameters
    ----------
    m_ctrl : float >= 0
        Multiple of the predicted control share for eps* (``alpha_ctrl_min``).
    m_comm : float >= 0
        Multiple of the predicted data share for ``rate_min_bps`` (``alpha_comm_min``).
    sensing_floor : float in [0, 1)
        Smallest sensing share.
    name : str, optional

    Raises
    ------
    ValueError
        A parameter that is not finite or out of its range (the message names it).
    """

    def __init__(self, m_ctrl: float, m_comm: float, sensing_floor: float = 0.01, name: str = "margin"):
        for field, value, lo, hi in (("m_ctrl", m_ctrl, 0.0, math.inf), ("m_comm", m_comm, 0.0, math.inf),
                                     ("sensing_floor", sensing_floor, 0.0, 1.0)):
            v = float(value)
            if not (math.isfinite(v) and lo <= v and (v < hi or hi == math.inf)):
                raise ValueError(f"{field} = {value!r}; use a finite number in [{lo}, {hi})")
        self.m_ctrl, self.m_comm, self.sensing_floor = float(m_ctrl), float(m_comm), float(sensing_floor)
        self.name = name

    @classmethod
    def tuned(cls, record: str = "margin", path: str | Path | None = None) -> MarginPolicy:
        """The policy with the multiples stored by ``python -m eval.tune margin`` (``record`` ``margin-urban``:
        tuned on the urban task).
        """
        t = load_tuned(record, path)
        p = t["params"]
        return cls(p["m_ctrl"], p["m_comm"], p["sensing_floor"])

    def split_batch(self, obs, state=None, episode_start=None):
        return margin_split(*predicted_needs(obs), self.m_ctrl, self.m_comm, self.sensing_floor), state

    def __repr__(self) -> str:
        return f"MarginPolicy(m_ctrl={self.m_ctrl:g}, m_comm={self.m_comm:g}, sensing_floor={self.sensing_floor:g})"


class RowMarginPolicy(SplitPolicy):
    """The margin rule with its own multiples per batch row: a tuning grid's points x seeds played in one batch
    (``python -m eval.tune margin``).
    """

    def __init__(self, m_ctrl, m_comm, sensing_floor):
        self.m_ctrl, self.m_comm, self.sensing_floor = (np.asarray(v) for v in (m_ctrl, m_comm, sensing_floor))

    def split_batch(self, obs, state=None, episode_start=None):
        return margin_split(*predicted_needs(obs), self.m_ctrl, self.m_comm, self.sensing_floor), state
