"""Reader for the Indoor Location Competition (ILC 2.0) trace format, plain or gzip.

Tab-separated records, first column Unix time in ms::

    1574559495263	TYPE_WAYPOINT	81.317215	93.31349
    1574559495401	TYPE_ACCELEROMETER	-0.85	1.82	9.83	2
    1574559497191	TYPE_WIFI	ssid	a8:0c:ca:03:9d:d7	-49	2422	1574559495450

Header lines start with '#'. Unknown record types are skipped; a malformed line of a known
type raises ``MapfilterError`` naming the file and line.
"""

from __future__ import annotations

import gzip
import math
import os
import zlib
from pathlib import Path

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.sensors.recording import Beacons, Recording, WifiScans
from mapfilter.sensors.wifi import ap_key, band_of_frequency

DEFAULT_MAX_WIFI_AGE_S = 5.0

# record type -> (number of numeric value columns after the type, name of the sensor list)
_VECTOR_TYPES = {
    "TYPE_ACCELEROMETER": "acc",
    "TYPE_GYROSCOPE": "gyro",
    "TYPE_MAGNETIC_FIELD": "magnet",
    "TYPE_ROTATION_VECTOR": "rotvec",
}


def read_ilc(path: str | os.PathLike, max_wifi_age_s: float = DEFAULT_MAX_WIFI_AGE_S) -> Recording:
    """Read one ILC trace into a ``Recording``.

    WiFi rows whose last-seen time is more than ``max_wifi_age_s`` before the scan time
    are stale cached results and are dropped (``inf`` keeps all); a BSSID heard twice in
    one scan on the same band keeps its strongest row.
    """
    path = Path(path)
    if not path.is_file():
        raise MapfilterError("file not found", path)
    opener = gzip.open if path.suffix == ".gz" else open
    vectors: dict[str, list[list[float]]] = {name: [] for name in _VECTOR_TYPES.values()}
    waypoints: list[tuple[float, float, float]] = []
    wifi_rows: list[tuple[float, str, float, float, float]] = []  # t_s, bssid, rssi, freq, age_s
    beacon_rows: list[tuple[float, str, float, float]] = []  # t_s, id, rssi, distance
    header: dict[str, str] = {}
    n_lines = 0
    try:
        with opener(path, "rt", encoding="utf-8", errors="replace") as handle:
            for line_no, raw in enumerate(handle, start=1):
                n_lines += 1
                line = raw.rstrip("\r\n")
                if not line.strip():
                    continue
                if line.startswith("#"):
                    for field in line[1:].split("\t"):
                        key, sep, value = field.strip().partition(":")
                        if sep:
                            header.setdefault(key, value)
                    continue
                fields = line.split("\t")
                if len(fields) < 2:
                    raise MapfilterError("malformed line: expected a time and a record type", path, line_no)
                kind = fields[1]
                if kind == "TYPE_WAYPOINT":
                    t_ms, x, y = _numbers(fields, (0, 2, 3), path, line_no)
                    waypoints.append((t_ms / 1000.0, x, y))
                elif kind in _VECTOR_TYPES:
                    t_ms, vx, vy, vz = _numbers(fields, (0, 2, 3, 4), path, line_no)
                    vectors[_VECTOR_TYPES[kind]].append([t_ms / 1000.0, vx, vy, vz])
                elif kind == "TYPE_WIFI":
                    if len(fields) < 7:
                        raise MapfilterError(f"malformed TYPE_WIFI line: {len(fields)} fields, expected 7", path, line_no)
                    t_ms, rssi, freq, seen_ms = _numbers(fields, (0, 4, 5, 6), path, line_no)
                    bssid = fields[3].strip()
                    if not bssid:
                        raise MapfilterError("malformed TYPE_WIFI line: empty BSSID", path, line_no)
                    wifi_rows.append((t_ms / 1000.0, bssid, rssi, freq, (t_ms - seen_ms) / 1000.0))
                elif kind == "TYPE_BEACON":
                    if len(fields) < 8:
                        raise MapfilterError(f"malformed TYPE_BEACON line: {len(fields)} fields, expected 10",
                                             path, line_no)
                    t_ms, rssi, distance = _numbers(fields, (0, 6, 7), path, line_no)
                    beacon_rows.append((t_ms / 1000.0, f"{fields[2]}:{fields[3]}:{fields[4]}", rssi, distance))
                # other record types are skipped
    except (OSError, EOFError, gzip.BadGzipFile, zlib.error) as exc:
        raise MapfilterError(f"cannot read log: {exc}", path) from None
    if n_lines == 0:
        raise MapfilterError("empty log", path)

    def vector_arrays(name: str) -> tuple[np.ndarray, np.ndarray]:
        rows = np.array(vectors[name], dtype=np.float64).reshape(-1, 4)
        order = np.argsort(rows[:, 0], kind="stable")
        return rows[order, 0], rows[order, 1:]

    acc_t, acc = vector_arrays("acc")
    gyro_t, gyro = vector_arrays("gyro")
    mag_t, mag = vector_arrays("magnet")
    rot_t, rot = vector_arrays("rotvec")
    wp = np.array(waypoints, dtype=np.float64).reshape(-1, 3)
    wp = wp[np.argsort(wp[:, 0], kind="stable")]
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
    )


def _numbers(fields: list[str], columns: tuple[int, ...], path: Path, line_no: int) -> list[float]:
    values = []
    for column in columns:
        if column >= len(fields):
            raise MapfilterError(
                f"malformed {fields[1]} line: {len(fields)} fields, expected at least {max(columns) + 1}", path, line_no)
        try:
            value = float(fields[column])
        except ValueError:
            raise MapfilterError(f"malformed {fields[1]} line: column {column + 1} is not a number: {fields[column]!r}",
                                 path, line_no) from None
        if not math.isfinite(value):
            raise MapfilterError(f"malformed {fields[1]} line: column {column + 1} is not finite: {fields[column]!r}",
                                 path, line_no)
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
