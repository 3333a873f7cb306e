"""Any phone log -> ``Recording``: the format is told by the file's content, not its name.

Two formats are known: the ILC 2.0 trace (``sensors/ilc.py``: tab-separated ``TYPE_...``
records, ``#`` header) and the GetSensorData log of the IPIN competitions (``sensors/ipin.py``:
``;``-separated ``ACCE``/``WIFI``/``POSI``... records, ``%`` header), each plain or gzip.
:func:`read_log` and :func:`read_log_header` are what commands and scripts call.

Ground truth in latitude/longitude (GetSensorData ``POSI`` rows) is in metres only once the
walk is placed in a georeferenced building: :func:`localise` returns a new ``Recording`` with
``waypoint_xy_m`` in each waypoint's floor frame; ``read_log(..., building=...)`` does it on
reading.
"""

from __future__ import annotations

import dataclasses
import os
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from mapfilter.errors import MapfilterError, not_a_file
from mapfilter.sensors import ilc, ipin
from mapfilter.sensors.logread import iter_bounded_lines, open_binary
from mapfilter.sensors.recording import Recording

if TYPE_CHECKING:  # only for annotations
    from mapfilter.maps.building import Building

ILC = ilc.FORMAT_NAME
GETSENSORDATA = ipin.FORMAT_NAME
KNOWN_FORMATS = (f"{ILC} (tab-separated TYPE_... records, '#' header)",
                 f"{GETSENSORDATA} (IPIN; ';'-separated ACCE/WIFI/POSI... records, '%' header)")
# how far into a log its format is looked for: a header is some 40 lines
_SNIFF_LINES = 200


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
    try:
        with open_binary(path) as handle:
            for line_no, line in iter_bounded_lines(handle):
                if line is None or not line.strip():
                    continue
                seen_any = True
                if ipin.looks_like_getsensordata(line):
                    return GETSENSORDATA
                if line.startswith("#") or "\tTYPE_" in line:
                    return ILC
                if line_no >= _SNIFF_LINES:
                    break
    except EOFError:
        pass  # a cut gzip: decide on what came before the cut
    except (OSError, zlib.error) as exc:
        raise MapfilterError(f"cannot read log: {exc}", path) from None
    if not seen_any:
        raise MapfilterError("empty log", path)
    raise MapfilterError(f"unknown log format: the known formats are {'; '.join(KNOWN_FORMATS)}", path)


def sniff_log_format(path: str | os.PathLike) -> str | None:
    """The format of ``path`` when it is a readable phone log, else None (never raises): for
    telling a log given where a map was meant (arguments in the wrong order)."""
    try:
        return log_format(path)
    except MapfilterError:
        return None


def read_log(path: str | os.PathLike, strict: bool = False, warn: Callable[[str], None] | None = None, *,
             max_wifi_age_s: float = ilc.DEFAULT_MAX_WIFI_AGE_S, building: Building | None = None) -> Recording:
    """Read a log of any known format (see :func:`log_format`) into a ``Recording``.

    ``strict`` and ``warn`` are the readers' (bad rows refused, where the one-line warning
    goes). With ``building``, latitude/longitude ground truth is placed in it (:func:`localise`);
    a log whose ground truth is already in metres is returned as read.
    """
    fmt = log_format(path)
    reader = ilc.read_ilc if fmt == ILC else ipin.read_ipin
    recording = reader(path, max_wifi_age_s, strict=strict, warn=warn)
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
