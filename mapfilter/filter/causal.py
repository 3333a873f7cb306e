"""The streaming tracker: a phone's records in, the causal estimate out, as they arrive.

A ``Tracker`` takes a walk's records in chunks of any size (``feed``: a ``Recording`` holding
some records of each sensor, in time order within each sensor; a whole recording is one chunk)
and gives the causal track's new rows after each chunk. Tracking a file is a replay of it.

Records are merged across sensors into one time order: a record is released once every sensor
still streaming has passed its time (a sensor that has sent nothing for ``PAUSED_AFTER_S``
while others go on is not waited for; a record older than what was released is late and
dropped, counted in ``late_records``). Released records become events, in time order:

- every detected step (PDR: ``sensors.pdr.OnlinePDR``, causal) moves the particles; for the
  ``cv``/``rw`` motion models a prediction tick does every ``tick_s``;
- every WiFi scan weighs them (its measurement from ``filter.evidence``);
- with a barometer in a building, an idle tick every ``IDLE_TICK_S`` without a step or scan
  lets the height weigh floors (a lift ride has no steps).

Each event is one filter step, and each step one row of the causal track, stamped with the time
a live system has it: a scan's own time, a step's ``available_s`` (the IMU sample that
revealed it). A row depends only on records stamped at or before its time, so the rows of a
log cut at any time are the rows of the whole log up to the cut, and feeding a log in chunks of
any size gives the same rows as feeding it whole.

The filter starts at the first scan with a usable measurement, drawn over the map's free space
from its likelihood (or around a given point); where nothing happened for longer than
``max_gap_s`` (a phone asleep, a row stamped years ahead), nothing is made for the gap and the
filter starts afresh at the next usable scan (``gaps``).
"""

from __future__ import annotations

import bisect
import dataclasses
import heapq
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.filter.estimate import circular_mean
from mapfilter.filter.events import CollapseEvent, StepReport
from mapfilter.filter.evidence import WalkEvidence
from mapfilter.filter.measurement import MeasurementSource
from mapfilter.filter.models.interface import FloorModel, MeasurementModel, MotionModel
from mapfilter.filter.models.motion import ConstantVelocityMotion, PDRMotion, RandomWalkMotion, StepInput
from mapfilter.filter.particle_filter import FilterConfig, ParticleFilter
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.sensors.logread import MAX_RECORD_LATENESS_S
from mapfilter.sensors.pdr import OnlinePDR, Steps
from mapfilter.sensors.recording import Recording
from mapfilter.sensors.wifi import iter_scans, scans_recording
from mapfilter.io.tracks import Track

__all__ = ["MOTION_MODELS", "CausalFilter", "Estimate", "MotionConfig", "RunSettings", "Start", "merge_steps",
           "run_over_scans"]

MOTION_MODELS = ("pdr", "cv", "rw")
# a sensor silent this long while others go on is not waited for: the ILC logger writes its IMU
# rows up to 1.8 s behind its WiFi rows, the GetSensorData logs every sensor in time order
PAUSED_AFTER_S = 3.0
# a log stream gives a WiFi scan once a record of a later time came (sensors/logs.LogStream), so the
# scans are taken as passed at the newest record's time less this (IMU samples' own times run a few ms
# from the times the scans are cut by): rows are not held for the next scan (docs/ipin.md)
SCAN_PASSED_BEFORE_NEWEST_S = 0.1
# while a sensor is paused (not waited for), nothing later than this before the newest record is
# released: no log reader gives a record farther behind the newest it gave (a clock set back is
# dropped, a time placed within its bound: logread.MAX_RECORD_LATENESS_S), so that a paused
# sensor's next record is never late however the log is chunked
PAUSED_RELEASE_BEHIND_S = MAX_RECORD_LATENESS_S
# at equal times, a step before a scan, ticks before both (a prediction to the scan's time)
_STEP, _SCAN, _TICK = 0, 1, 2
# PDR with a barometer in a building: the longest gap between filter steps. A lift ride has no
# steps, and scans are 2-4 s apart: about a walker's step interval, so the height weighs floors
# as often standing as walking
IDLE_TICK_S = 0.5
# PDR: spread of the start headings around the rotation vector's, which the building's steel
# bends by a few degrees (docs/accuracy.md)
INITIAL_HEADING_SIGMA_RAD = 0.2


@dataclasses.dataclass(frozen=True)
class MotionConfig:
    """How the particles move between measurements."""

    model: str = "pdr"  # pdr: steps and gyro (PDR) | cv: constant velocity | rw: random walk on a circle
    pdr: PDRMotion = dataclasses.field(default_factory=PDRMotion)  # the PDR motion model (thesis eq. 8.23)
    constant_velocity: ConstantVelocityMotion = dataclasses.field(default_factory=ConstantVelocityMotion)  # the cv model (Evennou & Marx)
    random_walk: RandomWalkMotion = dataclasses.field(default_factory=RandomWalkMotion)  # the rw model (Lund thesis eq. 6.6)
    tick_s: float = 1.0  # cv / rw: prediction interval between scans
    start_heading_from_rotation_vector: bool = True  # PDR: start headings from the rotation vector when the log has one
    # wide for the building's steel (tens of degrees in places); set before any run
    rotation_vector_sigma_deg: float = 25.0  # PDR: a scan outside the survey weighs headings against the rotation vector's by this spread (0: never)
    max_gap_s: float = 60.0  # nothing happened for longer than this: the filter starts afresh at the next scan

    def __post_init__(self) -> None:
        if self.model not in MOTION_MODELS:
            raise MapfilterError(f"unknown motion model {self.model!r}: choose one of {', '.join(MOTION_MODELS)}")
        for name in ("tick_s", "max_gap_s"):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise MapfilterError(f"motion setting {name} must be a positive number of seconds, got {value}")
        if not (self.rotation_vector_sigma_deg >= 0 and math.isfinite(self.rotation_vector_sigma_deg)):
            raise MapfilterError("motion setting rotation_vector_sigma_deg must be a number of degrees, 0 or more, "
                                 f"got {self.rotation_vector_sigma_deg}")

    @property
    def motion_model(self) -> MotionModel:
        """The motion model ``model`` names."""
        return {"pdr": self.pdr, "cv": self.constant_velocity, "rw": self.random_walk}[self.model]


# ---- records in: one time order over the sensors ---------------------------------------------------
_IMU = ("acc", "gyro", "rotvec")


class _Merge:
    """Per-sensor buffers of records released in one time order (``release``)."""

    def __init__(self) -> None:
        self.pending: dict[str, list] = {}  # sensor -> list of (t_s array, values...) chunks not yet released
        self.last_t: dict[str, float] = {}  # sensor -> time of its latest record
        self.released_t = -math.inf  # every record before this has been released
        self.late_records = 0
        # the reader may still give a record of this time (a scan being read, a stream whose
        # clock went back: ``Recording.pending_t_s``): nothing at or after it is released before it
        self.pending_t = math.inf

    def push(self, sensor: str, t_s: np.ndarray, *values) -> None:
        if len(t_s) == 0:
            return
        late = t_s < self.released_t
        if late.any():  # older than what was released: a live system has moved on
            self.late_records += int(np.count_nonzero(late))
            keep = ~late
            t_s, values = t_s[keep], tuple(v[keep] if isinstance(v, np.ndarray) else [x for x, k in zip(v, keep) if k]
                                           for v in values)
            if len(t_s) == 0:
                return
        self.pending.setdefault(sensor, []).append((t_s, *values))
        self.last_t[sensor] = max(self.last_t.get(sensor, -math.inf), float(t_s[-1]))

    def horizon(self, final: bool, passed_behind_s: dict[str, float] | None = None) -> float:
        """Records before this time can be released: every sensor still streaming has passed it.
        ``passed_behind_s``: {stream: s} of streams known to have passed the newest record's time
        less s (a sparse stream that was waited for would hold every row until its next record)."""
        if final:
            return math.inf
        if not self.last_t:
            return self.released_t
        newest = max(self.last_t.values())
        last = dict(self.last_t)
        behind = {"wifi": SCAN_PASSED_BEFORE_NEWEST_S, **(passed_behind_s or {})}
        for stream, behind_s in behind.items():
            if stream in last:
                last[stream] = max(last[stream], newest - behind_s)
        streaming = [t for t in last.values() if newest - t <= PAUSED_AFTER_S]
        horizon = min(min(streaming), self.pending_t)
        if len(streaming) < len(last):
            horizon = min(horizon, newest - PAUSED_RELEASE_BEHIND_S)
        return max(horizon, self.released_t)

    def release(self, horizon: float) -> dict[str, tuple]:
        """sensor -> (t_s, values...) of its records before ``horizon`` (all with ``inf``)."""
        out = {}
        for sensor, chunks in self.pending.items():
            if not chunks:
                continue
            parts = [np.concatenate([c[k] for c in chunks]) if isinstance(chunks[0][k], np.ndarray)
                     else [x for c in chunks for x in c[k]] for k in range(len(chunks[0]))]
            t_s = parts[0]
            n = int(np.searchsorted(t_s, horizon, side="left")) if math.isfinite(horizon) else len(t_s)
            if n:
                out[sensor] = tuple(p[:n] for p in parts)
            rest = tuple(p[n:] for p in parts)
            self.pending[sensor] = [rest] if len(rest[0]) else []
        if math.isfinite(horizon):
            self.released_t = max(self.released_t, horizon)
        return out


def _slice_steps(steps: Steps, start: int, stop: int) -> Steps:
    """Steps ``start`` to ``stop - 1``."""
    fields = {f.name: getattr(steps, f.name) for f in dataclasses.fields(Steps)}
    return Steps(**{name: value if name == "t0_s" or value is None else value[start:stop]
                    for name, value in fields.items()})


def _known_s(steps: Steps) -> np.ndarray:
    """When a live system has each step (``available_s`` where the detector gives it)."""
    available = getattr(steps, "available_s", None)
    return steps.t_s if available is None else available


class _StepLog:
    """The steps detected so far, kept in the pieces they came in: joining them at every chunk
    would copy the whole walk's steps each time (a live run's cost would grow with its length)."""

    def __init__(self) -> None:
        self._pieces: list[Steps] = []
        self._starts: list[int] = []  # the index of each piece's first step
        self._n = 0
        self._joined: Steps | None = None  # the pieces joined, kept until the next piece

    def __len__(self) -> int:
        return self._n

    def append(self, steps: Steps) -> None:
        if len(steps):
            self._pieces.append(steps)
            self._starts.append(self._n)
            self._n += len(steps)
            self._joined = None

    def heading_change_rad(self, index: int) -> float:
        """Step ``index``'s gyro heading change."""
        piece = bisect.bisect_right(self._starts, index) - 1
        return float(self._pieces[piece].heading_change_rad[index - self._starts[piece]])

    def latest_abs_heading_rad(self, t_s: float) -> float | None:
        """The rotation vector's heading at the latest step known at or before ``t_s`` (NaN: none
        yet); None when no step is known by then or the steps carry no such heading."""
        for piece in reversed(self._pieces):
            known = int(np.searchsorted(_known_s(piece), t_s, side="right"))
            if known:
                return None if piece.abs_heading_rad is None else float(piece.abs_heading_rad[known - 1])
        return None

    def joined(self) -> Steps | None:
        """Every step so far as one ``Steps`` (None before the first)."""
        if self._joined is None and self._pieces:
            self._joined = self._pieces[0]
            for piece in self._pieces[1:]:
                self._joined = merge_steps(self._joined, piece)
            self._pieces, self._starts = [self._joined], [0]
        return self._joined


def merge_steps(a: Steps | None, b: Steps) -> Steps:
    """``a`` followed by ``b`` (steps arrive in time order)."""
    if a is None or len(a) == 0:
        return b
    if len(b) == 0:
        return a
    fields = {}
    for field in dataclasses.fields(Steps):
        x, y = getattr(a, field.name), getattr(b, field.name)
        fields[field.name] = x if field.name == "t0_s" else (None if x is None or y is None else np.concatenate([x, y]))
    return Steps(**fields)


# ---- the tracker ------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Estimate:
    """One row of the causal track: the estimate a live system has at ``t_s``."""

    t_s: float
    xy_m: np.ndarray  # (2,) in the filter's plan frame (a building: the stack frame)
    std_m: float
    heading_rad: float  # NaN without PDR
    floor_shares: np.ndarray | None  # a building: the weight share of each floor
    floor_index: int | None  # a building: the estimate's floor


@dataclasses.dataclass(frozen=True)
class RunSettings:
    """The settings of a causal run: how particles move, the filter's own, and the heading the
    rotation vector's start heading is read against."""

    motion: MotionConfig
    filter: FilterConfig
    abs_heading_offset_rad: float = 0.0  # magnetic north to the map's +y axis (``PDRConfig``)


@dataclasses.dataclass(frozen=True)
class Start:
    """Where a run starts: from its first usable measurement's likelihood over the map, or, with
    ``xy_m``, ``share`` of the particles within ``radius_m`` of it (the rest from the likelihood).
    ``at_first_step``: a walk's known start, all particles there at its first step, which moves
    them from it (without steps: at the first usable measurement)."""

    xy_m: np.ndarray | None = None
    radius_m: float = 5.0
    share: float = 1.0
    at_first_step: bool = False


class CausalFilter:
    """The causal filter over a stream of records (module docstring).

    Parameters
    ----------
    plan : the filter's plan (a building's stack plan with ``floors``).
    evidence : the walk's measurements as they come (``filter.evidence``; empty at the start).
    settings, rng : the run's settings and its generator.
    steps : for the motion model ``pdr``: the walk's steps already detected (``Steps`` with
        ``available_s``: an evaluation detects them once per walk), or an ``OnlinePDR`` that
        detects them as the IMU records come.
    floors : the floor in the state (a building), else one floor.
    sources : measurement streams besides the WiFi scans (``MeasurementSource``).
    start : where the run starts (``Start``).
    on_step : called with every ``StepReport`` (the viewer, progress).
    history : keeps every step's cloud for the smoother (``offline.smoother``).
    """

    def __init__(self, plan: FloorPlan, evidence: WalkEvidence, settings: RunSettings, rng: np.random.Generator, *,
                 steps: Steps | OnlinePDR | None = None, floors: FloorModel | None = None,
                 sources: tuple[MeasurementSource, ...] = (), start: Start = Start(),
                 on_step: Callable[[StepReport], None] | None = None, history=None) -> None:
        motion = settings.motion
        self.evidence = evidence
        self.history = history  # an ``offline.smoother.ParticleHistory`` that keeps every step, or None
        self.sources = tuple(sources)
        self.motion = motion
        self.rng = rng
        self.pf = ParticleFilter(plan, motion.motion_model, settings.filter, rng, floors=floors)
        self._uses_steps = motion.model == "pdr"
        if self._uses_steps and steps is None:
            raise ValueError("PDR motion needs the walk's steps or an OnlinePDR")
        self._pdr = steps if isinstance(steps, OnlinePDR) else None
        self._given_steps = steps if isinstance(steps, Steps) else None
        self._abs_heading_offset_rad = settings.abs_heading_offset_rad
        # the rotation vector's heading weighs the particles' at each scan (0: not)
        self._rotation_vector_sigma_rad = math.radians(motion.rotation_vector_sigma_deg) if self._uses_steps else 0.0
        self._steps = _StepLog()  # the steps detected so far
        self._start_at = start
        self._on_step = on_step
        self._merge = _Merge()
        self._n_scans = 0  # scans released so far (the evidence may hold them already: a prepared walk)
        self._n_pressure = 0  # barometer readings released so far (likewise)
        self._events: list = []  # heap of (t_s, kind, sequence, payload)
        self._sequence = 0
        self._idle_ticks = motion.model == "pdr" and evidence.has_evidence_between_scans()
        self._rotvec: list[tuple[np.ndarray, np.ndarray]] = []  # released rotation-vector samples
        # the run's state
        self.started = False
        self._waiting_for_scan = False  # after a gap: start afresh at the next usable scan
        self._t0: float | None = None  # the first start (ticks count from it)
        self._last_event_t = -math.inf  # the latest event, used or not (the gap rule)
        self._last_row_t = -math.inf
        self._next_tick_t = math.inf
        self.rows: list[Estimate] = []
        self.gaps: list[tuple[float, float]] = []
        self.n_scans_used = 0
        self.closed = False

    # ---- records in --------------------------------------------------------------------------
    def feed(self, records: Recording) -> list[Estimate]:
        """Records of the walk (a ``Recording`` holding the next records of each sensor); returns the
        causal rows they completed."""
        if self.closed:
            raise RuntimeError("the tracker is closed")
        merge = self._merge
        merge.pending_t = records.pending_t_s
        merge.push("acc", records.acc_t_s, records.acc_mps2)
        merge.push("gyro", records.gyro_t_s, records.gyro_radps)
        merge.push("rotvec", records.rotvec_t_s, records.rotvec_xyz)
        merge.push("pressure", records.pressure_t_s, records.pressure_hpa)
        scans = list(iter_scans(records))
        if scans:
            merge.push("wifi", np.array([s.t_s for s in scans]), scans)
        for source in self.sources:
            taken = source.take(records)
            if taken is not None:
                merge.push(source.stream, *taken)
        return self._advance(final=False)

    def close(self) -> list[Estimate]:
        """The end of the walk: every record still held is processed; returns the last rows."""
        if self.closed:
            return []
        for source in self.sources:  # the records a source held back beyond the last chunk
            taken = source.take(None)
            if taken is not None:
                self._merge.push(source.stream, *taken)
        rows = self._advance(final=True)
        self.closed = True
        return rows

    @property
    def late_records(self) -> int:
        """Records dropped because they came after later ones had been processed."""
        return self._merge.late_records

    def _advance(self, final: bool) -> list[Estimate]:
        merge = self._merge
        horizon = merge.horizon(final, {s.stream: s.written_behind_s for s in self.sources
                                        if s.written_behind_s is not None})
        released = merge.release(horizon)
        n_before = len(self.rows)
        self._take_steps(released, final)
        if "pressure" in released and hasattr(self.evidence, "add_pressure"):
            t_s, hpa = released["pressure"]
            first = self._n_pressure
            self._n_pressure += len(t_s)
            known = self.evidence.n_pressure  # a prepared walk's evidence holds them already
            if known < self._n_pressure:
                self.evidence.add_pressure(t_s[max(known - first, 0):], hpa[max(known - first, 0):])
        if "wifi" in released:
            scans = list(released["wifi"][1])
            first = self._n_scans
            self._n_scans += len(scans)
            known = len(self.evidence.scans)
            if known < self._n_scans:
                self.evidence.add_scans(scans[max(known - first, 0):])
            for k, scan in enumerate(scans):
                self._push_event(float(scan.t_s), _SCAN, first + k)
        for number, source in enumerate(self.sources):
            if source.stream not in released:
                continue
            first = source.n_measurements
            times = source.add(released[source.stream], final)
            for k, t_s in enumerate(times):
                self._push_event(float(t_s), _SCAN, first + k, number)
        if final:  # every event, and ticks up to the last record or event
            last = max(merge.last_t.values()) if merge.last_t else -math.inf
            self._run_events(math.inf, inclusive=True)
            self._ticks_until(max(last, self._last_event_t), inclusive=True)
        else:
            self._run_events(horizon, inclusive=False)
        self._forget_old_rotation_vectors()
        return self.rows[n_before:]

    def _forget_old_rotation_vectors(self) -> None:
        """Keep the rotation-vector samples a later start can ask for: from the latest one at or
        before the latest event on (every later event is at or after it)."""
        rotvec = self._rotvec
        for i in range(len(rotvec) - 1, 0, -1):
            if rotvec[i][0].size and rotvec[i][0][0] <= self._last_event_t:
                del rotvec[:i]
                return

    def _take_steps(self, released: dict, final: bool) -> None:
        """The steps the released IMU records revealed, as events at the time each became known."""
        if not self._uses_steps:
            return
        if self._given_steps is not None:
            steps = self._given_steps
            done = len(self._steps)
            horizon = self._merge.released_t if not final else math.inf
            n = int(np.searchsorted(_known_s(steps), horizon, side="left")) if math.isfinite(horizon) else len(steps)
            new = _slice_steps(steps, done, n)
        else:
            t, stream, values = _imu_in_order(released)
            new = self._pdr.feed(t, stream, values) if t.size else None
            if final:
                tail = self._pdr.close()
                new = tail if new is None else merge_steps(new, tail)
        if "rotvec" in released:
            self._rotvec.append(released["rotvec"])
        if new is None or len(new) == 0:
            return
        first = len(self._steps)
        self._steps.append(new)
        known = _known_s(new)
        for k in range(len(new)):
            self._push_event(float(known[k]), _STEP, first + k)

    def _push_event(self, t_s: float, kind: int, index: int, source: int = -1) -> None:
        """An event at ``t_s``: a step, or measurement ``index`` of the WiFi evidence (source -1) or of
        ``sources[source]``."""
        heapq.heappush(self._events, (t_s, kind, self._sequence, source, index))
        self._sequence += 1

    # ---- events -----------------------------------------------------------------------------
    def _run_events(self, end_t: float, inclusive: bool) -> None:
        """Every event before ``end_t`` (at or before, with ``inclusive``), with the ticks between."""
        events = self._events
        while events and (events[0][0] < end_t or (inclusive and events[0][0] <= end_t)):
            t_s, kind, _, source, index = heapq.heappop(events)
            self._ticks_until(t_s, inclusive=False)
            self._event(t_s, kind, index, source)
        if math.isfinite(end_t):
            self._ticks_until(end_t, inclusive)

    def _ticks_until(self, end_t: float, inclusive: bool) -> None:
        """Prediction ticks (cv, rw) or idle ticks (PDR with a barometer) before ``end_t``."""
        while self.started and not self._waiting_for_scan:
            tick = self._next_tick_t
            if not (tick < end_t or (inclusive and tick <= end_t)) or tick - self._last_event_t > self.motion.max_gap_s:
                return
            self._tick(tick)

    def _schedule_ticks(self) -> None:
        """The next tick after an event: cv / rw tick every ``tick_s`` from the first start; PDR
        with a barometer ticks ``IDLE_TICK_S`` after the latest step or scan."""
        if not self._uses_steps:
            k = math.floor((self._last_event_t - self._t0) / self.motion.tick_s) + 1
            self._next_tick_t = self._t0 + k * self.motion.tick_s
        elif self._idle_ticks:
            self._next_tick_t = self._last_event_t + IDLE_TICK_S
        else:
            self._next_tick_t = math.inf

    def _tick(self, t_s: float) -> None:
        if self._uses_steps:
            # PDR standing still (a lift ride): only the barometer has news
            between = self.evidence.between_scans(t_s)
            if between is not None:
                self._step(t_s, None, self.evidence.model, between)
            self._next_tick_t = t_s + IDLE_TICK_S
        else:
            self._step(t_s, None, None, None)
            self._next_tick_t = t_s + self.motion.tick_s

    def _source(self, source: int):
        """(model, measurement getter) of the WiFi evidence (-1) or of a source."""
        if source < 0:
            return self.evidence.model, self.evidence.measurement
        return self.sources[source].model, self.sources[source].measurement

    def _event(self, t_s: float, kind: int, index: int, source: int = -1) -> None:
        if self.started and not self._waiting_for_scan and t_s - self._last_event_t > self.motion.max_gap_s:
            # start afresh at the next usable scan: the gap's length says nothing about where
            self.gaps.append((self._last_row_t, t_s))
            self._waiting_for_scan = True
        self._last_event_t = t_s
        if kind == _SCAN:
            model, measurement_of = self._source(source)
            measurement = measurement_of(index)
            if measurement is None:
                return
            if source < 0:
                measurement = self._with_rotation_vector(t_s, measurement)
            if not self.started or self._waiting_for_scan:
                self._start(t_s, model, measurement)
            else:
                # cv / rw move over the time since the last step by themselves; PDR only on steps
                self._step(t_s, None, model, measurement)
            self.n_scans_used += source < 0
        elif kind == _STEP and not self.started and self._start_at.at_first_step:
            # the walker stood at the known start until this step: placed there, then moved by it
            self._start(t_s, None, None, row=False)
            self._event(t_s, kind, index, source)
            return
        elif kind == _STEP and self.started and not self._waiting_for_scan:
            # in a building with a barometer, the height weighs floors at every step, not only at scans
            between = self.evidence.between_scans(t_s)
            step_input = StepInput(1, self._steps.heading_change_rad(index))
            self._step(t_s, step_input, self.evidence.model if between is not None else None, between)
        if self.started:
            self._schedule_ticks()

    def _step(self, t_s: float, step_input: StepInput | None, model, measurement) -> None:
        dt_s = max(t_s - self._last_row_t, 0.0)
        report = self.pf.step(t_s, dt_s, step_input, model, measurement)
        if self.history is not None:
            self.history.record(t_s, self.pf.particles.state, report.particles_weight, step_input, dt_s,
                                self.pf.last_jitter_m2, report.collapse is not None)
        self._add_row(report.t_s, report.estimate_xy_m, report.estimate_std_m,
                      report.heading_rad if report.heading_rad is not None else math.nan,
                      report.floor_shares, report.floor_index)
        self.evidence.observe(report)
        if self._on_step is not None:
            self._on_step(report)

    def _start(self, t_s: float, model: MeasurementModel, measurement: Any, row: bool = True) -> None:
        """Particles at a measurement: from its likelihood over the map, or around the start point
        (``row``: the start is a row of the track; else the step that follows at ``t_s`` is)."""
        pf = self.pf
        start = self._start_at
        if start.xy_m is None or self.started:
            pf.initialise_from_measurement(t_s, model, measurement)
        elif start.share < 1.0:
            pf.initialise_from_measurement_and_around(t_s, model, measurement, start.xy_m, start.radius_m, start.share)
        else:
            pf.initialise_around(start.xy_m, start.radius_m)
        if self._uses_steps:
            self._start_headings(t_s)
        self.started, self._waiting_for_scan = True, False
        if self._t0 is None:
            self._t0 = t_s
        particles = pf.particles
        report = pf.floors.report(particles.xy_m, particles.weight, pf.estimate_xy_m)
        heading = circular_mean(particles.heading_rad, particles.weight) if self._uses_steps else math.nan
        if self.history is not None:
            self.history.record(t_s, particles.state, particles.weight, None, 0.0, 0.0, True)
        if not row:
            self._last_row_t = float(t_s)
            return
        self._add_row(t_s, pf.estimate_xy_m.copy(), pf.estimate_std_m, heading, report.get("floor_shares"),
                      report.get("floor_index"))

    def _with_rotation_vector(self, t_s: float, measurement: Any) -> Any:
        """A scan's fix with the rotation vector's heading at the latest step known at ``t_s``
        (``filter.models.survey_reach``'s heading term), when the fix takes one and there is one."""
        if self._rotation_vector_sigma_rad <= 0 or not hasattr(measurement, "heading_rad"):
            return measurement
        heading = self._steps.latest_abs_heading_rad(t_s)
        if heading is None or not math.isfinite(heading):
            return measurement
        return dataclasses.replace(measurement, heading_rad=heading, heading_sigma_rad=self._rotation_vector_sigma_rad)

    def _start_headings(self, t_s: float) -> None:
        """PDR particles start with the rotation vector's heading (plus spread), else uniform: the
        gyro heading is relative; the rotation vector (magnetometer) gives the map heading, biased
        by the building's steel. The heading of the latest step known at the start, else of the
        latest rotation-vector sample."""
        n = self.pf.n
        heading = None
        if self.motion.start_heading_from_rotation_vector:
            heading = self._steps.latest_abs_heading_rad(t_s)
            if heading is None:
                heading = self._rotation_vector_heading(t_s)
        if heading is not None and math.isfinite(heading):
            self.pf.particles.heading_rad = heading + INITIAL_HEADING_SIGMA_RAD * self.rng.standard_normal(n)
        else:
            self.pf.particles.heading_rad = self.rng.uniform(-math.pi, math.pi, n)

    def _rotation_vector_heading(self, t_s: float) -> float | None:
        """The map heading of the phone's forward axis by the latest rotation-vector sample at or before
        ``t_s`` (``sensors.pdr.rotation_vector_heading`` of one sample), or None."""
        for t, xyz in reversed(self._rotvec):
            k = int(np.searchsorted(t, t_s, side="right"))
            if k:
                return float(rotation_vector_heading_of(xyz[k - 1], self._abs_heading_offset_rad))
        return None

    def _add_row(self, t_s, xy_m, std_m, heading_rad, floor_shares, floor_index) -> None:
        self.rows.append(Estimate(float(t_s), np.asarray(xy_m, dtype=np.float64), float(std_m), float(heading_rad),
                                  None if floor_shares is None else np.asarray(floor_shares, dtype=np.float64),
                                  None if floor_index is None else int(floor_index)))
        self._last_row_t = float(t_s)

    # ---- outputs ----------------------------------------------------------------------------
    @property
    def steps(self) -> Steps | None:
        """The steps detected so far (None before the first)."""
        return self._steps.joined()

    @property
    def collapses(self) -> tuple[CollapseEvent, ...]:
        return tuple(self.pf.collapses)

    @property
    def floor_shares(self) -> np.ndarray | None:
        """(T, F) the weight share of each floor per row, or None (one floor)."""
        return _floor_shares(self.rows)

    def track(self, rows: list[Estimate] | None = None) -> Track:
        """The causal rows so far (or ``rows``, e.g. those one ``feed`` returned) as a track in the
        plan's frame (``floor_p``: the share of the estimate's floor, in a building); headings
        with PDR motion only."""
        rows = self.rows if rows is None else rows
        shares = _floor_shares(rows)
        floor_p = None
        if shares is not None:
            # a probability (the shares of normalised weights may sum to 1 + 1e-16)
            floor_p = np.clip(shares[np.arange(len(rows)), [r.floor_index for r in rows]], 0.0, 1.0)
        heading = np.array([r.heading_rad for r in rows]) if self._uses_steps else None
        return Track(np.array([r.t_s for r in rows]), np.array([r.xy_m for r in rows]).reshape(-1, 2),
                     np.array([r.std_m for r in rows]), heading, name="pf", floor_p=floor_p)


def _floor_shares(rows: list[Estimate]) -> np.ndarray | None:
    """(T, F) the weight share of each floor per row, or None (one floor)."""
    if not rows or any(r.floor_shares is None for r in rows):
        return None
    return np.array([r.floor_shares for r in rows])

def rotation_vector_heading_of(xyz: np.ndarray, offset_rad: float) -> float:
    """Map heading of the phone's forward (+y) axis from one Android rotation vector (x, y, z of a
    unit quaternion, w >= 0): atan2(north, east) of the device y axis in East-North-Up."""
    x, y, z = (float(v) for v in xyz)
    w = math.sqrt(max(1.0 - x * x - y * y - z * z, 0.0))
    east = 2.0 * (x * y - z * w)
    north = 1.0 - 2.0 * (x * x + z * z)
    return math.atan2(north, east) + offset_rad


def _imu_in_order(released: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The released IMU records in one time order (ties: accelerometer, gyroscope, rotation vector)."""
    parts = [(released[s][0], np.full(len(released[s][0]), k, dtype=np.int8), released[s][1])
             for k, s in enumerate(_IMU) if s in released]
    if not parts:
        return np.zeros(0), np.zeros(0, dtype=np.int8), np.zeros((0, 3))
    t = np.concatenate([p[0] for p in parts])
    stream = np.concatenate([p[1] for p in parts])
    values = np.concatenate([p[2] for p in parts])
    order = np.lexsort((stream, t))
    return t[order], stream[order], values[order]


def run_over_scans(plan: FloorPlan, evidence: WalkEvidence, settings: RunSettings, rng: np.random.Generator,
                   steps: Steps | None, *, floors: FloorModel | None = None, sources: tuple[MeasurementSource, ...] = (),
                   start: Start = Start(), on_step: Callable[[StepReport], None] | None = None,
                   history=None) -> CausalFilter:
    """The causal filter over the scans the evidence already holds, the given steps and the
    ``sources``' measurements (``ReplayedMeasurements``): a second run over a walk, e.g. from a
    better start."""
    stream = CausalFilter(plan, evidence, settings, rng, steps=steps if settings.motion.model == "pdr" else None,
                          floors=floors, sources=sources, start=start, on_step=on_step, history=history)
    stream.feed(scans_recording(evidence.scans))
    stream.close()
    return stream
