"""Where the shipped agents and tuning records live (package data of ``iscc_gym.agents``), written once.

``agents/trained/ppo_iscc`` (:data:`PPO_AGENT`, ``python -m experiments.ship``), ``agents/trained/ppo_urban``
(:data:`URBAN_AGENT`, ``python -m experiments.ship --env iscc_gym/ISCC-Urban-v0``), ``agents/trained/ppo_field``
(:data:`FIELD_AGENT`, ``python -m experiments.ship --env iscc_gym/ISCC-Field-v0``; which agent each task ships:
:data:`iscc_gym.agents.tasks.TASK_POLICIES`), ``agents/trained/multi/k<K>``
(:func:`multi_agent_dir`, ``python -m experiments.multi_agents``), ``agents/trained/pareto/<family>/<label>``
(:data:`PARETO_DIR`, ``python -m experiments.pareto_agents``) and ``agents/tuned/<name>.yml`` (:data:`TUNED_DIR`,
``python -m eval.tune``).
"""

from __future__ import annotations

from pathlib import Path

from iscc_gym.tasks import ENV_ID, FIELD_ENV_ID, TASKS, URBAN_ENV_ID

__all__ = ["TRAINED_DIR", "PPO_AGENT", "URBAN_AGENT", "FIELD_AGENT", "MULTI_DIR", "PARETO_DIR", "TUNED_DIR",
           "agent_dir", "multi_agent_dir"]

#: The folder of the trained agents.
TRAINED_DIR = Path(__file__).resolve().parent / "trained"


def agent_dir(env_id: str) -> Path | None:
    """The shipped agent's folder of task ``env_id`` (the folder its task file names), None where none ships."""
    folder = TASKS[env_id].agent
    return None if folder is None else TRAINED_DIR / folder


#: The trained PPO agent of ``iscc_gym/ISCC-v0`` (``python -m eval``'s ``ppo``; the folder its task file names).
PPO_AGENT = agent_dir(ENV_ID)
#: The trained PPO agent of ``iscc_gym/ISCC-Urban-v0`` (``python -m eval --env iscc_gym/ISCC-Urban-v0``'s ``ppo``).
URBAN_AGENT = agent_dir(URBAN_ENV_ID)
#: The trained agent of ``iscc_gym/ISCC-Field-v0``: a residual on ``bayes``, trained with its critic shown the world
#: and the expected reward (``python -m eval --env iscc_gym/ISCC-Field-v0``'s ``ppo``).
FIELD_AGENT = agent_dir(FIELD_ENV_ID)
#: The multi-drone agents, one folder per drone count (``k4``, ``k4_lag``, ...).
MULTI_DIR = TRAINED_DIR / "multi"
#: The Pareto study's learned operating points, ``<family>/<label>``.
PARETO_DIR = TRAINED_DIR / "pareto"
#: The scripted baselines' tuning records.
TUNED_DIR = Path(__file__).resolve().parent / "tuned"


def multi_agent_dir(n_drones: int) -> Path:
    """Where ``python -m experiments.multi_agents`` ships the agent for ``n_drones`` drones."""
    return MULTI_DIR / f"k{int(n_drones)}"
