"""Several seeds of one training configuration (``python -m train --seeds 0,1,2``): one run per seed,
each scored on the held-out missions (:func:`evaluate_run`), and the table of their rewards.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
import yaml
from iscc_gym.commands.protocol import CALLBACK_EVAL_SEED_START
from iscc_gym.train.config import (
    Args,
    algo_class,
    check_args,
    check_hyperparams,
    check_resolved,
    expand_algo,
    resolve_args,
    resolve_policy_kwargs,
)

from iscc_gym.files import write_atomic

from .study_io import StudyConfigError


def evaluate_run(args: Args) -> tuple[float, float]:
    """Mean and std of the episode rewards of the model saved in ``args.out`` on the held-out seeds.

    The episodes are those of the EvalCallback's first evaluation (seeds ``CALLBACK_EVAL_SEED_START + i``,
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
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.vec_env import VecNormalize

    args, _ = resolve_args(args)
    out = Path(args.out)
    env = make_eval_env(args)
    if args.normalize:
        env = VecNormalize.load(str(out / "vecnormalize.pkl"), env)
        env.training, env.norm_reward = False, False
    model = algo_class(args.algo).load(str(out / "model.zip"), device="cpu")
    rewards, _ = evaluate_policy(model, env, n_eval_episodes=args.eval_episodes, deterministic=True,
                                 return_episode_rewards=True)
    env.close()
    return float(np.mean(rewards)), float(np.std(rewards))


# --- several seeds of one configuration -------------------------------------------------------------------

def check_run_config(args: Args) -> tuple[Args, dict]:
    """The resolved ``args`` and hyperparameters of a training run, checked before any run starts;
    a bad value raises :class:`StudyConfigError` (one line naming it).
    """
    try:
        check_args(args)
        resolved, hp = resolve_args(args)
        check_hyperparams(args.algo, resolve_policy_kwargs(hp))
    except ValueError as e:
        raise StudyConfigError(str(e)) from None
    return resolved, hp


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
    resolved, hp = check_run_config(args)
    for seed in seeds:  # every seed's run checked before the first one trains (a held-out seed among them)
        try:
            res, hp_seed = resolve_args(dataclasses.replace(expand_algo(args), seed=seed))
            check_resolved(res, check_hyperparams(res.algo, resolve_policy_kwargs(hp_seed)))
        except ValueError as e:
            raise StudyConfigError(f"--seeds {seed}: {e}") from None
    rows = []
    for seed in seeds:
        run = dataclasses.replace(args, seed=seed, out=str(Path(args.out) / f"seed_{seed}"))
        t0 = time.perf_counter()
        from iscc_gym.train.train import main

        summary = main(run)
        mean, std = evaluate_run(run)
        rows.append({"seed": seed, "out": run.out, "final_reward_mean": mean, "final_reward_std": std,
                     "timesteps": summary["timesteps"], "train_time_s": round(summary["wall_time_s"], 3),
                     "wall_time_s": round(time.perf_counter() - t0, 3)})
    finals = [r["final_reward_mean"] for r in rows]
    result = {"env_id": args.env_id, "algo": args.algo, "n_timesteps": resolved.total_timesteps,
              "n_envs": resolved.n_envs, "eval_episodes": args.eval_episodes,
              "eval_seed_start": CALLBACK_EVAL_SEED_START,
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
