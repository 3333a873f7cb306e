"""The test oracle of the filter step: each stage in plain numpy and Python, fed the same draws.

The filter's step runs as two numba passes (``mapfilter.filter.kernels.passes``) that call the
models' compiled kernels. Here every stage is written out plainly (numpy's cos and sin, a
brute-force wall check that clips the segment against every pixel square, numpy's cumsum and
searchsorted for the systematic resampling), taking the counter-based normals the kernels
draw (``kernels.draws.counter_normals``), so a test can hold each stage of the fast step to it.
"""

from __future__ import annotations

import math
import statistics

import numpy as np

from mapfilter.filter.kernels.draws import counter_normals
from mapfilter.filter.models import motion
from mapfilter.filter.particles import HEADING, STEP, VX, VY, X, Y
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import touched_pixels_reference


def normals(key: int, pairs: int, n: int) -> np.ndarray:
    """(2 pairs, n): the standard normals the move kernel gets (pair k in rows 2k, 2k + 1)."""
    rows = []
    for pair in range(pairs):
        rows.extend(counter_normals(key, pair, n))
    return np.array(rows).reshape(2 * pairs, n)


def move_random_walk(state: np.ndarray, z: np.ndarray, radius_m: float, sigma_m: float) -> np.ndarray:
    """Lund thesis eq. 6.6: a uniform direction (that of the second normal pair) and a Gaussian blur."""
    out = state.copy()
    phi = np.arctan2(z[3], z[2])
    out[X] += radius_m * np.cos(phi) + sigma_m * z[0]
    out[Y] += radius_m * np.sin(phi) + sigma_m * z[1]
    return out


def move_constant_velocity(state: np.ndarray, z: np.ndarray, dt_s: float, sigma: float, max_speed: float) -> np.ndarray:
    out = state.copy()
    a = sigma * z[:2]
    out[X] += state[VX] * dt_s + 0.5 * dt_s ** 2 * a[0]
    out[Y] += state[VY] * dt_s + 0.5 * dt_s ** 2 * a[1]
    v = state[VX:VY + 1] + a * dt_s
    speed = np.hypot(v[0], v[1])
    v *= np.where(speed > max_speed, max_speed / np.maximum(speed, 1e-300), 1.0)
    out[VX:VY + 1] = v
    return out


def move_pdr(state: np.ndarray, z: np.ndarray, model, n_steps: int, change_rad: float) -> np.ndarray:
    """Lund thesis eq. 8.23 with false turns: a particle ignores a turn when its sixth normal falls
    below the false-turn share's quantile."""
    out = state.copy()
    share = model.false_turn_fraction if abs(change_rad) >= motion.TURN_THRESHOLD_RAD else 0.0
    quantile = -math.inf if share <= 0 else statistics.NormalDist().inv_cdf(share) if share < 1 else math.inf
    change = np.where(z[5] < quantile, 0.0, change_rad)
    heading = state[HEADING] + change + model.heading_sigma_rad * z[0]
    heading = np.mod(heading + math.pi, 2 * math.pi) - math.pi
    length = state[STEP]
    if n_steps > 0:
        length = np.clip(length + motion.STEP_LENGTH_WALK_SIGMA_M * math.sqrt(n_steps) * z[1],
                         model.step_length_min_m, model.step_length_max_m)
    out[X] += n_steps * length * np.cos(heading) + motion.POSITION_SIGMA_M * math.sqrt(n_steps) * z[2]
    out[Y] += n_steps * length * np.sin(heading) + motion.POSITION_SIGMA_M * math.sqrt(n_steps) * z[3]
    out[HEADING] = heading
    out[STEP] = length
    return out


def crosses(plan: FloorPlan, a_xy_m: np.ndarray, b_xy_m: np.ndarray) -> np.ndarray:
    """Per segment: does it touch a wall pixel or leave the map (every pixel square it meets)?"""
    h, w = plan.wall_mask.shape
    ua, ub = plan.world_to_pixel(a_xy_m), plan.world_to_pixel(b_xy_m)
    out = np.zeros(len(ua), dtype=bool)
    for i in range(len(ua)):
        for row, col in touched_pixels_reference(ua[i], ub[i]):
            if not (0 <= row < h and 0 <= col < w) or plan.wall_mask[row, col]:
                out[i] = True
                break
    return out


def systematic_parents(weights: np.ndarray, u: float, n_out: int) -> np.ndarray:
    """Output j takes the particle whose cumulative-weight bin holds (j + u) / n_out."""
    cumulative = np.cumsum(weights / weights.sum())
    cumulative[np.flatnonzero(weights > 0)[-1]:] = 1.0  # round-off: the last positive weight closes at 1
    return np.searchsorted(cumulative, (np.arange(n_out) + u) / n_out, side="right")


def jitter(plan: FloorPlan, parent_state: np.ndarray, origin_xy_m: np.ndarray, key: int, tries: int, h: float,
           root: np.ndarray) -> np.ndarray:
    """The wall-safe jitter: per try t, the candidate parent + h root eps (eps: normal pair t), taken
    unless the move from the parent or from ``origin_xy_m`` touches a wall; else the parent."""
    n = parent_state.shape[1]
    xy = parent_state[X:Y + 1].T.copy()
    pending = np.arange(n)
    for t in range(tries):
        z0, z1 = counter_normals(key, t, n)
        eps = np.stack([z0, z1])[:, pending]
        candidate = xy[pending] + h * (root @ eps).T
        ok = ~crosses(plan, parent_state[X:Y + 1, pending].T, candidate) & ~crosses(plan, origin_xy_m[pending],
                                                                                     candidate)
        xy[pending[ok]] = candidate[ok]
        pending = pending[~ok]
    return xy
