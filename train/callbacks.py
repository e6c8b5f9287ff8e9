"""The callbacks and progress of a training run (:func:`iscc_gym.train.train.main`): SB3's EvalCallback on fixed
held-out missions with the best model kept as a unit, the learning curve, checkpoints, and the progress lines and
bar on stderr (the device trainer says its progress with the same functions).
"""

from __future__ import annotations

import copy
import sys
import time
from pathlib import Path

import numpy as np
from iscc_gym.commands.protocol import CALLBACK_EVAL_SEED_START

from .args import Args
from .runs import replace_unit, save_evaluations

__all__ = ["eval_callback", "curve_callback", "checkpoint_callback", "steps_callback", "progress_bar_on", "printer",
           "whole_rollouts", "say_rounding", "clock", "progress_text", "PROGRESS_EVERY_S"]

#: Seconds between two progress lines of the training loop on stderr (without a progress bar).
PROGRESS_EVERY_S = 10.0


def eval_callback(eval_env, args: Args, out: Path, identity: dict, resumed: dict, after=None,
                   callback_after_eval=None):
    """SB3's EvalCallback playing the same held-out missions at every evaluation (the eval env is
    re-seeded with :data:`CALLBACK_EVAL_SEED_START`: a VecEnv forgets its seeds after a reset, and ``best`` is
    chosen on one fixed set of episodes), keeping the best model unless beaten, saved as a unit with its
    own VecNormalize statistics in ``out/best`` (written whole, then swapped in: :func:`replace_unit`).

    Evaluations are due every ``eval_freq`` steps (rounded down to whole VecEnv steps) on a schedule of
    env steps, not of this session's calls: ``resumed`` (:func:`_resume`) continues the evaluations, the
    best score and the schedule of the run it resumes, and an evaluation that was due but never
    completed (a kill during it) is done at the start of training. ``after(callback)`` runs after each.
    """
    from stable_baselines3.common.callbacks import EvalCallback
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.vec_env import VecNormalize

    every = max(1, args.eval_freq // max(1, args.n_envs)) * max(1, args.n_envs)

    class HeldOutEvalCallback(EvalCallback):
        stop = False
        best_timesteps: int | None = None

        def schedule(self) -> dict:
            last = self.evaluations_timesteps[-1] if self.evaluations_timesteps else None
            return {"every": every, "last": last, "next": self.next_due}

        def _on_training_start(self) -> None:
            super()._on_training_start()
            if self.num_timesteps >= self.next_due:  # due before the run was cut off, and never completed
                self.stop = not self._evaluate()

        def _on_step(self) -> bool:
            if self.stop:
                return False
            return self._evaluate() if self.num_timesteps >= self.next_due else True

        def _evaluate(self) -> bool:
            self.eval_env.seed(CALLBACK_EVAL_SEED_START)
            vecnormalize = self.model.get_vec_normalize_env()
            if vecnormalize is not None and isinstance(self.eval_env, VecNormalize):
                # the training VecNormalize's statistics, whatever wrappers sit below it (a constrained
                # run's Lagrangian wrapper has no counterpart in the evaluation env)
                self.eval_env.obs_rms = copy.deepcopy(vecnormalize.obs_rms)
                self.eval_env.ret_rms = copy.deepcopy(vecnormalize.ret_rms)
            rewards, lengths = evaluate_policy(self.model, self.eval_env, n_eval_episodes=self.n_eval_episodes,
                                               deterministic=self.deterministic, return_episode_rewards=True,
                                               warn=self.warn)
            t = int(self.num_timesteps)
            self.evaluations_timesteps.append(t)
            self.evaluations_results.append([float(r) for r in rewards])
            self.evaluations_length.append([int(n) for n in lengths])
            self.next_due = (t // every + 1) * every
            save_evaluations(out / "eval" / "evaluations.npz", self.evaluations_timesteps, self.evaluations_results,
                             self.evaluations_length)
            mean = float(np.mean(rewards))
            self.last_mean_reward = mean
            if self.verbose >= 1:
                print(f"Eval num_timesteps={t}, episode_reward={mean:.2f} +/- {np.std(rewards):.2f}")
            self.logger.record("eval/mean_reward", mean)
            self.logger.record("eval/mean_ep_length", float(np.mean(lengths)))
            self.logger.record("time/total_timesteps", t, exclude="tensorboard")
            self.logger.dump(t)
            if mean > self.best_mean_reward:
                replace_unit(out / "best", self.model, vecnormalize, model_name="best_model.zip", timesteps=t,
                             mean_reward=mean, run=identity)
                self.best_mean_reward, self.best_timesteps = mean, t
            if after is not None:
                after(self)
            return self._on_event() if self.callback is not None else True

    cb = HeldOutEvalCallback(eval_env, n_eval_episodes=args.eval_episodes, eval_freq=every, deterministic=True,
                             verbose=args.verbose, callback_after_eval=callback_after_eval)
    history, schedule = resumed["evaluations"], resumed["schedule"] or {}
    cb.evaluations_timesteps = list(history["timesteps"])
    cb.evaluations_results = list(history["results"])
    cb.evaluations_length = list(history["ep_lengths"])
    cb.best_mean_reward, cb.best_timesteps = resumed["best"], resumed["best_timesteps"]
    last = cb.evaluations_timesteps[-1] if cb.evaluations_timesteps else 0
    # the saved schedule, unless the run resumes with another eval_freq (then from the last evaluation)
    cb.next_due = schedule["next"] if schedule.get("every") == every and schedule.get("next") is not None else (
        (last // every + 1) * every)
    return cb


def curve_callback(rows: list[dict] | None = None, wall_s: float = 0.0):
    """A callback recording (timesteps, wall time, mean training episode reward) at every rollout end,
    after ``rows`` (of the run it resumes; wall time goes on from its ``wall_s``); ``elapsed()`` is the
    run's wall time so far.
    """
    from stable_baselines3.common.callbacks import BaseCallback

    class _Curve(BaseCallback):
        def __init__(self):
            super().__init__()
            self.rows: list[dict] = list(rows or [])
            self.t0 = time.perf_counter() - wall_s

        def elapsed(self) -> float:
            return time.perf_counter() - self.t0

        def _on_step(self) -> bool:
            return True

        def _on_rollout_end(self) -> None:
            buf = self.model.ep_info_buffer
            self.rows.append({"timesteps": self.num_timesteps, "wall_s": self.elapsed(),
                              "train_ep_reward_mean": float(np.mean([e["r"] for e in buf])) if buf else float("nan"),
                              "train_ep_length_mean": float(np.mean([e["l"] for e in buf])) if buf else float("nan")})

    return _Curve()


def checkpoint_callback(every_calls: int, save):
    """Calls ``save(model)`` after every ``every_calls`` steps of the VecEnv, at the start of the next
    rollout: between two rollouts, when the model has been trained on the rollouts before, the
    multipliers updated and the learning curve's row recorded (SAC/TD3: the step's transitions are in
    the replay buffer). The run's last checkpoint is saved by :func:`main` after training.
    """
    from stable_baselines3.common.callbacks import BaseCallback

    class Checkpoints(BaseCallback):
        due = False

        def _on_step(self) -> bool:
            if self.n_calls % every_calls == 0:
                self.due = True
            return True

        def _on_rollout_start(self) -> None:
            if self.due:
                self.due = False
                save(self.model)

    return Checkpoints()


def progress_bar_on(args: Args) -> bool:
    """Whether to show SB3's progress bar: ``progress_bar``, else on a terminal unless ``quiet``
    (and only if tqdm and rich are installed).
    """
    import importlib.util

    on = args.progress_bar if args.progress_bar is not None else (not args.quiet and sys.stdout.isatty())
    return bool(on) and all(importlib.util.find_spec(m) is not None for m in ("tqdm", "rich"))


def printer(args: Args):
    """``say(text)``: a progress line ``train: text`` on stderr (flushed, so it shows without a terminal
    too), nothing with ``quiet``.
    """
    def say(text: str) -> None:
        if not args.quiet:
            print(f"train: {text}", file=sys.stderr, flush=True)

    return say


def whole_rollouts(start: int, total: int, n_envs: int, n_steps: int | None) -> int:
    """The step an on-policy run (``n_steps`` per env a rollout) stops at when asked to train from ``start`` to
    ``total``: it ends on whole rollouts, so ``total`` rounds up to ``start`` plus whole rollouts; ``total`` where
    ``n_steps`` is None (SAC, TD3: step by step).
    """
    if n_steps is None or total <= start:
        return total
    rollout = n_steps * n_envs
    return start + -(-(total - start) // rollout) * rollout


def say_rounding(say, asked: int, target: int, trainer: str, n_envs: int, n_steps: int | None) -> None:
    """Say where a budget of ``asked`` steps rounds up to ``target`` (:func:`whole_rollouts`; issue 43.11: runs
    trained 4,096 steps for 2,000 asked without a word).
    """
    if target != asked:
        say(f"--total-timesteps {asked:,} rounds up to {target:,}: {trainer} trains whole rollouts of {n_envs:,} envs "
            f"x {n_steps} steps = {n_envs * n_steps:,}")


def clock(seconds: float) -> str:
    """``H:MM:SS`` of ``seconds`` (0 for a negative time)."""
    s = max(int(round(seconds)), 0)
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


def progress_text(done: int, total: int, rate: float, elapsed_s: float) -> str:
    """One progress line of a training run: steps done of ``total``, steps/s, elapsed time, time left."""
    eta = clock((total - done) / rate) if rate > 0 else "?"
    return f"step {done:,}/{total:,}, {rate:,.0f} steps/s, elapsed {clock(elapsed_s)}, ETA {eta}"


def steps_callback(say, total: int):
    """A line every :data:`PROGRESS_EVERY_S` seconds: steps done of ``total``, steps/s of this session,
    elapsed time and the estimated time left.
    """
    from stable_baselines3.common.callbacks import BaseCallback

    class Steps(BaseCallback):
        def _on_training_start(self) -> None:
            self.t0 = self.last = time.perf_counter()
            self.start = int(self.num_timesteps)

        def _on_step(self) -> bool:
            now = time.perf_counter()
            if now - self.last >= PROGRESS_EVERY_S:
                self.last = now
                done = int(self.num_timesteps)
                rate = (done - self.start) / max(now - self.t0, 1e-9)
                say(progress_text(done, total, rate, now - self.t0))
            return True

    return Steps()
