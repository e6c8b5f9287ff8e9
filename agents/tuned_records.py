"""Tuning records of the scripted baselines: ``agents/tuned/<name>.yml``, written by ``python -m eval.tune``.

A record holds the tuned values (``params``), the training seeds they were tuned on (disjoint from every
evaluation seed), the objective and the command; the policies read their defaults from it.
"""

from __future__ import annotations

from pathlib import Path

from iscc_gym.agents.shipped import TUNED_DIR

from iscc_gym.files import write_atomic

__all__ = ["TUNED_DIR", "PER_SLOT_RECORD", "load_tuned", "save_tuned", "task_of", "record_task", "task_mismatch",
           "is_params", "record_name"]


#: The tuning record of per-slot SCA's design loss (``python -m eval.tune sca-per-slot``).
PER_SLOT_RECORD = "sca-per-slot"


def task_of(s) -> str:
    """The task a scenario poses: ``"urban"`` with blocked line of sight or a data queue (issue 25), ``"field"``
    with a world the designer's model does not know (a K-factor field or an RCS spread, issue 36), else
    ``"paper"``. The env/scenario checks (:func:`task_mismatch`) compare it; the tuning records read
    :func:`record_task`.
    """
    if s.blockage != "none" or s.queue_deadline_slots > 0:
        return "urban"
    if s.rician_k_std_db > 0.0 or s.rcs_std_db > 0.0:
        return "field"
    return "paper"


def record_task(s) -> str:
    """The task whose tuning records a scenario's baselines read (:func:`record_name`): the urban task's own, else
    the paper's. The field task's baselines are the paper's as designed and tuned there (the world they do not know
    is the task's point; ``adaptive``, the field's own rung, has its own record, ``adaptive``).
    """
    return "urban" if task_of(s) == "urban" else "paper"


def task_mismatch(env_id: str, scenario: str) -> tuple[str, str, str | None, str] | None:
    """Where preset ``scenario`` poses another task (:func:`task_of`) than the preset ``env_id`` is registered with:
    ``(its task, env_id's task, the iscc_gym env id of its task or None, env_id's own preset)``; None where the
    task is the same (a variant such as ``literal`` on ``iscc_gym/ISCC-v0``). An unknown preset raises as
    :func:`iscc_gym.scenario.make_scenario` does.
    """
    from iscc_gym.scenario import make_scenario
    from iscc_gym.tasks import TASKS, registered_scenario

    own = registered_scenario(env_id)
    task, env_task = task_of(make_scenario(scenario)), task_of(make_scenario(own))
    if task == env_task:
        return None
    other = next((e for e, t in TASKS.items() if t.entry_point == TASKS[env_id].entry_point
                  and task_of(make_scenario(t.preset)) == task), None) if env_id in TASKS else None
    return task, env_task, other, own


def is_params(params) -> bool:
    """Whether ``params`` is a tuning record's ``params``: a mapping of names to numbers (not booleans)."""
    return isinstance(params, dict) and all(isinstance(k, str) and isinstance(v, int | float)
                                            and not isinstance(v, bool) for k, v in params.items())


def record_name(policy: str, task: str) -> str:
    """The tuning record of ``policy`` on ``task``: ``<policy>`` on the paper's, ``<policy>-<task>`` on another."""
    return policy if task == "paper" else f"{policy}-{task}"



def load_tuned(name: str, path: str | Path | None = None) -> dict:
    """The tuning record of baseline ``name`` (``agents/tuned/<name>.yml`` unless ``path``).

    Raises
    ------
    FileNotFoundError
        No record: run ``python -m eval.tune <name>`` (``<policy> --scenario <task>`` for ``<policy>-<task>``).
    """
    import yaml

    p = Path(path) if path is not None else TUNED_DIR / f"{name}.yml"
    if not p.exists():
        policy = name[:-len("-urban")] if name.endswith("-urban") else name
        cmd = f"python -m eval.tune {policy}" + (" --scenario urban" if policy != name else "")
        raise FileNotFoundError(f"no tuned parameters for {name!r} at {p}; run `{cmd}`")
    with open(p) as f:
        record = yaml.safe_load(f)
    if not isinstance(record, dict) or "params" not in record:
        raise ValueError(f"{p} is not a tuning record (no 'params' mapping); rerun `python -m eval.tune {name}`")
    return record


def save_tuned(name: str, record: dict, path: str | Path | None = None) -> Path:
    """Write a tuning record atomically (temporary file in the same directory, then rename)."""
    import yaml

    return write_atomic(Path(path) if path is not None else TUNED_DIR / f"{name}.yml",
                        yaml.safe_dump(record, sort_keys=False))
