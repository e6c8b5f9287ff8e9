"""Stable-Baselines3 ``VecEnv`` over the native batched env, so PPO and friends train on it directly.

``ISCCBatchedVecEnv(num_envs, scenario=..., **overrides)`` wraps :class:`iscc_gym.envs.vector.ISCCVectorEnv`
in ``SameStep`` autoreset mode and speaks SB3's protocol: ``reset() -> obs``, ``step_wait() ->
(obs, rewards, dones, infos)`` with ``infos[i]["terminal_observation"]`` and
``infos[i]["TimeLimit.truncated"]`` where sub-env i's episode ended. To keep a step of a large batch
cheap, ``infos`` carry only those keys unless ``info_keys`` names more (e.g. ``("cost",)`` for
constrained RL or ``("tracking_error_m",)`` for an EvalCallback-style logger).

Sub-env i seeded s_i (``seed(s)`` gives s + i, SB3's convention) plays exactly the episodes of
``gymnasium.make("iscc_gym/ISCC-v0")`` reset with seed s_i, so a policy trained here and one trained on
``DummyVecEnv`` / ``SubprocVecEnv`` of the single env see the same environment.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from iscc_gym.envs.vector import ISCCVectorEnv
from iscc_gym.scenario import Scenario
from iscc_gym.sim.functional import INFO_KEYS

__all__ = ["ISCCBatchedVecEnv", "ConcatVecEnv"]


class ISCCBatchedVecEnv(VecEnv):
    """SB3 ``VecEnv`` of ``num_envs`` ISCC loops stepped as one batch (see the module docstring)."""

    def __init__(self, num_envs: int, scenario: str | Scenario = "paper", info_keys: Sequence[str] = (),
                 **overrides: Any):
        if isinstance(info_keys, str):
            raise ValueError(f"info_keys = {info_keys!r}; use a sequence of keys, e.g. ({info_keys!r},)")
        unknown = [k for k in info_keys if k not in INFO_KEYS]
        if unknown:
            import difflib

            near = {k: difflib.get_close_matches(k, INFO_KEYS, n=1) for k in unknown}
            hints = "; ".join(f"{k!r}" + (f" (did you mean {m[0]!r}?)" if m else "") for k, m in near.items())
            raise ValueError(f"info_keys: unknown {hints}; the env's info keys are {', '.join(INFO_KEYS)}")
        self.venv = ISCCVectorEnv(num_envs=num_envs, scenario=scenario, autoreset_mode="SameStep",
                                  **overrides)
        self.info_keys = tuple(info_keys)
        self.render_mode = None
        super().__init__(num_envs, self.venv.single_observation_space, self.venv.single_action_space)
        self._actions: np.ndarray | None = None

    # --- SB3 VecEnv protocol -----------------------------------------------------------------------
    def reset(self):
        seeds = self._seeds if any(s is not None for s in self._seeds) else None
        obs, _ = self.venv.reset(seed=seeds)
        self._reset_seeds()
        self._reset_options()
        self.reset_infos = [{} for _ in range(self.num_envs)]
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self):
        obs, reward, terminated, truncated, info = self.venv.step(self._actions)
        dones = terminated | truncated
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        ended = info.get("final_info", {})  # SB3's info of an ended episode: its last step's, not the reset's
        for key in self.info_keys:
            for i in np.flatnonzero(info["_" + key]):
                infos[i][key] = (ended if dones[i] else info)[key][i]
        for i in np.flatnonzero(dones):
            infos[i]["terminal_observation"] = info["final_obs"][i]
            infos[i]["TimeLimit.truncated"] = bool(truncated[i])
        return obs, reward.astype(np.float32), dones, infos

    def close(self) -> None:
        self.venv.close()

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        if attr_name == "render_mode":
            return [None for _ in self._get_indices(indices)]
        value = getattr(self.venv, attr_name)
        return [value for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        raise AttributeError(f"cannot set {attr_name!r}: the batched env's sub-envs share one scenario")

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        raise AttributeError(f"the batched env has no per-sub-env method {method_name!r}")

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self):
        raise NotImplementedError("the batched env does not render; use gymnasium.make(..., render_mode='rgb_array')")


class ConcatVecEnv(VecEnv):
    """Several SB3 VecEnvs as one, their sub-envs side by side (e.g. batched envs of different scenarios:
    training over randomised missions). ``seed(s)`` gives sub-env i of the whole the seed s + i, as one
    VecEnv of the total size would (SB3's convention).

    Raises
    ------
    ValueError
        No envs, or envs of different observation or action spaces.
    """

    def __init__(self, venvs: Sequence[VecEnv]):
        venvs = list(venvs)
        if not venvs:
            raise ValueError("ConcatVecEnv of no envs; give at least one")
        first = venvs[0]
        for v in venvs[1:]:
            if v.observation_space != first.observation_space or v.action_space != first.action_space:
                raise ValueError(f"ConcatVecEnv: spaces differ ({v.observation_space} / {v.action_space} against "
                                 f"{first.observation_space} / {first.action_space}); concatenate envs of one task")
        self.venvs = venvs
        self.sizes = [v.num_envs for v in venvs]
        self.offsets = np.cumsum([0] + self.sizes)
        self.render_mode = None
        super().__init__(int(self.offsets[-1]), first.observation_space, first.action_space)

    def seed(self, seed: int | None = None):
        if seed is None:  # one draw for the whole, so the sub-envs stay distinct (SB3's VecEnv.seed)
            seed = int(np.random.default_rng().integers(0, np.iinfo(np.uint32).max))
        return [s for v, off in zip(self.venvs, self.offsets, strict=False) for s in v.seed(int(seed) + int(off))]

    def reset(self):
        self.reset_infos = [{} for _ in range(self.num_envs)]
        return np.concatenate([v.reset() for v in self.venvs])

    def step_async(self, actions: np.ndarray) -> None:
        actions = np.asarray(actions)
        for v, lo, hi in zip(self.venvs, self.offsets[:-1], self.offsets[1:], strict=True):
            v.step_async(actions[lo:hi])

    def step_wait(self):
        parts = [v.step_wait() for v in self.venvs]
        return (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]),
                np.concatenate([p[2] for p in parts]), [info for p in parts for info in p[3]])

    def close(self) -> None:
        for v in self.venvs:
            v.close()

    def _split(self, indices):
        """``[(venv, local indices)]`` of global ``indices``."""
        out = []
        for v, lo, hi in zip(self.venvs, self.offsets[:-1], self.offsets[1:], strict=True):
            local = [i - lo for i in self._get_indices(indices) if lo <= i < hi]
            if local:
                out.append((v, local))
        return out

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        return [x for v, idx in self._split(indices) for x in v.get_attr(attr_name, idx)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        for v, idx in self._split(indices):
            v.set_attr(attr_name, value, idx)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        return [x for v, idx in self._split(indices)
                for x in v.env_method(method_name, *method_args, indices=idx, **method_kwargs)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [x for v, idx in self._split(indices) for x in v.env_is_wrapped(wrapper_class, idx)]

    def get_images(self):
        raise NotImplementedError("ConcatVecEnv does not render")
