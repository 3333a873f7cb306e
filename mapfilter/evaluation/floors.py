"""Evaluation in a building: errors and floor accuracy per method (``mapfilter evaluate
BUILDING.yaml LOGS``).

Every walk's true floor is its log header's (``FloorName``). The methods:

- ``pf``: the particle filter with the floor in its state (``floortracking.track_building``),
  the floor not given;
- ``pf-floor``: the same filter on the true floor (the floor given): the reference for what
  finding the floor costs in horizontal error; its floor accuracy is 1 by construction;
- ``kwnn``: per scan, the floor of the causal WiFi floor HMM (``sensors.floors``: forward
  probabilities of the KWNN floor vote) and the KWNN fix from that floor's fingerprints;
- ``pf-smooth`` (with ``--smooth``, offline, not causal): ``pf``'s offline track, its floor
  decided from the whole walk (``floortracking.whole_walk_floors``), each floor's stretch placed
  and map-matched on that floor (the lineage where a stretch has no steps).

``score_building_track`` scores one track of one walk as ``mapfilter track BUILDING.yaml LOG``
(one walk or ``--out-dir``) reports it.

``floor_accuracy`` is the share of waypoints (with an estimate) at which the method's causal
track is on the true floor (``pf-smooth``: its row nearest in time); errors are horizontal, each row compared in its own floor's frame.
With leave-one-out, each walk's radio map is the building's radio map without that walk; the
fix Gaussian of each floor is calibrated once from the floor's whole radio map (cross-validating
it again for every walk costs tens of seconds a walk; ``tools/sweep_ilc.py`` does the same).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from mapfilter.engine import Engine, run_each
from mapfilter.errors import MapfilterError
from mapfilter.evaluation.comparison import (Evaluation, EvaluationSetup, MethodResult, _collect_read_warnings,
                                              checked_log_paths)
from mapfilter.evaluation.metrics import FloorScore, WaypointErrors, errors_at_waypoints, floor_at_waypoints
from mapfilter.floortracking import track_building
from mapfilter.maps.building import Building
from mapfilter.maps.walls import count_wall_crossings
from mapfilter.sensors.floors import (build_building_radio_map, floor_hmm, floor_vote_log_likelihood,
                                     load_building_radio_map)
from mapfilter.sensors.ilc import read_ilc
from mapfilter.sensors.pdr import detect_steps
from mapfilter.sensors.radiomap import RadioMap, kwnn_fix_many
from mapfilter.sensors.recording import Recording
from mapfilter.sensors.wifi import scans_of
from mapfilter.tracking import calibrated_fix_sigma_m
from mapfilter.trackio import Track

BUILDING_METHODS = ("pf", "pf-floor", "kwnn")


@dataclasses.dataclass
class FloorMethodResult(MethodResult):
    """One method on one walk in a building: also how often it was on the right floor."""

    floor_score: FloorScore | None = None


@dataclasses.dataclass
class BuildingEvaluation(Evaluation):
    """All methods on all walks of a building; summary rows carry ``floor_accuracy``."""

    def summary_rows(self) -> list[dict]:
        rows = super().summary_rows()
        for row in rows:
            scores = [r.floor_score for r in self.results if r.method == row["method"] and r.floor_score]
            judged = sum(s.n_judged for s in scores)
            row["floor_accuracy"] = sum(s.n_right for s in scores) / judged if judged else float("nan")
        return rows

    def trace_rows(self) -> list[dict]:
        rows = super().trace_rows()
        for row, result in zip(rows, self.results):
            row["floor_accuracy"] = result.floor_score.accuracy if result.floor_score else float("nan")
        return rows


def evaluate_building_logs(building: Building, log_paths: Sequence[str | Path], setup: EvaluationSetup,
                           engine: Engine | None = None,
                           progress: Callable[[int, int, str], None] | None = None) -> BuildingEvaluation:
    """Every method of ``setup`` that a building supports (``BUILDING_METHODS``) on every walk."""
    engine = engine if engine is not None else Engine()
    paths = checked_log_paths(log_paths)
    methods = tuple(m for m in setup.methods if m in BUILDING_METHODS)
    if not methods:
        raise MapfilterError(f"in a building, evaluate compares {', '.join(BUILDING_METHODS)}: none was asked for")
    if setup.ap_table_path is not None:
        raise MapfilterError("a building is evaluated with a building's radio map, not an access-point table")
    if (setup.radio_map_path is None) == (not setup.leave_one_out):
        raise MapfilterError("give a building's radio map (--radiomap) or --leave-one-out, one of the two")
    started = time.perf_counter()
    read_warnings: list[str] = []
    with _collect_read_warnings(read_warnings):
        recordings = [read_ilc(p, strict=setup.strict) for p in paths]
    true_floors = []
    for rec, path in zip(recordings, paths):
        index = building.floor_of_log(rec.floor_name, path)
        if index is None:
            raise MapfilterError("the log's header names no floor (FloorName): its floor cannot be judged", path)
        true_floors.append(index)
    if setup.leave_one_out:
        if len(paths) < 2:
            raise MapfilterError("leave-one-out needs at least two logs")
        radio_map = build_building_radio_map(recordings, true_floors, building.floor_names)
    else:
        radio_map = load_building_radio_map(setup.radio_map_path, building.floor_names)
    sigma = None
    if setup.tracking.fix_sigma_m is None:
        sigma = {name: calibrated_fix_sigma_m(radio_map.floor_map(i), setup.tracking.kwnn_k)
                 for i, name in enumerate(building.floor_names)}
    setup = dataclasses.replace(setup, methods=methods)
    results: list[list[FloorMethodResult] | None] = [None] * len(paths)
    for i, per_trace in run_each(_evaluate_walk, range(len(paths)), engine,
                                 common=(building, setup, radio_map, sigma, paths, true_floors),
                                 progress=progress, label=lambda index: paths[index].name):
        results[i] = per_trace
    flat = [r for per_trace in results for r in (per_trace or [])]
    return BuildingEvaluation(flat, len(paths), time.perf_counter() - started, read_warnings)


def _evaluate_walk(building: Building, setup: EvaluationSetup, radio_map: RadioMap, sigma: dict | None,
                   paths: list[Path], true_floors: list[int], index: int) -> list[FloorMethodResult]:
    recording = read_ilc(paths[index], strict=setup.strict, warn=lambda message: None)
    if not recording.has_ground_truth:
        raise MapfilterError("the log has no waypoints to evaluate against", paths[index])
    if setup.leave_one_out:
        radio_map = radio_map.without_traces([recording.name])
    truth = building.floor_names[true_floors[index]]
    results: list[FloorMethodResult] = []

    def add(method: str, track: Track, collapses: int, runtime_s: float, causal: bool = True) -> None:
        err = errors_at_waypoints(track.t_s, track.xy_m, recording.waypoint_t_s, recording.waypoint_xy_m, causal)
        results.append(FloorMethodResult(method, recording.name, track, err.errors_m, err.missed,
                                         building_wall_crossings(building, track.xy_m, track.floor),
                                         collapses, runtime_s, causal,
                                         floor_score=floor_at_waypoints(track.t_s, track.floor,
                                                                        recording.waypoint_t_s, truth, causal)))

    try:
        has_steps = setup.tracking.motion != "pdr" or len(detect_steps(recording, setup.tracking.pdr)) > 0
    except MapfilterError:
        has_steps = False  # no usable IMU (a WiFi-only walk): the PDR filter is left out, as in comparison
    for method in setup.methods:
        rng = np.random.default_rng([setup.seed, index, BUILDING_METHODS.index(method)])
        if method in ("pf", "pf-floor"):
            if not has_steps:
                continue
            config = dataclasses.replace(setup.tracking, smooth=setup.smooth and method == "pf")
            outcome = track_building(building, recording, radio_map, config, rng,
                                     floor=truth if method == "pf-floor" else None, fix_sigma_per_floor_m=sigma)
            add(method, outcome.track, len(outcome.collapses), outcome.runtime_s)
            if outcome.smoothed is not None:
                add("pf-smooth", outcome.smoothed, len(outcome.collapses), outcome.runtime_s, causal=False)
        elif method == "kwnn":
            started = time.perf_counter()
            add(method, kwnn_floor_track(radio_map, scans_of(recording), setup.tracking.kwnn_k,
                                         building.floor_names), 0, time.perf_counter() - started)
    return results


def kwnn_floor_track(radio_map: RadioMap, scans, k: int, floor_names: list[str]) -> Track:
    """KWNN across floors: each scan on the causal floor HMM's floor, fixed from that floor's
    fingerprints; scans without a fix there are left out."""
    scan_t = np.array([s.t_s for s in scans])
    path = floor_hmm(floor_vote_log_likelihood(radio_map, radio_map.scan_matrix(scans), k=k), scan_t)
    floor = path.causal_floor()
    xy = np.full((len(scans), 2), np.nan)
    for f in np.unique(floor):
        on = np.flatnonzero(floor == f)
        sub = radio_map.floor_map(int(f))
        if len(sub):
            xy[on] = kwnn_fix_many(sub, sub.scan_matrix([scans[i] for i in on]), k=k).xy_m
    ok = np.all(np.isfinite(xy), axis=1)
    return Track(scan_t[ok], xy[ok], floor=[floor_names[f] for f in floor[ok]], name="kwnn")


@dataclasses.dataclass(frozen=True)
class BuildingTrackScore:
    """One building track of one walk, as ``mapfilter track BUILDING.yaml LOG`` reports it."""

    floors: list[str]  # the floors the track visits, in the building's order
    wall_crossings: int  # moves through a wall, each stretch on a floor against that floor's walls
    true_floor: str | list[str] | None  # the walker's floor: per waypoint (simulated logs) or the header's
    errors: WaypointErrors | None  # at the waypoints; None without ground truth or a known floor for it
    floor_score: FloorScore | None  # on ``true_floor`` at the waypoints; None when errors is None

    @property
    def off_floor(self) -> bool:
        """Some judged waypoint's estimate is on another floor (compared in its own floor's frame)."""
        return self.floor_score is not None and self.floor_score.n_right < self.floor_score.n_judged


def building_wall_crossings(building: Building, xy_m: np.ndarray, floor) -> int:
    """Moves of a track (rows ``xy_m`` on floors named ``floor``) through a wall: each unbroken
    stretch on one floor against that floor's walls; the move from one floor to the next is none."""
    floor = np.asarray(floor)
    if floor.size == 0:
        return 0
    change = np.flatnonzero(floor[1:] != floor[:-1]) + 1
    return sum(count_wall_crossings(building.floor(str(floor[start])).plan, xy_m[start:end])
               for start, end in zip(np.concatenate([[0], change]), np.concatenate([change, [floor.size]])))


def score_building_track(building: Building, recording: Recording, track: Track, header_floor: int | None,
                         causal: bool = True) -> BuildingTrackScore:
    """Floors visited, wall crossings, and (with ground truth whose floor is known) the horizontal
    errors and the floor accuracy at the waypoints of a track with a floor column.

    The walker's floor is each waypoint's own (a fifth waypoint column, written by the
    simulator for walks that change floor) where the log has it, else the header's
    (``header_floor``, an index into ``building.floors``; ILC walks keep one floor). Errors are
    horizontal, each row in its own floor's frame (as ``mapfilter evaluate`` compares them).
    """
    names = building.floor_names
    floor = np.array(track.floor if track.floor is not None else [names[header_floor or 0]] * len(track))
    visited = sorted(set(floor.tolist()), key=names.index)
    crossings = building_wall_crossings(building, track.xy_m, floor)
    true_floor: str | list[str] | None = None
    if recording.waypoint_floor is not None:
        true_floor = list(recording.waypoint_floor)
    elif header_floor is not None:
        true_floor = names[header_floor]
    errors = score = None
    if recording.has_ground_truth and true_floor is not None:
        errors = errors_at_waypoints(track.t_s, track.xy_m, recording.waypoint_t_s, recording.waypoint_xy_m, causal)
        score = floor_at_waypoints(track.t_s, list(floor), recording.waypoint_t_s, true_floor, causal)
    return BuildingTrackScore(visited, crossings, true_floor, errors, score)
