"""The reported position: the cloud's mean where it is free space, else its main mode, and a
track that walks round walls.

Evennou & Marx report the barycentre of the cloud, which can sit inside a wall (a cloud
split by a wall, or curved around a corner), and a track of barycentres cuts through walls
when the cloud splits. The causal filter reports the barycentre while it lies on free space,
and else the mean of the cloud's main mode (:func:`mode_estimate`): the densest 3 m x 3 m
window of the weight, the particle nearest to that window's mean as the mode's centre, and the
weighted mean of the particles within ``MODE_RADIUS_M`` of it that it sees (no wall between):
one side of a wall, one corridor. A mean that still falls in a wall gives way to the nearest
of those particles. (The mode everywhere costs IPIN 9 %: docs/accuracy.md.) Between two rows
the estimate walks round a wall as the walker must (:func:`toward`): when the straight move to
the new estimate touches a wall, the row is the farthest point of the shortest free path to it
that the previous row sees, so consecutive rows never cross a wall; the next rows follow the
path on.

:func:`weighted_estimate` (the weighted mean when it lies on free space, else the live
particle nearest to it) is what the smoother reports for each smoothed cloud.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import crosses_wall, crossings, wall_grid

__all__ = ["MODE_CELL_M", "MODE_RADIUS_M", "circular_mean", "mode_estimate", "toward", "weighted_estimate",
           "weighted_moments", "writable", "xy_moments"]

MODE_CELL_M = 1.0  # the weight's histogram cells: the densest 3 x 3 of them is the mode's window
MODE_RADIUS_M = 8.0  # the mode: the particles this close to its centre that it sees
# a row's walk round a wall searches at most this many cells: a larger window (a fine or large
# plan, or a whole map searched when the window held no path) is searched on coarser cells; a
# row's window on the ILC, office and IPIN maps fits (850,000 pixels of a 0.05 m plan took 5 s a row)
TOWARD_MAX_CELLS = 250_000
MODE_SIGHT_CHECKS = 512  # at most this many particles' sight checked (every k-th of those in reach)
# a larger cloud is read every k-th particle: its mode is as clear in 4,096 of them (a resampled
# cloud lies in its ancestors' order, so every k-th is a systematic sample), and the estimate
# costs about the same at any size
MODE_PARTICLES = 4096
_MAX_CELLS_SIDE = 128  # a cloud spread wider than 128 cells is binned coarser (the mode of a spread cloud)


@njit(cache=True)
def _moments(xy, w):
    return xy_moments(xy[:, 0], xy[:, 1], w)


@njit(cache=True, nogil=True)
def xy_moments(x, y, w):
    """(mean x, mean y, var x, cov xy, var y) of positions under (not necessarily normalised)
    weights: two passes (mean, then centred sums) for accuracy; serial: memory-bound and cheap.
    A kernel: the building's main-floor moments call it too."""
    total = 0.0
    mx = 0.0
    my = 0.0
    for i in range(w.shape[0]):
        total += w[i]
        mx += w[i] * x[i]
        my += w[i] * y[i]
    mx /= total
    my /= total
    sxx = 0.0
    sxy = 0.0
    syy = 0.0
    for i in range(w.shape[0]):
        dx = x[i] - mx
        dy = y[i] - my
        sxx += w[i] * dx * dx
        sxy += w[i] * dx * dy
        syy += w[i] * dy * dy
    return mx, my, sxx / total, sxy / total, syy / total


def writable(values: np.ndarray) -> np.ndarray:
    """``values`` as a contiguous float64 array that is not read-only (a copy if it is): numba
    compiles a kernel apart for read-only arrays (a resampled cloud's shared uniform weights), and
    each variant is one more load from its cache per process."""
    out = np.ascontiguousarray(values, dtype=np.float64)
    return out if out.flags.writeable else out.copy()


def weighted_moments(xy_m: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(mean (2,), covariance (2, 2)) of positions under (not necessarily normalised) weights."""
    mx, my, sxx, sxy, syy = _moments(np.ascontiguousarray(xy_m, dtype=np.float64), writable(weights))
    return np.array([mx, my]), np.array([[sxx, sxy], [sxy, syy]])


def weighted_estimate(floorplan: FloorPlan, xy_m: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, float, bool]:
    """(estimate_xy_m (2,), std_m, fell_back) of a weighted cloud.

    ``std_m`` is sqrt of the mean of the two weighted position variances. ``fell_back`` is
    True when the mean was in a wall and the nearest live particle was reported instead.
    """
    w = np.asarray(weights, dtype=np.float64)
    mean, cov = weighted_moments(xy_m, w)
    std = float(math.sqrt(max(0.5 * (cov[0, 0] + cov[1, 1]), 0.0)))
    if floorplan.is_free(mean[None, :])[0]:
        return mean, std, False
    live = np.flatnonzero(w > 0)
    d2 = ((xy_m[live] - mean) ** 2).sum(axis=1)
    candidates = live[np.argsort(d2)[:16]]
    free = floorplan.is_free(xy_m[candidates])
    pick = candidates[np.argmax(free)] if free.any() else live[np.argmax(w[live])]
    return xy_m[pick].copy(), std, True


def circular_mean(angles_rad: np.ndarray, weights: np.ndarray) -> float:
    """Weighted circular mean of angles, in (-pi, pi]."""
    w = np.asarray(weights, dtype=np.float64)
    return float(math.atan2(float(w @ np.sin(angles_rad)), float(w @ np.cos(angles_rad))))


@njit(cache=True, nogil=True, error_model="numpy")
def _mode(x, y, w, walls, cell_m, radius_m, max_checks, stride):
    """(mode mean x, y; its centre particle's x, y) of the cloud (module docstring), over every
    ``stride``-th particle; NaN without live particles."""
    n = w.shape[0]
    x_lo = math.inf
    x_hi = -math.inf
    y_lo = math.inf
    y_hi = -math.inf
    for i in range(0, n, stride):
        if w[i] > 0.0:
            x_lo = min(x_lo, x[i])
            x_hi = max(x_hi, x[i])
            y_lo = min(y_lo, y[i])
            y_hi = max(y_hi, y[i])
    if not x_lo <= x_hi:
        return math.nan, math.nan, math.nan, math.nan
    cell = max(cell_m, max(x_hi - x_lo, y_hi - y_lo) / _MAX_CELLS_SIDE)
    nx = int((x_hi - x_lo) / cell) + 1
    ny = int((y_hi - y_lo) / cell) + 1
    hist = np.zeros((ny + 2, nx + 2))  # a border of empty cells: the 3 x 3 sums need no bounds checks
    for i in range(0, n, stride):
        if w[i] > 0.0:
            hist[int((y[i] - y_lo) / cell) + 1, int((x[i] - x_lo) / cell) + 1] += w[i]
    best = -1.0
    best_r = 1
    best_c = 1
    for r in range(1, ny + 1):
        for c in range(1, nx + 1):
            total = (hist[r - 1, c - 1] + hist[r - 1, c] + hist[r - 1, c + 1] + hist[r, c - 1] + hist[r, c]
                     + hist[r, c + 1] + hist[r + 1, c - 1] + hist[r + 1, c] + hist[r + 1, c + 1])
            if total > best:  # the first of equal windows: the same cloud, the same mode
                best, best_r, best_c = total, r, c
    # the window's weighted mean, and the particle nearest to it: the mode's centre
    sw = 0.0
    sx = 0.0
    sy = 0.0
    for i in range(0, n, stride):
        if w[i] > 0.0 and abs(int((y[i] - y_lo) / cell) + 1 - best_r) <= 1 \
                and abs(int((x[i] - x_lo) / cell) + 1 - best_c) <= 1:
            sw += w[i]
            sx += w[i] * x[i]
            sy += w[i] * y[i]
    wx = sx / sw
    wy = sy / sw
    centre = -1
    near = math.inf
    for i in range(0, n, stride):
        if w[i] > 0.0:
            d = (x[i] - wx) ** 2 + (y[i] - wy) ** 2
            if d < near:
                near, centre = d, i
    cx = x[centre]
    cy = y[centre]
    # the particles in reach of the centre, every k-th of them checked for sight
    r2 = radius_m * radius_m
    m = 0
    for i in range(0, n, stride):
        if w[i] > 0.0 and (x[i] - cx) ** 2 + (y[i] - cy) ** 2 <= r2:
            m += 1
    every = (m + max_checks - 1) // max_checks
    k = min(m, max_checks)
    ax = np.full(k, cx)
    ay = np.full(k, cy)
    bx = np.empty(k)
    by = np.empty(k)
    index = np.empty(k, dtype=np.int64)
    j = 0
    seen = 0
    for i in range(0, n, stride):
        if w[i] > 0.0 and (x[i] - cx) ** 2 + (y[i] - cy) ** 2 <= r2:
            if seen % every == 0 and j < k:
                bx[j] = x[i]
                by[j] = y[i]
                index[j] = i
                j += 1
            seen += 1
    blocked = np.empty(j, dtype=np.bool_)
    crossings(walls, ax, ay, bx, by, j, blocked)
    sw = w[centre]
    sx = w[centre] * cx
    sy = w[centre] * cy
    for q in range(j):
        if not blocked[q]:
            sw += w[index[q]]
            sx += w[index[q]] * bx[q]
            sy += w[index[q]] * by[q]
    mx = sx / sw
    my = sy / sw
    # a mean in a wall (a mode curved round a corner): the seen particle nearest to it
    mask = walls.mask
    h, wd = mask.shape
    u = (mx - walls.x0_m) * walls.inv_resolution
    v = h - (my - walls.y0_m) * walls.inv_resolution
    if not (0.0 <= u < wd and 0.0 <= v < h) or mask[int(v), int(u)]:
        near = (cx - mx) ** 2 + (cy - my) ** 2
        px = cx
        py = cy
        for q in range(j):
            d = (bx[q] - mx) ** 2 + (by[q] - my) ** 2
            if not blocked[q] and d < near:
                near, px, py = d, bx[q], by[q]
        mx = px
        my = py
    return mx, my, cx, cy


def mode_estimate(floorplan: FloorPlan, xy_m: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(2,) the mean of the cloud's main mode (module docstring), a free point of ``floorplan``:
    the densest ``MODE_CELL_M`` 3 x 3 window's particle nearest to its mean is the mode's centre,
    and the estimate the weighted mean of the particles within ``MODE_RADIUS_M`` of it that it
    sees (the seen one nearest to that mean if the mean is in a wall)."""
    xy = np.asarray(xy_m, dtype=np.float64)
    stride = -(-len(xy) // MODE_PARTICLES)
    mx, my, _, _ = _mode(np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1]),
                         writable(weights), wall_grid(floorplan), MODE_CELL_M,
                         MODE_RADIUS_M, MODE_SIGHT_CHECKS, max(stride, 1))
    return np.array([mx, my])


def toward(floorplan: FloorPlan, from_xy_m: np.ndarray | None, to_xy_m: np.ndarray) -> np.ndarray:
    """The next row of a track from ``from_xy_m`` toward ``to_xy_m`` that crosses no wall: the
    point itself when the straight move touches none, else the farthest point of the shortest
    free path to it (``maps.paths.free_path``) that the straight move from ``from_xy_m`` reaches
    without touching a wall; ``to_xy_m`` when there is no previous row or no free path (two
    places that free space does not join)."""
    to = np.asarray(to_xy_m, dtype=np.float64)
    if from_xy_m is None or not np.isfinite(from_xy_m).all() or not np.isfinite(to).all():
        return to
    start = np.asarray(from_xy_m, dtype=np.float64)
    if not crosses_wall(floorplan, start[None, :], to[None, :])[0]:
        return to
    from mapfilter.maps.paths import free_path

    path = free_path(floorplan, start, to, max_cells=TOWARD_MAX_CELLS)
    if path is None:
        return to
    seen = ~crosses_wall(floorplan, np.repeat(start[None, :], len(path), axis=0), path)
    seen[0] = True  # the row itself
    return path[int(np.flatnonzero(seen)[-1])].copy()
