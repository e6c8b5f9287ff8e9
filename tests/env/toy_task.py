"""A user's own task, in one file (issue 44, point 2): the paper's loop on 10-second missions, a preset of its own
(``toy``: the ``paper`` preset with one parameter changed). Importing it registers it; every command then plays,
trains, tunes and lists it, e.g. ``python -m eval --gym-packages tests.env.toy_task --env toy/ISCC-Toy-v0``.
"""

import iscc_gym
from iscc_gym.tasks import Task

TASK = iscc_gym.register_task(Task(
    "toy/ISCC-Toy-v0", "toy", "iscc_gym.envs.env:ISCCEnv", "iscc_gym.envs.vector:ISCCVectorEnv",
    "a toy task: the paper's loop on 10-second missions", "tasks/paper", base="paper",
    overrides={"mission_duration_s": 10.0}, policies="myopic,margin,equal", reference="myopic",
    scripted=("myopic", "margin"), results_section="toy", results_title="The toy task",
    train_like="iscc_gym/ISCC-v0"))
