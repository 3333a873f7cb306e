"""Tracking in a building: one walk through the filter with the floor in its state.

``track_building`` is ``tracking.track_recording`` for a ``maps.building.Building``: with one
floor, or with the floor given, it is exactly that on the floor's plan (the same track for the
same seed); with several floors and the floor not given, the filter runs on the building's
stack plan (``filter.floors.FloorStack``): particles carry their floor, change floor only in
connectors (or anywhere at a small rate without any), and every scan weighs floors by the WiFi
floor vote and positions by the fix made from each floor's own fingerprints. Tracks come back
in each floor's own frame with the floor's name per row; the offline track's floor
(``config.smooth``) is decided from the whole walk (``whole_walk_floors``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.filter.events import StepReport
from mapfilter.filter.floors import FloorChangeConfig, FloorChanges, FloorFix, FloorFixLikelihood, FloorStack
from mapfilter.filter.placement import place_walk
from mapfilter.maps.building import Building
from mapfilter.sensors.floors import check_building_radio_map, floor_vote_log_likelihood, whole_walk_floor_path
from mapfilter.sensors.pdr import Steps, detect_steps
from mapfilter.sensors.radiomap import RadioMap
from mapfilter.sensors.recording import Recording
from mapfilter.sensors.wifi import WifiScan, scans_of
from mapfilter.tracking import (TrackingConfig, TrackingResult, WifiMeasurements, restarted_whole_walk, track_recording,
                                whole_walk_track)
from mapfilter.trackio import Track


# A phone barometer's height is good to about 0.25 m per sample and drifts with the weather by
# well under a metre in ten minutes; 1 m keeps a storey (4-5 m) four sigmas or more away.
BARO_SIGMA_M = 1.0
# the filter is sure of its floor (the barometer's reference may be moved to it) above this share
BARO_ANCHOR_SHARE = 0.95
# ... and only while the height is steady: less than this change over the last few seconds
BARO_STEADY_M = 0.5
BARO_STEADY_WINDOW_S = 3.0
# The reference follows the weather only, at most this fast: 0.01 m/s is 36 m/h, about 4 hPa/h,
# above any weather front (1-3 hPa/h). A climber pausing on the stairs looks steady for a few
# seconds; without this limit the reference crept up with each pause (1.25 m half-way up a
# simulated flight) and the new floor was found seconds late.
BARO_DRIFT_M_PER_S = 0.01


class BarometerReference:
    """The barometer's zero for floor evidence: a barometer measures height *changes* only (the
    weather moves its zero), so it is read against a reference, a floor the filter was sure of
    and the barometer's height then.

    ``update`` sets the reference when the filter is sure of its floor (``BARO_ANCHOR_SHARE``)
    while the height is steady, and afterwards moves it no faster than the weather moves a
    barometer (``BARO_DRIFT_M_PER_S``), never to a floor the barometer disagrees with;
    ``floor_log_likelihood`` gives a floor of elevation e the value
    -(e - (e_ref + h - h_ref))^2 / (2 BARO_SIGMA_M^2).
    """

    def __init__(self, elevation_m: np.ndarray) -> None:
        self.elevation_m = np.asarray(elevation_m, dtype=np.float64)
        self.anchor: tuple[int, float, float] | None = None  # (floor, barometer height, time)

    def update(self, t_s: float, height_m: float, steady: bool, floor_shares: np.ndarray) -> None:
        """After a filter step at ``t_s``: the barometer's height, whether it was steady, and the
        filter's share of weight per floor."""
        floor = int(np.argmax(floor_shares))
        if not (steady and float(np.max(floor_shares)) >= BARO_ANCHOR_SHARE):
            return
        if self.anchor is None:
            self.anchor = (floor, height_m, t_s)
            return
        ref_floor, h_ref, t_ref = self.anchor
        h_floor = h_ref + self.elevation_m[floor] - self.elevation_m[ref_floor]  # the floor's height by the reference
        # never move the reference to a floor the barometer disagrees with: a filter that
        # missed a floor change would otherwise silence the barometer for good
        if abs(height_m - h_floor) > 2.0 * BARO_SIGMA_M:
            return
        drift = BARO_DRIFT_M_PER_S * max(t_s - t_ref, 0.0)
        self.anchor = (floor, h_floor + float(np.clip(height_m - h_floor, -drift, drift)), t_s)

    def floor_log_likelihood(self, height_m: float) -> np.ndarray | None:
        """(F,) log-likelihood of each floor at barometer height ``height_m``; None before a reference."""
        if self.anchor is None:
            return None
        floor, h_ref, _ = self.anchor
        expected = self.elevation_m[floor] + height_m - h_ref
        return -0.5 * ((self.elevation_m - expected) / BARO_SIGMA_M) ** 2


class BuildingWifi:
    """A walk's scans as the multi-floor filter weighs them (``FloorFix`` per scan).

    Per floor, the fix of ``tracking.WifiMeasurements`` made from that floor's fingerprints only
    (so ``blend``, ``fix`` and the fix-sigma calibration work as on one floor), moved into the
    stack frame; per scan, the floor vote of ``sensors.floors.floor_vote_log_likelihood`` over
    the whole building's fingerprints.

    With a barometer (``pressure``: times and hPa), each scan, and each filter step between
    scans (``between_scans``), also weighs floors by height against a ``BarometerReference``
    that ``observe`` keeps.
    """

    def __init__(self, scans: list[WifiScan], radio_map: RadioMap, stack: FloorStack, config: TrackingConfig,
                 fix_sigma_per_floor_m: dict[str, float] | None = None, log_name: str = "the log",
                 pressure: tuple[np.ndarray, np.ndarray] | None = None,
                 floor_evidence: np.ndarray | None = None):
        names = stack.building.floor_names
        check_building_radio_map(radio_map, names)
        self.scans = scans
        n_scans, n_floors = len(scans), len(names)
        self.fix_xy_m = np.full((n_scans, n_floors, 2), np.nan)
        # each floor's own measurements (None: its fingerprints share nothing with the walk)
        self.floor_wifi: list[WifiMeasurements | None] = [None] * n_floors
        sigma = np.full(n_floors, 5.0)
        for f, floor in enumerate(stack.building.floors):
            sub = radio_map.floor_map(f)
            if len(sub) == 0:
                continue
            floor_config = config
            if fix_sigma_per_floor_m and floor.name in fix_sigma_per_floor_m:
                floor_config = dataclasses.replace(config, fix_sigma_m=fix_sigma_per_floor_m[floor.name])
            try:
                wifi = WifiMeasurements(scans, sub, None, floor.plan, floor_config, log_name)
            except MapfilterError:
                continue  # this floor's fingerprints share nothing with the walk: no fix there
            if wifi.fix_xy_m is None:
                raise MapfilterError("tracking across floors weighs fingerprint fixes: use the fingerprint "
                                     "model fix or blend")
            self.fix_xy_m[:, f] = stack.to_stack(wifi.fix_xy_m, f)
            self.floor_wifi[f] = wifi
            sigma[f] = wifi.model.sigma_m
        if floor_evidence is not None:
            self.floor_log_likelihood = np.asarray(floor_evidence, dtype=np.float64)
        else:
            self.floor_log_likelihood = floor_vote_log_likelihood(radio_map, radio_map.scan_matrix(scans),
                                                                  k=config.kwnn_k)
        self.elevation_m = np.array([f.elevation_m for f in stack.building.floors])
        self.pressure = pressure if pressure is not None and len(pressure[0]) >= 2 else None
        self.baro = None if self.pressure is None else barometric_height(*self.pressure)
        self.reference = BarometerReference(self.elevation_m)
        self.usable = np.isfinite(self.fix_xy_m).all(axis=2).any(axis=1)
        if not self.usable.any():
            raise MapfilterError(f"no WiFi scan of {log_name} gives a fingerprint fix with this radio map")
        self.model = FloorFixLikelihood(stack, sigma)

    def height_m(self, t_s: float) -> float:
        """The barometer's height at ``t_s`` (relative to its first sample), NaN without one."""
        if self.baro is None:
            return float("nan")
        # the last reading at or before t_s: nothing from the future
        i = int(np.searchsorted(self.baro[0], t_s, side="right")) - 1
        return float(self.baro[1][max(i, 0)])

    def observe(self, report: StepReport) -> None:
        """After each filter step: move the barometer's reference (``BarometerReference.update``);
        steady = less than ``BARO_STEADY_M`` of height change over ``BARO_STEADY_WINDOW_S``."""
        if self.baro is None or report.floor_shares is None:
            return
        h = self.height_m(report.t_s)
        steady = abs(h - self.height_m(report.t_s - BARO_STEADY_WINDOW_S)) < BARO_STEADY_M
        self.reference.update(report.t_s, h, steady, report.floor_shares)

    def between_scans(self, t_s: float) -> FloorFix | None:
        """The barometer alone at ``t_s`` (a step between scans): floors weighed by height as in
        ``measurement``, no position fix; None without a barometer or before a reference."""
        if self.baro is None:
            return None
        floor_ll = self.reference.floor_log_likelihood(self.height_m(t_s))
        if floor_ll is None:
            return None
        return FloorFix(np.full((len(self.elevation_m), 2), np.nan), floor_ll, int(np.argmax(floor_ll)))

    def measurement(self, index: int) -> FloorFix | None:
        """The scan ``index`` as a ``FloorFix`` (None when no floor gives it a fix)."""
        if not self.usable[index]:
            return None
        floor_ll = self.floor_log_likelihood[index]
        height_floor = None
        if self.baro is not None:
            height_ll = self.reference.floor_log_likelihood(self.height_m(self.scans[index].t_s))
            if height_ll is not None:
                floor_ll = floor_ll + height_ll
                height_floor = int(np.argmax(height_ll))
        return FloorFix(self.fix_xy_m[index], floor_ll, height_floor)


def barometric_height(t_s: np.ndarray, pressure_hpa: np.ndarray, window_s: float = 2.0,
                      centred: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(times, heights in metres relative to the first sample) from barometer readings: the
    international barometric formula h = 44330.8 (1 - (p / p_first)^(1 / 5.25588)) of the
    pressure smoothed causally, from the readings of the last ``window_s`` only (a phone
    barometer's noise is about 0.25 m per sample): the end of a straight line fitted to them,
    which, unlike their mean, does not lag a climb or a ride by half the window.

    ``centred`` (offline, the whole walk at hand): the same line read at its middle, i.e. the
    window's mean at the window's mean time, with half the noise of its end."""
    t = np.asarray(t_s, dtype=np.float64)
    p_hpa = np.asarray(pressure_hpa, dtype=np.float64)
    p = p_hpa - p_hpa[0]  # small numbers keep the windowed sums exact over long logs
    tr = t - t[0]
    lo = np.searchsorted(t, t - window_s, side="left")
    hi = np.arange(1, t.size + 1)  # reading i's window ends at reading i

    def window_sum(x: np.ndarray) -> np.ndarray:
        cum = np.concatenate([[0.0], np.cumsum(x)])
        return cum[hi] - cum[lo]

    # least squares p = mean_p + slope (t - mean_t) over each window, at the window's last reading
    n = (hi - lo).astype(np.float64)
    mean_t, mean_p = window_sum(tr) / n, window_sum(p) / n
    var_t = window_sum(tr * tr) / n - mean_t ** 2
    cov = window_sum(tr * p) / n - mean_t * mean_p
    slope = np.where(var_t > 1e-9, cov / np.maximum(var_t, 1e-9), 0.0)
    if centred:
        t, smooth = t[0] + mean_t, p_hpa[0] + mean_p
    else:
        smooth = p_hpa[0] + mean_p + slope * (tr - mean_t)
    return t, 44330.8 * (1.0 - (smooth / smooth[0]) ** (1.0 / 5.25588))


def track_building(
    building: Building,
    recording: Recording,
    radio_map: RadioMap,
    config: TrackingConfig = TrackingConfig(),
    rng: np.random.Generator | None = None,
    on_step: Callable[[StepReport], None] | None = None,
    floor: str | None = None,
    fix_sigma_per_floor_m: dict[str, float] | None = None,
    floor_changes: FloorChangeConfig = FloorChangeConfig(),
    use_barometer: bool = True,
    floor_evidence: np.ndarray | None = None,
    on_restart_step: Callable[[StepReport], None] | None = None,
) -> TrackingResult:
    """Track one walk in a building; tracks in each floor's own frame with a floor per row.

    Parameters
    ----------
    building : the floors (a one-floor building is a single map).
    recording : the walk.
    radio_map : a building's radio map (floor labels), or any radio map for one floor.
    config, rng, on_step : as for ``tracking.track_recording``.
    floor : track on this floor only (the floor given) instead of finding it.
    fix_sigma_per_floor_m : the fix Gaussian of each floor by name, instead of calibrating it
        from each floor's fingerprints.
    floor_changes : how particles change floor.
    use_barometer : weigh floors by the log's barometer (``TYPE_PRESSURE`` rows) when it has one.
    floor_evidence : (S, F) floor log-likelihood per scan instead of the WiFi floor vote (e.g.
        the true floor, to measure what finding the floor costs on a walk that changes floor).
    on_restart_step : as for ``tracking.track_recording``: the offline track's second filter run
        (``TrackingConfig.restart_from_placement``; here for a walk on one floor throughout).
    """
    rng = rng if rng is not None else np.random.default_rng(0)
    if building.is_single_floor or floor is not None:
        index = 0 if building.is_single_floor else building.floor_index(floor)
        plan = building.floors[index].plan
        floor_map = radio_map.floor_map(index) if radio_map.has_floors else radio_map
        if radio_map.has_floors and radio_map.floor_names[index] != building.floors[index].name:
            raise MapfilterError(f"the radio map's floor {radio_map.floor_names[index]!r} is not the building's "
                                 f"{building.floors[index].name!r}")
        if fix_sigma_per_floor_m and building.floors[index].name in fix_sigma_per_floor_m:
            config = dataclasses.replace(config, fix_sigma_m=fix_sigma_per_floor_m[building.floors[index].name])
        result = track_recording(plan, recording, floor_map, None, config, rng, on_step=on_step,
                                 on_restart_step=on_restart_step)
        name = building.floors[index].name
        result.track.floor = [name] * len(result.track)
        for track in (result.smoothed, result.restarted):
            if track is not None:
                track.floor = [name] * len(track)
        return result
    if not config.use_map:
        raise MapfilterError("tracking across floors needs the walls (the floors are kept apart by them): "
                             "drop --no-map or give the floor")
    stack = FloorStack(building)
    log_name = str(recording.path) if recording.path is not None else "the log"
    pressure = None
    if use_barometer and recording.pressure_t_s.size >= 2:
        pressure = (recording.pressure_t_s, recording.pressure_hpa)
    wifi = BuildingWifi(scans_of(recording), radio_map, stack, config, fix_sigma_per_floor_m, log_name,
                        pressure=pressure, floor_evidence=floor_evidence)
    changes = FloorChanges(stack, floor_changes)

    def step_hook(report: StepReport) -> None:
        wifi.observe(report)
        if on_step is not None:
            on_step(report)

    steps = detect_steps(recording, config.pdr) if config.motion == "pdr" else None  # once: filter and offline track
    result = track_recording(stack.plan, recording, None, None, config, rng, on_step=step_hook, steps=steps,
                             wifi=wifi, floors=changes)
    stack_track = result.track
    result.track = _to_floors(stack, result.track)
    if result.smoothed is not None:
        floor = whole_walk_floors(changes, wifi, result.smoothed.t_s, result.smoothed.xy_m)
        lineage = _on_floors(stack, result.smoothed, floor)

        def restart(f: int, placed: Track) -> Track:
            # a walk on one floor throughout: its offline track as --smooth makes it on that floor's
            # map, from a second (one-floor) filter run started at the placed start
            if not config.restart_from_placement or wifi.floor_wifi[f] is None:
                return placed
            result.restarted, smoothed = restarted_whole_walk(building.floors[f].plan, wifi.floor_wifi[f], steps,
                                                              config, rng, placed, on_restart_step)
            for track in (result.restarted, smoothed):
                track.floor = [building.floors[f].name] * len(track)
            return smoothed

        result.smoothed = (_whole_walk_by_floor(stack, wifi, steps, stack_track, lineage, floor, restart)
                           if steps is not None else lineage)
    return result


def _whole_walk_by_floor(stack: FloorStack, wifi: BuildingWifi, steps: Steps, causal_stack: Track, lineage: Track,
                         floor: np.ndarray, restart: Callable[[int, Track], Track] | None = None) -> Track:
    """The offline track, one stretch per floor of the whole-walk floor path: each stretch the
    one-floor whole-walk track of its floor (``_whole_walk_on_one_floor``), or the lineage's rows
    where a stretch has too few steps or no evidence on its floor. A walk on one floor throughout
    then goes through ``restart(floor, placed)`` (the restarted whole-walk track)."""
    if np.all(floor == floor[0]):  # one floor throughout: the one-map offline track
        placed = _whole_walk_on_one_floor(stack, wifi, steps, causal_stack, int(floor[0]))
        if placed is None:
            return lineage
        return restart(int(floor[0]), placed) if restart is not None else placed
    change = np.flatnonzero(floor[1:] != floor[:-1]) + 1
    starts, ends = np.concatenate([[0], change]), np.concatenate([change, [floor.size]])
    pieces: list[Track] = []
    for i, (start, end) in enumerate(zip(starts, ends)):
        # a stretch runs from the change into its floor to the change out of it; the first and
        # the last take every step before and after
        t0 = -np.inf if i == 0 else lineage.t_s[start]
        t1 = np.inf if i == len(starts) - 1 else lineage.t_s[end]
        placed = _whole_walk_on_one_floor(stack, wifi, steps.between(t0, t1), causal_stack, int(floor[start]), t0, t1)
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


def _whole_walk_on_one_floor(stack: FloorStack, wifi: BuildingWifi, steps: Steps, causal_stack: Track, floor: int,
                             t0_s: float = -np.inf, t1_s: float = np.inf) -> Track | None:
    """The one-floor offline track (``tracking.whole_walk_track``) of the stretch of a walk from
    ``t0_s`` to ``t1_s`` that the whole-walk floor keeps on ``floor`` (``steps``: its steps): its
    dead-reckoned shape placed by the fixes from that floor's fingerprints and the causal
    estimates on that floor, map-matched on that floor's plan. The particle lineage it replaces
    keeps the causal filter's errors (ILC site 1: see the README). None when the stretch has
    fewer than two steps or no evidence on that floor."""
    if len(steps) < 2:
        return None
    scan_t = np.array([scan.t_s for scan in wifi.scans])
    inside = (scan_t > t0_s) & (scan_t <= t1_s)
    fixes_local = np.where(inside[:, None], wifi.fix_xy_m[:, floor] - stack.shift_m[floor], np.nan)  # NaN: no fix
    causal_local, causal_floor = stack.to_floor(causal_stack.xy_m)
    latest = np.searchsorted(causal_stack.t_s, scan_t, side="right") - 1
    at_scan = (latest >= 0) & inside
    at_scan[at_scan] = causal_floor[latest[at_scan]] == floor
    evidence_t = np.concatenate([scan_t, scan_t[at_scan]])
    evidence_xy = np.vstack([fixes_local, causal_local[latest[at_scan]]])
    if not np.isfinite(evidence_xy).all(axis=1).any():
        return None
    placement = place_walk(steps, evidence_t, evidence_xy)
    track = whole_walk_track(stack.building.floors[floor].plan, placement, scan_t[inside])
    track.floor = [stack.building.floor_names[floor]] * len(track)
    return track


def whole_walk_floors(changes: FloorChanges, wifi: BuildingWifi, t_s: np.ndarray, stack_xy_m: np.ndarray) -> np.ndarray:
    """(T,) the floor of every row of an offline track (stack frame), decided from the whole walk.

    The filter's own model, smoothed instead of filtered (``sensors.floors.whole_walk_floor_path``,
    Viterbi): each usable scan weighs floors by the filter's floor evidence (the WiFi vote);
    the walker changes floor at the filter's rates (``FloorChangeConfig``): with connectors only
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
    evidence = np.zeros((n_rows, n_floors))
    scan_t = np.array([s.t_s for s in wifi.scans])
    # a scan weighs the last row at or before it (the row of the filter step it made); the scan
    # the filter started from comes before the lineage's first row: it weighs that row
    row = np.maximum(np.searchsorted(times, scan_t, side="right") - 1, 0)
    for i in np.flatnonzero(wifi.usable):
        evidence[row[i]] += wifi.floor_log_likelihood[i]
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
                    nearest = _next_floors(f, linked, wifi.elevation_m)
                    rates[k, f, nearest] += config.connector_rate_per_s / len(nearest)
    else:
        for f in range(n_floors):
            nearest = _next_floors(f, list(range(n_floors)), wifi.elevation_m)
            rates[:, f, nearest] = config.anywhere_rate_per_s / len(nearest)
    height = elevation = None
    if wifi.pressure is not None:
        baro_t, baro_h = barometric_height(*wifi.pressure, centred=True)
        height = np.interp(times, baro_t, baro_h)
        elevation = wifi.elevation_m
    return whole_walk_floor_path(times, evidence, rates, height, elevation, BARO_SIGMA_M).path


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


def _to_floors(stack: FloorStack, track: Track) -> Track:
    """A stack-frame track -> each row in its floor's own frame, with the floor's name."""
    xy, floor = stack.to_floor(track.xy_m)
    names = stack.building.floor_names
    return dataclasses.replace(track, xy_m=xy, floor=[names[f] for f in floor])

