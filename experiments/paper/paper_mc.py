r"""Closed-loop Monte Carlo of static splits for the paper's Figs. 5-8 (``python -m experiments.paper.reproduce``).

Every split of a list is flown on the same ``n_missions`` seeded missions (common random numbers:
the same trajectories, shadowing, fading, measurement, process-noise and drop draws for every split),
all splits and missions stepped as one batch through :func:`iscc_gym.sim.loop.step` (the env's
transition, compiled kernel). Per slot it records what the env reports (tracking error, PEB, data
rate, loss rate) and one thing the env does not: the LQG stage cost of eq:LQG_cost,
:math:`\mathbf x_n^T\mathbf Q\mathbf x_n + \tilde{\mathbf u}_n^T\mathbf R\tilde{\mathbf u}_n`, with
:math:`\mathbf x_n` the state minus the reference and :math:`\tilde{\mathbf u}_n` the applied command
(zero when the command is lost). The applied command is recovered exactly from the transition,
:math:`\mathbf B\tilde{\mathbf u}_n = \mathbf x_{n+1} - \mathbf A\mathbf x_n - \mathbf w_n`, with
:math:`\mathbf w_n` the slot's process noise regenerated from the episode's noise key
(:func:`iscc_gym.sim.loop.slot_noise`).

A mission that loses track (tracking error above ``max_tracking_error_m``, the env's termination)
stops counting at that slot, as in the env; its mean is the mean up to then and ``lost`` flags it.
"""

from __future__ import annotations

import numpy as np

from iscc_gym.physics.dynamics import model_matrices
from iscc_gym.scenario import Scenario
from iscc_gym.sim import loop
from iscc_gym.sim.task import check_split
from iscc_gym.trajectory import sample_reference

__all__ = ["fly_splits", "SPLIT_METRICS"]

#: Per split and mission (arrays (K, M)); :func:`fly_splits` also returns their mission means (K,).
SPLIT_METRICS = ("tracking_error_m", "tracking_ms_m2", "lqg_cost", "peb_m", "rate_mbps", "eps_ctrl",
                 "packet_loss", "lost", "slots")

#: Columns of the slot's normals that hold the process noise (:mod:`iscc_gym.sim.loop`'s layout).
_PROC = slice(11, 17)


def fly_splits(s: Scenario, splits, n_missions: int, seed: int = 0, n_slots: int | None = None) -> dict:
    """Fly every split of ``splits`` (K, 3) on the same ``n_missions`` seeded missions.

    Parameters
    ----------
    s : Scenario
        An ISAC-fed LQG scenario.
    splits : array_like, shape (K, 3)
        Static splits (alpha_sen, alpha_ctrl, alpha_comm), each summing to 1.
    n_missions : int
        Missions per split (the same for every split).
    seed : int
        Mission j draws its trajectory from ``default_rng(seed)`` (j-th draw) and its noise from
        ``default_rng([seed, j])``.
    n_slots : int, optional
        Slots flown per mission (default: the whole mission).

    Returns
    -------
    dict
        ``per_mission``: each of :data:`SPLIT_METRICS` as an array (K, M); and the same names as
        arrays (K,): means over missions (``lost``: the fraction of missions that lost track);
        ``tracking_rmse_m`` (K,) = sqrt(mean of ``tracking_ms_m2``); ``splits`` (K, 3).
    """
    al = check_split(np.asarray(splits, dtype=float).reshape(-1, 3), "splits")
    if isinstance(n_missions, bool) or int(n_missions) != n_missions or n_missions < 1:
        raise ValueError(f"n_missions = {n_missions!r} is invalid: must be an integer >= 1")
    k, m = len(al), int(n_missions)
    horizon = s.n_slots if n_slots is None else min(int(n_slots), s.n_slots)
    mm = model_matrices(s)
    rng = np.random.default_rng(seed)
    ref = loop.stack_references([sample_reference(s, rng) for _ in range(m)])
    b = k * m
    state = loop.init_state(s, np.broadcast_to(ref[None], (k,) + ref.shape).reshape((b,) + ref.shape[1:]).copy(),
                            [np.random.default_rng([seed, j]) for _ in range(k) for j in range(m)])
    alpha = np.repeat(al, m, axis=0)  # drone i flies split i // m on mission i % m
    b_pinv = np.linalg.pinv(mm.b)
    q_diag, r_diag = np.diag(mm.q), np.diag(mm.r)
    rows = np.arange(b)
    sums = {name: np.zeros(b) for name in ("tracking_error_m", "tracking_ms_m2", "lqg_cost", "peb_m", "rate_mbps",
                                           "eps_ctrl", "packet_loss")}
    count = np.zeros(b)
    alive = np.ones(b, dtype=bool)
    with np.errstate(over="ignore", invalid="ignore"):
        for _ in range(horizon):
            w = mm.chol_w * loop.slot_noise(state)[:, _PROC]
            x = state.x
            e = x - state.ref[rows, state.n, :6]
            state, met = loop.step(s, state, alpha)
            u = (state.x - x @ mm.a.T - w) @ b_pinv.T
            err = met["tracking_error_m"]
            stage = {
                "tracking_error_m": err,
                "tracking_ms_m2": err * err,
                "lqg_cost": (e * e) @ q_diag + (u * u) @ r_diag,
                "peb_m": met["peb_m"],
                "rate_mbps": met["rate_comm_bps"] * 1e-6,
                "eps_ctrl": met["eps_ctrl"],
                "packet_loss": (~met["packet_received"]).astype(float),
            }
            for name, v in stage.items():
                sums[name] += np.where(alive, v, 0.0)
            count += alive
            alive &= ~met["diverged"]
            if not alive.any():
                break
    per = {name: (v / np.maximum(count, 1)).reshape(k, m) for name, v in sums.items()}
    per["lost"] = (~alive).astype(float).reshape(k, m)
    per["slots"] = count.reshape(k, m)
    out = {name: v.mean(axis=1) for name, v in per.items()}
    out["tracking_rmse_m"] = np.sqrt(out["tracking_ms_m2"])
    out["per_mission"] = per
    out["splits"] = al
    out["n_missions"] = m
    out["n_slots"] = horizon
    return out
