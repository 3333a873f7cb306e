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

examples:
  mapfilter view maps/F1.yaml --rerun F1.rrd
  mapfilter view maps/F1.yaml out/walk.csv out/walk_kwnn.csv --log walk.txt.gz --spawn
"""


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "view", help="show a map with tracks and ground truth in rerun (no filtering)",
        description="Show a map, finished tracks and a log's ground truth in the rerun viewer.",
        epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("map", type=Path, metavar="MAP", help="map YAML (ROS map_server, as `mapfilter map` writes)")
    parser.add_argument("tracks", type=Path, nargs="*", metavar="TRACK", help="track files (CSV or TUM)")
    parser.add_argument("--log", type=Path, default=None, metavar="LOG",
                        help="phone log (ILC trace, .gz ok) whose waypoints are the ground truth")
    sink = parser.add_mutually_exclusive_group(required=True)
    sink.add_argument("--rerun", type=Path, default=None, metavar="OUT.rrd", help="write a rerun recording file")
    sink.add_argument("--spawn", action="store_true", help="open the rerun viewer and stream to it")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mapfilter.cli.common import warn
    from mapfilter.maps.floorplan import FloorPlan
    from mapfilter.sensors.ilc import read_ilc
    from mapfilter.trackio import read_track
    from mapfilter.viz import view_map

    if args.rerun is not None and args.rerun.suffix != ".rrd":
        raise MapfilterError("the output of --rerun must end in .rrd", args.rerun)
    # load everything before writing anything: a bad input leaves no half-made recording
    floorplan = FloorPlan.load(args.map)
    tracks = [read_track(path) for path in args.tracks]
    recording = read_ilc(args.log, warn=warn) if args.log is not None else None
    if recording is not None and not recording.has_ground_truth:
        print(f"note: {args.log} has no waypoints: no ground truth to show")
    view_map(floorplan, tracks, recording, rrd_path=args.rerun, spawn=args.spawn,
             recording_name=args.map.stem if recording is None else recording.name)
    if args.rerun is not None:
        print(f"wrote {args.rerun}")
    return 0
