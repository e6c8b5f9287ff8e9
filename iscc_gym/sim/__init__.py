"""The simulation: one slot of the closed loop and the env step, composed of :mod:`iscc_gym.physics`.

``effects`` (what a task adds to the paper's slot: blockage, the data queue, the preview; decided once per
scenario), ``schema`` (the columns of a step's output, the observation's entries, scales, bounds and layout,
the noise draws), ``params`` (the scenario's constants for compiled code), ``noise`` (counter-based per-slot
normals), ``mission`` (a mission's rows: the reference, and the channel along it), ``loop`` (one slot of the
closed loop, the data queue included), ``task`` (action map, reward and costs), ``kernel`` (the compiled
composition: split -> slot -> observation -> reward, batched).

Imports :mod:`iscc_gym.physics` and the scenario, never :mod:`iscc_gym.envs` or :mod:`iscc_gym.analysis`.
"""

from iscc_gym.lazy import lazy_names as _lazy_names

# a submodule on first use (iscc_gym.sim.<module> after import iscc_gym, as when iscc_gym imported the env eagerly)
__getattr__, __dir__ = _lazy_names(__name__, {}, globals())
