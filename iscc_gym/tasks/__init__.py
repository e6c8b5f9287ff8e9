"""The tasks: each registered env id's settings, one file per task.

A task is a registered env id over a Scenario preset, both of its sides as data (:class:`Task`): its entry points,
its mission length (the preset's ``n_slots``: the registered ``max_episode_steps``), the named variants of its
missions that the studies play (shifted missions, levers), its page on the documentation site, and its policy side
as strings the layers above resolve (``iscc_gym.agents.tasks``): the default comparison, the reference, the shipped
agent's folder, the docs sections. ``iscc_gym/__init__`` registers every entry of :data:`TASKS`. A new task is one
file here (``TASK = Task(...)``, listed in :data:`TASK_MODULES`) plus its physics (the preset's Scenario fields).

An env id's version ``-vN`` rises when its dynamics change (``CHANGELOG.md``): a trained agent, a tuned record or a
published figure names the dynamics it was made on by the id alone.
"""

from __future__ import annotations

import importlib

from iscc_gym.scenario import SCENARIOS, make_scenario
from iscc_gym.tasks.field import FIELD_ENV_ID
from iscc_gym.tasks.multi import MULTI_ENV_ID
from iscc_gym.tasks.paper import ENV_ID
from iscc_gym.tasks.task import Task, Variant
from iscc_gym.tasks.urban import URBAN_ENV_ID

__all__ = ["Variant", "Task", "TASKS", "TASK_MODULES", "ENV_ID", "URBAN_ENV_ID", "MULTI_ENV_ID", "FIELD_ENV_ID",
           "get_task", "variant_scenario", "registered_scenario", "add_task", "is_fleet"]

#: The task files, in registration order: each defines ``TASK``.
TASK_MODULES = ("paper", "urban", "multi", "field")

#: Every registered env id's task, in registration order.
TASKS: dict[str, Task] = {}


def add_task(task: Task) -> Task:
    """Add ``task`` to :data:`TASKS` (a task file's ``TASK``, or a user's own at run time: ``iscc_gym.register_task``
    registers its env id with Gymnasium too); ``ValueError`` if its env id is another task's.
    """
    if not isinstance(task, Task):
        raise TypeError(f"task must be an iscc_gym.tasks.Task, got {type(task).__name__}")
    if TASKS.get(task.env_id, task) != task:
        raise ValueError(f"env id {task.env_id!r} is another task's already; give the task its own id")
    if task.base is not None:
        SCENARIOS.setdefault(task.preset, task.scenario)  # Task checked it is new or the same scenario
    TASKS[task.env_id] = task
    return task


for _name in TASK_MODULES:
    add_task(importlib.import_module(f"{__name__}.{_name}").TASK)


def get_task(env_id: str) -> Task:
    """The task of ``env_id``; ``ValueError`` naming the registered ids if it is none of them."""
    try:
        return TASKS[env_id]
    except (KeyError, TypeError):
        raise ValueError(f"{env_id!r} is not a registered env id; use one of {', '.join(TASKS)}") from None


def is_fleet(env_id: str) -> bool:
    """Whether ``env_id`` is a registered task whose env flies several drones (:attr:`Task.fleet`)."""
    return env_id in TASKS and TASKS[env_id].fleet


def variant_scenario(env_id: str, name: str, base: str | None = None):
    """The Scenario of variant ``name`` of ``env_id``'s missions (``base``, default the task's preset, with the
    variant's overrides); ``ValueError`` naming the task's variants if it has none of that name.
    """
    task = get_task(env_id)
    if name not in task.variants:
        raise ValueError(f"variant {name!r} is not one of {env_id}'s: {', '.join(task.variants) or 'it has none'}")
    return make_scenario(base or task.preset, **task.variants[name].overrides)


def registered_scenario(env_id: str) -> str:
    """The Scenario preset ``env_id`` is registered with (:data:`iscc_gym.tasks.TASKS`; ``iscc_gym/ISCC-Urban-v0``:
    ``urban``); for an id registered elsewhere, its ``scenario`` keyword or ``paper``.
    """
    if env_id in TASKS:
        return TASKS[env_id].preset
    import gymnasium as gym

    try:
        kwargs = gym.spec(env_id).kwargs or {}
    except gym.error.Error:
        return "paper"
    return str(kwargs.get("scenario", "paper"))
