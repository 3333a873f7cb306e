"""A phone walk as arrays per sensor: what every reader produces and every stage consumes."""

from __future__ import annotations

import dataclasses
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


@dataclasses.dataclass
class Beacons:
    t_s: np.ndarray  # (B,)
    beacon_id: list[str]  # "uuid:major:minor"
    rssi_dbm: np.ndarray  # (B,)
    distance_m: np.ndarray  # (B,) the phone's own distance estimate


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
            kinds = ", ".join(f"{count} {kind}" for kind, count in sorted(self.duplicates.items()))
            parts.append(f"{n} exact duplicate row{'s' if n != 1 else ''} ({kinds})")
        gaps = self.gap_summary()
        if not parts and gaps is None:
            return None
        text = f"{self.path}: "
        if parts:
            text += "skipped " + "; ".join(parts)
        if gaps is not None:
            text += ("; " if parts else "") + gaps
        return text

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

    @property
    def has_ground_truth(self) -> bool:
        return self.waypoint_t_s.shape[0] > 0

    @property
    def needs_georeference(self) -> bool:
        """True while the ground truth is only in latitude/longitude (not yet in a building's metres)."""
        return (self.waypoint_latlon_deg is not None and self.waypoint_t_s.shape[0] > 0
                and bool(np.isnan(self.waypoint_xy_m).all()))

    @property
    def name(self) -> str:
        return "recording" if self.path is None else trace_name(self.path)


def trace_name(path: str | Path) -> str:
    """A log's trace name: its file name without ``.gz`` and ``.txt`` (the ILC trace id)."""
    name = Path(path).name
    for suffix in (".gz", ".txt"):
        name = name.removesuffix(suffix)
    return name
