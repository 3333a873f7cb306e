"""One causal pass of the particle filter over a walk: events in time order, one filter step each.

Events: every detected step moves the particles (PDR motion, one filter step per step, so the
wall check sees each short move) or, for the ``cv``/``rw`` motion models, a prediction tick every
``tick_s``; every WiFi scan weighs them; with a barometer in a building, an idle tick every
``idle_tick_s`` without a step or scan lets the height weigh floors (a lift ride has no steps).
The filter starts at the first scan that gives a usable measurement, drawn over the map's free
space from that scan's likelihood (the starting position is unknown), or around a given point.

Time and memory follow the walk's data, never its timestamps: where nothing happened for longer
than ``max_gap_s`` (a phone asleep, a row stamped years ahead), nothing is made for the gap;
the filter starts afresh at the next usable scan (``FilterRun.gaps``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.filter.estimate import circular_mean
from mapfilter.filter.events import CollapseEvent, StepReport
from mapfilter.filter.evidence import WalkEvidence
from mapfilter.filter.models.interface import FloorModel, MotionModel
from mapfilter.filter.models.motion import ConstantVelocityMotion, PDRMotion, RandomWalkMotion, StepInput
from mapfilter.filter.particle_filter import FilterConfig, ParticleFilter
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.sensors.pdr import Steps
from mapfilter.trackio import Track

MOTION_MODELS = ("pdr", "cv", "rw")


@dataclasses.dataclass(frozen=True)
class MotionConfig:
    """How the particles move between measurements."""

    model: str = "pdr"  # pdr: steps and gyro (PDR) | cv: constant velocity | rw: random walk on a circle
    # heading noise per step 0.02 rad: the gyro is good over a step; 0.05 (the PDRMotion default,
    # for coarser filter steps) let clouds fan out and measured worse on ILC F1
    pdr: PDRMotion = dataclasses.field(default_factory=lambda: PDRMotion(heading_sigma_rad=0.02))  # the PDR motion model (thesis eq. 8.23)
    constant_velocity: ConstantVelocityMotion = dataclasses.field(default_factory=ConstantVelocityMotion)  # the cv model (Evennou & Marx)
    random_walk: RandomWalkMotion = dataclasses.field(default_factory=RandomWalkMotion)  # the rw model (Lund thesis eq. 6.6)
    tick_s: float = 1.0  # cv / rw: prediction interval between scans
    # a lift ride has no steps, and scans are 2-4 s apart: about a walker's step interval, so
    # the height weighs floors as often standing as walking
    idle_tick_s: float = 0.5  # PDR with a barometer in a building: the longest gap between filter steps
    start_heading_from_rotation_vector: bool = True  # PDR: start headings from the rotation vector when the log has one
    # the rotation vector's heading deviates from the ILC waypoint legs by 8.8 deg median
    # (tools/report_pdr.py); 0.2 rad measured better and steadier across seeds than 30 deg on
    # ILC F1 (tools/tune_ilc.py: mean ratio to KWNN 0.775 vs 0.785-0.850)
    initial_heading_sigma_rad: float = 0.2  # PDR: spread of the start headings around the rotation vector's
    max_gap_s: float = 60.0  # nothing happened for longer than this: the filter starts afresh at the next scan

    def __post_init__(self) -> None:
        if self.model not in MOTION_MODELS:
            raise MapfilterError(f"unknown motion model {self.model!r}: choose one of {', '.join(MOTION_MODELS)}")
        for name in ("tick_s", "idle_tick_s", "max_gap_s"):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise MapfilterError(f"motion setting {name} must be a positive number of seconds, got {value}")
        if not (self.initial_heading_sigma_rad >= 0 and math.isfinite(self.initial_heading_sigma_rad)):
            raise MapfilterError(f"initial_heading_sigma_rad must be >= 0, got {self.initial_heading_sigma_rad}")

    @property
    def motion_model(self) -> MotionModel:
        """The motion model ``model`` names."""
        return {"pdr": self.pdr, "cv": self.constant_velocity, "rw": self.random_walk}[self.model]


@dataclasses.dataclass(frozen=True)
class FilterRun:
    """One causal pass: the estimate after every filter step, and what happened."""

    track: Track  # t_s, xy_m, std_m (and heading_rad with PDR) in the filter's plan frame
    collapses: tuple[CollapseEvent, ...]
    n_scans_used: int
    lineage: Track | None  # the final best particle's lineage (with keep_ancestry)
    gaps: tuple[tuple[float, float], ...] = ()  # (from, to) s: gaps over max_gap_s where the filter started afresh
    # a building: (T, F) the share of the weight on each floor after every step (the track's
    # rows); the track's ``floor_p`` is the share of its estimate's floor. None on one floor
    floor_shares: np.ndarray | None = None

    @property
    def n_filter_steps(self) -> int:
        return len(self.track.t_s) - 1


def run_filter(plan: FloorPlan, motion: MotionConfig, filter_config: FilterConfig, rng: np.random.Generator,
               evidence: WalkEvidence, steps: Steps | None, floors: FloorModel | None = None,
               on_step: Callable[[StepReport], None] | None = None, start_xy_m: np.ndarray | None = None,
               start_radius_m: float = 5.0, keep_ancestry: bool = False) -> FilterRun:
    """The filter over the whole walk, causally.

    Starts at the first usable scan: from that scan's likelihood over the map, or, given
    ``start_xy_m``, uniformly within ``start_radius_m`` of it. ``steps`` are the PDR steps
    (needed for ``motion.model == "pdr"``). ``on_step`` sees every ``StepReport``; the evidence
    observes each too (the barometer's reference).
    """
    pdr = motion.model == "pdr"
    if pdr and steps is None:
        raise ValueError("PDR motion needs the walk's steps")
    pf = ParticleFilter(plan, motion.motion_model, filter_config, rng, floors=floors, keep_ancestry=keep_ancestry)
    scans = evidence.scans
    first = int(np.argmax(evidence.usable))
    _start(pf, evidence, first, steps, motion, rng, start_xy_m, start_radius_m)
    step_input = step_inputs(steps) if pdr else []
    rows = _Rows()
    rows.add_start(float(scans[first].t_s), pf, pdr)
    n_scans, gaps = 1, []
    idle_tick_s = motion.idle_tick_s if evidence.has_evidence_between_scans() else None
    events = _events(scans, first, steps if pdr else None, motion.tick_s, idle_tick_s, motion.max_gap_s)
    n_event, previous_t = 0, rows.t_s[0]  # the time of the previous event, used or not
    while n_event < len(events):
        kind, t_s, index = events[n_event]
        n_event += 1
        if t_s - previous_t > motion.max_gap_s:
            # start afresh at the next usable scan: the gap's length says nothing about where
            gaps.append((rows.t_s[-1], t_s))
            restart = next((k for k in range(n_event - 1, len(events))
                            if events[k][0] == "scan" and evidence.usable[events[k][2]]), None)
            if restart is None:
                break
            _, previous_t, index = events[restart]
            n_event = restart + 1
            _start(pf, evidence, index, steps, motion, rng, None, start_radius_m)
            rows.add_start(previous_t, pf, pdr)
            n_scans += 1
            continue
        previous_t = t_s
        report = _filter_step(pf, evidence, kind, t_s, index, t_s - rows.t_s[-1], step_input)
        if report is None:
            continue
        n_scans += kind == "scan"
        rows.add(report)
        evidence.observe(report)
        if on_step is not None:
            on_step(report)
    lineage = None
    if pf.ancestry is not None:
        lineage_t, lineage_xy = pf.lineage_track()
        lineage = Track(lineage_t, lineage_xy, name="lineage")
    shares = rows.floor_shares()
    return FilterRun(rows.track(shares), tuple(pf.collapses), n_scans, lineage, tuple(gaps), shares)


def _filter_step(pf: ParticleFilter, evidence: WalkEvidence, kind: str, t_s: float, index: int, dt_s: float,
                 step_input: list[StepInput]) -> StepReport | None:
    """One event's filter step (None: the event has nothing to weigh or move)."""
    dt = max(dt_s, 0.0)
    if kind == "idle":
        # PDR standing still (a lift ride): only the barometer has news
        between = evidence.between_scans(t_s)
        return None if between is None else pf.step(t_s, dt, None, evidence.model, between)
    if kind == "scan":
        measurement = evidence.measurement(index)
        # cv / rw move over dt_s by themselves; PDR moves only on steps
        return None if measurement is None else pf.step(t_s, dt, None, evidence.model, measurement)
    if kind == "step":
        # in a building with a barometer, the height weighs floors at every step, not only at scans
        between = evidence.between_scans(t_s)
        return pf.step(t_s, dt, step_input[index], evidence.model if between is not None else None, between)
    return pf.step(t_s, dt, None)  # prediction tick for cv / rw


class _Rows:
    """The causal track, a row per filter step."""

    def __init__(self) -> None:
        self.t_s: list[float] = []
        self.xy_m: list[np.ndarray] = []
        self.std_m: list[float] = []
        self.heading_rad: list[float] = []
        # a building: (weight share per floor, the estimate's floor) per row; None on one floor
        self.floors: list[tuple[np.ndarray, int] | None] = []

    def add_start(self, t_s: float, pf: ParticleFilter, pdr: bool) -> None:
        """The freshly started cloud's estimate."""
        self.t_s.append(t_s)
        self.xy_m.append(pf.estimate_xy_m.copy())
        self.std_m.append(pf.estimate_std_m)
        self.heading_rad.append(circular_mean(pf.particles.heading_rad, pf.particles.weight) if pdr else math.nan)
        self.floors.append(_floor_belief(pf))

    def add(self, report: StepReport) -> None:
        self.t_s.append(report.t_s)
        self.xy_m.append(report.estimate_xy_m)
        self.std_m.append(report.estimate_std_m)
        self.heading_rad.append(report.heading_rad if report.heading_rad is not None else math.nan)
        self.floors.append(None if report.floor_shares is None else (report.floor_shares, report.floor_index))

    def floor_shares(self) -> np.ndarray | None:
        """(T, F) the weight share of each floor per row, or None (one floor)."""
        if not self.floors or any(f is None for f in self.floors):
            return None
        return np.array([f[0] for f in self.floors], dtype=np.float64)

    def track(self, shares: np.ndarray | None) -> Track:
        """The rows as a track; ``shares``: ``floor_shares()``, for the ``floor_p`` column."""
        heading = np.array(self.heading_rad)
        floor_p = None
        if shares is not None:
            # a probability (the shares of normalised weights may sum to 1 + 1e-16)
            floor_p = np.clip(shares[np.arange(len(self.floors)), [f[1] for f in self.floors]], 0.0, 1.0)
        return Track(np.array(self.t_s), np.array(self.xy_m), np.array(self.std_m),
                     heading if np.isfinite(heading).any() else None, name="pf", floor_p=floor_p)


def _floor_belief(pf: ParticleFilter) -> tuple[np.ndarray, int] | None:
    """(the weight share of each floor, the estimate's floor) of the filter as it stands, or None
    on one floor (``FloorModel.report`` tells nothing there); no random draw."""
    report = pf.floors.report(pf.particles.xy_m, pf.particles.weight, pf.estimate_xy_m)
    if report.get("floor_shares") is None:
        return None
    return np.asarray(report["floor_shares"], dtype=np.float64), int(report["floor_index"])


def _start(pf: ParticleFilter, evidence: WalkEvidence, index: int, steps: Steps | None, motion: MotionConfig,
           rng: np.random.Generator, start_xy_m: np.ndarray | None, start_radius_m: float) -> None:
    """Particles at scan ``index``: from its likelihood over the map, or around ``start_xy_m``."""
    t_s = float(evidence.scans[index].t_s)
    if start_xy_m is None:
        pf.initialise_from_measurement(t_s, evidence.model, evidence.measurement(index))
    else:
        pf.initialise_around(start_xy_m, start_radius_m)
    if motion.model == "pdr":
        _set_start_headings(pf, steps, t_s, motion, rng)


def step_inputs(steps: Steps) -> list[StepInput]:
    """One ``StepInput`` per detected step: the gyro's heading change; the particles walk their
    own adapted step length (thesis eq. 8.23)."""
    return [StepInput(1, float(steps.heading_change_rad[i])) for i in range(len(steps))]


def _events(scans, first: int, steps: Steps | None, tick_s: float, idle_tick_s: float | None,
            max_gap_s: float) -> list[tuple[str, float, int]]:
    """(kind, t_s, index) after the first measurement, in time order; a scan after a step at equal times.

    Without steps (cv / rw): a "tick" every ``tick_s``. With steps (PDR) and ``idle_tick_s``: an
    "idle" event wherever ``idle_tick_s`` passed without a step or scan (standing, riding a
    lift), for evidence that needs no motion (the barometer). No tick is made in a gap over
    ``max_gap_s``: the run starts afresh after it.
    """
    t0 = scans[first].t_s
    events = [(s.t_s, 1, "scan", i) for i, s in enumerate(scans) if i > first]
    if steps is not None:
        events += [(t, 0, "step", i) for i, t in enumerate(steps.t_s) if t > t0]
        if idle_tick_s is not None:
            times = np.array(sorted([t0] + [e[0] for e in events]))
            for a, b in zip(times[:-1], times[1:]):
                if b - a <= max_gap_s:
                    events += [(t, 0, "idle", -1) for t in np.arange(a + idle_tick_s, b - 1e-9, idle_tick_s)]
    else:
        scan_t = np.array([t0] + [s.t_s for s in scans[first + 1:]])
        for a, b in zip(scan_t[:-1], scan_t[1:]):
            if b - a <= max_gap_s:
                events += [(t, 0, "tick", -1) for t in _ticks(t0, scan_t[-1], a, b, tick_s)]
    events.sort(key=lambda e: (e[0], e[1]))
    return [(kind, float(t), i) for t, _, kind, i in events]


def _ticks(t0: float, t_end: float, a: float, b: float, tick_s: float) -> np.ndarray:
    """The prediction ticks of ``np.arange(t0 + tick_s, t_end, tick_s)`` that fall in (a, b]: the
    same numbers (numpy's arange makes element i as start + i * ((start + step) - start)),
    without making the ones outside."""
    start = t0 + tick_s
    delta = (start + tick_s) - start
    count = max(0, math.ceil((t_end - start) / tick_s))
    lo = max(0, math.floor((a - start) / delta) - 1)
    hi = min(count, math.ceil((b - start) / delta) + 2)
    ticks = start + np.arange(lo, max(hi, lo)) * delta
    return ticks[(ticks > a) & (ticks <= b)]


def _set_start_headings(pf: ParticleFilter, steps: Steps, t0_s: float, motion: MotionConfig,
                        rng: np.random.Generator) -> None:
    """PDR particles start with the rotation vector's heading (plus spread), else uniform.

    The gyro heading is relative; the rotation vector (magnetometer) gives the map heading,
    biased by the building's steel: the heading of the last step at or before the start
    (the first step if the walk starts standing).
    """
    n = pf.n
    if motion.start_heading_from_rotation_vector and steps.abs_heading_rad is not None and len(steps):
        upto = max(1, int(np.searchsorted(steps.t_s, t0_s, side="right")))
        heading = float(steps.abs_heading_rad[upto - 1])
        pf.particles.heading_rad = heading + motion.initial_heading_sigma_rad * rng.standard_normal(n)
    else:
        pf.particles.heading_rad = rng.uniform(-math.pi, math.pi, n)
