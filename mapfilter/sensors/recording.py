"""A phone walk as arrays per sensor: what every reader produces and every stage consumes."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np


@dataclasses.dataclass
class WifiScans:
    """WiFi scans, flat: one row per (scan, access point) heard.

    ``ap_keys[row_ap[i]]`` ("bssid@2.4" / "bssid@5") was heard at ``rssi_dbm[i]`` in scan
    ``row_scan[i]``, taken at ``t_s[row_scan[i]]``. Rows are grouped by scan, scans sorted by time.
    """

    t_s: np.ndarray  # (S,) scan times, Unix seconds
    ap_keys: list[str]  # (K,)
    row_scan: np.ndarray  # (R,) int64
    row_ap: np.ndarray  # (R,) int64
    rssi_dbm: np.ndarray  # (R,) float32
    freq_mhz: np.ndarray  # (R,) float32
    age_s: np.ndarray  # (R,) float32, scan time minus last-seen time

    def __len__(self) -> int:
        return self.t_s.shape[0]

    def scan(self, index: int) -> tuple[list[str], np.ndarray]:
        """The AP keys and RSSI values (dBm) of one scan."""
        rows = np.nonzero(self.row_scan == index)[0]
        return [self.ap_keys[a] for a in self.row_ap[rows]], self.rssi_dbm[rows]

    def matrix(self, keys: list[str] | None = None, missing_dbm: float = np.nan) -> np.ndarray:
        """(S, len(keys)) float32 RSSI matrix over ``keys`` (default: all of ours); unheard = ``missing_dbm``."""
        keys = self.ap_keys if keys is None else keys
        column = {k: j for j, k in enumerate(keys)}
        remap = np.array([column.get(k, -1) for k in self.ap_keys], dtype=np.int64)
        out = np.full((len(self), len(keys)), missing_dbm, dtype=np.float32)
        if self.row_ap.size:
            cols = remap[self.row_ap]
            keep = cols >= 0
            out[self.row_scan[keep], cols[keep]] = self.rssi_dbm[keep]
        return out

    @classmethod
    def empty(cls) -> WifiScans:
        """No scan at all."""
        return cls(t_s=np.zeros(0), ap_keys=[], row_scan=np.zeros(0, dtype=np.int64),
                   row_ap=np.zeros(0, dtype=np.int64), rssi_dbm=np.zeros(0, dtype=np.float32),
                   freq_mhz=np.zeros(0, dtype=np.float32), age_s=np.zeros(0, dtype=np.float32))

    @classmethod
    def concatenate(cls, parts: Sequence[WifiScans]) -> WifiScans:
        """The scans of ``parts`` one after the other, AP keys merged in order of first appearance."""
        keys: dict[str, int] = {}
        row_scan, row_ap = [np.zeros(0, dtype=np.int64)], [np.zeros(0, dtype=np.int64)]
        n_scans = 0
        for part in parts:
            remap = np.array([keys.setdefault(k, len(keys)) for k in part.ap_keys], dtype=np.int64)
            row_ap.append(remap[part.row_ap])
            row_scan.append(part.row_scan + n_scans)
            n_scans += len(part)
        return cls(t_s=np.concatenate([np.zeros(0)] + [p.t_s for p in parts]), ap_keys=list(keys),
                   row_scan=np.concatenate(row_scan), row_ap=np.concatenate(row_ap),
                   rssi_dbm=_concat_1d([p.rssi_dbm for p in parts], np.float32),
                   freq_mhz=_concat_1d([p.freq_mhz for p in parts], np.float32),
                   age_s=_concat_1d([p.age_s for p in parts], np.float32))

    def until(self, t_s: float) -> WifiScans:
        """The scans taken at or before ``t_s``; the AP keys those scans heard, in their order."""
        keep = self.t_s <= t_s
        new_index = np.cumsum(keep) - 1
        rows = keep[self.row_scan]
        used, row_ap = np.unique(self.row_ap[rows], return_inverse=True)
        return WifiScans(t_s=self.t_s[keep], ap_keys=[self.ap_keys[a] for a in used],
                         row_scan=new_index[self.row_scan[rows]].astype(np.int64),
                         row_ap=row_ap.astype(np.int64).reshape(-1), rssi_dbm=self.rssi_dbm[rows],
                         freq_mhz=self.freq_mhz[rows], age_s=self.age_s[rows])


@dataclasses.dataclass
class Beacons:
    """Bluetooth LE beacon sightings, one per row, in time order."""

    t_s: np.ndarray  # (B,)
    # the beacon's MAC address in upper case ("BE:AC:20:23:00:01"); an ILC row without a MAC:
    # "uuid:major:minor"
    beacon_id: list[str]
    rssi_dbm: np.ndarray  # (B,) float32
    distance_m: np.ndarray  # (B,) float32, the phone's own distance estimate (NaN: none)

    @classmethod
    def empty(cls) -> Beacons:
        return cls(t_s=np.zeros(0), beacon_id=[], rssi_dbm=np.zeros(0, dtype=np.float32),
                   distance_m=np.zeros(0, dtype=np.float32))

    @classmethod
    def concatenate(cls, parts: Sequence[Beacons]) -> Beacons:
        return cls(t_s=_concat_1d([p.t_s for p in parts], np.float64),
                   beacon_id=[b for p in parts for b in p.beacon_id],
                   rssi_dbm=_concat_1d([p.rssi_dbm for p in parts], np.float32),
                   distance_m=_concat_1d([p.distance_m for p in parts], np.float32))

    def until(self, t_s: float) -> Beacons:
        """The sightings at or before ``t_s``."""
        keep = self.t_s <= t_s
        return Beacons(t_s=self.t_s[keep], beacon_id=[b for b, k in zip(self.beacon_id, keep) if k],
                       rssi_dbm=self.rssi_dbm[keep], distance_m=self.distance_m[keep])


@dataclasses.dataclass
class ReadReport:
    """What one log held and what the log reader skipped."""

    path: Path
    n_lines: int = 0
    rows: dict[str, int] = dataclasses.field(default_factory=dict)  # good rows per record type
    bad_rows: dict[str, int] = dataclasses.field(default_factory=dict)  # skipped rows per record type
    first_bad: dict[str, str] = dataclasses.field(default_factory=dict)  # type -> "line N: reason"
    joined_lines: int = 0  # lines that held more than one record (missing newline), split
    truncated_after_line: int | None = None  # the gzip stream ended early after this line
    unknown_rows: int = 0  # rows of record types this reader does not know (skipped, not an error)
    needed: frozenset[str] = frozenset()  # the record types the run needs (the reader fills it in)
    format: str = ""  # the log format the reader took the file for ("ILC 2.0", "GetSensorData")
    duplicates: dict[str, int] = dataclasses.field(default_factory=dict)  # exact repeats dropped, per type
    # records dropped, per type, because their time is earlier than the previous kept record of
    # their stream (a clock that jumped back; a WiFi row after its scan was complete)
    went_back: dict[str, int] = dataclasses.field(default_factory=dict)
    # GetSensorData samples whose sensor clock strayed from their AppTimestamp (kept at the
    # AppTimestamp), per type
    clock_strays: dict[str, int] = dataclasses.field(default_factory=dict)
    # stretches longer than the reader's limit (sensors/logread.GAP_REPORT_S) with no record at
    # all, as (start, end) times in the recording's time base; reported, never filled in
    time_gaps_s: list[tuple[float, float]] = dataclasses.field(default_factory=list)
    time_span_s: tuple[float, float] | None = None  # first and last record time

    @property
    def n_bad_rows(self) -> int:
        return sum(self.bad_rows.values())

    @property
    def clean(self) -> bool:
        return not self.bad_rows and self.truncated_after_line is None

    def warning(self) -> str | None:
        """One line naming what was skipped (None when nothing was)."""
        parts = []
        for kind in sorted(self.bad_rows):
            n = self.bad_rows[kind]
            if kind == "?":  # a line with no record type, or one too long to read
                parts.append(f"{n} unreadable line{'s' if n != 1 else ''} (first at {self.first_bad[kind]})")
                continue
            use = "needed" if kind in self.needed else "not used"
            parts.append(f"{n} bad {kind} row{'s' if n != 1 else ''} ({use}; first at {self.first_bad[kind]})")
        if self.truncated_after_line is not None:
            parts.append(f"gzip stream ends early: kept the {self.truncated_after_line} lines before the cut")
        if self.duplicates:
            n = sum(self.duplicates.values())
            parts.append(f"{n} exact duplicate row{'s' if n != 1 else ''} ({_per_kind(self.duplicates)})")
        if self.went_back:
            n = sum(self.went_back.values())
            parts.append(f"{n} row{'s' if n != 1 else ''} that went back in time ({_per_kind(self.went_back)})")
        notes = []
        if self.clock_strays:
            n = sum(self.clock_strays.values())
            notes.append(f"{n} sample{'s' if n != 1 else ''} off their sensor clock, placed at their AppTimestamp "
                         f"({_per_kind(self.clock_strays)})")
        gaps = self.gap_summary()
        if gaps is not None:
            notes.append(gaps)
        if not parts and not notes:
            return None
        return f"{self.path}: " + "; ".join((["skipped " + "; ".join(parts)] if parts else []) + notes)

    def copy(self) -> ReadReport:
        """A copy that the reader's later rows do not change."""
        return dataclasses.replace(self, rows=dict(self.rows), bad_rows=dict(self.bad_rows),
                                   first_bad=dict(self.first_bad), duplicates=dict(self.duplicates),
                                   went_back=dict(self.went_back), clock_strays=dict(self.clock_strays),
                                   time_gaps_s=list(self.time_gaps_s))

    def gap_summary(self) -> str | None:
        """The time gaps in a few words (None when there are none)."""
        if not self.time_gaps_s:
            return None
        n = len(self.time_gaps_s)
        start, end = max(self.time_gaps_s, key=lambda gap: gap[1] - gap[0])
        first = self.time_span_s[0] if self.time_span_s is not None else start
        longest = "" if n == 1 else "longest "
        return (f"{n} time gap{'s' if n != 1 else ''} with no record ({longest}{format_duration(end - start)}, "
                f"from {start - first:.1f} s into the log)")


def _per_kind(counts: dict[str, int]) -> str:
    return ", ".join(f"{count} {kind}" for kind, count in sorted(counts.items()))


def format_duration(seconds: float) -> str:
    """A duration in the unit that reads best: s, min, h or days."""
    if seconds < 120:
        return f"{seconds:.1f} s"
    if seconds < 7200:
        return f"{seconds / 60:.1f} min"
    if seconds < 172800:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:.1f} days"


@dataclasses.dataclass
class Recording:
    """One walk. Times are Unix seconds (float64); IMU arrays are (M, 3) in the phone frame."""

    path: Path | None
    floor_name: str | None
    start_t_s: float | None
    waypoint_t_s: np.ndarray  # (W,) ground truth times
    waypoint_xy_m: np.ndarray  # (W, 2) ground truth positions, floor frame
    acc_t_s: np.ndarray
    acc_mps2: np.ndarray  # with gravity
    gyro_t_s: np.ndarray
    gyro_radps: np.ndarray
    magnet_t_s: np.ndarray
    magnet_ut: np.ndarray
    rotvec_t_s: np.ndarray
    rotvec_xyz: np.ndarray  # x, y, z of the unit quaternion
    wifi: WifiScans
    beacons: Beacons
    read_report: ReadReport | None = None  # what the log reader skipped (None: not read from a log)
    # a barometer (GetSensorData PRES rows; ILC TYPE_PRESSURE rows, which only the simulator writes)
    pressure_t_s: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    pressure_hpa: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    # the floor of each waypoint when a log names one (GetSensorData POSI rows; a fifth
    # TYPE_WAYPOINT column, written by the simulator); None: the header's floor throughout
    waypoint_floor: list[str] | None = None
    # ground truth in WGS-84 (latitude, longitude) degrees when the log gives it so (GetSensorData
    # POSI rows); until the walk is placed in a georeferenced building (sensors/logs.localise),
    # ``waypoint_xy_m`` is NaN
    waypoint_latlon_deg: np.ndarray | None = None
    phone_model: str | None = None  # the phone the log names in its header, if any
    # a chunk of a log read as it arrives (``sensors.logs.LogStream``): the earliest time a record
    # the filter reads can still come at (a WiFi scan not yet complete, a record held back, a stream
    # whose clock went back and has not passed its latest record again); inf: none, as in a whole log
    pending_t_s: float = math.inf

    @property
    def has_ground_truth(self) -> bool:
        return self.waypoint_t_s.shape[0] > 0

    @property
    def newest_t_s(self) -> float:
        """The time of the newest record of any sensor (ground truth aside; -inf: none)."""
        times = (self.acc_t_s, self.gyro_t_s, self.magnet_t_s, self.rotvec_t_s, self.pressure_t_s, self.wifi.t_s,
                 self.beacons.t_s)
        return max((float(np.max(t)) for t in times if len(t)), default=-np.inf)

    @property
    def source_rows(self) -> dict[str, int]:
        """{sensor: rows} of the sensors only measurement sources read (``filter.sources``), for reports."""
        return {"BLE": len(self.beacons.t_s)}

    @property
    def needs_georeference(self) -> bool:
        """True while the ground truth is only in latitude/longitude (not yet in a building's metres)."""
        return (self.waypoint_latlon_deg is not None and self.waypoint_t_s.shape[0] > 0
                and bool(np.isnan(self.waypoint_xy_m).all()))

    @property
    def name(self) -> str:
        return "recording" if self.path is None else trace_name(self.path)

    @classmethod
    def empty(cls, path: Path | None = None) -> Recording:
        """A recording without a single record (what a log stream returns while nothing is complete)."""
        return cls(path=path, floor_name=None, start_t_s=None, waypoint_t_s=np.zeros(0),
                   waypoint_xy_m=np.zeros((0, 2)), acc_t_s=np.zeros(0), acc_mps2=np.zeros((0, 3)),
                   gyro_t_s=np.zeros(0), gyro_radps=np.zeros((0, 3)), magnet_t_s=np.zeros(0),
                   magnet_ut=np.zeros((0, 3)), rotvec_t_s=np.zeros(0), rotvec_xyz=np.zeros((0, 3)),
                   wifi=WifiScans.empty(), beacons=Beacons.empty())

    def until(self, t_s: float) -> Recording:
        """The records of every stream with time <= ``t_s`` (scans by their scan time); the rest
        (path, header fields, read report) as they are. Not the same as reading the log cut at
        ``t_s``: see ``sensors/logs.LogStream``."""
        def cut(t: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            keep = t <= t_s
            return t[keep], values[keep]

        wp = self.waypoint_t_s <= t_s
        n_wp = int(np.count_nonzero(wp))
        floors = None if self.waypoint_floor is None or n_wp == 0 else [f for f, k in zip(self.waypoint_floor, wp) if k]
        latlon = None if self.waypoint_latlon_deg is None or n_wp == 0 else self.waypoint_latlon_deg[wp]
        acc_t, acc = cut(self.acc_t_s, self.acc_mps2)
        gyro_t, gyro = cut(self.gyro_t_s, self.gyro_radps)
        mag_t, mag = cut(self.magnet_t_s, self.magnet_ut)
        rot_t, rot = cut(self.rotvec_t_s, self.rotvec_xyz)
        baro_t, baro = cut(self.pressure_t_s, self.pressure_hpa)
        return dataclasses.replace(
            self, waypoint_t_s=self.waypoint_t_s[wp], waypoint_xy_m=self.waypoint_xy_m[wp],
            acc_t_s=acc_t, acc_mps2=acc, gyro_t_s=gyro_t, gyro_radps=gyro, magnet_t_s=mag_t, magnet_ut=mag,
            rotvec_t_s=rot_t, rotvec_xyz=rot, wifi=self.wifi.until(t_s), beacons=self.beacons.until(t_s),
            pressure_t_s=baro_t, pressure_hpa=baro, waypoint_floor=floors, waypoint_latlon_deg=latlon)


def concatenate(chunks: Sequence[Recording]) -> Recording:
    """One recording of consecutive chunks of one walk (what a log stream returns, call by call):
    every stream's records one after the other. The path, header fields (floor name, start time,
    phone) and read report are the last chunk's, which knew the most. Waypoint floors and
    latitudes/longitudes are kept when every chunk with waypoints has them."""
    if not chunks:
        raise ValueError("concatenate needs at least one chunk")
    last = chunks[-1]
    with_wp = [c for c in chunks if c.waypoint_t_s.size]
    floors = None
    if with_wp and all(c.waypoint_floor is not None for c in with_wp):
        floors = [f for c in with_wp for f in c.waypoint_floor]
    latlon = None
    if with_wp and all(c.waypoint_latlon_deg is not None for c in with_wp):
        latlon = np.concatenate([c.waypoint_latlon_deg for c in with_wp])

    def rows(name: str, width: int | None) -> np.ndarray:
        empty = np.zeros(0) if width is None else np.zeros((0, width))
        return np.concatenate([empty] + [getattr(c, name) for c in chunks])

    return Recording(
        path=last.path, floor_name=last.floor_name, start_t_s=last.start_t_s,
        waypoint_t_s=rows("waypoint_t_s", None), waypoint_xy_m=rows("waypoint_xy_m", 2),
        acc_t_s=rows("acc_t_s", None), acc_mps2=rows("acc_mps2", 3),
        gyro_t_s=rows("gyro_t_s", None), gyro_radps=rows("gyro_radps", 3),
        magnet_t_s=rows("magnet_t_s", None), magnet_ut=rows("magnet_ut", 3),
        rotvec_t_s=rows("rotvec_t_s", None), rotvec_xyz=rows("rotvec_xyz", 3),
        wifi=WifiScans.concatenate([c.wifi for c in chunks]),
        beacons=Beacons.concatenate([c.beacons for c in chunks]),
        read_report=last.read_report,
        pressure_t_s=rows("pressure_t_s", None), pressure_hpa=rows("pressure_hpa", None),
        waypoint_floor=floors, waypoint_latlon_deg=latlon, phone_model=last.phone_model,
        pending_t_s=last.pending_t_s,
    )


def _concat_1d(parts: list[np.ndarray], dtype) -> np.ndarray:
    return np.concatenate([np.zeros(0, dtype=dtype)] + parts).astype(dtype, copy=False)


def trace_name(path: str | Path) -> str:
    """A log's trace name: its file name without ``.gz`` and ``.txt`` (the ILC trace id)."""
    name = Path(path).name
    for suffix in (".gz", ".txt"):
        name = name.removesuffix(suffix)
    return name
