r"""SCA-based resource allocation: the paper's Algorithm 1 (alg:sca_allocation), static and per slot.

The reformulated problem of Sec. IV-B, in the shares :math:`\boldsymbol\alpha = (\alpha_\mathrm{sen},
\alpha_\mathrm{ctrl})` (``alpha_comm = 1 - alpha_sen - alpha_ctrl`` eliminated):

.. math::
    \min_{\boldsymbol\alpha}\ f_\mathrm{sen}(\alpha_\mathrm{sen})\quad\text{s.t.}\quad
    g(\alpha_\mathrm{ctrl}) \ge L(b),\quad
    \mathcal R_\mathrm{comm}(1-\alpha_\mathrm{sen}-\alpha_\mathrm{ctrl}) \ge \mathcal R_\mathrm{comm}^{\min},
    \quad \alpha_\mathrm{sen}+\alpha_\mathrm{ctrl} < 1,\quad 0<\alpha_i<1,\quad
    \alpha_\mathrm{ctrl} > \alpha_\mathrm{ctrl}^\star

with :math:`f_\mathrm{sen} = \operatorname{Tr}\mathrm{CRLB}_\mathbf p` and
:math:`g = (1-\varepsilon_\mathrm{ctrl})\mathcal R_\mathrm{ctrl}`. Each iteration replaces g by its
first-order expansion at :math:`\alpha_\mathrm{ctrl}^{(k)}`, adds the proximal term
:math:`\rho\|\boldsymbol\alpha - \boldsymbol\alpha^{(k)}\|^2` and solves the convex subproblem; it stops when
:math:`\|\boldsymbol\alpha^{(k)} - \boldsymbol\alpha^{(k-1)}\|^2 \le \delta`.

Three readings are needed to make this well posed (``docs/model.md`` Sec. 3.2):

* **Strict stability.** :math:`\alpha_\mathrm{ctrl} > \alpha_\mathrm{ctrl}^\star` is an open set: the
  objective does not depend on :math:`\alpha_\mathrm{ctrl}`, so the infimum sits on the stability
  boundary, where :math:`\rho(\mathbf M) = 1` and the error is unbounded. The threshold is therefore
  taken at a design loss rate :math:`\varepsilon_\mathrm{design} = ` ``loss_design_fraction``
  :math:`\times\,\varepsilon^\star` (default 0.1, i.e. one tenth of the critical loss rate;
  ``1.0`` is the paper's boundary).
* **Which loss rate.** ``loss_model="mean_snr"`` evaluates eq:ctrl_bler at the trajectory-averaged
  SNR (the paper's Fig. 5(b), :math:`\alpha_\mathrm{ctrl}^\star = 4.1\,\%`); ``"trajectory"`` averages
  it over the slots (positions, shadowing, fading), the paper's own definition of
  :math:`\varepsilon_\mathrm{ctrl}` below eq:omega_tilde_cov; ``"local"`` (default) requires it at every
  sampled position. The mean SNR is dominated by the near positions, so ``"mean_snr"``'s threshold
  is far too small for the far ones: the env diverges at its allocation.
* **Trust.** Whatever the reading, the threshold is at least the analytic evaluator's trust edge
  (every sampled position's loss rate at most 0.4 eps*, ``iscc_gym.analysis.TRUST_LOSS_FRACTION``;
  ``enforce_trust=False`` drops it): below it the env loses track on some missions although the
  loop is mean-square stable on paper (``experiments.paper.fading``).
* **L(b)** (eq:Lb) is degenerate as printed (``rate_cost_determinant="printed"`` gives 0 bits); with
  the pseudo-determinant it is below 2 bits per slot against :math:`10^5` bits per slot that even the
  smallest stable control share carries, so cons:rate_cost never binds. It is kept as written.

The data-rate constraint uses the trajectory-averaged FBL rate of the data link
(:class:`iscc_gym.analysis.StaticModel`; per slot: the slot's fading-averaged rate).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import brentq, minimize, nnls

from iscc_gym.analysis import StaticModel, static_model
from iscc_gym.analysis.sensing_share import crlb_trace
from iscc_gym.physics.fbl import ctrl_bler, ctrl_goodput_bits, min_shares
from iscc_gym.scenario import Scenario

__all__ = ["SCAProblem", "SCAResult", "solve_sca", "static_problem", "sca_allocation", "MIN_SHARE"]

#: Smallest share of any function: the strict bounds 0 < alpha_i < 1 of cons:alpha_range.
MIN_SHARE = 1e-3

LOSS_MODELS = ("local", "trajectory", "mean_snr")
MODES = ("static", "per_slot")


@dataclass
class SCAProblem:
    r"""One instance of the reformulated problem: the callables and constants Algorithm 1 needs.

    Attributes
    ----------
    f_sen : callable
        ``alpha_sen -> (f, df)``: :math:`\operatorname{Tr}\mathrm{CRLB}_\mathbf p` in m^2 and its derivative.
    g_ctrl : callable
        ``alpha_ctrl -> (g, dg)``: :math:`(1-\varepsilon_\mathrm{ctrl})\mathcal R_\mathrm{ctrl}\Delta t` in
        bits per slot and its derivative.
    rate_cost : callable
        ``(alpha_sen, alpha_ctrl) -> L(b)`` in bits per slot, evaluated at the current iterate.
    alpha_comm_min : float
        Data share carrying ``rate_min_bps``.
    alpha_ctrl_min : float
        Stability threshold (the design reading of :math:`\alpha_\mathrm{ctrl}^\star`).
    min_share : float
        Floor of every share (strict positivity).
    fallback_sen : float
        Sensing share of :func:`_fallback_split` when the constraint set is empty.
    """

    f_sen: object
    g_ctrl: object
    rate_cost: object
    alpha_comm_min: float
    alpha_ctrl_min: float
    min_share: float = MIN_SHARE
    fallback_sen: float = MIN_SHARE

    @property
    def sum_max(self) -> float:
        """Largest alpha_sen + alpha_ctrl: the data-rate constraint and alpha_comm >= min_share."""
        return 1.0 - max(self.alpha_comm_min, self.min_share)

    @property
    def ctrl_min(self) -> float:
        return max(self.alpha_ctrl_min, self.min_share)

    def feasible_start(self) -> np.ndarray | None:
        """A feasible point of the (non-linearised) constraint set, or None if it is empty."""
        u, lc, ls = self.sum_max, self.ctrl_min, self.min_share
        room = u - lc - ls
        if room < 0.0:
            return None
        return np.array([ls + room / 3.0, lc + room / 3.0])


@dataclass
class SCAResult:
    r"""Outcome of :func:`solve_sca`.

    Attributes
    ----------
    alpha : ndarray (3,)
        (alpha_sen, alpha_ctrl, alpha_comm).
    converged : bool
        The stopping rule :math:`\|\boldsymbol\alpha^{(k)}-\boldsymbol\alpha^{(k-1)}\|^2\le\delta` held.
    feasible : bool
        The constraint set was non-empty (else ``alpha`` is the fallback of :func:`_fallback_split`).
    iterations : int
    f_sen_m2 : float
        :math:`f_\mathrm{sen}` at the solution (PEB squared).
    g_bits, rate_cost_bits : float
        Both sides of cons:rate_cost at the solution.
    kkt_residual : float
        Norm of the projected gradient at the solution (stationarity, 0 at a KKT point), computed
        on the normalised objective with NNLS over the active constraints.
    history : list of ndarray (2,)
        The iterates :math:`\boldsymbol\alpha^{(k)}`.
    wall_time_s : float
    """

    alpha: np.ndarray
    converged: bool
    feasible: bool
    iterations: int
    f_sen_m2: float
    g_bits: float
    rate_cost_bits: float
    kkt_residual: float
    history: list = field(default_factory=list)
    wall_time_s: float = 0.0


# --------------------------------------------------------------------------------------------------
# the convex subproblem
# --------------------------------------------------------------------------------------------------
def _ctrl_bounds(prob: SCAProblem, g_k: float, dg_k: float, a_ck: float, l_k: float):
    """Bounds on alpha_ctrl from the stability threshold, the floor and the linearised g."""
    lo, hi = prob.ctrl_min, 1.0 - prob.min_share
    if dg_k > 0.0:
        lo = max(lo, a_ck + (l_k - g_k) / dg_k)
    elif dg_k < 0.0:
        hi = min(hi, a_ck + (l_k - g_k) / dg_k)
    elif g_k < l_k:
        lo = math.inf
    return lo, hi


def _subproblem_slsqp(prob, x_k, f0, rho, g_k, dg_k, l_k):
    """Solve the convex subproblem with SLSQP (scipy)."""
    a_sk, a_ck = float(x_k[0]), float(x_k[1])
    lo_c, hi_c = _ctrl_bounds(prob, g_k, dg_k, a_ck, l_k)
    u = prob.sum_max
    if lo_c > hi_c or lo_c + prob.min_share > u + 1e-15:
        return None

    def fun(x):
        f, df = prob.f_sen(x[0])
        d = x - x_k
        return f / f0 + rho * float(d @ d), np.array([df / f0 + 2.0 * rho * d[0], 2.0 * rho * d[1]])

    cons = [{"type": "ineq", "fun": lambda x: u - x[0] - x[1], "jac": lambda x: np.array([-1.0, -1.0])}]
    x0 = np.array([min(max(a_sk, prob.min_share), 1.0 - prob.min_share), min(max(a_ck, lo_c), hi_c)])
    if x0.sum() > u:
        x0[0] = max(prob.min_share, u - x0[1])
    res = minimize(fun, x0, jac=True, method="SLSQP", constraints=cons,
                   bounds=[(prob.min_share, 1.0 - prob.min_share), (lo_c, hi_c)],
                   options={"ftol": 1e-14, "maxiter": 200})
    x = np.clip(res.x, [prob.min_share, lo_c], [1.0 - prob.min_share, hi_c])
    if x.sum() > u:  # SLSQP may end a hair outside the coupling constraint
        x[0] = max(prob.min_share, u - x[1])
    return x


def _subproblem_kkt(prob, x_k, f0, rho, g_k, dg_k, l_k):
    r"""Solve the convex subproblem from its KKT conditions (no scipy optimiser).

    The objective is separable, :math:`\phi(\alpha_s) + \rho(\alpha_c - a_c)^2` with
    :math:`\phi = f_\mathrm{sen}/f_0 + \rho(\alpha_s - a_s)^2` convex, over a box with the single
    coupling :math:`\alpha_s + \alpha_c \le u`. Either the coupling is inactive (each variable its own
    clipped minimiser) or, on :math:`\alpha_s + \alpha_c = u`, the multiplier
    :math:`\mu = -\phi'(\alpha_s)` fixes :math:`\alpha_c = \mathrm{clip}(a_c - \mu/2\rho)` and the
    remaining scalar equation is monotone in :math:`\alpha_s` (bracketed root).
    """
    a_sk, a_ck = float(x_k[0]), float(x_k[1])
    lo_c, hi_c = _ctrl_bounds(prob, g_k, dg_k, a_ck, l_k)
    lo_s, hi_s = prob.min_share, 1.0 - prob.min_share
    u = prob.sum_max
    if lo_c > hi_c or lo_c + lo_s > u + 1e-15:
        return None

    def dphi(a):
        return prob.f_sen(a)[1] / f0 + 2.0 * rho * (a - a_sk)

    def argmin_s(shift):  # minimiser of phi(a) + shift * a on [lo_s, hi_s]
        if dphi(lo_s) + shift >= 0.0:
            return lo_s
        if dphi(hi_s) + shift <= 0.0:
            return hi_s
        return brentq(lambda a: dphi(a) + shift, lo_s, hi_s, xtol=1e-15)

    a_c = min(max(a_ck, lo_c), hi_c)
    a_s = argmin_s(0.0)
    if a_s + a_c <= u:
        return np.array([a_s, a_c])
    hi_line = min(hi_s, u - lo_c)

    def phi_line(a):  # increasing in a: a + alpha_c(mu(a)) - u
        return a + min(max(a_ck + dphi(a) / (2.0 * rho), lo_c), hi_c) - u

    if phi_line(lo_s) >= 0.0:
        a_s = lo_s
    elif phi_line(hi_line) <= 0.0:
        a_s = hi_line
    else:
        a_s = brentq(phi_line, lo_s, hi_line, xtol=1e-15)
    return np.array([a_s, min(max(u - a_s, lo_c), hi_c)])


SOLVERS = {"slsqp": _subproblem_slsqp, "kkt": _subproblem_kkt}


def solve_sca(prob: SCAProblem, x0=None, rho: float = 1.0, tol: float = 1e-12, max_iter: int = 100,
              solver: str = "slsqp") -> SCAResult:
    r"""Algorithm 1 (alg:sca_allocation): successive convex approximation of the reformulated problem.

    Parameters
    ----------
    prob : SCAProblem
    x0 : array_like (2,), optional
        Initial feasible point :math:`(\alpha_\mathrm{sen}^{(0)}, \alpha_\mathrm{ctrl}^{(0)})`; projected
        onto the constraint set; default :meth:`SCAProblem.feasible_start`.
    rho : float
        Proximal weight on the objective normalised by :math:`f_\mathrm{sen}(\alpha_\mathrm{sen}^{(0)})`.
    tol : float
        :math:`\delta` of the stopping rule :math:`\|\boldsymbol\alpha^{(k)}-\boldsymbol\alpha^{(k-1)}\|^2
        \le\delta`.
    max_iter : int
    solver : {"slsqp", "kkt"}
        Subproblem solver: scipy's SLSQP, or the exact KKT solution (:func:`_subproblem_kkt`, fast).

    Returns
    -------
    SCAResult

    Raises
    ------
    ValueError
        Unknown ``solver`` or non-positive ``rho``/``tol``.
    """
    if solver not in SOLVERS:
        raise ValueError(f"solver = {solver!r} is invalid: use one of {sorted(SOLVERS)}")
    if not rho > 0.0:
        raise ValueError(f"rho = {rho!r} is invalid: must be > 0")
    if not tol > 0.0:
        raise ValueError(f"tol = {tol!r} is invalid: must be > 0")
    t0 = time.perf_counter()
    start = prob.feasible_start()
    if start is None:
        alpha = _fallback_split(prob)
        return SCAResult(alpha, False, False, 0, float(prob.f_sen(alpha[0])[0]),
                         float(prob.g_ctrl(alpha[1])[0]), math.nan, math.nan, [],
                         time.perf_counter() - t0)
    x = start if x0 is None else _project(prob, np.asarray(x0, dtype=float))
    f0 = float(prob.f_sen(x[0])[0])
    sub = SOLVERS[solver]
    history = [x.copy()]
    converged = False
    iterations = 0
    for iterations in range(1, max_iter + 1):  # noqa: B007  (the count is reported)
        g_k, dg_k = (float(v) for v in prob.g_ctrl(x[1]))
        l_k = float(prob.rate_cost(x[0], x[1]))
        x_new = sub(prob, x, f0, rho, g_k, dg_k, l_k)
        if x_new is None:  # linearised rate-cost constraint infeasible: keep the last iterate
            break
        step = float(np.sum((x_new - x) ** 2))
        x = x_new
        history.append(x.copy())
        if step <= tol:
            converged = True
            break
    g, dg = (float(v) for v in prob.g_ctrl(x[1]))
    l_b = float(prob.rate_cost(x[0], x[1]))
    alpha = np.array([x[0], x[1], 1.0 - x[0] - x[1]])
    return SCAResult(alpha, converged, True, iterations, float(prob.f_sen(x[0])[0]), g, l_b,
                     _kkt_residual(prob, x, f0, g, dg, l_b), history, time.perf_counter() - t0)


def _project(prob: SCAProblem, x):
    lo_c = prob.ctrl_min
    a_c = min(max(float(x[1]), lo_c), 1.0 - prob.min_share)
    a_s = min(max(float(x[0]), prob.min_share), prob.sum_max - a_c)
    if a_s < prob.min_share:
        return prob.feasible_start()
    return np.array([a_s, a_c])


def _kkt_residual(prob, x, f0, g, dg, l_b, active_tol: float = 1e-7):
    r"""Stationarity of the original (non-linearised) problem at x: the smallest
    :math:`\|\nabla f/f_0 + \sum_i\lambda_i\nabla c_i\|` over :math:`\lambda\ge 0` and the active
    constraints :math:`c_i(\boldsymbol\alpha)\le 0`.
    """
    grad = np.array([prob.f_sen(x[0])[1] / f0, 0.0])
    normals = []
    u = prob.sum_max
    if x[0] + x[1] >= u - active_tol:
        normals.append([1.0, 1.0])
    if x[0] <= prob.min_share + active_tol:
        normals.append([-1.0, 0.0])
    if x[0] >= 1.0 - prob.min_share - active_tol:
        normals.append([1.0, 0.0])
    if x[1] <= prob.ctrl_min + active_tol:
        normals.append([0.0, -1.0])
    if x[1] >= 1.0 - prob.min_share - active_tol:
        normals.append([0.0, 1.0])
    if g - l_b <= active_tol * max(1.0, abs(l_b)):
        normals.append([0.0, -dg / max(abs(l_b), 1.0)])
    if not normals:
        return float(np.linalg.norm(grad))
    _, res = nnls(np.array(normals).T, -grad)
    return float(res)


def _fallback_split(prob: SCAProblem) -> np.ndarray:
    """Split used when the constraint set is empty (the slot cannot carry both the stable control
    share and the minimum rate). Stability comes first (the paper's "fundamental feasibility
    condition"): control gets its threshold share; sensing keeps ``prob.fallback_sen`` (per slot:
    the static design's sensing share) as far as control leaves room; the data link gets the rest,
    short of its minimum rate.
    """
    m = prob.min_share
    a_c = min(max(prob.ctrl_min, m), 1.0 - 2.0 * m)
    a_s = min(max(prob.fallback_sen, m), 1.0 - m - a_c)
    return np.array([a_s, a_c, 1.0 - a_s - a_c])


# --------------------------------------------------------------------------------------------------
# the static problem (trajectory-averaged quantities)
# --------------------------------------------------------------------------------------------------
def check_choice(name, value, choices):
    if value not in choices:
        raise ValueError(f"{name} = {value!r} is invalid: use one of {list(choices)}")


def static_problem(model: StaticModel, loss_model: str = "local", loss_design_fraction: float = 0.1,
                   ignore_loss: bool = False, enforce_trust: bool = True) -> SCAProblem:
    """The reformulated problem on a trajectory sample (the paper's static design).

    Parameters
    ----------
    model : StaticModel
        Trajectory sample and cached link, sensing and loss quantities.
    loss_model : {"local", "trajectory", "mean_snr"}
        Which loss rate defines the stability threshold and g (module docstring).
    loss_design_fraction : float in (0, 1]
        Design loss rate as a fraction of eps*.
    ignore_loss : bool
        Design as if every command arrived: eps_ctrl = 0 in g and L(b), no stability threshold
        (rho(M(0)) < 1 for any share), only the floor (the paper's failing baseline: no trust bound).
    enforce_trust : bool
        The stability threshold is at least the evaluator's trust edge
        (:meth:`iscc_gym.analysis.StaticModel.alpha_ctrl_trusted`: every sampled position's loss rate
        at most :data:`iscc_gym.analysis.TRUST_LOSS_FRACTION` x eps*), so that no reading of the
        threshold (``"mean_snr"``, ``"trajectory"``, a design fraction above 0.4) gives a split
        the env cannot hold. ``False``: the reading alone (e.g. the paper's literal alpha_ctrl*).

    Raises
    ------
    ValueError
        Unknown ``loss_model``; ``loss_design_fraction`` outside (0, 1].
    """
    check_choice("loss_model", loss_model, LOSS_MODELS)
    if not 0.0 < loss_design_fraction <= 1.0:
        raise ValueError(f"loss_design_fraction = {loss_design_fraction!r} is invalid: must be in (0, 1]")
    s = model.scenario
    eps_design = loss_design_fraction * model.eps_star
    coef = model.sensing

    def f_sen(a):
        tr, dtr = crlb_trace(coef, a)
        return float(np.mean(tr)), float(np.mean(dtr))

    gamma_bar = model.mean_snr
    ctrl_per_share_bits = model.rate_ctrl_per_share_bps * s.dt_s
    if loss_model == "mean_snr":
        def g_ctrl(a):
            g, dg = ctrl_goodput_bits(s, a, gamma_bar, ignore_loss=ignore_loss)
            return float(g), float(dg)

        def loss(a):
            return 0.0 if ignore_loss else float(ctrl_bler(s, a, gamma_bar))

        a_star = float(min_shares(s, gamma_bar, eps_design, 0.0)[0])
    else:
        def loss(a):
            return 0.0 if ignore_loss else float(model.eps_ctrl(a)[0])

        def g_ctrl(a):
            h = 1e-6 * max(a, 1e-3)
            e, e_p, e_m = loss(a), loss(a + h), loss(max(a - h, 1e-9))
            de = (e_p - e_m) / (a + h - max(a - h, 1e-9))
            return (1.0 - e) * a * ctrl_per_share_bits, ((1.0 - e) - de * a) * ctrl_per_share_bits

        a_star = model.alpha_ctrl_for_loss(eps_design, local=(loss_model == "local"))
    if ignore_loss:
        a_star = 0.0
    else:
        if enforce_trust:
            a_trust = model.alpha_ctrl_trusted()
            a_star = max(a_star, a_trust) if math.isfinite(a_trust) else math.nan
        if not math.isfinite(a_star):
            a_star = 1.0  # no share is enough: the problem is infeasible
        else:
            a_star *= 1.0 + 1e-9  # the strict inequality alpha_ctrl > alpha_ctrl*

    def rate_cost(a_s, a_c):
        return model.rate_cost_bits(float(a_s), loss(float(a_c)))

    return SCAProblem(f_sen, g_ctrl, rate_cost,
                      alpha_comm_min=s.rate_min_bps / model.rate_comm_per_share_bps,
                      alpha_ctrl_min=a_star)


def sca_allocation(s: Scenario, loss_model: str = "local", loss_design_fraction: float = 0.1,
                   ignore_loss: bool = False, model: StaticModel | None = None, rho: float = 1.0,
                   tol: float = 1e-12, max_iter: int = 100, solver: str = "slsqp",
                   enforce_trust: bool = True) -> SCAResult:
    """Static SCA allocation of scenario ``s`` (Algorithm 1 on trajectory-averaged quantities).

    ``model`` defaults to the cached :func:`iscc_gym.analysis.static_model` of ``s``; the other
    arguments as :func:`static_problem` and :func:`solve_sca`. ``wall_time_s`` covers the SCA
    iterations (the model is shared with the evaluator and built once per scenario).
    """
    model = static_model(s) if model is None else model
    t0 = time.perf_counter()
    prob = static_problem(model, loss_model, loss_design_fraction, ignore_loss, enforce_trust)
    res = solve_sca(prob, rho=rho, tol=tol, max_iter=max_iter, solver=solver)
    res.wall_time_s = time.perf_counter() - t0
    return res
