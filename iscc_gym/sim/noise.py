r"""Per-episode random streams: each slot's standard normals as a pure function of (key, slot).

``reset`` draws one 64-bit key per episode from the env's Generator (:func:`draw_keys`); the slot's
:data:`N_DRAWS` standard normals are then :func:`slot_normals` ``(key, n)``. The transition is thus a
pure function of the loop state (which carries the key, as a gymnax state carries its PRNG key):
a batch reproduces single loops bit for bit, a state can be copied and continued, and every policy
stepped from the same state meets the same noise (common random numbers).

Generator: the draws of slot n are the SplitMix64 outputs (Steele, Lea & Flood, *Fast splittable
pseudorandom number generators*, OOPSLA 2014) at counters :math:`n\,2^{24} + t + 1`, t = 0, 1, ...,
of the stream seeded with the key; each 64-bit output makes one normal by the 256-layer ziggurat
(Marsaglia & Tsang, *The ziggurat method for generating random variables*, JSS 2000) with NumPy's
table layout. Slot streams cannot overlap (a slot uses about 18 of its 2^24 counters).

The compiled scalar functions here are also called from inside :mod:`iscc_gym.sim.kernel`, so the env
draws its noise where it uses it, on all cores.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

from iscc_gym.sim.schema import N_DRAWS  # the layout of a slot's draws: iscc_gym.sim.schema.DRAWS

__all__ = ["N_DRAWS", "draw_keys", "slot_normals", "standard_normals", "ZIGGURAT_R", "fill_slot_normals", "mix64",
           "GOLDEN_GAMMA"]


#: Right edge of the ziggurat's base layer (NumPy's and Marsaglia & Tsang's 256-layer value).
ZIGGURAT_R = 3.6541528853610088


def _ziggurat_tables(r: float = ZIGGURAT_R, layers: int = 256):
    r"""``(k, w, f)``: acceptance thresholds (uint64), scales and densities of the ziggurat.

    Layer i >= 1 is the box [0, x_i] x [f(x_i), f(x_{i-1})] with x_0 = 0 and x_255 = r; every layer
    and the base (the box [0, V / f(r)] x [0, f(r)], its part beyond r standing in for the tail) has
    the area V of the base, :math:`V = r f(r) + \int_r^\infty f`, :math:`f(x) = e^{-x^2/2}`.
    """
    def f(x):
        return math.exp(-0.5 * x * x)

    v = r * f(r) + math.sqrt(0.5 * math.pi) * math.erfc(r / math.sqrt(2.0))
    x = np.zeros(layers)
    x[-1] = r
    for i in range(layers - 1, 1, -1):
        x[i - 1] = math.sqrt(-2.0 * math.log(v / x[i] + f(x[i])))
    scale = 2.0 ** 52
    base = v / f(r)
    k = np.empty(layers, np.uint64)
    w = np.empty(layers)
    fi = np.empty(layers)
    k[0], w[0], fi[0] = np.uint64(r / base * scale), base / scale, 1.0
    for i in range(1, layers):
        k[i] = np.uint64(x[i - 1] / x[i] * scale)
        w[i] = x[i] / scale
        fi[i] = f(x[i])
    for a in (k, w, fi):
        a.setflags(write=False)
    return k, w, fi


_ZIG_K, _ZIG_W, _ZIG_F = _ziggurat_tables()
_ZIG_INV_R = 1.0 / ZIGGURAT_R
_GAMMA = np.uint64(0x9E3779B97F4A7C15)  # SplitMix64's increment (the golden ratio in 64 bits)
_M1, _M2 = np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31 = np.uint64(30), np.uint64(27), np.uint64(31)
_S8, _S9, _S11, _SLOT_SHIFT = np.uint64(8), np.uint64(9), np.uint64(11), np.uint64(24)
_ONE, _BYTE, _MANTISSA = np.uint64(1), np.uint64(0xFF), np.uint64((1 << 52) - 1)


@njit(cache=True, error_model="numpy", inline="always")
def _mix64(z):
    """SplitMix64's output function (a bijection of 64-bit words)."""
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@njit(cache=True, error_model="numpy", inline="always")
def _uniform(word):
    """A double in [0, 1) from the top 53 bits of a 64-bit word."""
    return np.int64(word >> _S11) * (1.0 / 9007199254740992.0)


#: SplitMix64's increment and output function under public names (the device env's episode keys,
#: :mod:`iscc_gym.gpu.kernel`, derive from them).
GOLDEN_GAMMA = _GAMMA
mix64 = _mix64


@njit(cache=True, error_model="numpy")
def fill_slot_normals(key, n, out):
    """Write the standard normals of slot ``n`` of the stream ``key`` into ``out`` (length k)."""
    ctr = (np.uint64(n) << _SLOT_SHIFT) * _GAMMA + key
    for j in range(out.shape[0]):
        while True:
            ctr += _GAMMA
            r = _mix64(ctr)
            idx = r & _BYTE
            r >>= _S8
            rabs = (r >> _ONE) & _MANTISSA
            x = np.int64(rabs) * _ZIG_W[idx]  # rabs < 2^52: the signed conversion is exact and faster
            if r & _ONE:
                x = -x
            if rabs < _ZIG_K[idx]:  # inside the layer's inner box: ~99 % of draws
                break
            if idx == 0:  # the tail beyond R (Marsaglia's method)
                while True:
                    ctr += _GAMMA
                    xx = -_ZIG_INV_R * math.log1p(-_uniform(_mix64(ctr)))
                    ctr += _GAMMA
                    yy = -math.log1p(-_uniform(_mix64(ctr)))
                    if yy + yy > xx * xx:
                        break
                x = -(ZIGGURAT_R + xx) if (rabs >> _S9) & _ONE else ZIGGURAT_R + xx
                break
            ctr += _GAMMA
            if (_ZIG_F[idx - 1] - _ZIG_F[idx]) * _uniform(_mix64(ctr)) + _ZIG_F[idx] < math.exp(-0.5 * x * x):
                break
        out[j] = x


@njit(cache=True, error_model="numpy")
def _fill_batch(keys, n, out):
    for i in range(keys.shape[0]):
        fill_slot_normals(keys[i], n[i], out[i])


def slot_normals(key: ArrayLike, n: ArrayLike, k: int = N_DRAWS) -> np.ndarray:
    r"""The standard normals of slot ``n`` of the episode with ``key``.

    .. math::
        z_{n,j} = \mathrm{ziggurat}\big(\mathrm{mix64}(\kappa + (n\,2^{24} + t_j + 1)\,\gamma)\big)

    with :math:`\kappa` the key, :math:`\gamma` = 0x9E3779B97F4A7C15 and :math:`t_j` the counter
    the j-th normal starts at (one 64-bit word per normal, more on the ziggurat's rare rejections).

    Parameters
    ----------
    key : uint64 or ndarray (B,) of uint64
        Episode keys (:func:`draw_keys`).
    n : int or ndarray (B,) of int
        Slot indices, >= 0 (broadcast against ``key``).
    k : int
        Normals per slot.

    Returns
    -------
    ndarray, shape (k,) for scalar key and slot, else (B, k)
    """
    keys = np.asarray(key)
    if keys.dtype != np.uint64:
        raise TypeError(f"key must be uint64 (from iscc_gym.sim.noise.draw_keys), got dtype {keys.dtype}")
    keys, slots = np.broadcast_arrays(keys, np.asarray(n, dtype=np.int64))
    if (slots < 0).any():
        raise ValueError("slot index n must be >= 0")
    out = np.empty(keys.shape + (k,))
    _fill_batch(np.ravel(keys).copy(), np.ravel(slots).copy(), out.reshape(-1, k))
    return out


def _per_loop(rng, batch: int | None, draw):
    """``draw(g, size)`` for an unbatched loop (``batch=None``, one Generator, ``size=None``), else
    for a batch: from one Generator (``size=batch``) or from a sequence of ``batch`` Generators
    (row i from Generator i, exactly as an unbatched loop with that Generator would draw it).
    """
    if batch is None:
        if not isinstance(rng, np.random.Generator):
            raise TypeError("an unbatched loop takes one numpy Generator")
        return draw(rng, None)
    if isinstance(rng, np.random.Generator):
        return draw(rng, batch)
    if isinstance(rng, Sequence) and len(rng) == batch:
        return np.stack([draw(g, None) for g in rng])
    raise TypeError("rng must be a numpy Generator or a sequence of one Generator per drone")


def standard_normals(rng: np.random.Generator, batch: int | None, k: int = N_DRAWS) -> np.ndarray:
    """Standard normals for one slot drawn from Generators: shape (k,) for an unbatched loop
    (``batch=None``), else (batch, k) from one Generator or one Generator per loop.
    """
    return _per_loop(rng, batch, lambda g, size: g.standard_normal(k if size is None else (size, k)))


def draw_keys(rng: np.random.Generator, batch: int | None) -> np.ndarray:
    """Episode keys (uint64) from Generators: a 0-d array for an unbatched loop (``batch=None``),
    else (batch,) from one Generator or one Generator per loop.
    """
    return np.asarray(_per_loop(rng, batch, lambda g, size: g.integers(0, 2**64, size=size, dtype=np.uint64)))
