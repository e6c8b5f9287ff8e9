"""Kalman filter with the time-varying ISAC observation matrix (eq:observation_model, eq:KF_update).

The filter the env runs is compiled, one drone at a time: the measurement update with whitened rows
(:func:`kf_update_whitened_one`) and the time update of the double integrator (:func:`kf_predict_one`).
The batch Joseph-form update and the dense time update in numpy are test oracles
(``tests/oracle_kalman.py``).
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

__all__ = ["isac_observation_matrix", "kf_update_whitened_one", "kf_predict_one"]


def isac_observation_matrix(los_unit: ArrayLike):
    r""":math:`\mathbf C_n = \mathrm{blkdiag}(\mathbf I_3, \mathbf g_n^T)`, shape (..., 4, 6).

    Position is observed in 3-D; velocity only along the LoS unit vector :math:`\mathbf g_n`.
    """
    g = np.asarray(los_unit, dtype=float)
    c = np.zeros(g.shape[:-1] + (4, 6))
    c[..., 0, 0] = c[..., 1, 1] = c[..., 2, 2] = 1.0
    c[..., 3, 3:] = g
    return c


# --- compiled scalar forms: one drone, composed by the slot kernel (iscc_gym.sim.loop.step_one) ---------

@njit(cache=True, error_model="numpy", fastmath={"reassoc", "contract"})
def kf_update_whitened_one(x, p, y, w, x_post, p_post, h):
    r""":func:`kf_update` of one drone with a whitened measurement (unit noise), one row at a time.

    The rows of a whitened measurement have independent unit noise, so processing them one by one
    gives the same posterior as the batch update (Bierman, *Factorization Methods for Discrete
    Sequential Estimation*, 1977, ch. II). Row w with h = P w^T and s = w h + 1:

    .. math::
        \hat{\mathbf x} \leftarrow \hat{\mathbf x} + \mathbf h\,(y - \mathbf w\hat{\mathbf x})/s,\quad
        \mathbf P \leftarrow \mathbf P - \mathbf h\mathbf h^T/s

    (the Joseph form of a scalar update reduces to this), symmetric by construction; no rows: the
    prior is copied (a slot without a measurement). About a third of the batch update's arithmetic
    and no matrix inverse; it agrees with :func:`kf_update`'s batch Joseph form to rounding
    (``tests/physics/test_kernel.py``). Writes ``x_post`` (6), ``p_post`` (6, 6); ``h`` (6) is scratch.
    """
    for i in range(6):
        x_post[i] = x[i]
        for j in range(6):
            p_post[i, j] = p[i, j]
    for r in range(w.shape[0]):
        s = 1.0
        innov = y[r]
        for i in range(6):
            acc = 0.0
            for k in range(6):
                acc += p_post[i, k] * w[r, k]
            h[i] = acc
            s += w[r, i] * acc
            innov -= w[r, i] * x_post[i]
        inv_s = 1.0 / s
        gain = innov * inv_s
        for i in range(6):
            x_post[i] += h[i] * gain
            hi = h[i] * inv_s
            for j in range(i, 6):
                v = p_post[i, j] - hi * h[j]
                p_post[i, j] = v
                p_post[j, i] = v


@njit(cache=True, error_model="numpy", inline="always")
def kf_predict_one(dt, x_post, p_post, bu, sigma_w, x_hat_next, p_next, pa):
    """:func:`kf_predict` of one drone with A = [[I, dt I], [0, I]] (eq:AB_matrices), blockwise:
    writes ``x_hat_next`` (6) and the symmetrised ``p_next`` (6, 6); ``pa`` (6, 6) is scratch.
    """
    for j in range(6):
        axh = x_post[j] + dt * x_post[j + 3] if j < 3 else x_post[j]
        x_hat_next[j] = axh + bu[j]
    for j in range(3):
        for k in range(3):
            p12 = p_post[j, 3 + k] + dt * p_post[3 + j, 3 + k]
            pa[j, k] = p_post[j, k] + dt * p_post[3 + j, k] + dt * p12
            pa[j, 3 + k] = p12
            pa[3 + j, k] = p_post[3 + j, k] + dt * p_post[3 + j, 3 + k]
            pa[3 + j, 3 + k] = p_post[3 + j, 3 + k]
    for j in range(6):
        for k in range(6):
            p_next[j, k] = 0.5 * ((pa[j, k] + sigma_w[j, k]) + (pa[k, j] + sigma_w[k, j]))
