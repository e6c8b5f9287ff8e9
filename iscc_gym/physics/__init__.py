"""Per-drone physics: one module per concept of the paper's model, each equation written once.

``channel`` (path loss, shadowing, Rician fading, link SNR), ``signature`` (the OFDM radar's echo
signature), ``sensing`` (Fisher information and CRLB of the measurement), ``fbl`` (finite-blocklength
rates and block error rates), ``dynamics`` (the drone's double integrator and the LQG gain),
``kalman`` (the filter's update), ``trajectory`` (reference missions), ``stability`` (eps*, M, rho), ``blockage``
and ``queue`` (the urban task's), ``wind`` (Dryden low-altitude turbulence; not in the slot yet, issue 36).

Compiled scalar ``*_one`` functions, which the compiled slot (:mod:`iscc_gym.sim`) calls, beside their
array forms. Imports nothing of :mod:`iscc_gym.sim`, :mod:`iscc_gym.envs` or :mod:`iscc_gym.analysis`
(``tests/commands/test_imports.py``).
"""

from iscc_gym.lazy import lazy_names as _lazy_names

# a submodule on first use (iscc_gym.physics.<module> after import iscc_gym, as when iscc_gym imported the env eagerly)
__getattr__, __dir__ = _lazy_names(__name__, {}, globals())
