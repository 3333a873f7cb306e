"""``mapfilter check LOG...``: what each log holds and what the reader skipped, without tracking."""

from __future__ import annotations

import argparse
from pathlib import Path

from mapfilter.cli.common import add_strict_argument
from mapfilter.errors import MapfilterError

_EPILOG = """\
One line per log: its format (ILC 2.0 or GetSensorData, told by content) and phone, floor,
duration, waypoints, WiFi scans and access points, IMU rows (and whether dead reckoning is
possible), barometer and BLE rows, then what was skipped: bad rows per record type (with
the first bad line; values outside their physical range are bad rows), exact duplicate rows,
rows that went back in time (dropped), lines that held two records (split), a gzip stream cut short; and long stretches with no
record at all (time gaps). A last line counts the logs. The exit code is 1 if any log cannot
be read (each is named).

With --map MAP (a map or building YAML), a warning names each log whose waypoints fall in the
map's walls or outside it (latitude/longitude waypoints need a georeferenced building, as
`mapfilter map import-ipin` writes).

--truth GT.csv|GT.tum writes one log's ground truth as a track file (its waypoints; in a
building each on its floor; GetSensorData POSI rows in latitude/longitude need --map, a
georeferenced building, to be put in its metres), so that a track and its truth go into
trajectory tools: `evo_ape tum GT.tum TRACK.tum --t_max_diff 1`. With --at TRACK the ground
truth is written at that track's times instead (linear between waypoints, within their span),
and evo pairs every row without --t_max_diff.

examples:
  mapfilter check ../shared/data/ilc20/site1/*/path_data_files/*.txt.gz
  mapfilter check ../shared/data/ipin2023/logs/*.txt.gz
  mapfilter check walks/*.txt.gz --map floor.yaml
  mapfilter check walk.txt.gz --truth truth.tum --at track.tum
"""


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "check", help="report what logs hold and what the reader skips (no tracking)",
        description="Read logs as track and evaluate would, and report what each holds and what was skipped.",
        epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("logs", type=Path, nargs="+", metavar="LOG",
                        help="logs (ILC 2.0 traces or GetSensorData logs, plain or gzip)")
    parser.add_argument("--map", type=Path, metavar="MAP",
                        help="warn about waypoints that fall in the walls of this map or building YAML")
    parser.add_argument("--truth", type=Path, metavar="GT.csv|GT.tum",
                        help="write the log's ground truth as a track file (one log; format by the extension)")
    parser.add_argument("--at", type=Path, metavar="TRACK",
                        help="with --truth: the ground truth at this track's times (CSV or TUM)")
    add_strict_argument(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mapfilter.cli.common import check_map_first, check_output_path, input_paths, waypoints_in_walls, warn
    from mapfilter.maps.building import Building
    from mapfilter.sensors.logs import read_log  # not at import: --help loads no numerical library
    from mapfilter.io.tracks import read_track

    building = None
    if args.truth is not None:
        if len(args.logs) != 1:
            raise MapfilterError(f"--truth writes one log's ground truth: {len(args.logs)} logs given")
        # the output policy, before any work: never the log, the --at track, the map or what it names
        check_output_path(args.truth, "--truth", inputs=input_paths(args.logs, args.at, args.map))
    elif args.at is not None:
        raise MapfilterError("--at is for --truth: give --truth GT.tum too")
    at = read_track(args.at) if args.at is not None else None  # refused before any output
    if args.map is not None:
        check_map_first("mapfilter check LOG... --map MAP", args.map)
        building = Building.load(args.map)
    counts = {"readable": 0, "pdr": 0, "skipped": 0, "refused": 0, "gaps": 0}
    for path in args.logs:
        try:
            # the warning is part of this command's own line, not a separate one
            recording = read_log(path, strict=args.strict, warn=lambda message: None)
        except MapfilterError as exc:
            counts["refused"] += 1
            print(f"{exc} [refused]")
            continue
        counts["readable"] += 1
        counts["pdr"] += _has_imu(recording)
        report = recording.read_report
        if not report.clean or report.joined_lines or report.duplicates or report.went_back:
            counts["skipped"] += 1
        counts["gaps"] += bool(report.time_gaps_s)
        print(describe(recording))
        if building is not None:
            message = waypoints_in_walls(building, recording)
            if message is not None:
                warn(message)
        if args.truth is not None:
            _write_truth(recording, building, args.map, args.truth, at)
    print(f"{len(args.logs)} logs: {counts['readable']} readable ({counts['pdr']} with IMU for dead reckoning), "
          f"{counts['skipped']} with rows skipped or split, {counts['gaps']} with time gaps, "
          f"{counts['refused']} refused")
    return 1 if counts["refused"] else 0


def _write_truth(recording, building, map_path, out: Path, at) -> None:
    """The log's ground truth as a track file (``--truth``), at ``at``'s times if given."""
    from mapfilter.cli.track_cmd import track_format
    from mapfilter.evaluation.scoring import ground_truth_track
    from mapfilter.sensors.logs import localise
    from mapfilter.io.tracks import write_track

    if not recording.has_ground_truth:
        raise MapfilterError("the log has no waypoints: no ground truth to write", recording.path)
    if recording.needs_georeference:
        if building is None:
            raise MapfilterError("its ground truth is latitude/longitude (POSI rows): give --map BUILDING.yaml, a "
                                 "georeferenced building (mapfilter map import-ipin), to write it in the map's "
                                 "metres", recording.path)
        recording = localise(recording, building)
    truth = ground_truth_track(recording, None if at is None else at.t_s)
    if len(truth) == 0:
        raise MapfilterError("no row of the track lies within the log's waypoints' time span", out)
    write_track(truth, out, track_format(out, None), building)
    where = f" at the {len(truth)} times of {at.name}" if at is not None else ""
    print(f"wrote {out}: the ground truth of {recording.name}, {len(truth)} rows{where}")


def _has_imu(recording) -> bool:
    return recording.acc_t_s.size >= 2 and recording.gyro_t_s.size >= 2


def describe(recording) -> str:
    """One line: what the log holds and what its reader skipped."""
    report = recording.read_report
    wifi = recording.wifi
    if report is not None and report.time_span_s is not None:
        duration_s = report.time_span_s[1] - report.time_span_s[0]
    else:
        times = [t for t in (recording.wifi.t_s, recording.acc_t_s, recording.waypoint_t_s) if t.size]
        duration_s = max(float(t[-1]) for t in times) - min(float(t[0]) for t in times) if times else 0.0
    floors = recording.floor_name or "?"
    if recording.floor_name is None and recording.waypoint_floor:
        floors = "s " + "/".join(sorted(set(recording.waypoint_floor), key=recording.waypoint_floor.index))
    parts = [report.format if report is not None and report.format else "log",
             f"phone {recording.phone_model or '?'}", f"floor{floors if floors.startswith('s ') else ' ' + floors}",
             f"{duration_s:.0f} s", f"{recording.waypoint_t_s.size} waypoints"
             + (" (lat/lon)" if recording.waypoint_latlon_deg is not None else ""),
             f"{len(wifi)} WiFi scans ({len(wifi.ap_keys)} APs)"]
    if _has_imu(recording):
        parts.append(f"IMU {recording.acc_t_s.size} acc / {recording.gyro_t_s.size} gyro / "
                     f"{recording.rotvec_t_s.size} rotvec rows")
    else:
        parts.append("no IMU (WiFi only: no dead reckoning)")
    if recording.pressure_t_s.size:
        parts.append(f"{recording.pressure_t_s.size} barometer rows")
    parts += [f"{n} {sensor} rows" for sensor, n in recording.source_rows.items() if n]
    text = f"{recording.path}: " + ", ".join(parts)
    skipped = report.warning() if report is not None else None
    if skipped:
        text += "; " + skipped.removeprefix(f"{recording.path}: ")
    if report is not None and report.joined_lines:
        text += f"; {report.joined_lines} line{'s' if report.joined_lines != 1 else ''} held two records (split)"
    return text
