"""Reader for the Indoor Location Competition (ILC 2.0) trace format, plain or gzip.

Tab-separated records, first column Unix time in ms::

    1574559495263	TYPE_WAYPOINT	81.317215	93.31349
    1574559495401	TYPE_ACCELEROMETER	-0.85	1.82	9.83	2
    1574559497191	TYPE_WIFI	ssid	a8:0c:ca:03:9d:d7	-49	2422	1574559495450

Header lines start with '#'. Unknown record types are skipped. Two additions of ours, written
by the simulator: ``TYPE_PRESSURE`` rows (``time TYPE_PRESSURE hPa accuracy``, a barometer) and
a fifth ``TYPE_WAYPOINT`` column naming the waypoint's floor (a walk over several floors).
Beacons are told apart by their MAC (``TYPE_BEACON`` column 9, upper case; the site-1 beacons
share one ``uuid:major:minor``), by ``uuid:major:minor`` in a row without one.

The reader is a stream (:class:`IlcParser`, fed by ``sensors/logs.LogStream``): each record
depends on the lines before it only. Real logs hold oddities, and the reader keeps the walk
where it can:

- a bad row (too few fields, a value that is not a number, ``Infinity`` or ``NaN``, or one
  outside its physical range: ``logread.RANGES``) in a record type the run does not need
  (``needed``; beacons and the magnetometer by default) is skipped and counted;
- a bad row in a needed type is skipped too, unless ``strict``: then it is refused with an
  error naming the file and line;
- two records on one line (a missing newline) are split back into two records; a line longer
  than ``logread.MAX_LINE_BYTES`` is read past without being held, and counted as unreadable;
- each record type keeps file order: a record earlier than the previous kept one of its type
  went back in time and is dropped (counted), an exact repeat of a record of the same time is
  kept once; long stretches with no record are reported;
- a gzip stream that ends early (a cut download) keeps the complete lines before the cut
  (refused with ``strict``); a corrupted stream is refused, since its data cannot be trusted;
- a log with no usable record left is refused.

What was skipped is in ``Recording.read_report`` (``ReadReport.warning()`` is one line).
"""

from __future__ import annotations

import math
import os
import re
import zlib
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.sensors.logread import (BadRow, GapTracker, LogClock, LogReadWarning, RecordStream, ScanAssembler,
                                       TimeOrder, check_range, count_bad_row, group_scans, handle_each,
                                       iter_bounded_lines, on_log_clock, open_binary, parse_columns, parse_number,
                                       quick_numbers, read_whole, split_by, take_block)
from mapfilter.sensors.recording import Beacons, ReadReport, Recording

__all__ = ["DEFAULT_MAX_WIFI_AGE_S", "NEEDED_TYPES", "IlcParser", "LogReadWarning", "read_ilc", "read_ilc_header"]

DEFAULT_MAX_WIFI_AGE_S = 5.0
FORMAT_NAME = "ILC 2.0"

# record type -> (name of the sensor list, physical quantity of its three values)
_VECTOR_TYPES = {
    "TYPE_ACCELEROMETER": ("acc", "acc_mps2"),
    "TYPE_GYROSCOPE": ("gyro", "gyro_radps"),
    "TYPE_MAGNETIC_FIELD": ("magnet", "magnet_ut"),
    "TYPE_ROTATION_VECTOR": ("rotvec", "quaternion"),
}
# The sensors the causal filter merges by time (filter/causal.py): on the log's clock (``LogClock``)
_FOLLOWED = {kind: k for k, kind in enumerate(("TYPE_ACCELEROMETER", "TYPE_GYROSCOPE", "TYPE_ROTATION_VECTOR",
                                                "TYPE_PRESSURE", "TYPE_WIFI", "TYPE_BEACON"))}
# What tracking, evaluation and radio maps read: ground truth, WiFi, the IMU streams that dead
# reckoning uses (accelerometer, gyroscope, rotation vector) and the barometer the floor
# tracking uses. The magnetometer and the beacons are read but used by no stage.
NEEDED_TYPES = frozenset({"TYPE_WAYPOINT", "TYPE_ACCELEROMETER", "TYPE_GYROSCOPE", "TYPE_ROTATION_VECTOR",
                          "TYPE_WIFI", "TYPE_PRESSURE"})

# A record starts with a Unix time in ms: 13 digits from 2001 to 2286. A missing newline glues
# the previous record's last field to the next record's time, e.g. "3" + "1574559495401".
_TIME_DIGITS = 13
_RECORD_TYPE = re.compile(r"TYPE_[A-Z0-9_]+")
_MAC = re.compile(r"[0-9A-Fa-f]{2}(?::[0-9A-Fa-f]{2}){5}")

# What the block parse reads of each record type: the columns that are numbers (column 0, the
# time, first) and their quantities (logread.RANGES), as the line parse reads them
_NUMBER_COLUMNS = {
    **{kind: ((0, 2, 3, 4), ("unix_ms", quantity, quantity, quantity)) for kind, (_, quantity) in _VECTOR_TYPES.items()},
    "TYPE_WIFI": ((0, 4, 5, 6), ("unix_ms", "rssi_dbm", "freq_mhz", "unix_ms")),
    "TYPE_PRESSURE": ((0, 2), ("unix_ms", "pressure_hpa")),
    "TYPE_WAYPOINT": ((0, 2, 3), ("unix_ms", "position_m", "position_m")),
    "TYPE_BEACON": ((0, 6, 7), ("unix_ms", "rssi_dbm", "distance_m")),
}
# Below this share of lines the block parse takes, a block is read line by line (the same records)
_BLOCK_SHARE = 0.9


def read_ilc(path: str | os.PathLike, max_wifi_age_s: float = DEFAULT_MAX_WIFI_AGE_S, *,
             strict: bool = False, needed: Iterable[str] = NEEDED_TYPES,
             warn: Callable[[str], None] | None = None) -> Recording:
    """Read one ILC trace into a ``Recording`` (what was skipped: ``recording.read_report``).

    The trace is streamed (``logread.RecordStream`` with :class:`IlcParser`, what
    ``sensors/logs.LogStream`` does for an ILC log) and the pieces joined: the result is the
    replay of the log as a stream. WiFi rows whose last-seen time is more than
    ``max_wifi_age_s`` before the scan time are stale cached results and are dropped (``inf``
    keeps all); a BSSID heard twice in one scan on the same band keeps its strongest row.

    Bad rows (malformed, not finite, or outside the physical range of their quantity:
    ``logread.RANGES``) of a type outside ``needed`` are always skipped; bad rows of a needed
    type, over-long lines and a truncated gzip stream are skipped unless ``strict``, which
    refuses them with a ``MapfilterError`` naming the file and line. Within each record type,
    records keep file order: one earlier than the previous kept one went back in time and is
    dropped, an exact repeat of one of the same time is kept once. Long stretches with no record
    are reported (``ReadReport.time_gaps_s``). When anything was skipped or a gap found, the
    report's one-line warning goes to ``warn`` if given, else to ``warnings.warn`` as a
    ``LogReadWarning``.
    """
    stream = RecordStream(path, max_wifi_age_s, strict, needed, IlcParser)
    return read_whole(path, stream, warn)


class IlcParser:
    """ILC 2.0 lines -> the records of a ``Recording``, in the order they come (the parser a
    ``logread.RecordStream`` feeds). A WiFi scan is complete once a record of a later time comes."""

    FORMAT_NAME = FORMAT_NAME
    NEEDED_TYPES = NEEDED_TYPES

    def __init__(self, report: ReadReport, max_wifi_age_s: float, strict: bool):
        self._report = report
        self._strict = strict
        self._max_wifi_age_s = max_wifi_age_s
        # rows not yet taken, per sensor list, as tables of rows (t_s, x, y, z) / (t_s, hPa)
        self._vectors: dict[str, list[np.ndarray]] = {name: [] for name, _ in _VECTOR_TYPES.values()}
        self._vector_order = {name: TimeOrder(report, kind) for kind, (name, _) in _VECTOR_TYPES.items()}
        self._pressure: list[np.ndarray] = []
        self._pressure_order = TimeOrder(report, "TYPE_PRESSURE")
        self._waypoints = TimeOrder(report, "TYPE_WAYPOINT")  # records (t_s, x, y, floor or None)
        self._beacons = TimeOrder(report, "TYPE_BEACON")  # records (t_s, id, rssi, distance)
        self._scans = ScanAssembler(report, "TYPE_WIFI")  # rows (t_s, bssid, rssi, freq, age_s)
        self._clock = LogClock()  # the newest record of the sensors the filter follows
        self._gaps = GapTracker(report)
        self._header: dict[str, str] = {}

    def handle_line(self, line_no: int, line: str) -> None:
        if not line.strip():
            return
        if line.startswith("#"):
            _read_header_line(line, self._header)
            return
        records = _split_records(line.split("\t"))
        report = self._report
        if len(records) == 1:
            self._count(self._parse_record(records[0]))  # a bad row: BadRow to the stream
            return
        report.joined_lines += 1
        for fields in records:
            try:
                self._count(self._parse_record(fields))
            except BadRow as bad:
                count_bad_row(report, bad, line_no, self._strict, report.path)

    def handle_lines(self, first: int, lines: list[str | None], bad_row) -> None:
        """Lines ``first``, ``first + 1``, ...: what :meth:`handle_line` does to each in turn. The
        lines that hold one good record of a known type (a time, a ``TYPE_`` field and no other,
        every number read and in range) are parsed together per record type; the others (headers,
        blank, bad or glued lines) go through :meth:`handle_line` in their place in the order."""
        # each line's record type ("": not for the block parse), the lines of each type in order
        heads = [line.split("\t", 2) if line is not None and line[:1] != "#" and line.count("TYPE_") == 1 else None
                 for line in lines]
        kinds = [head[1] if head is not None and len(head) > 1 and head[1][:5] == "TYPE_" else "" for head in heads]
        groups = split_by(kinds)
        groups.pop("", None)
        n = len(lines)
        fast = np.zeros(n, dtype=bool)
        clock_t = np.full(n, -np.inf)  # each fast line's time, if it moves the WiFi scans' clock
        is_wifi = np.zeros(n, dtype=bool)
        parsed: dict[str, tuple[np.ndarray, object]] = {}  # kind -> (its lines, its records)
        for kind, index in groups.items():
            if kind not in _NUMBER_COLUMNS:
                fast[index] = True  # a type this reader does not know: counted, nothing else
                parsed[kind] = (index, None)
                continue
            texts = [lines[i] for i in index.tolist()]
            columns, quantities = _NUMBER_COLUMNS[kind]
            values, ok = parse_columns(texts, "\t", columns, quantities)
            t_s = values[:, 0] / 1000.0
            if kind in _VECTOR_TYPES or kind == "TYPE_PRESSURE":
                records = np.column_stack([t_s, values[:, 1:]])  # a float table
            elif kind == "TYPE_WIFI":
                bssids = [text.split("\t", 4)[3].strip() if ok_i else "" for text, ok_i in zip(texts, ok.tolist())]
                ok &= np.array([bool(b) for b in bssids], dtype=bool)
                age_s = (values[:, 0] - values[:, 3]) / 1000.0
                records = list(zip(t_s.tolist(), bssids, values[:, 1].tolist(), values[:, 2].tolist(), age_s.tolist()))
                is_wifi[index] = True
            elif kind == "TYPE_WAYPOINT":
                rows = [text.split("\t") for text in texts]
                records = [(t, x, y, row[4].strip() if len(row) > 4 and row[4].strip() else None)
                           for t, x, y, row in zip(t_s.tolist(), values[:, 1].tolist(), values[:, 2].tolist(), rows)]
            else:  # TYPE_BEACON
                rows = [text.split("\t") for text in texts]
                records = [(t, _beacon_id(row), rssi, distance) for t, rssi, distance, row in
                           zip(t_s.tolist(), values[:, 1].tolist(), values[:, 2].tolist(), rows)]
            fast[index[ok]] = True
            clock_t[index] = t_s
            parsed[kind] = (index, records)
        if np.count_nonzero(fast) < _BLOCK_SHARE * n:
            handle_each(self.handle_line, first, lines, bad_row)
            return
        begin = 0
        for slow in [*np.flatnonzero(~fast).tolist(), n]:
            if slow > begin:
                self._take_block(begin, slow, parsed, clock_t, is_wifi)
            if slow < n:
                handle_each(self.handle_line, first + slow, [lines[slow]], bad_row)
            begin = slow + 1

    def _take_block(self, begin: int, end: int, parsed: dict, clock_t: np.ndarray, is_wifi: np.ndarray) -> None:
        """The fast lines ``begin .. end - 1`` (all good records), as line by line."""
        take_block(parsed, begin, end, self._report, self._take_records, "TYPE_WIFI", self._scans, clock_t, is_wifi,
                   self._clock, _FOLLOWED)

    def _take_records(self, kind: str, records, kept: np.ndarray) -> None:
        """A block's records of one kind; ``kept``: each one is on the log's clock (``take_block``)."""
        if kind in _VECTOR_TYPES:
            self._vectors[_VECTOR_TYPES[kind][0]].append(records[kept])
        elif kind == "TYPE_PRESSURE":
            self._pressure.append(records[kept])
        elif kind == "TYPE_WAYPOINT":
            for record in records:
                self._waypoints.add(record[0], record)
        elif kind == "TYPE_BEACON":
            for record, k in zip(records, kept.tolist()):
                if k:
                    self._beacons.add(record[0], record)

    def take(self, final: bool) -> Recording:
        vectors = {}
        for name, order in self._vector_order.items():
            rows = order.accept(_table(self._vectors[name], 4), final)
            self._vectors[name] = []
            vectors[name] = rows[:, 0].copy(), rows[:, 1:].copy()
        baro = self._pressure_order.accept(_table(self._pressure, 2), final)
        self._pressure = []
        waypoints = self._waypoints.take(final)
        wp = np.array([w[:3] for w in waypoints], dtype=np.float64).reshape(-1, 3)
        floors = [w[3] for w in waypoints]
        beacons = self._beacons.take(final)
        scans = self._scans.take(final)
        beacon_t = np.array([b[0] for b in beacons], dtype=np.float64)
        self._gaps.add([t for t, _ in vectors.values()] + [wp[:, 0], baro[:, 0], [scan[0][0] for scan in scans],
                                                           beacon_t])
        start_ms = self._header.get("startTime")
        # the streams the filter merges by time: what it must wait for (the magnetometer and the
        # ground truth it does not read)
        pending = math.inf if final else min(
            [self._vector_order[name].pending_t for name in ("acc", "gyro", "rotvec")]
            + [self._pressure_order.pending_t, self._beacons.pending_t, self._scans.pending_t])
        return Recording(
            path=self._report.path,
            floor_name=self._header.get("FloorName") or None,
            start_t_s=float(start_ms) / 1000.0 if start_ms and start_ms.isdigit() else None,
            waypoint_t_s=wp[:, 0].copy(), waypoint_xy_m=wp[:, 1:3].copy(),
            acc_t_s=vectors["acc"][0], acc_mps2=vectors["acc"][1],
            gyro_t_s=vectors["gyro"][0], gyro_radps=vectors["gyro"][1],
            magnet_t_s=vectors["magnet"][0], magnet_ut=vectors["magnet"][1],
            rotvec_t_s=vectors["rotvec"][0], rotvec_xyz=vectors["rotvec"][1],
            wifi=group_scans([row for scan in scans for row in scan], self._max_wifi_age_s),
            beacons=Beacons(t_s=beacon_t, beacon_id=[b[1] for b in beacons],
                            rssi_dbm=np.array([b[2] for b in beacons], dtype=np.float32),
                            distance_m=np.array([b[3] for b in beacons], dtype=np.float32)),
            pressure_t_s=baro[:, 0].copy(), pressure_hpa=baro[:, 1].copy(),
            waypoint_floor=floors if floors and None not in floors else None,
            phone_model=self._header.get("Model") or None,
            pending_t_s=pending,
        )

    def _on_clock(self, kind: str, t_s: float) -> bool:
        """One record of a followed sensor on the log's clock (``LogClock``): whether it is kept
        (WiFi rows only move the clock; their scans' own rule decides)."""
        return on_log_clock(self._clock, self._report, kind, _FOLLOWED[kind], t_s, kind != "TYPE_WIFI")

    def _count(self, kind: str | None) -> None:
        report = self._report
        if kind is None:
            report.unknown_rows += 1
        else:
            report.rows[kind] = report.rows.get(kind, 0) + 1

    def _parse_record(self, fields: list[str]) -> str | None:
        """Take one record; return its type (None: unknown type). Raises ``BadRow``."""
        if len(fields) < 2:
            raise BadRow("?", "malformed line: expected a time and a record type")
        kind = fields[1]
        if kind in _VECTOR_TYPES:
            name, quantity = _VECTOR_TYPES[kind]
            t_ms = quick_numbers(fields, range(0, 1), "unix_ms")
            values = quick_numbers(fields, range(2, 5), quantity)
            if t_ms is not None and values is not None:  # the fast path: a good row
                t_s = t_ms[0] / 1000.0
            else:
                t_s = _time_s(fields)
                values = [check_range(kind, axis, parse_number(kind, fields, column), quantity)
                          for axis, column in (("x", 2), ("y", 3), ("z", 4))]
            if kind not in _FOLLOWED or self._on_clock(kind, t_s):
                self._vectors[name].append(np.array([[t_s, *values]], dtype=np.float64))
            self._scans.clock(t_s)
            return kind
        if kind == "TYPE_WIFI":
            if len(fields) < 7:
                raise BadRow(kind, f"malformed TYPE_WIFI line: {len(fields)} fields, expected 7")
            t_ms = check_range(kind, "time", parse_number(kind, fields, 0), "unix_ms")
            rssi = check_range(kind, "RSSI", parse_number(kind, fields, 4), "rssi_dbm")
            freq = check_range(kind, "frequency", parse_number(kind, fields, 5), "freq_mhz")
            seen_ms = check_range(kind, "last-seen time", parse_number(kind, fields, 6), "unix_ms")
            bssid = fields[3].strip()
            if not bssid:
                raise BadRow(kind, "malformed TYPE_WIFI line: empty BSSID")
            t_s = t_ms / 1000.0
            log_t = self._clock.newest_t
            self._on_clock(kind, t_s)  # a scan's own rule decides whether it went back (ScanAssembler)
            self._scans.add(t_s, (t_s, bssid, rssi, freq, (t_ms - seen_ms) / 1000.0), log_t)
            return kind
        if kind == "TYPE_WAYPOINT":
            t_s = _time_s(fields)
            x, y = (check_range(kind, name, parse_number(kind, fields, column), "position_m")
                    for name, column in (("x", 2), ("y", 3)))
            floor = fields[4].strip() if len(fields) > 4 and fields[4].strip() else None  # a walk over floors
            self._waypoints.add(t_s, (t_s, x, y, floor))
        elif kind == "TYPE_PRESSURE":
            t_s = _time_s(fields)
            hpa = check_range(kind, "pressure", parse_number(kind, fields, 2), "pressure_hpa")
            if self._on_clock(kind, t_s):
                self._pressure.append(np.array([[t_s, hpa]], dtype=np.float64))
        elif kind == "TYPE_BEACON":
            if len(fields) < 8:
                raise BadRow(kind, f"malformed TYPE_BEACON line: {len(fields)} fields, expected 10")
            t_s = _time_s(fields)
            rssi = check_range(kind, "RSSI", parse_number(kind, fields, 6), "rssi_dbm")
            distance = check_range(kind, "distance", parse_number(kind, fields, 7), "distance_m")
            if self._on_clock(kind, t_s):
                self._beacons.add(t_s, (t_s, _beacon_id(fields), rssi, distance))
        else:
            return None  # other record types are skipped
        self._scans.clock(t_s)
        return kind


def _beacon_id(fields: list[str]) -> str:
    """A TYPE_BEACON row's beacon: its MAC (the site-1 beacons share one uuid:major:minor), else
    ``uuid:major:minor``."""
    mac = fields[8].strip() if len(fields) > 8 else ""
    return mac.upper() if _MAC.fullmatch(mac) else f"{fields[2]}:{fields[3]}:{fields[4]}"


def _table(pieces: list[np.ndarray], width: int) -> np.ndarray:
    """Row tables (each (rows, width)) one under the other."""
    return np.concatenate(pieces) if pieces else np.zeros((0, width))


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


def _time_s(fields: list[str]) -> float:
    """The record's time (column 1, Unix ms) in seconds, checked for a plausible date."""
    kind = fields[1]
    return check_range(kind, "time", parse_number(kind, fields, 0), "unix_ms") / 1000.0
