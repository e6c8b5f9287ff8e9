"""Wrappers for constrained-RL libraries.

Two conventions exist for a per-step safety cost:

* **Gymnasium's 5-tuple with the cost in ``info``**: the env already returns
  ``info["cost"]`` (the normalised data-rate shortfall plus the stability-violation indicator;
  ``info["cost_rate"]`` and ``info["cost_stability"]`` separately). Libraries that read the cost
  from ``info`` (e.g. OmniSafe's Gymnasium adapters, a Lagrangian callback in SB3) need no wrapper.
* **Safety-Gymnasium's 6-tuple** ``(obs, reward, cost, terminated, truncated, info)``:
  :class:`SafetyCostWrapper`, for the single env and the native vector env alike.

The 6-tuple is a property of the outermost layer only: a Gymnasium wrapper placed around
:class:`SafetyCostWrapper` (``RecordEpisodeStatistics``, ``TimeLimit``, ``ClipAction``, ...) expects
the 5-tuple from what it wraps. :class:`SafetyCostWrapper` therefore returns the 6-tuple when its
caller is not a wrapper of it, and Gymnasium's 5-tuple (the cost still in ``info["cost"]``) when an
enclosing wrapper calls it, so it can sit at any depth of a wrapper stack; apply it outermost to get
the 6-tuple out of the stack. The same holds for the vector envs that step it as a sub-env
(Gymnasium's ``SyncVectorEnv`` and ``AsyncVectorEnv``, SB3's ``DummyVecEnv``): they get the 5-tuple,
and :class:`SafetyCostWrapper` around the vector env gives the costs as an array.
"""

from __future__ import annotations

import sys

import gymnasium as gym
import numpy as np

__all__ = ["SafetyCostWrapper", "SafetyCostVectorWrapper"]


def _called_by_enclosing_wrapper(wrapper, depth: int = 2) -> bool:
    """Whether the frame ``depth`` levels up expects Gymnasium's 5-tuple from ``wrapper``: a method of a
    wrapper that wraps it, of a vector env that holds it as a sub-env (``envs``: Gymnasium's
    ``SyncVectorEnv``, SB3's ``DummyVecEnv``), or any code of Gymnasium itself (its wrappers, the worker of
    ``AsyncVectorEnv``, its env checker).
    """
    frame = sys._getframe(depth)
    if frame.f_globals.get("__name__", "").startswith("gymnasium."):
        return True
    caller = frame.f_locals.get("self")
    if caller is None or caller is wrapper:
        return False
    if getattr(caller, "env", None) is wrapper:
        return isinstance(caller, (gym.Wrapper, gym.vector.VectorWrapper))
    envs = getattr(caller, "envs", None)
    return isinstance(envs, (list, tuple)) and any(e is wrapper for e in envs)


class SafetyCostWrapper(gym.Wrapper):
    """Return Safety-Gymnasium's 6-tuple ``(obs, reward, cost, terminated, truncated, info)``.

    ``cost`` is ``info["cost"]``: the normalised data-rate shortfall plus the stability-violation
    indicator of the slot (both also in ``info`` separately). ``reset`` is unchanged. Wrapping a
    vector env (``gymnasium.make_vec(..., vectorization_mode="vector_entry_point")`` or
    :class:`iscc_gym.envs.vector.ISCCVectorEnv`) gives a :class:`SafetyCostVectorWrapper` (``cost`` of
    shape (num_envs,)). Inside another Gymnasium wrapper or as a sub-env of a vector env it passes
    the 5-tuple through (module docstring), so it works in any order with Gymnasium's wrappers and
    inside ``gymnasium.make_vec(..., vectorization_mode="sync"/"async", wrappers=[SafetyCostWrapper])``.
    It can be deep-copied and pickled.

    Examples
    --------
    >>> import gymnasium as gym, iscc_gym
    >>> from iscc_gym.envs.wrappers import SafetyCostWrapper
    >>> env = SafetyCostWrapper(gym.wrappers.RecordEpisodeStatistics(gym.make("iscc_gym/ISCC-v0")))
    >>> obs, info = env.reset(seed=0)
    >>> obs, reward, cost, terminated, truncated, info = env.step(env.action_space.sample())
    """

    def __new__(cls, env=None, *args, **kwargs):
        # ``env`` is optional: copy and pickle rebuild the object with ``cls.__new__(cls)`` and then restore
        # its ``__dict__`` (deepcopy, pickle, the sub-env of AsyncVectorEnv)
        if isinstance(env, gym.vector.VectorEnv):
            return SafetyCostVectorWrapper(env)
        return super().__new__(cls)

    def __init__(self, env: gym.Env):
        if not isinstance(env, gym.Env):
            raise TypeError(f"SafetyCostWrapper wraps a gymnasium.Env or VectorEnv, got {type(env).__name__}")
        super().__init__(env)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        if _called_by_enclosing_wrapper(self):
            return obs, reward, terminated, truncated, info
        return obs, reward, float(info["cost"]), terminated, truncated, info


class SafetyCostVectorWrapper(gym.vector.VectorWrapper):
    """:class:`SafetyCostWrapper` of a vector env: ``(obs, rewards, costs, terminations, truncations,
    infos)`` with ``costs = infos["cost"]`` (float64, shape (num_envs,); 0 for a sub-env whose
    ``_cost`` mask is off, i.e. that did not step: an autoreset step; the ended step's ``final_info["cost"]`` for
    a sub-env reset in the same step, ``AutoresetMode.SAME_STEP``).
    """

    def step(self, actions):
        obs, rewards, terminations, truncations, infos = self.env.step(actions)
        if _called_by_enclosing_wrapper(self):
            return obs, rewards, terminations, truncations, infos
        costs = np.asarray(infos.get("cost", np.zeros(self.num_envs)), dtype=np.float64)
        mask = infos.get("_cost")
        if mask is not None:
            costs = np.where(np.asarray(mask, dtype=bool), costs, 0.0)
        final = infos.get("final_info")
        if final is not None and "cost" in final:  # SameStep: the top level holds a reset's info, the step's is here
            costs = np.where(np.asarray(final["_cost"], dtype=bool), np.asarray(final["cost"], np.float64), costs)
        return obs, rewards, costs, terminations, truncations, infos
