"""The policy side of each task, written once: what ``python -m eval`` compares on it, against what, and which
agent is shipped for it. Every command reads this table (``python -m eval``, its studies,
``python -m experiments.ship``); the env side (preset, variants, docs page) is :data:`iscc_gym.tasks.TASKS`.

Each :class:`TaskPolicies` is read from its task's file (:mod:`iscc_gym.tasks`: the policy side as strings); a new
task adds nothing here.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from iscc_gym.agents.shipped import agent_dir, multi_agent_dir

from iscc_gym.tasks import TASKS, Task

__all__ = ["TaskPolicies", "TASK_POLICIES", "task_policies", "policies_of", "SHIPPED_AGENTS"]


@dataclass(frozen=True)
class TaskPolicies:
    """What the commands play on one task.

    Parameters
    ----------
    env_id : str
        The task (:data:`iscc_gym.tasks.TASKS`).
    policies : str
        The default comparison of ``python -m eval --env ENV`` (specs of :func:`iscc_gym.agents.make_policy`;
        ``ppo``: the shipped agent).
    reference : str
        The policy every paired difference is taken against: the best per-slot rule the model knows.
    scripted : tuple of str
        The scripted policies a learned agent is compared with in the seeds study.
    focus : str
        The policy whose differences to every other are reported too.
    agent : Path or None
        The shipped agent (``python -m experiments.ship --env ENV``), None where one is shipped per drone count.
    results_section, results_title : str
        The section of ``docs/results.md`` the task's comparison study (``python -m experiments``) writes, and
        its title.
    readme : bool
        Whether that comparison is the README's main table too.
    agent_docs : tuple of str
        ``(results section, title, learning-curve figure)`` that ``python -m experiments.ship --env ENV`` writes.
    """

    env_id: str
    policies: str
    reference: str
    scripted: tuple[str, ...]
    results_section: str
    results_title: str
    focus: str = "ppo"
    agent: Path | None = None
    readme: bool = False
    agent_docs: tuple[str, ...] = ()

    @property
    def task(self) -> Task:
        """The env side of the task."""
        return TASKS[self.env_id]

    @property
    def fleet(self) -> bool:
        """Whether the task's env is the multi-drone one (its comparison: ``iscc_gym.eval.multi``)."""
        return self.task.fleet

    @property
    def ships_agent(self) -> bool:
        """Whether ``python -m experiments.ship`` trains and ships one agent for the task."""
        return self.agent is not None

    def shipped_agent(self, n_drones: int | None = None) -> Path:
        """The shipped agent's folder (on the multi-drone task, the one for ``n_drones`` drones)."""
        if self.agent is not None:
            return self.agent
        if n_drones is None:
            raise ValueError(f"{self.env_id} ships one agent per drone count: give n_drones")
        return multi_agent_dir(n_drones)


def policies_of(task: Task) -> TaskPolicies:
    """The policy side of ``task``, read from its task file (:class:`iscc_gym.tasks.Task`'s strings; the shipped
    agent's folder resolved under the package's trained agents).
    """
    return TaskPolicies(task.env_id, task.policies, task.reference, tuple(task.scripted), task.results_section,
                        task.results_title, focus=task.focus, agent=agent_dir(task.env_id), readme=task.readme,
                        agent_docs=tuple(task.agent_docs))


#: Every task's policies, keyed by env id (each from its task file, :mod:`iscc_gym.tasks`).
TASK_POLICIES: dict[str, TaskPolicies] = {env_id: policies_of(task) for env_id, task in TASKS.items()}
assert set(TASK_POLICIES) == set(TASKS), "every task needs its policies (iscc_gym.agents.tasks)"
#: The shipped agent of each task that ships one (``python -m experiments.ship --env ENV``; ``python -m eval --env
#: ENV``'s ``ppo``).
SHIPPED_AGENTS = {e: t.agent for e, t in TASK_POLICIES.items() if t.ships_agent}


def task_policies(env_id: str) -> TaskPolicies:
    """The policies of ``env_id``'s task; ``ValueError`` naming the tasks if it is none of them."""
    if isinstance(env_id, str) and env_id in TASK_POLICIES:
        return TASK_POLICIES[env_id]
    if isinstance(env_id, str) and env_id in TASKS:  # a task added at run time (iscc_gym.tasks.add_task)
        return policies_of(TASKS[env_id])
    raise ValueError(f"{env_id!r} is not a registered env id; use one of {', '.join(TASKS)}")
