"""iscc-gym: learned resource allocation for integrated sensing, communication and control.

The closed loop of Li et al., "Closed-Loop Integrated Sensing, Communication, and Control for
Efficient Drone Flight" around one frozen :class:`Scenario` (``scenario.py``), in four layers whose
imports run one way (``tests/test_imports.py``):

- :mod:`iscc_gym.physics`: per-drone equations, one module per concept;
- :mod:`iscc_gym.sim`: the compiled slot and env step composed of them;
- :mod:`iscc_gym.envs`: the Gymnasium and PettingZoo faces;
- :mod:`iscc_gym.analysis`: the steady-state evaluator, off the step path.

The repository's ``agents/``, ``train/`` and ``eval/`` folders install as ``iscc_gym.agents``,
``iscc_gym.train`` and ``iscc_gym.eval`` (``pyproject.toml``'s ``package-dir``); this core never imports them.
"""

import gymnasium as _gym

from iscc_gym import compile_note as _compile_note  # noqa: F401 (a note on stderr when the kernels are first built)
from iscc_gym.envs.env import ENV_ID, REGISTERED_MAX_EPISODE_STEPS, URBAN_ENV_ID, ISCCEnv
from iscc_gym.envs.multi import MULTI_ENV_ID
from iscc_gym.scenario import SCENARIOS, Scenario, make_scenario
from iscc_gym.sim.fleet import N_DRONES
from iscc_gym.sim.task import action_to_split, split_to_action

__all__ = ["Scenario", "SCENARIOS", "make_scenario", "ISCCEnv", "action_to_split", "split_to_action",
           "ENV_ID", "URBAN_ENV_ID", "MULTI_ENV_ID", "parallel_env"]

assert SCENARIOS["paper"].n_slots == REGISTERED_MAX_EPISODE_STEPS
if ENV_ID not in _gym.registry:
    _gym.register(id=ENV_ID, entry_point="iscc_gym.envs.env:ISCCEnv",
                  vector_entry_point="iscc_gym.envs.vector:ISCCVectorEnv",
                  max_episode_steps=REGISTERED_MAX_EPISODE_STEPS)
if URBAN_ENV_ID not in _gym.registry:
    _gym.register(id=URBAN_ENV_ID, entry_point="iscc_gym.envs.env:ISCCEnv",
                  vector_entry_point="iscc_gym.envs.vector:ISCCVectorEnv",
                  max_episode_steps=SCENARIOS["urban"].n_slots, kwargs={"scenario": "urban"})
if MULTI_ENV_ID not in _gym.registry:
    _gym.register(id=MULTI_ENV_ID, entry_point="iscc_gym.envs.multi:ISCCMultiEnv",
                  vector_entry_point="iscc_gym.envs.vector:ISCCMultiVectorEnv",
                  max_episode_steps=REGISTERED_MAX_EPISODE_STEPS)
__version__ = "0.1.0"


def parallel_env(n_drones: int = N_DRONES, **kwargs):
    """The PettingZoo ``ParallelEnv`` of the multi-drone env, one agent per drone
    (:func:`iscc_gym.envs.multi_pz.parallel_env`; needs ``pip install pettingzoo``, imported on first use).
    """
    from iscc_gym.envs.multi_pz import parallel_env as make

    return make(n_drones=n_drones, **kwargs)
