r"""Blocked line of sight along the path: the 3GPP aerial-UE LoS probability, LoS/NLoS path loss and
shadowing, spatially consistent random fields, and the GBS's channel-knowledge map.

Sources
-------
* LoS probability: 3GPP TR 36.777 (Rel-15) Annex B, Table B-1, UMa-AV and UMi-AV, for UE heights
  22.5 m < h <= 300 m; at or below 22.5 m the terrestrial TR 38.901 Table 7.4.2-1 (UMa with the
  height factor C'(h), UMi street canyon), as Table B-1 prescribes.
* Path loss and shadowing: TR 36.777 Table B-2 for 22.5 m < h <= 300 m (the paper's channel is its
  UMa-AV LoS row). Only these heights are modelled; ``scenario_checks`` refuses a blocked scenario whose
  altitude band reaches below.
* Spatial consistency: TR 38.901 Sec. 7.6.3: the LoS state of a position is drawn by comparing a
  spatially consistent uniform variable with the LoS probability, the uniform variable's normal score
  correlated as :math:`\exp(-\Delta/d_\mathrm{corr})` over the horizontal distance :math:`\Delta`
  (:math:`d_\mathrm{corr}` = 50 m for UMa and UMi, Table 7.6.3.1-2); shadowing likewise with its
  decorrelation distance (Table 7.5-6: UMa LoS 37 m, UMi LoS 10 m).

A zero-mean, unit-variance field with that correlation is drawn per mission as a sum of random
cosines (spectral sampling: the 2-D exponential correlation is the characteristic function of a
bivariate Cauchy law of wave vectors):

.. math::
    f(\mathbf x) = \sqrt{2/M}\sum_{m=1}^{M}\cos(\mathbf k_m\cdot\mathbf x + \phi_m),\quad
    \mathbf k_m = \frac{\mathbf z_m}{d_\mathrm{corr}\,|w_m|},\ \mathbf z_m \sim \mathcal N(0, \mathbf I_2),\
    w_m \sim \mathcal N(0, 1),\ \phi_m \sim \mathcal U[0, 2\pi)

so :math:`\mathbb E f(\mathbf x) f(\mathbf y) = \exp(-|\mathbf x - \mathbf y|/d_\mathrm{corr})` exactly,
and :math:`f` is Gaussian as M grows (M = 64 here). One place has one value within a mission.

The exponential correlation is rough (not differentiable at 0): thresholded, its LoS state flickers at the
metre scale, and most blocked stretches of a flight are a few metres long. ``kernel="gaussian"`` draws
:math:`\mathbf k_m = \sqrt 2\,\mathbf z_m/d_\mathrm{corr}` instead, the field with correlation
:math:`\exp(-\Delta^2/d_\mathrm{corr}^2)` (the same correlation distance: :math:`e^{-1}` at
:math:`d_\mathrm{corr}`), smooth, whose stretches have the scale of :math:`d_\mathrm{corr}`: a building's
(``Scenario.los_field_kernel``, ``docs/model.md`` Sec. 6.1).

The map: the GBS knows a field :math:`m` of the same law; the truth is
:math:`g = \rho\, m + \sigma_e\, e` with an independent error field :math:`e` and
:math:`\rho = \sqrt{1 - \sigma_e^2}` (``map_error_std`` = :math:`\sigma_e`). The position is LoS iff
:math:`g < \Phi^{-1}(P_\mathrm{LoS})`, so the map's LoS probability is
:math:`\Phi\big((\Phi^{-1}(P_\mathrm{LoS}) - \rho\, m)/\sigma_e\big)`, and its shadowing mean
:math:`\rho\, m_\mathrm{sh}` (in units of the shadowing std).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, vectorize
from numpy.typing import ArrayLike
from scipy.special import ndtr, ndtri

__all__ = ["BLOCKAGE_MODELS", "N_FIELD_FEATURES", "FIELD_KERNELS", "LOS_CORRELATION_M", "los_probability",
           "path_loss_db",
           "excess_loss_db", "shadowing_std_nlos_db", "shadowing_std_los_db", "draw_field", "field_at",
           "map_los_probability", "los_probability_one", "excess_loss_db_one", "shadowing_std_db_one",
           "field_one"]

#: ``Scenario.blockage`` as the code the compiled functions read: 0 no blockage (the paper: always LoS),
#: 1 UMa-AV, 2 UMi-AV (TR 36.777 Annex B).
BLOCKAGE_MODELS = {"none": 0.0, "uma_av": 1.0, "umi_av": 2.0}
#: Cosines per field (the field's marginal is Gaussian to within a few per cent at this size).
N_FIELD_FEATURES = 64
#: Correlation kernels of :func:`draw_field` (``Scenario.los_field_kernel``).
FIELD_KERNELS = ("exponential", "gaussian")
#: Correlation distance of the LoS state, m (TR 38.901 Table 7.6.3.1-2: UMa and UMi 50 m).
LOS_CORRELATION_M = 50.0


# --- the 3GPP formulas, compiled scalar forms ------------------------------------------------------

@njit(cache=True, error_model="numpy", inline="always")
def los_probability_one(model, h_m, d2d_m):
    r"""LoS probability of a UE at height ``h_m`` and horizontal distance ``d2d_m`` from the GBS.

    TR 36.777 Table B-1 for :math:`22.5 < h \le 300` m (:math:`p_1`, :math:`d_1` as tabulated), UMa-AV
    (``model`` 1) and UMi-AV (2):

    .. math::
        P_\mathrm{LoS} = \begin{cases} 1 & d \le d_1 \\
        \frac{d_1}{d} + e^{-d/p_1}\big(1 - \frac{d_1}{d}\big) & \text{else}\end{cases},\qquad d = d_\mathrm{2D}

    UMa-AV: :math:`p_1 = 4300\log_{10}h - 3800`, :math:`d_1 = \max(460\log_{10}h - 700, 18)`, and
    :math:`P_\mathrm{LoS} = 1` above 100 m; UMi-AV: :math:`p_1 = 233.98\log_{10}h - 0.95`,
    :math:`d_1 = \max(294.05\log_{10}h - 432.94, 18)`. At or below 22.5 m TR 38.901 Table 7.4.2-1
    (UMa: :math:`d_1 = 18`, :math:`p_1 = 63` times :math:`1 + C'(h)\tfrac54 (d/100)^3 e^{-d/150}`;
    UMi: :math:`d_1 = 18`, :math:`p_1 = 36`). ``model`` 0: 1 (no blockage).
    """
    if model == 0.0:
        return 1.0
    if h_m <= 22.5:
        if d2d_m <= 18.0:
            return 1.0
        p1 = 63.0 if model == 1.0 else 36.0
        base = 18.0 / d2d_m + math.exp(-d2d_m / p1) * (1.0 - 18.0 / d2d_m)
        if model == 1.0 and h_m > 13.0:
            c_h = ((h_m - 13.0) / 10.0) ** 1.5
            base *= 1.0 + c_h * 1.25 * (d2d_m / 100.0) ** 3 * math.exp(-d2d_m / 150.0)
        return min(base, 1.0)
    lh = math.log10(h_m)
    if model == 1.0:
        if h_m > 100.0:
            return 1.0
        p1 = 4300.0 * lh - 3800.0
        d1 = max(460.0 * lh - 700.0, 18.0)
    else:
        p1 = 233.98 * lh - 0.95
        d1 = max(294.05 * lh - 432.94, 18.0)
    if d2d_m <= d1:
        return 1.0
    return d1 / d2d_m + math.exp(-d2d_m / p1) * (1.0 - d1 / d2d_m)


@njit(cache=True, error_model="numpy", inline="always")
def excess_loss_db_one(model, los, h_m, d3d_m, fc_ghz):
    r"""Path loss of the link's state minus the paper's UMa-AV LoS loss, in dB.

    The paper's loss is :math:`28 + 22\log_{10}d + 20\log_{10}f_c`; the excess is what the link pays on
    top of :func:`iscc_gym.physics.channel.link_snr_one` (the radar echo pays it twice).
    TR 36.777 Table B-2, :math:`22.5 < h \le 300` m, d in m, f_c in GHz:

    * UMa-AV LoS: the paper's formula (0 dB excess);
    * UMa-AV NLoS: :math:`-17.5 + (46 - 7\log_{10}h)\log_{10}d + 20\log_{10}(40\pi f_c/3)`;
    * UMi-AV LoS: :math:`\max(\mathrm{PL_{FS}},\ 30.9 + (22.25 - 0.5\log_{10}h)\log_{10}d + 20\log_{10}f_c)`
      with :math:`\mathrm{PL_{FS}} = 20\log_{10}(40\pi d f_c/3)`;
    * UMi-AV NLoS: :math:`\max(\mathrm{PL_{LoS}},\ 32.4 + (43.2 - 7.6\log_{10}h)\log_{10}d + 20\log_{10}f_c)`.

    ``model`` 0 (no blockage) and UMa-AV LoS: 0.
    """
    if model == 0.0 or (model == 1.0 and los):
        return 0.0
    ld = math.log10(d3d_m)
    lh = math.log10(h_m)
    lf = math.log10(fc_ghz)
    paper = 28.0 + 22.0 * ld + 20.0 * lf
    if model == 1.0:
        return -17.5 + (46.0 - 7.0 * lh) * ld + 20.0 * math.log10(40.0 * math.pi * fc_ghz / 3.0) - paper
    pl = max(20.0 * math.log10(40.0 * math.pi * d3d_m * fc_ghz / 3.0), 30.9 + (22.25 - 0.5 * lh) * ld + 20.0 * lf)
    if not los:
        pl = max(pl, 32.4 + (43.2 - 7.6 * lh) * ld + 20.0 * lf)
    return pl - paper


@njit(cache=True, error_model="numpy", inline="always")
def shadowing_std_db_one(model, los, h_m, sf_a, sf_b):
    r"""Shadowing standard deviation, dB (TR 36.777 Table B-2): LoS of UMa-AV and of the paper
    :math:`a e^{-b h}` (``sf_a``, ``sf_b``: 4.64 dB, 0.0066/m); UMi-AV LoS :math:`\max(5 e^{-0.01 h}, 2)`;
    NLoS 6 dB (UMa-AV) and 8 dB (UMi-AV).
    """
    if model == 2.0:
        return max(5.0 * math.exp(-0.01 * h_m), 2.0) if los else 8.0
    if los or model == 0.0:
        return sf_a * math.exp(-sf_b * h_m)
    return 6.0


@njit(cache=True, error_model="numpy", inline="always")
def field_one(features, x, y):
    r""":math:`f(x, y)` of a field drawn by :func:`draw_field` (``features``: (M, 4) rows of
    :math:`k_x, k_y, \phi, \sqrt{2/M}`).
    """
    acc = 0.0
    for m in range(features.shape[0]):
        acc += math.cos(features[m, 0] * x + features[m, 1] * y + features[m, 2])
    return acc * features[0, 3]


# --- array forms -------------------------------------------------------------------------------------

@vectorize(["float64(float64, float64, float64)"], cache=True)
def _los_probability_ufunc(model, h_m, d2d_m):
    return los_probability_one(model, h_m, d2d_m)


@vectorize(["float64(float64, boolean, float64, float64, float64)"], cache=True)
def _excess_ufunc(model, los, h_m, d3d_m, fc_ghz):
    return excess_loss_db_one(model, los, h_m, d3d_m, fc_ghz)


@vectorize(["float64(float64, boolean, float64, float64, float64)"], cache=True)
def _shadowing_std_ufunc(model, los, h_m, sf_a, sf_b):
    return shadowing_std_db_one(model, los, h_m, sf_a, sf_b)


def _model_code(model: str) -> float:
    if model not in BLOCKAGE_MODELS:
        raise ValueError(f"model = {model!r} is not a blockage model; use one of {list(BLOCKAGE_MODELS)}")
    return BLOCKAGE_MODELS[model]


def los_probability(model: str, h_m: ArrayLike, d2d_m: ArrayLike):
    """:func:`los_probability_one` over arrays (``model``: a key of :data:`BLOCKAGE_MODELS`)."""
    return _los_probability_ufunc(_model_code(model), h_m, d2d_m)[()]


def excess_loss_db(model: str, los: ArrayLike, h_m: ArrayLike, d3d_m: ArrayLike, fc_ghz: float):
    """:func:`excess_loss_db_one` over arrays: path loss of the state minus the paper's UMa-AV LoS loss, dB."""
    return _excess_ufunc(_model_code(model), np.asarray(los, dtype=bool), h_m, d3d_m, fc_ghz)[()]


def path_loss_db(model: str, los: ArrayLike, h_m: ArrayLike, d3d_m: ArrayLike, fc_ghz: float):
    """Path loss of TR 36.777 Table B-2 in dB: the paper's UMa-AV LoS loss plus :func:`excess_loss_db`."""
    d = np.asarray(d3d_m, dtype=float)
    return 28.0 + 22.0 * np.log10(d) + 20.0 * np.log10(fc_ghz) + excess_loss_db(model, los, h_m, d, fc_ghz)


def shadowing_std_los_db(model: str, h_m: ArrayLike, sf_a: float = 4.64, sf_b: float = 0.0066):
    """:func:`shadowing_std_db_one` of a LoS link over arrays."""
    return _shadowing_std_ufunc(_model_code(model), True, h_m, sf_a, sf_b)[()]


def shadowing_std_nlos_db(model: str, h_m: ArrayLike):
    """:func:`shadowing_std_db_one` of an NLoS link over arrays (model "none" has none: its LoS value)."""
    return _shadowing_std_ufunc(_model_code(model), False, h_m, 4.64, 0.0066)[()]


def draw_field(rng: np.random.Generator, corr_distance_m: float, n_features: int = N_FIELD_FEATURES,
               kernel: str = "exponential"):
    r"""Draw one unit-variance field over the horizontal plane with correlation :math:`\exp(-\Delta/d)`
    (``kernel="exponential"``, TR 38.901 Sec. 7.6.3) or :math:`\exp(-\Delta^2/d^2)` (``"gaussian"``: smooth,
    wave vectors :math:`\mathbf k_m = \sqrt 2\,\mathbf z_m/d`), :math:`d` = ``corr_distance_m``.

    Returns its ``features`` (M, 4): rows :math:`(k_x, k_y, \phi, \sqrt{2/M})` for :func:`field_one` and
    :func:`field_at` (see the module docstring for the law of the wave vectors). Both kernels take the same
    draws from ``rng`` (the same :math:`\mathbf z_m`, :math:`w_m`, :math:`\phi_m`), so a mission's other
    draws do not depend on the kernel.
    """
    if not corr_distance_m > 0.0:
        raise ValueError(f"corr_distance_m = {corr_distance_m!r} must be > 0")
    if kernel not in FIELD_KERNELS:
        raise ValueError(f"kernel = {kernel!r} is invalid: must be one of {FIELD_KERNELS}")
    z = rng.standard_normal((n_features, 2))
    w = np.abs(rng.standard_normal(n_features))
    phase = rng.uniform(0.0, 2.0 * np.pi, n_features)
    if kernel == "gaussian":
        k = z * (math.sqrt(2.0) / corr_distance_m)
    else:
        k = z / (corr_distance_m * np.maximum(w, 1e-300))[:, None]
    if not (np.all(np.isfinite(k)) and np.max(np.abs(k)) < 1e150):  # a field value is cos(k . x): finite k . x
        raise ValueError(f"corr_distance_m = {corr_distance_m!r} is too short: the field's wave numbers overflow; "
                         "use a correlation distance of a centimetre or more")
    return np.column_stack([k, phase, np.full(n_features, math.sqrt(2.0 / n_features))])


@njit(cache=True, error_model="numpy")
def _field_loop(features, x, y, out):
    for i in range(x.shape[0]):
        out[i] = field_one(features, x[i], y[i])


def field_at(features: np.ndarray, x_m: ArrayLike, y_m: ArrayLike):
    """The field of :func:`draw_field` at horizontal positions (broadcast shapes)."""
    x, y = np.broadcast_arrays(np.asarray(x_m, dtype=float), np.asarray(y_m, dtype=float))
    out = np.empty(x.size)
    _field_loop(np.ascontiguousarray(features, dtype=float), np.ascontiguousarray(x).ravel(),
                np.ascontiguousarray(y).ravel(), out)
    return out.reshape(x.shape)[()]


def map_los_probability(p_los: ArrayLike, map_field: ArrayLike, map_error_std: float):
    r"""The map's LoS probability :math:`\Phi\big((\Phi^{-1}(P_\mathrm{LoS}) - \rho\,m)/\sigma_e\big)`,
    :math:`\rho = \sqrt{1 - \sigma_e^2}`: the probability that the truth :math:`\rho m + \sigma_e e` falls
    below the LoS threshold given the map's field value :math:`m`. ``map_error_std`` 0 gives the map's
    own state (0 or 1); 1 the prior :math:`P_\mathrm{LoS}`.
    """
    se = float(map_error_std)
    if not 0.0 <= se <= 1.0:
        raise ValueError(f"map_error_std = {map_error_std!r} must be in [0, 1]")
    rho = math.sqrt(1.0 - se * se)
    with np.errstate(divide="ignore"):
        thr = ndtri(np.clip(np.asarray(p_los, dtype=float), 0.0, 1.0))
    if se == 0.0:
        return (rho * np.asarray(map_field, dtype=float) < thr).astype(float)
    return ndtr((thr - rho * np.asarray(map_field, dtype=float)) / se)
