"""Mean-square stability under packet loss, steady-state covariances, LQG cost and rate-cost
function (the paper, Sec. III-B, III-C and IV-C).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike
from scipy.optimize import brentq

from iscc_gym.physics.dynamics import model_matrices
from iscc_gym.physics.fbl import ctrl_bler
from iscc_gym.scenario import Scenario, per_scenario

__all__ = [
    "LossOperator",
    "scenario_eps_star",
    "stability_matrix",
    "spectral_radius",
    "eps_star",
    "alpha_ctrl_star",
    "kalman_steady_state",
    "equivalent_noise_cov",
    "steady_state_covariance",
    "lqg_cost",
    "riccati_s_d",
    "lqg_cost_floor",
    "entropy_power",
    "rate_cost_bits",
]


def stability_matrix(a: ArrayLike, b: ArrayLike, k: ArrayLike, eps: ArrayLike):
    r"""Second-moment transition matrix, eq:M.

    .. math::
        \mathbf M = (1-\varepsilon)\,(\mathbf A-\mathbf B\mathbf K)\otimes(\mathbf A-\mathbf B\mathbf K)
        + \varepsilon\,\mathbf A\otimes\mathbf A

    Returns an array of shape (36, 36).
    """
    a_cl = a - b @ k
    return (1.0 - eps) * np.kron(a_cl, a_cl) + eps * np.kron(a, a)


def spectral_radius(m: ArrayLike):
    r""":math:`\rho(\mathbf M) = \max_i |\lambda_i(\mathbf M)|`."""
    return float(np.max(np.abs(np.linalg.eigvals(m))))


def eps_star(a: ArrayLike, b: ArrayLike, k: ArrayLike, xtol: float = 1e-12):
    r"""Largest control packet-loss rate that keeps the loop mean-square stable:
    the first root of :math:`\rho(\mathbf M(\varepsilon)) = 1` on (0, 1) (Sec. IV-C.1).

    The root is bracketed on a grid of 200 loss rates (at :math:`\varepsilon = 1`,
    :math:`\rho(\mathbf A\otimes\mathbf A) = 1` exactly for the double integrator, so the end
    point itself cannot serve as a bracket) and refined with Brent's method. Returns 1.0 if
    :math:`\rho(\mathbf M) < 1` on the whole grid.
    """
    def f(e):
        return spectral_radius(stability_matrix(a, b, k, e)) - 1.0

    if f(0.0) >= 0.0:
        raise ValueError("the loss-free closed loop A - BK is not Schur stable; check lqg weights")
    grid = np.linspace(0.0, 1.0, 201)[:-1]
    vals = np.array([f(e) for e in grid])
    above = np.flatnonzero(vals > 0.0)
    if above.size == 0:
        return 1.0
    i = int(above[0])
    return float(brentq(f, grid[i - 1], grid[i], xtol=xtol))


@per_scenario
def scenario_eps_star(s: Scenario) -> float:
    """:func:`eps_star` of a scenario's A, B and LQ gain K (cached per scenario)."""
    mm = model_matrices(s)
    return eps_star(mm.a, mm.b, mm.k)


def alpha_ctrl_star(s: Scenario, snr: ArrayLike, eps_max: float, xtol: float = 1e-12):
    r"""Smallest control share with :math:`\varepsilon_\mathrm{ctrl}(\alpha,\gamma) \le \varepsilon^\star`,
    the root of eq:ctrl_bler minus ``eps_max`` (Sec. IV-C.1).

    ``snr`` is a scalar linear SNR. Returns ``nan`` if even alpha_ctrl = 1 is not enough.
    """
    def f(al):
        return float(ctrl_bler(s, al, snr)) - eps_max

    if f(1.0) > 0.0:
        return float("nan")
    return float(brentq(f, 1e-12, 1.0, xtol=xtol))


def kalman_steady_state(a: ArrayLike, c: ArrayLike, sigma_w: ArrayLike, sigma_v: ArrayLike):
    r"""Steady-state Kalman covariances for a fixed observation model, via the filtering DARE.

    Returns
    -------
    p_prior : (6, 6)
        Predicted error covariance :math:`\mathbf P_{n|n-1}` (solution of the filtering DARE).
    sigma_est : (6, 6)
        Filtered error covariance :math:`\Sigma_\mathrm{est} = \mathbf P - \mathbf P\mathbf C^T
        (\mathbf C\mathbf P\mathbf C^T + \Sigma_\upsilon)^{-1}\mathbf C\mathbf P` (eq:omega_tilde_cov).
    """
    p = scipy.linalg.solve_discrete_are(a.T, c.T, sigma_w, sigma_v)
    p = 0.5 * (p + p.T)
    s_mat = c @ p @ c.T + sigma_v
    est = p - p @ c.T @ np.linalg.solve(s_mat, c @ p)
    return p, 0.5 * (est + est.T)


def equivalent_noise_cov(sigma_w: ArrayLike, b: ArrayLike, k: ArrayLike, sigma_est: ArrayLike, eps: ArrayLike):
    r"""Covariance of the equivalent process noise, eq:omega_tilde_cov.

    .. math:: \Sigma_{\tilde\omega} = \Sigma_\omega + (1-\varepsilon)\mathbf B\mathbf K
              \Sigma_\mathrm{est}\mathbf K^T\mathbf B^T
    """
    bk = b @ k
    return sigma_w + (1.0 - eps) * bk @ sigma_est @ bk.T


def steady_state_covariance(a: ArrayLike, b: ArrayLike, k: ArrayLike, eps: ArrayLike, sigma_wt: ArrayLike):
    r"""Steady state of eq:covariance_recursion,
    :math:`\mathrm{vec}(\Sigma_\infty) = (\mathbf I - \mathbf M)^{-1}\mathrm{vec}(\Sigma_{\tilde\omega})`.

    Raises ``ValueError`` if :math:`\rho(\mathbf M) \ge 1` (no steady state).
    """
    m = stability_matrix(a, b, k, eps)
    if spectral_radius(m) >= 1.0:
        raise ValueError(f"eps = {eps} is not mean-square stable (rho(M) >= 1): no steady state")
    n = a.shape[0]
    vec = np.linalg.solve(np.eye(n * n) - m, sigma_wt.reshape(-1, order="F"))
    sig = vec.reshape(n, n, order="F")
    return 0.5 * (sig + sig.T)


def lqg_cost(q: ArrayLike, r: ArrayLike, k: ArrayLike, eps: ArrayLike, sigma_x: ArrayLike, sigma_est: ArrayLike):
    r"""Average LQG cost b of eq:LQG_cost at steady state.

    .. math::
        b = \operatorname{Tr}(\mathbf Q\Sigma_\infty) + (1-\varepsilon)\operatorname{Tr}\big(
        \mathbf R\mathbf K(\Sigma_\infty - \Sigma_\mathrm{est})\mathbf K^T\big)

    since :math:`\tilde{\mathbf u} = -\delta\mathbf K\hat{\mathbf x}` and
    :math:`\mathbb E[\hat{\mathbf x}\hat{\mathbf x}^T] = \Sigma_\infty - \Sigma_\mathrm{est}`
    (orthogonality of the Kalman estimate), in tracking-error coordinates.
    """
    u_cov = k @ (sigma_x - sigma_est) @ k.T
    return float(np.trace(q @ sigma_x) + (1.0 - eps) * np.trace(r @ u_cov))


def riccati_s_d(a: ArrayLike, b: ArrayLike, q: ArrayLike, r: ArrayLike, eps: ArrayLike, tol: float = 1e-10,
                max_iter: int = 100_000):
    r"""Solve the coupled equations eq:Riccati_D and eq:Riccati_S by fixed-point iteration.

    .. math::
        \mathbf D = (1-\varepsilon)\mathbf S\mathbf B(\mathbf R+\mathbf B^T\mathbf S\mathbf B)^{-1}
        \mathbf B^T\mathbf S,\qquad \mathbf S = \mathbf Q + \mathbf A^T(\mathbf S - \mathbf D)\mathbf A

    For eps = 0 this is the control DARE. Raises ``ValueError`` if the iteration diverges (the
    loss rate is beyond what the modified Riccati equation tolerates).
    """
    s_mat = np.array(q, dtype=float)
    for _ in range(max_iter):
        g = s_mat @ b @ np.linalg.solve(r + b.T @ s_mat @ b, b.T @ s_mat)
        d = (1.0 - eps) * g
        s_new = q + a.T @ (s_mat - d) @ a
        s_new = 0.5 * (s_new + s_new.T)
        if not np.all(np.isfinite(s_new)) or np.max(np.abs(s_new)) > 1e15:
            raise ValueError(f"modified Riccati iteration diverges at eps = {eps}")
        if np.max(np.abs(s_new - s_mat)) <= tol * max(1.0, np.max(np.abs(s_new))):
            s_mat = s_new
            break
        s_mat = s_new
    else:
        raise ValueError(f"modified Riccati iteration did not converge at eps = {eps}")
    d = (1.0 - eps) * s_mat @ b @ np.linalg.solve(r + b.T @ s_mat @ b, b.T @ s_mat)
    return s_mat, 0.5 * (d + d.T)


def lqg_cost_floor(p_dare: ArrayLike, sigma_w: ArrayLike):
    r""":math:`b_\min = \operatorname{Tr}(\mathbf P\Sigma_\omega)`: the average LQR cost with perfect
    state and no loss (eq:Lb), with P the control DARE solution.
    """
    return float(np.trace(p_dare @ sigma_w))


def entropy_power(cov: ArrayLike):
    r"""Entropy power of a Gaussian vector,
    :math:`N = \frac{1}{2\pi e}\exp(\tfrac{2}{n}h) = (\det\Sigma)^{1/n}`.
    """
    n = cov.shape[-1]
    sign, logdet = np.linalg.slogdet(cov)
    if sign <= 0:
        return 0.0
    return float(np.exp(logdet / n))


def rate_cost_bits(a: ArrayLike, b_target: ArrayLike, b_min: ArrayLike, noise_entropy_power: ArrayLike, d: ArrayLike,
                   determinant: str = "pseudo"):
    r"""Rate-cost function L(b) of eq:Lb, in bits per control sample (slot).

    .. math::
        L(b) = \log_2|\det\mathbf A| + \frac{n}{2}\log_2\left(1 + \frac{n\,N(\tilde\omega)\,
        |\det\mathbf D|^{1/n}}{b - b_\min}\right),\quad n = 6

    :math:`\mathbf D` of eq:Riccati_D has rank 3 (B is 6 x 3), so the printed ``determinant="printed"``
    gives :math:`\det\mathbf D = 0` and :math:`L(b) = \log_2|\det\mathbf A| = 0` for every b.
    ``determinant="pseudo"`` (default) replaces :math:`n` and :math:`\det` in the second term by the
    rank r of D and its pseudo-determinant (product of the non-zero eigenvalues), see docs/model.md.
    Returns ``inf`` for :math:`b \le b_\min`.
    """
    n = a.shape[0]
    if b_target <= b_min:
        return float("inf")
    base = float(np.log2(abs(np.linalg.det(a))))
    if determinant == "printed":
        dim, det_root = n, abs(np.linalg.det(d)) ** (1.0 / n)
    else:
        ev = np.linalg.eigvalsh(0.5 * (d + d.T))
        nz = ev[ev > 1e-9 * max(ev.max(), 1e-300)]
        dim = len(nz)
        if dim == 0:
            return base
        det_root = float(np.exp(np.mean(np.log(nz))))
    return base + 0.5 * dim * float(np.log2(1.0 + dim * noise_entropy_power * det_root
                                            / (b_target - b_min)))


class LossOperator:
    r"""The per-axis closed-loop map :math:`\mathrm{vec}\,\Sigma = (\mathbf I - \mathbf M_1(\varepsilon))^{-1}
    \mathrm{vec}\,\mathbf N` as a rational function of the loss rate.

    With :math:`\mathbf M_1(\varepsilon) = \mathbf M_\mathrm{cl} + \varepsilon\Delta`,
    :math:`(\mathbf I - \mathbf M_1)^{-1} = \mathbf X_0(\mathbf I - \varepsilon\mathbf Y)^{-1}`,
    :math:`\mathbf X_0 = (\mathbf I - \mathbf M_\mathrm{cl})^{-1}`, :math:`\mathbf Y = \Delta\mathbf X_0`,
    and by Cayley-Hamilton :math:`(\mathbf I - \varepsilon\mathbf Y)^{-1} = \sum_{d=0}^{3}\varepsilon^d
    \mathbf C_d / \det(\mathbf I - \varepsilon\mathbf Y)`, :math:`\mathbf C_d = \sum_{k\le d}
    c_{d-k}\mathbf Y^k` with :math:`c` the characteristic-polynomial coefficients of Y.
    """

    _OUT = (0, 2, 3)  # column-major vec indices of the (0,0), (0,1), (1,1) entries

    def __init__(self, a1, b1, k1):
        a_cl = a1 - b1 @ k1
        self.m_cl = np.kron(a_cl, a_cl)
        self.m_a = np.kron(a1, a1)
        x0 = np.linalg.inv(np.eye(4) - self.m_cl)
        y = (self.m_a - self.m_cl) @ x0
        c = np.poly(y)  # [1, c1, c2, c3, c4]
        powers = [np.eye(4), y, y @ y, y @ y @ y]
        cd = [sum(c[d - k] * powers[k] for k in range(d + 1)) for d in range(4)]
        # rows: outputs; applied to vec N with N symmetric: columns n00, n01 (twice), n11
        self.lin = np.stack([(x0 @ cd[d])[list(self._OUT)] for d in range(4)], -1)  # (3, 4, 4deg)
        self.det_coef = c  # det(I - eps Y) = sum_i c_i eps^i

    def project(self, n_mat, weights):
        r"""Numerator coefficients of linear functionals of the steady state.

        ``n_mat`` (..., 2, 2): noise matrices N; ``weights`` (k, 3): functionals
        :math:`w_0\Sigma_{00} + w_1\Sigma_{01} + w_2\Sigma_{11}`. Returns (..., k, 4 degrees).
        """
        vec = np.stack([n_mat[..., 0, 0], n_mat[..., 1, 0], n_mat[..., 0, 1], n_mat[..., 1, 1]], -1)
        lin = np.einsum("ke,evd->vkd", np.asarray(weights, dtype=float), self.lin).reshape(4, -1)
        return (vec @ lin).reshape(vec.shape[:-1] + (len(weights), 4))

    def evaluate(self, eta_a, eta_b, eps):
        r"""Steady-state outputs for noise :math:`\mathbf N_a + (1-\varepsilon)\mathbf N_b`.

        ``eta_*`` (..., 4 degrees) are :meth:`project` outputs (or linear combinations of them);
        ``eps`` broadcasts against ``eta_*[..., 0]``. Returns shape ``eta_*.shape[:-1]``.
        """
        e = np.asarray(eps, dtype=float)
        coef = eta_a + (1.0 - e)[..., None] * eta_b
        num = ((coef[..., 3] * e + coef[..., 2]) * e + coef[..., 1]) * e + coef[..., 0]
        c = self.det_coef
        det = (((c[4] * e + c[3]) * e + c[2]) * e + c[1]) * e + c[0]
        return num / det

    def spectral_radius(self, eps):
        r""":math:`\rho(\mathbf M(\varepsilon))` of eq:M (equal to that of the per-axis 4 x 4 map)."""
        e = np.atleast_1d(np.asarray(eps, dtype=float))
        m = (1.0 - e)[:, None, None] * self.m_cl + e[:, None, None] * self.m_a
        return np.max(np.abs(np.linalg.eigvals(m)), axis=-1)
