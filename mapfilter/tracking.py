"""Tracking: one walk (map + log) through the particle filter, from WiFi scans and PDR steps.

This is the pipeline behind ``mapfilter track`` and the ``pf*`` methods of ``mapfilter
evaluate``: it reads nothing and writes nothing, it turns a ``Recording`` into a ``Track``.

Events, in time order: every detected step moves the particles (PDR motion, one filter step
per step, so the wall check sees each short move) or, for the ``cv``/``rw`` motion models,
a prediction tick every ``tick_s``; every WiFi scan weighs them. The filter starts at the
first scan that gives a usable measurement, drawn over the map's free space from that
scan's likelihood (the starting position is unknown).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.filter.adaptive_pathloss import AdaptationConfig, AdaptiveTrilaterationLikelihood, BlockingConfig
from mapfilter.filter.estimate import circular_mean
from mapfilter.filter.events import CollapseEvent, StepReport
from mapfilter.filter.map_matching import map_match
from mapfilter.filter.measurement import GaussianFixLikelihood, PositionFix, TrilaterationLikelihood
from mapfilter.filter.motion import ConstantVelocityMotion, PDRMotion, RandomWalkMotion, StepInput
from mapfilter.filter.pf import FilterConfig, ParticleFilter
from mapfilter.filter.placement import WalkPlacement, place_walk, shift_onto_free_space
from mapfilter.filter.radiomap_likelihood import RadioMapLikelihood, RadioMapLikelihoodConfig, radio_map_likelihood
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.paths import detour_wall_crossings, wall_free_track
from mapfilter.sensors.pathloss import AccessPointTable, least_squares_position, match_scan
from mapfilter.sensors.pdr import PDRConfig, Steps, detect_steps
from mapfilter.sensors.radiomap import (STRONG_MIN_RSSI_DBM, RadioMap, cross_validated_fix_errors, kwnn_fix_many,
                                       strong_kwnn_fixes)
from mapfilter.sensors.recording import Recording
from mapfilter.sensors.wifi import WifiScan, scans_of
from mapfilter.trackio import Track

MOTION_MODELS = ("pdr", "cv", "rw")
FINGERPRINT_MODELS = ("fix", "blend", "likelihood")


@dataclasses.dataclass(frozen=True)
class TrackingConfig:
    """How a walk is tracked (defaults in comments are what ``mapfilter track`` uses)."""

    motion: str = "pdr"  # pdr | cv (constant velocity) | rw (random walk on a circle)
    n_particles: int = 10_000  # Evennou & Marx use 10,000
    use_map: bool = True  # False: walls ignored (the "pf-nomap" comparison)
    # fix: KWNN fix + Gaussian (Evennou & Marx) | blend: the fix is the mean of the KWNN fix and
    # the radio-map likelihood's best cell (two estimators that err differently where the survey
    # is thin; on ILC site 1 blend lowered pf's mean error on all three sets: F1 sparse 11.7 ->
    # 10.7 m, F1 dense 6.1 -> 5.4 m, F2 21.3 -> 20.8 m) | likelihood: per-particle radio map
    fingerprint_model: str = "blend"
    # Gaussian of the fingerprint fix; None = calibrated from the radio map itself: the RMS of
    # its cross-validated KWNN errors over sqrt(2) (a 2-D Gaussian's E|d|^2 = 2 sigma^2). Evennou
    # & Marx fix 5 m for a dense office survey; the bundled office calibrates to 2.4 m, ILC
    # site1 F1 (leave-one-trace-out) to about 18 m, where 5-30 m tried by tools/tune_ilc.py put
    # the best at 15-20 m: the calibration lands where tuning would.
    fix_sigma_m: float | None = None
    kwnn_k: int = 4  # Chang et al.
    # the filter's KWNN fixes use readings at or above this only (``strong_kwnn_fixes``: phones
    # disagree most on weak APs); None = plain KWNN over every reading, as the kwnn baseline
    kwnn_min_rssi_dbm: float | None = STRONG_MIN_RSSI_DBM
    rssi_variance_db2: float = 25.0  # trilateration (Lund thesis)
    tick_s: float = 1.0  # cv / rw: prediction interval between scans
    # PDR: the longest gap between filter steps while a barometer can weigh floors (a lift ride
    # has no steps, and scans are 2-4 s apart): about a walker's step interval, so the height
    # weighs floors as often standing as walking
    idle_tick_s: float = 0.5
    use_abs_heading: bool = True  # PDR: start headings from the rotation vector when the log has one
    heading_source: str = "gyro"  # PDR per step: gyro (heading change) | rotation_vector (absolute heading)
    # spread around that start heading: the rotation vector's heading deviates from the ILC
    # waypoint legs by 8.8 deg median (tools/report_pdr.py); 0.2 rad (11.5 deg) measured better
    # and steadier across seeds than 30 deg on ILC F1 (tools/tune_ilc.py: mean ratio to KWNN
    # 0.775 vs 0.785-0.850)
    initial_heading_sigma_rad: float = 0.2
    step_length_source: str = "state"  # PDR: state (per-particle, adapted; thesis eq. 8.23) | weinberg (per step)
    # also return the offline track: with PDR the whole-walk estimate (``whole_walk_track``),
    # otherwise the lineage of the final best particle (ancestry; costs memory)
    smooth: bool = False
    # the offline track's causal evidence from a second filter run, started where the first
    # run's whole-walk track puts the walk's start (RESTART_RADIUS_M) instead of at its first fix.
    # ILC site 1, pf-smooth mean / p75 m over seeds 0-4: F1 sparse 7.24 / 7.12 -> 6.94 / 7.17, F1 dense
    # 4.14 / 4.99 -> 4.11 / 4.89, F2 16.80 / 24.57 -> 16.82 / 24.29 (docs/accuracy.md); a third run
    # gained nothing. Costs a second filter run per walk
    restart_from_placement: bool = True
    filter: FilterConfig = dataclasses.field(default_factory=FilterConfig)  # n_particles above wins
    pdr: PDRConfig = dataclasses.field(default_factory=PDRConfig)
    # heading noise per step 0.02 rad: the gyro is good over a step; 0.05 (the PDRMotion default,
    # for coarser filter steps) let clouds fan out and measured worse on ILC F1
    pdr_motion: PDRMotion = dataclasses.field(default_factory=lambda: PDRMotion(heading_sigma_rad=0.02))
    radio_map_likelihood: RadioMapLikelihoodConfig = dataclasses.field(default_factory=RadioMapLikelihoodConfig)
    # trilateration only (Lund thesis chapter 7, ``filter/adaptive_pathloss.py``):
    adapt_path_loss: bool = False  # online adaptation of C (per AP) and alpha (per band) (7.1-7.2)
    blocking_compensation: bool = True  # H dB off every AP while all drop together (7.3)
    adaptation: AdaptationConfig = dataclasses.field(default_factory=AdaptationConfig)
    blocking: BlockingConfig = dataclasses.field(default_factory=BlockingConfig)

    def __post_init__(self) -> None:
        if self.motion not in MOTION_MODELS:
            raise MapfilterError(f"unknown motion model {self.motion!r}: choose one of {', '.join(MOTION_MODELS)}")
        if self.fingerprint_model not in FINGERPRINT_MODELS:
            raise MapfilterError(f"unknown fingerprint model {self.fingerprint_model!r}: "
                                 f"choose one of {', '.join(FINGERPRINT_MODELS)}")
        if self.step_length_source not in ("state", "weinberg"):
            raise MapfilterError(f"unknown step length source {self.step_length_source!r}: choose state or weinberg")
        if self.heading_source not in ("gyro", "rotation_vector"):
            raise MapfilterError(f"unknown heading source {self.heading_source!r}: choose gyro or rotation_vector")
        if self.n_particles < 1:
            raise MapfilterError(f"the number of particles must be at least 1, got {self.n_particles}")


@dataclasses.dataclass
class TrackingResult:
    track: Track  # causal: the estimate after every filter step
    smoothed: Track | None  # offline, whole walk (only with config.smooth)
    collapses: list[CollapseEvent]
    n_filter_steps: int
    n_scans_used: int
    runtime_s: float
    ap_table: AccessPointTable | None = None  # trilateration: the table at the end (adapted with adapt_path_loss)
    # the second filter run, started at the placed start (``TrackingConfig.restart_from_placement``):
    # its causal estimates placed the offline track; None without that run
    restarted: Track | None = None


class WifiMeasurements:
    """Turns a walk's WiFi scans into (model, measurement) pairs for the filter.

    Fingerprinting (a radio map): ``fix`` makes one KWNN fix per scan (Chang et al.) and
    weighs it with a Gaussian (Evennou & Marx); ``blend`` weighs the mean of that fix and the
    radio-map likelihood's best cell the same way; ``likelihood`` weighs each particle by the
    radio map's own probability of the scan. Trilateration (an access-point table): the Lund
    thesis path-loss likelihood.
    """

    def __init__(self, scans: list[WifiScan], radio_map: RadioMap | None, ap_table: AccessPointTable | None,
                 floorplan: FloorPlan, config: TrackingConfig, log_name: str = "the log"):
        if (radio_map is None) == (ap_table is None):
            raise MapfilterError("give either a radio map (fingerprinting) or an access-point table (trilateration)")
        self.scans = scans
        self._radio_map, self._floorplan, self._config = radio_map, floorplan, config.radio_map_likelihood
        self.fix_xy_m: np.ndarray | None = None  # fingerprint fixes, one per scan (NaN: none)
        self.kwnn_xy_m: np.ndarray | None = None  # KWNN fixes, one per scan (NaN: none)
        self._radio_map_model: RadioMapLikelihood | None = None
        self._best_cell_xy_m: np.ndarray | None = None
        self.usable = np.ones(len(scans), dtype=bool)
        if radio_map is not None:
            shared = np.array([sum(k in radio_map.key_index for k in s.ap_keys) for s in scans])
            if not shared.any():
                raise MapfilterError(f"the radio map shares no access point with {log_name}")
            if config.fingerprint_model in ("fix", "blend"):
                matrix = radio_map.scan_matrix(scans)
                if config.kwnn_min_rssi_dbm is None:
                    self.kwnn_xy_m = kwnn_fix_many(radio_map, matrix, k=config.kwnn_k).xy_m
                else:
                    self.kwnn_xy_m = strong_kwnn_fixes(radio_map, matrix, config.kwnn_k, config.kwnn_min_rssi_dbm)
                self.fix_xy_m = self.kwnn_xy_m
                if config.fingerprint_model == "blend":
                    best = self.best_cell_xy_m()
                    self.fix_xy_m = np.where(np.isfinite(best), 0.5 * (self.kwnn_xy_m + best), self.kwnn_xy_m)
                self.usable = np.all(np.isfinite(self.fix_xy_m), axis=1)
                sigma_m = config.fix_sigma_m if config.fix_sigma_m is not None else calibrated_fix_sigma_m(
                    radio_map, config.kwnn_k)
                self.model = GaussianFixLikelihood(sigma_m=sigma_m)
            else:
                self.model = self.radio_map_model()
                self.usable = shared >= 1
        else:
            assert ap_table is not None
            rows = [match_scan(ap_table, s)[0] for s in scans]
            self.usable = np.array([r.size > 0 for r in rows])
            if not self.usable.any():
                raise MapfilterError(f"the access-point table shares no access point with {log_name}")
            self.model = trilateration_model(ap_table, config)
        if not self.usable.any():
            raise MapfilterError(f"no WiFi scan of {log_name} gives a fingerprint fix with this radio map")

    def measurement(self, index: int) -> Any:
        """The measurement the filter weighs for scan ``index`` (None when the scan is unusable)."""
        if not self.usable[index]:
            return None
        if self.fix_xy_m is not None:
            return PositionFix(self.fix_xy_m[index])
        return self.scans[index]

    def between_scans(self, t_s: float) -> Any:
        """What the filter weighs at a step between scans: nothing on one floor (a building's
        ``floortracking.BuildingWifi`` gives the barometer's floor evidence there)."""
        return None

    def radio_map_model(self) -> RadioMapLikelihood:
        """The radio-map likelihood (needs a radio map): built once per radio map and shared with
        the other walks tracked with it (per-AP tables for the APs the walks hear)."""
        if self._radio_map_model is None:
            heard = {key for scan in self.scans for key in scan.ap_keys}
            self._radio_map_model = radio_map_likelihood(self._radio_map, self._floorplan, self._config, heard)
        return self._radio_map_model

    def best_cell_xy_m(self) -> np.ndarray:
        """(S, 2) the radio-map likelihood's best cell per scan (NaN: scan without a fix, or for
        the likelihood model without a known AP: it says nothing about where it was)."""
        if self._best_cell_xy_m is None:
            model = self.radio_map_model()
            out = np.full((len(self.scans), 2), np.nan)
            for i, scan in enumerate(self.scans):
                known = self.usable[i] if self.kwnn_xy_m is None else np.isfinite(self.kwnn_xy_m[i]).all()
                if known:
                    out[i] = model.best_position(scan)
            self._best_cell_xy_m = out
        return self._best_cell_xy_m

    def position_fixes(self) -> list[np.ndarray]:
        """Position estimates per scan from each WiFi estimator at hand, each (S, 2), NaN where
        none: with a radio map the KWNN fixes (fix, blend) and the radio-map likelihood's best
        cell, with an access-point table the least-squares trilateration (3 APs or more)."""
        if self._radio_map is not None:
            return [f for f in (self.kwnn_xy_m, self.best_cell_xy_m()) if f is not None]
        out = np.full((len(self.scans), 2), np.nan)
        for i, scan in enumerate(self.scans):
            if self.usable[i] and match_scan(self.model.ap_table, scan)[0].size >= 3:
                out[i] = least_squares_position(self.model.ap_table, scan)
        return [out]


def trilateration_model(ap_table: AccessPointTable, config: TrackingConfig):
    """The path-loss likelihood, adaptive (Lund thesis ch. 7) when the config asks for adaptation or blocking."""
    if not (config.adapt_path_loss or config.blocking_compensation):
        return TrilaterationLikelihood(ap_table, variance_db2=config.rssi_variance_db2)
    return AdaptiveTrilaterationLikelihood(
        ap_table, variance_db2=config.rssi_variance_db2,
        adaptation=config.adaptation if config.adapt_path_loss else None,
        blocking=config.blocking if config.blocking_compensation else None)


def calibrated_fix_sigma_m(radio_map: RadioMap, k: int = 4, default_m: float = 5.0) -> float:
    """Fix sigma from the radio map's cross-validated KWNN errors: RMS / sqrt(2), in [1, 50] m.

    ``default_m`` (Evennou & Marx's 5 m) when the map is too small to cross-validate.
    """
    errors = cross_validated_fix_errors(radio_map, k=k)
    if errors.size < 10:
        return default_m
    return float(np.clip(np.sqrt(np.mean(errors**2) / 2.0), 1.0, 50.0))


def track_recording(
    floorplan: FloorPlan,
    recording: Recording,
    radio_map: RadioMap | None = None,
    ap_table: AccessPointTable | None = None,
    config: TrackingConfig = TrackingConfig(),
    rng: np.random.Generator | None = None,
    on_step: Callable[[StepReport], None] | None = None,
    steps: Steps | None = None,
    wifi: WifiMeasurements | None = None,
    floors: Any = None,
    on_restart_step: Callable[[StepReport], None] | None = None,
) -> TrackingResult:
    """Track one walk with the particle filter.

    Parameters
    ----------
    floorplan : the map (walls kill particles unless ``config.use_map`` is False).
    recording : the walk (WiFi scans; IMU for PDR).
    radio_map / ap_table : fingerprinting or trilateration (exactly one).
    config : ``TrackingConfig``.
    rng : the only source of randomness; same seed, same track.
    on_step : called with every ``StepReport`` (the rerun viewer, progress).
    on_restart_step : called with every ``StepReport`` of the offline track's second filter run
        (``TrackingConfig.restart_from_placement``; progress: that run takes as long as the first).
    steps : PDR steps if already detected (else detected here when the motion is PDR).
    wifi : the walk's ``WifiMeasurements`` if already made with this radio map or AP table and
        config (several filters on one walk share them), else made here.
    floors : a building's ``filter.floors.FloorChanges`` (``floortracking.track_building``):
        ``floorplan`` is its stack plan and ``wifi`` weighs floors; the offline track is then
        the lineage of the final best particle.
    """
    started = time.perf_counter()
    rng = rng if rng is not None else np.random.default_rng(0)
    log_name = str(recording.path) if recording.path is not None else "the log"
    scans = scans_of(recording)
    if wifi is None:
        wifi = WifiMeasurements(scans, radio_map, ap_table, floorplan, config, log_name)
    plan = floorplan if config.use_map else FloorPlan(np.zeros_like(floorplan.wall_mask), floorplan.resolution_m,
                                                       floorplan.origin_m, floorplan.floor_name)
    if config.motion == "pdr":
        motion: Any = config.pdr_motion
        if steps is None:
            steps = detect_steps(recording, config.pdr)
    else:
        motion = ConstantVelocityMotion() if config.motion == "cv" else RandomWalkMotion()
    whole_walk = config.smooth and config.motion == "pdr" and len(steps) > 0 and floors is None
    # without steps to place, the offline track is the lineage of the final best particle
    filter_config = dataclasses.replace(config.filter, n_particles=config.n_particles,
                                        keep_ancestry=(config.smooth and not whole_walk) or config.filter.keep_ancestry)
    pf, track, n_scans = _filter_walk(plan, motion, filter_config, rng, wifi, scans, steps, config, floors, on_step)
    smoothed = restarted = None
    if whole_walk:
        scan_t = np.array([scan.t_s for scan in wifi.scans])
        placement = place_walk(steps, *placement_evidence(wifi, track.t_s, track.xy_m))
        smoothed = whole_walk_track(plan, placement, scan_t)
        if config.restart_from_placement:
            restarted, smoothed = restarted_whole_walk(plan, wifi, steps, config, rng, smoothed, on_restart_step)
    if config.smooth and smoothed is None:
        t_s, xy_m = detour_wall_crossings(plan, *pf.smoothed_track())
        smoothed = Track(t_s, xy_m, name="pf-smooth")
    return TrackingResult(track, smoothed, list(pf.collapses), len(track.t_s) - 1, n_scans,
                          time.perf_counter() - started, getattr(wifi.model, "ap_table", None) if ap_table else None,
                          restarted)


# the restarted filter's particles start uniformly within this radius of the placed start: the
# whole-walk track's error at a walk's start is a few metres (3, 5 and 10 m measured alike on ILC)
RESTART_RADIUS_M = 5.0


def restarted_whole_walk(plan: FloorPlan, wifi: WifiMeasurements, steps: Steps, config: TrackingConfig,
                         rng: np.random.Generator, placed: Track,
                         on_step: Callable[[StepReport], None] | None = None) -> tuple[Track, Track]:
    """The whole-walk track again, its causal evidence from a second PDR filter run started where
    the first whole-walk track ``placed`` has the walker at the first usable scan (within
    ``RESTART_RADIUS_M``): (that run's causal track, named "restarted"; the new whole-walk track).

    The first run started at the walk's first fix; once the whole walk has placed the start, it
    is known better. A first fix tens of metres off can leave the map-bound cloud in the wrong
    corridor for the rest of the walk, and its estimates then pull the placement with it.
    """
    scans = wifi.scans
    t0 = float(scans[int(np.argmax(wifi.usable))].t_s)
    start_xy = placed.xy_m[int(np.clip(np.searchsorted(placed.t_s, t0), 0, placed.t_s.size - 1))]
    filter_config = dataclasses.replace(config.filter, n_particles=config.n_particles)
    _, restarted, _ = _filter_walk(plan, config.pdr_motion, filter_config, rng, wifi, scans, steps, config, None,
                                   on_step, start_xy_m=start_xy)
    restarted.name = "restarted"
    placement = place_walk(steps, *placement_evidence(wifi, restarted.t_s, restarted.xy_m))
    return restarted, whole_walk_track(plan, placement, np.array([scan.t_s for scan in scans]))


def _filter_walk(plan: FloorPlan, motion: Any, filter_config: FilterConfig, rng: np.random.Generator,
                 wifi: Any, scans: list[WifiScan], steps: Steps | None, config: TrackingConfig, floors: Any,
                 on_step: Callable[[StepReport], None] | None,
                 start_xy_m: np.ndarray | None = None) -> tuple[ParticleFilter, Track, int]:
    """One causal filter run over the walk: (the filter at the end, its track, scans used).

    Starts at the first usable scan: from that scan's likelihood over the map, or, given
    ``start_xy_m``, uniformly within ``RESTART_RADIUS_M`` of it (the restart from the whole-walk
    placement, ``TrackingConfig.restart_from_placement``).
    """
    pf = ParticleFilter(plan, motion, filter_config, rng, floors=floors)
    first = int(np.argmax(wifi.usable))
    t0 = float(scans[first].t_s)
    if start_xy_m is None:
        pf.initialise_from_measurement(t0, wifi.model, wifi.measurement(first))
    else:
        pf.initialise_around(start_xy_m, RESTART_RADIUS_M)
    if config.motion == "pdr":
        _set_start_headings(pf, steps, t0, config, rng)
        step_input = step_inputs(steps, use_abs_heading=config.heading_source == "rotation_vector",
                                 with_step_length=config.step_length_source == "weinberg")

    start_heading = circular_mean(pf.particles.heading_rad, pf.particles.weight) if config.motion == "pdr" else math.nan
    out_t, out_xy, out_std, out_heading = [t0], [pf.estimate_xy_m.copy()], [pf.estimate_std_m], [start_heading]
    last_t = t0
    n_scans = 1
    pdr = config.motion == "pdr"
    for kind, t_s, index in _events(scans, first, steps if pdr else None,
                                    config.idle_tick_s if pdr else config.tick_s):
        dt = max(t_s - last_t, 0.0)
        if kind == "idle":
            # PDR standing still (a lift ride): only the barometer has news; on one floor, nothing
            between = wifi.between_scans(t_s)
            if between is None:
                continue
            report = pf.step(t_s, dt, None, wifi.model, between)
        elif kind == "scan":
            measurement = wifi.measurement(index)
            if measurement is None:
                continue
            n_scans += 1
            # cv / rw move over dt_s by themselves; PDR moves only on steps
            report = pf.step(t_s, dt, None, wifi.model, measurement)
        elif kind == "step":
            # in a building with a barometer, the height weighs floors at every step, not only at scans
            between = wifi.between_scans(t_s)
            report = pf.step(t_s, dt, step_input[index], wifi.model if between is not None else None, between)
        else:  # prediction tick for cv / rw
            report = pf.step(t_s, dt, None)
        last_t = t_s
        out_t.append(t_s)
        out_xy.append(report.estimate_xy_m)
        out_std.append(report.estimate_std_m)
        out_heading.append(report.heading_rad if report.heading_rad is not None else math.nan)
        if on_step is not None:
            on_step(report)

    heading = np.array(out_heading)
    track = Track(np.array(out_t), np.array(out_xy), np.array(out_std),
                  heading if np.isfinite(heading).any() else None, name="pf")
    return pf, track, n_scans


def placement_evidence(wifi: WifiMeasurements, causal_t_s: np.ndarray, causal_xy_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where the walk was at each scan, by every estimator at hand: (times (E,), positions (E, 2)).

    Three estimators with different failure modes, each once per scan: the scan's own position
    fix (KWNN, or trilateration), with a radio map also the radio-map likelihood's best cell
    (a per-AP model of mean, spread and P(heard) errs differently from nearest neighbours where
    the survey is thin), and the causal filter's estimate at the scan (map-aware). On ILC
    site 1 (sparse and dense F1, F2) placing the walk by all three measured better than by
    any one or two of them.
    """
    scan_t = np.array([s.t_s for s in wifi.scans])
    fixes = wifi.position_fixes()
    parts_t, parts_xy = [scan_t] * len(fixes), list(fixes)
    latest = np.searchsorted(causal_t_s, scan_t, side="right") - 1
    have = latest >= 0
    parts_t.append(scan_t[have])
    parts_xy.append(causal_xy_m[latest[have]])
    return np.concatenate(parts_t), np.concatenate(parts_xy)


def whole_walk_track(floorplan: FloorPlan, placement: WalkPlacement, scan_t_s: np.ndarray) -> Track:
    """The offline track: the walk's placed dead-reckoned shape, map-matched and wall-free.

    ``placement`` (``filter.placement.place_walk``) puts the shape where every estimate of the
    walk says, robustly; within half a typical fix error of there, the shape moves to where
    most of it lies in free space (``filter.placement.shift_onto_free_space``). A forward-backward
    pass over the plan's free cells (``filter.map_matching.map_match``), observing the placed
    shape at the scan times ``scan_t_s``, then lets the walk bend where the walls say it must
    (the rigid shape drifts). Points still in walls move to the nearest free pixel and moves
    that still cross a wall walk round it by the shortest free path (``maps.paths.wall_free_track``).
    (A second particle filter following the placed shape did the same job with more error:
    ILC F2 18.9 m mean / 31.7 m p75 against 18.5 / 29.0, and cost a filter run.)
    """
    placement = shift_onto_free_space(floorplan, placement)
    matched = map_match(floorplan, placement.t_s, placement.xy_m, scan_t_s)
    t_s, xy_m = wall_free_track(floorplan, matched.t_s, matched.xy_m)
    return Track(t_s, xy_m, name="pf-smooth")


def step_inputs(steps: Steps, use_abs_heading: bool = False, with_step_length: bool = False) -> list[StepInput]:
    """One ``StepInput`` per detected step: the filter moves its particles once per step.

    ``use_abs_heading`` gives each step the rotation vector's map heading (when the log has
    one) instead of only the gyro's change; ``with_step_length`` gives the Weinberg length,
    else the particles walk their own adapted length (thesis eq. 8.23).
    """
    absolute = steps.abs_heading_rad if use_abs_heading else None
    return [StepInput(1, float(steps.heading_change_rad[i]), None if absolute is None else float(absolute[i]),
                      float(steps.step_length_m[i]) if with_step_length else None)
            for i in range(len(steps))]


def _events(scans: list[WifiScan], first: int, steps: Steps | None, tick_s: float):
    """(kind, t_s, index) after the first measurement, in time order; a scan after a step at equal times.

    Without steps (cv / rw): a "tick" every ``tick_s``. With steps (PDR): an "idle" event
    wherever ``tick_s`` (``TrackingConfig.idle_tick_s``) passed without a step or scan
    (standing, riding a lift), for evidence that needs no motion (the barometer)."""
    t0 = scans[first].t_s
    events = [(s.t_s, 1, "scan", i) for i, s in enumerate(scans) if i > first]
    if steps is not None:
        events += [(t, 0, "step", i) for i, t in enumerate(steps.t_s) if t > t0]
        times = np.array(sorted([t0] + [e[0] for e in events]))
        for a, b in zip(times[:-1], times[1:]):
            events += [(t, 0, "idle", -1) for t in np.arange(a + tick_s, b - 1e-9, tick_s)]
    else:
        t_end = scans[-1].t_s
        events += [(t, 0, "tick", -1) for t in np.arange(t0 + tick_s, t_end, tick_s)]
    events.sort(key=lambda e: (e[0], e[1]))
    return [(kind, float(t), i) for t, _, kind, i in events]


def _set_start_headings(pf: ParticleFilter, steps: Steps, t0_s: float, config: TrackingConfig,
                        rng: np.random.Generator) -> None:
    """PDR particles start with the rotation vector's heading (plus spread), else uniform.

    The gyro heading is relative; the rotation vector (magnetometer) gives the map heading,
    biased by the building's steel: the heading of the last step at or before the start
    (the first step if the walk starts standing).
    """
    n = pf.n
    if config.use_abs_heading and steps.abs_heading_rad is not None and len(steps):
        upto = max(1, int(np.searchsorted(steps.t_s, t0_s, side="right")))
        heading = float(steps.abs_heading_rad[upto - 1])
        pf.particles.heading_rad = heading + config.initial_heading_sigma_rad * rng.standard_normal(n)
    else:
        pf.particles.heading_rad = rng.uniform(-math.pi, math.pi, n)

