"""The filter step in two passes over the particles: the fused path of ``ParticleFilter.step``.

The named stages of ``filter/pf.py`` (move, wall kill, weigh, normalise, resample, regularise)
each make a pass or several over every particle, and numpy adds its own passes in between
(about two dozen at 100,000 particles). Here the common step is two numba kernels over
fixed blocks of ``BLOCK`` particles:

1. :func:`advance` -- move (random walk on a circle, constant velocity or PDR), the wall check
   of every live particle's move (the same answer as ``maps.walls.crosses_wall``), the
   measurement's log-likelihood (a Gaussian fix, the RSSI path-loss model, or values a model
   computed itself), and per block the sums that the normalisation, the effective sample
   size, the estimate and the regularisation's covariance need;
2. :func:`resample_regularise` -- systematic resampling, the gather of the ancestors' state
   and the wall-safe regularisation jitter of each new particle, with the sums of the new
   estimate.

Each block's sums are kept apart and added in block order, so the result does not depend on
how the blocks are spread over threads (``threads.for_slices``). Random numbers come from a
counter-based generator: word ``s`` of particle ``i`` is SplitMix64's output function of
``key + (SLOTS i + s) gamma`` (Steele, Lea & Flood, "Fast splittable pseudorandom number
generators", OOPSLA 2014), with one ``key`` per step drawn from the filter's
``numpy.random.Generator``; a particle's draws depend on the key and its index only, so the
same seed gives the same track whatever the number of threads. Normals are Box-Muller on two
32-bit uniforms of one word, with ln, cos and sin evaluated by series that vectorise (as in
``filter/gaussian.py``); the tails stop at sqrt(-2 ln 2^-32) = 6.7 sigma.

Models describe themselves to these kernels through ``MotionModel.kernel_move`` and
``MeasurementModel.kernel_likelihood`` (``filter/models.py``), with the terms made here
(:func:`circle_walk`, :func:`constant_velocity`, :func:`pdr_step`, :func:`no_move`,
:func:`gaussian_fix`, :func:`rssi_path_loss`; a model without terms is weighed by its own
``log_likelihood``, passed in with :func:`given_values`). These kernels compile in a few
seconds on first use, which is why the filter takes this path only for large clouds
(``FilterConfig.fused_from_particles``).
"""

from __future__ import annotations

import dataclasses
import math
import statistics

import numpy as np
from numba import njit, types
from numba.extending import intrinsic

from mapfilter.maps.walls import NO_BUFFER, _segment_crosses_world
from mapfilter.sensors.pathloss import MIN_DISTANCE_M
from mapfilter.threads import MIN_PER_THREAD, for_slices

__all__ = ["BLOCK", "Likelihood", "Move", "advance", "circle_walk", "constant_velocity", "counter_normals",
           "counter_uniforms", "flat", "gaussian_fix", "given_values", "no_move", "pdr_step",
           "resample_regularise", "rssi_path_loss", "weigh"]

BLOCK = 1024  # particles per block: the draws and per-AP loops over a block vectorise
SLOTS = 8  # random words per particle and key
_MIN_BLOCKS_PER_THREAD = max(MIN_PER_THREAD // BLOCK, 1)
# The kernels that call the wall walk, exp or the bit tricks are compiled without fast maths:
# numba compiles a function called from a kernel with the kernel's flags, and keeps that
# version for every caller; reassociation would fold (x + 1.5 2^52) - 1.5 2^52 back to x and
# change the walk's arithmetic. Only the leaf loops (draws, cos/sin, the RSSI terms) use it,
# and where infinities are data (the weights) comparisons are written out instead of min/max,
# whose implementations numba shares between callers in the same way.

# what the move kernel does (Move.kind)
MOVE_NONE, MOVE_CIRCLE, MOVE_CV, MOVE_PDR = 0, 1, 2, 3
# the measurement (Likelihood.kind); LL_GIVEN: values the model computed itself
LL_NONE, LL_FIX, LL_RSSI, LL_GIVEN = 0, 1, 2, 3

# per-block sums of advance(): the block's largest log weight m and, with e = exp(lw - m),
# sum e, sum e^2, sum e dx, e dy, e dx^2, e dx dy, e dy^2 (d = position - shift), particles
# alive after the wall check, with a finite weight after weighing, best live log-likelihood
A_MAX, A_SUM, A_SUM2, A_X, A_Y, A_XX, A_XY, A_YY, A_ALIVE, A_FINITE, A_BEST_LL = range(11)
N_ADVANCE_SUMS = 11
# per-block sums of resample_regularise(): dx, dy, dx^2, dx dy, dy^2, cos h, sin h, step length
R_X, R_Y, R_XX, R_XY, R_YY, R_COS, R_SIN, R_STEP = range(8)
N_RESAMPLE_SUMS = 8


# ---- the terms models give ---------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Move:
    """One step's move as the kernel does it (``MotionModel.kernel_move``)."""

    kind: int  # MOVE_*
    params: np.ndarray  # float64, by kind (see the factories below)


def no_move() -> Move:
    """Particles stay where they are (PDR between steps)."""
    return Move(MOVE_NONE, np.zeros(1))


def circle_walk(radius_m: float, sigma_m: float) -> Move:
    """x += r (cos phi, sin phi) + sigma e, phi ~ U[0, 2 pi), e ~ N(0, I) (Lund thesis eq. 6.6);
    (cos phi, sin phi) is the direction of a second normal pair."""
    return Move(MOVE_CIRCLE, np.array([radius_m, sigma_m], dtype=np.float64))


def constant_velocity(dt_s: float, accel_sigma_mps2: float, max_speed_mps: float) -> Move:
    """x += v dt + a dt^2 / 2, v += a dt, a ~ N(0, sigma^2 I), speeds above the maximum scaled back."""
    return Move(MOVE_CV, np.array([dt_s, accel_sigma_mps2, max_speed_mps], dtype=np.float64))


# PDR parameters, in this order
(P_STEPS, P_CHANGE, P_ABS, P_ABS_HEADING, P_HEADING_SIGMA, P_FALSE_TURN, P_WALK_LENGTH, P_LENGTH_SIGMA,
 P_LENGTH_MIN, P_LENGTH_MAX, P_GIVEN, P_GIVEN_LENGTH, P_GIVEN_SIGMA, P_POSITION_SIGMA) = range(14)


def pdr_step(n_steps: int, heading_change_rad: float, heading_abs_rad: float | None, heading_sigma_rad: float,
             false_turn_fraction: float, step_length_sigma_m: float, step_length_min_m: float,
             step_length_max_m: float, given_step_length_m: float | None, given_sigma_m: float,
             position_sigma_m: float) -> Move:
    """A PDR step as ``motion.PDRMotion.propagate`` makes it (its docstring has the model):
    ``false_turn_fraction`` is the share ignoring this change (0 when it is no turn),
    ``step_length_sigma_m`` and ``position_sigma_m`` are already scaled by sqrt(n_steps)."""
    p = np.zeros(14)
    p[P_STEPS] = n_steps
    p[P_CHANGE] = heading_change_rad
    p[P_ABS] = heading_abs_rad is not None
    p[P_ABS_HEADING] = 0.0 if heading_abs_rad is None else heading_abs_rad
    p[P_HEADING_SIGMA] = heading_sigma_rad
    # a particle ignores the change when a standard normal falls below this quantile
    p[P_FALSE_TURN] = (-math.inf if false_turn_fraction <= 0.0 else math.inf if false_turn_fraction >= 1.0
                       else statistics.NormalDist().inv_cdf(false_turn_fraction))
    p[P_WALK_LENGTH] = n_steps > 0
    p[P_LENGTH_SIGMA] = step_length_sigma_m
    p[P_LENGTH_MIN] = step_length_min_m
    p[P_LENGTH_MAX] = step_length_max_m
    p[P_GIVEN] = given_step_length_m is not None
    p[P_GIVEN_LENGTH] = 0.0 if given_step_length_m is None else given_step_length_m
    p[P_GIVEN_SIGMA] = given_sigma_m
    p[P_POSITION_SIGMA] = position_sigma_m
    return Move(MOVE_PDR, p)


@dataclasses.dataclass(frozen=True)
class Likelihood:
    """One measurement's log-likelihood as the kernel evaluates it (``MeasurementModel.kernel_likelihood``)."""

    kind: int  # LL_*
    fix: np.ndarray  # LL_FIX: [x_m, y_m, 1 / (2 sigma^2)]; LL_RSSI: [1 / (2 var), 0, 0]
    values: np.ndarray  # LL_GIVEN: (N,) float64
    rssi: np.ndarray = dataclasses.field(default_factory=lambda: _NO_RSSI)  # LL_RSSI: (7, K) float32 per AP:
    # x, y, C, 5 n, alpha, d_max, observed


_NO_RSSI = np.zeros((7, 0), dtype=np.float32)
_NO_FIX = np.zeros(3)
_NO_VALUES = np.zeros(0)


def flat() -> Likelihood:
    """Log-likelihood 0 everywhere (a measurement that says nothing, or none this step)."""
    return Likelihood(LL_NONE, _NO_FIX, _NO_VALUES)


def gaussian_fix(xy_m, sigma_m: float) -> Likelihood:
    """-|x - fix|^2 / (2 sigma^2) (``measurement.GaussianFixLikelihood``)."""
    fx, fy = (float(v) for v in np.asarray(xy_m, dtype=np.float64).ravel()[:2])
    return Likelihood(LL_FIX, np.array([fx, fy, 0.5 / (sigma_m * sigma_m)]), _NO_VALUES)


def rssi_path_loss(ap_xy_m: np.ndarray, c_dbm: np.ndarray, n: np.ndarray, alpha_db_per_m: np.ndarray,
                   d_max_m: np.ndarray, observed_rssi_dbm: np.ndarray, variance_db2: float) -> Likelihood:
    """-sum_k (z_k - R_k(d))^2 / (2 var) of the Lund path-loss model, in float32, as
    ``measurement.rssi_log_likelihood`` (access points with a NaN reading left out)."""
    if not (math.isfinite(variance_db2) and variance_db2 > 0):
        raise ValueError(f"variance_db2 must be positive, got {variance_db2}")
    observed = np.asarray(observed_rssi_dbm, dtype=np.float64).ravel()
    heard = np.isfinite(observed)

    def per_ap(a):
        return np.broadcast_to(np.asarray(a, dtype=np.float64).ravel(), observed.shape)[heard]

    ap = np.asarray(ap_xy_m, dtype=np.float64).reshape(-1, 2)[heard]
    table = np.array([ap[:, 0], ap[:, 1], per_ap(c_dbm), 5.0 * per_ap(n).astype(np.float32), per_ap(alpha_db_per_m),
                      per_ap(d_max_m), observed[heard]], dtype=np.float32)
    return Likelihood(LL_RSSI, np.array([0.5 / variance_db2, 0.0, 0.0]), _NO_VALUES, table)


def given_values(values: np.ndarray) -> Likelihood:
    """Log-likelihoods a model computed itself (non-finite ones count as -inf)."""
    return Likelihood(LL_GIVEN, _NO_FIX, np.ascontiguousarray(values, dtype=np.float64))


# ---- bit casts -------------------------------------------------------------------------------------
@intrinsic
def _as_float(typingctx, bits):
    """The float whose bits are the 64- or 32-bit integer ``bits`` (a register bitcast: unlike
    an array view, the compiler cannot lose track of the memory behind it)."""
    if not isinstance(bits, types.Integer) or bits.bitwidth not in (32, 64):
        return None
    out = types.float64 if bits.bitwidth == 64 else types.float32

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], context.get_value_type(out))
    return out(bits), codegen


@intrinsic
def _as_int(typingctx, value):
    """The bits of a float64 (float32) as an int64 (int32)."""
    if not isinstance(value, types.Float):
        return None
    out = types.int64 if value.bitwidth == 64 else types.int32

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], context.get_value_type(out))
    return out(value), codegen


# ---- counter-based random numbers ---------------------------------------------------------------
_GAMMA = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_LOW32 = np.uint64(0xFFFFFFFF)
_S30, _S27, _S31, _S32 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(32)
_TWO_M32 = 2.0 ** -32


@njit(cache=True, nogil=True, _nrt=False)
def _word(key, counter):
    # SplitMix64: the output function of the state key + counter * gamma
    z = key + np.uint64(counter) * _GAMMA
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


_ONE_BITS = np.uint64(0x3FF0000000000000)  # 1.0: a float in [1, 2) takes its mantissa from the word
_S20 = np.uint64(20)


@njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def _normal_pairs(key, slot, lo, idx, m, z0, z1, u1):
    """z0[j], z1[j] ~ N(0, 1), independent, for particles lo + idx[j], j < m (word ``slot``):
    Box-Muller, radius sqrt(-2 ln u1) and angle 2 pi u2 (``u1`` is scratch). The uniforms are
    the two 32-bit halves of the word as the top of a mantissa (floats in [1, 2), so no
    integer-to-float conversion, which AVX2 lacks for 64-bit integers)."""
    ln2 = math.log(2.0)
    for j in range(m):
        z = _word(key, np.uint64((lo + idx[j]) * SLOTS + slot))
        u1[j] = _as_float(((z >> _S32) << _S20) | _ONE_BITS)
        z1[j] = _as_float(((z & _LOW32) << _S20) | _ONE_BITS)
    for j in range(m):
        u = 2.0 - u1[j]  # in (0, 1]: ln is finite
        bits = _as_int(u)
        mantissa = _as_float((bits & 0x000FFFFFFFFFFFFF) | 0x3FF0000000000000)
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
def _cos_sin(angle):
    """(cos, sin) of an angle in [-pi, pi] from series of b = angle / 2 in [-pi/2, pi/2] and the
    double-angle formulas (|error| < 1e-7; no branch, so the loops calling it vectorise)."""
    b = 0.5 * angle
    b2 = b * b
    sin_b = b * (1.0 - b2 / 6.0 * (1.0 - b2 / 20.0 * (1.0 - b2 / 42.0 * (1.0 - b2 / 72.0 * (1.0 - b2 / 110.0)))))
    cos_b = 1.0 - b2 / 2.0 * (1.0 - b2 / 12.0 * (1.0 - b2 / 30.0 * (1.0 - b2 / 56.0 * (
        1.0 - b2 / 90.0 * (1.0 - b2 / 132.0)))))
    return 1.0 - 2.0 * sin_b * sin_b, 2.0 * sin_b * cos_b


@njit(cache=True, nogil=True, error_model="numpy")
def _draws_kernel(lo_block, hi_block, key, slot, n, normal, out0, out1):
    iota = np.empty(BLOCK, dtype=np.int64)
    for j in range(BLOCK):
        iota[j] = j
    z0 = np.empty(BLOCK)
    z1 = np.empty(BLOCK)
    u1 = np.empty(BLOCK)
    for block in range(lo_block, hi_block):
        lo = block * BLOCK
        m = min(n, lo + BLOCK) - lo
        if normal:
            _normal_pairs(key, slot, lo, iota, m, z0, z1, u1)
            for j in range(m):
                out0[lo + j] = z0[j]
                out1[lo + j] = z1[j]
        else:
            for j in range(m):
                z = _word(key, np.uint64((lo + j) * SLOTS + slot))
                out0[lo + j] = _as_float(((z >> _S32) << _S20) | _ONE_BITS) - 1.0
                out1[lo + j] = _as_float(((z & _LOW32) << _S20) | _ONE_BITS) - 1.0


def counter_normals(key: int, slot: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The two standard normals of word ``slot`` of particles 0..n-1 under ``key`` (as the
    kernels draw them): for tests, and to feed the same draws to the named stages."""
    out0, out1 = np.empty(n), np.empty(n)
    _draws_kernel(0, (n + BLOCK - 1) // BLOCK, np.uint64(key), slot, n, True, out0, out1)
    return out0, out1


def counter_uniforms(key: int, slot: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The two uniforms in [0, 1) of word ``slot`` of particles 0..n-1 under ``key`` (the
    Box-Muller inputs of :func:`counter_normals`: radius from 1 minus the first, angle 2 pi
    times the second)."""
    out0, out1 = np.empty(n), np.empty(n)
    _draws_kernel(0, (n + BLOCK - 1) // BLOCK, np.uint64(key), slot, n, False, out0, out1)
    return out0, out1


# random words of a particle in one step: advance() uses slots 0-2 under the move key (a normal
# pair each), resample_regularise() slot t for its try t under the jitter key
SLOT_MOVE_A, SLOT_MOVE_B, SLOT_MOVE_C = 0, 1, 2


# ---- exp --------------------------------------------------------------------------------------
_LOG2E = 1.0 / math.log(2.0)
_LN2_HI = 6.93147180369123816490e-01  # ln 2 in two parts (Cody & Waite): k ln2_hi is exact
_LN2_LO = 1.90821492927058770002e-10
_ROUND = 6755399441055744.0  # 1.5 * 2^52: x + _ROUND rounds x to an integer, held in the low bits


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _exp_block(x, m, out):
    """out[j] = exp(x[j]) for x <= 0 (-inf -> 0), in a loop that vectorises: exp(x) = 2^k exp(r),
    k = round(x / ln 2), r = x - k ln 2 in [-ln2/2, ln2/2], exp(r) by its Taylor series to r^12
    (relative error < 1e-14), 2^k built in the exponent bits; below 2^-1022 the result is 0."""
    for j in range(m):
        xj = x[j] if x[j] > -745.0 else -745.0
        rounded = xj * _LOG2E + _ROUND
        k = rounded - _ROUND
        # k from the low bits of 1.5 * 2^52 + k (mantissa 2^51 + k): its low 32 bits, sign-extended
        ki = ((_as_int(rounded) & 0xFFFFFFFF) ^ 0x80000000) - 0x80000000
        scale = _as_float((ki + 1023) << 52) if ki >= -1022 else 0.0
        r = (xj - k * _LN2_HI) - k * _LN2_LO
        p = 1.0 + r * (1.0 + r * (1.0 / 2.0 + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (
            1.0 / 720.0 + r * (1.0 / 5040.0 + r * (1.0 / 40320.0 + r * (1.0 / 362880.0 + r * (
                1.0 / 3628800.0 + r * (1.0 / 39916800.0 + r * (1.0 / 479001600.0))))))))))))
        out[j] = p * scale


# ---- the wall check -----------------------------------------------------------------------------
_MARCH_STEPS = 12  # clearance steps from each end before the exact walk
_MIN_MARCH_PX = 0.5  # fronts whose clearance is below this stop the march


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _crosses(mask, clearance, x0_m, y0_m, inv_res, ax, ay, bx, by, no_buffer):
    """``maps.walls.crosses_wall`` of one move (the same answer): first the clearance of the
    pixels at its ends (a segment shorter than the clearance of a pixel it starts in touches no
    wall, and either end can be its start), whether it ends in a wall, a march along the
    clearance from both ends, then the exact walk.

    The kernels test the start pixel themselves before they call this: written out in the
    loop, that test costs a fifth of a call (numba's inline="always" made it slower still)."""
    h, w = clearance.shape
    u0 = (ax - x0_m) * inv_res
    v0 = h - (ay - y0_m) * inv_res
    u1 = (bx - x0_m) * inv_res
    v1 = h - (by - y0_m) * inv_res
    du = u1 - u0
    dv = v1 - v0
    length = math.sqrt(du * du + dv * dv)
    if not (0.0 <= u1 < w and 0.0 <= v1 < h) or mask[int(v1), int(u1)]:
        return True  # it ends in a wall pixel or off the map (NaN ends in the walk below)
    c_end = clearance[int(v1), int(u1)]
    c_start = clearance[int(v0), int(u0)] if 0.0 <= u0 < w and 0.0 <= v0 < h else 0.0
    if length < c_start or length < c_end:
        return False
    if length > 0.0:
        # clearance from both ends ("sphere tracing" from each): a piece shorter than the
        # clearance of the pixel it starts in touches no wall; when the pieces from the start
        # and from the end meet, no piece of the move does
        step = 0.999 / length
        t_lo = c_start * step
        t_hi = 1.0 - c_end * step
        for _ in range(_MARCH_STEPS):
            pu = u0 + t_lo * du
            pv = v0 + t_lo * dv
            c_lo = clearance[int(pv), int(pu)] if 0.0 <= pu < w and 0.0 <= pv < h else 0.0
            qu = u0 + t_hi * du
            qv = v0 + t_hi * dv
            c_hi = clearance[int(qv), int(qu)] if 0.0 <= qu < w and 0.0 <= qv < h else 0.0
            if c_lo < _MIN_MARCH_PX and c_hi < _MIN_MARCH_PX:
                break  # against a wall at both fronts: the exact walk decides
            t_lo += c_lo * step
            t_hi -= c_hi * step
            if t_lo >= t_hi:
                return False
        # a wall pixel under the middle of the piece in between: the move touches it (the fronts
        # stop on both sides of a thin wall, most crossing moves end here)
        t_mid = 0.5 * (max(t_lo, 0.0) + min(t_hi, 1.0))
        mu = u0 + t_mid * du
        mv = v0 + t_mid * dv
        if 0.0 <= mu < w and 0.0 <= mv < h and mask[int(mv), int(mu)]:
            return True
        if t_lo > 0.0 or t_hi < 1.0:
            # the exact walk of the piece in between (the pieces at the ends touch no wall)
            return _segment_crosses_world(mask, clearance, x0_m, y0_m, inv_res, ax + t_lo * (bx - ax),
                                          ay + t_lo * (by - ay), ax + t_hi * (bx - ax), ay + t_hi * (by - ay),
                                          no_buffer)
    return _segment_crosses_world(mask, clearance, x0_m, y0_m, inv_res, ax, ay, bx, by, no_buffer)


# ---- pass 1: move, wall check, weigh, block sums -------------------------------------------------
@njit(cache=True, nogil=True, fastmath=True, error_model="numpy", _nrt=False)
def _rssi_block(lo, m, xy, ap, inv_two_var, xf, yf, d2, log10_d2, acc, out):
    """out[j] = -sum_k (z_k - R_k)^2 / (2 var) for particles lo + j, float32 inside, as
    ``measurement._rssi_ll_kernel`` (log10(d^2) from the float's exponent and a series of its
    mantissa); ``ap`` is the (7, K) table of ``rssi_path_loss``."""
    ln2 = np.float32(math.log(2.0))
    inv_ln10 = np.float32(1.0 / math.log(10.0))
    one = np.float32(MIN_DISTANCE_M * MIN_DISTANCE_M)
    for j in range(m):
        xf[j] = np.float32(xy[lo + j, 0])
        yf[j] = np.float32(xy[lo + j, 1])
        acc[j] = np.float32(0.0)
    for k in range(ap.shape[1]):
        ax = ap[0, k]
        ay = ap[1, k]
        for j in range(m):
            dx = xf[j] - ax
            dy = yf[j] - ay
            dd = max(dx * dx + dy * dy, one)  # distance clamped at the 1 m reference
            d2[j] = dd
            bits = _as_int(dd)
            mantissa = _as_float(np.int32((bits & 0x007FFFFF) | 0x3F800000))  # same mantissa, exponent 0
            exponent = np.float32((bits >> 23) - 127)
            t = (mantissa - np.float32(1.0)) / (mantissa + np.float32(1.0))
            t2 = t * t
            ln_m = np.float32(2.0) * t * (np.float32(1.0) + t2 * (np.float32(1.0 / 3.0) + t2 * (
                np.float32(0.2) + t2 * (np.float32(1.0 / 7.0) + t2 * np.float32(1.0 / 9.0)))))
            log10_d2[j] = (exponent * ln2 + ln_m) * inv_ln10
        ck = ap[2, k]
        nk = ap[3, k]
        ak = ap[4, k]
        dk = ap[5, k]
        zk = ap[6, k]
        for j in range(m):
            # R(d) = C - 10 n log10(d) - alpha min(d, d_max), with 10 n log10(d) = 5 n log10(d^2)
            r = zk - (ck - nk * log10_d2[j] - ak * min(math.sqrt(d2[j]), dk))
            acc[j] += r * r
    for j in range(m):
        out[j] = -np.float64(acc[j] * inv_two_var)


@njit(cache=True, nogil=True, error_model="numpy")
def _advance_kernel(lo_block, hi_block, n, do_move, do_kill, do_weigh, key, move_kind, mp, prev_xy, prev_vel,
                    prev_head, prev_step, prev_lw, mask, clearance, x0_m, y0_m, inv_res, no_buffer, ll_kind, fix,
                    rssi, given, shift_x, shift_y, xy, vel, head, step, lw, killed, e_out, sums):
    iota = np.empty(BLOCK, dtype=np.int64)
    for j in range(BLOCK):
        iota[j] = j
    zz = np.empty((6, BLOCK))
    ubuf = np.empty(BLOCK)
    ll = np.empty(BLOCK)
    xf = np.empty(BLOCK, dtype=np.float32)
    yf = np.empty(BLOCK, dtype=np.float32)
    d2 = np.empty(BLOCK, dtype=np.float32)
    log10_d2 = np.empty(BLOCK, dtype=np.float32)
    acc = np.empty(BLOCK, dtype=np.float32)
    two_pi = 2.0 * math.pi
    mask_h, mask_w = clearance.shape
    for block in range(lo_block, hi_block):
        lo = block * BLOCK
        m = min(n, lo + BLOCK) - lo
        if do_move:
            # the draws first, from one call site each (every inlined copy costs compile time):
            # normal pairs of slots A (and B, C for PDR), uniforms of slot U
            n_pairs = 3 if move_kind == MOVE_PDR else (2 if move_kind == MOVE_CIRCLE else (
                1 if move_kind == MOVE_CV else 0))
            for slot in range(n_pairs):
                _normal_pairs(key, SLOT_MOVE_A + slot, lo, iota, m, zz[2 * slot], zz[2 * slot + 1], ubuf)
            z0 = zz[0]
            z1 = zz[1]
            for j in range(m):
                i = lo + j
                x = prev_xy[i, 0]
                y = prev_xy[i, 1]
                vx = prev_vel[i, 0]
                vy = prev_vel[i, 1]
                h = prev_head[i]
                sl = prev_step[i]
                if move_kind == MOVE_CIRCLE:
                    # (cos phi, sin phi), phi ~ U[0, 2 pi): the direction of the normal pair of slot B
                    r = math.sqrt(zz[2, j] * zz[2, j] + zz[3, j] * zz[3, j])
                    x += mp[0] * zz[2, j] / r + mp[1] * z0[j]
                    y += mp[0] * zz[3, j] / r + mp[1] * z1[j]
                elif move_kind == MOVE_CV:
                    dt = mp[0]
                    ax = mp[1] * z0[j]
                    ay = mp[1] * z1[j]
                    x += vx * dt + 0.5 * dt * dt * ax
                    y += vy * dt + 0.5 * dt * dt * ay
                    vx += ax * dt
                    vy += ay * dt
                    speed = math.sqrt(vx * vx + vy * vy)
                    if speed > mp[2]:
                        vx *= mp[2] / speed
                        vy *= mp[2] / speed
                elif move_kind == MOVE_PDR:
                    # z0: heading noise, z1: step-length walk, zz[2], zz[3]: position, zz[4]: given
                    # length, zz[5]: false turns (below the quantile of the false-turn share)
                    noise = mp[P_HEADING_SIGMA] * z0[j]
                    if mp[P_ABS] != 0.0:
                        h = mp[P_ABS_HEADING] + noise
                    else:
                        change = mp[P_CHANGE]
                        if zz[5, j] < mp[P_FALSE_TURN]:
                            change = 0.0
                        h = h + change + noise
                    if not -math.pi <= h < math.pi:
                        h = ((h + math.pi) % two_pi) - math.pi
                    if mp[P_WALK_LENGTH] != 0.0:
                        sl = min(max(sl + mp[P_LENGTH_SIGMA] * z1[j], mp[P_LENGTH_MIN]), mp[P_LENGTH_MAX])
                    length = mp[P_GIVEN_LENGTH] + mp[P_GIVEN_SIGMA] * zz[4, j] if mp[P_GIVEN] != 0.0 else sl
                    c, s = _cos_sin(h)
                    distance = mp[P_STEPS] * length
                    x += distance * c + mp[P_POSITION_SIGMA] * zz[2, j]
                    y += distance * s + mp[P_POSITION_SIGMA] * zz[3, j]
                xy[i, 0] = x
                xy[i, 1] = y
                vel[i, 0] = vx
                vel[i, 1] = vy
                head[i] = h
                step[i] = sl
        if do_kill:
            # a move through a wall kills its particle (Evennou & Marx: P_m = 0); the dead stay dead
            for j in range(m):
                i = lo + j
                w0 = prev_lw[i]
                dead = not (w0 > -np.inf and w0 < np.inf)
                hit = False
                if not dead:
                    # the start pixel's clearance decides most moves (see _crosses)
                    ax = prev_xy[i, 0]
                    ay = prev_xy[i, 1]
                    bx = xy[i, 0]
                    by = xy[i, 1]
                    u0 = (ax - x0_m) * inv_res
                    v0 = mask_h - (ay - y0_m) * inv_res
                    du = (bx - ax) * inv_res
                    dv = (by - ay) * inv_res
                    c = 0.0
                    if 0.0 <= u0 < mask_w and 0.0 <= v0 < mask_h:
                        c = clearance[int(v0), int(u0)]
                    if not du * du + dv * dv < c * c:
                        hit = _crosses(mask, clearance, x0_m, y0_m, inv_res, ax, ay, bx, by, no_buffer)
                killed[i] = hit
                lw[i] = -np.inf if hit else w0
        if do_weigh:
            if ll_kind == LL_RSSI:
                _rssi_block(lo, m, xy, rssi, np.float32(fix[0]), xf, yf, d2, log10_d2, acc, ll)
            elif ll_kind == LL_FIX:
                for j in range(m):
                    dx = xy[lo + j, 0] - fix[0]
                    dy = xy[lo + j, 1] - fix[1]
                    ll[j] = -(dx * dx + dy * dy) * fix[2]
            elif ll_kind == LL_GIVEN:
                for j in range(m):
                    ll[j] = given[lo + j]
            else:
                for j in range(m):
                    ll[j] = 0.0
            alive = 0
            finite = 0
            best_ll = -np.inf
            top = -np.inf
            for j in range(m):  # without branches: the dead are interleaved at random
                i = lo + j
                w0 = lw[i]
                v = ll[j]
                # NaN or +inf is a model defect: no weight instead of a poisoned sum
                v = v if -np.inf < v < np.inf else -np.inf
                live = w0 > -np.inf
                alive += live
                if live and v > best_ll:
                    best_ll = v
                w1 = w0 + v
                lw[i] = w1
                finite += w1 > -np.inf
                if w1 > top:
                    top = w1
            s = 0.0
            s2 = 0.0
            sx = 0.0
            sy = 0.0
            sxx = 0.0
            sxy = 0.0
            syy = 0.0
            if finite > 0:
                for j in range(m):
                    ll[j] = lw[lo + j] - top
                _exp_block(ll, m, ll)  # 0 for the dead
                for j in range(m):
                    i = lo + j
                    e = ll[j]
                    e_out[i] = e
                    dx = xy[i, 0] - shift_x
                    dy = xy[i, 1] - shift_y
                    s += e
                    s2 += e * e
                    sx += e * dx
                    sy += e * dy
                    sxx += e * dx * dx
                    sxy += e * dx * dy
                    syy += e * dy * dy
            else:
                for j in range(m):
                    e_out[lo + j] = 0.0
            sums[block, A_MAX] = top
            sums[block, A_SUM] = s
            sums[block, A_SUM2] = s2
            sums[block, A_X] = sx
            sums[block, A_Y] = sy
            sums[block, A_XX] = sxx
            sums[block, A_XY] = sxy
            sums[block, A_YY] = syy
            sums[block, A_ALIVE] = alive
            sums[block, A_FINITE] = finite
            sums[block, A_BEST_LL] = best_ll


@dataclasses.dataclass
class Advanced:
    """What :func:`advance` leaves: the moved state, log weights, and the combined block sums."""

    xy_m: np.ndarray
    velocity_mps: np.ndarray
    heading_rad: np.ndarray
    step_length_m: np.ndarray
    log_weight: np.ndarray  # after the wall check (and the measurement, once weighed)
    killed: np.ndarray  # (N,) bool: killed by a wall this step
    e: np.ndarray  # (N,) exp(log_weight - the block's largest)
    sums: np.ndarray  # (blocks, N_ADVANCE_SUMS)


def _blocks(n: int) -> int:
    return (n + BLOCK - 1) // BLOCK


_EMPTY_MASK = np.zeros((1, 1), dtype=np.bool_)
_EMPTY_CLEARANCE = np.zeros((1, 1), dtype=np.float32)


def advance(prev_xy_m, prev_velocity_mps, prev_heading_rad, prev_step_length_m, prev_log_weight, *,
            move: Move | None, key: int, floorplan=None, clearance=None, likelihood: Likelihood | None = None,
            shift_xy_m=(0.0, 0.0), state: Advanced | None = None) -> Advanced:
    """One pass over the particles, in blocks on the shared threads.

    ``move`` (None: the moved state is ``state``'s) moves every particle with draws under
    ``key``; ``floorplan`` (None: no wall check) kills the live particles whose move touches a
    wall pixel; ``likelihood`` (None: not weighed yet) adds the measurement's log-likelihood
    and fills the block sums (about ``shift_xy_m``, a point near the cloud). The three can
    run in one call (one floor) or in turn on the same ``state`` (a building, whose floor
    changes happen between the wall check and the measurement).
    """
    n = prev_log_weight.shape[0]
    nb = _blocks(n)
    if state is None:
        state = Advanced(np.empty((n, 2)), np.empty((n, 2)), np.empty(n), np.empty(n), np.empty(n),
                         np.zeros(n, dtype=np.bool_), np.empty(n), np.empty((nb, N_ADVANCE_SUMS)))
    if floorplan is None and move is not None:
        state.log_weight[:] = prev_log_weight  # no wall check: the weights stay as they were
    mv = move if move is not None else no_move()
    ll = likelihood if likelihood is not None else flat()
    if floorplan is not None:
        mask, clear = floorplan.wall_mask, clearance
        x0, y0, inv = float(floorplan.origin_m[0]), float(floorplan.origin_m[1]), 1.0 / floorplan.resolution_m
    else:
        mask, clear, x0, y0, inv = _EMPTY_MASK, _EMPTY_CLEARANCE, 0.0, 0.0, 1.0
    for_slices(_advance_kernel, nb, n, move is not None, floorplan is not None, likelihood is not None,
               np.uint64(key), mv.kind, mv.params, prev_xy_m, prev_velocity_mps, prev_heading_rad,
               prev_step_length_m, prev_log_weight, mask, clear, x0, y0, inv, NO_BUFFER, ll.kind, ll.fix, ll.rssi,
               ll.values if ll.kind == LL_GIVEN else _NO_VALUES, float(shift_xy_m[0]),
               float(shift_xy_m[1]), state.xy_m, state.velocity_mps, state.heading_rad, state.step_length_m,
               state.log_weight, state.killed, state.e, state.sums, min_per_thread=_MIN_BLOCKS_PER_THREAD)
    return state


def weigh(xy_m: np.ndarray, log_weight: np.ndarray, likelihood: Likelihood, shift_xy_m=(0.0, 0.0)) -> Advanced:
    """Points weighed by a measurement, with the block sums (the pass of :func:`advance`
    without the move and the wall check): e.g. candidates to draw particles from."""
    n = log_weight.shape[0]
    xy = np.ascontiguousarray(xy_m, dtype=np.float64)
    state = Advanced(xy, np.zeros((n, 2)), np.zeros(n), np.zeros(n), np.array(log_weight, dtype=np.float64),
                     np.zeros(n, dtype=np.bool_), np.empty(n), np.empty((_blocks(n), N_ADVANCE_SUMS)))
    return advance(xy, state.velocity_mps, state.heading_rad, state.step_length_m, state.log_weight, move=None, key=0,
                   likelihood=likelihood, shift_xy_m=shift_xy_m, state=state)


@dataclasses.dataclass(frozen=True)
class Totals:
    """The block sums of :func:`advance` added up (in block order)."""

    log_normaliser: float  # log sum exp(log_weight): -inf when no weight is left
    ess: float  # 1 / sum(w^2) of the normalised weights
    mean_xy_m: np.ndarray  # (2,) weighted mean
    covariance_m2: np.ndarray  # (2, 2) weighted covariance
    n_alive_after_kill: int
    n_finite: int
    best_log_likelihood: float  # over the particles alive after the wall check
    max_log_weight: float
    block_scale: np.ndarray  # (blocks,) exp(block max - log_normaliser): w_i = e_i * scale of its block
    block_weight: np.ndarray  # (blocks,) normalised weight of each block


def totals(state: Advanced, shift_xy_m) -> Totals:
    s = state.sums
    top = s[:, A_MAX]
    n_alive = int(s[:, A_ALIVE].sum())
    n_finite = int(s[:, A_FINITE].sum())
    best_ll = float(s[:, A_BEST_LL].max())
    m = float(top.max())
    if not n_finite or not math.isfinite(m):
        zeros = np.zeros(len(s))
        return Totals(-math.inf, 0.0, np.full(2, np.nan), np.full((2, 2), np.nan), n_alive, n_finite, best_ll,
                      m, zeros, zeros)
    f = np.exp(top - m)  # 0 for blocks without weight
    total = float(f @ s[:, A_SUM])
    log_norm = m + math.log(total)
    ess = total * total / float((f * f) @ s[:, A_SUM2])
    ex, ey = float(f @ s[:, A_X]) / total, float(f @ s[:, A_Y]) / total
    cxx = float(f @ s[:, A_XX]) / total - ex * ex
    cxy = float(f @ s[:, A_XY]) / total - ex * ey
    cyy = float(f @ s[:, A_YY]) / total - ey * ey
    mean = np.array([float(shift_xy_m[0]) + ex, float(shift_xy_m[1]) + ey])
    return Totals(log_norm, ess, mean, np.array([[cxx, cxy], [cxy, cyy]]), n_alive, n_finite, best_ll, m,
                  f / total, f * s[:, A_SUM] / total)


# ---- pass 2: systematic resampling, gather, regularisation -----------------------------------------
@njit(cache=True, nogil=True, error_model="numpy")
def _resample_kernel(lo_block, hi_block, n, e, block_scale, cum_start, last, u, key, tries, walks, h, root, mask,
                     clearance, x0_m, y0_m, inv_res, no_buffer, origin_xy, src_xy, src_vel, src_head, src_step,
                     shift_x, shift_y, parent, xy, vel, head, step, sums):
    z0 = np.empty(BLOCK)
    z1 = np.empty(BLOCK)
    ubuf = np.empty(BLOCK)
    pending = np.empty(BLOCK, dtype=np.int64)
    n_in_blocks = block_scale.shape[0]
    mask_h, mask_w = clearance.shape
    for block in range(lo_block, hi_block):
        lo = block * BLOCK
        m = min(n, lo + BLOCK) - lo
        # systematic resampling: output j takes the particle whose cumulative-weight bin holds
        # (j + u) / n. The walk starts at the input block where the block's first position falls
        p0 = (lo + u) / n
        b = 0
        hi_b = n_in_blocks - 1
        while b < hi_b:  # the last input block whose cumulative start is <= p0
            mid = (b + hi_b + 1) // 2
            if cum_start[mid] <= p0:
                b = mid
            else:
                hi_b = mid - 1
        i = b * BLOCK
        w = e[i] * block_scale[b]
        cum = cum_start[b] + w
        for j in range(m):
            p = (lo + j + u) / n
            # the last positive weight closes the last bin at 1 (round-off guard); zero weights have empty bins
            while (p >= cum or w <= 0.0) and i < last:
                i += 1
                w = e[i] * block_scale[i // BLOCK]
                cum += w
            parent[lo + j] = i
        # gather, and the jitter of the Regularised Particle Filter: parent + h root eps, redrawn
        # up to ``tries`` times while the move from the parent or from the parent's position
        # before the step touches a wall, else the particle stays at its parent
        for j in range(m):
            k = parent[lo + j]
            xy[lo + j, 0] = src_xy[k, 0]
            xy[lo + j, 1] = src_xy[k, 1]
            pending[j] = j
        n_pending = m
        for t in range(tries):
            if n_pending == 0:
                break
            # draws for the pending particles only (a particle's draw at try t is the same whichever are)
            _normal_pairs(key, t, lo, pending, n_pending, z0, z1, ubuf)
            n_left = 0
            for q in range(n_pending):
                j = pending[q]
                i = lo + j
                k = parent[i]
                px = src_xy[k, 0]
                py = src_xy[k, 1]
                cx = px + h * (root[0, 0] * z0[q] + root[0, 1] * z1[q])
                cy = py + h * (root[1, 0] * z0[q] + root[1, 1] * z1[q])
                hit = False
                for end in range(2):  # from the parent, then from the parent's position before the step
                    ax = px if end == 0 else origin_xy[k, 0]
                    ay = py if end == 0 else origin_xy[k, 1]
                    # the start pixel's clearance decides most moves (see _crosses)
                    u0 = (ax - x0_m) * inv_res
                    v0 = mask_h - (ay - y0_m) * inv_res
                    du = (cx - ax) * inv_res
                    dv = (cy - ay) * inv_res
                    c = 0.0
                    if 0.0 <= u0 < mask_w and 0.0 <= v0 < mask_h:
                        c = clearance[int(v0), int(u0)]
                    if not du * du + dv * dv < c * c:
                        hit = _crosses(mask, clearance, x0_m, y0_m, inv_res, ax, ay, cx, cy, no_buffer)
                        if hit:
                            break
                if hit:
                    pending[n_left] = j  # q >= n_left: already read
                    n_left += 1
                    continue
                xy[i, 0] = cx
                xy[i, 1] = cy
            n_pending = n_left
        sx = 0.0
        sy = 0.0
        sxx = 0.0
        sxy = 0.0
        syy = 0.0
        sc = 0.0
        ss = 0.0
        sl = 0.0
        for j in range(m):
            i = lo + j
            k = parent[i]
            vel[i, 0] = src_vel[k, 0]
            vel[i, 1] = src_vel[k, 1]
            head[i] = src_head[k]
            step[i] = src_step[k]
            dx = xy[i, 0] - shift_x
            dy = xy[i, 1] - shift_y
            sx += dx
            sy += dy
            sxx += dx * dx
            sxy += dx * dy
            syy += dy * dy
            if walks:
                heading = head[i]
                if not -math.pi <= heading <= math.pi:
                    heading = ((heading + math.pi) % (2.0 * math.pi)) - math.pi
                c, s = _cos_sin(heading)
                sc += c
                ss += s
                sl += step[i]
        sums[block, R_X] = sx
        sums[block, R_Y] = sy
        sums[block, R_XX] = sxx
        sums[block, R_XY] = sxy
        sums[block, R_YY] = syy
        sums[block, R_COS] = sc
        sums[block, R_SIN] = ss
        sums[block, R_STEP] = sl


@dataclasses.dataclass
class Resampled:
    """What :func:`resample_regularise` leaves: the new particles' state and their parents."""

    parent: np.ndarray  # (N,) int64 index into the particles before resampling
    xy_m: np.ndarray
    velocity_mps: np.ndarray
    heading_rad: np.ndarray
    step_length_m: np.ndarray
    sums: np.ndarray  # (blocks, N_RESAMPLE_SUMS)


def last_positive(state: Advanced, t: Totals) -> int:
    """Index of the last particle with a positive normalised weight (the resampler's last bin)."""
    blocks = np.flatnonzero(t.block_weight > 0)
    b = int(blocks[-1])
    seg = state.e[b * BLOCK:(b + 1) * BLOCK] * t.block_scale[b]
    return b * BLOCK + int(np.flatnonzero(seg > 0)[-1])


def resample_regularise(state: Advanced, t: Totals, prev_xy_m: np.ndarray, *, u: float, key: int, tries: int,
                        h: float, root: np.ndarray, floorplan, clearance, shift_xy_m, walks: bool = False,
                        n_out: int | None = None) -> Resampled:
    """Systematic resampling of ``state`` by its weights (positions (j + u) / N), the gather of
    the parents' state and the regularisation jitter ``h root eps`` (``tries`` draws under
    ``key``, 0: no jitter), never through a wall from the parent nor from the parent's position
    before the step (``prev_xy_m``); one pass over the new particles, in blocks on the shared threads.
    ``walks``: also sum cos and sin of the headings and the step lengths (PDR's report).
    ``n_out``: how many to draw (default: as many as there are)."""
    n = state.log_weight.shape[0] if n_out is None else int(n_out)
    nb = _blocks(n)
    if not 0 <= tries <= SLOTS:
        raise ValueError(f"the fused regularisation draws at most {SLOTS} tries, got {tries}")
    cum_start = np.concatenate([[0.0], np.cumsum(t.block_weight)[:-1]])
    out = Resampled(np.empty(n, dtype=np.int64), np.empty((n, 2)), np.empty((n, 2)), np.empty(n), np.empty(n),
                    np.empty((nb, N_RESAMPLE_SUMS)))
    for_slices(_resample_kernel, nb, n, state.e, t.block_scale, cum_start, last_positive(state, t), float(u),
               np.uint64(key), int(tries), bool(walks), float(h), np.ascontiguousarray(root, dtype=np.float64),
               floorplan.wall_mask, clearance, float(floorplan.origin_m[0]), float(floorplan.origin_m[1]),
               1.0 / floorplan.resolution_m, NO_BUFFER, prev_xy_m, state.xy_m, state.velocity_mps, state.heading_rad, state.step_length_m,
               float(shift_xy_m[0]), float(shift_xy_m[1]), out.parent, out.xy_m, out.velocity_mps, out.heading_rad,
               out.step_length_m, out.sums, min_per_thread=_MIN_BLOCKS_PER_THREAD)
    return out
