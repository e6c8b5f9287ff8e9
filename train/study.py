"""Hyperparameter studies on Optuna and multi-seed runs: ``python -m train --optimize`` / ``--seeds``.

Usage::

    # one machine: the study lives in OUT/study.db (SQLite)
    python -m train --optimize --n-trials 20 --trial-timesteps 200000 --out runs/study
    # many machines: the same command with one shared storage URL joins the same study
    python -m train --optimize --n-trials 4 --storage postgresql://USER:PASS@HOST/DB --study-name ppo-a --out runs/study
    # one configuration (the YAML's, with --set overrides) trained with several seeds
    python -m train --seeds 0,1,2,3,4 --out runs/seeds

Each trial samples PPO hyperparameters (:func:`sample_ppo_params`), trains with
:func:`iscc_gym.train.train.main` into ``OUT/trial_<n>`` and reports every held-out evaluation of the
EvalCallback (mean episode reward on the seeds from :data:`train.train.EVAL_SEED_START`) to Optuna,
which may prune it. The objective, maximised, is the final model's mean reward on the same held-out
episodes. The best trial is exported as a ``hyperparams.yml`` entry, ``OUT/best_hyperparams.yml``,
which ``python -m train --hyperparams OUT/best_hyperparams.yml`` trains directly.

Storage (``--storage``): omitted, ``sqlite:///OUT/study.db``; otherwise any SQLAlchemy URL Optuna's
``RDBStorage`` takes (``sqlite:///PATH``, ``postgresql://USER:PASS@HOST[:PORT]/DB``,
``mysql+pymysql://USER:PASS@HOST/DB``; the driver must be installed) or ``journal:PATH``, an Optuna
journal file (``JournalFileBackend``) on a filesystem every worker mounts (NFS: no database server;
SQLite files on NFS are not safe). Workers that run the same command with the same ``--storage`` and
``--study-name`` share one study (``load_if_exists``); each worker runs ``--n-trials`` trials.

Reproducibility: the sampler of trial ``n`` is seeded from ``(--seed, n)``, so a single worker's study
is reproducible given ``--seed``, and parallel workers with the same ``--seed`` never draw the same
random start-up configurations.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import socket
import time
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml
from iscc_gym.train.train import (
    EVAL_SEED_START,
    Args,
    _check,
    _resolve_policy_kwargs,
    check_hyperparams,
    load_hyperparams,
    main,
    resolve_args,
)

from iscc_gym.files import write_atomic

if TYPE_CHECKING:  # pragma: no cover
    import optuna

SAMPLERS = ("tpe", "random")
PRUNERS = ("median", "none")

#: The PPO search space: name -> choices (a list) or ``(low, high, "log" | "linear")``. ``n_minibatches``
#: sets ``batch_size = n_envs * n_steps / n_minibatches`` (always a divisor of the rollout);
#: ``net_width`` x ``net_depth`` is ``policy_kwargs.net_arch``; ``log_std_init`` goes into
#: ``policy_kwargs``. A name fixed by ``--n-envs`` or ``--set`` is not sampled.
PPO_SPACE: dict[str, Any] = {
    "n_envs": [32, 64, 128, 256],
    "n_steps": [16, 32, 64, 128, 256],
    "n_minibatches": [1, 2, 4, 8, 16, 32],
    "n_epochs": [1, 3, 5, 10, 20],
    "learning_rate": (1e-5, 3e-3, "log"),
    # low discounts too: an allocation acts mostly within the slot (docs/learning.md)
    "gamma": [0.3, 0.5, 0.7, 0.8, 0.9, 0.95, 0.98, 0.99],
    "gae_lambda": [0.8, 0.9, 0.92, 0.95, 0.98, 0.99, 1.0],
    "clip_range": [0.1, 0.2, 0.3, 0.4],
    "ent_coef": (1e-8, 1e-1, "log"),  # the low end is ~0: no entropy bonus
    "net_width": [32, 64, 128, 256],
    "net_depth": [1, 2, 3],
    "log_std_init": (-4.0, 0.5, "linear"),
}

#: Ports probed (TCP, with a timeout) before a database URL without one is handed to SQLAlchemy.
_DEFAULT_PORTS = {"postgresql": 5432, "mysql": 3306, "mariadb": 3306, "mssql": 1433, "oracle": 1521}
CONNECT_TIMEOUT_S = 10


class StudyConfigError(ValueError):
    """A study flag with a bad value; the message names the flag and the fix."""


@dataclass
class StudyArgs:
    """Settings of a study (``python -m train --optimize``), beside the training :class:`~train.train.Args`.

    Attributes
    ----------
    n_trials : int
        Trials this worker runs (>= 1); every worker of a shared study runs its own ``n_trials``.
    storage : str or None
        Optuna storage URL (``sqlite:///PATH``, ``postgresql://...``, ``mysql+pymysql://...``) or
        ``journal:PATH``; None: ``sqlite:///OUT/study.db``.
    study_name : str or None
        Name of the study in the storage; None: ``<env name>-<algo>``, e.g. ``ISCC-v0-ppo``.
    sampler : str
        ``tpe`` (Optuna's TPESampler, random for the first ``n_startup_trials``) or ``random``.
    pruner : str
        ``median`` (MedianPruner) or ``none``.
    n_startup_trials : int
        Random trials before TPE models the results, and trials before the median pruner prunes.
    trial_timesteps : int or None
        Env steps per trial; None: ``--total-timesteps``, else the YAML's ``n_timesteps``, else 200k.
    n_evaluations : int
        Held-out evaluations reported to Optuna per trial (every ``trial_timesteps / n_evaluations``
        env steps); the median pruner waits for ``max(1, n_evaluations // 3)`` of them.
    """

    n_trials: int = 10
    storage: str | None = None
    study_name: str | None = None
    sampler: str = "tpe"
    pruner: str = "median"
    n_startup_trials: int = 5
    trial_timesteps: int | None = None
    n_evaluations: int = 4


_STUDY_HELP = {
    "n_trials": "trials this worker runs (each worker of a shared study runs its own)",
    "storage": "Optuna storage: sqlite:///PATH, postgresql://USER:PASS@HOST/DB, mysql+pymysql://..., or "
               "journal:PATH (a journal file on a shared filesystem); default sqlite:///OUT/study.db",
    "study_name": "study name in the storage (default <env>-<algo>); workers with the same name share it",
    "sampler": "tpe | random (seeded from --seed and the trial number)",
    "pruner": "median | none",
    "n_startup_trials": "random trials before TPE, and trials before the median pruner prunes",
    "trial_timesteps": "env steps per trial (default --total-timesteps, else the YAML's n_timesteps)",
    "n_evaluations": "held-out evaluations reported to Optuna per trial",
}


def add_study_arguments(ap: argparse.ArgumentParser) -> None:
    """Add ``--optimize``, ``--seeds`` and the :class:`StudyArgs` flags to the ``python -m train`` parser.

    Parameters
    ----------
    ap : argparse.ArgumentParser
        The parser of :func:`iscc_gym.train.train.build_parser`.
    """
    group = ap.add_argument_group("hyperparameter studies (Optuna) and multi-seed runs")
    group.add_argument("--optimize", action="store_true",
                       help="run a study: each trial samples PPO hyperparameters and trains into OUT/trial_<n>")
    group.add_argument("--seeds", default=None, metavar="S0,S1,...",
                       help="train the configuration once per seed into OUT/seed_<s>; summary in OUT/seeds.yml")
    defaults = StudyArgs()
    for f in dataclasses.fields(StudyArgs):
        default = getattr(defaults, f.name)
        kind = int if f.name in ("trial_timesteps",) or isinstance(default, int) else str
        group.add_argument("--" + f.name.replace("_", "-"), type=kind, default=default, help=_STUDY_HELP[f.name])


def study_args_from_namespace(ns: argparse.Namespace) -> StudyArgs:
    """The :class:`StudyArgs` of a namespace parsed by a parser with :func:`add_study_arguments`."""
    return StudyArgs(**{f.name: getattr(ns, f.name) for f in dataclasses.fields(StudyArgs)})


def run_cli(ap: argparse.ArgumentParser, ns: argparse.Namespace, args: Args) -> dict:
    """``python -m train --optimize`` / ``--seeds``: run, print, and turn bad input into a one-line error.

    Parameters
    ----------
    ap : argparse.ArgumentParser
        The parser (for its program name and ``exit``).
    ns : argparse.Namespace
        The parsed flags.
    args : Args
        The training arguments of the same command line.

    Returns
    -------
    dict
        The study summary (:func:`optimize`) or the multi-seed summary (:func:`run_seeds`).
    """
    try:
        if ns.optimize and ns.seeds is not None:
            raise StudyConfigError("--optimize and --seeds: use one (a study, or one configuration over seeds)")
        if ns.optimize:
            result = optimize(args, study_args_from_namespace(ns))
            print(result["report"])
            return result
        return run_seeds(args, parse_seeds(ns.seeds))
    except StudyConfigError as e:
        ap.exit(2, f"{ap.prog}: error: {e}\n")


# --- validation -----------------------------------------------------------------------------------------

def parse_seeds(text: str) -> list[int]:
    """``"0,1,2"`` -> ``[0, 1, 2]``.

    Raises
    ------
    StudyConfigError
        Empty, non-integer, negative or repeated seeds.
    """
    try:
        seeds = [int(s) for s in text.split(",")]
    except ValueError:
        raise StudyConfigError(f"--seeds {text!r}: use comma-separated integers, e.g. --seeds 0,1,2,3,4") from None
    if any(s < 0 for s in seeds) or len(set(seeds)) != len(seeds):
        raise StudyConfigError(f"--seeds {text!r}: use distinct non-negative integers, e.g. --seeds 0,1,2,3,4")
    return seeds


def _check_study(args: Args, study: StudyArgs) -> None:
    if args.algo != "ppo":
        raise StudyConfigError(f"--algo {args.algo}: the study's search space is PPO's; use --algo ppo "
                               "(--seeds runs a fixed configuration of any algorithm)")
    if study.sampler not in SAMPLERS:
        raise StudyConfigError(f"--sampler {study.sampler!r}: use one of {', '.join(SAMPLERS)}")
    if study.pruner not in PRUNERS:
        raise StudyConfigError(f"--pruner {study.pruner!r}: use one of {', '.join(PRUNERS)}")
    for name in ("n_trials", "n_evaluations", "trial_timesteps"):
        value = getattr(study, name)
        if value is not None and value < 1:
            raise StudyConfigError(f"--{name.replace('_', '-')} {value}: use an integer >= 1")
    if study.n_startup_trials < 0:
        raise StudyConfigError(f"--n-startup-trials {study.n_startup_trials}: use an integer >= 0")
    if args.resume:
        raise StudyConfigError("--resume: a study starts every trial afresh; drop --resume")
    try:
        _check(args)
        _, hp = resolve_args(args)
        check_hyperparams(args.algo, _resolve_policy_kwargs(hp))
    except ValueError as e:
        raise StudyConfigError(str(e)) from None


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
        ``RDBStorage`` (heartbeat every 60 s: a killed worker's trial is marked failed) or
        ``JournalStorage``.
    shown : str
        The URL as printed (no password).

    Raises
    ------
    StudyConfigError
        Unparsable URL, unknown dialect, missing driver, unreachable host (TCP probe with a
        ``CONNECT_TIMEOUT_S`` timeout, and the same connect timeout for the driver) or a database
        that cannot be opened.
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
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        try:
            from optuna.storages.journal import JournalFileBackend

            return optuna.storages.JournalStorage(JournalFileBackend(path)), url
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
                storage = optuna.storages.RDBStorage(url, engine_kwargs=engine_kwargs, heartbeat_interval=60,
                                                     grace_period=180)
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


# --- the search space and the trial -----------------------------------------------------------------------

def _minibatch_size(rollout: int, n_minibatches: int) -> int:
    """The largest minibatch size ``rollout / k`` with ``k <= n_minibatches`` dividing the rollout, >= 2."""
    k = max(1, min(n_minibatches, rollout // 2))
    while rollout % k:
        k -= 1
    return rollout // k


def sample_ppo_params(trial: optuna.Trial, base: Mapping[str, Any], fixed: Mapping[str, Any]) -> tuple[int, dict]:
    """Sample one PPO configuration from :data:`PPO_SPACE`.

    Parameters
    ----------
    trial : optuna.Trial
        The trial that records the draws.
    base : mapping
        The YAML entry with the ``--set`` overrides (its ``policy_kwargs``, e.g. ``activation_fn``, are kept).
    fixed : mapping
        Values not to sample: ``n_envs``, any PPO keyword (``n_steps``, ``batch_size``...) and
        ``policy_kwargs.<key>`` (``policy_kwargs.net_arch``, ``policy_kwargs.log_std_init``).

    Returns
    -------
    n_envs : int
        Parallel envs.
    overrides : dict
        PPO keyword arguments for :attr:`Args.overrides` (``batch_size`` divides ``n_envs * n_steps``).
    """

    def pick(name: str) -> Any:
        if name in fixed:
            return fixed[name]
        space = PPO_SPACE[name]
        if isinstance(space, list):
            return trial.suggest_categorical(name, space)
        low, high, scale = space
        return trial.suggest_float(name, low, high, log=scale == "log")

    n_envs = int(pick("n_envs"))
    hp: dict[str, Any] = {"n_steps": int(pick("n_steps"))}
    rollout = n_envs * hp["n_steps"]
    hp["batch_size"] = int(fixed["batch_size"]) if "batch_size" in fixed else _minibatch_size(rollout,
                                                                                            pick("n_minibatches"))
    for name in ("n_epochs", "learning_rate", "gamma", "gae_lambda", "clip_range", "ent_coef"):
        hp[name] = pick(name)
    pk = dict(base.get("policy_kwargs") or {})
    if "policy_kwargs.net_arch" in fixed:
        pk["net_arch"] = fixed["policy_kwargs.net_arch"]
    else:
        pk["net_arch"] = [int(pick("net_width"))] * int(pick("net_depth"))
    key = "policy_kwargs.log_std_init"
    pk["log_std_init"] = float(fixed[key] if key in fixed else pick("log_std_init"))
    hp["policy_kwargs"] = pk
    return n_envs, hp


def _fixed_values(args: Args) -> dict:
    fixed = dict(args.overrides)
    for key, value in (args.overrides.get("policy_kwargs") or {}).items():
        fixed[f"policy_kwargs.{key}"] = value
    if args.n_envs is not None:
        fixed["n_envs"] = args.n_envs
    return fixed


def _trial_callback(trial: optuna.Trial):
    """An EvalCallback ``callback_after_eval`` that reports each held-out evaluation to ``trial``.

    Reports ``parent.last_mean_reward`` at step ``k`` (the k-th evaluation, so trials of different
    ``n_envs`` are compared at the same point of their budget; every evaluation plays the same
    held-out episodes, :func:`iscc_gym.train.train.main` re-seeds them) and stops training, setting
    ``pruned``, when the pruner says so.
    """
    from stable_baselines3.common.callbacks import BaseCallback

    class TrialEvalCallback(BaseCallback):
        def __init__(self):
            super().__init__()
            self.trial = trial
            self.evaluations: list[tuple[int, float]] = []
            self.pruned = False

        def _on_step(self) -> bool:
            value = float(self.parent.last_mean_reward)
            self.evaluations.append((int(self.parent.num_timesteps), value))
            self.trial.report(value, len(self.evaluations))
            if self.trial.should_prune():
                self.pruned = True
                return False
            return True

    return TrialEvalCallback()


def evaluate_run(args: Args) -> tuple[float, float]:
    """Mean and std of the episode rewards of the model saved in ``args.out`` on the held-out seeds.

    The episodes are those of the EvalCallback's first evaluation (seeds ``EVAL_SEED_START + i``,
    ``args.eval_episodes`` of them, ``args.eval_max_steps`` slots at most), deterministic actions, with
    the run's VecNormalize statistics (frozen).

    Parameters
    ----------
    args : Args
        The arguments the run was trained with.

    Returns
    -------
    mean, std : float
        Over the ``args.eval_episodes`` episodes.
    """
    from iscc_gym.train.train import make_eval_env
    from stable_baselines3 import PPO, SAC, TD3
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.vec_env import VecNormalize

    args, _ = resolve_args(args)
    out = Path(args.out)
    env = make_eval_env(args)
    if args.normalize:
        env = VecNormalize.load(str(out / "vecnormalize.pkl"), env)
        env.training, env.norm_reward = False, False
    model = {"ppo": PPO, "sac": SAC, "td3": TD3}[args.algo].load(str(out / "model.zip"), device="cpu")
    rewards, _ = evaluate_policy(model, env, n_eval_episodes=args.eval_episodes, deterministic=True,
                                 return_episode_rewards=True)
    env.close()
    return float(np.mean(rewards)), float(np.std(rewards))


def _budget(args: Args, study: StudyArgs) -> int:
    if study.trial_timesteps is not None:
        return study.trial_timesteps
    return int(args.total_timesteps if args.total_timesteps is not None else resolve_args(args)[0].total_timesteps)


def make_objective(args: Args, study: StudyArgs) -> Callable[[optuna.Trial], float]:
    """The objective: sample, train into ``OUT/trial_<n>`` reporting evaluations, return the final reward.

    Parameters
    ----------
    args : Args
        Training arguments shared by every trial (env, ``--set`` overrides, eval settings, seed).
    study : StudyArgs
        The study settings (budget and evaluations per trial).

    Returns
    -------
    callable
        ``objective(trial) -> float``; raises ``optuna.TrialPruned`` when the pruner stops a trial.
    """
    import optuna

    base = load_hyperparams(args.hyperparams, args.env_id, args.algo, args.overrides)
    fixed = _fixed_values(args)
    budget = _budget(args, study)

    def objective(trial: optuna.Trial) -> float:
        n_envs, hp = sample_ppo_params(trial, base, fixed)
        run = dataclasses.replace(args, n_envs=n_envs, total_timesteps=budget, overrides={**args.overrides, **hp},
                                  out=str(Path(args.out) / f"trial_{trial.number}"),
                                  eval_freq=max(n_envs, budget // study.n_evaluations))
        resolved, kwargs = resolve_args(run)
        trial.set_user_attr("n_envs", n_envs)
        trial.set_user_attr("n_timesteps", budget)
        trial.set_user_attr("normalize", bool(resolved.normalize))
        trial.set_user_attr("hyperparams", kwargs)
        trial.set_user_attr("out", str(Path(run.out).resolve()))
        trial.set_user_attr("worker", f"{socket.gethostname()}:{os.getpid()}")
        callback = _trial_callback(trial)
        t0 = time.perf_counter()
        summary = main(run, callback_after_eval=callback)
        trial.set_user_attr("wall_time_s", time.perf_counter() - t0)
        trial.set_user_attr("timesteps", summary["timesteps"])
        if callback.pruned:
            raise optuna.TrialPruned(f"evaluation {len(callback.evaluations)}: {callback.evaluations[-1][1]:.1f} "
                                     f"at {callback.evaluations[-1][0]} steps")
        mean, std = evaluate_run(run)
        trial.set_user_attr("final_reward_std", std)
        if not math.isfinite(mean):
            raise FloatingPointError(f"final held-out reward {mean}")
        return mean

    return objective


def open_study(args: Args, study: StudyArgs):
    """Create or join (``load_if_exists``) the study of ``study.storage`` / ``study.study_name``.

    Parameters
    ----------
    args : Args
        Training arguments (``out`` holds the default storage, ``seed`` seeds the sampler).
    study : StudyArgs
        The study settings.

    Returns
    -------
    study : optuna.Study
        Direction ``maximize``.
    shown : str
        The storage URL as printed (no password).

    Raises
    ------
    StudyConfigError
        Bad flags, an unusable storage, or an existing study of that name that minimizes.
    """
    import optuna

    _check_study(args, study)
    storage, shown = make_storage(study.storage, args.out)
    name = study.study_name or f"{args.env_id.split('/')[-1]}-{args.algo}"
    sampler = make_sampler(study.sampler, args.seed, study.n_startup_trials)
    pruner = make_pruner(study.pruner, study.n_startup_trials, study.n_evaluations)
    s = optuna.create_study(storage=storage, study_name=name, direction="maximize", sampler=sampler, pruner=pruner,
                            load_if_exists=True)
    if s.directions != [optuna.study.StudyDirection.MAXIMIZE]:
        found = " and ".join(d.name.lower() for d in s.directions)
        raise StudyConfigError(f"--study-name {name}: the study of that name in {shown} has direction {found}; this "
                               "objective (held-out reward) is maximized: choose another --study-name")
    return s, shown


def optimize(args: Args, study: StudyArgs) -> dict:
    """Run ``study.n_trials`` trials of a (possibly shared) study and export its best trial.

    Parameters
    ----------
    args : Args
        Training arguments shared by every trial.
    study : StudyArgs
        The study settings.

    Returns
    -------
    dict
        ``study`` (the ``optuna.Study``), ``best_path`` (``OUT/best_hyperparams.yml``, None before a trial
        completes), ``best`` (the exported entry) and ``report`` (the printed text).

    Notes
    -----
    Every trial trains with the same ``args.seed`` (trials are compared on paired training draws). A
    trial that raises ``ValueError`` (e.g. torch rejecting NaN action means after a diverged update)
    or ``FloatingPointError`` is recorded as failed and the worker goes on; any other exception
    stops the worker.
    """
    import optuna
    from iscc_gym.train.train import _progress

    s, shown = open_study(args, study)
    bar = _progress(args)  # trials done / total (each trial's own bar is off)
    if args.quiet:
        optuna.logging.set_verbosity(optuna.logging.WARNING)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        s.optimize(make_objective(dataclasses.replace(args, progress_bar=False), study), n_trials=study.n_trials,
                   catch=(ValueError, FloatingPointError), gc_after_trial=True, show_progress_bar=bar)
    states = [t.state for t in s.get_trials(deepcopy=False)]
    counts = ", ".join(f"{sum(x == st for x in states)} {st.name.lower()}" for st in
                       (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED,
                        optuna.trial.TrialState.FAIL, optuna.trial.TrialState.RUNNING))
    lines = [f"study {s.study_name!r} in {shown}: {len(states)} trials ({counts})"]
    result: dict[str, Any] = {"study": s, "best_path": None, "best": None}
    best = best_trial(s)
    if best is not None:
        path = Path(args.out) / "best_hyperparams.yml"
        text = export_best(s, args.env_id, args.algo, path)
        result.update(best_path=str(path), best=yaml.safe_load(text))
        lines += [f"best trial #{best.number}: held-out reward {best.value:.2f} -> {path}", text.rstrip()]
    else:
        lines.append("no completed trial yet: nothing exported")
    result["report"] = "\n".join(lines)
    return result


def best_trial(s: optuna.Study) -> optuna.trial.FrozenTrial | None:
    """The completed trial of highest value that :func:`make_objective` ran (None if there is none yet)."""
    import optuna

    done = [t for t in s.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))
            if "hyperparams" in t.user_attrs and t.value is not None]
    return max(done, key=lambda t: t.value, default=None)


def best_entry(trial: optuna.trial.FrozenTrial, env_id: str, algo: str) -> dict:
    """The hyperparams.yml content of a completed trial, in rl-zoo3's layout.

    Parameters
    ----------
    trial : optuna.trial.FrozenTrial
        A trial run by :func:`make_objective` (its user attributes hold the configuration).
    env_id, algo : str
        The env id of the entry and the algorithm (named under ``iscc_gym.train.algo``).

    Returns
    -------
    dict
        ``{env_id: entry, "iscc_gym.train": {"algo": algo}}``: the entry holds ``n_timesteps``, ``n_envs``,
        ``normalize`` (read by :func:`iscc_gym.train.train.resolve_args` and by rl-zoo3) and the
        algorithm's keyword arguments, ``policy_kwargs`` as rl-zoo3's ``dict(...)`` string.
    """
    from iscc_gym.train.train import OWN_SECTION, format_policy_kwargs

    attrs = trial.user_attrs
    hp = dict(attrs["hyperparams"])
    if hp.get("policy_kwargs"):
        hp["policy_kwargs"] = format_policy_kwargs(hp["policy_kwargs"])
    entry = {"n_timesteps": int(attrs["n_timesteps"]), "n_envs": int(attrs["n_envs"]),
             "normalize": bool(attrs["normalize"]), **hp}
    return {env_id: entry, OWN_SECTION: {"algo": algo}}


def export_best(s: optuna.Study, env_id: str, algo: str, path: str | os.PathLike) -> str:
    """Write the best trial as a hyperparams.yml entry to ``path`` (temporary name, then rename).

    Parameters
    ----------
    s : optuna.Study
        A study with at least one completed trial run by :func:`make_objective` (:func:`best_trial`).
    env_id, algo : str
        The keys of the entry.
    path : path-like
        Destination, e.g. ``OUT/best_hyperparams.yml``.

    Returns
    -------
    str
        The YAML text written.
    """
    best = best_trial(s)
    if best is None:
        raise ValueError(f"study {s.study_name!r} has no completed trial to export yet")
    header = (f"# Best trial #{best.number} of Optuna study {s.study_name!r}: final held-out mean episode reward "
              f"{best.value:.4f}\n# ({len(s.trials)} trials in the study when exported). Train it with:\n"
              f"#   python -m train --hyperparams {path}\n"
              f"# or rl-zoo3 (its layout): python -m rl_zoo3.train --algo {algo} --env {env_id} "
              f"--gym-packages iscc_gym -conf {path}\n")
    text = header + yaml.safe_dump(best_entry(best, env_id, algo), sort_keys=False)
    write_atomic(path, text)
    return text


# --- several seeds of one configuration -------------------------------------------------------------------

def run_seeds(args: Args, seeds: list[int]) -> dict:
    """Train the configuration of ``args`` once per seed into ``OUT/seed_<s>`` and summarise.

    Parameters
    ----------
    args : Args
        The configuration (YAML entry, ``--set`` overrides, run settings); ``seed`` and ``out`` are
        replaced per seed.
    seeds : list of int
        Training seeds.

    Returns
    -------
    dict
        ``runs`` (per seed: ``seed``, ``out``, ``final_reward_mean``, ``final_reward_std``, ``timesteps``,
        ``train_time_s`` of ``model.learn``, ``wall_time_s`` of the run and its final evaluation), the
        mean and std over seeds of the final held-out reward, ``hyperparams`` (the resolved
        configuration) and ``path`` of ``OUT/seeds.yml`` (written atomically).
    """
    if not seeds:
        raise StudyConfigError("--seeds: name at least one seed, e.g. --seeds 0,1,2")
    try:
        _check(args)
        resolved, hp = resolve_args(args)
        check_hyperparams(args.algo, _resolve_policy_kwargs(hp))
    except ValueError as e:
        raise StudyConfigError(str(e)) from None
    rows = []
    for seed in seeds:
        run = dataclasses.replace(args, seed=seed, out=str(Path(args.out) / f"seed_{seed}"))
        t0 = time.perf_counter()
        summary = main(run)
        mean, std = evaluate_run(run)
        rows.append({"seed": seed, "out": run.out, "final_reward_mean": mean, "final_reward_std": std,
                     "timesteps": summary["timesteps"], "train_time_s": round(summary["wall_time_s"], 3),
                     "wall_time_s": round(time.perf_counter() - t0, 3)})
    finals = [r["final_reward_mean"] for r in rows]
    result = {"env_id": args.env_id, "algo": args.algo, "n_timesteps": resolved.total_timesteps,
              "n_envs": resolved.n_envs, "eval_episodes": args.eval_episodes, "eval_seed_start": EVAL_SEED_START,
              "final_reward_mean": float(np.mean(finals)),
              "final_reward_std": float(np.std(finals, ddof=1)) if len(finals) > 1 else 0.0,
              "runs": rows, "hyperparams": hp}
    path = Path(args.out) / "seeds.yml"
    write_atomic(path, yaml.safe_dump(result, sort_keys=False))
    result["path"] = str(path)
    print(format_seed_table(result))
    return result


def format_seed_table(result: dict) -> str:
    """The per-seed table of :func:`run_seeds` as printed."""
    lines = [f"{'seed':>6}  {'final held-out reward':>24}  {'wall s':>8}  out"]
    for r in result["runs"]:
        lines.append(f"{r['seed']:>6}  {r['final_reward_mean']:>12.2f} +- {r['final_reward_std']:<9.2f}  "
                     f"{r['wall_time_s']:>8.1f}  {r['out']}")
    lines.append(f"{'mean':>6}  {result['final_reward_mean']:>12.2f} +- {result['final_reward_std']:<9.2f}  "
                 f"{'':>8}  (std over seeds; {result['eval_episodes']} held-out episodes per seed)")
    return "\n".join(lines)
