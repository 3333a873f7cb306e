"""The half-floor split: tracking scored where the survey never was, by a fixed rule.

A floor's walks are split by one line: across the longer side of the bounding box of every
waypoint of the floor's walks, at the median of the waypoints' coordinate along it (so each
half holds half the waypoints). The rule is the same for every floor and never tuned. In one
direction of the split, the *survey* is every walk whose waypoints all lie in one half (the
surveyed half; a straight leg between two of its waypoints stays in that half too, so its
scans do), and the *test* walks are the others: every walk with a waypoint in the other half.
Each test walk is scored at its waypoints in the surveyed half and, apart, at those in the
unsurveyed half. The second direction surveys the other half, so that every walk is scored
and every waypoint is scored once in the unsurveyed half.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.evaluation.metrics import errors_at_waypoints
from mapfilter.io.tracks import Track

__all__ = ["HalfSplit", "SplitDirection", "errors_by_half", "half_split", "split_directions"]

AXIS_NAMES = ("x", "y")


@dataclasses.dataclass(frozen=True)
class HalfSplit:
    """A floor cut in two at ``cut_m`` along ``axis`` (0: x, 1: y); side 1 is ``>= cut_m``."""

    axis: int
    cut_m: float

    def side(self, xy_m: np.ndarray) -> np.ndarray:
        """Each point's half (0 below the cut, 1 at or above it)."""
        return (np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)[:, self.axis] >= self.cut_m).astype(np.int64)

    def describe(self, side: int | None = None) -> str:
        """The cut (``x = 160.07 m``), or one half of it (``x < 160.07 m``)."""
        relation = "=" if side is None else ("<" if side == 0 else ">=")
        return f"{AXIS_NAMES[self.axis]} {relation} {self.cut_m:.2f} m"


@dataclasses.dataclass(frozen=True)
class SplitDirection:
    """One direction of a split: which half is surveyed, by which walks, and which are tested."""

    surveyed_side: int
    survey: tuple[int, ...]  # indices of the walks whose waypoints all lie in the surveyed half
    test: tuple[int, ...]  # the other walks: each has a waypoint in the unsurveyed half


def half_split(waypoint_xy_m: Sequence[np.ndarray]) -> HalfSplit:
    """The split of a floor by its walks' waypoints (one ``(W, 2)`` array per walk): across the
    longer side of their bounding box, at the median of their coordinate along it."""
    points = [np.asarray(xy, dtype=np.float64).reshape(-1, 2) for xy in waypoint_xy_m]
    points = np.concatenate(points) if points else np.zeros((0, 2))
    if len(points) < 2:
        raise MapfilterError("a half split needs at least two waypoints")
    extent = points.max(axis=0) - points.min(axis=0)
    axis = int(np.argmax(extent))  # x when the sides are equal
    return HalfSplit(axis, float(np.median(points[:, axis])))


def split_directions(split: HalfSplit, waypoint_xy_m: Sequence[np.ndarray]) -> list[SplitDirection]:
    """Both directions of the split (half 0 surveyed, then half 1) over these walks' waypoints."""
    sides = [split.side(xy) for xy in waypoint_xy_m]
    directions = []
    for surveyed in (0, 1):
        survey = tuple(i for i, s in enumerate(sides) if s.size and np.all(s == surveyed))
        test = tuple(i for i, s in enumerate(sides) if i not in survey and s.size)
        directions.append(SplitDirection(surveyed, survey, test))
    return directions


def errors_by_half(split: HalfSplit, surveyed_side: int, track: Track, waypoint_t_s: np.ndarray,
                   waypoint_xy_m: np.ndarray, causal: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """A track's horizontal errors at the waypoints (``metrics.errors_at_waypoints``), split:
    (errors at the waypoints in the surveyed half, errors at those in the unsurveyed half).
    Waypoints before a causal track's first row are in neither."""
    errors = errors_at_waypoints(track.t_s, track.xy_m, waypoint_t_s, waypoint_xy_m, causal)
    side = split.side(np.asarray(waypoint_xy_m)[errors.waypoint_index])
    return errors.errors_m[side == surveyed_side], errors.errors_m[side != surveyed_side]
