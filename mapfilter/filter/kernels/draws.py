"""Counter-based random numbers and the vectorising maths of the filter's kernels.

Word ``s`` of particle ``i`` under a step's ``key`` is SplitMix64's output function of
``key + (SLOTS i + s) gamma`` (Steele, Lea & Flood, "Fast splittable pseudorandom number
generators", OOPSLA 2014): a particle's draws depend on the key and its index only, so the same
seed gives the same track whatever the number of threads. Normals are Box-Muller on the two
32-bit halves of one word, with ln, cos and sin evaluated by series that the compiler
vectorises; the tails stop at sqrt(-2 ln 2^-32) = 6.7 sigma.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

__all__ = ["SLOTS", "counter_normals", "counter_uniforms"]

SLOTS = 8  # random words per particle and key
BLOCK = 1024  # particles per block of every kernel: the draws and per-block loops vectorise


@intrinsic
def as_float(typingctx, bits):
    """The float whose bits are the 64- or 32-bit integer ``bits`` (a register bitcast)."""
    if not isinstance(bits, types.Integer) or bits.bitwidth not in (32, 64):
        return None
    out = types.float64 if bits.bitwidth == 64 else types.float32

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], context.get_value_type(out))
    return out(bits), codegen


@intrinsic
def as_int(typingctx, value):
    """The bits of a float64 (float32) as an int64 (int32)."""
    if not isinstance(value, types.Float):
        return None
    out = types.int64 if value.bitwidth == 64 else types.int32

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], context.get_value_type(out))
    return out(value), codegen


@intrinsic
def trailing_zeros(typingctx, word):
    """The index of the lowest set bit of an integer (its bit width when it is 0): LLVM's cttz."""
    if not isinstance(word, types.Integer):
        return None

    def codegen(context, builder, signature, args):
        return builder.cttz(args[0], ir.Constant(ir.IntType(1), 0))
    return word(word), codegen


_GAMMA = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_LOW32 = np.uint64(0xFFFFFFFF)
_S30, _S27, _S31, _S32, _S20 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(32), np.uint64(20)
_ONE_BITS = np.uint64(0x3FF0000000000000)  # 1.0: a float in [1, 2) takes its mantissa from the word


@njit(cache=True, nogil=True, _nrt=False)
def word(key, counter):
    """SplitMix64: the output function of the state key + counter * gamma."""
    z = key + np.uint64(counter) * _GAMMA
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def normal_pairs(key, slot, lo, idx, m, z0, z1, scratch):
    """z0[j], z1[j] ~ N(0, 1), independent, for particles lo + idx[j], j < m (word ``slot``).

    Box-Muller: radius sqrt(-2 ln u1), angle 2 pi u2, the uniforms the two 32-bit halves of the
    word as the top of a mantissa (floats in [1, 2): no integer-to-float conversion, which AVX2
    lacks for 64-bit integers); ``scratch`` holds u1."""
    ln2 = math.log(2.0)
    for j in range(m):
        z = word(key, np.uint64((lo + idx[j]) * SLOTS + slot))
        scratch[j] = as_float(((z >> _S32) << _S20) | _ONE_BITS)
        z1[j] = as_float(((z & _LOW32) << _S20) | _ONE_BITS)
    for j in range(m):
        u = 2.0 - scratch[j]  # in (0, 1]: ln is finite
        bits = as_int(u)
        mantissa = as_float((bits & 0x000FFFFFFFFFFFFF) | 0x3FF0000000000000)
        # ln u from the exponent and 2 atanh((m - 1)/(m + 1)) of the mantissa m in [1, 2)
        exponent = float((bits >> 52) - 1023)
        t = (mantissa - 1.0) / (mantissa + 1.0)
        t2 = t * t
        ln_m = 2.0 * t * (1.0 + t2 * (1.0 / 3.0 + t2 * (1.0 / 5.0 + t2 * (1.0 / 7.0 + t2 * (
            1.0 / 9.0 + t2 * (1.0 / 11.0 + t2 * (1.0 / 13.0 + t2 * (1.0 / 15.0))))))))
        radius = math.sqrt(max(-2.0 * (exponent * ln2 + ln_m), 0.0))
        # angle 2 pi u2 = 2 (b + pi/2) with b in [-pi/2, pi/2): double-angle formulas from series
        b = math.pi * (z1[j] - 1.0) - 0.5 * math.pi
        b2 = b * b
        sin_b = b * (1.0 - b2 / 6.0 * (1.0 - b2 / 20.0 * (1.0 - b2 / 42.0 * (1.0 - b2 / 72.0 * (
            1.0 - b2 / 110.0)))))
        cos_b = 1.0 - b2 / 2.0 * (1.0 - b2 / 12.0 * (1.0 - b2 / 30.0 * (1.0 - b2 / 56.0 * (
            1.0 - b2 / 90.0 * (1.0 - b2 / 132.0)))))
        z0[j] = radius * (1.0 - 2.0 * cos_b * cos_b)  # cos(2 b + pi)
        z1[j] = radius * (-2.0 * cos_b * sin_b)  # sin(2 b + pi)


@njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def cos_sin(angle):
    """(cos, sin) of an angle in [-pi, pi] from series of b = angle / 2 in [-pi/2, pi/2] and the
    double-angle formulas (|error| < 3e-7; no branch, so the loops calling it vectorise)."""
    b = 0.5 * angle
    b2 = b * b
    sin_b = b * (1.0 - b2 / 6.0 * (1.0 - b2 / 20.0 * (1.0 - b2 / 42.0 * (1.0 - b2 / 72.0 * (1.0 - b2 / 110.0)))))
    cos_b = 1.0 - b2 / 2.0 * (1.0 - b2 / 12.0 * (1.0 - b2 / 30.0 * (1.0 - b2 / 56.0 * (
        1.0 - b2 / 90.0 * (1.0 - b2 / 132.0)))))
    return 1.0 - 2.0 * sin_b * sin_b, 2.0 * sin_b * cos_b


_LOG2E = 1.0 / math.log(2.0)
_LN2_HI = 6.93147180369123816490e-01  # ln 2 in two parts (Cody & Waite): k ln2_hi is exact
_LN2_LO = 1.90821492927058770002e-10
_ROUND = 6755399441055744.0  # 1.5 * 2^52: x + _ROUND rounds x to an integer, held in the low bits


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def exp_block(x, m, out):
    """out[j] = exp(x[j]) for x <= 0 (-inf -> 0), in a loop that vectorises: exp(x) = 2^k exp(r),
    k = round(x / ln 2), r = x - k ln 2 in [-ln2/2, ln2/2], exp(r) by its Taylor series to r^12
    (relative error < 1e-14), 2^k built in the exponent bits; below 2^-1022 the result is 0."""
    for j in range(m):
        xj = x[j] if x[j] > -745.0 else -745.0
        rounded = xj * _LOG2E + _ROUND
        k = rounded - _ROUND
        # k from the low bits of 1.5 * 2^52 + k (mantissa 2^51 + k): its low 32 bits, sign-extended
        ki = ((as_int(rounded) & 0xFFFFFFFF) ^ 0x80000000) - 0x80000000
        scale = as_float((ki + 1023) << 52) if ki >= -1022 else 0.0
        r = (xj - k * _LN2_HI) - k * _LN2_LO
        p = 1.0 + r * (1.0 + r * (1.0 / 2.0 + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (
            1.0 / 720.0 + r * (1.0 / 5040.0 + r * (1.0 / 40320.0 + r * (1.0 / 362880.0 + r * (
                1.0 / 3628800.0 + r * (1.0 / 39916800.0 + r * (1.0 / 479001600.0))))))))))))
        out[j] = p * scale


@njit(cache=True, nogil=True, error_model="numpy")
def _draws_kernel(key, slot, n, normal, out0, out1):
    iota = np.arange(BLOCK)
    z0 = np.empty(BLOCK)
    z1 = np.empty(BLOCK)
    scratch = np.empty(BLOCK)
    for lo in range(0, n, BLOCK):
        m = min(n, lo + BLOCK) - lo
        if normal:
            normal_pairs(key, slot, lo, iota, m, z0, z1, scratch)
            out0[lo:lo + m] = z0[:m]
            out1[lo:lo + m] = z1[:m]
        else:
            for j in range(m):
                z = word(key, np.uint64((lo + j) * SLOTS + slot))
                out0[lo + j] = as_float(((z >> _S32) << _S20) | _ONE_BITS) - 1.0
                out1[lo + j] = as_float(((z & _LOW32) << _S20) | _ONE_BITS) - 1.0


def counter_normals(key: int, slot: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The two standard normals of word ``slot`` of particles 0..n-1 under ``key``, as the kernels
    draw them (for the test oracle)."""
    out0, out1 = np.empty(n), np.empty(n)
    _draws_kernel(np.uint64(key), slot, n, True, out0, out1)
    return out0, out1


def counter_uniforms(key: int, slot: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The two uniforms in [0, 1) of word ``slot`` of particles 0..n-1 under ``key`` (the
    Box-Muller inputs of :func:`counter_normals`: radius from 1 minus the first, angle 2 pi times
    the second)."""
    out0, out1 = np.empty(n), np.empty(n)
    _draws_kernel(np.uint64(key), slot, n, False, out0, out1)
    return out0, out1
