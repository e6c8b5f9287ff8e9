r"""``python -m train --learner dagger``: a student of ``aware`` under DAgger (:mod:`agents.student`).

Round 0 plays the teacher, ``aware`` (``myopic`` shown the slot's world by the world-shown env), on ``n_envs``
training missions; each later round plays, slot by slot and env by env, the teacher with probability
:math:`\beta_r = \beta^r` and the student otherwise (Ross et al.'s DAgger mixture), every visited slot labelled with
the teacher's split. The student is refitted after each round on all rounds' data (warm-started; truncated
back-propagation through time over the missions in order, Adam, the cross-entropy of its split against the
teacher's). A share of each round's missions is held out of the fit; the summary gives the held-out cross-entropy
after each round. The student never reads the world block: its inputs are the observation without it and the
measurements ``bayes`` reads.

Writes into OUT: ``student.pt`` (``--policies student:OUT``), ``config.yml`` and ``summary.yml``.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import yaml

from iscc_gym.files import write_atomic

from .callbacks import printer
from .estimator import check_out, learner_scenario, settings_of, tbptt_pass

__all__ = ["main", "rollout", "fit_student", "SETTINGS"]

#: The student's settings (``--set KEY=VALUE``) and defaults.
SETTINGS = {"hidden": 64, "rounds": 4, "beta": 0.5, "epochs": 8, "chunk": 100, "learning_rate": 3e-3,
            "held_out": 0.125}


def rollout(scenario, student, n_envs: int, n_slots: int, seed: int, beta: float, rng, say=None) -> dict:
    """One DAgger round: ``n_envs`` world-shown missions from ``seed``, each slot played by ``aware`` with probability
    ``beta`` (per env and slot; 1: the teacher alone) and by ``student`` otherwise. Returns the student's inputs
    (T, N, F), the teacher's splits (T, N, 3), the played rewards (T, N) and the share the student played.
    """
    from iscc_gym.agents import make_policy
    from iscc_gym.agents.sb3_vec_env import ISCCBatchedVecEnv
    from iscc_gym.train.privileged import world_entries

    from iscc_gym.sim.task import split_to_action

    shown = scenario.replace(show_world=True)
    venv = ISCCBatchedVecEnv(n_envs, scenario=shown)
    venv.seed(seed)
    nw = world_entries(scenario)
    teacher = make_policy("myopic", shown)
    obs = venv.reset()
    out = None
    played = 0
    t0 = time.perf_counter()
    for t in range(n_slots):
        label, _ = teacher.split_batch(np.asarray(obs, dtype=float))
        split, _ = student.split_batch(obs[:, :-nw])
        if out is None:
            out = {"x": np.empty((n_slots, n_envs, student.inputs.shape[1]), np.float32),
                   "obs": np.empty((n_slots, n_envs, obs.shape[1] - nw), np.float32),
                   "y": np.empty((n_slots, n_envs, 3), np.float32), "reward": np.empty((n_slots, n_envs))}
        out["x"][t], out["y"][t], out["obs"][t] = student.inputs, label, obs[:, :-nw]
        own = rng.random(n_envs) >= beta
        played += int(own.sum())
        obs, reward, _, _ = venv.step(split_to_action(np.where(own[:, None], split, label)))
        out["reward"][t] = reward
        if say is not None and (t + 1) % 1000 == 0:
            say(f"played {t + 1:,} of {n_slots:,} slots on {n_envs} envs ({time.perf_counter() - t0:.0f} s)")
    venv.close()
    out["student_share"] = played / (n_envs * n_slots)
    return out


def fit_student(net, x, y, epochs: int, chunk: int, learning_rate: float, fit_rows, val_rows, say=None) -> float:
    """Fit ``net`` on inputs ``x`` (T, N, F) and teacher splits ``y`` (T, N, 3) over the envs ``fit_rows`` (index
    arrays); returns the held-out rows' mean cross-entropy after the last epoch (NaN without held-out rows).
    """
    import torch

    opt = torch.optim.Adam(net.parameters(), lr=learning_rate)
    xt, yt = torch.from_numpy(x), torch.from_numpy(y)

    def run(rows, train: bool) -> float:
        def slot_losses(t, logits):
            return (-(yt[t, rows] * torch.log_softmax(logits[0], 1)).sum(),)

        return tbptt_pass(net, xt, rows, chunk, slot_losses, opt if train else None)[0]

    val = math.nan
    for epoch in range(epochs):
        net.train()
        fit_ce = run(fit_rows, True)
        net.eval()
        val = run(val_rows, False) if len(val_rows) else math.nan
        if say is not None:
            say(f"  epoch {epoch + 1}/{epochs}: cross-entropy {fit_ce:.5f} (held out {val:.5f})")
    return val


def main(args) -> dict:
    """Train the student of ``args`` (``env_id``, ``out``, ``seed``, ``n_envs``, ``total_timesteps`` slots a round in
    all, ``overrides``: :data:`SETTINGS`); returns the summary.
    """
    import torch
    from iscc_gym.agents.estimator import recurrent_heads, save_estimator
    from iscc_gym.agents.student import FILE, StudentPolicy, n_student_inputs, student_inputs

    from iscc_gym.sim.schema import obs_size

    say = printer(args)
    preset, scenario = learner_scenario(args, "dagger")
    settings = settings_of(args, SETTINGS)
    n_envs = int(args.n_envs or 64)
    n_slots = max(1, int(args.total_timesteps or 320_000) // n_envs)
    out = Path(args.out)
    check_out(out, args.overwrite, (FILE, "config.yml", "summary.yml"))
    torch.set_num_threads(args.torch_threads)
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    t0 = time.perf_counter()
    size = obs_size(scenario)
    net = recurrent_heads(n_student_inputs(size), (3,), settings["hidden"])
    meta = {"kind": "student", "inputs": n_student_inputs(size), "hidden": settings["hidden"], "scenario": preset,
            "env_overrides": dict(args.env_overrides), "obs_mean": [0.0] * size, "obs_std": [1.0] * size}
    student = StudentPolicy(scenario, net=net, meta=meta)
    xs, ys, rounds = [], [], []
    n_val = max(1, int(round(settings["held_out"] * n_envs))) if n_envs > 1 else 0
    for r in range(settings["rounds"]):
        beta = settings["beta"] ** r
        say(f"round {r + 1}/{settings['rounds']}: {n_envs} training missions, {n_slots:,} slots, the teacher "
            f"playing with probability {beta:.3g}")
        data = rollout(scenario, student, n_envs, n_slots, args.seed + 10_000 * r, beta, rng, say)
        if r == 0:  # the observation's standardisation, from the teacher's own missions
            o = data["obs"].reshape(-1, size).astype(float)
            std = o.std(axis=0)
            meta["obs_mean"], meta["obs_std"] = o.mean(axis=0).tolist(), np.where(std > 1e-9, std, 1.0).tolist()
            x = data["x"].reshape(-1, data["x"].shape[-1])
            data["x"] = student_inputs(x[:, :-size], o, np.asarray(meta["obs_mean"]),
                                       np.asarray(meta["obs_std"])).reshape(data["x"].shape)
            student = StudentPolicy(scenario, net=net, meta=meta)
        xs.append(data["x"])
        ys.append(data["y"])
        x, y = np.concatenate(xs, axis=1), np.concatenate(ys, axis=1)
        val_rows = np.concatenate([np.arange(k * n_envs + n_envs - n_val, (k + 1) * n_envs) for k in range(r + 1)])
        fit_rows = np.setdiff1d(np.arange(x.shape[1]), val_rows)
        val = fit_student(net, x, y, settings["epochs"], settings["chunk"], settings["learning_rate"], fit_rows,
                          val_rows, say)
        rounds.append({"round": r + 1, "beta": round(beta, 6), "student_share": round(data["student_share"], 4),
                       "mean_reward": round(float(data["reward"].mean()), 5),
                       "held_out_cross_entropy": round(val, 6)})
        say(f"round {r + 1}: mean reward a slot {rounds[-1]['mean_reward']:.4f} (student played "
            f"{data['student_share']:.0%}), held-out cross-entropy {val:.5f}")
    out.mkdir(parents=True, exist_ok=True)
    net.eval()
    save_estimator(out / FILE, net, meta)
    wall = time.perf_counter() - t0
    config = {"learner": "dagger", "env_id": args.env_id, "scenario": preset, "env_overrides": dict(args.env_overrides),
              "seed": args.seed, "n_envs": n_envs, "slots_per_round": n_slots * n_envs, "settings": settings}
    write_atomic(out / "config.yml", yaml.safe_dump(config, sort_keys=False))
    summary = {"learner": "dagger", "timesteps": n_slots * n_envs * settings["rounds"], "wall_time_s": round(wall, 1),
               "rounds": rounds, "out": str(out)}
    write_atomic(out / "summary.yml", yaml.safe_dump(summary, sort_keys=False))
    return summary
