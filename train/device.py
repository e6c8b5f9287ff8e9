"""``python -m train --device cuda|standin``: the device PPO (:mod:`iscc_gym.agents.device_ppo`) configured from the
task's YAML entry.
"""

from __future__ import annotations

from pathlib import Path

from iscc_gym.agents.device_ppo import DEVICE_DEFAULTS, DevicePPOConfig, train

__all__ = ["config_from_args", "main"]


def config_from_args(args, device: str) -> DevicePPOConfig:
    """The device run of ``python -m train --device cuda`` (or ``standin``): the task's YAML entry
    (:mod:`iscc_gym.train.config`: discount, GAE, clip range, entropy, learning rate, network, normalisation, budget)
    on the device's batch sizes (:data:`DEVICE_DEFAULTS`, unless ``--n-envs`` or ``--set n_steps=`` / ``batch_size=``
    say otherwise).

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
    for name, flag in (("residual", "--residual"), ("init_policy", "--init-policy"), ("randomize", "--randomize"),
                       ("cost_limit", "--cost-limit")):
        value = getattr(resolved, name)
        if value not in (None, "none"):
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
    kw = {"n_envs": DEVICE_DEFAULTS["n_envs"] if args.n_envs is None else resolved.n_envs,
          "n_steps": int(over.get("n_steps", DEVICE_DEFAULTS["n_steps"])),
          "batch_size": int(over.get("batch_size", DEVICE_DEFAULTS["batch_size"]))}
    unknown = sorted(set(hp) - {"policy", "n_steps", "batch_size", "n_epochs", "learning_rate", "gamma", "gae_lambda",
                                "clip_range", "ent_coef", "vf_coef", "max_grad_norm", "policy_kwargs"})
    if unknown:
        raise ValueError(f"hyperparameters {unknown} of {args.env_id}'s entry (or --set) have no meaning to the device "
                         "trainer; drop them or train with SB3 (drop --device)")
    return DevicePPOConfig(
        env_id=args.env_id, device="cuda" if device == "cuda" else "cpu", total_timesteps=int(resolved.total_timesteps),
        n_epochs=int(hp.get("n_epochs", 10)), learning_rate=float(lr), gamma=float(hp.get("gamma", 0.99)),
        gae_lambda=float(hp.get("gae_lambda", 0.95)), clip_range=float(hp.get("clip_range", 0.2)),
        ent_coef=float(hp.get("ent_coef", 0.0)), vf_coef=float(hp.get("vf_coef", 0.5)),
        max_grad_norm=float(hp.get("max_grad_norm", 0.5)), net_arch=list(pk.get("net_arch", [64, 64])),
        activation=act, log_std_init=float(pk.get("log_std_init", 0.0)), normalize=bool(resolved.normalize),
        norm_reward=bool(resolved.norm_reward), seed=int(args.seed), env_overrides=dict(resolved.env_overrides),
        pool_size=DEVICE_DEFAULTS["pool_size"], **kw)


def main(args, device: str) -> dict:
    """``python -m train --device cuda|standin``: train on the device env into ``args.out`` (refusing a non-empty
    folder unless ``--overwrite``); returns the summary.
    """
    out = Path(args.out)
    if out.exists() and any(out.iterdir()) and not args.overwrite:
        raise FileExistsError(f"{out} is not empty: pass --overwrite to replace its run, or another --out")
    cfg = config_from_args(args, device)
    summary = train(cfg, out=out, quiet=args.quiet)
    summary["out"] = str(out)
    return summary
