"""``mapfilter track MAP LOG``: track one walk, write the track, print the errors.
``mapfilter track MAP LOG... --out-dir DIR``: track many walks, one track file each + a summary."""

from __future__ import annotations

import argparse
import contextlib
import csv
import dataclasses
import json
import os
import stat
import sys
import textwrap
import time
from collections import Counter
from pathlib import Path

from mapfilter.io.atomic import atomic_paths
from mapfilter.cli.common import (SMOOTH_EXTRA_RUNS, ProgressBar, add_engine_arguments, add_strict_argument,
                                  announce_estimate, announce_recording_size, bounded_int, check_distinct_outputs,
                                  check_map_first, check_output_path, duration_text, engine_from, estimate_tracking_s,
                                  input_paths, is_stdout, walk_spans_s, warn)
from mapfilter.cli.tracking_options import (add_source_arguments, add_start_argument, add_tracking_arguments,
                                            load_sources, source_files, source_paths, start_from,
                                            tracking_config_from)
from mapfilter.filter.sources import registered
from mapfilter.errors import MapfilterError
from mapfilter.runtime.memory import building_extents_m, check_tracking_fits

TRACK_FORMATS = ("csv", "tum")
MAX_COLLAPSE_LINES = 3  # more collapses than this are summarised in one line

_EPILOG = """\
WiFi: --radiomap RM (fingerprinting; build one with `mapfilter radiomap build`) or --aps
APS.csv (trilateration with the path-loss model); without either, the map's own
access-point table (mapfilter: access_points in its YAML) is used for trilateration, unless a
measurement source's files are given: then that source alone (and, in a building, the
barometer) places the walker.

{sources}

The start: without --start, the filter starts from the first usable WiFi scan (or measurement
of another source), drawn over the map's free space. --start X,Y[,FLOOR] says where the walk
started (metres in the map's frame, the floor's name in a building): the particles start within
2 m of it at the first step. A start in a wall, outside the map or on a floor the building does
not have is refused. If the log has waypoints, the errors at the waypoint times are
printed (the latest estimate at or before each waypoint; see "What the numbers mean" in the
README).

Track files: CSV t_s,x_m,y_m,std_m,heading_rad (a building adds floor), or TUM
t x y z qx qy qz qw (evo reads it; the rotation is the heading about z); the format follows
the file's extension (.csv, .tum). With --smooth, --out PATH gets the offline track and the
causal track goes beside it as PATH with .causal before the extension.

Many walks: give several logs and --out-dir DIR: one track per walk (DIR/<trace>.csv, with
--smooth also DIR/<trace>.causal.csv), DIR/summary.csv (one row per walk: status ok | failed
| crashed, the reason, errors), DIR/summary.json and DIR/config.yaml (the settings that ran:
`--config DIR/config.yaml` repeats the run). A walk that fails is reported and the others go
on; the exit code is 1 if any walk failed. --jobs N runs the walks on N local worker
processes, --scheduler tcp://HOST:PORT on a Dask cluster you trust (see `mapfilter evaluate
--help`).

A building (MAP a building YAML, docs/building.md) with a building's radio map: the floor is
part of the filter's state and found from the WiFi (and barometer), or given with --floor
NAME; x, y are in the frame of the floor each row is on, named in the floor column. A log
whose header names a floor the map does not have is refused (--floor tracks it anyway).

A live run: LOG - reads the log from standard input as it is written (a phone streaming its
sensors, `tail -f`, a socket) and prints each causal estimate as a CSV row on standard output
as soon as it exists (the columns of a track file). --out FILE gets each row before it is
printed: the file is in place from the first row on (an earlier FILE is replaced then, not
before), so `tail -f FILE` follows it, and whatever stops the run it holds every row printed,
in whole lines. --rerun FILE.rrd grows alike, --spawn shows the run in a viewer as it happens,
--plot draws the track (and the log's ground truth) at the end. Ctrl-C or SIGTERM while the
run waits for its input ends the walk there: the records read are tracked to the end, the
summary is printed, and the exit code is 130 (143 for SIGTERM).

examples:
  mapfilter track maps/office.yaml maps/office_walk.txt.gz --radiomap maps/office_radiomap.npz --smooth
  zcat maps/office_walk.txt.gz | mapfilter track maps/office.yaml - --radiomap maps/office_radiomap.npz
  mapfilter track F1.yaml walk.txt.gz --radiomap F1_radiomap.npz --out track.csv --seed 3
  mapfilter track F1.yaml walks/*.txt.gz --radiomap F1_radiomap.npz --out-dir tracks --jobs 2
  mapfilter track F1.yaml walk.txt.gz --radiomap F1_radiomap.npz --config my_settings.yaml
"""


def _epilog() -> str:
    """The epilog with each measurement source's paragraph (``filter.sources``)."""
    paragraphs = [textwrap.fill(entry.help, 94) for entry in registered() if entry.help]
    return _EPILOG.replace("{sources}", "\n\n".join(paragraphs) if paragraphs else "(no other measurement source)")


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "track", help="track a walk (map + phone log) with the particle filter",
        description="Track a walk on a floor plan with the map-aware particle filter.",
        epilog=_epilog(), formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("map", type=Path, metavar="MAP", help="map YAML (ROS map_server) or building YAML")
    parser.add_argument("logs", type=Path, nargs="+", metavar="LOG",
                        help="phone log(s) (.txt or .txt.gz); several need --out-dir; - reads one from standard "
                             "input as it is written and prints each estimate as soon as it exists")
    wifi = parser.add_mutually_exclusive_group()
    wifi.add_argument("--radiomap", type=Path, metavar="RM", help="radio map (.npz) for fingerprinting")
    wifi.add_argument("--aps", type=Path, metavar="APS.csv", help="access-point table for trilateration")
    parser.add_argument("--floor", metavar="NAME",
                        help="track on this floor of the map (default: the log's floor, found in a building)")
    add_start_argument(parser)
    parser.add_argument("--out", type=Path, metavar="FILE", help="write the track here (one log): .csv or .tum")
    parser.add_argument("--out-dir", type=Path, metavar="DIR",
                        help="track every LOG: one track file per walk, summary.csv, summary.json, config.yaml")
    parser.add_argument("--format", choices=TRACK_FORMATS, default=None,
                        help="track file format; by default the --out file's extension (csv unless .tum); "
                             "with --out-dir: csv")
    parser.add_argument("--evaal-out", type=Path, metavar="FILE",
                        help="also write the IPIN competition's estimates (pts,lon,lat,floor; the log's clock): what "
                             "`mapfilter evaal` would send on a trial of this log (a second run, the log served as "
                             "the server serves it; with --smooth, an offline trial's); a georeferenced MAP")
    parser.add_argument("--evaal-start", metavar="LON,LAT,FLOOR",
                        help="with --evaal-out, online: the trial's initial position, as the competition gives it "
                             "(default: the log's first POSI point; a log without one needs it)")
    parser.add_argument("--adapted-aps", type=Path, metavar="OUT.csv",
                        help="with --adapt: write the access-point table as adapted at the end of the walk")
    add_tracking_arguments(parser)
    add_source_arguments(parser)
    view = parser.add_mutually_exclusive_group()
    view.add_argument("--rerun", type=Path, metavar="FILE.rrd", help="write a rerun recording of the run")
    view.add_argument("--spawn", action="store_true", help="stream the run to a new rerun viewer")
    parser.add_argument("--plot", type=Path, metavar="FILE.png",
                        help="draw the tracks, the ground truth (when the log has one) and the walls into a PNG "
                             "(no viewer needed)")
    parser.add_argument("--max-drawn-particles", type=bounded_int(0, 1_000_000), default=5000, metavar="N",
                        help="cap on particles drawn per step in rerun (default: 5000)")
    add_engine_arguments(parser)
    add_strict_argument(parser)
    parser.set_defaults(func=run)


def track_format(path: Path | None, given: str | None) -> str:
    """The track format: ``given``, else the extension's (.tum: tum, else csv); a ``given``
    format that contradicts the extension is refused."""
    suffix = path.suffix.lower().lstrip(".") if path is not None else ""
    if given is not None:
        if suffix in TRACK_FORMATS and suffix != given:
            raise MapfilterError(f"--format {given} but the file ends in .{suffix}: give a .{given} name or "
                                 f"drop --format", path)
        return given
    return suffix if suffix in TRACK_FORMATS else "csv"


def causal_path(path: Path) -> Path:
    """Where the causal track goes beside an offline track file: ``track.csv`` -> ``track.causal.csv``."""
    return path.with_name(f"{path.stem}.causal{path.suffix}") if path.suffix else path.with_name(path.name + ".causal")


def run(args: argparse.Namespace) -> int:
    check_map_first("mapfilter track MAP LOG...", args.map, args.logs)
    config = tracking_config_from(args)
    # every output checked before the work: none is an input, a link, a device or another's file
    inputs = input_paths(args.map, args.logs, args.radiomap, args.aps, *source_paths(args), args.config)
    if is_stdout(args.out) and config.smooth:
        raise MapfilterError("--out - with --smooth: the offline and the causal track need two files; give a "
                             "file name")
    check_output_path(args.out, inputs=inputs, allow_stdout=True)
    if args.out is not None and config.smooth:
        check_output_path(causal_path(args.out), inputs=inputs)
    check_output_path(args.rerun, "--rerun", inputs=inputs)
    check_output_path(args.plot, "--plot", inputs=inputs)
    if args.plot is not None and args.plot.suffix.lower() != ".png":
        raise MapfilterError("the picture of --plot must end in .png", args.plot)
    check_output_path(args.adapted_aps, "--adapted-aps", inputs=inputs, allow_stdout=True)
    check_output_path(args.evaal_out, "--evaal-out", inputs=inputs)
    check_distinct_outputs([("--out", args.out), ("--out (causal track)", causal_path(args.out) if args.out
                                                   is not None and config.smooth else None),
                            ("--rerun", args.rerun), ("--plot", args.plot), ("--adapted-aps", args.adapted_aps),
                            ("--evaal-out", args.evaal_out)])
    if args.evaal_out is not None and (args.out_dir is not None or is_stdout(args.logs[0])):
        raise MapfilterError("--evaal-out is for one log file (not --out-dir, not a live run)")
    if args.evaal_start is not None and args.evaal_out is None:
        raise MapfilterError("--evaal-start is the initial position of --evaal-out: give --evaal-out FILE too")
    if sum(is_stdout(p) for p in (args.out, args.adapted_aps)) > 1:
        raise MapfilterError("--out - and --adapted-aps -: only one output can go to standard output")
    if args.adapted_aps is not None and args.out_dir is not None:
        raise MapfilterError("--adapted-aps is for one walk, not for --out-dir")
    if args.out_dir is not None:
        if is_stdout(args.out_dir):
            raise MapfilterError("--out-dir needs a directory name, not -")
        for option in ("out", "rerun", "plot"):
            if getattr(args, option) is not None:
                raise MapfilterError(f"--{option} is for one walk: with --out-dir every walk gets its own track "
                                     "file")
        out_dir = check_output_path(args.out_dir, "--out-dir", directory=True, inputs=inputs)
        return _run_batch(args, config, out_dir)
    if len(args.logs) > 1:
        raise MapfilterError(f"{len(args.logs)} logs: tracking several walks needs --out-dir DIR")
    if is_stdout(args.logs[0]):
        return _run_live(args, config)
    if args.jobs != 1 or args.scheduler:
        raise MapfilterError("--jobs and --scheduler spread many walks: give them with --out-dir DIR")
    return _run_one(args, config, args.logs[0])


def _wifi_source(args: argparse.Namespace, building, config):
    """(radio map, access-point table) of the run: --radiomap, --aps, or the map's own table;
    (None, None) with a measurement source's files and neither (the source alone)."""
    from mapfilter.sensors.floor_vote import load_building_radio_map
    from mapfilter.sensors.pathloss import access_points_for_map
    from mapfilter.sensors.radiomap import RadioMap, check_radio_map_on_map

    if args.radiomap is not None:
        if args.adapt or args.adapted_aps is not None:
            raise MapfilterError("--adapt and --adapted-aps adapt a path-loss table: they need trilateration "
                                 "(--aps APS.csv or the map's table), not --radiomap")
        if not building.is_single_floor and args.floor is None:
            radio_map = load_building_radio_map(args.radiomap, building.floor_names)
        else:
            radio_map = RadioMap.load(args.radiomap)
        check_radio_map_on_map(radio_map, building, args.radiomap, args.map)
        return radio_map, None
    if source_files(args) and args.aps is None:
        if args.adapt or args.adapted_aps is not None:
            raise MapfilterError("--adapt and --adapted-aps adapt an access-point table: give --aps APS.csv")
        return None, None
    if not building.is_single_floor and args.floor is None:
        raise MapfilterError("tracking in a building needs a building's radio map: --radiomap RM (mapfilter "
                             "radiomap build BUILDING.yaml LOGS...), or --floor NAME with --aps")
    floor = building.floors[0 if args.floor is None else building.floor_index(args.floor, args.map)]
    if args.adapted_aps is not None and not config.trilateration.adapt_path_loss:
        raise MapfilterError("--adapted-aps writes the adapted table: give --adapt too")
    return None, access_points_for_map(args.aps, floor.plan, floor.map_path or args.map,
                                       hint="give --radiomap RM or --aps APS.csv")


def wifi_source_text(args: argparse.Namespace, building, ap_table) -> str:
    """What the run weighs the WiFi with, for the summary: the radio map, the --aps table or the
    map's own access-point table (named, so that a forgotten --radiomap shows); and a radio map
    lying beside the map (``STEM*.npz``) that was not used."""
    if args.radiomap is not None:
        return f"WiFi: fingerprints of the radio map {args.radiomap}"
    if ap_table is None:
        return "WiFi: none (the measurement sources alone)"
    if args.aps is not None:
        text = f"WiFi: trilateration from the access-point table {args.aps} ({len(ap_table)} APs)"
    else:
        floor = building.floors[0 if args.floor is None else building.floor_index(args.floor)]
        table = os.path.relpath(floor.plan.access_points_csv)
        if table.startswith(".."):
            table = str(floor.plan.access_points_csv)
        text = f"WiFi: trilateration from the map's own access-point table {table} ({len(ap_table)} APs)"
    beside = sorted(args.map.parent.glob(f"{args.map.stem}*.npz"))
    if beside:
        text += (f"; not used: the radio map {beside[0]} beside the map (give --radiomap {beside[0]} to "
                 "fingerprint with it)")
    return text


def _run_one(args: argparse.Namespace, config, log_path: Path) -> int:
    out_format = track_format(args.out, args.format)
    spawn = args.spawn and _viewer_can_start()
    building = _checked_building(args, config)
    start = start_from(args, building, args.floor)
    evaal_start = _checked_evaal_start(args, config, building, log_path)
    recording, header_floor, walk, ap_table = _prepared_walk(args, config, building, log_path)
    _announce_walk(args, config, recording)

    from mapfilter.viz import make_logger  # rerun is imported only when a viewer is asked for

    shown_floor = walk.floor_index if walk.floor_index is not None else (header_floor or 0)
    logger = make_logger(building.floors[shown_floor].plan, rrd_path=args.rerun, spawn=spawn,
                         max_particles=args.max_drawn_particles, recording_name=recording.name, stack=walk.stack,
                         warn=warn)
    progress = _Progress(recording, config)
    with logger, progress:
        result = _track_walk(walk, config, recording, header_floor, logger, progress, start)
        written = _write_walk_outputs(args, config, building, walk, recording, result, log_path, evaal_start,
                                      out_format)
    if args.rerun is not None:
        written.append((args.rerun, "rerun recording"))
    if args.plot is not None:
        _plot(building.floors[shown_floor], recording, result, args.plot, walk.floor_index is None)
        written.append((args.plot, "picture of the tracks"))
    # the track itself on standard output: the summary goes to stderr, out of its way
    summary_to = sys.stderr if any(is_stdout(path) for path, _ in written) else sys.stdout
    print(_summary(building, recording, result, header_floor, written,
                   wifi_source_text(args, building, ap_table) + _start_text(start)), file=summary_to)
    if args.out is None:
        print("  no track file written: give --out track.csv (or .tum) to keep the track", file=summary_to)
    return 0


def _start_text(start) -> str:
    """The summary's words for a known start ("" without one)."""
    if start is None:
        return ""
    from mapfilter.pipeline.tracker import KNOWN_START_RADIUS_M

    return f"; started at {start} as given (--start: within {KNOWN_START_RADIUS_M:g} m of it at the first step)"


def _checked_building(args: argparse.Namespace, config):
    """The map or building of ``args.map``, refused when nobody can walk on it, when the tracking
    settings do not fit it, or when it has no floor ``--floor``."""
    from mapfilter.maps.building import Building

    building = Building.load(args.map)
    _check_walkable(building, args.map)
    check_tracking_fits(config, building_extents_m(building), args.radiomap is not None)
    if args.floor is not None:
        building.floor_index(args.floor, args.map)
    return building


def _checked_evaal_start(args: argparse.Namespace, config, building, log_path: Path):
    """--evaal-start parsed (None without it); with --evaal-out, the log checked for a replay."""
    evaal_start = None
    if args.evaal_start is not None:
        from mapfilter.evaal.protocol import parse_position

        evaal_start = parse_position(args.evaal_start, "--evaal-start")
    if args.evaal_out is not None:
        from mapfilter.evaal.replay import check_replay

        check_replay(building, log_path, args.map, online=not config.smooth, initial=evaal_start)
    return evaal_start


def _prepared_walk(args: argparse.Namespace, config, building, log_path: Path):
    """The log read and prepared for tracking: (recording, the floor its header names, the
    prepared walk, the access-point table); a warning for waypoints in walls."""
    from mapfilter.sensors.logs import read_log
    from mapfilter.pipeline.tracker import prepare_walk

    recording = read_log(log_path, strict=args.strict, warn=warn, building=building)
    header_floor = building.floor_of_log(recording.floor_name, log_path, args.floor)  # refuses another floor
    radio_map, ap_table = _wifi_source(args, building, config)
    sources = load_sources(args, building)
    floor = None if building.is_single_floor else args.floor
    walk = prepare_walk(building, recording, radio_map, ap_table, config, floor=floor, sources=sources)
    if recording.has_ground_truth and walk.floor_index is not None and recording.waypoint_floor is None:
        plan = building.floors[walk.floor_index].plan
        in_walls = ~plan.is_free(recording.waypoint_xy_m)
        if in_walls.any():
            warn(f"{log_path}: {int(in_walls.sum())} of {in_walls.size} waypoints lie in walls or outside the "
                 f"map {args.map}")
    return recording, header_floor, walk, ap_table


def _announce_walk(args: argparse.Namespace, config, recording) -> None:
    """How long the tracking will take, and how large the rerun recording will be."""
    span_s = _span_s(recording)
    particles = config.filter.n_particles
    announce_estimate(f"tracking {recording.name}", estimate_tracking_s(
        [span_s], particles, 1 + (SMOOTH_EXTRA_RUNS if config.smooth else 0)),
        f"a {duration_text(span_s)} walk, {particles} particles")
    if args.rerun is not None:
        announce_recording_size(span_s, min(particles, args.max_drawn_particles), args.rerun)


def _track_walk(walk, config, recording, header_floor, logger, progress, start=None):
    """The walk tracked (from ``start`` when it is known), each step and the tracks drawn by
    ``logger`` (and the ground truth), progress on the bar; the ``TrackResult``."""
    from mapfilter.pipeline.tracker import track_prepared

    if recording.has_ground_truth and (walk.stack is None or header_floor is not None
                                       or recording.waypoint_floor is not None):
        logger.log_ground_truth(recording.waypoint_t_s, recording.waypoint_xy_m, recording.waypoint_floor)

    def on_step(report) -> None:
        logger.log_step(report)
        progress.update(report.t_s)

    result = track_prepared(walk, config, on_step=on_step, on_offline_step=progress.offline_step,
                            on_smoothed=logger.log_smoothed if logger.enabled else None, start=start)
    progress.finish()  # a walk without steps to place has no second run
    if result.restarted is not None:
        # the second causal run, from the placed start, whose estimates placed the offline track
        logger.log_track("restarted", result.restarted.t_s, result.restarted.xy_m, result.restarted.floor)
    if result.offline is not None:
        logger.log_track("smoothed", result.offline.t_s, result.offline.xy_m, result.offline.floor)
    return result


def _write_walk_outputs(args: argparse.Namespace, config, building, walk, recording, result, log_path: Path,
                        evaal_start, out_format: str) -> list[tuple]:
    """The track files (--out, with its causal track beside an offline one), --adapted-aps and
    --evaal-out written; [(path, what)] of each."""
    from mapfilter.io.tracks import write_track

    written = []
    if args.out is not None:
        if result.offline is not None:
            with atomic_paths(args.out, causal_path(args.out)) as (tmp, tmp_causal):  # both files or neither
                write_track(result.offline, tmp, out_format, building)
                write_track(result.causal, tmp_causal, out_format, building)
            written += [(args.out, "offline track"), (causal_path(args.out), "causal track")]
        else:
            write_track(result.causal, args.out, out_format, building)
            written.append((args.out, "causal track"))
    if args.adapted_aps is not None:
        result.access_points.write_csv(args.adapted_aps)
        written.append((args.adapted_aps, "adapted access-point table"))
    if args.evaal_out is not None:
        from mapfilter.evaal.replay import replay_log
        from mapfilter.pipeline.tracker import Tracker

        # the server sends no header: the log's phone model as the competitor knows it
        inputs = dataclasses.replace(walk.inputs, phone_model=recording.phone_model)
        floor = None if building.is_single_floor else args.floor
        replay = replay_log(Tracker(building, inputs, config, floor=floor), log_path, initial=evaal_start)
        replay.estimates.write(args.evaal_out)
        written.append((args.evaal_out, f"competition estimates, {'offline' if config.smooth else 'online'}"))
    return written


def _run_live(args: argparse.Namespace, config) -> int:
    """``mapfilter track MAP -``: the log on standard input as it is written (a phone streaming its
    sensors, ``tail -f``, a socket); each causal estimate printed to standard output as a CSV row
    as soon as it exists, and written to ``--out`` before that (``io.live``: the file is in place
    from the first row on and holds every row printed, whatever stops the run; ``--rerun`` grows
    alike). Ctrl-C or SIGTERM while waiting for input ends the walk there: the records already
    read are tracked to the end and the summary printed; the exit code is the signal's."""
    import numpy as np

    from mapfilter.io.live import LiveTrackFile
    from mapfilter.maps.building import Building
    from mapfilter.pipeline.tracker import Tracker, TrackingInputs

    if config.smooth:
        raise MapfilterError("--smooth needs the whole walk: a live run (LOG -) gives the causal track")
    if is_stdout(args.out):
        raise MapfilterError("a live run (LOG -) prints its rows on standard output: --out takes a file name")
    if args.adapted_aps is not None:
        raise MapfilterError("--adapted-aps is not for a live run (LOG -)")
    _refuse_standard_input_as_output(args)
    out_format = track_format(args.out, args.format)
    building = Building.load(args.map)
    _check_walkable(building, args.map)
    check_tracking_fits(config, building_extents_m(building), args.radiomap is not None)
    radio_map, ap_table = _wifi_source(args, building, config)
    floor = None if building.is_single_floor else args.floor
    start = start_from(args, building, args.floor)
    spawn = args.spawn and _viewer_can_start()
    logger = None

    def on_step(report) -> None:
        logger.log_step(report)

    tracker = Tracker(building, TrackingInputs(radio_map, ap_table, load_sources(args, building)), config, floor=floor,
                      log_name="standard input", on_step=on_step, start=start)
    shown = 0 if floor is None else building.floor_index(floor, args.map)

    from mapfilter.viz import make_logger  # rerun is imported only when a viewer is asked for

    logger = make_logger(building.floors[shown].plan, rrd_path=args.rerun, spawn=spawn,
                         max_particles=args.max_drawn_particles, recording_name="standard input", stack=tracker.stack,
                         warn=warn, growing=True)
    with logger:
        with LiveTrackFile(args.out, out_format, building) if args.out is not None else contextlib.nullcontext() as out:
            printed, truth, interrupted = _follow_standard_input(args, building, tracker, out)
        result = tracker.result()
    written = [(path, what) for path, what in ((args.out, f"causal track, {printed} rows as they came"),
                                                (args.rerun, "rerun recording, drawn as it came")) if path is not None]
    if args.plot is not None:
        several = floor is None and not building.is_single_floor
        if several:  # the floor most rows are on
            names, counts = np.unique(result.causal.floor, return_counts=True)
            shown = building.floor_index(str(names[np.argmax(counts)]))
        _plot(building.floors[shown], truth, result, args.plot, several)
        written.append((args.plot, "picture of the tracks"))
    ended = ""
    if interrupted is not None:
        from mapfilter.cli import Terminated

        ended = f"ended by {'SIGTERM' if isinstance(interrupted, Terminated) else 'Ctrl-C'}; "
    print(f"standard input: {ended}{result.n_filter_steps} filter steps, {result.n_scans_used} WiFi scans used{_measured(result)}, "
          f"{len(result.collapses)} collapses; causal {result.causal_runtime_s:.1f} s"
          + "".join(f"; wrote {path} ({what})" for path, what in written), file=sys.stderr)
    print(f"  {wifi_source_text(args, building, ap_table)}{_start_text(start)}", file=sys.stderr)
    if interrupted is not None:
        raise interrupted  # the exit code says how the walk ended (130, 143)
    return 0


def _follow_standard_input(args: argparse.Namespace, building, tracker, out):
    """Feed standard input to ``tracker`` as it comes and print (after writing it to ``out``)
    each chunk of rows: (rows printed, the log's ground truth as a ``Recording``, the interrupt
    that ended the input or None)."""
    import numpy as np

    from mapfilter.io.tracks import csv_header, csv_rows, with_latlon
    from mapfilter.sensors.logs import LogStream, localise
    from mapfilter.sensors.recording import Recording

    stream = LogStream("-", strict=args.strict)
    printed = 0
    truth_t, truth_xy, truth_floor = [], [], []  # the waypoints read, for the picture

    def emit(rows) -> None:
        nonlocal printed
        if not len(rows):
            return
        if building.georeference is not None:
            rows = with_latlon(rows, building)
        if out is not None:
            out.append(rows)  # the file first: it holds every row printed
        lines = [",".join(row) for row in csv_rows(rows)]
        if not printed:
            lines.insert(0, ",".join(csv_header(rows)))
        print("\n".join(lines), flush=True)
        printed += len(rows)

    def keep_truth(records: Recording) -> Recording:
        if records.has_ground_truth:
            if records.needs_georeference and building.georeference is not None:
                records = localise(records, building)
            if not records.needs_georeference:
                truth_t.append(records.waypoint_t_s)
                truth_xy.append(records.waypoint_xy_m)
                truth_floor.append(records.waypoint_floor)
        return records

    interrupted = None
    source = sys.stdin.buffer
    try:
        while True:
            try:
                data = _read_when_it_comes(source)  # what has arrived, as soon as anything has
            except KeyboardInterrupt as signal:  # Ctrl-C or SIGTERM while waiting: the walk ends here
                interrupted = signal
                break
            if not data:
                break
            emit(tracker.feed(keep_truth(stream.feed_bytes(data))))
        emit(tracker.feed(keep_truth(stream.close())))
        emit(tracker.close())
    except KeyboardInterrupt:
        kept = f"; {args.out} holds them" if out is not None and out.n_rows else ""
        print(f"standard input: stopped after {printed} rows{kept}", file=sys.stderr)
        raise
    if stream.report.warning():
        warn(stream.report.warning())
    truth = Recording.empty(Path("standard input"))
    if truth_t:
        floors = None if any(f is None for f in truth_floor) else [name for part in truth_floor for name in part]
        truth = dataclasses.replace(truth, waypoint_t_s=np.concatenate(truth_t), waypoint_xy_m=np.concatenate(truth_xy),
                                    waypoint_floor=floors)
    return printed, truth, interrupted


def _read_when_it_comes(source, wake_s: float = 0.5) -> bytes:
    """What standard input has, once it has something (b"" at its end). Between waits of
    ``wake_s`` the main thread raises a Ctrl-C or SIGTERM that came meanwhile: one the kernel gave
    another thread does not interrupt a read blocked in the main one, and one whose exception a
    finalizer swallowed while the last chunk was tracked is only noted (``runtime.interrupts``);
    either would otherwise leave a live run waiting on an input that stays open (``tail -f``)."""
    import select

    from mapfilter.runtime.interrupts import raise_pending_signal

    raise_pending_signal()
    try:
        fd = source.fileno()
    except (AttributeError, OSError, ValueError):  # a stand-in without a descriptor
        return source.read1(65536)
    if os.name == "nt":  # select() takes sockets only there
        return source.read1(65536)
    while not select.select([fd], [], [], wake_s)[0]:
        raise_pending_signal()
    return os.read(fd, 65536)


def _refuse_standard_input_as_output(args: argparse.Namespace) -> None:
    """A live run reading a file (``< live.csv``) never writes its --out over that file."""
    try:
        given = os.fstat(sys.stdin.fileno())
    except (OSError, ValueError, AttributeError):  # no standard input, or a stand-in without a descriptor
        return
    for option, path in (("--out", args.out), ("--rerun", args.rerun), ("--plot", args.plot)):
        if path is not None and stat.S_ISREG(given.st_mode) and path.exists() and os.path.samestat(given, os.stat(path)):
            raise MapfilterError(f"{option} is the file standard input reads: give another name", path)


def _span_s(recording) -> float:
    """The walk's time in seconds: its span less the gaps its reader found (else its WiFi scans')."""
    report = recording.read_report
    if report is not None and report.time_span_s is not None:
        gaps = sum(end - start for start, end in report.time_gaps_s or ())
        return float(report.time_span_s[1] - report.time_span_s[0] - gaps)
    times = recording.wifi.t_s
    return float(times[-1] - times[0]) if len(times) else 0.0


def _plot(floor, recording, result, path: Path, several_floors: bool) -> None:
    """The tracks and the ground truth over the floor's walls (``evaluation.plots``); with several
    floors, the rows on this floor only."""
    import numpy as np

    from mapfilter.evaluation.plots import plot_tracks_on_map

    tracks = {}
    for name, track in (("causal", result.causal), ("offline", result.offline)):
        if track is None:
            continue
        on = np.ones(len(track), dtype=bool) if track.floor is None or not several_floors else (
            np.array(track.floor) == floor.name)
        tracks[name] = track.xy_m[on]
    truth = None
    if recording.has_ground_truth:
        truth = recording.waypoint_xy_m
        if recording.waypoint_floor is not None:
            truth = truth[np.array(recording.waypoint_floor) == floor.name]
    plot_tracks_on_map(floor.plan, tracks, path, truth, title=f"{recording.name} on {floor.name}")


def _viewer_can_start() -> bool:
    """--spawn: whether a rerun viewer can start here; if not, one line says so and the run goes
    on without one (a viewer spawned without a display blocks, and its run could hang)."""
    from mapfilter.viz import viewer_problem

    problem = viewer_problem()
    if problem is not None:
        warn(f"--spawn: no rerun viewer can start here: {problem}; tracking without one (write a recording "
             "with --rerun FILE.rrd and open it where there is a display)")
    return problem is None


def _check_walkable(building, map_path: Path) -> None:
    """A map with no free space is refused; one whose free space is mostly cut off is warned about."""
    from mapfilter.maps.walkable import check_before_tracking

    for message in check_before_tracking(building, map_path):
        warn(message)


def _collapse_lines(collapses, t0: float) -> list[str]:
    """One line per collapse, or one line for them all when they repeat."""
    if len(collapses) <= MAX_COLLAPSE_LINES:
        return [f"  collapse at t={e.t_s - t0:+.1f} s ({e.cause}, {e.particles_lost} particles lost) -> recovered by "
                f"{e.recovery}" for e in collapses]
    causes = Counter(e.cause for e in collapses)
    recoveries = Counter(e.recovery for e in collapses)
    return [f"  {len(collapses)} collapses from t={collapses[0].t_s - t0:+.1f} s to t={collapses[-1].t_s - t0:+.1f} s "
            f"({', '.join(f'{c} {n}' for c, n in causes.most_common())}; recovered by "
            f"{', '.join(f'{r} {n}' for r, n in recoveries.most_common())}): the map may trap the particles "
            "(look at its preview) or the WiFi may disagree with it"]


def _measured(result) -> str:
    """", 120 windows" for each measurement source that measured (its ``counts``)."""
    counts = {entry.name: entry.counts for entry in registered()}
    return "".join(f", {n} {counts[name]}" for name, n in result.n_measurements.items() if n)


def _summary(building, recording, result, header_floor, written, wifi: str) -> str:
    """The printout of one walk: what ran (``wifi``: what weighed the WiFi), each track's numbers,
    collapses, the files written."""
    from mapfilter.evaluation.metrics import summarise_errors
    from mapfilter.evaluation.scoring import score_track

    collapses = f"{len(result.collapses)} collapse{'s' if len(result.collapses) != 1 else ''}"
    if result.collapses:
        collapses += " (all recovered)"
    lines = [f"{recording.name}: {result.n_filter_steps} filter steps, {result.n_scans_used} WiFi scans used"
             f"{_measured(result)}, "
             f"{collapses}; causal {result.causal_runtime_s:.1f} s"
             + (f", offline {result.offline_runtime_s:.1f} s" if result.offline is not None else ""), f"  {wifi}"]
    tracks = [("causal", result.causal, True)]
    if result.offline is not None:
        tracks.append(("offline", result.offline, False))
    for label, track, causal in tracks:
        score = score_track(building, recording, track, header_floor, causal)
        text = f"  {label:8s} wall crossings {score.wall_crossings}"
        if not building.is_single_floor:
            text += f"; floors {', '.join(score.floors)}"
        if score.errors is not None:
            s = summarise_errors(score.errors.errors_m)
            text += (f"; error at {s['n']} waypoints: mean {s['mean']:.2f} m, median {s['median']:.2f} m, "
                     f"p75 {s['p75']:.2f} m, max {s['max']:.2f} m")
            if score.errors.missed:
                n = score.errors.missed
                text += f" ({n} waypoint{'s' if n != 1 else ''} before the first estimate, not scored)"
            if score.floor_score is not None:
                right = score.floor_score
                where = score.true_floor if isinstance(score.true_floor, str) else "the walker's floor"
                text += f"; on {where} at {right.n_right} of {right.n_judged} waypoints ({right.accuracy:.0%})"
                if score.off_floor:
                    text += " (rows on another floor compared in their own floor's frame)"
        lines.append(text)
    t0 = float(recording.wifi.t_s[0]) if len(recording.wifi) else 0.0
    lines += _collapse_lines(result.collapses, t0)
    for start, end in result.gaps:
        lines.append(f"  gap in the log from t={start - t0:+.1f} s to t={end - t0:+.1f} s: the filter started afresh")
    for path, what in written:
        lines.append(f"  wrote {'standard output' if is_stdout(path) else path} ({what})")
    return "\n".join(lines)


# the files of a batch itself: a walk whose trace has one of these names gets "<trace>.track.<format>"
BATCH_FILES = ("summary.csv", "summary.json", "config.yaml")


def batch_track_names(traces: list[str], out_format: str, smooth: bool) -> dict[str, str]:
    """{trace: its track file's name in --out-dir}: ``<trace>.<format>``, or
    ``<trace>.track.<format>`` where that is one of the batch's own files (a log named
    summary.txt.gz) or another walk's causal track; refused if two walks would still share one."""
    names: dict[str, str] = {}
    taken = set(BATCH_FILES)
    plain = {f"{t}.{out_format}" for t in traces}
    for trace in traces:
        name = f"{trace}.{out_format}"
        causal = {causal_path(Path(n)).name for n in plain if n != name} if smooth else set()
        if name in taken or name in causal:
            name = f"{trace}.track.{out_format}"
        files = {name, causal_path(Path(name)).name} if smooth else {name}
        if files & taken:
            raise MapfilterError(f"the track files of walk {trace} ({', '.join(sorted(files))}) would overwrite "
                                 "another output of this run: rename the log")
        taken |= files
        names[trace] = name
    return names


def _run_batch(args: argparse.Namespace, config, out_dir) -> int:
    from mapfilter.batch import BUILDING_SUMMARY_COLUMNS, SUMMARY_COLUMNS, BatchSetup, track_logs
    from mapfilter.sensors.recording import trace_name

    _check_batch_logs(args)
    engine = engine_from(args)
    building = _checked_building(args, config)
    radio_map, ap_table = _wifi_source(args, building, config)
    setup = BatchSetup(tracking=config, strict=args.strict, floor=None if building.is_single_floor else args.floor,
                       sources=load_sources(args, building), start=start_from(args, building, args.floor))
    columns = SUMMARY_COLUMNS if building.is_single_floor else BUILDING_SUMMARY_COLUMNS
    out_format = args.format or "csv"
    track_names = batch_track_names([trace_name(p) for p in args.logs], out_format, config.smooth)
    write = _BatchTrackWriter(out_dir, building, track_names, out_format, config.smooth)
    _announce_batch(args, config)
    started = time.perf_counter()
    try:
        with ProgressBar("track", len(args.logs)) as progress:
            results = track_logs(building, args.logs, radio_map, ap_table, setup, engine, progress=progress,
                                 on_result=write)
        wall_time_s = time.perf_counter() - started
        summary = _write_batch_summary(args, config, out_dir, engine, results, write.track_files, columns,
                                       wall_time_s)
        out_dir.commit()
    except KeyboardInterrupt:
        out_dir.commit()  # an interrupted batch keeps the tracks it finished
        raise
    finally:
        out_dir.discard()  # after a failure: nothing of this run, the earlier files whole
    bad = [r for r in results if not r.ok]
    for result in bad:
        print(f"mapfilter: {result.status}: {result.reason}", file=sys.stderr)
    print(_batch_summary_line(results, engine, wall_time_s))
    print(f"wrote {sum(r.ok for r in results)} tracks, {summary}, summary.json and config.yaml to {args.out_dir}")
    return 1 if bad else 0


def _check_batch_logs(args: argparse.Namespace) -> None:
    """Refuse --spawn with --out-dir, and a log that is not there, before any work."""
    from mapfilter.sensors.logs import missing_log

    if args.spawn:
        raise MapfilterError("--spawn is for one walk, not for --out-dir")
    for path in args.logs:
        if not path.is_file():
            raise missing_log(path)


class _BatchTrackWriter:
    """``on_result`` of a batch: each walk's track (and causal track) staged in --out-dir as the
    walk finishes; they are committed together at the end (an earlier run's files stay whole if
    this one fails), or when the batch is interrupted. ``track_files``: {trace: its file}."""

    def __init__(self, out_dir, building, track_names: dict[str, str], out_format: str, smooth: bool) -> None:
        self.out_dir, self.building, self.track_names = out_dir, building, track_names
        self.out_format, self.smooth = out_format, smooth
        self.track_files: dict[str, str] = {}

    def __call__(self, result) -> None:
        from mapfilter.io.tracks import write_track

        if result.read_warning:
            warn(result.read_warning)
        if result.ok:
            name = self.track_names[result.trace]
            with self.out_dir.writing(name) as (tmp,):
                write_track(result.track, tmp, self.out_format, self.building)
            if self.smooth and result.causal is not None:
                with self.out_dir.writing(causal_path(Path(name)).name) as (tmp,):
                    write_track(result.causal, tmp, self.out_format, self.building)
            self.track_files[result.trace] = name


def _announce_batch(args: argparse.Namespace, config) -> None:
    """How long tracking the walks will take."""
    spans = walk_spans_s(args.logs)
    workers = args.jobs if args.scheduler is None else 1
    announce_estimate(f"tracking {len(args.logs)} walk{'s' if len(args.logs) != 1 else ''}", estimate_tracking_s(
        spans, config.filter.n_particles, 1 + (SMOOTH_EXTRA_RUNS if config.smooth else 0), workers),
        f"{duration_text(sum(spans))} of walks, {config.filter.n_particles} particles, {workers} worker"
        + ("s" if workers != 1 else ""))


def _write_batch_summary(args: argparse.Namespace, config, out_dir, engine, results, track_files: dict[str, str],
                         columns, wall_time_s: float) -> Path:
    """summary.csv (a row per walk), summary.json (the run's inputs, engine, settings and rows) and
    config.yaml staged in --out-dir; the path of summary.csv."""
    from mapfilter.batch import summary_row

    summary = out_dir.path / BATCH_FILES[0]
    rows = [summary_row(result, track_files.get(result.trace), columns) for result in results]
    with out_dir.writing(*BATCH_FILES) as (tmp, tmp_json, tmp_yaml):
        with tmp.open("w", newline="") as handle:
            writer = csv.DictWriter(handle, columns)
            writer.writeheader()
            for row in rows:
                writer.writerow({k: (f"{v:.4f}" if isinstance(v, float) else ("" if v is None else v))
                                 for k, v in row.items()})
        tmp_json.write_text(json.dumps({"map": str(args.map), "logs": [str(p) for p in args.logs],
                                        "radiomap": None if args.radiomap is None else str(args.radiomap),
                                        "aps": None if args.aps is None else str(args.aps),
                                        "sources": {name: {key: str(path) for key, path in files.items()}
                                                    for name, files in source_files(args).items()},
                                        "engine": engine.describe(), "wall_time_s": wall_time_s,
                                        "config": config.to_dict(), "walks": rows}, indent=1))
        tmp_yaml.write_text(config.to_yaml())
    return summary


def _batch_summary_line(results, engine, wall_time_s: float) -> str:
    """The batch in one line: walks tracked, failed and crashed, time, mean error, floor."""
    import numpy as np

    tracked = [r for r in results if r.ok]
    errors = [r.error_stats["mean"] for r in tracked if r.error_stats and r.error_stats["n"]]
    line = (f"{len(results)} walks ({engine.describe()}): {len(tracked)} tracked, "
            f"{sum(r.status == 'failed' for r in results)} failed, {sum(r.status == 'crashed' for r in results)} "
            f"crashed; {wall_time_s:.1f} s, {60 * len(results) / max(wall_time_s, 1e-9):.1f} walks/min")
    if errors:
        line += f"; mean of per-walk mean errors {np.mean(errors):.2f} m"
    judged = sum(r.floor_score.n_judged for r in tracked if r.floor_score)
    if judged:
        right = sum(r.floor_score.n_right for r in tracked if r.floor_score)
        line += f"; on the walker's floor at {right} of {judged} waypoints ({right / judged:.0%})"
    return line


class _Progress:
    """Progress through the walk's time span on a tqdm bar (drawn only on a terminal)."""

    def __init__(self, recording, config) -> None:
        times = recording.wifi.t_s
        self.t0 = float(times[0]) if times.size else 0.0
        self.span_s = max(float(times[-1]) - self.t0, 1e-9) if times.size else 1.0
        # filter runs over the walk, each an equal share of the bar: with --smooth and PDR the
        # offline track of a walk on one floor runs the filter a second time (``finish`` ends
        # the bar where a walk has no second run)
        self.runs = 2 if config.smooth and config.motion.model == "pdr" else 1
        self.bar = ProgressBar("tracking", 100, unit="%")

    def update(self, t_s: float, run: int = 0) -> None:
        done = min(max((t_s - self.t0) / self.span_s, 0.0), 1.0)
        self.bar.update_to(int(100 * (run + done) / self.runs))

    def offline_step(self, report) -> None:
        """A step of the offline stage's second filter run (``on_offline_step``)."""
        self.update(report.t_s, run=1)

    def finish(self) -> None:
        self.bar.update_to(100)

    def __enter__(self) -> _Progress:
        return self

    def __exit__(self, *exc_info) -> None:
        self.bar.close()
