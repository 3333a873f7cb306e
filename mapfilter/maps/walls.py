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
against every pixel square) agrees with it except on float ties a few ulps apart. The numba
check also skips pieces of a move that the clearance map proves wall free (``clearance_px``).
"""

from __future__ import annotations

import math
import weakref

import numpy as np
from numba import njit

from mapfilter.maps.floorplan import FloorPlan
from mapfilter.runtime.threads import for_slices

# The walk and its kernels are compiled without numba's reference counting (_nrt=False:
# they allocate nothing). With it, every call counted its array arguments in and out with
# atomic operations: the 100k-segment check took 6.7 ms of CPU instead of 3.5. (IR-level
# inline="always" hid that cost before, at 10 s of compile time on a fresh install.) The
# kernels use numpy's error model (no ZeroDivisionError branches), as prange loops did.
# the walk records nothing in check mode; passed in (a global would be a read-only constant)
NO_BUFFER = np.empty(0, dtype=np.int64)

__all__ = [
    "crosses_wall",
    "move_crosses",
    "crosses_wall_uv",
    "clearance_px",
    "count_wall_crossings",
    "forget_clearance",
    "wall_crossing_mask",
    "touched_pixels",
    "touched_pixels_capacity",
    "touched_pixels_into",
    "touched_pixels_reference",
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


_MIN_JUMP_PX = 2.0  # jump ahead on the clearance map only when it skips at least this much


@njit(cache=True, _nrt=False)
def _walk_until_clear(mask, clearance_px, u0, v0, u1, v1):
    """The check-mode walk of a segment with du != 0 and dv != 0 that stops on entering a
    pixel whose clearance is at least ``_MIN_JUMP_PX`` (not the end pixel).

    Returns (1, t, 0) on touching a wall, (0, 1, 0) on reaching the end without, or
    (2, t, c): stopped where the segment enters a clear pixel at parameter t, clearance c.
    Same touching rule as ``_walk`` (corners, end points on grid lines).
    """
    du = u1 - u0
    dv = v1 - v0
    ix = int(math.floor(u0))
    iy = int(math.floor(v0))
    sx = 1 if du > 0 else -1
    sy = 1 if dv > 0 else -1
    nx = abs(int(math.floor(u1)) - ix)
    ny = abs(int(math.floor(v1)) - iy)
    if _hit(mask, iy, ix):
        return 1, 0.0, 0.0
    for e in range(2):
        pu = u0 if e == 0 else u1
        pv = v0 if e == 0 else v1
        cu = int(math.floor(pu))
        cv = int(math.floor(pv))
        if pu == cu or pv == cv:
            for dc in range(-1 if pu == cu else 0, 1):
                for dr in range(-1 if pv == cv else 0, 1):
                    if _hit(mask, cv + dr, cu + dc):
                        return 1, 0.0, 0.0
    adu = abs(du)
    adv = abs(dv)
    while nx > 0 or ny > 0:
        order = _next_crossing(ix, iy, sx, sy, u0, v0, adu, adv, nx, ny)
        if order == 0:
            if _hit(mask, iy, ix + sx) or _hit(mask, iy + sy, ix):
                return 1, 0.0, 0.0
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
        if _hit(mask, iy, ix):
            return 1, 0.0, 0.0
        if nx > 0 or ny > 0:
            c = clearance_px[iy, ix]
            if c >= _MIN_JUMP_PX:
                # parameter where the segment entered this pixel (the boundary just crossed)
                if order <= 0:
                    t_enter = abs((ix if sx > 0 else ix + 1) - u0) / adu
                else:
                    t_enter = abs((iy if sy > 0 else iy + 1) - v0) / adv
                return 2, t_enter, c
    return 0, 1.0, 0.0


@njit(cache=True, _nrt=False)
def _segment_crosses_world(mask, clearance_px, x0_m, y0_m, inv_resolution, ax, ay, bx, by, no_buffer):
    """One move in world metres: does it touch a wall pixel (exact walk, clearance jumps)?"""
    h, w = mask.shape
    # world -> continuous pixel coordinates, as FloorPlan.world_to_pixel
    u0 = (ax - x0_m) * inv_resolution
    v0 = h - (ay - y0_m) * inv_resolution
    u1 = (bx - x0_m) * inv_resolution
    v1 = h - (by - y0_m) * inv_resolution
    if not (math.isfinite(u0) and math.isfinite(v0) and math.isfinite(u1) and math.isfinite(v1)):
        return True
    du = u1 - u0
    dv = v1 - v0
    length = math.sqrt(du * du + dv * dv)
    if du == 0.0 or dv == 0.0:
        # axis-aligned (measure zero for particles): the plain walk handles grid-line cases
        pass
    else:
        # "Sphere tracing" on the clearance map: a piece of the segment shorter than the
        # clearance of the pixel it starts in touches no wall, so it is skipped; the pieces in
        # between are walked exactly until they enter a clear pixel again. Splitting a segment
        # does not change the set of pixels it touches (a pixel is touched by a point of it).
        t = 0.0
        while True:
            pu = u0 + t * du
            pv = v0 + t * dv
            c = 0.0
            if 0.0 <= pu < w and 0.0 <= pv < h:
                c = clearance_px[int(pv), int(pu)]
            remaining = (1.0 - t) * length
            if c > 0.0 and remaining < c:
                return False
            if c >= _MIN_JUMP_PX:
                t += 0.999 * c / length  # a jump strictly shorter than the clearance
                continue
            status, s, c_stop = _walk_until_clear(mask, clearance_px, pu, pv, u1, v1)
            if status != 2:
                return status == 1
            t_entry = t + s * (1.0 - t)
            if (1.0 - t_entry) * length < c_stop:
                return False
            t = t_entry + 0.999 * c_stop / length
    return _walk(mask, u0, v0, u1, v1, False, no_buffer, no_buffer) == 1


_MARCH_STEPS = 12  # clearance steps from each end before the exact walk
_MIN_MARCH_PX = 0.5  # fronts whose clearance is below this stop the march


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def move_crosses(mask, clearance, x0_m, y0_m, inv_res, ax, ay, bx, by, no_buffer):
    """Does the move (ax, ay) -> (bx, by) in world metres touch a wall pixel? The filter's wall
    check (its passes and the smoother).

    First whether it ends in a wall or off the map, then the clearance of the pixels at its
    ends (a segment shorter than the sum of the clearances of its end pixels touches no wall:
    the two discs cover it), a march along the clearance from both ends ("sphere tracing"), a
    look at the pixel under the middle of what is left, and the exact walk of that piece.
    Callers in a hot loop test the start pixel's clearance themselves first (most moves end
    there; written out in the loop, that test costs a fifth of a call).

    The same answer as :func:`crosses_wall` except for a move through a lattice corner exactly
    (the pieces are split at float points): measure zero for particles, whose positions are
    continuous; :func:`crosses_wall` is exact."""
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
    if length > 0.0 and math.isfinite(length):
        step = 0.999 / length
        t_lo = c_start * step
        t_hi = 1.0 - c_end * step
        if t_lo >= t_hi:
            return False
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


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _crosses_world_kernel(lo, hi, mask, clearance_px, x0_m, y0_m, resolution_m, from_xy_m, to_xy_m, out, no_buffer):
    inv = 1.0 / resolution_m
    for i in range(lo, hi):
        out[i] = _segment_crosses_world(mask, clearance_px, x0_m, y0_m, inv, from_xy_m[i, 0], from_xy_m[i, 1],
                                        to_xy_m[i, 0], to_xy_m[i, 1], no_buffer)


_CLEARANCE_CACHE: "weakref.WeakKeyDictionary[FloorPlan, tuple[np.ndarray, np.ndarray]]" = weakref.WeakKeyDictionary()


def clearance_px(floorplan: FloorPlan) -> np.ndarray:
    """(H, W) float32: a segment starting in pixel (r, c) and shorter than this touches no wall.

    With D = distance from the pixel's centre to the nearest wall pixel's centre (the map's
    outside counts as wall), any point q of a segment of length L from p reaches at most
    |centre - q| <= L + sqrt(2)/2, and touching a wall pixel needs |q - wall centre| <=
    sqrt(2)/2; so L < D - sqrt(2) cannot touch one. Cached per FloorPlan (and mask object):
    after editing a mask *in place*, call :func:`forget_clearance` (a new mask array or a new
    FloorPlan is picked up by itself).
    """
    cached = _CLEARANCE_CACHE.get(floorplan)
    if cached is not None and cached[0] is floorplan.wall_mask:
        return cached[1]
    import cv2  # OpenCV's exact Euclidean transform (Felzenszwalb): scipy.ndimage takes 0.3 s to import

    padded = np.pad(floorplan.wall_mask, 1, constant_values=True)
    distance = cv2.distanceTransform((~padded).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[1:-1, 1:-1]
    clearance = np.maximum(distance - math.sqrt(2.0), 0.0).astype(np.float32)
    # float32 rounding must not make the bound optimistic: shave a little off
    clearance = np.maximum(clearance - np.float32(1e-3), np.float32(0.0))
    _CLEARANCE_CACHE[floorplan] = (floorplan.wall_mask, clearance)
    return clearance


def forget_clearance(floorplan: FloorPlan) -> None:
    """Drop the cached clearance map of ``floorplan`` (needed only after editing its mask in place)."""
    _CLEARANCE_CACHE.pop(floorplan, None)


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
    for_slices(_crosses_world_kernel, a.shape[0], floorplan.wall_mask, clearance_px(floorplan),
               floorplan.origin_m[0], floorplan.origin_m[1], floorplan.resolution_m, a, b, out, NO_BUFFER)
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

