"""The filter step's two passes over the particles, in blocks of ``SPAN`` on the shared threads.

1. :func:`advance_pass` -- per block: the motion model's kernel moves every particle (with
   normals drawn here; ``BLOCK`` particles a call), the wall check kills the live particles whose
   move touches a wall (64 moves' looks at a time, the few undecided ones checked alone), the
   measurement model's kernel adds its log-likelihood, and the block's sums (``ADVANCE_SUMS``:
   largest log weight, sums of e = exp(lw - max), e^2, e dx, e dy, e dx^2, e dx dy, e dy^2,
   particles alive, with a finite weight, the best live log-likelihood) are kept for the
   normalisation, the ESS, the estimate and the regularisation's covariance. The three stages can
   run in one call (one floor) or in turn on the same arrays (a building, whose floor changes
   happen in between).
2. :func:`resample_pass` -- systematic resampling from the block sums, the gather of the
   ancestors' state and the wall-safe jitter of the Regularised Particle Filter (Musso, Oudjane
   & Le Gland), with the sums of the new cloud (``RESAMPLE_SUMS``).

Each stage is a named function over one block (``_move_block``, ``_kill_block``, ``_weigh_block``,
``_block_moments``; ``_systematic_block``, ``_gather_block``, ``_jitter_block``,
``_new_cloud_sums``), written so that its loops vectorise: no branch per particle on the data (the
wall looks gather their answers into the bits of a word, the rare exceptions are found by their
set bits), and loops over views of the block (numba wraps a possibly negative index, and the
wrap-around turned contiguous loads into gathers).

Each block's sums are kept apart and added in block order, and every random number is a
counter-based draw of the particle's index, so the result does not depend on how the blocks
are spread over threads.

The kernels take their arguments as a few small structs (the ``NamedTuple`` classes below),
handed over as plain tuples (numba types a plain tuple in its C dispatcher, a named one in Python
at several times the cost) and named again on entry (``Advance(*advance)``).

Models plug in through two function-pointer types, compiled once with these signatures
(``kernels.pointers`` turns a model's kernel into the addresses the passes call):

- ``MOVE_SIGNATURE``: ``move(params, src, dst, normals, lo, m)`` writes the moved state of
  particles ``lo .. lo + m - 1`` (``src``, ``dst``: the (STATE_ROWS, N) state arrays of
  ``filter.particles``) using ``normals[k, j]``, standard normals of particle ``lo + j``
  (``k`` < twice the pairs the model asked for);
- ``LIKELIHOOD_SIGNATURE``: ``log_likelihood(params, state, lo, m, out)`` writes
  ``out[j] = log p(z | particle lo + j)`` (finite or -inf; NaN and +inf count as -inf).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np
from numba import njit, types

from mapfilter.filter.kernels.draws import BLOCK, cos_sin, exp_block, normal_pairs, trailing_zeros
from mapfilter.filter.kernels.pointers import function_at, pointer
from mapfilter.maps.walls import LOOK, WALL_GRID, WallGrid, look_move, look_two_moves, move_crosses
from mapfilter.runtime.threads import MIN_PER_THREAD, for_slices

__all__ = ["ADVANCE_SUMS", "BLOCK", "SPAN", "LIKELIHOOD_SIGNATURE", "MOVE_SIGNATURE", "RESAMPLE_SUMS", "Advance", "Advanced",
           "Cloud", "ModelCall", "Resample", "Resampled", "Totals", "Weights", "advance_pass", "killed_moves",
           "likelihood_call", "move_call", "resample_pass"]

# rows of the state array (filter.particles)
X, Y, VX, VY, HEADING, STEP = range(6)
STATE_ROWS = 6

_state = types.float64[:, ::1]
_params = types.float64[::1]
MOVE_SIGNATURE = types.void(_params, _state, _state, _state, types.int64, types.int64)
LIKELIHOOD_SIGNATURE = types.void(_params, _state, types.int64, types.int64, types.float64[::1])
_move_at = function_at(MOVE_SIGNATURE)
_likelihood_at = function_at(LIKELIHOOD_SIGNATURE)
# particles per block of the passes (each block's sums are kept apart): several of a model's calls
# (``BLOCK`` particles at most, what a model's kernel may size its scratch by); longer runs over each
# row of the state let the memory keep up (at 100,000 particles, blocks of BLOCK cost the step 10-20 %
# more, of 4 BLOCK 0-5 % more)
SPAN = 8 * BLOCK

# what advance_pass does (flags)
MOVE, KILL, WEIGH = 1, 2, 4

# per-block sums of advance_pass, relative to the block's largest log weight (e = exp(lw - max));
# dx, dy: a particle's position less the pass' shift; written by the weighing, but for the
# particles the wall check killed, which it writes
ADVANCE_SUMS = np.dtype([("max_log_weight", np.float64), ("e", np.float64), ("e2", np.float64),
                         ("e_dx", np.float64), ("e_dy", np.float64), ("e_dxx", np.float64), ("e_dxy", np.float64),
                         ("e_dyy", np.float64), ("alive", np.int64), ("finite", np.int64),
                         ("best_log_likelihood", np.float64), ("killed", np.int64)])
# per-block sums of resample_pass over the new cloud (every particle weighs the same)
RESAMPLE_SUMS = np.dtype([("dx", np.float64), ("dy", np.float64), ("dxx", np.float64), ("dxy", np.float64),
                          ("dyy", np.float64), ("cos_heading", np.float64), ("sin_heading", np.float64),
                          ("step_length_m", np.float64)])

_u64 = types.uint64
_f64 = types.float64
_i64 = types.int64
_vector = types.float64[::1]


def _tuple_type(cls, **field_types) -> types.Tuple:
    """The numba type of ``tuple(an instance of cls)``: the fields' types in the NamedTuple's order."""
    return types.Tuple(tuple(field_types[name] for name in cls._fields))


class Advance(NamedTuple):
    """What pass 1 does."""

    flags: int  # MOVE | KILL | WEIGH
    key: np.uint64  # the step's counter-based draws
    normal_pairs: int  # pairs of standard normals per particle that the move takes
    shift_x_m: float  # the origin of the sums' dx, dy (near the cloud: no cancellation)
    shift_y_m: float


class ModelCall(NamedTuple):
    """A model's kernel as a pass calls it (:func:`move_call`, :func:`likelihood_call`)."""

    c_address: np.uint64
    jit_address: np.uint64
    params: np.ndarray  # float64


class Cloud(NamedTuple):
    """The particles a pass reads."""

    state: np.ndarray  # (STATE_ROWS, N)
    log_weight: np.ndarray  # (N,)


class Advanced(NamedTuple):
    """What pass 1 writes."""

    state: np.ndarray  # (STATE_ROWS, N) the moved state
    log_weight: np.ndarray  # (N,) -inf: dead
    killed: np.ndarray  # (N,) bool: killed by the wall check of this call
    e: np.ndarray  # (N,) exp(log weight - its block's largest)
    sums: np.ndarray  # (blocks,) ADVANCE_SUMS


class Resample(NamedTuple):
    """What pass 2 does: systematic resampling with offset ``u`` and the jitter ``h root eps``."""

    u: float  # output j takes the particle whose cumulative-weight bin holds (j + u) / n_out
    log_weight: float  # every new particle's, -log n_out
    last: int  # the last particle with a positive weight (it closes the last bin at 1)
    key: np.uint64  # the jitter's counter-based draws
    tries: int  # a jitter through a wall is drawn again this often, then the particle stays put
    h: float  # the bandwidth
    root: np.ndarray  # (2, 2) a square root of the jitter's covariance
    walks: bool  # also sum the headings' cos and sin and the step lengths
    shift_x_m: float  # the origin of the sums' dx, dy
    shift_y_m: float


class Weights(NamedTuple):
    """Pass 1's weights as pass 2 draws from them: w_i = e[i] * block_scale[block of i]."""

    e: np.ndarray  # (N,)
    block_scale: np.ndarray  # (blocks,)
    cum_start: np.ndarray  # (blocks,) the summed weight of the blocks before


class Resampled(NamedTuple):
    """What pass 2 writes."""

    parent: np.ndarray  # (n_out,) int64
    state: np.ndarray  # (STATE_ROWS, n_out)
    log_weight: np.ndarray  # (n_out,)
    sums: np.ndarray  # (blocks,) RESAMPLE_SUMS


_ADVANCE = _tuple_type(Advance, flags=_i64, key=_u64, normal_pairs=_i64, shift_x_m=_f64, shift_y_m=_f64)
_MODEL_CALL = _tuple_type(ModelCall, c_address=_u64, jit_address=_u64, params=_params)
_CLOUD = _tuple_type(Cloud, state=_state, log_weight=_vector)
_ADVANCED = _tuple_type(Advanced, state=_state, log_weight=_vector, killed=types.boolean[::1], e=_vector,
                        sums=numba.from_dtype(ADVANCE_SUMS)[::1])
_RESAMPLE = _tuple_type(Resample, u=_f64, log_weight=_f64, last=_i64, key=_u64, tries=_i64, h=_f64, root=types.float64[:, ::1],
                        walks=types.boolean, shift_x_m=_f64, shift_y_m=_f64)
_WEIGHTS = _tuple_type(Weights, e=_vector, block_scale=_vector, cum_start=_vector)
_RESAMPLED = _tuple_type(Resampled, parent=types.int64[::1], state=_state, log_weight=_vector,
                         sums=numba.from_dtype(RESAMPLE_SUMS)[::1])
_WALLS = _tuple_type(WallGrid, **dict(zip(WallGrid._fields, WALL_GRID.types)))


def move_call(function, params: np.ndarray) -> ModelCall:
    """A motion model's kernel (compiled with ``MOVE_SIGNATURE``) with its parameters."""
    return ModelCall(*pointer(function, MOVE_SIGNATURE), np.ascontiguousarray(params, dtype=np.float64))


def likelihood_call(function, params: np.ndarray) -> ModelCall:
    """A measurement model's kernel (compiled with ``LIKELIHOOD_SIGNATURE``) with its parameters."""
    return ModelCall(*pointer(function, LIKELIHOOD_SIGNATURE), np.ascontiguousarray(params, dtype=np.float64))


# ---- pass 1, stage by stage over a block of particles lo .. lo + m - 1 ----------------------------
@njit(cache=True, nogil=True, error_model="numpy")
def _move_block(advance, move, src, dst, lo, m, iota, normals, scratch):
    """The motion model's kernel moves the block, BLOCK particles a call, with standard normals drawn here."""
    move_function = _move_at(move.c_address, move.jit_address)
    for first in range(lo, lo + m, BLOCK):
        count = min(lo + m - first, BLOCK)
        for pair in range(advance.normal_pairs):
            normal_pairs(advance.key, pair, first, iota, count, normals[2 * pair], normals[2 * pair + 1], scratch)
        move_function(move.params, src, dst, normals, first, count)


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _bit(word, k):
    """Bit k of a uint64 word, as a bool."""
    return (word >> np.uint64(k)) & np.uint64(1) != 0


@njit(cache=True, nogil=True, error_model="numpy")
def _kill_block(walls, src, dst, log_weight_before, log_weight, killed, lo, m):
    """A move through a wall kills its particle (Evennou & Marx: P_m = 0); the dead stay dead, and their
    moves are looked at but not decided. LOOK particles at a time: the look at every move and which are
    alive, as bits (a loop that vectorises), the rare undecided live move checked alone, then the kills
    written. Returns how many it killed."""
    n_killed = 0
    for first in range(lo, lo + m, LOOK):
        count = min(lo + m - first, LOOK)
        # views of the chunk: indices that start at 0 make contiguous loads (first + k could be negative)
        xa, ya = src[X, first:first + count], src[Y, first:first + count]
        xb, yb = dst[X, first:first + count], dst[Y, first:first + count]
        weight_before = log_weight_before[first:first + count]
        free = wall = alive = np.uint64(0)
        for k in range(count):
            f, w = look_move(walls, xa[k], ya[k], xb[k], yb[k])
            w0 = weight_before[k]
            free |= np.uint64(f) << np.uint64(k)
            wall |= np.uint64(w) << np.uint64(k)
            alive |= np.uint64((w0 > -np.inf) & (w0 < np.inf)) << np.uint64(k)
        undecided = alive & ~(free | wall)
        while undecided != 0:  # over its set bits only: a loop over all would keep the next from vectorising
            k = trailing_zeros(undecided)
            undecided &= undecided - np.uint64(1)
            i = first + k
            if move_crosses(walls, src[X, i], src[Y, i], dst[X, i], dst[Y, i]):
                wall |= np.uint64(1) << k
        dies = alive & wall
        survives = alive & ~wall
        killed_chunk, weight_after = killed[first:first + count], log_weight[first:first + count]
        for k in range(count):
            killed_chunk[k] = _bit(dies, k)
            n_killed += _bit(dies, k)
            weight_after[k] = weight_before[k] if _bit(survives, k) else -np.inf
    return n_killed


@njit(cache=True, nogil=True, error_model="numpy")
def _weigh_block(likelihood, dst, log_weight, lo, m, ll):
    """The measurement model's kernel adds its log-likelihood to the block's log weights (BLOCK particles
    a call). Returns (the largest log weight, the best live log-likelihood, the particles alive, those
    with a finite weight)."""
    log_likelihood = _likelihood_at(likelihood.c_address, likelihood.jit_address)
    for first in range(lo, lo + m, BLOCK):
        log_likelihood(likelihood.params, dst, first, min(lo + m - first, BLOCK), ll[first - lo:])
    top = -np.inf
    best_ll = -np.inf
    alive = 0
    finite = 0
    weights = log_weight[lo:lo + m]  # a view: indices from 0 make contiguous loads (lo + j could be negative)
    for j in range(m):
        w0 = weights[j]
        v = ll[j]
        # NaN or +inf is a model defect: such a particle gets no weight instead of a poisoned sum
        v = v if -np.inf < v < np.inf else -np.inf
        live = w0 > -np.inf
        alive += live
        best_ll = v if live and v > best_ll else best_ll
        w1 = w0 + v
        weights[j] = w1
        finite += w1 > -np.inf
        top = w1 if w1 > top else top
    return top, best_ll, alive, finite


# fastmath's reassoc: the sums may be added in any order that the compiler vectorises (the same order
# whatever the threads: a block is summed by one compiled loop)
_REASSOCIATE = {"reassoc", "contract"}


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_REASSOCIATE)
def _block_moments(advance, dst, log_weight, e, lo, m, top, shifted, e_block, sums):
    """e = exp(log weight - top) of the block's particles (0 for the dead) into ``e``, and their sums
    (e, e^2, e dx, e dy, e dx^2, e dx dy, e dy^2; dx, dy from the pass' shift) into the block's
    ``sums`` record."""
    s = s2 = sx = sy = sxx = sxy = syy = 0.0
    weights, e_out, x, y = log_weight[lo:lo + m], e[lo:lo + m], dst[X, lo:lo + m], dst[Y, lo:lo + m]
    for j in range(m):
        shifted[j] = weights[j] - top
    exp_block(shifted, m, e_block)  # not in place: aliasing kept it from vectorising
    for j in range(m):
        w = e_block[j]
        e_out[j] = w
        dx = x[j] - advance.shift_x_m
        dy = y[j] - advance.shift_y_m
        s += w
        s2 += w * w
        sx += w * dx
        sy += w * dy
        sxx += w * dx * dx
        sxy += w * dx * dy
        syy += w * dy * dy
    sums.e, sums.e2, sums.e_dx, sums.e_dy, sums.e_dxx, sums.e_dxy, sums.e_dyy = s, s2, sx, sy, sxx, sxy, syy


@njit(types.void(_i64, _i64, _ADVANCE, _MODEL_CALL, _MODEL_CALL, _WALLS, _CLOUD, _ADVANCED),
      cache=True, nogil=True, error_model="numpy")
def _advance_kernel(lo_block, hi_block, advance, move, likelihood, walls, before, after):
    advance = Advance(*advance)
    move = ModelCall(*move)
    likelihood = ModelCall(*likelihood)
    walls = WallGrid(*walls)
    before = Cloud(*before)
    after = Advanced(*after)
    n = before.state.shape[1]
    iota = np.arange(BLOCK)
    normals = np.empty((6, BLOCK))
    work = np.empty((3, SPAN))  # the draws' scratch, the log-likelihoods, the exponentials
    for block in range(lo_block, hi_block):
        lo = block * SPAN
        m = min(n, lo + SPAN) - lo
        sums = after.sums[block]
        if advance.flags & MOVE:
            _move_block(advance, move, before.state, after.state, lo, m, iota, normals, work[0])
        if advance.flags & KILL:
            sums.killed = _kill_block(walls, before.state, after.state, before.log_weight, after.log_weight,
                                      after.killed, lo, m)
        if advance.flags & WEIGH:
            top, best_ll, alive, finite = _weigh_block(likelihood, after.state, after.log_weight, lo, m, work[1])
            sums.max_log_weight, sums.best_log_likelihood, sums.alive, sums.finite = top, best_ll, alive, finite
            if finite > 0:
                _block_moments(advance, after.state, after.log_weight, after.e, lo, m, top, work[1], work[2], sums)
            else:
                after.e[lo:lo + m] = 0.0
                sums.e = sums.e2 = sums.e_dx = sums.e_dy = sums.e_dxx = sums.e_dxy = sums.e_dyy = 0.0


# ---- pass 2, stage by stage over a block of new particles lo .. lo + m - 1 ---------------------------
@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _outputs_below(cum, n, u):
    """How many of the n positions (j + u) / n lie below the cumulative weight ``cum``: ceil(cum n - u)
    within [0, n]."""
    x = np.ceil(cum * n - u)
    x = x if x > 0.0 else 0.0
    return int(x if x < n else n)


@njit(cache=True, nogil=True, error_model="numpy")
def _systematic_block(weights, u, last, n, lo, m, parent, mark):
    """parent[lo + j], j < m: systematic resampling, output j takes the particle whose bin of the
    cumulative weights holds (j + u) / n: input i takes the outputs below ceil(C_i n - u) (C_i its
    cumulative weight) that no input before it took, and ``last`` (the last positive weight) closes the
    last bin at 1 (round-off guard); zero weights take none. Each input marks the first output it takes
    and each output takes the last mark at or before it: no branch per output on the weights
    (``mark``: m + 1 entries)."""
    e = weights.e
    scale = weights.block_scale
    cum_start = weights.cum_start
    # the walk starts at the last input block whose cumulative start is <= the block's first position
    p0 = (lo + u) / n
    b = 0
    hi_b = min(cum_start.shape[0] - 1, last // SPAN)
    while b < hi_b:
        mid = (b + hi_b + 1) // 2
        if cum_start[mid] <= p0:
            b = mid
        else:
            hi_b = mid - 1
    mark[:m + 1] = -1
    i = b * SPAN
    cum = cum_start[b]
    taken = min(_outputs_below(cum, n, u), lo)  # the outputs the inputs before the walk took
    while True:
        w = e[i] * scale[i // SPAN]
        cum += w
        upto = n if i >= last else _outputs_below(cum, n, u)
        # an input that takes no output marks the spare slot m (a store that waits on no load)
        mark[max(taken - lo, 0) if (w > 0.0) & (upto > taken) else m] = i
        taken = max(taken, upto)
        if taken >= lo + m or i >= last:
            break
        i += 1
    run = -1
    out = parent[lo:lo + m]
    for j in range(m):
        k = mark[j]
        run += (k - run) & -np.int64(k >= 0)  # k where marked, else the mark before (max() branched)
        out[j] = run


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _gather_block(src, dst, parent, lo, m):
    """The new particles' state: their parents' (row by row: each row's reads run forward)."""
    parents = parent[lo:lo + m]
    for row in range(dst.shape[0]):
        to, source = dst[row, lo:lo + m], src[row]
        for j in range(m):
            to[j] = source[np.uintp(parents[j])]  # unsigned: no wrap-around of negative indices


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _jittered(resample, x, y, z0, z1):
    """(x, y) + h root (z0, z1): the jitter's candidate."""
    root = resample.root
    return (x + resample.h * (root[0, 0] * z0 + root[0, 1] * z1),
            y + resample.h * (root[1, 0] * z0 + root[1, 1] * z1))


@njit(cache=True, nogil=True, error_model="numpy")
def _jitter_looks(resample, walls, ox, oy, dst, pending, all_pending, lo, first, count, z0, z1):
    """Bit k: the candidate of pending copy first + k (of copy first + k when ``all_pending``) touches no
    wall from the copy nor from its parent's position before the step (``ox``, ``oy``: the block's); a
    pending copy has not moved yet, so it sits at its parent's position."""
    free = wall = np.uint64(0)
    if all_pending:  # views of the chunk: indices from 0 make contiguous loads
        x, y = dst[X, lo + first:lo + first + count], dst[Y, lo + first:lo + first + count]
        x0, y0 = ox[first:first + count], oy[first:first + count]
        z0s, z1s = z0[first:first + count], z1[first:first + count]
        for k in range(count):  # no memory written: this loop vectorises
            cx, cy = _jittered(resample, x[k], y[k], z0s[k], z1s[k])
            f, w = look_two_moves(walls, x[k], y[k], x0[k], y0[k], cx, cy)
            free |= np.uint64(f) << np.uint64(k)
            wall |= np.uint64(w) << np.uint64(k)
    else:
        x, y = dst[X, lo:], dst[Y, lo:]
        for k in range(count):
            q = first + k
            j = np.uintp(pending[q])
            cx, cy = _jittered(resample, x[j], y[j], z0[q], z1[q])
            f, w = look_two_moves(walls, x[j], y[j], ox[j], oy[j], cx, cy)
            free |= np.uint64(f) << np.uint64(k)
            wall |= np.uint64(w) << np.uint64(k)
    undecided = ~(free | wall) & (np.uint64(0xFFFFFFFFFFFFFFFF) >> np.uint64(LOOK - count))
    while undecided != 0:  # over its set bits only
        k = trailing_zeros(undecided)
        undecided &= undecided - np.uint64(1)
        q = first + k
        j = q if all_pending else pending[q]
        px, py = dst[X, lo + j], dst[Y, lo + j]
        cx, cy = _jittered(resample, px, py, z0[q], z1[q])
        if not (move_crosses(walls, px, py, cx, cy) or move_crosses(walls, ox[j], oy[j], cx, cy)):
            free |= np.uint64(1) << k
    return free


@njit(cache=True, nogil=True, error_model="numpy")
def _jitter_block(resample, walls, origin, dst, parent, lo, m, pending, buffers):
    """The jitter of the Regularised Particle Filter: each copy moves to copy + h root eps, drawn again
    (up to ``resample.tries`` times) while the move from the copy or from its parent's position before
    the step (``origin``) touches a wall; then the copy stays at its parent. LOOK copies at a time: one
    look at both moves of each (:func:`_jitter_looks`, in a loop that vectorises), the accepted written,
    the others kept for the next try. ``pending``: SPAN entries; ``buffers``: (5, SPAN)."""
    z0, z1, scratch, ox, oy = buffers[0], buffers[1], buffers[2], buffers[3], buffers[4]
    _gather_block(origin[X:Y + 1], buffers[3:5], parent[lo:], 0, m)  # the parents' positions before the step
    for j in range(m):
        pending[j] = j
    n_pending = m
    for t in range(resample.tries):
        if n_pending == 0:
            break
        # draws for the pending copies only (a copy's draw at try t is the same whichever are)
        normal_pairs(resample.key, t, lo, pending, n_pending, z0, z1, scratch)
        n_left = 0
        for first in range(0, n_pending, LOOK):
            count = min(n_pending - first, LOOK)
            accepted = _jitter_looks(resample, walls, ox, oy, dst, pending, t == 0, lo, first, count, z0, z1)
            # the accepted copies move to their candidates, computed again as in the look
            if t == 0:
                x, y = dst[X, lo + first:lo + first + count], dst[Y, lo + first:lo + first + count]
                z0s, z1s = z0[first:first + count], z1[first:first + count]
                for k in range(count):
                    cx, cy = _jittered(resample, x[k], y[k], z0s[k], z1s[k])
                    x[k] = cx if _bit(accepted, k) else x[k]
                    y[k] = cy if _bit(accepted, k) else y[k]
            else:
                for k in range(count):
                    q = first + k
                    i = lo + pending[q]
                    cx, cy = _jittered(resample, dst[X, i], dst[Y, i], z0[q], z1[q])
                    dst[X, i] = cx if _bit(accepted, k) else dst[X, i]
                    dst[Y, i] = cy if _bit(accepted, k) else dst[Y, i]
            blocked = ~accepted & (np.uint64(0xFFFFFFFFFFFFFFFF) >> np.uint64(LOOK - count))
            while blocked != 0:  # q >= n_left: already read
                pending[n_left] = pending[first + trailing_zeros(blocked)]
                n_left += 1
                blocked &= blocked - np.uint64(1)
        n_pending = n_left


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_REASSOCIATE)
def _new_cloud_sums(resample, dst, lo, m, sums):
    """The block's sums of the new cloud (``RESAMPLE_SUMS``; every particle weighs the same) into its
    ``sums`` record."""
    sx = sy = sxx = sxy = syy = sc = ss = sl = 0.0
    x, y = dst[X, lo:lo + m], dst[Y, lo:lo + m]
    for j in range(m):
        dx = x[j] - resample.shift_x_m
        dy = y[j] - resample.shift_y_m
        sx += dx
        sy += dy
        sxx += dx * dx
        sxy += dx * dy
        syy += dy * dy
    if resample.walks:
        for j in range(m):
            heading = dst[HEADING, lo + j]
            if not -math.pi <= heading <= math.pi:
                heading = ((heading + math.pi) % (2.0 * math.pi)) - math.pi
            c, s = cos_sin(heading)
            sc += c
            ss += s
            sl += dst[STEP, lo + j]
    sums.dx, sums.dy, sums.dxx, sums.dxy, sums.dyy = sx, sy, sxx, sxy, syy
    sums.cos_heading, sums.sin_heading, sums.step_length_m = sc, ss, sl


@njit(types.void(_i64, _i64, _RESAMPLE, _WEIGHTS, _WALLS, _state, _state, _RESAMPLED),
      cache=True, nogil=True, error_model="numpy")
def _resample_kernel(lo_block, hi_block, resample, weights, walls, origin, src, after):
    resample = Resample(*resample)
    weights = Weights(*weights)
    walls = WallGrid(*walls)
    after = Resampled(*after)
    n = after.state.shape[1]
    mark = np.empty(SPAN + 1, dtype=np.int64)
    pending = np.empty(SPAN, dtype=np.int64)
    buffers = np.empty((5, SPAN))
    for block in range(lo_block, hi_block):
        lo = block * SPAN
        m = min(n, lo + SPAN) - lo
        _systematic_block(weights, resample.u, resample.last, n, lo, m, after.parent, mark)
        _gather_block(src, after.state, after.parent, lo, m)
        after.log_weight[lo:lo + m] = resample.log_weight
        if resample.tries > 0:
            _jitter_block(resample, walls, origin, after.state, after.parent, lo, m, pending, buffers)
        _new_cloud_sums(resample, after.state, lo, m, after.sums[block])


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


# ---- the Python side: structs in, sums added up ---------------------------------------------------
MIN_BLOCKS_PER_THREAD = MIN_PER_THREAD // SPAN  # below 2 x 16,384 particles a step runs on one thread


def n_blocks(n: int) -> int:
    return (n + SPAN - 1) // SPAN


def advance_sums(n: int) -> np.ndarray:
    """The block sums array that :func:`advance_pass` writes for ``n`` particles."""
    return np.empty(n_blocks(n), dtype=ADVANCE_SUMS)


def advance_pass(advance: Advance, move: ModelCall, likelihood: ModelCall, walls: WallGrid, before: Cloud,
                 after: Advanced) -> None:
    """Pass 1 over every particle: the stages ``advance.flags`` asks for (MOVE | KILL | WEIGH), from
    ``before`` into ``after`` (moved state, log weights, killed, e and the block sums)."""
    for_slices(_advance_kernel, n_blocks(before.state.shape[1]), tuple(advance), tuple(move), tuple(likelihood),
               tuple(walls), tuple(before), tuple(after), min_per_thread=MIN_BLOCKS_PER_THREAD)


class Totals:
    """The block sums of :func:`advance_pass` added up, in block order."""

    __slots__ = ("log_normaliser", "ess", "mean_xy_m", "covariance_m2", "n_alive", "n_finite", "best_log_likelihood",
                 "max_log_weight", "block_scale", "block_weight")

    def __init__(self, sums: np.ndarray, shift_xy_m: np.ndarray) -> None:
        top = sums["max_log_weight"]
        self.n_alive = int(sums["alive"].sum())  # alive after the wall check
        self.n_finite = int(sums["finite"].sum())  # with a finite weight after weighing
        self.best_log_likelihood = float(sums["best_log_likelihood"].max())
        m = float(top.max())
        self.max_log_weight = m
        if not self.n_finite or not math.isfinite(m):
            zeros = np.zeros(len(sums))
            self.log_normaliser, self.ess = -math.inf, 0.0
            self.mean_xy_m, self.covariance_m2 = np.full(2, np.nan), np.full((2, 2), np.nan)
            self.block_scale = self.block_weight = zeros
            return
        f = np.exp(top - m)  # 0 for blocks without weight
        total = float(f @ sums["e"])
        self.log_normaliser = m + math.log(total)
        self.ess = total * total / float((f * f) @ sums["e2"])
        ex, ey = float(f @ sums["e_dx"]) / total, float(f @ sums["e_dy"]) / total
        cxx = float(f @ sums["e_dxx"]) / total - ex * ex
        cxy = float(f @ sums["e_dxy"]) / total - ex * ey
        cyy = float(f @ sums["e_dyy"]) / total - ey * ey
        self.mean_xy_m = np.array([float(shift_xy_m[0]) + ex, float(shift_xy_m[1]) + ey])
        self.covariance_m2 = np.array([[cxx, cxy], [cxy, cyy]])
        self.block_scale = f / total  # w_i = e_i * block_scale[block of i]
        self.block_weight = f * sums["e"] / total


def resample_pass(totals: Totals, e: np.ndarray, u: float, key: int, tries: int, walks: bool, h: float,
                  root: np.ndarray, walls: WallGrid, origin: np.ndarray, src: np.ndarray, shift_xy_m: np.ndarray,
                  after: Resampled) -> None:
    """Pass 2: ``after.state``'s particles drawn systematically (positions (j + u) / n_out) by the
    weights of pass 1 (``totals``, ``e``), their ancestors' state gathered from ``src`` and jittered
    by ``h root eps`` (``tries`` draws, 0: no jitter), never through a wall from the ancestor nor
    from ``origin`` (the state before the step); ``walks``: also sum the headings' cos and sin and
    the step lengths into ``after.sums`` (``RESAMPLE_SUMS``)."""
    blocks = np.flatnonzero(totals.block_weight > 0)
    b = int(blocks[-1])
    segment = e[b * SPAN:(b + 1) * SPAN] * totals.block_scale[b]
    last = b * SPAN + int(np.flatnonzero(segment > 0)[-1])  # the last positive weight: the last bin
    cum_start = np.concatenate([[0.0], np.cumsum(totals.block_weight)[:-1]])
    resample = Resample(float(u), -math.log(after.state.shape[1]), last, np.uint64(key), int(tries), float(h),
                        np.ascontiguousarray(root, dtype=np.float64), bool(walks), float(shift_xy_m[0]),
                        float(shift_xy_m[1]))
    for_slices(_resample_kernel, n_blocks(after.state.shape[1]), tuple(resample),
               tuple(Weights(e, totals.block_scale, cum_start)), tuple(walls), origin, src, tuple(after),
               min_per_thread=MIN_BLOCKS_PER_THREAD)


@njit(types.void(_i64, _i64, types.boolean[::1], types.int64[::1], _state, _state, types.float64[:, ::1],
                 types.float64[:, ::1]), cache=True, nogil=True)
def _killed_kernel(lo_block, hi_block, killed, start, before, after, from_xy, to_xy):
    n = killed.shape[0]
    for block in range(lo_block, hi_block):
        row = start[block]
        for first in range(block * SPAN, min(n, (block + 1) * SPAN), LOOK):
            count = min(n - first, LOOK)
            chunk = killed[first:first + count]
            dies = np.uint64(0)
            for k in range(count):  # vectorises
                dies |= np.uint64(chunk[k]) << np.uint64(k)
            while dies != 0:  # the killed only, in order
                i = first + trailing_zeros(dies)
                dies &= dies - np.uint64(1)
                from_xy[row, 0] = before[X, i]
                from_xy[row, 1] = before[Y, i]
                to_xy[row, 0] = after[X, i]
                to_xy[row, 1] = after[Y, i]
                row += 1


def killed_moves(killed: np.ndarray, sums: np.ndarray, before: np.ndarray, after: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """((K, 2), (K, 2)): where the particles that pass 1's wall check killed (``killed``, counted
    per block in ``sums``) moved from and to, in particle order (gathered on the threads: a large
    cloud's kills are too many for numpy's gather to stay out of the step's way)."""
    counts = sums["killed"]
    start = np.zeros(len(counts), dtype=np.int64)  # each block's first row
    np.cumsum(counts[:-1], out=start[1:])
    total = int(counts.sum())
    from_xy, to_xy = np.empty((total, 2)), np.empty((total, 2))
    if total:
        for_slices(_killed_kernel, len(counts), killed, start, before, after, from_xy, to_xy,
                   min_per_thread=MIN_BLOCKS_PER_THREAD)
    return from_xy, to_xy


def resample_sums(n: int) -> np.ndarray:
    """The block sums array that :func:`resample_pass` writes for ``n`` particles."""
    return np.empty(n_blocks(n), dtype=RESAMPLE_SUMS)


def run_move(function, params: np.ndarray, state: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """The state after a move kernel's move of every particle of ``state`` (serially, block by
    block), given each particle's normals (rows: the kernel's normal pairs, columns: particles)."""
    out = np.empty_like(state)
    block = np.zeros((max(normals.shape[0], 1), BLOCK))
    for lo in range(0, state.shape[1], BLOCK):
        m = min(state.shape[1], lo + BLOCK) - lo
        block[:normals.shape[0], :m] = normals[:, lo:lo + m]
        function(params, state, out, block, lo, m)
    return out


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
