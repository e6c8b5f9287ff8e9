"""Policies of ``python -m eval`` from their specs, and playing them in worker processes.

Lives apart from ``eval/__main__.py`` so that spawned worker processes can import what they run.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

from iscc_gym.agents.shipped import PPO_AGENT

from iscc_gym.scenario import make_scenario

# the rollout loop and the compiled physics (eval.evaluate, iscc_gym.sim) are imported where a policy is built or
# played, so that the specs are checked before they load (issue 43.12)

__all__ = ["build_policy", "build_policies", "play", "run_parallel", "world_spec", "WORLD_SUFFIX", "resolve_specs",
           "check_specs", "policy_name",
           "SLOW_SPECS", "SHIPPED_AGENT"]

#: The trained PPO agent shipped with the package (``agents/trained/ppo_iscc``; produced by
#: ``python -m experiments.ship``).
SHIPPED_AGENT = PPO_AGENT

#: Specs whose policy is expensive to build (a solve or tables): known valid, so not built to check them.
_KNOWN_SPECS = ("sca", "sca-per-slot", "sca-ignore-loss", "grid", "evolutionary", "myopic")


#: What a trained agent of another env's observations is told to do (``python -m eval`` has ``--env``).
ENV_FIX = "compare it with --env set to the env it was trained on"


#: A scripted spec ending in this is designed on the world its missions are played on (the true parameters of
#: a variant, :func:`iscc_gym.eval.engine.compare`), not on the task's preset: the model-knowledge bound.
WORLD_SUFFIX = "@world"
#: Aliases of world-designed specs: ``aware`` is ``myopic`` given the world's true parameters (issue 36).
WORLD_ALIASES = {"aware": "myopic" + WORLD_SUFFIX}
#: The specs that read a field world's slot values (K, RCS) from the observation when designed on it (``show_world``);
#: every other ``SPEC@world`` on a field world is designed on the world's law (its Scenario: the variant's mean K
#: and RCS, their spreads), the observation the task's own (issue 43.7: ``sca@world`` was built for the shown
#: world's observation and failed mid-run on the env's).
WORLD_READERS = ("myopic",)


def world_spec(item: str) -> tuple[str, bool]:
    """``(spec, designed on the world)`` of a scripted item: ``myopic@world`` and ``aware`` give ``("myopic",
    True)``, ``myopic`` gives ``("myopic", False)``.
    """
    item = WORLD_ALIASES.get(item.strip().lower(), item)
    if item.endswith(WORLD_SUFFIX):
        return item[:-len(WORLD_SUFFIX)], True
    return item, False


def build_policy(item: str, scenario: str = "paper", fix: str = ENV_FIX, world=None, tuned: dict | None = None):
    """``(name, policy)`` of one ``NAME=PATH`` (a trained agent) or :func:`agents.make_policy` spec; ``fix`` ends
    the error for an agent of another env's observations (the option of the calling command that fixes it).
    A spec ending in ``@world`` (or ``aware``) is built on ``world`` (the Scenario the missions are played on;
    default ``scenario``) instead of ``scenario``: the designer knows the world. On a field world, a spec of
    :data:`WORLD_READERS` is shown the slot's world too; the others are designed on the world's law. ``tuned``: the
    parameters a model-based spec plays instead of its record's (``make_policy``'s; the engine's ``retune``).
    """
    from iscc_gym.agents import make_policy

    from iscc_gym.sim.effects import task_effects
    from iscc_gym.sim.schema import obs_size

    if "=" in item:
        name, path = item.split("=", 1)
        from iscc_gym.agents.sb3_policy import SB3Policy

        policy = SB3Policy.load(path, check_env=None)
        want = (obs_size(make_scenario(scenario)),)  # the env the comparison runs, not always the paper's
        if policy.obs_shape != want:
            raise ValueError(f"--policies {item!r}: the model takes observations of shape {policy.obs_shape}, the "
                             f"{scenario if isinstance(scenario, str) else 'given'} scenario's env gives {want}: it "
                             f"was trained on another env; {fix}")
        return name, policy
    spec, designed = world_spec(item)
    if designed and world is not None:
        w = make_scenario(world) if isinstance(world, str) else world
        if task_effects(w).field and spec.strip().lower() in WORLD_READERS:
            w = w.replace(show_world=True)  # a world that changes along the mission: the env shows it the slot's values
        return item, make_policy(spec, w, tuned=tuned)
    return item, make_policy(spec, scenario, tuned=tuned)


def build_policies(specs: str, scenario: str = "paper") -> dict:
    """``{name: policy}`` from a comma-separated list of ``NAME=PATH`` or make_policy specs."""
    return dict(build_policy(item, scenario) for item in resolve_specs(specs))


def policy_name(item: str) -> str:
    """The name a policy item is reported under: ``NAME`` of ``NAME=PATH``, else the spec itself."""
    return item.split("=", 1)[0] if "=" in item else item


def resolve_specs(specs: str, agent: Path | None = SHIPPED_AGENT) -> list[str]:
    """The items of a ``--policies`` value: a bare ``ppo`` becomes the shipped ``agent`` (``ppo=`` its path;
    by default the paper env's, :data:`iscc_gym.agents.tasks.TASK_POLICIES` holds each task's; None: the task ships
    none); ``ValueError`` if it is empty, names a policy twice (results are keyed by name) or a bare ``ppo`` where
    no agent ships.
    """
    items = [p.strip() for p in split_specs(specs) if p.strip()]
    if not items:
        raise ValueError("--policies is empty; e.g. --policies ppo,sca,equal")
    if agent is None and any(item.lower() == "ppo" for item in items):
        raise ValueError(f"--policies {specs!r}: this task ships no agent; name a trained one, ppo=RUN_DIR")
    items = [f"ppo={agent}" if item.lower() == "ppo" else item for item in items]
    names = [policy_name(item) for item in items]
    for item, name in zip(items, names, strict=True):
        if not name:
            raise ValueError(f"--policies {item!r}: give the policy a name, NAME=PATH (e.g. ppo=runs/ppo)")
    dup = [n for n in dict.fromkeys(names) if names.count(n) > 1]
    if dup:
        raise ValueError(f"--policies names {dup[0]!r} twice; every policy needs its own name (NAME=PATH for "
                         "trained agents, e.g. ppo=runs/a,ppo2=runs/b)")
    return items




#: What ``--policies`` takes besides :data:`iscc_gym.agents.POLICY_SPECS`, as its help and errors name them.
COMMAND_SPECS = ("ppo (the task's shipped agent)", "NAME=PATH (a trained agent)",
                 "aware (myopic designed on the world played)", "SPEC@world (SPEC designed on the world played)")


def check_spec_name(item: str) -> None:
    """``ValueError`` for a scripted item whose name is no policy's (issue 43.12: the message named neither ``aware``,
    ``ppo`` nor ``NAME=PATH`` and suggested no near name): it names every kind of policy and the nearest name.
    """
    import difflib

    from iscc_gym.agents import POLICY_SPECS

    spec = world_spec(item)[0].strip().lower()
    heads = {p.split(":")[0] + (":" if ":" in p else ""): p for p in POLICY_SPECS}
    if (spec.split(":")[0] + ":" if ":" in spec else spec) in heads:
        return
    names = ["ppo", "aware", *(p.split(":")[0] for p in POLICY_SPECS)]
    near = difflib.get_close_matches(item.strip().lower(), names, n=1, cutoff=0.6)
    raise ValueError(f"--policies {item!r}: no such policy" + (f" (did you mean {near[0]!r}?)" if near else "")
                     + "; choose among " + ", ".join(COMMAND_SPECS) + " and the scripted specs "
                     + ", ".join(POLICY_SPECS))


def check_specs(items: list[str], scenario: str = "paper") -> None:
    """Check every item before any episode is played: a trained agent's path holds a model (and torch and
    SB3 are installed), a scripted spec is one :func:`agents.make_policy` understands. ``OSError`` /
    ``ValueError`` with one line naming the item otherwise. Builds only the cheap scripted policies.
    """
    learned = False
    for item in items:  # names and paths first: nothing heavy is loaded for a mistake there
        if "=" in item:
            name, path = item.split("=", 1)
            p = Path(path).expanduser()
            model = p / "model.zip" if p.is_dir() else p
            if not model.is_file():
                raise FileNotFoundError(f"--policies {name}={path}: no trained agent there (give a run directory "
                                        "of python -m train holding model.zip, or a model .zip file)")
            learned = True
        else:
            check_spec_name(item)
    cheap = [spec for item in items if "=" not in item
             and (spec := world_spec(item)[0]).strip().lower() not in _KNOWN_SPECS]
    if cheap:
        from iscc_gym.agents import make_policy

        for spec in cheap:
            make_policy(spec, scenario)  # cheap for the others; raises ValueError naming what is wrong
    if learned:
        missing = [m for m in ("torch", "stable_baselines3") if importlib.util.find_spec(m) is None]
        if missing:
            raise ModuleNotFoundError(f"a trained agent needs {' and '.join(missing)}: pip install 'iscc-gym[train]' "
                                      "(or evaluate scripted policies only, e.g. --policies sca,margin,myopic)",
                                      name=missing[0])  # iscc_gym.commands.cli.run: one line, exit code 2


#: Specs whose evaluation takes longest (an optimisation every slot): started first by the workers.
SLOW_SPECS = ("sca-per-slot", "myopic", "grid", "evolutionary")

_PROGRESS = None  # a worker's queue for progress reports (None: no reports)


def _worker_init(torch_threads: int, progress_queue=None) -> None:
    """A worker process: one numba thread (the workers already use the cores) and ``torch_threads``."""
    global _PROGRESS
    import numba

    numba.set_num_threads(1)
    if torch_threads and importlib.util.find_spec("torch") is not None:
        import torch

        torch.set_num_threads(torch_threads)
    _PROGRESS = progress_queue
    if progress_queue is not None:
        progress_queue.cancel_join_thread()  # a report still in the pipe never holds up the worker's exit


def _run_item(index: int, item: str, seeds, scenario: str, max_steps, record: int, world=None, tuned=None,
              trace_info=()):
    from iscc_gym.eval.evaluate import run_episodes

    name, policy = build_policy(item, scenario, world=world, tuned=tuned)
    progress = None
    if _PROGRESS is not None:
        done = [0]

        def progress(n):
            done[0] += n
            _PROGRESS.put((index, done[0]))

    return name, run_episodes(policy, seeds, scenario if world is None else world, max_steps, record,
                              progress=progress, trace_info=trace_info)


class TimeLeft:
    """Seconds left of jobs of very different paces (the main job's myopic and per-slot SCA take 31 s and 17 s, its
    four other policies 0.4-1.7 s each: ``python -m eval --workers 1 --json PATH``) played in order by ``workers``
    processes, from each job's own pace rather than the slots done overall (issue 43.11: that estimate, the slow
    policies' pace applied to every slot left, ran 5x high mid-run).

    A job's pace (seconds a slot) is measured from its first report on (its start-up excluded); a job not yet measured
    takes the mean pace of the measured jobs of its class (``slow``: :data:`SLOW_SPECS`, started first), or, with
    none: a slow job the slowest pace measured, a fast one none (negligible beside the slow ones, as measured above).
    The jobs left are then scheduled on the workers in their order, each to the first worker free (as the pool
    does); the estimate is when the last one ends. ``clock``: seconds (tests pass their own).
    """

    def __init__(self, horizons: list[int], slow: list[bool], workers: int, clock=None):
        import time

        self.horizons, self.slow, self.workers = list(horizons), list(slow), max(1, int(workers))
        self.clock = clock or time.monotonic
        self.first: dict[int, tuple[float, int]] = {}
        self.last: dict[int, tuple[float, int]] = {}

    def report(self, i: int, done: int) -> None:
        """Job ``i`` has played ``done`` slots (cumulative)."""
        now = self.clock()
        self.first.setdefault(i, (now, done))
        self.last[i] = (now, min(done, self.horizons[i]))

    def _pace(self, i: int) -> float | None:
        if i not in self.first:
            return None
        (t0, n0), (t1, n1) = self.first[i], self.last[i]
        return (t1 - t0) / (n1 - n0) if n1 > n0 and t1 > t0 else None

    def seconds(self) -> float | None:
        """The estimate, None until a pace is measured."""
        n = len(self.horizons)
        paces = {i: p for i in range(n) if (p := self._pace(i)) is not None}
        if not paces:
            return None

        def pace(i):
            if i in paces:
                return paces[i]
            same = [p for j, p in paces.items() if self.slow[j] == self.slow[i]]
            return sum(same) / len(same) if same else max(paces.values()) if self.slow[i] else 0.0

        left = {i: (h - self.last.get(i, (0.0, 0))[1]) * pace(i) for i, h in enumerate(self.horizons)
                if self.last.get(i, (0.0, 0))[1] < h}
        running = [left[i] for i in left if i in self.first]
        free = sorted(running[:self.workers] + [0.0] * max(self.workers - len(running), 0))
        for i in sorted(i for i in left if i not in self.first):
            free[0] += left[i]
            free.sort()
        return max(free)


def play(items: list[str], seeds, scenario: str = "paper", worlds: dict | None = None, max_steps=None,
         record: int = 0, workers: int = 2, torch_threads: int = 1, progress=None, time_left=None,
         tuned: dict | None = None, trace_info=()) -> dict:
    """``{world: {name: run_episodes result}}``: every policy item (built for preset ``scenario``) played on each
    of ``worlds`` (``{name: Scenario or preset}``; default ``{scenario: scenario}``) on the same seeds, in
    ``workers`` processes (spawned, one numba thread each; 1: in this process). Every run is seeded, so the results
    are those of one process.

    ``progress(n)``, if given, is called in this process with the slots played since its last call (the
    workers report through a queue; a run's calls add up to its horizon when it finishes); ``time_left(s)``, if given
    too, after it with the estimate of :class:`TimeLeft` (seconds, or None before one can be made). The first
    error of a worker is raised as soon as it happens (the runs not started are cancelled). ``tuned``: ``{(world,
    item): params}`` an item plays on that world instead of its record's (:func:`build_policy`); ``trace_info``: info
    keys traced slot by slot for the first ``record`` missions (:func:`~iscc_gym.eval.evaluate.run_episodes`).
    """
    import multiprocessing
    from concurrent.futures import FIRST_EXCEPTION, ProcessPoolExecutor, wait
    from queue import Empty

    from iscc_gym.eval.evaluate import horizon_slots, run_episodes

    worlds = {scenario: scenario} if worlds is None else dict(worlds)
    seeds = list(seeds)
    # (world, item) jobs, the slow policies first
    jobs = [(w, it) for it in sorted(items, key=lambda it: world_spec(it.split("=")[0])[0] not in SLOW_SPECS)
            for w in worlds]
    horizons = [horizon_slots(worlds[w], max_steps) for w, _ in jobs]
    serial = workers <= 1 or len(jobs) <= 1
    clock = TimeLeft(horizons, [world_spec(it.split("=")[0])[0] in SLOW_SPECS for _, it in jobs],
                     1 if serial else workers)
    if serial:
        if torch_threads and any("=" in it for it in items):
            import torch

            torch.set_num_threads(torch_threads)
        results = {}
        for i, (w, it) in enumerate(jobs):
            name, policy = build_policy(it, scenario, world=worlds[w], tuned=(tuned or {}).get((w, it)))
            results[i] = name, run_episodes(policy, seeds, worlds[w], max_steps, record,
                                            progress=None if progress is None else _job_progress(
                                                i, progress, clock, time_left), trace_info=trace_info)
            clock.report(i, horizons[i])
        return _by_world(results, jobs, items, worlds)
    ctx = multiprocessing.get_context("spawn")
    queue = ctx.Queue() if progress is not None else None
    done = [0] * len(jobs)
    reported = 0

    def report(block: bool) -> None:
        """Read the workers' reports (waiting up to 0.2 s for the first if ``block``), pass on the new slots."""
        nonlocal reported
        try:
            i, n = queue.get(timeout=0.2) if block else queue.get_nowait()
            while True:
                done[i] = max(done[i], min(n, horizons[i]))
                clock.report(i, done[i])
                i, n = queue.get_nowait()
        except Empty:
            pass
        for i, f in futures.items():
            if f.done() and not f.cancelled() and f.exception() is None and done[i] < horizons[i]:
                done[i] = horizons[i]
                clock.report(i, done[i])
        total = sum(done)
        if total > reported:
            progress(total - reported)
            reported = total
            if time_left is not None:
                time_left(clock.seconds())

    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init,
                             initargs=(torch_threads, queue)) as pool:
        futures = {i: pool.submit(_run_item, i, it, seeds, scenario, max_steps, record, worlds[w],
                                  (tuned or {}).get((w, it)), tuple(trace_info))
                   for i, (w, it) in enumerate(jobs)}
        pending = set(futures.values())
        try:
            while pending:
                finished, pending = wait(pending, timeout=None if queue is None else 0,
                                         return_when=FIRST_EXCEPTION)
                for f in finished:
                    if f.exception() is not None:
                        raise f.exception()
                if queue is not None:
                    report(block=bool(pending))
        except BaseException:
            _stop(pool)  # the error is reported now, not after the runs still being played
            raise
        results = {i: futures[i].result() for i in futures}
    if queue is not None:
        queue.close()
    return _by_world(results, jobs, items, worlds)


def _job_progress(i: int, progress, clock: TimeLeft, time_left):
    """The progress callback of job ``i`` played in this process: passes the slots on, feeds ``clock``."""
    done = [0]

    def report(n: int) -> None:
        done[0] += n
        clock.report(i, done[0])
        progress(n)
        if time_left is not None:
            time_left(clock.seconds())

    return report


def _by_world(results: dict, jobs: list, items: list[str], worlds: dict) -> dict:
    """``{world: {name: run}}`` of the jobs' ``(name, run)`` results, each world's policies in ``items``' order."""
    by_world: dict = {w: {} for w in worlds}
    for i, (w, _) in enumerate(jobs):
        name, run = results[i]
        by_world[w][name] = run
    return {w: {policy_name(it): by_world[w][policy_name(it)] for it in items} for w in worlds}


def run_parallel(specs: str, seeds, scenario: str = "paper", max_steps=None, record: int = 0, workers: int = 2,
                 torch_threads: int = 1, progress=None) -> dict:
    """``{name: run_episodes result}`` of every policy of ``specs`` on ``scenario`` (:func:`play`, one world)."""
    return play(resolve_specs(specs), seeds, scenario, None, max_steps, record, workers, torch_threads,
                progress)[scenario]


def pool_map(fn, *iterables, workers: int) -> list:
    """``list(map(fn, *iterables))`` in a pool of ``workers`` processes. An error, or Ctrl-C (SIGINT, a
    ``KeyboardInterrupt`` here), stops the pool at once (:func:`_stop`) instead of waiting for the calls
    still running, and is raised.
    """
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(workers) as pool:
        futures = [pool.submit(fn, *args) for args in zip(*iterables, strict=True)]
        try:
            return [f.result() for f in futures]
        except BaseException:
            _stop(pool)
            raise


def _stop(pool) -> None:
    """Cancel what a pool has not started and end its worker processes (Python 3.14's ``terminate_workers``,
    else each process of the pool).
    """
    terminate = getattr(pool, "terminate_workers", None)
    if terminate is not None:
        terminate()
        return
    processes = list((getattr(pool, "_processes", None) or {}).values())  # shutdown forgets them
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in processes:
        if proc.is_alive():
            proc.terminate()


def split_specs(specs: str) -> list[str]:
    """Split on commas, except inside ``fixed:a,b,c`` and ``margin:a,b``."""
    out, parts = [], specs.split(",")
    i = 0
    while i < len(parts):
        p = parts[i]
        width = 3 if p.strip().startswith("fixed:") else 2 if p.strip().startswith("margin:") else 1
        out.append(",".join(parts[i:i + width]))
        i += width
    return out
