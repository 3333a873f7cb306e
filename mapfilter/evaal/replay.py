"""The EvaalAPI client over a log file, without a server (``track --evaal-out``): the file's
lines served as the server serves them, the same estimates ``client.py`` would send, to the bit.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.evaal.client import OnlineTracker, offline_run
from mapfilter.evaal.protocol import (DEFAULT_HORIZON_S, Estimates, TrialRun, check_building, floor_number,
                                      served_time_s)
from mapfilter.maps.building import Building
from mapfilter.pipeline.tracker import Tracker
from mapfilter.sensors.logread import iter_bounded_lines, open_binary


def _served_lines(log_path: str | Path) -> Iterable[tuple[str, float | None]]:
    """A log file's lines as the server serves them, with their time: from the first line with a
    time on (the header and the blank lines before it are not served)."""
    from mapfilter.sensors.logs import GETSENSORDATA, log_format

    path = Path(log_path)
    if log_format(path) != GETSENSORDATA:  # also one line naming the file when it is missing or no log
        raise MapfilterError("the competition's trials are GetSensorData logs (IPIN); this is another format", path)
    serving = False
    with open_binary(path) as handle:
        for _, line in iter_bounded_lines(handle):
            if line is None:
                continue  # longer than any record: the reader would skip it anyway
            t_s = served_time_s(line)
            serving = serving or (t_s is not None and not line.startswith("%"))
            if serving:
                yield line + "\n", t_s  # the reader gives lines without their end


def replay_online(tracker: Tracker, log_path: str | Path, horizon_s: float = DEFAULT_HORIZON_S,
                  initial: tuple[float, float, int] | None = None) -> TrialRun:
    """The online client over a log file, without a server: the file's lines served as the server
    serves them (no header; ``[T, T + h)`` of their first numeric field, from the first line with
    one), the same estimates at the same trial times, to the bit: what ``run_online`` sends on a
    trial of this log. ``initial`` (lon, lat, floor) is the trial's initial position, the log's
    first POSI point if not given."""
    if not (horizon_s > 0 and math.isfinite(horizon_s)):
        raise MapfilterError(f"the horizon must be a positive number of seconds, got {horizon_s}")
    online = OnlineTracker(tracker, str(log_path))
    batch: list[str] = []
    sent: list[tuple[float, float, float, int]] = []
    given: list[int] = []
    trial_s: float | None = None  # the server's trial time: the next request gets [trial_s, trial_s + h)
    started = time.perf_counter()
    for line, t_s in _served_lines(log_path):
        if trial_s is None:  # the first request: the initial position, kept at the first line's time
            initial = initial if initial is not None else _first_posi(log_path)
            trial_s = t_s
            sent.append((trial_s, *_initial(initial)))
            given.append(0)
        while t_s is not None and t_s >= trial_s + horizon_s:  # that batch is served: the next request
            online.feed("".join(batch))
            batch = []
            trial_s += horizon_s
            sent.append((trial_s, *(online.position or _initial(initial))))
            given.append(online.rows)
        batch.append(line)
    if trial_s is None:
        raise MapfilterError("the log has no line with a time", log_path)
    online.feed("".join(batch))
    trial_s += horizon_s
    sent.append((trial_s, *(online.position or _initial(initial))))  # the request that finds the log's end
    given.append(online.rows)
    result = online.close()
    return TrialRun(str(log_path), False, Estimates.of_rows(sent), len(sent), "", None, time.perf_counter() - started,
                    None, None, result=result, rows_given=np.array(given))


def replay_offline(tracker: Tracker, log_path: str | Path) -> TrialRun:
    """The offline client over a log file, without a server: the file's lines as the server serves
    them (no header), the whole-walk track (``tracker`` with ``config.smooth``), the estimates
    ``run_offline`` posts on a trial of this log, to the bit."""
    if not tracker.config.smooth:
        raise ValueError("the offline estimates are the whole-walk track's: give the tracker config.smooth")
    started = time.perf_counter()
    text = "".join(line for line, _ in _served_lines(log_path))
    estimates, result = offline_run(tracker, text, str(log_path))
    return TrialRun(str(log_path), True, estimates, 1, "", None, time.perf_counter() - started, None, None,
                    result=result)


_NO_START = ("the log has no POSI point to start the trial from: give the trial's initial position (the competition "
             "gives it with the trial): track --evaal-start LON,LAT,FLOOR, or replay_online(..., initial=(lon, lat, "
             "floor))")


def _initial(initial: tuple[float, float, int] | None) -> tuple[float, float, int]:
    if initial is None:
        raise MapfilterError(_NO_START)
    return initial


def _first_posi(log_path: str | Path) -> tuple[float, float, int] | None:
    with open_binary(Path(log_path)) as handle:
        for _, line in iter_bounded_lines(handle):
            if line is not None and line.startswith("POSI;"):
                fields = line.split(";")
                try:
                    return float(fields[4]), float(fields[3]), floor_number(fields[5])
                except (IndexError, ValueError, MapfilterError):
                    return None
    return None


def check_replay(building: Building, log_path: str | Path, map_path: str | Path | None = None, *,
                 online: bool = False, initial: tuple[float, float, int] | None = None) -> None:
    """Before a replay (``track --evaal-out``): a building the positions can come from
    (:func:`check_building`), a GetSensorData log, and for an ``online`` one an initial position
    (``initial``, or the log's first POSI point); ``MapfilterError`` naming the file otherwise."""
    from mapfilter.sensors.logs import GETSENSORDATA, log_format

    check_building(building, map_path)
    if log_format(log_path) != GETSENSORDATA:
        raise MapfilterError("the competition's trials are GetSensorData logs (IPIN); this is another format", log_path)
    if online and initial is None and _first_posi(log_path) is None:
        raise MapfilterError(_NO_START, log_path)


def replay_log(tracker: Tracker, log_path: str | Path, horizon_s: float = DEFAULT_HORIZON_S,
               initial: tuple[float, float, int] | None = None) -> TrialRun:
    """The estimates a trial of this log would get from ``tracker``: the offline ones
    (``replay_offline``) when its config smooths, else the online ones (``replay_online``, from
    ``initial`` or the log's first POSI point)."""
    check_building(tracker.building)
    if tracker.config.smooth:
        return replay_offline(tracker, log_path)
    return replay_online(tracker, log_path, horizon_s, initial)
