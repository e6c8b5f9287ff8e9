"""``python -m train --device cuda|standin``: the device PPO (:mod:`iscc_gym.train.device_ppo`) configured from the
task's YAML entry.
"""

from __future__ import annotations

import math
from dataclasses import asdict
from pathlib import Path

import yaml
from iscc_gym.train.device_ppo import DEVICE_DEFAULTS, DevicePPOConfig, default_n_envs, to_sb3, train
from iscc_gym.train.runs import plot_curve, prepare_out, save_unit

from iscc_gym.files import write_atomic
from iscc_gym.tasks import registered_scenario

__all__ = ["config_from_args", "main"]


def config_from_args(args, device: str) -> DevicePPOConfig:
    """The device run of ``python -m train --device cuda`` (or ``standin``): the task's YAML entry
    (:mod:`iscc_gym.train.config`: discount, GAE, clip range, entropy, learning rate, network, normalisation, budget)
    on the device's batch sizes and rate schedule (:data:`DEVICE_DEFAULTS`: on a GPU as many envs as fill it, a
    rollout cut into four minibatches, the rate adapted to a KL target (rsl_rl's), the rows started spread over the
    mission; unless ``--n-envs`` or ``--set n_steps=`` /
    ``batch_size=`` / ``lr_schedule=`` / ``desired_kl=`` say otherwise).

    Raises
    ------
    ValueError
        A setting the device trainer does not have (another algorithm, a residual or warm-started or randomised run,
        a learning-rate schedule), naming it.
    """
    from iscc_gym.train.config import resolve_args

    if args.algo != "ppo":
        raise ValueError(f"--algo {args.algo}: --device {device} trains PPO only; drop --device for SB3's {args.algo}")
    resolved, hp = resolve_args(args)
    for name, flag, plain in (("residual", "--residual", "none"), ("init_policy", "--init-policy", "none"),
                              ("randomize", "--randomize", "none"), ("cost_limit", "--cost-limit", "none"),
                              ("reward", "--reward", "sampled"), ("critic", "--critic", "own")):
        value = getattr(resolved, name)
        if value not in (None, "none", plain):
            raise ValueError(f"{flag} {value!r} (set by the flag or the YAML entry of {args.env_id}): the device "
                             f"trainer has no {name.replace('_', ' ')}; train it with SB3 (drop --device)")
    pk = dict(hp.get("policy_kwargs") or {})
    act = pk.get("activation_fn", "Tanh")
    act = act if isinstance(act, str) else act.__name__
    act = {"tanh": "Tanh", "relu": "ReLU", "elu": "ELU", "leaky_relu": "LeakyReLU", "gelu": "GELU"}.get(
        act.split(".")[-1].lower(), act.split(".")[-1])
    lr = hp.get("learning_rate", 3e-4)
    if not isinstance(lr, (int, float)):
        raise ValueError(f"learning_rate = {lr!r}: the device trainer takes a constant; --set learning_rate=3e-4")
    over = args.overrides or {}
    kw = {"n_envs": default_n_envs(device) if args.n_envs is None else resolved.n_envs,
          "n_steps": int(over.get("n_steps", DEVICE_DEFAULTS["n_steps"])),
          "batch_size": int(over["batch_size"]) if "batch_size" in over else None,
          "lr_schedule": str(over.get("lr_schedule", DEVICE_DEFAULTS["lr_schedule"])),
          "desired_kl": float(over.get("desired_kl", DEVICE_DEFAULTS["desired_kl"]))}
    unknown = sorted(set(hp) - {"policy", "n_steps", "batch_size", "n_epochs", "learning_rate", "gamma", "gae_lambda",
                                "clip_range", "ent_coef", "vf_coef", "max_grad_norm", "policy_kwargs", "lr_schedule",
                                "desired_kl"})
    if unknown:
        raise ValueError(f"hyperparameters {unknown} of {args.env_id}'s entry (or --set) have no meaning to the device "
                         "trainer; drop them or train with SB3 (drop --device)")
    return DevicePPOConfig(
        env_id=args.env_id, scenario=resolved.scenario, device="cuda" if device == "cuda" else "cpu",
        total_timesteps=int(resolved.total_timesteps),
        n_epochs=int(hp.get("n_epochs", 10)), learning_rate=float(lr), gamma=float(hp.get("gamma", 0.99)),
        gae_lambda=float(hp.get("gae_lambda", 0.95)), clip_range=float(hp.get("clip_range", 0.2)),
        ent_coef=float(hp.get("ent_coef", 0.0)), vf_coef=float(hp.get("vf_coef", 0.5)),
        max_grad_norm=float(hp.get("max_grad_norm", 0.5)), net_arch=list(pk.get("net_arch", [64, 64])),
        activation=act, log_std_init=float(pk.get("log_std_init", 0.0)), normalize=bool(resolved.normalize),
        norm_reward=bool(resolved.norm_reward), seed=int(args.seed), env_overrides=dict(resolved.env_overrides),
        pool_size=DEVICE_DEFAULTS["pool_size"], **kw)


def main(args, device: str) -> dict:
    """``python -m train --device cuda|standin``: train on the device env, then save the agent into ``args.out`` as a
    unit of ``python -m train`` (:func:`iscc_gym.train.runs.save_unit`: ``model.zip``, ``vecnormalize.pkl``,
    ``config.yml`` and the manifest, each under a temporary name first; the folder checked and, with ``--overwrite``,
    cleared by :func:`iscc_gym.train.runs.prepare_out`, as an SB3 run's); returns the summary.
    """
    if args.resume:
        raise ValueError(f"--resume: --device {device} keeps no checkpoints; train afresh (--overwrite) or drop "
                         "--device")
    from iscc_gym.train.config import check_args

    check_args(args)  # the checks of an SB3 run: the env id, the seed, a scenario of another task, ...
    cfg = config_from_args(args, device)
    prepare_out(args)
    from iscc_gym.train.callbacks import printer, say_rounding, whole_rollouts

    say = printer(args)
    target = whole_rollouts(0, cfg.total_timesteps, cfg.n_envs, cfg.n_steps)
    say_rounding(say, cfg.total_timesteps, target, "the device PPO", cfg.n_envs, cfg.n_steps)
    say(f"training {target:,} steps on {cfg.n_envs:,} device envs ({device}) into {args.out}; the first rollout "
        "compiles the device step")
    rows = []
    summary, trained = train(cfg, callback=_progress(say, target, rows), quiet=True)
    model, vecnormalize = to_sb3(cfg, trained, summary["timesteps"])
    run = {"algo": "ppo", "env_id": cfg.env_id, "scenario": cfg.scenario or registered_scenario(cfg.env_id),
           "env_overrides": dict(cfg.env_overrides), "normalize": cfg.normalize, "residual": None,
           "trainer": "device_ppo", "device": device}
    record = {"args": {**run, **{k: v for k, v in asdict(cfg).items() if k not in run}},
              "timesteps": int(summary["timesteps"]), "wall_time_s": float(summary["wall_time_s"]),
              "steps_per_s": float(summary["steps_per_s"])}
    out = save_unit(args.out, model, vecnormalize, texts={"config.yml": yaml.safe_dump(record, sort_keys=False)},
                    timesteps=int(summary["timesteps"]), run=run)
    summary["out"] = str(out)
    write_device_curve(out, rows)
    write_atomic(out / "summary.yml", yaml.safe_dump(
        {"out": str(out), "timesteps": int(summary["timesteps"]), "wall_time_s": float(summary["wall_time_s"]),
         "env_steps_per_s": float(summary["steps_per_s"]), "rollout_s": float(summary["rollout_s"]),
         "update_s": float(summary["update_s"]), "iterations": int(summary["iterations"]), "device": device,
         "trainer": "device_ppo"}, sort_keys=False))
    say(f"done: {summary['timesteps']:,} steps in {summary['wall_time_s']:.1f} s -> {out}")
    return summary


def _progress(say, target: int, rows: list):
    """The trainer's callback: records each update's row of the learning curve and says the progress every
    :data:`iscc_gym.train.train.PROGRESS_EVERY_S` seconds and at the first and last update (steps, steps/s,
    elapsed, ETA), as an SB3 run does.
    """
    from iscc_gym.train.callbacks import PROGRESS_EVERY_S, progress_text

    last = [-math.inf]

    def callback(summary, policy, obs_rms) -> bool:
        done, wall = int(summary["timesteps"]), float(summary["wall_time_s"])
        _, reward, _, lr, kl = summary["curve"][-1]
        rows.append({"timesteps": done, "wall_s": wall, "reward_per_step": float(reward), "learning_rate": lr,
                     "approx_kl": kl})
        if wall - last[0] >= PROGRESS_EVERY_S or done >= target or len(rows) == 1:
            last[0] = wall
            rate = done / max(wall, 1e-9)
            say(f"{progress_text(done, target, rate, wall)}, reward per step {rows[-1]['reward_per_step']:.3f}")
        return False

    return callback


def write_device_curve(out: Path, rows: list[dict]) -> None:
    """A device run's ``learning_curve.csv`` (timesteps, wall time, the mean reward per step of each update's
    rollout: the device env's rows rarely end an episode within a rollout, so no episode means; the update's last
    learning rate and mean approximate KL) and its ``.png`` against env steps and against seconds.
    """
    lines = ["timesteps,wall_s,train_reward_per_step_mean,learning_rate,approx_kl"]
    lines += [f"{r['timesteps']},{r['wall_s']:.3f},{r['reward_per_step']!r},{r['learning_rate']!r},{r['approx_kl']!r}"
              for r in rows]
    write_atomic(out / "learning_curve.csv", "\n".join(lines) + "\n")
    plot_curve(out, [([r["timesteps"] for r in rows], [r["reward_per_step"] for r in rows], "-", "train rollouts")],
               "mean reward per step", seconds=[r["wall_s"] for r in rows])
