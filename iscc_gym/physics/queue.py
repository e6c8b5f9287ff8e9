r"""The drone's downlink data queue: bursty arrivals, FIFO service by the data share, a delivery deadline.

The buffer holds bits by the number of slots they have waited: ``q[j]`` bits arrived j slots ago,
j = 0 .. D-1, with D the deadline in slots (:attr:`iscc_gym.scenario.Scenario.queue_deadline_slots`, the one
conversion of the scenario's ``queue_deadline_s``). A slot:

1. the slot's arrivals join at age 0, :math:`A_n = \lambda\,\Delta t\; e^{\sigma z_n - \sigma^2/2}`
   (log-normal burstiness: mean :math:`\lambda\Delta t`, coefficient of variation
   :math:`c_v = \sqrt{e^{\sigma^2} - 1}`, ``queue_arrival_cv``; :math:`c_v = 0` is a constant stream);
2. the data share serves :math:`\mathcal R_\mathrm{comm}\Delta t` bits (eq:rate_equation at the slot's
   SNR), oldest first;
3. bits that have now waited D slots unserved (age D-1 before aging) are dropped;
4. every remaining bit ages by one slot.

So every bit has D chances to be served, and every slot conserves bits:
:math:`A_n = S_n + X_n + (B_{n+1} - B_n)` (arrivals, served, dropped, backlog change).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

__all__ = ["arrival_bits_one", "queue_step_one", "queue_step", "arrival_sigma", "oldest_age_one"]


def arrival_sigma(cv: float) -> float:
    r"""The log-normal's :math:`\sigma = \sqrt{\ln(1 + c_v^2)}` for an arrival coefficient of variation ``cv``."""
    if not cv >= 0.0:
        raise ValueError(f"queue_arrival_cv = {cv!r} must be >= 0")
    return math.sqrt(math.log1p(cv * cv))


@njit(cache=True, error_model="numpy", inline="always")
def arrival_bits_one(mean_bits, sigma, z):
    r"""A slot's arrivals :math:`\bar A\, e^{\sigma z - \sigma^2/2}` (``mean_bits`` = :math:`\lambda\Delta t`)."""
    return mean_bits * math.exp(sigma * z - 0.5 * sigma * sigma)


@njit(cache=True, error_model="numpy")
def queue_step_one(q, arrivals_bits, capacity_bits):
    """One slot of the queue (the module docstring's steps 1-4), ``q`` (D,) updated in place.

    Returns ``(served_bits, dropped_bits)``.
    """
    d = q.shape[0]
    q[0] += arrivals_bits
    left = capacity_bits if capacity_bits > 0.0 else 0.0
    served = 0.0
    for j in range(d - 1, -1, -1):
        take = q[j] if q[j] < left else left
        q[j] -= take
        served += take
        left -= take
        if left <= 0.0:
            break
    dropped = q[d - 1]
    for j in range(d - 1, 0, -1):
        q[j] = q[j - 1]
    q[0] = 0.0
    return served, dropped


@njit(cache=True, error_model="numpy", inline="always")
def oldest_age_one(q):
    """Slots the oldest waiting bit has waited (0 for an empty buffer)."""
    for j in range(q.shape[0] - 1, -1, -1):
        if q[j] > 0.0:
            return float(j)
    return 0.0


@njit(cache=True, error_model="numpy")
def _queue_loop(q, arrivals, capacity, served, dropped):
    for i in range(q.shape[0]):
        served[i], dropped[i] = queue_step_one(q[i], arrivals[i], capacity[i])


def queue_step(q: ArrayLike, arrivals_bits: ArrayLike, capacity_bits: ArrayLike):
    """:func:`queue_step_one` over a batch: ``q`` (B, D), arrivals and capacities (B,).

    Returns ``(q_next, served_bits, dropped_bits)``; ``q`` is not modified.
    """
    q_next = np.array(q, dtype=float, ndmin=2, order="C", copy=True)
    a, c = (np.ascontiguousarray(np.broadcast_to(np.asarray(v, dtype=float), q_next.shape[:1]))
            for v in (arrivals_bits, capacity_bits))
    served, dropped = np.empty(len(q_next)), np.empty(len(q_next))
    _queue_loop(q_next, a, c, served, dropped)
    return q_next, served, dropped
