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
- ``BLE4`` Bluetooth LE beacons, named by their MAC in upper case (iBeacon and Eddystone alike;
  no distance estimate: ``distance_m`` is NaN);
- ``POSI`` the ground truth: time, latitude, longitude and floor id of each marked point
  (``waypoint_latlon_deg``, ``waypoint_floor``; ``waypoint_xy_m`` stays NaN until the walk is
  placed in a georeferenced building: ``sensors/logs.localise``);
- the header's phone model; other record types (``GNSS``, ``LIGH``, ``SOUN``, ...) are skipped.

Time base. Every record has an AppTimestamp (s since the log started, set when the app read
the sample: one clock for all sensors); sensor records also have the sensor's own timestamp
(s since the phone booted, exact sample intervals, but an epoch of its own). The recording's
times are Unix seconds: the header's creation date plus the AppTimestamp (0 plus it when the
header has no date), so WiFi, ground truth and IMU share one clock as in an ILC log. IMU and
barometer samples are placed on it by their sensor timestamp plus that stream's median
(AppTimestamp - SensorTimestamp): the app reads samples in bursts (AppTimestamp intervals
scatter by 5-9 ms around 20 ms on the IPIN 2023 logs, the sensor's by under 1 ms), and the
median latency is a few ms. A sample whose sensor time strays more than
:data:`MAX_CLOCK_DISAGREEMENT_S` from its AppTimestamp (a clock reset) keeps its AppTimestamp.
A WiFi row's age is its scan's AppTimestamp minus its sensor timestamp (the last-seen time on
the boot clock, moved by the accelerometer's offset); rows older than ``max_wifi_age_s`` are
stale cached results and are dropped as in the ILC reader.

Bad rows are handled as by the ILC reader (``sensors/logread.py``): skipped and counted in
``Recording.read_report``, refused with ``strict`` when their type is needed; values outside
their physical range are bad rows; exact duplicates are kept once; time gaps are reported.
"""

from __future__ import annotations

import datetime as dt
import os
import re
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.sensors.logread import (BadRow, check_range, check_usable, count_record, drop_duplicate_records,
                                       drop_duplicate_rows, emit_warning, find_time_gaps, group_scans,
                                       iter_bounded_lines, open_binary, parse_number, quick_numbers, read_lines)
from mapfilter.sensors.recording import Beacons, ReadReport, Recording

FORMAT_NAME = "GetSensorData"
DEFAULT_MAX_WIFI_AGE_S = 5.0  # as for ILC logs
# what tracking, evaluation and radio maps read (the magnetometer and the beacons no stage uses)
NEEDED_TYPES = frozenset({"POSI", "ACCE", "GYRO", "AHRS", "WIFI", "PRES"})
# a sensor timestamp further than this from its AppTimestamp (after the stream's offset) is not trusted
MAX_CLOCK_DISAGREEMENT_S = 1.0
# WiFi ages whose median over the log falls outside this range mean the WiFi sensor timestamps
# are on another clock than the IMU's: the ages are unknown (0) and no row is dropped as stale
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
_RECORD = re.compile(r"[A-Z][A-Z0-9]{3};")


def looks_like_getsensordata(line: str) -> bool:
    """True for a line only a GetSensorData log has: its header or a ``TYPE;`` record."""
    return ("GetSensorData" in line and line.startswith("%")) or bool(_RECORD.match(line))


def read_ipin(path: str | os.PathLike, max_wifi_age_s: float = DEFAULT_MAX_WIFI_AGE_S, *,
              strict: bool = False, needed: Iterable[str] = NEEDED_TYPES,
              warn: Callable[[str], None] | None = None) -> Recording:
    """Read one GetSensorData log into a ``Recording`` (see the module docstring).

    Bad rows of a type outside ``needed`` are always skipped; bad rows of a needed type,
    over-long lines and a truncated gzip stream are skipped unless ``strict``, which refuses
    them with a ``MapfilterError`` naming the file and line. When anything was skipped or a
    time gap found, the one-line warning goes to ``warn`` if given, else to ``warnings.warn``.
    """
    path = Path(path)
    if not path.is_file():
        raise MapfilterError("file not found", path)
    report = ReadReport(path=path, needed=frozenset(needed), format=FORMAT_NAME)
    sensors: dict[str, list[tuple[float, ...]]] = {name: [] for name, _, _ in _SENSOR_TYPES.values()}
    wifi_rows: list[tuple[float, str, float, float, float]] = []  # app_s, bssid, rssi, freq, sensor_s
    beacon_rows: list[tuple[float, str, float, float]] = []
    posi_rows: list[tuple[float, float, float, str]] = []  # app_s, lat, lon, floor
    header: list[str] = []

    def handle_line(line_no: int, line: str) -> None:
        if not line.strip():
            return
        if line.startswith("%"):
            header.append(line)
            return
        count_record(report, lambda: _parse_record(line.split(";"), sensors, wifi_rows, beacon_rows, posi_rows),
                     line_no, strict, path)

    read_lines(path, report, strict, handle_line)
    check_usable(report, path)
    info = parse_header(header)
    base_s = info.get("start_t_s", 0.0)

    streams = {}
    offsets = {}
    for kind, (name, _, n_values) in _SENSOR_TYPES.items():
        # (app_s, sensor_s, values...) -> duplicates dropped -> (t_s, values) on the common clock
        rows = drop_duplicate_rows(np.array(sensors[name], dtype=np.float64).reshape(-1, 2 + n_values), report, kind)
        t_s, offsets[kind] = _common_clock(rows[:, 0], rows[:, 1])
        order = np.argsort(t_s, kind="stable")
        streams[name] = (base_s + t_s[order], rows[order, 2:])
    wifi_rows = drop_duplicate_records(wifi_rows, report, "WIFI")
    beacon_rows = drop_duplicate_records(beacon_rows, report, "BLE4")
    posi_rows = drop_duplicate_records(posi_rows, report, "POSI")
    posi_rows.sort(key=lambda r: r[0])
    wifi = group_scans(_wifi_with_ages(wifi_rows, offsets.get("ACCE"), base_s), max_wifi_age_s)
    waypoint_t = np.array([base_s + r[0] for r in posi_rows], dtype=np.float64)
    latlon = np.array([[r[1], r[2]] for r in posi_rows], dtype=np.float64).reshape(-1, 2)
    floors = [r[3] for r in posi_rows]
    find_time_gaps([t for t, _ in streams.values()] + [waypoint_t, base_s + np.array([r[0] for r in wifi_rows]),
                                                       base_s + np.array([r[0] for r in beacon_rows])], report)
    emit_warning(report, warn)
    return Recording(
        path=path,
        floor_name=floors[0] if floors and len(set(floors)) == 1 else None,
        start_t_s=info.get("start_t_s"),
        waypoint_t_s=waypoint_t,
        waypoint_xy_m=np.full((len(posi_rows), 2), np.nan),
        acc_t_s=streams["acc"][0], acc_mps2=streams["acc"][1],
        gyro_t_s=streams["gyro"][0], gyro_radps=streams["gyro"][1],
        magnet_t_s=streams["magnet"][0], magnet_ut=streams["magnet"][1],
        rotvec_t_s=streams["rotvec"][0], rotvec_xyz=streams["rotvec"][1],
        wifi=wifi,
        beacons=Beacons(t_s=np.array([base_s + r[0] for r in beacon_rows], dtype=np.float64),
                        beacon_id=[r[1] for r in beacon_rows],
                        rssi_dbm=np.array([r[2] for r in beacon_rows], dtype=np.float32),
                        distance_m=np.full(len(beacon_rows), np.nan, dtype=np.float32)),
        read_report=report,
        pressure_t_s=streams["pressure"][0], pressure_hpa=streams["pressure"][1][:, 0],
        waypoint_floor=floors or None,
        waypoint_latlon_deg=latlon if posi_rows else None,
        phone_model=info.get("Model"),
    )


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
        text = line.lstrip("%").strip()
        key, sep, value = text.partition(":")
        key, value = key.strip(), value.strip()
        if not sep or not value or "'" in text or not re.fullmatch(r"[A-Za-z][A-Za-z ]*", key):
            continue  # the record-format lines ("Accelerometer data: 'ACCE;...'") are not fields
        if key == "Date of creation":
            start = _creation_time_s(value)
            if start is not None:
                info.setdefault("start_t_s", start)
            continue
        info.setdefault(key, value)
    return info


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


def _common_clock(app_s: np.ndarray, sensor_s: np.ndarray) -> tuple[np.ndarray, float | None]:
    """Times of one sensor stream on the AppTimestamp clock: sensor time + the stream's median
    (app - sensor), except where that disagrees with the AppTimestamp by more than
    ``MAX_CLOCK_DISAGREEMENT_S``. Returns the times and the offset (None: no rows)."""
    if app_s.size == 0:
        return app_s.copy(), None
    offset = float(np.median(app_s - sensor_s))
    t_s = sensor_s + offset
    stray = np.abs(t_s - app_s) > MAX_CLOCK_DISAGREEMENT_S
    t_s[stray] = app_s[stray]
    return t_s, offset


def _wifi_with_ages(rows: list[tuple[float, str, float, float, float]], boot_offset_s: float | None,
                    base_s: float) -> list[tuple[float, str, float, float, float]]:
    """(t_s, bssid, rssi, freq, age_s) rows: age = scan AppTimestamp - last-seen time on the app clock."""
    if not rows:
        return []
    ages = np.zeros(len(rows))
    if boot_offset_s is not None:
        ages = np.array([app - (sensor + boot_offset_s) for app, _, _, _, sensor in rows])
        low, high = _PLAUSIBLE_MEDIAN_WIFI_AGE_S
        if not low <= float(np.median(ages)) <= high:
            ages[:] = 0.0  # another clock: the ages are unknown
    return [(base_s + app, bssid, rssi, freq, float(age)) for (app, bssid, rssi, freq, _), age in zip(rows, ages)]


def _floor_id(text: str) -> str:
    """A floor id as the venue writes it, integers normalised ("00" -> "0", "-02" -> "-2")."""
    text = text.strip()
    try:
        return str(int(text))
    except ValueError:
        return text


def _parse_record(fields: list[str], sensors, wifi_rows, beacon_rows, posi_rows) -> str | None:
    """Append one record to its list; return its type (None: a type not read). Raises ``BadRow``."""
    kind = fields[0].strip()
    if kind in _SENSOR_TYPES:
        name, quantity, n_values = _SENSOR_TYPES[kind]
        first = 6 if kind == "AHRS" else 3
        app = quick_numbers(fields, range(1, 2), "log_s")
        sensor = quick_numbers(fields, range(2, 3), "sensor_s")
        values = quick_numbers(fields, range(first, first + n_values), quantity)
        if app is not None and sensor is not None and values is not None and (
                kind != "AHRS" or values[0] ** 2 + values[1] ** 2 + values[2] ** 2 <= 1.0 + 1e-3):
            sensors[name].append((app[0], sensor[0], *values))  # the fast path: a good row
            return kind
        app_s = _app_time(kind, fields)
        sensor_s = check_range(kind, "SensorTimestamp", parse_number(kind, fields, 2), "sensor_s")
        values = [check_range(kind, _AXES[j] if n_values > 1 else quantity.split("_")[0],
                              parse_number(kind, fields, first + j), quantity) for j in range(n_values)]
        if kind == "AHRS" and values[0] ** 2 + values[1] ** 2 + values[2] ** 2 > 1.0 + 1e-3:
            raise BadRow(kind, "AHRS quaternion out of range: x^2 + y^2 + z^2 > 1 (not a unit quaternion)")
        sensors[name].append((app_s, sensor_s, *values))
    elif kind == "WIFI":
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
        wifi_rows.append((app_s, bssid, rssi, freq, sensor_s))
    elif kind == "BLE4":
        if len(fields) < 5:
            raise BadRow(kind, f"malformed BLE4 line: {len(fields)} fields, expected at least 5")
        app_s = _app_time(kind, fields)
        rssi = check_range(kind, "RSSI", parse_number(kind, fields, 4), "rssi_dbm")
        beacon_rows.append((app_s, fields[3].strip().upper(), rssi, np.nan))  # iBeacon or Eddystone: its MAC
    elif kind == "POSI":
        if len(fields) < 6:
            raise BadRow(kind, f"malformed POSI line: {len(fields)} fields, expected 7")
        app_s = _app_time(kind, fields)
        lat = check_range(kind, "latitude", parse_number(kind, fields, 3), "latitude_deg")
        lon = check_range(kind, "longitude", parse_number(kind, fields, 4), "longitude_deg")
        floor = _floor_id(fields[5])
        if not floor:
            raise BadRow(kind, "malformed POSI line: empty floor id")
        posi_rows.append((app_s, lat, lon, floor))
    elif _RECORD.match(kind + ";"):
        return None  # GNSS, LIGH, SOUN, PROX, ...: not read
    else:
        raise BadRow("?", f"malformed line: expected a record type such as ACCE; or WIFI;, got {kind[:20]!r}")
    return kind


def _app_time(kind: str, fields: list[str]) -> float:
    return check_range(kind, "AppTimestamp", parse_number(kind, fields, 1), "log_s")
