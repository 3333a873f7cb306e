"""Shortest wall-free paths on the floor plan, and tracks made wall-free with them.

A track that jumps (e.g. a smoothed mean across a collapse recovery) may cross a wall between
two free points. ``detour_wall_crossings`` replaces every such segment with the shortest path
between its ends over free pixels (Dijkstra on the 8-connected pixel grid of a window around
the segment), so the track walks round the wall as the person must have.

Moves between pixel centres are wall-free by the wall walk's own rule (``maps.walls``): a move
to a side neighbour touches the two pixels only; a diagonal move passes through a lattice
corner, which touches all four pixels around it, so it is allowed only when all four are free.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import crosses_wall, wall_crossing_mask

__all__ = ["free_path", "detour_wall_crossings", "nearest_free", "wall_free_track"]


def nearest_free(floorplan: FloorPlan, xy_m: np.ndarray, blocked_mask: np.ndarray | None = None) -> np.ndarray:
    """(N, 2) each point, or the centre of the free pixel nearest to it if it is in a wall or off
    the map (Euclidean distance transform). ``blocked_mask`` (default: the walls) says which
    pixels count as not free; it must leave some pixel free."""
    from scipy import ndimage

    blocked_px = floorplan.wall_mask if blocked_mask is None else blocked_mask
    xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
    rows, cols, off_map = _pixels(floorplan, xy)
    blocked = blocked_px[rows, cols] | off_map
    out = xy.copy()
    if blocked.any():
        _, (near_rows, near_cols) = ndimage.distance_transform_edt(blocked_px, return_indices=True)
        r, c = near_rows[rows[blocked], cols[blocked]], near_cols[rows[blocked], cols[blocked]]
        out[blocked] = floorplan.pixel_to_world(np.column_stack([c + 0.5, r + 0.5]))
    return out


def _pixels(floorplan: FloorPlan, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows and columns of points (clipped to the map) and whether each was off the map."""
    height, width = floorplan.shape_px
    uv = floorplan.world_to_pixel(xy)
    cols = np.clip(np.floor(uv[:, 0]).astype(np.int64), 0, width - 1)
    rows = np.clip(np.floor(uv[:, 1]).astype(np.int64), 0, height - 1)
    return rows, cols, (uv[:, 0] < 0) | (uv[:, 0] >= width) | (uv[:, 1] < 0) | (uv[:, 1] >= height)


def wall_free_track(floorplan: FloorPlan, t_s: np.ndarray, xy_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A track moved onto the map's free space, in one piece.

    A person stays in one connected free area, so every point goes to the nearest pixel of the
    area (4-connected free pixels) that holds most of the track once it is off the walls; then
    every move that still crosses a wall walks round it (``detour_wall_crossings``), which
    within one area always finds a way.
    """
    from scipy import ndimage

    xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
    if xy.shape[0] == 0 or not (~floorplan.wall_mask).any():
        return np.asarray(t_s, dtype=np.float64).copy(), xy.copy()
    areas, _ = ndimage.label(~floorplan.wall_mask)  # 4-connected: the wall walk passes no corner
    rows, cols, _ = _pixels(floorplan, nearest_free(floorplan, xy))
    main_area = np.bincount(areas[rows, cols]).argmax()
    moved = nearest_free(floorplan, xy, areas != main_area)
    # a point exactly on a pixel edge touches the pixels on both sides (the wall walk's rule):
    # beside a wall, take its own pixel's centre instead
    on_edge = crosses_wall(floorplan, moved, moved)
    if on_edge.any():
        rows, cols, _ = _pixels(floorplan, moved[on_edge])
        moved[on_edge] = floorplan.pixel_to_world(np.column_stack([cols + 0.5, rows + 0.5]))
    return detour_wall_crossings(floorplan, t_s, moved)


def free_path(floorplan: FloorPlan, from_xy_m: np.ndarray, to_xy_m: np.ndarray,
              margin_m: float = 20.0, max_cells: int | None = None) -> np.ndarray | None:
    """Shortest wall-free polyline (K, 2) from ``from_xy_m`` to ``to_xy_m``, both ends included.

    The search covers the segment's bounding box plus ``margin_m`` on every side (then the whole
    map if that fails). None when either end is in a wall or no free path joins them. With
    ``max_cells``, a window of more pixels is searched on square cells of k x k pixels, a cell
    free only where all its pixels are (a bounded cost on a fine plan: the search's time grows
    with its cells; at the native pixels where an end's cell is not free).
    """
    a = np.asarray(from_xy_m, dtype=np.float64).reshape(2)
    b = np.asarray(to_xy_m, dtype=np.float64).reshape(2)
    height, width = floorplan.shape_px
    uv = floorplan.world_to_pixel(np.stack([a, b]))
    cols, rows = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    if np.any((cols < 0) | (cols >= width) | (rows < 0) | (rows >= height)):
        return None
    wall = floorplan.wall_mask
    if wall[rows[0], cols[0]] or wall[rows[1], cols[1]]:
        return None
    margin_px = int(math.ceil(margin_m / floorplan.resolution_m))
    for pad in (margin_px, max(height, width)):
        r0, r1 = max(rows.min() - pad, 0), min(rows.max() + pad + 1, height)
        c0, c1 = max(cols.min() - pad, 0), min(cols.max() + pad + 1, width)
        window = ~wall[r0:r1, c0:c1]  # the window's free pixels (not the whole plan's: a building's is large)
        ends = ((rows[0] - r0, cols[0] - c0), (rows[1] - r0, cols[1] - c0))
        k = 1 if max_cells is None else max(1, math.ceil(math.sqrt(window.size / max_cells)))
        if k > 1:
            h, w = -(-window.shape[0] // k) * k, -(-window.shape[1] // k) * k
            padded = np.zeros((h, w), dtype=bool)
            padded[:window.shape[0], :window.shape[1]] = window
            coarse = padded.reshape(h // k, k, w // k, k).all(axis=(1, 3))
            if all(coarse[r // k, c // k] for r, c in ends):
                cells = _grid_path(coarse, *[(r // k, c // k) for r, c in ends])
                if cells is not None:  # each cell's centre, in the window's pixels
                    cells = cells * k + (k - 1) / 2.0
            else:
                cells = _grid_path(window, *ends)
        else:
            cells = _grid_path(window, *ends)
        if cells is not None:
            centres = floorplan.pixel_to_world(np.column_stack([cells[:, 1] + c0 + 0.5, cells[:, 0] + r0 + 0.5]))
            return np.vstack([a, centres, b])
    return None


def _grid_path(free: np.ndarray, start: tuple[int, int], goal: tuple[int, int]) -> np.ndarray | None:
    """(K, 2) rows/cols of the shortest 8-connected path over ``free`` (corner rule above), None
    when no free path joins the two pixels (``_grid_search``)."""
    free = np.ascontiguousarray(free, dtype=np.bool_)
    pred = np.empty(free.size, dtype=np.int64)
    w = free.shape[1]
    s, g = int(start[0]) * w + int(start[1]), int(goal[0]) * w + int(goal[1])
    if not _grid_search(free, s, g, pred):
        return None
    chain = [g]
    while chain[-1] != s:
        chain.append(int(pred[chain[-1]]))
    chain = np.array(chain[::-1], dtype=np.int64)
    return np.column_stack([chain // w, chain % w])


# Dijkstra's search as scipy.sparse.csgraph.dijkstra runs it (scipy 1.17, as the test holds it:
# a queue of (distance, index) pairs, popped nearest first and, of equal distances, the higher
# index first; an entry whose pixel got nearer since is skipped; a neighbour takes the popped
# pixel as predecessor when it comes strictly nearer), on the graph scipy was given (each free pixel's neighbours in
# row-major order, a side move 1 and a diagonal sqrt 2 past two free pixels; pixel ids in
# row-major order rank as the free pixels' indices do), stopped when the goal is popped: every
# pixel of its path was popped before it, and a popped pixel's distance and predecessor never
# change again. tests/maps/test_paths.py holds the paths to scipy's, pixel for pixel.
@njit(cache=True, nogil=True, inline="always")
def _before(d_a, a, d_b, b):
    # the queue's order: the nearer first, of equal distances the higher index
    return d_a < d_b or (d_a == d_b and a > b)


@njit(cache=True, nogil=True)
def _grid_search(free, start, goal, pred):
    """Shortest path from pixel ``start`` to ``goal`` (row-major indices of ``free``) over the free
    pixels (module docstring's moves): True when found, ``pred`` then leading back from the goal."""
    h, w = free.shape
    dist = np.full(h * w, np.inf)
    # the queue, a binary heap: a free pixel enters it each time it comes strictly nearer, at most
    # once per neighbour (8); the room is reserved, not written (a search touches what it uses)
    room = 8 * np.count_nonzero(free) + 1
    dist_q = np.empty(room)
    node_q = np.empty(room, dtype=np.int64)
    diagonal = math.hypot(1.0, 1.0)
    dist[start] = 0.0
    dist_q[0], node_q[0], size = 0.0, start, 1
    while size > 0:
        d, v = dist_q[0], node_q[0]  # pop: the last entry sifted down from the top
        size -= 1
        last_d, last = dist_q[size], node_q[size]
        i = 0
        while True:
            child = 2 * i + 1
            if child >= size:
                break
            if child + 1 < size and _before(dist_q[child + 1], node_q[child + 1], dist_q[child], node_q[child]):
                child += 1
            if not _before(dist_q[child], node_q[child], last_d, last):
                break
            dist_q[i], node_q[i] = dist_q[child], node_q[child]
            i = child
        dist_q[i], node_q[i] = last_d, last
        if dist[v] < d:
            continue  # an entry from before the pixel came nearer
        if v == goal:
            return True
        r = v // w
        c = v - r * w
        for dr in range(-1, 2):  # the neighbours in row-major order, as the CSR rows list them
            rr = r + dr
            if rr < 0 or rr >= h:
                continue
            for dc in range(-1, 2):
                cc = c + dc
                if (dr == 0 and dc == 0) or cc < 0 or cc >= w or not free[rr, cc]:
                    continue
                if dr != 0 and dc != 0 and not (free[rr, c] and free[r, cc]):
                    continue
                j = rr * w + cc
                step = d + (diagonal if dr != 0 and dc != 0 else 1.0)
                if dist[j] > step:
                    dist[j] = step
                    pred[j] = v
                    i = size  # push: sifted up from the end
                    size += 1
                    while i > 0:
                        up = (i - 1) // 2
                        if not _before(step, j, dist_q[up], node_q[up]):
                            break
                        dist_q[i], node_q[i] = dist_q[up], node_q[up]
                        i = up
                    dist_q[i], node_q[i] = step, j
    return False


def detour_wall_crossings(floorplan: FloorPlan, t_s: np.ndarray, xy_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The track with every wall-crossing segment replaced by the shortest free path between its ends.

    The detour's points get times spread over the segment's time span in proportion to the
    distance along the path. A segment whose ends are in walls or not joined by free space is
    kept as it was.
    """
    t = np.asarray(t_s, dtype=np.float64)
    xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
    if xy.shape[0] < 2:
        return t.copy(), xy.copy()
    crossing = wall_crossing_mask(floorplan, xy)
    if not crossing.any():
        return t.copy(), xy.copy()
    out_t, out_xy = [t[:1]], [xy[:1]]
    for k in range(1, xy.shape[0]):
        path = free_path(floorplan, xy[k - 1], xy[k]) if crossing[k - 1] else None
        if path is not None and path.shape[0] > 2:
            along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
            fraction = along / along[-1] if along[-1] > 0 else np.linspace(0, 1, path.shape[0])
            out_t.append(t[k - 1] + fraction[1:] * (t[k] - t[k - 1]))
            out_xy.append(path[1:])
        else:
            out_t.append(t[k:k + 1])
            out_xy.append(xy[k:k + 1])
    return np.concatenate(out_t), np.concatenate(out_xy)
