"""The tasks: each registered env id's settings, written once.

A task is a registered env id over a Scenario preset: its entry points, its mission length (the preset's
``n_slots``: the registered ``max_episode_steps``), the named variants of its missions that the studies play
(shifted missions, levers) and its page on the documentation site. ``iscc_gym/__init__`` registers every entry of
:data:`TASKS`; the commands read the policy side of a task (default and reference policies, the shipped agent) from
``iscc_gym.agents.tasks``, one table above the core. A new task is one entry here plus its physics (the preset's
Scenario fields), and one entry there.

An env id's version ``-vN`` rises when its dynamics change (``CHANGELOG.md``): a trained agent, a tuned record or a
published figure names the dynamics it was made on by the id alone.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from iscc_gym.scenario import SCENARIOS, make_scenario

__all__ = ["Variant", "Task", "TASKS", "ENV_ID", "URBAN_ENV_ID", "MULTI_ENV_ID", "FIELD_ENV_ID", "get_task",
           "variant_scenario", "registered_scenario"]

#: The registered id of the paper's task.
ENV_ID = "iscc_gym/ISCC-v0"
#: The urban task (issue 25): the ``urban`` preset, a 1,200-slot mission.
URBAN_ENV_ID = "iscc_gym/ISCC-Urban-v0"
#: Many drones sharing one band (issue 19).
MULTI_ENV_ID = "iscc_gym/ISCC-Multi-v0"
#: The field task (issue 36): the paper's loop in a world its designer's model does not know.
FIELD_ENV_ID = "iscc_gym/ISCC-Field-v0"


@dataclass(frozen=True)
class Variant:
    """A named variant of a task's missions: Scenario overrides of the task's preset and why the values are
    physical (each within the range its source states).
    """

    overrides: Mapping[str, Any]
    why: str

    def __post_init__(self):
        object.__setattr__(self, "overrides", MappingProxyType(dict(self.overrides)))


@dataclass(frozen=True)
class Task:
    """One registered env id.

    Parameters
    ----------
    env_id : str
        The id ``gymnasium.make`` takes.
    preset : str
        The Scenario preset (:data:`iscc_gym.scenario.SCENARIOS`) its env plays; its ``n_slots`` is the
        registered ``max_episode_steps``.
    entry_point, vector_entry_point : str
        The env class and its native vector env, ``module:Class``.
    title : str
        One line naming the task (docs, ``--help``).
    docs_page : str
        Its page on the documentation site (``docs/site/...``).
    variants : Mapping[str, Variant]
        Named variants of its missions (shifted missions, levers), played by the studies.
    shifts : tuple of str
        The variants that ``python -m train --randomize <task>-shifts`` trains over and the shifted-mission
        study plays (missions drawn with other statistics than the preset's; ``"none"`` is the preset).
    """

    env_id: str
    preset: str
    entry_point: str
    vector_entry_point: str
    title: str
    docs_page: str
    variants: Mapping[str, Variant] = field(default_factory=dict)
    shifts: tuple[str, ...] = ()

    def __post_init__(self):
        if self.preset not in SCENARIOS:
            raise ValueError(f"task {self.env_id}: preset {self.preset!r} is not one of {sorted(SCENARIOS)}")
        unknown = [v for v in self.shifts if v not in self.variants]
        if unknown:
            raise ValueError(f"task {self.env_id}: shifts {unknown} are not among its variants {list(self.variants)}")
        object.__setattr__(self, "variants", MappingProxyType(dict(self.variants)))

    @property
    def max_episode_steps(self) -> int:
        """The registered TimeLimit: the preset's whole mission."""
        return SCENARIOS[self.preset].n_slots

    @property
    def kwargs(self) -> dict:
        """The keywords the env id is registered with (the preset, where it is not the env's default)."""
        return {} if self.preset == "paper" else {"scenario": self.preset}

    def shift_overrides(self) -> dict[str, dict[str, Any]]:
        """``{name: overrides}`` of :attr:`shifts` (without the preset itself)."""
        return {name: dict(self.variants[name].overrides) for name in self.shifts if name != "none"}


_MAP_ERROR = {"map_error_std": 0.8}

#: The urban task's variants: the shifted missions (``none`` .. ``map error 0.8``) and the levers of
#: ``experiments/urban_levers.py`` (``urban`` .. ``umi_av``: a change of the blockage statistics, the data's deadline,
#: rate or weight, the map's error).
URBAN_VARIANTS: dict[str, Variant] = {
    "none": Variant({}, "the preset's missions (UMa-AV, 30-60 m, 5 Mbit/s within 1 s, map error 0.4)"),
    "umi_av": Variant({"blockage": "umi_av"}, "TR 36.777 UMi-AV instead of UMa-AV: more of the path blocked"),
    "altitude 60-100 m": Variant({"altitude_min_m": 60.0, "altitude_max_m": 100.0},
                                 "higher flights (UMa-AV's LoS probability rises with height)"),
    "10 Mbit/s within 2 s": Variant({"queue_arrival_bps": 10e6, "queue_deadline_s": 2.0},
                                    "twice the data, twice the deadline"),
    "map error 0.8": Variant(_MAP_ERROR, "the channel map's error doubled"),
    "urban": Variant({}, "the preset (TR 38.901's exponential LoS field, 1 s deadline, 5 Mbit/s, w_rate 1)"),
    "smooth": Variant({"los_field_kernel": "gaussian"},
                      "smooth LoS field, the same 50 m correlation distance: building-scale blocked stretches"),
    "smooth w_rate=5": Variant({"los_field_kernel": "gaussian", "w_rate": 5.0},
                               "a dropped slot of data costs 5 m-slots of tracking error"),
    "smooth deadline=3s": Variant({"los_field_kernel": "gaussian", "queue_deadline_s": 3.0},
                                  "a buffered video stream's latency budget"),
    "smooth 15Mbps": Variant({"los_field_kernel": "gaussian", "queue_arrival_bps": 15e6}, "a 4K video downlink"),
    "w_rate=5": Variant({"w_rate": 5.0}, "the preset, data worth 5x"),
    "map_error=0.8": Variant(_MAP_ERROR, "a coarse map (correlation 0.6 with the truth)"),
    "smooth 40Mbps deadline=5s": Variant(
        {"los_field_kernel": "gaussian", "queue_arrival_bps": 40e6, "queue_deadline_s": 5.0},
        "data scarce while the link is clear (about 3/4 of a clear link's capacity), a 5 s buffer"),
    "calm smooth 20Mbps deadline=3s": Variant(
        {"process_noise_pos": 0.005, "process_noise_vel": 0.05, "los_field_kernel": "gaussian",
         "queue_arrival_bps": 20e6, "queue_deadline_s": 3.0},
        "light wind: process noise 5 mm and 0.05 m/s per slot (the diagonal of a white-noise acceleration model, "
        "0.5-1 m/s^2), so that tracking depends on sensing while the link is clear; the paper's R_min 20 Mbit/s, a "
        "3 s buffer"),
}

#: Worlds that differ from the paper's model, which every scripted policy of the paper task is designed on (issue 36:
#: where learned allocation can earn its place): a constant offset each, the probe's starting point. ``python -m eval
#: --policies myopic,aware --variants ...`` plays ``myopic`` designed on the paper's model against ``aware``, ``myopic``
#: designed on the world (the model-knowledge bound).
PAPER_VARIANTS: dict[str, Variant] = {
    "rcs -10 dB": Variant({"rcs_m2": 0.001}, "the drone's radar cross section 10 dB below Table I's 0.01 m^2"),
    "rcs +10 dB": Variant({"rcs_m2": 0.1}, "the drone's radar cross section 10 dB above Table I's 0.01 m^2"),
    "noise x3": Variant({"process_noise_pos": 0.6, "process_noise_vel": 0.006},
                        "Table I's process noise tripled (a gustier flight)"),
    "noise x1/4": Variant({"process_noise_pos": 0.05, "process_noise_vel": 0.0005},
                          "Table I's process noise quartered (a calm flight)"),
    "link -6 dB": Variant({"comm_snr_offset_db": -10.2}, "the command and data link 6 dB below the calibrated budget "
                                                          "(antenna pattern, misalignment)"),
}

#: The field task's worlds outside the ranges its preset draws from (the out-of-range table: every policy left as
#: designed, tuned or trained on the preset).
FIELD_VARIANTS: dict[str, Variant] = {
    "K spread 8 dB": Variant({"rician_k_std_db": 8.0}, "the K-factor's spread 8 dB, beyond TR 38.901's largest "
                                                         "LoS sigma_K (5 dB, UMi)"),
    "K mean 4 dB": Variant({"rician_k_db": 4.0}, "the K-factor's mean 5 dB below the model's 9 dB (more scattering "
                                                 "than TR 38.901's LoS means, 7-9 dB)"),
    "RCS spread 6 dB": Variant({"rcs_std_db": 6.0}, "the RCS's spread 6 dB, beyond Rel-19's 3.74 dB of a small UAV"),
}

#: Every registered env id's task, in registration order.
TASKS: dict[str, Task] = {
    ENV_ID: Task(ENV_ID, "paper", "iscc_gym.envs.env:ISCCEnv", "iscc_gym.envs.vector:ISCCVectorEnv",
                 "the paper's closed loop: one drone, Rician LoS link, 500 s mission", "tasks/paper", PAPER_VARIANTS),
    URBAN_ENV_ID: Task(URBAN_ENV_ID, "urban", "iscc_gym.envs.env:ISCCEnv", "iscc_gym.envs.vector:ISCCVectorEnv",
                       "a low-altitude urban flight: blocked line of sight, a map preview, a data queue with a "
                       "deadline", "tasks/urban", URBAN_VARIANTS,
                       shifts=("none", "umi_av", "altitude 60-100 m", "10 Mbit/s within 2 s", "map error 0.8")),
    MULTI_ENV_ID: Task(MULTI_ENV_ID, "paper", "iscc_gym.envs.multi:ISCCMultiEnv",
                       "iscc_gym.envs.vector:ISCCMultiVectorEnv",
                       "K drones sharing one base station's band, the paper's loop each", "tasks/multi"),
    FIELD_ENV_ID: Task(FIELD_ENV_ID, "field", "iscc_gym.envs.env:ISCCEnv", "iscc_gym.envs.vector:ISCCVectorEnv",
                       "the paper's loop in a world its model does not know: the links' K-factor a field along the "
                       "path, the drone's RCS drawn per mission", "tasks/field", FIELD_VARIANTS),
}


def get_task(env_id: str) -> Task:
    """The task of ``env_id``; ``ValueError`` naming the registered ids if it is none of them."""
    try:
        return TASKS[env_id]
    except (KeyError, TypeError):
        raise ValueError(f"{env_id!r} is not a registered env id; use one of {', '.join(TASKS)}") from None


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
