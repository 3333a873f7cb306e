"""Any phone log -> ``Recording``: the format is told by the file's content, not its name.

Two formats are known: the ILC 2.0 trace (``sensors/ilc.py``: tab-separated ``TYPE_...``
records, ``#`` header) and the GetSensorData log of the IPIN competitions (``sensors/ipin.py``:
``;``-separated ``ACCE``/``WIFI``/``POSI``... records, ``%`` header), each plain or gzip.
:func:`read_log` and :func:`read_log_header` are what commands and scripts call;
:class:`LogStream` reads a log as it arrives (a live phone, standard input, a competition
server), and :func:`read_log` is that stream fed the whole file.

Ground truth in latitude/longitude (GetSensorData ``POSI`` rows) is in metres only once the
walk is placed in a georeferenced building: :func:`localise` returns a new ``Recording`` with
``waypoint_xy_m`` in each waypoint's floor frame; ``read_log(..., building=...)`` does it on
reading.
"""

from __future__ import annotations

import dataclasses
import os
import zlib
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from mapfilter.errors import MapfilterError, not_a_file
from mapfilter.sensors import ilc, ipin
from mapfilter.sensors.logread import (SNIFF_LINES, LogParser, RecordStream, iter_bounded_lines, no_format_reason,
                                       open_binary, read_whole)
from mapfilter.sensors.recording import Recording

if TYPE_CHECKING:  # only for annotations
    from mapfilter.maps.building import Building

ILC = ilc.FORMAT_NAME
GETSENSORDATA = ipin.FORMAT_NAME
KNOWN_FORMATS = (f"{ILC} (tab-separated TYPE_... records, '#' header)",
                 f"{GETSENSORDATA} (IPIN; ';'-separated ACCE/WIFI/POSI... records, '%' header)")
_PARSERS: dict[str, type[LogParser]] = {ILC: ilc.IlcParser, GETSENSORDATA: ipin.GsdParser}


def format_of_line(line: str) -> str | None:
    """The format a non-empty line of a log's start shows (None: it shows none)."""
    if ipin.looks_like_getsensordata(line):
        return GETSENSORDATA
    if line.startswith("#") or "\tTYPE_" in line:
        return ILC
    return None


def _unknown_format(path: str | os.PathLike, reason: str) -> MapfilterError:
    return MapfilterError(f"unknown log format ({reason}): the known formats are {'; '.join(KNOWN_FORMATS)}", path)


class LogStream(RecordStream):
    """A phone log read as it arrives: feed it text or bytes in any pieces, get the records
    that each piece completed.

    ``LogStream(name, max_wifi_age_s, strict, needed, format)``: ``name`` names the log in
    errors and in the report (``"-"``: standard input); ``max_wifi_age_s``, ``strict`` and
    ``needed`` are the readers' (``needed`` None: the format's own); ``format`` ("ILC 2.0" or
    "GetSensorData") fixes the format, else it is told by the first non-empty lines as
    :func:`log_format` does, and text is held until it is known.

    :meth:`feed_text`, :meth:`feed_bytes` (UTF-8, invalid bytes replaced; a line longer than
    ``logread.MAX_LINE_BYTES`` is counted as unreadable and never held whole) and
    :meth:`feed_lines` each return a ``Recording`` of the records completed since the previous
    call: zero-length arrays when none (never None). A partial line is kept until its newline
    arrives. :meth:`close` returns the rest (with a last line that had no newline) and refuses
    a log that was empty, of no known format or without a usable record. :attr:`report` is the
    ``ReadReport`` so far; each chunk carries a copy of it as it stood.

    What a stream holds back, so that each record depends on the records before it only:

    - a WiFi scan until a record of a later time (of any type) arrives, or :meth:`close`:
      only then is it known to be complete;
    - a record more than ``logread.JUMP_CHECK_S`` (60 s) after the previous kept one of its
      type, until the next one of its type: dropped if that one goes back (a lone row stamped
      far ahead), kept otherwise and at :meth:`close`;
    - in a GetSensorData log, every record until the log's AppTimestamp passes its first
      record's by ``ipin.CLOCK_WINDOW_S`` (0.5 s): each sensor stream's clock offset is the
      median over that stretch (``sensors/ipin.py``).

    Within each record type, records keep file order; a record earlier than the previous kept
    one of its type went back in time and is dropped (``ReadReport.went_back``), an exact
    repeat of a record of the same time is dropped (``ReadReport.duplicates``). The chunks of
    a log, fed in any pieces, concatenated (``sensors/recording.concatenate``) are the
    ``Recording`` that :func:`read_log` gives, array by array.

    A log cut at the line where time passes T reads as the whole log's records up to the
    earliest time written after the cut (``Recording.until``; how far that is from T, format by
    format: docs/formats.md). A log cut at any line may end inside a WiFi scan: its rows so far
    are read as a complete scan.
    """

    def __init__(self, name: str | os.PathLike = "-", max_wifi_age_s: float = ilc.DEFAULT_MAX_WIFI_AGE_S,
                 strict: bool = False, needed: Iterable[str] | None = None, format: str | None = None):
        if format is not None and format not in _PARSERS:
            raise ValueError(f"unknown log format {format!r}: expected one of {', '.join(_PARSERS)}")
        super().__init__(name, max_wifi_age_s, strict, needed, _PARSERS.get(format))

    def _choose_parser(self, line: str) -> type[LogParser] | None:
        return self._parser_class or _PARSERS.get(format_of_line(line))

    def _no_format(self, reason: str) -> None:
        raise _unknown_format(self.report.path, reason)


def missing_log(path: str | os.PathLike) -> MapfilterError:
    """The error for a log path that is not a file: a directory names the logs meant."""
    return not_a_file(path, f"give the logs in it, e.g. {os.path.join(path, '*.txt.gz')}")


def log_format(path: str | os.PathLike) -> str:
    """``"ILC 2.0"`` or ``"GetSensorData"``, from the first lines of the file (plain or gzip).

    ``MapfilterError`` naming the file and the formats known when it is neither (or missing,
    empty or unreadable).
    """
    path = Path(path)
    if not path.is_file():
        raise missing_log(path)
    seen_any = False
    n_lines = 0
    try:
        with open_binary(path) as handle:
            for n_lines, line in iter_bounded_lines(handle):
                reason = no_format_reason(n_lines, line)
                if reason is not None:
                    raise _unknown_format(path, reason)
                if line.strip():
                    seen_any = True
                    fmt = format_of_line(line)
                    if fmt is not None:
                        return fmt
                if n_lines >= SNIFF_LINES:
                    break
    except EOFError:
        pass  # a cut gzip: decide on what came before the cut
    except (OSError, zlib.error) as exc:
        raise MapfilterError(f"cannot read log: {exc}", path) from None
    if not seen_any:
        raise MapfilterError(f"empty log ({n_lines} blank lines)" if n_lines else "empty log", path)
    raise _unknown_format(path, f"none of its first {n_lines} lines shows one")


def sniff_log_format(path: str | os.PathLike) -> str | None:
    """The format of ``path`` when it is a readable phone log, else None (never raises): for
    telling a log given where a map was meant (arguments in the wrong order)."""
    try:
        return log_format(path)
    except MapfilterError:
        return None


def read_log(path: str | os.PathLike, strict: bool = False, warn: Callable[[str], None] | None = None, *,
             max_wifi_age_s: float = ilc.DEFAULT_MAX_WIFI_AGE_S, building: Building | None = None) -> Recording:
    """Read a log of any known format (see :func:`log_format`) into a ``Recording``: a
    :class:`LogStream` fed the file and closed, its chunks concatenated.

    ``strict`` and ``warn`` are the readers' (bad rows refused, where the one-line warning
    goes). With ``building``, latitude/longitude ground truth is placed in it (:func:`localise`);
    a log whose ground truth is already in metres is returned as read.
    """
    if not Path(path).is_file():
        raise missing_log(path)  # a directory says so, and names the logs in it
    recording = read_whole(path, LogStream(path, max_wifi_age_s, strict), warn)
    if building is not None and recording.needs_georeference:
        recording = localise(recording, building)
    return recording


# a stretch longer than this with no record is a gap in the log, not walking time
SPAN_GAP_S = 60.0


def log_time_span_s(path: str | os.PathLike) -> float:
    """Seconds of walking in a log: from its first record to its last, read from their time
    stamps alone (ILC: the first column, ms; GetSensorData: a record's first time, s) without
    parsing the records, less any stretch over ``SPAN_GAP_S`` with no record: for estimating a
    run's time before it starts. 0 when the log has no timed record."""
    fmt = log_format(path)
    previous = None
    span = 0.0
    try:
        with open_binary(Path(path)) as handle:
            for _, line in iter_bounded_lines(handle):
                if not line or line[0] in "#%":
                    continue
                fields = line.split("\t" if fmt == ILC else ";", 2)
                try:
                    t = float(fields[0]) / 1000.0 if fmt == ILC else float(fields[1])
                except (IndexError, ValueError):
                    continue
                if previous is not None and 0.0 < t - previous <= SPAN_GAP_S:
                    span += t - previous
                previous = t if previous is None else max(previous, t)
    except EOFError:
        pass  # a cut gzip stream: the span up to the cut
    except (OSError, zlib.error) as exc:
        raise MapfilterError(f"cannot read log: {exc}", path) from None
    return span


def read_log_header(path: str | os.PathLike) -> dict[str, str]:
    """A log's header fields without reading its sensor records: ``FloorName`` (when the log
    names one floor), ``Model``, and ``format`` ("ILC 2.0" or "GetSensorData"), as strings."""
    fmt = log_format(path)
    if fmt == ILC:
        header = ilc.read_ilc_header(path)
        header["format"] = ILC
        return header
    return ipin.read_ipin_header(path)


def localise(recording: Recording, building: Building) -> Recording:
    """A new ``Recording`` whose latitude/longitude ground truth is in metres of the building.

    Each waypoint goes to the frame of its own floor (``waypoint_floor``, the venue's floor
    ids, which are the floor names of a building from ``mapfilter map import-ipin``); a
    one-floor building takes every waypoint on its floor. The input is not changed.
    ``MapfilterError`` naming the log when the building has no georeference or lacks a floor.
    """
    if recording.waypoint_latlon_deg is None or recording.waypoint_t_s.size == 0:
        return recording
    floors = recording.waypoint_floor
    if floors is None:
        if recording.floor_name is None and not building.is_single_floor:
            raise MapfilterError("the log names no floor for its ground truth", recording.path)
        floors = recording.floor_name or building.floors[0].name
    xy = building.latlon_to_floor_xy(recording.waypoint_latlon_deg, floors, recording.path)
    return dataclasses.replace(recording, waypoint_xy_m=np.ascontiguousarray(xy))
