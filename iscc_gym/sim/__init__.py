"""The simulation: one slot of the closed loop and the env step, composed of :mod:`iscc_gym.physics`.

``schema`` (the columns of a step's output, the observation's entries and scales, the noise draws),
``params`` (the scenario's constants for compiled code), ``noise`` (counter-based per-slot normals),
``loop`` (one slot of the closed loop), ``task`` (action map, reward and costs), ``kernel`` (the compiled
composition: split -> slot -> observation -> reward, batched).

Imports :mod:`iscc_gym.physics` and the scenario, never :mod:`iscc_gym.envs` or :mod:`iscc_gym.analysis`.
"""
