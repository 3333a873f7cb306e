"""``mapfilter track MAP LOG``: track one walk, write the track, print the errors.
``mapfilter track MAP LOG... --out-dir DIR``: track many walks, one track file each + a summary."""

from __future__ import annotations

import argparse
import csv
import sys
import time
from pathlib import Path

from mapfilter.atomic import atomic_paths
from mapfilter.cli.common import ProgressBar, add_engine_arguments, add_strict_argument, engine_from, warn
from mapfilter.errors import MapfilterError

# What mapfilter.tracking defines (MOTION_MODELS, FINGERPRINT_MODELS, TrackingConfig defaults),
# written out so that --help imports no numerical library: tests/test_cli_startup.py holds
# them equal to the library's.
MOTION_MODELS = ("pdr", "cv", "rw")
FINGERPRINT_MODELS = ("fix", "blend", "likelihood")
DEFAULT_FINGERPRINT_MODEL = "blend"
DEFAULT_KWNN_MIN_RSSI_DBM = -85.0  # TrackingConfig.kwnn_min_rssi_dbm


def kwnn_min_rssi(text: str) -> float | None:
    """``--kwnn-min-rssi``: a dBm value, or ``none`` for plain KWNN over every reading."""
    if text.strip().lower() == "none":
        return None
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a dBm value or none, got {text!r}") from None


def add_kwnn_min_rssi_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--kwnn-min-rssi", type=kwnn_min_rssi, default=DEFAULT_KWNN_MIN_RSSI_DBM, metavar="DBM",
                        help="the filter's KWNN fixes use readings at or above this only (phones disagree most "
                             "on weak APs); none: every reading, as the kwnn baseline "
                             f"(default: {DEFAULT_KWNN_MIN_RSSI_DBM:g})")
DEFAULT_PARTICLES = 10_000
DEFAULT_ADAPT_RSSI_LIMIT_DBM = -36.0  # AdaptationConfig.rssi_limit_dbm (the thesis' limit)

_EPILOG = """\
WiFi: --radiomap RM (fingerprinting; build one with `mapfilter radiomap build`) or --aps
APS.csv (trilateration with the path-loss model); without either, the map's own
access-point table (mapfilter: access_points in its YAML) is used for trilateration.

The starting position is unknown: the filter starts from the first usable WiFi scan, drawn
over the map's free space. If the log has waypoints, the errors at the waypoint times are
printed (the latest estimate at or before each waypoint).

Many walks: give several logs and --out-dir DIR: one track per walk (DIR/<trace>.csv or
.tum) and DIR/summary.csv (one row per walk: status ok | failed | crashed, the reason,
errors). A walk that fails is reported and the others go on; the exit code is 1 if any
walk failed. Each walk is tracked as `mapfilter track MAP LOG --seed S` tracks it alone.
--jobs N runs the walks on N local Dask worker processes, --scheduler tcp://HOST:PORT on an
existing Dask cluster (see `mapfilter evaluate --help`).

A building (MAP a building YAML, docs/building.md) with a building's radio map (built with
`mapfilter radiomap build BUILDING.yaml LOGS...`): the floor is part of the filter's state
and found from the WiFi (or given with --floor NAME); the track's x, y are in the frame of
the floor it is on, and a `floor` column names that floor. The log's header floor
(FloorName), when it names one, must be a floor of the building; it is used only to print
how often the track was on it (on each waypoint's own floor where the log names it, as
simulated walks that change floor do). With --out-dir, summary.csv adds header_floor, floors
(the floors the track visits) and floor_accuracy; a log whose header floor the building
does not have is refused before any walk is tracked.

example:
  mapfilter track maps/office.yaml maps/office_walk.txt --radiomap maps/office_radiomap.npz
  mapfilter track site1.yaml walk.txt.gz --radiomap site1_radiomap.npz --out track.csv
  mapfilter track F1.yaml walks/*.txt.gz --radiomap F1_radiomap.npz --out-dir tracks --jobs 2
  mapfilter track site1.yaml walks/*.txt.gz --radiomap site1_radiomap.npz --out-dir tracks
"""


def add_trilateration_arguments(parser: argparse.ArgumentParser) -> None:
    """The Lund thesis chapter 7 options (track and evaluate)."""
    parser.add_argument("--adapt", action="store_true",
                        help="trilateration: adapt the path-loss parameters during the run (C of the AP the phone "
                             "is below when a scan's strongest RSSI is above the limit, alpha per band; "
                             "Lund thesis 7.1-7.2)")
    parser.add_argument("--adapt-rssi-limit", type=float, default=DEFAULT_ADAPT_RSSI_LIMIT_DBM, metavar="DBM",
                        help="with --adapt: a scan whose strongest RSSI is above this adapts (default: %(default)s, "
                             "the thesis' value; about the RSSI 1-1.5 m from an AP of your building)")
    parser.add_argument("--no-blocking-compensation", action="store_true",
                        help="trilateration: do not compensate signal blocking (by default a term H is taken off "
                             "every AP while the six strongest drop together by more than 6 dB; Lund thesis 7.3)")


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "track", help="track a walk (map + phone log) with the particle filter",
        description="Track a walk on a floor plan with the map-aware particle filter.",
        epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("map", type=Path, metavar="MAP", help="map YAML (ROS map_server) or building YAML")
    parser.add_argument("logs", type=Path, nargs="+", metavar="LOG",
                        help="phone log(s) in the ILC trace format (.txt or .txt.gz); several need --out-dir")
    wifi = parser.add_mutually_exclusive_group()
    wifi.add_argument("--radiomap", type=Path, metavar="RM", help="radio map (.npz) for fingerprinting")
    wifi.add_argument("--aps", type=Path, metavar="APS.csv", help="access-point table for trilateration")
    parser.add_argument("--motion", choices=MOTION_MODELS, default="pdr",
                        help="motion model: pdr (steps + gyro), cv (constant velocity), rw (random walk) (default: pdr)")
    parser.add_argument("--fingerprint-model", choices=FINGERPRINT_MODELS, default=DEFAULT_FINGERPRINT_MODEL,
                        help="fix: KWNN fix weighed by a Gaussian; blend: that fix averaged with the radio-map "
                             "likelihood's best cell; likelihood: per-particle radio-map likelihood "
                             f"(default: {DEFAULT_FINGERPRINT_MODEL})")
    parser.add_argument("--particles", type=int, default=DEFAULT_PARTICLES, metavar="N",
                        help=f"number of particles (default: {DEFAULT_PARTICLES})")
    add_kwnn_min_rssi_argument(parser)
    add_trilateration_arguments(parser)
    parser.add_argument("--adapted-aps", type=Path, metavar="OUT.csv",
                        help="with --adapt: write the access-point table as adapted at the end of the walk")
    parser.add_argument("--floor", metavar="NAME",
                        help="a building: track on this floor only (default: find the floor)")
    parser.add_argument("--seed", type=int, default=0, metavar="S", help="random seed (default: 0)")
    parser.add_argument("--no-map", action="store_true", help="ignore the walls (to see what the map buys)")
    parser.add_argument("--smooth", action="store_true",
                        help="write the offline track from the whole walk: the dead-reckoned shape placed by every "
                             "scan, kept to free space (never crosses a wall)")
    parser.add_argument("--out", type=Path, metavar="FILE", help="write the track here (one log)")
    parser.add_argument("--out-dir", type=Path, metavar="DIR",
                        help="track every LOG: one track file per walk and summary.csv in DIR")
    parser.add_argument("--format", choices=("csv", "tum"), default="csv",
                        help="csv: t_s,x_m,y_m,std_m,heading_rad; tum: t x y z qx qy qz qw (evo) (default: csv)")
    view = parser.add_mutually_exclusive_group()
    view.add_argument("--rerun", type=Path, metavar="FILE.rrd", help="write a rerun recording of the run")
    view.add_argument("--spawn", action="store_true", help="stream the run to a new rerun viewer")
    parser.add_argument("--max-drawn-particles", type=int, default=5000, metavar="N",
                        help="cap on particles drawn per step in rerun (default: 5000)")
    add_engine_arguments(parser)
    add_strict_argument(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from mapfilter.maps.floorplan import FloorPlan
    from mapfilter.sensors.ilc import read_ilc
    from mapfilter.tracking import track_recording
    from mapfilter.trackio import write_track_csv, write_track_tum

    if args.particles < 1:
        raise MapfilterError(f"--particles must be at least 1, got {args.particles}")
    if args.adapted_aps is not None and args.out_dir is not None:
        raise MapfilterError("--adapted-aps is for one walk, not for --out-dir")
    if args.out_dir is not None:
        return _run_batch(args)
    if len(args.logs) > 1:
        raise MapfilterError(f"{len(args.logs)} logs: tracking several walks needs --out-dir DIR")
    if args.jobs != 1 or args.scheduler:
        raise MapfilterError("--jobs and --scheduler spread many walks: give them with --out-dir DIR")
    args.log = args.logs[0]
    from mapfilter.maps.building import Building

    building = Building.load(args.map)
    if not building.is_single_floor:
        return _run_building(args, building)
    if args.floor is not None:
        raise MapfilterError("--floor picks a floor of a building: this map has one floor", args.map)
    if args.radiomap is not None and (args.adapt or args.adapted_aps is not None):
        raise MapfilterError("--adapt and --adapted-aps adapt a path-loss table: they need trilateration "
                             "(--aps APS.csv or the map's table), not --radiomap")
    if args.adapted_aps is not None and not args.adapt:
        raise MapfilterError("--adapted-aps writes the adapted table: give --adapt too")
    floorplan = building.floors[0].plan
    recording = read_ilc(args.log, strict=args.strict, warn=warn)
    radio_map, ap_table = _wifi_source(args, floorplan)
    if recording.has_ground_truth:
        in_walls = ~floorplan.is_free(recording.waypoint_xy_m)
        if in_walls.any():
            print(f"mapfilter: warning: {args.log}: {int(in_walls.sum())} of {in_walls.size} waypoints lie in walls "
                  f"or outside the map {args.map}", file=sys.stderr)
    config = _tracking_config(args)

    from mapfilter.viz import make_logger  # rerun is imported only when a viewer is asked for

    logger = make_logger(floorplan, rrd_path=args.rerun, spawn=args.spawn, max_particles=args.max_drawn_particles,
                         recording_name=recording.name)
    progress = _Progress(recording, config)
    with logger, progress:
        if recording.has_ground_truth:
            logger.log_ground_truth(recording.waypoint_t_s, recording.waypoint_xy_m)

        def on_step(report) -> None:
            logger.log_step(report)
            progress.update(report.t_s)

        result = track_recording(floorplan, recording, radio_map, ap_table, config, np.random.default_rng(args.seed),
                                 on_step=on_step, on_restart_step=progress.restart_step)
        progress.finish()  # a walk without steps to place has no second run
        if result.restarted is not None:
            # the second causal run, from the placed start, whose estimates placed the offline track
            logger.log_track("restarted", result.restarted.t_s, result.restarted.xy_m)
        if result.smoothed is not None:
            logger.log_track("smoothed", result.smoothed.t_s, result.smoothed.xy_m)
        output = result.smoothed if args.smooth else result.track
        if args.out is not None:
            (write_track_tum if args.format == "tum" else write_track_csv)(output, args.out)
        if args.adapted_aps is not None:
            result.ap_table.write_csv(args.adapted_aps)

    _print_summary(floorplan, recording, result, args)
    return 0


def _run_building(args: argparse.Namespace, building) -> int:
    """One walk in a several-floor building: the floor in the filter's state (or --floor)."""
    import numpy as np

    from mapfilter.floortracking import track_building
    from mapfilter.sensors.ilc import read_ilc
    from mapfilter.trackio import write_track_csv, write_track_tum

    from mapfilter.sensors.floors import load_building_radio_map

    _check_building_options(args, building)
    recording = read_ilc(args.log, strict=args.strict, warn=warn)
    header_floor = building.floor_of_log(recording.floor_name, args.log)  # refuses a floor not in the building
    radio_map = load_building_radio_map(args.radiomap, building.floor_names)
    config = _tracking_config(args)

    from mapfilter.viz import make_logger  # rerun is imported only when a viewer is asked for

    from mapfilter.filter.floors import FloorStack

    stack = FloorStack(building) if args.floor is None else None
    plan = building.floors[building.floor_index(args.floor) if args.floor else (header_floor or 0)].plan
    logger = make_logger(plan, rrd_path=args.rerun, spawn=args.spawn, max_particles=args.max_drawn_particles,
                         recording_name=recording.name, stack=stack)
    progress = _Progress(recording, config)
    with logger, progress:
        if recording.has_ground_truth and (header_floor is not None or args.floor is not None):
            logger.log_ground_truth(recording.waypoint_t_s, recording.waypoint_xy_m)

        def on_step(report) -> None:
            logger.log_step(report)
            progress.update(report.t_s)

        result = track_building(building, recording, radio_map, config, np.random.default_rng(args.seed),
                                on_step=on_step, floor=args.floor,
                                on_restart_step=progress.restart_step)
        progress.finish()  # a walk that changes floor has no second run
        if result.restarted is not None:
            logger.log_track("restarted", result.restarted.t_s, result.restarted.xy_m)
        if result.smoothed is not None:
            logger.log_track("smoothed", result.smoothed.t_s, result.smoothed.xy_m)
        output = result.smoothed if args.smooth and result.smoothed is not None else result.track
        if args.out is not None:
            (write_track_tum if args.format == "tum" else write_track_csv)(output, args.out)
    _print_building_summary(building, recording, result, header_floor, args)
    return 0


def _check_building_options(args: argparse.Namespace, building) -> None:
    """The options of a building run (one walk or --out-dir)."""
    if args.radiomap is None:
        raise MapfilterError("tracking in a building needs a building's radio map: --radiomap RM (mapfilter "
                             "radiomap build BUILDING.yaml LOGS...)")
    if args.adapt or args.adapted_aps is not None:
        raise MapfilterError("--adapt is for trilateration on one floor, not for a building")
    if args.floor is not None:
        building.floor_index(args.floor, args.map)


def _print_building_summary(building, recording, result, header_floor, args) -> None:
    from mapfilter.evaluation.floors import score_building_track
    from mapfilter.evaluation.metrics import summarise_errors

    lines = [f"{recording.name}: {result.n_filter_steps} filter steps, {result.n_scans_used} WiFi scans, "
             f"{len(result.collapses)} collapses, {result.runtime_s:.1f} s"]
    tracks = [("causal", result.track, True)]
    if result.smoothed is not None:
        tracks.append(("smoothed", result.smoothed, False))
    for label, track, causal in tracks:
        score = score_building_track(building, recording, track, header_floor, causal)
        text = f"  {label:8s} floors {', '.join(score.floors)}"
        if score.errors is not None:
            right = score.floor_score
            where = score.true_floor if isinstance(score.true_floor, str) else "the walker's floor"
            s = summarise_errors(score.errors.errors_m)
            text += (f"; on {where} at {right.n_right} of {right.n_judged} waypoints ({right.accuracy:.0%}); "
                     f"error at {s['n']} waypoints: mean {s['mean']:.2f} m, median {s['median']:.2f} m, "
                     f"p75 {s['p75']:.2f} m, max {s['max']:.2f} m")
            if score.off_floor:
                text += " (rows on another floor compared in their own floor's frame)"
        lines.append(text)
    if args.out is not None:
        lines.append(f"  wrote {args.out}")
    if args.rerun is not None:
        lines.append(f"  wrote {args.rerun}")
    print("\n".join(lines))


def _print_summary(floorplan, recording, result, args) -> None:
    from mapfilter.evaluation.metrics import errors_at_waypoints, summarise_errors
    from mapfilter.maps.walls import count_wall_crossings

    collapses = f"{len(result.collapses)} collapses" + (" (all recovered)" if result.collapses else "")
    lines = [f"{recording.name}: {result.n_filter_steps} filter steps, {result.n_scans_used} WiFi scans, "
             f"{collapses}, {result.runtime_s:.1f} s"]
    tracks = [("causal", result.track, True)]
    if result.smoothed is not None:
        tracks.append(("smoothed", result.smoothed, False))
    for label, track, causal in tracks:
        crossings = count_wall_crossings(floorplan, track.xy_m)
        text = f"  {label:8s} wall crossings {crossings}"
        if recording.has_ground_truth:
            err = errors_at_waypoints(track.t_s, track.xy_m, recording.waypoint_t_s, recording.waypoint_xy_m, causal)
            s = summarise_errors(err.errors_m)
            text += (f"; error at {s['n']} waypoints: mean {s['mean']:.2f} m, median {s['median']:.2f} m, "
                     f"p75 {s['p75']:.2f} m, max {s['max']:.2f} m")
            if err.missed:
                text += f" ({err.missed} waypoint{'s' if err.missed != 1 else ''} before the first estimate)"
        lines.append(text)
    for event in result.collapses:
        lines.append(f"  collapse at t={event.t_s - recording.wifi.t_s[0]:+.1f} s ({event.cause}, "
                     f"{event.particles_lost} particles lost) -> recovered by {event.recovery}")
    if args.out is not None:
        lines.append(f"  wrote {args.out}")
    if getattr(args, "adapted_aps", None) is not None:
        lines.append(f"  wrote {args.adapted_aps} (adapted access-point table)")
    if args.rerun is not None:
        lines.append(f"  wrote {args.rerun}")
    print("\n".join(lines))


def _wifi_source(args: argparse.Namespace, floorplan):
    from mapfilter.sensors.pathloss import access_points_for_map
    from mapfilter.sensors.radiomap import RadioMap

    radio_map = RadioMap.load(args.radiomap) if args.radiomap else None
    ap_table = None
    if radio_map is None:
        ap_table = access_points_for_map(args.aps, floorplan, args.map, hint="give --radiomap RM or --aps APS.csv")
    return radio_map, ap_table


def _tracking_config(args: argparse.Namespace):
    from mapfilter.filter.adaptive_pathloss import AdaptationConfig
    from mapfilter.tracking import TrackingConfig

    return TrackingConfig(motion=args.motion, n_particles=args.particles, use_map=not args.no_map,
                          fingerprint_model=args.fingerprint_model, smooth=args.smooth, adapt_path_loss=args.adapt,
                          kwnn_min_rssi_dbm=args.kwnn_min_rssi,
                          adaptation=AdaptationConfig(rssi_limit_dbm=args.adapt_rssi_limit),
                          blocking_compensation=not args.no_blocking_compensation)


def _run_batch(args: argparse.Namespace) -> int:
    import numpy as np

    from mapfilter.batch import (BUILDING_SUMMARY_COLUMNS, SUMMARY_COLUMNS, BatchSetup, WalkResult, summary_row,
                                 track_building_logs, track_logs)
    from mapfilter.trackio import write_track_csv, write_track_tum

    for option in ("out", "rerun"):
        if getattr(args, option) is not None:
            raise MapfilterError(f"--{option} is for one walk: with --out-dir every walk gets its own track file")
    if args.spawn:
        raise MapfilterError("--spawn is for one walk, not for --out-dir")
    if args.out_dir.exists() and not args.out_dir.is_dir():
        raise MapfilterError("the output must be a directory", args.out_dir)
    for path in args.logs:
        if not path.is_file():
            raise MapfilterError("file not found", path)
    engine = engine_from(args)
    from mapfilter.maps.building import Building

    building = Building.load(args.map)
    setup = BatchSetup(tracking=_tracking_config(args), seed=args.seed, strict=args.strict, floor=args.floor)
    if building.is_single_floor:
        if args.floor is not None:
            raise MapfilterError("--floor picks a floor of a building: this map has one floor", args.map)
        floorplan = building.floors[0].plan
        radio_map, ap_table = _wifi_source(args, floorplan)
        columns = SUMMARY_COLUMNS

        def track_all(**kwargs):
            return track_logs(floorplan, args.logs, radio_map, ap_table, setup, engine, **kwargs)
    else:
        from mapfilter.sensors.floors import load_building_radio_map

        _check_building_options(args, building)
        radio_map = load_building_radio_map(args.radiomap, building.floor_names)
        columns = BUILDING_SUMMARY_COLUMNS

        def track_all(**kwargs):
            return track_building_logs(building, args.logs, radio_map, setup, engine, **kwargs)
    suffix = ".tum" if args.format == "tum" else ".csv"
    track_files: dict[str, str] = {}

    def write(result: WalkResult) -> None:
        # each track is written as its walk finishes (atomically): an interrupted batch keeps them
        if result.read_warning:
            warn(result.read_warning)
        if result.ok:
            path = args.out_dir / f"{result.trace}{suffix}"
            (write_track_tum if args.format == "tum" else write_track_csv)(result.track, path)
            track_files[result.trace] = path.name

    started = time.perf_counter()
    with ProgressBar("track", len(args.logs)) as progress:
        results = track_all(progress=progress, on_result=write)
    wall_time_s = time.perf_counter() - started
    summary = args.out_dir / "summary.csv"
    with atomic_paths(summary) as (tmp,), tmp.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, columns)
        writer.writeheader()
        for result in results:
            row = summary_row(result, track_files.get(result.trace), columns)
            writer.writerow({k: (f"{v:.4f}" if isinstance(v, float) else ("" if v is None else v))
                             for k, v in row.items()})
    bad = [r for r in results if not r.ok]
    for result in bad:
        print(f"mapfilter: {result.status}: {result.reason}", file=sys.stderr)
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
    print(line)
    print(f"wrote {len(tracked)} tracks and {summary}")
    return 1 if bad else 0


class _Progress:
    """Progress through the walk's time span on a tqdm bar (drawn only on a terminal)."""

    def __init__(self, recording, config) -> None:
        times = recording.wifi.t_s
        self.t0 = float(times[0]) if times.size else 0.0
        self.span_s = max(float(times[-1]) - self.t0, 1e-9) if times.size else 1.0
        # filter runs over the walk, each an equal share of the bar: with --smooth the offline
        # track runs the filter a second time (restart_from_placement; ``finish`` ends the bar
        # where a walk has no second run)
        self.runs = 2 if config.smooth and config.restart_from_placement else 1
        self.bar = ProgressBar("tracking", 100, unit="%")

    def update(self, t_s: float, run: int = 0) -> None:
        done = min(max((t_s - self.t0) / self.span_s, 0.0), 1.0)
        self.bar.update_to(int(100 * (run + done) / self.runs))

    def restart_step(self, report) -> None:
        """A step of the second filter run (``on_restart_step``)."""
        self.update(report.t_s, run=1)

    def finish(self) -> None:
        self.bar.update_to(100)

    def __enter__(self) -> _Progress:
        return self

    def __exit__(self, *exc_info) -> None:
        self.bar.close()
