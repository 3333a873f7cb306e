"""``mapfilter radiomap build|fit-aps|fit-beacons|grow``: radio maps, access-point and beacon
tables from logs."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mapfilter.cli.common import (SMOOTH_EXTRA_RUNS, ProgressBar, add_engine_arguments, add_strict_argument,
                                  announce_estimate, bounded_float, bounded_int, check_map_first, check_output_path,
                                  duration_text, engine_from, estimate_tracking_s, input_paths, is_stdout,
                                  non_negative_int, warn)
from mapfilter.errors import MapfilterError

# mapfilter.sensors.pathloss.ApFitConfig.min_observations, written out so that --help imports
# no numerical library (tests/cli/test_cli_startup.py holds the two equal)
_MIN_OBSERVATIONS = 8
# mapfilter.pipeline.selftrain.GrowConfig.max_iterations, likewise
_MAX_ITERATIONS = 3
# mapfilter.sensors.beacons.BeaconFitConfig.min_readings, likewise
_MIN_BEACON_READINGS = 30
# a beacon's readings fitting another beacon's position better than its own by this much is
# reported (an id on the wrong position); less is the noise of a few readings
_BETTER_ELSEWHERE_DB = 1.0


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("radiomap", help="build a WiFi radio map or fit access points from survey logs",
                                   description="Radio maps (fingerprint databases) and access-point tables "
                                               "from survey logs with waypoints (ILC traces or GetSensorData logs, .gz ok; "
                                               "latitude/longitude ground truth needs a georeferenced building).")
    sub = parser.add_subparsers(dest="radiomap_command", metavar="SUBCOMMAND", required=True)
    _add_build(sub)
    _add_fit_aps(sub)
    _add_fit_beacons(sub)
    _add_grow(sub)


def _add_common(p: argparse.ArgumentParser, logs_help: str = "survey logs with waypoints") -> None:
    """MAP, LOG... and the options every subcommand reads logs with."""
    p.add_argument("map", type=Path, metavar="MAP",
                   help="floor map YAML (ROS map_server), or a building YAML (build: each log's floor from "
                        "its header, FloorName, or its ground truth; fit-aps: one floor of it)")
    p.add_argument("logs", type=Path, nargs="+", metavar="LOG", help=logs_help)
    p.add_argument("--exclude", action="append", default=[], metavar="TRACE",
                   help="leave out a log, by file name or trace id (repeatable)")
    p.add_argument("--max-wifi-age", type=bounded_float(0.0, 3600.0), default=5.0, metavar="S",
                   help="drop WiFi rows last seen more than S seconds before their scan (default 5)")
    add_strict_argument(p)


def _add_build(sub) -> None:
    """``radiomap build``."""
    build = sub.add_parser("build", help="build a radio map (.npz)")
    _add_common(build)
    build.add_argument("--out", type=Path, required=True, metavar="RADIOMAP", help="output radio map (.npz)")
    build.add_argument("--steps", action="store_true",
                       help="label scans by the detected steps between waypoints instead of linearly in time")
    build.set_defaults(func=run_build)


def _add_fit_aps(sub) -> None:
    """``radiomap fit-aps``."""
    fit = sub.add_parser("fit-aps", help="estimate access-point positions and path-loss parameters (CSV)")
    _add_common(fit)
    fit.add_argument("--out", type=Path, required=True, metavar="APS_CSV",
                     help="output table bssid,x,y,band,C,n,alpha,d_max")
    fit.add_argument("--min-observations", type=bounded_int(None, 1_000_000), default=_MIN_OBSERVATIONS, metavar="N",
                     help=f"fit only APs heard in N labelled scans (default {_MIN_OBSERVATIONS})")
    fit.add_argument("--floor", metavar="NAME",
                     help="with a building YAML: the floor to fit (default: the one floor every log is on)")
    fit.set_defaults(func=run_fit_aps)


def _add_fit_beacons(sub) -> None:
    """``radiomap fit-beacons``."""
    beacons = sub.add_parser(
        "fit-beacons", help="fit BLE beacons' path-loss parameters (CSV beacon table)",
        description="Fit each BLE beacon's path-loss parameters (C at 1 m and the exponent n; one loss per floor "
                    "for all) from survey logs with waypoints, the beacons' positions and floors as given: each "
                    "beacon reading labelled by the walker's position between waypoints, robust least squares. "
                    "A beacon with fewer than --min-readings readings takes the values fitted over every "
                    "beacon. Prints how each beacon fits, and says so when a beacon's readings fit another "
                    "beacon's position better than its own (an id on the wrong position); logs that name their "
                    "phone (GetSensorData) also give each phone model's RSSI offset against the table (written "
                    "as its column offset_db:MODEL: track and evaal apply it to a log of that phone).",
        epilog="examples:\n"
               "  mapfilter radiomap fit-beacons venue.yaml survey/*.txt.gz --positions beacons.csv "
               "--out fitted.csv\n"
               "  mapfilter radiomap fit-beacons venue.yaml logs/*.txt.gz --positions BLE_Locations.csv \\\n"
               "      --ids BLE1=BE:AC:20:23:00:01,BLE2=BE:AC:20:23:00:03,... --out beacons.csv",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    _add_common(beacons)
    beacons.add_argument("--positions", type=Path, required=True, metavar="CSV",
                         help="the beacons: beacon_id,x,y[,floor] (metres, each floor's frame) or "
                              "beacon_id,latitude,longitude[,floor] (a georeferenced building); an IPIN venue's "
                              "BLE_Locations.csv (bleID,Lat,Lon,floor) with --ids")
    beacons.add_argument("--ids", metavar="NAME=ID,...",
                         help="the logs' id of each beacon the positions file names (e.g. BLE1=BE:AC:20:23:00:01,...)")
    beacons.add_argument("--out", type=Path, required=True, metavar="BEACONS_CSV",
                         help="output table beacon_id,x,y,floor,C,n,floor_loss")
    beacons.add_argument("--min-readings", type=bounded_int(None, 1_000_000), default=_MIN_BEACON_READINGS,
                         metavar="N", help=f"fit a beacon's own C and n from N labelled readings or more (default "
                                           f"{_MIN_BEACON_READINGS})")
    beacons.set_defaults(func=run_fit_beacons)


def _add_grow(sub) -> None:
    """``radiomap grow``."""
    grow = sub.add_parser(
        "grow", help="grow a radio map from tracked walks (self-training)",
        description="Track every walk without waypoints offline over the radio map, add its scans as grown "
                    "reference points at the offline track's positions (each with a position uncertainty), and "
                    "repeat until the map stops changing. Logs with waypoints are added as surveyed points. "
                    "The result loads everywhere a radio map does (docs/self-training.md).")
    _add_common(grow, "walks: without waypoints they grow the map, with waypoints they are added as surveyed "
                      "points (unless --ignore-waypoints)")
    grow.add_argument("--radiomap", type=Path, required=True, metavar="BASE", help="the radio map to grow (.npz)")
    grow.add_argument("--out", type=Path, required=True, metavar="RADIOMAP", help="the grown radio map (.npz)")
    grow.add_argument("--iterations", type=bounded_int(None, 100), default=_MAX_ITERATIONS, metavar="N",
                      help=f"at most N rounds of tracking every walk (default {_MAX_ITERATIONS}; fewer when the "
                           "grown points stop moving)")
    grow.add_argument("--particles", type=bounded_int(), default=10_000, metavar="N", help="particles (default 10000)")
    grow.add_argument("--seed", type=non_negative_int, default=0, help="random seed (default 0)")
    grow.add_argument("--ignore-waypoints", action="store_true",
                      help="grow from every log, its waypoints never read (e.g. to measure growing on survey logs)")
    grow.add_argument("--wifi-only", action="store_true",
                      help="also grow walks without IMU data (placed by a constant-velocity filter: on ILC F2 "
                           "this made the map worse)")
    add_engine_arguments(grow)
    grow.set_defaults(func=run_grow)


def _load(args: argparse.Namespace):
    from mapfilter.maps.building import Building
    from mapfilter.sensors.logs import read_log

    check_map_first(f"mapfilter radiomap {args.radiomap_command} MAP LOG...", args.map, args.logs)
    # fit-aps writes a CSV, which may go to standard output (--out -); a radio map is binary
    check_output_path(args.out, inputs=input_paths(args.map, args.logs, getattr(args, "radiomap", None),
                                                   getattr(args, "positions", None)),
                      allow_stdout=args.radiomap_command in ("fit-aps", "fit-beacons"))
    building = Building.load(args.map)
    floorplan = building.floors[0].plan if building.is_single_floor else building
    excluded = set(args.exclude)
    paths = [p for p in args.logs if not excluded & {p.name, _trace_id(p)}]
    unused = excluded - {n for p in args.logs for n in (p.name, _trace_id(p))}
    if unused:
        raise MapfilterError(f"--exclude {sorted(unused)[0]!r} matches none of the logs")
    if not paths:
        raise MapfilterError("every log is excluded: nothing to build from")
    # latitude/longitude ground truth (GetSensorData) is placed in the (georeferenced) building
    recordings = []
    with ProgressBar("reading logs", len(paths), unit="log") as progress:
        for done, path in enumerate(paths, start=1):
            recording = read_log(path, strict=args.strict, warn=warn, max_wifi_age_s=args.max_wifi_age,
                                 building=building)
            if building.is_single_floor:
                # a walk of another floor surveys nothing here: refused, as track refuses it
                building.floor_of_log(recording.floor_name, path)
            recordings.append(recording)
            progress(done, len(paths), path.name)
    return floorplan, recordings


def _span_s(recording) -> float:
    """The walk's time in seconds: its span less the gaps its reader found."""
    report = recording.read_report
    if report is None or report.time_span_s is None:
        return 0.0
    return float(report.time_span_s[1] - report.time_span_s[0] - sum(b - a for a, b in report.time_gaps_s or ()))


def _trace_id(path: Path) -> str:
    name = path.name
    for suffix in (".gz", ".txt"):
        name = name.removesuffix(suffix)
    return name


def run_build(args: argparse.Namespace) -> int:
    import numpy as np

    from mapfilter.maps.building import Building
    from mapfilter.sensors.floor_vote import build_building_radio_map
    from mapfilter.sensors.radiomap import build_radio_map, check_radio_map_on_map

    floorplan, recordings = _load(args)
    if isinstance(floorplan, Building):
        building = floorplan
        floors = _log_floors(building, recordings, "the log's header names no floor (FloorName): a building's "
                                                   "radio map needs the floor of every log")
        radio_map = build_building_radio_map(recordings, floors, building.floor_names, use_steps=args.steps)
        check_radio_map_on_map(radio_map, building, map_path=args.map)  # waypoints of another map or frame
        radio_map.save(args.out)
        counts = ", ".join(f"{name} {int(np.sum(radio_map.floor == i))}" for i, name in enumerate(building.floor_names))
        print(f"radio map: {len(radio_map)} reference points ({counts}), {len(radio_map.ap_keys)} access points "
              f"from {len(recordings)} logs -> {args.out}")
        return 0
    from mapfilter.filter.models.radio_map import keep_tables

    radio_map = build_radio_map(recordings, floorplan, use_steps=args.steps)
    check_radio_map_on_map(radio_map, floorplan, map_path=args.map)
    keep_tables(radio_map, floorplan)  # the likelihood's grid on this map, for every walk tracked with it
    radio_map.save(args.out)
    print(f"radio map: {len(radio_map)} reference points, {len(radio_map.ap_keys)} access points "
          f"from {len(recordings)} logs -> {args.out}")
    return 0


def _one_floor(building, recordings, floor_name: str | None, where: Path):
    """The plan of the floor whose access points fit-aps fits in a building: ``floor_name``, or
    the one floor every log is on; every log must be on it."""
    on = []
    for rec in recordings:
        names = set(rec.waypoint_floor) if rec.waypoint_floor else {rec.floor_name}
        if None in names or len(names) != 1:
            raise MapfilterError("fit-aps fits one floor's access points: the log is not on one named floor",
                                 rec.path)
        on.append(names.pop())
    if floor_name is None:
        if len(set(on)) != 1:
            raise MapfilterError(f"the logs are on floors {', '.join(sorted(set(on)))}: fit-aps fits one floor's "
                                 "access points (choose it with --floor, or give that floor's map YAML)", where)
        floor_name = on[0]
    wrong = next((rec for rec, name in zip(recordings, on) if name != floor_name), None)
    if wrong is not None:
        raise MapfilterError(f"the log is on floor {on[recordings.index(wrong)]}, not on floor {floor_name}",
                             wrong.path)
    return building.floor(floor_name).plan


def run_fit_aps(args: argparse.Namespace) -> int:
    if args.min_observations < 3:
        raise MapfilterError(f"--min-observations must be at least 3 (4 parameters per AP), got {args.min_observations}")
    from mapfilter.sensors.pathloss import ApFitConfig, estimate_access_points
    from mapfilter.sensors.radiomap import build_radio_map

    floorplan, recordings = _load(args)
    if not hasattr(floorplan, "wall_mask"):
        floorplan = _one_floor(floorplan, recordings, getattr(args, "floor", None), args.map)
    table = estimate_access_points(build_radio_map(recordings, floorplan),
                                   ApFitConfig(min_observations=args.min_observations))
    table.write_csv(args.out)
    print(f"access points: {len(table)} fitted from {len(recordings)} logs -> "
          + ("standard output" if is_stdout(args.out) else str(args.out)),
          file=sys.stderr if is_stdout(args.out) else sys.stdout)
    return 0


def run_fit_beacons(args: argparse.Namespace) -> int:
    if args.min_readings < 3:
        raise MapfilterError(f"--min-readings must be at least 3 (2 parameters per beacon), got {args.min_readings}")
    ids = None
    if args.ids is not None:
        from mapfilter.sensors.beacons import parse_beacon_ids

        try:
            ids = parse_beacon_ids(args.ids)
        except ValueError as exc:
            raise MapfilterError(f"--ids: {exc}") from None
    from mapfilter.maps.building import Building
    from mapfilter.sensors.beacons import (BeaconFitConfig, BeaconTable, check_beacons_on_map, fit_beacons,
                                           labelled_readings)

    building = Building.load(args.map)
    positions = BeaconTable.read_csv(args.positions, building, ids)  # before the logs: a bad table fails fast
    check_beacons_on_map(positions, building, args.map)
    _, recordings = _load(args)
    fit = fit_beacons(positions, labelled_readings(positions, building, recordings),
                      BeaconFitConfig(min_readings=args.min_readings))
    fit.table.write_csv(args.out)
    where = "standard output" if is_stdout(args.out) else str(args.out)
    loss = (f"floor loss {fit.floor_loss_db:.1f} dB" if fit.floor_loss_fitted
            else f"floor loss {fit.floor_loss_db:.1f} dB (the table's: too few readings across floors to fit it)")
    lines = [f"beacons: {len(fit.table)} fitted from {fit.n_readings} labelled readings of {len(recordings)} logs "
             f"({loss}; shared C {fit.shared_c_dbm:.1f} dBm, n {fit.shared_n:.2f}) -> {where}"]
    for row, c, n in zip(fit.rows, fit.table.c_dbm, fit.table.n):
        text = (f"  {row.beacon_id}: {row.readings} readings ({row.on_its_floor} on its floor), C {c:.1f} dBm, "
                f"n {n:.2f}" + ("" if row.own_fit else " (shared: too few readings)"))
        if row.readings:
            text += f", RMS {row.rmse_db:.1f} dB"
        if row.best_position != row.beacon_id and row.best_position_rmse_db < row.rmse_db - _BETTER_ELSEWHERE_DB:
            text += (f"; its readings fit {row.best_position}'s position better (RMS {row.best_position_rmse_db:.1f} "
                     "dB): is its id on the wrong position?")
        lines.append(text)
    for phone, offset in fit.phone_offsets_db.items():
        lines.append(f"  phone {phone}: RSSI {offset:+.1f} dB against the table ({fit.phone_readings[phone]} readings; "
                     f"column offset_db:{phone}, applied to a log of that phone)")
    print("\n".join(lines), file=sys.stderr if is_stdout(args.out) else sys.stdout)
    return 0


def run_grow(args: argparse.Namespace) -> int:
    if args.iterations < 1:
        raise MapfilterError(f"--iterations must be at least 1, got {args.iterations}")
    if args.particles < 1:
        raise MapfilterError(f"--particles must be at least 1, got {args.particles}")
    engine = engine_from(args)
    from mapfilter.runtime import memory

    # the particles are refused before the logs are read (about 200 bytes each)
    memory.check_fits(memory.particle_filter_bytes(args.particles), f"--particles {args.particles}",
                      "use fewer particles (the default is 10000)")
    from mapfilter.maps.building import Building
    from mapfilter.pipeline.selftrain import GrowConfig, grow_radio_map, labelled_and_unlabelled
    from mapfilter.config import TrackingConfig
    from mapfilter.sensors.radiomap import merge_radio_maps

    space, recordings = _load(args)
    memory.check_tracking_fits(TrackingConfig().with_particles(args.particles),
                               memory.building_extents_m(space) if isinstance(space, Building)
                               else [tuple(space.extent_m)])
    base = _base_radio_map(args, space)
    labelled, unlabelled = ([], recordings) if args.ignore_waypoints else labelled_and_unlabelled(recordings)
    surveyed = None
    if labelled:
        surveyed = _surveyed_points(space, labelled)
        base = merge_radio_maps([base, surveyed])
    config = GrowConfig(tracking=TrackingConfig().with_particles(args.particles), max_iterations=args.iterations,
                        wifi_only=args.wifi_only, seed=args.seed)
    _announce_growing(args, unlabelled)
    with ProgressBar("grow", len(unlabelled) * args.iterations) as progress:
        grown, report = grow_radio_map(space, base, unlabelled, config, progress=progress, engine=engine)
    if not isinstance(space, Building):
        from mapfilter.filter.models.radio_map import keep_tables

        keep_tables(grown, space)
    grown.save(args.out)
    for walk in report.walks:
        if walk.skipped:
            warn(f"{walk.name}: grew nothing: {walk.skipped}")
    _print_growth(args, report, grown, base, labelled, unlabelled, surveyed)
    return 0


def _base_radio_map(args: argparse.Namespace, space):
    """The radio map to grow (--radiomap): the building's when MAP is a building, else one floor's;
    checked against the map."""
    from mapfilter.maps.building import Building
    from mapfilter.sensors.radiomap import RadioMap, check_radio_map_on_map

    if isinstance(space, Building):
        from mapfilter.sensors.floor_vote import load_building_radio_map

        base = load_building_radio_map(args.radiomap, space.floor_names)
    else:
        base = RadioMap.load(args.radiomap)
        if base.has_floors:
            raise MapfilterError("a building's radio map: give the building's YAML as MAP", args.radiomap)
    check_radio_map_on_map(base, space, args.radiomap, args.map)
    return base


def _log_floors(building, recordings, no_floor: str) -> list[int | None]:
    """The floor of each log in a building, from its header (None: a walk over several floors,
    each scan on its waypoints' floor); ``no_floor`` is the message for a log that names none."""
    floors = []
    for rec in recordings:
        index = building.floor_of_log(rec.floor_name, rec.path)
        if index is None and not rec.waypoint_floor:
            raise MapfilterError(no_floor, rec.path)
        floors.append(index)
    return floors


def _surveyed_points(space, labelled):
    """The walks with waypoints as surveyed points (their labelled scans)."""
    from mapfilter.maps.building import Building
    from mapfilter.sensors.radiomap import build_radio_map

    if isinstance(space, Building):
        from mapfilter.sensors.floor_vote import build_building_radio_map

        floors = _log_floors(space, labelled, "the log has waypoints but neither its header (FloorName) nor its "
                                              "waypoints name a floor: its points need a floor")
        return build_building_radio_map(labelled, floors, space.floor_names)
    return build_radio_map(labelled, space)


def _announce_growing(args: argparse.Namespace, unlabelled) -> None:
    """How long growing will take: every walk tracked offline, up to --iterations rounds."""
    spans = [_span_s(rec) for rec in unlabelled]
    workers = args.jobs if args.scheduler is None else 1
    announce_estimate(f"growing from {len(unlabelled)} walks", estimate_tracking_s(
        spans, args.particles, args.iterations * (1 + SMOOTH_EXTRA_RUNS), workers),
        f"{duration_text(sum(spans))} of walks, up to {args.iterations} rounds of {args.particles} particles, "
        f"{workers} worker{'s' if workers != 1 else ''}")


def _print_growth(args: argparse.Namespace, report, grown, base, labelled, unlabelled, surveyed) -> None:
    """What was grown (or why nothing), what was surveyed, and the radio map written."""
    import numpy as np

    sigma = grown.xy_sigma_m[len(base):]
    last = report.iterations[-1] if report.iterations else {}
    moved = last.get("moved_median_m", float("nan"))
    if unlabelled:
        walks = "walks (their waypoints not read)" if args.ignore_waypoints else "walks without waypoints"
        print(f"grown: {report.points} points from {report.grown_walks} of {len(unlabelled)} {walks}"
              + (f", position sigma median {np.median(sigma):.1f} m, p90 {np.percentile(sigma, 90):.1f} m"
                 if sigma.size else "")
              + (f"; {len(report.iterations)} iteration{'s' if len(report.iterations) != 1 else ''}"
                 if report.iterations else "")
              + (f", last moved {moved:.2f} m (median)" if np.isfinite(moved) else ""))
    else:
        n = len(labelled)
        print(f"grown: nothing: {'the walk has' if n == 1 else f'all {n} walks have'} waypoints, so "
              f"{'it was' if n == 1 else 'they were'} added as surveyed points (labelled scans) instead; "
              "--ignore-waypoints grows from walks with waypoints without reading them")
    if labelled:
        print(f"surveyed: {len(surveyed)} points from {len(labelled)} walks with waypoints")
    print(f"radio map: {len(grown)} reference points ({len(base) - (len(surveyed) if labelled else 0)} from "
          f"{args.radiomap.name}), {len(grown.ap_keys)} access points -> {args.out}")
