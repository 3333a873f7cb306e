"""``mapfilter view MAP [TRACK ...] [--log LOG] (--rerun OUT.rrd | --spawn)``: look at a map,
finished tracks and ground truth in rerun without running the filter."""

from __future__ import annotations

import argparse
from pathlib import Path

from mapfilter.errors import MapfilterError

_EPILOG = """\
tracks: CSV (t_s,x_m,y_m[,...]) or TUM files written by `mapfilter track`; each is drawn as a
path plus a moving position on the trace_time timeline. --log adds the log's ground-truth
waypoints and path, and each track's error against it (plots/error_m/<track>).

A building (MAP a building YAML, docs/building.md): every floor's plan in its own view
(floors/<floor>/...), each track row on the plan of its floor (the track's floor column, as
`mapfilter track BUILDING.yaml` writes it; a track without one, e.g. TUM, is drawn on the
log's header floor), and the ground truth on its floor: each waypoint's own where the log
names it (simulated walks), else the log's header floor (FloorName).

examples:
  mapfilter view maps/F1.yaml --rerun F1.rrd
  mapfilter view maps/F1.yaml out/walk.csv out/walk_kwnn.csv --log walk.txt.gz --spawn
  mapfilter view site1.yaml tracks/walk.csv --log walk.txt.gz --rerun walk.rrd
"""


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "view", help="show a map with tracks and ground truth in rerun (no filtering)",
        description="Show a map, finished tracks and a log's ground truth in the rerun viewer.",
        epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("map", type=Path, metavar="MAP",
                        help="map YAML (ROS map_server, as `mapfilter map` writes) or building YAML")
    parser.add_argument("tracks", type=Path, nargs="*", metavar="TRACK", help="track files (CSV or TUM)")
    parser.add_argument("--log", type=Path, default=None, metavar="LOG",
                        help="phone log (ILC trace or GetSensorData log, .gz ok) whose waypoints are the ground truth")
    sink = parser.add_mutually_exclusive_group(required=True)
    sink.add_argument("--rerun", type=Path, default=None, metavar="OUT.rrd", help="write a rerun recording file")
    sink.add_argument("--spawn", action="store_true", help="open the rerun viewer and stream to it")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mapfilter.cli.common import check_map_first, check_output_path, input_paths, warn
    from mapfilter.maps.building import Building
    from mapfilter.sensors.logs import read_log
    from mapfilter.io.tracks import read_track
    from mapfilter.viz import view_map

    if args.rerun is not None and args.rerun.suffix != ".rrd":
        raise MapfilterError("the output of --rerun must end in .rrd", args.rerun)
    check_map_first("mapfilter view MAP [TRACK...] --log LOG", args.map, [] if args.log is None else [args.log])
    check_output_path(args.rerun, "--rerun", inputs=input_paths(args.map, args.tracks, args.log))
    if args.spawn:
        from mapfilter.viz import viewer_problem

        problem = viewer_problem()
        if problem is not None:
            raise MapfilterError(f"--spawn: no rerun viewer can start here: {problem}; write the recording with "
                                 "--rerun FILE.rrd and open it where there is a display")
    # load everything before writing anything: a bad input leaves no half-made recording
    building = Building.load(args.map)
    tracks = [read_track(path) for path in args.tracks]
    # latitude/longitude ground truth (GetSensorData) is placed in the (georeferenced) building
    recording = read_log(args.log, warn=warn, building=building) if args.log is not None else None
    if recording is not None and not recording.has_ground_truth:
        print(f"note: {args.log} has no waypoints: no ground truth to show")
    truth_floor = None
    if not building.is_single_floor:
        truth_floor = _floors_on_plans(building, tracks, args.tracks, recording, args.log)
    view_map(building.floors[0].plan if building.is_single_floor else building, tracks, recording,
             rrd_path=args.rerun, spawn=args.spawn,
             recording_name=args.map.stem if recording is None else recording.name, truth_floor=truth_floor,
             warn=warn)
    if args.rerun is not None:
        print(f"wrote {args.rerun}")
    return 0


def _floors_on_plans(building, tracks, track_paths, recording, log_path):
    """A building: every track row's floor checked (a track without a floor column gets the log's
    header floor); the floor of the ground truth (per waypoint, or the header's; None: unknown)."""
    header = None
    if recording is not None:
        index = building.floor_of_log(recording.floor_name, log_path)  # refuses a floor not in the building
        header = None if index is None else building.floor_names[index]
    known = set(building.floor_names)
    for track, path in zip(tracks, track_paths):
        if track.floor is None:
            if header is None:
                raise MapfilterError("the track has no floor column: give --log LOG whose header names its floor "
                                     f"(floors: {', '.join(building.floor_names)})", path)
            track.floor = [header] * len(track)
            continue
        wrong = next((i for i, name in enumerate(track.floor) if name not in known), None)
        if wrong is not None:
            raise MapfilterError(f"floor {track.floor[wrong]!r} is not in the building {building.path} "
                                 f"(floors: {', '.join(building.floor_names)})", path, wrong + 2)
    if recording is None or not recording.has_ground_truth:
        return None
    if recording.waypoint_floor is not None:
        wrong = next((name for name in recording.waypoint_floor if name not in known), None)
        if wrong is not None:
            raise MapfilterError(f"a waypoint's floor {wrong!r} is not in the building {building.path}", log_path)
        return list(recording.waypoint_floor)
    if header is None:
        print(f"note: {log_path} names no floor (FloorName): its ground truth is not drawn")
    return header
