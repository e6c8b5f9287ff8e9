"""Train an SB3 agent (PPO by default; SAC, TD3) on ``iscc_gym/ISCC-v0``.

Usage::

    python -m train --total-timesteps 200000 --n-envs 4 --vec-env batched --out runs/ppo
    python -m train --out runs/ppo --resume --total-timesteps 400000   # continue that run

Writes into ``--out`` (new or empty; ``--resume`` continues a run there, ``--overwrite`` deletes it):
``model.zip`` + ``vecnormalize.pkl`` (the final model and its statistics), ``best/`` (the best model
on the held-out eval seeds with its own statistics), ``checkpoints/step_<N>/`` (model, statistics and,
for SAC/TD3, the replay buffer, for ``--resume``), ``eval/evaluations.npz``, ``config.yml`` (the
resolved configuration), ``learning_curve.csv`` and ``.png``, ``summary.yml`` and TensorBoard logs in
``tb/`` (``tensorboard --logdir OUT/tb``). Each model directory is a unit: every file is written under
a temporary name and renamed, and its ``manifest.yml`` (sizes and SHA-256 of the files) last, so an
interrupted write is never taken for a complete one. Model files and ``vecnormalize.pkl`` are
pickles: load only files you trust.

The hyperparameters come from ``train/hyperparams.yml``, in rl-zoo3's layout (env id -> the PPO
hyperparameters; ``python -m rl_zoo3.train --algo ppo --env iscc_gym/ISCC-v0 --gym-packages iscc_gym
-conf train/hyperparams.yml`` trains the same configuration); its ``iscc_gym.train`` key, which
rl-zoo3 never reads, holds this command's own run settings (the warm start) and the SAC/TD3 entries.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import io
import os
import re
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from iscc_gym.agents.sb3_logging import stdout_logger
from iscc_gym.agents.sb3_policy import MANIFEST, read_manifest, write_manifest

from iscc_gym.files import atomic_target, write_atomic

HYPERPARAMS = Path(__file__).with_name("hyperparams.yml")
ALGOS = ("ppo", "sac", "td3")
VEC_ENVS = ("dummy", "subproc", "batched")
#: Seeds of the EvalCallback's held-out episodes start here (training seeds are small integers, the
#: final comparison uses ``eval --seed-start``'s, 10_000 by default).
EVAL_SEED_START = 1_000_000
#: Seeds of the behaviour-cloning warm start's missions: INIT_SEED_START + 1000 * seed + i (training
#: seeds, disjoint from every evaluation seed).
INIT_SEED_START = 200_000


@dataclass
class Args:
    """Everything a training run depends on (``python -m train --help`` lists them; :data:`FIELD_HELP`)."""

    env_id: str = "iscc_gym/ISCC-v0"
    algo: str = "ppo"  # ppo | sac | td3
    # None: the YAML entry's ``n_timesteps`` / ``n_envs`` (rl-zoo3's keys), else RUN_DEFAULTS
    total_timesteps: int | None = None
    n_envs: int | None = None
    vec_env: str = "batched"  # dummy | subproc | batched (the native batched env)
    seed: int = 0
    scenario: str = "paper"
    env_overrides: dict = field(default_factory=dict)  # Scenario field overrides, e.g. {"observation_source": "gnss"}
    out: str = "runs/ppo"
    hyperparams: str = str(HYPERPARAMS)
    overrides: dict = field(default_factory=dict)  # hyperparameter overrides, e.g. {"n_steps": 64}
    normalize: bool | None = None  # VecNormalize of observations and rewards (None: the YAML's, else True)
    # warm start by behaviour cloning of a scripted policy (agents.make_policy spec; train/pretrain.py);
    # None: the YAML's init_policy / init_envs / init_steps (steps per env) / init_log_std
    init_policy: str | None = None
    init_envs: int | None = None
    init_steps: int | None = None
    init_log_std: float | None = None
    eval_freq: int = 500_000  # env steps between evaluations (0: none)
    eval_episodes: int = 8
    eval_max_steps: int = 5000  # slots per eval episode (the full mission by default)
    checkpoint_freq: int = 1_000_000  # env steps between checkpoints (0: none)
    resume: bool = False  # continue from the newest complete checkpoint in ``out``
    overwrite: bool = False  # start afresh in a non-empty ``out`` (its previous run's files are deleted)
    tensorboard: bool = True
    progress_bar: bool | None = None  # None: on a terminal (stdout a TTY) unless ``quiet``
    quiet: bool = False  # no progress bar, no closing line
    torch_threads: int = 1  # threads of torch (1 is fastest here: python -m eval.bench)
    numba_threads: int | None = None  # threads of the env's compiled kernel (None: numba's default, all cores)
    verbose: int = 0


#: The ``--help`` text of every :class:`Args` field.
FIELD_HELP = {
    "env_id": "Gymnasium env id to train on (an entry of --hyperparams)",
    "algo": "SB3 algorithm: ppo | sac | td3",
    "total_timesteps": "env steps to train (default: the YAML entry's n_timesteps, else 200000)",
    "n_envs": "parallel envs (default: the YAML entry's n_envs, else 4)",
    "vec_env": "dummy | subproc | batched (the ISCC env's own batched env, fastest)",
    "seed": "training seed (envs, networks, sampling)",
    "scenario": "Scenario preset of the env (e.g. paper)",
    "out": "run directory; must be empty or new unless --resume or --overwrite",
    "hyperparams": "hyperparameter YAML in rl-zoo3's layout (env id -> hyperparameters; see train/hyperparams.yml)",
    "normalize": "VecNormalize observations and rewards (default: the YAML entry's normalize, else on)",
    "init_policy": "warm start: behaviour-clone this scripted policy (agents.make_policy spec, e.g. myopic; "
                   "none: no warm start; default: the YAML's)",
    "init_envs": "envs the scripted policy plays during the warm start (default: the YAML's, else 16)",
    "init_steps": "steps per env of the warm start (default: the YAML's, else 5000)",
    "init_log_std": "log standard deviation of the actions after the warm start (default: the YAML's, else kept)",
    "eval_freq": "env steps between held-out evaluations (0: none); the best model goes to OUT/best/",
    "eval_episodes": "held-out missions per evaluation (seeds from 1,000,000)",
    "eval_max_steps": "slots per held-out episode at most (the full mission by default)",
    "checkpoint_freq": "env steps between checkpoints in OUT/checkpoints/ (0: none)",
    "resume": "continue the run in OUT from its newest complete checkpoint (same algo, env, scenario, "
              "normalisation)",
    "overwrite": "start afresh in a non-empty OUT: its previous run's files are deleted first",
    "tensorboard": "write TensorBoard logs to OUT/tb (tensorboard --logdir OUT/tb)",
    "progress_bar": "show a progress bar (default: on a terminal unless --quiet)",
    "quiet": "no progress bar and no closing line",
    "torch_threads": "torch threads (1 is fastest here: python -m eval.bench)",
    "numba_threads": "threads of the env's compiled kernel (default: all cores)",
    "verbose": "SB3 verbosity: 0 quiet, 1 training logs, 2 debug",
}

#: Run settings a YAML entry may hold beside the algorithm's hyperparameters (rl-zoo3's names), mapped
#: to the :class:`Args` field they fill, and the value used when neither the flag nor the YAML sets it.
#: ``init_*`` are python -m train's own: in a file rl-zoo3 reads too, they go under ``iscc_gym.train.settings``.
RUN_KEYS = {"n_timesteps": "total_timesteps", "n_envs": "n_envs", "normalize": "normalize",
            "init_policy": "init_policy", "init_envs": "init_envs", "init_steps": "init_steps",
            "init_log_std": "init_log_std"}
RUN_DEFAULTS = {"total_timesteps": 200_000, "n_envs": 4, "normalize": True, "init_policy": None, "init_envs": 16,
                "init_steps": 5000, "init_log_std": None}


def _to_int(v):
    f = float(v)
    if not f.is_integer():
        raise ValueError
    return int(f)


def _to_bool(v):
    if not isinstance(v, bool):
        raise ValueError
    return v


_RUN_TYPES = {"total_timesteps": _to_int, "n_envs": _to_int, "normalize": _to_bool, "init_policy": str,
              "init_envs": _to_int, "init_steps": _to_int, "init_log_std": float}

#: The key of a hyperparameter file that only python -m train reads (rl-zoo3 reads the entry of its env id).
OWN_SECTION = "iscc_gym.train"
_ACTIVATIONS = {"Tanh": "tanh", "ReLU": "relu", "ELU": "elu", "LeakyReLU": "leaky_relu", "GELU": "gelu"}


def parse_policy_kwargs(value, where: str = "policy_kwargs") -> dict:
    """``policy_kwargs`` of a YAML entry as a dict, activation functions as names (``"tanh"``).

    Reads rl-zoo3's string form ``"dict(net_arch=[64, 64], activation_fn=nn.Tanh)"`` without eval'ing
    it: only ``dict(...)`` / ``{...}`` of literals and ``nn.<activation>`` names are accepted. A YAML
    mapping is taken as it is.

    Raises
    ------
    ValueError
        Anything else in the string (a call, a name, an unknown activation).
    """
    import ast

    if value is None:
        return {}
    if isinstance(value, dict):
        return dict(value)
    if not isinstance(value, str):
        raise ValueError(f"{where} = {value!r}; use a mapping or rl-zoo3's string 'dict(net_arch=[64, 64])'")

    def read(node):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "dict" \
                and not node.args and all(k.arg for k in node.keywords):
            return {k.arg: read(k.value) for k in node.keywords}
        if isinstance(node, ast.Dict):
            return {ast.literal_eval(k): read(v) for k, v in zip(node.keys, node.values, strict=True)}
        if isinstance(node, ast.List | ast.Tuple):
            return [read(e) for e in node.elts]
        if isinstance(node, ast.Attribute) and node.attr in _ACTIVATIONS and ast.unparse(node.value) in (
                "nn", "th.nn", "torch.nn"):
            return _ACTIVATIONS[node.attr]
        return ast.literal_eval(node)

    try:
        out = read(ast.parse(value.strip(), mode="eval").body)
    except (SyntaxError, ValueError, TypeError):
        raise ValueError(f"{where} = {value!r}: python -m train reads dict(...) of literals and nn.<activation> "
                         f"({', '.join('nn.' + a for a in _ACTIVATIONS)}) and evaluates nothing else") from None
    if not isinstance(out, dict):
        raise ValueError(f"{where} = {value!r}: use dict(...)")
    return out


def format_policy_kwargs(pk: dict) -> str:
    """The rl-zoo3 string of ``policy_kwargs`` (inverse of :func:`parse_policy_kwargs`)."""
    names = {v: k for k, v in _ACTIVATIONS.items()}

    def fmt(key, v):
        if isinstance(v, dict):
            return "dict(" + ", ".join(f"{k}={fmt(k, x)}" for k, x in v.items()) + ")"
        if isinstance(v, list | tuple):
            return "[" + ", ".join(fmt(None, x) for x in v) + "]"
        if key == "activation_fn" and isinstance(v, str):
            if v.lower() not in names:
                raise ValueError(f"policy_kwargs.activation_fn = {v!r}; use one of {sorted(names)}")
            return "nn." + names[v.lower()]
        return repr(v)

    return fmt(None, dict(pk))


def _entries(table: dict, path, algo: str, env_id: str) -> tuple[dict, dict]:
    """``(entries by env id, python -m train's settings by env id)`` of ``algo`` in a hyperparameter file."""
    own = table.pop(OWN_SECTION, None) or {}
    if not isinstance(own, dict) or set(own) - {"algo", "settings", *ALGOS}:
        raise ValueError(f"{path}: {OWN_SECTION} holds algo, settings and entries per algorithm ({', '.join(ALGOS)}); "
                         f"found {sorted(own) if isinstance(own, dict) else own!r}")
    file_algo = own.get("algo")
    if algo in own and algo != file_algo:
        return dict(own[algo] or {}), {}
    if file_algo not in (None, algo):
        raise ValueError(f"algo {algo!r} has no entry for {env_id} in {path}: its entries are {file_algo}'s "
                         f"(rl-zoo3's layout, one algorithm per file); add {OWN_SECTION}.{algo}.{env_id} or pass "
                         f"--hyperparams with a file of {algo} entries")
    return table, dict(own.get("settings") or {})


def load_hyperparams(path: str | os.PathLike, env_id: str, algo: str, overrides: dict | None = None) -> dict:
    """The hyperparameters of ``algo`` on ``env_id`` from the YAML file, with ``overrides`` applied.

    The file is in rl-zoo3's layout (env id -> hyperparameters of one algorithm, e.g.
    ``train/hyperparams.yml``); its ``iscc_gym.train`` key (which rl-zoo3 never reads) names that
    algorithm (``algo``), holds python -m train's own run settings per env id (``settings``) and other
    algorithms' entries (``sac``, ``td3``). The older layout (env id -> algo -> hyperparameters) is
    read too. ``policy_kwargs`` comes back as a dict, activations as names (:func:`parse_policy_kwargs`,
    never eval'd); the run settings of :data:`RUN_KEYS` stay in the dict; :func:`resolve_args` takes them out.
    """
    try:
        with open(path) as f:
            table = yaml.safe_load(f)
    except yaml.YAMLError as e:
        raise ValueError(f"{path}: not valid YAML ({str(e).splitlines()[0]})") from None
    if not isinstance(table, dict):
        raise ValueError(f"{path}: expected a mapping of env ids to hyperparameters (rl-zoo3's layout)")
    entries, settings = _entries(table, path, algo, env_id)
    if env_id not in entries:
        raise ValueError(f"env_id {env_id!r} has no entry in {path}; add one (keys: {sorted(entries)})")
    entry = entries[env_id]
    if isinstance(entry, dict) and entry and set(entry) <= set(ALGOS) and all(isinstance(v, dict) for v in
                                                                             entry.values()):
        if algo not in entry:  # the older layout: env id -> algo -> hyperparameters
            raise ValueError(f"algo {algo!r} has no entry for {env_id} in {path}; add one or use {sorted(entry)}")
        entry = entry[algo]
    if not isinstance(entry, dict):
        raise ValueError(f"{path}: the entry of {env_id} is {entry!r}; use a mapping of hyperparameters")
    hp = {**dict(settings.get(env_id) or {}), **entry}
    hp.update(overrides or {})
    if "policy_kwargs" in hp:
        hp["policy_kwargs"] = parse_policy_kwargs(hp["policy_kwargs"])
    return hp


def resolve_args(args: Args) -> tuple[Args, dict]:
    """``(args, hyperparameters)``: the run settings that ``args`` leaves at None filled from the
    YAML entry (``n_timesteps``, ``n_envs``, ``normalize``, ``init_*``), else from :data:`RUN_DEFAULTS`;
    rl-zoo3's ``env_kwargs`` join ``env_overrides`` (a flag wins); the returned hyperparameters are the
    algorithm's keyword arguments only."""
    hp = load_hyperparams(args.hyperparams, args.env_id, args.algo, args.overrides)
    filled: dict[str, Any] = {}
    for key, name in RUN_KEYS.items():
        value = hp.pop(key, None)
        if getattr(args, name) is None:
            value = RUN_DEFAULTS[name] if value is None else value
            if value is None:
                filled[name] = None
                continue
            try:
                filled[name] = _RUN_TYPES[name](value)
            except (TypeError, ValueError):
                kind = {"normalize": "true or false", "init_policy": "a policy spec",
                        "init_log_std": "a number"}.get(name, "an integer")
                raise ValueError(f"{key} = {value!r} in {args.hyperparams} or --set; use {kind}") from None
    env_kwargs = hp.pop("env_kwargs", None) or {}
    if not isinstance(env_kwargs, dict):
        raise ValueError(f"env_kwargs = {env_kwargs!r}; use a mapping of Scenario fields")
    if env_kwargs:
        filled["env_overrides"] = {**env_kwargs, **args.env_overrides}
    return dataclasses.replace(args, **filled), hp


def check_hyperparams(algo: str, hp: dict) -> dict:
    """Names and types of the algorithm's keyword arguments, checked against its constructor; returns
    them with whole numbers where it takes integers (``n_steps: 6.4e1`` -> 64).

    Raises
    ------
    ValueError
        An unknown name (with the closest known ones), or a text or other non-number where the
        algorithm takes a number (e.g. ``--set n_steps=abc``), or a fraction where it takes an integer.
    """
    import difflib
    import inspect

    from stable_baselines3 import PPO, SAC, TD3

    cls = {"ppo": PPO, "sac": SAC, "td3": TD3}[algo]
    params = inspect.signature(cls.__init__).parameters
    extra = {"noise_type", "noise_std"} if algo in ("sac", "td3") else set()
    hp = dict(hp)
    for key, value in hp.items():
        if key in extra:
            continue
        if key not in params or key in ("self", "env"):
            near = difflib.get_close_matches(key, [p for p in params if p not in ("self", "env")], n=3)
            raise ValueError(f"hyperparameter {key!r} is not an argument of {cls.__name__}"
                             + (f"; did you mean {', '.join(near)}?" if near else ""))
        default = params[key].default
        if isinstance(default, bool) or not isinstance(default, int | float):
            continue
        if key in ("learning_rate", "clip_range", "clip_range_vf") and (isinstance(value, str) or callable(value)):
            continue  # lin_<value> (linear_schedule checks it)
        if key == "train_freq" and isinstance(value, list | tuple):
            continue
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ValueError(f"{key} = {value!r}; use a number")
        if isinstance(default, int):
            if not float(value).is_integer():
                raise ValueError(f"{key} = {value!r}; use an integer")
            hp[key] = int(value)
    return hp


def _resolve_policy_kwargs(hp: dict) -> dict:
    import torch.nn as nn

    hp = dict(hp)
    pk = dict(hp.get("policy_kwargs") or {})
    if "activation_fn" in pk and isinstance(pk["activation_fn"], str):
        names = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU, "leaky_relu": nn.LeakyReLU, "gelu": nn.GELU}
        key = pk["activation_fn"].lower()
        if key not in names:
            raise ValueError(f"policy_kwargs.activation_fn = {pk['activation_fn']!r}; use one of {sorted(names)}")
        pk["activation_fn"] = names[key]
    if pk:
        hp["policy_kwargs"] = pk
    for key in ("learning_rate", "clip_range"):
        if isinstance(hp.get(key), str):
            hp[key] = linear_schedule(hp[key], key)
    if isinstance(hp.get("train_freq"), list):  # rl-zoo3's [1, "episode"]
        hp["train_freq"] = tuple(hp["train_freq"])
    return hp


def _action_noise(kw: dict, n_envs: int, dim: int) -> dict:
    """rl-zoo3's ``noise_type`` (``normal`` | ``ornstein-uhlenbeck``) and ``noise_std`` keys as SB3's
    ``action_noise`` (one independent noise process per env) for SAC/TD3."""
    kw = dict(kw)
    kind, std = kw.pop("noise_type", None), kw.pop("noise_std", None)
    if kind is None:
        if std is not None:
            raise ValueError("noise_std is set without noise_type; add noise_type: normal")
        return kw
    from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise, VectorizedActionNoise

    classes = {"normal": NormalActionNoise, "ornstein-uhlenbeck": OrnsteinUhlenbeckActionNoise}
    if kind not in classes:
        raise ValueError(f"noise_type = {kind!r}; use one of {sorted(classes)}")
    sigma = float(0.1 if std is None else std)
    if not sigma > 0:
        raise ValueError(f"noise_std = {std!r}; use a positive number")
    base = classes[kind](mean=np.zeros(dim), sigma=sigma * np.ones(dim))
    kw["action_noise"] = VectorizedActionNoise(base, n_envs) if n_envs > 1 else base
    return kw


def linear_schedule(text: str, name: str = "learning_rate"):
    """rl-zoo3's ``lin_<value>``: a schedule falling linearly from ``value`` to 0 over training
    (SB3 calls it with the remaining progress, 1 -> 0).

    Raises
    ------
    ValueError
        Not ``lin_`` followed by a positive number.
    """
    try:
        if not text.startswith("lin_"):
            raise ValueError
        start = float(text[len("lin_"):])
        if not start > 0:
            raise ValueError
    except ValueError:
        raise ValueError(f"{name} = {text!r}; use a number or 'lin_<number>' (rl-zoo3's linear schedule, "
                         "e.g. lin_3e-4)") from None

    def schedule(progress_remaining: float) -> float:
        return progress_remaining * start

    return schedule


def _check(args: Args) -> None:
    if args.algo not in ALGOS:
        raise ValueError(f"algo = {args.algo!r}; use one of {ALGOS}")
    if args.vec_env not in VEC_ENVS:
        raise ValueError(f"vec_env = {args.vec_env!r}; use one of {VEC_ENVS}")
    if args.vec_env == "batched" and args.env_id != "iscc_gym/ISCC-v0":
        raise ValueError("vec_env = 'batched' is the ISCC env's own batched env; use dummy or subproc for "
                         f"{args.env_id}")
    for name in ("total_timesteps", "n_envs", "eval_episodes", "eval_max_steps", "torch_threads", "numba_threads"):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            raise ValueError(f"{name} = {getattr(args, name)}; use an integer >= 1")


def make_train_env(args: Args):
    """The training VecEnv, with episode statistics (Monitor / VecMonitor) for the logs."""
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecMonitor

    if args.vec_env == "batched":
        from iscc_gym.agents.sb3_vec_env import ISCCBatchedVecEnv

        venv = ISCCBatchedVecEnv(args.n_envs, scenario=args.scenario, **args.env_overrides)
        venv.seed(args.seed)
        return VecMonitor(venv)
    kwargs = {"scenario": args.scenario, **args.env_overrides} if args.env_id == "iscc_gym/ISCC-v0" else {}
    cls = SubprocVecEnv if args.vec_env == "subproc" else DummyVecEnv
    # make_vec_env wraps each env in a Monitor already
    return make_vec_env(args.env_id, n_envs=args.n_envs, seed=args.seed, vec_env_cls=cls, env_kwargs=kwargs)


def make_eval_env(args: Args):
    """Held-out evaluation episodes: seeds EVAL_SEED_START + i, one sub-env per episode."""
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor

    if args.env_id == "iscc_gym/ISCC-v0":
        from iscc_gym.agents.sb3_vec_env import ISCCBatchedVecEnv

        venv = ISCCBatchedVecEnv(args.eval_episodes, scenario=args.scenario, **args.env_overrides)
        if args.eval_max_steps < venv.venv.max_steps:
            venv.venv.max_steps = args.eval_max_steps
        venv.seed(EVAL_SEED_START)
        return VecMonitor(venv)
    venv = make_vec_env(args.env_id, n_envs=args.eval_episodes, vec_env_cls=DummyVecEnv)
    venv.seed(EVAL_SEED_START)
    return venv


def set_numba_threads(n: int | None) -> None:
    """Threads of the env's compiled kernel: ``n`` (at most numba's ``NUMBA_NUM_THREADS``), or
    numba's default (all of them) for None.

    Raises
    ------
    ValueError
        ``n`` above the threads numba was started with (set ``NUMBA_NUM_THREADS``).
    """
    import numba

    top = numba.config.NUMBA_NUM_THREADS
    if n is not None and not 1 <= n <= top:
        raise ValueError(f"numba_threads = {n}; use 1 to {top} (NUMBA_NUM_THREADS={top} caps it)")
    numba.set_num_threads(top if n is None else n)


def _behaviour_clone(model, venv, args: Args) -> dict:
    """The warm start of :mod:`train.pretrain` (``args.init_policy`` played ``init_steps`` steps per env)."""
    from iscc_gym.agents import make_policy
    from iscc_gym.train.pretrain import behaviour_clone

    if args.algo != "ppo":
        raise ValueError(f"init_policy = {args.init_policy!r} needs algo = 'ppo' (got {args.algo!r}); "
                         "unset init_policy for SAC/TD3")
    from iscc_gym.agents.sb3_vec_env import ISCCBatchedVecEnv
    from stable_baselines3.common.vec_env import VecNormalize

    if not isinstance(venv, VecNormalize) or args.vec_env != "batched":
        raise ValueError("init_policy needs normalize: true and vec_env = 'batched'")
    policy = make_policy(args.init_policy, args.scenario)
    play = ISCCBatchedVecEnv(args.init_envs, scenario=args.scenario, **args.env_overrides)
    play.seed(INIT_SEED_START + 1000 * args.seed)
    play = VecNormalize(play, gamma=venv.gamma, clip_obs=venv.clip_obs, clip_reward=venv.clip_reward)
    res = behaviour_clone(model, venv, policy, args.init_steps, collect_env=play, log_std=args.init_log_std,
                          seed=args.seed, log=print if args.verbose else (lambda *_: None))
    play.close()
    return {"policy": args.init_policy, "envs": args.init_envs, "steps_per_env": args.init_steps, **res}


#: What a run writes into ``out`` (what ``overwrite`` deletes first).
RUN_FILES = ("model.zip", "vecnormalize.pkl", MANIFEST, "config.yml", "summary.yml", "learning_curve.csv",
             "learning_curve.png", "checkpoints", "best", "eval", "tb")
#: What a resumed run must share with the run it continues (SAC/TD3: ``n_envs`` too, the replay buffer's shape).
IDENTITY = ("env_id", "algo", "scenario", "env_overrides", "normalize", "eval_episodes", "eval_max_steps")


def run_identity(args: Args) -> dict:
    """The settings of :data:`IDENTITY` of resolved ``args``, as written into every unit's manifest."""
    ident = {k: getattr(args, k) for k in IDENTITY}
    if args.algo in ("sac", "td3"):
        ident["n_envs"] = args.n_envs
    return yaml.safe_load(yaml.safe_dump(ident))


def save_unit(directory: str | os.PathLike, model, vecnormalize=None, *, model_name: str = "model.zip",
              replay_buffer: bool = False, **meta) -> Path:
    """Save ``model`` with its VecNormalize statistics (and replay buffer) as one unit in ``directory``.

    Every file goes to a temporary name and is renamed (:func:`iscc_gym.files.atomic_target`); the
    manifest (:func:`iscc_gym.agents.sb3_policy.write_manifest`, sizes and SHA-256, plus ``meta``)
    is written last, so a unit interrupted anywhere is recognised as incomplete.
    """
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    files = []
    if vecnormalize is not None:
        with atomic_target(d / "vecnormalize.pkl") as tmp:
            vecnormalize.save(str(tmp))
        files.append("vecnormalize.pkl")
    if replay_buffer:
        with atomic_target(d / "replay_buffer.pkl") as tmp:
            model.save_replay_buffer(tmp)
        files.append("replay_buffer.pkl")
    with atomic_target(d / model_name) as tmp:
        model.save(tmp)
    files.append(model_name)
    write_manifest(d, files, **meta)
    return d


def latest_checkpoint(ckpt_dir: str | os.PathLike) -> tuple[Path | None, dict | None, list[str]]:
    """``(directory, manifest, skipped)`` of the newest complete checkpoint ``ckpt_dir/step_<N>``
    (None, None if there is none); ``skipped`` says why each newer one was passed over."""
    found = []
    for p in Path(ckpt_dir).glob("step_*"):
        m = re.fullmatch(r"step_(\d+)", p.name)
        if m and p.is_dir():
            found.append((int(m.group(1)), p))
    skipped = []
    for _, p in sorted(found, reverse=True):
        try:
            return p, read_manifest(p), skipped
        except (FileNotFoundError, ValueError) as e:
            skipped.append(str(e))
    return None, None, skipped


def _is_run_dir(out: Path) -> bool:
    """Whether ``out`` holds a run of python -m train (its config.yml or manifest), so ``overwrite`` may delete."""
    for name, key in (("config.yml", "args"), (MANIFEST, "files")):
        try:
            if key in yaml.safe_load((out / name).read_text()):
                return True
        except (OSError, yaml.YAMLError, TypeError):
            continue
    return False


def _prepare_out(args: Args) -> tuple[Path | None, dict | None]:
    """Check ``args.out`` for the run: new or empty, or ``overwrite`` (its run files deleted), or
    ``resume`` from its newest complete checkpoint with the same :data:`IDENTITY`. Returns the
    checkpoint's directory and manifest (None, None without ``resume``)."""
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"out {out} is a file; name a directory")
    if args.resume and args.overwrite:
        raise ValueError("--resume and --overwrite: use one (continue the run in OUT, or start afresh)")
    if args.resume:
        ckpt, manifest, skipped = latest_checkpoint(out / "checkpoints")
        for why in skipped:
            print(f"resume: skipped an incomplete checkpoint: {why}")
        if ckpt is None:
            older = " (model_<N>_steps.zip files of an older python -m train carry no manifest: retrain)" if list(
                (out / "checkpoints").glob("model_*_steps.zip")) else ""
            raise FileNotFoundError(f"resume: no complete checkpoint in {out / 'checkpoints'}"
                                    + (f" ({len(skipped)} incomplete)" if skipped else "") + older
                                    + "; train without --resume first (with --checkpoint-freq > 0)")
        was, now = manifest.get("run") or {}, run_identity(args)
        diff = [f"{k} {was.get(k)!r} -> {now[k]!r}" for k in now if was.get(k) != now[k]]
        if diff:
            raise ValueError(f"resume: {out} was trained with other settings ({'; '.join(diff)}); resume with the "
                             "same ones, or train into another --out")
        return ckpt, manifest
    if out.exists() and any(out.iterdir()):
        if not args.overwrite:
            raise FileExistsError(f"out {out} is not empty (a previous run?); pass --resume to continue it, "
                                  "--overwrite to start afresh (deletes its run files), or another --out")
        if not _is_run_dir(out):
            raise FileExistsError(f"--overwrite: {out} holds no run of python -m train (no config.yml or "
                                  f"{MANIFEST} of one); nothing deleted: choose another --out")
        for name in RUN_FILES:
            p = out / name
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            elif p.exists() or p.is_symlink():
                p.unlink()
    return None, None


def _eval_callback(eval_env, args: Args, out: Path, identity: dict, history: dict, best_reward: float,
                   callback_after_eval=None):
    """SB3's EvalCallback playing the same held-out missions at every evaluation (the eval env is
    re-seeded with :data:`EVAL_SEED_START`: a VecEnv forgets its seeds after a reset, and ``best`` is
    chosen on one fixed set of episodes), continuing ``history`` (``evaluations.npz`` of the run it
    resumes), keeping the best model unless beaten, saved as a unit with its own VecNormalize
    statistics in ``out/best``; every file written atomically."""
    from stable_baselines3.common.callbacks import EvalCallback
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.vec_env import sync_envs_normalization

    class HeldOutEvalCallback(EvalCallback):
        def _on_step(self) -> bool:
            if not (self.eval_freq > 0 and self.n_calls % self.eval_freq == 0):
                return True
            self.eval_env.seed(EVAL_SEED_START)
            vecnormalize = self.model.get_vec_normalize_env()
            if vecnormalize is not None:
                sync_envs_normalization(self.training_env, self.eval_env)
            rewards, lengths = evaluate_policy(self.model, self.eval_env, n_eval_episodes=self.n_eval_episodes,
                                               deterministic=self.deterministic, return_episode_rewards=True,
                                               warn=self.warn)
            self.evaluations_timesteps.append(int(self.num_timesteps))
            self.evaluations_results.append([float(r) for r in rewards])
            self.evaluations_length.append([int(n) for n in lengths])
            save_evaluations(out / "eval" / "evaluations.npz", self.evaluations_timesteps, self.evaluations_results,
                             self.evaluations_length)
            mean = float(np.mean(rewards))
            self.last_mean_reward = mean
            if self.verbose >= 1:
                print(f"Eval num_timesteps={self.num_timesteps}, episode_reward={mean:.2f} +/- {np.std(rewards):.2f}")
            self.logger.record("eval/mean_reward", mean)
            self.logger.record("eval/mean_ep_length", float(np.mean(lengths)))
            self.logger.record("time/total_timesteps", self.num_timesteps, exclude="tensorboard")
            self.logger.dump(self.num_timesteps)
            if mean > self.best_mean_reward:
                self.best_mean_reward = mean
                save_unit(out / "best", self.model, vecnormalize, model_name="best_model.zip",
                          timesteps=int(self.num_timesteps), mean_reward=mean, run=identity)
            return self._on_event() if self.callback is not None else True

    cb = HeldOutEvalCallback(eval_env, n_eval_episodes=args.eval_episodes,
                             eval_freq=max(1, args.eval_freq // max(1, args.n_envs)), deterministic=True,
                             verbose=args.verbose, callback_after_eval=callback_after_eval)
    cb.evaluations_timesteps = list(history["timesteps"])
    cb.evaluations_results = list(history["results"])
    cb.evaluations_length = list(history["ep_lengths"])
    cb.best_mean_reward = best_reward
    return cb


def save_evaluations(path: str | os.PathLike, timesteps, results, ep_lengths) -> None:
    """``evaluations.npz`` as SB3's EvalCallback writes it (``timesteps``, ``results``, ``ep_lengths``), atomically."""
    with atomic_target(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, timesteps=np.asarray(timesteps, dtype=np.int64), results=np.asarray(results, dtype=np.float64),
                 ep_lengths=np.asarray(ep_lengths, dtype=np.int64))


def _read_history(out: Path, upto: int) -> tuple[dict, list[dict], float]:
    """What a resumed run continues: the evaluations and learning-curve rows of ``out`` up to step
    ``upto`` (later ones belong to the continuation that was cut off, replayed now), and the reward
    of the best model kept in ``out/best`` (-inf if there is none, or it is incomplete)."""
    history = {"timesteps": [], "results": [], "ep_lengths": []}
    npz = out / "eval" / "evaluations.npz"
    if npz.exists():
        with np.load(npz) as d:
            keep = d["timesteps"] <= upto
            history = {k: d[k][keep].tolist() for k in history}
    rows = []
    curve = out / "learning_curve.csv"
    if curve.exists():
        with open(curve, newline="") as f:
            for r in csv.DictReader(f):
                if r["wall_s"] and int(r["timesteps"]) <= upto:
                    rows.append({"timesteps": int(r["timesteps"]), "wall_s": float(r["wall_s"]),
                                 "train_ep_reward_mean": float(r["train_ep_reward_mean"]),
                                 "train_ep_length_mean": float(r["train_ep_length_mean"])})
    best = -np.inf
    try:
        best = float(read_manifest(out / "best")["mean_reward"])
    except (FileNotFoundError, ValueError, KeyError, TypeError):
        pass
    return history, rows, best


def _curve_callback(rows: list[dict] | None = None):
    """A callback recording (timesteps, wall time, mean training episode reward) at every rollout end,
    after ``rows`` (of the run it resumes; wall time goes on from theirs)."""
    from stable_baselines3.common.callbacks import BaseCallback

    class _Curve(BaseCallback):
        def __init__(self):
            super().__init__()
            self.rows: list[dict] = list(rows or [])
            self.t0 = time.perf_counter() - (self.rows[-1]["wall_s"] if self.rows else 0.0)

        def _on_step(self) -> bool:
            return True

        def _on_rollout_end(self) -> None:
            buf = self.model.ep_info_buffer
            self.rows.append({"timesteps": self.num_timesteps, "wall_s": time.perf_counter() - self.t0,
                              "train_ep_reward_mean": float(np.mean([e["r"] for e in buf])) if buf else float("nan"),
                              "train_ep_length_mean": float(np.mean([e["l"] for e in buf])) if buf else float("nan")})

    return _Curve()


def _checkpoint_callback(every_calls: int, save, at_rollout_end: bool = False):
    """Calls ``save(model)`` every ``every_calls`` steps of the VecEnv; ``at_rollout_end``: at the end of
    the rollout of that step (SAC/TD3: after the step's transitions are in the replay buffer, which
    happens after the step's callbacks)."""
    from stable_baselines3.common.callbacks import BaseCallback

    class Checkpoints(BaseCallback):
        due = False

        def _on_step(self) -> bool:
            if self.n_calls % every_calls == 0:
                if at_rollout_end:
                    self.due = True
                else:
                    save(self.model)
            return True

        def _on_rollout_end(self) -> None:
            if self.due:
                self.due = False
                save(self.model)

    return Checkpoints()


def _progress(args: Args) -> bool:
    """Whether to show SB3's progress bar: ``progress_bar``, else on a terminal unless ``quiet``
    (and only if tqdm and rich are installed)."""
    import importlib.util
    import sys

    on = args.progress_bar if args.progress_bar is not None else (not args.quiet and sys.stdout.isatty())
    return bool(on) and all(importlib.util.find_spec(m) is not None for m in ("tqdm", "rich"))



def main(args: Args, callback_after_eval=None) -> dict:
    """Train, save everything into ``args.out``; returns a summary (paths, steps, wall time).

    ``args.out`` must be new or empty, unless ``args.resume`` (continue from its newest complete
    checkpoint: same algo, env, scenario, normalisation and evaluation episodes; evaluations, learning
    curve and best model kept) or ``args.overwrite`` (its run files deleted first).

    ``callback_after_eval`` (an SB3 ``BaseCallback``, optional) runs after every held-out evaluation
    as the EvalCallback's child (``parent.last_mean_reward``); returning False stops training. The
    Optuna studies of :mod:`train.study` report and prune through it.
    """
    import torch
    from stable_baselines3 import PPO, SAC, TD3
    from stable_baselines3.common.callbacks import CallbackList
    from stable_baselines3.common.vec_env import VecNormalize

    import iscc_gym  # noqa: F401  (registers the env)

    _check(args)
    if callback_after_eval is not None and args.eval_freq <= 0:
        raise ValueError(f"eval_freq = {args.eval_freq} with a callback_after_eval; use eval_freq >= 1")
    args, hp = resolve_args(args)
    kw = check_hyperparams(args.algo, _resolve_policy_kwargs(hp))
    ckpt, manifest = _prepare_out(args)
    identity = run_identity(args)
    torch.set_num_threads(args.torch_threads)
    set_numba_threads(args.numba_threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    algo_cls = {"ppo": PPO, "sac": SAC, "td3": TD3}[args.algo]
    off_policy = args.algo in ("sac", "td3")
    venv = make_train_env(args)
    warm_start = None
    ckpt_dir = out / "checkpoints"
    start = int(manifest["timesteps"]) if manifest else 0
    history, rows, best_reward = _read_history(out, start) if ckpt else (
        {"timesteps": [], "results": [], "ep_lengths": []}, [], -np.inf)
    if args.normalize:
        if ckpt is not None:
            venv = VecNormalize.load(str(ckpt / "vecnormalize.pkl"), venv)
            venv.training = True
        else:
            venv = VecNormalize(venv, gamma=kw.get("gamma", 0.99))
    tb = str(out / "tb") if args.tensorboard else None
    if ckpt is not None:
        model = algo_cls.load(str(ckpt / "model.zip"), env=venv, device="cpu", tensorboard_log=tb)
        if "replay_buffer.pkl" in manifest["files"]:
            model.load_replay_buffer(ckpt / "replay_buffer.pkl")
    else:
        kw = _action_noise(kw, venv.num_envs, venv.action_space.shape[0])
        policy = kw.pop("policy", "MlpPolicy")
        model = algo_cls(policy, venv, seed=args.seed, device="cpu", verbose=args.verbose, tensorboard_log=tb, **kw)
        if args.init_policy and args.init_policy.lower() != "none":
            warm_start = _behaviour_clone(model, venv, args)
    if tb is None:
        model.set_logger(stdout_logger(args.verbose))
    resolved = {"args": dataclasses.asdict(args), "hyperparams": hp}
    write_atomic(out / "config.yml", yaml.safe_dump(resolved, sort_keys=False))
    vecnormalize = venv if args.normalize else None
    saved = {"step": start if ckpt else None}

    def checkpoint(m) -> None:
        step = int(m.num_timesteps)
        save_unit(ckpt_dir / f"step_{step}", m, vecnormalize, replay_buffer=off_policy, timesteps=step, run=identity)
        saved["step"] = step

    callbacks = [curve := _curve_callback(rows)]
    per_env = max(1, args.n_envs)
    if args.checkpoint_freq > 0:
        callbacks.append(_checkpoint_callback(max(1, args.checkpoint_freq // per_env), checkpoint, off_policy))
    eval_cb = None
    if args.eval_freq > 0:
        eval_env = make_eval_env(args)
        if args.normalize:
            eval_env = VecNormalize(eval_env, training=False, norm_reward=False)
        eval_cb = _eval_callback(eval_env, args, out, identity, history, best_reward, callback_after_eval)
        callbacks.append(eval_cb)
    remaining = args.total_timesteps - start
    t0 = time.perf_counter()
    if remaining > 0:
        model.learn(remaining, callback=CallbackList(callbacks), reset_num_timesteps=ckpt is None,
                    progress_bar=_progress(args), tb_log_name=args.algo)
    wall = time.perf_counter() - t0
    if args.checkpoint_freq > 0 and saved["step"] != model.num_timesteps:
        checkpoint(model)  # --resume with a larger --total-timesteps goes on from the end
    save_unit(out, model, vecnormalize, timesteps=int(model.num_timesteps), run=identity)
    evals = []
    if eval_cb is not None and eval_cb.evaluations_timesteps:
        evals = list(zip(eval_cb.evaluations_timesteps, [float(np.mean(r)) for r in eval_cb.evaluations_results],
                         strict=True))
    elif history["timesteps"]:
        evals = list(zip(history["timesteps"], [float(np.mean(r)) for r in history["results"]], strict=True))
    _write_curve(out, curve.rows, evals)
    venv.close()
    bc_wall = warm_start["wall_time_s"] if warm_start else 0.0
    summary = {"out": str(out), "timesteps": int(model.num_timesteps), "wall_time_s": wall + bc_wall,
               "env_steps_per_s": (remaining / wall) if remaining > 0 and wall > 0 else None,
               "evaluations": evals, "resumed_from": str(ckpt) if ckpt else None,
               "warm_start": warm_start}
    write_atomic(out / "summary.yml", yaml.safe_dump(summary, sort_keys=False))
    return summary


def _write_curve(out: Path, rows: list[dict], evals: list[tuple[int, float]]) -> None:
    buf = io.StringIO(newline="")
    w = csv.writer(buf)
    w.writerow(["timesteps", "wall_s", "train_ep_reward_mean", "train_ep_length_mean", "eval_reward_mean"])
    ev = dict(evals)
    for r in rows:
        w.writerow([r["timesteps"], f"{r['wall_s']:.3f}", r["train_ep_reward_mean"], r["train_ep_length_mean"],
                    ev.get(r["timesteps"], "")])
    for t, v in evals:
        if t not in {r["timesteps"] for r in rows}:
            w.writerow([t, "", "", "", v])
    write_atomic(out / "learning_curve.csv", buf.getvalue())
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 3.5), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    if rows:
        ax.plot([r["timesteps"] for r in rows], [r["train_ep_reward_mean"] for r in rows], label="train episodes")
    if evals:
        ax.plot(*zip(*evals, strict=True), "o-", label="held-out eval")
    ax.set_xlabel("env steps")
    ax.set_ylabel("episode reward")
    ax.legend()
    fig.tight_layout()
    with atomic_target(out / "learning_curve.png") as tmp:
        fig.savefig(tmp, format="png")


PICKLE_WARNING = ("Model files (.zip) and vecnormalize.pkl are pickles: loading one executes code it holds. "
                  "Load only files you trust (and --resume only runs of your own).")


def build_parser(prog: str = "python -m train") -> argparse.ArgumentParser:
    """The parser of ``python -m train``: every :class:`Args` field is a flag (help: :data:`FIELD_HELP`),
    ``--set`` / ``--env-set`` override hyperparameters / Scenario fields, and :mod:`train.study` adds
    ``--optimize``, ``--seeds``."""
    ap = argparse.ArgumentParser(
        prog=prog, description=__doc__.split("\n")[0],
        epilog="Writes into OUT: model.zip and vecnormalize.pkl (the final model and its statistics), best/ "
               "(the best model on the held-out missions, with its own statistics), checkpoints/step_<N>/ "
               "(for --resume), eval/evaluations.npz, learning_curve.csv/.png, config.yml, summary.yml, tb/. "
               + PICKLE_WARNING)
    defaults = Args()
    for f in dataclasses.fields(Args):
        if f.name in ("overrides", "env_overrides"):
            continue
        flag = "--" + f.name.replace("_", "-")
        default = getattr(defaults, f.name)
        help_ = FIELD_HELP[f.name]
        if isinstance(default, bool) or f.name in ("normalize", "progress_bar"):
            ap.add_argument(flag, action=argparse.BooleanOptionalAction, default=default, help=help_)
        elif default is None:  # a run setting the YAML fills (RUN_KEYS), or numba's default
            kind = {"init_policy": str, "init_log_std": float}.get(f.name, int)
            ap.add_argument(flag, type=kind, default=None, help=help_)
        else:
            ap.add_argument(flag, type=type(default), default=default, help=help_ + f" (default: {default})")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a hyperparameter of the YAML, e.g. --set n_steps=256 (value read as YAML)")
    ap.add_argument("--env-set", action="append", default=[], metavar="FIELD=VALUE",
                    help="override a Scenario field of the env, e.g. --env-set observation_source=gnss")
    from iscc_gym.train.study import add_study_arguments

    add_study_arguments(ap)
    return ap


def args_from_namespace(ap: argparse.ArgumentParser, ns: argparse.Namespace) -> Args:
    """The :class:`Args` of flags parsed by :func:`build_parser` (``--set`` values parsed as YAML)."""

    def pairs(items, flag):
        out: dict[str, Any] = {}
        for item in items:
            if "=" not in item or not item.split("=", 1)[0]:
                ap.error(f"{flag} {item!r}: use KEY=VALUE")
            k, v = item.split("=", 1)
            try:
                out[k] = parse_value(v)
            except yaml.YAMLError:
                ap.error(f"{flag} {item!r}: the value is not valid YAML")
        return out

    kw = {f.name: getattr(ns, f.name) for f in dataclasses.fields(Args) if f.name not in ("overrides", "env_overrides")}
    return Args(overrides=pairs(ns.set, "--set"), env_overrides=pairs(ns.env_set, "--env-set"), **kw)


def parse_value(text: str):
    """A ``--set`` / ``--env-set`` value: YAML, with numbers YAML 1.1 leaves as strings (``5e-5``,
    ``1e6``) read as numbers."""
    value = yaml.safe_load(text)
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            pass
    return value


def parse_args(argv: list[str] | None = None) -> Args:
    """``Args`` from the command line (every field is a flag; ``--set key=value`` overrides a
    hyperparameter, the value parsed as YAML)."""
    ap = build_parser()
    return args_from_namespace(ap, ap.parse_args(argv))


def cli(argv: list[str] | None = None, prog: str = "python -m train") -> dict:
    """``python -m train``: train once, or run a study (``--optimize``) or several seeds (``--seeds``);
    returns the summary (for Python callers; the console commands end through :func:`console`)."""
    ap = build_parser(prog)
    ns = ap.parse_args(argv)
    args = args_from_namespace(ap, ns)
    if ns.optimize or ns.seeds is not None:
        from iscc_gym.train.study import run_cli

        return run_cli(ap, ns, args)
    summary = main(args)
    if not args.quiet:
        print(f"trained {summary['timesteps']} steps in {summary['wall_time_s']:.1f} s -> {summary['out']}")
    return summary


def console(argv: list[str] | None = None, prog: str = "iscc-train") -> int:
    """The ``iscc-train`` / ``python -m train`` entry point: exit code 0 on success, 2 with one line
    for a user's mistake (:func:`iscc_gym.cli.run`)."""
    from iscc_gym.cli import run

    return run(lambda a: cli(a, prog=prog), argv, prog)
