"""Every method on the same walks in one run: the engine behind ``mapfilter evaluate``.

Methods (same inputs, same output: a track; errors at the ground-truth waypoint times,
causal: each method's latest estimate at or before the waypoint):

=============  ==========================================================================
``pf``         particle filter: map + WiFi + PDR (the project's method)
``pf-nomap``   the same with the walls ignored (what the map buys)
``pf-nopdr``   the same with a constant-velocity motion model instead of PDR
``kwnn``       K-weighted nearest-neighbour fixes (Chang et al.), one per scan
``pdr-kwnn``   KWNN with the PDR-predicted position and heading in the distance (Chang et al.)
``kf``         Kalman filter on the KWNN fixes with PDR steps as input (Evennou & Marx; Seitz)
``pdr``        dead reckoning from the first fix
``ls``         least-squares trilateration per scan (needs an access-point table)
=============  ==========================================================================

With ``leave_one_out`` the radio map (and the fitted access-point table) of each walk is
built from the *other* walks only, as the ILC evaluation needs. The smoothed PF track
(``pf-smooth``, offline) is reported as a separate, non-causal row.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from mapfilter.engine import Engine, run_each
from mapfilter.errors import MapfilterError
from mapfilter.evaluation.baselines import kalman_track, pdr_kwnn_track, pdr_track
from mapfilter.evaluation.diagnostics import DIAGNOSTIC_COLUMNS, walk_diagnostics
from mapfilter.evaluation.metrics import errors_at_waypoints, summarise_errors
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import count_wall_crossings
from mapfilter.sensors.ilc import LogReadWarning, read_ilc
from mapfilter.sensors.pathloss import AccessPointTable, estimate_access_points, least_squares_position, match_scan
from mapfilter.sensors.pdr import detect_steps
from mapfilter.sensors.radiomap import RadioMap, build_radio_map, kwnn_fix_many
from mapfilter.sensors.recording import Recording, trace_name
from mapfilter.sensors.wifi import scans_of
from mapfilter.tracking import TrackingConfig, WifiMeasurements, calibrated_fix_sigma_m, track_recording
from mapfilter.trackio import Track

ALL_METHODS = ("pf", "pf-nomap", "pf-nopdr", "kwnn", "pdr-kwnn", "kf", "pdr", "ls")
PF_METHODS = {"pf": {}, "pf-nomap": {"use_map": False}, "pf-nopdr": {"motion": "cv"}}


@dataclasses.dataclass(frozen=True)
class EvaluationSetup:
    """What every walk is evaluated with."""

    methods: tuple[str, ...] = ALL_METHODS
    radio_map_path: Path | None = None  # one radio map for all walks
    ap_table_path: Path | None = None  # one access-point table for all walks
    leave_one_out: bool = False  # radio map (and fitted APs for ls) of each walk from the other walks
    fit_aps: bool = False  # with leave_one_out: fit an AP table per walk even if no method asks for it
    smooth: bool = False  # also report the smoothed PF track (pf-smooth)
    seed: int = 0
    strict: bool = False  # refuse a walk with a bad row in a record type it needs (default: skip the row, warn)
    tracking: TrackingConfig = dataclasses.field(default_factory=TrackingConfig)


@dataclasses.dataclass
class MethodResult:
    """One method on one walk."""

    method: str
    trace: str
    track: Track
    errors_m: np.ndarray
    missed: int
    wall_crossings: int
    collapses: int
    runtime_s: float
    causal: bool = True
    diagnostics: dict[str, float] = dataclasses.field(default_factory=dict)  # the walk's (same for every method)


@dataclasses.dataclass
class AllWalks:
    """Leave-one-out material built once from every walk: each walk's fold removes its share."""

    radio_map: RadioMap
    ap_table: AccessPointTable | None  # APs fitted on every walk (None when no method needs them)


def evaluate_trace(floorplan: FloorPlan, log_paths: Sequence[Path], index: int, setup: EvaluationSetup,
                   all_walks: AllWalks | None = None) -> list[MethodResult]:
    """Run every method of ``setup`` on walk ``log_paths[index]``.

    With leave-one-out, ``all_walks`` (built from every walk) loses this walk's reference
    points. Random draws come from ``default_rng([seed, index, method])``, so the result does
    not depend on how walks are spread over processes.
    """
    recording = read_ilc(log_paths[index], strict=setup.strict)
    if not recording.has_ground_truth:
        raise MapfilterError("the log has no waypoints to evaluate against", log_paths[index])
    radio_map, ap_table = _wifi_sources(recording, setup, all_walks)
    scans = scans_of(recording)
    try:
        steps = detect_steps(recording, setup.tracking.pdr)
    except MapfilterError:
        steps = None  # no usable IMU: the PDR methods are left out, kf and pdr-kwnn go without steps
    scan_t = np.array([s.t_s for s in scans])
    tracking = setup.tracking
    if radio_map is not None and tracking.fix_sigma_m is None and tracking.fingerprint_model in ("fix", "blend"):
        # calibrate once for the three pf variants, not once each
        tracking = dataclasses.replace(tracking, fix_sigma_m=calibrated_fix_sigma_m(radio_map, tracking.kwnn_k))
    results: list[MethodResult] = []
    # the pf variants share one set of fingerprint measurements (fixes, radio-map likelihood: no
    # state); trilateration models may adapt during a run, so each run makes its own
    wifi = None
    if any(m in PF_METHODS for m in setup.methods) and radio_map is not None:
        wifi = WifiMeasurements(scans, radio_map, None, floorplan, tracking, str(log_paths[index]))
    fixes = None
    if wifi is not None and wifi.kwnn_xy_m is not None and tracking.kwnn_min_rssi_dbm is None:
        fixes = wifi.kwnn_xy_m  # the same KWNN fixes the filter weighs: made once
    elif radio_map is not None:  # the baselines keep plain KWNN (Chang et al.) over every reading
        fixes = kwnn_fix_many(radio_map, radio_map.scan_matrix(scans), k=setup.tracking.kwnn_k).xy_m
    elif ap_table is not None:
        fixes = _ls_fixes(ap_table, scans)

    def add(method: str, make: Callable[[], tuple[Track, int]], causal: bool = True) -> None:
        started = time.perf_counter()
        track, collapses = make()
        runtime = time.perf_counter() - started
        err = errors_at_waypoints(track.t_s, track.xy_m, recording.waypoint_t_s, recording.waypoint_xy_m, causal)
        results.append(MethodResult(method, recording.name, track, err.errors_m, err.missed,
                                    count_wall_crossings(floorplan, track.xy_m) if len(track) else 0,
                                    collapses, runtime, causal))

    for method in setup.methods:
        if method in PF_METHODS:
            if radio_map is None and ap_table is None:
                continue
            if steps is None and PF_METHODS[method].get("motion", "pdr") == "pdr":
                continue
            config = dataclasses.replace(tracking, smooth=setup.smooth and method == "pf", **PF_METHODS[method])
            rng = np.random.default_rng([setup.seed, index, ALL_METHODS.index(method)])
            outcome = track_recording(floorplan, recording, radio_map, ap_table if radio_map is None else None,
                                      config, rng, steps=steps, wifi=wifi)
            add(method, lambda: (outcome.track, len(outcome.collapses)))
            results[-1].runtime_s = outcome.runtime_s
            if outcome.smoothed is not None:
                add("pf-smooth", lambda: (outcome.smoothed, len(outcome.collapses)), causal=False)
                results[-1].runtime_s = outcome.runtime_s
        elif method == "kwnn" and radio_map is not None:
            add(method, lambda: (_fix_track(scan_t, fixes, "kwnn"), 0))
        elif method == "pdr-kwnn" and radio_map is not None:
            add(method, lambda: (pdr_kwnn_track(radio_map, scans, steps), 0))
        elif method == "kf" and fixes is not None:
            ok = np.all(np.isfinite(fixes), axis=1)
            add(method, lambda: (kalman_track(scan_t[ok], fixes[ok], steps), 0))
        elif method == "pdr" and fixes is not None and steps is not None:
            ok = np.flatnonzero(np.all(np.isfinite(fixes), axis=1))
            if ok.size:
                add(method, lambda: (pdr_track(steps, scan_t[ok[0]], fixes[ok[0]]), 0))
        elif method == "ls" and ap_table is not None:
            add(method, lambda: (_fix_track(scan_t, _ls_fixes(ap_table, scans), "ls"), 0))
    diagnostics = walk_diagnostics(recording, scan_t, fixes, radio_map, steps)
    for result in results:
        result.diagnostics = diagnostics
    return results


def _wifi_sources(recording: Recording, setup: EvaluationSetup,
                  all_walks: AllWalks | None) -> tuple[RadioMap | None, AccessPointTable | None]:
    radio_map = RadioMap.load(setup.radio_map_path) if setup.radio_map_path else None
    ap_table = AccessPointTable.read_csv(setup.ap_table_path) if setup.ap_table_path else None
    if setup.leave_one_out:
        if all_walks is None:
            raise ValueError("leave-one-out needs the radio map of all walks")
        radio_map = _drop_unheard_aps(all_walks.radio_map.without_traces([recording.name]))
        if len(radio_map) == 0:
            raise MapfilterError("leave-one-out needs other walks with waypoints and WiFi", recording.path)
        if ap_table is None and all_walks.ap_table is not None:
            ap_table = _leave_one_out_aps(all_walks, radio_map, recording.name)
    return radio_map, ap_table


def _needs_fitted_aps(setup: EvaluationSetup) -> bool:
    return setup.leave_one_out and setup.ap_table_path is None and (setup.fit_aps or "ls" in setup.methods)


def _leave_one_out_aps(all_walks: AllWalks, fold_map: RadioMap, trace: str) -> AccessPointTable:
    """The AP table fitted without ``trace``: an AP's fit depends only on its own observations,
    so only the APs this walk heard are fitted again (on the fold's radio map); the others keep
    their all-walks fit, which is exactly what a fit without this walk gives them."""
    full = all_walks.radio_map
    mine = np.isin(full.trace, [i for i, name in enumerate(full.source_traces) if name == trace])
    heard = set(np.array(full.ap_keys)[~np.all(np.isnan(full.rssi_dbm[mine]), axis=0)].tolist())
    columns = [j for j, key in enumerate(fold_map.ap_keys) if key in heard]
    table = all_walks.ap_table
    keep = [i for i, key in enumerate(table.keys) if key not in heard]
    parts = [_select_aps(table, keep)]
    if columns:
        subset = RadioMap(fold_map.xy_m, [fold_map.ap_keys[j] for j in columns], fold_map.rssi_dbm[:, columns],
                          fold_map.t_s, fold_map.trace, fold_map.source_traces, fold_map.floor_name)
        try:
            parts.append(estimate_access_points(subset))
        except MapfilterError:
            pass  # none of this walk's APs can be fitted from the other walks
    return _concat_aps(parts)


def _select_aps(table: AccessPointTable, rows: list[int]) -> AccessPointTable:
    return AccessPointTable([table.bssid[i] for i in rows], [table.band[i] for i in rows], table.xy_m[rows],
                            table.c_dbm[rows], table.n[rows], table.alpha_db_per_m[rows], table.d_max_m[rows])


def _concat_aps(tables: list[AccessPointTable]) -> AccessPointTable:
    return AccessPointTable(
        [b for t in tables for b in t.bssid], [b for t in tables for b in t.band],
        np.concatenate([t.xy_m for t in tables]).reshape(-1, 2),
        *(np.concatenate([getattr(t, f) for t in tables]) for f in ("c_dbm", "n", "alpha_db_per_m", "d_max_m")))


def _drop_unheard_aps(radio_map: RadioMap) -> RadioMap:
    """Without the walk under test, some APs are heard nowhere: drop them, as a radio map built
    from the other walks alone would never have had them."""
    return radio_map.select_aps(~np.all(np.isnan(radio_map.rssi_dbm), axis=0))


def _fix_track(scan_t: np.ndarray, fixes: np.ndarray, name: str) -> Track:
    ok = np.all(np.isfinite(fixes), axis=1)
    return Track(scan_t[ok], fixes[ok], name=name)


def _ls_fixes(ap_table: AccessPointTable, scans) -> np.ndarray:
    fixes = np.full((len(scans), 2), np.nan)
    for i, scan in enumerate(scans):
        if match_scan(ap_table, scan)[0].size >= 3:
            fixes[i] = least_squares_position(ap_table, scan)
    return fixes


# ---- many walks ------------------------------------------------------------------------------
def checked_log_paths(log_paths: Sequence[str | os.PathLike]) -> list[Path]:
    """The logs as paths; ``MapfilterError`` for a missing file or two logs with one trace name
    (walks are told apart by name: leave-one-out drops a walk's points by it)."""
    paths = [Path(p) for p in log_paths]
    for path in paths:
        if not path.is_file():
            raise MapfilterError("file not found", path)
    names = [trace_name(p) for p in paths]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise MapfilterError(f"two logs share the trace name {repeated[0]}: walks are told apart by name")
    return paths


@dataclasses.dataclass
class Evaluation:
    """All methods on all walks."""

    results: list[MethodResult]
    n_traces: int
    wall_time_s: float
    read_warnings: list[str] = dataclasses.field(default_factory=list)  # rows the log reader skipped, per log

    def methods(self) -> list[str]:
        seen: list[str] = []
        for r in self.results:
            if r.method not in seen:
                seen.append(r.method)
        return seen

    def errors_by_method(self) -> dict[str, np.ndarray]:
        return {m: np.concatenate([r.errors_m for r in self.results if r.method == m]) for m in self.methods()}

    def summary_rows(self) -> list[dict]:
        """One row per method: error statistics over all waypoints of all walks, and totals."""
        rows = []
        for method in self.methods():
            mine = [r for r in self.results if r.method == method]
            stats = summarise_errors(np.concatenate([r.errors_m for r in mine]))
            rows.append({"method": method, **stats, "missed": sum(r.missed for r in mine),
                         "wall_crossings": sum(r.wall_crossings for r in mine),
                         "collapses": sum(r.collapses for r in mine),
                         "runtime_s": sum(r.runtime_s for r in mine), "traces": len(mine),
                         "causal": mine[0].causal})
        return rows

    def walk_rows(self) -> list[dict]:
        """One row per walk: why it went well or wrong (``evaluation.diagnostics``) and each
        method's mean error on it."""
        rows: dict[str, dict] = {}
        for r in self.results:
            row = rows.setdefault(r.trace, {"trace": r.trace, **{c: r.diagnostics.get(c, math.nan)
                                                                  for c in DIAGNOSTIC_COLUMNS}})
            row[f"{r.method} mean"] = float(r.errors_m.mean()) if r.errors_m.size else math.nan
        return list(rows.values())

    def trace_rows(self) -> list[dict]:
        """One row per walk and method."""
        return [{"trace": r.trace, "method": r.method, **summarise_errors(r.errors_m), "missed": r.missed,
                 "wall_crossings": r.wall_crossings, "collapses": r.collapses, "runtime_s": r.runtime_s}
                for r in self.results]


def evaluate_logs(floorplan: FloorPlan, log_paths: Sequence[str | os.PathLike], setup: EvaluationSetup,
                  jobs: int = 1, progress: Callable[[int, int, str], None] | None = None,
                  map_path: str | os.PathLike | None = None, engine: Engine | None = None) -> Evaluation:
    """Evaluate every method on every walk, one walk per task on ``engine`` (default:
    ``Engine(jobs)``: serial for 1, else ``jobs`` local Dask worker processes). Each walk seeds
    its own generator, so the numbers do not depend on the engine. ``map_path`` is not needed
    any more (the map itself is sent to the workers) and is ignored."""
    engine = engine if engine is not None else Engine(jobs=jobs)
    paths = checked_log_paths(log_paths)
    unknown = [m for m in setup.methods if m not in ALL_METHODS]
    if unknown:
        raise MapfilterError(f"unknown method(s) {', '.join(unknown)}: choose from {', '.join(ALL_METHODS)}")
    if setup.radio_map_path is None and setup.ap_table_path is None and not setup.leave_one_out:
        raise MapfilterError("no WiFi source: give a radio map, an access-point table or leave-one-out")
    if setup.radio_map_path is not None and setup.leave_one_out:
        raise MapfilterError("give a radio map or leave-one-out, not both (leave-one-out builds its own)")
    started = time.perf_counter()
    all_walks = None
    read_warnings: list[str] = []
    if setup.leave_one_out:
        if len(paths) < 2:
            raise MapfilterError("leave-one-out needs at least two logs")
        with _collect_read_warnings(read_warnings):
            recordings = [read_ilc(p, strict=setup.strict) for p in paths]
        radio_map = build_radio_map(recordings, floorplan)
        all_walks = AllWalks(radio_map, estimate_access_points(radio_map) if _needs_fitted_aps(setup) else None)
    results: list[list[MethodResult] | None] = [None] * len(paths)
    # the path list goes with the shared inputs (sent once), each task carries only its index
    for i, (per_trace, warned) in run_each(_evaluate_walk, range(len(paths)), engine,
                                           common=(floorplan, setup, all_walks, paths),
                                           progress=progress, label=lambda index: paths[index].name):
        results[i] = per_trace
        read_warnings.extend(w for w in warned if w not in read_warnings)
    flat = [r for per_trace in results for r in (per_trace or [])]
    return Evaluation(flat, len(paths), time.perf_counter() - started, read_warnings)


def _evaluate_walk(floorplan: FloorPlan, setup: EvaluationSetup, all_walks: AllWalks | None, paths: list[Path],
                   index: int) -> tuple[list[MethodResult], list[str]]:
    """One task: ``evaluate_trace`` on walk ``index``, with the reader's warnings brought back
    (a worker's warnings would otherwise end, if anywhere, in the worker's log)."""
    warned: list[str] = []
    with _collect_read_warnings(warned):
        results = evaluate_trace(floorplan, paths, index, setup, all_walks)
    return results, warned


class _collect_read_warnings(warnings.catch_warnings):
    """Append the message of every ``LogReadWarning`` raised inside to ``into``; others pass."""

    def __init__(self, into: list[str]) -> None:
        super().__init__(record=True)
        self.into = into

    def __enter__(self):
        self.caught = super().__enter__()
        warnings.simplefilter("always", LogReadWarning)
        return self.caught

    def __exit__(self, *exc_info):
        super().__exit__(*exc_info)
        for w in self.caught:
            if issubclass(w.category, LogReadWarning):
                message = str(w.message)
                if message not in self.into:
                    self.into.append(message)
            else:
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)


def nan_to_none(value):
    """JSON has no NaN: write null."""
    if isinstance(value, float) and math.isnan(value):
        return None
    return value
