r"""``bayes``: the per-slot optimiser of :mod:`agents.myopic` on the posterior of a Bayesian filter of the world.

The field task (``iscc_gym/ISCC-Field-v0``, ``docs/model.md`` Sec. 8) hides two things from the designer's model: the
links' Rician K-factor, a field along the path, and the drone's RCS, one offset per mission. :class:`BayesPolicy` is
what a careful estimation engineer writes with the field's own prior (the preset's law, nothing learned):

* **State and prior.** A point-mass (grid) filter over :math:`(K_\mathrm{dB}, \Delta\sigma_\mathrm{dB})` per env,
  ``k_points`` x ``rcs_points`` cells over :math:`\pm 4` standard deviations. At a mission's start the prior is the
  world's law: :math:`K_\mathrm{dB} \sim \mathcal N(\mu_K, \sigma_K^2)` (``rician_k_db``, ``rician_k_std_db``),
  :math:`\Delta\sigma_\mathrm{dB} \sim \mathcal N(0, \sigma_\mathrm{RCS}^2)` (``rcs_std_db``), independent.
* **Dynamics.** The K-factor's field has exponential correlation over the plane (``physics.blockage.draw_field``),
  so along the path it is Gauss-Markov in the distance flown:
  :math:`K_{t+1} = \mu_K + \rho (K_t - \mu_K) + \sqrt{1-\rho^2}\,\sigma_K\,\epsilon`,
  :math:`\rho = e^{-\Delta d/\ell}` (``rician_k_correlation_m``), :math:`\Delta d` the horizontal distance between the
  slots' estimated positions (from the observation's range and direction). The RCS offset is constant. **Stated
  approximation:** a path that comes back near an earlier point is correlated with it in the world, not in the
  filter.
* **Likelihood.** The observation's measured block carries the last slot's fading power gain of the command link,
  :math:`g`, and its echo SNR. Both fade with the slot's K (independent draws, ``loop.step_one``): the link's exact
  unit-mean Rician power density
  :math:`f(g\mid K) = (K+1)e^{-K}e^{-(K+1)g} I_0\!\left(2\sqrt{K(K+1)g}\right)`, and the echo's power over the model's
  prediction at the slot's estimated geometry, :math:`e = h\,10^{\Delta\sigma/10}` with :math:`h \sim f(\cdot\mid K)`,
  so :math:`p(e\mid K, \Delta\sigma) = 10^{-\Delta\sigma/10} f(e\,10^{-\Delta\sigma/10}\mid K)`, jointly. The echo's
  likelihood is raised to ``echo_weight`` (the predicted geometry's error makes it a little less sharp than the
  law; tuned on training missions).
* **Design.** Each slot is designed on the posterior-predictive fading law, not a point estimate: the fading
  quadrature's nodes are the quantiles of the mixture :math:`\sum_i w_i f(\cdot\mid K_i)` at the bins of
  :func:`iscc_gym.analysis.quadrature.rician_power_nodes`, and the probability that the slot's fade pushes the
  command's loss above :math:`\varepsilon^\star` is the mixture's CDF. The RCS enters the CRLB as an inverse
  power, so the slot is designed for the offset whose inverse power is the posterior mean of
  :math:`10^{-\Delta\sigma/10}`.

At the limits: no spread in the prior (:math:`\sigma_K = \sigma_\mathrm{RCS} = 0`) the posterior is the model's point
and the policy is ``myopic``; a posterior concentrated on the true world is ``aware`` (``myopic`` shown it)
(``tests/agents/test_bayes.py``, with the filter against Monte Carlo). ``echo_weight`` and ``correlation_scale``
are tuned on training seeds (``python -m eval.tune bayes --scenario field``; ``agents/tuned/bayes.yml``).
"""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy.special import chndtr, i0e, ndtr

from iscc_gym.scenario import Scenario
from iscc_gym.sim.functional import decode_observation
from iscc_gym.units import db_to_lin

from .adaptive import check_world_estimator, model_echo_snr_db
from .base import as_obs_batch
from .geometry import predicted_geometry
from .myopic import MyopicPolicy

__all__ = ["BayesPolicy", "rician_log_pdf", "transition_matrix", "MixtureLaw", "estimator_inputs", "ESTIMATOR_INPUTS"]

#: Width of the grids, in prior standard deviations either side of the mean.
GRID_SIGMAS = 4.0
#: With ``learn_prior``: the grids' width in the designer's standard deviations (room for a wider or shifted law).
LEARN_GRID_SIGMAS = 6.0
#: With ``learn_prior``: the designer's prior counts as this many filtered posteriors (row-slots).
PRIOR_PSEUDO_SLOTS = 2000.0
#: The gain grid of the mixture's CDF table: log-spaced, wide enough for the deepest quadrature bin at K = -20 dB.
_LOG_G = np.linspace(math.log(1e-12), math.log(60.0), 6001)


#: What a learned estimator of the world reads each slot (:func:`estimator_inputs`; ``agents/estimator.py``).
ESTIMATOR_INPUTS = ("new mission", "link fade dB / 10", "link fade gain", "echo over prediction dB / 10",
                    "echo over prediction (power ratio)", "echo measured", "distance flown / correlation distance")


def estimator_inputs(new, g, e_db, step) -> np.ndarray:
    """The measurements :class:`BayesPolicy`'s likelihood and dynamics read, as a learned estimator's inputs
    (:data:`ESTIMATOR_INPUTS`), float32 (n, 7): ``new`` (n,) bool, the row's first slot (every other entry 0 there);
    ``g`` the link's last fading power gain, in dB and as a power ratio (the Rician log-likelihood is close to linear
    in both); ``e_db`` the last echo over its prediction, dB (NaN: none), the same two ways; ``step`` the horizontal
    distance flown since the last slot over the prior's correlation distance (NaN: none). Clipped: the dB entries to
    [-6, 2] (60 dB below the mean to 20 dB above), the power ratios to [0, 10], the distance to [0, 5].
    """
    new = np.asarray(new, dtype=bool)
    seen = ~new
    fade = np.clip(np.log10(np.maximum(np.asarray(g, dtype=float), 1e-6)), -6.0, 2.0)
    e = np.asarray(e_db, dtype=float)
    ok = seen & np.isfinite(e)
    echo = np.clip(np.where(ok, e, 0.0) / 10.0, -6.0, 2.0)
    s = np.asarray(step, dtype=float)
    s = np.clip(np.where(seen & np.isfinite(s), s, 0.0), 0.0, 5.0)
    fade = np.where(seen, fade, 0.0)
    return np.stack([new, fade, np.minimum(10.0 ** fade, 10.0) * seen, echo,
                     np.where(ok, np.minimum(10.0 ** echo, 10.0), 0.0), ok, s], axis=1).astype(np.float32)


@functools.lru_cache(maxsize=1)
def _mids() -> np.ndarray:
    """The fading quadrature's bin midpoints (probabilities), from its weights
    (:func:`iscc_gym.analysis.quadrature.rician_power_nodes`: the quantiles at the bins' midpoints).
    """
    from iscc_gym.analysis.quadrature import rician_power_nodes

    w = rician_power_nodes(1.0)[1]
    return np.cumsum(w) - 0.5 * w


def rician_log_pdf(g, k_lin):
    r""":math:`\log f(g\mid K)` of the unit-mean Rician power gain (broadcast ``g`` >= 0 against ``k_lin``):
    :math:`\log(K+1) - K - (K+1)g + \log I_0(2\sqrt{K(K+1)g})`, through the scaled Bessel function (no overflow).
    """
    g = np.maximum(np.asarray(g, dtype=float), 0.0)
    k = np.asarray(k_lin, dtype=float)
    z = 2.0 * np.sqrt(k * (k + 1.0) * g)
    return np.log1p(k) - k - (k + 1.0) * g + np.log(i0e(z)) + z


def transition_matrix(grid, mean, std, rho):
    r"""Row-stochastic ``(n, G, G)`` matrices of the Gauss-Markov step on ``grid`` (G,) for correlations ``rho``
    (n,): row i is :math:`\mathcal N(\mu + \rho(x_i - \mu), (1-\rho^2)\sigma^2)` integrated over each cell (edges
    halfway between grid points, the outer ones at infinity), so a step shorter than a cell keeps its mass.
    """
    grid = np.asarray(grid, dtype=float)
    rho = np.asarray(rho, dtype=float)[:, None, None]
    edges = np.concatenate([[-np.inf], 0.5 * (grid[1:] + grid[:-1]), [np.inf]])
    m = mean + rho * (grid[None, :, None] - mean)
    s = np.maximum(std * np.sqrt(np.maximum(1.0 - rho * rho, 0.0)), 1e-12)
    cdf = ndtr((edges[None, None, :] - m) / s)
    return np.diff(cdf, axis=-1)


@functools.lru_cache(maxsize=8)
def _cdf_table(k_db: tuple) -> np.ndarray:
    """The Rician power CDF at every K of ``k_db`` on :data:`_LOG_G`, (G, 6001), read-only."""
    k = db_to_lin(np.asarray(k_db, dtype=float))[:, None]
    table = chndtr(np.exp(_LOG_G)[None, :] * (2.0 * (k + 1.0)), 2.0, 2.0 * k)
    table.setflags(write=False)
    return table


class MixtureLaw:
    r"""The posterior-predictive fading law of a batch: the mixture :math:`\sum_i w_{ni} f(\cdot\mid K_i)` per row.

    :meth:`cdf` evaluates it at gains of any shape (n, ...); :meth:`nodes` gives its quantiles at the fading
    quadrature's bins (n, 30), the nodes :class:`agents.myopic.MyopicPolicy` designs on.
    """

    def __init__(self, k_db, weights):
        self.cdf_table = np.asarray(weights, dtype=float) @ _cdf_table(tuple(np.asarray(k_db, dtype=float)))
        np.maximum.accumulate(self.cdf_table, axis=1, out=self.cdf_table)  # monotone to round-off

    def nodes(self) -> np.ndarray:
        """The mixture's quantiles at the quadrature's bin midpoints, (n, 30): interpolated in (log CDF, log g)."""
        log_cdf = np.log(np.maximum(self.cdf_table, 1e-300))
        q = np.log(_mids())
        return np.stack([np.exp(np.interp(q, row, _LOG_G)) for row in log_cdf])

    def cdf(self, x) -> np.ndarray:
        r""":math:`P(g \le x)` per row, ``x`` (n, ...): linear in log g between the table's points; below the table
        the CDF's linear start (a power gain's density is finite at 0), above it 1.
        """
        x = np.asarray(x, dtype=float)
        n, m = self.cdf_table.shape
        step = _LOG_G[1] - _LOG_G[0]
        u = (np.log(np.maximum(x, 1e-300)) - _LOG_G[0]) / step
        i = np.clip(np.floor(u).astype(np.intp), 0, m - 2)
        t = np.clip(u - i, 0.0, 1.0)
        rows = np.arange(n).reshape((n,) + (1,) * (x.ndim - 1))
        c = (1.0 - t) * self.cdf_table[rows, i] + t * self.cdf_table[rows, i + 1]
        low = self.cdf_table[rows, 0] * np.exp(np.minimum(u, 0.0) * step)
        return np.where(u < 0.0, low, np.where(u >= m - 1, 1.0, c))


class BayesPolicy(MyopicPolicy):
    r""":class:`agents.myopic.MyopicPolicy` designed each slot on the posterior of a grid filter of the world
    (see the module docstring). Keeps one posterior per env of the batch (the rows of the observations, in the order
    the vector env gives them); a row at slot 0 starts from the prior.

    Parameters
    ----------
    scenario : Scenario or str
        The designer's model with the world's law: a scenario with the field (``rician_k_std_db`` or
        ``rcs_std_db`` > 0), whose observation has the measured block; its ``rician_k_db``, ``rician_k_std_db``,
        ``rician_k_correlation_m`` and ``rcs_std_db`` are the prior.
    k_points, rcs_points : int
        Grid cells of the K-factor and of the RCS offset (>= 3, odd: the prior's mean is a cell).
    echo_weight : float
        Exponent in [0, 1] of the echo's likelihood (0: the link's gains alone).
    correlation_scale : float
        The prior's correlation distance times this (> 0; 1: the world's law).
    learn_prior : bool
        Re-estimate the prior's moments online (empirical Bayes): the mean and spread of the K-factor and of the RCS
        offset, from every filtered posterior seen (all the batch's missions and slots so far, pooled with
        :data:`PRIOR_PSEUDO_SLOTS` pseudo-observations of the designer's prior) by the law of total variance,
        :math:`\hat\mu = \overline{\mathbb E[x]}`, :math:`\hat\sigma^2 = \overline{\mathrm{Var}[x] +
        \mathbb E[x]^2} - \hat\mu^2`; a new mission starts from them and the K-factor's steps revert to them. The
        correlation distance stays the prior's. The grids then span :data:`LEARN_GRID_SIGMAS` of the designer's
        spreads. False (the default): the designer's prior throughout.
    **kwargs
        :class:`agents.myopic.MyopicPolicy`'s search parameters.
    """

    def __init__(self, scenario: Scenario | str = "field", k_points: int = 41, rcs_points: int = 31,
                 echo_weight: float = 1.0, correlation_scale: float = 1.0, learn_prior: bool = False, **kwargs):
        super().__init__(scenario, **kwargs)
        s = self.scenario
        check_world_estimator(self, "filters")
        for name, value in (("k_points", k_points), ("rcs_points", rcs_points)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 3 or value % 2 == 0:
                raise ValueError(f"{name} = {value!r} is invalid: must be an odd integer >= 3")
        for name, value, ok, where in (("echo_weight", echo_weight, lambda v: 0.0 <= v <= 1.0, "in [0, 1]"),
                                       ("correlation_scale", correlation_scale, lambda v: 0.0 < v, "> 0")):
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or \
                    not math.isfinite(float(value)) or not ok(float(value)):
                raise ValueError(f"{name} = {value!r} is invalid: must be a finite number {where}")
        self.echo_weight = float(echo_weight)
        self.correlation_scale = float(correlation_scale)
        self.k_points, self.rcs_points = int(k_points), int(rcs_points)
        self.k_mean, self.k_std = float(s.rician_k_db), float(s.rician_k_std_db)
        self.rcs_std = float(s.rcs_std_db)
        self.correlation_m = float(s.rician_k_correlation_m) * self.correlation_scale
        if not isinstance(learn_prior, (bool, np.bool_)):
            raise ValueError(f"learn_prior = {learn_prior!r} is invalid: must be True or False")
        self.learn_prior = bool(learn_prior)
        width = LEARN_GRID_SIGMAS if self.learn_prior else GRID_SIGMAS
        self.k_grid = self.k_mean + self.k_std * np.linspace(-width, width, self.k_points) \
            if self.k_std > 0 else np.array([self.k_mean])
        self.rcs_grid = self.rcs_std * np.linspace(-width, width, self.rcs_points) \
            if self.rcs_std > 0 else np.array([0.0])
        self._k_lin = db_to_lin(self.k_grid)
        self.rcs_mean = 0.0
        # the pooled sufficient statistics of the filtered posteriors (learn_prior), the designer's prior as
        # PRIOR_PSEUDO_SLOTS pseudo-observations
        n0 = PRIOR_PSEUDO_SLOTS
        self._stats = np.array([n0, n0 * self.k_mean, n0 * (self.k_std ** 2 + self.k_mean ** 2),
                                n0 * 0.0, n0 * self.rcs_std ** 2])
        self._set_prior()
        self._rows = 0
        self.name = "bayes-learn" if self.learn_prior else "bayes"

    def _set_prior(self) -> None:
        """The joint prior of a new mission from the current (designer's or learned) moments."""
        self._prior = self._prior_of(self.k_grid, self.k_mean, self.k_std)[:, None] * \
            self._prior_of(self.rcs_grid, self.rcs_mean, self.rcs_std)[None, :]

    def _learn(self, post, seen) -> None:
        """Pool the filtered posteriors of the rows ``seen`` into the moments (see ``learn_prior``)."""
        if not seen.any():
            return
        p = post[seen]
        wk, wr = p.sum(axis=2), p.sum(axis=1)
        mk, mr = wk @ self.k_grid, wr @ self.rcs_grid
        self._stats += np.array([len(p), mk.sum(), (wk @ self.k_grid ** 2).sum(), mr.sum(),
                                 (wr @ self.rcs_grid ** 2).sum()])
        n, s1, s2, r1, r2 = self._stats
        self.k_mean = s1 / n
        self.k_std = math.sqrt(max(s2 / n - self.k_mean ** 2, 1e-6)) if self.k_std > 0 else 0.0
        self.rcs_mean = r1 / n
        self.rcs_std = math.sqrt(max(r2 / n - self.rcs_mean ** 2, 1e-6)) if self.rcs_std > 0 else 0.0
        self._set_prior()

    @staticmethod
    def _prior_of(grid, mean, std):
        if std <= 0:
            return np.ones(1)
        p = np.exp(-0.5 * ((grid - mean) / std) ** 2)
        return p / p.sum()

    def _restart(self, n: int) -> None:
        self._rows = n
        self.posterior = np.repeat(self._prior[None], n, axis=0)
        self._echo_pred_db = np.full(n, np.nan)
        self._pos = np.full((n, 2), np.nan)

    # --- the filter ---------------------------------------------------------------------------
    def measure(self, decoded: dict):
        """Each row's last measurements against the model and this slot's geometry: ``(g, e_db, step_m, pos,
        echo_pred_db)``, the link's last fading power gain, the last echo SNR over its prediction (dB; NaN where
        none), the horizontal distance flown since the last slot (m; NaN at a row's first slot), this slot's
        estimated horizontal position (n, 2) and the echo SNR the model predicts for it (dB). Reads, never sets,
        the per-row memory (:meth:`remember` does).
        """
        g = db_to_lin(decoded["last_fade_db"])
        e_db = decoded["last_echo_snr_db"] - self._echo_pred_db
        dist, trig, shadow_db = predicted_geometry(self.scenario, decoded["snr_db"], decoded["range_m"],
                                                   decoded["sin_elevation"], decoded["cos_azimuth"],
                                                   decoded["sin_azimuth"], self._gain)
        cos_az, sin_az, cos_el, _ = trig
        pos = np.stack([dist * cos_el * cos_az, dist * cos_el * sin_az], axis=1)
        return g, e_db, np.hypot(*(pos - self._pos).T), pos, model_echo_snr_db(self.scenario, dist, shadow_db)

    def measured_inputs(self) -> np.ndarray:
        """The last update's measurements (:attr:`measured`: new-mission flags, link gains, echoes over their
        prediction, distances flown) as a learned estimator's inputs (:func:`estimator_inputs`), the distance over
        the prior's correlation distance.
        """
        new, g, e_db, step = self.measured
        return estimator_inputs(new, g, e_db, step / self.correlation_m)

    def remember(self, pos, echo_pred_db) -> None:
        """Keep this slot's position and echo prediction for the next slot's :meth:`measure`."""
        self._pos = pos
        self._echo_pred_db = echo_pred_db

    def update(self, decoded: dict) -> None:
        """Take in each row's last measurement (the link's gain and the echo against its prediction) and step the
        K-factor to this slot's position; rows at slot 0 restart from the prior.
        """
        n = decoded["snr_db"].shape[0]
        if self._rows != n:
            self._restart(n)
        new = decoded["slot"] < 0.5
        post = self.posterior
        post[new] = self._prior
        seen = ~new
        g, e_db, step, pos, echo_pred_db = self.measure(decoded)
        self.measured = (new, g, e_db, step)
        if seen.any():
            log_l = np.zeros(post.shape)
            log_l += rician_log_pdf(g[:, None], self._k_lin[None, :])[:, :, None]
            ok = seen & np.isfinite(e_db) & (self.echo_weight > 0.0)
            if ok.any():
                h = db_to_lin(e_db[:, None, None] - self.rcs_grid[None, None, :])
                log_e = rician_log_pdf(np.where(ok[:, None, None], h, 1.0), self._k_lin[None, :, None]) \
                    - (math.log(10.0) / 10.0) * self.rcs_grid[None, None, :]
                log_l += np.where(ok[:, None, None], self.echo_weight * log_e, 0.0)
            log_l -= log_l.max(axis=(1, 2), keepdims=True)
            upd = post * np.exp(log_l)
            upd /= np.maximum(upd.sum(axis=(1, 2), keepdims=True), 1e-300)
            post = np.where(seen[:, None, None], upd, post)
            if self.learn_prior:
                self._learn(post, seen)
        # the K-factor's step to this slot's position (Gauss-Markov in the distance flown)
        if self.k_std > 0 and seen.any():
            rho = np.exp(-np.where(np.isfinite(step), step, 0.0) / self.correlation_m)
            trans = transition_matrix(self.k_grid, self.k_mean, self.k_std, rho)
            moved = np.einsum("nij,nir->njr", trans, post)
            post = np.where(seen[:, None, None], moved, post)
        self.posterior = post
        self.remember(pos, echo_pred_db)

    def k_marginal(self) -> np.ndarray:
        """The posterior of this slot's K-factor on :attr:`k_grid`, (n, k_points)."""
        return self.posterior.sum(axis=2)

    def rcs_offset_db(self) -> np.ndarray:
        r"""The RCS offset the slot is designed for, dB (n,): :math:`-10\log_{10}\mathbb E[10^{-\Delta\sigma/10}]`
        over the posterior (the CRLB's inverse power, averaged).
        """
        inv = (self.posterior.sum(axis=1) * db_to_lin(-self.rcs_grid)[None, :]).sum(axis=1)
        return -10.0 * np.log10(inv)

    def k_estimate_db(self) -> tuple[np.ndarray, np.ndarray]:
        """The posterior mean and standard deviation of this slot's K-factor, dB (n,) each (for figures)."""
        w = self.k_marginal()
        mean = w @ self.k_grid
        return mean, np.sqrt(np.maximum(w @ (self.k_grid ** 2) - mean ** 2, 0.0))

    # --- the design ---------------------------------------------------------------------------
    def slot_context(self, obs):
        """Decode a batch of observations, update the filter, and design on the posterior-predictive law."""
        s = self.scenario
        o, _ = as_obs_batch(obs, self.obs_size)
        if not np.all(np.isfinite(o)):
            raise ValueError("obs contains NaN or inf; pass the env's (finite) observations")
        d = decode_observation(o, s)
        self.update(d)
        law = MixtureLaw(self.k_grid, self.k_marginal())
        return self.context(d["snr_db"], d["range_m"], d["sin_elevation"], d["cos_azimuth"], d["sin_azimuth"],
                            d.get("echo_snr_db"), d.get("backlog_bits"), rcs_offset_db=self.rcs_offset_db(),
                            fade=law.nodes(), fade_cdf=law.cdf)

    def __repr__(self) -> str:
        return (f"BayesPolicy(echo_weight={self.echo_weight:g}, correlation_scale={self.correlation_scale:g}, "
                f"k_points={self.k_points}, rcs_points={self.rcs_points}, "
                + super().__repr__().split("(", 1)[1])
