"""The IPIN competition's trials: the EvaalAPI client (online and offline), the competition's
estimates and their score.

Since 2021 the IPIN competition's smartphone tracks run through EvaalAPI (the organisers' web
server, https://github.com/wnlab-isti/evaalapi; its evaalapi.md is the protocol), which plays a
trial's log to the competitor:

- online, the client asks for the next ``h`` seconds of log lines
  (``GET TRIAL/nextdata?horizon=h&position=POS``) and, with each request, sets its position for
  the trial time reached so far; the server keeps a slack ``s`` (at most ``S``):
  ``s += V h - (c - p)`` at each request (``c``, ``p``: the wall clock of this request and the
  previous one), and the trial times out when ``s < 0``. A scoring trial with ``V > 2`` refuses a
  request that comes faster than real time (423);
- offline, the client gets the whole log at once (``nextdata?offline``) and posts every estimate
  in one go (``POST TRIAL/estimates``, lines ``pts,POS``) within ``S`` seconds.

A position is ``longitude,latitude,floor`` (WGS-84 degrees; the floor's number, 0 the ground
floor, -1 the one below); the score is the 75th percentile of the horizontal error plus 15 m per
floor off, at the log's ground-truth (``POSI``) points.

Times. The server's times (``pts``) are the log's own clock: GetSensorData AppTimestamps, seconds
since the log started. The tracker stamps its rows in the recording's time, the header's creation
date plus the AppTimestamp (``sensors/ipin.py``); the server sends no header, so a log read from
it has no date and its rows are AppTimestamps. Either way a row's AppTimestamp is its time minus
``Recording.start_t_s`` (0 without a date): :func:`log_clock_offset_s`.

What an online estimate is. With the request for trial time T the client sends the latest row its
tracker has given after every line before T (the lines of ``[T - h, T)`` came with the previous
request). The tracker gives a row once the records it depends on are complete: a WiFi scan waits
for a record of a later time, the merged sensors wait for each other (a barometer sample every
0.1-0.17 s), an IMU sample's time is its sensor time (a few ms from its AppTimestamp). So a row
stamped just before T can come only with the next batch, and the estimate for T is then the row
before it: what a live system would have shown (on the IPIN 2023 logs a row is sent 0.3-0.5 s after
its stamp, median, at most 0.65 s). :func:`replay_online` is that client over a log file (the same
batches, no server): the estimates ``mapfilter evaal`` would send, to the bit. The ``POSI`` rows the
server may send are ground truth: the tracker does not read them, the offline estimates take their
times. The offline estimates are the whole-walk track at every 0.5 s of the log's clock from its
first line and at its ``POSI`` times, interpolated.

Connections. Every request has a timeout; a request whose connection dropped is sent again with
the same ``label`` (evaalapi.py answers a repeated label with the data it sent for it, so no batch
is lost or read twice; evaalapi.md does not list the parameter, and a server that refuses it is
asked without), after asking the trial's ``state`` where it stands.
"""

from __future__ import annotations

import dataclasses
import gzip
import http.client
import math
import re
import secrets
import time
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from mapfilter.atomic import atomic_paths
from mapfilter.errors import MapfilterError
from mapfilter.evaluation.metrics import ipin_errors_m, ipin_score
from mapfilter.maps.building import Building, storey_of_floor_name
from mapfilter.maps.georef import LocalFrame
from mapfilter.sensors.logs import LogStream
from mapfilter.sensors.logread import iter_bounded_lines, open_binary
from mapfilter.sensors.recording import Recording, concatenate
from mapfilter.tracking import TrackResult, Tracker
from mapfilter.trackio import Track, with_latlon

__all__ = ["DEFAULT_HORIZON_S", "ESTIMATE_STEP_S", "Estimates", "EvaalClient", "Reply", "TrialRun", "TrialState",
           "CompetitionScore", "competition_times", "floor_number", "log_clock_offset_s", "log_clock_s",
           "check_building", "check_replay", "offline_estimates", "read_estimates", "replay_log", "replay_offline",
           "replay_online", "run_offline", "run_online", "score_against_log", "score_estimates"]

DEFAULT_HORIZON_S = 0.5  # the horizon evaalapi.md recommends: one estimate every 0.5 s
ESTIMATE_STEP_S = 0.5  # offline: an estimate every 0.5 s of the log's clock (and at each POSI time)
# a scoring trial with V > 2 refuses a request less than h after the previous one (423): the
# client then waits this much beyond h (the server's clock reads the request a little later)
_PACE_MARGIN_S = 0.02
_SERVER_HEADER = "pts,c,h,s,pos"  # the first line of the server's estimates (GET TRIAL/estimates)


# ---- the server's state line -------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class TrialState:
    """A trial's state line (``GET TRIAL/state``; a 405 reply): ``TS,REM,V,S,p,h,PTS,POS``."""

    trial_s: float  # TS: the trial time the next estimate is for; 0 not started, -1 finished
    remaining_s: float  # REM: time left until a timeout; not started: -1 online, -2 offline
    slowdown: float  # V: the trial's time runs V times slower than real time (0: offline)
    slack_s: float  # S: the most slack a trial keeps (offline: the time allowed to post)
    previous_wall_s: float  # p: the wall clock of the previous request
    horizon_s: float  # h: the previous request's horizon (-2 offline)
    estimate_s: float  # PTS: the time of the latest estimate
    position: str  # POS: the latest estimate (not started: the initial position)

    @classmethod
    def parse(cls, text: str) -> TrialState:
        """The state line of ``text`` (``MapfilterError`` when it is not one)."""
        line = text.strip()
        fields = line.split(",", 7)
        try:
            numbers = [float(f) for f in fields[:7]]
        except ValueError:
            numbers = []
        if len(fields) != 8 or len(numbers) != 7 or not all(map(math.isfinite, numbers)):
            raise MapfilterError(f"the server's reply is not a trial state (TS,REM,V,S,p,h,PTS,POS): {line[:120]!r}")
        return cls(*numbers, fields[7])

    @property
    def offline(self) -> bool:
        return self.slowdown == 0.0

    @property
    def started(self) -> bool:
        """Running: a first ``nextdata`` came (its wall clock is ``p``), or finished."""
        return self.finished or self.trial_s > 0.0 or self.previous_wall_s > 0.0

    @property
    def finished(self) -> bool:
        return self.trial_s == -1.0

    @property
    def timed_out(self) -> bool:
        """Finished by a timeout (REM < 0 in a finished state)."""
        return self.finished and self.remaining_s < 0.0


# ---- HTTP ------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Reply:
    """One answer of the server."""

    status: int
    text: str


class _Dropped(Exception):
    """The connection dropped, timed out or was refused before an answer came."""


class EvaalClient:
    """The EvaalAPI commands of one trial over HTTP (standard library only).

    ``server_url``: the API's root, e.g. ``https://evaal.aaloa.org/evaalapi/``; ``trial``: the
    trial's name. Every request times out after ``timeout_s``; a dropped connection is retried for
    up to ``retry_s`` seconds (:meth:`call`), ``on_retry`` told each time.
    """

    def __init__(self, server_url: str, trial: str, timeout_s: float = 10.0, retry_s: float = 30.0,
                 on_retry: Callable[[str], None] | None = None,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        parts = urllib.parse.urlsplit(server_url)
        if parts.scheme not in ("http", "https") or not parts.netloc:
            raise MapfilterError(f"the server URL must be http://HOST[:PORT]/PATH or https://..., got {server_url!r}")
        if not trial or not re.fullmatch(r"[A-Za-z0-9_.~-]+", trial):
            raise MapfilterError(f"a trial name is letters, digits and _.~- only, got {trial!r}")
        if not (timeout_s > 0 and math.isfinite(timeout_s)) or not (retry_s >= 0 and math.isfinite(retry_s)):
            raise ValueError("timeout_s must be > 0 and retry_s >= 0")
        self.trial = trial
        self.url = server_url.rstrip("/") + "/" + trial
        self.timeout_s = timeout_s
        self.retry_s = retry_s
        self.on_retry = on_retry
        self.sleep = sleep
        self.dropped = 0  # requests sent again after a dropped connection

    def request(self, command: str, query: dict[str, str] | None = None, body: bytes | None = None) -> Reply:
        """One request: ``GET TRIAL/command?query`` (``POST`` with ``body``); raises ``_Dropped``
        when no answer came."""
        url = f"{self.url}/{command}" + (f"?{urllib.parse.urlencode(query)}" if query else "")
        headers = {"Accept-Encoding": "gzip"}  # the server compresses text when asked (Flask-Compress)
        if body is not None:
            headers["Content-Type"] = "text/csv; charset=us-ascii"  # the only type POST estimates takes
        req = urllib.request.Request(url, data=body, headers=headers, method="POST" if body is not None else "GET")
        try:
            with urllib.request.urlopen(req, timeout=self.timeout_s) as response:
                return Reply(response.status, _decode(response.read(), response.headers))
        except urllib.error.HTTPError as exc:  # an answer, with an error status
            with exc:
                try:
                    text = _decode(exc.read(), exc.headers)
                except (OSError, http.client.HTTPException):
                    text = ""
            return Reply(exc.code, text)
        except (urllib.error.URLError, OSError, http.client.HTTPException, EOFError) as exc:
            reason = getattr(exc, "reason", None) or exc
            raise _Dropped(f"{type(reason).__name__}: {reason}" if str(reason) else type(reason).__name__) from None

    def call(self, command: str, query: dict[str, str] | None = None, body: bytes | None = None,
             before_retry: Callable[[], Reply | None] | None = None) -> Reply:
        """:meth:`request`, sent again while the connection drops (for up to ``retry_s``, pausing
        0.2 s, then twice as long each time up to 2 s). ``before_retry`` runs before each new try
        and may return the answer instead (e.g. the trial finished meanwhile)."""
        deadline = time.monotonic() + self.retry_s
        pause_s = 0.2
        while True:
            try:
                return self.request(command, query, body)
            except _Dropped as exc:
                if time.monotonic() + pause_s > deadline:
                    raise MapfilterError(f"no answer from {self.url}/{command} ({exc}) for {self.retry_s:g} s: the "
                                         "server is down or unreachable; run the command again to continue "
                                         "(the trial's state says where it stands)") from None
                self.dropped += 1
                if self.on_retry is not None:
                    self.on_retry(f"{command}: {exc}; trying again in {pause_s:.1f} s")
                self.sleep(pause_s)
                pause_s = min(2 * pause_s, 2.0)
                if before_retry is not None:
                    answer = before_retry()
                    if answer is not None:
                        return answer

    def state(self) -> TrialState:
        """The trial's state (``GET TRIAL/state``)."""
        reply = self.call("state")
        _check_found(reply, self.trial)
        if reply.status != 200:
            raise MapfilterError(f"trial {self.trial}: the server answered {reply.status} to state: "
                                 f"{_short(reply.text)}")
        return TrialState.parse(reply.text)

    def reload(self) -> TrialState:
        """Put a test trial back to its start (``GET TRIAL/reload``; a scoring trial refuses: 422)."""
        reply = self.call("reload")
        _check_found(reply, self.trial)
        if reply.status != 200:
            raise MapfilterError(f"trial {self.trial} cannot be reloaded ({reply.status}: {_short(reply.text)}): only "
                                 "test trials can")
        return TrialState.parse(reply.text)

    def estimates(self) -> Reply:
        """The estimates the server holds (``GET TRIAL/estimates``: ``pts,c,h,s,pos`` lines)."""
        return self.call("estimates")


def _decode(data: bytes, headers) -> str:
    if (headers.get("Content-Encoding") or "").lower() == "gzip":
        data = gzip.decompress(data)
    return data.decode("utf-8", errors="replace")


def _short(text: str) -> str:
    text = " ".join(text.split())
    return text if len(text) <= 200 else text[:200] + "..."


def _check_found(reply: Reply, trial: str) -> None:
    if reply.status == 404:
        raise MapfilterError(f"the server has no trial {trial!r} (404): check the trial name and the server URL "
                             "(it ends in /evaalapi/)")


# ---- positions and estimates ----------------------------------------------------------------------
def floor_number(name: str) -> int:
    """The competition's floor number of a floor name: ``"-2"`` -> -2, ``"0"`` -> 0; ILC-style
    names by their storey (``F1`` -> 0, ``B1`` -> -1). ``MapfilterError`` for any other name."""
    text = str(name).strip()
    if re.fullmatch(r"[+-]?\d+", text):
        return int(text)
    storey = storey_of_floor_name(text)
    if storey is None:
        raise MapfilterError(f"floor {name!r} has no floor number: the competition wants 0 for the ground floor, "
                             "-1 for the one below; name the building's floors so (e.g. '0', '-1')")
    return storey


@dataclasses.dataclass(frozen=True)
class Estimates:
    """Competition estimates: at ``t_s`` (the log's clock, s) the position ``lon_deg``, ``lat_deg``
    (WGS-84) on floor number ``floor``."""

    t_s: np.ndarray  # (N,)
    lon_deg: np.ndarray  # (N,)
    lat_deg: np.ndarray  # (N,)
    floor: np.ndarray  # (N,) int

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    @classmethod
    def of_rows(cls, rows: Iterable[tuple[float, float, float, int]]) -> Estimates:
        """From (t_s, lon_deg, lat_deg, floor) rows."""
        table = np.array(list(rows), dtype=np.float64).reshape(-1, 4)
        return cls(table[:, 0].copy(), table[:, 1].copy(), table[:, 2].copy(), table[:, 3].astype(np.int64))

    def position(self, i: int) -> str:
        """Estimate ``i`` as the server takes it: ``lon,lat,floor`` (1e-9 degrees: 0.1 mm)."""
        return format_position(self.lon_deg[i], self.lat_deg[i], int(self.floor[i]))

    def lines(self) -> list[str]:
        """``pts,lon,lat,floor`` lines: what ``POST TRIAL/estimates`` takes (times to the ms, as the
        server keeps them)."""
        return [f"{self.t_s[i]:.3f},{self.position(i)}" for i in range(len(self))]

    def write(self, path: str | Path) -> None:
        """The :meth:`lines`, no header: the file can be posted as it is (atomically written)."""
        with atomic_paths(path) as (tmp,):
            tmp.write_text("".join(line + "\n" for line in self.lines()), encoding="ascii")


def format_position(lon_deg: float, lat_deg: float, floor: int) -> str:
    return f"{lon_deg:.9f},{lat_deg:.9f},{floor}"


def parse_position(text: str, where: str = "position") -> tuple[float, float, int]:
    """``lon,lat,floor`` (or ``;``-separated) -> (lon, lat, floor number)."""
    fields = re.split(r"[,;]", text.strip())
    try:
        lon, lat, floor = float(fields[0]), float(fields[1]), float(fields[2])
    except (ValueError, IndexError):
        raise MapfilterError(f"{where} is not longitude,latitude,floor: {text[:80]!r}") from None
    if len(fields) != 3 or not (-180.0 <= lon <= 180.0 and -90.0 <= lat <= 90.0) or floor != int(floor):
        raise MapfilterError(f"{where} is not longitude,latitude,floor (degrees, a whole floor number): {text[:80]!r}")
    return lon, lat, int(floor)


def read_estimates(path: str | Path) -> Estimates:
    """An estimates file: ``pts,lon,lat,floor`` lines (``mapfilter evaal``'s and ``track
    --evaal-out``'s, what the server takes), or the server's own list (``GET TRIAL/estimates``:
    the header ``pts,c,h,s,pos``, then ``pts,c,h,s,lon,lat,floor`` lines). Times must not go
    back; ``MapfilterError`` naming the file and line otherwise."""
    path = Path(path)
    if not path.is_file():
        raise MapfilterError("file not found", path)
    rows = []
    server = False
    try:
        with open_binary(path) as handle:
            for line_no, line in iter_bounded_lines(handle):
                if line is None:
                    raise MapfilterError("line too long for an estimate", path, line_no)
                text = line.strip()
                if not text:
                    continue
                if not rows and not server and text.replace(" ", "") == _SERVER_HEADER:
                    server = True
                    continue
                fields = text.split(",")
                width = 7 if server else 4
                if len(fields) != width:
                    raise MapfilterError(f"expected {width} comma-separated fields ("
                                         + ("pts,c,h,s,lon,lat,floor" if server else "pts,lon,lat,floor")
                                         + f"), got {len(fields)}", path, line_no)
                try:
                    t_s = float(fields[0])
                except ValueError:
                    raise MapfilterError(f"the time is not a number: {fields[0][:40]!r}", path, line_no) from None
                if not math.isfinite(t_s):
                    raise MapfilterError(f"the time is not finite: {fields[0]!r}", path, line_no)
                lon, lat, floor = parse_position(",".join(fields[-3:]), f"{path}:{line_no}: the position")
                if rows and t_s < rows[-1][0]:
                    raise MapfilterError(f"the time goes back ({t_s:g} s after {rows[-1][0]:g} s)", path, line_no)
                rows.append((t_s, lon, lat, floor))
    except OSError as exc:
        raise MapfilterError(f"cannot read estimates: {exc}", path) from None
    if not rows:
        raise MapfilterError("no estimates in the file", path)
    return Estimates.of_rows(rows)


def log_clock_offset_s(recording: Recording) -> float:
    """Recording time minus the log's own clock (AppTimestamp): the header's creation date, 0
    without one (a log from the server)."""
    return float(recording.start_t_s) if recording.start_t_s is not None else 0.0


def log_clock_s(t_s: np.ndarray, recording: Recording) -> np.ndarray:
    """Recording times on the log's own clock, to the microsecond (a date of 1.7e9 s plus an
    AppTimestamp is only kept to 2e-7 s: 68.0502 comes back as 68.05019999)."""
    return np.round(np.asarray(t_s, dtype=np.float64) - log_clock_offset_s(recording), 6)


def competition_times(first_s: float, last_s: float, posi_s: np.ndarray | None = None,
                      step_s: float = ESTIMATE_STEP_S) -> np.ndarray:
    """The times of offline estimates on the log's clock, to the millisecond (as the server keeps
    them): every ``step_s`` from the log's first line to its last, and every POSI time, rounded
    down (an estimate a fraction of a millisecond after its point would miss it); sorted, each once."""
    if not (math.isfinite(first_s) and math.isfinite(last_s) and last_s >= first_s):
        raise ValueError("first_s and last_s must be finite, first_s <= last_s")
    grid = first_s + step_s * np.arange(int(math.floor((last_s - first_s) / step_s + 1e-9)) + 1)
    posi = np.zeros(0) if posi_s is None else np.floor(np.asarray(posi_s, dtype=np.float64) * 1000.0 + 1e-6) / 1000.0
    return np.unique(np.concatenate([np.round(grid, 3), posi]))


def offline_estimates(track: Track, building: Building, times_s: np.ndarray, offset_s: float) -> Estimates:
    """A whole-walk track's estimates at ``times_s`` (the log's clock; track time = log time +
    ``offset_s``): the position interpolated in time (in latitude and longitude: the floors share
    the building's frame, and over a row's 0.5 s the two are linear in metres to far below a
    millimetre), the floor of the nearest row; clamped to the track's ends."""
    if len(track) == 0:
        raise MapfilterError("the track has no rows: no estimate can be made")
    latlon = with_latlon(track, building).latlon_deg if track.latlon_deg is None else track.latlon_deg
    names = track.floor if track.floor is not None else [building.floors[0].name] * len(track)
    floors = np.array([floor_number(n) for n in names], dtype=np.int64)
    t_log = track.t_s - offset_s
    times = np.asarray(times_s, dtype=np.float64)
    lat = np.interp(times, t_log, latlon[:, 0])
    lon = np.interp(times, t_log, latlon[:, 1])
    after = np.clip(np.searchsorted(t_log, times), 0, len(track) - 1)
    before = np.clip(after - 1, 0, len(track) - 1)
    nearest = np.where(np.abs(t_log[before] - times) <= np.abs(t_log[after] - times), before, after)
    return Estimates(times.copy(), lon, lat, floors[nearest])


# ---- scoring ---------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class CompetitionScore:
    """Estimates against a log's POSI points, as the competition counts them."""

    errors_m: np.ndarray  # (n,) horizontal error at each scored point
    floors_off: np.ndarray  # (n,) floors between the estimate's and the true one
    missed: int  # POSI points before the first estimate (not scored)
    n_points: int

    @property
    def score_m(self) -> float:
        """The IPIN score: the 75th percentile of error + 15 m per floor off (NaN: no point)."""
        return ipin_score(self.errors_m, self.floors_off)

    @property
    def competition_errors_m(self) -> np.ndarray:
        return ipin_errors_m(self.errors_m, self.floors_off)

    @property
    def floor_accuracy(self) -> float:
        return float(np.mean(self.floors_off == 0)) if self.errors_m.size else math.nan


def score_estimates(estimates: Estimates, posi_t_s: np.ndarray, posi_latlon_deg: np.ndarray,
                    posi_floor: list[str]) -> CompetitionScore:
    """Score ``estimates`` at the POSI points (times on the log's clock, latitude/longitude, floor
    ids): at each point the latest estimate at or before its time (what a live system showed when
    the walker passed it), the horizontal distance on the WGS-84 ellipsoid (the tangent plane at
    the first point: under a centimetre off over a building) and the floors between."""
    t = np.asarray(posi_t_s, dtype=np.float64)
    if t.size == 0:
        raise MapfilterError("the log has no POSI points to score against")
    latlon = np.asarray(posi_latlon_deg, dtype=np.float64).reshape(-1, 2)
    row = np.searchsorted(estimates.t_s, t, side="right") - 1
    have = row >= 0
    frame = LocalFrame(float(latlon[0, 0]), float(latlon[0, 1]))
    est = np.column_stack([estimates.lat_deg[row[have]], estimates.lon_deg[row[have]]])
    errors = np.linalg.norm(frame.to_xy_m(est) - frame.to_xy_m(latlon[have]), axis=1)
    truth = np.array([floor_number(f) for f in posi_floor], dtype=np.int64)
    floors_off = np.abs(estimates.floor[row[have]] - truth[have]).astype(np.float64)
    return CompetitionScore(errors, floors_off, int((~have).sum()), int(t.size))


def score_against_log(estimates: Estimates, recording: Recording) -> CompetitionScore:
    """:func:`score_estimates` at a log's POSI points (``read_log``'s recording)."""
    if recording.waypoint_latlon_deg is None or recording.waypoint_floor is None or not recording.has_ground_truth:
        raise MapfilterError("the log has no POSI points (latitude, longitude, floor) to score against",
                             recording.path)
    return score_estimates(estimates, log_clock_s(recording.waypoint_t_s, recording),
                           recording.waypoint_latlon_deg, list(recording.waypoint_floor))


# ---- the runs --------------------------------------------------------------------------------------
@dataclasses.dataclass
class TrialRun:
    """One trial entered (online or offline), or one log replayed as an online trial."""

    trial: str
    offline: bool
    estimates: Estimates  # what the server keeps from this run, in its order (online: one per request)
    requests: int  # nextdata requests the server took
    reply: str  # the server's last answer (online: the final state line; offline: the POST's)
    final: TrialState | None  # the state at the end (None: a replay)
    wall_s: float  # from the first request to the last answer
    slack_left_s: float | None  # online: the slack at the last request; offline: S minus the time taken
    lowest_slack_s: float | None  # online: the lowest slack at any request
    too_fast: int = 0  # requests refused as faster than real time (423), sent again later
    dropped: int = 0  # requests sent again after a dropped connection
    resumed_at_s: float | None = None  # a run that continued a running trial: the trial time it took over at
    result: TrackResult | None = None  # the tracker's run (None when it never gave a row)
    rows_given: np.ndarray | None = None  # online: the rows the tracker had given when each estimate was sent
    # online: the client's own time per batch, from an answer to the next request (the tracker's work;
    # a trial allows V h a request on average, S ahead)
    busy_s: np.ndarray | None = None

    @property
    def timed_out(self) -> bool:
        return self.final is not None and self.final.timed_out


def _first_time(text: str) -> float | None:
    """The time of the first line with a number, as the server reads it: its first numeric field."""
    for line in text.splitlines():
        for field in line.strip().split(";"):
            try:
                value = float(field)
            except ValueError:
                continue
            if math.isfinite(value):
                return value
    return None


class _OnlineTracker:
    """The tracker fed the batches of an online trial; the position of its latest row."""

    def __init__(self, tracker: Tracker, name: str) -> None:
        self.tracker = tracker
        self.building = tracker.building
        self.stream = LogStream(name)
        self.position: tuple[float, float, int] | None = None
        self.rows = 0

    def feed(self, text: str) -> None:
        chunk = self.stream.feed_text(text)
        self._rows(self.tracker.feed(chunk))

    def close(self) -> TrackResult | None:
        chunk = self.stream.close() if self.stream.format is not None else None
        if chunk is not None:
            self._rows(self.tracker.feed(chunk))
        self.tracker.close()
        return self.tracker.result() if self.rows else None

    def _rows(self, rows: Track) -> None:
        if len(rows):
            self.rows += len(rows)
            last = rows.rows(slice(len(rows) - 1, len(rows)))
            (lat, lon), = with_latlon(last, self.building).latlon_deg
            floor = floor_number(last.floor[0] if last.floor is not None else self.building.floors[0].name)
            self.position = (float(lon), float(lat), floor)


def run_online(client: EvaalClient, tracker: Tracker, horizon_s: float = DEFAULT_HORIZON_S, *,
               progress: Callable[[str], None] | None = None, progress_every_s: float = 30.0,
               clock: Callable[[], float] = time.time) -> TrialRun:
    """Enter an online trial with ``tracker`` (fresh, its building georeferenced): reads the
    trial's state, then asks for the next ``horizon_s`` of lines until the trial ends, sending with
    each request the latest row's position (before the first row: the position the server holds).

    A trial another run started is continued from its trial time with this fresh tracker. A request
    refused as faster than real time (423) is sent again ``h`` after the previous one, and from
    then on every request waits for that. ``progress`` gets a line every ``progress_every_s`` of
    trial time (the trial time, the requests, the slack as this client counts it). Returns the
    run, also when it timed out (``TrialRun.timed_out``); ``MapfilterError`` for an offline or
    finished trial, a refused request (422) or a lost server.
    """
    if not (horizon_s > 0 and math.isfinite(horizon_s)):
        raise MapfilterError(f"the horizon must be a positive number of seconds, got {horizon_s}")
    state = client.state()
    name = f"trial {client.trial}"
    if state.offline:
        raise MapfilterError(f"{name} is an offline trial: enter it with --offline")
    if state.finished:
        raise MapfilterError(f"{name} has finished{' by a timeout' if state.timed_out else ''}: a test trial can be "
                             "reloaded (--reload)")
    held = parse_position(state.position, f"{name}: the server's position")
    resumed = state.started
    online = _OnlineTracker(tracker, name)
    trial_s: float | None = state.trial_s if resumed else None
    sent: list[tuple[float, float, float, int]] = []
    given: list[int] = []
    busy: list[float] = []
    answered_s: float | None = None  # when the previous batch came
    labels = secrets.token_hex(4)  # this run's own request labels
    use_labels = True
    slowdown, slack_max_s = state.slowdown, state.slack_s
    slack_s, lowest_s = slack_max_s, math.inf
    previous_s: float | None = None  # wall clock of the previous request the server took
    previous_h = 0.0
    paced = False
    too_fast = requests = 0
    next_report_s = -math.inf
    started_s = clock()
    final: TrialState | None = None
    reply_text = ""
    while True:
        position = held if online.position is None else online.position
        query = {"horizon": f"{horizon_s:g}", "position": format_position(*position)}
        if use_labels:
            query["label"] = f"{labels}-{requests}"
        if answered_s is not None:
            busy.append(clock() - answered_s)
            answered_s = None
        if paced and previous_s is not None:
            wait_s = previous_s + previous_h + _PACE_MARGIN_S - clock()
            if wait_s > 0:
                client.sleep(wait_s)
        sent_s = clock()
        reply = client.call("nextdata", query, before_retry=_where_it_stands(client, trial_s, horizon_s))
        if reply.status == 423:  # faster than real time: from now on, wait h after the previous one
            too_fast += 1
            paced = True
            client.sleep(_PACE_MARGIN_S)  # the server's clock read the previous one later than ours: never spin
            continue
        if reply.status == 422 and use_labels and "label" in reply.text:
            use_labels = False  # a server without retry labels
            continue
        _check_found(reply, client.trial)
        if reply.status == 405:
            final = TrialState.parse(reply.text)
            reply_text = reply.text.strip()
            if not final.timed_out and trial_s is not None:
                sent.append((trial_s, *position))  # the server keeps the position of the request that ended it
                given.append(online.rows)
                requests += 1
            break
        if reply.status == 422:
            raise MapfilterError(f"{name}: the server refused the request (422): {_short(reply.text)}")
        if reply.status != 200:
            raise MapfilterError(f"{name}: the server answered {reply.status}: {_short(reply.text)}")
        requests += 1
        if previous_s is not None:
            slack_s = min(slack_max_s, slack_s + slowdown * previous_h - (sent_s - previous_s))
        lowest_s = min(lowest_s, slack_s)
        previous_s, previous_h = sent_s, horizon_s
        if trial_s is None:  # the first request: the server keeps its initial position at the first line
            trial_s = _first_time(reply.text)
            if trial_s is None:
                raise MapfilterError(f"{name}: the first batch of the log has no line with a time")
            sent.append((trial_s, *held))
        else:
            sent.append((trial_s, *position))
        given.append(online.rows)
        trial_s += horizon_s  # as the server counts it
        answered_s = clock()
        online.feed(reply.text)
        if progress is not None and trial_s >= next_report_s:
            progress(f"trial time {trial_s:.1f} s: {requests} requests, {online.rows} tracker rows, slack "
                     f"{slack_s:.1f} s (lowest {lowest_s:.1f} s)")
            next_report_s = trial_s + progress_every_s
    result = online.close()
    wall_s = clock() - started_s
    slack_left_s, lowest = _server_slack(client)
    return TrialRun(client.trial, False, Estimates.of_rows(sent), requests, reply_text, final, wall_s,
                    slack_left_s if slack_left_s is not None else slack_s,
                    lowest if lowest is not None else (lowest_s if math.isfinite(lowest_s) else None),
                    too_fast, client.dropped, state.trial_s if resumed else None, result, np.array(given),
                    np.array(busy))


def _where_it_stands(client: EvaalClient, trial_s: float | None, horizon_s: float) -> Callable[[], Reply | None]:
    """Before a ``nextdata`` is sent again: the trial's state. Finished: that is the answer (as the
    405 it would give). Still at ``trial_s`` (not taken) or one horizon on (taken: the repeated
    label gets the same lines back): send it again. Anywhere else: another client moved it."""
    def check() -> Reply | None:
        try:
            reply = client.request("state")
        except _Dropped:
            return None  # still down: the retry loop goes on
        if reply.status != 200:
            return None
        state = TrialState.parse(reply.text)
        if state.finished:
            return Reply(405, reply.text)
        if trial_s is not None and state.started and not any(
                abs(state.trial_s - t) < 1e-3 for t in (trial_s, trial_s + horizon_s)):
            raise MapfilterError(f"trial {client.trial} moved to trial time {state.trial_s:.3f} s while this client "
                                 f"was at {trial_s:.3f} s: is another client using it?")
        return None
    return check


def _server_slack(client: EvaalClient) -> tuple[float | None, float | None]:
    """(the slack at the last request, the lowest) from the server's own list of estimates."""
    try:
        reply = client.request("estimates")
    except _Dropped:
        return None, None
    if reply.status != 200:
        return None, None
    slack = []
    for line in reply.text.splitlines()[2:]:  # the header, then the initial position (s = S)
        fields = line.split(",")
        try:
            slack.append(float(fields[3]))
        except (IndexError, ValueError):
            continue
    return (slack[-1], min(slack)) if slack else (None, None)


def run_offline(client: EvaalClient, tracker: Tracker, *, progress: Callable[[str], None] | None = None,
                clock: Callable[[], float] = time.time) -> TrialRun:
    """Enter an offline trial with ``tracker`` (fresh, with ``config.smooth``): the whole log
    (``nextdata?offline``), the whole-walk track, then its estimates (:func:`competition_times`)
    posted in one go. Returns the run (the POST's answer in ``reply``; a timeout in
    ``timed_out``); ``MapfilterError`` for an online, started or finished trial."""
    name = f"trial {client.trial}"
    state = client.state()
    if not state.offline:
        raise MapfilterError(f"{name} is an online trial: enter it without --offline")
    if state.finished:
        raise MapfilterError(f"{name} has finished: a test trial can be reloaded (--reload)")
    if state.started:
        raise MapfilterError(f"{name} has started: an offline trial sends its log once; a test trial can be "
                             "reloaded (--reload)")
    if not tracker.config.smooth:
        raise ValueError("an offline trial posts the whole-walk track: give the tracker config.smooth")
    started_s = clock()

    def data_lost() -> Reply | None:
        state_now = client.state()
        if state_now.started or state_now.finished:
            raise MapfilterError(f"{name}: the connection dropped while the server sent the log, and an offline "
                                 "trial sends it once: a test trial can be reloaded (--reload)")
        return None

    reply = client.call("nextdata", {"offline": ""}, before_retry=data_lost)
    _check_found(reply, client.trial)
    if reply.status != 200:
        raise MapfilterError(f"{name}: the server answered {reply.status} to nextdata?offline: {_short(reply.text)}")
    if progress is not None:
        progress(f"the log: {reply.text.count(chr(10))} lines in {clock() - started_s:.1f} s; tracking (the server "
                 f"takes the estimates for {state.slack_s:g} s)")
    estimates, result = _offline_run(tracker, reply.text, name)
    taken_s = clock() - started_s
    if progress is not None:
        progress(f"{len(estimates)} estimates after {taken_s:.1f} s: posting")

    def posted_meanwhile() -> Reply | None:
        # the answer was lost with the connection: the state says whether the estimates were taken
        state_now = client.state()
        if not state_now.finished:
            return None
        return Reply(405 if state_now.timed_out else 201, "the server took the estimates (its answer was lost)")

    post = client.call("estimates", body="".join(line + "\n" for line in estimates.lines()).encode("ascii"),
                       before_retry=posted_meanwhile)
    final = client.state()
    if post.status not in (201, 409, 405):
        raise MapfilterError(f"{name}: the server answered {post.status} to the estimates: {_short(post.text)}")
    return TrialRun(client.trial, True, estimates, 1, post.text.strip(), final, clock() - started_s,
                    state.slack_s - taken_s, None, dropped=client.dropped, result=result)


def _offline_run(tracker: Tracker, text: str, name: str) -> tuple[Estimates, TrackResult]:
    """The whole log's text through ``tracker`` (with smoothing): the offline estimates at the
    competition's times (:func:`competition_times`) and the run."""
    stream = LogStream(name)
    recording = concatenate([stream.feed_text(text), stream.close()])
    first_s = _first_time(text)
    last_s = next((t for t in map(_first_time, reversed(text.splitlines())) if t is not None), None)
    if first_s is None or last_s is None:
        raise MapfilterError(f"{name}: the log has no line with a time")
    tracker.feed(recording)
    tracker.close()
    result = tracker.result()
    times = competition_times(first_s, last_s, log_clock_s(recording.waypoint_t_s, recording))
    return offline_estimates(result.offline, tracker.building, times, log_clock_offset_s(recording)), result


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
            t_s = _first_time(line)
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
    online = _OnlineTracker(tracker, str(log_path))
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
    estimates, result = _offline_run(tracker, text, str(log_path))
    return TrialRun(str(log_path), True, estimates, 1, "", None, time.perf_counter() - started, None, None,
                    result=result)


def _initial(initial: tuple[float, float, int] | None) -> tuple[float, float, int]:
    if initial is None:
        raise MapfilterError("the log has no POSI point to start from: give the initial position")
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


def check_building(building: Building, where: str | None = None) -> None:
    """A building the competition's positions can come from: georeferenced, each floor with a
    number (``MapfilterError`` naming ``where`` otherwise)."""
    if building.georeference is None:
        raise MapfilterError("the competition wants latitude and longitude: the map has no georeference (make "
                             "the venue with 'mapfilter map import-ipin' or add a 'georeference' to its YAML)",
                             where or building.path)
    for floor in building.floors:
        floor_number(floor.name)


def check_replay(building: Building, log_path: str | Path, map_path: str | Path | None = None) -> None:
    """Before a replay (``track --evaal-out``): a building the positions can come from
    (:func:`check_building`) and a GetSensorData log (``MapfilterError`` naming the file)."""
    from mapfilter.sensors.logs import GETSENSORDATA, log_format

    check_building(building, map_path)
    if log_format(log_path) != GETSENSORDATA:
        raise MapfilterError("the competition's trials are GetSensorData logs (IPIN); this is another format", log_path)


def replay_log(tracker: Tracker, log_path: str | Path, horizon_s: float = DEFAULT_HORIZON_S) -> TrialRun:
    """The estimates a trial of this log would get from ``tracker``: the offline ones
    (``replay_offline``) when its config smooths, else the online ones (``replay_online``)."""
    check_building(tracker.building)
    if tracker.config.smooth:
        return replay_offline(tracker, log_path)
    return replay_online(tracker, log_path, horizon_s)
