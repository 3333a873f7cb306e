"""What every log reader shares: bounded line reading, physical ranges, duplicates, time gaps.

The ILC reader (``ilc.py``) and the GetSensorData reader (``ipin.py``) read their records
through :func:`read_lines` and check them with the helpers here, so that a broken or hostile
log is handled the same way whatever its format:

- a log is read in bounded pieces: a line longer than :data:`MAX_LINE_BYTES` is never held
  in memory, it is skipped (a bad row) while the reader reads on to its end;
- every value is checked against the physical range of its quantity (:data:`RANGES`); a value
  outside it makes the row bad, like a value that is not a number;
- exact duplicate records (same time, same values) are kept once (:func:`drop_duplicate_rows`);
- long stretches with no record at all are reported (:func:`find_time_gaps`), never filled in.

Memory is proportional to the log's size, whatever its timestamps.
"""

from __future__ import annotations

import gzip
import math
import warnings
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.sensors.recording import ReadReport, WifiScans
from mapfilter.sensors.wifi import ap_key, band_of_frequency

# The longest line a reader holds in memory. Real ILC and GetSensorData lines are under 500 bytes
# (the longest are GetSensorData header lines); 64 KiB leaves room for many records glued
# together by missing newlines (the ILC reader splits those) and bounds what one line can take.
MAX_LINE_BYTES = 65536
# A stretch with no record of any kind longer than this is reported as a time gap. A phone
# logs its IMU at 50-200 Hz and scans WiFi every few seconds: the longest pause in the 191 ILC
# site-1 logs is 9.5 s (a log without IMU), in the 29 IPIN 2023 logs 0.03 s.
GAP_REPORT_S = 60.0

# Physical ranges (inclusive) of the values in a log. Wide on purpose: a value outside is not
# merely unusual, it cannot come from the sensor (RSSI above the 1 W legal transmit limit, an
# acceleration beyond a phone accelerometer's largest range of +-16 g, ...).
RANGES: dict[str, tuple[float, float, str]] = {
    "rssi_dbm": (-150.0, 30.0, "dBm"),  # a received signal: above +30 dBm (1 W) it cannot be
    "acc_mps2": (-200.0, 200.0, "m/s^2"),  # phone accelerometers: at most +-16 g (157 m/s^2)
    "gyro_radps": (-50.0, 50.0, "rad/s"),  # phone gyroscopes: at most +-2000 deg/s (34.9 rad/s)
    "magnet_ut": (-5000.0, 5000.0, "uT"),  # phone magnetometers: at most +-4900 uT; the Earth ~25-65
    "quaternion": (-1.0001, 1.0001, ""),  # a component of a unit quaternion (float round-off allowed)
    "angle_deg": (-360.0, 360.0, "deg"),
    "pressure_hpa": (300.0, 1100.0, "hPa"),  # barometer chips' range: Everest ~330, Dead Sea ~1070
    "freq_mhz": (700.0, 70000.0, "MHz"),  # WiFi bands from 900 MHz (802.11ah) to 60 GHz
    "latitude_deg": (-90.0, 90.0, "deg"),
    "longitude_deg": (-180.0, 180.0, "deg"),
    "position_m": (-1.0e5, 1.0e5, "m"),  # a floor-plan coordinate: within 100 km of the plan's origin
    "distance_m": (0.0, 1.0e5, "m"),
    # ILC: Unix time in ms, from 1970 (hand-made logs count from 0) to 2100-01-01
    "unix_ms": (0.0, 4102444800000.0, "ms"),
    # GetSensorData: seconds since the log started; no log runs for a century
    "log_s": (0.0, 100 * 365.25 * 86400.0, "s"),
    # GetSensorData sensor timestamps: the sensor's own clock (since boot), used for intervals only
    "sensor_s": (-1.0e10, 1.0e10, "s"),
}


class LogReadWarning(UserWarning):
    """Rows of a log were skipped (the message is one line naming the file, types and lines)."""


class BadRow(Exception):
    """A row that cannot be read; ``kind`` is its record type ("?" when it has none), ``reason`` why."""

    def __init__(self, kind: str, reason: str):
        super().__init__(reason)
        self.kind = kind
        self.reason = reason


def check_range(kind: str, name: str, value: float, quantity: str) -> float:
    """``value`` if it lies in the physical range of ``quantity`` (:data:`RANGES`), else ``BadRow``."""
    low, high, unit = RANGES[quantity]
    if not low <= value <= high:
        unit = f" {unit}" if unit else ""
        raise BadRow(kind, f"{kind} {name} out of range: {value:g}{unit} (expected {low:g} to {high:g})")
    return value


def quick_numbers(fields: list[str], columns: range, quantity: str) -> list[float] | None:
    """The fields ``columns`` as floats when all are numbers within the range of ``quantity``,
    else None (then the caller's checked parse says what is wrong). The fast path of the readers:
    most rows are good, and a comparison chain also turns NaN and infinities away."""
    low, high, _ = RANGES[quantity]
    try:
        values = [float(fields[c]) for c in columns]
    except (ValueError, IndexError):
        return None
    for value in values:
        if not low <= value <= high:
            return None
    return values


def parse_number(kind: str, fields: list[str], column: int, separator_name: str = "column") -> float:
    """Field ``column`` of a row as a finite float; ``BadRow`` naming the column otherwise."""
    if column >= len(fields):
        raise BadRow(kind, f"malformed {kind} line: {len(fields)} fields, expected at least {column + 1}")
    text = fields[column]
    try:
        value = float(text)
    except ValueError:
        raise BadRow(kind, f"malformed {kind} line: {separator_name} {column + 1} is not a number: "
                           f"{text[:40]!r}") from None
    if not math.isfinite(value):
        # Android writes "Infinity" for a beacon distance it cannot estimate
        raise BadRow(kind, f"malformed {kind} line: {separator_name} {column + 1} is not finite: {text[:40]!r}")
    return value


def is_gzip(path: Path) -> bool:
    """True if the file starts with the gzip magic bytes (the content decides, not the name)."""
    with path.open("rb") as handle:
        return handle.read(2) == b"\x1f\x8b"


def open_binary(path: Path):
    """The log's bytes, decompressed if it is gzip (by content)."""
    return gzip.open(path, "rb") if is_gzip(path) else path.open("rb")


def iter_bounded_lines(handle, max_bytes: int = MAX_LINE_BYTES) -> Iterator[tuple[int, str | None]]:
    """(line number, text without the line end) of each line; ``None`` for a line longer than
    ``max_bytes``, which is read past in pieces of at most ``max_bytes`` and never held whole."""
    line_no = 0
    while True:
        raw = handle.readline(max_bytes + 1)
        if not raw:
            return
        line_no += 1
        if len(raw) > max_bytes and not raw.endswith(b"\n"):
            while raw and not raw.endswith(b"\n"):  # skip the rest of the over-long line
                raw = handle.readline(max_bytes)
            yield line_no, None
            continue
        yield line_no, raw.decode("utf-8", errors="replace").rstrip("\r\n")


def read_lines(path: Path, report: ReadReport, strict: bool,
               handle_line: Callable[[int, str], None]) -> None:
    """Feed every line of the log at ``path`` to ``handle_line(line_no, text)``.

    ``handle_line`` raises ``BadRow`` for a row it cannot use; the row is counted in ``report``
    (or refused with ``strict`` when its type is needed or unknown). An over-long line is a bad
    row of type "?". A gzip stream that ends early keeps the lines before the cut (refused with
    ``strict``); a corrupted stream is refused. Fills ``report.n_lines``.
    """
    line_no = 0
    try:
        with open_binary(path) as handle:
            for line_no, text in iter_bounded_lines(handle):
                try:
                    if text is None:
                        raise BadRow("?", f"line longer than {MAX_LINE_BYTES} bytes")
                    handle_line(line_no, text)
                except BadRow as bad:
                    count_bad_row(report, bad, line_no, strict, path)
    except EOFError:
        # gzip without its end-of-stream marker: every line handed out before the cut was complete
        # (readline only returns a line once its newline has been decompressed)
        if strict:
            raise MapfilterError(f"gzip stream ends early after line {line_no} (truncated file)", path) from None
        report.truncated_after_line = line_no
    except (OSError, gzip.BadGzipFile, zlib.error) as exc:
        raise MapfilterError(f"cannot read log: {exc}", path) from None
    report.n_lines = line_no


def count_record(report: ReadReport, parse: Callable[[], str | None], line_no: int, strict: bool,
                 path: Path) -> None:
    """Parse one record with ``parse`` (which returns its record type, None for a type the reader
    does not know) and count it in ``report``: a bad row (``BadRow``) skipped and counted
    (refused with ``strict``, ``count_bad_row``), an unknown type counted, a good row counted by type."""
    try:
        kind = parse()
    except BadRow as bad:
        count_bad_row(report, bad, line_no, strict, path)
        return
    if kind is None:
        report.unknown_rows += 1
    else:
        report.rows[kind] = report.rows.get(kind, 0) + 1


def count_bad_row(report: ReadReport, bad: BadRow, line_no: int, strict: bool, path: Path) -> None:
    """Count a bad row in ``report``, or refuse it with ``strict`` if its type is needed or unknown."""
    if strict and (bad.kind in report.needed or bad.kind == "?"):
        raise MapfilterError(bad.reason, path, line_no) from None
    report.bad_rows[bad.kind] = report.bad_rows.get(bad.kind, 0) + 1
    report.first_bad.setdefault(bad.kind, f"line {line_no}: {bad.reason}")


def check_usable(report: ReadReport, path: Path) -> None:
    """Refuse an empty log and one with no usable record left."""
    if report.n_lines == 0:
        raise MapfilterError("empty log", path)
    if not report.rows:
        detail = f" ({report.n_bad_rows} bad rows, first at {next(iter(report.first_bad.values()))})" \
            if report.bad_rows else ""
        raise MapfilterError(f"no usable record in the log{detail}", path)


def emit_warning(report: ReadReport, warn: Callable[[str], None] | None) -> None:
    """The report's one-line warning (if any) to ``warn``, else as a ``LogReadWarning``."""
    message = report.warning()
    if message is None:
        return
    if warn is not None:
        warn(message)
    else:
        warnings.warn(message, LogReadWarning, stacklevel=3)


def drop_duplicate_rows(rows: np.ndarray, report: ReadReport, kind: str) -> np.ndarray:
    """Rows of a float table sorted by time (column 0, stable) with exact duplicates kept once.

    Two records with the same time and the same values are one record written twice (a log
    concatenated with itself, a logger that repeats itself): counting both would count a
    waypoint twice. The number dropped goes to ``report.duplicates[kind]``.
    """
    if rows.shape[0] == 0:
        return rows
    # sorted by every column, duplicates are neighbours; the rows kept keep their file order
    # among equal times (a stable sort by time), as the readers always ordered them
    by_value = np.lexsort(rows.T[::-1])
    repeat = np.all(rows[by_value[1:]] == rows[by_value[:-1]], axis=1)
    keep = np.ones(rows.shape[0], dtype=bool)
    keep[by_value[1:][repeat]] = False
    dropped = int(np.count_nonzero(repeat))
    if dropped:
        report.duplicates[kind] = report.duplicates.get(kind, 0) + dropped
    rows = rows[keep]
    return rows[np.argsort(rows[:, 0], kind="stable")]


def drop_duplicate_records(records: list[tuple], report: ReadReport, kind: str) -> list[tuple]:
    """``records`` (tuples of any values) in their order with exact repeats kept once."""
    seen: set[tuple] = set()
    kept = []
    for record in records:
        if record not in seen:
            seen.add(record)
            kept.append(record)
    dropped = len(records) - len(kept)
    if dropped:
        report.duplicates[kind] = report.duplicates.get(kind, 0) + dropped
    return kept


def find_time_gaps(times_s: list[np.ndarray], report: ReadReport, gap_s: float = GAP_REPORT_S) -> None:
    """Record in ``report.time_gaps_s`` every stretch longer than ``gap_s`` with no record of any
    kind, as (start, end) times, over the union of ``times_s``. Nothing is filled in: a row stamped
    years ahead costs one array entry here, and the stages that walk through time are told."""
    nonempty = [np.asarray(t, dtype=np.float64).ravel() for t in times_s if np.size(t)]
    if not nonempty:
        return
    every = np.sort(np.concatenate(nonempty))
    jumps = np.nonzero(np.diff(every) > gap_s)[0]
    report.time_gaps_s = [(float(every[i]), float(every[i + 1])) for i in jumps]
    report.time_span_s = (float(every[0]), float(every[-1]))


def group_scans(rows: list[tuple[float, str, float, float, float]], max_age_s: float) -> WifiScans:
    """WiFi rows (t_s, bssid, rssi_dbm, freq_mhz, age_s) grouped by scan time: rows older than
    ``max_age_s`` (stale cached results) dropped, APs keyed by BSSID and band, and a BSSID heard
    twice in one scan on the same band keeping its strongest row."""
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
