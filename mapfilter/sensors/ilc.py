"""Reader for the Indoor Location Competition (ILC 2.0) trace format, plain or gzip.

Tab-separated records, first column Unix time in ms::

    1574559495263	TYPE_WAYPOINT	81.317215	93.31349
    1574559495401	TYPE_ACCELEROMETER	-0.85	1.82	9.83	2
    1574559497191	TYPE_WIFI	ssid	a8:0c:ca:03:9d:d7	-49	2422	1574559495450

Header lines start with '#'. Unknown record types are skipped. Two additions of ours, written
by the simulator: ``TYPE_PRESSURE`` rows (``time TYPE_PRESSURE hPa accuracy``, a barometer) and
a fifth ``TYPE_WAYPOINT`` column naming the waypoint's floor (a walk over several floors). Real logs hold oddities, and
the reader keeps the walk where it can:

- a bad row (too few fields, a value that is not a number, ``Infinity`` or ``NaN``, or one
  outside its physical range: ``logread.RANGES``) in a record type the run does not need
  (``needed``; beacons and the magnetometer by default) is skipped and counted;
- a bad row in a needed type is skipped too, unless ``strict``: then it is refused with an
  error naming the file and line;
- two records on one line (a missing newline) are split back into two records; a line longer
  than ``logread.MAX_LINE_BYTES`` is read past without being held, and counted as unreadable;
- exact duplicate records are kept once; long stretches with no record are reported;
- a gzip stream that ends early (a cut download) keeps the complete lines before the cut
  (refused with ``strict``); a corrupted stream is refused, since its data cannot be trusted;
- a log with no usable record left is refused.

What was skipped is in ``Recording.read_report`` (``ReadReport.warning()`` is one line).
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.sensors.logread import (BadRow, LogReadWarning, check_range, check_usable, count_record, drop_duplicate_records,
                                       drop_duplicate_rows, emit_warning, find_time_gaps, iter_bounded_lines,
                                       group_scans, open_binary, parse_number, quick_numbers, read_lines)
from mapfilter.sensors.recording import Beacons, ReadReport, Recording, WifiScans

__all__ = ["DEFAULT_MAX_WIFI_AGE_S", "NEEDED_TYPES", "LogReadWarning", "read_ilc", "read_ilc_header"]

DEFAULT_MAX_WIFI_AGE_S = 5.0
FORMAT_NAME = "ILC 2.0"

# record type -> (name of the sensor list, physical quantity of its three values)
_VECTOR_TYPES = {
    "TYPE_ACCELEROMETER": ("acc", "acc_mps2"),
    "TYPE_GYROSCOPE": ("gyro", "gyro_radps"),
    "TYPE_MAGNETIC_FIELD": ("magnet", "magnet_ut"),
    "TYPE_ROTATION_VECTOR": ("rotvec", "quaternion"),
}
# What tracking, evaluation and radio maps read: ground truth, WiFi, the IMU streams that dead
# reckoning uses (accelerometer, gyroscope, rotation vector) and the barometer the floor
# tracking uses. The magnetometer and the beacons are read but used by no stage.
NEEDED_TYPES = frozenset({"TYPE_WAYPOINT", "TYPE_ACCELEROMETER", "TYPE_GYROSCOPE", "TYPE_ROTATION_VECTOR",
                          "TYPE_WIFI", "TYPE_PRESSURE"})

# A record starts with a Unix time in ms: 13 digits from 2001 to 2286. A missing newline glues
# the previous record's last field to the next record's time, e.g. "3" + "1574559495401".
_TIME_DIGITS = 13
_RECORD_TYPE = re.compile(r"TYPE_[A-Z0-9_]+")


def read_ilc(path: str | os.PathLike, max_wifi_age_s: float = DEFAULT_MAX_WIFI_AGE_S, *,
             strict: bool = False, needed: Iterable[str] = NEEDED_TYPES,
             warn: Callable[[str], None] | None = None) -> Recording:
    """Read one ILC trace into a ``Recording`` (what was skipped: ``recording.read_report``).

    WiFi rows whose last-seen time is more than ``max_wifi_age_s`` before the scan time
    are stale cached results and are dropped (``inf`` keeps all); a BSSID heard twice in
    one scan on the same band keeps its strongest row.

    Bad rows (malformed, not finite, or outside the physical range of their quantity:
    ``logread.RANGES``) of a type outside ``needed`` are always skipped; bad rows of a needed
    type, over-long lines and a truncated gzip stream are skipped unless ``strict``, which
    refuses them with a ``MapfilterError`` naming the file and line. Exact duplicate records
    are kept once; long stretches with no record are reported (``ReadReport.time_gaps_s``).
    When anything was skipped or a gap found, the report's one-line warning goes to ``warn``
    if given, else to ``warnings.warn`` as a ``LogReadWarning``.
    """
    path = Path(path)
    if not path.is_file():
        raise MapfilterError("file not found", path)
    report = ReadReport(path=path, needed=frozenset(needed), format=FORMAT_NAME)
    vectors: dict[str, list[tuple[float, float, float, float]]] = {name: [] for name, _ in _VECTOR_TYPES.values()}
    waypoints: list[tuple[float, float, float]] = []
    waypoint_floors: list[str] = []  # a fifth TYPE_WAYPOINT column (several floors), if any
    pressure: list[tuple[float, float]] = []  # t_s, hPa
    wifi_rows: list[tuple[float, str, float, float, float]] = []  # t_s, bssid, rssi, freq, age_s
    beacon_rows: list[tuple[float, str, float, float]] = []  # t_s, id, rssi, distance
    header: dict[str, str] = {}

    def handle_line(line_no: int, line: str) -> None:
        if not line.strip():
            return
        if line.startswith("#"):
            _read_header_line(line, header)
            return
        records = _split_records(line.split("\t"))
        if len(records) > 1:
            report.joined_lines += 1
        for fields in records:
            count_record(report, lambda: _parse_record(fields, vectors, waypoints, wifi_rows, beacon_rows,
                                                       waypoint_floors, pressure), line_no, strict, path)

    read_lines(path, report, strict, handle_line)
    check_usable(report, path)

    def vector_arrays(name: str, kind: str) -> tuple[np.ndarray, np.ndarray]:
        rows = drop_duplicate_rows(np.array(vectors[name], dtype=np.float64).reshape(-1, 4), report, kind)
        return rows[:, 0], rows[:, 1:]

    acc_t, acc = vector_arrays("acc", "TYPE_ACCELEROMETER")
    gyro_t, gyro = vector_arrays("gyro", "TYPE_GYROSCOPE")
    mag_t, mag = vector_arrays("magnet", "TYPE_MAGNETIC_FIELD")
    rot_t, rot = vector_arrays("rotvec", "TYPE_ROTATION_VECTOR")
    wp_floor = None
    if waypoint_floors and len(waypoint_floors) == len(waypoints):
        records = drop_duplicate_records([(*w, f) for w, f in zip(waypoints, waypoint_floors)], report,
                                         "TYPE_WAYPOINT")
        order = sorted(range(len(records)), key=lambda i: records[i][0])  # stable: by time
        wp = np.array([records[i][:3] for i in order], dtype=np.float64).reshape(-1, 3)
        wp_floor = [records[i][3] for i in order]
    else:
        wp = drop_duplicate_rows(np.array(waypoints, dtype=np.float64).reshape(-1, 3), report, "TYPE_WAYPOINT")
    baro = drop_duplicate_rows(np.array(pressure, dtype=np.float64).reshape(-1, 2), report, "TYPE_PRESSURE")
    wifi_rows = drop_duplicate_records(wifi_rows, report, "TYPE_WIFI")
    beacon_rows = drop_duplicate_records(beacon_rows, report, "TYPE_BEACON")
    find_time_gaps([acc_t, gyro_t, mag_t, rot_t, wp[:, 0], baro[:, 0], [r[0] for r in wifi_rows],
                    [r[0] for r in beacon_rows]], report)
    emit_warning(report, warn)
    start_ms = header.get("startTime")
    return Recording(
        path=path,
        floor_name=header.get("FloorName") or None,
        start_t_s=float(start_ms) / 1000.0 if start_ms and start_ms.isdigit() else None,
        waypoint_t_s=wp[:, 0],
        waypoint_xy_m=wp[:, 1:3],
        acc_t_s=acc_t, acc_mps2=acc,
        gyro_t_s=gyro_t, gyro_radps=gyro,
        magnet_t_s=mag_t, magnet_ut=mag,
        rotvec_t_s=rot_t, rotvec_xyz=rot,
        wifi=group_scans(wifi_rows, max_wifi_age_s),
        beacons=beacons_of(beacon_rows),
        read_report=report,
        pressure_t_s=baro[:, 0], pressure_hpa=baro[:, 1],
        waypoint_floor=wp_floor,
        phone_model=header.get("Model") or None,
    )


def beacons_of(rows: list[tuple[float, str, float, float]]) -> Beacons:
    """``Beacons`` of (t_s, id, rssi_dbm, distance_m) rows, sorted by time."""
    rows = sorted(rows, key=lambda r: r[0])
    return Beacons(
        t_s=np.array([r[0] for r in rows], dtype=np.float64),
        beacon_id=[r[1] for r in rows],
        rssi_dbm=np.array([r[2] for r in rows], dtype=np.float32),
        distance_m=np.array([r[3] for r in rows], dtype=np.float32),
    )


def read_ilc_header(path: str | os.PathLike) -> dict[str, str]:
    """The header of an ILC trace (``key:value`` fields of its leading ``#`` lines, e.g.
    ``FloorName``) without reading the records: a cheap look before a long run."""
    path = Path(path)
    if not path.is_file():
        raise MapfilterError("file not found", path)
    header: dict[str, str] = {}
    try:
        with open_binary(path) as handle:
            for _, line in iter_bounded_lines(handle):
                if line is None or (line.strip() and not line.startswith("#")):
                    break
                if line.strip():
                    _read_header_line(line, header)
    except (OSError, EOFError, zlib.error) as exc:
        raise MapfilterError(f"cannot read log: {exc}", path) from None
    return header


def _read_header_line(line: str, header: dict[str, str]) -> None:
    """The ``key:value`` fields of one ``#`` line into ``header`` (the first value of a key wins)."""
    for field in line[1:].split("\t"):
        key, sep, value = field.strip().partition(":")
        if sep:
            header.setdefault(key, value)


def _split_records(fields: list[str]) -> list[list[str]]:
    """Split the fields of one line into records: a record-type field after the second column
    means a missing newline glued two records, the field before it ending in the next time."""
    starts = [j for j in range(2, len(fields)) if _RECORD_TYPE.fullmatch(fields[j])]
    if not starts:
        return [fields]
    records, begin = [], 0
    head = fields[0]
    for j in starts:
        glued = fields[j - 1]
        if len(glued) < _TIME_DIGITS or not glued[-_TIME_DIGITS:].isdigit():
            continue  # not a glued time: leave the field to the row check
        # exactly 13 digits: the previous record had lost its last field before the join
        last_field = [glued[:-_TIME_DIGITS]] if len(glued) > _TIME_DIGITS else []
        records.append([head, *fields[begin + 1:j - 1], *last_field])
        head, begin = glued[-_TIME_DIGITS:], j - 1
    records.append([head, *fields[begin + 1:]])
    return records


def _parse_record(fields, vectors, waypoints, wifi_rows, beacon_rows, waypoint_floors, pressure) -> str | None:
    """Append one record to its list; return its type (None: unknown type). Raises ``BadRow``."""
    if len(fields) < 2:
        raise BadRow("?", "malformed line: expected a time and a record type")
    kind = fields[1]
    if kind == "TYPE_WAYPOINT":
        t_s = _time_s(fields)
        x, y = (check_range(kind, name, parse_number(kind, fields, column), "position_m")
                for name, column in (("x", 2), ("y", 3)))
        waypoints.append((t_s, x, y))
        if len(fields) > 4 and fields[4].strip():
            waypoint_floors.append(fields[4].strip())  # the floor (a walk over several floors)
    elif kind in _VECTOR_TYPES:
        name, quantity = _VECTOR_TYPES[kind]
        t_ms = quick_numbers(fields, range(0, 1), "unix_ms")
        values = quick_numbers(fields, range(2, 5), quantity)
        if t_ms is not None and values is not None:
            vectors[name].append((t_ms[0] / 1000.0, *values))  # the fast path: a good row
            return kind
        t_s = _time_s(fields)
        values = [check_range(kind, axis, parse_number(kind, fields, column), quantity)
                  for axis, column in (("x", 2), ("y", 3), ("z", 4))]
        vectors[name].append((t_s, *values))
    elif kind == "TYPE_WIFI":
        if len(fields) < 7:
            raise BadRow(kind, f"malformed TYPE_WIFI line: {len(fields)} fields, expected 7")
        t_ms = check_range(kind, "time", parse_number(kind, fields, 0), "unix_ms")
        rssi = check_range(kind, "RSSI", parse_number(kind, fields, 4), "rssi_dbm")
        freq = check_range(kind, "frequency", parse_number(kind, fields, 5), "freq_mhz")
        seen_ms = check_range(kind, "last-seen time", parse_number(kind, fields, 6), "unix_ms")
        bssid = fields[3].strip()
        if not bssid:
            raise BadRow(kind, "malformed TYPE_WIFI line: empty BSSID")
        wifi_rows.append((t_ms / 1000.0, bssid, rssi, freq, (t_ms - seen_ms) / 1000.0))
    elif kind == "TYPE_PRESSURE":
        t_s = _time_s(fields)
        pressure.append((t_s, check_range(kind, "pressure", parse_number(kind, fields, 2), "pressure_hpa")))
    elif kind == "TYPE_BEACON":
        if len(fields) < 8:
            raise BadRow(kind, f"malformed TYPE_BEACON line: {len(fields)} fields, expected 10")
        t_s = _time_s(fields)
        rssi = check_range(kind, "RSSI", parse_number(kind, fields, 6), "rssi_dbm")
        distance = check_range(kind, "distance", parse_number(kind, fields, 7), "distance_m")
        beacon_rows.append((t_s, f"{fields[2]}:{fields[3]}:{fields[4]}", rssi, distance))
    else:
        return None  # other record types are skipped
    return kind


def _time_s(fields: list[str]) -> float:
    """The record's time (column 1, Unix ms) in seconds, checked for a plausible date."""
    kind = fields[1]
    return check_range(kind, "time", parse_number(kind, fields, 0), "unix_ms") / 1000.0
