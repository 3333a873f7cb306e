"""The Python API: what a script or notebook needs to track walks, build radio maps and evaluate.

``import mapfilter as mf`` gives these names (loaded on first use, so that importing the package
stays cheap)::

    building = mf.load_map("maps/office.yaml")                # a map or building YAML
    walk = mf.read_log("maps/office_walk.txt.gz")             # any log format the reader knows
    radio_map = mf.load_radio_map("maps/office_radiomap.npz")
    config = mf.TrackingConfig(smooth=True, seed=3)           # or TrackingConfig.from_yaml(text or path)
    result = mf.track(building, walk, radio_map=radio_map, config=config)
    result.causal.xy_m, result.offline.xy_m                  # numpy arrays (+ t_s, std_m, heading_rad, floor)

Every function here is a thin wrapper over the stage that does the work (named in its docstring).
The functions take each other's results and paths alike: a ``Building`` or a map YAML's path, a
``Recording`` or a log's path, a ``RadioMap`` or its ``.npz``, an ``AccessPointTable`` or its CSV.
An argument of another type is a one-line ``TypeError`` naming the argument.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np

from mapfilter.config import TrackingConfig
from mapfilter.runtime.dispatch import Engine
from mapfilter.errors import MapfilterError
from mapfilter.evaluation.comparison import Evaluation, EvaluationSetup, evaluate as _evaluate
from mapfilter.filter.events import StepReport
from mapfilter.filter.models.radio_map import keep_tables
from mapfilter.maps.building import Building
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.sensors.beacons import BeaconFit, BeaconFitConfig, BeaconTable
from mapfilter.sensors.beacons import fit_beacons as _fit_beacons
from mapfilter.sensors.beacons import labelled_readings
from mapfilter.sensors.floor_vote import build_building_radio_map
from mapfilter.sensors.logs import LogStream, localise, sniff_log_format
from mapfilter.sensors.logs import read_log as _read_log
from mapfilter.sensors.pathloss import AccessPointTable
from mapfilter.sensors.radiomap import RadioMap
from mapfilter.sensors.radiomap import build_radio_map as _build_one_floor
from mapfilter.pipeline.selftrain import GrowConfig, GrowReport
from mapfilter.pipeline.selftrain import grow_radio_map as _grow
from mapfilter.sensors.recording import Recording
from mapfilter.pipeline.tracker import TRUE_START, Tracker, TrackingInputs, TrackResult, WalkStart, as_start
from mapfilter.pipeline.tracker import track as _track
from mapfilter.filter.sources import plugin
from mapfilter.io.tracks import Track, read_track, write_track

__all__ = ["BeaconFit", "BeaconTable", "Building", "Evaluation", "GrowConfig", "GrowReport", "LogStream", "RadioMap",
           "Recording", "Track", "TrackResult", "Tracker", "TrackingConfig", "TrackingInputs", "build_radio_map",
           "enter_trial", "evaluate", "fit_beacons", "grow_radio_map", "load_access_points", "load_beacons",
           "load_map", "load_radio_map", "load_sources", "read_log", "read_track", "score", "track", "write_track"]

PathLike = str | os.PathLike


def load_map(path: PathLike) -> Building:
    """A map YAML (ROS map_server) as a one-floor building, or a building YAML (``maps.building``)."""
    _check_path(path, "path", "a map or building YAML")
    if not str(path).lower().endswith((".yaml", ".yml")):
        log_format = sniff_log_format(path)
        if log_format is not None:
            raise MapfilterError(f"is a phone log ({log_format}), not a map: load it with mf.read_log", path)
    return Building.load(path)


def read_log(path: PathLike, strict: bool = False, warn: Callable[[str], None] | None = None,
             building: Building | PathLike | None = None) -> Recording:
    """One phone log as a ``Recording``, its format (ILC trace or GetSensorData) told by its content
    (``sensors.logs``). Bad rows are skipped with one warning line (to ``warn``, else a
    ``LogReadWarning``); ``strict`` refuses a log with a bad row the tracker needs. Ground truth
    in latitude/longitude (IPIN logs) is put in metres by a georeferenced ``building``
    (``track`` and ``evaluate`` do that themselves)."""
    _check_path(path, "path", "a phone log")
    if str(path).lower().endswith((".yaml", ".yml")):
        raise MapfilterError("is a map YAML, not a phone log: load it with mf.load_map", path)
    return _read_log(path, strict=strict, warn=warn, building=_building(building, "building", optional=True))


def load_radio_map(path: PathLike) -> RadioMap:
    """A radio map (``.npz``, one floor or a building's), as ``mapfilter radiomap build`` writes it."""
    _check_path(path, "path", "a radio map (.npz)")
    return RadioMap.load(path)


def load_access_points(path: PathLike) -> AccessPointTable:
    """An access-point table (CSV: positions and path-loss parameters) for trilateration."""
    _check_path(path, "path", "an access-point table (CSV)")
    return AccessPointTable.read_csv(path)


def track(building: Building | FloorPlan | PathLike, recording: Recording | PathLike,
          radio_map: RadioMap | PathLike | None = None, access_points: AccessPointTable | PathLike | None = None,
          config: TrackingConfig | None = None, *, floor: str | None = None,
          on_step: Callable[[StepReport], None] | None = None,
          on_offline_step: Callable[[StepReport], None] | None = None,
          rng: np.random.Generator | None = None, sources: Mapping[str, object] | None = None,
          start: tuple | str | None = None) -> TrackResult:
    """Track one walk (``pipeline.tracker.track``): the causal track and, with ``config.smooth``, the
    offline one. ``radio_map`` (fingerprinting) or ``access_points`` (trilateration), at most
    one; ``sources``: measurement sources weighed too (alone without the other two), ``{name: its
    input, or its file (several files: {option: path})}`` (``load_sources``); ``floor`` tracks on
    one floor of a building; ``on_step`` sees every filter step; ``rng``: the run's random
    numbers (default: from ``config.seed``); ``start``: where the walk started, if known, ``(x, y)``
    or ``(x, y, floor name)`` in metres of the map's frame (``track --start X,Y[,FLOOR]``)."""
    building = _building(building, "building")
    recording = _recording(recording, "recording", building)
    radio_map, access_points, sources, config = _tracking_inputs(building, radio_map, access_points, sources, config,
                                                                 floor)
    if rng is not None and not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng: expected a numpy.random.Generator, got {type(rng).__name__}")
    start = as_start(start)
    if start is not None:
        start.place(building, floor)  # one line for a start in a wall or on a floor the building lacks
    return _track(building, recording, radio_map, access_points, config, floor=floor, on_step=on_step,
                  on_offline_step=on_offline_step, rng=rng, sources=sources, start=start)


def load_sources(sources: Mapping[str, object], building: Building | PathLike) -> dict[str, object]:
    """The inputs of measurement sources (``filter.sources``) by name: each given as the input
    itself (e.g. a ``BeaconTable`` for ``"ble"``), the path of its one file, or ``{option: path}``
    for a source of several files (the options' names without dashes, e.g. ``{"anchors": ...}``)."""
    building = _building(building, "building")
    if not isinstance(sources, Mapping):
        raise _type_error("sources", "a mapping {source name: its input or file}", sources)
    loaded = {}
    for name, value in sources.items():
        entry = plugin(name)
        keys = [o.key for o in entry.options]
        if _is_path(value) and len(keys) == 1:
            loaded[name] = entry.load({keys[0]: Path(value)}, building)
        elif isinstance(value, Mapping) and all(_is_path(v) for v in value.values()):
            missing = sorted(set(keys) - set(value))
            if missing or set(value) - set(keys):
                raise TypeError(f"sources[{name!r}]: expected the files {{{', '.join(map(repr, keys))}}}, got "
                                f"{{{', '.join(map(repr, value))}}}")
            loaded[name] = entry.load({k: Path(v) for k, v in value.items()}, building)
        else:
            loaded[name] = entry.check(value)
    return loaded


def load_beacons(path: PathLike, building: Building | PathLike | None = None,
                 ids: Mapping[str, str] | None = None) -> BeaconTable:
    """A BLE beacon table (CSV: ids, positions, floors, path-loss parameters; ``sensors.beacons``).
    Positions in latitude/longitude need a georeferenced ``building``; ``ids`` maps the file's
    beacon names to the logs' ids (an IPIN venue's ``BLE_Locations.csv``: ``{"BLE1": "BE:AC:...", ...}``)."""
    _check_path(path, "path", "a beacon table CSV")
    return BeaconTable.read_csv(path, _building(building, "building", optional=True), ids)


def fit_beacons(building: Building | PathLike, positions: BeaconTable | PathLike,
                recordings: Sequence[Recording | PathLike], config: BeaconFitConfig | None = None) -> BeaconFit:
    """The beacons' path-loss parameters fitted from survey walks with waypoints (``sensors.beacons``,
    as ``mapfilter radiomap fit-beacons``): ``.table`` is the fitted table (``mf.track(...,
    sources={"ble": table})``), ``.rows`` how each beacon fitted and whether its readings fit another's position
    better. Walks given as ``Recording``s have their latitude/longitude ground truth placed in the
    building (``read_log(..., building=)``)."""
    building = _building(building, "building")
    positions = _beacons(positions, "positions", building, optional=False)
    recordings = _recordings(recordings, "recordings", building)
    readings = labelled_readings(positions, building, recordings)
    return _fit_beacons(positions, readings, config if config is not None else BeaconFitConfig())


def build_radio_map(building: Building | PathLike, recordings: Sequence[Recording | PathLike]) -> RadioMap:
    """A radio map from survey walks with waypoints (``sensors.radiomap``): on one floor, every
    scan labelled by its walk's waypoints; in a building, each walk's points on the floor its log
    names (``sensors.floor_vote``)."""
    building = _building(building, "building")
    recordings = _recordings(recordings, "recordings", building)
    if building.is_single_floor:
        # with the radio-map likelihood's grid on the floor kept for its file (filter.models.radio_map)
        return keep_tables(_build_one_floor(recordings, building.floors[0].plan), building.floors[0].plan)
    # a walk over several floors (waypoints naming their floors) labels each scan by its waypoints
    floors = [building.floor_of_log(rec.floor_name, rec.path) for rec in recordings]
    return build_building_radio_map(recordings, floors, building.floor_names)


def grow_radio_map(building: Building | PathLike, radio_map: RadioMap | PathLike,
                   recordings: Sequence[Recording | PathLike], config: TrackingConfig | None = None,
                   grow: GrowConfig | None = None, jobs: int = 1,
                   progress: Callable[[int, int, str], None] | None = None) -> tuple[RadioMap, GrowReport]:
    """The radio map grown from walks without labels (``selftrain``, docs/self-training.md): each
    walk tracked offline over the map (``config``), its scans added where its offline track puts
    them, with their position uncertainty, until the map stops changing. Their waypoints, if any,
    are never read. Returns the grown map (surveyed + grown points) and what was added."""
    building = _building(building, "building")
    radio_map = _radio_map(radio_map, "radio_map", optional=False)
    recordings = _recordings(recordings, "recordings", building)
    config = _config(config)
    if grow is not None and not isinstance(grow, GrowConfig):
        raise TypeError(f"grow: expected a GrowConfig, got {type(grow).__name__}")
    _check_jobs(jobs)
    grow = grow if grow is not None else GrowConfig()
    if config is not None:
        grow = dataclasses.replace(grow, tracking=config, seed=config.seed)
    space = building.floors[0].plan if building.is_single_floor else building
    grown, report = _grow(space, radio_map, recordings, grow, progress=progress, engine=Engine(jobs=jobs))
    return (keep_tables(grown, space) if building.is_single_floor else grown), report


def evaluate(building: Building | PathLike, logs: Sequence[Recording | PathLike], *,
             radio_map: RadioMap | PathLike | None = None, access_points: AccessPointTable | PathLike | None = None,
             survey: Sequence[Recording | PathLike] = (), leave_one_out: bool = False,
             unlabelled: Sequence[Recording | PathLike] = (), transductive: bool = False,
             methods: Sequence[str] | None = None, sources: Mapping[str, object] | None = None,
             config: TrackingConfig | None = None, jobs: int = 1, scheduler: str | None = None,
             progress: Callable[[int, int, str], None] | None = None, waypoints: str = "common",
             start: tuple | str | None = None) -> Evaluation:
    """Every method on the same walks (``evaluation.comparison``), as ``mapfilter evaluate`` runs them:
    ``evaluation.summary_rows()`` is its table, ``errors_by_method()`` its CDF.

    The walks (``logs``, ``survey``, ``unlabelled``): ``Recording``s or log paths. The radio map:
    a ``RadioMap`` or its file (``radio_map``), ``survey`` walks, or ``leave_one_out`` (each walk's
    from the other walks); ``unlabelled`` walks grow it (self-training), ``transductive`` the
    evaluated walks too. ``sources``: measurement sources (as ``track`` takes them), each adding
    its methods (``pf+NAME``, ``pf-NAME``; a source may fit its input again on the survey or
    the other walks).
    ``jobs``/``scheduler``: walks on local worker processes or a Dask cluster. ``waypoints``:
    ``"common"`` scores every method of a walk at the waypoints every method has an estimate for,
    ``"own"`` each at every waypoint from its own first estimate on. ``start``: where every walk
    started, if known (as ``track`` takes it): the particle filter methods start there; ``"truth"``:
    each walk at its own first waypoint (``evaluate --start truth``).
    """
    building = _building(building, "building")
    walks = _walks(logs, "logs")
    if methods is not None and (isinstance(methods, str) or not all(isinstance(m, str) for m in methods)):
        raise TypeError(f"methods: expected a list of method names, got {methods!r}")
    _check_jobs(jobs)
    if waypoints not in ("common", "own"):
        raise ValueError(f"waypoints: expected 'common' or 'own', got {waypoints!r}")
    if scheduler is not None and not isinstance(scheduler, str):
        raise TypeError(f"scheduler: expected an address such as 'tcp://HOST:8786', got {type(scheduler).__name__}")
    given_map, map_path = _object_or_path(radio_map, RadioMap, "radio_map", "a RadioMap (mf.load_radio_map)")
    given_aps, aps_path = _object_or_path(access_points, AccessPointTable, "access_points",
                                          "an AccessPointTable (mf.load_access_points)")
    loaded = load_sources(sources, building) if sources is not None else {}
    config = _config(config)
    setup = EvaluationSetup(methods=None if methods is None else tuple(methods),
                            radio_map_path=None if map_path is None else Path(map_path),
                            ap_table_path=None if aps_path is None else Path(aps_path), survey_paths=tuple(_walks(survey, "survey")),
                            leave_one_out=bool(leave_one_out), tracking=config if config is not None else TrackingConfig(),
                            unlabelled_paths=tuple(_walks(unlabelled, "unlabelled")), transductive=bool(transductive),
                            radio_map=given_map, access_points=given_aps, sources=loaded,
                            common_waypoints=waypoints == "common", start=_start_on(start, building))
    return _evaluate(building, walks, setup, Engine(jobs=jobs, scheduler=scheduler), progress=progress)


def score(track: Track | PathLike, recording: Recording | PathLike, building: Building | PathLike, *,
          causal: bool = True) -> dict[str, object]:
    """One track's error against its walk's ground truth, as ``evaluate`` scores a method on a walk
    at its own waypoints (``evaluation.scoring.score_track``; a row of its per-walk table with
    ``waypoints="own"``): ``mean``, ``median``,
    ``p75`` (the IPIN/EvAAL score), ``p90``, ``ce95``, ``max``, ``rmse`` (metres), ``n`` (waypoints
    scored), ``missed`` (waypoints before the first row, not scored), ``availability``,
    ``wall_crossings``, ``errors_m`` (each scored waypoint's error, e.g. for a CDF), and with
    several floors ``floor_accuracy`` (the share of waypoints on the walker's floor).

    ``track``: a ``Track`` or a track file; ``recording``: the walk (a ``Recording`` or its log),
    with waypoints; ``building``: the map it was tracked on. ``causal``: each waypoint takes the
    latest row at or before it, as a live system has it (a causal track; ``evaluate``'s ``pf``),
    else the track interpolated at its time (an offline track: ``result.offline``).
    """
    from mapfilter.evaluation.metrics import availability, summarise_errors
    from mapfilter.evaluation.scoring import score_track

    building = _building(building, "building")
    if not isinstance(track, Track):
        _check_path(track, "track", "a Track or a track file")
        track = read_track(track)
    recording = _recording(recording, "recording", building)
    if not recording.has_ground_truth:
        raise MapfilterError("the log has no waypoints to score against", recording.path)
    if recording.needs_georeference:
        raise MapfilterError("the log's ground truth is in latitude/longitude and the map has no georeference",
                             recording.path)
    header_floor = building.floor_of_log(recording.floor_name, recording.path)
    result = score_track(building, recording, track, header_floor, bool(causal))
    if result.errors is None:
        raise MapfilterError("the log names no floor for its ground truth in this building", recording.path)
    errors_m = result.errors.errors_m
    scores: dict[str, object] = {**summarise_errors(errors_m), "missed": result.errors.missed,
                                 "availability": availability(errors_m.size, result.errors.missed),
                                 "wall_crossings": result.wall_crossings, "errors_m": errors_m}
    if not building.is_single_floor:
        scores["floor_accuracy"] = result.floor_score.accuracy if result.floor_score is not None else float("nan")
    return scores


def enter_trial(server_url: str, trial: str, building: Building | PathLike, *,
                radio_map: RadioMap | PathLike | None = None, access_points: AccessPointTable | PathLike | None = None,
                sources: Mapping[str, object] | None = None, config: TrackingConfig | None = None,
                offline: bool = False, floor: str | None = None, timeout_s: float = 10.0, retry_s: float = 30.0,
                phone: str | None = None):
    """Enter an IPIN competition trial on its EvaalAPI server (``evaal``), as ``mapfilter evaal``
    does: online, the streaming tracker's causal estimate with each request for the next 0.5 s of
    log; ``offline``, the whole-walk track's estimates posted in one go. ``building`` must be
    georeferenced; ``sources``: measurement sources weighed too, or alone (as ``track``); ``phone``:
    the trial's phone model (the server sends no log header: a beacon table's offset for it). Each
    request must be answered within ``timeout_s``; a dropped connection is retried for ``retry_s``.
    Returns the ``evaal.protocol.TrialRun`` (``estimates``: what the server keeps)."""
    from mapfilter.evaal.client import EvaalClient, run_offline, run_online
    from mapfilter.evaal.protocol import check_building
    from mapfilter.pipeline.tracker import Tracker

    building = _building(building, "building")
    radio_map, access_points, sources, config = _tracking_inputs(building, radio_map, access_points, sources, config,
                                                                 floor)
    config = config if config is not None else TrackingConfig()
    if offline and not config.smooth:
        config = dataclasses.replace(config, smooth=True)
    check_building(building)
    tracker = Tracker(building, TrackingInputs(radio_map, access_points, sources, phone_model=phone), config,
                      floor=floor, log_name=f"trial {trial}")
    client = EvaalClient(server_url, trial, timeout_s=timeout_s, retry_s=retry_s)
    return run_offline(client, tracker) if offline else run_online(client, tracker)


# ---- the arguments: the objects the functions return, or paths; anything else a TypeError ------
def _type_error(name: str, expected: str, value) -> TypeError:
    got = "None" if value is None else type(value).__name__
    return TypeError(f"{name}: expected {expected}, got {got}")


def _is_path(value) -> bool:
    return isinstance(value, (str, os.PathLike))


def _check_path(value, name: str, what: str) -> None:
    if not _is_path(value):
        raise _type_error(name, f"the path of {what}", value)


def _tracking_inputs(building: Building, radio_map, access_points, sources, config, floor):
    """The checked radio map, access points, sources' inputs and config of a tracking call
    (``floor`` a floor name or None)."""
    if floor is not None and not isinstance(floor, str):
        raise TypeError(f"floor: expected a floor name (str), got {type(floor).__name__}")
    return (_radio_map(radio_map, "radio_map"), _access_points(access_points, "access_points"),
            load_sources(sources, building) if sources is not None else {}, _config(config))


def _start_on(value, building: Building) -> WalkStart | str | None:
    """The checked ``start`` argument (``as_start``), on a floor of ``building`` and its free space;
    ``TRUE_START`` as it is."""
    if isinstance(value, str) and value == TRUE_START:
        return TRUE_START
    start = as_start(value)
    if start is not None:
        start.place(building)
    return start


def _building(value, name: str, optional: bool = False) -> Building | None:
    """A ``Building``: given, made from a ``FloorPlan``, or loaded from a map or building YAML."""
    if value is None and optional:
        return None
    if isinstance(value, Building):
        return value
    if isinstance(value, FloorPlan):
        return Building.from_plan(value)
    if _is_path(value):
        return load_map(value)
    raise _type_error(name, "a Building (mf.load_map) or the path of a map or building YAML", value)


def _recording(value, name: str, building: Building) -> Recording:
    """A ``Recording`` (its latitude/longitude ground truth placed in ``building``), or a log read."""
    if isinstance(value, Recording):
        return localise(value, building) if value.needs_georeference else value
    if _is_path(value):
        return read_log(value, building=building)
    raise _type_error(name, "a Recording (mf.read_log) or the path of a phone log", value)


def _recordings(values, name: str, building: Building) -> list[Recording]:
    if _is_path(values) or isinstance(values, Recording) or not isinstance(values, Sequence):
        raise _type_error(name, "a list of Recordings or log paths", values)
    return [_recording(value, f"{name}[{i}]", building) for i, value in enumerate(values)]


def _walks(values, name: str) -> list[Recording | str | os.PathLike]:
    """Walks for ``evaluate``: Recordings or log paths, checked, not read (the evaluation reads them)."""
    if _is_path(values) or isinstance(values, Recording) or not isinstance(values, Sequence):
        raise _type_error(name, "a list of Recordings or log paths", values)
    for i, value in enumerate(values):
        if not (isinstance(value, Recording) or _is_path(value)):
            raise _type_error(f"{name}[{i}]", "a Recording (mf.read_log) or the path of a phone log", value)
    return list(values)


def _radio_map(value, name: str, optional: bool = True) -> RadioMap | None:
    given, path = _object_or_path(value, RadioMap, name, "a RadioMap (mf.load_radio_map)", optional)
    return given if path is None else RadioMap.load(path)


def _access_points(value, name: str) -> AccessPointTable | None:
    given, path = _object_or_path(value, AccessPointTable, name, "an AccessPointTable (mf.load_access_points)")
    return given if path is None else AccessPointTable.read_csv(path)


def _object_or_path(value, kind: type, name: str, expected: str, optional: bool = True):
    """(the object, None) or (None, its path); (None, None) for an optional argument not given."""
    if value is None and optional:
        return None, None
    if isinstance(value, kind):
        return value, None
    if _is_path(value):
        return None, os.fspath(value)
    raise _type_error(name, f"{expected} or the path of its file", value)


def _beacons(value, name: str, building: Building, optional: bool = True) -> BeaconTable | None:
    """A ``BeaconTable``, or its CSV read (latitude/longitude placed in ``building``)."""
    given, path = _object_or_path(value, BeaconTable, name, "a BeaconTable (mf.load_beacons)", optional)
    return given if path is None else BeaconTable.read_csv(path, building)


def _config(value) -> TrackingConfig | None:
    if value is None or isinstance(value, TrackingConfig):
        return value
    raise _type_error("config", "a TrackingConfig (mf.TrackingConfig(...) or mf.TrackingConfig.from_yaml(text or "
                      "path))", value)


def _check_jobs(jobs) -> None:
    if isinstance(jobs, bool) or not isinstance(jobs, (int, np.integer)):
        raise _type_error("jobs", "a whole number of worker processes", jobs)
    if jobs < 1:
        raise ValueError(f"jobs: at least 1 worker process, got {jobs}")
