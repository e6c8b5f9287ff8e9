"""The policy side of each task, written once: what ``python -m eval`` compares on it, against what, and which
agent is shipped for it. Every command reads this table (``python -m eval``, its studies,
``python -m experiments.ship``); the env side (preset, variants, docs page) is :data:`iscc_gym.tasks.TASKS`.

A new task adds one :class:`TaskPolicies` here beside its :class:`iscc_gym.tasks.Task`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from iscc_gym.agents.shipped import FIELD_AGENT, PPO_AGENT, URBAN_AGENT, multi_agent_dir

from iscc_gym.tasks import ENV_ID, FIELD_ENV_ID, MULTI_ENV_ID, TASKS, URBAN_ENV_ID, Task

__all__ = ["TaskPolicies", "TASK_POLICIES", "task_policies", "SHIPPED_AGENTS"]


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
        The section of ``docs/results.md`` ``python -m eval --env ENV --write-docs`` writes, and its title.
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
        return self.task.entry_point.endswith(":ISCCMultiEnv")

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


#: Every task's policies, keyed by env id.
TASK_POLICIES: dict[str, TaskPolicies] = {
    ENV_ID: TaskPolicies(ENV_ID, "ppo,sca,sca-per-slot,margin,myopic,equal", "sca", ("sca", "margin", "myopic"),
                         "comparison", "Learned vs scripted allocation", agent=PPO_AGENT, readme=True,
                         agent_docs=("agent", "The shipped PPO agent", "ppo_learning_curve.png")),
    # the urban task: the shipped agent, the per-slot rules, the queue's drift-plus-penalty, the look-ahead planner
    # and its oracle bound; myopic, the model's per-slot optimum, is the reference (mpc is within noise of it)
    URBAN_ENV_ID: TaskPolicies(URBAN_ENV_ID, "ppo,myopic,margin,dpp,mpc,oracle", "myopic",
                               ("myopic", "margin", "dpp", "mpc"), "urban-comparison",
                               "The urban task: the learned agent, look-ahead and per-slot policies",
                               agent=URBAN_AGENT, agent_docs=("urban-agent", "The shipped PPO agent of the urban task",
                                                              "ppo_urban_learning_curve.png")),
    MULTI_ENV_ID: TaskPolicies(MULTI_ENV_ID, "equal-sca,joint-sca,margin,margin-starved", "joint-sca",
                               ("equal-sca", "joint-sca", "margin"), "multi", "Many drones, one base station",
                               focus="agent"),
    # the field task: the shipped agent (a residual on adaptive), the designer's per-slot policies on the paper's
    # model, the adaptive rung that re-estimates the world, and the model-knowledge bound (aware: myopic shown the
    # world's hidden values); every difference against myopic, the agent's against every rung
    FIELD_ENV_ID: TaskPolicies(FIELD_ENV_ID, "ppo,myopic,margin,sca,adaptive,aware", "myopic",
                               ("myopic", "margin", "sca", "adaptive"), "field-comparison",
                               "The field task: the agent and the baseline ladder where the world is not the model",
                               agent=FIELD_AGENT, agent_docs=("field-agent", "The shipped PPO agent of the field task",
                                                              "ppo_field_learning_curve.png")),
}
assert set(TASK_POLICIES) == set(TASKS), "every task needs its policies (iscc_gym.agents.tasks)"
#: The shipped agent of each task that ships one (``python -m experiments.ship --env ENV``; ``python -m eval --env
#: ENV``'s ``ppo``).
SHIPPED_AGENTS = {e: t.agent for e, t in TASK_POLICIES.items() if t.ships_agent}


def task_policies(env_id: str) -> TaskPolicies:
    """The policies of ``env_id``'s task; ``ValueError`` naming the tasks if it is none of them."""
    try:
        return TASK_POLICIES[env_id]
    except (KeyError, TypeError):
        raise ValueError(f"{env_id!r} is not a registered env id; use one of {', '.join(TASK_POLICIES)}") from None
