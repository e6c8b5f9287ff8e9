"""Off the step path: the steady-state (static) evaluator of a split and what it is built of.

``static`` (:func:`static_model`, :class:`StaticModel`: the analytic tracking error, stability and rates of
a static split, re-exported here), ``allocation`` (a split's metrics), ``averages`` (trajectory samples and
averaged bounds, SNRs and rates), ``kalman_steady`` (the filter's steady state), ``quadrature``
(Gauss-Hermite and Rician quantiles), ``sensing_share`` (the CRLB as a function of the sensing share).

Imports :mod:`iscc_gym.physics` and :mod:`iscc_gym.sim`; nothing on the step path imports it.
"""

from iscc_gym.analysis.static import DEFAULT_SAMPLE, TRUST_LOSS_FRACTION, StaticModel, static_model

__all__ = ["TRUST_LOSS_FRACTION", "StaticModel", "static_model", "DEFAULT_SAMPLE"]
