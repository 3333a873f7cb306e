"""Self-training: the radio map grows from the walks the tracker tracks.

A radio map is only as good as its survey. Every walk a user tracks also hears WiFi, and its
offline (whole-walk) track knows where it was to a few metres, from the walk's shape, the
walls and every scan of it. ``grow_radio_map`` puts those scans back into the radio map as
*grown* reference points (``sensors.radiomap.GROWN``), each with a position uncertainty
(``RadioMap.xy_sigma_m``), and repeats:

1. every walk is tracked offline over the base map plus the points grown from the *other*
   walks (never its own: a walk tracked over its own points would find them again exactly);
2. its scans become grown points at the offline track's position at each scan, with a
   position sigma from the causal filter's spread there (``GrowConfig.sigma_per_spread``);
3. until the grown points move less than ``GrowConfig.stop_moved_m`` (median) in an
   iteration, or ``GrowConfig.max_iterations``.

Walks are tracked against the previous iteration's points (all of them at once), so the result
does not depend on the order of the walks or on how they are spread over processes. Walks
without IMU (no steps, no dead-reckoned shape) are left out unless ``GrowConfig.wifi_only``:
their offline track is then a constant-velocity filter's, smoothed, which on ILC F2 placed them
too badly to help (docs/self-training.md).

In a building, the offline track's floor (the smoother's) decides each grown point's floor.

Every call to the tracker is in ``track_for_growing``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence

import numpy as np

from mapfilter.config import TrackingConfig
from mapfilter.runtime.dispatch import Engine, run_each
from mapfilter.errors import MapfilterError
from mapfilter.filter.evidence import calibrated_fix_sigma_m
from mapfilter.maps.building import Building
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.sensors.radiomap import GROWN, RadioMap, build_radio_map, merge_radio_maps
from mapfilter.sensors.recording import Recording
from mapfilter.sensors.wifi import scans_of
from mapfilter.pipeline.tracker import track
from mapfilter.io.tracks import Track

__all__ = ["GrowConfig", "GrowReport", "OfflineWalk", "grow_radio_map", "grown_by_fold", "labelled_and_unlabelled",
           "track_for_growing"]


@dataclasses.dataclass(frozen=True)
class GrowConfig:
    """How a radio map grows from walks without waypoints (the same for every floor and site)."""

    # how each walk is tracked; the offline track is always made (smooth is forced on)
    tracking: TrackingConfig = dataclasses.field(default_factory=TrackingConfig)
    # by the third iteration the grown points barely move (docs/accuracy.md)
    max_iterations: int = 3
    stop_moved_m: float = 0.5  # done when the grown points moved less than this (median) in an iteration
    # A grown point's position sigma (per axis) is sigma_per_spread x (s - spread_floor_m), s the
    # causal filter's position spread at the scan: the trust signal that ranked the grown points'
    # errors best (docs/accuracy.md, docs/self-training.md)
    sigma_per_spread: float = 4.0
    spread_floor_m: float = 1.5
    wifi_only: bool = False  # also grow walks without IMU (a constant-velocity filter; see the module docstring)
    seed: int = 0

    def __post_init__(self) -> None:
        if self.max_iterations < 1:
            raise MapfilterError(f"growing needs at least one iteration, got {self.max_iterations}")
        if not (self.stop_moved_m >= 0 and self.sigma_per_spread >= 0 and self.spread_floor_m >= 0):
            raise MapfilterError("stop_moved_m, sigma_per_spread and spread_floor_m must be >= 0")


@dataclasses.dataclass
class OfflineWalk:
    """What the tracker says about one walk, at each of its WiFi scans."""

    name: str
    scan_t_s: np.ndarray  # (S,)
    xy_m: np.ndarray  # (S, 2) the offline track (in the floor's own frame in a building)
    floor: list[str] | None  # a building: the offline track's floor at each scan
    spread_m: np.ndarray  # (S,) the causal filter's position spread (particle std) at the scan


@dataclasses.dataclass
class WalkGrowth:
    """One walk's part in the grown map."""

    name: str
    points: int = 0  # grown points in the final map
    sigma_median_m: float = math.nan
    floors: str = ""  # a building: the floors its points went to
    skipped: str = ""  # why the walk grew nothing ("" if it did)


@dataclasses.dataclass
class GrowReport:
    """What growing did: per walk and per iteration."""

    walks: list[WalkGrowth]
    iterations: list[dict]  # iteration, points, moved_median_m, fix_sigma_m
    labelled: int = 0  # walks with waypoints added to the base map as surveyed points
    offline: list[OfflineWalk] = dataclasses.field(default_factory=list)  # the last iteration's tracks

    @property
    def points(self) -> int:
        return sum(w.points for w in self.walks)

    @property
    def grown_walks(self) -> int:
        return sum(1 for w in self.walks if w.points)


def track_for_growing(space: FloorPlan | Building, recording: Recording, radio_map: RadioMap, config: TrackingConfig,
                      rng: np.random.Generator, fix_sigma: float | dict[str, float] | None) -> tuple[Track, Track]:
    """The one call to the tracker: (the walk's offline track, the causal track that placed it).

    ``fix_sigma``: the fix Gaussian (m; per floor name in a building), None to calibrate it."""
    config = dataclasses.replace(config, smooth=True)
    per_floor = fix_sigma if isinstance(fix_sigma, dict) else None
    if fix_sigma is not None and per_floor is None:
        config = dataclasses.replace(config, wifi=dataclasses.replace(config.wifi, fix_sigma_m=fix_sigma))
    result = track(space, recording, radio_map=radio_map, config=config, fix_sigma_by_floor_m=per_floor, rng=rng)
    if result.offline is None or len(result.offline) == 0:
        raise MapfilterError("the tracker gave no offline track", recording.path)
    return result.offline, (result.restarted if result.restarted is not None else result.causal)


def _has_imu(recording: Recording) -> bool:
    return recording.acc_t_s.shape[0] >= 100  # as radiomap._steps_or_none: 2 s at 50 Hz


def track_offline(space: FloorPlan | Building, radio_map: RadioMap, config: GrowConfig, recording: Recording,
                  rng: np.random.Generator, fix_sigma: float | dict[str, float] | None = None) -> OfflineWalk:
    """Track one walk offline over ``radio_map``: its position and spread at every scan."""
    tracking = config.tracking
    if not _has_imu(recording):  # no steps: a constant-velocity filter's, smoothed, is the offline track
        tracking = dataclasses.replace(tracking, motion=dataclasses.replace(tracking.motion, model="cv"))
    smoothed, causal = track_for_growing(space, recording, radio_map, tracking, rng, fix_sigma)
    t = np.array([s.t_s for s in scans_of(recording)])
    xy = np.column_stack([np.interp(t, smoothed.t_s, smoothed.xy_m[:, 0]),
                          np.interp(t, smoothed.t_s, smoothed.xy_m[:, 1])])
    floor = None
    if smoothed.floor is not None:  # interpolating across a floor change would mix two frames: the nearest row
        row = np.clip(np.searchsorted(smoothed.t_s, t), 0, len(smoothed) - 1)
        before = np.clip(row - 1, 0, len(smoothed) - 1)
        row = np.where(np.abs(smoothed.t_s[before] - t) < np.abs(smoothed.t_s[row] - t), before, row)
        floor = [smoothed.floor[i] for i in row]
        xy = np.where(np.array([smoothed.floor[i] == smoothed.floor[j] for i, j in zip(before, row)])[:, None], xy,
                      smoothed.xy_m[row])
    latest = np.clip(np.searchsorted(causal.t_s, t, side="right") - 1, 0, len(causal) - 1)
    spread = causal.std_m[latest] if causal.std_m is not None else np.full(t.size, np.nan)
    return OfflineWalk(recording.name, t, xy, floor, np.asarray(spread, dtype=np.float64))


def point_sigma_m(walk: OfflineWalk, config: GrowConfig) -> np.ndarray:
    """(S,) position sigma of each scan's grown point: ``GrowConfig.sigma_per_spread`` x the
    causal spread above ``spread_floor_m`` (a walk without a spread: the largest seen, 4 m)."""
    spread = np.nan_to_num(walk.spread_m, nan=4.0, posinf=4.0)
    return config.sigma_per_spread * np.maximum(spread - config.spread_floor_m, 0.0)


def grown_points(recording: Recording, walk: OfflineWalk, sigma_m: np.ndarray,
                 floor_names: Sequence[str] | None = None) -> RadioMap | None:
    """The walk's scans as grown reference points at their offline positions (None: no point).

    Built as a survey log whose waypoints are the offline positions at the scans
    (``build_radio_map``): the same scans and readings a survey of that walk would give."""
    if walk.scan_t_s.size == 0:
        return None
    t, xy = walk.scan_t_s, walk.xy_m
    if t.size == 1:  # a survey log needs two waypoints: the walker stood there a second longer
        t, xy = np.append(t, t[0] + 1.0), np.vstack([xy, xy])
    pseudo = dataclasses.replace(recording, waypoint_t_s=t, waypoint_xy_m=xy)
    try:
        points = build_radio_map([pseudo])
    except MapfilterError:
        return None
    index = np.clip(np.searchsorted(walk.scan_t_s, points.t_s), 0, walk.scan_t_s.size - 1)
    at_scan = walk.scan_t_s[index] == points.t_s
    points = points.select(at_scan)
    index = index[at_scan]
    if len(points) == 0:
        return None
    points.source = np.full(len(points), GROWN, dtype=np.int8)
    points.xy_sigma_m = np.asarray(sigma_m, dtype=np.float64)[index]
    if floor_names is not None:
        if walk.floor is None:
            raise ValueError("a building's grown points need the offline track's floor")
        points.floor = np.array([list(floor_names).index(walk.floor[i]) for i in index], dtype=np.int64)
        points.floor_names = list(floor_names)
        points.floor_name = None
    return points


def _without_waypoints(recording: Recording) -> Recording:
    """The walk as the tracker may see it while growing: no ground truth at all."""
    return dataclasses.replace(recording, waypoint_t_s=np.zeros(0), waypoint_xy_m=np.zeros((0, 2)),
                               waypoint_floor=None)


def _grow_walk(space: FloorPlan | Building, base: RadioMap, config: GrowConfig, fix_sigma, task):
    """One task: track walk ``task`` over the base map plus the other walks' points."""
    index, recording, others, seed = task
    radio_map = merge_radio_maps([base, *others]) if others else base
    try:
        return index, track_offline(space, radio_map, config, recording, np.random.default_rng(seed), fix_sigma), ""
    except MapfilterError as exc:
        return index, None, str(exc).removeprefix(f"{recording.path}: ")


def _fix_sigma(space: FloorPlan | Building, radio_map: RadioMap, config: GrowConfig):
    """The fix Gaussian of this iteration's map, calibrated once for every walk tracked over it
    (the maps differ by one walk's points: calibrating each would cost (points)^2 per walk)."""
    wifi = config.tracking.wifi
    if wifi.fix_sigma_m is not None:
        return wifi.fix_sigma_m
    if isinstance(space, Building):
        return {name: calibrated_fix_sigma_m(radio_map.floor_map(i), wifi.kwnn_k)
                for i, name in enumerate(radio_map.floor_names)}
    return calibrated_fix_sigma_m(radio_map, wifi.kwnn_k)


def labelled_and_unlabelled(recordings: Sequence[Recording]) -> tuple[list[Recording], list[Recording]]:
    """Walks with waypoints (two or more: a survey) and the others."""
    labelled = [r for r in recordings if r.waypoint_t_s.shape[0] >= 2]
    return labelled, [r for r in recordings if r.waypoint_t_s.shape[0] < 2]


def grow_radio_map(space: FloorPlan | Building, radio_map: RadioMap, recordings: Sequence[Recording],
                   config: GrowConfig = GrowConfig(), progress: Callable[[int, int, str], None] | None = None,
                   engine: Engine | None = None) -> tuple[RadioMap, GrowReport]:
    """The radio map grown from ``recordings``: (base points + grown points, report).

    Parameters
    ----------
    space : the floor's plan, or a building (``radio_map`` must then be the building's).
    radio_map : the base map (surveyed, or grown before: its points are kept as they are).
    recordings : the walks to grow from; their waypoints, if any, are never read (to add
        labelled walks as surveyed points, merge ``build_radio_map`` of them into the base
        first: ``labelled_and_unlabelled`` splits them).
    config : ``GrowConfig``.
    progress : ``progress(done, total, walk)`` after each walk of each iteration (total: walks
        x ``max_iterations``; it jumps to the end when the map stops changing earlier).
    engine : where the walks of an iteration run (default: serial).

    Random draws come from ``default_rng([config.seed, iteration, walk index])``.
    """
    engine = engine or Engine(jobs=1)
    building = _check_building_map(space, radio_map)
    walks = [WalkGrowth(r.name) for r in recordings]
    usable = _usable_walks(recordings, walks, config)
    if not usable:  # nothing to track: the base map as it is
        return merge_radio_maps([radio_map]), GrowReport(walks, [])
    blind = {i: _without_waypoints(recordings[i]) for i in usable}
    grown: dict[int, RadioMap] = {}
    positions: dict[int, np.ndarray] = {}
    offline: dict[int, OfflineWalk] = {}
    iterations: list[dict] = []
    total = len(usable) * config.max_iterations
    floor_names = radio_map.floor_names if building else None
    for iteration in range(config.max_iterations):
        current = merge_radio_maps([radio_map, *grown.values()])
        fix_sigma = _fix_sigma(space, current, config)
        tasks = [(i, blind[i], [g for j, g in grown.items() if j != i], [config.seed, iteration, i]) for i in usable]
        new = _track_walks(space, radio_map, config, fix_sigma, tasks, walks, engine, progress,
                           iteration * len(usable), total)
        moved = [float(np.median(np.linalg.norm(walk.xy_m - positions[i], axis=1)))
                 for i, walk in new.items() if i in positions and positions[i].shape == walk.xy_m.shape]
        grown = _grown_points_of(new, recordings, walks, positions, offline, config, floor_names)
        moved_median = float(np.median(moved)) if moved else math.nan
        iterations.append({"iteration": iteration + 1, "points": sum(len(g) for g in grown.values()),
                           "walks": len(grown), "moved_median_m": moved_median,
                           "fix_sigma_m": fix_sigma if not isinstance(fix_sigma, dict) else math.nan})
        if moved and moved_median < config.stop_moved_m:
            break
    if progress is not None:
        progress(total, total, "")
    for i, points in grown.items():
        walks[i].points = len(points)
        walks[i].sigma_median_m = float(np.median(points.xy_sigma_m))
        if building:
            walks[i].floors = ",".join(dict.fromkeys(floor_names[f] for f in points.floor))
    result = merge_radio_maps([radio_map, *(grown[i] for i in sorted(grown))])
    return result, GrowReport(walks, iterations, 0, [offline[i] for i in sorted(offline)])


def _check_building_map(space: FloorPlan | Building, radio_map: RadioMap) -> bool:
    """Whether growing is in a building; refused when the radio map is not the building's."""
    building = isinstance(space, Building)
    if building and not radio_map.has_floors:
        raise MapfilterError("growing in a building needs the building's radio map (radiomap build BUILDING.yaml)")
    if building and list(radio_map.floor_names) != list(space.floor_names):
        raise MapfilterError(f"the radio map's floors ({', '.join(radio_map.floor_names)}) are not the building's "
                             f"({', '.join(space.floor_names)})")
    return building


def _usable_walks(recordings: Sequence[Recording], walks: list[WalkGrowth], config: GrowConfig) -> list[int]:
    """The walks that can be grown (with WiFi, and an IMU unless ``wifi_only``); each other one's
    reason noted in ``walks``."""
    usable = []
    for i, rec in enumerate(recordings):
        if len(rec.wifi) == 0:
            walks[i].skipped = "no WiFi scans"
        elif not _has_imu(rec) and not config.wifi_only:
            walks[i].skipped = "no IMU (WiFi-only walks are not grown)"
        else:
            usable.append(i)
    return usable


def _track_walks(space: FloorPlan | Building, radio_map: RadioMap, config: GrowConfig, fix_sigma, tasks: list,
                 walks: list[WalkGrowth], engine: Engine, progress: Callable[[int, int, str], None] | None,
                 done_before: int, total: int) -> dict[int, OfflineWalk]:
    """One iteration's walks tracked offline (``_grow_walk``): {walk: its offline track}; a walk
    that could not be tracked has its reason in ``walks``."""
    def tick(done: int, _total: int, name: str) -> None:
        if progress is not None:
            progress(done_before + done, total, name)

    new: dict[int, OfflineWalk] = {}
    for _, (i, walk, reason) in run_each(_grow_walk, tasks, engine, common=(space, radio_map, config, fix_sigma),
                                         progress=tick, label=lambda task: task[1].name):
        if walk is None:
            walks[i].skipped = reason
        else:
            new[i] = walk
    return new


def _grown_points_of(new: dict[int, OfflineWalk], recordings: Sequence[Recording], walks: list[WalkGrowth],
                     positions: dict[int, np.ndarray], offline: dict[int, OfflineWalk], config: GrowConfig,
                     floor_names) -> dict[int, RadioMap]:
    """The grown points of each walk tracked this iteration, at its offline track's positions
    (kept in ``positions`` and ``offline`` for the next)."""
    grown = {}
    for i, walk in new.items():
        positions[i], offline[i] = walk.xy_m, walk
        points = grown_points(recordings[i], walk, point_sigma_m(walk, config), floor_names)
        if points is not None:
            grown[i] = points
            walks[i].skipped = ""
        else:
            walks[i].skipped = "no scan with a position"
    return grown


def grown_by_fold(space: FloorPlan | Building, labelled: Sequence[Recording], unlabelled: Sequence[Recording],
                  config: GrowConfig = GrowConfig(), folds: int = 4, base_of=None,
                  progress: Callable[[int, int, str], None] | None = None,
                  engine: Engine | None = None, fold: Sequence[int] | None = None,
                  fold_walks: Sequence[Sequence[Recording]] | None = None,
                  ) -> tuple[list[RadioMap], list[GrowReport], np.ndarray]:
    """Grown points for a leave-one-out evaluation of the ``labelled`` walks that never uses a
    scored walk's labels: (grown points of each fold, its report, the fold of each labelled walk).

    Growing over every labelled walk and then scoring each one leave-one-out leaks its labels:
    the walks grown near it were placed by its points, and their points then stand in for its
    own (it scored better than the walks' true labels: docs/self-training.md). Here the labelled
    walks are split into ``folds`` (walk i in fold i % folds); the unlabelled walks grow once per
    fold over the labelled walks of the other folds; walk i is then scored with its map (the
    other labelled walks) plus ``grown[fold[i]]``, points grown without its labels. A fold's
    base has (folds - 1) / folds of the labelled walks, so this errs on the pessimistic side.

    ``base_of(recordings) -> RadioMap`` builds a base map (default: ``build_radio_map`` on a
    floor, ``sensors.floor_vote.build_building_radio_map`` with each log's header floor in a building).
    ``fold``: each labelled walk's fold (0 .. folds - 1) instead, so that walks that must leave a
    survey together (a route's repetitions) share one. ``fold_walks``: per fold, walks that grow
    only that fold's points, over the same base: a transductive evaluation's scored walks of
    that fold, without their labels (each then scored with ``grown.without_traces([walk])``, its
    own grown points left out).
    """
    if folds < 1:
        raise MapfilterError(f"folds must be at least 1, got {folds}")
    if base_of is None:
        base_of = (lambda recs: _building_base(space, recs)) if isinstance(space, Building) else (
            lambda recs: build_radio_map(recs, space))
    fold = np.arange(len(labelled)) % folds if fold is None else np.asarray(fold, dtype=np.int64)
    if fold.shape != (len(labelled),) or (fold.size and (fold.min() < 0 or fold.max() >= folds)):
        raise ValueError(f"fold: one index in 0..{folds - 1} per labelled walk")
    grown, reports = [], []
    for f in range(folds):
        base = base_of([r for r, g in zip(labelled, fold) if g != f or folds == 1])
        growing = list(unlabelled) + (list(fold_walks[f]) if fold_walks is not None else [])

        def tick(done: int, total: int, name: str, f: int = f) -> None:
            if progress is not None:
                progress(f * total + done, folds * total, name)

        result, report = grow_radio_map(space, base, growing, config, progress=tick, engine=engine)
        grown.append(result.select(result.source == GROWN))
        reports.append(report)
    return grown, reports, fold


def _building_base(building: Building, recordings: Sequence[Recording]) -> RadioMap:
    from mapfilter.sensors.floor_vote import build_building_radio_map

    floors = []
    for rec in recordings:
        index = building.floor_of_log(rec.floor_name, rec.path)
        if index is None:
            raise MapfilterError("the log's header names no floor (FloorName)", rec.path)
        floors.append(index)
    return build_building_radio_map(recordings, floors, building.floor_names)
