"""A task's two sides as data: :class:`Task` (its env: preset, entry points, variants, docs page; its policies, as
strings the layers above resolve) and :class:`Variant` (a named variant of its missions). Each task is one file of
this package (:mod:`iscc_gym.tasks`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from iscc_gym.scenario import SCENARIOS, Scenario, make_scenario

__all__ = ["Variant", "Task"]


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
    policies, reference, scripted, focus : str, str, tuple of str, str
        The policy side, as strings the layers above resolve (``iscc_gym.agents.tasks``): the default comparison of
        ``python -m eval --env ENV`` (specs of ``iscc_gym.agents.make_policy``; ``ppo``: the shipped agent), the
        policy every paired difference is taken against, the scripted policies a learned agent is compared with in
        the seeds study, the policy whose differences to every other are reported too.
    results_section, results_title : str
        The section of ``docs/results.md`` the task's comparison study (``python -m experiments``) writes, and
        its title.
    agent : str or None
        The shipped agent's folder under the package's ``agents/trained`` (``python -m experiments.ship --env
        ENV``), None where none ships (or one per drone count: the multi-drone task).
    readme : bool
        Whether the task's comparison is the README's main table too.
    agent_docs : tuple of str
        ``(results section, title, learning-curve figure)`` that ``python -m experiments.ship --env ENV`` writes.
    seeds_docs : tuple of str
        ``(results section, title)`` of the shipped configuration over training seeds (``python -m experiments.seeds
        ROOT --env ENV --write-docs``); empty where the study does not run on the task.
    tuned : tuple of str
        The model-based baselines tuned on this task's missions (``python -m eval.tune <policy> --scenario
        <preset>``: their grids are ``iscc_gym.eval.tune.MODEL_GRIDS``; records ``<policy>-<preset>``, or the
        policy's own name for the field task's ``adaptive``).
    share_of : tuple of str
        The policies whose share of the gap between the reference and the bound (``oracle`` or ``aware``, where the
        comparison plays one) ``python -m eval`` reports, with its interval (default: the shipped agent's).
    base, overrides : str or None, Mapping
        A task on a preset of its own: ``preset`` is then a new name, the Scenario ``base`` (a preset) with
        ``overrides`` (validated here); :func:`iscc_gym.tasks.add_task` adds it to the presets, so every command
        that takes ``--scenario`` takes its name. None (the default): ``preset`` is an existing preset.
    train_like : str
        The env id whose entry of the hyperparameter YAML (``train/hyperparams.yml``) ``python -m train`` trains
        this task with where the file holds none of its own (default: its own env id, which then needs one).
    """

    env_id: str
    preset: str
    entry_point: str
    vector_entry_point: str
    title: str
    docs_page: str
    variants: Mapping[str, Variant] = field(default_factory=dict)
    shifts: tuple[str, ...] = ()
    policies: str = ""
    reference: str = ""
    scripted: tuple[str, ...] = ()
    results_section: str = ""
    results_title: str = ""
    focus: str = "ppo"
    agent: str | None = None
    readme: bool = False
    agent_docs: tuple[str, ...] = ()
    seeds_docs: tuple[str, ...] = ()
    tuned: tuple[str, ...] = ()
    share_of: tuple[str, ...] = ("ppo",)
    base: str | None = None
    overrides: Mapping[str, Any] = field(default_factory=dict)
    train_like: str = ""

    def __post_init__(self):
        if self.base is None and self.overrides:
            raise ValueError(f"task {self.env_id}: overrides need a base preset (base=...) and a new preset name")
        if self.base is not None:
            if self.base not in SCENARIOS:
                raise ValueError(f"task {self.env_id}: base {self.base!r} is not one of {sorted(SCENARIOS)}")
            own = make_scenario(self.base, **self.overrides)  # validated field by field
            if self.preset in SCENARIOS and SCENARIOS[self.preset] != own:
                raise ValueError(f"task {self.env_id}: preset {self.preset!r} is another scenario already; give "
                                 "the task's preset a new name")
        elif self.preset not in SCENARIOS:
            raise ValueError(f"task {self.env_id}: preset {self.preset!r} is not one of {sorted(SCENARIOS)}; or "
                             "give base= and overrides= to define it")
        unknown = [v for v in self.shifts if v not in self.variants]
        if unknown:
            raise ValueError(f"task {self.env_id}: shifts {unknown} are not among its variants {list(self.variants)}")
        object.__setattr__(self, "variants", MappingProxyType(dict(self.variants)))
        object.__setattr__(self, "overrides", MappingProxyType(dict(self.overrides)))

    @property
    def scenario(self) -> Scenario:
        """The task's Scenario: its preset, or ``base`` with ``overrides``."""
        return make_scenario(self.base, **self.overrides) if self.base is not None else SCENARIOS[self.preset]

    @property
    def max_episode_steps(self) -> int:
        """The registered TimeLimit: the preset's whole mission."""
        return self.scenario.n_slots

    @property
    def hyperparams_key(self) -> str:
        """The env id of the YAML entry the task trains with where the file has none of its own."""
        return self.train_like or self.env_id

    @property
    def fleet(self) -> bool:
        """Whether the task's env is the multi-drone one (its comparison: ``iscc_gym.eval.multi``)."""
        return self.entry_point.endswith(":ISCCMultiEnv")

    @property
    def kwargs(self) -> dict:
        """The keywords the env id is registered with (the preset, where it is not the env's default)."""
        return {} if self.preset == "paper" else {"scenario": self.preset}

    def shift_overrides(self) -> dict[str, dict[str, Any]]:
        """``{name: overrides}`` of :attr:`shifts` (without the preset itself)."""
        return {name: dict(self.variants[name].overrides) for name in self.shifts if name != "none"}
