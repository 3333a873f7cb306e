"""Tracking one walk: a map or building + a phone log -> the causal track and the offline track.

This is the pipeline behind ``mapfilter track``, ``mapfilter evaluate``'s ``pf`` methods and
``mapfilter.track``: it reads nothing and writes nothing. A single map is a one-floor building;
the floor enters the filter's state only when the building has more than one floor and none is
given. The stages, in order:

1. the walk's evidence: its WiFi scans as the filter weighs them (``filter.evidence``), and its
   PDR steps (``sensors.pdr``);
2. the causal filter over the walk (``filter.run.run_filter``);
3. with ``smooth``, the offline track from the whole walk (``offline``).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable

import numpy as np

from mapfilter.config import TrackingConfig
from mapfilter.errors import MapfilterError
from mapfilter.filter.events import CollapseEvent, StepReport
from mapfilter.filter.evidence import BuildingEvidence, WifiEvidence
from mapfilter.filter.models.building import FloorChanges, FloorStack
from mapfilter.filter.run import FilterRun, run_filter
from mapfilter.maps.building import Building
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.offline.floors import building_offline_track, to_floors
from mapfilter.offline.whole_walk import OfflineTrack, offline_track
from mapfilter.sensors.pathloss import AccessPointTable
from mapfilter.sensors.pdr import Steps, detect_steps
from mapfilter.sensors.radiomap import RadioMap
from mapfilter.sensors.recording import Recording
from mapfilter.sensors.wifi import scans_of
from mapfilter.trackio import Track

__all__ = ["PreparedWalk", "TrackResult", "prepare_walk", "track", "track_prepared"]


@dataclasses.dataclass(frozen=True)
class TrackResult:
    """One walk tracked: tracks in each floor's own frame (``floor`` names the floor of each row)."""

    causal: Track  # the estimate after every filter step (t_s, xy_m, std_m; heading_rad with PDR)
    offline: Track | None  # the whole-walk track (with config.smooth), else None
    restarted: Track | None  # the second filter run whose estimates placed the offline track
    collapses: tuple[CollapseEvent, ...]
    n_filter_steps: int
    n_scans_used: int
    causal_runtime_s: float  # the causal filter's run (and the walk's evidence)
    offline_runtime_s: float  # the offline stage (0 without smooth)
    config: TrackingConfig
    gaps: tuple[tuple[float, float], ...] = ()  # (from, to) s: gaps in the log where the filter started afresh
    access_points: AccessPointTable | None = None  # trilateration: the table at the end (adapted with adapt_path_loss)

    @property
    def runtime_s(self) -> float:
        return self.causal_runtime_s + self.offline_runtime_s


@dataclasses.dataclass(frozen=True)
class PreparedWalk:
    """A walk's evidence made once, to be tracked with one or more configs that share its WiFi
    settings (``prepare_walk``, ``track_prepared``)."""

    building: Building
    floor_index: int | None  # the floor tracked on; None: the floor is in the filter's state
    evidence: WifiEvidence | BuildingEvidence
    steps: Steps | None  # PDR steps (None without PDR)
    stack: FloorStack | None  # several floors: the stack plan the filter runs on
    recording: Recording


def prepare_walk(building: Building | FloorPlan, recording: Recording, radio_map: RadioMap | None = None,
                 access_points: AccessPointTable | None = None, config: TrackingConfig | None = None, *,
                 floor: str | None = None, steps: Steps | None = None,
                 fix_sigma_by_floor_m: dict[str, float] | None = None,
                 floor_evidence: np.ndarray | None = None) -> PreparedWalk:
    """The walk's evidence (``filter.evidence``) and PDR steps, checked against the building.

    The arguments are ``track``'s. Only ``config.wifi``, ``config.trilateration``,
    ``config.steps``, ``config.motion.model`` and ``config.floors`` matter here.
    """
    config = config if config is not None else TrackingConfig()
    building = building if isinstance(building, Building) else Building.from_plan(building)
    if (radio_map is None) == (access_points is None):
        raise MapfilterError("give either a radio map (fingerprinting) or an access-point table (trilateration)")
    log_name = str(recording.path) if recording.path is not None else "the log"
    pdr = config.motion.model == "pdr"
    if pdr and steps is None:
        steps = detect_steps(recording, config.steps)
    steps = steps if pdr else None
    scans = scans_of(recording)
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
        evidence = WifiEvidence(scans, radio_map, access_points, plan_floor.plan, wifi, config.trilateration, log_name)
        return PreparedWalk(building, index, evidence, steps, None, recording)
    if access_points is not None:
        raise MapfilterError("tracking across floors needs a building's radio map, not an access-point table "
                             "(or give the floor)")
    stack = FloorStack(building)
    pressure = None
    if config.floors.use_barometer and recording.pressure_t_s.size >= 2:
        pressure = (recording.pressure_t_s, recording.pressure_hpa)
    evidence = BuildingEvidence(scans, radio_map, stack, config.wifi, fix_sigma_by_floor_m, log_name,
                                pressure=pressure, barometer=config.floors.barometer, floor_evidence=floor_evidence)
    return PreparedWalk(building, None, evidence, steps, stack, recording)


def track(building: Building | FloorPlan, recording: Recording, radio_map: RadioMap | None = None,
          access_points: AccessPointTable | None = None, config: TrackingConfig | None = None, *,
          floor: str | None = None, steps: Steps | None = None,
          on_step: Callable[[StepReport], None] | None = None,
          on_offline_step: Callable[[StepReport], None] | None = None,
          fix_sigma_by_floor_m: dict[str, float] | None = None,
          floor_evidence: np.ndarray | None = None, rng: np.random.Generator | None = None) -> TrackResult:
    """Track one walk.

    Parameters
    ----------
    building : the map (a ``Building``, or a ``FloorPlan`` as a one-floor building).
    recording : the walk (WiFi scans; IMU for PDR).
    radio_map / access_points : fingerprinting or trilateration (exactly one; a building with
        several floors needs a building's radio map).
    config : every setting (``TrackingConfig``; default: the defaults). Its seed seeds the run.
    floor : track on this floor of the building only (default: find the floor, or the only one).
    steps : the walk's PDR steps if already detected with ``config.steps`` (else detected here).
    on_step : called with every ``StepReport`` of the causal run (the viewer, progress).
    on_offline_step : called with every ``StepReport`` of the offline stage's second filter run.
    fix_sigma_by_floor_m : the fix Gaussian of each floor by name, instead of calibrating it
        from each floor's fingerprints (an evaluation calibrates once for many walks).
    floor_evidence : (S, F) floor log-likelihood per scan instead of the WiFi floor vote (e.g.
        the true floor, to measure what finding the floor costs).
    rng : the run's random numbers (default: ``default_rng(config.seed)``; an evaluation gives
        each walk and method its own).

    Tracks carry a floor name per row when the building has several floors.
    """
    started = time.perf_counter()
    walk = prepare_walk(building, recording, radio_map, access_points, config, floor=floor, steps=steps,
                        fix_sigma_by_floor_m=fix_sigma_by_floor_m, floor_evidence=floor_evidence)
    return track_prepared(walk, config, rng=rng, on_step=on_step, on_offline_step=on_offline_step, started=started)


def track_prepared(walk: PreparedWalk, config: TrackingConfig | None = None, *, rng: np.random.Generator | None = None,
                   on_step: Callable[[StepReport], None] | None = None,
                   on_offline_step: Callable[[StepReport], None] | None = None,
                   started: float | None = None) -> TrackResult:
    """Track a walk whose evidence ``prepare_walk`` made (with the same WiFi settings as ``config``)."""
    config = config if config is not None else TrackingConfig()
    started = started if started is not None else time.perf_counter()
    rng = rng if rng is not None else np.random.default_rng(config.seed)
    steps = walk.steps if config.motion.model == "pdr" else None
    if config.motion.model == "pdr" and steps is None:
        raise MapfilterError("PDR motion needs the walk's steps: prepare the walk with the PDR motion model")
    if walk.stack is None:
        return _track_on_floor(walk, config, rng, steps, on_step, on_offline_step, started)
    if not config.use_map:
        raise MapfilterError("tracking across floors needs the walls (the floors are kept apart by them): "
                             "drop --no-map or give the floor")
    return _track_in_building(walk, config, rng, steps, on_step, on_offline_step, started)


def _track_on_floor(walk: PreparedWalk, config: TrackingConfig, rng: np.random.Generator, steps: Steps | None,
                    on_step, on_offline_step, started: float) -> TrackResult:
    """One floor: the filter on that floor's plan, no floor in the state."""
    floor = walk.building.floors[walk.floor_index]
    plan = floor.plan if config.use_map else FloorPlan(np.zeros_like(floor.plan.wall_mask), floor.plan.resolution_m,
                                                        floor.plan.origin_m, floor.plan.floor_name)
    evidence = walk.evidence
    # without steps to place, the offline track is the lineage of the final best particle
    whole_walk = steps is not None and len(steps) > 0
    run = run_filter(plan, config.motion, config.filter, rng, evidence, steps, on_step=on_step,
                     keep_ancestry=config.smooth and not whole_walk)
    causal_done = time.perf_counter()
    offline = None
    if config.smooth:
        offline = offline_track(plan, evidence, steps, run.track, run.lineage, config.motion, config.filter, rng,
                                config.offline, on_offline_step)
    names = [floor.name] if not walk.building.is_single_floor else None
    return _result(run, offline, config, started, causal_done, evidence.access_points,
                   lambda t: dataclasses.replace(t, floor=names * len(t)) if names and t.floor is None else t)


def _track_in_building(walk: PreparedWalk, config: TrackingConfig, rng: np.random.Generator, steps: Steps | None,
                       on_step, on_offline_step, started: float) -> TrackResult:
    """Several floors: the floor in the filter's state (``filter.floors``)."""
    stack, evidence = walk.stack, walk.evidence
    changes = FloorChanges(stack, config.floors.changes)
    run = run_filter(stack.plan, config.motion, config.filter, rng, evidence, steps, floors=changes, on_step=on_step,
                     keep_ancestry=config.smooth)
    causal_done = time.perf_counter()
    offline = None
    if config.smooth:
        offline = building_offline_track(changes, evidence, steps, run.track, run.lineage, config.motion,
                                         config.filter, rng, config.offline, on_offline_step)
    return _result(run, offline, config, started, causal_done, None,
                   lambda t: to_floors(stack, t) if t.floor is None else t)


def _result(run: FilterRun, offline: OfflineTrack | None, config: TrackingConfig, started: float,
            causal_done: float, access_points: AccessPointTable | None,
            on_floors: Callable[[Track], Track]) -> TrackResult:
    return TrackResult(
        causal=on_floors(run.track),
        offline=None if offline is None else on_floors(offline.track),
        restarted=None if offline is None or offline.restarted is None else on_floors(offline.restarted),
        collapses=run.collapses, n_filter_steps=run.n_filter_steps, n_scans_used=run.n_scans_used,
        causal_runtime_s=causal_done - started, offline_runtime_s=time.perf_counter() - causal_done,
        config=config, gaps=run.gaps, access_points=access_points)
