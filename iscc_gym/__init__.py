"""iscc-gym: learned resource allocation for integrated sensing, communication and control.

The closed loop of Li et al., "Closed-Loop Integrated Sensing, Communication, and Control for
Efficient Drone Flight" around one frozen :class:`Scenario` (``scenario.py``), in four layers whose
imports run one way (``tests/commands/test_imports.py``):

- :mod:`iscc_gym.physics`: per-drone equations, one module per concept;
- :mod:`iscc_gym.sim`: the compiled slot and env step composed of them;
- :mod:`iscc_gym.envs`: the Gymnasium and PettingZoo faces;
- :mod:`iscc_gym.analysis`: the steady-state evaluator, off the step path.

The repository's ``agents/``, ``commands/``, ``train/`` and ``eval/`` folders install as ``iscc_gym.agents``,
``iscc_gym.commands``, ``iscc_gym.train`` and ``iscc_gym.eval`` (``pyproject.toml``'s ``package-dir``); this core
never imports them.
"""

import gymnasium as _gym

from iscc_gym import compile_note as _compile_note  # noqa: F401 (a note on stderr when the kernels are first built)
from iscc_gym.lazy import lazy_names as _lazy_names
from iscc_gym.scenario import SCENARIOS, Scenario, make_scenario
from iscc_gym.tasks import ENV_ID, FIELD_ENV_ID, MULTI_ENV_ID, TASKS, URBAN_ENV_ID, Task, add_task

#: The names imported on first use (:mod:`iscc_gym.lazy`): the env and the compiled physics behind it are not loaded
#: by ``import iscc_gym`` itself (nor by a command checking its arguments, issue 43.12: a mistake was refused only
#: after the whole package, the compiled kernels included, had loaded); ``gymnasium.make`` loads them by entry point.
__getattr__, __dir__ = _lazy_names(__name__, {"ISCCEnv": "iscc_gym.envs.env", "N_DRONES": "iscc_gym.sim.fleet",
                                              "action_to_split": "iscc_gym.sim.task",
                                              "split_to_action": "iscc_gym.sim.task"}, globals())

__all__ = ["Scenario", "SCENARIOS", "make_scenario", "ISCCEnv", "action_to_split", "split_to_action",
           "ENV_ID", "URBAN_ENV_ID", "MULTI_ENV_ID", "FIELD_ENV_ID", "TASKS", "register_task", "parallel_env"]



def register_task(task: Task) -> Task:
    """Add ``task`` (:class:`iscc_gym.tasks.Task`, e.g. a user's own task file's ``TASK``) to the task table
    (:func:`iscc_gym.tasks.add_task`) and register its env id with Gymnasium, once; returns it. The commands then
    play, train and compare it like the shipped tasks.
    """
    add_task(task)
    if task.env_id not in _gym.registry:
        _gym.register(id=task.env_id, entry_point=task.entry_point, vector_entry_point=task.vector_entry_point,
                      max_episode_steps=task.max_episode_steps, kwargs=task.kwargs)
    return task


for _task in list(TASKS.values()):  # every env id from the task files (iscc_gym.tasks)
    register_task(_task)
__version__ = "0.1.0"


def parallel_env(n_drones: int | None = None, **kwargs):
    """The PettingZoo ``ParallelEnv`` of the multi-drone env, one agent per drone
    (:func:`iscc_gym.envs.multi_pz.parallel_env`; needs ``pip install pettingzoo``, imported on first use).
    """
    from iscc_gym.envs.multi_pz import parallel_env as make
    from iscc_gym.sim.fleet import N_DRONES

    return make(n_drones=N_DRONES if n_drones is None else n_drones, **kwargs)
