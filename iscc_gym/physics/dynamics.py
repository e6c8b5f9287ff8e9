"""Drone dynamics (double integrator), process noise, and the LQ feedback gain (Sec. III-A)."""

from __future__ import annotations

import control
import numpy as np
from numba import njit
from numpy.typing import ArrayLike

from iscc_gym.scenario import Scenario, per_scenario

__all__ = ["axis_matrices", "axis_gain", "system_matrices", "process_noise_cov", "lqg_weights", "lqr_gain",
           "model_matrices", "lqg_command_one", "input_one", "propagate_one"]


def axis_matrices(dt_s: float):
    r"""Per-axis state transition and input matrices of the double integrator (eq:AB_matrices, one axis).

    .. math::
        \mathbf A_1 = \begin{bmatrix}1 & \Delta t\\ 0 & 1\end{bmatrix},\qquad
        \mathbf B_1 = \begin{bmatrix}\tfrac12\Delta t^2\\ \Delta t\end{bmatrix}

    The three axes are decoupled: :func:`system_matrices` is :math:`\mathbf A_1\otimes\mathbf I_3`,
    :math:`\mathbf B_1\otimes\mathbf I_3`.

    Returns
    -------
    A1 : ndarray, shape (2, 2)
    B1 : ndarray, shape (2, 1)
    """
    return np.array([[1.0, dt_s], [0.0, 1.0]]), np.array([[0.5 * dt_s * dt_s], [dt_s]])


def system_matrices(dt_s: float):
    r"""State transition and input matrices of the discretised double integrator, eq:AB_matrices.

    .. math::
        \mathbf A = \begin{bmatrix}\mathbf I_3 & \Delta t\,\mathbf I_3\\ \mathbf 0_3 &
        \mathbf I_3\end{bmatrix},\qquad
        \mathbf B = \begin{bmatrix}\tfrac12\Delta t^2\,\mathbf I_3\\ \Delta t\,\mathbf I_3
        \end{bmatrix}

    for the state [p, v] (m, m/s): :func:`axis_matrices` of each axis, stacked.

    Returns
    -------
    A : ndarray, shape (6, 6)
    B : ndarray, shape (6, 3)
    """
    a1, b1 = axis_matrices(dt_s)
    eye = np.eye(3)
    return np.kron(a1, eye), np.kron(b1, eye)


def process_noise_cov(s: Scenario):
    r"""Process-noise covariance :math:`\Sigma_\omega = \mathrm{blkdiag}(\sigma_p^2\mathbf I_3,
    \sigma_v^2\mathbf I_3)` (eq:state), with the Table I values read per ``process_noise_reading``.
    """
    return np.diag([s.process_noise_var_pos_m2] * 3 + [s.process_noise_var_vel_m2s2] * 3)


def lqg_weights(s: Scenario):
    r"""LQG weights :math:`\mathbf Q = \mathrm{blkdiag}(Q_p\mathbf I_3, Q_v\mathbf I_3)` and
    :math:`\mathbf R = r\,\mathbf I_3` (Table I).
    """
    return np.diag([s.lqg_q_pos] * 3 + [s.lqg_q_vel] * 3), s.lqg_r * np.eye(3)


def lqr_gain(a: ArrayLike, b: ArrayLike, q: ArrayLike, r: ArrayLike):
    r"""Feedback gain from the DARE via python-control (eq:LQG_control_input).

    .. math::
        \mathbf K = (\mathbf R + \mathbf B^T\mathbf P\mathbf B)^{-1}\mathbf B^T\mathbf P\mathbf A,\quad
        \mathbf P = \mathbf A^T\mathbf P\mathbf A - \mathbf A^T\mathbf P\mathbf B(\mathbf R +
        \mathbf B^T\mathbf P\mathbf B)^{-1}\mathbf B^T\mathbf P\mathbf A + \mathbf Q

    Returns
    -------
    K : ndarray, shape (3, 6)
    P : ndarray, shape (6, 6)
    """
    k, p, _ = control.dlqr(a, b, q, r)
    return np.asarray(k, dtype=float), np.asarray(p, dtype=float)


def _weights_message(s: Scenario, what: str) -> str:
    return (f"Scenario.lqg_q_pos = {s.lqg_q_pos!r}, lqg_q_vel = {s.lqg_q_vel!r}, lqg_r = {s.lqg_r!r} (dt_s = "
            f"{s.dt_s!r}) give no LQG feedback gain: {what}; bring the weights closer together (Table I: "
            f"lqg_q_pos = 1e4, lqg_q_vel = 1e2, lqg_r = 0.01)")


class ModelMatrices:
    """The constant matrices of one scenario: A, B, K, P (DARE), Q, R, Sigma_omega, A - BK, and the
    constants of the slot transition (GBS antenna position, Cholesky factor of Sigma_omega, GNSS whitening).
    """

    __slots__ = ("a", "b", "k", "p", "q", "r", "sigma_w", "a_cl", "chol_w", "gbs_pos", "gnss_whiten")

    def __init__(self, s: Scenario):
        self.a, self.b = system_matrices(s.dt_s)
        self.q, self.r = lqg_weights(s)
        try:
            self.k, self.p = lqr_gain(self.a, self.b, self.q, self.r)
        except (np.linalg.LinAlgError, ValueError, ArithmeticError) as e:  # the DARE solver's failures
            raise ValueError(_weights_message(s, f"the DARE has no solution ({str(e).splitlines()[0]})")) from e
        self.sigma_w = process_noise_cov(s)
        self.a_cl = self.a - self.b @ self.k
        radius = float(np.max(np.abs(np.linalg.eigvals(self.a_cl)))) if np.all(np.isfinite(self.a_cl)) else np.inf
        if not radius < 1.0:
            raise ValueError(_weights_message(s, f"the LQ gain does not stabilise the loop (spectral radius of "
                                                 f"A - BK = {radius:.12g})"))
        self.chol_w = np.sqrt(np.diag(self.sigma_w))
        # constants of the slot transition (loop.step)
        self.gbs_pos = np.array([0.0, 0.0, s.gbs_height_m])
        gnss_std = np.array([s.gnss_pos_std_m] * 3 + [s.gnss_vel_std_mps] * 3)
        self.gnss_whiten = np.diag(1.0 / gnss_std)
        for v in (self.a, self.b, self.k, self.p, self.q, self.r, self.sigma_w, self.a_cl,
                  self.chol_w, self.gbs_pos, self.gnss_whiten):
            v.setflags(write=False)


@per_scenario
def axis_gain(s: Scenario):
    r"""Per-axis LQ feedback gain :math:`\mathbf K_1`, shape (1, 2): the (position, velocity) entries of one
    axis of the isotropic gain :math:`\mathbf K` of :func:`model_matrices` (for :func:`axis_matrices`'
    :math:`\mathbf A_1`, :math:`\mathbf B_1`). Read-only.
    """
    k1 = np.asarray(model_matrices(s).k)[:1, [0, 3]]
    k1.setflags(write=False)
    return k1


@per_scenario
def model_matrices(s: Scenario) -> ModelMatrices:
    """Cached :class:`ModelMatrices` of a (hashable, frozen) scenario."""
    return ModelMatrices(s)


# --- compiled scalar forms: one drone, composed by the slot kernel (iscc_gym.sim.loop.step_one) ---------
# ``inline="always"``: numba inlines them into the caller's IR, so they compile with the caller's flags.

@njit(cache=True, error_model="numpy", inline="always")
def lqg_command_one(k_mat, x_hat, ref_row, feedforward, u):
    r"""eq:LQG_control_input of one drone, :math:`\mathbf u = -\mathbf K(\hat{\mathbf x} -
    \mathbf x_\mathrm{ref})` (plus the reference acceleration ``ref_row[6:9]`` with ``feedforward``),
    written into ``u`` (3).
    """
    for j in range(3):
        acc = 0.0
        for k in range(6):
            acc += k_mat[j, k] * (x_hat[k] - ref_row[k])
        u[j] = -acc
        if feedforward:
            u[j] += ref_row[6 + j]


@njit(cache=True, error_model="numpy", inline="always")
def input_one(b_mat, u, bu):
    r""":math:`\mathbf B\mathbf u` of one drone into ``bu`` (6)."""
    for j in range(6):
        acc = 0.0
        for k in range(3):
            acc += b_mat[j, k] * u[k]
        bu[j] = acc


@njit(cache=True, error_model="numpy", inline="always")
def propagate_one(dt, x, bu, chol_w, z, z0, x_next):
    r"""eq:state of one drone, :math:`\mathbf x_{n+1} = \mathbf A\mathbf x_n + \mathbf B\mathbf u_n
    + \omega_n` with A = [[I, dt I], [0, I]] and :math:`\omega_n` = ``chol_w * z[z0:z0 + 6]``
    (Sigma_omega is diagonal), into ``x_next`` (6).
    """
    for j in range(6):
        ax = x[j] + dt * x[j + 3] if j < 3 else x[j]
        x_next[j] = ax + bu[j] + chol_w[j] * z[z0 + j]
