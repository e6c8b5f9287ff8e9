"""Test oracle of the Kalman filter in numpy: the batch measurement update in Joseph form and the dense
time update, batched over a leading axis (states (..., 6), covariances (..., 6, 6)).

The library runs the compiled :func:`iscc_gym.physics.kalman.kf_update_whitened_one` and
:func:`iscc_gym.physics.kalman.kf_predict_one`; ``tests/physics/test_kalman.py`` checks them against these.
"""

from __future__ import annotations

import numpy as np


def symmetrize(p):
    """:math:`(\\mathbf P + \\mathbf P^T)/2` over the last two axes."""
    return 0.5 * (p + p.swapaxes(-1, -2))


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
