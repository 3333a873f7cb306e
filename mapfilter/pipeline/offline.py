"""The offline track: a walk's causal run, then the whole walk for every point.

``offline_track`` is a function of what the causal run left (``CausalRun``): the smoother
(``offline.smoother``) over the filter's own run, and, for a walk on one floor with PDR steps
and WiFi (in a building: one the smoother keeps on one floor throughout), the whole walk placed
(``offline.whole_walk``): its dead-reckoned shape placed through the causal track (and through
the walk's start, when the user knows it) starts half
the particles of a second forward pass on that floor's map, with every measurement source's
measurements replayed there (``filter.measurement.ReplayedMeasurements``), and placed through that
pass's smoothed track it is the offline track (docs/accuracy.md), unless that smoothed track
stays far from every wall (``WALL_REACH_SIGMAS``): then the smoothed track is. The second pass
weighs its particles' headings against the rotation vector only where the causal track stays that
far from every wall (near walls the walls hold them). In a building with
a barometer, a run whose smoothed track spent more than ``OTHER_FLOOR_MAX_S`` on other floors than
every scan of the walk together puts it on is first run again from that floor.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from mapfilter.config import TrackingConfig
from mapfilter.filter.causal import RunSettings, Start, run_over_scans
from mapfilter.filter.measurement import MeasurementSource, ReplayedMeasurements
from mapfilter.filter.events import StepReport
from mapfilter.filter.evidence import BuildingEvidence, NoWifiEvidence, WifiEvidence
from mapfilter.filter.models.building import FloorChanges, FloorStack
from mapfilter.filter.models.frame import StateFrame
from mapfilter.io.tracks import Track
from mapfilter.maps.building import Building
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.paths import detour_wall_crossings
from mapfilter.offline.placement import Anchor
from mapfilter.offline.smoother import ParticleHistory, smooth
from mapfilter.offline.whole_walk import placed_track
from mapfilter.sensors.pdr import Steps

__all__ = ["OTHER_FLOOR_MAX_S", "RESTART_RADIUS_M", "RESTART_SHARE", "WALL_REACH_SIGMAS", "CausalRun", "offline_track",
           "smoothed_track"]

# the second forward pass: half its particles near the placed start, the rest from the first
# scan as in the first pass, so that a wrong placement costs little (docs/accuracy.md)
RESTART_SHARE = 0.5
RESTART_RADIUS_M = 5.0
# the placed shape is bent by the walls within reach of its placement's error (the map
# matching's anchor_sigma_m); a walk whose smoothed track stays, at its median, farther from every
# wall than this many times that error keeps the smoothed track: there the rigid shape only adds
# its drift (docs/accuracy.md)
WALL_REACH_SIGMAS = 2.0
# a floor change reaches the smoothed track 0.5-1.5 s after the barometer (docs/ipin.md); longer
# on another floor than the whole walk's barometer says, and the run goes again from that floor
OTHER_FLOOR_MAX_S = 10.0


@dataclasses.dataclass(frozen=True)
class CausalRun:
    """What a walk's causal run leaves for the offline track (``pipeline.tracker.Tracker``)."""

    building: Building
    config: TrackingConfig
    plan: FloorPlan  # the filter's plan (a building's stack plan)
    evidence: WifiEvidence | BuildingEvidence | NoWifiEvidence
    stack: FloorStack | None  # several floors: the stack
    floors: FloorChanges | None  # several floors: the floor in the state
    floor_index: int | None  # the floor tracked on (None: the floor is in the state)
    steps: Steps | None  # the PDR steps the run took (None without PDR)
    causal: Track  # the causal track in the plan's frame
    history: ParticleHistory  # every step's cloud
    sources: tuple[MeasurementSource, ...]  # the measurement sources, with what they measured
    rng: np.random.Generator  # the run's generator, as the causal run left it
    start: Start = Start()  # where the run started (a known start: ``at_first_step``, in the plan's frame)


def offline_track(run: CausalRun, on_offline_step: Callable[[StepReport], None] | None = None,
                  on_smoothed: Callable[[float, np.ndarray, np.ndarray], None] | None = None
                  ) -> tuple[Track, Track | None]:
    """(the offline track in the plan's frame, or a floor's with its name; the second forward
    pass's causal track, None without one) (module docstring). ``on_offline_step`` sees the second
    pass step by step, ``on_smoothed`` the smoothed cloud of the filter's own run."""
    config, building = run.config, run.building
    steps = run.steps if config.motion.model == "pdr" else None
    places_shape = steps is not None and len(steps) > 0 and run.evidence.has_wifi  # by the scans
    smoothed = None
    if run.stack is not None or not places_shape or on_smoothed is not None:
        smoothed = smoothed_track(run.history, run.plan, config, run.floors, run.stack, on_smoothed)
    if run.stack is not None:
        again = _on_the_whole_walks_floor(run, smoothed)
        if again is not None:
            run = again
            smoothed = smoothed_track(run.history, run.plan, config, run.floors, run.stack, on_smoothed)
    if not places_shape:
        return smoothed, None
    plan, evidence, causal, floor_name, floor = run.plan, run.evidence, run.causal, None, run.floor_index
    if run.stack is not None:
        floor_of = run.stack.floor_of(smoothed.xy_m)
        floor = int(floor_of[0])
        if np.any(floor_of != floor) or run.evidence.floor_wifi[floor] is None:
            return smoothed, None
        # on one floor throughout: the walk as on that floor's own map
        plan, evidence, floor_name = building.floors[floor].plan, run.evidence.floor_wifi[floor], building.floor_names[floor]
        causal = dataclasses.replace(causal, xy_m=run.stack.to_floor(causal.xy_m)[0])
    anchor = _known_start_anchor(run, steps, floor)
    placed = placed_track(plan, evidence, steps, causal, config.offline, anchor)
    t0 = float(evidence.scans[int(np.argmax(evidence.usable))].t_s)
    start_xy = placed.xy_m[int(np.clip(np.searchsorted(placed.t_s, t0), 0, len(placed) - 1))]
    history = ParticleHistory()
    frame = StateFrame(building, floor or 0)  # every source's measurements, weighed on this floor's map
    sources = tuple(ReplayedMeasurements(source, source.model_on(frame)) for source in run.sources)
    # the second pass starts where the placed shape, turned by the rotation vector, puts the walk:
    # its particles' headings are left to the walls and the fixes where walls are within reach of
    # the causal track; on an open floor nothing but the rotation vector holds them (docs/accuracy.md)
    motion = config.motion
    if not _out_of_the_walls_reach(plan, causal.xy_m, config):
        motion = dataclasses.replace(config.motion, rotation_vector_sigma_deg=0.0)
    settings = RunSettings(motion, config.filter, config.steps.abs_heading_offset_rad)
    second = run_over_scans(plan, evidence, settings, run.rng, steps, sources=sources,
                            start=Start(start_xy, RESTART_RADIUS_M, RESTART_SHARE), on_step=on_offline_step,
                            history=history)
    second_smoothed = smoothed_track(history, plan, config)
    track = (second_smoothed if _out_of_the_walls_reach(plan, second_smoothed.xy_m, config)
             else placed_track(plan, evidence, steps, second_smoothed, config.offline, anchor))
    restarted = dataclasses.replace(second.track(), name="restarted")
    if floor_name is not None:  # the floor's probability is the smoother's at or before each row
        row = np.clip(np.searchsorted(smoothed.t_s, track.t_s, side="right") - 1, 0, len(smoothed) - 1)
        track = dataclasses.replace(track, floor=[floor_name] * len(track),
                                    floor_p=None if smoothed.floor_p is None else smoothed.floor_p[row])
        restarted = dataclasses.replace(restarted, floor=[floor_name] * len(restarted))
    return track, restarted


def _out_of_the_walls_reach(plan: FloorPlan, xy_m: np.ndarray, config: TrackingConfig) -> bool:
    """A track that stays, at its median, farther from every wall than ``WALL_REACH_SIGMAS``
    times the map matching's observation error: an open floor, where no wall bends a placed shape
    or holds a heading (module docstring; docs/accuracy.md)."""
    reach_m = WALL_REACH_SIGMAS * config.offline.map_matching.anchor_sigma_m
    return bool(np.median(plan.distance_to_wall_m(xy_m)) > reach_m)


def _on_the_whole_walks_floor(run: CausalRun, smoothed: Track) -> CausalRun | None:
    """The causal run again, its barometer's reference started on the floor every scan of the
    walk together puts the start on, when the smoothed run spent more than ``OTHER_FLOOR_MAX_S``
    on other floors than the barometer puts it on from there (a filter sure of the floor below
    from a start that matches it a little better: IPIN trial 01); None when the walk has no
    barometer, its scans do not say, or they agree with the run."""
    if not isinstance(run.evidence, BuildingEvidence) or len(smoothed) == 0:
        return None
    evidence = run.evidence
    floor = evidence.whole_walk_start_floor()
    if floor is None:
        return None
    expected = np.array([evidence.reference.floor_at(evidence.height_m(t)) for t in smoothed.t_s])
    off = run.stack.floor_of(smoothed.xy_m) != expected
    if np.sum(np.diff(smoothed.t_s, append=smoothed.t_s[-1])[off]) <= OTHER_FLOOR_MAX_S:
        return None
    history = ParticleHistory()
    evidence = evidence.restarted_on(floor)
    frame = StateFrame(run.building, 0, run.stack)
    sources = tuple(ReplayedMeasurements(source, source.model_on(frame)) for source in run.sources)
    settings = RunSettings(run.config.motion, run.config.filter, run.config.steps.abs_heading_offset_rad)
    steps = run.steps if run.config.motion.model == "pdr" else None
    again = run_over_scans(run.plan, evidence, settings, run.rng, steps, floors=run.floors, sources=sources,
                           start=run.start, history=history)
    return dataclasses.replace(run, evidence=evidence, causal=again.track(), history=history)


def _known_start_anchor(run: CausalRun, steps: Steps, floor: int | None) -> Anchor | None:
    """A known start as the placement's anchor (``offline.placement.Anchor``): the walk's shape,
    before its first step, within the start's radius of it, on the floor's own map (None: no
    known start, or one on another floor than the walk's)."""
    if not run.start.at_first_step or run.start.xy_m is None:
        return None
    xy = np.asarray(run.start.xy_m, dtype=np.float64).reshape(1, 2)
    if run.stack is not None:
        xy, start_floor = run.stack.to_floor(xy)
        if int(start_floor[0]) != floor:
            return None
    return Anchor(float(steps.t0_s), xy[0], float(run.start.radius_m))


def smoothed_track(history: ParticleHistory, plan: FloorPlan, config: TrackingConfig,
                   floors: FloorChanges | None = None, stack: FloorStack | None = None,
                   on_row: Callable[[float, np.ndarray, np.ndarray], None] | None = None) -> Track:
    """The smoothed means of a forward pass, made wall-free, with each row's floor share (a
    building's stack: ``floors`` and ``stack``)."""
    smoothed = smooth(history, plan, config.motion.motion_model, floors, on_row)
    floor_p, runs = None, [np.arange(len(smoothed.t_s))]
    if smoothed.floor_shares is not None:
        floor_of = stack.floor_of(smoothed.xy_m)
        floor_p = np.clip(smoothed.floor_shares[np.arange(len(floor_of)), floor_of], 0.0, 1.0)
        # a change of floor is a jump between floors' places in the stack's plan, not a move
        # through its walls: each stretch on one floor walks round its own walls
        runs = np.split(runs[0], np.flatnonzero(np.diff(floor_of)) + 1)
    parts = [detour_wall_crossings(plan, smoothed.t_s[run], smoothed.xy_m[run]) for run in runs]
    t_s, xy_m = np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
    row = np.clip(np.searchsorted(smoothed.t_s, t_s), 0, len(smoothed.t_s) - 1)
    return Track(t_s, xy_m, smoothed.std_m[row], smoothed.heading_rad[row], name="pf-smooth",
                 floor_p=None if floor_p is None else floor_p[row])
