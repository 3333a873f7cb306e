"""The offline track of a walk in a building: its floors decided from the whole walk, then each
floor's stretch placed and map-matched on that floor (``offline.whole_walk``).

``whole_walk_floors`` is the filter's own floor model smoothed instead of filtered (Viterbi);
``building_offline_track`` cuts the walk where that path changes floor and makes each stretch's
one-floor offline track, falling back to the filter's lineage where a stretch has too few steps
or no evidence on its floor. A walk on one floor throughout gets exactly the one-floor offline
track on that floor's map, restart run included.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from mapfilter.filter.models.barometer import barometric_height
from mapfilter.filter.events import StepReport
from mapfilter.filter.evidence import BuildingEvidence
from mapfilter.filter.models.building import FloorChanges, FloorStack
from mapfilter.filter.particle_filter import FilterConfig
from mapfilter.filter.tracker import MotionConfig
from mapfilter.maps.paths import detour_wall_crossings
from mapfilter.offline.placement import place_walk
from mapfilter.offline.whole_walk import OfflineConfig, OfflineTrack, restarted_run, placed_track, whole_walk_track
from mapfilter.sensors.floor_vote import WholeWalkFloors, whole_walk_floor_path
from mapfilter.sensors.pdr import Steps
from mapfilter.trackio import Track


def building_offline_track(changes: FloorChanges, evidence: BuildingEvidence, steps: Steps | None,
                           causal_stack: Track, lineage_stack: Track, motion: MotionConfig,
                           filter_config: FilterConfig, rng: np.random.Generator,
                           config: OfflineConfig = OfflineConfig(),
                           on_step: Callable[[StepReport], None] | None = None) -> OfflineTrack:
    """The offline track of a walk in a building, each row in its floor's frame with its floor's
    name and ``floor_p``, the whole-walk posterior of that floor.

    ``causal_stack`` and ``lineage_stack``: the causal track and the final best particle's
    lineage in the stack frame. The floors come from ``whole_walk_floors`` over the lineage
    (walked round the stack's walls); with PDR steps each floor's stretch is placed on its floor
    (``_by_floor``), else the lineage is the offline track.
    """
    stack = changes.stack
    t_s, xy_m = detour_wall_crossings(stack.plan, lineage_stack.t_s, lineage_stack.xy_m)
    whole = whole_walk_floors(changes, evidence, t_s, xy_m)
    track = _offline_track(stack, evidence, steps, causal_stack, t_s, xy_m, whole.path, motion, filter_config, rng,
                           config, on_step)
    return dataclasses.replace(track, track=_with_floor_p(stack, track.track, t_s, whole.posterior))


def _with_floor_p(stack: FloorStack, track: Track, t_s: np.ndarray, posterior: np.ndarray) -> Track:
    """The track with ``floor_p``: each row's floor's posterior at the nearest lineage row in time
    (the offline rows between two lineage rows are on the floor both of them are on)."""
    after = np.clip(np.searchsorted(t_s, track.t_s), 0, t_s.size - 1)
    before = np.clip(after - 1, 0, t_s.size - 1)
    row = np.where(np.abs(t_s[before] - track.t_s) <= np.abs(t_s[after] - track.t_s), before, after)
    floor = np.array([stack.building.floor_index(name) for name in track.floor])
    return dataclasses.replace(track, floor_p=np.clip(posterior[row, floor], 0.0, 1.0))


def _offline_track(stack: FloorStack, evidence: BuildingEvidence, steps: Steps | None, causal_stack: Track,
                   t_s: np.ndarray, xy_m: np.ndarray, floor: np.ndarray, motion: MotionConfig,
                   filter_config: FilterConfig, rng: np.random.Generator, config: OfflineConfig,
                   on_step: Callable[[StepReport], None] | None) -> OfflineTrack:
    """The offline track of the lineage rows ``t_s``, ``xy_m`` (stack frame) on the floors ``floor``."""
    lineage = _on_floors(stack, Track(t_s, xy_m, name="pf-smooth"), floor)
    if steps is None or motion.model != "pdr":
        return OfflineTrack(lineage)
    if np.all(floor == floor[0]):  # one floor throughout: the one-map offline track
        f = int(floor[0])
        placed = _stretch_on_floor(stack, evidence, steps, causal_stack, f, config)
        if placed is None:
            return OfflineTrack(lineage)
        floor_evidence = evidence.floor_wifi[f]
        if not config.restart_from_placement or floor_evidence is None:
            return OfflineTrack(placed)
        plan = stack.building.floors[f].plan
        name = stack.building.floor_names[f]
        restarted = restarted_run(plan, floor_evidence, steps, placed, motion, filter_config, rng, config, on_step)
        smoothed = placed_track(plan, floor_evidence, steps, restarted, config)
        return OfflineTrack(dataclasses.replace(smoothed, floor=[name] * len(smoothed)),
                            dataclasses.replace(restarted, floor=[name] * len(restarted)))
    return OfflineTrack(_by_floor(stack, evidence, steps, causal_stack, lineage, floor, config))


def _by_floor(stack: FloorStack, evidence: BuildingEvidence, steps: Steps, causal_stack: Track, lineage: Track,
              floor: np.ndarray, config: OfflineConfig) -> Track:
    """One stretch per floor of the whole-walk floor path: each stretch the one-floor offline track
    of its floor (``_stretch_on_floor``), or the lineage's rows where a stretch has too few steps
    or no evidence on its floor."""
    change = np.flatnonzero(floor[1:] != floor[:-1]) + 1
    starts, ends = np.concatenate([[0], change]), np.concatenate([change, [floor.size]])
    pieces: list[Track] = []
    for i, (start, end) in enumerate(zip(starts, ends)):
        # a stretch runs from the change into its floor to the change out of it; the first and
        # the last take every step before and after
        t0 = -np.inf if i == 0 else lineage.t_s[start]
        t1 = np.inf if i == len(starts) - 1 else lineage.t_s[end]
        placed = _stretch_on_floor(stack, evidence, steps.between(t0, t1), causal_stack, int(floor[start]), config,
                                   t0, t1)
        rows = np.arange(start, end)
        placed_t, placed_xy = np.zeros(0), np.zeros((0, 2))
        if placed is not None:
            # the stretch's first and last rows stay the lineage's, where the floor changes (in a
            # connector, as the whole-walk floor had it); so do its rows outside the placed steps
            # (a lift ride has none); the placed steps fill the rest
            first, last = lineage.t_s[start], lineage.t_s[end - 1]
            inner = ((placed.t_s > first) | (i == 0)) & ((placed.t_s < last) | (i == len(starts) - 1))
            placed_t, placed_xy = placed.t_s[inner], placed.xy_m[inner]
            if placed_t.size:
                outside = (lineage.t_s[rows] < placed_t[0]) | (lineage.t_s[rows] > placed_t[-1])
                rows = rows[outside | ((rows == start) & (i > 0)) | ((rows == end - 1) & (i < len(starts) - 1))]
        t_s = np.concatenate([lineage.t_s[rows], placed_t])
        order = np.argsort(t_s, kind="stable")
        piece = Track(t_s[order], np.vstack([lineage.xy_m[rows], placed_xy])[order],
                      floor=[lineage.floor[start]] * len(order), name=lineage.name)
        if pieces:  # keep time increasing across stretches
            keep = piece.t_s > pieces[-1].t_s[-1]
            piece = Track(piece.t_s[keep], piece.xy_m[keep], floor=[f for f, k in zip(piece.floor, keep) if k],
                          name=piece.name)
        pieces.append(piece)
    return Track(np.concatenate([p.t_s for p in pieces]), np.vstack([p.xy_m for p in pieces]),
                 floor=[f for p in pieces for f in p.floor], name=lineage.name)


def _stretch_on_floor(stack: FloorStack, evidence: BuildingEvidence, steps: Steps, causal_stack: Track, floor: int,
                      config: OfflineConfig, t0_s: float = -np.inf, t1_s: float = np.inf) -> Track | None:
    """The one-floor offline track (``offline.whole_walk.whole_walk_track``) of the stretch of a
    walk from ``t0_s`` to ``t1_s`` that the whole-walk floor keeps on ``floor`` (``steps``: its
    steps): its dead-reckoned shape placed by the fixes from that floor's fingerprints and the
    causal estimates on that floor, map-matched on that floor's plan. None when the stretch has
    fewer than two steps or no evidence on that floor."""
    if len(steps) < 2:
        return None
    scan_t = np.array([scan.t_s for scan in evidence.scans])
    inside = (scan_t > t0_s) & (scan_t <= t1_s)
    fixes_local = np.where(inside[:, None], evidence.fix_xy_m[:, floor] - stack.shift_m[floor], np.nan)  # NaN: no fix
    causal_local, causal_floor = stack.to_floor(causal_stack.xy_m)
    latest = np.searchsorted(causal_stack.t_s, scan_t, side="right") - 1
    at_scan = (latest >= 0) & inside
    at_scan[at_scan] = causal_floor[latest[at_scan]] == floor
    evidence_t = np.concatenate([scan_t, scan_t[at_scan]])
    evidence_xy = np.vstack([fixes_local, causal_local[latest[at_scan]]])
    if not np.isfinite(evidence_xy).all(axis=1).any():
        return None
    placement = place_walk(steps, evidence_t, evidence_xy, huber_m=config.placement.huber_m)
    track = whole_walk_track(stack.building.floors[floor].plan, placement, scan_t[inside], config)
    return dataclasses.replace(track, floor=[stack.building.floor_names[floor]] * len(track))


def whole_walk_floors(changes: FloorChanges, evidence: BuildingEvidence, t_s: np.ndarray,
                      stack_xy_m: np.ndarray) -> WholeWalkFloors:
    """The floor of every row (T,) of an offline track (stack frame), decided from the whole walk,
    and each row's floor posterior (``WholeWalkFloors``).

    The filter's own model, smoothed instead of filtered (``sensors.floor_vote.whole_walk_floor_path``,
    Viterbi; the posterior by forward-backward): each usable scan weighs floors by the filter's
    floor evidence (the WiFi vote); the walker changes floor at the filter's rates (``FloorChangeConfig``): with connectors only
    between floors a connector links and only at rows where the track's building-frame point is
    inside it on the floor left (at ``connector_rate_per_s``), without any anywhere (at
    ``anywhere_rate_per_s``); unlike the filter's particles, one storey at a time (to the next
    floor up or down, ``_next_floors``), as the walker's height passes every floor between. With
    a barometer, the height (centred, the whole walk at hand) weighs every row against the
    floors' elevations with one unknown offset for the walk.
    """
    stack, config = changes.stack, changes.config
    times = np.asarray(t_s, dtype=np.float64)
    n_rows, n_floors = times.size, stack.n_floors
    floor_evidence = np.zeros((n_rows, n_floors))
    scan_t = np.array([s.t_s for s in evidence.scans])
    # a scan weighs the last row at or before it (the row of the filter step it made); the scan
    # the filter started from comes before the lineage's first row: it weighs that row
    row = np.maximum(np.searchsorted(times, scan_t, side="right") - 1, 0)
    for i in np.flatnonzero(evidence.usable):
        floor_evidence[row[i]] += evidence.floor_log_likelihood[i]
    rates = np.zeros((max(n_rows - 1, 0), n_floors, n_floors))
    if changes.has_connectors:
        building_xy = stack.to_building(stack_xy_m)
        for f, floor in enumerate(stack.building.floors):
            local = floor.from_building(building_xy)
            _, _, inside = floor.plan.pixel_index(local)
            rows_px, cols_px, inside_stack = stack.plan.pixel_index(stack.to_stack(local, f))
            conn = np.full(n_rows, -1, dtype=np.int64)
            ok = inside & inside_stack
            conn[ok] = changes.connector_id[rows_px[ok], cols_px[ok]]
            # the filter moves a particle after its step's move: the position at the row reached
            for k in np.flatnonzero(conn[1:] >= 0):
                linked = list(changes.connector_cells[conn[k + 1]])
                if f in linked:
                    nearest = _next_floors(f, linked, evidence.elevation_m)
                    rates[k, f, nearest] += config.connector_rate_per_s / len(nearest)
    else:
        for f in range(n_floors):
            nearest = _next_floors(f, list(range(n_floors)), evidence.elevation_m)
            rates[:, f, nearest] = config.anywhere_rate_per_s / len(nearest)
    height = elevation = None
    if evidence.pressure is not None:
        baro_t, baro_h = barometric_height(*evidence.pressure, centred=True)
        height = np.interp(times, baro_t, baro_h)
        elevation = evidence.elevation_m
    return whole_walk_floor_path(times, floor_evidence, rates, height, elevation, evidence.barometer.sigma_m)


def _next_floors(floor: int, linked: list[int], elevation_m: np.ndarray) -> list[int]:
    """The floors of ``linked`` next above and next below ``floor`` by elevation: a walker's height
    passes every floor in between (a lift ride two storeys up passes the middle floor's height
    half-way), so over a walk's rows a floor change goes one storey at a time."""
    above = [g for g in linked if elevation_m[g] > elevation_m[floor]]
    below = [g for g in linked if elevation_m[g] < elevation_m[floor]]
    out = []
    if above:
        out.append(min(above, key=lambda g: elevation_m[g]))
    if below:
        out.append(max(below, key=lambda g: elevation_m[g]))
    # floors at one elevation (a building file without elevations): any of them
    return out or [g for g in linked if g != floor]


def _on_floors(stack: FloorStack, track: Track, floor: np.ndarray) -> Track:
    """A stack-frame track -> row k on floor ``floor[k]``, at the same building-frame point."""
    building_xy = stack.to_building(track.xy_m)
    xy = np.empty_like(building_xy)
    for f in np.unique(floor):
        on = floor == f
        xy[on] = stack.building.floors[f].from_building(building_xy[on])
    names = stack.building.floor_names
    return dataclasses.replace(track, xy_m=xy, floor=[names[f] for f in floor])


def to_floors(stack: FloorStack, track: Track) -> Track:
    """A stack-frame track -> each row in its floor's own frame, with the floor's name."""
    xy, floor = stack.to_floor(track.xy_m)
    names = stack.building.floor_names
    return dataclasses.replace(track, xy_m=xy, floor=[names[f] for f in floor])
