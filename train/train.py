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
interrupted write is never taken for a complete one; ``best/`` is written whole beside the old one and
swapped in. A checkpoint also holds ``resume.yml``: the learning curve and wall time, the evaluations
and their schedule, the best score and a constrained run's multipliers, all a resume continues
(``learning_curve.csv`` is rewritten at every evaluation and checkpoint). Model files and
``vecnormalize.pkl`` are pickles: load only files you trust.

Progress goes to stderr, also without a terminal: a line per stage (setup, warm start, each
evaluation and checkpoint) and every :data:`~iscc_gym.train.callbacks.PROGRESS_EVERY_S` seconds (steps,
steps/s, elapsed, ETA);
``--quiet`` silences it.

The hyperparameters come from ``train/hyperparams.yml``, in rl-zoo3's layout (env id -> the PPO
hyperparameters; ``python -m rl_zoo3.train --algo ppo --env iscc_gym/ISCC-v0 --gym-packages iscc_gym
-conf train/hyperparams.yml`` trains the same configuration); its ``iscc_gym.train`` key, which
rl-zoo3 never reads, holds this command's own run settings (the warm start) and the SAC/TD3 entries.
"""

from __future__ import annotations

import dataclasses
import math
import pickle
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import yaml
from iscc_gym.agents.residual import RECORD_KEYS
from iscc_gym.agents.sb3_logging import stdout_logger
from iscc_gym.agents.sb3_policy import LAGRANGE_FILE
from iscc_gym.commands.protocol import CALLBACK_EVAL_SEED_START, INIT_SEED_START

from iscc_gym.files import write_atomic
from iscc_gym.tasks import TASKS, is_fleet

from .callbacks import (
    checkpoint_callback,
    curve_callback,
    eval_callback,
    printer,
    progress_bar_on,
    say_rounding,
    steps_callback,
    whole_rollouts,
)
from .config import (
    Args,
    action_noise,
    algo_class,
    check_args,
    check_hyperparams,
    check_resolved,
    expand_algo,
    has_residual,
    has_warm_start,
    randomized,
    randomized_overrides,
    resolve_args,
    resolve_policy_kwargs,
)
from .runs import (
    RESUME_FILE,
    best_score,
    load_vecnormalize,
    prepare_out,
    read_history,
    read_resume,
    recover_unit,
    resume_state,
    run_identity,
    save_unit,
    write_curve,
)

__all__ = ["main", "make_train_env", "make_env", "make_eval_env", "with_residual", "batched_kwargs", "world_critic",
           "world_entries",
           "set_numba_threads"]


def make_env(env_id: str, **kwargs):
    """``gymnasium.make(env_id, **kwargs)``: each env of a dummy or subproc training VecEnv. A subproc worker
    (started by forkserver) begins with gymnasium's registry alone; it unpickles this function by reference,
    importing this module and so ``iscc_gym``, whose import registers the env ids.
    """
    import gymnasium as gym

    import iscc_gym  # noqa: F401  (the env ids, in a worker that has not imported it yet)

    return gym.make(env_id, **kwargs)


def make_train_env(args: Args, residual: dict | None = None):
    """The training VecEnv, with episode statistics (Monitor / VecMonitor) for the logs; a residual run's base
    built from its record ``residual`` (:func:`with_residual`).
    """
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecMonitor

    if args.vec_env == "batched":
        from iscc_gym.agents.sb3_vec_env import ISCCBatchedVecEnv

        keys = ("cost_rate", "cost_stability") if args.cost_limit else ()
        if randomized(args):  # equal shares of the envs (the first ones one more), one scenario per share
            from iscc_gym.agents.sb3_vec_env import ConcatVecEnv

            sets = randomized_overrides(args)
            sizes = [args.n_envs // len(sets) + (k < args.n_envs % len(sets)) for k in range(len(sets))]
            venv = ConcatVecEnv([ISCCBatchedVecEnv(n, scenario=args.scenario, info_keys=keys, **o)
                                 for n, o in zip(sizes, sets, strict=True) if n > 0])
        elif args.reward == "expected":  # the world shown to the simulator's reward, hidden from the agent
            from iscc_gym.train.privileged import INFO_KEYS, ExpectedRewardVecEnv

            from iscc_gym.scenario import make_scenario

            venv = ISCCBatchedVecEnv(args.n_envs, scenario=args.scenario, info_keys=tuple(dict.fromkeys(
                keys + INFO_KEYS)), **{**batched_kwargs(args), "show_world": True})
            venv.seed(args.seed)
            venv = ExpectedRewardVecEnv(venv, make_scenario(args.scenario, **args.env_overrides),
                                        keep_world=world_critic(args))
            return VecMonitor(with_residual(venv, args, residual))
        else:
            venv = ISCCBatchedVecEnv(args.n_envs, scenario=args.scenario, info_keys=keys, **batched_kwargs(args),
                                     **({"show_world": True} if world_critic(args) else {}))
        venv.seed(args.seed)
        return VecMonitor(with_residual(venv, args, residual))
    kwargs = {"scenario": args.scenario, **args.env_overrides} if args.env_id in TASKS else {}
    kwargs["env_id"] = args.env_id  # made by make_env, which a subproc worker imports iscc_gym for
    cls = SubprocVecEnv if args.vec_env == "subproc" else DummyVecEnv
    # make_vec_env wraps each env in a Monitor already (below the residual: it records the env's rewards)
    return with_residual(make_vec_env(make_env, n_envs=args.n_envs, seed=args.seed, vec_env_cls=cls,
                                      env_kwargs=kwargs), args, residual)


def with_residual(venv, args: Args, residual: dict | None = None):
    """``venv`` as a residual agent's env (:class:`agents.residual.ResidualVecEnv` on ``args.residual``, built
    for the run's scenario with the tuned parameters of the run's record ``residual``, by default
    :func:`agents.residual.residual_record` now), or unchanged without a residual.
    """
    if not has_residual(args):
        return venv
    from iscc_gym.agents.residual import ResidualVecEnv, base_policy, residual_record

    if residual is None:
        residual = residual_record(args.residual, args.residual_scale, args.scenario, args.env_overrides,
                                   args.residual_space or "action")
    base = base_policy(residual)
    return ResidualVecEnv(venv, base, residual["residual_scale"], residual.get("residual_space", "action"),
                          world_entries=world_entries(args))


def world_critic(args: Args) -> bool:
    """Whether the run's critic is shown the world (``--critic world``: the env shows it, the actor hides it)."""
    return getattr(args, "critic", "own") == "world"


def world_entries(args: Args) -> int:
    """The world block's entries in the run's observations (0 unless the critic is shown the world)."""
    if not world_critic(args):
        return 0
    from iscc_gym.train.privileged import world_entries as entries

    from iscc_gym.scenario import make_scenario

    return entries(make_scenario(args.scenario, **args.env_overrides))


def batched_kwargs(args: Args) -> dict:
    """The batched env's keyword arguments: the env overrides, and for the multi-drone env its
    ``n_drones`` (default :data:`iscc_gym.sim.fleet.N_DRONES`).
    """
    kw = dict(args.env_overrides)
    if is_fleet(args.env_id):
        from iscc_gym.sim.fleet import N_DRONES

        kw.setdefault("n_drones", N_DRONES)
    return kw


def make_eval_env(args: Args, residual: dict | None = None):
    """Held-out evaluation episodes: seeds CALLBACK_EVAL_SEED_START + i, one sub-env per episode (a residual run's
    base built from its record ``residual``).
    """
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor

    if args.env_id in TASKS:
        from iscc_gym.agents.sb3_vec_env import ISCCBatchedVecEnv

        venv = ISCCBatchedVecEnv(args.eval_episodes, scenario=args.scenario, **batched_kwargs(args),
                                 **({"show_world": True} if world_critic(args) else {}))
        if args.eval_max_steps < venv.venv.max_steps:
            venv.venv.max_steps = args.eval_max_steps
        venv.seed(CALLBACK_EVAL_SEED_START)
        return VecMonitor(with_residual(venv, args, residual))
    venv = make_vec_env(args.env_id, n_envs=args.eval_episodes, vec_env_cls=DummyVecEnv)
    venv.seed(CALLBACK_EVAL_SEED_START)
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
    play = ISCCBatchedVecEnv(args.init_envs, scenario=args.scenario, **batched_kwargs(args))
    if is_fleet(args.env_id):  # a multi-drone baseline (agents.multi) for the env's per-drone scenario
        from iscc_gym.agents.multi import make_multi_policy

        policy = make_multi_policy(args.init_policy, play.venv.scenario, play.venv.n_drones)
    else:
        policy = make_policy(args.init_policy, args.scenario)
    play.seed(INIT_SEED_START + 1000 * args.seed)
    play = VecNormalize(play, gamma=venv.gamma, clip_obs=venv.clip_obs, clip_reward=venv.clip_reward)
    res = behaviour_clone(model, venv, policy, args.init_steps, collect_env=play, log_std=args.init_log_std,
                          seed=args.seed, log=print if args.verbose else (lambda *_: None))
    play.close()
    return {"policy": args.init_policy, "envs": args.init_envs, "steps_per_env": args.init_steps, **res}


def _load_model(algo_cls, path: Path, **kw):
    """``algo_cls.load`` of a checkpoint's model, a ``ValueError`` naming the file if it cannot be loaded."""
    try:
        return algo_cls.load(str(path), **kw)
    except (zipfile.BadZipFile, EOFError, pickle.UnpicklingError, KeyError, ValueError, RuntimeError) as e:
        raise ValueError(f"{path}: not a model python -m train can resume ({type(e).__name__}: {e})") from None


def _warn(text: str) -> None:
    """A line on stderr that ``quiet`` does not silence (what a resume could not keep)."""
    print(f"train: warning: {text}", file=sys.stderr, flush=True)


def _resume(args: Args, out: Path, ckpt: Path | None, manifest: dict | None, say=_warn) -> dict:
    """What a run continues: for a new run nothing; for a resumed one its checkpoint's
    :data:`~train.runs.RESUME_FILE` (an older checkpoint without one: ``out``'s evaluations, learning curve
    and ``lagrange.yml``), the best score of ``out/best`` (after :func:`recover_unit`), and, for a
    constrained run, the multipliers (checked: :func:`train.lagrangian.check_lagrange`).

    Raises
    ------
    ValueError, FileNotFoundError
        A damaged file, naming it and the field; a constrained run whose multipliers are nowhere.
    """
    fresh = {"evaluations": {"timesteps": [], "results": [], "ep_lengths": []}, "curve": [], "wall_s": 0.0,
             "schedule": None, "best": -np.inf, "best_timesteps": None, "lagrange": None}
    if ckpt is None:
        return fresh
    from .lagrangian import check_lagrange, load_lagrange, parse_cost_limits

    start = int(manifest["timesteps"])
    state = read_resume(ckpt, manifest)
    names = list(parse_cost_limits(args.cost_limit)) if args.cost_limit else None
    res = dict(fresh)
    if state is not None:
        res.update(evaluations=state["evaluations"], curve=state["curve"], wall_s=float(state["wall_s"]),
                   schedule=state["schedule"])
        if names is not None:
            if state["lagrange"] is None:
                raise ValueError(f"{ckpt / RESUME_FILE}: lagrange = None; the run is constrained ({args.cost_limit}) "
                                 "but its checkpoint holds no multipliers (a damaged checkpoint: move it away)")
            res["lagrange"] = check_lagrange(state["lagrange"], f"{ckpt / RESUME_FILE}: lagrange", names)
    else:
        say(f"{ckpt} predates {RESUME_FILE}: its evaluations, learning curve and multipliers are read from {out}")
        history, rows = read_history(out, start)
        res.update(evaluations=history, curve=rows, wall_s=rows[-1]["wall_s"] if rows else 0.0)
        if names is not None:
            res["lagrange"] = load_lagrange(out, names)
            if res["lagrange"] is None:
                raise FileNotFoundError(f"resume: {out / LAGRANGE_FILE} is missing and {ckpt} (of an older python -m "
                                        "train) holds no multipliers: they would restart at 0; train into another "
                                        "--out")
            res["lagrange"]["history"] = [h for h in res["lagrange"]["history"] if h["timesteps"] <= start]
    note = recover_unit(out / "best")
    if note:
        say(note)
    res["best"], res["best_timesteps"], why = best_score(out)
    recorded = (state or {}).get("best")
    if why is not None or (recorded is not None and not math.isfinite(res["best"])):
        say(f"{out / 'best'} is missing or incomplete ({why or 'no such directory'}); "
            + (f"the checkpoint recorded a best of {recorded['mean_reward']:.2f} at step {recorded['timesteps']:,}; "
               if recorded else "") + "the best model is chosen afresh from the next evaluation")
    return res


def main(args: Args, callback_after_eval=None) -> dict:
    """Train, save everything into ``args.out``; returns a summary (paths, steps, wall time).

    ``args.out`` must be new or empty, unless ``args.resume`` (continue from its newest complete
    checkpoint: same algo, env, scenario, normalisation, evaluation episodes, constraints and
    hyperparameters; evaluations and their schedule, learning curve, wall time, best model and score,
    and multipliers continued) or ``args.overwrite`` (its run files deleted first). Every setting is
    checked before any work (:func:`~train.config.check_hyperparams`, :func:`~train.config.check_resolved`).

    ``callback_after_eval`` (an SB3 ``BaseCallback``, optional) runs after every held-out evaluation
    as the EvalCallback's child (``parent.last_mean_reward``); returning False stops training. The
    Optuna studies of :mod:`train.study` report and prune through it.
    """
    import torch
    from stable_baselines3.common.callbacks import CallbackList
    from stable_baselines3.common.vec_env import VecNormalize

    import iscc_gym  # noqa: F401  (registers the env)

    say = printer(args)
    args = expand_algo(args)
    check_args(args)
    if callback_after_eval is not None and args.eval_freq <= 0:
        raise ValueError(f"eval_freq = {args.eval_freq} with a callback_after_eval; use eval_freq >= 1")
    args, hp = resolve_args(args)
    if args.cost_limit:  # the multipliers alone price the costs, unless the run sets the weights
        args = dataclasses.replace(args, env_overrides={"w_rate": 0.0, "w_stab": 0.0, **args.env_overrides})
    kw = check_hyperparams(args.algo, resolve_policy_kwargs(hp))
    check_resolved(args, kw)
    ckpt, manifest = prepare_out(args, hp)
    identity = run_identity(args, hp, manifest)
    # the residual base's record, resolved once: the base trains on it and every saved model holds it
    residual = {k: identity[k] for k in RECORD_KEYS} if identity["residual"] else None
    out = Path(args.out)
    resumed = _resume(args, out, ckpt, manifest)
    say((f"resuming {out} from {ckpt} (step {int(manifest['timesteps']):,})" if ckpt is not None else
         f"setting up {args.algo} on {args.env_id} into {out}")
        + f": {args.total_timesteps:,} steps on {args.n_envs} envs ({args.vec_env})")
    set_numba_threads(args.numba_threads)
    # after numba's: launching numba's OpenMP pool (first in a process, again in a fork) sets OpenMP's thread
    # count, which torch shares; the other order left torch on numba's threads (2 instead of 1 in a forked worker)
    torch.set_num_threads(args.torch_threads)
    out.mkdir(parents=True, exist_ok=True)
    algo_cls = algo_class(args.algo)
    off_policy = args.algo in ("sac", "td3")
    venv = make_train_env(args, residual)
    lagrange = None
    if args.cost_limit:
        from .lagrangian import LagrangianVecEnv, parse_cost_limits

        venv = lagrange = LagrangianVecEnv(venv, parse_cost_limits(args.cost_limit),
                                           resumed["lagrange"]["lambdas"] if resumed["lagrange"] else None)
    warm_start = None
    ckpt_dir = out / "checkpoints"
    start = int(manifest["timesteps"]) if manifest else 0
    history = resumed["evaluations"]
    if args.normalize:
        if ckpt is not None:
            venv = load_vecnormalize(ckpt / "vecnormalize.pkl", venv)
            venv.training = True
        else:
            venv = VecNormalize(venv, gamma=kw.get("gamma", 0.99), norm_reward=bool(args.norm_reward))
    tb = str(out / "tb") if args.tensorboard else None
    if ckpt is not None:
        model = _load_model(algo_cls, ckpt / "model.zip", env=venv, device="cpu", tensorboard_log=tb)
        if "replay_buffer.pkl" in manifest["files"]:
            try:
                model.load_replay_buffer(ckpt / "replay_buffer.pkl")
            except (EOFError, pickle.UnpicklingError, AttributeError, TypeError, ValueError) as e:
                raise ValueError(f"{ckpt / 'replay_buffer.pkl'}: not a replay buffer python -m train can resume "
                                 f"({type(e).__name__}: {e})") from None
    else:
        kw = action_noise(kw, venv.num_envs, venv.action_space.shape[0])
        policy = kw.pop("policy", "MlpPolicy")
        if world_critic(args):  # the critic shown the world, the actor not (agents/world_critic.py)
            from iscc_gym.agents.world_critic import WorldCriticPolicy

            policy = WorldCriticPolicy
            kw["policy_kwargs"] = {**kw.get("policy_kwargs", {}), "world_entries": world_entries(args)}
        model = algo_cls(policy, venv, seed=args.seed, device="cpu", verbose=args.verbose, tensorboard_log=tb, **kw)
        if has_warm_start(args):
            say(f"warm start: cloning {args.init_policy} played on {args.init_envs} envs x {args.init_steps:,} steps")
            warm_start = _behaviour_clone(model, venv, args)
            say(f"warm start done in {warm_start['wall_time_s']:.1f} s (actor MSE {warm_start['actor_mse']:.3g})")
    if tb is None:
        model.set_logger(stdout_logger(args.verbose))
    resolved = {"args": dataclasses.asdict(args), "hyperparams": hp}
    write_atomic(out / "config.yml", yaml.safe_dump(resolved, sort_keys=False))
    vecnormalize = venv if args.normalize else None
    saved = {"step": start if ckpt else None}
    curve = curve_callback(resumed["curve"], resumed["wall_s"])
    lagrange_cb = eval_cb = None

    def evaluations() -> dict:
        if eval_cb is None:
            return history
        return {"timesteps": list(eval_cb.evaluations_timesteps), "results": list(eval_cb.evaluations_results),
                "ep_lengths": list(eval_cb.evaluations_length)}

    def means() -> list[tuple[int, float]]:
        ev = evaluations()
        return list(zip(ev["timesteps"], [float(np.mean(r)) for r in ev["results"]], strict=True))

    def best() -> dict | None:
        score, t = (eval_cb.best_mean_reward, eval_cb.best_timesteps) if eval_cb is not None else (
            resumed["best"], resumed["best_timesteps"])
        return {"mean_reward": float(score), "timesteps": t} if math.isfinite(score) and t is not None else None

    def checkpoint(m) -> None:
        step = int(m.num_timesteps)
        schedule = eval_cb.schedule() if eval_cb is not None else resumed["schedule"]
        state = resume_state(timesteps=step, wall_s=curve.elapsed(), curve=curve.rows, evaluations=evaluations(),
                             schedule=schedule or {"every": None, "last": None, "next": None}, best=best(),
                             lagrange=lagrange_cb.state() if lagrange_cb is not None else None)
        d = save_unit(ckpt_dir / f"step_{step}", m, vecnormalize, replay_buffer=off_policy,
                      texts={RESUME_FILE: state}, timesteps=step, run=identity)
        saved["step"] = step
        write_curve(out, curve.rows, means(), png=False)
        say(f"checkpoint at step {step:,} -> {d}")

    def evaluated(cb) -> None:
        write_curve(out, curve.rows, means(), png=False)
        at = f" at step {cb.best_timesteps:,}" if cb.best_timesteps is not None else ""
        say(f"evaluation at step {cb.evaluations_timesteps[-1]:,}: mean reward {cb.last_mean_reward:.2f} "
            f"(best {cb.best_mean_reward:.2f}{at})")

    callbacks = [curve]
    if lagrange is not None:
        from .lagrangian import LagrangeCallback

        callbacks.append(lagrange_cb := LagrangeCallback(
            lagrange, args.lagrange_lr, out, history=resumed["lagrange"]["history"] if resumed["lagrange"] else None))
    if args.eval_freq > 0:
        eval_env = make_eval_env(args, residual)
        if args.normalize:
            eval_env = VecNormalize(eval_env, training=False, norm_reward=False)
        eval_cb = eval_callback(eval_env, args, out, identity, resumed, evaluated, callback_after_eval)
        callbacks.append(eval_cb)
    per_env = max(1, args.n_envs)
    if args.checkpoint_freq > 0:  # after the evaluation of the same step: the checkpoint holds it
        callbacks.append(checkpoint_callback(max(1, args.checkpoint_freq // per_env), checkpoint))
    bar = progress_bar_on(args)
    remaining = args.total_timesteps - start
    n_steps = model.n_steps if isinstance(getattr(model, "n_steps", None), int) else None  # on-policy only
    target = whole_rollouts(start, args.total_timesteps, model.n_envs, n_steps)
    say_rounding(say, args.total_timesteps, target, args.algo, model.n_envs, n_steps)
    if not args.quiet and not bar:
        callbacks.append(steps_callback(say, target))
    t0 = time.perf_counter()
    if remaining > 0:
        say(f"training from step {start:,} to {target:,}")
        model.learn(remaining, callback=CallbackList(callbacks), reset_num_timesteps=ckpt is None,
                    progress_bar=bar, tb_log_name=args.algo)
    wall = time.perf_counter() - t0
    if args.checkpoint_freq > 0 and saved["step"] != model.num_timesteps:
        checkpoint(model)  # --resume with a larger --total-timesteps goes on from the end
    save_unit(out, model, vecnormalize, timesteps=int(model.num_timesteps), run=identity)
    evals = means()
    write_curve(out, curve.rows, evals)
    venv.close()
    bc_wall = warm_start["wall_time_s"] if warm_start else 0.0
    summary = {"out": str(out), "timesteps": int(model.num_timesteps), "wall_time_s": wall + bc_wall,
               "env_steps_per_s": (remaining / wall) if remaining > 0 and wall > 0 else None,
               "evaluations": evals, "best": best(), "resumed_from": str(ckpt) if ckpt else None,
               "warm_start": warm_start}
    if lagrange is not None:
        lagrange_cb.save()
        summary["lagrange"] = {**lagrange.as_dict(), "lr": args.lagrange_lr,
                               "last_outage": lagrange_cb.history[-1]["outage"] if lagrange_cb.history else None}
    write_atomic(out / "summary.yml", yaml.safe_dump(summary, sort_keys=False))
    say(f"done: {summary['timesteps']:,} steps in {summary['wall_time_s']:.1f} s -> {out}")
    return summary
