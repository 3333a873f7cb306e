"""A walk on one floor placed whole: its dead-reckoned shape placed by every scan's evidence,
moved onto free space and map-matched.

Dead reckoning gets a walk's *shape* right; what WiFi gets wrong is where that shape sits. The
offline track (``pipeline.tracker.Tracker``) places the shape twice: through the causal track, to start a
second forward pass near the walk's true start, and through that pass's smoothed track
(``offline.smoother``), for the offline track itself. Each placement:

1. ``placement_evidence``: where the walk was at each scan, by every estimator at hand (the
   scan's position fixes and the filter's estimate there);
2. ``offline.placement.place_walk``: the shape placed by that evidence, robustly;
3. ``whole_walk_track``: the placed shape moved onto free space, map-matched on the plan and
   made wall-free.

Every function takes a walk's evidence and returns a new track; nothing is changed in place.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.filter.evidence import WifiEvidence
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.paths import wall_free_track
from mapfilter.offline.map_matching import MapMatchConfig, map_match
from mapfilter.offline.placement import Anchor, PlacementConfig, WalkPlacement, place_walk, shift_onto_free_space
from mapfilter.sensors.pdr import Steps
from mapfilter.io.tracks import Track


@dataclasses.dataclass(frozen=True)
class OfflineConfig:
    """How the offline (whole-walk) track is made."""

    lag_s: float = 0.0  # a live tracker's fixed-lag smoothed estimate this many seconds behind (0: none)
    placement: PlacementConfig = dataclasses.field(default_factory=PlacementConfig)  # placing the shape by the evidence
    map_matching: MapMatchConfig = dataclasses.field(default_factory=MapMatchConfig)  # bending it to the walls

    def __post_init__(self) -> None:
        if not (self.lag_s >= 0 and math.isfinite(self.lag_s)):
            raise MapfilterError(f"lag_s must be a number of seconds, 0 or more, got {self.lag_s}")


def scan_times(evidence: WifiEvidence) -> np.ndarray:
    """(S,) the walk's scan times."""
    return np.array([scan.t_s for scan in evidence.scans])


def placement_evidence(evidence: WifiEvidence, causal: Track) -> tuple[np.ndarray, np.ndarray]:
    """Where the walk was at each scan, by every estimator at hand: (times (E,), positions (E, 2)).

    Three estimators with different failure modes, each once per scan: the scan's own position
    fix (KWNN, or trilateration), with a radio map also the radio-map likelihood's best cell
    (a per-AP model of mean, spread and P(heard) errs differently from nearest neighbours where
    the survey is thin), and the causal filter's estimate at the scan (map-aware): all three
    measured better than any one or two of them (docs/accuracy.md).
    """
    scan_t = scan_times(evidence)
    fixes = evidence.position_fixes()
    parts_t, parts_xy = [scan_t] * len(fixes), list(fixes)
    latest = np.searchsorted(causal.t_s, scan_t, side="right") - 1
    have = latest >= 0
    parts_t.append(scan_t[have])
    parts_xy.append(causal.xy_m[latest[have]])
    return np.concatenate(parts_t), np.concatenate(parts_xy)


def whole_walk_track(plan: FloorPlan, placement: WalkPlacement, scan_t_s: np.ndarray,
                     config: OfflineConfig = OfflineConfig()) -> Track:
    """The placed dead-reckoned shape, map-matched and wall-free.

    Within half a typical fix error of where ``placement`` put it, the shape moves to where most
    of it lies in free space (``offline.placement.shift_onto_free_space``). A forward-backward
    pass over the plan's free cells (``offline.map_matching.map_match``), observing the placed
    shape at the scan times ``scan_t_s``, then lets the walk bend where the walls say it must
    (the rigid shape drifts). Points still in walls move to the nearest free pixel and moves
    that still cross a wall walk round it by the shortest free path (``maps.paths.wall_free_track``).
    (A second particle filter following the placed shape did the same job with more error and
    cost a filter run: docs/accuracy.md.)
    """
    placement = shift_onto_free_space(plan, placement, config.placement)
    matched = map_match(plan, placement.t_s, placement.xy_m, scan_t_s, config.map_matching)
    t_s, xy_m = wall_free_track(plan, matched.t_s, matched.xy_m)
    std_m = None if matched.std_m is None else np.interp(t_s, matched.t_s, matched.std_m)
    return Track(t_s, xy_m, std_m, _step_headings(placement, t_s), name="pf-smooth")


def _step_headings(placement: WalkPlacement, t_s: np.ndarray) -> np.ndarray:
    """The walker's heading at ``t_s``: the dead-reckoned heading of the step being walked (the
    placed shape's move into its next point; the first move's before the first step)."""
    move = np.diff(placement.xy_m, axis=0)
    if move.shape[0] == 0:
        return np.full(t_s.shape, np.nan)
    heading = np.arctan2(move[:, 1], move[:, 0])
    index = np.clip(np.searchsorted(placement.t_s, t_s, side="left") - 1, 0, heading.size - 1)
    return heading[index]


def placed_track(plan: FloorPlan, evidence: WifiEvidence, steps: Steps, causal: Track,
                 config: OfflineConfig = OfflineConfig(), anchor: Anchor | None = None) -> Track:
    """``whole_walk_track`` of the walk placed by its scans' fixes and the causal estimates (and
    through ``anchor``, where the walk is known to have been)."""
    placement = place_walk(steps, *placement_evidence(evidence, causal), huber_m=config.placement.huber_m,
                           anchor=anchor)
    return whole_walk_track(plan, placement, scan_times(evidence), config)
