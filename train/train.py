"""Train an SB3 agent (PPO by default; SAC, TD3) on ``iscc_gym/ISCC-v0``.

Usage::

    python -m train --total-timesteps 200000 --n-envs 4 --vec-env batched --out runs/ppo

Writes into ``--out``: ``model.zip`` (final), ``best/best_model.zip`` (best on the held-out eval
seeds), ``vecnormalize.pkl``, ``config.yml`` (the resolved configuration), ``learning_curve.csv`` and
``.png``, ``checkpoints/`` (periodic model + VecNormalize, for ``--resume``) and TensorBoard logs in
``tb/`` (``tensorboard --logdir OUT/tb``).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from iscc_gym.files import write_atomic

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
    """Everything a training run depends on (``python -m train --help`` lists them)."""

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
    resume: bool = False  # continue from the latest checkpoint in ``out``
    tensorboard: bool = True
    progress_bar: bool = False
    torch_threads: int = 1  # threads of torch (1 is fastest here: python -m eval.bench)
    numba_threads: int | None = None  # threads of the env's compiled kernel (None: numba's default, all cores)
    verbose: int = 0


#: Run settings a YAML entry may hold beside the algorithm's hyperparameters (rl-zoo3's names), mapped
#: to the :class:`Args` field they fill, and the value used when neither the flag nor the YAML sets it.
RUN_KEYS = {"n_timesteps": "total_timesteps", "n_envs": "n_envs", "normalize": "normalize",
            "init_policy": "init_policy", "init_envs": "init_envs", "init_steps": "init_steps",
            "init_log_std": "init_log_std"}
RUN_DEFAULTS = {"total_timesteps": 200_000, "n_envs": 4, "normalize": True, "init_policy": None, "init_envs": 16,
                "init_steps": 5000, "init_log_std": None}
_RUN_TYPES = {"total_timesteps": lambda v: int(float(v)), "n_envs": int, "normalize": bool, "init_policy": str,
              "init_envs": int, "init_steps": int, "init_log_std": float}


def load_hyperparams(path: str | os.PathLike, env_id: str, algo: str, overrides: dict | None = None) -> dict:
    """The hyperparameters of ``algo`` on ``env_id`` from the YAML file, with ``overrides`` applied.

    ``policy_kwargs.activation_fn`` is a name looked up in ``torch.nn`` (never eval'd). The run
    settings of :data:`RUN_KEYS` stay in the dict; :func:`resolve_args` takes them out.
    """
    with open(path) as f:
        table = yaml.safe_load(f)
    if env_id not in table:
        raise ValueError(f"env_id {env_id!r} has no entry in {path}; add one (keys: {sorted(table)})")
    if algo not in table[env_id]:
        raise ValueError(f"algo {algo!r} has no entry for {env_id} in {path}; add one or use {sorted(table[env_id])}")
    hp = dict(table[env_id][algo])
    hp.update(overrides or {})
    return hp


def resolve_args(args: Args) -> tuple[Args, dict]:
    """``(args, hyperparameters)``: the run settings that ``args`` leaves at None filled from the
    YAML entry (``n_timesteps``, ``n_envs``, ``normalize``), else from :data:`RUN_DEFAULTS`; the
    returned hyperparameters are the algorithm's keyword arguments only."""
    hp = load_hyperparams(args.hyperparams, args.env_id, args.algo, args.overrides)
    filled = {}
    for key, name in RUN_KEYS.items():
        value = hp.pop(key, None)
        if getattr(args, name) is None:
            value = RUN_DEFAULTS[name] if value is None else value
            filled[name] = None if value is None else _RUN_TYPES[name](value)
    return dataclasses.replace(args, **filled), hp


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


def _held_out_eval_callback(base):
    """``base`` (SB3's EvalCallback) re-seeding its env with :data:`EVAL_SEED_START` before every
    evaluation, so every evaluation plays the same held-out missions (a VecEnv forgets its seeds
    after a reset) and ``best_model`` is chosen on one fixed set of episodes."""

    class HeldOutEvalCallback(base):
        def _on_step(self) -> bool:
            if self.eval_freq > 0 and self.n_calls % self.eval_freq == 0:
                self.eval_env.seed(EVAL_SEED_START)
            return super()._on_step()

    return HeldOutEvalCallback


def _curve_callback():
    """A callback recording (timesteps, wall time, mean training episode reward) at every rollout end."""
    from stable_baselines3.common.callbacks import BaseCallback

    class _Curve(BaseCallback):
        def __init__(self):
            super().__init__()
            self.rows: list[dict] = []
            self.t0 = time.perf_counter()

        def _on_step(self) -> bool:
            return True

        def _on_rollout_end(self) -> None:
            buf = self.model.ep_info_buffer
            self.rows.append({"timesteps": self.num_timesteps, "wall_s": time.perf_counter() - self.t0,
                              "train_ep_reward_mean": float(np.mean([e["r"] for e in buf])) if buf else float("nan"),
                              "train_ep_length_mean": float(np.mean([e["l"] for e in buf])) if buf else float("nan")})

    return _Curve()


def _latest_checkpoint(ckpt_dir: Path) -> tuple[Path, Path | None] | None:
    best = None
    for p in ckpt_dir.glob("model_*_steps.zip"):
        m = re.match(r"model_(\d+)_steps\.zip", p.name)
        if m and (best is None or int(m.group(1)) > best[0]):
            best = (int(m.group(1)), p)
    if best is None:
        return None
    vn = ckpt_dir / f"model_vecnormalize_{best[0]}_steps.pkl"
    return best[1], vn if vn.exists() else None


def main(args: Args, callback_after_eval=None) -> dict:
    """Train, save everything into ``args.out``; returns a summary (paths, steps, wall time).

    ``callback_after_eval`` (an SB3 ``BaseCallback``, optional) runs after every held-out evaluation
    as the EvalCallback's child (``parent.last_mean_reward``); returning False stops training. The
    Optuna studies of :mod:`train.study` report and prune through it.
    """
    import torch
    from stable_baselines3 import PPO, SAC, TD3
    from stable_baselines3.common.callbacks import CallbackList, CheckpointCallback, EvalCallback
    from stable_baselines3.common.vec_env import VecNormalize

    import iscc_gym  # noqa: F401  (registers the env)

    _check(args)
    if callback_after_eval is not None and args.eval_freq <= 0:
        raise ValueError(f"eval_freq = {args.eval_freq} with a callback_after_eval; use eval_freq >= 1")
    args, hp = resolve_args(args)
    torch.set_num_threads(args.torch_threads)
    set_numba_threads(args.numba_threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    algo_cls = {"ppo": PPO, "sac": SAC, "td3": TD3}[args.algo]
    venv = make_train_env(args)
    warm_start = None
    ckpt_dir = out / "checkpoints"
    latest = _latest_checkpoint(ckpt_dir) if args.resume else None
    if args.resume and latest is None:
        raise FileNotFoundError(f"resume: no checkpoint in {ckpt_dir}; train without --resume first")
    if args.normalize:
        if latest is not None and latest[1] is not None:
            venv = VecNormalize.load(str(latest[1]), venv)
            venv.training = True
        else:
            venv = VecNormalize(venv, gamma=hp.get("gamma", 0.99))
    tb = str(out / "tb") if args.tensorboard else None
    if latest is not None:
        model = algo_cls.load(str(latest[0]), env=venv, device="cpu", tensorboard_log=tb)
    else:
        kw = _resolve_policy_kwargs(hp)
        kw = _action_noise(kw, venv.num_envs, venv.action_space.shape[0])
        policy = kw.pop("policy", "MlpPolicy")
        model = algo_cls(policy, venv, seed=args.seed, device="cpu", verbose=args.verbose, tensorboard_log=tb, **kw)
        if args.init_policy and args.init_policy.lower() != "none":
            warm_start = _behaviour_clone(model, venv, args)
    resolved = {"args": dataclasses.asdict(args), "hyperparams": hp}
    write_atomic(out / "config.yml", yaml.safe_dump(resolved, sort_keys=False))
    callbacks = [curve := _curve_callback()]
    per_env = max(1, args.n_envs)
    if args.checkpoint_freq > 0:
        callbacks.append(CheckpointCallback(max(1, args.checkpoint_freq // per_env), str(ckpt_dir), name_prefix="model",
                                            save_vecnormalize=args.normalize))
    eval_cb = None
    if args.eval_freq > 0:
        eval_env = make_eval_env(args)
        if args.normalize:
            eval_env = VecNormalize(eval_env, training=False, norm_reward=False)
        eval_cb = _held_out_eval_callback(EvalCallback)(eval_env, n_eval_episodes=args.eval_episodes,
                               eval_freq=max(1, args.eval_freq // per_env),
                               best_model_save_path=str(out / "best"), log_path=str(out / "eval"),
                               deterministic=True, verbose=args.verbose, callback_after_eval=callback_after_eval)
        callbacks.append(eval_cb)
    remaining = args.total_timesteps - (model.num_timesteps if latest is not None else 0)
    t0 = time.perf_counter()
    if remaining > 0:
        model.learn(remaining, callback=CallbackList(callbacks), reset_num_timesteps=latest is None,
                    progress_bar=args.progress_bar, tb_log_name=args.algo)
    wall = time.perf_counter() - t0
    model.save(str(out / "model"))
    if args.normalize:
        venv.save(str(out / "vecnormalize.pkl"))
    evals = []
    if eval_cb is not None and eval_cb.evaluations_timesteps:
        evals = list(zip(eval_cb.evaluations_timesteps, [float(np.mean(r)) for r in eval_cb.evaluations_results],
                         strict=True))
    _write_curve(out, curve.rows, evals)
    venv.close()
    bc_wall = warm_start["wall_time_s"] if warm_start else 0.0
    summary = {"out": str(out), "timesteps": int(model.num_timesteps), "wall_time_s": wall + bc_wall,
               "env_steps_per_s": (remaining / wall) if remaining > 0 and wall > 0 else None,
               "evaluations": evals, "resumed_from": str(latest[0]) if latest else None,
               "warm_start": warm_start}
    write_atomic(out / "summary.yml", yaml.safe_dump(summary, sort_keys=False))
    return summary


def _write_curve(out: Path, rows: list[dict], evals: list[tuple[int, float]]) -> None:
    with open(out / "learning_curve.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["timesteps", "wall_s", "train_ep_reward_mean", "train_ep_length_mean", "eval_reward_mean"])
        ev = dict(evals)
        for r in rows:
            w.writerow([r["timesteps"], f"{r['wall_s']:.3f}", r["train_ep_reward_mean"], r["train_ep_length_mean"],
                        ev.get(r["timesteps"], "")])
        for t, v in evals:
            if t not in {r["timesteps"] for r in rows}:
                w.writerow([t, "", "", "", v])
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
    fig.savefig(out / "learning_curve.png")


def build_parser() -> argparse.ArgumentParser:
    """The parser of ``python -m train``: every :class:`Args` field is a flag, ``--set`` / ``--env-set``
    override hyperparameters / Scenario fields, and :mod:`train.study` adds ``--optimize``, ``--seeds``."""
    ap = argparse.ArgumentParser(prog="python -m train", description=__doc__.split("\n")[0])
    defaults = Args()
    for f in dataclasses.fields(Args):
        if f.name in ("overrides", "env_overrides"):
            continue
        flag = "--" + f.name.replace("_", "-")
        default = getattr(defaults, f.name)
        if isinstance(default, bool) or f.name == "normalize":
            ap.add_argument(flag, action=argparse.BooleanOptionalAction, default=default)
        elif default is None:  # a run setting the YAML fills (RUN_KEYS), or numba's default
            hint = "all cores" if f.name == "numba_threads" else "the YAML entry's value"
            kind = {"init_policy": str, "init_log_std": float}.get(f.name, int)
            ap.add_argument(flag, type=kind, default=None, help=f"default: {hint}")
        else:
            ap.add_argument(flag, type=type(default), default=default)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a hyperparameter of the YAML, e.g. --set n_steps=256")
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
            if "=" not in item:
                ap.error(f"{flag} {item!r}: use KEY=VALUE")
            k, v = item.split("=", 1)
            out[k] = parse_value(v)
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


def cli(argv: list[str] | None = None) -> dict:
    """``python -m train``: train once, or run a study (``--optimize``) or several seeds (``--seeds``)."""
    ap = build_parser()
    ns = ap.parse_args(argv)
    args = args_from_namespace(ap, ns)
    if ns.optimize or ns.seeds is not None:
        from iscc_gym.train.study import run_cli

        return run_cli(ap, ns, args)
    summary = main(args)
    print(f"trained {summary['timesteps']} steps in {summary['wall_time_s']:.1f} s -> {summary['out']}")
    return summary
