"""iscc-gym: learned resource allocation for integrated sensing, communication and control.

The closed loop of Li et al., "Closed-Loop Integrated Sensing, Communication, and Control for
Efficient Drone Flight", as pure batched numpy functions (``channel``, ``fbl``, ``sensing``,
``dynamics``, ``kalman``, ``stability``, ``trajectory``, ``loop``) around one frozen
:class:`Scenario`.
"""

import os as _os

import gymnasium as _gym

from . import compile_note as _compile_note  # noqa: F401 (a note on stderr when the kernels are first built)
from . import multi
from .env import REGISTERED_MAX_EPISODE_STEPS, ISCCEnv, action_to_split, split_to_action
from .scenario import SCENARIOS, Scenario, make_scenario

__all__ = ["Scenario", "SCENARIOS", "make_scenario", "ISCCEnv", "action_to_split", "split_to_action",
           "ENV_ID", "MULTI_ENV_ID", "multi"]

#: The registered environment id.
ENV_ID = "iscc_gym/ISCC-v0"

assert SCENARIOS["paper"].n_slots == REGISTERED_MAX_EPISODE_STEPS
if ENV_ID not in _gym.registry:
    _gym.register(id=ENV_ID, entry_point="iscc_gym.env:ISCCEnv",
                  vector_entry_point="iscc_gym.vector:ISCCVectorEnv",
                  max_episode_steps=REGISTERED_MAX_EPISODE_STEPS)
#: The registered id of the multi-drone env (:mod:`iscc_gym.multi`).
MULTI_ENV_ID = "iscc_gym/ISCC-Multi-v0"
if MULTI_ENV_ID not in _gym.registry:
    _gym.register(id=MULTI_ENV_ID, entry_point="iscc_gym.multi:ISCCMultiEnv",
                  vector_entry_point="iscc_gym.vector:ISCCMultiVectorEnv",
                  max_episode_steps=REGISTERED_MAX_EPISODE_STEPS)
__version__ = "0.1.0"

# agents/, train/ and eval/ sit at the top of the repo and install as iscc_gym.agents, iscc_gym.train
# and iscc_gym.eval (pyproject's package-dir). In a source checkout that is not installed that way
# (a plain `pip install .` run from the repo root, or no install at all), let this package's path
# reach the checkout's folders too, so `python -m eval` from the root resolves `iscc_gym.agents`.
_root = _os.path.dirname(_os.path.dirname(_os.path.abspath(__file__)))
if (not _os.path.isdir(_os.path.join(_os.path.dirname(_os.path.abspath(__file__)), "agents"))
        and _os.path.isfile(_os.path.join(_root, "pyproject.toml"))
        and _os.path.isfile(_os.path.join(_root, "agents", "__init__.py"))):
    __path__.append(_root)  # noqa: F821 (the package's own __path__)
