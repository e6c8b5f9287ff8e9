"""The effects a task composes into the slot, decided once per scenario.

The paper's task is the closed loop alone (sense, estimate, command, deliver, fly). A task adds effects to it;
each is a switch of :class:`TaskEffects`, derived from the Scenario's fields here and nowhere else, and each layer
that composes the slot reads the record instead of testing the scenario's fields:

* the compiled slot's constants (:func:`iscc_gym.sim.params.slot_params`: the record's switches, which
  :func:`iscc_gym.sim.loop.step_one` and :mod:`iscc_gym.sim.kernel` test), and the compiled blockage branch
  (:func:`iscc_gym.sim.loop.blocked_switch`);
* the step's layout (:mod:`iscc_gym.sim.schema`: the observation's blocks, the slot's normals);
* the mission's rows (:mod:`iscc_gym.sim.mission`: the channel along the path with blockage, the world with the
  field), the loop state's
  buffer (:func:`iscc_gym.sim.loop.init_state`), and the multi-drone fleet (the paper's task only).

A new effect: a field here (off for the existing presets), its equation in the physics module that owns it, its
call in :func:`iscc_gym.sim.loop.step_one`, its observation block in :data:`iscc_gym.sim.schema.OBS_BLOCKS`.
Plain Python; imports only the Scenario's cache.
"""

from __future__ import annotations

from typing import NamedTuple

from iscc_gym.scenario import Scenario, per_scenario

__all__ = ["TaskEffects", "task_effects"]


class TaskEffects(NamedTuple):
    """The switches of a task's slot (an immutable record; :func:`task_effects`).

    Attributes
    ----------
    blockage : bool
        LoS blockage (:mod:`iscc_gym.physics.blockage`, ``Scenario.blockage`` not ``"none"``): the channel along
        the mission in its rows, the excess loss on the link and twice on the echo, the echo's observation entry.
    queue : bool
        The downlink data queue (:mod:`iscc_gym.physics.queue`, ``queue_deadline_s`` > 0): arrivals served by the
        data share, drops at the deadline, the queue's observation entries and reward term, one more normal a slot.
    queue_deadline_slots : int
        The queue's deadline D in slots (:attr:`iscc_gym.scenario.Scenario.queue_deadline_slots`; 0 without).
    preview_points : int
        Points of the look-ahead in the observation (``preview_slots``; 0 none).
    preview_stride_slots : int
        Slots between the preview's points.
    preview_truth : bool
        The preview reads the realised channel (``preview_source="truth"``, the oracle), not the GBS's map.
    gnss : bool
        GNSS fixes instead of the ISAC measurement (``observation_source="gnss"``).
    open_loop : bool
        The reference acceleration stored on board, no command link (``control_mode="open_loop"``).
    feedforward : bool
        The LQG command adds the reference acceleration (``reference_feedforward``).
    field : bool
        The world the designer's model does not know (the field task: ``rician_k_std_db`` or ``rcs_std_db`` > 0):
        the K-factor along the mission and the drone's RCS in its rows (:mod:`iscc_gym.sim.mission`), read by the
        compiled field branch (:func:`iscc_gym.sim.loop.field_switch`), and the observation's measured block (the
        last slot's fading gain of the command link and echo SNR).
    show_world : bool
        The observation's world block (``show_world``: the hidden values, for the ``aware`` bound).
    """

    blockage: bool
    queue: bool
    queue_deadline_slots: int
    preview_points: int
    preview_stride_slots: int
    preview_truth: bool
    gnss: bool
    open_loop: bool
    feedforward: bool
    field: bool = False
    show_world: bool = False

    @property
    def paper_task(self) -> bool:
        """No effect beyond the paper's closed loop (no blockage, no queue, no preview)."""
        return not (self.blockage or self.queue or self.preview_points or self.field)


@per_scenario
def task_effects(s: Scenario) -> TaskEffects:
    """The :class:`TaskEffects` of a scenario (cached: asked on the env's hot path)."""
    return TaskEffects(blockage=s.blockage != "none", queue=s.queue_deadline_slots > 0,
                       queue_deadline_slots=s.queue_deadline_slots, preview_points=s.preview_slots,
                       preview_stride_slots=s.preview_stride_slots, preview_truth=s.preview_source == "truth",
                       gnss=s.observation_source == "gnss", open_loop=s.control_mode == "open_loop",
                       feedforward=bool(s.reference_feedforward),
                       field=s.rician_k_std_db > 0.0 or s.rcs_std_db > 0.0, show_world=bool(s.show_world))
