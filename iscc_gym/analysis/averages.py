"""Trajectory-averaged link quantities and bounds: the averages of the paper's Sec. IV-C over
positions sampled along seeded reference trajectories (Sec. V-A).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from iscc_gym.physics.channel import large_scale_snr
from iscc_gym.physics.fbl import comm_rate_bps
from iscc_gym.physics.sensing import crlb, peb, veb
from iscc_gym.scenario import Scenario
from iscc_gym.trajectory import sample_reference

__all__ = ["TrajectorySample", "sample_positions", "mean_snr", "mean_comm_rate_bps", "mean_bounds"]


@dataclass(frozen=True)
class TrajectorySample:
    """Drone positions along sampled reference trajectories (every ``stride``-th slot).

    Attributes
    ----------
    pos_m : ndarray, shape (n, 3)
        Reference positions in m, trajectories concatenated.
    n_trajectories : int
    """

    pos_m: np.ndarray
    n_trajectories: int


def sample_positions(s: Scenario, n_trajectories: int, seed: int = 0, stride: int = 10) -> TrajectorySample:
    """Reference positions of ``n_trajectories`` seeded trajectories (Sec. V-A), one every
    ``stride`` slots (slot 0 included).

    Raises
    ------
    ValueError
        ``n_trajectories`` or ``stride`` not a positive integer.
    """
    for name, v in (("n_trajectories", n_trajectories), ("stride", stride)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise ValueError(f"{name} = {v!r} is invalid: must be an integer >= 1")
    rng = np.random.default_rng(seed)
    pos = [sample_reference(s, rng).pos_m[::stride] for _ in range(n_trajectories)]
    return TrajectorySample(np.concatenate(pos), int(n_trajectories))


def mean_snr(s: Scenario, sample: TrajectorySample) -> float:
    r"""Trajectory-averaged SNR :math:`\bar\gamma` (linear mean of the large-scale SNR, shadowing at
    its 0 dB median, :math:`\mathbb E|g|^2 = 1`), the SNR of the paper's Sec. IV-C.1.
    """
    return float(np.mean(large_scale_snr(s, sample.pos_m, 0.0)))


def mean_comm_rate_bps(s: Scenario, sample: TrajectorySample, alpha_comm: float = 1.0) -> float:
    """Trajectory average of the data link's FBL rate (eq:rate_equation) at ``alpha_comm``, in bit/s
    (large-scale SNR, no fading).
    """
    return float(np.mean(comm_rate_bps(s, alpha_comm, large_scale_snr(s, sample.pos_m, 0.0))))


def mean_bounds(s: Scenario, sample: TrajectorySample, alpha_sen: float):
    """Trajectory-averaged PEB (m) and VEB (m/s) at ``alpha_sen`` (large-scale echo, no fading)."""
    cp, cv = crlb(s, alpha_sen, sample.pos_m, 0.0)
    return float(np.mean(peb(cp))), float(np.mean(veb(cv)))
