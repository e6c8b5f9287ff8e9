"""The multi-drone task, ``iscc_gym/ISCC-Multi-v0`` (issue 19): K drones sharing one base station's band, the
paper's loop each (preset ``paper``). One agent ships per drone count (``agents/trained/multi/k<K>``).
"""

from __future__ import annotations

from iscc_gym.tasks.task import Task

__all__ = ["MULTI_ENV_ID", "TASK"]

#: Many drones sharing one band (issue 19).
MULTI_ENV_ID = "iscc_gym/ISCC-Multi-v0"

TASK = Task(MULTI_ENV_ID, "paper", "iscc_gym.envs.multi:ISCCMultiEnv", "iscc_gym.envs.vector:ISCCMultiVectorEnv",
            "K drones sharing one base station's band, the paper's loop each", "tasks/multi",
            policies="equal-sca,joint-sca,margin,margin-starved", reference="joint-sca",
            scripted=("equal-sca", "joint-sca", "margin"), results_section="multi",
            results_title="Many drones, one base station", focus="agent")
