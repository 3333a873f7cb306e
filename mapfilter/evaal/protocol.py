"""The IPIN competition's EvaalAPI protocol: the trial's state line, positions, estimates
and their score.

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
"""

from __future__ import annotations

import dataclasses
import math
import re
from array import array
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.evaluation.metrics import ipin_errors_m, ipin_score
from mapfilter.io.atomic import atomic_paths
from mapfilter.io.tracks import Track, with_latlon
from mapfilter.maps.building import Building, storey_of_floor_name
from mapfilter.maps.georef import LocalFrame
from mapfilter.sensors.logread import iter_bounded_lines, open_binary
from mapfilter.sensors.recording import Recording

if TYPE_CHECKING:
    from mapfilter.pipeline.tracker import TrackResult

DEFAULT_HORIZON_S = 0.5  # the horizon evaalapi.md recommends: one estimate every 0.5 s
MAX_ESTIMATES = 200_000  # an estimates file: one every 0.5 s for 28 hours (a trial is a walk)
ESTIMATE_STEP_S = 0.5  # offline: an estimate every 0.5 s of the log's clock (and at each POSI time)
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
    rows = _EstimateRows()
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
                if rows and t_s < rows.t_s[-1]:
                    raise MapfilterError(f"the time goes back ({t_s:g} s after {rows.t_s[-1]:g} s)", path, line_no)
                if len(rows) >= MAX_ESTIMATES:
                    raise MapfilterError(f"more than {MAX_ESTIMATES} estimates (one every 0.5 s for "
                                         f"{MAX_ESTIMATES / 2 / 3600:.0f} hours): not a trial's", path, line_no)
                rows.append(t_s, lon, lat, floor)
    except OSError as exc:
        raise MapfilterError(f"cannot read estimates: {exc}", path) from None
    if not rows:
        raise MapfilterError("no estimates in the file", path)
    return rows.estimates()


class _EstimateRows:
    """Estimates as they are read: four packed columns (32 bytes a row, not a tuple's 200)."""

    def __init__(self) -> None:
        self.t_s, self.lon_deg, self.lat_deg = array("d"), array("d"), array("d")
        self.floor = array("q")

    def __len__(self) -> int:
        return len(self.t_s)

    def append(self, t_s: float, lon_deg: float, lat_deg: float, floor: int) -> None:
        self.t_s.append(t_s)
        self.lon_deg.append(lon_deg)
        self.lat_deg.append(lat_deg)
        self.floor.append(floor)

    def estimates(self) -> Estimates:
        return Estimates(*(np.frombuffer(column, dtype=dtype).copy() for column, dtype in (
            (self.t_s, np.float64), (self.lon_deg, np.float64), (self.lat_deg, np.float64), (self.floor, np.int64))))


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


FAR_FROM_THE_POINTS_M = 1000.0  # a venue's POSI points lie within a few hundred metres of each other


def far_from_the_points(estimates: Estimates, recording: Recording, score: CompetitionScore) -> str | None:
    """A score that cannot be the venue's (a median error over ``FAR_FROM_THE_POINTS_M``): a line
    saying how far the estimates lie, naming latitude and longitude swapped when the swapped
    estimates lie near the points; None for a score within the venue."""
    if score.errors_m.size == 0 or float(np.median(score.errors_m)) <= FAR_FROM_THE_POINTS_M:
        return None
    far_km = float(np.median(score.errors_m)) / 1000.0
    if np.all(np.abs(estimates.lon_deg) <= 90.0):
        swapped = score_against_log(dataclasses.replace(estimates, lon_deg=estimates.lat_deg,
                                                        lat_deg=estimates.lon_deg), recording)
        near_m = float(np.median(swapped.errors_m)) if swapped.errors_m.size else math.inf
        if near_m <= FAR_FROM_THE_POINTS_M:
            return (f"the estimates lie {far_km:,.0f} km from the log's POSI points (median), and {near_m:.1f} m with "
                    "latitude and longitude swapped: the file has them swapped (its lines must be "
                    "pts,longitude,latitude,floor)")
    return (f"the estimates lie {far_km:,.0f} km from the log's POSI points (median): estimates of another venue "
            "or another log?")


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


def served_time_s(text: str) -> float | None:
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



def check_building(building: Building, where: str | None = None) -> None:
    """A building the competition's positions can come from: georeferenced, each floor with a
    number (``MapfilterError`` naming ``where`` otherwise)."""
    if building.georeference is None:
        raise MapfilterError("the competition wants latitude and longitude: the map has no georeference (make "
                             "the venue with 'mapfilter map import-ipin' or add a 'georeference' to its YAML)",
                             where or building.path)
    for floor in building.floors:
        floor_number(floor.name)
