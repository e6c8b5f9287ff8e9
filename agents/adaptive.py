r"""``adaptive``: the per-slot optimiser of :mod:`agents.myopic` on a world it re-estimates online.

The field task (``iscc_gym/ISCC-Field-v0``, ``docs/model.md`` Sec. 8) plays the paper's loop in a world the
designer's model does not know: the Rician K-factor of the links varies along the path and the drone's radar cross
section differs from ``rcs_m2``. :class:`AdaptivePolicy` estimates both from what the GBS measures, the
observation's measured block (the last slot's fading gain of the command link, from the acknowledgement's pilots,
and its echo SNR), and designs each slot for the estimate with :class:`agents.myopic.MyopicPolicy`'s objective:

* **K-factor**, by the moment method of Greenstein, Michelson and Erceg ("Moment-method estimation of the Ricean
  K-factor", IEEE Commun. Lett. 3(6), 1999) on the measured power gains :math:`g_n` (unit mean):
  exponentially weighted moments :math:`m_1, m_2` of :math:`g` and :math:`g^2` over a window of ``k_window_slots``
  (the K-factor changes along the path), started at the model's :math:`K_0` (``rician_k_db``),

  .. math::
      \gamma = \frac{m_2 - m_1^2}{m_1^2},\qquad \hat K = \frac{\sqrt{1 - \gamma}}{1 - \sqrt{1 - \gamma}}

  (:math:`\gamma = (1 + 2K)/(1 + K)^2` for a Rician power gain; :math:`\gamma \ge 1` reads as Rayleigh, K = -20 dB).
  The echo's fading has the same K: the measured echo SNR over the model's prediction is its gain times the unknown
  RCS, a scale :math:`\gamma` does not see, so its moments (from its first measurement) give a second
  :math:`\gamma`, mixed in with weight ``echo_weight``;
* **RCS offset**, the mean over the mission of the measured echo SNR minus the one the model predicts at the
  slot's predicted geometry (:func:`iscc_gym.physics.sensing.echo_amplitude_sq` with the link's shadowing), less the
  mean of :math:`10\log_{10} g` of the estimated K's fading, shrunk towards the model's 0 dB by ``rcs_prior_slots``
  pseudo-observations (the RCS is one value per mission).

A new mission (the observation's slot 0) restarts both. ``k_window_slots`` and ``echo_weight`` are tuned on training
seeds (``python -m eval.tune adaptive --scenario field``; ``agents/tuned/adaptive.yml``), never on the held-out ones.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from iscc_gym.physics.sensing import echo_amplitude_sq, sensing_noise_var_w
from iscc_gym.scenario import Scenario
from iscc_gym.sim.effects import task_effects
from iscc_gym.units import db_to_lin

from .geometry import predicted_geometry
from .myopic import MyopicPolicy, rician_nodes_at

__all__ = ["AdaptivePolicy", "greenstein_k", "mean_log_gain_db", "model_echo_snr_db", "check_world_estimator"]

#: The K-factor range the estimate is held to, dB (the table of :func:`agents.myopic.rician_nodes_at`).
K_RANGE_DB = (-20.0, 40.0)


def check_world_estimator(policy, verb: str) -> None:
    """Refuse a policy that estimates the field's world (``policy``, a :class:`agents.myopic.MyopicPolicy`) on a
    scenario without the field (no measured block to estimate from) or shown the world (not causal);
    ``verb`` says what it does (``"estimates"``, ``"filters"``).
    """
    who = type(policy).__name__
    if not task_effects(policy.scenario).field:
        raise ValueError(f"{who} {verb} the field task's world: scenario needs rician_k_std_db or rcs_std_db > 0 (its "
                         "observation carries the measured block), e.g. the 'field' preset")
    if policy.shows_world:
        raise ValueError(f"{who} is causal: its scenario must not show the world (show_world=False)")


def model_echo_snr_db(s: Scenario, dist_m, shadow_db):
    """The echo SNR (dB, per element and subcarrier) the designer's model predicts at a geometry, with the model's
    RCS: what the field's rungs compare the measured echo with (its fading and RCS offset are the difference).
    """
    return 10.0 * np.log10(echo_amplitude_sq(s, dist_m, shadow_db, 1.0) / sensing_noise_var_w(s))


def greenstein_k(m1, m2):
    r"""The moment-method K-factor (linear) from the first two moments of a Rician power gain,
    :math:`\gamma = (m_2 - m_1^2)/m_1^2`, :math:`K = \sqrt{1-\gamma}/(1 - \sqrt{1-\gamma})`; clamped to
    :data:`K_RANGE_DB` (:math:`\gamma \ge 1`: the lower end, :math:`\gamma \le 0`: the upper).
    """
    m1 = np.asarray(m1, dtype=float)
    gamma = (np.asarray(m2, dtype=float) - m1 * m1) / np.maximum(m1 * m1, 1e-300)
    lo, hi = db_to_lin(K_RANGE_DB[0]), db_to_lin(K_RANGE_DB[1])
    r = np.sqrt(np.clip(1.0 - gamma, 0.0, 1.0))
    with np.errstate(divide="ignore"):
        k = np.where(r < 1.0, r / np.maximum(1.0 - r, 1e-300), hi)
    return np.clip(k, lo, hi)


@functools.lru_cache(maxsize=1)
def _node_weights():
    """The fading quadrature's weights (its bins' probabilities: the same at every K), computed once."""
    from iscc_gym.analysis.quadrature import rician_power_nodes

    weight = rician_power_nodes(1.0)[1]
    weight.setflags(write=False)
    return weight


def mean_log_gain_db(k_db):
    r""":math:`\mathbb E[10\log_{10} g]` of the unit-mean Rician power gain at K-factors ``k_db`` (dB), by the
    fading quadrature (:func:`agents.myopic.rician_nodes_at`): what a fade takes from a measured SNR in dB on average.
    """
    return (10.0 * np.log10(np.maximum(rician_nodes_at(k_db), 1e-300))) @ _node_weights()


class AdaptivePolicy(MyopicPolicy):
    r""":class:`agents.myopic.MyopicPolicy` designed each slot for the world it estimates from the measured block
    (see the module docstring). Keeps one estimate per env of the batch (the rows of the observations, in the
    order the vector env gives them); a row at slot 0 starts afresh.

    Parameters
    ----------
    scenario : Scenario or str
        The designer's model: a scenario with the field (``rician_k_std_db`` or ``rcs_std_db`` > 0), whose
        observation has the measured block; its ``rician_k_db`` and ``rcs_m2`` are the estimates' start.
    k_window_slots : float
        Time constant of the K-factor's moments, slots (>= 1).
    rcs_prior_slots : float
        Pseudo-observations of the model's RCS (0 dB offset) the RCS estimate starts with (>= 0; 0: the first
        measurement's).
    echo_weight : float
        Weight in [0, 1] of the echo's :math:`\gamma` in the K-factor's estimate (0: the command link's alone).
    **kwargs
        :class:`agents.myopic.MyopicPolicy`'s search parameters.
    """

    def __init__(self, scenario: Scenario | str = "field", k_window_slots: float = 20.0,
                 rcs_prior_slots: float = 0.0, echo_weight: float = 0.0, **kwargs):
        super().__init__(scenario, **kwargs)
        s = self.scenario
        check_world_estimator(self, "estimates")
        for name, value, lo in (("k_window_slots", k_window_slots, 1.0), ("rcs_prior_slots", rcs_prior_slots, 0.0),
                                ("echo_weight", echo_weight, 0.0)):
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or \
                    not (math.isfinite(float(value)) and float(value) >= lo):
                raise ValueError(f"{name} = {value!r} is invalid: must be a finite number >= {lo:g}")
        self.k_window_slots = float(k_window_slots)
        self.rcs_prior_slots = float(rcs_prior_slots)
        if float(echo_weight) > 1.0:
            raise ValueError(f"echo_weight = {echo_weight!r} is invalid: must be in [0, 1]")
        self.echo_weight = float(echo_weight)
        k0 = db_to_lin(s.rician_k_db)
        self._m1_0 = 1.0
        self._m2_0 = 1.0 + (1.0 + 2.0 * k0) / (1.0 + k0) ** 2
        self._rows = 0
        self.name = "adaptive"

    def _restart(self, n: int) -> None:
        self._rows = n
        self._m1 = np.full(n, self._m1_0)
        self._m2 = np.full(n, self._m2_0)
        self._e1 = np.full(n, self._m1_0)
        self._e2 = np.full(n, self._m2_0)
        self._rcs_sum = np.zeros(n)
        self._rcs_n = np.zeros(n)
        self._echo_pred_db = np.full(n, np.nan)
        self._k_db = np.full(n, self.scenario.rician_k_db)

    def world_of(self, decoded: dict):
        """``(k_db, rcs_offset_db)`` estimated for each row, after taking in the row's last measurement."""
        s = self.scenario
        n = decoded["snr_db"].shape[0]
        if self._rows != n:
            self._restart(n)
        new = decoded["slot"] < 0.5
        a = 1.0 / self.k_window_slots
        g = db_to_lin(decoded["last_fade_db"])
        seen = ~new
        self._m1 = np.where(seen, (1.0 - a) * self._m1 + a * g, self._m1_0)
        self._m2 = np.where(seen, (1.0 - a) * self._m2 + a * g * g, self._m2_0)
        # the echo measured in the last slot against the model's prediction there, less the fading's mean in dB
        resid = decoded["last_echo_snr_db"] - self._echo_pred_db - mean_log_gain_db(self._k_db)
        ok = seen & np.isfinite(resid)
        self._rcs_sum = np.where(new, 0.0, self._rcs_sum + np.where(ok, resid, 0.0))
        self._rcs_n = np.where(new, 0.0, self._rcs_n + ok)
        # the echo's power over the model's prediction: its fading times the RCS, a scale gamma does not see; the
        # moments start at the first measurement with the model's gamma (no transient from the unknown scale)
        e = db_to_lin(np.where(ok, decoded["last_echo_snr_db"] - self._echo_pred_db, 0.0))
        first = ok & (self._rcs_n == 1)
        self._e1 = np.where(first, e, np.where(ok, (1.0 - a) * self._e1 + a * e, self._e1))
        self._e2 = np.where(first, e * e * self._m2_0, np.where(ok, (1.0 - a) * self._e2 + a * e * e, self._e2))
        w = self.echo_weight
        gamma_link = (self._m2 - self._m1 ** 2) / self._m1 ** 2
        gamma_echo = (self._e2 - self._e1 ** 2) / np.maximum(self._e1 ** 2, 1e-300)
        gamma = (1.0 - w) * gamma_link + w * gamma_echo
        self._k_db = 10.0 * np.log10(greenstein_k(1.0, 1.0 + gamma))
        rcs_db = self._rcs_sum / (self._rcs_n + self.rcs_prior_slots) if self.rcs_prior_slots > 0 else \
            np.where(self._rcs_n > 0, self._rcs_sum / np.maximum(self._rcs_n, 1.0), 0.0)
        dist, _, shadow_db = predicted_geometry(s, decoded["snr_db"], decoded["range_m"], decoded["sin_elevation"],
                                                decoded["cos_azimuth"], decoded["sin_azimuth"], self._gain)
        self._echo_pred_db = model_echo_snr_db(s, dist, shadow_db)
        return self._k_db.copy(), rcs_db

    def __repr__(self) -> str:
        return (f"AdaptivePolicy(k_window_slots={self.k_window_slots:g}, rcs_prior_slots={self.rcs_prior_slots:g}, "
                f"echo_weight={self.echo_weight:g}, "
                + super().__repr__().split("(", 1)[1])
