"""Standard normal draws for the hot loop: Box-Muller on the Generator's uniforms, vectorised.

numpy's ziggurat costs about 9 ns per normal on this machine and was the largest serial
part of a 100k-particle step (400k normals: motion noise and regularisation jitter). Here the
uniforms come from the same ``numpy.random.Generator`` (so a seed still fixes everything)
and the Box-Muller transform z = sqrt(-2 ln u1) (cos 2 pi u2, sin 2 pi u2) runs in a
numba kernel (on several threads for large draws) whose ln, cos and sin are series that the
compiler vectorises: ln from the float's exponent plus 2 atanh((m - 1)/(m + 1)) of its mantissa m in [1, 2)
(8 odd terms), cos/sin by the double-angle formulas from Taylor series on [-pi/2, pi/2];
the draws agree with exact Box-Muller on the same uniforms to 1e-7.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from mapfilter.threads import MIN_PER_THREAD, for_slices

__all__ = ["standard_normal"]

_BLOCK = 1024  # pairs per block; each block's loops vectorise


@njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def _box_muller(first_block, end_block, u, out):
    # blocks [first_block, end_block) of _BLOCK pairs; the caller slices by blocks
    n_pairs = u.shape[0] // 2
    ln2 = math.log(2.0)
    for block in range(first_block, end_block):
        lo = block * _BLOCK
        m = min(n_pairs, lo + _BLOCK) - lo
        u1 = np.empty(_BLOCK, dtype=np.float64)
        mantissa_bits = np.empty(_BLOCK, dtype=np.int64)
        for j in range(m):
            u1[j] = 1.0 - u[2 * (lo + j)]  # in (0, 1]: ln is finite
        for j in range(m, _BLOCK):
            u1[j] = 1.0
        bits = u1.view(np.int64)
        for j in range(_BLOCK):
            mantissa_bits[j] = (bits[j] & 0x000FFFFFFFFFFFFF) | 0x3FF0000000000000
        mantissa = mantissa_bits.view(np.float64)
        for j in range(m):
            exponent = float((bits[j] >> 52) - 1023)
            t = (mantissa[j] - 1.0) / (mantissa[j] + 1.0)
            t2 = t * t
            ln_m = 2.0 * t * (1.0 + t2 * (1.0 / 3.0 + t2 * (1.0 / 5.0 + t2 * (1.0 / 7.0 + t2 * (
                1.0 / 9.0 + t2 * (1.0 / 11.0 + t2 * (1.0 / 13.0 + t2 * (1.0 / 15.0))))))))
            radius = math.sqrt(max(-2.0 * (exponent * ln2 + ln_m), 0.0))
            # angle 2 pi u2 = 2 (b + pi/2) with b in [-pi/2, pi/2)
            b = math.pi * u[2 * (lo + j) + 1] - 0.5 * math.pi
            b2 = b * b
            sin_b = b * (1.0 - b2 / 6.0 * (1.0 - b2 / 20.0 * (1.0 - b2 / 42.0 * (1.0 - b2 / 72.0 * (
                1.0 - b2 / 110.0)))))
            cos_b = 1.0 - b2 / 2.0 * (1.0 - b2 / 12.0 * (1.0 - b2 / 30.0 * (1.0 - b2 / 56.0 * (
                1.0 - b2 / 90.0 * (1.0 - b2 / 132.0)))))
            out[2 * (lo + j)] = radius * (1.0 - 2.0 * cos_b * cos_b)  # cos(2 b + pi)
            out[2 * (lo + j) + 1] = radius * (-2.0 * cos_b * sin_b)  # sin(2 b + pi)


def standard_normal(rng: np.random.Generator, shape: int | tuple[int, ...]) -> np.ndarray:
    """float64 N(0, 1) draws of ``shape`` from ``rng``'s uniforms (Box-Muller, parallel)."""
    size = int(np.prod(shape))
    n_uniform = size + (size & 1)
    u = rng.random(n_uniform)
    out = np.empty(n_uniform, dtype=np.float64)
    n_blocks = (n_uniform // 2 + _BLOCK - 1) // _BLOCK
    for_slices(_box_muller, n_blocks, u, out, min_per_thread=max(MIN_PER_THREAD // (2 * _BLOCK), 1))
    return out[:size].reshape(shape)
