r"""Receding-horizon planning over the urban task's preview: ``mpc`` (and ``oracle`` on the truth's preview).

Each slot, for every env of a batch at once, the planner looks at the slot and the H preview points ahead
(``preview_slots`` points ``preview_stride_slots`` = S slots apart, the next H S slots) and chooses the data
shares of the blocks that maximise the expected reward over the horizon; the current slot's split is applied
and the plan is made anew next slot.

The model, each piece the env's own:

* **Per slot, tracking and stability.** For a data share d, the best control share c of the slot's expected
  reward without its data term, :math:`v(d) = \max_c -T(1 - c - d, \bar\varepsilon(c)) - w_\mathrm{stab}
  P(\varepsilon_\mathrm{ctrl} > \varepsilon^\star)` (:class:`iscc_gym.agents.MyopicPolicy`'s objective with no data
  term: the steady-state tracking error at the slot's geometry and echo, and the fading's stability violation),
  on a grid of d and a geometric grid of c. The current slot uses its measured SNRs (the observation's
  ``snr_db``, ``echo_snr_db``); a preview point uses the map's SNRs in LoS and in NLoS and the current geometry
  (range and angles change little over the horizon), one value per state (the dynamic programme below weighs
  them by the map's LoS probability p).
* **The queue, as a fluid.** In units of a slot's mean arrivals A, the backlog b gains 1 a slot, loses the
  bits the data share carries on average (:math:`d\,\bar C`, the fading-averaged FBL rate of the slot's state),
  and what has waited past the deadline D is dropped: b above D - 1 after the service (a FIFO buffer fed at a
  constant rate holds the last b slots' arrivals; ``deadline_margin`` slots lower, for the bursts and the fading
  the fluid does not see). Each dropped unit costs ``rate_weight`` (the env's ``w_rate`` unless tuned otherwise),
  and each unit held a slot ``holding_cost`` x ``rate_weight``.
* **Dynamic programming** over the blocks (the current slot, then H blocks of S slots, each block's data share
  held) on ``levels`` backlog levels in [0, D - 1], linear interpolation between them, and a terminal value
  :math:`-\kappa b` (``terminal_weight``: what a backlog left at the horizon's end is worth). A block's LoS state
  is known when the block comes (the slot measures it), so its data share is chosen per state and the value is
  the map's mixture of the two states' best, :math:`V_k(b) = p_k \max_d[\ldots]_\mathrm{LoS} + (1 - p_k)
  \max_d[\ldots]_\mathrm{NLoS}` (a stochastic programme over the states, the blocks' states taken as independent),
  not a plan for the mean channel: a backlog carried into a block that may be blocked is priced as the risk it is.
* **The current slot's split** is the search of :class:`iscc_gym.agents.MyopicPolicy` (a coarse grid of every
  split, then local refinement) of the slot's value, less the fluid's cost of the slot, plus the plan's value of
  the backlog it leaves: with no preview and no queue cost it is ``myopic`` with no data term.

``oracle`` is the same planner on ``preview_source="truth"`` (the realised LoS state and shadowing ahead, the
same missions): a bound on what better knowledge of the channel is worth, not a policy to beat. ``mpc-hold``
(``preview="hold"``) is the same planner blind to the preview: it takes the slot's measured channel to hold over
the horizon (LoS with the measured SNRs), so ``mpc`` against ``mpc-hold`` is what the preview is worth to the
planner, apart from its other approximations.
"""

from __future__ import annotations

import math

import numpy as np

from iscc_gym.scenario import Scenario, make_scenario
from iscc_gym.sim.functional import decode_observation
from iscc_gym.sim.schema import obs_size

from .base import SplitPolicy, as_obs_batch
from .myopic import MyopicPolicy

__all__ = ["LookaheadPolicy", "DATA_GRID", "PREVIEW_MODES"]

#: What the planner reads of the path ahead: the observation's preview, or the slot's channel held.
PREVIEW_MODES = ("shown", "hold", "truth")

#: The data shares the planner chooses among (per block).
DATA_GRID = (0.0, 0.03, 0.07, 0.12, 0.18, 0.25, 0.35, 0.5, 0.7)


class LookaheadPolicy(SplitPolicy):
    r"""Receding-horizon planner over the preview (see the module docstring).

    Parameters
    ----------
    scenario : Scenario or str
        A scenario with a data queue and a preview (the ``urban`` preset; ``preview_source="truth"`` for the
        oracle).
    terminal_weight : float
        :math:`\kappa` >= 0, the value per unit of backlog left at the horizon's end (in ``rate_weight`` units of A).
    deadline_margin : float
        Slots the fluid model takes off the deadline (>= 0): the real queue drops earlier than the fluid one
        under bursty arrivals and fading, so the planner keeps the backlog this far below D - 1.
    rate_weight : float, optional
        The planner's price of a dropped unit of data (>= 0; ``holding_cost`` and ``terminal_weight`` are in its
        units). Default: the scenario's ``w_rate`` (the env's reward). As :class:`iscc_gym.agents.MyopicPolicy`'s
        ``rate_weight``, another value corrects what the per-slot model misprices (it is tuned on training seeds).
    holding_cost : float
        :math:`\eta` >= 0: the cost of a unit of backlog held one slot, in ``rate_weight`` units. The fluid sees no risk
        in a backlog (no bursts, no fading, no blocked slot the map missed), so where serving now and later cost
        the same it may defer; a backlog carried into a surprise is what the real queue drops. 0: no such cost.
    data_grid : sequence of float
        Data shares to choose among, in [0, 1).
    ctrl_points : int
        Points of the geometric control-share grid from ``ctrl_floor`` (>= 4).
    levels : int
        Backlog levels of the dynamic programme (>= 3).
    sensing_floor, ctrl_floor : float
        Smallest sensing and control shares (as :class:`iscc_gym.agents.MyopicPolicy`'s).
    preview : str
        ``"shown"``: plan over the observation's preview; ``"hold"``: ignore it, the slot's measured channel held
        over the horizon (``mpc-hold``, the planner without knowledge of the future); ``"truth"``: plan over the
        truth ahead (``oracle``, the full-information bound: the env shows it the truth's preview, its
        ``scenario_overrides``; not a causal policy).
    name : str

    Raises
    ------
    ValueError
        A scenario without a queue or a preview, or a parameter out of its range (named).
    """

    def __init__(self, scenario: Scenario | str = "urban", terminal_weight: float = 0.0, deadline_margin: float = 0.0,
                 holding_cost: float = 0.0, rate_weight: float | None = None,
                 data_grid=DATA_GRID, ctrl_points: int = 10, levels: int = 21, sensing_floor: float = 1e-3,
                 ctrl_floor: float = 1e-3, preview: str = "shown", name: str = "mpc"):
        s = make_scenario(scenario) if isinstance(scenario, str) else scenario
        if not isinstance(s, Scenario):
            raise ValueError(f"scenario must be a Scenario or a preset name, got {type(scenario).__name__}")
        if s.queue_deadline_slots == 0 or s.preview_slots == 0:
            raise ValueError("LookaheadPolicy plans over a data queue and a preview: the scenario needs "
                             "queue_deadline_s > 0 and preview_slots > 0 (e.g. the 'urban' preset)")
        if not (math.isfinite(float(terminal_weight)) and float(terminal_weight) >= 0.0):
            raise ValueError(f"terminal_weight = {terminal_weight!r} is invalid: must be a finite number >= 0")
        grid = np.asarray(data_grid, dtype=float)
        if grid.ndim != 1 or len(grid) < 2 or not np.all((grid >= 0.0) & (grid < 1.0)):
            raise ValueError(f"data_grid = {data_grid!r} is invalid: at least two shares in [0, 1)")
        for field, value, lo in (("ctrl_points", ctrl_points, 4), ("levels", levels, 3)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lo:
                raise ValueError(f"{field} = {value!r} is invalid: must be an integer >= {lo}")
        if preview not in PREVIEW_MODES:
            raise ValueError(f"preview = {preview!r} is invalid: must be one of {PREVIEW_MODES}")
        self.preview = preview
        if preview == "truth":  # what the env shows it (iscc_gym.eval.evaluate.run_episodes applies it); its model too
            self.scenario_overrides = {"preview_source": "truth"}
            s = s.replace(**self.scenario_overrides)
        self.scenario = s
        self.slot = MyopicPolicy(s, rate_weight=0.0, sensing_floor=sensing_floor, ctrl_floor=ctrl_floor)
        self.terminal_weight = float(terminal_weight)
        top = s.queue_deadline_slots - 1  # the deadline D less the slot the service takes
        if not (math.isfinite(float(deadline_margin)) and 0.0 <= float(deadline_margin) < top):
            raise ValueError(f"deadline_margin = {deadline_margin!r} is invalid: must be in [0, {top}) "
                             "slots (the queue's deadline minus one)")
        self.deadline_margin = float(deadline_margin)
        if not (math.isfinite(float(holding_cost)) and float(holding_cost) >= 0.0):
            raise ValueError(f"holding_cost = {holding_cost!r} is invalid: must be a finite number >= 0")
        self.holding_cost = float(holding_cost)
        rw = s.w_rate if rate_weight is None else rate_weight
        if isinstance(rw, bool) or not (isinstance(rw, (int, float, np.integer, np.floating))
                                        and math.isfinite(float(rw)) and float(rw) >= 0.0):
            raise ValueError(f"rate_weight = {rate_weight!r} is invalid: must be a finite number >= 0")
        self.rate_weight = float(rw)
        #: The planner's largest backlog (units of A): the deadline less one slot and the margin.
        self.top = s.queue_deadline_slots - 1.0 - self.deadline_margin
        self.data_grid = grid
        self.ctrl_grid = np.geomspace(ctrl_floor, 1.0 - sensing_floor, int(ctrl_points))
        self.levels = int(levels)
        self.sensing_floor = float(sensing_floor)
        self.obs_size = obs_size(s)
        self.name = name

    def _block_values(self, d: dict, n: int):
        """Per preview point, in LoS (rows 0..H-1) and in NLoS (rows H..2H-1): the best value v(d) on the data grid
        and the capacity per unit data share (units of A). The current slot is :meth:`_now`'s.
        """
        rows = 2 * self.scenario.preview_slots

        def tile(x):
            return np.repeat(np.asarray(x, dtype=float), rows)

        snr = np.concatenate([d["snr_los_ahead_db"], d["snr_nlos_ahead_db"]], 1)
        echo = np.concatenate([d["echo_los_ahead_db"], d["echo_nlos_ahead_db"]], 1)
        ctx = self.slot.context(snr.reshape(-1), tile(d["range_m"]), tile(d["sin_elevation"]),
                                tile(d["cos_azimuth"]), tile(d["sin_azimuth"]), echo.reshape(-1),
                                np.zeros(n * rows))
        c = self.ctrl_grid[None, :, None]
        dd = self.data_grid[None, None, :]
        value, _ = self.slot.objective(ctx, c, dd)  # the control terms once per c, not per (c, d)
        value = np.where(c + dd <= 1.0 - self.sensing_floor + 1e-12, value, -np.inf)
        best = value.argmax(1)  # (N, J)
        v = np.take_along_axis(value, best[:, None, :], 1)[:, 0, :]
        cap = ctx.rate_per_share @ self.slot.fade_w  # (N,)
        shape = (n, rows)
        return v.reshape(shape + (-1,)), cap.reshape(shape)

    def _fluid(self, b, served_per_slot, slots: int):
        """``slots`` slots of the fluid queue from backlogs ``b``: ``(b_after, dropped, held)`` (units of A; ``held``
        the backlog summed over the slots' ends, what :attr:`holding_cost` charges).
        """
        top = self.top
        shape = np.broadcast_shapes(np.shape(b), np.shape(served_per_slot))
        dropped, held = np.zeros(shape), np.zeros(shape)
        for _ in range(slots):
            b = b + 1.0
            b = b - np.minimum(b, served_per_slot)
            over = np.maximum(b - top, 0.0)
            dropped = dropped + over
            b = b - over
            held = held + b
        return b, dropped, held

    def _queue_cost(self, b, served_per_slot, slots: int):
        """The fluid's ``(b_after, cost)``: ``rate_weight`` (dropped + ``holding_cost`` x held), reward units."""
        b, dropped, held = self._fluid(b, served_per_slot, slots)
        return b, self.rate_weight * (dropped + self.holding_cost * held)

    def _interp(self, value, b):
        """``value`` (n, L) on the backlog levels, at backlogs ``b`` (n, ...): linear between levels."""
        top = self.top
        step = top / (self.levels - 1) if top > 0 else 1.0
        u = np.clip(b / step, 0.0, self.levels - 1 - 1e-9)
        i = u.astype(np.int64)
        w = u - i
        n = value.shape[0]
        idx = (np.arange(n).reshape((n,) + (1,) * (b.ndim - 1)), i)
        return (1.0 - w) * value[idx] + w * value[idx[0], i + 1]

    def split_batch(self, obs, state=None, episode_start=None):
        s = self.scenario
        o, _ = as_obs_batch(obs, self.obs_size)
        if not np.all(np.isfinite(o)):
            raise ValueError("obs contains NaN or inf; pass the env's (finite) observations")
        d = decode_observation(o, s)
        n = len(o)
        h, stride = s.preview_slots, s.preview_stride_slots
        if self.preview == "hold":  # the measured channel of the slot, held over the horizon
            d = {**d, "p_los_ahead": np.ones((n, h)), "snr_los_ahead_db": np.repeat(d["snr_db"][:, None], h, 1),
                 "echo_los_ahead_db": np.repeat(d["echo_snr_db"][:, None], h, 1)}
        v, cap = self._block_values(d, n)
        p = d["p_los_ahead"]  # (n, H)
        levels = np.linspace(0.0, self.top, self.levels)
        value = np.broadcast_to(-self.terminal_weight * self.rate_weight * levels, (n, self.levels))
        grid = self.data_grid
        for k in range(h - 1, -1, -1):
            # the block's LoS state is measured when it comes: the best data share in each state, weighed by the
            # map's probability (the states of different blocks taken as independent)
            branch = []
            for row in (k, h + k):  # LoS, NLoS
                served = grid[None, None, :] * cap[:, row, None, None]  # (n, 1, J)
                b_next, cost = self._queue_cost(levels[None, :, None], served, stride)  # (n, L, J)
                total = stride * v[:, row, None, :] - cost + self._interp(value, b_next)
                branch.append(total.max(-1))
            value = p[:, k, None] * branch[0] + (1.0 - p[:, k, None]) * branch[1]
        backlog = d["backlog_bits"] / (s.queue_arrival_bps * s.dt_s)
        ctrl, comm = self._now(d, backlog, value)
        split = np.stack([np.maximum(1.0 - ctrl - comm, 0.0), ctrl, comm], -1)
        return split / split.sum(-1, keepdims=True), state

    def _now(self, d: dict, backlog, value_next):
        """The current slot's (control, data) shares: :meth:`iscc_gym.agents.MyopicPolicy.search` of the slot's value
        (measured channel), less the fluid queue's cost, plus the plan's value of the backlog the slot leaves, both
        averaged over the fading's quadrature nodes (the slot's service is the faded rate's, not its mean's).
        """
        ctx = self.slot.context(d["snr_db"], d["range_m"], d["sin_elevation"], d["cos_azimuth"], d["sin_azimuth"],
                                d["echo_snr_db"], np.zeros(len(backlog)))
        n = len(backlog)
        w = self.slot.fade_w

        def score(cc, dd):
            v, _ = self.slot.objective(ctx, cc, dd)
            extra = (1,) * np.ndim(dd)
            rate = ctx.rate_per_share.reshape((n,) + extra[1:] + (-1,))  # the fading's nodes on the last axis
            b_next, cost = self._queue_cost(backlog.reshape((n,) + extra), dd[..., None] * rate, 1)
            return v + (self._interp(value_next, b_next) - cost) @ w

        return self.slot.search(len(backlog), score)

    def __repr__(self) -> str:
        return (f"LookaheadPolicy(name={self.name!r}, terminal_weight={self.terminal_weight:g}, "
                f"deadline_margin={self.deadline_margin:g}, holding_cost={self.holding_cost:g}, "
                f"rate_weight={self.rate_weight:g}, "
                f"preview={self.preview!r}, "
                f"data_grid={len(self.data_grid)} shares, ctrl_points={len(self.ctrl_grid)}, levels={self.levels})")
