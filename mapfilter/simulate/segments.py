"""Segments against a wall mask, for the simulator: clearance along a segment and the walls it crosses.

Exact pixel walks (numba) with the filter's own rule for which pixels a segment touches
(``mapfilter.maps.walls.touched_pixels_into``): a route planned with them never crosses a
wall by the filter's check, and the multi-wall path-loss model counts the same walls.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import touched_pixels_capacity, touched_pixels_into


@njit(cache=True)
def _touched(u0, v0, u1, v1, rows, cols):
    """The segment's pixels (walls.touched_pixels_into) in ``rows``/``cols``, which are replaced
    by buffers twice as long when too short: returns (rows, cols, count)."""
    cap = touched_pixels_capacity(u0, v0, u1, v1)
    if rows.shape[0] < cap:
        rows = np.empty(2 * cap, dtype=np.int64)
        cols = np.empty(2 * cap, dtype=np.int64)
    return rows, cols, touched_pixels_into(u0, v0, u1, v1, rows, cols)


@njit(cache=True)
def _segments_min_clearance_px(clearance_px, uv0, uv1):
    """Per segment, the smallest ``clearance_px`` over every pixel it touches.

    The pixels are those of the filter's own wall check (``touched_pixels_into``, closed
    pixels: a pass exactly through a lattice corner touches all four pixels there, so a move
    that only clips a wall corner is caught). Outside the mask counts as 0 (wall); so does a
    segment with a non-finite coordinate.
    """
    # serial on purpose: the planner calls this with a few dozen segments at a time, where a
    # parallel launch costs milliseconds on a busy machine and the work only microseconds
    h, w = clearance_px.shape
    out = np.empty(uv0.shape[0])
    rows = np.empty(64, dtype=np.int64)
    cols = np.empty(64, dtype=np.int64)
    for i in range(uv0.shape[0]):
        u0, v0, u1, v1 = uv0[i, 0], uv0[i, 1], uv1[i, 0], uv1[i, 1]
        rows, cols, k = _touched(u0, v0, u1, v1, rows, cols)
        best = math.inf if k > 0 else 0.0
        for j in range(k):
            r = rows[j]
            c = cols[j]
            value = clearance_px[r, c] if (0 <= r < h and 0 <= c < w) else 0.0
            if value < best:
                best = value
        out[i] = best
    return out


@njit(cache=True)
def _segments_wall_runs(wall_mask, uv0, uv1):
    """Per segment, the number of walls it enters: free->wall transitions along its pixel walk.

    A thick wall is one wall (one run of wall pixels). The start pixel's own state is the
    initial state, so an AP mounted inside a wall pixel is not attenuated by that wall.
    Outside the mask counts as free (no wall there to attenuate). The walk is
    ``touched_pixels_into`` from the start pixel to the end pixel, in order; where the line
    passes exactly through a lattice corner, the two side pixels there are one position of
    the line (wall if either is: the corner point belongs to both closed squares). The
    closed-rule extras after the end pixel (far sides of grid lines) are not walls the line
    passes through and are ignored. A non-finite segment crosses no wall.
    """
    # serial: one scan is a few dozen AP->phone lines (see _segments_min_clearance_px)
    h, w = wall_mask.shape
    out = np.zeros(uv0.shape[0], dtype=np.int64)
    rows = np.empty(64, dtype=np.int64)
    cols = np.empty(64, dtype=np.int64)
    for i in range(uv0.shape[0]):
        u0, v0, u1, v1 = uv0[i, 0], uv0[i, 1], uv1[i, 0], uv1[i, 1]
        rows, cols, k = _touched(u0, v0, u1, v1, rows, cols)
        end_row = int(math.floor(v1)) if k > 0 else 0
        end_col = int(math.floor(u1)) if k > 0 else 0
        runs = 0
        in_wall = False
        corner_wall = False  # the first side pixel of a lattice corner was a wall
        for j in range(k):
            r = rows[j]
            c = cols[j]
            wall = 0 <= r < h and 0 <= c < w and wall_mask[r, c]
            if j + 1 < k and abs(rows[j + 1] - r) == 1 and abs(cols[j + 1] - c) == 1 and not (
                    r == end_row and c == end_col):
                # the first of the two side pixels of a lattice corner (they are diagonal to
                # each other; a side pixel is never the end pixel): the next entry is the same
                # position of the line
                corner_wall = wall
                continue
            wall = wall or corner_wall
            corner_wall = False
            if wall and not in_wall and j > 0:
                runs += 1
            in_wall = wall
            if r == end_row and c == end_col:
                break  # the rest are the closed rule's extras
        out[i] = runs
    return out


def segments_min_clearance_m(floorplan: FloorPlan, a_m: np.ndarray, b_m: np.ndarray) -> np.ndarray:
    """Smallest distance to a wall (m) over the pixels each segment a->b touches; 0 = touches a wall.

    Distances are ``FloorPlan.wall_distance_px`` (pixel centre to wall pixel centre); route
    planning uses them to keep walkers off walls.

    Parameters
    ----------
    a_m, b_m : (N, 2) world points.
    """
    uv0 = np.ascontiguousarray(floorplan.world_to_pixel(np.atleast_2d(a_m)))
    uv1 = np.ascontiguousarray(floorplan.world_to_pixel(np.atleast_2d(b_m)))
    clearance = np.ascontiguousarray(floorplan.wall_distance_px, dtype=np.float64)
    return _segments_min_clearance_px(clearance, uv0, uv1) * floorplan.resolution_m


def segments_cross_wall(floorplan: FloorPlan, a_m: np.ndarray, b_m: np.ndarray) -> np.ndarray:
    """(N,) bool: does the move a->b touch a wall pixel (or leave the map)? Exact pixel walk.

    The planner's serial check: the same pixels as the filter's own
    ``mapfilter.maps.walls.crosses_wall`` (closed-pixel rule), which checks the finished ground
    truth once more in ``simulate_walk``.
    """
    return segments_min_clearance_m(floorplan, a_m, b_m) <= 0.0


def count_walls_crossed(floorplan: FloorPlan, a_m: np.ndarray, b_m: np.ndarray) -> np.ndarray:
    """(N,) int: walls (runs of wall pixels) on each line a->b, Motley-Keenan style.

    Outside the map is free; a line starting inside a wall is not attenuated by that wall; a
    pass exactly through a lattice corner touches both side pixels there (``_segments_wall_runs``).
    """
    uv0 = np.ascontiguousarray(floorplan.world_to_pixel(np.atleast_2d(a_m)))
    uv1 = np.ascontiguousarray(floorplan.world_to_pixel(np.atleast_2d(b_m)))
    return _segments_wall_runs(floorplan.wall_mask, uv0, uv1)
