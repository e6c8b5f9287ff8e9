"""What every ``python -m eval...`` command shares on its command line: one-line errors, checked numbers,
seeds and output paths (checked before any work starts), and progress bars on a terminal.

The checks raise ``ValueError``/``OSError`` with one line naming the flag; :func:`iscc_gym.commands.cli.run` turns
them into ``PROG: error: MESSAGE`` and exit code 2, and Python callers get the exception.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import os
import sys
import tempfile
import time
from pathlib import Path

from iscc_gym.commands.cli import invoked_prog

from iscc_gym.files import destination

__all__ = ["Parser", "import_gym_packages", "GYM_PACKAGES", "PICKLE_WARNING", "positive_int", "nonneg_int",
           "parse_seeds", "check_writable_file", "check_writable_dir", "show_progress", "progress_bar", "LineProgress",
           "Stages", "run_console", "docs_command", "env_scenario"]

#: Said in ``--help`` wherever a path to a trained model is accepted.
PICKLE_WARNING = ("A model .zip and its vecnormalize.pkl are pickles: loading them executes code they contain, so "
                  "load only files you trust.")


class Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors are one line, ``PROG: error: MESSAGE (see --help)``, exit code 2, and
    whose ``prog`` is the command as invoked (:func:`iscc_gym.commands.cli.invoked_prog`: ``python -m
    experiments.seeds`` for ``python -m experiments.seeds`` when run under the installed name). With
    ``gym_packages=True`` it takes rl-zoo3's ``--gym-packages MODULE...`` and imports them before it reads the
    other flags (:func:`import_gym_packages`).
    """

    def __init__(self, *args, prog: str | None = None, gym_packages: bool = False, **kwargs):
        super().__init__(*args, prog=invoked_prog(prog) if prog else None, **kwargs)
        self.gym_packages = gym_packages
        if gym_packages:
            self.add_argument("--gym-packages", nargs="+", default=[], metavar="MODULE",
                              help="modules to import before anything else: a module that registers a task of its "
                                   "own (iscc_gym.register_task) or other envs; rl-zoo3's flag of the same name")

    def error(self, message: str):  # noqa: D102 (argparse's hook)
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")

    def parse_known_args(self, args=None, namespace=None):  # noqa: D102 (argparse's hook)
        if self.gym_packages:
            try:
                import_gym_packages(sys.argv[1:] if args is None else list(args))
            except ValueError as e:
                self.error(str(e))
        return super().parse_known_args(args, namespace)


#: The modules ``--gym-packages`` imported in this process (a command that starts another Python passes them on).
GYM_PACKAGES: list[str] = []


def import_gym_packages(argv: list[str]) -> list[str]:
    """Import the modules that ``--gym-packages`` names in ``argv`` (before the arguments are read: a module
    registers the env ids the other flags name); returns their names. ``ValueError`` for one that does not import.
    """
    names, taking = [], False
    for a in map(str, argv):
        if a.startswith("--gym-packages="):
            names.append(a.split("=", 1)[1])
            taking = False
        elif a == "--gym-packages":
            taking = True
        elif taking and not a.startswith("-"):
            names.append(a)
        else:
            taking = False
    for name in names:
        try:
            importlib.import_module(name)
        except ModuleNotFoundError as e:
            raise ValueError(f"--gym-packages {name}: no module named {e.name!r} (a module on the Python path, "
                             "e.g. my_tasks for my_tasks.py in the working directory)") from None
        if name not in GYM_PACKAGES:
            GYM_PACKAGES.append(name)
    return names


def positive_int(text: str) -> int:
    """An argparse ``type``: an integer >= 1."""
    return _int_at_least(text, 1)


def nonneg_int(text: str) -> int:
    """An argparse ``type``: an integer >= 0."""
    return _int_at_least(text, 0)


def _int_at_least(text: str, low: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < low:
        raise argparse.ArgumentTypeError(f"{value}: use an integer >= {low}")
    return value


def parse_names(text: str, flag: str, choices=None) -> list[str]:
    """Comma-separated distinct names (spaces around each dropped), at least one, each among ``choices`` if given;
    ``ValueError`` naming the flag otherwise (issue 43.3: ``--variants ,`` played nothing and wrote an empty table).
    """
    names = [p.strip() for p in str(text).split(",") if p.strip()]
    among = f"; choose among {', '.join(choices)}" if choices is not None else ""
    if not names:
        raise ValueError(f"{flag} {text!r} names nothing: give one name or more, comma-separated{among}")
    unknown = [n for n in names if choices is not None and n not in choices]
    if unknown:
        raise ValueError(f"{flag} {text!r}: unknown {', '.join(map(repr, unknown))}{among}")
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"{flag} {text!r}: {dup[0]!r} is given twice")
    return names


def parse_seeds(text: str, flag: str = "--seeds") -> list[int]:
    """Comma-separated distinct non-negative integer seeds; ``ValueError`` naming the flag otherwise."""
    parts = [p.strip() for p in str(text).split(",")]
    if not parts or any(p == "" for p in parts):
        raise ValueError(f"{flag} {text!r}: give comma-separated integers, e.g. {flag} 10000,10001")
    try:
        seeds = [int(p) for p in parts]
    except ValueError:
        raise ValueError(f"{flag} {text!r}: give comma-separated integers, e.g. {flag} 10000,10001") from None
    negative = [s for s in seeds if s < 0]
    if negative:
        raise ValueError(f"{flag}: seed {negative[0]} is negative; seeds are integers >= 0")
    dup = sorted({s for s in seeds if seeds.count(s) > 1})
    if dup:
        raise ValueError(f"{flag}: seed {dup[0]} is given twice; every mission must be a different seed")
    return seeds


def _nearest_existing(path: Path) -> Path:
    p = path.absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _probe_dir(directory: Path, flag: str, path: Path) -> None:
    """``OSError`` unless a file can be created in the existing directory ``directory``."""
    try:
        with tempfile.TemporaryFile(dir=directory):
            pass
    except OSError as e:
        raise OSError(f"{flag} {path}: cannot write in {directory} ({e.strerror or e})") from None


def env_scenario(env: str, scenario: str | None, write_docs: bool = False) -> str:
    """The scenario preset a command plays on env id ``env``: ``--scenario``, by default the one ``env`` is
    registered with (``urban`` for ``iscc_gym/ISCC-Urban-v0``, else ``paper``).

    Raises
    ------
    ValueError
        An unknown preset; a preset of another task than ``env``'s (:func:`iscc_gym.agents.tuned_records.task_of`:
        the command would play that task's missions under ``env``'s policies, reference, shipped agent and docs
        section), naming both and the fix; with ``write_docs``, any preset but ``env``'s own (the docs sections
        are of it). A variant of the same task (``literal`` on ``iscc_gym/ISCC-v0``) passes.
    """
    from iscc_gym.agents.tuned_records import task_mismatch

    from iscc_gym.tasks import registered_scenario

    own = registered_scenario(env)
    if scenario is None:
        return own
    try:
        mismatch = task_mismatch(env, scenario)
    except (ValueError, TypeError) as e:
        raise ValueError(f"--scenario {scenario!r}: {e.args[0] if e.args else e}") from None
    if mismatch is not None:
        task, env_task, other, _ = mismatch
        raise ValueError(f"--scenario {scenario!r} is the {task} task, but --env {env} is the {env_task} task (its "
                         f"policies, reference, shipped agent and docs section): use --env {other} for "
                         f"{scenario!r}, or drop --scenario to play {env}'s own {own!r}")
    if write_docs and scenario != own:
        raise ValueError(f"--write-docs writes the docs of --env {env}, whose scenario is {own!r}: drop --scenario "
                         f"{scenario!r} or --write-docs")
    return scenario


def check_writable_file(path: str | os.PathLike, flag: str) -> Path:
    """Check, before any work, that a file can be written at ``path`` (its missing parent directories
    would be created); ``OSError`` naming ``flag`` otherwise. Creates nothing. A destination that is
    written into rather than replaced (``/dev/stdout``, a device, a FIFO:
    :func:`iscc_gym.files.destination`) needs write permission on itself; a symbolic link, on the
    directory of its target.
    """
    p = Path(path)
    if p.is_dir():
        raise OSError(f"{flag} {p}: is a directory; give a file name")
    kind, target = destination(p)
    if kind == "descriptor":
        return p
    if kind == "stream":
        if not os.access(target, os.W_OK):
            raise OSError(f"{flag} {p}: not writable (permission denied)")
        return p
    base = _nearest_existing(target.parent)
    if not base.is_dir():
        raise OSError(f"{flag} {p}: {base} is a file, not a directory")
    _probe_dir(base, flag, p)
    return p


def check_writable_dir(path: str | os.PathLike, flag: str) -> Path:
    """Check, before any work, that files can be written into directory ``path`` (created if missing);
    ``OSError`` naming ``flag`` otherwise. Creates nothing.
    """
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise OSError(f"{flag} {p}: is a file, not a directory")
    base = _nearest_existing(p)
    if not base.is_dir():
        raise OSError(f"{flag} {p}: {base} is a file, not a directory")
    _probe_dir(base, flag, p)
    return p


def show_progress(quiet: bool = False) -> bool:
    """Progress is shown unless ``quiet``: a bar on a terminal, a line every :data:`LINE_INTERVAL_S` seconds (and
    per stage) to stderr otherwise (a log file, CI, ``nohup``), see :func:`progress_bar`.
    """
    return not quiet


def _isatty(stream) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False


#: Seconds between two progress lines when stderr is not a terminal.
LINE_INTERVAL_S = 10.0


class LineProgress:
    """Progress as plain lines on a stream that is not a terminal (tqdm's bar there is a mess of carriage
    returns): one line when a stage starts (:meth:`set_postfix_str`), then at most one every ``interval`` seconds
    (done/total, rate, elapsed, estimated time left), and one at the end. The part of tqdm's API the commands use.

    The time left is estimated from the work done since the first progress report, so the start-up before it
    (spawning workers, importing, compiling the kernels: seconds, against a few slots done) does not inflate it; no
    estimate is shown until a report after the first has come. ``clock``: seconds (tests pass their own).
    """

    def __init__(self, total: float, desc: str, unit: str = "it", stream=None, interval: float = LINE_INTERVAL_S,
                 clock=time.monotonic):
        self.total, self.desc, self.unit, self.n = total, desc, unit, 0
        self.stream, self.interval, self.clock = stream if stream is not None else sys.stderr, interval, clock
        self.t0 = self.last = clock()
        self.timed_from = None  # (time, done) at the first report: the rate is measured from there
        self.postfix, self.closed = "", False
        self.told = None  # (time, seconds left or None) of the caller's own estimates (set_time_left); None: the rate's

    def _line(self, text: str) -> None:
        print(f"[{self.desc}] {text}", file=self.stream, flush=True)

    def _status(self) -> str:
        now = self.clock()
        elapsed = now - self.t0
        done = f"{self.n:,.0f}/{self.total:,.0f} {self.unit}" if self.total else f"{self.n:,.0f} {self.unit}"
        eta = ""
        if self.told is not None:  # the caller's estimate only, once it gives them
            if self.n < self.total and self.told[1] is not None:
                eta = f", about {max(self.told[1] - (now - self.told[0]), 0.0):.0f} s left"
        elif self.total and self.n < self.total and self.timed_from is not None:
            t1, n1 = self.timed_from
            if self.n > n1 and now > t1:
                eta = f", about {(now - t1) * (self.total - self.n) / (self.n - n1):.0f} s left"
        stage = f" ({self.postfix})" if self.postfix else ""
        return f"{done}{stage}, {elapsed:.0f} s elapsed{eta}"

    def count(self, n: float = 1) -> None:
        """Add ``n`` done, printing nothing (the first report starts the timing of the estimate)."""
        self.n += n
        if self.timed_from is None and n > 0:
            self.timed_from = (self.clock(), self.n)

    def update(self, n: float = 1) -> None:
        self.count(n)
        now = self.clock()
        if now - self.last >= self.interval:
            self.last = now
            self._line(self._status())

    def write(self, s: str) -> None:
        """A message line on stdout, as ``tqdm.write`` prints one."""
        print(s, flush=True)

    def set_time_left(self, seconds: float | None) -> None:
        """The caller's estimate of the seconds left (it knows its jobs' paces), shown instead of the rate's; None:
        none yet (no estimate shown).
        """
        self.told = (self.clock(), None if seconds is None else float(seconds))

    def set_postfix_str(self, s: str) -> None:
        self.postfix = s
        self.last = self.clock()
        self._line(self._status())

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._line(f"done: {self._status()}")

    def __enter__(self) -> LineProgress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def progress_bar(total: float, desc: str, unit: str = "it", enabled: bool = True, **kw):
    """A tqdm bar on stderr when it is a terminal, else :class:`LineProgress` lines to stderr (a disabled tqdm,
    which does nothing, if not ``enabled``).
    """
    from tqdm.auto import tqdm

    if enabled and not _isatty(sys.stderr):
        return LineProgress(total, desc, unit)
    return tqdm(total=total, desc=desc, unit=unit, disable=not enabled, file=sys.stderr, dynamic_ncols=True,
                leave=False, **kw)


class Stages:
    """A progress bar over the named stages of a long command: ``st.next("model level")`` marks the
    previous stage done and shows the new one's name. A no-op when not ``enabled``.
    """

    def __init__(self, total: int, desc: str, enabled: bool = True):
        self.bar = progress_bar(total, desc, unit="stage", enabled=enabled,
                                bar_format="{desc}: {n_fmt}/{total_fmt} stages |{bar}| {elapsed}{postfix}")
        self.started = False

    def next(self, label: str) -> None:
        if self.started:
            if isinstance(self.bar, LineProgress):
                self.bar.count(1)  # the stage's own line follows: no interval line with the old stage's name
            else:
                self.bar.update(1)
        self.started = True
        self.bar.set_postfix_str(label)

    def close(self) -> None:
        if self.started and self.bar.n < self.bar.total:
            self.bar.update(1)
        self.bar.close()

    def __enter__(self) -> Stages:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def run_console(main, argv: list[str] | None, prog: str) -> int:
    """``main(argv, prog=prog)`` ended with an exit code (:func:`iscc_gym.commands.cli.run`): 0 on success, 2 after
    a one-line error for a user's mistake, 130 on Ctrl-C. For ``sys.exit`` in a command's ``__main__``.
    """
    from iscc_gym.commands.cli import run

    return run(functools.partial(main, prog=prog), argv, prog)


def claims_parser(prog: str, description: str, *, missions: int, quick_missions: int, seed_base: int,
                  figures_default: str) -> Parser:
    """The parser of a measurement command that states claims (``experiments.paper.fading``,
    ``experiments.paper.sensitivity``): ``--quick``, ``--seed``, ``--json``, ``--figures``, ``--no-figures``.
    """
    p = Parser(prog=prog, description=description)
    p.add_argument("--quick", action="store_true",
                   help=f"{quick_missions} missions per point on a coarser grid (smoke run; default {missions})")
    p.add_argument("--seed", type=nonneg_int, default=0,
                   help=f"run seed: missions {seed_base:,} + 1000 x SEED + i (held-out evaluation seeds; default 0)")
    p.add_argument("--json", metavar="PATH", default=None, help="write the results (with the claims) as JSON")
    p.add_argument("--figures", metavar="DIR", default=figures_default,
                   help=f"directory of the PNG figures (default {figures_default})")
    p.add_argument("--no-figures", action="store_true", help="draw no figures")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    p.set_defaults(prog=p.prog)
    return p


def run_claims_command(args, run, draw, check_seeds, report=None) -> dict:
    """Check the outputs first, then ``run(quick, seed)``, ``draw(res, dir)``, print the claims (and
    ``report(res)``), write ``--json`` atomically; returns the results.
    """
    import json

    from iscc_gym.files import write_atomic

    if args.json:
        check_writable_file(args.json, "--json")
    if not args.no_figures:
        check_writable_dir(args.figures, "--figures")
    check_seeds(args)
    with Stages(1 if args.no_figures else 2, args.prog, enabled=not getattr(args, "quiet", False)) as st:
        st.next("quick missions" if args.quick else "missions")
        res = run(quick=args.quick, seed=args.seed)
        if not args.no_figures:
            st.next("figures")
            res["figures"] = draw(res, args.figures)
    for c in res["claims"]:
        print(f"[{'holds' if c['holds'] else 'does not hold'}] {c['id']} ({c['figure']}): {c['ours']}")
    if report is not None:
        report(res)
    if args.json:
        write_atomic(args.json, json.dumps(res, indent=1))
        print(f"wrote {args.json}")
    return res


#: Flags that say where a run's output goes or how it is shown, not what it computes: left out of the
#: command quoted in generated docs (a local ``--json /tmp/x.json`` is no part of how to regenerate them).
_OUTPUT_FLAGS = {"--write-docs": 0, "--quiet": 0, "--json": 1, "--plots": 1, "--figures": 1}


#: ``(prog, arguments)`` of the study entry running now (``python -m experiments NAME``): its own arguments, the
#: table's, are left out of the command quoted in the docs it writes (``python -m experiments NAME`` regenerates them).
STUDY: list[tuple[str, list[str]]] = []


def docs_command(prog: str, argv: list[str] | None = None) -> str:
    """The command line quoted in generated docs: ``prog`` and ``argv`` (default ``sys.argv[1:]``)
    without the output flags (:data:`_OUTPUT_FLAGS`, with their values); under a study entry of ``python -m
    experiments`` (:data:`STUDY`), without the entry's own arguments.
    """
    import sys

    args = list(sys.argv[1:] if argv is None else argv)
    if STUDY and STUDY[-1][0] == prog and args[:len(STUDY[-1][1])] == STUDY[-1][1]:
        args = args[len(STUDY[-1][1]):]
    out, i = [prog], 0
    while i < len(args):
        a = args[i]
        name = a.split("=", 1)[0]
        if name in _OUTPUT_FLAGS:
            i += 1 + (_OUTPUT_FLAGS[name] if "=" not in a else 0)
            continue
        out.append(a)
        i += 1
    return " ".join(out)
