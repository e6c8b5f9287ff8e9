"""The tiny training runs the train tests share: 256 steps on 2 envs, evaluations and checkpoints every 128."""

from iscc_gym.train import Args

TINY = {"n_steps": 64, "batch_size": 64, "n_epochs": 1}


def tiny_args(out, **kw) -> Args:
    """A tiny run into ``out``; keyword arguments override any field of :class:`Args`."""
    base = dict(total_timesteps=256, n_envs=2, eval_freq=128, eval_episodes=2, eval_max_steps=50,
                checkpoint_freq=128, out=str(out), overrides=dict(TINY), tensorboard=False, init_policy="none")
    base.update(kw)
    return Args(**base)
