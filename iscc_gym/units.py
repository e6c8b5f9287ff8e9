"""Unit conversions: the only place where dB, dBm and linear values meet.

Every function broadcasts over numpy arrays.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["db_to_lin", "lin_to_db", "dbm_to_w", "w_to_dbm"]


def db_to_lin(x_db: ArrayLike):
    """Power ratio in dB -> linear, :math:`10^{x/10}`."""
    return 10.0 ** (np.asarray(x_db, dtype=float) / 10.0)


def lin_to_db(x: ArrayLike):
    r"""Linear power ratio -> dB, :math:`10\log_{10} x`."""
    return 10.0 * np.log10(np.asarray(x, dtype=float))


def dbm_to_w(p_dbm: ArrayLike):
    """Power in dBm -> watts."""
    return 10.0 ** ((np.asarray(p_dbm, dtype=float) - 30.0) / 10.0)


def w_to_dbm(p_w: ArrayLike):
    """Power in watts -> dBm."""
    return 10.0 * np.log10(np.asarray(p_w, dtype=float)) + 30.0
