"""Colours, draw orders and the pure helpers of the viewer (nothing here imports rerun)."""

from __future__ import annotations

import math
import re

import numpy as np

DEFAULT_MAX_PARTICLES = 5000
# A trail of the estimate is logged in finished pieces of this many steps plus the growing
# piece, so the data logged per step stays bounded (re-logging the whole trail each step
# would be quadratic in the walk length).
TRAIL_PIECE_STEPS = 100
# Ground-truth walking direction: over this window, and only if the walker moved this far in it.
GT_HEADING_WINDOW_S = 1.0
GT_HEADING_MIN_MOVE_M = 0.3
# Times at or above this are taken as Unix seconds (2001-09-09 onwards).
UNIX_TIME_MIN_S = 1.0e9
# Particle colours: relative weight w / w_max shown over this many decades (log scale).
WEIGHT_DECADES = 3.0

# Viridis anchor colours (dark purple = low weight, yellow = high weight).
RAMP = np.array(
    [[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], dtype=np.float64
)
# finished tracks: none orange (the live estimate), green (ground truth), red or magenta (events)
TRACK_COLOURS = [(31, 119, 180), (148, 103, 189), (23, 190, 207), (188, 189, 34), (140, 86, 75), (127, 127, 127)]
RED = (230, 40, 40)
BACKGROUND = (235, 235, 235)  # the map view's background, also under transparent plan pixels
GT_COLOUR = (40, 200, 40)
RECOVERY_COLOUR = (220, 0, 220)
ESTIMATE_COLOUR = (255, 140, 0)
SMOOTHED_COLOUR = (0, 150, 255)  # the smoother's cloud, beside the filter's (weight-coloured) one

# Draw orders: pictures at the bottom, then paths, particles, the estimate, event markers on top.
# The ground truth (thin) lies over the tracks (wider), so both stay visible where they agree.
Z_IMAGE, Z_MASK, Z_TRACK, Z_GT, Z_PARTICLES, Z_KILLED, Z_MEAS, Z_ESTIMATE, Z_EVENTS = (
    -20.0, -10.0, 5.0, 6.0, 10.0, 12.0, 15.0, 20.0, 30.0,
)


def weight_faithful_subsample(weight: np.ndarray, max_points: int) -> np.ndarray:
    """Indices of at most ``max_points`` particles whose density follows the weights.

    With no more live particles than ``max_points`` every particle of non-zero weight is
    kept. Otherwise ``max_points`` indices are drawn by systematic resampling with a fixed
    offset of one half (deterministic, no random draw) and duplicates are merged, so a heavy
    particle shows once and the spatial density of the shown points follows the posterior.

    Parameters
    ----------
    weight : (N,) non-negative weights (need not be normalised; NaN counts as zero).
    max_points : cap on the number of indices returned (>= 1).

    Returns
    -------
    (M,) int64 sorted unique indices, ``M <= max_points``; empty when no weight is positive.
    """
    if max_points < 1:
        raise ValueError(f"max_points must be at least 1, got {max_points}")
    w = np.nan_to_num(np.asarray(weight, dtype=np.float64), nan=0.0, posinf=0.0)
    w = np.where(w > 0.0, w, 0.0)
    alive = np.flatnonzero(w)
    if alive.size <= max_points:
        return alive.astype(np.int64)
    cumulative = np.cumsum(w[alive])
    cumulative /= cumulative[-1]
    cumulative[-1] = 1.0  # avoid round-off: the last bin must catch the last position
    positions = (np.arange(max_points) + 0.5) / max_points
    picks = np.searchsorted(cumulative, positions, side="left")
    return alive[np.unique(picks)].astype(np.int64)


def weight_colours(weight: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 colours: viridis over log10(w / w_max), spanning ``WEIGHT_DECADES`` decades."""
    w = np.asarray(weight, dtype=np.float64)
    if w.size == 0:
        return np.zeros((0, 3), dtype=np.uint8)
    w_max = float(np.max(w))
    if not w_max > 0.0:
        return np.tile(RAMP[0].astype(np.uint8), (w.size, 1))
    with np.errstate(divide="ignore"):
        level = 1.0 + np.log10(np.maximum(w, 0.0) / w_max) / WEIGHT_DECADES
    level = np.clip(np.nan_to_num(level, nan=0.0, neginf=0.0), 0.0, 1.0) * (len(RAMP) - 1)
    lower = np.minimum(level.astype(np.int64), len(RAMP) - 2)
    frac = (level - lower)[:, None]
    rgb = RAMP[lower] * (1.0 - frac) + RAMP[lower + 1] * frac
    return np.round(rgb).astype(np.uint8)


def circle_xy(centre_xy: np.ndarray, radius: float, n_vertices: int = 48) -> np.ndarray:
    """(n_vertices + 1, 2) closed polyline of a circle."""
    angle = np.linspace(0.0, 2.0 * math.pi, n_vertices + 1)
    return np.column_stack([centre_xy[0] + radius * np.cos(angle), centre_xy[1] + radius * np.sin(angle)])


def interpolate_ground_truth(wp_t_s: np.ndarray, wp_xy_m: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """Ground-truth positions at ``t_s`` by linear interpolation between waypoints.

    The walker went roughly straight between waypoints (ILC README). Times outside the
    waypoints' time span get NaN: no extrapolation.
    """
    t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
    out = np.full((t.size, 2), np.nan)
    if wp_t_s.size == 0:
        return out
    inside = (t >= wp_t_s[0]) & (t <= wp_t_s[-1])
    out[inside, 0] = np.interp(t[inside], wp_t_s, wp_xy_m[:, 0])
    out[inside, 1] = np.interp(t[inside], wp_t_s, wp_xy_m[:, 1])
    return out


def entity_name(name: str) -> str:
    """A track name as one entity-path part (rerun paths split on '/', and spaces need escaping)."""
    cleaned = re.sub(r"[^A-Za-z0-9_.\-]+", "_", name).strip("_")
    return cleaned or "track"


def wrap_deg(angle_rad: float) -> float:
    return (math.degrees(angle_rad) + 180.0) % 360.0 - 180.0
