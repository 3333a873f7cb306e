"""Many walks through the filter: one task per walk on an ``Engine``, none skipped silently.

Each walk is tracked exactly as ``mapfilter track MAP LOG`` tracks it alone (the config's seed,
its own ``default_rng(seed)``), so a batch track of a walk equals its single-walk track,
wherever the task ran. A walk that fails becomes a ``WalkResult`` with ``status`` "failed" (an
error in its input, e.g. no usable WiFi) or "crashed" (a bug: the exception's type and message)
and the other walks go on. In a building with several floors, results also carry the floors
the track visits and how often it was on the walker's floor. Logs whose header names a floor
the building does not have are refused before any walk runs.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
import traceback
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from mapfilter.config import TrackingConfig
from mapfilter.runtime.dispatch import Engine, run_each
from mapfilter.errors import MapfilterError
from mapfilter.evaluation.metrics import FloorScore, summarise_errors
from mapfilter.evaluation.scoring import score_track
from mapfilter.maps.building import Building
from mapfilter.sensors.floor_vote import check_building_radio_map
from mapfilter.sensors.logs import read_log, read_log_header
from mapfilter.sensors.pathloss import AccessPointTable
from mapfilter.sensors.radiomap import RadioMap
from mapfilter.sensors.recording import Recording, trace_name
from mapfilter.pipeline.tracker import track
from mapfilter.io.tracks import Track

STATUSES = ("ok", "failed", "crashed")


@dataclasses.dataclass(frozen=True)
class BatchSetup:
    """How every walk of a batch is tracked."""

    tracking: TrackingConfig = dataclasses.field(default_factory=TrackingConfig)  # seed included
    strict: bool = False  # refuse a walk with a bad row in a record type it needs (default: skip the row, warn)
    floor: str | None = None  # track every walk on this floor (default: find the floor, or the header's)
    # {measurement source name: its input} (``filter.sources``), weighed besides (or, without WiFi,
    # instead of) the WiFi
    sources: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    start: Any = None  # where every walk started, if known (``pipeline.tracker.WalkStart``)


@dataclasses.dataclass
class WalkResult:
    """One walk of a batch: its tracks and numbers, or why it has none."""

    log_path: Path
    trace: str
    status: str  # ok | failed (the input's fault; reason says why) | crashed (a bug)
    reason: str = ""
    track: Track | None = None  # the offline track when the setup smooths, else the causal one
    causal: Track | None = None  # the causal track (also with smooth)
    n_filter_steps: int = 0
    n_scans_used: int = 0
    collapses: int = 0
    wall_crossings: int = 0
    error_stats: dict[str, float] | None = None  # summarise_errors at the waypoints (None: no ground truth)
    missed_waypoints: int = 0
    runtime_s: float = 0.0
    read_warning: str | None = None  # what the log reader skipped
    floors: list[str] | None = None  # the floors the track visits (a building with several floors)
    header_floor: str | None = None  # the log header's floor (FloorName), if it names one
    floor_score: FloorScore | None = None  # on the walker's floor at the waypoints (several floors)

    @property
    def ok(self) -> bool:
        return self.status == "ok"


def track_walk(building: Building, radio_map: RadioMap | None, access_points: AccessPointTable | None,
               setup: BatchSetup, log_path: Path) -> WalkResult:
    """Track one walk as ``mapfilter track MAP LOG`` does; never raises: a failure is returned as
    the result's status and reason."""
    started = time.perf_counter()
    warned: list[str] = []
    result = WalkResult(Path(log_path), trace_name(log_path), "ok")
    try:
        recording = read_log(log_path, strict=setup.strict, warn=warned.append, building=building)
        _track_into(result, building, recording, radio_map, access_points, setup)
    except MapfilterError as exc:
        result = WalkResult(result.log_path, result.trace, "failed", str(exc))
    except Exception as exc:  # noqa: BLE001 - a bug in one walk must not lose the other walks' work
        where = traceback.extract_tb(exc.__traceback__)[-1]
        result = WalkResult(result.log_path, result.trace, "crashed",
                            f"{type(exc).__name__}: {exc} (at {Path(where.filename).name}:{where.lineno})")
    result.read_warning = warned[0] if warned else None
    result.runtime_s = time.perf_counter() - started
    return result


def _track_into(result: WalkResult, building: Building, recording: Recording, radio_map: RadioMap | None,
                access_points: AccessPointTable | None, setup: BatchSetup) -> None:
    header_floor = building.floor_of_log(recording.floor_name, result.log_path, setup.floor)
    outcome = track(building, recording, radio_map, access_points, setup.tracking, floor=setup.floor,
                    sources=setup.sources, start=setup.start)
    smoothed = outcome.offline is not None
    result.track = outcome.offline if smoothed else outcome.causal
    result.causal = outcome.causal
    result.n_filter_steps, result.n_scans_used = outcome.n_filter_steps, outcome.n_scans_used
    result.collapses = len(outcome.collapses)
    score = score_track(building, recording, result.track, header_floor, causal=not smoothed)
    result.wall_crossings = score.wall_crossings
    if not building.is_single_floor:
        result.floors = score.floors
        result.header_floor = None if header_floor is None else building.floor_names[header_floor]
        result.floor_score = score.floor_score
    if score.errors is not None:
        result.error_stats = summarise_errors(score.errors.errors_m)
        result.missed_waypoints = score.errors.missed


def track_logs(building: Building, log_paths: Sequence[str | os.PathLike], radio_map: RadioMap | None,
               access_points: AccessPointTable | None, setup: BatchSetup, engine: Engine = Engine(),
               progress: Callable[[int, int, str], None] | None = None,
               on_result: Callable[[WalkResult], None] | None = None) -> list[WalkResult]:
    """Track every walk on ``engine``; results in the order of ``log_paths``.

    Before any walk runs, every log's header is read: one whose floor (``FloorName``) the
    building does not have is refused with a ``MapfilterError`` naming it (a wrong building for
    these logs, not a walk to skip); a header that cannot be read is left to its walk, which then
    fails as any unreadable log does. ``on_result`` sees each result as it arrives (to write its
    track file at once, so that an interrupted batch keeps the walks already done).
    """
    paths = _distinct_paths(log_paths)
    if radio_map is None and access_points is None and not setup.sources:
        raise MapfilterError("nothing to weigh the particles by: give a radio map or an access-point table (or a "
                             "measurement source's input)")
    if not building.is_single_floor and setup.floor is None and (radio_map is not None or access_points is not None):
        if radio_map is None:
            raise MapfilterError("tracking across floors needs a building's radio map (or give the floor)")
        check_building_radio_map(radio_map, building.floor_names)
    if setup.floor is not None:
        building.floor_index(setup.floor)
    for path in paths:
        try:
            floor_name = read_log_header(path).get("FloorName") or None
        except MapfilterError:
            continue
        building.floor_of_log(floor_name, path, setup.floor)
    results: list[WalkResult | None] = [None] * len(paths)
    for i, result in run_each(track_walk, paths, engine, common=(building, radio_map, access_points, setup),
                              progress=progress, label=lambda path: path.name):
        results[i] = result
        if on_result is not None:
            on_result(result)
    return results


def _distinct_paths(log_paths: Sequence[str | os.PathLike]) -> list[Path]:
    paths = [Path(p) for p in log_paths]
    names = [trace_name(p) for p in paths]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise MapfilterError(f"two logs share the trace name {repeated[0]}: their track files would collide")
    return paths


SUMMARY_COLUMNS = ("trace", "status", "reason", "track_file", "filter_steps", "scans_used", "collapses",
                   "wall_crossings", "waypoints", "missed_waypoints", "mean_m", "median_m", "p75_m", "max_m",
                   "runtime_s", "skipped_rows", "log")


# a building's summary.csv: the floors the track visits, the header's floor, and the share of
# the waypoints (with an estimate) at which the track was on the walker's floor
BUILDING_SUMMARY_COLUMNS = (SUMMARY_COLUMNS[:4] + ("header_floor", "floors") + SUMMARY_COLUMNS[4:-3]
                            + ("floor_accuracy",) + SUMMARY_COLUMNS[-3:])


def summary_row(result: WalkResult, track_file: str | None, columns: Sequence[str] = SUMMARY_COLUMNS) -> dict:
    """One line of a batch's summary.csv: ``columns`` (``BUILDING_SUMMARY_COLUMNS`` in a building)."""
    stats = result.error_stats or {}

    def stat(name: str) -> float | None:
        value = stats.get(name)
        return None if value is None or math.isnan(value) else value

    row = {"trace": result.trace, "status": result.status, "reason": result.reason, "track_file": track_file,
           "filter_steps": result.n_filter_steps, "scans_used": result.n_scans_used,
           "collapses": result.collapses, "wall_crossings": result.wall_crossings,
           "waypoints": stats.get("n"), "missed_waypoints": result.missed_waypoints if stats else None,
           "mean_m": stat("mean"), "median_m": stat("median"), "p75_m": stat("p75"), "max_m": stat("max"),
           "runtime_s": result.runtime_s, "skipped_rows": result.read_warning, "log": str(result.log_path),
           "header_floor": result.header_floor,
           "floors": None if result.floors is None else ";".join(result.floors),
           "floor_accuracy": None if result.floor_score is None or not result.floor_score.n_judged
           else result.floor_score.accuracy}
    return {name: row[name] for name in columns}
