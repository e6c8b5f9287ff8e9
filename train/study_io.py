"""Where an Optuna study lives and what it exports: the storage (a SQLite file by default, any
database URL for many machines), the seeded sampler and pruner, and the best trial as an entry of
the hyperparameter file.
"""

from __future__ import annotations

import json
import os
import socket
import stat
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from iscc_gym.files import create_exclusive

if TYPE_CHECKING:  # pragma: no cover
    import optuna

SAMPLERS = ("tpe", "random")
PRUNERS = ("median", "none")

#: Ports probed (TCP, with a timeout) before a database URL without one is handed to SQLAlchemy.
_DEFAULT_PORTS = {"postgresql": 5432, "mysql": 3306, "mariadb": 3306, "mssql": 1433, "oracle": 1521}
CONNECT_TIMEOUT_S = 10
#: Heartbeats of a running trial (every HEARTBEAT_INTERVAL_S, in the storage): a RUNNING trial whose last
#: one is older than GRACE_PERIOD_S (its worker was killed, or its machine lost) is marked FAIL by the
#: next worker that starts a trial of the study, and queued again once (MAX_RETRY) with the same
#: hyperparameters, as a new trial. SQLite and server databases (Optuna's RDBStorage) and journal files
#: (:func:`journal_storage`) alike.
HEARTBEAT_INTERVAL_S = 60
GRACE_PERIOD_S = 180
MAX_RETRY = 1
#: The trial system attribute holding a journal trial's last heartbeat (seconds since the epoch).
HEARTBEAT_ATTR = "iscc_gym:heartbeat"
#: ``OUT/study.yml``: the study whose trials ``OUT/trial_<n>`` are (one study per ``--out``).
STUDY_FILE = "study.yml"


class StudyConfigError(ValueError):
    """A study flag with a bad value; the message names the flag and the fix."""


# --- storage, sampler, pruner ---------------------------------------------------------------------------

def make_storage(url: str | None, out: str | os.PathLike) -> tuple[Any, str]:
    """The Optuna storage of ``url`` (checked: reachable, openable), and the URL (password hidden).

    Parameters
    ----------
    url : str or None
        ``sqlite:///PATH``, any other SQLAlchemy URL (``postgresql://``, ``mysql+pymysql://``...),
        ``journal:PATH``, or None for ``sqlite:///<out>/study.db``.
    out : path-like
        The run directory (holds the default SQLite file).

    Returns
    -------
    storage : optuna.storages.BaseStorage
        ``RDBStorage`` or a ``JournalStorage`` (:func:`journal_storage`), both with heartbeats: a killed
        worker's trial is marked failed and run again once (:data:`HEARTBEAT_INTERVAL_S`).
    shown : str
        The URL as printed (no password).

    Raises
    ------
    StudyConfigError
        Unparsable URL, unknown dialect, missing driver, unreachable host (TCP probe with a
        ``CONNECT_TIMEOUT_S`` timeout, and the same connect timeout for the driver), a database
        that cannot be opened, or a journal path that is not a regular file or not an Optuna journal.
    """
    import optuna
    import sqlalchemy.exc
    from sqlalchemy.engine import make_url

    if url is None:
        path = Path(out) / "study.db"
        path.parent.mkdir(parents=True, exist_ok=True)
        url = f"sqlite:///{path.resolve()}"
    if url.startswith("journal:"):
        path = url[len("journal:"):]
        if not path:
            raise StudyConfigError("--storage journal:: name the journal file, e.g. "
                                   "--storage journal:/shared/study.log")
        check_journal_file(path, url)
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        try:
            from optuna.storages.journal import JournalFileBackend

            return journal_storage(JournalFileBackend(path)), url
        except OSError as e:
            raise StudyConfigError(f"--storage {url}: cannot open the journal file ({e}); "
                                   "use a writable path") from None
    fix = "use sqlite:///PATH, postgresql://USER:PASS@HOST/DB, mysql+pymysql://USER:PASS@HOST/DB or journal:PATH"
    try:
        parsed = make_url(url)
    except sqlalchemy.exc.ArgumentError:
        raise StudyConfigError(f"--storage {url!r}: not a storage URL; {fix}") from None
    shown = parsed.render_as_string(hide_password=True)
    backend = parsed.get_backend_name()
    engine_kwargs: dict[str, Any] = {}
    if backend == "sqlite":
        if parsed.database and parsed.database != ":memory:":
            Path(parsed.database).parent.mkdir(parents=True, exist_ok=True)
        engine_kwargs["connect_args"] = {"timeout": 60}  # wait for another worker's write lock
    else:
        engine_kwargs["connect_args"] = {"connect_timeout": CONNECT_TIMEOUT_S}
        if parsed.host:
            port = parsed.port or _DEFAULT_PORTS.get(backend)
            if port is not None:
                _probe(parsed.host, port, shown)
    last: Exception | None = None
    for attempt in range(5):  # workers creating the tables of a new SQLite file at once may collide
        try:
            with warnings.catch_warnings():  # heartbeat_interval is flagged experimental
                warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
                storage = optuna.storages.RDBStorage(url, engine_kwargs=engine_kwargs,
                                                     heartbeat_interval=HEARTBEAT_INTERVAL_S,
                                                     grace_period=GRACE_PERIOD_S, **_stale_trial_callback())
            return storage, shown
        except (ModuleNotFoundError, ImportError) as e:
            raise StudyConfigError(f"--storage {shown}: the database driver is not installed ({e}); install it "
                                   "(psycopg2-binary for postgresql, pymysql for mysql+pymysql) or "
                                   "use sqlite:///PATH or journal:PATH") from None
        except sqlalchemy.exc.NoSuchModuleError:
            raise StudyConfigError(f"--storage {shown}: unknown database dialect {parsed.drivername!r}; "
                                   f"{fix}") from None
        except (sqlalchemy.exc.OperationalError, sqlalchemy.exc.IntegrityError) as e:
            last = e  # SQLite: another worker is creating the tables ("locked", "UNIQUE constraint failed")
            if backend != "sqlite":
                break
            time.sleep(0.2 * (attempt + 1) + 0.1 * np.random.default_rng().random())
        except Exception as e:  # noqa: BLE001  (any other driver error: say what it was)
            last = e
            break
    reason = str(getattr(last, "orig", None) or last).splitlines()[0]
    raise StudyConfigError(f"--storage {shown}: cannot open the database ({reason}); check the URL, credentials "
                           "and that the server is running")


def check_journal_file(path: str, url: str) -> None:
    """Refuse a ``journal:PATH`` that is not a regular file (``/dev/zero`` was read without end) or a
    file whose first line is not an Optuna journal entry; a missing or empty file is a new journal.

    Raises
    ------
    StudyConfigError
        Naming ``--storage`` and the fix.
    """
    try:
        mode = os.stat(path).st_mode  # follows a symbolic link to what it names
    except FileNotFoundError:
        return
    except OSError as e:
        raise StudyConfigError(f"--storage {url}: cannot read {path} ({e.strerror or e}); "
                               "use a readable path") from None
    if not stat.S_ISREG(mode):
        kind = "a directory" if stat.S_ISDIR(mode) else "not a regular file (a device, a FIFO or a socket)"
        raise StudyConfigError(f"--storage {url}: {path} is {kind}; name an Optuna journal file, or a new file "
                               "to start one, e.g. --storage journal:/shared/study.log")
    try:
        with open(path, "rb") as f:
            first = f.readline(_JOURNAL_LINE_MAX)
    except OSError as e:
        raise StudyConfigError(f"--storage {url}: cannot read {path} ({e.strerror or e}); "
                               "use a readable path") from None
    if not first:
        return
    try:
        entry = json.loads(first.decode("utf-8"))
    except (UnicodeDecodeError, ValueError):
        entry = None
    if not (isinstance(entry, dict) and "op_code" in entry and "worker_id" in entry):
        raise StudyConfigError(f"--storage {url}: {path} is not an Optuna journal (its first line is not a journal "
                               "entry); name a journal file written by --storage journal:PATH, or a new file")


#: The first line of an Optuna journal (the study's creation) is well under this many bytes.
_JOURNAL_LINE_MAX = 1 << 20


def _stale_trial_callback() -> dict:
    """The keyword giving a storage the callback that queues a stale trial again (:data:`MAX_RETRY`)."""
    import optuna

    retry = getattr(optuna.storages, "RetryHeartbeatStaleTrialCallback", None)
    with warnings.catch_warnings():  # flagged experimental
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        if retry is not None:  # Optuna >= 4.9
            return {"heartbeat_stale_trial_callback": retry(max_retry=MAX_RETRY)}
        return {"failed_trial_callback": optuna.storages.RetryFailedTrialCallback(max_retry=MAX_RETRY)}


def journal_storage(backend, heartbeat_interval: float | None = None, grace_period: float | None = None):
    """An Optuna ``JournalStorage`` on ``backend`` with heartbeats, as Optuna's ``RDBStorage`` has them.

    Optuna's journal storage has none: a worker killed during a trial left it RUNNING for ever. Here a
    thread of the worker records the trial's heartbeat (a trial system attribute, :data:`HEARTBEAT_ATTR`)
    every ``heartbeat_interval`` s; a worker starting a trial marks FAIL every RUNNING trial of the
    study whose last heartbeat is older than ``grace_period`` s and queues it again (:data:`MAX_RETRY`).
    The ages are read on the workers' clocks, which must agree within the grace period (NTP).

    Parameters
    ----------
    backend : optuna.storages.journal.BaseJournalBackend
        E.g. ``JournalFileBackend(PATH)``.
    heartbeat_interval, grace_period : float, optional
        Seconds (fractions allowed); default :data:`HEARTBEAT_INTERVAL_S`, :data:`GRACE_PERIOD_S`.

    Returns
    -------
    optuna.storages.JournalStorage
    """
    import optuna
    from optuna.storages._heartbeat import BaseHeartbeat
    from optuna.trial import TrialState

    interval = float(HEARTBEAT_INTERVAL_S if heartbeat_interval is None else heartbeat_interval)
    grace = float(GRACE_PERIOD_S if grace_period is None else grace_period)
    callback = next(iter(_stale_trial_callback().values()))

    class HeartbeatJournalStorage(optuna.storages.JournalStorage, BaseHeartbeat):
        def record_heartbeat(self, trial_id: int) -> None:
            try:
                self.set_trial_system_attr(trial_id, HEARTBEAT_ATTR, time.time())
            except optuna.exceptions.UpdateFinishedTrialError:
                pass  # the trial ended while the beat was on its way

        def _get_stale_trial_ids(self, study_id: int) -> list[int]:
            now = time.time()
            stale = []
            for t in self.get_all_trials(study_id, deepcopy=False, states=(TrialState.RUNNING,)):
                beat = t.system_attrs.get(HEARTBEAT_ATTR)
                if beat is None:  # started, first beat not yet written
                    beat = t.datetime_start.timestamp() if t.datetime_start is not None else now
                if now - float(beat) > grace:
                    stale.append(t._trial_id)
            return stale

        def get_heartbeat_interval(self) -> float:
            return interval

        def get_heartbeat_stale_trial_callback(self):
            return callback

        def get_failed_trial_callback(self):  # the name Optuna < 4.9 calls
            return callback

    return HeartbeatJournalStorage(backend)


def claim_out(out: str | os.PathLike, study_name: str, shown: str | None = None,
              has_trials: bool | None = None) -> Path:
    """Record in ``OUT/study.yml`` that ``OUT``'s trial directories are study ``study_name``'s, or check
    that they are: one study per ``--out`` (``trial_<n>`` of two studies would collide).

    Parameters
    ----------
    out : path-like
        The study's ``--out``.
    study_name : str
        The study being opened.
    shown : str, optional
        Its storage URL as printed (recorded for the message).
    has_trials : bool, optional
        Whether the study already has trials (an ``--out`` of an earlier version, with trial directories
        but no ``study.yml``, is taken as this study's only then). None: only check an existing
        ``study.yml`` (before the study is opened), record nothing.

    Returns
    -------
    Path
        ``OUT/study.yml``.

    Raises
    ------
    StudyConfigError
        ``OUT`` holds another study's trials; the message names both studies.
    """
    path = Path(out) / STUDY_FILE
    if not path.exists():
        if has_trials is None:
            return path
        earlier = sorted(p.name for p in Path(out).glob("trial_*"))
        if earlier and not has_trials:
            raise StudyConfigError(f"--out {out}: holds trial directories of an earlier study ({', '.join(earlier[:3])}"
                                   f"{', ...' if len(earlier) > 3 else ''}) and no {STUDY_FILE}; study "
                                   f"{study_name!r} has no trials yet: give it its own --out")
        create_exclusive(path, yaml.safe_dump({"study_name": study_name, "storage": shown}, sort_keys=False))
    try:
        doc = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as e:
        raise StudyConfigError(f"--out {out}: cannot read {path} ({str(e).splitlines()[0]}); it names the study "
                               "whose trials this directory holds: restore it, or give another --out") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("study_name"), str):
        raise StudyConfigError(f"--out {out}: {path} names no study_name; restore it, or give another --out")
    if doc["study_name"] != study_name:
        raise StudyConfigError(f"--out {out}: holds the trials of study {doc['study_name']!r} (storage "
                               f"{doc.get('storage')}); study {study_name!r} would overwrite them (trial_0, ...): "
                               f"give it its own --out, or --study-name {doc['study_name']} to add trials to that one")
    return path


def _probe(host: str, port: int, shown: str) -> None:
    try:
        socket.getaddrinfo(host, port)
    except OSError as e:
        raise StudyConfigError(f"--storage {shown}: cannot resolve host {host!r} ({e}); check the host name") from None
    try:
        with socket.create_connection((host, port), timeout=CONNECT_TIMEOUT_S):
            pass
    except OSError as e:
        raise StudyConfigError(f"--storage {shown}: cannot reach {host}:{port} ({e}); check the host, port and that "
                               "the database server is running") from None


def trial_seed(seed: int, number: int) -> int:
    """The sampler seed of trial ``number`` in a study seeded ``seed`` (independent streams)."""
    return int(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, int(number)]).generate_state(1)[0])


def _sampler_base():
    import optuna

    class TrialSeededSampler(optuna.samplers.BaseSampler):
        """Delegate to ``factory(trial_seed(seed, n))``, a fresh sampler for trial ``n``.

        Optuna's samplers keep their random state in the process; seeding per trial number makes a
        trial's random draws a function of ``(seed, n)`` whichever worker runs it. TPE and random
        sampling read everything else from the study's storage.
        """

        def __init__(self, factory: Callable[[int], optuna.samplers.BaseSampler], seed: int):
            self._factory = factory
            self._seed = seed
            self._inner = factory(trial_seed(seed, 0))

        def before_trial(self, study, trial):
            self._inner = self._factory(trial_seed(self._seed, trial.number))
            self._inner.before_trial(study, trial)

        def infer_relative_search_space(self, study, trial):
            return self._inner.infer_relative_search_space(study, trial)

        def sample_relative(self, study, trial, search_space):
            return self._inner.sample_relative(study, trial, search_space)

        def sample_independent(self, study, trial, param_name, param_distribution):
            return self._inner.sample_independent(study, trial, param_name, param_distribution)

        def after_trial(self, study, trial, state, values):
            self._inner.after_trial(study, trial, state, values)

        def reseed_rng(self) -> None:
            self._inner.reseed_rng()

    return TrialSeededSampler


def make_sampler(name: str, seed: int, n_startup_trials: int = 5):
    """The sampler ``tpe`` or ``random``, seeded per trial from ``seed`` (see :func:`trial_seed`).

    Parameters
    ----------
    name : str
        ``tpe`` or ``random``.
    seed : int
        The study's seed (``--seed``).
    n_startup_trials : int
        TPE's random start-up trials.

    Returns
    -------
    optuna.samplers.BaseSampler
    """
    import optuna

    if name not in SAMPLERS:
        raise StudyConfigError(f"--sampler {name!r}: use one of {', '.join(SAMPLERS)}")
    if name == "tpe":
        def factory(s):
            return optuna.samplers.TPESampler(n_startup_trials=n_startup_trials, seed=s)
    else:
        def factory(s):
            return optuna.samplers.RandomSampler(seed=s)
    return _sampler_base()(factory, seed)


def make_pruner(name: str, n_startup_trials: int = 5, n_evaluations: int = 4):
    """``median``: prune a trial whose evaluation ``k`` is below the median of earlier trials' at ``k``.

    Parameters
    ----------
    name : str
        ``median`` or ``none``.
    n_startup_trials : int
        Trials completed before pruning starts.
    n_evaluations : int
        Evaluations per trial; the first ``max(1, n_evaluations // 3)`` never prune.

    Returns
    -------
    optuna.pruners.BasePruner
    """
    import optuna

    if name not in PRUNERS:
        raise StudyConfigError(f"--pruner {name!r}: use one of {', '.join(PRUNERS)}")
    if name == "none":
        return optuna.pruners.NopPruner()
    # evaluations are reported at steps 1, 2, ...; steps below n_warmup_steps never prune
    return optuna.pruners.MedianPruner(n_startup_trials=n_startup_trials,
                                       n_warmup_steps=max(1, n_evaluations // 3) + 1)
