"""The comparison engine: policies x mission variants x seeds on one task, with common random numbers.

Every policy is built for the task's preset (the model its designer knows: a scripted policy's tuned record, an
agent's training env) and plays each variant's missions (the world: the preset with the variant's overrides,
:data:`iscc_gym.tasks.TASKS`), all on the same seeds, so each difference is paired. The runs are played by
:func:`play` (one rollout loop, :func:`iscc_gym.eval.evaluate.run_episodes`, in worker processes or in this one)
and summarised by :func:`iscc_gym.eval.evaluate.summarize` (means, paired differences and their 95 % intervals).
``python -m eval`` is its command line (``--variants``, ``--runs``); the studies (the seeds study, the shifted
missions) are presets over it that only choose the policies, variants and table.

Example::

    from iscc_gym.eval.engine import compare
    res = compare("iscc_gym/ISCC-Urban-v0", ["myopic", "margin"], seeds=range(10000, 10004), max_steps=50,
                  variants=["none", "umi_av"], reference="myopic")
    res["umi_av"]["paired"]["margin_vs_myopic"]["reward_diff_mean"]
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from pathlib import Path

from iscc_gym.agents.tasks import task_policies
from iscc_gym.eval.policies import check_specs, play, policy_name, resolve_specs, world_spec

from iscc_gym.scenario import Scenario, make_scenario
from iscc_gym.tasks import get_task, variant_scenario

__all__ = ["compare", "worlds", "seed_runs", "runs_items"]


def worlds(env_id: str, variants: Sequence[str] | str | None, scenario: str | None = None) -> dict[str, Scenario]:
    """``{variant: the Scenario its missions are played on}``: ``None`` gives the task's own missions (``scenario``,
    default the task's preset, under its name); ``"shifts"`` the task's shifted missions; else variant names of the
    task (``ValueError`` naming them if one is unknown).
    """
    task = get_task(env_id)
    base = scenario or task.preset
    if variants is None:
        return {base: make_scenario(base)}
    names = list(task.shifts) if variants == "shifts" else [v.strip() for v in
                                                            (variants.split(",") if isinstance(variants, str)
                                                             else variants) if v.strip()]
    if not names:
        raise ValueError(f"--variants {variants!r}: name some of {env_id}'s variants "
                         f"({', '.join(task.variants) or 'it has none'}) or 'shifts'")
    return {name: variant_scenario(env_id, name, base) for name in names}


def seed_runs(root: str | Path) -> dict[int, Path]:
    """``{seed: run directory}`` of the ``seed_<s>`` directories under ``root`` holding a model (``python -m train
    --seeds 0,1,2 --out ROOT``); ``FileNotFoundError`` naming the command if there is none.
    """
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"{root} is not a directory; train with `python -m train --seeds 0,1,2 --out {root}`")
    runs = {}
    for p in sorted(root.iterdir()):
        m = re.fullmatch(r"seed_(\d+)", p.name)
        if m and (p / "model.zip").exists():
            runs[int(m.group(1))] = p
    if not runs:
        raise FileNotFoundError(f"no seed_<s>/model.zip under {root}; train with "
                                f"`python -m train --seeds 0,1,2 --out {root}`")
    return dict(sorted(runs.items()))


def runs_items(root: str | Path | dict[int, Path]) -> list[str]:
    """The policy items ``seed_<s>=ROOT/seed_<s>`` of every seed's run under ``root`` (:func:`seed_runs`; or of
    ``root`` itself, a ``{seed: run directory}`` it returned, the folder listed once).
    """
    runs = root if isinstance(root, dict) else seed_runs(root)
    return [f"seed_{s}={p}" for s, p in runs.items()]


def compare(env_id: str, policies: Sequence[str] | str | None = None, seeds: Sequence[int] = (),
            variants: Sequence[str] | str | None = None, scenario: str | None = None,
            reference: str | None = None, focus: str | None = None, max_steps: int | None = None,
            record: int = 0, workers: int = 1, torch_threads: int = 1,
            progress: Callable[[int], None] | None = None, check: bool = True,
            time_left: Callable[[float | None], None] | None = None) -> dict[str, dict]:
    """Play every policy on every variant's missions of task ``env_id`` on ``seeds``; one
    :func:`~iscc_gym.eval.evaluate.summarize` result per variant, keyed by its name (without ``variants``: one
    entry, keyed by the preset's name).

    Parameters
    ----------
    env_id : str
        The task (:data:`iscc_gym.tasks.TASKS`).
    policies : str or sequence of str, optional
        Policy items: specs of :func:`iscc_gym.agents.make_policy`, ``NAME=PATH`` trained agents, ``ppo`` (the
        task's shipped agent). Default: the task's comparison (:data:`iscc_gym.agents.tasks.TASK_POLICIES`).
    seeds : sequence of int
        The missions, the same for every policy and variant (common random numbers).
    variants : sequence of str, "shifts" or None
        Variants of the task's missions (:func:`worlds`); the policies stay built for ``scenario``.
    scenario : str, optional
        The preset the policies are built for and, without variants, played on (default: the task's).
    reference, focus : str, optional
        Paired differences against ``reference`` (default: the task's, if played) and of ``focus`` against every
        other policy (default: the task's, if played).
    max_steps, record : int
        Slots per mission (None: the whole mission); slot-by-slot traces of the first ``record`` missions.
    workers, torch_threads : int
        Processes playing the runs side by side (1: all in this one); torch threads of a learned policy.
    progress : callable, optional
        Called with the slots played since its last call.
    time_left : callable, optional
        Called after ``progress`` with the seconds left (:class:`~iscc_gym.eval.policies.TimeLeft`: each policy's
        own pace), or None before an estimate can be made.
    check : bool
        Check every policy item before any mission is played (:func:`~iscc_gym.eval.policies.check_specs`;
        False where the caller has).
    """
    pol = task_policies(env_id)
    if pol.fleet:
        raise ValueError(f"{env_id}: its comparison is python -m eval --env {env_id} (iscc_gym.eval.multi)")
    specs = policies if isinstance(policies, str) or policies is None else ",".join(policies)
    items = resolve_specs(specs or pol.policies, pol.agent)
    names = [policy_name(it) for it in items]
    reference = reference if reference is not None else (pol.reference if pol.reference in names else None)
    focus = focus if focus is not None else (pol.focus if pol.focus in names else None)
    for flag, name in (("--reference", reference), ("--focus", focus)):
        if name is not None and name not in names:
            raise ValueError(f"{flag} {name!r} is not one of the policies played: {', '.join(names)}")
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise ValueError("seeds is empty; pass at least one mission seed")
    base = scenario or pol.task.preset
    if check:
        check_specs(items, base)
    played = worlds(env_id, variants, base)
    from iscc_gym.eval.evaluate import summarize

    notes = world_notes(items, played, base)
    runs = play(items, seeds, base, worlds=played, max_steps=max_steps, record=record, workers=workers,
                torch_threads=torch_threads, progress=progress, time_left=time_left)
    out = {v: summarize(runs[v], seeds, reference, focus) for v in played}
    for v, lines in notes.items():
        out[v]["notes"] = lines
    return out


def world_notes(items: list[str], played: dict[str, Scenario], base: str) -> dict[str, list[str]]:
    """``{world: notes}``: where a world-designed item (``aware``, ``SPEC@world``) plays a world that is the model
    its plain spec is designed on (the preset's own missions, no hidden world), a note that it plays as that spec
    (issue 43.12: ``aware`` on the paper task played ``myopic`` without a word).
    """
    from iscc_gym.agents.tuned_records import task_of

    model = make_scenario(base)
    out: dict[str, list[str]] = {}
    for w, s in played.items():
        if s != model or task_of(s) == "field":
            continue
        for item in items:
            spec, designed = world_spec(item) if "=" not in item else (item, False)
            if designed:
                out.setdefault(w, []).append(
                    f"{policy_name(item)} is {spec} designed on the world played, and these missions' world is the "
                    f"model {spec} is designed on ({base!r}, no hidden world): it plays as {spec}; play it on a "
                    "variant (--variants) or the field task for a bound")
    return out
