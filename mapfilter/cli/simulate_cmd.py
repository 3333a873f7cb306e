"""``mapfilter simulate MAP --aps APS.csv --out walk.txt``: a synthetic walk in the ILC format.

MAP is a map YAML (one floor, as always) or a building YAML (docs/building.md): in a building
with several floors the walk changes floor by its stairs and lifts (``simulate.building``).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from mapfilter.cli.common import (bounded_float, bounded_int, check_distinct_outputs, check_map_first, check_output_path,
                                  input_paths, non_negative_int)
from mapfilter.errors import MapfilterError

# The defaults of mapfilter.simulate.walk.SimConfig that the options show, written out so that
# --help imports no numerical library (tests/cli/test_cli_startup.py holds them equal to SimConfig).
_SIM_DEFAULTS = {"duration_s": 120.0, "survey_spacing_m": 2.0, "survey_scans_per_point": 3,
                 "shadowing_sigma_db": 5.0, "wall_loss_2g4_db": 3.5, "wall_loss_5g_db": 5.0,
                 "start_time_ms": 1_600_000_000_000}
# ...and of mapfilter.simulate.building.BuildingSimConfig (tests/cli/test_cli_simulate_building.py
# holds them equal to the library's).
_BUILDING_DEFAULTS = {"segment_s": (25.0, 40.0), "floor_loss_db": 15.0}
DEFAULT_FLOOR_CHANGES = 3  # as tools/floor_sim.py walks
# The limits of mapfilter.simulate.walk (MAX_*), written out for the same reason
# (tests/cli/test_cli_startup.py holds them equal): far beyond any real use, they keep a typo from
# asking for more memory or time than the machine has.
_SIM_LIMITS = {"MAX_DURATION_S": 14400.0, "MAX_SCANS_PER_POINT": 100, "MAX_DB": 100.0,
               "MAX_START_TIME_MS": 4_102_444_800_000}
_MIN_SURVEY_SPACING_M = 0.25  # SimConfig.grid_m: a survey cannot be finer than the route grid
_MAX_FLOOR_CHANGES = 1000

_BUILDING_HELP = """\
A building (MAP a building YAML with several floors, docs/building.md): the walk starts on
--start-floor (default: a floor drawn from the seed) and takes --floor-changes N floor changes,
each by a connector (stairs, escalator: to the next floor it links up or down; lift: to any
floor it links) drawn from the seed, or the changes given with --change CONNECTOR FLOOR
(repeatable, in order). It wanders --segment-s seconds on a floor before and after each
change. Waypoints carry their floor (a fifth column, each in its floor's frame) and a
barometer writes TYPE_PRESSURE rows (--no-barometer: none). --survey --floor NAME surveys one
floor, hearing every floor's access points. Access points: each floor map's own table
(mapfilter: access_points in its YAML), or --aps: that table on every floor, each floor's copy
with its own BSSIDs (the fourth octet set to the floor's number, 00 for the first floor).
WiFi loses --floor-loss-db per floor between the phone and an access point.
"""


_DB = bounded_float(0.0, _SIM_LIMITS["MAX_DB"])  # a loss or a spread in dB


def register(subparsers: argparse._SubParsersAction) -> None:
    defaults = argparse.Namespace(**_SIM_DEFAULTS, **_BUILDING_DEFAULTS)
    parser = subparsers.add_parser(
        "simulate",
        help="simulate a phone walk (or a radio-map survey) over a map or a building, written as an ILC trace",
        description="Simulate a pedestrian walk over a floor plan: ground-truth waypoints at every step, "
                    "a 50 Hz IMU, and WiFi scans from a multi-wall path-loss model, written in the ILC "
                    "trace format (.gz compresses).",
        epilog=_BUILDING_HELP,
    )
    parser.add_argument("map", type=Path, metavar="MAP", help="map YAML (ROS map_server) or building YAML")
    parser.add_argument("--aps", type=Path, default=None,
                        help="access-point table CSV (bssid,x,y,band,C,n,alpha,d_max); default: the map's own "
                             "(a building: each floor map's own; --aps: this table on every floor)")
    parser.add_argument("--out", type=Path, required=True, help="output trace (.txt or .txt.gz)")
    parser.add_argument("--duration", type=bounded_float(0.0, _SIM_LIMITS["MAX_DURATION_S"], low_open=True),
                        default=None,
                        help=f"seconds of walking (default {defaults.duration_s:g}; survey: until every point is "
                             f"visited; a building: see --segment-s)")
    parser.add_argument("--seed", type=non_negative_int, default=0, help="random seed (same seed, same file)")
    parser.add_argument("--survey", action="store_true",
                        help="radio-map survey: stand at reference points on a grid and scan there "
                             "(a building: of the floor --floor)")
    parser.add_argument("--survey-spacing", type=bounded_float(_MIN_SURVEY_SPACING_M, 1e4),
                        default=defaults.survey_spacing_m, metavar="M",
                        help="survey grid spacing in metres (default %(default)s)")
    parser.add_argument("--scans-per-point", type=bounded_int(1, _SIM_LIMITS["MAX_SCANS_PER_POINT"]),
                        default=defaults.survey_scans_per_point, metavar="N",
                        help="survey scans at each reference point (default %(default)s)")
    parser.add_argument("--shadowing-db", type=_DB, default=defaults.shadowing_sigma_db, metavar="DB",
                        help="log-normal shadowing sigma in dB (default %(default)s)")
    parser.add_argument("--wall-loss-db", type=_DB, nargs=2, metavar=("DB_2G4", "DB_5G"),
                        default=(defaults.wall_loss_2g4_db, defaults.wall_loss_5g_db),
                        help="attenuation per wall crossed at 2.4 and 5 GHz (default %(default)s)")
    parser.add_argument("--blocking", type=bounded_float(-1e6, 1e6), nargs=3, action="append", default=[],
                        metavar=("START_S", "END_S", "H_DB"),
                        help="signal blocking (a hand over the phone): every AP reads H_DB weaker from START_S to "
                             "END_S after the walk's start (repeatable)")
    parser.add_argument("--write-aps", type=Path, default=None, metavar="OUT.csv",
                        help="also write the access-point table the walk was simulated with, shifted by "
                             "--aps-c-offset / --aps-alpha-offset (a deliberately wrong table for --adapt; "
                             "one floor only)")
    parser.add_argument("--aps-c-offset", type=bounded_float(-_SIM_LIMITS["MAX_DB"], _SIM_LIMITS["MAX_DB"]),
                        default=0.0, metavar="DB",
                        help="added to every AP's C in --write-aps (default 0)")
    parser.add_argument("--aps-alpha-offset", type=bounded_float(-10.0, 10.0), default=0.0, metavar="DB_PER_M",
                        help="added to every AP's alpha in --write-aps, clipped at 0 (default 0)")
    parser.add_argument("--start-time-ms", type=bounded_int(0, _SIM_LIMITS["MAX_START_TIME_MS"]),
                        default=defaults.start_time_ms,
                        help="Unix time (ms) of the first record (default %(default)s)")
    _add_building_arguments(parser, defaults)
    parser.set_defaults(func=run)


def _add_building_arguments(parser: argparse.ArgumentParser, defaults: argparse.Namespace) -> None:
    """The options of a walk over several floors (MAP a building YAML)."""
    building = parser.add_argument_group("a building with several floors (MAP a building YAML)")
    building.add_argument("--start-floor", default=None, metavar="NAME",
                          help="the floor the walk starts on (default: drawn from the seed)")
    building.add_argument("--floor-changes", type=bounded_int(0, _MAX_FLOOR_CHANGES), default=None, metavar="N",
                          help=f"floor changes by connectors and floors drawn from the seed "
                               f"(default {DEFAULT_FLOOR_CHANGES}; 0: the walk stays on its floor)")
    building.add_argument("--change", nargs=2, action="append", default=[], metavar=("CONNECTOR", "FLOOR"),
                          help="take connector CONNECTOR to floor FLOOR (repeatable, in order; instead of "
                               "--floor-changes)")
    building.add_argument("--floor", default=None, metavar="NAME", help="--survey: the floor to survey")
    building.add_argument("--segment-s", type=bounded_float(0.0, _SIM_LIMITS["MAX_DURATION_S"]), nargs=2,
                          default=defaults.segment_s, metavar=("MIN", "MAX"),
                          help="seconds of wandering on a floor before and after each change, drawn between MIN "
                               f"and MAX (default {defaults.segment_s[0]:g} {defaults.segment_s[1]:g})")
    building.add_argument("--floor-loss-db", type=_DB, default=defaults.floor_loss_db, metavar="DB",
                          help="WiFi attenuation per floor between phone and access point (default %(default)s)")
    building.add_argument("--no-barometer", action="store_true", help="write no TYPE_PRESSURE rows")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from mapfilter.maps.building import Building
    from mapfilter.sensors.pathloss import access_points_for_map
    from mapfilter.simulate.ilc_writer import write_ilc
    from mapfilter.simulate.walk import SimConfig, offset_access_points, simulate_walk

    check_map_first("mapfilter simulate MAP --out WALK.txt.gz", args.map)
    inputs = input_paths(args.map, args.aps)
    check_output_path(args.out, inputs=inputs, allow_stdout=True)  # the summary goes to stderr
    check_output_path(args.write_aps, "--write-aps", inputs=inputs)
    check_distinct_outputs([("--out", args.out), ("--write-aps", args.write_aps)])
    building = Building.load(args.map)  # a map YAML is a one-floor building
    if not building.is_single_floor:
        return _run_building(args, building)
    _refuse_building_options(args)
    floor = building.floors[0]
    floorplan = floor.plan
    ap_table = access_points_for_map(args.aps, floorplan, floor.map_path or args.map)
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


def _refuse_building_options(args: argparse.Namespace) -> None:
    """The building options with a one-floor map: refused, naming the map (as track --floor is)."""
    given = [name for name, value in (("--start-floor", args.start_floor), ("--floor", args.floor),
                                      ("--floor-changes", args.floor_changes), ("--change", args.change or None))
             if value is not None]
    given += [name for name, value, default in (
        ("--segment-s", tuple(args.segment_s), _BUILDING_DEFAULTS["segment_s"]),
        ("--floor-loss-db", args.floor_loss_db, _BUILDING_DEFAULTS["floor_loss_db"]),
        ("--no-barometer", args.no_barometer, False)) if value != default]
    if given:
        raise MapfilterError(f"{', '.join(given)}: for a building with several floors; this map has one floor",
                             args.map)


def _run_building(args: argparse.Namespace, building) -> int:
    """A walk over several floors (or a survey of one floor) of a building."""
    import numpy as np

    from mapfilter.simulate.ilc_writer import write_ilc

    _check_building_options(args)
    tables = _checked_floor_tables(args, building)
    config = _building_config(args)
    walk, happened = _simulate_in_building(args, building, tables, config, np.random.default_rng(args.seed))
    if args.no_barometer:
        walk = dataclasses.replace(walk, pressure_t_s=None, pressure_hpa=None)
    write_ilc(walk, args.out)
    t0 = walk.start_t_s
    n_pressure = 0 if walk.pressure_t_s is None else walk.pressure_t_s.size
    route = "".join(f", {a} -> {b} by {kind} at {s - t0:.1f} s" for _, s, _, a, b, kind in happened)
    print(f"{args.out}: {walk.end_t_s - t0:.1f} s, {walk.n_steps} steps, {walk.waypoint_t_s.size} waypoints, "
          f"{walk.scan_t_s.size} WiFi scans ({walk.row_ap.size} rows)"
          + (f", {walk.reference_xy_m.shape[0]} reference points on {args.floor}" if args.survey else
             f", {n_pressure} pressure rows; starts on {walk.floor_name}{route}"), file=sys.stderr)
    return 0


def _check_building_options(args: argparse.Namespace) -> None:
    """The one-floor options refused in a building; --segment-s and --floor-loss-db checked."""
    where = args.map
    if args.duration is not None:
        raise MapfilterError("--duration: in a building a walk lasts its floor changes and --segment-s of wandering "
                             "before and after each; a survey visits every point", where)
    if args.write_aps is not None or args.aps_c_offset or args.aps_alpha_offset:
        raise MapfilterError("--write-aps / --aps-c-offset / --aps-alpha-offset are for a one-floor map, not a "
                             "building", where)
    lo, hi = args.segment_s
    if not (0.0 <= lo <= hi):
        raise MapfilterError(f"--segment-s needs 0 <= MIN <= MAX, got {lo:g} {hi:g}")
    if not args.floor_loss_db >= 0.0:
        raise MapfilterError(f"--floor-loss-db must be >= 0, got {args.floor_loss_db:g}")


def _checked_floor_tables(args: argparse.Namespace, building) -> dict:
    """Each floor's access points (``_floor_tables``), refused naming the file to fix when BSSIDs of
    different floors collide."""
    from mapfilter.simulate.building import building_access_points

    tables = _floor_tables(args, building)
    try:
        building_access_points(building, tables)
    except MapfilterError as exc:  # BSSIDs shared between floors: name the file to fix
        raise MapfilterError(exc.reason + (" (their copies on different floors collide)" if args.aps else
                                           " (each floor map's table: mapfilter: access_points; or pass --aps to "
                                           "copy one table onto every floor with its own BSSIDs)"),
                             args.aps or args.map) from None
    return tables


def _building_config(args: argparse.Namespace):
    """The walk's settings in a building (``BuildingSimConfig``), checked."""
    from mapfilter.simulate.building import BuildingSimConfig
    from mapfilter.simulate.walk import SimConfig

    walk_cfg = dataclasses.replace(
        SimConfig(), start_time_ms=args.start_time_ms, survey_spacing_m=args.survey_spacing,
        survey_scans_per_point=args.scans_per_point, shadowing_sigma_db=args.shadowing_db,
        wall_loss_2g4_db=args.wall_loss_db[0], wall_loss_5g_db=args.wall_loss_db[1],
        blocking_episodes=tuple(tuple(e) for e in args.blocking),
    )
    walk_cfg.validate()
    return BuildingSimConfig(walk=walk_cfg, segment_s=tuple(args.segment_s), floor_loss_db=args.floor_loss_db)


def _simulate_in_building(args: argparse.Namespace, building, tables: dict, config, rng) -> tuple:
    """(the simulated walk, its floor changes): a survey of --floor, or a walk by the schedule
    --change / --floor-changes make."""
    from mapfilter.simulate.building import simulate_building_survey, simulate_building_walk

    where = args.map
    if args.survey:
        if args.start_floor is not None or args.floor_changes is not None or args.change:
            raise MapfilterError("--survey surveys one floor (--floor NAME): --start-floor, --floor-changes and "
                                 "--change are for walks", where)
        if args.floor is None:
            raise MapfilterError(f"--survey in a building surveys one floor: pass --floor NAME (floors: "
                                 f"{', '.join(building.floor_names)})", where)
        building.floor_index(args.floor, where)
        return simulate_building_survey(building, tables, args.floor, config, rng, site_id=args.map.stem), []
    if args.floor is not None:
        raise MapfilterError("--floor names the floor to survey (with --survey); a walk starts on --start-floor",
                             where)
    start, changes = _schedule(args, building, rng)
    return simulate_building_walk(building, tables, start, changes, config, rng, site_id=args.map.stem)


def _floor_tables(args: argparse.Namespace, building) -> dict:
    """Each floor's access points in its own frame: its map's table, or --aps copied onto every floor."""
    from mapfilter.sensors.pathloss import AccessPointTable, access_points_for_map, check_access_points_on_map

    if args.aps is None:
        return {floor.name: access_points_for_map(None, floor.plan, floor.map_path or args.map,
                                                  hint="pass --aps APS.csv (copied onto every floor)")
                for floor in building.floors}
    base = AccessPointTable.read_csv(args.aps)
    check_access_points_on_map(base, building, args.map)  # each floor's copy is in that floor's frame
    if len(building.floors) > 256:
        raise MapfilterError("--aps copies the table onto at most 256 floors (one BSSID octet each)", args.aps)
    for bssid in base.bssid:
        octets = bssid.split(":")
        if len(octets) != 6 or not all(len(o) == 2 for o in octets):
            raise MapfilterError(f"--aps gives every floor's copy its own BSSIDs (the fourth octet set to the floor's "
                                 f"number): {bssid!r} is not a MAC address aa:bb:cc:dd:ee:ff", args.aps)
    tables = {}
    for i, floor in enumerate(building.floors):
        bssid = [b[:9] + f"{i:02x}" + b[11:] for b in base.bssid]
        tables[floor.name] = dataclasses.replace(base, bssid=bssid, xy_m=base.xy_m.copy())
    return tables


def _schedule(args: argparse.Namespace, building, rng) -> tuple:
    """The start floor and the floor changes: as given, or drawn from ``rng`` (the seed)."""
    from mapfilter.simulate.building import FloorChange

    where, names = args.map, building.floor_names
    if args.change and args.floor_changes is not None:
        raise MapfilterError("give --floor-changes N or --change CONNECTOR FLOOR, not both", where)
    if args.start_floor is not None:
        floor = building.floor_index(args.start_floor, where)
    else:
        floor = int(rng.integers(0, len(names)))
    start = names[floor]
    connectors = {c.name: c for c in building.connectors}
    if args.change:
        changes = []
        for name, to_floor in args.change:
            building.floor_index(to_floor, where)
            if name not in connectors:
                raise MapfilterError(f"--change {name} {to_floor}: the building has no connector {name!r} "
                                     f"(connectors: {', '.join(connectors) or 'none'})", where)
            changes.append(FloorChange(name, to_floor))
        return start, changes
    n = DEFAULT_FLOOR_CHANGES if args.floor_changes is None else args.floor_changes
    if n < 0:
        raise MapfilterError(f"--floor-changes must be >= 0, got {n}")
    if n and not building.connectors:
        raise MapfilterError("the building has no connectors (stairs, escalators, lifts), so a walk cannot change "
                             "floor: add connectors (docs/building.md) or pass --floor-changes 0", where)
    changes = []
    for _ in range(n):
        options = [(c.name, g) for c in building.connectors for g in _destinations(building, c, names[floor])]
        if not options:
            raise MapfilterError(f"no connector leaves floor {names[floor]!r} for another floor", where)
        name, to_floor = options[int(rng.integers(0, len(options)))]
        changes.append(FloorChange(name, to_floor))
        floor = building.floor_index(to_floor)
    return start, changes


def _destinations(building, connector, here: str) -> list[str]:
    """Floors ``connector`` takes a walker on floor ``here`` to: a lift, any other floor it links;
    stairs and escalators, the next floor it links below and above (by elevation)."""
    if here not in connector.polygons:
        return []
    linked = [f.name for f in building.floors if f.name in connector.polygons]
    if connector.kind == "lift":
        return [name for name in linked if name != here]
    elevation = {f.name: f.elevation_m for f in building.floors}
    ordered = sorted(linked, key=lambda name: (elevation[name], linked.index(name)))
    i = ordered.index(here)
    return [ordered[j] for j in (i - 1, i + 1) if 0 <= j < len(ordered)]
