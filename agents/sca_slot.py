"""Per-slot SCA: the paper's Algorithm 1 (:mod:`iscc_gym.agents.sca`) as a policy, static or re-solved
every slot for the slot's predicted link and geometry, decoded from the observation.
"""

from __future__ import annotations

import math

import numpy as np

from iscc_gym.analysis import StaticModel, static_model
from iscc_gym.analysis.quadrature import mean_ctrl_loss, rician_nodes
from iscc_gym.analysis.sensing_share import crlb_trace_one
from iscc_gym.physics.channel import matched_gain
from iscc_gym.physics.fbl import comm_rate_bps, ctrl_goodput_bits
from iscc_gym.physics.stability import scenario_eps_star
from iscc_gym.scenario import Scenario
from iscc_gym.sim.functional import decode_observation
from iscc_gym.sim.schema import obs_size
from iscc_gym.units import db_to_lin

from .base import SplitPolicy, validate_split
from .geometry import predicted_sensing
from .sca import LOSS_MODELS, MODES, SOLVERS, SCAProblem, SCAResult, check_choice, sca_allocation, solve_sca
from .tuned_records import PER_SLOT_RECORD, load_tuned

__all__ = ["SCAPolicy", "per_slot_loss_design_fraction"]

#: The decoded observation entries the per-slot problem reads (:func:`iscc_gym.sim.functional.decode_observation`).
_READ = ("snr_db", "range_m", "sin_elevation", "cos_azimuth", "sin_azimuth")


# --------------------------------------------------------------------------------------------------
# the per-slot problem (the slot's predicted SNR and geometry, read from the observation)
# --------------------------------------------------------------------------------------------------
class _SlotTables:
    """Per-scenario cache of the per-slot SCA: quadrature of the Rician fading and, on a grid of the
    slot's large-scale SNR, the stability threshold and the minimum data share.
    """

    SNR_DB_GRID = np.linspace(-30.0, 70.0, 1001)

    def __init__(self, s: Scenario, eps_design: float, ignore_loss: bool):
        self.fade, self.fade_w = rician_nodes(s)
        snr_ls = db_to_lin(self.SNR_DB_GRID)
        rate = comm_rate_bps(s, 1.0, snr_ls[:, None] * self.fade[None, :]) @ self.fade_w
        self.comm_min = s.rate_min_bps / np.maximum(rate, 1e-300)
        if ignore_loss:
            self.ctrl_min = np.zeros_like(self.comm_min)
        else:
            # smallest share with fading-averaged loss <= eps_design: vectorised bisection in log alpha
            lo = np.full(len(self.SNR_DB_GRID), np.log(1e-6))
            hi = np.zeros(len(self.SNR_DB_GRID))
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                ok = mean_ctrl_loss(s, np.exp(mid), snr_ls) <= eps_design
                hi = np.where(ok, mid, hi)
                lo = np.where(ok, lo, mid)
            reach = mean_ctrl_loss(s, 1.0, snr_ls) <= eps_design
            self.ctrl_min = np.where(reach, np.exp(hi) * (1.0 + 1e-9), np.inf)

    def lookup(self, snr_db):
        """``(ctrl_min, comm_min)`` at large-scale SNRs ``snr_db`` (arrays, or floats for a float):
        linear interpolation on the grid, an unreachable stability threshold (inf) where either
        neighbour is.
        """
        g = self.SNR_DB_GRID
        x = np.clip(np.asarray(snr_db, dtype=float), g[0], g[-1])
        i = np.minimum(((x - g[0]) / (g[1] - g[0])).astype(np.int64), len(g) - 2)
        t = (x - g[i]) / (g[1] - g[0])
        c0, c1 = self.ctrl_min[i], self.ctrl_min[i + 1]
        finite = np.isfinite(c0) & np.isfinite(c1)
        with np.errstate(invalid="ignore"):
            ctrl = np.where(finite, (1.0 - t) * c0 + t * c1, np.maximum(c0, c1))
        comm = (1.0 - t) * self.comm_min[i] + t * self.comm_min[i + 1]
        if np.ndim(snr_db) == 0:
            return float(ctrl), float(comm)
        return ctrl, comm


class _Constant:
    def __init__(self, value: float):
        self.value = value

    def __call__(self, *args) -> float:
        return self.value


#: Name of per-slot SCA's tuning record (``agents/tuned/sca-per-slot.yml``, ``python -m eval.tune sca-per-slot``).


def per_slot_loss_design_fraction(path=None) -> float:
    """Per-slot SCA's design loss fraction as tuned by ``python -m eval.tune sca-per-slot`` on training
    seeds (the record ``agents/tuned/sca-per-slot.yml`` unless ``path``).
    """
    return float(load_tuned(PER_SLOT_RECORD, path)["params"]["loss_design_fraction"])


class SCAPolicy(SplitPolicy):
    r"""The paper's SCA allocation (Algorithm 1) as a policy.

    ``mode="static"``: one allocation from trajectory-averaged quantities
    (:func:`sca_allocation`), played every slot (the paper's design). ``mode="per_slot"``: Algorithm 1
    re-solved every slot for that slot's predicted link and geometry.

    What ``per_slot`` reads from the observation (``iscc_gym.sim.schema.OBS_NAMES``), all predicted by the
    GBS from its estimate :math:`\hat{\mathbf x}_{n|n-1}` before the slot's fading is drawn, decoded
    by :func:`iscc_gym.sim.functional.decode_observation`:

    * ``snr_db``: the slot's large-scale SNR :math:`\bar\gamma_n` (path loss, beam gain,
      shadowing). The stability threshold is the smallest share whose loss rate eq:ctrl_bler,
      averaged over the slot's Rician fading, is at most the design loss rate; the data share is
      ``rate_min_bps`` over the fading-averaged FBL rate (cons:comm_rate of slot n). Both come from
      a table over the SNR built once per policy (``alpha_ctrl_min``, ``alpha_comm_min`` are the same
      quantities without fading and at eps*, and are not used).
    * ``range``, ``sin_elevation``, ``cos_azimuth``, ``sin_azimuth``: the geometry of
      :math:`f_\mathrm{sen} = \operatorname{Tr}\mathrm{CRLB}_\mathbf p` (the slot's shadowing,
      which also scales the echo, is recovered from the SNR and the range).

    Nothing else (errors, estimate, time) enters Algorithm 1. The right-hand side L(b) of
    cons:rate_cost is a property of the loop's statistics, not of one slot: per slot it is the
    static design's value (under 2 bits per slot, far from binding). When a slot cannot carry both
    the stable control share and the minimum rate (far from the GBS), stability comes first and
    sensing keeps the static design's share; the data link gets the rest (:func:`_fallback_split`).
    The recurrent ``state`` (n, 2) holds each env's last solution, the warm start of the next
    slot's iterations; ``episode_start`` discards it.

    Parameters
    ----------
    scenario : Scenario
    mode : {"static", "per_slot"}
    ignore_loss : bool
        Design with eps_ctrl = 0 (the paper's "ISCC ignoring control packet loss").
    loss_model : {"local", "trajectory", "mean_snr"}
        Static mode: which loss rate defines the stability threshold (see :mod:`agents.sca`).
    loss_design_fraction : float in (0, 1], optional
        Design loss rate as a fraction of eps*: the bound on every sampled position's loss rate
        (static, ``loss_model="local"``) or on the slot's fading-averaged loss rate (per slot).
        Default 0.1 (static) and, per slot, the value tuned by ``python -m eval.tune sca-per-slot``
        on training seeds (:func:`per_slot_loss_design_fraction`): a slot's fading pushes single
        slots over eps*, which the env charges as a stability violation, so the per-slot design
        needs a lower loss rate than the static one.
    rho, tol, max_iter :
        Algorithm 1's proximal weight, tolerance and iteration cap.
    solver : {"slsqp", "kkt"}, optional
        Subproblem solver; default SLSQP (static) and the exact KKT solver (per slot, for speed).
    model : StaticModel, optional
        Trajectory sample for the static design (default: the cached one of ``scenario``).

    Raises
    ------
    ValueError
        Unknown ``mode``, ``loss_model`` or ``solver``; bad numbers.
    """

    def __init__(self, scenario: Scenario, mode: str = "static", ignore_loss: bool = False,
                 loss_model: str = "local", loss_design_fraction: float | None = None, rho: float = 1.0,
                 tol: float = 1e-12, max_iter: int = 100, solver: str | None = None,
                 model: StaticModel | None = None):
        check_choice("mode", mode, MODES)
        check_choice("loss_model", loss_model, LOSS_MODELS)
        if not isinstance(scenario, Scenario):
            raise ValueError(f"scenario must be a Scenario, got {type(scenario).__name__}")
        self.scenario = scenario
        self.obs_size = obs_size(scenario)
        self.mode = mode
        self.ignore_loss = bool(ignore_loss)
        self.loss_model = loss_model
        if loss_design_fraction is None:
            loss_design_fraction = per_slot_loss_design_fraction() if mode == "per_slot" else 0.1
        self.loss_design_fraction = float(loss_design_fraction)
        self.rho, self.tol, self.max_iter = float(rho), float(tol), int(max_iter)
        self.solver = solver or ("slsqp" if mode == "static" else "kkt")
        check_choice("solver", self.solver, tuple(SOLVERS))
        model = static_model(scenario) if model is None else model
        self.result = sca_allocation(scenario, loss_model, self.loss_design_fraction, self.ignore_loss,
                                     model=model, rho=self.rho, tol=self.tol, max_iter=self.max_iter,
                                     solver="slsqp" if mode == "static" else self.solver)
        self.split = validate_split(self.result.alpha, "SCA allocation")
        self.name = "sca" + ("-per-slot" if mode == "per_slot" else "") + ("-ignore-loss" if ignore_loss else "")
        if mode == "per_slot":
            self._tables = _SlotTables(scenario, self.loss_design_fraction * scenario_eps_star(scenario),
                                       self.ignore_loss)
            self._rate_cost_bits = float(self.result.rate_cost_bits)
            self._gain = matched_gain(scenario) if scenario.beamforming == "matched" else None

    # --- per slot ---------------------------------------------------------------------------------
    def slot_problem(self, obs_row) -> SCAProblem:
        """The reformulated problem of one slot, from one observation (23,)."""
        d = decode_observation(np.asarray(obs_row, dtype=float), self.scenario)
        return self._slot_problem(*(float(d[k]) for k in _READ))

    def slot_terms(self, snr_db, range_m, sin_el, cos_az, sin_az):
        r"""The per-slot problem's inputs for slots with these decoded observation entries (arrays or
        floats): ``(coefficients, ctrl_min, comm_min)``: the
        :class:`iscc_gym.analysis.sensing_share.SensingCoefficients` of :math:`f_\mathrm{sen}`, the stability
        threshold and the data share (see the class docstring).
        """
        coef = predicted_sensing(self.scenario, snr_db, range_m, sin_el, cos_az, sin_az, self._gain)
        ctrl_min, comm_min = self._tables.lookup(snr_db)
        return coef, ctrl_min, comm_min

    def _slot_problem(self, snr_db, range_m, sin_el, cos_az, sin_az) -> SCAProblem:
        s = self.scenario
        c, ctrl_min, comm_min = self.slot_terms(snr_db, range_m, sin_el, cos_az, sin_az)
        info = (float(c.info_range), float(c.info_az), float(c.info_cross), float(c.info_el), float(c.prior))

        def f_sen(a):
            return crlb_trace_one(*info, float(a))

        snr = 10.0 ** (snr_db / 10.0) * self._tables.fade
        tables = self._tables
        ignore = self.ignore_loss

        def g_ctrl(a):
            g, dg = ctrl_goodput_bits(s, a, snr, ignore_loss=ignore)
            return float(g @ tables.fade_w), float(dg @ tables.fade_w)

        l_b = self._rate_cost_bits
        return SCAProblem(f_sen, g_ctrl, _Constant(l_b), alpha_comm_min=comm_min,
                          alpha_ctrl_min=ctrl_min if math.isfinite(ctrl_min) else 1.0,
                          fallback_sen=float(self.split[0]))

    def solve_slot(self, obs_row, x0=None) -> SCAResult:
        """Algorithm 1 for one slot (see the class docstring for what is read)."""
        return solve_sca(self.slot_problem(obs_row), x0=x0, rho=self.rho, tol=self.tol,
                         max_iter=self.max_iter, solver=self.solver)

    def split_batch(self, obs, state=None, episode_start=None):
        n = len(obs)
        if self.mode == "static":
            return np.tile(self.split, (n, 1)), state
        prev = None if state is None else np.asarray(state, dtype=float).reshape(n, 2)
        starts = np.zeros(n, dtype=bool) if episode_start is None else np.broadcast_to(
            np.asarray(episode_start, dtype=bool), (n,))
        out = np.empty((n, 3))
        new_state = np.empty((n, 2))
        d = decode_observation(np.asarray(obs, dtype=float), self.scenario)
        cols = [np.asarray(d[k], dtype=float) for k in _READ]
        for i in range(n):
            x0 = None if prev is None or starts[i] else prev[i]
            res = solve_sca(self._slot_problem(*(float(c[i]) for c in cols)), x0=x0, rho=self.rho, tol=self.tol,
                            max_iter=self.max_iter, solver=self.solver)
            a = np.clip(res.alpha, 0.0, 1.0)
            out[i] = a / a.sum()
            new_state[i] = out[i, :2]
        return out, new_state

    def __repr__(self) -> str:
        return (f"SCAPolicy(mode={self.mode!r}, ignore_loss={self.ignore_loss}, loss_model={self.loss_model!r}, "
                f"split={np.round(self.split, 4).tolist()})")
