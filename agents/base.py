"""The policy protocol shared by scripted and learned agents, and the fixed-split policies.

Every policy answers SB3's ``predict(obs, state=None, episode_start=None, deterministic=True) ->
(action, state)``, so evaluation code treats a scripted policy and a trained SB3 model alike. The
action is the env's action in [-1, 1]^3 (:func:`iscc_gym.sim.task.split_to_action` of the split); the env
maps it back onto the simplex with :func:`iscc_gym.sim.task.action_to_split`.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np

from iscc_gym.sim.schema import OBS_NAMES
from iscc_gym.sim.task import check_split, split_to_action

__all__ = ["Policy", "SplitPolicy", "FixedSplitPolicy", "EqualSplitPolicy", "validate_split", "as_obs_batch"]

N_OBS = len(OBS_NAMES)


@runtime_checkable
class Policy(Protocol):
    """SB3-style policy: ``predict`` maps an observation (23,) or a batch (n, 23) to an action (3,)
    or (n, 3) in [-1, 1] and a recurrent state (``None`` for stateless policies).
    """

    def predict(self, obs, state=None, episode_start=None, deterministic: bool = True) -> tuple[np.ndarray, Any]:
        ...


def validate_split(split, name: str = "split") -> np.ndarray:
    """Return ``split`` as a float array (3,) if it is a split (finite, non-negative, summing to 1).

    Raises
    ------
    ValueError
        Naming ``name`` and what is wrong.
    """
    a = np.asarray(split, dtype=float)
    if a.shape != (3,):
        raise ValueError(f"{name} must have 3 entries (alpha_sen, alpha_ctrl, alpha_comm), got shape {a.shape}")
    check_split(a, name)
    return a / a.sum()


def as_obs_batch(obs, size: int | None = None) -> tuple[np.ndarray, bool]:
    """``(batch (n, size), was_single)`` from one observation (size,) or a batch (n, size).

    ``size``: the scenario's observation length (:func:`iscc_gym.sim.schema.obs_size`); None accepts any length
    from the paper's 23 on (a rule that reads only the first 23 entries, which every task shares).

    Raises
    ------
    ValueError
        Any other shape.
    """
    o = np.asarray(obs, dtype=float)
    ok = (lambda m: m >= N_OBS) if size is None else (lambda m: m == size)
    if o.ndim == 1 and ok(o.shape[0]):
        return o[None], True
    if o.ndim == 2 and ok(o.shape[1]):
        return o, False
    want = f"{N_OBS} or more" if size is None else str(size)
    raise ValueError(f"obs must have shape (m,) or (n, m) with m = {want} entries (this scenario's observation), "
                     f"got {o.shape}")


class SplitPolicy:
    """Base of the scripted policies: subclasses implement :meth:`split_batch` (the split per
    observation); :meth:`predict` turns splits into env actions.
    """

    def split_batch(self, obs: np.ndarray, state=None, episode_start=None) -> tuple[np.ndarray, Any]:
        """Splits (n, 3) for observations (n, 23), and the new state."""
        raise NotImplementedError

    def predict(self, obs, state=None, episode_start=None, deterministic: bool = True):
        """SB3's ``predict``: the env action(s) playing this policy's split(s).

        Parameters
        ----------
        obs : array_like, shape (23,) or (n, 23)
            Env observation(s) (``iscc_gym.sim.schema.OBS_NAMES``).
        state : optional
            Recurrent state returned by the previous call (``None`` to start afresh).
        episode_start : array_like of bool, shape (n,), optional
            True where a new episode starts (the state of that entry is discarded).
        deterministic : bool
            Ignored: scripted policies are deterministic.

        Returns
        -------
        action : ndarray, float32, shape (3,) or (n, 3)
            In [-1, 1]; the env maps it to the split with ``action_to_split``.
        state
            Recurrent state for the next call.
        """
        batch, single = as_obs_batch(obs, getattr(self, "obs_size", None))
        split, state = self.split_batch(batch, state, episode_start)
        action = split_to_action(split)
        return (action[0] if single else action), state

    def __call__(self, obs, state=None, episode_start=None, deterministic: bool = True):
        return self.predict(obs, state, episode_start, deterministic)


class FixedSplitPolicy(SplitPolicy):
    """Play the same split every slot.

    Parameters
    ----------
    split : array_like, shape (3,)
        (alpha_sen, alpha_ctrl, alpha_comm), non-negative, summing to 1.
    name : str, optional
        Label for tables.

    Raises
    ------
    ValueError
        ``split`` is not a split.
    """

    def __init__(self, split, name: str | None = None):
        self.split = validate_split(split)
        self.action = split_to_action(self.split)
        self.name = name or "fixed:" + ",".join(f"{x:g}" for x in self.split)

    def split_batch(self, obs, state=None, episode_start=None):
        return np.tile(self.split, (len(obs), 1)), state

    def predict(self, obs, state=None, episode_start=None, deterministic: bool = True):
        batch, single = as_obs_batch(obs)
        return (self.action.copy() if single else np.tile(self.action, (len(batch), 1))), state

    def __repr__(self) -> str:
        return f"FixedSplitPolicy({self.split.tolist()}, name={self.name!r})"


class EqualSplitPolicy(FixedSplitPolicy):
    """Equal thirds, (1/3, 1/3, 1/3)."""

    def __init__(self):
        super().__init__(np.full(3, 1.0 / 3.0), name="equal")

    def __repr__(self) -> str:
        return "EqualSplitPolicy()"
