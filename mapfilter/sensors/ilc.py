"""Reader for the Indoor Location Competition (ILC 2.0) trace format, plain or gzip.

Tab-separated records, first column Unix time in ms::

    1574559495263	TYPE_WAYPOINT	81.317215	93.31349
    1574559495401	TYPE_ACCELEROMETER	-0.85	1.82	9.83	2
    1574559497191	TYPE_WIFI	ssid	a8:0c:ca:03:9d:d7	-49	2422	1574559495450

Header lines start with '#'. Unknown record types are skipped. Two additions of ours, written
by the simulator: ``TYPE_PRESSURE`` rows (``time TYPE_PRESSURE hPa accuracy``, a barometer) and
a fifth ``TYPE_WAYPOINT`` column naming the waypoint's floor (a walk over several floors). Real logs hold oddities, and
the reader keeps the walk where it can:

- a bad row (too few fields, a value that is not a number, ``Infinity`` or ``NaN``) in a
  record type the run does not need (``needed``; beacons by default) is skipped and counted;
- a bad row in a needed type is skipped too, unless ``strict``: then it is refused with an
  error naming the file and line;
- two records on one line (a missing newline) are split back into two records;
- a gzip stream that ends early (a cut download) keeps the complete lines before the cut
  (refused with ``strict``); a corrupted stream is refused, since its data cannot be trusted;
- a log with no usable record left is refused.

What was skipped is in ``Recording.read_report`` (``ReadReport.warning()`` is one line).
"""

from __future__ import annotations

import gzip
import math
import os
import re
import warnings
import zlib
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.sensors.recording import Beacons, ReadReport, Recording, WifiScans
from mapfilter.sensors.wifi import ap_key, band_of_frequency

DEFAULT_MAX_WIFI_AGE_S = 5.0

# record type -> name of the sensor list
_VECTOR_TYPES = {
    "TYPE_ACCELEROMETER": "acc",
    "TYPE_GYROSCOPE": "gyro",
    "TYPE_MAGNETIC_FIELD": "magnet",
    "TYPE_ROTATION_VECTOR": "rotvec",
}
# What tracking, evaluation and radio maps read: ground truth, WiFi, and the IMU streams that
# dead reckoning uses (accelerometer, gyroscope, rotation vector). The magnetometer and the
# beacons are read but used by no stage.
NEEDED_TYPES = frozenset({"TYPE_WAYPOINT", "TYPE_ACCELEROMETER", "TYPE_GYROSCOPE", "TYPE_ROTATION_VECTOR",
                          "TYPE_WIFI"})

# A record starts with a Unix time in ms: 13 digits from 2001 to 2286. A missing newline glues
# the previous record's last field to the next record's time, e.g. "3" + "1574559495401".
_TIME_DIGITS = 13
_RECORD_TYPE = re.compile(r"TYPE_[A-Z0-9_]+")


class LogReadWarning(UserWarning):
    """Rows of a log were skipped (the message is one line naming the file, types and lines)."""


class _BadRow(Exception):
    """A row that cannot be read; ``reason`` says why."""

    def __init__(self, kind: str, reason: str):
        super().__init__(reason)
        self.kind = kind
        self.reason = reason


def read_ilc(path: str | os.PathLike, max_wifi_age_s: float = DEFAULT_MAX_WIFI_AGE_S, *,
             strict: bool = False, needed: Iterable[str] = NEEDED_TYPES,
             warn: Callable[[str], None] | None = None) -> Recording:
    """Read one ILC trace into a ``Recording`` (what was skipped: ``recording.read_report``).

    WiFi rows whose last-seen time is more than ``max_wifi_age_s`` before the scan time
    are stale cached results and are dropped (``inf`` keeps all); a BSSID heard twice in
    one scan on the same band keeps its strongest row.

    Bad rows of a type outside ``needed`` are always skipped; bad rows of a needed type and
    a truncated gzip stream are skipped unless ``strict``, which refuses them with a
    ``MapfilterError`` naming the file and line. When anything was skipped, the report's
    one-line warning goes to ``warn`` if given, else to ``warnings.warn`` as a ``LogReadWarning``.
    """
    path = Path(path)
    if not path.is_file():
        raise MapfilterError("file not found", path)
    report = ReadReport(path=path, needed=frozenset(needed))
    opener = gzip.open if path.suffix == ".gz" else open
    vectors: dict[str, list[list[float]]] = {name: [] for name in _VECTOR_TYPES.values()}
    waypoints: list[tuple[float, float, float]] = []
    waypoint_floors: list[str] = []  # a fifth TYPE_WAYPOINT column (several floors), if any
    pressure: list[tuple[float, float]] = []  # t_s, hPa
    wifi_rows: list[tuple[float, str, float, float, float]] = []  # t_s, bssid, rssi, freq, age_s
    beacon_rows: list[tuple[float, str, float, float]] = []  # t_s, id, rssi, distance
    header: dict[str, str] = {}
    line_no = 0
    try:
        with opener(path, "rt", encoding="utf-8", errors="replace") as handle:
            for line_no, raw in enumerate(handle, start=1):
                line = raw.rstrip("\r\n")
                if not line.strip():
                    continue
                if line.startswith("#"):
                    _read_header_line(line, header)
                    continue
                records = _split_records(line.split("\t"))
                if len(records) > 1:
                    report.joined_lines += 1
                for fields in records:
                    try:
                        kind = _parse_record(fields, vectors, waypoints, wifi_rows, beacon_rows, waypoint_floors,
                                             pressure)
                    except _BadRow as bad:
                        if strict and (bad.kind in report.needed or bad.kind == "?"):
                            raise MapfilterError(bad.reason, path, line_no) from None
                        report.bad_rows[bad.kind] = report.bad_rows.get(bad.kind, 0) + 1
                        report.first_bad.setdefault(bad.kind, f"line {line_no}: {bad.reason}")
                        continue
                    if kind is None:
                        report.unknown_rows += 1
                    else:
                        report.rows[kind] = report.rows.get(kind, 0) + 1
    except EOFError:
        # gzip without its end-of-stream marker: every line handed out before the cut was complete
        # (the text layer only yields a line once its newline has been decompressed)
        if strict:
            raise MapfilterError(f"gzip stream ends early after line {line_no} (truncated file)", path) from None
        report.truncated_after_line = line_no
    except (OSError, gzip.BadGzipFile, zlib.error) as exc:
        raise MapfilterError(f"cannot read log: {exc}", path) from None
    report.n_lines = line_no
    if line_no == 0:
        raise MapfilterError("empty log", path)
    if not report.rows:
        detail = f" ({report.n_bad_rows} bad rows, first at {next(iter(report.first_bad.values()))})" \
            if report.bad_rows else ""
        raise MapfilterError(f"no usable record in the log{detail}", path)
    message = report.warning()
    if message is not None:
        if warn is not None:
            warn(message)
        else:
            warnings.warn(message, LogReadWarning, stacklevel=2)

    def vector_arrays(name: str) -> tuple[np.ndarray, np.ndarray]:
        rows = np.array(vectors[name], dtype=np.float64).reshape(-1, 4)
        order = np.argsort(rows[:, 0], kind="stable")
        return rows[order, 0], rows[order, 1:]

    acc_t, acc = vector_arrays("acc")
    gyro_t, gyro = vector_arrays("gyro")
    mag_t, mag = vector_arrays("magnet")
    rot_t, rot = vector_arrays("rotvec")
    wp = np.array(waypoints, dtype=np.float64).reshape(-1, 3)
    wp_order = np.argsort(wp[:, 0], kind="stable")
    wp = wp[wp_order]
    wp_floor = None
    if waypoint_floors and len(waypoint_floors) == len(waypoints):
        wp_floor = [waypoint_floors[i] for i in wp_order]
    baro = np.array(pressure, dtype=np.float64).reshape(-1, 2)
    baro = baro[np.argsort(baro[:, 0], kind="stable")]
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
        wifi=_group_scans(wifi_rows, max_wifi_age_s),
        beacons=Beacons(
            t_s=np.array([r[0] for r in beacon_rows], dtype=np.float64),
            beacon_id=[r[1] for r in beacon_rows],
            rssi_dbm=np.array([r[2] for r in beacon_rows], dtype=np.float32),
            distance_m=np.array([r[3] for r in beacon_rows], dtype=np.float32),
        ),
        read_report=report,
        pressure_t_s=baro[:, 0], pressure_hpa=baro[:, 1],
        waypoint_floor=wp_floor,
    )


def read_ilc_header(path: str | os.PathLike) -> dict[str, str]:
    """The header of an ILC trace (``key:value`` fields of its leading ``#`` lines, e.g.
    ``FloorName``) without reading the records: a cheap look before a long run."""
    path = Path(path)
    if not path.is_file():
        raise MapfilterError("file not found", path)
    opener = gzip.open if path.suffix == ".gz" else open
    header: dict[str, str] = {}
    try:
        with opener(path, "rt", encoding="utf-8", errors="replace") as handle:
            for raw in handle:
                line = raw.rstrip("\r\n")
                if not line.strip():
                    continue
                if not line.startswith("#"):
                    break
                _read_header_line(line, header)
    except (OSError, EOFError, gzip.BadGzipFile, zlib.error) as exc:
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


def _parse_record(fields, vectors, waypoints, wifi_rows, beacon_rows, waypoint_floors=None,
                  pressure=None) -> str | None:
    """Append one record to its list; return its type (None: unknown type). Raises ``_BadRow``."""
    if len(fields) < 2:
        raise _BadRow("?", "malformed line: expected a time and a record type")
    kind = fields[1]
    if kind == "TYPE_WAYPOINT":
        t_ms, x, y = _numbers(fields, (0, 2, 3))
        waypoints.append((t_ms / 1000.0, x, y))
        if waypoint_floors is not None and len(fields) > 4 and fields[4].strip():
            waypoint_floors.append(fields[4].strip())  # the floor (a walk over several floors)
    elif kind in _VECTOR_TYPES:
        t_ms, vx, vy, vz = _numbers(fields, (0, 2, 3, 4))
        vectors[_VECTOR_TYPES[kind]].append([t_ms / 1000.0, vx, vy, vz])
    elif kind == "TYPE_WIFI":
        if len(fields) < 7:
            raise _BadRow(kind, f"malformed TYPE_WIFI line: {len(fields)} fields, expected 7")
        t_ms, rssi, freq, seen_ms = _numbers(fields, (0, 4, 5, 6))
        bssid = fields[3].strip()
        if not bssid:
            raise _BadRow(kind, "malformed TYPE_WIFI line: empty BSSID")
        wifi_rows.append((t_ms / 1000.0, bssid, rssi, freq, (t_ms - seen_ms) / 1000.0))
    elif kind == "TYPE_PRESSURE" and pressure is not None:
        t_ms, hpa = _numbers(fields, (0, 2))
        pressure.append((t_ms / 1000.0, hpa))
    elif kind == "TYPE_BEACON":
        if len(fields) < 8:
            raise _BadRow(kind, f"malformed TYPE_BEACON line: {len(fields)} fields, expected 10")
        t_ms, rssi, distance = _numbers(fields, (0, 6, 7))
        beacon_rows.append((t_ms / 1000.0, f"{fields[2]}:{fields[3]}:{fields[4]}", rssi, distance))
    else:
        return None  # other record types are skipped
    return kind


def _numbers(fields: list[str], columns: tuple[int, ...]) -> list[float]:
    kind = fields[1]
    values = []
    for column in columns:
        if column >= len(fields):
            raise _BadRow(kind, f"malformed {kind} line: {len(fields)} fields, expected at least {max(columns) + 1}")
        try:
            value = float(fields[column])
        except ValueError:
            raise _BadRow(kind, f"malformed {kind} line: column {column + 1} is not a number: "
                                f"{fields[column]!r}") from None
        if not math.isfinite(value):
            # Android writes "Infinity" for a beacon distance it cannot estimate
            raise _BadRow(kind, f"malformed {kind} line: column {column + 1} is not finite: {fields[column]!r}")
        values.append(value)
    return values


def _group_scans(rows: list[tuple[float, str, float, float, float]], max_age_s: float) -> WifiScans:
    """Group rows by scan time, drop stale rows, key APs by BSSID and band."""
    keys: dict[str, int] = {}
    per_scan: dict[float, dict[int, tuple[float, float, float]]] = {}
    for t_s, bssid, rssi, freq, age_s in rows:
        if age_s > max_age_s:
            continue
        index = keys.setdefault(ap_key(bssid, band_of_frequency(freq)), len(keys))
        scan = per_scan.setdefault(t_s, {})
        if index not in scan or rssi > scan[index][0]:
            scan[index] = (rssi, freq, age_s)
    scan_times = sorted(per_scan)
    row_scan, row_ap, rssi_dbm, freq_mhz, age = [], [], [], [], []
    for s, t_s in enumerate(scan_times):
        for index, (rssi, freq, age_s) in per_scan[t_s].items():
            row_scan.append(s)
            row_ap.append(index)
            rssi_dbm.append(rssi)
            freq_mhz.append(freq)
            age.append(age_s)
    return WifiScans(
        t_s=np.array(scan_times, dtype=np.float64),
        ap_keys=list(keys),
        row_scan=np.array(row_scan, dtype=np.int64),
        row_ap=np.array(row_ap, dtype=np.int64),
        rssi_dbm=np.array(rssi_dbm, dtype=np.float32),
        freq_mhz=np.array(freq_mhz, dtype=np.float32),
        age_s=np.array(age, dtype=np.float32),
    )
