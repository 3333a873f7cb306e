"""The line check: does a move a -> b touch a wall pixel of the mask? (exact grid walk)

Evennou & Marx kill a particle whose move crosses a wall by checking the pixels between its
old and new position. We check *every* pixel the segment touches with the Amanatides-Woo
voxel traversal (DDA) over continuous pixel coordinates ``(u, v)`` (see ``FloorPlan``), not
points sampled along the segment (which miss moves that only clip a pixel's corner).

Touching rule (conservative, closed pixels): the closed segment touches pixel ``(row, col)``
when it meets the *closed* square ``[col, col + 1] x [row, row + 1]``. Consequences:

- a segment through a lattice corner touches all four pixels around it, so a particle can
  never slip between two diagonal wall pixels (an 8-connected diagonal wall is closed);
- a segment lying exactly on a grid line touches the pixels on both sides of it;
- an end point exactly on a grid line touches the pixels on both sides of it.

Leaving the map counts as touching a wall. A segment with a non-finite coordinate crosses.
The walk decides which grid line comes next by comparing dist_x |dv| with dist_y |du| (no
division), which is exact for lattice-aligned coordinates, where exact corner passes happen;
the plain-Python oracle (:func:`touched_pixels_reference`, a brute-force clip of the segment
against every pixel square) agrees with it except on float ties a few ulps apart.

The filter's check (:func:`move_crosses`, behind :func:`crosses_wall`) gives the walk's answer
cheaper, from tables built once per plan (:class:`WallGrid`). First a look that reads five table
entries and takes no branch on the data (:func:`look_move`; loops of it vectorise): a move that
ends off the map or in a wall pixel touches it; one whose box of pixels (those whose closed squares
meet the segment's bounding box) holds no wall, counted from a summed-area table in four reads,
touches none. That decides most moves of a particle step (94-97 % on the bench's maps). Any other
move reads one table entry per pixel row (or column) it spans, and the walk decides the rare move
that passes within a millionth of a pixel of a pixel edge. :func:`look_two_moves` looks at two moves
to one end (a jitter from a particle and from its position before the step) in one box.
"""

from __future__ import annotations

import math
import weakref
from typing import NamedTuple

import numpy as np
from numba import njit, types

from mapfilter.maps.floorplan import FloorPlan
from mapfilter.runtime.threads import for_slices

# The walk and its kernels are compiled without numba's reference counting (_nrt=False: they
# allocate nothing, and counting every array argument in and out doubled a check's cost), with
# numpy's error model (no ZeroDivisionError branches).
# the walk records nothing in check mode; passed in (a global would be a read-only constant)
NO_BUFFER = np.empty(0, dtype=np.int64)

__all__ = [
    "WALL_GRID",
    "WallGrid",
    "crosses_wall",
    "move_crosses",
    "crosses_wall_uv",
    "LOOK",
    "crossings",
    "look_move",
    "look_two_moves",
    "clearance_px",
    "count_wall_crossings",
    "forget_clearance",
    "wall_crossing_mask",
    "touched_pixels",
    "touched_pixels_capacity",
    "touched_pixels_into",
    "touched_pixels_reference",
    "touches_wall_reference",
    "wall_grid",
]


@njit(cache=True, _nrt=False)
def _hit(mask, row, col):
    """True if pixel (row, col) is a wall or outside the map."""
    h, w = mask.shape
    if row < 0 or row >= h or col < 0 or col >= w:
        return True
    return mask[row, col]


@njit(cache=True, _nrt=False)
def _next_crossing(ix, iy, sx, sy, u0, v0, adu, adv, nx, ny):
    """Which boundary the segment meets next from pixel (iy, ix): -1 the column boundary,
    1 the row boundary, 0 both at once (a lattice corner).

    Compares t_x = dist_x / |du| with t_y = dist_y / |dv| as dist_x |dv| vs dist_y |du|
    (no division in the loop); exact for lattice-aligned (dyadic) coordinates, where the
    corner cases live.
    """
    if nx == 0:
        return 1
    if ny == 0:
        return -1
    ex = abs((ix + 1 if sx > 0 else ix) - u0) * adv
    ey = abs((iy + 1 if sy > 0 else iy) - v0) * adu
    if ex == ey:
        return 0
    return -1 if ex < ey else 1


@njit(cache=True, _nrt=False)
def _walk(mask, u0, v0, u1, v1, record, rows_out, cols_out):
    """Walk every pixel the closed segment (u0, v0)-(u1, v1) touches.

    ``record=False``: return 1 as soon as a wall/outside pixel is touched, else 0.
    ``record=True``: write every touched pixel to ``rows_out``/``cols_out`` (duplicates
    possible) and return how many were written (the mask is ignored).
    """
    if not (math.isfinite(u0) and math.isfinite(v0) and math.isfinite(u1) and math.isfinite(v1)):
        return 1 if not record else 0
    k = 0
    du = u1 - u0
    dv = v1 - v0
    ix = int(math.floor(u0))
    iy = int(math.floor(v0))
    ex = int(math.floor(u1))
    ey = int(math.floor(v1))
    sx = 1 if du > 0 else (-1 if du < 0 else 0)
    sy = 1 if dv > 0 else (-1 if dv < 0 else 0)
    nx = abs(ex - ix)
    ny = abs(ey - iy)
    # A segment lying on a vertical/horizontal grid line also touches the column/row before.
    extra_col = du == 0.0 and u0 == math.floor(u0)
    extra_row = dv == 0.0 and v0 == math.floor(v0)

    # start cell (and its grid-line neighbours, visited with the end-point rule below)
    if record:
        rows_out[k] = iy
        cols_out[k] = ix
        k += 1
    elif _hit(mask, iy, ix):
        return 1
    adu = abs(du)
    adv = abs(dv)
    while nx > 0 or ny > 0:
        order = _next_crossing(ix, iy, sx, sy, u0, v0, adu, adv, nx, ny)
        if order == 0:
            # exactly through a lattice corner: touch both diagonal neighbours, then go diagonal
            if record:
                rows_out[k] = iy
                cols_out[k] = ix + sx
                rows_out[k + 1] = iy + sy
                cols_out[k + 1] = ix
                k += 2
            elif _hit(mask, iy, ix + sx) or _hit(mask, iy + sy, ix):
                return 1
            ix += sx
            iy += sy
            nx -= 1
            ny -= 1
        elif order < 0:
            ix += sx
            nx -= 1
        else:
            iy += sy
            ny -= 1
        if record:
            rows_out[k] = iy
            cols_out[k] = ix
            k += 1
        elif _hit(mask, iy, ix):
            return 1
    # segments on a grid line: the same walk one column / row over
    if extra_col or extra_row:
        lo_r = min(iy, int(math.floor(v0)))
        hi_r = max(iy, int(math.floor(v0)))
        lo_c = min(ix, int(math.floor(u0)))
        hi_c = max(ix, int(math.floor(u0)))
        if extra_col:
            for r in range(lo_r, hi_r + 1):
                if record:
                    rows_out[k] = r
                    cols_out[k] = ix - 1
                    k += 1
                elif _hit(mask, r, ix - 1):
                    return 1
        if extra_row:
            for c in range(lo_c, hi_c + 1):
                if record:
                    rows_out[k] = iy - 1
                    cols_out[k] = c
                    k += 1
                elif _hit(mask, iy - 1, c):
                    return 1
    # end points on grid lines touch the pixels on the other side of the line too
    for e in range(2):
        pu = u0 if e == 0 else u1
        pv = v0 if e == 0 else v1
        cu = int(math.floor(pu))
        cv = int(math.floor(pv))
        on_u = pu == cu
        on_v = pv == cv
        if on_u or on_v:
            for dc in range(-1 if on_u else 0, 1):
                for dr in range(-1 if on_v else 0, 1):
                    if record:
                        rows_out[k] = cv + dr
                        cols_out[k] = cu + dc
                        k += 1
                    elif _hit(mask, cv + dr, cu + dc):
                        return 1
    return k if record else 0


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _crosses_uv_kernel(lo, hi, mask, u0, v0, u1, v1, out, no_buffer):
    for i in range(lo, hi):
        out[i] = _walk(mask, u0[i], v0[i], u1[i], v1[i], False, no_buffer, no_buffer) == 1


class WallGrid(NamedTuple):
    """A plan's walls as the numba checks take them (:func:`wall_grid`; the filter's passes, the
    smoother and :func:`crosses_wall`)."""

    mask: np.ndarray  # (H, W) bool, True = wall
    clearance_px: np.ndarray  # (H, W) float32: a move starting in the pixel and shorter than this touches no wall (the simulator's)
    wall_ahead_in_row: np.ndarray  # (H, W) uint16: columns from pixel (r, c) to the first wall at or after it in row r
    wall_ahead_in_column: np.ndarray  # (W, H) uint16: the same down column c (the transposed mask's table)
    is_wall: np.ndarray  # (H * W,) uint32: the mask row by row, 1 = wall (the vectorised looks gather 32-bit words)
    wall_sums: np.ndarray  # ((H + 3) * (W + 3),) uint32: wall pixels above-left of each corner of the mask padded with a ring of wall
    x0_m: float  # world position of the mask's lower-left corner
    y0_m: float
    inv_resolution: float  # pixels per metre
    no_buffer: np.ndarray  # the recording walk's buffer, unused in check mode (a global would be read-only)


WALL_GRID = types.NamedTuple((types.boolean[:, ::1], types.float32[:, ::1], types.uint16[:, ::1],
                              types.uint16[:, ::1], types.uint32[::1], types.uint32[::1], types.float64, types.float64, types.float64,
                              types.int64[::1]), WallGrid)

_AHEAD_MAX = 65535  # uint16: a run this long or longer is left to the exact walk
# The band check's margin in pixels: far above the rounding of the u (or v) it computes where the
# segment meets a band's edge (a few ulps of coordinates below 10^6 px: < 1e-9 px), far below a pixel
_EDGE_PX = 1e-6


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _bands(ahead, n_lines, n_across, p0, q0, p1, q1):
    """Does the closed segment (p0, q0)-(p1, q1) touch a wall pixel? Line by line along q: pixel
    line r (the band r <= q <= r + 1) is touched over the closed run of pixels whose squares meet the
    piece of the segment inside the band, and ``ahead[r, first]`` says whether a wall lies in that
    run. Called with q the axis the segment advances less along (fewest lines).

    Returns 1 (touches), 0 (does not) or 2: a run's end lies within ``_EDGE_PX`` of a pixel edge,
    where the rounding of the computed end could decide (the exact walk decides then)."""
    q_lo = min(q0, q1)
    q_hi = max(q0, q1)
    p_lo = min(p0, p1)
    p_hi = max(p0, p1)
    # the outside of the map: exact, from the end points' own coordinates
    if q_lo <= 0.0 or q_hi >= n_lines or p_lo <= 0.0 or p_hi >= n_across:
        return 1
    if p_lo <= _EDGE_PX or p_hi >= n_across - _EDGE_PX or p_hi - p_lo + 2.0 >= _AHEAD_MAX:
        return 2  # a run's widened end outside the map, or a run longer than the table counts
    if q1 < q0:
        p0, q0, p1, q1 = p1, q1, p0, q0
    undecided = False
    r_first = int(math.ceil(q0)) - 1
    r_last = int(math.floor(q1))
    if q1 == q0:  # along the lines: the same run on the one or two lines it touches
        first = int(math.ceil(p_lo - _EDGE_PX)) - 1
        last = int(math.floor(p_hi + _EDGE_PX))
        for r in range(r_first, r_last + 1):
            if ahead[np.uintp(r), np.uintp(first)] <= last - first:
                first_sure = int(math.ceil(p_lo + _EDGE_PX)) - 1
                last_sure = int(math.floor(p_hi - _EDGE_PX))
                if first_sure <= last_sure and ahead[np.uintp(r), np.uintp(first_sure)] <= last_sure - first_sure:
                    return 1
                undecided = True
        return 2 if undecided else 0
    slope = (p1 - p0) / (q1 - q0)
    if not math.isfinite(slope):
        return 2  # a minor axis so short that the slope overflows
    # the piece in band r runs from p at q = max(r, q0) to p at min(r + 1, q1): the end points' own
    # p at the ends, computed (rounded) in between
    pa = p0
    for r in range(r_first, r_last + 1):
        edge = r + 1.0
        pb = p1 if edge >= q1 else p0 + (edge - q0) * slope
        lo = min(pa, pb)
        hi = max(pa, pb)
        # pixel c's closed square meets [lo, hi] when c <= hi and c + 1 >= lo; widened by the margin
        first = int(math.ceil(lo - _EDGE_PX)) - 1
        last = int(math.floor(hi + _EDGE_PX))
        # r and first are >= 0 here (the outside was ruled out above): unsigned, numba adds no wrap-around
        if ahead[np.uintp(r), np.uintp(first)] <= last - first:
            # a wall in the widened run; in the narrowed one too, or only within the margins?
            first_sure = int(math.ceil(lo + _EDGE_PX)) - 1
            last_sure = int(math.floor(hi - _EDGE_PX))
            if first_sure <= last_sure and ahead[np.uintp(r), np.uintp(first_sure)] <= last_sure - first_sure:
                return 1
            undecided = True
        pa = pb
    return 2 if undecided else 0


LOOK = 64  # moves looked at in one loop (:func:`look_move`): one bit each in a 64-bit word


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _pixel_uv(walls, x, y):
    """World metres to the mask's continuous pixel coordinates (u right, v down)."""
    return (x - walls.x0_m) * walls.inv_resolution, walls.mask.shape[0] - (y - walls.y0_m) * walls.inv_resolution


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _clamped(x, lo, hi):
    """x within [lo, hi] (NaN: lo), without a branch."""
    x = x if x > lo else lo
    return x if x < hi else hi


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _box_is_free(walls, u_min, u_max, v_min, v_max):
    """No wall pixel (nor the outside) among the pixels whose closed squares meet the box [u_min, u_max]
    x [v_min, v_max] (columns ceil(u_min) - 1 .. floor(u_max), the same for rows): four reads of
    ``wall_sums``, each inside the table whatever the coordinates, and no branch."""
    h, w = walls.mask.shape
    # unsigned indices: numba adds no wrap-around of negative ones, which kept the loads from vectorising
    width = np.uintp(w) + np.uintp(3)
    # the box in the padded table's pixels (the ring of wall round the mask at -1 and w, h)
    col_lo = np.uintp(_clamped(np.ceil(u_min), 0.0, w + 1.0))  # ceil(u_min) - 1 + 1
    col_hi = np.uintp(_clamped(np.floor(u_max), -1.0, w + 0.0) + 2.0)  # past floor(u_max) + 1
    row_lo = np.uintp(_clamped(np.ceil(v_min), 0.0, h + 1.0)) * width
    row_hi = np.uintp(_clamped(np.floor(v_max), -1.0, h + 0.0) + 2.0) * width
    sums = walls.wall_sums
    # the wall pixels in the box, modulo 2^32 (the table's sums wrap; a box holds fewer pixels)
    return np.uint32(sums[row_hi + col_hi] - sums[row_lo + col_hi] - sums[row_hi + col_lo] + sums[row_lo + col_lo]) == 0


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _in_wall(walls, u, v):
    """Is the point (u, v) off the map or in a wall pixel? One read, inside the table whatever (u, v) is."""
    h, w = walls.mask.shape
    inside = (u >= 0.0) & (u < w) & (v >= 0.0) & (v < h)
    index = np.uintp(_clamped(v, 0.0, h - 1.0)) * np.uintp(w) + np.uintp(_clamped(u, 0.0, w - 1.0))
    return (not inside) | (walls.is_wall[index] != 0)


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _box(walls, u_min, u_max, v_min, v_max, u_end, v_end, finite):
    """(free, wall) for segments that end at (u_end, v_end) and lie in the box [u_min, u_max] x [v_min,
    v_max], from five table reads and no branch: wall when a coordinate is not ``finite`` or the end is
    off the map or in a wall pixel; free when the box holds no wall (:func:`_box_is_free`); neither:
    undecided (:func:`_decide`). A loop of these vectorises (gathers)."""
    wall = (not finite) | _in_wall(walls, u_end, v_end)
    return _box_is_free(walls, u_min, u_max, v_min, v_max) & (not wall), wall


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _look(walls, u0, v0, u1, v1):
    """:func:`_box` of the segment (u0, v0)-(u1, v1): (free, wall)."""
    du = u1 - u0
    dv = v1 - v0
    return _box(walls, min(u0, u1), max(u0, u1), min(v0, v1), max(v0, v1), u1, v1,
                du * du + dv * dv < math.inf)  # not finite when a coordinate is not


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _decide(walls, u0, v0, u1, v1):
    """Does a segment that :func:`_look` left undecided touch a wall? One table read per pixel row (or
    column) it spans (:func:`_bands`), and the exact walk when it passes within ``_EDGE_PX`` of a pixel
    edge."""
    mask = walls.mask
    h, w = mask.shape
    if abs(v1 - v0) <= abs(u1 - u0):
        found = _bands(walls.wall_ahead_in_row, h, w, u0, v0, u1, v1)
    else:
        found = _bands(walls.wall_ahead_in_column, w, h, v0, u0, v1, u1)
    if found == 2:
        return _walk(mask, u0, v0, u1, v1, False, walls.no_buffer, walls.no_buffer) == 1
    return found == 1


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def move_crosses(walls, ax, ay, bx, by):
    """Does the move (ax, ay) -> (bx, by) in world metres touch a wall pixel or leave the map? The
    filter's wall check for one move (the smoother's; the passes and :func:`crosses_wall` take a batch
    of moves: :func:`look_move`, :func:`crossings`), with the same answer as the exact walk of every pixel
    the segment touches (the module's touching rule).

    A move that ends in a wall pixel or off the map touches it; one whose box of pixels holds no wall
    does not (:func:`_look`: a few table reads decide most moves); any other is checked band by band
    along its minor axis (one table read per pixel row or column it spans: :func:`_bands`), and the
    rare move that passes within ``_EDGE_PX`` of a pixel edge is walked pixel by pixel
    (:func:`_decide`)."""
    u0, v0 = _pixel_uv(walls, ax, ay)
    u1, v1 = _pixel_uv(walls, bx, by)
    free, wall = _look(walls, u0, v0, u1, v1)
    if free or wall:
        return wall
    return _decide(walls, u0, v0, u1, v1)


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def look_move(walls, ax, ay, bx, by):
    """(free, wall) of the move (ax, ay) -> (bx, by) in world metres from a few table reads and no branch
    (:func:`_look`): free, it surely touches no wall; wall, it surely does; neither, ask
    :func:`move_crosses`. A loop of these that writes no memory vectorises (the passes gather 64 moves'
    answers into the bits of a word)."""
    u0, v0 = _pixel_uv(walls, ax, ay)
    u1, v1 = _pixel_uv(walls, bx, by)
    return _look(walls, u0, v0, u1, v1)


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def look_two_moves(walls, ax, ay, bx, by, cx, cy):
    """(free, wall) as :func:`look_move` gives them, for the two moves a -> c and b -> c: free when neither
    touches a wall, wall when c is in a wall pixel or off the map (or a coordinate is not finite), from
    the box of the three points: one look for two moves that share an end and lie near each other (a
    jitter from a particle and from its position before the step); neither: check each move."""
    ua, va = _pixel_uv(walls, ax, ay)
    ub, vb = _pixel_uv(walls, bx, by)
    uc, vc = _pixel_uv(walls, cx, cy)
    finite = abs(ua) + abs(va) + abs(ub) + abs(vb) + abs(uc) + abs(vc) < math.inf
    return _box(walls, min(ua, ub, uc), max(ua, ub, uc), min(va, vb, vc), max(va, vb, vc), uc, vc, finite)


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def crossings(walls, ax, ay, bx, by, m, out):
    """``out[k]`` = :func:`move_crosses` of the move (ax[k], ay[k]) -> (bx[k], by[k]), k < m: the look at
    LOOK moves at a time (:func:`look_move`, which decides most of them, in a loop that vectorises), then
    the rest one by one. Written out over a batch: numba passes each array of ``walls`` as several
    words, and a mispredicted branch per move cost more than the look."""
    for lo in range(0, m, LOOK):
        count = min(m - lo, LOOK)
        free_bits = np.uint64(0)
        wall_bits = np.uint64(0)
        # views of the chunk: indices that start at 0 make contiguous loads (first + k could be negative)
        xa, ya, xb, yb = ax[lo:lo + count], ay[lo:lo + count], bx[lo:lo + count], by[lo:lo + count]
        for k in range(count):  # no memory written: this loop vectorises
            free, wall = look_move(walls, xa[k], ya[k], xb[k], yb[k])
            free_bits |= np.uint64(free) << np.uint64(k)
            wall_bits |= np.uint64(wall) << np.uint64(k)
        for k in range(count):
            hit = (wall_bits >> np.uint64(k)) & np.uint64(1) != 0
            if ((free_bits | wall_bits) >> np.uint64(k)) & np.uint64(1) == 0:
                hit = move_crosses(walls, ax[lo + k], ay[lo + k], bx[lo + k], by[lo + k])
            out[lo + k] = hit


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _crosses_world_kernel(lo, hi, walls, ax, ay, bx, by, out):
    crossings(walls, ax[lo:hi], ay[lo:hi], bx[lo:hi], by[lo:hi], hi - lo, out[lo:hi])


_GRIDS: "weakref.WeakKeyDictionary[FloorPlan, tuple[np.ndarray, WallGrid]]" = weakref.WeakKeyDictionary()


def _clearance_table(wall_mask: np.ndarray) -> np.ndarray:
    """(H, W) float32: the distance in pixels from any point of each pixel to the nearest wall pixel
    (the outside of the map counts as wall), less a margin.

    Why a move shorter than this touches no wall: a move of length L starts at a point p of pixel
    P (the closed unit square of column c, row r), so each of its points q lies within L of p. Every
    point of P is at least d(P, Q) = sqrt(max(|c' - c| - 1, 0)^2 + max(|r' - r| - 1, 0)^2) from
    wall pixel Q (column c', row r': the gaps between two unit squares along each axis), so
    dist(q, Q) >= d(P, Q) - L > 0 when L < d(P, Q): no point of the move lies in a wall pixel.
    The smallest d(P, Q) over the walls is the Euclidean distance between pixel centres to the
    walls dilated by one pixel in all 8 directions (Q + e, e in {-1, 0, 1}^2, nearest at
    e = sign(Q - P) per axis, makes each axis' |d| into max(|d| - 1, 0)). A one-pixel ring of
    wall around the mask stands for the outside: the nearest outside pixel is in that ring.
    """
    import cv2  # OpenCV's exact Euclidean transform (Felzenszwalb): scipy.ndimage takes 0.3 s to import

    padded = np.pad(wall_mask, 1, constant_values=True).astype(np.uint8)
    dilated = cv2.dilate(padded, np.ones((3, 3), np.uint8))
    distance = cv2.distanceTransform(1 - dilated, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[1:-1, 1:-1]
    # float32 rounding of sqrt(integer) must not make the bound optimistic: shave a little off
    return np.maximum(distance - np.float32(1e-3), np.float32(0.0)).astype(np.float32)


def _wall_ahead(wall_mask: np.ndarray) -> np.ndarray:
    """(H, W) uint16: per pixel, how many columns on to the first wall at or after it in its row
    (the column past the map's right edge counts as wall), capped at ``_AHEAD_MAX``."""
    h, w = wall_mask.shape
    column = np.arange(w, dtype=np.int64)
    next_wall = np.where(wall_mask, column[None, :], w)
    next_wall = np.minimum.accumulate(next_wall[:, ::-1], axis=1)[:, ::-1]
    return np.ascontiguousarray(np.minimum(next_wall - column[None, :], _AHEAD_MAX).astype(np.uint16))


def _wall_sums(wall_mask: np.ndarray) -> np.ndarray:
    """((H + 3) * (W + 3),) uint32, row by row: entry (r, c) counts the wall pixels in rows < r and columns < c of the mask
    padded with a ring of wall (the outside), modulo 2^32; the count in a box is four reads (a summed-area
    table), exact as long as the box holds fewer than 2^32 pixels."""
    padded = np.pad(wall_mask, 1, constant_values=True)
    sums = np.zeros((padded.shape[0] + 1, padded.shape[1] + 1), dtype=np.uint32)
    np.cumsum(np.cumsum(padded, axis=0, dtype=np.uint32), axis=1, dtype=np.uint32, out=sums[1:, 1:])
    return sums.ravel()


def wall_grid(floorplan: FloorPlan) -> WallGrid:
    """The plan's :class:`WallGrid`, built once per FloorPlan (and mask object): after editing a mask
    *in place*, call :func:`forget_clearance` (a new mask array or a new FloorPlan is picked up by
    itself)."""
    cached = _GRIDS.get(floorplan)
    if cached is not None and cached[0] is floorplan.wall_mask:
        return cached[1]
    mask = np.ascontiguousarray(floorplan.wall_mask, dtype=np.bool_)
    grid = WallGrid(mask, _clearance_table(mask), _wall_ahead(mask), _wall_ahead(np.ascontiguousarray(mask.T)),
                    mask.astype(np.uint32).ravel(), _wall_sums(mask), float(floorplan.origin_m[0]), float(floorplan.origin_m[1]), 1.0 / float(floorplan.resolution_m),
                    NO_BUFFER)
    _GRIDS[floorplan] = (floorplan.wall_mask, grid)
    return grid


def clearance_px(floorplan: FloorPlan) -> np.ndarray:
    """(H, W) float32: a segment starting in pixel (r, c) and shorter than this touches no wall (the
    proof: :func:`_clearance_table`). Part of the plan's :func:`wall_grid`."""
    return wall_grid(floorplan).clearance_px


def forget_clearance(floorplan: FloorPlan) -> None:
    """Drop the cached wall grid of ``floorplan`` (needed only after editing its mask in place)."""
    _GRIDS.pop(floorplan, None)


def crosses_wall_uv(wall_mask: np.ndarray, from_uv_px: np.ndarray, to_uv_px: np.ndarray) -> np.ndarray:
    """Per segment in continuous pixel coordinates: does it touch a wall pixel or leave the mask?

    Parameters
    ----------
    wall_mask : (H, W) bool, True = wall.
    from_uv_px, to_uv_px : (N, 2) float, ``(u, v)`` = (column, row) continuous coordinates.

    Returns
    -------
    (N,) bool
    """
    a = np.ascontiguousarray(from_uv_px, dtype=np.float64).reshape(-1, 2)
    b = np.ascontiguousarray(to_uv_px, dtype=np.float64).reshape(-1, 2)
    if a.shape != b.shape:
        raise ValueError(f"from and to must have the same shape, got {a.shape} and {b.shape}")
    out = np.empty(a.shape[0], dtype=np.bool_)
    for_slices(_crosses_uv_kernel, a.shape[0], np.ascontiguousarray(wall_mask, dtype=np.bool_),
               a[:, 0].copy(), a[:, 1].copy(), b[:, 0].copy(), b[:, 1].copy(), out, NO_BUFFER)
    return out


def crosses_wall(floorplan: FloorPlan, from_xy_m: np.ndarray, to_xy_m: np.ndarray) -> np.ndarray:
    """Per move: does the straight segment from ``from_xy_m`` to ``to_xy_m`` touch a wall?

    Leaving the map counts as crossing; so does a non-finite coordinate. A move that starts
    or ends inside a wall pixel crosses (its end pixels are touched).

    Parameters
    ----------
    floorplan : the map.
    from_xy_m, to_xy_m : (N, 2) world positions in metres.

    Returns
    -------
    (N,) bool, True = the move touches a wall pixel (closed-pixel rule, module docstring).

    Examples
    --------
    >>> import numpy as np
    >>> mask = np.zeros((5, 5), bool); mask[:, 2] = True      # a wall column at x in [2, 3) m
    >>> fp = FloorPlan(mask, 1.0)
    >>> crosses_wall(fp, np.array([[0.5, 0.5], [0.5, 0.5]]), np.array([[1.5, 4.5], [3.5, 0.5]]))
    array([False,  True])
    """
    a = np.ascontiguousarray(from_xy_m, dtype=np.float64).reshape(-1, 2)
    b = np.ascontiguousarray(to_xy_m, dtype=np.float64).reshape(-1, 2)
    if a.shape != b.shape:
        raise ValueError(f"from and to must have the same shape, got {a.shape} and {b.shape}")
    out = np.empty(a.shape[0], dtype=np.bool_)
    for_slices(_crosses_world_kernel, a.shape[0], wall_grid(floorplan), a[:, 0].copy(), a[:, 1].copy(),
               b[:, 0].copy(), b[:, 1].copy(), out)
    return out


def wall_crossing_mask(floorplan: FloorPlan, track_xy_m: np.ndarray) -> np.ndarray:
    """(T-1,) bool: which consecutive moves of a track touch a wall (non-finite rows skipped)."""
    xy = np.asarray(track_xy_m, dtype=np.float64).reshape(-1, 2)
    xy = xy[np.isfinite(xy).all(axis=1)]
    if xy.shape[0] < 2:
        return np.zeros(0, dtype=bool)
    return crosses_wall(floorplan, xy[:-1], xy[1:])


def count_wall_crossings(floorplan: FloorPlan, track_xy_m: np.ndarray) -> int:
    """Number of consecutive moves of a track (T, 2) that touch a wall pixel or leave the map.

    Rows with a non-finite coordinate (no estimate) are dropped first.
    """
    return int(np.count_nonzero(wall_crossing_mask(floorplan, track_xy_m)))


_NO_MASK = np.zeros((1, 1), dtype=np.bool_)  # the recording walk ignores the mask


@njit(cache=True)
def touched_pixels_capacity(u0, v0, u1, v1):
    """Buffer length that :func:`touched_pixels_into` never overruns for this segment (0 if non-finite).

    The walk writes 1 start pixel, 1 per grid line crossed and 3 per lattice corner (which
    uses up 2 crossings), so at most 1.5 per crossing; a segment lying on a grid line adds one
    row/column per crossing (+1), and each end point on grid lines at most 4 more.
    """
    if not (math.isfinite(u0) and math.isfinite(v0) and math.isfinite(u1) and math.isfinite(v1)):
        return 0
    n_crossings = abs(int(math.floor(u1)) - int(math.floor(u0))) + abs(int(math.floor(v1)) - int(math.floor(v0)))
    return 2 * n_crossings + 16


@njit(cache=True)
def touched_pixels_into(u0, v0, u1, v1, rows_out, cols_out):
    """Record every pixel the closed segment (u0, v0)-(u1, v1) touches; returns how many.

    The same walk and touching rule as :func:`crosses_wall` (module docstring): a pass
    exactly through a lattice corner touches all four pixels there. ``rows_out``/``cols_out``
    (int64) need :func:`touched_pixels_capacity` entries. A non-finite coordinate records
    nothing (returns 0). Duplicates are possible.

    Order: first the walk from the start pixel ``(floor(v0), floor(u0))`` to the end pixel
    ``(floor(v1), floor(u1))``, each pixel once, consecutive pixels sharing an edge, except
    at a lattice corner, where the two side pixels (diagonal to each other) come between the
    pixel before the corner and the diagonal pixel after it; then the extra pixels of the
    closed rule (the far side of a grid line the segment lies on or ends on), in no
    particular order.
    """
    return _walk(_NO_MASK, u0, v0, u1, v1, True, rows_out, cols_out)


def touched_pixels(from_uv_px, to_uv_px) -> set[tuple[int, int]]:
    """The set of (row, col) pixels the numba walk touches for one segment (for tests/debug)."""
    u0, v0 = float(from_uv_px[0]), float(from_uv_px[1])
    u1, v1 = float(to_uv_px[0]), float(to_uv_px[1])
    cap = touched_pixels_capacity(u0, v0, u1, v1)
    rows = np.empty(cap, dtype=np.int64)
    cols = np.empty(cap, dtype=np.int64)
    k = touched_pixels_into(u0, v0, u1, v1, rows, cols)
    return set(zip(rows[:k].tolist(), cols[:k].tolist()))


def touched_pixels_reference(from_uv_px, to_uv_px) -> set[tuple[int, int]]:
    """Plain-Python oracle: every (row, col) whose closed square the closed segment meets.

    Brute force over the segment's bounding box with a Liang-Barsky clip of the segment
    against each closed pixel square; no grid walk. Slow; for tests only.
    """
    u0, v0 = float(from_uv_px[0]), float(from_uv_px[1])
    u1, v1 = float(to_uv_px[0]), float(to_uv_px[1])
    du, dv = u1 - u0, v1 - v0
    touched = set()
    for col in range(math.floor(min(u0, u1)) - 1, math.floor(max(u0, u1)) + 2):
        for row in range(math.floor(min(v0, v1)) - 1, math.floor(max(v0, v1)) + 2):
            if _segment_meets_square(u0, v0, du, dv, col, row):
                touched.add((row, col))
    return touched


def _segment_meets_square(u0, v0, du, dv, col, row) -> bool:
    t_lo, t_hi = 0.0, 1.0
    for p0, dp, lo in ((u0, du, col), (v0, dv, row)):
        if dp == 0.0:
            if p0 < lo or p0 > lo + 1:
                return False
            continue
        ta = (lo - p0) / dp
        tb = (lo + 1 - p0) / dp
        t_enter, t_exit = (ta, tb) if ta <= tb else (tb, ta)
        t_lo = max(t_lo, t_enter)
        t_hi = min(t_hi, t_exit)
        if t_lo > t_hi:
            return False
    return True


def touches_wall_reference(floorplan: FloorPlan, from_xy_m: np.ndarray, to_xy_m: np.ndarray) -> np.ndarray:
    """Plain-Python oracle of the wall check, per move: whether it touches a wall pixel or leaves
    the map (every pixel square the segment meets, :func:`touched_pixels_reference`). Slow; the
    reference step's (``filter.reference``) and the tests'."""
    rows, cols = floorplan.wall_mask.shape
    from_uv, to_uv = floorplan.world_to_pixel(from_xy_m), floorplan.world_to_pixel(to_xy_m)
    out = np.zeros(len(from_uv), dtype=bool)
    for i in range(len(from_uv)):
        out[i] = any(not (0 <= row < rows and 0 <= col < cols) or floorplan.wall_mask[row, col]
                     for row, col in touched_pixels_reference(from_uv[i], to_uv[i]))
    return out
