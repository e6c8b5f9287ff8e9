r"""Scripted baselines of the multi-drone env (``iscc_gym/ISCC-Multi-v0``, :mod:`iscc_gym.envs.multi`).

Each maps a batch of observations (n, 23K) to the 3K shares of every env and plays them with
:func:`iscc_gym.sim.fleet.shares_to_action` (SB3's ``predict``, like the single-drone policies):

* ``equal-sca`` (:class:`EqualShareSCA`): every drone gets 1/K of the band and, inside it, the paper's
  per-slot Algorithm 1 solution for that drone (:class:`iscc_gym.agents.sca_slot.SCAPolicy`,
  ``mode="per_slot"``). Algorithm 1's per-slot objective, :math:`\operatorname{Tr}\mathrm{CRLB}_\mathbf p
  (\alpha_\mathrm{sen})`, does not depend on the control and data shares and decreases in the sensing
  share, and the rate-cost constraint is far from binding per slot (under 2 bits), so its solution is
  the smallest control share meeting the stability design and the smallest data share carrying the
  drone's rate, sensing the rest; within a share b that is ``ctrl = ctrl_min``, ``comm = comm_min``,
  ``sen = b - ctrl - comm``. Where they do not fit, :class:`SCAPolicy`'s fallback inside the share:
  control first, sensing keeps the static design's share, data the rest.
* ``joint-sca`` (:class:`JointSCA`): Algorithm 1's problem over all K drones (Sec. 5 of
  docs/model.md): minimise :math:`\sum_k \operatorname{Tr}\mathrm{CRLB}_{\mathbf p,k}(\alpha_{k,\mathrm{sen}})`
  subject to every drone's stability design and rate and the shares summing to 1. With the
  constraints separable and the objective convex and decreasing in each sensing share, the KKT point
  is control and data at their bounds and the sensing shares water-filled: equal marginal CRLB
  decrease :math:`-f'_k(\alpha_{k,\mathrm{sen}}) = \mu` (bisection on :math:`\mu`), no
  linearisation needed (the SCA's iterations would converge to it). Where the drones' bounds do not fit in
  the band (the problem is infeasible: at K = 8 on the ``paper`` preset the control bounds alone exceed it),
  control first, every drone's bound (where they exceed the band, the largest cut to a common level, so
  that as many drones as possible meet theirs), then data scaled into what is left above a total sensing
  floor, sensing water-filled over the rest (:data:`JointSCA.sensing_floor`, by default the tuned
  ``margin``'s floor). The fallback used to keep the static design's sensing share (0.54 of the band) and scale the
  control down into the rest: at K = 4 and 8 it starved the drones' control links and lost track (issue 34).
* ``margin`` (:class:`MultiMarginPolicy`): the tuned single-drone ``margin`` rule per drone (control
  ``m_ctrl`` times its predicted need, data ``m_comm`` times it), the demands renormalised onto the
  band (control first, then data, above a total sensing floor), sensing the rest split equally.
* ``margin-starved`` (:class:`ScaledSensing` of ``margin``, :data:`STARVED_SCALE`): ``margin`` with every
  drone's sensing share cut to a tenth, the rest given to the drone's data link: a policy that buys
  rate with its radar, the direction the old summed-penalty reward paid for (issue 23). Under the
  per-drone mean reward it scores worse than ``margin`` (docs/learning.md, tests/agents/test_multi_agents.py).
"""

from __future__ import annotations

import numpy as np

from iscc_gym.analysis.sensing_share import crlb_trace
from iscc_gym.scenario import Scenario
from iscc_gym.sim.fleet import multi_split, shares_to_action
from iscc_gym.sim.functional import decode_observation
from iscc_gym.sim.schema import N_OBS

from .margin import predicted_needs
from .sca import MIN_SHARE
from .sca_slot import SCAPolicy
from .tuned_records import load_tuned

__all__ = ["MultiSharePolicy", "EqualShareSCA", "JointSCA", "MultiMarginPolicy", "ScaledSensing", "fit_demands",
           "level_cap", "make_multi_policy", "MULTI_POLICY_SPECS", "STARVED_SCALE"]

#: The spec names of :func:`make_multi_policy`.
MULTI_POLICY_SPECS = ("equal-sca", "joint-sca", "margin", "margin-starved", "equal")
#: The sensing scale of ``margin-starved`` (:class:`ScaledSensing`).
STARVED_SCALE = 0.1


class MultiSharePolicy:
    """Base of the multi-drone scripted policies: :meth:`shares_batch` gives the shares (n, K, 3) of
    observations (n, 23K); :meth:`predict` plays them (SB3's protocol).
    """

    def __init__(self, n_drones: int):
        self.n_drones = int(n_drones)

    def shares_batch(self, obs: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def predict(self, obs, state=None, episode_start=None, deterministic: bool = True):
        o = np.asarray(obs, dtype=float)
        single = o.ndim == 1
        k = self.n_drones
        if o.shape[-1] != k * N_OBS or o.ndim not in (1, 2):
            raise ValueError(f"obs must have shape ({k * N_OBS},) or (n, {k * N_OBS}) for {k} drones, got {o.shape}")
        shares = self.shares_batch(o.reshape(-1, k, N_OBS))
        action = shares_to_action(shares)
        return (action[0] if single else action), state


def fit_demands(ctrl, comm, floor: float = 0.0, level: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Control and data shares (n, K) fitted onto the band above a total sensing ``floor``: control
    first (scaled down together if the drones' control demands exceed ``1 - floor``; with ``level``, cut to a
    common level instead, :func:`level_cap`), then data in what is left (scaled down together).
    """
    room = 1.0 - floor
    c_tot = ctrl.sum(-1, keepdims=True)
    if level:
        ctrl = level_cap(ctrl, room)
    else:
        ctrl = ctrl * np.minimum(1.0, room / np.maximum(c_tot, 1e-300))
    left = room - ctrl.sum(-1, keepdims=True)
    m_tot = comm.sum(-1, keepdims=True)
    comm = comm * np.minimum(1.0, np.maximum(left, 0.0) / np.maximum(m_tot, 1e-300))
    return ctrl, comm


def level_cap(x, total: float) -> np.ndarray:
    r"""Demands ``x`` (n, K) cut to a common level where they exceed ``total``: :math:`\min(x_k, \lambda)` with
    :math:`\sum_k \min(x_k, \lambda) = ` ``total`` (rows within it unchanged). Every demand up to the level is met
    in full, so as many drones as the band allows meet theirs; only the largest are cut, equally.
    """
    x = np.asarray(x, dtype=float)
    n, k = x.shape
    s = np.sort(x, axis=-1)
    below = np.concatenate([np.zeros((n, 1)), np.cumsum(s, axis=-1)[:, :-1]], axis=-1)
    lam = (total - below) / (k - np.arange(k))  # the level if the j smallest demands are met in full
    level = lam[np.arange(n), np.argmax(lam <= s, axis=-1)]
    return np.where((s.sum(-1) > total)[:, None], np.minimum(x, level[:, None]), x)


class _SlotBounds(MultiSharePolicy):
    """Per-slot SCA terms of every drone (:meth:`SCAPolicy.slot_terms`)."""

    def __init__(self, scenario: Scenario, n_drones: int):
        super().__init__(n_drones)
        self.scenario = scenario
        self.sca = SCAPolicy(scenario, mode="per_slot")

    def terms(self, obs: np.ndarray):
        d = decode_observation(obs, self.scenario)
        coef, ctrl, comm = self.sca.slot_terms(d["snr_db"], d["range_m"], d["sin_elevation"], d["cos_azimuth"],
                                               d["sin_azimuth"])
        ctrl = np.where(np.isfinite(ctrl), ctrl, 1.0)
        return coef, np.maximum(ctrl, MIN_SHARE), np.maximum(comm, MIN_SHARE)


class EqualShareSCA(_SlotBounds):
    """1/K of the band per drone, per-slot Algorithm 1 inside it (module docstring)."""

    name = "equal-sca"

    def shares_batch(self, obs):
        _, ctrl, comm = self.terms(obs)
        b = 1.0 / self.n_drones
        fits = ctrl + comm <= b * (1.0 - MIN_SHARE)
        # SCAPolicy's fallback inside the share: control first, sensing keeps the static design's share
        c_fb = np.minimum(ctrl, b * (1.0 - 2.0 * MIN_SHARE))
        s_fb = np.minimum(np.maximum(self.sca.split[0] * b, MIN_SHARE * b), b * (1.0 - MIN_SHARE) - c_fb)
        ctrl = np.where(fits, ctrl, c_fb)
        sen = np.where(fits, b - ctrl - comm, s_fb)
        return np.stack([sen, ctrl, b - sen - ctrl], axis=-1)


class JointSCA(_SlotBounds):
    """Algorithm 1's per-slot problem over all K drones: bounds, then water-filled sensing (module
    docstring). Where the drones' bounds do not fit in the band: control first (every drone's bound; above
    ``1 - sensing_floor`` the largest bounds cut to a common level, :func:`level_cap`), data scaled into what is left
    above the total ``sensing_floor``, sensing water-filled over the rest.
    ``iterations``: bisection steps of the multiplier and of each drone's share.
    """

    name = "joint-sca"

    def __init__(self, scenario: Scenario, n_drones: int, iterations: int = 40, sensing_floor: float = 0.0345):
        super().__init__(scenario, n_drones)
        self.iterations = int(iterations)
        floor = float(sensing_floor)
        if not (np.isfinite(floor) and self.n_drones * MIN_SHARE <= floor < 1.0):
            raise ValueError(f"sensing_floor = {sensing_floor!r}; use a total sensing share in "
                             f"[{self.n_drones * MIN_SHARE:g}, 1) (at least {MIN_SHARE:g} per drone)")
        self.sensing_floor = floor

    def shares_batch(self, obs):
        coef, ctrl, comm = self.terms(obs)
        k = self.n_drones
        fits = (ctrl.sum(-1) + comm.sum(-1) <= 1.0 - k * MIN_SHARE)[:, None]
        c_fb, m_fb = fit_demands(ctrl, comm, self.sensing_floor, level=True)
        ctrl, comm = np.where(fits, ctrl, c_fb), np.where(fits, comm, m_fb)
        sen = self.water_fill(coef, 1.0 - ctrl.sum(-1) - comm.sum(-1))
        return np.stack([sen, ctrl, comm], axis=-1)

    def water_fill(self, coef, total):
        r"""Sensing shares (n, K) summing to ``total`` (n,) with equal :math:`-f'_k`: for a multiplier
        :math:`\mu`, each drone's share solves :math:`-f'_k(a) = \mu` (bisection in log a, f' increasing),
        and :math:`\mu` is bisected (in log) until the shares add up to the total.
        """
        n, k = coef.info_range.shape
        lo_a, hi_a = np.log(1e-9), 0.0

        def shares(mu):  # (n,) -> (n, K)
            lo = np.full((n, k), lo_a)
            hi = np.full((n, k), hi_a)
            for _ in range(self.iterations):
                mid = 0.5 * (lo + hi)
                _, df = crlb_trace(coef, np.exp(mid))
                big = -df > mu[:, None]  # the marginal gain still above mu: a larger share
                lo, hi = np.where(big, mid, lo), np.where(big, hi, mid)
            return np.exp(0.5 * (lo + hi))

        lo_mu, hi_mu = np.full(n, -60.0), np.full(n, 60.0)  # log mu
        for _ in range(self.iterations):
            mid = 0.5 * (lo_mu + hi_mu)
            over = shares(np.exp(mid)).sum(-1) > total  # too much: raise mu
            lo_mu, hi_mu = np.where(over, mid, lo_mu), np.where(over, hi_mu, mid)
        a = shares(np.exp(hi_mu))
        s = a.sum(-1, keepdims=True)
        return np.where(s > 0, a * (total[:, None] / np.where(s > 0, s, 1.0)), total[:, None] / k)


class MultiMarginPolicy(MultiSharePolicy):
    """The ``margin`` rule per drone, renormalised onto the band (module docstring)."""

    name = "margin"

    def __init__(self, n_drones: int, m_ctrl: float, m_comm: float, sensing_floor: float):
        super().__init__(n_drones)
        self.m_ctrl, self.m_comm, self.sensing_floor = float(m_ctrl), float(m_comm), float(sensing_floor)

    @classmethod
    def tuned(cls, n_drones: int) -> MultiMarginPolicy:
        """With the single-drone multiples of ``python -m eval.tune margin``."""
        p = load_tuned("margin")["params"]
        return cls(n_drones, p["m_ctrl"], p["m_comm"], p["sensing_floor"])

    def shares_batch(self, obs):
        n, k, _ = obs.shape
        need_c, need_m = predicted_needs(obs.reshape(n * k, N_OBS))
        ctrl = self.m_ctrl * np.maximum(need_c, 0.0).reshape(n, k)
        comm = self.m_comm * np.maximum(need_m, 0.0).reshape(n, k)
        ctrl, comm = fit_demands(ctrl, comm, self.sensing_floor)
        sen = (1.0 - ctrl.sum(-1, keepdims=True) - comm.sum(-1, keepdims=True)) / k
        return np.concatenate([np.broadcast_to(sen, (n, k))[..., None], ctrl[..., None], comm[..., None]], axis=-1)


class ScaledSensing(MultiSharePolicy):
    """Another multi-drone policy's shares with every drone's sensing share times ``scale``.

    The difference goes to (``scale`` < 1) or comes from (``scale`` > 1, at most the whole data share)
    the same drone's data share, so its control share and its band are the base policy's. ``base``: any
    policy with SB3's ``predict`` on the env with ``n_drones`` drones (a scripted baseline or a trained
    agent); its actions are read as shares with :func:`iscc_gym.sim.fleet.multi_split`.
    """

    def __init__(self, base, n_drones: int, scale: float):
        super().__init__(n_drones)
        scale = float(scale)
        if not (np.isfinite(scale) and scale >= 0.0):
            raise ValueError(f"scale = {scale!r}; use a finite sensing multiple >= 0")
        self.base, self.scale = base, scale
        self.name = f"{getattr(base, 'name', 'policy')}-sensing-x{scale:g}"

    def shares_batch(self, obs):
        n, k, _ = obs.shape
        action, _ = self.base.predict(obs.reshape(n, k * N_OBS), deterministic=True)
        alpha = multi_split(action, k).copy()
        sen = alpha[..., 0]
        new = np.minimum(sen * self.scale, sen + alpha[..., 2])
        alpha[..., 2] += sen - new
        alpha[..., 0] = new
        alpha = np.maximum(alpha, 0.0)
        return alpha / alpha.sum((-2, -1), keepdims=True)


class _EqualShares(MultiSharePolicy):
    name = "equal"

    def shares_batch(self, obs):
        return np.full((obs.shape[0], self.n_drones, 3), 1.0 / (3 * self.n_drones))


def make_multi_policy(spec: str, scenario: Scenario, n_drones: int):
    """A multi-drone baseline from its spec (:data:`MULTI_POLICY_SPECS`), for the per-drone ``scenario``
    (the env's ``scenario``, :func:`iscc_gym.sim.fleet.drone_scenario`).
    """
    key = str(spec).strip().lower()
    if key == "equal-sca":
        return EqualShareSCA(scenario, n_drones)
    if key == "joint-sca":
        return JointSCA(scenario, n_drones, sensing_floor=load_tuned("margin")["params"]["sensing_floor"])
    if key == "margin":
        return MultiMarginPolicy.tuned(n_drones)
    if key == "margin-starved":
        return ScaledSensing(MultiMarginPolicy.tuned(n_drones), n_drones, STARVED_SCALE)
    if key == "equal":
        return _EqualShares(n_drones)
    raise ValueError(f"multi-drone policy {spec!r} is unknown; use one of {', '.join(MULTI_POLICY_SPECS)} or a "
                     "trained run's directory")
