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
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from iscc_gym.agents.tasks import task_policies
from iscc_gym.eval.policies import check_specs, play, policy_name, resolve_specs, world_spec

from iscc_gym.scenario import Scenario, make_scenario
from iscc_gym.tasks import TASKS, get_task, variant_scenario

__all__ = ["compare", "evaluate", "worlds", "seed_runs", "runs_items", "fleet_entries", "load_fleet_agent"]


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
            time_left: Callable[[float | None], None] | None = None, n_drones: int | None = None,
            retune: Mapping[str, Any] | None = None, tune_seeds: Sequence[int] = (),
            trace_info: Sequence[str] = ()) -> dict[str, dict]:
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
    retune : mapping, optional
        ``{item: grid}``: a model-based item (``myopic``, ``dpp``, ``mpc``, ``adaptive``, with or without ``@world``)
        tuned on each variant before it plays there: every point of ``grid`` (``{parameter: values}``, or a callable
        of the variant's Scenario returning one) on ``tune_seeds`` of the variant's missions
        (:func:`iscc_gym.eval.tune.tune_model_grid`; training seeds, never ``seeds``); ``{item: other item}`` plays
        the other's tuned parameters (``oracle@world`` with ``mpc@world``'s).
    tune_seeds : sequence of int
        The tuning missions of ``retune`` (seeds outside the evaluation ranges).
    trace_info : sequence of str
        Info keys traced slot by slot for the first ``record`` missions (a figure's).
    n_drones : int, optional
        The fleet task's drones (default :data:`iscc_gym.sim.fleet.N_DRONES`): its policies are the baselines of
        :mod:`iscc_gym.agents.multi` and agents for that many drones (:func:`fleet_entries`), played in this
        process on the preset's missions (no variants); the other tasks take none.
    """
    pol = task_policies(env_id)
    specs = policies if isinstance(policies, str) or policies is None else ",".join(policies)
    if pol.fleet:
        return {scenario or pol.task.preset: _fleet(pol, specs, seeds, variants, scenario, reference, focus,
                                                    max_steps, record, progress, n_drones)}
    if n_drones is not None:
        raise ValueError(f"n_drones = {n_drones}: {env_id} flies one drone; the fleet task is "
                         + ", ".join(e for e, t in TASKS.items() if t.fleet))
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
    tuned = retuned(items, played, retune, tune_seeds, max_steps) if retune else None
    runs = play(items, seeds, base, worlds=played, max_steps=max_steps, record=record, workers=workers,
                torch_threads=torch_threads, progress=progress, time_left=time_left, tuned=tuned,
                trace_info=trace_info)
    out = {v: summarize(runs[v], seeds, reference, focus) for v in played}
    for v, lines in notes.items():
        out[v]["notes"] = lines
    for (v, it), params in (tuned or {}).items():
        out[v].setdefault("tuned", {})[policy_name(it)] = params
    return out


def _fleet(pol, specs, seeds, variants, scenario, reference, focus, max_steps, record, progress, n_drones) -> dict:
    """:func:`compare` on the fleet task: its entries for ``n_drones`` drones, played by :func:`evaluate`."""
    from iscc_gym.sim.fleet import N_DRONES

    if variants is not None:
        raise ValueError(f"variants = {variants!r}: the fleet task's comparison plays its preset's missions")
    items = [p.strip() for p in (specs or pol.policies).split(",") if p.strip()]
    entries = fleet_entries(items, N_DRONES if n_drones is None else n_drones, scenario or pol.task.preset,
                            pol.task.env_id)
    names = list(entries)
    reference = reference if reference is not None else (pol.reference if pol.reference in names else None)
    focus = focus if focus is not None else (pol.focus if pol.focus in names else None)
    if not seeds:
        raise ValueError("seeds is empty; pass at least one mission seed")
    return evaluate(entries, [int(s) for s in seeds], scenario or pol.task.preset, reference=reference,
                    max_steps=max_steps, record=record, focus=focus, progress=progress)


def evaluate(policies: Mapping[str, Any], seeds: Sequence[int], scenario: str | Scenario = "paper",
             reference: str | None = None, max_steps: int | None = None, record: int = 0,
             focus: str | None = None, progress: Callable[[int], None] | None = None,
             done: Callable[[str], None] | None = None) -> dict:
    """Evaluate every policy (or :class:`~iscc_gym.eval.evaluate.Entry`: a policy and its scheme's Scenario
    overrides) on the same seeds, one rollout loop (:func:`~iscc_gym.eval.evaluate.run_episodes`); paired
    differences vs ``reference`` (:func:`~iscc_gym.eval.evaluate.summarize`).

    Returns a JSON-able dict: ``policies.<name>`` with ``<metric>_mean``, ``<metric>_ci95`` per
    metric of :data:`~iscc_gym.eval.evaluate.EPISODE_METRICS` (``reward_mean``, ``reward_ci95``, ...), ``episodes`` (the
    per-episode values) and ``wall_time_s``; ``paired.<name>_vs_<reference>`` with
    ``<metric>_diff_mean`` and ``<metric>_diff_ci95`` (name minus reference, per episode). Every
    interval is clamped to its metric's range (:data:`~iscc_gym.eval.evaluate.METRIC_RANGES`). ``progress(n)``: as
    in :func:`~iscc_gym.eval.evaluate.run_episodes`, for every policy in turn; ``done(name)`` after each policy.
    """
    from .evaluate import Entry, run_episodes, summarize

    if not policies:
        raise ValueError("policies is empty; pass at least one policy")
    if reference is not None and reference not in policies:
        raise ValueError(f"reference = {reference!r} is not one of the policies {list(policies)}")
    runs = {}
    for name, entry in policies.items():
        entry = entry if isinstance(entry, Entry) else Entry(entry)
        runs[name] = run_episodes(entry.policy, seeds, scenario, max_steps, record, progress=progress,
                                  **entry.overrides)
        if done is not None:
            done(name)
    return summarize(runs, seeds, reference, focus)


def fleet_entries(items: Sequence[str], n_drones: int, scenario: str = "paper", env_id: str | None = None) -> dict:
    """``{name: Entry}`` of the fleet task's policy items for ``n_drones`` drones: ``NAME=PATH`` a trained agent
    (its observation shape checked against the K-drone env's), a bare ``ppo`` the shipped agent for K
    (:func:`iscc_gym.agents.tasks.TaskPolicies.shipped_agent`), anything else a baseline of
    :func:`iscc_gym.agents.multi.make_multi_policy`. ``env_id``: the fleet task (default: the registered one).
    """
    from iscc_gym.agents.multi import MULTI_POLICY_SPECS, make_multi_policy

    from iscc_gym.sim.fleet import check_n_drones, drone_scenario

    from .evaluate import Entry

    k = check_n_drones(n_drones)
    s = drone_scenario(make_scenario(scenario), k)
    entries = {}
    for item in items:
        if item == "ppo":
            fleet = env_id or next(e for e, t in TASKS.items() if t.fleet)
            item = f"ppo={task_policies(fleet).shipped_agent(k)}"
        if "=" in item:
            name, path = item.split("=", 1)
            entries[name] = Entry(load_fleet_agent(path, k), {"n_drones": k})
        elif item in MULTI_POLICY_SPECS:
            entries[item] = Entry(make_multi_policy(item, s, k), {"n_drones": k})
        else:
            raise ValueError(f"policy {item!r}: use NAME=PATH (a trained agent), ppo or one of "
                             f"{', '.join(MULTI_POLICY_SPECS)}")
    return entries


def load_fleet_agent(path, n_drones: int):
    """A trained agent of the fleet task for ``n_drones`` drones; ``ValueError`` if it takes another shape."""
    from iscc_gym.agents.sb3_policy import SB3Policy

    from iscc_gym.sim.schema import N_OBS

    pol = SB3Policy.load(path, check_env=None)
    if pol.obs_shape != (n_drones * N_OBS,):
        raise ValueError(f"--agent {path}: the model takes observations of shape {pol.obs_shape}; the env with "
                         f"{n_drones} drones gives ({n_drones * N_OBS},): train it with --env-set n_drones={n_drones}")
    return pol


def retuned(items: Sequence[str], played: dict[str, Scenario], retune: Mapping[str, Any],
            tune_seeds: Sequence[int], max_steps: int | None = None) -> dict[tuple[str, str], dict]:
    """``{(variant, item): params}``: each item of ``retune`` tuned on each variant's world (:func:`compare`'s
    ``retune``), on ``tune_seeds``; ``ValueError`` for an item that is not played, a grid of a policy no grid tunes,
    or no tuning seeds.
    """
    from iscc_gym.eval.tune import MODEL_GRIDS, tune_model_grid

    unknown = [it for it in retune if it not in items]
    if unknown:
        raise ValueError(f"retune: {unknown} are not among the policies played ({', '.join(items)})")
    if not list(tune_seeds):
        raise ValueError("retune needs tune_seeds: the training missions each variant's tuning plays")
    out: dict[tuple[str, str], dict] = {}
    grids = {it: g for it, g in retune.items() if not isinstance(g, str)}
    for it in grids:
        if world_spec(it)[0] not in MODEL_GRIDS:
            raise ValueError(f"retune: {it!r} is not tuned on a grid; use one of {', '.join(MODEL_GRIDS)}")
    for v, world in played.items():
        for it, grid in grids.items():
            g = grid(world) if callable(grid) else grid
            out[v, it] = tune_model_grid(world_spec(it)[0], list(tune_seeds), world, log=lambda *_: None,
                                         max_steps=max_steps, grid=g)["params"]
        for it, source in retune.items():
            if isinstance(source, str):
                if source not in grids:
                    raise ValueError(f"retune: {it!r} takes {source!r}'s parameters, which is not tuned here")
                out[v, it] = out[v, source]
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
