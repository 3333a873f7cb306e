"""The reported position: weighted mean and spread, never inside a wall.

Evennou & Marx report the barycentre of the cloud, which can sit inside a wall (a cloud
split by a wall, or curved around a corner). We report the weighted mean when it lies on
free space and the live particle nearest to it otherwise (every live particle is on free
space), so the estimate is always a walkable point.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from mapfilter.maps.floorplan import FloorPlan

__all__ = ["circular_mean", "weighted_estimate", "weighted_moments"]


@njit(cache=True)
def _moments(xy, w):
    # two passes (mean, then centred sums) for accuracy; serial: memory-bound and cheap
    total = 0.0
    mx = 0.0
    my = 0.0
    for i in range(w.shape[0]):
        total += w[i]
        mx += w[i] * xy[i, 0]
        my += w[i] * xy[i, 1]
    mx /= total
    my /= total
    sxx = 0.0
    sxy = 0.0
    syy = 0.0
    for i in range(w.shape[0]):
        dx = xy[i, 0] - mx
        dy = xy[i, 1] - my
        sxx += w[i] * dx * dx
        sxy += w[i] * dx * dy
        syy += w[i] * dy * dy
    return mx, my, sxx / total, sxy / total, syy / total


def weighted_moments(xy_m: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(mean (2,), covariance (2, 2)) of positions under (not necessarily normalised) weights."""
    mx, my, sxx, sxy, syy = _moments(np.ascontiguousarray(xy_m, dtype=np.float64),
                                     np.ascontiguousarray(weights, dtype=np.float64))
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
