"""``mapfilter simulate MAP --aps APS.csv --out walk.txt``: a synthetic walk in the ILC format."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from mapfilter.errors import MapfilterError

# The defaults of mapfilter.simulate.walk.SimConfig that the options show, written out so that
# --help imports no numerical library (tests/test_cli_startup.py holds them equal to SimConfig).
_SIM_DEFAULTS = {"duration_s": 120.0, "survey_spacing_m": 2.0, "survey_scans_per_point": 3,
                 "shadowing_sigma_db": 5.0, "wall_loss_2g4_db": 3.5, "wall_loss_5g_db": 5.0,
                 "start_time_ms": 1_600_000_000_000}


def register(subparsers: argparse._SubParsersAction) -> None:
    defaults = argparse.Namespace(**_SIM_DEFAULTS)
    parser = subparsers.add_parser(
        "simulate",
        help="simulate a phone walk (or a radio-map survey) over a map, written as an ILC trace",
        description="Simulate a pedestrian walk over a floor plan: ground-truth waypoints at every step, "
                    "a 50 Hz IMU, and WiFi scans from a multi-wall path-loss model, written in the ILC "
                    "trace format (.gz compresses).",
    )
    parser.add_argument("map", type=Path, metavar="MAP", help="map YAML (ROS map_server)")
    parser.add_argument("--aps", type=Path, default=None,
                        help="access-point table CSV (bssid,x,y,band,C,n,alpha,d_max); default: the map's own")
    parser.add_argument("--out", type=Path, required=True, help="output trace (.txt or .txt.gz)")
    parser.add_argument("--duration", type=float, default=None,
                        help=f"seconds of walking (default {defaults.duration_s:g}; survey: until every point is visited)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (same seed, same file)")
    parser.add_argument("--survey", action="store_true",
                        help="radio-map survey: stand at reference points on a grid and scan there")
    parser.add_argument("--survey-spacing", type=float, default=defaults.survey_spacing_m, metavar="M",
                        help="survey grid spacing in metres (default %(default)s)")
    parser.add_argument("--scans-per-point", type=int, default=defaults.survey_scans_per_point, metavar="N",
                        help="survey scans at each reference point (default %(default)s)")
    parser.add_argument("--shadowing-db", type=float, default=defaults.shadowing_sigma_db, metavar="DB",
                        help="log-normal shadowing sigma in dB (default %(default)s)")
    parser.add_argument("--wall-loss-db", type=float, nargs=2, metavar=("DB_2G4", "DB_5G"),
                        default=(defaults.wall_loss_2g4_db, defaults.wall_loss_5g_db),
                        help="attenuation per wall crossed at 2.4 and 5 GHz (default %(default)s)")
    parser.add_argument("--blocking", type=float, nargs=3, action="append", default=[],
                        metavar=("START_S", "END_S", "H_DB"),
                        help="signal blocking (a hand over the phone): every AP reads H_DB weaker from START_S to "
                             "END_S after the walk's start (repeatable)")
    parser.add_argument("--write-aps", type=Path, default=None, metavar="OUT.csv",
                        help="also write the access-point table the walk was simulated with, shifted by "
                             "--aps-c-offset / --aps-alpha-offset (a deliberately wrong table for --adapt)")
    parser.add_argument("--aps-c-offset", type=float, default=0.0, metavar="DB",
                        help="added to every AP's C in --write-aps (default 0)")
    parser.add_argument("--aps-alpha-offset", type=float, default=0.0, metavar="DB_PER_M",
                        help="added to every AP's alpha in --write-aps, clipped at 0 (default 0)")
    parser.add_argument("--start-time-ms", type=int, default=defaults.start_time_ms,
                        help="Unix time (ms) of the first record (default %(default)s)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from mapfilter.maps.floorplan import FloorPlan
    from mapfilter.sensors.pathloss import access_points_for_map
    from mapfilter.simulate.ilc_writer import write_ilc
    from mapfilter.simulate.walk import SimConfig, offset_access_points, simulate_walk

    if args.seed < 0:
        raise MapfilterError(f"--seed must be a non-negative integer, got {args.seed}")
    floorplan = FloorPlan.load(args.map)
    ap_table = access_points_for_map(args.aps, floorplan, args.map)
    duration = args.duration
    if duration is None and not args.survey:
        duration = SimConfig.duration_s
    config = dataclasses.replace(
        SimConfig(), duration_s=duration, start_time_ms=args.start_time_ms, survey=args.survey,
        survey_spacing_m=args.survey_spacing, survey_scans_per_point=args.scans_per_point,
        shadowing_sigma_db=args.shadowing_db, wall_loss_2g4_db=args.wall_loss_db[0],
        wall_loss_5g_db=args.wall_loss_db[1], blocking_episodes=tuple(tuple(e) for e in args.blocking),
    )
    if (args.aps_c_offset or args.aps_alpha_offset) and args.write_aps is None:
        raise MapfilterError("--aps-c-offset / --aps-alpha-offset need --write-aps OUT.csv")
    walk = simulate_walk(floorplan, ap_table, config, np.random.default_rng(args.seed), site_id=args.map.stem)
    write_ilc(walk, args.out)
    if args.write_aps is not None:
        offset_access_points(ap_table, args.aps_c_offset, args.aps_alpha_offset).write_csv(args.write_aps)
    print(f"{args.out}: {walk.end_t_s - walk.start_t_s:.1f} s, {walk.n_steps} steps, "
          f"{walk.waypoint_t_s.size} waypoints, {walk.scan_t_s.size} WiFi scans ({walk.row_ap.size} rows)"
          + (f", {walk.reference_xy_m.shape[0]} reference points" if args.survey else ""), file=sys.stderr)
    return 0
