"""A trained SB3 agent behind the policy protocol: the model plus its VecNormalize statistics."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np

__all__ = ["SB3Policy"]


class SB3Policy:
    """``predict`` of a saved SB3 model on raw env observations (normalised with the training
    run's VecNormalize statistics, if any), so it plugs into the evaluator like a scripted policy.

    Parameters
    ----------
    model : stable_baselines3 BaseAlgorithm
    vecnormalize : stable_baselines3 VecNormalize, optional
        Only its observation statistics are used (``normalize_obs``), never updated.
    """

    def __init__(self, model, vecnormalize=None):
        self.model = model
        self.vecnormalize = vecnormalize
        if vecnormalize is not None:
            vecnormalize.training = False

    @classmethod
    def load(cls, path: str | Path, best: bool = False) -> SB3Policy:
        """Load a run directory written by ``python -m train`` (``model.zip``, or
        ``best/best_model.zip`` with ``best=True``, and ``vecnormalize.pkl``), or a model ``.zip``
        (with a ``vecnormalize.pkl`` beside it, if there is one)."""
        import yaml
        from stable_baselines3 import PPO, SAC, TD3

        p = Path(path)
        if p.is_dir():
            run_dir = p
            model_path = p / ("best/best_model.zip" if best else "model.zip")
        else:
            run_dir, model_path = p.parent, p
        if not model_path.exists():
            raise FileNotFoundError(f"no SB3 model at {model_path}; train one with `python -m train --out DIR`")
        algo = "ppo"
        cfg = run_dir / "config.yml"
        if cfg.exists():
            algo = yaml.safe_load(cfg.read_text())["args"]["algo"]
        model = {"ppo": PPO, "sac": SAC, "td3": TD3}[algo].load(str(model_path), device="cpu")
        vn_path = run_dir / "vecnormalize.pkl"
        vecnormalize = None
        if vn_path.exists():
            with open(vn_path, "rb") as f:
                vecnormalize = pickle.load(f)
        return cls(model, vecnormalize)

    def predict(self, obs, state=None, episode_start=None, deterministic: bool = True):
        """SB3's ``predict`` on raw observations (23,) or (n, 23)."""
        o = np.asarray(obs, dtype=np.float32)
        if self.vecnormalize is not None:
            o = self.vecnormalize.normalize_obs(o).astype(np.float32)
        return self.model.predict(o, state=state, episode_start=episode_start, deterministic=deterministic)
