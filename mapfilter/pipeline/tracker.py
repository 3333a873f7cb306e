"""Tracking one walk: a map or building + a phone's records -> the causal track (and the offline one).

This is the pipeline behind ``mapfilter track``, ``mapfilter evaluate``'s ``pf`` methods and
``mapfilter.track``: it reads nothing and writes nothing. A single map is a one-floor building;
the floor enters the filter's state only when the building has more than one floor and none is
given. :class:`Tracker` takes the records as they arrive (a live phone, a log read line by
line) and gives each causal estimate as soon as it exists; :func:`track` is the replay of a whole
recording through it. The stages:

1. the walk's evidence as it comes: its WiFi scans as the filter weighs them
   (``filter.evidence``), the measurements of every measurement source given an input
   (``filter.sources``: with WiFi or alone), its steps (``sensors.pdr.OnlinePDR``, causal);
2. the causal filter (``filter.causal.CausalFilter``: one event, one filter step);
3. with ``smooth``, after the last record, the offline track from the whole walk
   (``pipeline.offline``).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from mapfilter.config import TrackingConfig
from mapfilter.errors import MapfilterError
from mapfilter.filter.causal import CausalFilter, RunSettings, Start
from mapfilter.filter.measurement import MeasurementSource
from mapfilter.filter.events import CollapseEvent, StepReport
from mapfilter.filter.evidence import BuildingEvidence, NoWifiEvidence, WifiEvidence
from mapfilter.filter.models.building import FloorChanges, FloorStack, floor_stack
from mapfilter.filter.models.frame import StateFrame
from mapfilter.filter.sources import registered
from mapfilter.io.tracks import Track
from mapfilter.maps.building import Building
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.offline.smoother import FixedLagSmoother, ParticleHistory
from mapfilter.pipeline.offline import CausalRun, offline_track
from mapfilter.sensors.pathloss import AccessPointTable
from mapfilter.sensors.pdr import OnlinePDR, Steps, detect_steps
from mapfilter.sensors.radiomap import RadioMap
from mapfilter.sensors.recording import Recording
from mapfilter.sensors.wifi import scans_of

__all__ = ["KNOWN_START_RADIUS_M", "TRUE_START", "PreparedWalk", "TrackResult", "Tracker", "TrackingInputs", "WalkStart",
           "as_start", "prepare_walk", "track", "track_prepared"]

# a start the user knows ("the entrance I walked in from"): the particles within this radius of
# it, the walker's first steps from there; a person points at their start this closely
KNOWN_START_RADIUS_M = 2.0
# an evaluation's start for every walk (``evaluate --start truth``): each walk's own first waypoint
TRUE_START = "truth"


@dataclasses.dataclass(frozen=True)
class WalkStart:
    """Where a walk started, if the user knows: ``xy_m`` in the floor's own frame (metres, as the
    map's), ``floor`` its name (needed in a building with several floors unless the floor is
    given). A walk's input, like its log: not a setting of the config."""

    xy_m: tuple[float, float]
    floor: str | None = None

    def __str__(self) -> str:
        return f"{self.xy_m[0]:g},{self.xy_m[1]:g}" + (f",{self.floor}" if self.floor is not None else "")

    @classmethod
    def parse(cls, text: str, option: str = "--start") -> WalkStart:
        """``X,Y[,FLOOR]`` (metres of the floor's frame; FLOOR a floor name of the building)."""
        parts = [part.strip() for part in str(text).split(",")]
        if len(parts) not in (2, 3) or not all(parts):
            raise MapfilterError(f"{option} {text!r}: expected X,Y or X,Y,FLOOR (metres in the map's frame, the "
                                 "floor's name)")
        try:
            xy = (float(parts[0]), float(parts[1]))
        except ValueError:
            raise MapfilterError(f"{option} {text!r}: X and Y must be numbers (metres in the map's frame)") from None
        if not all(np.isfinite(xy)):
            raise MapfilterError(f"{option} {text!r}: X and Y must be finite numbers")
        return cls(xy, parts[2] if len(parts) == 3 else None)

    def place(self, building: Building, floor: str | None = None) -> tuple[int, np.ndarray]:
        """(the start's floor index, its position in that floor's frame): on a floor the building
        has (its own, else ``floor``, the floor tracked on, else the only one) and on its free
        space; ``MapfilterError`` in one line otherwise."""
        name = self.floor if self.floor is not None else floor
        if name is None:
            if not building.is_single_floor:
                raise MapfilterError(f"the start {self}: the building has floors {', '.join(building.floor_names)}: "
                                     "give the start's floor too (X,Y,FLOOR)")
            index = 0
        else:
            if floor is not None and self.floor is not None and self.floor != floor:
                raise MapfilterError(f"the start {self} is on floor {self.floor}, but the walk is tracked on "
                                     f"floor {floor}")
            if self.floor is not None and building.is_single_floor and building.floors[0].name in (None, ""):
                index = 0
            else:
                try:
                    index = building.floor_index(name)
                except MapfilterError:
                    raise MapfilterError(f"the start {self}: the building has no floor {name!r} (floors: "
                                         f"{', '.join(building.floor_names)})") from None
        xy = np.array(self.xy_m, dtype=np.float64)
        plan = building.floors[index].plan
        if not plan.is_free(xy[None, :])[0]:
            where = "a wall" if plan.pixel_index(xy[None, :])[2][0] else "outside the map"
            raise MapfilterError(f"the start {self} is not on the free space of "
                                 f"{'the map' if building.is_single_floor else 'floor ' + building.floor_names[index]}"
                                 f" ({where} there): give a point where the walker can stand")
        return index, xy


def as_start(value, name: str = "start") -> WalkStart | None:
    """A ``WalkStart`` from what the API takes: None, a ``WalkStart``, ``(x, y)``, ``(x, y, floor)``
    or the text ``"X,Y[,FLOOR]"``; ``TypeError`` naming the argument otherwise."""
    if value is None or isinstance(value, WalkStart):
        return value
    if isinstance(value, str):
        return WalkStart.parse(value, name)
    if isinstance(value, (tuple, list)) and len(value) in (2, 3) and all(
            isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) for v in value[:2]) \
            and (len(value) == 2 or isinstance(value[2], str)):
        return WalkStart.parse(",".join(str(v) for v in value), name)
    raise TypeError(f"{name}: expected (x, y) or (x, y, floor name) in metres of the map's frame, got {value!r}")


@dataclasses.dataclass(frozen=True)
class TrackingInputs:
    """What a walk is tracked with besides its map: WiFi (a radio map for fingerprinting or an
    access-point table for trilateration, at most one) and the inputs of measurement sources
    (``{source name: its input}``, ``filter.sources``: e.g. ``{"ble": a table}``); with no
    WiFi, the sources alone."""

    radio_map: RadioMap | None = None
    access_points: AccessPointTable | None = None
    sources: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    # the fix Gaussian of each floor by name, instead of calibrating it from each floor's
    # fingerprints (an evaluation calibrates once for many walks)
    fix_sigma_by_floor_m: dict[str, float] | None = None
    # (S, F) floor log-likelihood per scan instead of the WiFi floor vote (e.g. the true floor, to
    # measure what finding the floor costs)
    floor_evidence: np.ndarray | None = None
    # the phone, where the log does not name it (a competition server sends no header): what a
    # source knows of it applies (a table's RSSI offset for that phone model)
    phone_model: str | None = None

    def __post_init__(self) -> None:
        known = {p.name for p in registered()}
        unknown = sorted(set(self.sources) - known)
        if unknown:
            raise MapfilterError(f"no measurement source named {unknown[0]!r} (registered: {', '.join(sorted(known))})")


@dataclasses.dataclass(frozen=True)
class TrackResult:
    """One walk tracked: tracks in each floor's own frame (``floor`` names the floor of each row)."""

    causal: Track  # the estimate after every filter step, stamped with the time a live system has it
    offline: Track | None  # the whole-walk track (with config.smooth), else None
    restarted: Track | None  # one floor with steps: the second forward pass the offline track smooths
    collapses: tuple[CollapseEvent, ...]
    n_filter_steps: int
    n_scans_used: int
    causal_runtime_s: float  # the causal filter's run (and the walk's evidence)
    offline_runtime_s: float  # the offline stage (0 without smooth)
    config: TrackingConfig
    gaps: tuple[tuple[float, float], ...] = ()  # (from, to) s: gaps in the log where the filter started afresh
    access_points: AccessPointTable | None = None  # trilateration: the table at the end (adapted with adapt_path_loss)
    late_records: int = 0  # records dropped because they came after later ones had been processed
    # {source name: measurements it made} of every measurement source given an input
    n_measurements: dict[str, int] = dataclasses.field(default_factory=dict)

    @property
    def runtime_s(self) -> float:
        return self.causal_runtime_s + self.offline_runtime_s


@dataclasses.dataclass(frozen=True)
class PreparedWalk:
    """A walk's evidence and steps made once, to be tracked with one or more configs that share its
    WiFi and step settings (``prepare_walk``, ``track_prepared``)."""

    building: Building
    floor_index: int | None  # the floor tracked on; None: the floor is in the filter's state
    evidence: WifiEvidence | BuildingEvidence | NoWifiEvidence
    steps: Steps | None  # PDR steps (None without PDR)
    stack: FloorStack | None  # several floors: the stack plan the filter runs on
    recording: Recording
    inputs: TrackingInputs  # what the walk is tracked with (its sources weighed when it is tracked)
    prepare_s: float = 0.0  # the time making it took (counted in each of its tracks' causal runtime)


def _to_floors(stack: FloorStack, track: Track) -> Track:
    """A stack-frame track -> each row in its floor's own frame, with the floor's name."""
    xy, floor = stack.to_floor(track.xy_m)
    names = stack.building.floor_names
    return dataclasses.replace(track, xy_m=xy, floor=[names[f] for f in floor])


def _as_building(building: Building | FloorPlan) -> Building:
    return building if isinstance(building, Building) else Building.from_plan(building)


def _empty_evidence(building: Building, inputs: TrackingInputs, config: TrackingConfig, floor: str | None,
                    log_name: str) -> tuple[WifiEvidence | BuildingEvidence | NoWifiEvidence, int | None,
                                            FloorStack | None]:
    """(the walk's evidence, not yet holding a scan; the floor index or None; the stack plan or None).
    Without a radio map and an access-point table, measurement sources alone: no WiFi evidence
    (in a building, the barometer's)."""
    radio_map, access_points = inputs.radio_map, inputs.access_points
    sigma, floor_evidence = inputs.fix_sigma_by_floor_m, inputs.floor_evidence
    if radio_map is not None and access_points is not None:
        raise MapfilterError("give either a radio map (fingerprinting) or an access-point table (trilateration)")
    if radio_map is None and access_points is None:
        if not inputs.sources:
            others = "".join(f", {p.title} ({' '.join(o.flag for o in p.options)})" for p in registered())
            raise MapfilterError(f"nothing to weigh the particles by: give a radio map (fingerprinting), an "
                                 f"access-point table (trilateration){others}")
        if building.is_single_floor or floor is not None:
            return NoWifiEvidence(log_name), 0 if building.is_single_floor else building.floor_index(floor), None
        stack = floor_stack(building)
        return (BuildingEvidence(None, stack, config.wifi, None, log_name, config.floors.use_barometer,
                                 config.floors.barometer, floor_evidence), None, stack)
    if building.is_single_floor or floor is not None:
        index = 0 if building.is_single_floor else building.floor_index(floor)
        plan_floor = building.floors[index]
        if radio_map is not None and radio_map.has_floors:
            if radio_map.floor_names[index] != plan_floor.name:
                raise MapfilterError(f"the radio map's floor {radio_map.floor_names[index]!r} is not the building's "
                                     f"{plan_floor.name!r}")
            radio_map = radio_map.floor_map(index)
        wifi = config.wifi
        if sigma and plan_floor.name in sigma:
            wifi = dataclasses.replace(wifi, fix_sigma_m=sigma[plan_floor.name])
        evidence = WifiEvidence(radio_map, access_points, plan_floor.plan, wifi, config.trilateration, log_name)
        return evidence, index, None
    if access_points is not None:
        raise MapfilterError("tracking across floors needs a building's radio map, not an access-point table "
                             "(or give the floor)")
    stack = floor_stack(building)
    evidence = BuildingEvidence(radio_map, stack, config.wifi, sigma, log_name, config.floors.use_barometer,
                                config.floors.barometer, floor_evidence)
    return evidence, None, stack


def _sources(building: Building, inputs: TrackingInputs, config: TrackingConfig, floor_index: int | None,
             stack: FloorStack | None) -> tuple[MeasurementSource, ...]:
    """A measurement source for each registered source given an input, in the registry's order."""
    frame = StateFrame(building, floor_index or 0, stack)
    return tuple(p.source(inputs.sources[p.name], frame, getattr(config.sources, p.name))
                 for p in registered() if p.name in inputs.sources)


class _Recorders:
    """Hands every filter step to several recorders (the whole walk's history, the fixed lag)."""

    def __init__(self, recorders: tuple) -> None:
        self.recorders = recorders

    def record(self, *args) -> None:
        for recorder in self.recorders:
            recorder.record(*args)


class Tracker:
    """Track a walk as its records arrive: ``feed`` chunks of records (``Recording``s holding the
    next records of each sensor, e.g. from ``sensors.logs.LogStream``), get the causal rows each
    completes, ``close`` at the end. Each row is stamped with the time a live system has it and
    depends only on records stamped at or before it: feeding a walk in chunks of any size gives
    the rows of feeding it whole.

    Parameters
    ----------
    building : the map (a ``Building``, or a ``FloorPlan`` as a one-floor building).
    inputs : what the walk is tracked with (``TrackingInputs``: WiFi and measurement sources).
    config : every setting (``TrackingConfig``; default: the defaults). Its seed seeds the run.
    floor : track on this floor of the building only (default: find the floor, or the only one).
    rng : the run's random numbers (default: ``default_rng(config.seed)``).
    on_step : called with every ``StepReport`` of the causal run (the viewer, progress).
    log_name : the log's name in messages.
    steps : the walk's PDR steps if already detected with ``config.steps`` (else detected as the
        records come).
    prepared : a ``prepare_walk``'s evidence and steps, not made again (its inputs are the run's).
    start : where the walk started, if known (``WalkStart``, ``(x, y[, floor])``): the particles
        start within ``KNOWN_START_RADIUS_M`` of it at the first step (without PDR, at the first
        usable scan), instead of from the first measurement's likelihood over the map.
    """

    def __init__(self, building: Building | FloorPlan, inputs: TrackingInputs | None = None,
                 config: TrackingConfig | None = None, *, floor: str | None = None,
                 rng: np.random.Generator | None = None, on_step: Callable[[StepReport], None] | None = None,
                 log_name: str = "the log", steps: Steps | None = None, prepared: PreparedWalk | None = None,
                 start: WalkStart | tuple | None = None) -> None:
        if inputs is not None and not isinstance(inputs, TrackingInputs):
            raise TypeError(f"inputs: expected TrackingInputs(radio_map=..., access_points=..., sources=...), got "
                            f"{type(inputs).__name__}")
        self.config = config = config if config is not None else TrackingConfig()
        self.building = _as_building(building)
        if prepared is None:
            self.inputs = inputs if inputs is not None else TrackingInputs()
            evidence, self.floor_index, stack = _empty_evidence(self.building, self.inputs, config, floor, log_name)
        else:
            self.inputs = prepared.inputs
            evidence, self.floor_index, stack, steps = (prepared.evidence, prepared.floor_index, prepared.stack,
                                                        prepared.steps)
        self.evidence = evidence
        self.stack = stack
        self.rng = rng if rng is not None else np.random.default_rng(config.seed)
        pdr = config.motion.model == "pdr"
        floors = None
        if stack is None:
            floor_plan = self.building.floors[self.floor_index].plan
            plan = floor_plan if config.use_map else FloorPlan(np.zeros_like(floor_plan.wall_mask),
                                                               floor_plan.resolution_m, floor_plan.origin_m,
                                                               floor_plan.floor_name)
        else:
            if not config.use_map:
                raise MapfilterError("tracking across floors needs the walls (the floors are kept apart by them): "
                                     "drop --no-map or give the floor")
            floors = FloorChanges(stack, config.floors.changes)
            plan = stack.plan
        self.plan = plan
        self.history = ParticleHistory() if config.smooth else None
        self.fixed_lag = None
        if config.offline.lag_s > 0:
            self.fixed_lag = FixedLagSmoother(plan, config.motion.motion_model, floors, config.offline.lag_s)
        recorders = tuple(r for r in (self.history, self.fixed_lag) if r is not None)
        self.sources = _sources(self.building, self.inputs, config, self.floor_index, stack)
        settings = RunSettings(config.motion, config.filter, config.steps.abs_heading_offset_rad)
        steps_in = (steps if steps is not None else OnlinePDR(config.steps)) if pdr else None
        self.start = as_start(start)
        self._start_at = self._known_start(floor)
        self.stream = CausalFilter(plan, evidence, settings, self.rng, steps=steps_in, floors=floors,
                                   sources=self.sources, on_step=on_step, start=self._start_at,
                                   history=_Recorders(recorders) if recorders else None)
        self._floors = floors
        self.runtime_s = 0.0

    def _known_start(self, floor: str | None) -> Start:
        """The causal filter's start: within ``KNOWN_START_RADIUS_M`` of the known start (in the
        filter's plan: a building's stack), at the first step; else from the first measurement."""
        if self.start is None:
            return Start()
        index, xy = self.start.place(self.building, floor)
        if self.stack is not None:
            xy = self.stack.to_stack(xy[None, :], index)[0]
            if isinstance(self.evidence, BuildingEvidence):  # the barometer's zero is the start's floor
                self.evidence.start_on(index)
        elif index != self.floor_index:
            raise MapfilterError(f"the start {self.start} is on floor {self.building.floor_names[index]}, but the "
                                 f"walk is tracked on floor {self.building.floor_names[self.floor_index]}")
        return Start(xy, KNOWN_START_RADIUS_M, 1.0, at_first_step=True)

    def feed(self, records: Recording) -> Track:
        """The next records of the walk; returns the causal rows they completed (floor frames)."""
        if self.inputs.phone_model is not None and records.phone_model is None:
            records = dataclasses.replace(records, phone_model=self.inputs.phone_model)
        started = time.perf_counter()
        rows = self.stream.feed(records)
        self.runtime_s += time.perf_counter() - started
        return self._on_floors(self.stream.track(rows))

    def close(self) -> Track:
        """The end of the walk; returns the last causal rows."""
        started = time.perf_counter()
        rows = self.stream.close()
        if self.fixed_lag is not None:
            self.fixed_lag.close()
        self.runtime_s += time.perf_counter() - started
        return self._on_floors(self.stream.track(rows))

    @property
    def causal(self) -> Track:
        """The causal track so far, each row in its floor's frame."""
        return self._on_floors(self.stream.track())

    @property
    def lagged(self) -> Track | None:
        """With ``offline.lag_s``: the fixed-lag smoothed rows so far (each floor's frame), a row per
        filter step, stamped with its step's time; a live system has each ``lag_s`` later. None
        without a lag."""
        if self.fixed_lag is None:
            return None
        rows = self.fixed_lag.rows
        track = Track(np.array([r[0] for r in rows]), np.array([r[2] for r in rows]).reshape(-1, 2),
                      np.array([r[3] for r in rows]), np.array([r[4] for r in rows]), name="pf-lag")
        if self.stack is not None and len(rows):
            shares = np.array([r[5] for r in rows])
            floor = self.stack.floor_of(track.xy_m)
            track = dataclasses.replace(track, floor_p=np.clip(shares[np.arange(len(floor)), floor], 0.0, 1.0))
        return self._on_floors(track)

    def _on_floors(self, track: Track) -> Track:
        if self.stack is not None:
            return _to_floors(self.stack, track) if track.floor is None else track
        if not self.building.is_single_floor and track.floor is None:
            return dataclasses.replace(track, floor=[self.building.floors[self.floor_index].name] * len(track))
        return track

    def causal_run(self) -> CausalRun:
        """What the causal run leaves for the offline track (``pipeline.offline``; after ``close``,
        with ``config.smooth``)."""
        return CausalRun(self.building, self.config, self.plan, self.evidence, self.stack, self._floors,
                         self.floor_index, self.stream.steps, self.stream.track(), self.history, self.sources, self.rng,
                         self._start_at)

    def result(self, on_offline_step: Callable[[StepReport], None] | None = None,
               on_smoothed: Callable[[float, np.ndarray, np.ndarray], None] | None = None) -> TrackResult:
        """The walk tracked (after ``close``): the causal track and, with ``config.smooth``, the
        offline one (``pipeline.offline.offline_track``). ``on_offline_step`` sees the offline
        stage's second forward pass step by step, ``on_smoothed(t_s, xy_m, weight)`` the smoothed
        cloud of every step of the filter's own run (the plan's frame; a building's stack frame)."""
        if not self.stream.closed:
            raise RuntimeError("close the tracker before asking for the result")
        if not self.stream.rows:
            if self.sources:
                titles = " or ".join(p.title for p in registered() if p.name in self.inputs.sources)
                raise MapfilterError(f"no WiFi scan of {self.evidence.log_name} gives a measurement, and neither do "
                                     f"its {titles}")
            raise MapfilterError(f"no WiFi scan of {self.evidence.log_name} gives a fingerprint fix with this "
                                 "radio map")
        config, stream = self.config, self.stream
        started = time.perf_counter()
        offline = restarted = None
        if config.smooth:
            offline, restarted = offline_track(self.causal_run(), on_offline_step, on_smoothed)
        offline_s = time.perf_counter() - started
        access_points = self.evidence.access_points if isinstance(self.evidence, WifiEvidence) else None
        names = [p.name for p in registered() if p.name in self.inputs.sources]
        return TrackResult(
            causal=self.causal,
            offline=None if offline is None else self._on_floors(offline),
            restarted=None if restarted is None else self._on_floors(restarted),
            collapses=stream.collapses, n_filter_steps=len(stream.rows) - 1, n_scans_used=stream.n_scans_used,
            causal_runtime_s=self.runtime_s, offline_runtime_s=offline_s, config=config, gaps=tuple(stream.gaps),
            access_points=access_points, late_records=stream.late_records,
            n_measurements={name: source.n_measurements for name, source in zip(names, self.sources)})


def _inputs(radio_map: RadioMap | None, access_points: AccessPointTable | None,
            fix_sigma_by_floor_m: dict[str, float] | None, floor_evidence: np.ndarray | None,
            sources: Mapping[str, Any] | None) -> TrackingInputs:
    return TrackingInputs(radio_map, access_points, dict(sources or {}), fix_sigma_by_floor_m, floor_evidence)


def prepare_walk(building: Building | FloorPlan, recording: Recording, radio_map: RadioMap | None = None,
                 access_points: AccessPointTable | None = None, config: TrackingConfig | None = None, *,
                 floor: str | None = None, steps: Steps | None = None,
                 fix_sigma_by_floor_m: dict[str, float] | None = None, floor_evidence: np.ndarray | None = None,
                 sources: Mapping[str, Any] | None = None) -> PreparedWalk:
    """The walk's evidence (every scan's measurement) and PDR steps, checked against the building.

    The arguments are ``track``'s. Only ``config.wifi``, ``config.trilateration``,
    ``config.steps``, ``config.motion.model`` and ``config.floors`` matter here; the sources'
    measurements are made when the walk is tracked.
    """
    started = time.perf_counter()
    config = config if config is not None else TrackingConfig()
    inputs = _inputs(radio_map, access_points, fix_sigma_by_floor_m, floor_evidence, sources)
    building = _as_building(building)
    log_name = str(recording.path) if recording.path is not None else "the log"
    scans = scans_of(recording)
    evidence, index, stack = _empty_evidence(building, inputs, config, floor, log_name)
    evidence.prepare(scans)
    evidence.add_scans(scans)
    if stack is not None and config.floors.use_barometer and recording.pressure_t_s.size >= 2:
        evidence.add_pressure(recording.pressure_t_s, recording.pressure_hpa)
    evidence.require_usable()
    pdr = config.motion.model == "pdr"
    if pdr and steps is None:
        steps = detect_steps(recording, config.steps)
    return PreparedWalk(building, index, evidence, steps if pdr else None, stack, recording, inputs,
                        time.perf_counter() - started)


def track(building: Building | FloorPlan, recording: Recording, radio_map: RadioMap | None = None,
          access_points: AccessPointTable | None = None, config: TrackingConfig | None = None, *,
          floor: str | None = None, steps: Steps | None = None,
          on_step: Callable[[StepReport], None] | None = None,
          on_offline_step: Callable[[StepReport], None] | None = None,
          fix_sigma_by_floor_m: dict[str, float] | None = None,
          floor_evidence: np.ndarray | None = None, rng: np.random.Generator | None = None,
          sources: Mapping[str, Any] | None = None, start: WalkStart | tuple | None = None) -> TrackResult:
    """Track one walk: the replay of its records through a ``Tracker``.

    Parameters
    ----------
    building : the map (a ``Building``, or a ``FloorPlan`` as a one-floor building).
    recording : the walk (WiFi scans; IMU for PDR).
    radio_map / access_points : fingerprinting or trilateration (at most one; a building with
        several floors needs a building's radio map); neither: the measurement sources alone.
    config : every setting (``TrackingConfig``; default: the defaults). Its seed seeds the run.
    floor : track on this floor of the building only (default: find the floor, or the only one).
    steps : the walk's PDR steps if already detected with ``config.steps`` (else detected as the
        records come).
    on_step : called with every ``StepReport`` of the causal run (the viewer, progress).
    on_offline_step : called with every ``StepReport`` of the offline stage's second filter run.
    fix_sigma_by_floor_m, floor_evidence : ``TrackingInputs``'.
    rng : the run's random numbers (default: ``default_rng(config.seed)``; an evaluation gives
        each walk and method its own).
    sources : ``{source name: its input}`` of measurement sources (``filter.sources``; e.g.
        ``{"ble": a table}``), weighed too, or alone without WiFi.
    start : where the walk started, if known (``Tracker``'s).

    Tracks carry a floor name per row when the building has several floors.
    """
    config = config if config is not None else TrackingConfig()
    log_name = str(recording.path) if recording.path is not None else "the log"
    tracker = Tracker(building, _inputs(radio_map, access_points, fix_sigma_by_floor_m, floor_evidence, sources),
                      config, floor=floor, rng=rng, on_step=on_step, log_name=log_name, steps=steps, start=start)
    tracker.evidence.prepare(scans_of(recording))  # one line naming the log when no scan can be used
    tracker.feed(recording)
    tracker.close()
    return tracker.result(on_offline_step)


def track_prepared(walk: PreparedWalk, config: TrackingConfig | None = None, *, rng: np.random.Generator | None = None,
                   on_step: Callable[[StepReport], None] | None = None,
                   on_offline_step: Callable[[StepReport], None] | None = None,
                   on_smoothed: Callable[[float, np.ndarray, np.ndarray], None] | None = None,
                   start: WalkStart | tuple | None = None) -> TrackResult:
    """Track a walk whose evidence ``prepare_walk`` made (with the same WiFi settings as ``config``);
    the callbacks are ``Tracker.result``'s and ``on_step`` the filter's; ``start`` the ``Tracker``'s."""
    config = config if config is not None else TrackingConfig()
    if config.motion.model == "pdr" and walk.steps is None:
        raise MapfilterError("PDR motion needs the walk's steps: prepare the walk with the PDR motion model")
    floor = None if walk.floor_index is None or walk.building.is_single_floor else \
        walk.building.floor_names[walk.floor_index]
    tracker = Tracker(walk.building, config=config, rng=rng, on_step=on_step, prepared=walk, start=start, floor=floor)
    tracker.feed(walk.recording)
    tracker.close()
    tracker.runtime_s += walk.prepare_s  # the walk's evidence is part of tracking it
    return tracker.result(on_offline_step, on_smoothed)
