"""The filter step's two passes over the particles, in blocks of ``BLOCK`` on the shared threads.

1. :func:`advance_pass` -- per block: the motion model's kernel moves every particle (with
   normals drawn here), the wall check kills the live particles whose move touches a wall, the
   measurement model's kernel adds its log-likelihood, and the block's sums (largest log weight,
   sums of e = exp(lw - max), e^2, e dx, e dy, e dx^2, e dx dy, e dy^2, particles alive, with a
   finite weight, the best live log-likelihood) are kept for the normalisation, the ESS, the
   estimate and the regularisation's covariance. The three stages can run in one call (one
   floor) or in turn on the same arrays (a building, whose floor changes happen in between).
2. :func:`resample_pass` -- systematic resampling from the block sums, the gather of the
   ancestors' state and the wall-safe jitter of the Regularised Particle Filter (Musso, Oudjane
   & Le Gland), with the sums of the new cloud.

Each block's sums are kept apart and added in block order, and every random number is a
counter-based draw of the particle's index, so the result does not depend on how the blocks
are spread over threads.

Models plug in through two function-pointer types, compiled once with these signatures:

- ``MOVE_SIGNATURE``: ``move(params, src, dst, normals, lo, m)`` writes the moved state of
  particles ``lo .. lo + m - 1`` (``src``, ``dst``: the (STATE_ROWS, N) state arrays of
  ``filter.particles``) using ``normals[k, j]``, standard normals of particle ``lo + j``
  (``k`` < twice the pairs the model asked for);
- ``LIKELIHOOD_SIGNATURE``: ``log_likelihood(params, state, lo, m, out)`` writes
  ``out[j] = log p(z | particle lo + j)`` (finite or -inf; NaN and +inf count as -inf).
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from mapfilter.filter.kernels.draws import BLOCK, cos_sin, exp_block, normal_pairs
from mapfilter.maps.walls import NO_BUFFER, move_crosses
from mapfilter.runtime.threads import for_slices

__all__ = ["BLOCK", "LIKELIHOOD_SIGNATURE", "MOVE_SIGNATURE", "advance_pass", "resample_pass"]

# rows of the state array (filter.particles)
X, Y, VX, VY, HEADING, STEP = range(6)
STATE_ROWS = 6

_state = types.float64[:, ::1]
_params = types.float64[::1]
MOVE_SIGNATURE = types.void(_params, _state, _state, _state, types.int64, types.int64)
LIKELIHOOD_SIGNATURE = types.void(_params, _state, types.int64, types.int64, types.float64[::1])
MOVE_FUNCTION = types.FunctionType(MOVE_SIGNATURE)
LIKELIHOOD_FUNCTION = types.FunctionType(LIKELIHOOD_SIGNATURE)


def _function_from_addresses(function_type):
    """An intrinsic that makes a first-class function of ``function_type`` from its two addresses
    (the C wrapper's and the compiled function's): the kernels take models' functions as integers,
    because numba's own unboxing of a function argument costs tens of microseconds per call."""

    @intrinsic
    def make(typingctx, c_address, jit_address):
        def codegen(context, builder, signature, args):
            value = cgutils.create_struct_proxy(function_type)(context, builder)
            void_pointer = context.get_value_type(types.voidptr)
            value.c_addr = builder.inttoptr(args[0], void_pointer)
            value.py_addr = ir.Constant(void_pointer, None)
            value.jit_addr = builder.inttoptr(args[1], void_pointer)  # called directly (numba's convention)
            return value._getvalue()
        return function_type(types.uint64, types.uint64), codegen

    return make


_move_at = _function_from_addresses(MOVE_FUNCTION)
_likelihood_at = _function_from_addresses(LIKELIHOOD_FUNCTION)
_ADDRESSES: dict = {}


def function_addresses(function, signature) -> tuple[int, int]:
    """(C wrapper address, compiled function address) of a model's kernel compiled with ``signature``."""
    addresses = _ADDRESSES.get(function)  # a kernel has one signature (hashing numba's types is slow)
    if addresses is None:
        from numba.experimental.function_type import _get_jit_address, _get_wrapper_address

        addresses = _ADDRESSES[function] = (_get_wrapper_address(function, signature),
                                            _get_jit_address(function, signature))
    return addresses


# what advance_pass does (flags)
MOVE, KILL, WEIGH = 1, 2, 4
# per-block sums of advance_pass
A_MAX, A_SUM, A_SUM2, A_X, A_Y, A_XX, A_XY, A_YY, A_ALIVE, A_FINITE, A_BEST_LL = range(11)
N_ADVANCE_SUMS = 11
# per-block sums of resample_pass: dx, dy, dx^2, dx dy, dy^2, cos h, sin h, step length
R_X, R_Y, R_XX, R_XY, R_YY, R_COS, R_SIN, R_STEP = range(8)
N_RESAMPLE_SUMS = 8

_bool2 = types.boolean[:, ::1]
_f32_2 = types.float32[:, ::1]
_f64 = types.float64
_i64 = types.int64
_i64_1 = types.int64[::1]


_u64 = types.uint64


@njit(types.void(_i64, _i64, _i64, _i64, _u64, _i64, _u64, _u64, _params, _state, types.float64[::1],
                 _bool2, _f32_2, _f64, _f64, _f64, _i64_1, _u64, _u64, _params, _f64, _f64, _state,
                 types.float64[::1], types.boolean[::1], types.float64[::1], types.float64[:, ::1]),
      cache=True, nogil=True, error_model="numpy")
def _advance_kernel(lo_block, hi_block, n, flags, key, n_pairs, move_c, move_jit, move_params, src, src_lw, mask,
                    clearance, x0_m, y0_m, inv_res, no_buffer, ll_c, ll_jit, ll_params, shift_x, shift_y, dst, lw,
                    killed, e_out, sums):
    move = _move_at(move_c, move_jit)
    log_likelihood = _likelihood_at(ll_c, ll_jit)
    iota = np.arange(BLOCK)
    normals = np.empty((6, BLOCK))
    scratch = np.empty(BLOCK)
    ll = np.empty(BLOCK)
    e_block = np.empty(BLOCK)
    mask_h, mask_w = clearance.shape
    for block in range(lo_block, hi_block):
        lo = block * BLOCK
        m = min(n, lo + BLOCK) - lo
        if flags & MOVE:
            for pair in range(n_pairs):
                normal_pairs(key, pair, lo, iota, m, normals[2 * pair], normals[2 * pair + 1], scratch)
            move(move_params, src, dst, normals, lo, m)
        if flags & KILL:
            # a move through a wall kills its particle (Evennou & Marx: P_m = 0); the dead stay dead
            for j in range(m):
                i = lo + j
                w0 = src_lw[i]
                hit = False
                if w0 > -np.inf and w0 < np.inf:
                    ax = src[X, i]
                    ay = src[Y, i]
                    bx = dst[X, i]
                    by = dst[Y, i]
                    # the start pixel's clearance decides most moves (see maps.walls.move_crosses)
                    u0 = (ax - x0_m) * inv_res
                    v0 = mask_h - (ay - y0_m) * inv_res
                    du = (bx - ax) * inv_res
                    dv = (by - ay) * inv_res
                    c = 0.0
                    if 0.0 <= u0 < mask_w and 0.0 <= v0 < mask_h:
                        c = clearance[int(v0), int(u0)]
                    if not du * du + dv * dv < c * c:
                        hit = move_crosses(mask, clearance, x0_m, y0_m, inv_res, ax, ay, bx, by, no_buffer)
                else:
                    w0 = -np.inf
                killed[i] = hit
                lw[i] = -np.inf if hit else w0
        if flags & WEIGH:
            log_likelihood(ll_params, dst, lo, m, ll)
            top = -np.inf
            best_ll = -np.inf
            alive = 0
            finite = 0
            for j in range(m):
                i = lo + j
                w0 = lw[i]
                v = ll[j]
                # NaN or +inf is a model defect: such a particle gets no weight instead of a poisoned sum
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
                exp_block(ll, m, e_block)  # 0 for the dead (not in place: aliasing kept it from vectorising)
                for j in range(m):
                    i = lo + j
                    e = e_block[j]
                    e_out[i] = e
                    dx = dst[X, i] - shift_x
                    dy = dst[Y, i] - shift_y
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


@njit(types.void(_i64, _i64, _i64, types.float64[::1], types.float64[::1], types.float64[::1], _i64, _f64,
                 types.uint64, _i64, types.boolean, _f64, types.float64[:, ::1], _bool2, _f32_2, _f64, _f64, _f64,
                 _i64_1, _state, _state, _f64, _f64, _i64_1, _state, types.float64[:, ::1]),
      cache=True, nogil=True, error_model="numpy")
def _resample_kernel(lo_block, hi_block, n, e, block_scale, cum_start, last, u, key, tries, walks, h, root, mask,
                     clearance, x0_m, y0_m, inv_res, no_buffer, origin, src, shift_x, shift_y, parent, dst, sums):
    z0 = np.empty(BLOCK)
    z1 = np.empty(BLOCK)
    scratch = np.empty(BLOCK)
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
        # gather, and the jitter: parent + h root eps, redrawn up to ``tries`` times while the move
        # from the parent or from the parent's position before the step touches a wall, else the
        # particle stays at its parent
        for j in range(m):
            k = parent[lo + j]
            for row in range(dst.shape[0]):
                dst[row, lo + j] = src[row, k]
            pending[j] = j
        n_pending = m
        for t in range(tries):
            if n_pending == 0:
                break
            # draws for the pending particles only (a particle's draw at try t is the same whichever are)
            normal_pairs(key, t, lo, pending, n_pending, z0, z1, scratch)
            n_left = 0
            for q in range(n_pending):
                j = pending[q]
                i = lo + j
                k = parent[i]
                px = src[X, k]
                py = src[Y, k]
                cx = px + h * (root[0, 0] * z0[q] + root[0, 1] * z1[q])
                cy = py + h * (root[1, 0] * z0[q] + root[1, 1] * z1[q])
                hit = False
                for end in range(2):  # from the parent, then from the parent's position before the step
                    ax = px if end == 0 else origin[X, k]
                    ay = py if end == 0 else origin[Y, k]
                    u0 = (ax - x0_m) * inv_res
                    v0 = mask_h - (ay - y0_m) * inv_res
                    du = (cx - ax) * inv_res
                    dv = (cy - ay) * inv_res
                    c = 0.0
                    if 0.0 <= u0 < mask_w and 0.0 <= v0 < mask_h:
                        c = clearance[int(v0), int(u0)]
                    if not du * du + dv * dv < c * c:
                        hit = move_crosses(mask, clearance, x0_m, y0_m, inv_res, ax, ay, cx, cy, no_buffer)
                        if hit:
                            break
                if hit:
                    pending[n_left] = j  # q >= n_left: already read
                    n_left += 1
                    continue
                dst[X, i] = cx
                dst[Y, i] = cy
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
            dx = dst[X, i] - shift_x
            dy = dst[Y, i] - shift_y
            sx += dx
            sy += dy
            sxx += dx * dx
            sxy += dx * dy
            syy += dy * dy
            if walks:
                heading = dst[HEADING, i]
                if not -math.pi <= heading <= math.pi:
                    heading = ((heading + math.pi) % (2.0 * math.pi)) - math.pi
                c, s = cos_sin(heading)
                sc += c
                ss += s
                sl += dst[STEP, i]
        sums[block, R_X] = sx
        sums[block, R_Y] = sy
        sums[block, R_XX] = sxx
        sums[block, R_XY] = sxy
        sums[block, R_YY] = syy
        sums[block, R_COS] = sc
        sums[block, R_SIN] = ss
        sums[block, R_STEP] = sl


@njit(LIKELIHOOD_SIGNATURE, cache=True, nogil=True)
def flat_log_likelihood(params, state, lo, m, out):
    """No measurement: every particle 0."""
    for j in range(m):
        out[j] = 0.0


@njit(LIKELIHOOD_SIGNATURE, cache=True, nogil=True)
def given_log_likelihood(params, state, lo, m, out):
    """Values a model computed itself over all particles, passed as the params."""
    for j in range(m):
        out[j] = params[lo + j]


@njit(MOVE_SIGNATURE, cache=True, nogil=True)
def stay(params, src, dst, normals, lo, m):
    """No move: every particle keeps its state."""
    for row in range(src.shape[0]):
        for j in range(m):
            dst[row, lo + j] = src[row, lo + j]



# ---- the Python side: arrays in, sums added up ---------------------------------------------------
MIN_BLOCKS_PER_THREAD = 16  # below 2 x 16,384 particles a step runs on one thread (the hand-over costs more)


def n_blocks(n: int) -> int:
    return (n + BLOCK - 1) // BLOCK


class WallGrid:
    """A plan's wall mask and clearance as the kernels take them (``None`` plan: no walls)."""

    __slots__ = ("mask", "clearance", "x0_m", "y0_m", "inv_resolution")

    def __init__(self, plan) -> None:
        from mapfilter.maps.walls import clearance_px

        self.mask = np.ascontiguousarray(plan.wall_mask, dtype=np.bool_)
        self.clearance = np.ascontiguousarray(clearance_px(plan), dtype=np.float32)
        self.x0_m = float(plan.origin_m[0])
        self.y0_m = float(plan.origin_m[1])
        self.inv_resolution = 1.0 / float(plan.resolution_m)


def advance_pass(flags: int, key: int, n_pairs: int, move, move_params: np.ndarray, src: np.ndarray,
                 src_log_weight: np.ndarray, walls: WallGrid, log_likelihood, ll_params: np.ndarray,
                 shift_xy_m: np.ndarray, dst: np.ndarray, log_weight: np.ndarray, killed: np.ndarray,
                 e: np.ndarray, sums: np.ndarray) -> None:
    """Pass 1 over every particle: the stages ``flags`` asks for (MOVE | KILL | WEIGH), writing
    ``dst`` (moved state), ``log_weight``, ``killed``, ``e`` and the block ``sums``."""
    n = src.shape[1]
    move_c, move_jit = function_addresses(move, MOVE_SIGNATURE)
    ll_c, ll_jit = function_addresses(log_likelihood, LIKELIHOOD_SIGNATURE)
    for_slices(_advance_kernel, n_blocks(n), n, int(flags), np.uint64(key), int(n_pairs), move_c, move_jit, move_params,
               src, src_log_weight, walls.mask, walls.clearance, walls.x0_m, walls.y0_m, walls.inv_resolution,
               NO_BUFFER, ll_c, ll_jit, ll_params, float(shift_xy_m[0]), float(shift_xy_m[1]), dst, log_weight,
               killed, e, sums, min_per_thread=MIN_BLOCKS_PER_THREAD)


class Totals:
    """The block sums of :func:`advance_pass` added up, in block order."""

    __slots__ = ("log_normaliser", "ess", "mean_xy_m", "covariance_m2", "n_alive", "n_finite", "best_log_likelihood",
                 "max_log_weight", "block_scale", "block_weight")

    def __init__(self, sums: np.ndarray, shift_xy_m: np.ndarray) -> None:
        top = sums[:, A_MAX]
        self.n_alive = int(sums[:, A_ALIVE].sum())  # alive after the wall check
        self.n_finite = int(sums[:, A_FINITE].sum())  # with a finite weight after weighing
        self.best_log_likelihood = float(sums[:, A_BEST_LL].max())
        m = float(top.max())
        self.max_log_weight = m
        if not self.n_finite or not math.isfinite(m):
            zeros = np.zeros(len(sums))
            self.log_normaliser, self.ess = -math.inf, 0.0
            self.mean_xy_m, self.covariance_m2 = np.full(2, np.nan), np.full((2, 2), np.nan)
            self.block_scale = self.block_weight = zeros
            return
        f = np.exp(top - m)  # 0 for blocks without weight
        total = float(f @ sums[:, A_SUM])
        self.log_normaliser = m + math.log(total)
        self.ess = total * total / float((f * f) @ sums[:, A_SUM2])
        ex, ey = float(f @ sums[:, A_X]) / total, float(f @ sums[:, A_Y]) / total
        cxx = float(f @ sums[:, A_XX]) / total - ex * ex
        cxy = float(f @ sums[:, A_XY]) / total - ex * ey
        cyy = float(f @ sums[:, A_YY]) / total - ey * ey
        self.mean_xy_m = np.array([float(shift_xy_m[0]) + ex, float(shift_xy_m[1]) + ey])
        self.covariance_m2 = np.array([[cxx, cxy], [cxy, cyy]])
        self.block_scale = f / total  # w_i = e_i * block_scale[block of i]
        self.block_weight = f * sums[:, A_SUM] / total


def resample_pass(totals: Totals, e: np.ndarray, n_out: int, u: float, key: int, tries: int, walks: bool,
                  h: float, root: np.ndarray, walls: WallGrid, origin: np.ndarray, src: np.ndarray,
                  shift_xy_m: np.ndarray, parent: np.ndarray, dst: np.ndarray, sums: np.ndarray) -> None:
    """Pass 2: ``n_out`` particles drawn systematically (positions (j + u) / n_out) by the weights of
    pass 1, their ancestors' state gathered into ``dst`` and jittered by ``h root eps`` (``tries``
    draws, 0: no jitter), never through a wall from the ancestor nor from ``origin`` (the state
    before the step); ``walks``: also sum the headings' cos and sin and the step lengths."""
    blocks = np.flatnonzero(totals.block_weight > 0)
    b = int(blocks[-1])
    segment = e[b * BLOCK:(b + 1) * BLOCK] * totals.block_scale[b]
    last = b * BLOCK + int(np.flatnonzero(segment > 0)[-1])  # the last positive weight: the last bin
    cum_start = np.concatenate([[0.0], np.cumsum(totals.block_weight)[:-1]])
    for_slices(_resample_kernel, n_blocks(n_out), n_out, e, totals.block_scale, cum_start, last, float(u),
               np.uint64(key), int(tries), bool(walks), float(h), np.ascontiguousarray(root, dtype=np.float64),
               walls.mask, walls.clearance, walls.x0_m, walls.y0_m, walls.inv_resolution, NO_BUFFER, origin, src,
               float(shift_xy_m[0]), float(shift_xy_m[1]), parent, dst, sums, min_per_thread=MIN_BLOCKS_PER_THREAD)


def run_likelihood(function, params: np.ndarray, state: np.ndarray) -> np.ndarray:
    """(N,) a likelihood kernel's values over every particle of ``state`` (serially, block by
    block): for models and callers that need the values themselves."""
    n = state.shape[1]
    out = np.empty(n)
    block = np.empty(BLOCK)
    for lo in range(0, n, BLOCK):
        m = min(n, lo + BLOCK) - lo
        function(params, state, lo, m, block)
        out[lo:lo + m] = block[:m]
    return out
