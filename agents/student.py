r"""``student:PATH``: a recurrent policy distilled from ``aware`` under DAgger (learning by cheating).

Chen et al.'s "learning by cheating" (arXiv 1912.12294) trains a privileged teacher, then a student that sees only
what a deployed policy sees and imitates the teacher on the student's own rollouts (DAgger: Ross et al., 2011). The
field task's privileged teacher needs no training: ``aware`` (``myopic`` designed on the slot's true K-factor and RCS)
is the bound. :class:`StudentPolicy` reads each slot's observation (the world block hidden) and the measurements
:class:`agents.bayes.BayesPolicy`'s filter reads (:data:`agents.bayes.ESTIMATOR_INPUTS`), keeps a GRU state over the
mission, and outputs the split (a softmax of three logits). ``python -m train --learner dagger``
(:mod:`iscc_gym.train.dagger`) fits it by the cross-entropy of its split against ``aware``'s.

What it can learn is the teacher's split averaged over the worlds the history leaves possible, not the split that is
best under that uncertainty (``bayes``'s design): a stated limit of imitating a teacher who knows more than the
student can.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from iscc_gym.scenario import Scenario
from iscc_gym.sim.functional import decode_observation

from .base import as_obs_batch
from .bayes import ESTIMATOR_INPUTS
from .estimator import RecurrentPolicy, load_estimator

__all__ = ["StudentPolicy", "FILE", "student_inputs", "n_student_inputs"]

#: The file of a trained student in its run directory.
FILE = "student.pt"


def n_student_inputs(obs_size: int) -> int:
    """The student's inputs a slot: the measurements and the observation's entries."""
    return len(ESTIMATOR_INPUTS) + obs_size


def student_inputs(measured, obs, mean, std) -> np.ndarray:
    """The student's inputs (n, :func:`n_student_inputs`), float32: ``measured`` (:func:`agents.bayes.estimator_inputs`)
    and the observation standardised by ``mean`` and ``std`` (its training data's), clipped to +-10.
    """
    z = np.clip((np.asarray(obs, dtype=float) - mean) / std, -10.0, 10.0)
    return np.concatenate([measured, z], axis=1).astype(np.float32)


class StudentPolicy(RecurrentPolicy):
    """The DAgger student (module docstring): a split per slot from its GRU over the hidden observation and the
    measurements (:class:`agents.estimator.RecurrentPolicy`).

    Parameters
    ----------
    scenario : Scenario or str
        The field task's scenario (its observation without the world block).
    path : str or Path
        A run directory of ``python -m train --learner dagger`` (or its :data:`FILE`).
    net, meta : optional
        The network and its meta in place of ``path`` (the trainer's student during its rollouts).
    """

    def __init__(self, scenario: Scenario | str = "field", path: str | Path = "", net=None, meta=None, **kwargs):
        if net is None:
            net, meta = load_estimator(path, "student")
        super().__init__(scenario, **kwargs)
        if int(meta["inputs"]) != n_student_inputs(self.obs_size):
            raise ValueError(f"student:{path} reads {meta['inputs']} inputs a slot, this scenario's student "
                             f"{n_student_inputs(self.obs_size)}: it was trained on another env; retrain it")
        self.net, self.meta = net, meta
        self._mean = np.asarray(meta["obs_mean"], dtype=float)
        self._std = np.asarray(meta["obs_std"], dtype=float)
        self.path = str(path)
        self.name = "student"

    def net_inputs(self, obs) -> np.ndarray:
        """The measurements and the observation, standardised (:func:`student_inputs`)."""
        return student_inputs(self.measured_inputs(), obs, self._mean, self._std)

    def split_batch(self, obs, state=None, episode_start=None):
        """The student's splits (n, 3) for observations (n, obs_size); its inputs are kept in :attr:`inputs`."""
        o, _ = as_obs_batch(obs, self.obs_size)
        if not np.all(np.isfinite(o)):
            raise ValueError("obs contains NaN or inf; pass the env's (finite) observations")
        (split,) = self.advance(decode_observation(o, self.scenario), o)
        return split, state
