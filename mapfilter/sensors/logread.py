"""What every log reader shares: streaming, bounded lines, physical ranges, record order, gaps.

The ILC reader (``ilc.py``) and the GetSensorData reader (``ipin.py``) are parsers of lines
that a :class:`RecordStream` feeds (``sensors/logs.LogStream`` is the public one), and they
check their records with the helpers here, so that a broken or hostile log is handled the same
way whatever its format, and a log read whole is the replay of the same log streamed:

- a log is read in pieces cut anywhere (:class:`LineSplitter`): a line longer than
  :data:`MAX_LINE_BYTES` is never held in memory, it is skipped (a bad row) while the reader
  reads on to its end;
- every value is checked against the physical range of its quantity (:data:`RANGES`); a value
  outside it makes the row bad, like a value that is not a number;
- each stream keeps its records in file order: a record earlier than the previous kept one of
  its stream went back in time and is dropped, an exact repeat of a record of the same time is
  kept once (:class:`TimeOrder`); WiFi rows become scans once a scan is complete
  (:class:`ScanAssembler`);
- long stretches with no record at all are reported (:class:`GapTracker`), never filled in.

Memory is proportional to the log's size, whatever its timestamps.
"""

from __future__ import annotations

import gzip
import math
import os
import warnings
import zlib
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Protocol

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.sensors.recording import ReadReport, Recording, WifiScans, concatenate
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


def parse_columns(lines: list[str], delimiter: str, columns: tuple[int, ...], quantities: tuple[str, ...]
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The fields ``columns`` of every line (split at ``delimiter``) as one float table (lines,
    columns), and whether each line's values are all numbers within the ranges of their
    ``quantities`` (:data:`RANGES`): the lines that the line-by-line parse takes as they are.

    numpy's text reader parses the table in one call: its numbers are those of Python's
    ``float`` (both are CPython's correctly rounded ``PyOS_string_to_double``), and what it
    refuses (a field that is not a number, too few fields) sends the lines to ``float`` one by
    one, which also takes what only ``float`` reads (``1_000``, other scripts' digits). A line
    that fails is left to the line-by-line parse, which says what is wrong with it."""
    values = None
    if lines:
        try:
            values = np.loadtxt(lines, dtype=np.float64, delimiter=delimiter, usecols=columns, comments=None,
                                ndmin=2, quotechar=None)
        except (ValueError, IndexError, TypeError):
            values = None
        if values is not None and values.shape != (len(lines), len(columns)):
            values = None  # e.g. a carriage return inside a line made two rows of it
    if values is None:
        values = np.full((len(lines), len(columns)), np.nan)
        for i, line in enumerate(lines):
            fields = line.split(delimiter)
            try:
                values[i] = [float(fields[c]) for c in columns]
            except (ValueError, IndexError):
                pass
    ok = np.ones(len(lines), dtype=bool)
    for j, quantity in enumerate(quantities):
        low, high, _ = RANGES[quantity]
        ok &= (values[:, j] >= low) & (values[:, j] <= high)  # NaN fails both
    return values, ok


def clock_before_rows(times_s: np.ndarray, is_row: np.ndarray) -> tuple[np.ndarray, float]:
    """Records in file order with ``times_s`` (-inf: a record that moves no clock), of which
    ``is_row`` are WiFi rows: the latest time among the other records since the row before, for
    each row, and among those after the last row (what :meth:`ScanAssembler.add_rows` takes)."""
    clock = np.where(is_row, -np.inf, times_s)
    rows = np.flatnonzero(is_row)
    if clock.size == 0:
        return np.zeros(0), -math.inf
    if rows.size == 0:
        return np.zeros(0), float(clock.max())
    # spans [0, r0), [r0, r1), ..., [r_last, end): each holds its row's -inf, so none is empty
    spans = np.maximum.reduceat(clock, np.concatenate(([0], rows)))
    return spans[:-1], float(spans[-1])


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


def emit_warning(report: ReadReport, warn: Callable[[str], None] | None, stacklevel: int = 3) -> None:
    """The report's one-line warning (if any) to ``warn``, else as a ``LogReadWarning``
    (attributed to the caller ``stacklevel`` - 1 frames up)."""
    message = report.warning()
    if message is None:
        return
    if warn is not None:
        warn(message)
    else:
        warnings.warn(message, LogReadWarning, stacklevel=stacklevel)


def group_scans(rows: list[tuple[float, str, float, float, float]], max_age_s: float) -> WifiScans:
    """WiFi rows (t_s, bssid, rssi_dbm, freq_mhz, age_s) grouped by scan time: rows older than
    ``max_age_s`` (stale cached results) dropped, APs keyed by BSSID and band in the order they
    were first heard, and a BSSID heard twice in one scan on the same band keeping its strongest
    row (the first of equals) in the place where the scan first heard it."""
    rows = [row for row in rows if not row[4] > max_age_s]
    if not rows:
        return WifiScans.empty()
    t_s, bssids, rssi, freq, age = zip(*rows)
    rssi, freq = np.array(rssi, dtype=np.float64), np.array(freq, dtype=np.float64)
    keys = list(map(ap_key, bssids, map(band_of_frequency, freq.tolist())))
    index = {key: j for j, key in enumerate(dict.fromkeys(keys))}
    ap = np.fromiter(map(index.__getitem__, keys), dtype=np.int64, count=len(keys))
    scan_times, scan = np.unique(np.array(t_s, dtype=np.float64), return_inverse=True)
    scan = scan.reshape(-1).astype(np.int64)
    position = np.arange(len(rows))
    pair = scan * len(index) + ap
    # per (scan, AP): the strongest row, the first of equals, kept where the scan first heard the AP
    order = np.lexsort((position, -rssi, pair))
    starts = np.flatnonzero(np.concatenate(([True], pair[order][1:] != pair[order][:-1])))
    best = order[starts]
    first_heard = np.minimum.reduceat(position[order], starts)
    best = best[np.lexsort((first_heard, scan[best]))]
    return WifiScans(
        t_s=scan_times,
        ap_keys=list(index),
        row_scan=scan[best],
        row_ap=ap[best],
        rssi_dbm=rssi[best].astype(np.float32),
        freq_mhz=freq[best].astype(np.float32),
        age_s=np.array(age, dtype=np.float64)[best].astype(np.float32),
    )


# ---- streaming: a log's bytes as they come -> the records completed so far ----------------------

# A record this far after the previous one of its stream is held until the next one confirms
# the jump (a pause, or a clock set forward) or goes back (a lone row stamped ahead: dropped).
# The longest pause in one stream of the real logs: 28.5 s (ILC beacons), 78 s (IPIN beacons,
# which are then held, not dropped).
JUMP_CHECK_S = GAP_REPORT_S
# A record of a sensor the filter follows stamped this far before the newest such record the log
# already gave came after the log's clock (or its sensor's) went back: dropped as went back, read
# whole or live (``LogClock``). The ILC logger writes its IMU rows up to 1.8 s behind its WiFi rows
# (191 logs); a GetSensorData log is in AppTimestamp order. A live run's filter does not wait for
# a sensor this far behind (filter/causal.py PAUSED_AFTER_S) and would have moved on.
RECORD_BEHIND_LOG_S = 3.0
# a reader may place a record's time this far from the log's clock (GetSensorData: a sensor's own
# time trusted within this of its AppTimestamp, sensors.ipin)
MAX_CLOCK_DISAGREEMENT_S = 1.0
# the farthest a record a reader gives can lie behind the newest followed record it gave before:
# dropped beyond RECORD_BEHIND_LOG_S, then placed up to MAX_CLOCK_DISAGREEMENT_S either way
MAX_RECORD_LATENESS_S = RECORD_BEHIND_LOG_S + 2.0 * MAX_CLOCK_DISAGREEMENT_S
# A WiFi scan stamped this far before a record the log already gave came after the log's clock
# went back: dropped as went back, read whole or live. A live run's filter takes the WiFi as
# passed at its newest record's time less this (filter/causal.py SCAN_PASSED_BEFORE_NEWEST_S)
# and has moved on by then; in every real log (191 ILC, 29 IPIN 2023) a scan's first row comes
# before any record stamped after it.
SCAN_BEHIND_LOG_S = 0.1
# How far into a log its format is looked for (a header is some 40 lines), blank lines included:
# lines are held until then.
SNIFF_LINES = 200
# A line with a NUL, or with more than this share of characters that are no text (bytes that are
# not UTF-8, control characters other than a tab), is binary data, not a log's line.
BINARY_SHARE = 0.1


def looks_binary(text: str) -> bool:
    """Whether a line (decoded with ``errors="replace"``) is binary data rather than text."""
    if "\x00" in text:
        return True
    odd = sum(1 for c in text if c == "\ufffd" or (c < " " and c != "\t") or c == "\x7f")
    return odd > BINARY_SHARE * len(text)


def no_format_reason(line_no: int, text: str | None) -> str | None:
    """Why a log whose line ``line_no`` is ``text``, read before its format is known, cannot be
    a phone log of any format (None: it may still be one): an over-long line, binary data."""
    if text is None:
        return f"line {line_no} is longer than {MAX_LINE_BYTES} bytes: binary data, not a phone log"
    if looks_binary(text):
        return f"line {line_no} is binary data, not text"
    return None
# The pieces a whole file is read in (the result does not depend on it).
READ_CHUNK_BYTES = 1 << 20


class LineSplitter:
    """Bytes as they come -> numbered lines of text, as :func:`iter_bounded_lines` reads a file.

    A partial line is kept until its newline arrives; a line longer than ``max_bytes`` is
    never held whole: it comes out as ``None`` as soon as it is known to be too long, and its
    rest is read past. Lines are decoded as UTF-8 with ``errors="replace"``, without their
    line end (``\\n``, and any ``\\r`` before it).
    """

    def __init__(self, max_bytes: int = MAX_LINE_BYTES):
        self._max = max_bytes
        self._partial: list[bytes] = []  # the pieces of the line not yet ended
        self._partial_len = 0
        self._skipping = False  # inside an over-long line, already reported
        self.n_lines = 0  # lines handed out so far

    def feed(self, data: bytes) -> tuple[int, list[str | None]]:
        """(number of the first line, the lines that ``data`` completed)."""
        first = self.n_lines + 1
        lines: list[str | None] = []
        if self._skipping:
            newline = data.find(b"\n")
            if newline < 0:
                return first, lines
            self._skipping = False
            data = data[newline + 1:]
        end = data.rfind(b"\n")
        if end >= 0:
            begin = 0
            if self._partial:  # the held start of a line and its end in data
                begin = data.find(b"\n") + 1
                self._partial.append(data[:begin - 1])
                lines.append(self._decode_line(b"".join(self._partial)))
                self._partial, self._partial_len = [], 0
            if begin <= end:
                lines.extend(self._decode_block(data[begin:end]))
            data = data[end + 1:]
        if data:
            self._partial.append(data)
            self._partial_len += len(data)
            if self._partial_len > self._max:
                lines.append(None)
                self._skipping = True
                self._partial, self._partial_len = [], 0
        self.n_lines += len(lines)
        return first, lines

    def close(self, drop_partial: bool = False) -> tuple[int, list[str | None]]:
        """The last line if it had no newline (dropped with ``drop_partial``: a cut stream)."""
        first = self.n_lines + 1
        lines: list[str | None] = []
        if self._partial and not drop_partial:
            lines.append(self._decode_line(b"".join(self._partial)))
        self._partial, self._partial_len = [], 0
        self.n_lines += len(lines)
        return first, lines

    def _decode_line(self, raw: bytes) -> str | None:
        if len(raw) > self._max:
            return None
        return raw.decode("utf-8", errors="replace").rstrip("\r")

    def _decode_block(self, block: bytes) -> list[str | None]:
        """The lines of ``block`` (lines separated by newlines, the last one without)."""
        if len(block) > self._max:
            ends = np.flatnonzero(np.frombuffer(block, dtype=np.uint8) == 10)
            lengths = np.diff(np.concatenate(([-1], ends, [len(block)]))) - 1
            if lengths.max() > self._max:
                return [self._decode_line(raw) for raw in block.split(b"\n")]
        # one decode for the block: a newline byte never belongs to a multibyte character, so this
        # is the decode of each line, invalid bytes replaced alike
        text = block.decode("utf-8", errors="replace")
        if "\r" in text:
            return [line.rstrip("\r") for line in text.split("\n")]
        return text.split("\n")


def _count(counts: dict[str, int], kind: str, n: int) -> None:
    counts[kind] = counts.get(kind, 0) + n


class TimeOrder:
    """One stream's records kept in file order and in time order.

    A record earlier than the previous kept one of its stream went back in time and is dropped
    (``report.went_back``); a record equal in every value to a kept record of the same time is
    a repeat and is dropped (``report.duplicates``): a repeat can only be recognised among
    records of one time. A record more than :data:`JUMP_CHECK_S` after the previous kept one is
    held until the next record of its stream: kept if that one is not earlier (a pause, or a
    clock set forward), else dropped as went back (one row stamped years ahead does not make
    the rest of its stream go back); at the end of the log it is kept. Each record's fate
    depends on the records before it and that next one only, so records fed in any pieces give
    the same records.

    Records come one at a time (:meth:`add`, then :meth:`take`) or as tables whose column 0
    is the time and whose every column is compared for repeats (:meth:`accept`).
    """

    def __init__(self, report: ReadReport, kind: str):
        self._report = report
        self._kind = kind
        self._last_t = -math.inf
        self._tail: set[tuple] = set()  # the kept records of time _last_t
        self._held: tuple[float, tuple] | None = None  # (time, record) far after the last kept one
        self._kept: list[tuple] = []  # kept records not yet taken
        self._behind = False  # its latest record went back: its clock has not passed _last_t again

    @property
    def pending_t(self) -> float:
        """The earliest time a later record of this stream can still be kept at: a record it holds
        back, or, while its records go back in time (a clock set back), the latest kept one's;
        inf when neither (its next records come after what it gave)."""
        held = self._held[0] if self._held is not None else math.inf
        return min(held, self._last_t) if self._behind else held

    def add(self, t: float, record: tuple) -> None:
        """One record of time ``t``; ``record`` holds all its values."""
        if self._held is not None:
            held_t, held = self._held
            self._held = None
            if t >= held_t:
                self._keep(held_t, held)
            else:
                _count(self._report.went_back, self._kind, 1)
        self._behind = t < self._last_t
        if t < self._last_t:
            _count(self._report.went_back, self._kind, 1)
        elif t == self._last_t:
            if record in self._tail:
                _count(self._report.duplicates, self._kind, 1)
            else:
                self._keep(t, record)
        elif t - self._last_t > JUMP_CHECK_S and self._last_t > -math.inf:
            self._held = (t, record)
        else:
            self._keep(t, record)

    def take(self, final: bool) -> list[tuple]:
        """The records kept since the last call (``final``: the log has ended, a held one is kept)."""
        if final and self._held is not None:
            self._keep(*self._held)
            self._held = None
        kept, self._kept = self._kept, []
        return kept

    def _keep(self, t: float, record: tuple) -> None:
        if t == self._last_t:
            self._tail.add(record)
        else:
            self._last_t = t
            self._tail = {record}
        self._kept.append(record)

    def accept(self, rows: np.ndarray, final: bool) -> np.ndarray:
        """The rows of ``rows`` (the stream's next records, a float table) that are kept."""
        if rows.shape[0] == 0 and (self._held is None or not final):
            return rows
        t = rows[:, 0]
        before = np.maximum.accumulate(np.concatenate(([self._last_t], t[:-1])))
        if self._held is not None or np.any((t - before > JUMP_CHECK_S) & (before > -math.inf)):
            for row in rows.tolist():  # a jump: record by record (the values stay the same floats)
                self.add(row[0], tuple(row))
            return np.array(self.take(final), dtype=np.float64).reshape(-1, rows.shape[1])
        back = t < before
        self._behind = bool(back[-1])
        if back.any():
            _count(self._report.went_back, self._kind, int(np.count_nonzero(back)))
            rows = rows[~back]
            if rows.shape[0] == 0:
                return rows
            t = rows[:, 0]
        same = t[1:] == t[:-1]
        at_last = bool(t[0] == self._last_t)
        if at_last or same.any():
            rows = self._drop_repeats(rows, same, at_last)
            if rows.shape[0] == 0:
                return rows
            t = rows[:, 0]
        last = float(t[-1])
        tail = set(map(tuple, rows[t == last].tolist()))
        self._tail = self._tail | tail if last == self._last_t else tail
        self._last_t = last
        return rows

    def _drop_repeats(self, rows: np.ndarray, same: np.ndarray, at_last: bool) -> np.ndarray:
        """``rows`` without the exact repeats among records of one time (and of the kept tail)."""
        shared = np.zeros(rows.shape[0], dtype=bool)  # rows sharing their time with another
        shared[1:] |= same
        shared[:-1] |= same
        shared[0] |= at_last
        index = np.flatnonzero(shared)
        tail = np.array(sorted(self._tail) if at_last else [], dtype=np.float64).reshape(-1, rows.shape[1])
        group = np.concatenate([tail, rows[index]])
        # sorted by every column (stable), repeats are neighbours and the first kept is the earliest
        by_value = np.lexsort(group.T[::-1])
        repeat = np.all(group[by_value[1:]] == group[by_value[:-1]], axis=1)
        drop = by_value[1:][repeat] - tail.shape[0]
        if drop.size == 0:
            return rows
        _count(self._report.duplicates, self._kind, int(drop.size))
        keep = np.ones(rows.shape[0], dtype=bool)
        keep[index[drop]] = False
        return rows[keep]


class LogClock:
    """The log's clock: the newest record so far, in file order, of the sensors the filter follows.
    A record stamped more than :data:`RECORD_BEHIND_LOG_S` before it came after a clock went
    back (the log's, or its sensor's alone) and is not kept. Records more than
    :data:`JUMP_CHECK_S` ahead of it move it only once two sensors have each given two such
    records in a row (a pause, or the log's clock set forward): a lone row stamped ahead, or one
    sensor whose clock ran ahead, does not. Its verdicts depend on the records before each in
    the file only, whatever pieces they come in."""

    def __init__(self) -> None:
        self.newest_t = -math.inf
        # sensor -> (its earliest record of its latest run far ahead of the clock, records in that run)
        self._ahead: dict[int, tuple[float, int]] = {}

    def keep_one(self, t_s: float, sensor: int) -> bool:
        """``keep`` of one record, without arrays (a reader's line-by-line path)."""
        return self._one(float(t_s), int(sensor))

    def keep(self, t_s, sensor) -> tuple[np.ndarray, np.ndarray]:
        """(each of these records is kept: within :data:`RECORD_BEHIND_LOG_S` of the clock before
        it (N,) bool; the clock before each (N,)) of the next records in file order (``sensor``:
        each one's sensor, a small integer); the clock moves on."""
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        if t.size == 0:
            return np.ones(0, dtype=bool), np.zeros(0)
        before = np.maximum.accumulate(np.concatenate(([self.newest_t], t[:-1])))
        if not self._ahead and not np.any((t - before > JUMP_CHECK_S) & (before > -math.inf)):
            self.newest_t = max(self.newest_t, float(t.max()))  # a record behind never holds the maximum
            return ~(t < before - RECORD_BEHIND_LOG_S), before
        sensors = np.broadcast_to(np.asarray(sensor), t.shape).tolist()
        kept, before = np.ones(t.size, dtype=bool), np.empty(t.size)
        for i, x in enumerate(t.tolist()):
            before[i] = self.newest_t
            kept[i] = self._one(x, int(sensors[i]))
        return kept, before

    def _one(self, t: float, sensor: int) -> bool:
        if t < self.newest_t - RECORD_BEHIND_LOG_S:
            return False
        if t - self.newest_t > JUMP_CHECK_S and self.newest_t > -math.inf:
            first, run = self._ahead.get(sensor, (t, 0))
            self._ahead[sensor] = (min(first, t), run + 1)
            moved = [first for first, run in self._ahead.values() if run >= 2]
            if len(moved) >= 2:  # two sensors went on far ahead: the log's clock moved on
                self.newest_t = min(moved)
                self._ahead = {k: v for k, v in self._ahead.items() if v[0] - self.newest_t > JUMP_CHECK_S}
            return True
        self._ahead.pop(sensor, None)
        self.newest_t = max(self.newest_t, t)
        return True


class ScanAssembler:
    """WiFi rows -> scans: the rows of one time are one scan, complete once a record of a later
    time (of any type: :meth:`clock`) has come, or the stream ends (:meth:`finish`).

    A row earlier than the scan being filled, or of the time of a scan already complete, went
    back in time and is dropped; an exact repeat within a scan is a duplicate. As in
    :class:`TimeOrder`, a scan more than :data:`JUMP_CHECK_S` after the previous one is held
    until the next scan begins, and dropped (its rows went back) if that one is earlier.
    """

    def __init__(self, report: ReadReport, kind: str):
        self._report = report
        self._kind = kind
        self.open_t = math.inf  # the time of the scan being filled (inf: none)
        self._open_far = False  # it is far after the scan before it
        self._rows: list[tuple] = []
        self._seen: set = set()
        self._last_t = -math.inf  # the time of the latest scan (not dropped)
        self._before_t = -math.inf  # the time of the scan before the one being filled
        self._held: tuple[float, list[tuple], float] | None = None  # a complete far scan, the time before it
        self._complete: list[list[tuple]] = []  # scans complete and not yet taken, each its rows
        self._behind = False  # its latest row went back: its clock has not passed _last_t again

    @property
    def pending_t(self) -> float:
        """The earliest time a later scan can still come at: the scan being filled, a far scan
        held back, or, while rows go back in time, the latest scan's; inf when none of those."""
        pending = min(self.open_t if self._rows else math.inf, self._held[0] if self._held is not None else math.inf)
        return min(pending, self._last_t) if self._behind else pending

    def add(self, t: float, row: tuple, log_t: float = -math.inf) -> None:
        """One WiFi row of scan time ``t``; ``row`` holds all its values; ``log_t``: the log's
        clock before it (``LogClock``), which a new scan may not be behind by more than
        :data:`SCAN_BEHIND_LOG_S`."""
        if t == self.open_t:
            if row in self._seen:
                _count(self._report.duplicates, self._kind, 1)
                return
            self._seen.add(row)
            self._rows.append(row)
            return
        if t > self.open_t or (self._open_far and t < self.open_t):
            self.finish()
        if self._held is not None:
            held_t, rows, before_t = self._held
            self._held = None
            if t >= held_t:
                self._complete.append(rows)
            else:
                _count(self._report.went_back, self._kind, len(rows))
                self._last_t = before_t
        self._behind = t <= self._last_t or t < log_t - SCAN_BEHIND_LOG_S
        if self._behind:  # behind its own scans, or the log's clock (SCAN_BEHIND_LOG_S)
            _count(self._report.went_back, self._kind, 1)
            return
        self._open_far = t - self._last_t > JUMP_CHECK_S and self._last_t > -math.inf
        self._before_t = self._last_t
        self.open_t = self._last_t = t
        self._rows = [row]
        self._seen = {row}

    def clock(self, t: float) -> None:
        """A record of time ``t`` came: a scan of an earlier time is complete."""
        if t > self.open_t:
            self.finish()

    def add_rows(self, rows: list[tuple], clock_before: np.ndarray, clock_after: float,
                 log_before: np.ndarray | None = None) -> None:
        """WiFi rows in file order (each's time first), each after a :meth:`clock` of
        ``clock_before`` (the latest record of another type since the row before: -inf, none),
        then a clock of ``clock_after``: what :meth:`add` and :meth:`clock` would do line by line
        (``log_before``: the log's clock before each row, ``add``'s ``log_t``)."""
        logs = log_before.tolist() if log_before is not None else [-math.inf] * len(rows)
        for row, t, log_t in zip(rows, clock_before.tolist(), logs):
            if t > self.open_t:
                self.finish()
            self.add(row[0], row, log_t)
        if clock_after > self.open_t:
            self.finish()

    def finish(self) -> None:
        """The scan being filled is complete."""
        if self._rows:
            if self._open_far:
                self._held = (self.open_t, self._rows, self._before_t)
            else:
                self._complete.append(self._rows)
        self._rows, self._seen = [], set()
        self.open_t = math.inf
        self._open_far = False

    def take(self, final: bool) -> list[list[tuple]]:
        """The complete scans since the last call (``final``: the log has ended, all are)."""
        if final:
            self.finish()
            if self._held is not None:
                self._complete.append(self._held[1])
                self._held = None
        scans, self._complete = self._complete, []
        return scans


class GapTracker:
    """The time gaps over every record so far (``report.time_gaps_s``, ``report.time_span_s``),
    kept as the runs of times with no gap: records of any time may come in any order."""

    def __init__(self, report: ReadReport, gap_s: float = GAP_REPORT_S):
        self._report = report
        self._gap_s = gap_s
        self._runs: list[tuple[float, float]] = []  # (first, last) time of each run, sorted

    def add(self, times_s: list[np.ndarray]) -> None:
        nonempty = [np.asarray(t, dtype=np.float64).ravel() for t in times_s if np.size(t)]
        if not nonempty:
            return
        every = np.sort(np.concatenate(nonempty))
        cuts = np.flatnonzero(np.diff(every) > self._gap_s)
        starts = every[np.concatenate(([0], cuts + 1))]
        ends = every[np.concatenate((cuts, [every.size - 1]))]
        runs = sorted(self._runs + list(zip(starts.tolist(), ends.tolist())))
        merged = [runs[0]]
        for start, end in runs[1:]:
            first, last = merged[-1]
            if start - last > self._gap_s:
                merged.append((start, end))
            elif end > last:
                merged[-1] = (first, end)
        self._runs = merged
        self._report.time_gaps_s = [(merged[i][1], merged[i + 1][0]) for i in range(len(merged) - 1)]
        self._report.time_span_s = (merged[0][0], max(end for _, end in merged))


def handle_each(handle_line: Callable[[int, str], None], first: int, lines: list[str | None],
                bad_row: Callable[[BadRow, int], None]) -> None:
    """``handle_line`` of each line in turn, a line it cannot use (or one too long) to ``bad_row``."""
    for line_no, text in enumerate(lines, first):
        try:
            if text is None:
                raise BadRow("?", f"line longer than {MAX_LINE_BYTES} bytes")
            handle_line(line_no, text)
        except BadRow as bad:
            bad_row(bad, line_no)


def split_by(labels: list[str]) -> dict[str, np.ndarray]:
    """The positions of each label in ``labels`` (ascending), labels in the order they first come."""
    codes = {label: j for j, label in enumerate(dict.fromkeys(labels))}
    code = np.fromiter(map(codes.__getitem__, labels), dtype=np.int64, count=len(labels))
    order = np.argsort(code, kind="stable")
    bounds = np.searchsorted(code[order], np.arange(len(codes) + 1))
    return {label: order[bounds[j]:bounds[j + 1]] for label, j in codes.items()}


def count_rows(report: ReadReport, kinds: list[str], counts: list[int]) -> None:
    """Add ``counts`` rows of ``kinds`` (in the order the kinds first came) to ``report.rows``."""
    for kind, n in zip(kinds, counts):
        report.rows[kind] = report.rows.get(kind, 0) + n


def count_went_back(report: ReadReport, kind: str, n: int = 1) -> None:
    """``n`` records of ``kind`` dropped: they came after the log's clock went back (``LogClock``)."""
    report.went_back[kind] = report.went_back.get(kind, 0) + n


def on_log_clock(clock: LogClock, report: ReadReport, kind: str, sensor: int, t_s: float, counted: bool) -> bool:
    """One record of a followed sensor on the log's clock: whether it is kept; one that is not is
    counted as went back when ``counted`` (a WiFi row is not: its scan's own rule decides,
    ``ScanAssembler``, and the row only moves the clock)."""
    kept = clock.keep_one(t_s, sensor)
    if not kept and counted:
        count_went_back(report, kind)
    return kept


def take_block(parsed: dict[str, tuple[np.ndarray, object]], begin: int, end: int, report: ReadReport,
               take: Callable[[str, object, np.ndarray], None], wifi_kind: str, scans: ScanAssembler,
               clock_s: np.ndarray, is_wifi: np.ndarray, log_clock: LogClock, followed: dict[str, int]) -> None:
    """The fast lines ``begin .. end - 1`` of a block parse (``parsed``: kind -> (its lines, its
    records, None for a kind not read)), as line by line: the records of the ``followed`` sensors
    (kind -> a small integer) put on the log's clock (``log_clock``: those that went back with it
    are counted in ``report.went_back``), each kind's records in the range to ``take(kind,
    records, kept)`` in the order of ``parsed``, the WiFi rows (``wifi_kind``) to ``scans`` with
    the clocks before them (``clock_s``, ``is_wifi``: each line's), the rows counted (the kinds
    read in the order their first line comes, the others as unknown)."""
    n_lines = end - begin
    on_clock = np.zeros(n_lines, dtype=bool)
    sensor_of = np.zeros(n_lines, dtype=np.int64)
    for kind, (index, _) in parsed.items():
        if kind in followed:
            lo, hi = np.searchsorted(index, (begin, end))
            on_clock[index[lo:hi] - begin] = True
            sensor_of[index[lo:hi] - begin] = followed[kind]
    keep, log_before = np.ones(n_lines, dtype=bool), np.full(n_lines, -np.inf)
    at = np.flatnonzero(on_clock)
    keep[at], log_before[at] = log_clock.keep(clock_s[begin:end][at], sensor_of[at])
    first_line, counts, wifi = [], [], None
    for kind, (index, records) in parsed.items():
        lo, hi = np.searchsorted(index, (begin, end))
        if hi == lo:
            continue
        first_line.append(int(index[lo]))
        counts.append((kind, int(hi - lo)))
        if records is None:
            continue
        if kind == wifi_kind:  # a scan's own rule decides whether it went back (ScanAssembler)
            wifi = records[lo:hi]
            continue
        kept = keep[index[lo:hi] - begin]
        if not kept.all():
            count_went_back(report, kind, int(np.count_nonzero(~kept)))
        take(kind, records[lo:hi], kept)
    order = np.argsort(first_line, kind="stable").tolist()
    known = [counts[i] for i in order if parsed[counts[i][0]][1] is not None]
    count_rows(report, [kind for kind, _ in known], [n for _, n in known])
    report.unknown_rows += sum(n for kind, n in counts if parsed[kind][1] is None)
    before, after = clock_before_rows(clock_s[begin:end], is_wifi[begin:end])
    scans.add_rows(wifi or [], before, after, log_before[is_wifi[begin:end]])


class LogParser(Protocol):
    """What a log format gives a :class:`RecordStream`: its lines in, records out."""

    FORMAT_NAME: str
    NEEDED_TYPES: frozenset[str]

    def __init__(self, report: ReadReport, max_wifi_age_s: float, strict: bool) -> None: ...

    def handle_line(self, line_no: int, line: str) -> None:
        """Read one line (without its line end); ``BadRow`` for a line it cannot use."""

    def handle_lines(self, first: int, lines: list[str | None], bad_row: Callable[[BadRow, int], None]) -> None:
        """Lines ``first``, ``first + 1``, ... (None: a line too long to read): what
        :meth:`handle_line` does to each in turn, the common rows parsed together; each line
        it cannot use goes to ``bad_row`` with its number."""

    def take(self, final: bool) -> Recording:
        """The records completed since the last call (``final``: the log has ended)."""


class RecordStream:
    """A log's text as it comes -> the records completed so far, by one format's parser.

    The machinery of ``sensors/logs.LogStream`` (which tells the format by content; see there
    for what a stream gives). ``parser``: the format's parser class, or None when a subclass
    chooses it (:meth:`_choose_parser`) from the first non-empty lines, held until then.
    """

    def __init__(self, name: str | os.PathLike, max_wifi_age_s: float, strict: bool,
                 needed: Iterable[str] | None, parser: type[LogParser] | None):
        self._report = ReadReport(path=Path(name))
        self._needed = None if needed is None else frozenset(needed)
        self._max_wifi_age_s = max_wifi_age_s
        self._strict = strict
        self._parser_class = parser
        self._parser: LogParser | None = None
        self._lines = LineSplitter()
        self._held: list[str | None] = []  # the lines before the format is known, from line 1
        self._seen_text = False
        self._closed = False
        self._new_lines = False  # lines handled since the last chunk
        self._last_chunk: Recording | None = None

    @property
    def report(self) -> ReadReport:
        """What the stream held and skipped so far (the live report, not a copy)."""
        return self._report

    @property
    def format(self) -> str | None:
        """The log's format ("ILC 2.0", "GetSensorData"); None while not yet known."""
        return self._report.format or None

    def feed_bytes(self, data: bytes) -> Recording:
        """The next bytes of the log, cut anywhere (inside a line or a UTF-8 character): the
        records completed since the previous call (possibly none)."""
        self._check_open()
        self._handle(*self._lines.feed(bytes(data)))
        return self._take(final=False)

    def feed_text(self, text: str) -> Recording:
        """The next text of the log, cut anywhere: a partial line is kept until its newline."""
        return self.feed_bytes(text.encode("utf-8", errors="surrogatepass"))

    def feed_lines(self, lines: Iterable[str]) -> Recording:
        """The next lines of the log, each with or without its line end (after text that ended
        inside a line, the first completes that line)."""
        return self.feed_text("".join(line.rstrip("\r\n") + "\n" for line in lines))

    def close(self, truncated: bool = False) -> Recording:
        """The end of the log: the rest of the records (with a last line that had no newline).

        ``truncated``: the log was cut short (a gzip stream without its end): a partial last
        line is dropped and the cut is reported, or refused with ``strict``. ``MapfilterError``
        when the log was empty, of no known format, or held no usable record.
        """
        self._check_open()
        self._closed = True
        path = self._report.path
        if truncated and self._strict:
            raise MapfilterError(f"gzip stream ends early after line {self._lines.n_lines} (truncated file)", path)
        if truncated:
            self._report.truncated_after_line = self._lines.n_lines
        self._handle(*self._lines.close(drop_partial=truncated))
        if self._parser is None:
            if not self._seen_text:
                blank = f" ({self._lines.n_lines} blank lines)" if self._lines.n_lines else ""
                raise MapfilterError(f"empty log{blank}", path)
            self._no_format(f"none of its {self._lines.n_lines} lines shows one")
        chunk = self._take(final=True)
        check_usable(self._report, path)
        return chunk

    def _choose_parser(self, line: str) -> type[LogParser] | None:
        """The parser for a log whose first non-empty line so far is ``line`` (None: look on)."""
        return self._parser_class

    def _no_format(self, reason: str) -> None:
        raise MapfilterError(f"unknown log format ({reason})", self._report.path)

    def _check_open(self) -> None:
        if self._closed:
            raise ValueError(f"{self._report.path}: the log stream is closed")

    def _handle(self, first: int, lines: list[str | None]) -> None:
        if self._parser is None:
            first, lines = self._sniff(first, lines)
        report = self._report
        report.n_lines = self._lines.n_lines
        if not lines:
            return
        self._new_lines = True
        self._parser.handle_lines(first, lines, self._bad_row)

    def _bad_row(self, bad: BadRow, line_no: int) -> None:
        report = self._report
        count_bad_row(report, bad, line_no, self._strict, report.path)

    def _sniff(self, first: int, lines: list[str | None]) -> tuple[int, list[str | None]]:
        """Hold lines until the format is known (at most ``SNIFF_LINES``, blank ones included);
        then all lines held so far (from line 1). Binary data is refused at its first line."""
        self._held.extend(lines)
        for line_no in range(first, first + len(lines)):
            text = self._held[line_no - 1]
            reason = no_format_reason(line_no, text)
            if reason is not None:
                self._seen_text = True
                self._no_format(reason)
            if text.strip():
                self._seen_text = True
                parser = self._choose_parser(text)
                if parser is not None:
                    report = self._report
                    report.format = parser.FORMAT_NAME
                    report.needed = parser.NEEDED_TYPES if self._needed is None else self._needed
                    self._parser = parser(report, self._max_wifi_age_s, self._strict)
                    held, self._held = self._held, []
                    return 1, held
            if line_no >= SNIFF_LINES:
                self._no_format(f"none of its first {SNIFF_LINES} lines shows one" if self._seen_text
                                else f"its first {SNIFF_LINES} lines are blank")
        return first, []

    def _take(self, final: bool) -> Recording:
        if self._parser is not None and (final or self._new_lines):
            chunk = self._last_chunk = self._parser.take(final)
        else:  # no line, no record: only the header fields known so far
            chunk = Recording.empty(self._report.path)
            if self._last_chunk is not None:
                last = self._last_chunk
                chunk.floor_name, chunk.start_t_s, chunk.phone_model = last.floor_name, last.start_t_s, last.phone_model
        self._new_lines = False
        chunk.read_report = self._report.copy()
        return chunk


def read_whole(path: str | os.PathLike, stream: RecordStream, warn: Callable[[str], None] | None) -> Recording:
    """A whole log file (plain or gzip) fed to ``stream`` in pieces and closed: the chunks as one
    ``Recording``. A gzip stream that ends early keeps the complete lines before the cut
    (refused with ``strict``); a corrupted one is refused. The report's warning, if any, goes
    to ``warn`` (else ``warnings.warn``)."""
    path = Path(path)
    if not path.is_file():
        raise MapfilterError("file not found", path)
    chunks = []
    truncated = False
    pending: list[bytes] = []  # pieces read and not yet fed: fed READ_CHUNK_BYTES at a time
    try:
        with open_binary(path) as handle:
            while data := handle.read1(READ_CHUNK_BYTES):
                pending.append(data)
                if sum(map(len, pending)) >= READ_CHUNK_BYTES:
                    chunks.append(stream.feed_bytes(b"".join(pending)))
                    pending = []
    except EOFError:
        # gzip without its end-of-stream marker: what was decompressed before the cut is fed
        truncated = True
    except (OSError, gzip.BadGzipFile, zlib.error) as exc:
        raise MapfilterError(f"cannot read log: {exc}", path) from None
    if pending:
        chunks.append(stream.feed_bytes(b"".join(pending)))
    chunks.append(stream.close(truncated=truncated))
    recording = concatenate(chunks)
    emit_warning(recording.read_report, warn, stacklevel=4)  # the caller of read_log / read_ilc / read_ipin
    return recording
