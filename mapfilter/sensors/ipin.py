"""Reader for GetSensorData logs (the IPIN competitions' smartphone logger), plain or gzip.

One record per line, fields separated by ``;``, comment lines start with ``%`` (the header
names the phone and spells out every record type)::

    ACCE;0.0448;2558.6338;-1.13967;6.03836;6.58426;3
    AHRS;0.0456;2558.6338;38.443356;6.974803;-157.526794;0.12037100;-0.31112301;-0.92053300;3
    WIFI;1.2635;2559.8518;SSID2023_0006;20:23:00:00:00:90;2437;-75
    POSI;60.4451;1;49.460948188642;11.110539036217;0;100

What is read, into the same ``Recording`` the ILC reader makes:

- ``ACCE`` accelerometer (m/s^2), ``GYRO`` gyroscope (rad/s), ``MAGN`` magnetometer (uT);
- ``AHRS`` the phone's orientation: its last three numbers are x, y, z of the unit quaternion
  of Android's rotation vector (device -> East-North-Up, w >= 0 implied), exactly what
  ``Recording.rotvec_xyz`` holds (the pitch, roll and yaw before them are not needed);
- ``PRES`` the barometer (mbar = hPa);
- ``WIFI`` one row per access point heard; the rows of one scan share their AppTimestamp, so a
  scan is the rows of one AppTimestamp, keyed ``bssid@2.4`` / ``bssid@5`` as everywhere;
- ``BLE4`` Bluetooth LE beacons (iBeacon and Eddystone), each named by its MAC in upper case
  (``BE:AC:20:23:00:01``), kept for whoever uses them (no distance estimate: ``distance_m`` is NaN);
- ``POSI`` the ground truth: time, latitude, longitude and floor id of each marked point
  (``waypoint_latlon_deg``, ``waypoint_floor``; ``waypoint_xy_m`` stays NaN until the walk is
  placed in a georeferenced building: ``sensors/logs.localise``);
- the header's phone model; other record types (``GNSS``, ``LIGH``, ``SOUN``, ...) are skipped.

Time base. Every record has an AppTimestamp (s since the log started, set when the app read
the sample: one clock for all sensors); sensor records also have the sensor's own timestamp
(s since the phone booted, exact sample intervals, but an epoch of its own). The recording's
times are Unix seconds: the header's creation date plus the AppTimestamp (0 plus it when the
header has no date), so WiFi, ground truth and IMU share one clock as in an ILC log. IMU and
barometer samples are placed on it by their sensor timestamp plus that stream's offset, the
median (AppTimestamp - SensorTimestamp) over its records in the log's first
:data:`CLOCK_WINDOW_S` (from the log's first record; a stream that starts later: its own first
0.5 s). The app reads samples in bursts (AppTimestamp intervals scatter by 5-9 ms around 20 ms
on the IPIN 2023 logs, the sensor's by under 1 ms), and the median latency is a few ms; over
0.5 s it is within 7 ms of the whole log's median. A sample whose sensor time strays more than
:data:`MAX_CLOCK_DISAGREEMENT_S` from its AppTimestamp (a clock reset) keeps its AppTimestamp
(counted: ``ReadReport.clock_strays``). A WiFi row's age is its scan's AppTimestamp minus its
sensor timestamp (the last-seen time on the boot clock, moved by the accelerometer's offset);
when a scan's median age is implausible its ages are unknown (0); rows older than
``max_wifi_age_s`` are stale cached results and are dropped as in the ILC reader.

The reader is a stream (:class:`GsdParser`, fed by ``sensors/logs.LogStream``): it holds
every record until the log's AppTimestamp passes its first record's by 0.5 s (the offsets and
the time base are then known), a WiFi scan until a record of a later AppTimestamp comes.

Bad rows are handled as by the ILC reader (``sensors/logread.py``): skipped and counted in
``Recording.read_report``, refused with ``strict`` when their type is needed; values outside
their physical range are bad rows; each record type keeps file order (a record earlier than the
previous kept one of its type is dropped), exact repeats are kept once; time gaps are reported.
"""

from __future__ import annotations

import datetime as dt
import math
import os
import re
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.sensors.logread import (MAX_CLOCK_DISAGREEMENT_S, BadRow, GapTracker, LogClock, RecordStream,
                                       ScanAssembler, TimeOrder, check_range, group_scans, handle_each,
                                       iter_bounded_lines, on_log_clock, open_binary, parse_columns, parse_number,
                                       quick_numbers, read_whole, split_by, take_block)
from mapfilter.sensors.recording import Beacons, ReadReport, Recording

FORMAT_NAME = "GetSensorData"
DEFAULT_MAX_WIFI_AGE_S = 5.0  # as for ILC logs
# what tracking, evaluation and radio maps read (the magnetometer and the beacons no stage uses)
NEEDED_TYPES = frozenset({"POSI", "ACCE", "GYRO", "AHRS", "WIFI", "PRES"})
# each sensor stream's clock offset is the median over its records in the log's first 0.5 s: on the
# 29 IPIN 2023 logs within 7 ms of the whole log's median (1.4 ms median)
CLOCK_WINDOW_S = 0.5
# WiFi ages whose median over a scan falls outside this range mean the WiFi sensor timestamps
# are on another clock than the IMU's: the scan's ages are unknown (0) and no row is dropped as stale
_PLAUSIBLE_MEDIAN_WIFI_AGE_S = (-1.0, 10.0)

# record type -> (name of the sensor list, physical quantity of its values, number of values)
_SENSOR_TYPES = {
    "ACCE": ("acc", "acc_mps2", 3),
    "GYRO": ("gyro", "gyro_radps", 3),
    "MAGN": ("magnet", "magnet_ut", 3),
    "AHRS": ("rotvec", "quaternion", 3),  # columns 7-9: the quaternion's x, y, z (pitch/roll/yaw skipped)
    "PRES": ("pressure", "pressure_hpa", 1),
}
_AXES = ("x", "y", "z")
# The sensors the causal filter merges by time (filter/causal.py): on the log's clock (``LogClock``)
_FOLLOWED = {kind: k for k, kind in enumerate(("ACCE", "GYRO", "AHRS", "PRES", "WIFI", "BLE4"))}
_RECORD = re.compile(r"[A-Z][A-Z0-9]{3};")
# What the block parse reads of each record type as numbers (AppTimestamp first) and their
# quantities (logread.RANGES), as the line parse reads them
_NUMBER_COLUMNS = {
    **{kind: ((1, 2, *range(6 if kind == "AHRS" else 3, (6 if kind == "AHRS" else 3) + n_values)),
              ("log_s", "sensor_s", *[quantity] * n_values)) for kind, (_, quantity, n_values) in _SENSOR_TYPES.items()},
    "WIFI": ((1, 2, 5, 6), ("log_s", "sensor_s", "freq_mhz", "rssi_dbm")),
    "BLE4": ((1, 4), ("log_s", "rssi_dbm")),
}
# Below this share of lines the block parse takes, a block is read line by line (the same records)
_BLOCK_SHARE = 0.9


def looks_like_getsensordata(line: str) -> bool:
    """True for a line only a GetSensorData log has: its header or a ``TYPE;`` record."""
    return ("GetSensorData" in line and line.startswith("%")) or bool(_RECORD.match(line))


def read_ipin(path: str | os.PathLike, max_wifi_age_s: float = DEFAULT_MAX_WIFI_AGE_S, *,
              strict: bool = False, needed: Iterable[str] = NEEDED_TYPES,
              warn: Callable[[str], None] | None = None) -> Recording:
    """Read one GetSensorData log into a ``Recording`` (see the module docstring).

    The log is streamed (``logread.RecordStream`` with :class:`GsdParser`, what
    ``sensors/logs.LogStream`` does for a GetSensorData log) and the pieces joined: the result
    is the replay of the log as a stream. Bad rows of a type outside ``needed`` are always
    skipped; bad rows of a needed type, over-long lines and a truncated gzip stream are skipped
    unless ``strict``, which refuses them with a ``MapfilterError`` naming the file and line.
    When anything was skipped or a time gap found, the one-line warning goes to ``warn`` if
    given, else to ``warnings.warn``.
    """
    stream = RecordStream(path, max_wifi_age_s, strict, needed, GsdParser)
    return read_whole(path, stream, warn)


class GsdParser:
    """GetSensorData lines -> the records of a ``Recording``, in the order they come (the parser
    a ``logread.RecordStream`` feeds).

    Every record is held until the log's AppTimestamp passes its first record's by
    :data:`CLOCK_WINDOW_S`: each sensor stream's clock offset is the median (AppTimestamp -
    SensorTimestamp) of its records so far, and the creation date of the header read so far is
    the time base. A stream whose first record comes later holds its records for
    :data:`CLOCK_WINDOW_S` from it, for the same median. A WiFi scan is complete once a record
    of a later AppTimestamp comes.
    """

    FORMAT_NAME = FORMAT_NAME
    NEEDED_TYPES = NEEDED_TYPES

    def __init__(self, report: ReadReport, max_wifi_age_s: float, strict: bool):
        self._report = report
        self._max_wifi_age_s = max_wifi_age_s
        # rows not yet placed on the app clock, per sensor list, as tables of rows (app_s, sensor_s, values...)
        self._raw: dict[str, list[np.ndarray]] = {name: [] for name, _, _ in _SENSOR_TYPES.values()}
        self._order = {name: TimeOrder(report, kind) for kind, (name, _, _) in _SENSOR_TYPES.items()}
        self._offset_s: dict[str, float] = {}  # each sensor stream's (app - sensor) once known
        self._window_end_s: dict[str, float] = {}  # streams that began late -> end of their own window
        self._waiting: set[str] = set()  # streams without a record when the log's window ended
        self._log_window_end_s: float | None = None  # None: no record yet
        self._next_end_s = -math.inf  # the earliest end of a window still open (-inf: no record yet)
        self._released = False  # the log's window has ended: records go out
        self._wifi = ScanAssembler(report, "WIFI")  # rows (app_s, bssid, rssi, freq, sensor_s)
        self._clock = LogClock()  # the newest AppTimestamp of the sensors the filter follows
        self._wifi_offset_s: float | None = None  # the accelerometer's: WiFi last-seen times are on its clock
        self._posi = TimeOrder(report, "POSI")  # records (app_s, lat, lon, floor)
        self._beacons = TimeOrder(report, "BLE4")  # records (app_s, MAC, rssi)
        self._floors: list[str] = []  # the distinct floors of the ground truth so far
        self._info: dict[str, str | float] = {}  # the header's fields so far
        self._base_s = 0.0  # Unix seconds of AppTimestamp 0 (the header's creation date, if any)
        self._start_t_s: float | None = None
        self._gaps = GapTracker(report)

    def handle_line(self, line_no: int, line: str) -> None:
        if not line.strip():
            return
        if line.startswith("%"):
            _read_header_line(line, self._info)
            return
        kind = self._parse_record(line.split(";"))
        report = self._report
        if kind is None:
            report.unknown_rows += 1
        else:
            report.rows[kind] = report.rows.get(kind, 0) + 1

    def handle_lines(self, first: int, lines: list[str | None], bad_row) -> None:
        """Lines ``first``, ``first + 1``, ...: what :meth:`handle_line` does to each in turn. The
        lines that hold one good record of a type read in bulk (the sensors, WiFi, BLE4 and the
        types not read; every number read and in range) are parsed together per record type; the
        others (headers, blank or bad lines, POSI), and a record that ends a clock window or
        begins a late stream, go through :meth:`handle_line` in their place in the order."""
        fast, app_t, is_wifi, parsed = _parse_block(lines)
        if np.count_nonzero(fast) < _BLOCK_SHARE * len(lines):
            handle_each(self.handle_line, first, lines, bad_row)
            return
        self._take_in_order(first, lines, bad_row, fast, app_t, is_wifi, parsed)

    def _take_in_order(self, first: int, lines: list[str | None], bad_row, fast: np.ndarray, app_t: np.ndarray,
                       is_wifi: np.ndarray, parsed: dict) -> None:
        """The block's lines in their order: runs of fast lines taken together, each slow line, and
        each record that ends a clock window or begins a late stream, line by line."""
        n = len(lines)
        stream = np.full(n, -1)  # a sensor record's stream (its place in _SENSOR_TYPES)
        for j, kind in enumerate(_SENSOR_TYPES):
            if kind in parsed:
                stream[parsed[kind][0]] = j
        begin = 0
        for slow in [*np.flatnonzero(~fast).tolist(), n]:
            while begin < slow:
                # the next record that ends a window (or the log's first) or begins a late stream
                event = app_t[begin:slow] > self._next_end_s
                if self._waiting:
                    event |= np.isin(stream[begin:slow], [j for j, (name, _, _) in enumerate(_SENSOR_TYPES.values())
                                                          if name in self._waiting])
                end = begin + int(np.argmax(event)) if event.any() else slow
                if end > begin:
                    self._take_block(begin, end, parsed, app_t, is_wifi)
                if end < slow:
                    handle_each(self.handle_line, first + end, [lines[end]], bad_row)
                    end += 1
                begin = end
            if slow < n:
                handle_each(self.handle_line, first + slow, [lines[slow]], bad_row)
            begin = slow + 1

    def _take_block(self, begin: int, end: int, parsed: dict, app_t: np.ndarray, is_wifi: np.ndarray) -> None:
        """The fast lines ``begin .. end - 1`` (good records; none ends a window), as line by line."""
        take_block(parsed, begin, end, self._report, self._take_records, "WIFI", self._wifi, app_t, is_wifi,
                   self._clock, _FOLLOWED)

    def _take_records(self, kind: str, records, kept: np.ndarray) -> None:
        """A block's records of one kind; ``kept``: each one is on the log's clock (``take_block``)."""
        if kind in _SENSOR_TYPES:
            self._raw[_SENSOR_TYPES[kind][0]].append(records[kept])
        elif kind == "BLE4":
            for record, k in zip(records, kept.tolist()):
                if k:
                    self._beacons.add(record[0], record)

    def take(self, final: bool) -> Recording:
        if final:
            self._end_windows()
        if not self._released:  # everything is held
            chunk = Recording.empty(self._report.path)
            chunk.phone_model = self._phone_model()
            return chunk
        base_s = self._base_s
        streams = {}
        for kind, (name, _, n_values) in _SENSOR_TYPES.items():
            offset_s = self._offset_s.get(name)
            rows = []
            if offset_s is not None:  # else the stream is still in its own window: it keeps its rows
                rows, self._raw[name] = self._raw[name], []
            raw = np.concatenate(rows) if rows else np.zeros((0, 2 + n_values))
            t_s = self._place(kind, raw, offset_s) if rows else raw[:, 0]
            # (t_s on the app clock, app_s, sensor_s, values...): ordered by t_s, repeats by every column
            placed = self._order[name].accept(np.column_stack([t_s, raw]), final)
            streams[name] = base_s + placed[:, 0], placed[:, 3:].copy()
        scans = self._wifi.take(final)
        wifi_rows = [row for scan in scans for row in self._with_ages(scan)]
        posi = self._posi.take(final)
        beacons = self._beacons.take(final)
        for floor in (r[3] for r in posi):
            if floor not in self._floors:
                self._floors.append(floor)
        waypoint_t = np.array([base_s + r[0] for r in posi], dtype=np.float64)
        beacon_t = np.array([base_s + r[0] for r in beacons], dtype=np.float64)
        self._gaps.add([t for t, _ in streams.values()] + [waypoint_t, [base_s + scan[0][0] for scan in scans],
                                                           beacon_t])
        floors = [r[3] for r in posi]
        # the streams the filter merges by time: what it must wait for (a stream still in its own
        # clock window holds rows whose placed times lie within MAX_CLOCK_DISAGREEMENT_S of their app times)
        pending = math.inf
        if not final:
            held = [np.concatenate(self._raw[name])[:, 0].min() for name in ("acc", "gyro", "rotvec", "pressure")
                    if self._offset_s.get(name) is None and self._raw[name]]
            pending = min([base_s + t - MAX_CLOCK_DISAGREEMENT_S for t in held]
                          + [base_s + self._order[name].pending_t for name in ("acc", "gyro", "rotvec", "pressure")]
                          + [base_s + self._beacons.pending_t, base_s + self._wifi.pending_t])
        return Recording(
            path=self._report.path,
            floor_name=self._floors[0] if len(self._floors) == 1 else None,
            start_t_s=self._start_t_s,
            waypoint_t_s=waypoint_t,
            waypoint_xy_m=np.full((len(posi), 2), np.nan),
            acc_t_s=streams["acc"][0], acc_mps2=streams["acc"][1],
            gyro_t_s=streams["gyro"][0], gyro_radps=streams["gyro"][1],
            magnet_t_s=streams["magnet"][0], magnet_ut=streams["magnet"][1],
            rotvec_t_s=streams["rotvec"][0], rotvec_xyz=streams["rotvec"][1],
            wifi=group_scans(wifi_rows, self._max_wifi_age_s),
            beacons=Beacons(t_s=beacon_t, beacon_id=[r[1] for r in beacons],
                            rssi_dbm=np.array([r[2] for r in beacons], dtype=np.float32),
                            distance_m=np.full(len(beacons), np.nan, dtype=np.float32)),
            pressure_t_s=streams["pressure"][0], pressure_hpa=streams["pressure"][1][:, 0].copy(),
            waypoint_floor=floors or None,
            waypoint_latlon_deg=np.array([[r[1], r[2]] for r in posi], dtype=np.float64) if posi else None,
            phone_model=self._phone_model(),
            pending_t_s=pending,
        )

    def _on_clock(self, kind: str, app_s: float) -> bool:
        """One record of a followed sensor on the log's clock (``logread.LogClock``): whether it is
        kept (WiFi rows only move the clock; their scans' own rule decides)."""
        return on_log_clock(self._clock, self._report, kind, _FOLLOWED[kind], app_s, kind != "WIFI")

    def _phone_model(self) -> str | None:
        model = self._info.get("Model")
        return model if isinstance(model, str) else None

    def _place(self, kind: str, raw: np.ndarray, offset_s: float) -> np.ndarray:
        """Times on the app clock: sensor time + the stream's offset, or the AppTimestamp where
        that disagrees with it by more than ``MAX_CLOCK_DISAGREEMENT_S`` (counted)."""
        app_s, sensor_s = raw[:, 0], raw[:, 1]
        t_s = sensor_s + offset_s
        stray = np.abs(t_s - app_s) > MAX_CLOCK_DISAGREEMENT_S
        if stray.any():
            t_s[stray] = app_s[stray]
            strays = self._report.clock_strays
            strays[kind] = strays.get(kind, 0) + int(np.count_nonzero(stray))
        return t_s

    def _with_ages(self, scan: list[tuple[float, str, float, float, float]]) -> list[tuple[float, str, float, float, float]]:
        """(t_s, bssid, rssi, freq, age_s) rows of one scan: age = the scan's AppTimestamp - the
        row's last-seen time moved to the app clock; unknown (0) when the scan's median age is
        implausible (the WiFi timestamps on another clock) or no accelerometer gave the offset."""
        ages = np.zeros(len(scan))
        if self._wifi_offset_s is not None:
            ages = np.array([app - (sensor + self._wifi_offset_s) for app, _, _, _, sensor in scan])
            low, high = _PLAUSIBLE_MEDIAN_WIFI_AGE_S
            if not low <= float(np.median(ages)) <= high:
                ages[:] = 0.0
        base_s = self._base_s
        return [(base_s + app, bssid, rssi, freq, float(age)) for (app, bssid, rssi, freq, _), age in zip(scan, ages)]

    def _at(self, app_s: float) -> None:
        """A record of AppTimestamp ``app_s`` came: the windows it ends, the log's first record."""
        if self._log_window_end_s is None:
            self._log_window_end_s = self._next_end_s = app_s + CLOCK_WINDOW_S
            return
        if not self._released and app_s > self._log_window_end_s:
            self._release()
        for name, end_s in list(self._window_end_s.items()):
            if app_s > end_s:
                self._offset_s[name] = _median_offset(self._raw[name])
                del self._window_end_s[name]
        self._next_end_s = min(self._window_end_s.values(), default=math.inf)

    def _release(self) -> None:
        """The log's window has ended: the clock offsets of the streams in it, the time base."""
        self._released = True
        for name, rows in self._raw.items():
            if rows:
                self._offset_s[name] = _median_offset(rows)
            else:
                self._waiting.add(name)
        self._wifi_offset_s = self._offset_s.get("acc")
        self._start_t_s = self._info.get("start_t_s")
        self._base_s = self._start_t_s if self._start_t_s is not None else 0.0

    def _end_windows(self) -> None:
        """The log ended: every window ends with what it holds."""
        if not self._released:
            self._release()
        for name in self._window_end_s:
            self._offset_s[name] = _median_offset(self._raw[name])
        self._window_end_s.clear()
        self._next_end_s = math.inf

    def _begin_late_stream(self, name: str, app_s: float) -> None:
        """The first record of a stream that had none in the log's window: its own window."""
        self._waiting.discard(name)
        self._window_end_s[name] = app_s + CLOCK_WINDOW_S
        self._next_end_s = min(self._next_end_s, app_s + CLOCK_WINDOW_S)

    def _parse_record(self, fields: list[str]) -> str | None:
        """Take one record; return its type (None: a type not read). Raises ``BadRow``."""
        kind = fields[0].strip()
        if kind in _SENSOR_TYPES:
            self._take_sensor(kind, fields)
            return kind
        if kind == "WIFI":
            self._take_wifi(fields)
            return kind
        if kind == "BLE4":
            app_s = self._take_ble4(fields)
        elif kind == "POSI":
            app_s = self._take_posi(fields)
        elif _RECORD.match(kind + ";"):
            return None  # GNSS, LIGH, SOUN, PROX, ...: not read
        else:
            raise BadRow("?", f"malformed line: expected a record type such as ACCE; or WIFI;, got {kind[:20]!r}")
        if app_s > self._next_end_s:
            self._at(app_s)
        self._wifi.clock(app_s)
        return kind

    def _take_sensor(self, kind: str, fields: list[str]) -> None:
        """An IMU, magnetometer, pressure or AHRS record: its times and values into its stream."""
        name, quantity, n_values = _SENSOR_TYPES[kind]
        first = 6 if kind == "AHRS" else 3
        app = quick_numbers(fields, range(1, 2), "log_s")
        sensor = quick_numbers(fields, range(2, 3), "sensor_s")
        values = quick_numbers(fields, range(first, first + n_values), quantity)
        if app is not None and sensor is not None and values is not None and (
                kind != "AHRS" or values[0] ** 2 + values[1] ** 2 + values[2] ** 2 <= 1.0 + 1e-3):
            app_s, sensor_s = app[0], sensor[0]  # the fast path: a good row
        else:
            app_s = _app_time(kind, fields)
            sensor_s = check_range(kind, "SensorTimestamp", parse_number(kind, fields, 2), "sensor_s")
            values = [check_range(kind, _AXES[j] if n_values > 1 else quantity.split("_")[0],
                                  parse_number(kind, fields, first + j), quantity) for j in range(n_values)]
            if kind == "AHRS" and values[0] ** 2 + values[1] ** 2 + values[2] ** 2 > 1.0 + 1e-3:
                raise BadRow(kind, "AHRS quaternion out of range: x^2 + y^2 + z^2 > 1 (not a unit quaternion)")
        if app_s > self._next_end_s:
            self._at(app_s)
        if app_s > self._wifi.open_t:
            self._wifi.clock(app_s)
        if name in self._waiting:
            self._begin_late_stream(name, app_s)
        if kind not in _FOLLOWED or self._on_clock(kind, app_s):
            self._raw[name].append(np.array([[app_s, sensor_s, *values]], dtype=np.float64))

    def _take_wifi(self, fields: list[str]) -> None:
        """A WIFI record: a row of its scan."""
        kind = "WIFI"
        while len(fields) > 7 and not fields[-1].strip():
            fields = fields[:-1]  # a trailing ';'
        if len(fields) < 7:
            raise BadRow(kind, f"malformed WIFI line: {len(fields)} fields, expected 7")
        # an SSID may hold ';': BSSID, frequency and RSS are the last three fields
        tail = [fields[0], fields[1], fields[2], fields[-3], fields[-2], fields[-1]]
        app_s = _app_time(kind, tail)
        sensor_s = check_range(kind, "SensorTimestamp", parse_number(kind, tail, 2), "sensor_s")
        freq = check_range(kind, "frequency", parse_number(kind, tail, 4), "freq_mhz")
        rssi = check_range(kind, "RSSI", parse_number(kind, tail, 5), "rssi_dbm")
        bssid = tail[3].strip()
        if not bssid:
            raise BadRow(kind, "malformed WIFI line: empty BSSID")
        if app_s > self._next_end_s:
            self._at(app_s)
        log_t = self._clock.newest_t
        self._on_clock(kind, app_s)  # a scan's own rule decides whether it went back (ScanAssembler)
        self._wifi.add(app_s, (app_s, bssid, rssi, freq, sensor_s), log_t)

    def _take_ble4(self, fields: list[str]) -> float:
        """A BLE4 record (iBeacon and Eddystone alike, by MAC); its AppTimestamp."""
        kind = "BLE4"
        if len(fields) < 5:
            raise BadRow(kind, f"malformed BLE4 line: {len(fields)} fields, expected at least 5")
        app_s = _app_time(kind, fields)
        rssi = check_range(kind, "RSSI", parse_number(kind, fields, 4), "rssi_dbm")
        mac = fields[3].strip().upper()
        if not mac:
            raise BadRow(kind, "malformed BLE4 line: empty MAC")
        if self._on_clock(kind, app_s):
            self._beacons.add(app_s, (app_s, mac, rssi))
        return app_s

    def _take_posi(self, fields: list[str]) -> float:
        """A POSI record (ground truth: latitude, longitude, floor); its AppTimestamp."""
        kind = "POSI"
        if len(fields) < 6:
            raise BadRow(kind, f"malformed POSI line: {len(fields)} fields, expected 7")
        app_s = _app_time(kind, fields)
        lat = check_range(kind, "latitude", parse_number(kind, fields, 3), "latitude_deg")
        lon = check_range(kind, "longitude", parse_number(kind, fields, 4), "longitude_deg")
        floor = _floor_id(fields[5])
        if not floor:
            raise BadRow(kind, "malformed POSI line: empty floor id")
        self._posi.add(app_s, (app_s, lat, lon, floor))
        return app_s


def _parse_block(lines: list[str | None]) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """The lines of a block parsed per record type: (each line is fast: one good record of a type
    read in bulk or not read; each fast line's AppTimestamp, if it moves the clocks; each line is a
    WiFi row; kind -> (its lines, its records, None for a type not read))."""
    kinds = [line[:4] if line is not None and line[4:5] == ";" else "" for line in lines]
    groups = split_by(kinds)
    n = len(lines)
    fast = np.zeros(n, dtype=bool)
    app_t = np.full(n, -np.inf)
    is_wifi = np.zeros(n, dtype=bool)
    parsed: dict[str, tuple[np.ndarray, object]] = {}
    for kind, index in groups.items():
        if kind in _SENSOR_TYPES or kind in ("WIFI", "BLE4"):
            texts = [lines[i] for i in index.tolist()]
            app_s, ok, records = _block_records(kind, texts)
            if kind == "WIFI":
                is_wifi[index] = True
            fast[index[ok]] = True
            app_t[index] = app_s
            parsed[kind] = (index, records)
        elif kind and kind != "POSI" and _RECORD.match(kind + ";"):
            fast[index] = True  # a type not read (GNSS, LIGH, SOUN, ...): counted, nothing else
            parsed[kind] = (index, None)
    return fast, app_t, is_wifi, parsed


def _block_records(kind: str, texts: list[str]) -> tuple[np.ndarray, np.ndarray, object]:
    """The lines of one type read in bulk: (AppTimestamps, each line good, the records: a float
    table of a sensor, WiFi rows, BLE4 readings)."""
    columns, quantities = _NUMBER_COLUMNS[kind]
    values, ok = parse_columns(texts, ";", columns, quantities)
    app_s = values[:, 0]
    if kind in _SENSOR_TYPES:
        if kind == "AHRS":  # a unit quaternion's x, y, z
            ok &= values[:, 2] ** 2 + values[:, 3] ** 2 + values[:, 4] ** 2 <= 1.0 + 1e-3
        return app_s, ok, values
    if kind == "WIFI":
        rows = [text.split(";") for text in texts]
        bssids = [row[4].strip() if len(row) == 7 else "" for row in rows]  # a plain row: 7 fields
        ok &= np.array([bool(b) for b in bssids], dtype=bool)
        return app_s, ok, list(zip(app_s.tolist(), bssids, values[:, 3].tolist(), values[:, 2].tolist(),
                                   values[:, 1].tolist()))
    # BLE4: iBeacon and Eddystone alike, by MAC
    macs = [text.split(";", 4)[3].strip().upper() if ok_i else "" for text, ok_i in zip(texts, ok.tolist())]
    ok &= np.array([bool(m) for m in macs], dtype=bool)
    return app_s, ok, list(zip(app_s.tolist(), macs, values[:, 1].tolist()))


def _median_offset(rows: list[np.ndarray]) -> float:
    """The median (AppTimestamp - SensorTimestamp) of tables of (app_s, sensor_s, ...) rows."""
    raw = np.concatenate(rows)
    return float(np.median(raw[:, 0] - raw[:, 1]))


def read_ipin_header(path: str | os.PathLike) -> dict[str, str]:
    """The header of a GetSensorData log as ``key: value`` strings (``Model``, ``Manufacturer``,
    ``format``), plus ``FloorName`` when every POSI row names the same floor: a look before a
    long run. The header has no floor, so the POSI rows are read (a pass over the file; nothing
    else is kept)."""
    path = Path(path)
    if not path.is_file():
        raise MapfilterError("file not found", path)
    header: list[str] = []
    floors: set[str] = set()
    try:
        with open_binary(path) as handle:
            for _, line in iter_bounded_lines(handle):
                if line is None:
                    continue
                if line.startswith("%"):
                    header.append(line)
                elif line.startswith("POSI;"):
                    fields = line.split(";")
                    if len(fields) > 5:
                        floors.add(_floor_id(fields[5]))
    except EOFError:
        pass  # a cut gzip: what was read before the cut is the header
    except (OSError, ValueError) as exc:
        raise MapfilterError(f"cannot read log: {exc}", path) from None
    info = {k: v for k, v in parse_header(header).items() if isinstance(v, str)}
    info["format"] = FORMAT_NAME
    if len(floors) == 1:
        info["FloorName"] = floors.pop()
    return info


def parse_header(lines: list[str]) -> dict[str, str | float]:
    """``Manufacturer``, ``Model``, ... (``%`` lines of the form ``key: value``) and
    ``start_t_s`` (Unix seconds of the 'Date of creation', when it parses)."""
    info: dict[str, str | float] = {}
    for line in lines:
        _read_header_line(line, info)
    return info


def _read_header_line(line: str, info: dict[str, str | float]) -> None:
    """The field of one ``%`` line into ``info`` (the first value of a key wins)."""
    text = line.lstrip("%").strip()
    key, sep, value = text.partition(":")
    key, value = key.strip(), value.strip()
    if not sep or not value or "'" in text or not re.fullmatch(r"[A-Za-z][A-Za-z ]*", key):
        return  # the record-format lines ("Accelerometer data: 'ACCE;...'") are not fields
    if key == "Date of creation":
        start = _creation_time_s(value)
        if start is not None:
            info.setdefault("start_t_s", start)
        return
    info.setdefault(key, value)


def _creation_time_s(text: str) -> float | None:
    """Unix seconds of e.g. 'Thu Jun 15 10:01:26 GMT+02:00 2023' (Java's Date.toString)."""
    match = re.fullmatch(r"\w{3} (\w{3}) (\d{1,2}) (\d{2}):(\d{2}):(\d{2}) (?:GMT|UTC)?([+-]\d{2}):?(\d{2})? (\d{4})",
                         text.strip())
    if match is None:
        return None
    month, day, hh, mm, ss, tz_h, tz_m, year = match.groups()
    try:
        offset = dt.timedelta(hours=int(tz_h), minutes=int(tz_m or 0) * (1 if int(tz_h) >= 0 else -1))
        when = dt.datetime.strptime(f"{year} {month} {day} {hh}:{mm}:{ss}", "%Y %b %d %H:%M:%S")
        return (when.replace(tzinfo=dt.timezone(offset))).timestamp()
    except ValueError:
        return None


def _floor_id(text: str) -> str:
    """A floor id as the venue writes it, integers normalised ("00" -> "0", "-02" -> "-2")."""
    text = text.strip()
    try:
        return str(int(text))
    except ValueError:
        return text


def _app_time(kind: str, fields: list[str]) -> float:
    return check_range(kind, "AppTimestamp", parse_number(kind, fields, 1), "log_s")
