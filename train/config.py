"""Configuration of a training run: the hyperparameter file in rl-zoo3's layout (``train/hyperparams.yml``), its
resolution against the command line's :class:`~iscc_gym.train.args.Args` and their checks.
"""

from __future__ import annotations

import dataclasses
import math
import os
from typing import Any

import gymnasium as gym
import numpy as np
import yaml
from iscc_gym.agents.sb3_policy import ALGOS as SB3_ALGOS
from iscc_gym.agents.sb3_policy import algo_class
from iscc_gym.commands.protocol import INIT_SEED_START, check_outside_evaluation

from iscc_gym.tasks import TASKS, is_fleet, registered_scenario

from .args import (  # noqa: F401 (re-exported: the settings of a run, read by train, studies and tests)
    FIELD_HELP,
    HYPERPARAMS,
    PPO_LAG_LIMITS,
    RUN_DEFAULTS,
    RUN_KEYS,
    RUN_TYPES,
    Args,
    expand_algo,
    has_residual,
    has_warm_start,
    randomize_sets,
    randomized,
    randomized_overrides,
    run_flags,
    run_settings,
)

ALGOS = SB3_ALGOS  # ppo, sac, td3 and ppo_lstm (sb3-contrib's RecurrentPPO, rl-zoo3's name for it)
#: The on-policy algorithms (rollouts of n_steps per env, advantages normalised per mini-batch).
ON_POLICY = ("ppo", "ppo_lstm")
VEC_ENVS = ("dummy", "subproc", "batched")
#: ``--reward``: the env's sampled reward, or the simulator's expected one (train/privileged.py).
REWARDS = ("sampled", "expected")
#: ``--critic``: the critic reads the agent's observation, or the world too (agents/world_critic.py).
CRITICS = ("own", "world")

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
    key = env_id if env_id in entries or env_id not in TASKS else TASKS[env_id].hyperparams_key
    if key not in entries:
        raise ValueError(f"env_id {env_id!r} has no entry in {path}; add one (keys: {sorted(entries)}), or name "
                         "the task's train_like")
    entry = entries[key]
    if isinstance(entry, dict) and entry and set(entry) <= set(ALGOS) and all(isinstance(v, dict) for v in
                                                                             entry.values()):
        if algo not in entry:  # the older layout: env id -> algo -> hyperparameters
            raise ValueError(f"algo {algo!r} has no entry for {env_id} in {path}; add one or use {sorted(entry)}")
        entry = entry[algo]
    if not isinstance(entry, dict):
        raise ValueError(f"{path}: the entry of {env_id} is {entry!r}; use a mapping of hyperparameters")
    hp = {**dict(settings.get(key) or {}), **entry}
    hp.update(overrides or {})
    if "policy_kwargs" in hp:
        hp["policy_kwargs"] = parse_policy_kwargs(hp["policy_kwargs"])
    return hp


def resolve_args(args: Args) -> tuple[Args, dict]:
    """``(args, hyperparameters)``: the run settings that ``args`` leaves at None filled from the
    YAML entry (``n_timesteps``, ``n_envs``, ``normalize``, ``init_*``), else from :data:`RUN_DEFAULTS`;
    rl-zoo3's ``env_kwargs`` join ``env_overrides`` (a flag wins); the returned hyperparameters are the
    algorithm's keyword arguments only.
    """
    args = expand_algo(args)
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
                filled[name] = RUN_TYPES[name](value)
            except (TypeError, ValueError):
                kind = {"normalize": "true or false", "norm_reward": "true or false", "init_policy": "a policy spec",
                        "residual": "a policy spec", "residual_space": "action or split",
                        "init_log_std": "a number", "residual_scale": "a number"}.get(name, "an integer")
                raise ValueError(f"{key} = {value!r} in {args.hyperparams} or --set; use {kind}") from None
    env_kwargs = hp.pop("env_kwargs", None) or {}
    if not isinstance(env_kwargs, dict):
        raise ValueError(f"env_kwargs = {env_kwargs!r}; use a mapping of Scenario fields")
    if env_kwargs:
        filled["env_overrides"] = {**env_kwargs, **args.env_overrides}
    if args.scenario is None:
        filled["scenario"] = registered_scenario(args.env_id)
    check_no_world_shown(filled.get("env_overrides", args.env_overrides))
    return dataclasses.replace(args, **filled), hp


def check_no_world_shown(env_overrides: dict) -> None:
    """Refuse a run whose policy would observe the hidden world (``show_world``, by ``--env-set`` or the YAML's
    ``env_kwargs``): the env shows it only to the model-knowledge bound (``aware``); a deployed policy reads the
    observation, so ``python -m eval`` refuses such an agent ("trained on another env"), after its whole training
    (issue 43.9). A privileged signal belongs in the training, not in the policy's observation.
    """
    value = env_overrides.get("show_world")
    if value is not None and value is not False and str(value).strip().lower() not in ("false", "0", "no"):
        raise ValueError(f"env_overrides show_world = {value!r}: the policy would observe the hidden world (the field "
                         "task's K-factor and RCS), which the env shows only the aware bound; a deployed policy "
                         "reads the observation, and python -m eval refuses an agent trained on it. Drop "
                         "--env-set show_world=true (or env_kwargs' show_world)")


def _closed(lo, hi):
    return f"in [{lo}, {hi}]", lambda v: lo <= v <= hi


def _above(lo, strict=True):
    return (f"> {lo}", lambda v: v > lo) if strict else (f">= {lo}", lambda v: v >= lo)


#: The valid range of each numeric hyperparameter, as (text, test); ``n_steps`` etc. are integers (the
#: constructor's defaults say which). PPO's ``batch_size`` must be above 1 (advantages are normalised
#: per mini-batch); ``gradient_steps`` may be -1 (as many as the rollout's steps).
HYPERPARAM_RANGES = {
    "learning_rate": _above(0, False), "n_steps": _above(1, False), "batch_size": _above(1, False),
    "n_epochs": _above(1, False), "gamma": _closed(0, 1), "gae_lambda": _closed(0, 1), "clip_range": _above(0),
    "clip_range_vf": _above(0), "ent_coef": _above(0, False), "vf_coef": _above(0, False),
    "max_grad_norm": _above(0), "target_kl": _above(0), "sde_sample_freq": _above(-1, False),
    "stats_window_size": _above(1, False), "buffer_size": _above(1, False), "learning_starts": _above(0, False),
    "tau": ("in (0, 1]", lambda v: 0 < v <= 1), "train_freq": _above(1, False),
    "gradient_steps": (">= 1, or -1", lambda v: v >= 1 or v == -1), "target_update_interval": _above(1, False),
    "policy_delay": _above(1, False), "target_policy_noise": _above(0, False), "target_noise_clip": _above(0, False),
    "noise_std": _above(0),
}


def _check_ranges(algo: str, hp: dict) -> None:
    """Every numeric hyperparameter finite and in :data:`HYPERPARAM_RANGES` (a ``ValueError`` naming the key)."""
    for key, value in hp.items():
        if key not in HYPERPARAM_RANGES or value is None or callable(value):
            continue  # None: the algorithm's "off" (clip_range_vf, target_kl); callables: schedules
        if isinstance(value, str) and (key in ("learning_rate", "clip_range") or (key, algo) == ("ent_coef", "sac")):
            continue  # lin_<value> (linear_schedule checks it), SAC's "auto"
        if key == "train_freq" and isinstance(value, list | tuple):
            value = value[0]
        text, ok = HYPERPARAM_RANGES[key]
        if algo in ON_POLICY and key == "batch_size":
            text, ok = _above(2, False)
        if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
            raise ValueError(f"{key} = {value!r}; use a number {text}")
        good = math.isfinite(float(value)) and ok(float(value))
        if not good:
            raise ValueError(f"{key} = {value!r} is out of range; use a value {text}")
    log_std = (hp.get("policy_kwargs") or {}).get("log_std_init") if isinstance(hp.get("policy_kwargs"),
                                                                                dict) else None
    if log_std is not None and not (isinstance(log_std, int | float) and math.isfinite(log_std)):
        raise ValueError(f"policy_kwargs.log_std_init = {log_std!r}; use a finite number")


def check_hyperparams(algo: str, hp: dict) -> dict:
    """Names, types and ranges of the algorithm's keyword arguments, checked against its constructor and
    :data:`HYPERPARAM_RANGES`; returns them with whole numbers where it takes integers (``n_steps: 6.4e1`` -> 64).

    Raises
    ------
    ValueError
        An unknown name (with the closest known ones), or a text or other non-number where the
        algorithm takes a number (e.g. ``--set n_steps=abc``), or a fraction where it takes an integer,
        or a value out of its range (``gamma = 2``, ``n_steps = 0``, NaN), naming the key and the range.
    """
    import difflib
    import inspect

    cls = algo_class(algo)
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
    _check_ranges(algo, hp)
    return hp


def resolve_policy_kwargs(hp: dict) -> dict:
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


def action_noise(kw: dict, n_envs: int, dim: int) -> dict:
    """rl-zoo3's ``noise_type`` (``normal`` | ``ornstein-uhlenbeck``) and ``noise_std`` keys as SB3's
    ``action_noise`` (one independent noise process per env) for SAC/TD3.
    """
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


def check_args(args: Args) -> None:
    if args.env_id not in gym.registry:  # before any setting that depends on the env (vec_env, the YAML entry)
        raise ValueError(f"env_id {args.env_id!r} is not a registered env id; use one of {', '.join(TASKS)} "
                         "(or another registered Gymnasium id, e.g. Pendulum-v1)")
    if args.algo not in (*ALGOS, "ppo-lag"):
        raise ValueError(f"algo = {args.algo!r}; use one of {', '.join((*ALGOS, 'ppo-lag'))}")
    args = expand_algo(args)
    if args.vec_env not in VEC_ENVS:
        raise ValueError(f"vec_env = {args.vec_env!r}; use one of {VEC_ENVS}")
    if args.cost_limit is not None:
        from .lagrangian import parse_cost_limits

        parse_cost_limits(args.cost_limit)
        if not (args.lagrange_lr > 0.0 and math.isfinite(args.lagrange_lr)):
            raise ValueError(f"lagrange_lr = {args.lagrange_lr!r}; use a positive number, e.g. 0.05")
        if args.env_id not in TASKS:
            raise ValueError(f"cost_limit: {args.env_id} has no ISCC costs in info; use one of {list(TASKS)}")
    if args.vec_env == "batched" and args.env_id not in TASKS:
        raise ValueError("vec_env = 'batched' is the ISCC env's own batched env; use dummy or subproc for "
                         f"{args.env_id}")
    for name in ("total_timesteps", "n_envs", "eval_episodes", "eval_max_steps", "torch_threads", "numba_threads",
                 "init_envs", "init_steps"):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            raise ValueError(f"{name} = {getattr(args, name)}; use an integer >= 1")
    for name in ("eval_freq", "checkpoint_freq"):
        if getattr(args, name) < 0:
            raise ValueError(f"{name} = {getattr(args, name)}; use an integer >= 0 (0: none)")
    if not 0 <= args.seed < 2**32:
        raise ValueError(f"seed = {args.seed}; use an integer in [0, 2**32)")
    if args.scenario is not None and args.env_id in TASKS:
        check_task(args.env_id, args.scenario)
    check_no_world_shown(args.env_overrides)  # the flag's (the YAML's env_kwargs: resolve_args)
    if has_residual(args):
        if args.env_id not in TASKS or is_fleet(args.env_id):
            raise ValueError(f"residual = {args.residual!r}: a scripted base policy plays the single-drone tasks "
                             f"({', '.join(e for e in TASKS if not is_fleet(e))}) only, not {args.env_id}; "
                             "unset residual")
        if has_warm_start(args):
            raise ValueError(f"residual = {args.residual!r} and init_policy = {args.init_policy!r}: use one (a "
                             "residual agent starts at its base policy already)")
    if args.reward is not None and args.reward not in REWARDS:
        raise ValueError(f"reward = {args.reward!r}; use one of {', '.join(REWARDS)}")
    if args.critic is not None and args.critic not in CRITICS:
        raise ValueError(f"critic = {args.critic!r}; use one of {', '.join(CRITICS)}")
    if randomized(args):
        sets = randomize_sets()
        if args.randomize not in sets:
            raise ValueError(f"randomize = {args.randomize!r}; use one of {sorted(sets)} or none")
        env = sets[args.randomize][0]
        if args.env_id != env or args.vec_env != "batched":
            raise ValueError(f"randomize = {args.randomize!r} draws {TASKS[env].preset} missions on the batched env; "
                             f"use --env {env} with vec_env = 'batched'")
    if args.residual_scale is not None:
        from iscc_gym.agents.residual import check_scale

        check_scale(args.residual_scale)
    if args.residual_space is not None:
        from iscc_gym.agents.residual import check_space

        check_space(args.residual_space)
    if args.init_log_std is not None and not math.isfinite(args.init_log_std):
        raise ValueError(f"init_log_std = {args.init_log_std}; use a finite number (a log standard deviation)")


def check_task(env_id: str, scenario: str) -> None:
    """Refuse a Scenario preset of another task than ``env_id``'s (its hyperparameters, evaluation and shipped agent
    are its registered preset's task, :func:`iscc_gym.agents.tuned_records.task_of`): ``--env
    iscc_gym/ISCC-Urban-v0 --scenario paper`` trained a paper agent under the urban task's name. A variant of the
    same task (``literal`` on ``iscc_gym/ISCC-v0``) passes.

    Raises
    ------
    ValueError
        Naming both, the env id of the scenario's task and the env id's own preset.
    """
    from iscc_gym.agents.tuned_records import task_mismatch

    mismatch = task_mismatch(env_id, scenario)
    if mismatch is not None:
        task, env_task, other, own = mismatch
        raise ValueError(f"scenario = {scenario!r} is the {task} task, but {env_id} is the {env_task} task (its "
                         "hyperparameters, evaluation and shipped agent): "
                         + (f"use --env {other} for {scenario!r}, or " if other else "")
                         + f"drop --scenario to train on {env_id}'s own {own!r}")


def _check_privileged(args: Args) -> None:
    """A resolved run's ``reward`` and ``critic`` (flags or the YAML's): what only the simulator knows is shown on
    the field task's batched env alone, PPO's critic to boot.
    """
    field_env = next((e for e, t in TASKS.items() if t.preset == "field"), "the field task")
    for name, value, default, valid in (("reward", args.reward, "sampled", REWARDS),
                                        ("critic", args.critic, "own", CRITICS)):
        if value not in (None, *valid):
            raise ValueError(f"{name} = {value!r} in {args.hyperparams} or --set; use one of {', '.join(valid)}")
        if value in (None, default):
            continue
        from iscc_gym.scenario import make_scenario
        from iscc_gym.sim.effects import task_effects

        scenario = args.scenario or registered_scenario(args.env_id)
        if (name == "critic" and args.algo != "ppo") or args.vec_env != "batched" or randomized(args) \
                or args.env_id not in TASKS or is_fleet(args.env_id) \
                or not task_effects(make_scenario(scenario, **args.env_overrides)).field:
            what = ("pays the field task's expected one-slot reward" if name == "reward" else
                    "shows PPO's critic the field task's world")
            raise ValueError(f"{name} = {value!r} {what} on its batched env: use --env {field_env}"
                             + (" with --algo ppo," if name == "critic" else " with") + " vec_env = 'batched' and no "
                             f"--randomize, or --{name} {default}")


def _seed_ranges(args: Args) -> list[tuple[str, int, int]]:
    """The seeds a resolved run trains on, as (what, first, last): the training envs' (``seed`` + i, SB3's
    convention) and the warm start's (:data:`iscc_gym.commands.protocol.INIT_SEED_START` + 1000 ``seed`` + i).
    """
    ranges = [("the training envs' seeds", args.seed, args.seed + args.n_envs - 1)]
    if has_warm_start(args):
        first = INIT_SEED_START + 1000 * args.seed
        ranges.append(("the warm start's seeds", first, first + args.init_envs - 1))
    return ranges


def check_resolved(args: Args, hyperparams: dict) -> None:
    """Checks of a run's resolved settings (:func:`resolve_args`), before any work: the run settings the
    YAML may fill (``init_*``, as :func:`check_args` does for the flags), PPO's rollout size, an env for each
    mission set of a randomised run, and training seeds outside :data:`iscc_gym.commands.protocol.EVAL_SEED_RANGES` (the
    held-out missions stay unseen in training).

    Raises
    ------
    ValueError
        Naming the setting and its valid range (for seeds: both ranges).
    """
    check_args(args)
    _check_privileged(args)
    if args.algo in ON_POLICY and args.n_envs * int(hyperparams.get("n_steps", 2048)) < 2:
        raise ValueError(f"n_steps = {hyperparams.get('n_steps')} with n_envs = {args.n_envs}: PPO needs a rollout "
                         "of at least 2 steps (n_steps x n_envs >= 2)")
    if randomized(args) and args.n_envs < len(shares := randomized_overrides(args)):
        raise ValueError(f"randomize = {args.randomize!r} with n_envs = {args.n_envs}: each of its {len(shares)} "
                         f"mission sets needs an env of its own; use --n-envs {len(shares)} or more")
    for what, lo, hi in _seed_ranges(args):
        check_outside_evaluation(lo, hi, f"seed = {args.seed}: {what}",
                                 "train on another seed (the held-out missions must stay unseen in training)")
