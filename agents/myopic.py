r"""Model-based per-slot optimiser: each slot, the split that maximises the expected one-slot reward.

:class:`MyopicPolicy` reads what the GBS knows before the slot (the observation: predicted
large-scale SNR, geometry) and picks, for every env of a batch at once, the split
:math:`(\alpha_\mathrm{sen}, \alpha_\mathrm{ctrl}, \alpha_\mathrm{comm})` that maximises the env's
reward in expectation over the slot's Rician fading. Every equation comes from :mod:`iscc_gym`:
the FBL link (:func:`iscc_gym.physics.fbl.slot_link`, :func:`iscc_gym.physics.fbl.min_shares`), the fading
quadrature (:func:`iscc_gym.analysis.quadrature.rician_power_nodes`), the CRLB
(:func:`iscc_gym.analysis.sensing_share.sensing_coefficients`,
:func:`iscc_gym.analysis.sensing_share.local_crlb`), the Kalman
steady state (:func:`iscc_gym.analysis.kalman_steady.axis_kalman_steady_state`), the second-moment recursion under
packet loss (:func:`iscc_gym.physics.stability.stability_matrix`) and the mean error norm
(:func:`iscc_gym.analysis.quadrature.expected_norm`). The local tracking model is the library's:
:func:`~iscc_gym.analysis.tracking.rician_power_cdf` (the CDF of :func:`iscc_gym.physics.channel.rician_gain_one`)
and :class:`~iscc_gym.analysis.tracking.LocalTrackingModel` (the steady-state tracking error at one geometry, for any
sensing share and loss rate).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, fields, replace

import numpy as np

from iscc_gym.analysis.quadrature import mean_ctrl_loss, rician_nodes, rician_power_nodes
from iscc_gym.analysis.sensing_share import SensingCoefficients
from iscc_gym.analysis.tracking import LocalTrackingModel, local_tracking_model, rician_power_cdf
from iscc_gym.physics.channel import matched_gain
from iscc_gym.physics.fbl import comm_rate_bps, min_shares
from iscc_gym.physics.stability import scenario_eps_star
from iscc_gym.scenario import Scenario, make_scenario
from iscc_gym.sim.effects import task_effects
from iscc_gym.sim.functional import decode_observation
from iscc_gym.sim.kernel import reward_from_costs
from iscc_gym.sim.schema import obs_size
from iscc_gym.sim.task import check_split
from iscc_gym.units import db_to_lin

from .base import SplitPolicy, as_obs_batch
from .geometry import predicted_sensing

__all__ = ["MyopicPolicy", "LocalTrackingModel", "rician_power_cdf", "rician_nodes_at", "SlotContext", "lead_axes",
           "refine_lattice"]


@dataclass(frozen=True)
class SlotContext:
    r"""What :class:`MyopicPolicy` decodes from a batch of n observations (arrays with leading n).

    Attributes
    ----------
    snr : (n,)
        Predicted large-scale SNR :math:`\bar\gamma_n` (linear), from ``snr_db`` of
        :func:`iscc_gym.sim.functional.decode_observation`.
    coef : SensingCoefficients
        Position-domain Fisher information at :math:`\alpha_\mathrm{sen} = 1` at the predicted range
        and direction (``range``, ``sin_elevation``, ``cos_azimuth``, ``sin_azimuth``) with the slot's
        shadowing (recovered from the SNR and the range).
    rate_per_share : (n, J)
        Data rate per unit share over ``rate_min_bps`` at the fading nodes
        (:func:`iscc_gym.analysis.quadrature.rician_power_nodes`); unused if ``rate_min_bps`` is 0. With a data
        queue: the bits a unit share carries in the slot over a slot's mean arrivals A.
    need : (n,) or None
        With a queue: the backlog and a slot's mean arrivals, over A (what serving the queue greedily clears).
    backlog : (n,) or None
        With a queue: the backlog over A.
    k_lin : (n,) or None
        The slot's Rician K-factor (linear) where the policy is given one (the field task's ``aware`` bound, or an
        estimate: ``adaptive``); None: the scenario's ``rician_k_db``.
    fade : (n, J) or None
        The fading quadrature's gain nodes at ``k_lin`` (:func:`rician_nodes_at`; the weights do not depend on K),
        or of another law of the slot's fade (a posterior-predictive mixture: ``agents.bayes``).
    fade_cdf : callable or None
        That other law's CDF, ``x (n, ...) -> P(g <= x)``, where ``fade`` is not one K's (None: ``k_lin``'s).
    """

    snr: np.ndarray
    coef: SensingCoefficients
    rate_per_share: np.ndarray
    need: np.ndarray | None = None
    backlog: np.ndarray | None = None
    k_lin: np.ndarray | None = None
    fade: np.ndarray | None = None
    fade_cdf: object = None


#: The K-factor grid of :func:`rician_nodes_at`'s table, dB (outside it, clamped: below -20 dB the gain is
#: Rayleigh's to 1 %, above 40 dB a constant to 1e-4).
_K_GRID_DB = np.arange(-20.0, 40.0 + 1e-9, 0.25)


@functools.lru_cache(maxsize=1)
def _nodes_table():
    return np.stack([rician_power_nodes(float(db_to_lin(k)))[0] for k in _K_GRID_DB])


def rician_nodes_at(k_db):
    """The gain nodes of :func:`iscc_gym.analysis.quadrature.rician_power_nodes` at K-factors ``k_db`` (n,) in dB,
    shape (n, J): linear interpolation in dB on a 0.25 dB table (-20 .. 40 dB, clamped). Between grid points the
    nodes are within 2e-3 relative of the exact ones at the K-factors ``tests/agents/test_field_agents.py`` samples,
    but the deepest node (the 5e-7 quantile) is up to 3.3 % off near 10 dB (a dense sweep; ``agents.bayes.MixtureLaw``
    is within 1e-3): a known inaccuracy of ``aware``'s and ``adaptive``'s deepest fade, whose weight is 1e-6. The
    weights are K's for any K.
    """
    table = _nodes_table()
    u = (np.clip(np.asarray(k_db, dtype=float), _K_GRID_DB[0], _K_GRID_DB[-1]) - _K_GRID_DB[0]) / 0.25
    i = np.minimum(u.astype(np.intp), len(_K_GRID_DB) - 2)
    t = (u - i)[..., None]
    return (1.0 - t) * table[i] + t * table[i + 1]


def lead_axes(x, ndim):
    """(n,) -> (n, 1, ..., 1) with ``ndim`` axes."""
    return np.reshape(x, np.shape(x)[:1] + (1,) * (ndim - 1))


class MyopicPolicy(SplitPolicy):
    r"""Per-slot split maximising the expected one-slot reward given the observation.

    Each slot and for each env of the batch,

    .. math::
        \boldsymbol\alpha_n = \arg\max_{\boldsymbol\alpha\in\Delta}\;
        -\,T\big(\alpha_\mathrm{sen}, \bar\varepsilon(\alpha_\mathrm{ctrl})\big)
        - w_\mathrm{rate}\,\mathbb E_g\!\left[\frac{(R_\min - \mathcal R_\mathrm{comm}(\alpha_\mathrm{comm},
        g\bar\gamma_n))^+}{R_\min}\right]
        - w_\mathrm{stab}\,P_g\!\left(\varepsilon_\mathrm{ctrl}(\alpha_\mathrm{ctrl}, g\bar\gamma_n)
        > \varepsilon^\star\right)

    over :math:`\Delta = \{\alpha_\mathrm{sen} \ge` ``sensing_floor``,
    :math:`\alpha_\mathrm{ctrl} \ge` ``ctrl_floor``, :math:`\alpha_\mathrm{comm} \ge 0`, sum 1\},
    the env's reward (:func:`iscc_gym.sim.task.reward_and_costs`) in expectation over the slot's
    small-scale fading :math:`g = |g_C|^2` (Rician, drawn after the allocation), where

    * :math:`\bar\gamma_n` is ``snr_db`` (the predicted large-scale SNR); the rate
      (:func:`iscc_gym.physics.fbl.slot_link`) shortfall is averaged over the fading quadrature of
      :func:`iscc_gym.analysis.quadrature.rician_power_nodes`;
    * the stability term is in closed form: :math:`\varepsilon_\mathrm{ctrl}` falls with the SNR,
      so :math:`P(\varepsilon_\mathrm{ctrl} > \varepsilon^\star) = F_g(\gamma^\star(\alpha_\mathrm{ctrl})
      / \bar\gamma_n)` with :math:`\gamma^\star` the inverse of
      :func:`iscc_gym.physics.fbl.min_shares` at :math:`\varepsilon^\star` (tabulated) and :math:`F_g`
      :func:`rician_power_cdf`;
    * :math:`T` is the steady-state mean tracking error at the predicted geometry
      (:class:`LocalTrackingModel`: range, direction, shadowing) for the
      sensing share held and the fading-averaged loss rate
      :math:`\bar\varepsilon(\alpha_\mathrm{ctrl}) = \mathbb E_g\,\varepsilon_\mathrm{ctrl}`. It is
      the error the loop settles to if the split is held (filter and loop forget a slot within a
      few slots), so sensing is valued for the estimate it maintains and the loss rate for the
      commands it drops; at :math:`\bar\varepsilon \ge \varepsilon^\star` it is the cap
      ``max_tracking_error_m``.

    The search: a coarse lattice of ``n_coarse`` control shares (geometric from ``ctrl_floor``) by
    ``n_coarse`` fractions of the rest given to data, then ``n_refine`` local lattices of
    ``refine_points`` x ``refine_points`` around the incumbent (control shares on a log scale, data
    shares linear), each ``refine_factor`` times finer and always containing the incumbent, all
    envs at once in numpy (about 5 ms per slot for 20 envs). Nothing is tuned on evaluation seeds:
    the search defaults were chosen by the objective gap to a 400 x 400 brute-force grid and the
    wall time, on 250 observations of seeds 500000-500099 plus five constructed far, shadowed
    positions where ``rate_min_bps`` is out of reach (largest gap 7e-5, against 3e-2 for a
    10-point coarse lattice refined by halving); the weights are the scenario's.

    Parameters
    ----------
    scenario : Scenario or str
        Scenario (or preset name); must have ``control_mode="lqg"`` and ``observation_source="isac"``.
    rate_weight : float, optional
        :math:`w_\mathrm{rate}` of the objective (>= 0). Default: the scenario's ``w_rate`` (the
        env's reward); another value trades rate outage for tracking error.
    stability_weight : float, optional
        :math:`w_\mathrm{stab}` (>= 0). Default: the scenario's ``w_stab``.
    sensing_floor : float
        Smallest sensing share, in [0, 0.5). Default 1e-3 (as SCA's ``MIN_SHARE``).
    ctrl_floor : float
        Smallest control share, in (0, 0.5). Default 1e-3.
    n_coarse : int
        Coarse lattice points per axis (>= 3). Default 12.
    n_refine : int
        Refinement rounds (>= 0). Default 4.
    refine_points : int
        Odd points per axis of a refinement lattice (>= 3). Default 7.
    refine_factor : float
        Step reduction per refinement round (> 1). Default 3.

    Raises
    ------
    ValueError
        Naming the bad parameter; ``predict``: observations of the wrong shape or not finite.

    See Also
    --------
    agents.sca.SCAPolicy : the paper's Algorithm 1, static or per slot.
    """

    def __init__(self, scenario: Scenario | str = "paper", rate_weight: float | None = None,
                 stability_weight: float | None = None, sensing_floor: float = 1e-3, ctrl_floor: float = 1e-3,
                 n_coarse: int = 12, n_refine: int = 4, refine_points: int = 7, refine_factor: float = 3.0):
        s = make_scenario(scenario) if isinstance(scenario, str) else scenario
        if not isinstance(s, Scenario):
            raise ValueError(f"scenario must be a Scenario or a preset name, got {type(scenario).__name__}")
        if s.control_mode != "lqg" or s.observation_source != "isac":
            raise ValueError("MyopicPolicy models the ISAC-fed LQG loop: scenario.control_mode must be 'lqg' and "
                             f"scenario.observation_source 'isac' (got {s.control_mode!r}, {s.observation_source!r})")
        self.scenario = s
        self.rate_weight = _weight("rate_weight", s.w_rate if rate_weight is None else rate_weight)
        self.stability_weight = _weight("stability_weight", s.w_stab if stability_weight is None else stability_weight)
        self.sensing_floor = _number("sensing_floor", sensing_floor, 0.0, 0.5, "in [0, 0.5)", lo_open=False)
        self.ctrl_floor = _number("ctrl_floor", ctrl_floor, 0.0, 0.5, "in (0, 0.5)")
        self.n_coarse = _integer("n_coarse", n_coarse, 3)
        self.n_refine = _integer("n_refine", n_refine, 0)
        self.refine_points = _integer("refine_points", refine_points, 3)
        if self.refine_points % 2 == 0:
            raise ValueError(f"refine_points = {refine_points!r} is invalid: must be odd (the incumbent is the centre)")
        self.refine_factor = _number("refine_factor", refine_factor, 1.0, math.inf, "> 1")
        self.eps_star = scenario_eps_star(s)
        self.fade, self.fade_w = rician_nodes(s)
        # gamma*(alpha): the SNR at which alpha_ctrl gives eps* (inverse of min_ctrl_share, decreasing)
        log_snr = np.linspace(-6.0, 16.0, 4401) * math.log(10.0)
        a_star = min_shares(s, np.exp(log_snr), self.eps_star, 0.0)[0]
        ok = a_star < 1e6
        self._log_alpha_star = np.log(a_star[ok])[::-1]
        self._log_snr_star = log_snr[ok][::-1]
        self.tracking = local_tracking_model(s)
        self._gain = matched_gain(s) if s.beamforming == "matched" else None
        self.obs_size = obs_size(s)
        self.shows_world = task_effects(s).show_world
        if self.shows_world:  # what the env shows it (eval.evaluate.run_episodes applies it): the aware bound
            self.scenario_overrides = {"show_world": True}
        self.name = "myopic"

    # --- the model ------------------------------------------------------------------------------
    def slot_context(self, obs) -> SlotContext:
        """Decode a batch of observations (n, 23) (see :class:`SlotContext`)."""
        s = self.scenario
        o, _ = as_obs_batch(obs, self.obs_size)
        if not np.all(np.isfinite(o)):
            raise ValueError("obs contains NaN or inf; pass the env's (finite) observations")
        d = decode_observation(o, s)
        k_db, rcs_db = self.world_of(d)
        return self.context(d["snr_db"], d["range_m"], d["sin_elevation"], d["cos_azimuth"], d["sin_azimuth"],
                            d.get("echo_snr_db"), d.get("backlog_bits"), k_db, rcs_db)

    def world_of(self, decoded: dict):
        """The world the policy designs the slot for, ``(k_db, rcs_offset_db)`` (arrays (n,), or None: the
        scenario's constants), from the decoded observations: the hidden world block where the env shows it (the
        ``aware`` bound, ``show_world``), else the model's (None, None). :class:`agents.adaptive.AdaptivePolicy`
        estimates them instead.
        """
        if self.shows_world:
            return decoded["world_k_db"], decoded["world_rcs_offset_db"]
        return None, None

    def context(self, snr_db, range_m, sin_el, cos_az, sin_az, echo_snr_db=None, backlog_bits=None, k_db=None,
                rcs_offset_db=None, fade=None, fade_cdf=None) -> SlotContext:
        """:class:`SlotContext` of slots given by their decoded entries (arrays (n,)): the predicted large-scale
        SNR and geometry, with blockage the echo's SNR, with a queue the backlog in bits (what
        :meth:`slot_context` reads from observations; a planner passes the slots it looks ahead to); the world's
        K-factor and the RCS's offset in dB where the policy knows or estimates them (default the scenario's); or,
        instead of a K-factor, the slot's fading law as quadrature nodes ``fade`` (n, J) and its CDF ``fade_cdf``.
        """
        s = self.scenario
        snr_db = np.asarray(snr_db, dtype=float)
        coef = predicted_sensing(s, snr_db, range_m, sin_el, cos_az, sin_az, self._gain, echo_snr_db, rcs_offset_db)
        snr = db_to_lin(snr_db)
        if fade is not None:  # a law of the slot's fade given by its nodes and CDF (a posterior-predictive mixture)
            if s.queue_deadline_slots > 0:
                raise ValueError("a world fading law with a data queue is not modelled (the field task has none)")
            rate = comm_rate_bps(s, 1.0, snr[:, None] * fade) / max(s.rate_min_bps, 1e-300)
            return SlotContext(snr=snr, coef=coef, rate_per_share=rate, fade=np.asarray(fade, dtype=float),
                               fade_cdf=fade_cdf)
        if k_db is not None:  # the slot's own fading law: its nodes, its K for the stability term's CDF
            fade = rician_nodes_at(k_db)
            rate = comm_rate_bps(s, 1.0, snr[:, None] * fade) / max(s.rate_min_bps, 1e-300)
            if s.queue_deadline_slots > 0:
                raise ValueError("a world K-factor with a data queue is not modelled (the field task has none)")
            return SlotContext(snr=snr, coef=coef, rate_per_share=rate, k_lin=db_to_lin(np.asarray(k_db, float)),
                               fade=fade)
        if s.queue_deadline_slots > 0:  # the queue, served greedily: clear the backlog and the slot's mean arrivals
            mean_bits = s.queue_arrival_bps * s.dt_s
            rate = comm_rate_bps(s, 1.0, snr[:, None] * self.fade) * (s.dt_s / mean_bits)
            backlog = np.asarray(backlog_bits, dtype=float) / mean_bits
            return SlotContext(snr=snr, coef=coef, rate_per_share=rate, need=backlog + 1.0, backlog=backlog)
        rate = comm_rate_bps(s, 1.0, snr[:, None] * self.fade) / max(s.rate_min_bps, 1e-300)
        return SlotContext(snr=snr, coef=coef, rate_per_share=rate)

    def ctrl_terms(self, ctx: SlotContext, alpha_ctrl):
        r"""Fading-averaged loss rate :math:`\bar\varepsilon` and :math:`P(\varepsilon_\mathrm{ctrl} >
        \varepsilon^\star)` of control shares ``alpha_ctrl`` (n, ...), each of that shape.
        """
        c = np.asarray(alpha_ctrl, dtype=float)
        snr = lead_axes(ctx.snr, c.ndim)
        nodes = None if ctx.fade is None else (ctx.fade.reshape(ctx.fade.shape[:1] + (1,) * (c.ndim - 1) + (-1,)),
                                               self.fade_w)
        eps_bar = mean_ctrl_loss(self.scenario, c, snr, nodes)
        log_snr = np.interp(np.log(np.maximum(c, 1e-300)), self._log_alpha_star, self._log_snr_star)
        if ctx.fade_cdf is not None:
            p_viol = ctx.fade_cdf(np.exp(log_snr) / snr)
        else:
            p_viol = rician_power_cdf(self.scenario, np.exp(log_snr) / snr,
                                      None if ctx.k_lin is None else lead_axes(ctx.k_lin, c.ndim))
        return eps_bar, np.where(c > 0.0, p_viol, 1.0)

    def rate_shortfall(self, ctx: SlotContext, alpha_comm):
        r""":math:`\mathbb E_g (R_\min - \mathcal R_\mathrm{comm})^+/R_\min` of data shares
        ``alpha_comm`` (n, ...), of that shape. With a queue, served greedily:
        :math:`\mathbb E_g (B + A - \mathcal R_\mathrm{comm}\Delta t)^+/A` (backlog B, a slot's mean arrivals A),
        the bits the slot would leave waiting, priced as if dropped.
        """
        d = np.asarray(alpha_comm, dtype=float)
        rate = ctx.rate_per_share.reshape(ctx.rate_per_share.shape[:1] + (1,) * (d.ndim - 1) + (-1,))
        if ctx.need is not None:  # the queue: what the slot leaves of the backlog and its mean arrivals
            need = lead_axes(ctx.need, d.ndim + 1)
            return np.maximum(need - d[..., None] * rate, 0.0) @ self.fade_w
        if self.scenario.rate_min_bps <= 0.0:  # no rate requirement: the env charges nothing
            return np.zeros(np.broadcast_shapes(d.shape, ctx.snr.shape + (1,) * (d.ndim - 1)))
        return np.maximum(1.0 - d[..., None] * rate, 0.0) @ self.fade_w

    def _coef(self, ctx: SlotContext, ndim: int) -> SensingCoefficients:
        return replace(ctx.coef, **{f.name: lead_axes(getattr(ctx.coef, f.name), ndim)
                                    for f in fields(ctx.coef) if f.name != "prior"})

    def objective(self, ctx, c, d):
        """The objective of control shares ``c`` and data shares ``d`` (broadcastable, leading n) and its terms."""
        sen = 1.0 - c - d
        eps_bar, p_viol = self.ctrl_terms(ctx, c)
        lam = self.tracking.axis_variances(self._coef(ctx, np.ndim(sen)), np.maximum(sen, 0.0),
                                           weights=self.tracking.loss_weights(eps_bar))
        t = self.tracking._error(lam, np.broadcast_to(eps_bar, lam.shape[:-1]))
        short = self.rate_shortfall(ctx, d)
        value = reward_from_costs(self.tracking.e_max, self.rate_weight, self.stability_weight, t, short, p_viol)
        return value, {"tracking_error_m": t, "rate_shortfall": short, "stability_violation": p_viol,
                       "eps_ctrl": eps_bar}

    def expected_terms(self, obs, split) -> dict:
        """The objective and its terms for candidate splits.

        Parameters
        ----------
        obs : array_like, shape (23,) or (n, 23)
        split : array_like, shape (m, 3) or (n, m, 3)
            Candidate splits (alpha_sen, alpha_ctrl, alpha_comm), shared by every observation or
            one set per observation.

        Returns
        -------
        dict of ndarray, shape (n, m)
            ``reward`` (the objective), ``tracking_error_m`` (T), ``rate_shortfall``,
            ``stability_violation`` (probability), ``eps_ctrl`` (fading-averaged loss rate).

        Raises
        ------
        ValueError
            Bad observation shape; ``split`` of the wrong shape or not on the simplex.
        """
        ctx = self.slot_context(obs)
        n = len(ctx.snr)
        a = np.asarray(split, dtype=float)
        if a.ndim == 2:
            a = np.broadcast_to(a, (n,) + a.shape)
        if a.ndim != 3 or a.shape[0] != n or a.shape[2] != 3:
            raise ValueError(f"split must have shape (m, 3) or ({n}, m, 3), got {np.shape(split)}")
        check_split(a, "split")
        value, terms = self.objective(ctx, a[..., 1], a[..., 2])
        return {"reward": value, **terms}

    def expected_reward(self, obs, split) -> np.ndarray:
        """The objective of candidate splits, shape (n, m) (see :meth:`expected_terms`)."""
        return self.expected_terms(obs, split)["reward"]

    # --- the search -----------------------------------------------------------------------------
    def search(self, n: int, score):
        """The (control, data) shares maximising ``score(cc, dd)`` (the value of candidate shares of shape
        (n, ...)) for n slots: a coarse grid of every feasible split (control geometric, data a fraction of what is
        left), then :func:`refine_lattice` around the best. Returns ``(control, data)``, arrays (n,). The search of
        :meth:`split_batch` (``score`` the objective) and of the planner's current slot.
        """
        rows = np.arange(n)
        top = 1.0 - self.sensing_floor
        c_grid = np.geomspace(self.ctrl_floor, top, self.n_coarse)
        u_grid = np.linspace(0.0, 1.0, self.n_coarse)
        c = np.broadcast_to(c_grid[None, :, None], (n, self.n_coarse, 1))
        d = (top - c) * u_grid  # (n, C, U): every point feasible
        value = score(c, d)
        best = value.reshape(n, -1).argmax(1)
        ic, iu = np.unravel_index(best, value.shape[1:])
        c0, d0 = c_grid[ic], d[rows, ic, iu]
        return refine_lattice(score, c0, d0, math.log(c_grid[1] / c_grid[0]), top / (self.n_coarse - 1),
                              self.n_refine, self.refine_points, self.refine_factor, self.ctrl_floor, top)

    def split_batch(self, obs, state=None, episode_start=None):
        ctx = self.slot_context(obs)
        c0, d0 = self.search(len(ctx.snr), lambda cc, dd: self.objective(ctx, cc, dd)[0])
        split = np.stack([np.maximum(1.0 - c0 - d0, 0.0), c0, d0], -1)
        return split / split.sum(-1, keepdims=True), state

    def __repr__(self) -> str:
        return (f"MyopicPolicy(rate_weight={self.rate_weight:g}, stability_weight={self.stability_weight:g}, "
                f"sensing_floor={self.sensing_floor:g}, ctrl_floor={self.ctrl_floor:g}, n_coarse={self.n_coarse}, "
                f"n_refine={self.n_refine}, refine_points={self.refine_points}, "
                f"refine_factor={self.refine_factor:g})")


def refine_lattice(score, c0, d0, log_step: float, d_step: float, rounds: int, points: int, factor: float,
                   ctrl_floor: float, top: float):
    """Local search of (control, data) shares around ``(c0, d0)`` (arrays (n,)): ``rounds`` lattices of ``points`` x
    ``points`` centred on the incumbent, control shares on a log scale and data shares linear, each round's steps
    ``factor`` times finer than the last (from ``log_step``, ``d_step``), kept feasible (control in
    [``ctrl_floor``, ``top``], data in [0, ``top`` - control]); ``score(cc, dd)`` gives the value of a lattice
    (n, points, points). Returns the best ``(c, d)``: the refinement of :meth:`MyopicPolicy.search`.
    """
    rows = np.arange(len(c0))
    k = np.arange(points) - points // 2
    for _ in range(rounds):
        log_step /= factor
        d_step /= factor
        cc = np.clip(c0[:, None, None] * np.exp(log_step * k)[None, :, None], ctrl_floor, top)
        dd = np.clip(d0[:, None, None] + d_step * k[None, None, :], 0.0, top - cc)
        value = score(cc, dd)
        best = value.reshape(len(c0), -1).argmax(1)
        ic, id_ = np.unravel_index(best, value.shape[1:])
        c0, d0 = cc[rows, ic, 0], dd[rows, ic, id_]
    return c0, d0


def _weight(name, value):
    return _number(name, value, 0.0, math.inf, ">= 0 and finite", lo_open=False)


def _number(name, value, lo, hi, what, lo_open=True):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} = {value!r} is invalid: must be a number {what}")
    v = float(value)
    if not math.isfinite(v) or v < lo or (lo_open and v == lo) or v >= hi:
        raise ValueError(f"{name} = {value!r} is invalid: must be {what}")
    return v


def _integer(name, value, lo):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lo:
        raise ValueError(f"{name} = {value!r} is invalid: must be an integer >= {lo}")
    return int(value)
