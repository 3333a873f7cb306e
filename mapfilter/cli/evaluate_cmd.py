"""``mapfilter evaluate MAP LOG...``: every method on the same walks, one table, one CDF plot."""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
from pathlib import Path

from mapfilter.atomic import atomic_paths
from mapfilter.cli.track_cmd import (DEFAULT_FINGERPRINT_MODEL, DEFAULT_PARTICLES, FINGERPRINT_MODELS,
                                     add_kwnn_min_rssi_argument,
                                     add_trilateration_arguments)
from mapfilter.cli.common import ProgressBar, add_engine_arguments, add_strict_argument, engine_from, warn
from mapfilter.errors import MapfilterError

# mapfilter.evaluation.comparison.ALL_METHODS, written out so that --help imports no numerical
# library (tests/test_cli_startup.py holds the two equal)
ALL_METHODS = ("pf", "pf-nomap", "pf-nopdr", "kwnn", "pdr-kwnn", "kf", "pdr", "ls")

_EPILOG = f"""\
methods: {', '.join(ALL_METHODS)} (default: all that the WiFi source allows)
  pf        particle filter: map + WiFi + PDR       kwnn      KWNN fixes (Chang et al.)
  pf-nomap  the same, walls ignored                 pdr-kwnn  KWNN with PDR (Chang et al.)
  pf-nopdr  the same, constant velocity, no PDR     kf        Kalman filter on fixes + PDR
  pdr       dead reckoning from the first fix       ls        least-squares trilateration

Errors are taken at the ground-truth waypoint times from each method's latest estimate at
or before that time (causal); waypoints before a method's first estimate are counted as
missed. --smooth adds pf-smooth, the offline whole-walk track (not causal). walks.csv says
why each walk went wrong: radio-map coverage (metres, and dB per AP from the nearest
reference point), fix error and bias, heading offset, step scale.

writes into OUT: summary.csv, summary.json (with per-trace and per-walk rows), traces.csv, walks.csv, cdf.png,
tracks/<trace>.png (tracks on the floor plan) and tracks/<trace>/<method>.csv.

example (ILC floor, each walk's radio map from the other walks):
  mapfilter evaluate F1.yaml ../shared/data/ilc20/site1/F1/path_data_files/*.txt.gz \\
      --leave-one-out --out results/F1 --jobs 2

A building (MAP a building YAML with several floors, docs/building.md): every walk's true
floor is its header's (FloorName); the methods are pf (the floor in the filter's state, not
given), pf-floor (the same filter on the true floor) and kwnn (each scan on the floor of the
causal WiFi floor HMM); the table adds floor_accuracy, the share of waypoints at which a
method was on the right floor. Each floor's fix sigma is calibrated once from its whole radio map.
  mapfilter evaluate site1.yaml ../shared/data/ilc20/site1/*/path_data_files/*.txt.gz \
      --leave-one-out --out results/site1

--jobs N runs the walks on N local Dask worker processes; --scheduler tcp://HOST:PORT on an
existing Dask cluster (pip install 'mapfilter[distributed]'; start one with
`dask scheduler --host HOST --port PORT` and `dask worker tcp://HOST:PORT --nworkers N
--nthreads 1`; the workers need the logs at the same paths). Every walk seeds its own
generator: serial, --jobs and a cluster give the same numbers.
"""

SUMMARY_COLUMNS = ("method", "mean", "median", "p75", "p90", "max", "rmse", "n", "missed", "wall_crossings",
                   "collapses", "runtime_s")


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "evaluate", help="compare every method on the same walks (errors, CDF plot, tracks)",
        description="Run every method on the same walks and compare their errors against ground truth.",
        epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("map", type=Path, metavar="MAP", help="map YAML or building YAML")
    parser.add_argument("logs", type=Path, nargs="+", metavar="LOG", help="walks with waypoints (ILC format)")
    parser.add_argument("--methods", default=",".join(ALL_METHODS), metavar="M1,M2",
                        help="comma-separated methods (default: all)")
    parser.add_argument("--radiomap", type=Path, metavar="RM", help="one radio map for all walks")
    parser.add_argument("--aps", type=Path, metavar="APS.csv", help="access-point table (ls; pf if no radio map)")
    parser.add_argument("--leave-one-out", action="store_true",
                        help="each walk's radio map (and fitted APs for ls) from the other walks only")
    parser.add_argument("--particles", type=int, default=DEFAULT_PARTICLES, metavar="N",
                        help=f"particles for the pf methods (default: {DEFAULT_PARTICLES})")
    parser.add_argument("--fingerprint-model", choices=FINGERPRINT_MODELS, default=DEFAULT_FINGERPRINT_MODEL,
                        help=f"how pf weighs fingerprints (default: {DEFAULT_FINGERPRINT_MODEL})")
    add_kwnn_min_rssi_argument(parser)
    add_trilateration_arguments(parser)
    parser.add_argument("--seed", type=int, default=0, metavar="S", help="random seed (default: 0)")
    parser.add_argument("--smooth", action="store_true", help="also report the smoothed pf track (pf-smooth)")
    add_engine_arguments(parser)
    add_strict_argument(parser)
    parser.add_argument("--out", type=Path, required=True, metavar="DIR", help="output directory")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mapfilter.evaluation.comparison import EvaluationSetup, evaluate_logs
    from mapfilter.filter.adaptive_pathloss import AdaptationConfig
    from mapfilter.evaluation.metrics import format_table
    from mapfilter.tracking import TrackingConfig

    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    unknown = [m for m in methods if m not in ALL_METHODS + ("pf-floor",)]
    if unknown:
        raise MapfilterError(f"unknown method(s) {', '.join(unknown)}: choose from {', '.join(ALL_METHODS)}")
    if args.particles < 1:
        raise MapfilterError(f"--particles must be at least 1, got {args.particles}")
    engine = engine_from(args)
    if args.out.exists() and not args.out.is_dir():
        raise MapfilterError("the output must be a directory", args.out)
    from mapfilter.maps.building import Building

    building = Building.load(args.map)
    floorplan = building.floors[0].plan
    setup = EvaluationSetup(
        methods=methods, radio_map_path=args.radiomap, ap_table_path=args.aps, leave_one_out=args.leave_one_out,
        smooth=args.smooth, seed=args.seed, strict=args.strict,
        tracking=TrackingConfig(n_particles=args.particles, fingerprint_model=args.fingerprint_model,
                                kwnn_min_rssi_dbm=args.kwnn_min_rssi,
                                adapt_path_loss=args.adapt,
                                adaptation=AdaptationConfig(rssi_limit_dbm=args.adapt_rssi_limit),
                                blocking_compensation=not args.no_blocking_compensation))

    columns = SUMMARY_COLUMNS
    with ProgressBar("evaluate", len(args.logs)) as progress:
        if building.is_single_floor:
            evaluation = evaluate_logs(floorplan, args.logs, setup, progress=progress, engine=engine)
        else:
            from mapfilter.evaluation.floors import evaluate_building_logs

            if args.methods == ",".join(ALL_METHODS):  # the default: every method a building has
                setup = dataclasses.replace(setup, methods=("pf", "pf-floor", "kwnn"))
            evaluation = evaluate_building_logs(building, args.logs, setup, engine=engine, progress=progress)
            floorplan = building
            columns = SUMMARY_COLUMNS + ("floor_accuracy",)
    for message in evaluation.read_warnings:
        warn(message)
    summary = evaluation.summary_rows()
    table = format_table(summary, columns)
    waypoints = summary[0]["n"] + summary[0]["missed"] if summary else 0
    print(f"{evaluation.n_traces} walks, {waypoints} waypoints, {evaluation.wall_time_s:.1f} s\n{table}")
    _write_outputs(args, floorplan, evaluation, summary, columns)
    print(f"wrote {args.out}/summary.csv, summary.json, traces.csv, walks.csv (why each walk went wrong), "
          "cdf.png, tracks/")
    return 0


def _write_outputs(args, floorplan, evaluation, summary, columns=SUMMARY_COLUMNS) -> None:
    from mapfilter.evaluation.comparison import nan_to_none
    from mapfilter.evaluation.plots import plot_error_cdf, plot_tracks_on_map
    from mapfilter.sensors.ilc import read_ilc
    from mapfilter.trackio import write_track_csv

    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    with atomic_paths(out / "summary.csv", out / "traces.csv", out / "walks.csv",
                      out / "summary.json") as (s_csv, t_csv, w_csv, s_json):
        _write_csv(s_csv, summary, columns)
        trace_rows = evaluation.trace_rows()
        _write_csv(t_csv, trace_rows, ("trace",) + columns)
        walk_rows = evaluation.walk_rows()
        _write_csv(w_csv, walk_rows, list(dict.fromkeys(k for row in walk_rows for k in row)) or ["trace"])
        s_json.write_text(json.dumps({
            "map": str(args.map), "logs": [str(p) for p in args.logs], "leave_one_out": args.leave_one_out,
            "particles": args.particles, "seed": args.seed, "wall_time_s": evaluation.wall_time_s,
            "summary": [{k: nan_to_none(v) for k, v in row.items()} for row in summary],
            "traces": [{k: nan_to_none(v) for k, v in row.items()} for row in trace_rows],
            "walks": [{k: nan_to_none(v) for k, v in row.items()} for row in walk_rows],
        }, indent=1))
    plot_error_cdf(evaluation.errors_by_method(), out / "cdf.png",
                   title=f"{evaluation.n_traces} walks on {args.map.name}")
    tracks_dir = out / "tracks"
    by_trace: dict[str, list] = {}
    for result in evaluation.results:
        by_trace.setdefault(result.trace, []).append(result)
    for log_path in args.logs:
        recording = read_ilc(log_path, warn=lambda message: None)  # its warning was printed above
        results = by_trace.get(recording.name, [])
        for result in results:
            write_track_csv(dataclasses.replace(result.track, name=result.method),
                            tracks_dir / recording.name / f"{result.method}.csv")
        shown = {r.method: r.track.xy_m for r in results if r.method in ("pf", "pf-smooth", "kwnn", "kf", "pdr")}
        plan = floorplan
        if not hasattr(floorplan, "wall_mask"):  # a building: the walk's own floor (rows elsewhere drawn on it too)
            plan = floorplan.floors[floorplan.floor_of_log(recording.floor_name, log_path) or 0].plan
        plot_tracks_on_map(plan, shown, tracks_dir / f"{recording.name}.png", recording.waypoint_xy_m,
                           title=recording.name)


def _write_csv(path: Path, rows: list[dict], columns) -> None:
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(columns)
        for row in rows:
            writer.writerow([_cell(row.get(c)) for c in columns])


def _cell(value) -> str:
    if isinstance(value, float):
        return "" if value != value else f"{value:.4f}"
    return "" if value is None else str(value)
