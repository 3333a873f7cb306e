"""Many walks through the filter: one task per walk on an ``Engine``, none skipped silently.

Each walk is tracked exactly as ``mapfilter track MAP LOG --seed S`` tracks it alone (its own
``default_rng(seed)``), so a batch track of a walk equals its single-walk track, wherever the
task ran. A walk that fails becomes a ``WalkResult`` with ``status`` "failed" (an error in
its input, e.g. no usable WiFi) or "crashed" (a bug: the exception's type and message) and
the other walks go on.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from mapfilter.engine import Engine, run_each
from mapfilter.errors import MapfilterError
from mapfilter.evaluation.metrics import errors_at_waypoints, summarise_errors
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import count_wall_crossings
from mapfilter.sensors.ilc import read_ilc
from mapfilter.sensors.pathloss import AccessPointTable
from mapfilter.sensors.radiomap import RadioMap
from mapfilter.sensors.recording import trace_name
from mapfilter.tracking import TrackingConfig, track_recording
from mapfilter.trackio import Track

STATUSES = ("ok", "failed", "crashed")


@dataclasses.dataclass(frozen=True)
class BatchSetup:
    """How every walk of a batch is tracked."""

    tracking: TrackingConfig = dataclasses.field(default_factory=TrackingConfig)
    seed: int = 0  # every walk uses default_rng(seed), as `mapfilter track --seed` does for one walk
    strict: bool = False  # refuse a walk with a bad row in a record type it needs (default: skip the row, warn)


@dataclasses.dataclass
class WalkResult:
    """One walk of a batch: its track and numbers, or why it has none."""

    log_path: Path
    trace: str
    status: str  # ok | failed (the input's fault; reason says why) | crashed (a bug)
    reason: str = ""
    track: Track | None = None  # the smoothed track when the setup smooths, else the causal one
    n_filter_steps: int = 0
    n_scans_used: int = 0
    collapses: int = 0
    wall_crossings: int = 0
    error_stats: dict[str, float] | None = None  # summarise_errors at the waypoints (None: no ground truth)
    missed_waypoints: int = 0
    runtime_s: float = 0.0
    read_warning: str | None = None  # what the log reader skipped

    @property
    def ok(self) -> bool:
        return self.status == "ok"


def track_walk(floorplan: FloorPlan, radio_map: RadioMap | None, ap_table: AccessPointTable | None,
               setup: BatchSetup, log_path: Path) -> WalkResult:
    """Track one walk; never raises: a failure is returned as the result's status and reason."""
    started = time.perf_counter()
    warned: list[str] = []
    result = WalkResult(Path(log_path), trace_name(log_path), "ok")
    try:
        recording = read_ilc(log_path, strict=setup.strict, warn=warned.append)
        outcome = track_recording(floorplan, recording, radio_map, ap_table, setup.tracking,
                                  np.random.default_rng(setup.seed))
    except MapfilterError as exc:
        result.status, result.reason = "failed", str(exc)
    except Exception as exc:  # noqa: BLE001 - a bug in one walk must not lose the other walks' work
        where = traceback.extract_tb(exc.__traceback__)[-1]
        result.status = "crashed"
        result.reason = f"{type(exc).__name__}: {exc} (at {Path(where.filename).name}:{where.lineno})"
    else:
        track = outcome.smoothed if setup.tracking.smooth else outcome.track
        result.track = track
        result.n_filter_steps, result.n_scans_used = outcome.n_filter_steps, outcome.n_scans_used
        result.collapses = len(outcome.collapses)
        result.wall_crossings = count_wall_crossings(floorplan, track.xy_m) if len(track) else 0
        if recording.has_ground_truth:
            err = errors_at_waypoints(track.t_s, track.xy_m, recording.waypoint_t_s, recording.waypoint_xy_m,
                                      causal=not setup.tracking.smooth)
            result.error_stats = summarise_errors(err.errors_m)
            result.missed_waypoints = err.missed
    result.read_warning = warned[0] if warned else None
    result.runtime_s = time.perf_counter() - started
    return result


def track_logs(floorplan: FloorPlan, log_paths: Sequence[str | os.PathLike], radio_map: RadioMap | None,
               ap_table: AccessPointTable | None, setup: BatchSetup, engine: Engine = Engine(),
               progress: Callable[[int, int, str], None] | None = None,
               on_result: Callable[[WalkResult], None] | None = None) -> list[WalkResult]:
    """Track every walk on ``engine``; results in the order of ``log_paths``.

    ``on_result`` sees each result as it arrives (to write its track file at once, so that an
    interrupted batch keeps the walks already done).
    """
    paths = [Path(p) for p in log_paths]
    names = [trace_name(p) for p in paths]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise MapfilterError(f"two logs share the trace name {repeated[0]}: their track files would collide")
    if radio_map is None and ap_table is None:
        raise MapfilterError("no WiFi source: give a radio map or an access-point table")
    results: list[WalkResult | None] = [None] * len(paths)
    for i, result in run_each(track_walk, paths, engine, common=(floorplan, radio_map, ap_table, setup),
                              progress=progress, label=lambda path: path.name):
        results[i] = result
        if on_result is not None:
            on_result(result)
    return results


SUMMARY_COLUMNS = ("trace", "status", "reason", "track_file", "filter_steps", "scans_used", "collapses",
                   "wall_crossings", "waypoints", "missed_waypoints", "mean_m", "median_m", "p75_m", "max_m",
                   "runtime_s", "skipped_rows", "log")


def summary_row(result: WalkResult, track_file: str | None) -> dict:
    """One line of a batch's summary.csv."""
    stats = result.error_stats or {}

    def stat(name: str) -> float | None:
        value = stats.get(name)
        return None if value is None or math.isnan(value) else value

    return {"trace": result.trace, "status": result.status, "reason": result.reason, "track_file": track_file,
            "filter_steps": result.n_filter_steps, "scans_used": result.n_scans_used,
            "collapses": result.collapses, "wall_crossings": result.wall_crossings,
            "waypoints": stats.get("n"), "missed_waypoints": result.missed_waypoints if stats else None,
            "mean_m": stat("mean"), "median_m": stat("median"), "p75_m": stat("p75"), "max_m": stat("max"),
            "runtime_s": result.runtime_s, "skipped_rows": result.read_warning, "log": str(result.log_path)}
