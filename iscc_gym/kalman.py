"""Kalman filter with the time-varying ISAC observation matrix (eq:observation_model, eq:KF_update).

Batched over a leading axis: states (..., 6), covariances (..., 6, 6).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["isac_observation_matrix", "kf_predict", "kf_update", "symmetrize", "kf_update_whitened_one",
           "kf_predict_one"]


def symmetrize(p):
    """:math:`(\\mathbf P + \\mathbf P^T)/2` over the last two axes."""
    return 0.5 * (p + p.swapaxes(-1, -2))


def isac_observation_matrix(los_unit):
    """:math:`\\mathbf C_n = \\mathrm{blkdiag}(\\mathbf I_3, \\mathbf g_n^T)`, shape (..., 4, 6).

    Position is observed in 3-D; velocity only along the LoS unit vector :math:`\\mathbf g_n`.
    """
    g = np.asarray(los_unit, dtype=float)
    c = np.zeros(g.shape[:-1] + (4, 6))
    c[..., 0, 0] = c[..., 1, 1] = c[..., 2, 2] = 1.0
    c[..., 3, 3:] = g
    return c


def kf_predict(x, p, a, bu, sigma_w):
    """Time update :math:`\\hat{\\mathbf x}_{n+1|n} = \\mathbf A\\hat{\\mathbf x}_n + \\mathbf B\\tilde{\\mathbf u}_n`,
    :math:`\\mathbf P_{n+1|n} = \\mathbf A\\mathbf P_n\\mathbf A^T + \\Sigma_\\omega`.

    ``bu`` is :math:`\\mathbf B\\tilde{\\mathbf u}_n` (..., 6), the command as received (the GBS learns
    :math:`\\delta_n` from the acknowledgement).
    """
    x_new = (a @ x[..., None])[..., 0] + bu
    p_new = a @ p @ a.T + sigma_w
    return x_new, symmetrize(p_new)


def kf_update(x, p, y, c, r):
    """Measurement update, eq:KF_update, with the covariance in Joseph form.

    .. math::
        \\mathbf L_n &= \\mathbf P\\mathbf C^T(\\mathbf C\\mathbf P\\mathbf C^T + \\Sigma_\\upsilon)^{-1},\\quad
        \\hat{\\mathbf x}_n = \\hat{\\mathbf x}_{n|n-1} + \\mathbf L_n(\\mathbf y_n - \\mathbf C_n
        \\hat{\\mathbf x}_{n|n-1}),\\\\
        \\mathbf P_n &= (\\mathbf I - \\mathbf L_n\\mathbf C_n)\\mathbf P(\\mathbf I - \\mathbf L_n\\mathbf C_n)^T
        + \\mathbf L_n\\Sigma_\\upsilon\\mathbf L_n^T

    The Joseph form plus explicit symmetrisation keeps P symmetric PSD for any noise sequence.
    Every product is a stacked matrix product (one BLAS call per batch item with the same shapes),
    so a batch reproduces per-item results bit for bit.

    Parameters
    ----------
    x : (..., 6) prior mean;  p : (..., 6, 6) prior covariance
    y : (..., m) measurement;  c : (..., m, 6)
    r : (..., m, m) measurement covariance, or None for a whitened measurement (identity)

    Returns
    -------
    x_post : (..., 6);  p_post : (..., 6, 6);  gain : (..., 6, m)
    """
    ct = c.swapaxes(-1, -2)
    pct = p @ ct
    s_mat = c @ pct
    if r is None:  # whitened measurement: unit noise covariance
        s_mat += _eye_like(s_mat)
    else:
        s_mat += r
    gain = pct @ np.linalg.inv(s_mat)
    innov = y - (c @ x[..., None])[..., 0]
    x_post = x + (gain @ innov[..., None])[..., 0]
    ikc = _eye_like(p) - gain @ c
    noise = gain @ gain.swapaxes(-1, -2) if r is None else gain @ r @ gain.swapaxes(-1, -2)
    p_post = ikc @ p @ ikc.swapaxes(-1, -2) + noise
    return x_post, symmetrize(p_post), gain


_EYES: dict[int, np.ndarray] = {}


def _eye_like(p):
    n = p.shape[-1]
    if n not in _EYES:
        _EYES[n] = np.eye(n)
        _EYES[n].setflags(write=False)
    return _EYES[n]


# --- compiled scalar forms: one drone, composed by the slot kernel (iscc_gym.loop.step_one) ---------

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
    (``tests/test_kernel.py``). Writes ``x_post`` (6), ``p_post`` (6, 6); ``h`` (6) is scratch.
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
    writes ``x_hat_next`` (6) and the symmetrised ``p_next`` (6, 6); ``pa`` (6, 6) is scratch."""
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
