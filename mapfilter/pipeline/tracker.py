"""Tracking one walk: a map or building + a phone's records -> the causal track (and the offline one).

This is the pipeline behind ``mapfilter track``, ``mapfilter evaluate``'s ``pf`` methods and
``mapfilter.track``: it reads nothing and writes nothing. A single map is a one-floor building;
the floor enters the filter's state only when the building has more than one floor and none is
given. :class:`Tracker` takes the records as they arrive (a live phone, a log read line by
line) and gives each causal estimate as soon as it exists; :func:`track` is the replay of a whole
recording through it. The stages:

1. the walk's evidence as it comes: its WiFi scans as the filter weighs them
   (``filter.evidence``), its BLE beacon readings with a beacon table (``filter.models.ble``,
   with WiFi or alone), its steps (``sensors.pdr.OnlinePDR``, causal);
2. the causal filter (``filter.causal.CausalFilter``: one event, one filter step);
3. with ``smooth``, after the last record, the offline track from the whole walk (``offline``).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable

import numpy as np

from mapfilter.config import TrackingConfig
from mapfilter.errors import MapfilterError
from mapfilter.filter.events import CollapseEvent, StepReport
from mapfilter.filter.evidence import BuildingEvidence, NoWifiEvidence, WifiEvidence
from mapfilter.filter.models.ble import beacon_source
from mapfilter.filter.models.building import FloorChanges, FloorStack
from mapfilter.filter.causal import ReplayedMeasurements, CausalFilter, run_over_scans
from mapfilter.maps.building import Building
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.paths import detour_wall_crossings
from mapfilter.offline.smoother import FixedLagSmoother, ParticleHistory, smooth
from mapfilter.offline.whole_walk import placed_track
from mapfilter.sensors.beacons import BeaconTable
from mapfilter.sensors.pathloss import AccessPointTable
from mapfilter.sensors.pdr import OnlinePDR, Steps, detect_steps
from mapfilter.sensors.radiomap import RadioMap
from mapfilter.sensors.recording import Recording
from mapfilter.sensors.wifi import scans_of
from mapfilter.io.tracks import Track

__all__ = ["PreparedWalk", "TrackResult", "Tracker", "prepare_walk", "track", "track_prepared"]


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
    n_beacon_windows: int = 0  # measurements made of the BLE beacon readings (with a beacon table)

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
    beacons: BeaconTable | None = None  # BLE beacons weighed besides (or instead of) the WiFi
    prepare_s: float = 0.0  # the time making it took (counted in each of its tracks' causal runtime)


# the second forward pass of a walk on one floor (``Tracker._offline_track``): half its particles
# within 5 m of the placed start, the rest from the first scan as in the first pass, so that a
# wrong placement costs little (ILC F1 sparse: 8.23 m mean with half, 8.27 m with all of them;
# the placed start is a few metres off: 3, 5 and 10 m measured alike)
RESTART_SHARE = 0.5
RESTART_RADIUS_M = 5.0
# The placed shape is bent by the walls within reach of its placement's error (the map
# matching's anchor_sigma_m); a walk whose smoothed track stays, at its median, farther from
# every wall than this many times that error keeps the smoothed track: there the rigid shape
# only adds its drift (IPIN 2023's open floors, 18-30 m: 2.84 m mean against 4.82 m placed;
# ILC site 1 F1's walks, 0.4-9.6 m, keep the placed shape: docs/accuracy.md)
WALL_REACH_SIGMAS = 2.0


def _to_floors(stack: FloorStack, track: Track) -> Track:
    """A stack-frame track -> each row in its floor's own frame, with the floor's name."""
    xy, floor = stack.to_floor(track.xy_m)
    names = stack.building.floor_names
    return dataclasses.replace(track, xy_m=xy, floor=[names[f] for f in floor])


def _as_building(building: Building | FloorPlan) -> Building:
    return building if isinstance(building, Building) else Building.from_plan(building)


def _empty_evidence(building: Building, radio_map: RadioMap | None, access_points: AccessPointTable | None,
                    config: TrackingConfig, floor: str | None, fix_sigma_by_floor_m: dict[str, float] | None,
                    floor_evidence: np.ndarray | None, log_name: str, beacons: BeaconTable | None = None
                    ) -> tuple[WifiEvidence | BuildingEvidence | NoWifiEvidence, int | None, FloorStack | None]:
    """(the walk's evidence, not yet holding a scan; the floor index or None; the stack plan or None).
    Without a radio map and an access-point table, a beacon table alone: no WiFi evidence (in a
    building, the barometer's)."""
    if radio_map is not None and access_points is not None:
        raise MapfilterError("give either a radio map (fingerprinting) or an access-point table (trilateration)")
    if radio_map is None and access_points is None:
        if beacons is None:
            raise MapfilterError("give a radio map (fingerprinting), an access-point table (trilateration) or a "
                                 "beacon table (BLE)")
        if building.is_single_floor or floor is not None:
            return NoWifiEvidence(log_name), 0 if building.is_single_floor else building.floor_index(floor), None
        stack = FloorStack(building)
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
        if fix_sigma_by_floor_m and plan_floor.name in fix_sigma_by_floor_m:
            wifi = dataclasses.replace(wifi, fix_sigma_m=fix_sigma_by_floor_m[plan_floor.name])
        evidence = WifiEvidence(radio_map, access_points, plan_floor.plan, wifi, config.trilateration, log_name)
        return evidence, index, None
    if access_points is not None:
        raise MapfilterError("tracking across floors needs a building's radio map, not an access-point table "
                             "(or give the floor)")
    stack = FloorStack(building)
    evidence = BuildingEvidence(radio_map, stack, config.wifi, fix_sigma_by_floor_m, log_name,
                                config.floors.use_barometer, config.floors.barometer, floor_evidence)
    return evidence, None, stack


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

    Parameters are ``track``'s; ``evidence`` and ``steps`` (a ``prepare_walk``'s) skip making
    them again.
    """

    def __init__(self, building: Building | FloorPlan, radio_map: RadioMap | None = None,
                 access_points: AccessPointTable | None = None, config: TrackingConfig | None = None, *,
                 floor: str | None = None, rng: np.random.Generator | None = None,
                 on_step: Callable[[StepReport], None] | None = None,
                 fix_sigma_by_floor_m: dict[str, float] | None = None, floor_evidence: np.ndarray | None = None,
                 log_name: str = "the log", evidence: WifiEvidence | BuildingEvidence | NoWifiEvidence | None = None,
                 steps: Steps | None = None, stack: FloorStack | None = None, beacons: BeaconTable | None = None
                 ) -> None:
        self.config = config = config if config is not None else TrackingConfig()
        self.building = _as_building(building)
        if evidence is None:
            evidence, self.floor_index, stack = _empty_evidence(self.building, radio_map, access_points, config, floor,
                                                                fix_sigma_by_floor_m, floor_evidence, log_name, beacons)
        else:
            self.floor_index = None if stack is not None else (0 if self.building.is_single_floor
                                                               else self.building.floor_index(floor))
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
        self._beacon_table = beacons
        self.beacons = None if beacons is None else beacon_source(beacons, self.building, config.ble,
                                                                  floor=self.floor_index or 0, stack=stack)
        self.stream = CausalFilter(plan, evidence, config.motion, config.filter, self.rng,
                                   pdr=OnlinePDR(config.steps) if pdr and steps is None else None,
                                   steps=steps if pdr else None, floors=floors, on_step=on_step,
                                   abs_heading_offset_rad=config.steps.abs_heading_offset_rad,
                                   sources=() if self.beacons is None else (self.beacons,),
                                   history=_Recorders(recorders) if recorders else None)
        self._floors = floors
        self.runtime_s = 0.0

    def feed(self, records: Recording) -> Track:
        """The next records of the walk; returns the causal rows they completed (floor frames)."""
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

    def _offline_track(self, on_offline_step: Callable[[StepReport], None] | None,
                       on_smoothed: Callable[[float, np.ndarray, np.ndarray], None] | None
                       ) -> tuple[Track, Track | None]:
        """The offline track (the plan's frame, or a floor's with its name) and the second forward
        pass's causal track (None without one).

        The smoother (``offline.smoother``) over the filter's own run. A walk on one floor with PDR
        steps (in a building: one the smoother keeps on one floor throughout) is placed whole as
        well (``offline.whole_walk``): its dead-reckoned shape placed through the causal track
        starts half the particles of a second forward pass on that floor's map, and placed through
        that pass's smoothed track it is the offline track (ILC F1 sparse 8.23 m mean against
        8.83 m for the smoothed track alone, and 8.34 m for the shape placed through a restarted
        filter run: docs/accuracy.md), unless that smoothed track stays far from every wall
        (``WALL_REACH_SIGMAS``): then the smoothed track is. ``on_smoothed`` sees the smoothed cloud of the filter's own
        run (``offline.smoother.smooth``'s ``on_row``)."""
        config, stream = self.config, self.stream
        steps = stream.steps if config.motion.model == "pdr" else None
        places_shape = steps is not None and len(steps) > 0 and self.evidence.has_wifi  # by the scans
        smoothed = None
        if self.stack is not None or not places_shape or on_smoothed is not None:
            smoothed = self._smoothed(self.history, self.plan, self._floors, on_smoothed)
        if not places_shape:
            return smoothed, None
        plan, evidence, causal, floor_name = self.plan, self.evidence, stream.track(), None
        if self.stack is not None:
            floor_of = self.stack.floor_of(smoothed.xy_m)
            f = int(floor_of[0])
            if np.any(floor_of != f) or self.evidence.floor_wifi[f] is None:
                return smoothed, None
            # on one floor throughout: the walk as on that floor's own map
            plan, evidence, floor_name = self.building.floors[f].plan, self.evidence.floor_wifi[f], self.building.floor_names[f]
            causal = dataclasses.replace(causal, xy_m=self.stack.to_floor(causal.xy_m)[0])
        placed = placed_track(plan, evidence, steps, causal, config.offline)
        t0 = float(evidence.scans[int(np.argmax(evidence.usable))].t_s)
        start_xy = placed.xy_m[int(np.clip(np.searchsorted(placed.t_s, t0), 0, len(placed) - 1))]
        history = ParticleHistory()
        sources = ()
        if self.beacons is not None:  # the same beacon windows, weighed on this floor's map
            model = beacon_source(self._beacon_table, self.building, config.ble,
                                  floor=self.floor_index if floor_name is None else f).model
            sources = (ReplayedMeasurements(self.beacons.stream, model, [m.t_s for m in self.beacons.measurements],
                                            self.beacons.measurements),)
        second = run_over_scans(plan, evidence, config.motion, config.filter, self.rng, steps, start_xy_m=start_xy,
                                start_radius_m=RESTART_RADIUS_M, start_share=RESTART_SHARE, on_step=on_offline_step,
                                history=history, sources=sources)
        second_smoothed = self._smoothed(history, plan, None)
        reach_m = WALL_REACH_SIGMAS * config.offline.map_matching.anchor_sigma_m
        track = (second_smoothed if np.median(plan.distance_to_wall_m(second_smoothed.xy_m)) > reach_m
                 else placed_track(plan, evidence, steps, second_smoothed, config.offline))
        restarted = dataclasses.replace(second.track(), name="restarted")
        if floor_name is not None:  # the floor's probability is the smoother's at or before each row
            row = np.clip(np.searchsorted(smoothed.t_s, track.t_s, side="right") - 1, 0, len(smoothed) - 1)
            track = dataclasses.replace(track, floor=[floor_name] * len(track),
                                        floor_p=None if smoothed.floor_p is None else smoothed.floor_p[row])
            restarted = dataclasses.replace(restarted, floor=[floor_name] * len(restarted))
        return track, restarted

    def _smoothed(self, history: ParticleHistory, plan: FloorPlan, floors: FloorChanges | None,
                  on_row: Callable[[float, np.ndarray, np.ndarray], None] | None = None) -> Track:
        """The smoothed means of a forward pass, made wall-free, with each row's floor share."""
        smoothed = smooth(history, plan, self.config.motion.motion_model, floors, on_row)
        floor_p, runs = None, [np.arange(len(smoothed.t_s))]
        if smoothed.floor_shares is not None:
            floor_of = self.stack.floor_of(smoothed.xy_m)
            floor_p = np.clip(smoothed.floor_shares[np.arange(len(floor_of)), floor_of], 0.0, 1.0)
            # a change of floor is a jump between floors' places in the stack's plan, not a move
            # through its walls: each stretch on one floor walks round its own walls
            runs = np.split(runs[0], np.flatnonzero(np.diff(floor_of)) + 1)
        parts = [detour_wall_crossings(plan, smoothed.t_s[run], smoothed.xy_m[run]) for run in runs]
        t_s, xy_m = np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
        row = np.clip(np.searchsorted(smoothed.t_s, t_s), 0, len(smoothed.t_s) - 1)
        return Track(t_s, xy_m, smoothed.std_m[row], smoothed.heading_rad[row], name="pf-smooth",
                     floor_p=None if floor_p is None else floor_p[row])

    def result(self, on_offline_step: Callable[[StepReport], None] | None = None,
               on_smoothed: Callable[[float, np.ndarray, np.ndarray], None] | None = None) -> TrackResult:
        """The walk tracked (after ``close``): the causal track and, with ``config.smooth``, the
        offline one. ``on_offline_step`` sees the offline stage's second forward pass step by step,
        ``on_smoothed(t_s, xy_m, weight)`` the smoothed cloud of every step of the filter's own run
        (the plan's frame; a building's stack frame)."""
        if not self.stream.closed:
            raise RuntimeError("close the tracker before asking for the result")
        if not self.stream.rows:
            if self.beacons is not None:
                raise MapfilterError(f"no WiFi scan and no reading of the table's beacons in {self.evidence.log_name} "
                                     "gives a measurement")
            raise MapfilterError(f"no WiFi scan of {self.evidence.log_name} gives a fingerprint fix with this "
                                 "radio map")
        config, stream = self.config, self.stream
        started = time.perf_counter()
        offline = restarted = None
        if config.smooth:
            offline, restarted = self._offline_track(on_offline_step, on_smoothed)
        offline_s = time.perf_counter() - started
        access_points = self.evidence.access_points if isinstance(self.evidence, WifiEvidence) else None
        return TrackResult(
            causal=self.causal,
            offline=None if offline is None else self._on_floors(offline),
            restarted=None if restarted is None else self._on_floors(restarted),
            collapses=stream.collapses, n_filter_steps=len(stream.rows) - 1, n_scans_used=stream.n_scans_used,
            causal_runtime_s=self.runtime_s, offline_runtime_s=offline_s, config=config, gaps=tuple(stream.gaps),
            access_points=access_points, late_records=stream.late_records,
            n_beacon_windows=0 if self.beacons is None else len(self.beacons.measurements))


def prepare_walk(building: Building | FloorPlan, recording: Recording, radio_map: RadioMap | None = None,
                 access_points: AccessPointTable | None = None, config: TrackingConfig | None = None, *,
                 floor: str | None = None, steps: Steps | None = None,
                 fix_sigma_by_floor_m: dict[str, float] | None = None,
                 floor_evidence: np.ndarray | None = None, beacons: BeaconTable | None = None) -> PreparedWalk:
    """The walk's evidence (every scan's measurement) and PDR steps, checked against the building.

    The arguments are ``track``'s. Only ``config.wifi``, ``config.trilateration``,
    ``config.steps``, ``config.motion.model`` and ``config.floors`` matter here; the beacons are
    weighed when the walk is tracked.
    """
    started = time.perf_counter()
    config = config if config is not None else TrackingConfig()
    building = _as_building(building)
    log_name = str(recording.path) if recording.path is not None else "the log"
    scans = scans_of(recording)
    evidence, index, stack = _empty_evidence(building, radio_map, access_points, config, floor, fix_sigma_by_floor_m,
                                             floor_evidence, log_name, beacons)
    evidence.prepare(scans)
    evidence.add_scans(scans)
    if stack is not None and config.floors.use_barometer and recording.pressure_t_s.size >= 2:
        evidence.add_pressure(recording.pressure_t_s, recording.pressure_hpa)
    evidence.require_usable()
    pdr = config.motion.model == "pdr"
    if pdr and steps is None:
        steps = detect_steps(recording, config.steps)
    return PreparedWalk(building, index, evidence, steps if pdr else None, stack, recording, beacons,
                        time.perf_counter() - started)


def track(building: Building | FloorPlan, recording: Recording, radio_map: RadioMap | None = None,
          access_points: AccessPointTable | None = None, config: TrackingConfig | None = None, *,
          floor: str | None = None, steps: Steps | None = None,
          on_step: Callable[[StepReport], None] | None = None,
          on_offline_step: Callable[[StepReport], None] | None = None,
          fix_sigma_by_floor_m: dict[str, float] | None = None,
          floor_evidence: np.ndarray | None = None, rng: np.random.Generator | None = None,
          beacons: BeaconTable | None = None) -> TrackResult:
    """Track one walk: the replay of its records through a ``Tracker``.

    Parameters
    ----------
    building : the map (a ``Building``, or a ``FloorPlan`` as a one-floor building).
    recording : the walk (WiFi scans; IMU for PDR).
    radio_map / access_points : fingerprinting or trilateration (at most one; a building with
        several floors needs a building's radio map); neither: the beacons alone.
    config : every setting (``TrackingConfig``; default: the defaults). Its seed seeds the run.
    floor : track on this floor of the building only (default: find the floor, or the only one).
    steps : the walk's PDR steps if already detected with ``config.steps`` (else detected as the
        records come).
    on_step : called with every ``StepReport`` of the causal run (the viewer, progress).
    on_offline_step : called with every ``StepReport`` of the offline stage's second filter run.
    fix_sigma_by_floor_m : the fix Gaussian of each floor by name, instead of calibrating it
        from each floor's fingerprints (an evaluation calibrates once for many walks).
    floor_evidence : (S, F) floor log-likelihood per scan instead of the WiFi floor vote (e.g.
        the true floor, to measure what finding the floor costs).
    rng : the run's random numbers (default: ``default_rng(config.seed)``; an evaluation gives
        each walk and method its own).
    beacons : a BLE beacon table (``sensors.beacons``): the log's beacon readings weigh the
        particles too (``config.ble``), or alone without a radio map and an access-point table.

    Tracks carry a floor name per row when the building has several floors.
    """
    config = config if config is not None else TrackingConfig()
    log_name = str(recording.path) if recording.path is not None else "the log"
    tracker = Tracker(building, radio_map, access_points, config, floor=floor, rng=rng, on_step=on_step,
                      fix_sigma_by_floor_m=fix_sigma_by_floor_m, floor_evidence=floor_evidence, log_name=log_name,
                      steps=steps, beacons=beacons)
    tracker.evidence.prepare(scans_of(recording))  # one line naming the log when no scan can be used
    tracker.feed(recording)
    tracker.close()
    return tracker.result(on_offline_step)


def track_prepared(walk: PreparedWalk, config: TrackingConfig | None = None, *, rng: np.random.Generator | None = None,
                   on_step: Callable[[StepReport], None] | None = None,
                   on_offline_step: Callable[[StepReport], None] | None = None,
                   on_smoothed: Callable[[float, np.ndarray, np.ndarray], None] | None = None) -> TrackResult:
    """Track a walk whose evidence ``prepare_walk`` made (with the same WiFi settings as ``config``);
    the callbacks are ``Tracker.result``'s and ``on_step`` the filter's."""
    config = config if config is not None else TrackingConfig()
    if config.motion.model == "pdr" and walk.steps is None:
        raise MapfilterError("PDR motion needs the walk's steps: prepare the walk with the PDR motion model")
    floor = None if walk.floor_index is None or walk.building.is_single_floor \
        else walk.building.floor_names[walk.floor_index]
    tracker = Tracker(walk.building, config=config, floor=floor, rng=rng, on_step=on_step, evidence=walk.evidence,
                      steps=walk.steps, stack=walk.stack, beacons=walk.beacons)
    tracker.feed(walk.recording)
    tracker.close()
    tracker.runtime_s += walk.prepare_s  # the walk's evidence is part of tracking it
    return tracker.result(on_offline_step, on_smoothed)
