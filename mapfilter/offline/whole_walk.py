"""The offline track of a walk on one floor: its dead-reckoned shape placed by every scan's
evidence, moved onto free space, map-matched, and placed again from a second filter run.

Dead reckoning gets a walk's *shape* right; what WiFi gets wrong is where that shape sits. The
offline stage uses the whole walk for every point (it is not causal):

1. ``placement_evidence``: where the walk was at each scan, by every estimator at hand (the
   scan's position fixes and the causal filter's estimate there);
2. ``offline.placement.place_walk``: the shape placed by that evidence, robustly;
3. ``whole_walk_track``: the placed shape moved onto free space, map-matched on the plan and
   made wall-free;
4. ``restarted_run``: the causal filter run again from where step 3 puts the walk's start,
   whose estimates place the walk once more (``one_floor_offline_track``).

Every function takes a walk's evidence and returns a new track; nothing is changed in place.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.filter.events import StepReport
from mapfilter.filter.evidence import WifiEvidence
from mapfilter.filter.particle_filter import FilterConfig
from mapfilter.filter.tracker import MotionConfig, run_over_scans
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.paths import detour_wall_crossings, wall_free_track
from mapfilter.offline.map_matching import MapMatchConfig, map_match
from mapfilter.offline.placement import PlacementConfig, WalkPlacement, place_walk, shift_onto_free_space
from mapfilter.sensors.pdr import Steps
from mapfilter.trackio import Track


@dataclasses.dataclass(frozen=True)
class OfflineConfig:
    """How the offline (whole-walk) track is made."""

    # ILC site 1, pf-smooth mean / p75 m over seeds 0-4: F1 sparse 7.24 / 7.12 -> 6.94 / 7.17,
    # F1 dense 4.14 / 4.99 -> 4.11 / 4.89, F2 16.80 / 24.57 -> 16.82 / 24.29 (docs/accuracy.md);
    # a third run gained nothing. Costs a second filter run per walk
    method: str = "smoother"  # smoother: the filter's own model smoothed | placement: the placed dead-reckoned shape
    restart_from_placement: bool = True  # place the walk again from a second filter run started at the placed start
    # the whole-walk track's error at a walk's start is a few metres (3, 5 and 10 m measured alike on ILC)
    restart_radius_m: float = 5.0  # the second run's particles start within this of the placed start
    lag_s: float = 0.0  # a live tracker's fixed-lag smoothed estimate this many seconds behind (0: none)
    restart_share: float = 0.5  # smoother: the share of the second run's particles started at the placed start (0: no second run)
    placement: PlacementConfig = dataclasses.field(default_factory=PlacementConfig)  # placing the shape by the evidence
    map_matching: MapMatchConfig = dataclasses.field(default_factory=MapMatchConfig)  # bending it to the walls

    def __post_init__(self) -> None:
        if not (self.restart_radius_m > 0 and math.isfinite(self.restart_radius_m)):
            raise MapfilterError(f"restart_radius_m must be a positive number, got {self.restart_radius_m}")


@dataclasses.dataclass(frozen=True)
class OfflineTrack:
    """The offline track and the second filter run whose estimates placed it (None without one)."""

    track: Track
    restarted: Track | None = None


def scan_times(evidence: WifiEvidence) -> np.ndarray:
    """(S,) the walk's scan times."""
    return np.array([scan.t_s for scan in evidence.scans])


def placement_evidence(evidence: WifiEvidence, causal: Track) -> tuple[np.ndarray, np.ndarray]:
    """Where the walk was at each scan, by every estimator at hand: (times (E,), positions (E, 2)).

    Three estimators with different failure modes, each once per scan: the scan's own position
    fix (KWNN, or trilateration), with a radio map also the radio-map likelihood's best cell
    (a per-AP model of mean, spread and P(heard) errs differently from nearest neighbours where
    the survey is thin), and the causal filter's estimate at the scan (map-aware). On ILC
    site 1 (sparse and dense F1, F2) placing the walk by all three measured better than by
    any one or two of them.
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
    (A second particle filter following the placed shape did the same job with more error:
    ILC F2 18.9 m mean / 31.7 m p75 against 18.5 / 29.0, and cost a filter run.)
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


def motion_headings(t_s: np.ndarray, xy_m: np.ndarray) -> np.ndarray:
    """The direction of motion along a track (rad): of the move into each row (the first row: of
    the first move); standing rows keep the heading before them."""
    move = np.diff(xy_m, axis=0)
    if move.shape[0] == 0:
        return np.full(t_s.shape, np.nan)
    moving = np.hypot(move[:, 0], move[:, 1]) > 1e-9
    heading = np.arctan2(move[:, 1], move[:, 0])
    # standing: the last heading while moving (forward fill), the first moving one before any
    last = np.maximum.accumulate(np.where(moving, np.arange(move.shape[0]), -1))
    first = int(np.argmax(moving)) if moving.any() else 0
    heading = heading[np.where(last >= 0, last, first)]
    return np.concatenate([heading[:1], heading])


def placed_track(plan: FloorPlan, evidence: WifiEvidence, steps: Steps, causal: Track,
                 config: OfflineConfig = OfflineConfig()) -> Track:
    """``whole_walk_track`` of the walk placed by its scans' fixes and the causal estimates."""
    placement = place_walk(steps, *placement_evidence(evidence, causal), huber_m=config.placement.huber_m)
    return whole_walk_track(plan, placement, scan_times(evidence), config)


def restarted_run(plan: FloorPlan, evidence: WifiEvidence, steps: Steps, placed: Track, motion: MotionConfig,
                  filter_config: FilterConfig, rng: np.random.Generator, config: OfflineConfig = OfflineConfig(),
                  on_step: Callable[[StepReport], None] | None = None) -> Track:
    """The causal filter again, started within ``restart_radius_m`` of where ``placed`` has the
    walker at the first usable scan: its track, named "restarted".

    The first run started at the walk's first fix; once the whole walk has placed the start, it
    is known better. A first fix tens of metres off can leave the map-bound cloud in the wrong
    corridor for the rest of the walk, and its estimates then pull the placement with it.
    """
    t0 = float(evidence.scans[int(np.argmax(evidence.usable))].t_s)
    start_xy = placed.xy_m[int(np.clip(np.searchsorted(placed.t_s, t0), 0, placed.t_s.size - 1))]
    run = run_over_scans(plan, evidence, motion, filter_config, rng, steps, on_step=on_step, start_xy_m=start_xy,
                         start_radius_m=config.restart_radius_m)
    return dataclasses.replace(run.track(), name="restarted")


def one_floor_offline_track(plan: FloorPlan, evidence: WifiEvidence, steps: Steps | None, causal: Track,
                            lineage: Track | None, motion: MotionConfig, filter_config: FilterConfig,
                            rng: np.random.Generator, config: OfflineConfig = OfflineConfig(),
                            on_step: Callable[[StepReport], None] | None = None) -> OfflineTrack:
    """The offline track of a walk on one floor.

    With PDR steps: the placed, map-matched shape (``placed_track``), placed once more from a
    second filter run when ``restart_from_placement`` (``restarted_run``). Without steps (cv /
    rw motion, or none detected): the final best particle's ``lineage`` walked round the walls.
    """
    if steps is None or len(steps) == 0 or motion.model != "pdr":
        if lineage is None:
            raise ValueError("an offline track without steps needs the filter's lineage (keep_ancestry)")
        t_s, xy_m = detour_wall_crossings(plan, lineage.t_s, lineage.xy_m)
        # its spread: the causal cloud's at the same filter step
        step = np.clip(np.searchsorted(causal.t_s, t_s, side="right") - 1, 0, len(causal.t_s) - 1)
        std_m = causal.std_m[step] if causal.std_m is not None else None
        return OfflineTrack(Track(t_s, xy_m, std_m, motion_headings(t_s, xy_m), name="pf-smooth"))
    placed = placed_track(plan, evidence, steps, causal, config)
    if not config.restart_from_placement:
        return OfflineTrack(placed)
    restarted = restarted_run(plan, evidence, steps, placed, motion, filter_config, rng, config, on_step)
    return OfflineTrack(placed_track(plan, evidence, steps, restarted, config), restarted)
