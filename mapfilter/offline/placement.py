"""Whole-walk placement: where a walk's dead-reckoned shape sits on the map, from every fix.

Dead reckoning gets a walk's *shape* right (on ILC site 1, PDR with the rotation vector's
heading offset, placed by the oracle translation, errs 1.7-1.9 m mean); what WiFi gets wrong is
where that shape sits, and most of the WiFi error is one bias per walk. A step-by-step filter
seeded from one fix keeps much of that error; a whole-walk estimate uses every scan for every
point. This is the robust "cost minimisation" of the top ILC 2.0 write-ups with the PDR moves
taken as exact over the walk: the translation is the Huber M-estimate (IRLS) of the offsets
fix_i - shape(t_i), so fixes tens of metres off (scans where the radio map has no reference
points) are down-weighted instead of dragging the walk.

The heading offset (gyro heading -> map heading) comes from the rotation vector when the log
has one (its circular mean over the walk); without one it is searched over the full circle
against the fixes. ``offline.whole_walk`` then shifts the placed shape onto free space
(``shift_onto_free_space``) and map-matches it (``offline.map_matching``) so that the result
never crosses a wall.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.sensors.pdr import Steps

__all__ = ["Anchor", "PlacementConfig", "WalkPlacement", "pdr_shape", "place_walk", "robust_offset",
           "shift_onto_free_space"]


@dataclasses.dataclass(frozen=True)
class PlacementConfig:
    """How a walk's shape is placed by its evidence and then moved onto free space."""

    # the error hardly depends on it over 2-20 m (docs/accuracy.md): the middle
    huber_m: float = 10.0  # Huber threshold of the fix offsets: residuals beyond it count linearly
    # half: the walls correct the placement without overruling its evidence (docs/accuracy.md)
    map_shift_share: float = 0.5  # the walls may move the placement by this share of its median fix residual
    map_shift_step_m: float = 0.5  # grid of the shifts tried
    map_shift_max_m: float = 10.0  # ... and never farther than this

    def __post_init__(self) -> None:
        for name in ("huber_m", "map_shift_step_m"):
            if not (getattr(self, name) > 0 and math.isfinite(getattr(self, name))):
                raise MapfilterError(f"placement setting {name} must be a positive number, got {getattr(self, name)}")
        if not (self.map_shift_share >= 0 and self.map_shift_max_m >= 0):
            raise MapfilterError("placement settings map_shift_share and map_shift_max_m must be >= 0")


HUBER_M = PlacementConfig.huber_m


@dataclasses.dataclass(frozen=True)
class WalkPlacement:
    """A walk's dead-reckoned shape placed on the map."""

    t_s: np.ndarray  # (S + 1,) the shape's times: half a step period before the first step, then each step
    xy_m: np.ndarray  # (S + 1, 2) placed positions
    heading_offset_rad: float  # added to the gyro heading (relative to the first step) to get the map heading
    offset_xy_m: np.ndarray  # (2,) translation of the shape (its start point)
    fix_residual_median_m: float  # median distance from the fixes to the placed shape: the WiFi scatter
    n_fixes: int
    max_shift_m: float | None = None  # placed through an anchor: the walls move it this far at most

    def position_at(self, t_s: np.ndarray) -> np.ndarray:
        """Placed positions at ``t_s`` (linear between steps, clamped to the ends), shape (T, 2)."""
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        return np.column_stack([np.interp(t, self.t_s, self.xy_m[:, 0]), np.interp(t, self.t_s, self.xy_m[:, 1])])

    def heading_at_step(self, steps: Steps) -> np.ndarray:
        """Map heading of each step (rad)."""
        return steps.heading_rad - steps.heading_rad[0] + self.heading_offset_rad


def pdr_shape(steps: Steps, heading_offset_rad: float, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """The dead-reckoned walk from (0, 0): (t_s (S + 1,), xy_m (S + 1, 2)).

    Step k moves its Weinberg length along gyro heading (relative to the first step) plus
    ``heading_offset_rad``. The start point is set half a median step period before the first
    step (the walker stands there until then).
    """
    if len(steps) == 0:
        raise MapfilterError("no steps detected: the walk has no dead-reckoned shape")
    heading = steps.heading_rad - steps.heading_rad[0] + heading_offset_rad
    moves = scale * steps.step_length_m[:, None] * np.column_stack([np.cos(heading), np.sin(heading)])
    period = float(np.median(np.diff(steps.t_s))) if len(steps) > 1 else 0.5
    t_s = np.concatenate([[steps.t_s[0] - 0.5 * period], steps.t_s])
    return t_s, np.vstack([np.zeros((1, 2)), np.cumsum(moves, axis=0)])


def robust_offset(offsets_xy_m: np.ndarray, huber_m: float = HUBER_M, iterations: int = 30) -> np.ndarray:
    """Huber M-estimate of the mean of 2-D offsets (IRLS from the coordinate-wise median).

    Weights are 1 within ``huber_m`` of the estimate and ``huber_m / r`` beyond: a far outlier
    pulls with a bounded force instead of its full distance.
    """
    d = np.asarray(offsets_xy_m, dtype=np.float64).reshape(-1, 2)
    if d.shape[0] == 0:
        raise ValueError("no offsets")
    m = np.median(d, axis=0)
    for _ in range(iterations):
        r = np.linalg.norm(d - m, axis=1)
        w = np.where(r <= huber_m, 1.0, huber_m / np.maximum(r, 1e-12))
        new = (w[:, None] * d).sum(axis=0) / w.sum()
        if np.linalg.norm(new - m) < 1e-6:
            return new
        m = new
    return m


def _huber_cost(r: np.ndarray, huber_m: float) -> float:
    return float(np.where(r <= huber_m, 0.5 * r * r, huber_m * r - 0.5 * huber_m * huber_m).sum())


def rotation_vector_heading_offset(steps: Steps) -> float | None:
    """Gyro-to-map heading offset: circular mean over all steps of the rotation vector's heading
    minus the gyro heading (relative to the first step); None without a rotation vector."""
    if steps.abs_heading_rad is None or len(steps) == 0:
        return None
    diff = steps.abs_heading_rad - (steps.heading_rad - steps.heading_rad[0])
    return float(math.atan2(np.sin(diff).mean(), np.cos(diff).mean()))


@dataclasses.dataclass(frozen=True)
class Anchor:
    """Where the walk is known to have been at a time (its start, as the user gives it), within
    ``sigma_m``: the placed shape passes there, whatever the fixes say, and the walls may move it
    by that much at most."""

    t_s: float
    xy_m: np.ndarray
    sigma_m: float


def place_walk(steps: Steps, fix_t_s: np.ndarray, fix_xy_m: np.ndarray, heading_offset_rad: float | None = None,
               huber_m: float = HUBER_M, anchor: Anchor | None = None) -> WalkPlacement:
    """Place a walk's dead-reckoned shape by every position fix of the walk.

    Parameters
    ----------
    steps : the detected steps (shape from gyro heading changes and Weinberg lengths).
    fix_t_s, fix_xy_m : (F,) times and (F, 2) positions of the WiFi fixes; rows with NaN are skipped.
    heading_offset_rad : gyro-to-map heading offset; None takes the rotation vector's
        (``rotation_vector_heading_offset``), and without one searches 72 directions for the
        offset whose placed shape fits the fixes best (Huber cost).
    huber_m : Huber threshold of the fix offsets.
    anchor : a point the walk is known to pass (``Anchor``): the translation puts the shape
        there, and the fixes only choose the heading offset when the log has no rotation vector.
    """
    fix_t = np.asarray(fix_t_s, dtype=np.float64).reshape(-1)
    fix_xy = np.asarray(fix_xy_m, dtype=np.float64).reshape(-1, 2)
    ok = np.all(np.isfinite(fix_xy), axis=1) & np.isfinite(fix_t)
    fix_t, fix_xy = fix_t[ok], fix_xy[ok]
    if fix_t.size == 0:
        raise MapfilterError("no position fix to place the walk by")
    if heading_offset_rad is None:
        heading_offset_rad = rotation_vector_heading_offset(steps)
    candidates = [heading_offset_rad] if heading_offset_rad is not None else list(np.arange(72) * (2 * math.pi / 72))
    best = None
    for theta in candidates:
        t_s, shape_xy = pdr_shape(steps, float(theta))
        at_fixes = np.column_stack([np.interp(fix_t, t_s, shape_xy[:, 0]), np.interp(fix_t, t_s, shape_xy[:, 1])])
        if anchor is None:
            offset = robust_offset(fix_xy - at_fixes, huber_m)
        else:
            at_anchor = np.array([np.interp(anchor.t_s, t_s, shape_xy[:, k]) for k in (0, 1)])
            offset = np.asarray(anchor.xy_m, dtype=np.float64).reshape(2) - at_anchor
        residual = np.linalg.norm(fix_xy - at_fixes - offset, axis=1)
        cost = _huber_cost(residual, huber_m)
        if best is None or cost < best[0]:
            best = (cost, float(theta), t_s, shape_xy + offset, offset, residual)
    _, theta, t_s, xy, offset, residual = best
    return WalkPlacement(t_s, xy, theta, offset, float(np.median(residual)), int(fix_t.size),
                         None if anchor is None else float(anchor.sigma_m))


def shift_onto_free_space(floorplan: FloorPlan, placement: WalkPlacement,
                          config: PlacementConfig = PlacementConfig()) -> WalkPlacement:
    """Move the placed shape, by at most ``map_shift_share`` x its median fix residual (and
    ``map_shift_max_m``), to where the largest share of its points lies in free space; of equally
    good shifts the shortest. The fixes fix the placement to within their bias; the walls say
    which of the nearby placements a walker could have walked."""
    radius = min(config.map_shift_share * placement.fix_residual_median_m, config.map_shift_max_m)
    if placement.max_shift_m is not None:
        radius = min(radius, placement.max_shift_m)
    step_m = config.map_shift_step_m
    if not (radius >= step_m):
        return placement
    grid = np.arange(-radius, radius + 1e-9, step_m)
    dx, dy = np.meshgrid(grid, grid)
    shifts = np.column_stack([dx.ravel(), dy.ravel()])
    length = np.hypot(shifts[:, 0], shifts[:, 1])
    shifts, length = shifts[length <= radius], length[length <= radius]
    free_share = np.array([floorplan.is_free(placement.xy_m + shift).mean() for shift in shifts])
    best = np.flatnonzero(free_share >= free_share.max() - 1e-12)
    shift = shifts[best[np.argmin(length[best])]]
    return dataclasses.replace(placement, xy_m=placement.xy_m + shift, offset_xy_m=placement.offset_xy_m + shift)
