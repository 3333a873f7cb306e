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
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from pathlib import Path

from mapfilter.config import TrackingConfig
from mapfilter.engine import Engine
from mapfilter.evaluation.comparison import Evaluation, EvaluationSetup, evaluate as _evaluate
from mapfilter.maps.building import Building
from mapfilter.sensors.floors import build_building_radio_map
from mapfilter.sensors.logs import read_log as _read_log
from mapfilter.sensors.pathloss import AccessPointTable
from mapfilter.sensors.radiomap import RadioMap
from mapfilter.sensors.radiomap import build_radio_map as _build_one_floor
from mapfilter.selftrain import GrowConfig, GrowReport
from mapfilter.selftrain import grow_radio_map as _grow
from mapfilter.sensors.recording import Recording
from mapfilter.tracking import TrackResult, track
from mapfilter.trackio import Track, read_track, write_track

__all__ = ["Building", "Evaluation", "GrowConfig", "GrowReport", "RadioMap", "Recording", "Track", "TrackResult",
           "TrackingConfig", "build_radio_map", "evaluate", "grow_radio_map", "load_access_points", "load_map",
           "enter_trial", "load_radio_map", "read_log", "read_track", "track", "write_track"]


def load_map(path: str | os.PathLike) -> Building:
    """A map YAML (ROS map_server) as a one-floor building, or a building YAML (``maps.building``)."""
    return Building.load(path)


def read_log(path: str | os.PathLike, strict: bool = False, warn: Callable[[str], None] | None = None,
             building: Building | None = None) -> Recording:
    """One phone log as a ``Recording``, its format (ILC trace or GetSensorData) told by its content
    (``sensors.logs``). Bad rows are skipped with one warning line (to ``warn``, else a
    ``LogReadWarning``); ``strict`` refuses a log with a bad row the tracker needs. Ground truth
    in latitude/longitude (IPIN logs) is put in metres by a georeferenced ``building``
    (``track`` and ``evaluate`` do that themselves)."""
    return _read_log(path, strict=strict, warn=warn, building=building)


def load_radio_map(path: str | os.PathLike) -> RadioMap:
    """A radio map (``.npz``, one floor or a building's), as ``mapfilter radiomap build`` writes it."""
    return RadioMap.load(path)


def load_access_points(path: str | os.PathLike) -> AccessPointTable:
    """An access-point table (CSV: positions and path-loss parameters) for trilateration."""
    return AccessPointTable.read_csv(path)


def build_radio_map(building: Building, recordings: Sequence[Recording]) -> RadioMap:
    """A radio map from survey walks with waypoints (``sensors.radiomap``): on one floor, every
    scan labelled by its walk's waypoints; in a building, each walk's points on the floor its log
    names (``sensors.floors``)."""
    if building.is_single_floor:
        return _build_one_floor(list(recordings), building.floors[0].plan)
    # a walk over several floors (waypoints naming their floors) labels each scan by its waypoints
    floors = [building.floor_of_log(rec.floor_name, rec.path) for rec in recordings]
    return build_building_radio_map(list(recordings), floors, building.floor_names)


def grow_radio_map(building: Building, radio_map: RadioMap, recordings: Sequence[Recording],
                   config: TrackingConfig | None = None, grow: GrowConfig | None = None, jobs: int = 1,
                   progress: Callable[[int, int, str], None] | None = None) -> tuple[RadioMap, GrowReport]:
    """The radio map grown from walks without labels (``selftrain``, docs/self-training.md): each
    walk tracked offline over the map (``config``), its scans added where its offline track puts
    them, with their position uncertainty, until the map stops changing. Their waypoints, if any,
    are never read. Returns the grown map (surveyed + grown points) and what was added."""
    grow = grow if grow is not None else GrowConfig()
    if config is not None:
        grow = dataclasses.replace(grow, tracking=config, seed=config.seed)
    space = building.floors[0].plan if building.is_single_floor else building
    return _grow(space, radio_map, recordings, grow, progress=progress, engine=Engine(jobs=jobs))


def evaluate(building: Building, logs: Sequence[str | os.PathLike], *, radio_map: str | os.PathLike | None = None,
             access_points: str | os.PathLike | None = None, survey: Sequence[str | os.PathLike] = (),
             leave_one_out: bool = False, unlabelled: Sequence[str | os.PathLike] = (), transductive: bool = False,
             methods: Sequence[str] | None = None,
             config: TrackingConfig | None = None, jobs: int = 1, scheduler: str | None = None,
             progress: Callable[[int, int, str], None] | None = None) -> Evaluation:
    """Every method on the same walks (``evaluation.comparison``), as ``mapfilter evaluate`` runs them:
    ``evaluation.summary_rows()`` is its table, ``errors_by_method()`` its CDF.

    The radio map: a file (``radio_map``), ``survey`` logs, or ``leave_one_out`` (each walk's from
    the other walks); ``unlabelled`` walks grow it (self-training), ``transductive`` the evaluated
    walks too. ``jobs``/``scheduler``: walks on local Dask worker processes or a cluster.
    """
    setup = EvaluationSetup(methods=None if methods is None else tuple(methods),
                            radio_map_path=None if radio_map is None else Path(radio_map),
                            ap_table_path=None if access_points is None else Path(access_points),
                            survey_paths=tuple(Path(p) for p in survey), leave_one_out=leave_one_out,
                            tracking=config if config is not None else TrackingConfig(),
                            unlabelled_paths=tuple(Path(p) for p in unlabelled), transductive=transductive)
    return _evaluate(building, logs, setup, Engine(jobs=jobs, scheduler=scheduler), progress=progress)


def enter_trial(server_url: str, trial: str, building: Building, *, radio_map: RadioMap | None = None,
                access_points: AccessPointTable | None = None, config: TrackingConfig | None = None,
                offline: bool = False, floor: str | None = None, timeout_s: float = 10.0):
    """Enter an IPIN competition trial on its EvaalAPI server (``evaal``), as ``mapfilter evaal``
    does: online, the streaming tracker's causal estimate with each request for the next 0.5 s of
    log; ``offline``, the whole-walk track's estimates posted in one go. ``building`` must be
    georeferenced. Returns the ``evaal.TrialRun`` (``estimates``: what the server keeps)."""
    from mapfilter import evaal
    from mapfilter.tracking import Tracker

    config = config if config is not None else TrackingConfig()
    if offline and not config.smooth:
        config = dataclasses.replace(config, smooth=True)
    evaal.check_building(building)
    tracker = Tracker(building, radio_map, access_points, config, floor=floor, log_name=f"trial {trial}")
    client = evaal.EvaalClient(server_url, trial, timeout_s=timeout_s)
    return evaal.run_offline(client, tracker) if offline else evaal.run_online(client, tracker)
