"""Every method on the same walks in one run: the engine behind ``mapfilter evaluate``.

Methods (same inputs, same output: a track; errors at the ground-truth waypoint times,
causal: each method's latest estimate at or before the waypoint). On one floor:

=============  ==========================================================================
``pf``         particle filter: map + WiFi + PDR (the project's method)
``pf-nomap``   the same with the walls ignored (what the map buys)
``pf-nopdr``   the same with a constant-velocity motion model instead of PDR
``kwnn``       K-weighted nearest-neighbour fixes (Chang et al.), one per scan
``pdr-kwnn``   KWNN with the PDR-predicted position and heading in the distance (Chang et al.)
``kf``         Kalman filter on the KWNN fixes with PDR steps as input (Evennou & Marx; Seitz)
``pdr``        dead reckoning from the first fix
``ls``         least-squares trilateration per scan (needs an access-point table)
``pdr-start``  dead reckoning from the walk's true start (its first waypoint: ground truth no
               other method sees): what the steps alone give, to show what WiFi adds or costs
=============  ==========================================================================

With a ``start`` (``pipeline.tracker.WalkStart``: where every walk started, as a user who knows
the entrance says it), the particle filter methods start there at each walk's first step; with
``TRUE_START`` each walk starts at its own first waypoint (as a competition gives a trial's
initial position, and as a user who knows where each walk began would).

With a measurement source's input (``sources``: ``{name: input}``, ``filter.sources``), also
``pf+NAME`` (``pf`` with the source's measurements weighed too; with ``smooth``, its offline
track ``pf-smooth+NAME``), ``pf-NAME`` (the filter on the source alone, no WiFi) and in a
building ``pf-floor+NAME`` (``pf-floor`` with the source). With survey logs or
``leave_one_out``, a source may fit its input again on the labelled walks, never on the walk
itself (``SourcePlugin.survey``, ``for_walk``);
with a radio map file, the inputs as given.

In a building with several floors: ``pf`` (the floor in the filter's state, not given),
``pf-floor`` (the same filter on the walker's floor, given: what finding the floor costs; a
walk that changes floor has no one floor to give), ``kwnn`` (each scan on the causal WiFi floor
HMM's floor, fixed from that floor's fingerprints), and ``kf`` and ``pdr`` on those same KWNN
fixes and floors (the Kalman filter and the dead reckoning run in one floor's frame, each row on
the floor of the latest scan); each also scored by its floor accuracy at the waypoints and the
IPIN score (the 75th percentile of the horizontal error plus 15 m per storey off).

With ``smooth`` in the tracking config, ``pf``'s offline track is reported as ``pf-smooth``
(not causal). The radio map of the walks comes from a radio map file, from survey logs
(``survey_paths``), or, with ``leave_one_out``, from the other evaluated walks (and any survey
logs): each walk's fold drops its own points, as the ILC evaluation needs. With ``groups``
(``evaluation.groups``: every repetition of an IPIN trial, or a user's grouping) each walk's fold
drops every walk of its group, and so does everything fitted from the survey for that walk: the
access-point table, the sources' fits, the fix calibration, the points the growing places.

Self-training (``selftrain``, docs/self-training.md): walks without labels grow that radio map.
``unlabelled_paths`` grow it and are never scored (with ``leave_one_out``, grown once per fold of
the labelled walks, so no scored walk's labels place the points it is scored with:
``selftrain.grown_by_fold``; with ``groups``, a group's walks share a fold); ``transductive``: the
evaluated walks grow it too, their waypoints never read, and each walk is scored with the other
walks' grown points (a user who tracks a batch, grows the map and tracks it again); left out by
walk or group, each fold's evaluated walks grow that fold's points over the survey of the other
folds.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
import traceback
import warnings
from collections.abc import Callable, Collection, Mapping, Sequence
from typing import Any
from pathlib import Path

import numpy as np

from mapfilter.config import TrackingConfig
from mapfilter.runtime.dispatch import Engine, run_each
from mapfilter.errors import MapfilterError
from mapfilter.evaluation.baselines import kalman_track, pdr_kwnn_track, pdr_start_track, pdr_track
from mapfilter.evaluation.diagnostics import DIAGNOSTIC_COLUMNS, walk_diagnostics
from mapfilter.evaluation.groups import Grouping
from mapfilter.evaluation.metrics import (FloorScore, availability, floor_detection, ipin_errors_m, ipin_score,
                                         summarise_errors)
from mapfilter.evaluation.scoring import score_track
from mapfilter.filter.evidence import calibrated_fix_sigma_m
from mapfilter.filter.sources import evaluation_methods, plugin
from mapfilter.pipeline.selftrain import GrowConfig, grow_radio_map, grown_by_fold
from mapfilter.maps.building import Building
from mapfilter.sensors.floor_vote import (build_building_radio_map, check_building_radio_map, floor_hmm,
                                         floor_vote_log_likelihood)
from mapfilter.sensors.logread import LogReadWarning
from mapfilter.sensors.logs import localise, missing_log, read_log, read_log_header
from mapfilter.sensors.pathloss import (AccessPointTable, check_access_points_on_map, estimate_access_points,
                                       least_squares_position, match_scan)
from mapfilter.sensors.pdr import Steps, detect_steps
from mapfilter.sensors.radiomap import (GROWN, RadioMap, build_radio_map, check_radio_map_on_map, kwnn_fix_many,
                                       merge_radio_maps)
from mapfilter.sensors.recording import Recording, trace_name
from mapfilter.sensors.wifi import scans_of
from mapfilter.pipeline.tracker import TRUE_START, TrackResult, WalkStart, prepare_walk, track_prepared
from mapfilter.io.tracks import Track

# {method: (source name, what it runs: pf | pf-floor | alone)} of every registered source
SOURCE_METHODS = {**evaluation_methods(single_floor=True), **evaluation_methods(single_floor=False)}
# the index of a method here seeds its runs: a new method goes at the end, so that the others keep their numbers
ALL_METHODS = ("pf", "pf-nomap", "pf-nopdr", "kwnn", "pdr-kwnn", "kf", "pdr", "ls", *evaluation_methods(True),
               "pdr-start")
BUILDING_METHODS = ("pf", "pf-floor", "kwnn", "kf", "pdr", *evaluation_methods(False), "pdr-start")
STATUSES = ("ok", "failed", "crashed")


def methods_for(building: Building, sources: Collection[str] = ()) -> tuple[str, ...]:
    """The methods ``evaluate`` compares on this building (its floor count decides), with those
    of the measurement sources named in ``sources``."""
    methods = ALL_METHODS if building.is_single_floor else BUILDING_METHODS
    return tuple(m for m in methods if m not in SOURCE_METHODS or SOURCE_METHODS[m][0] in sources)


# A walk to evaluate: its log's path, or the log already read (the Python API takes both).
Walk = Path | Recording


def walk_start(start, recording, building):
    """The start a walk's particle filter methods are given: ``start`` (every walk's, or None), or
    with ``TRUE_START`` the walk's first waypoint (on its floor in a ``building`` with several)."""
    if not (isinstance(start, str) and start == TRUE_START):
        return start
    if not len(recording.waypoint_t_s):
        return None
    floor = str(recording.waypoint_floor[0]) if recording.waypoint_floor and not building.is_single_floor else None
    x, y = (float(v) for v in recording.waypoint_xy_m[0])
    return WalkStart((x, y), floor)


@dataclasses.dataclass(frozen=True)
class EvaluationSetup:
    """What every walk is evaluated with."""

    methods: tuple[str, ...] | None = None  # None: every method of ``methods_for`` the WiFi source allows
    radio_map_path: Path | None = None  # one radio map for all walks
    ap_table_path: Path | None = None  # one access-point table for all walks
    survey_paths: tuple[Walk, ...] = ()  # logs with waypoints that make the radio map (never scored)
    leave_one_out: bool = False  # the evaluated walks join the radio map; each walk's fold drops its own points
    fit_aps: bool = False  # with leave_one_out or a survey: fit an AP table even if no method asks for it
    strict: bool = False  # refuse a walk with a bad row in a record type it needs (default: skip the row, warn)
    tracking: TrackingConfig = dataclasses.field(default_factory=TrackingConfig)  # seed and smooth included
    unlabelled_paths: tuple[Walk, ...] = ()  # walks that grow the radio map (waypoints never read), never scored
    transductive: bool = False  # the evaluated walks grow the radio map too, without their own labels
    radio_map: RadioMap | None = None  # one radio map for all walks, already loaded (instead of radio_map_path)
    access_points: AccessPointTable | None = None  # one access-point table, already loaded (instead of ap_table_path)
    # {measurement source name: its input} (``filter.sources``), each adding its methods
    sources: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    # leave a group out (evaluation.groups): each walk's survey drops every walk of its group; the
    # evaluated walks survey each other, as with leave_one_out
    groups: Grouping | None = None
    # score every method of a walk at the same waypoints (those every method has an estimate for);
    # False: each at every waypoint from its own first estimate on
    common_waypoints: bool = True
    # where every walk started, if known (``pipeline.tracker.WalkStart``; ``TRUE_START``: each walk's
    # first waypoint): the pf methods start there
    start: Any = None

    @property
    def leaves_out(self) -> bool:
        """The evaluated walks survey each other, each walk's fold without its walk or group."""
        return self.leave_one_out or self.groups is not None

    def left_out_with(self, trace: str) -> list[str]:
        """The walks that leave the survey with walk ``trace``: its group's, or itself."""
        return self.groups.members(trace) if self.groups is not None else [trace]

    @property
    def protocol(self) -> str:
        """What the walks are scored against, for the tables."""
        if self.groups is not None:
            return self.groups.protocol
        if self.leave_one_out:
            return "leave-one-walk-out" + (" (with survey logs)" if self.survey_paths else "")
        if self.survey_paths:
            return "survey logs (never scored)"
        return "a given radio map" if self.has_radio_map else "a given access-point table"

    def radio_map_source(self, n_walks: int) -> str:
        """Where the walks' radio map (or access-point table) came from, in plain words for the
        summary line, e.g. "each walk's radio map built from the other 11 walks (leave-one-walk-out)"."""
        surveyed = len(self.survey_paths)
        survey = f"{surveyed} survey walk{'s' if surveyed != 1 else ''} (--survey, not scored)"
        if self.groups is not None:
            return (f"each walk's radio map built from the walks of the other {self.groups.unit}s"
                    + (f" and the {survey}" if surveyed else "") + f" ({self.groups.protocol})")
        if self.leave_one_out:
            others = n_walks - 1
            return (f"each walk's radio map built from the other {others} walk{'s' if others != 1 else ''}"
                    + (f" and the {survey}" if surveyed else "") + " (leave-one-walk-out)")
        if surveyed:
            return f"the radio map built from the {survey}"
        if self.radio_map_path is not None:
            return f"the radio map {self.radio_map_path}"
        if self.radio_map is not None:
            return "the radio map given"
        if self.ap_table_path is not None:
            return f"trilateration from the access-point table {self.ap_table_path}"
        return "trilateration from the access-point table given"

    @property
    def grows(self) -> bool:
        return bool(self.unlabelled_paths) or self.transductive

    @property
    def has_radio_map(self) -> bool:
        return self.radio_map is not None or self.radio_map_path is not None

    @property
    def has_access_points(self) -> bool:
        return self.access_points is not None or self.ap_table_path is not None

    def load_radio_map(self) -> RadioMap | None:
        """The one radio map of every walk (given or read from its file), or None."""
        if self.radio_map is not None:
            return self.radio_map
        return RadioMap.load(self.radio_map_path) if self.radio_map_path is not None else None

    def load_access_points(self) -> AccessPointTable | None:
        """The one access-point table of every walk (given or read from its file), or None."""
        if self.access_points is not None:
            return self.access_points
        return AccessPointTable.read_csv(self.ap_table_path) if self.ap_table_path is not None else None


@dataclasses.dataclass
class MethodResult:
    """One method on one walk."""

    method: str
    trace: str
    track: Track
    errors_m: np.ndarray
    missed: int
    wall_crossings: int
    collapses: int
    runtime_s: float
    causal: bool = True
    diagnostics: dict[str, float] = dataclasses.field(default_factory=dict)  # the walk's (same for every method)
    floor_score: FloorScore | None = None  # several floors: on the walker's floor at the waypoints
    phone: str | None = None  # the phone model the log names (GetSensorData headers)
    # scored at the waypoints common to every method of the walk: those of them it has no estimate for
    not_scored: int = 0
    detection_score: FloorScore | None = None  # scored at the common waypoints: the floors at all of them
    skipped: int = 0  # estimated waypoints left out: before another method's first estimate

    @property
    def floor_detection(self) -> float:
        """ISO/IEC 18305's floor detection probability over all the walk's waypoints."""
        score = self.detection_score or self.floor_score
        return floor_detection([score]) if score is not None else math.nan

    @property
    def n_waypoints(self) -> int:
        """The walk's waypoints (scored, missed, or left to the other methods' first estimates)."""
        return int(self.errors_m.size) + self.missed + self.skipped

    def from_waypoint(self, first: int) -> MethodResult:
        """This result scored only at the walk's waypoints ``first`` on (a method's scored
        waypoints are always the walk's last ones: a causal track has none before its first
        estimate, an offline track all); ``not_scored`` counts those of them it has no estimate for."""
        skip = max(first - self.missed, 0)
        not_scored = max(self.missed - first, 0) if self.errors_m.size else self.n_waypoints - first
        floor_score = self.floor_score
        if floor_score is not None and floor_score.storeys_off is not None and skip:
            storeys = floor_score.storeys_off[skip:]
            floor_score = FloorScore(int(np.count_nonzero(storeys == 0)), int(storeys.size), first, storeys)
        # the floor detection probability stays over all the walk's points, as ISO/IEC 18305 counts it
        return dataclasses.replace(self, errors_m=self.errors_m[skip:], floor_score=floor_score,
                                   not_scored=not_scored, detection_score=self.floor_score, skipped=self.skipped + skip)

    @property
    def ipin_errors_m(self) -> np.ndarray:
        """Each judged waypoint's error plus 15 m per storey off (``metrics.ipin_errors_m``)."""
        storeys = self.floor_score.storeys_off if self.floor_score is not None else None
        if storeys is None or storeys.shape != self.errors_m.shape:
            return self.errors_m
        return ipin_errors_m(self.errors_m, storeys)


@dataclasses.dataclass
class WalkOutcome:
    """Every method on one walk, or why the walk has no results."""

    index: int
    trace: str
    log_path: Path | None  # None: a walk given as a Recording that was read from no file
    status: str  # ok | failed (the input's fault) | crashed (a bug)
    reason: str = ""
    results: list[MethodResult] = dataclasses.field(default_factory=list)
    read_warnings: list[str] = dataclasses.field(default_factory=list)
    runtime_s: float = 0.0
    # the files made where the walk ran (``evaluate``'s ``walk_files``): name -> content
    files: dict[str, bytes] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass
class AllWalks:
    """The radio map (and fitted access points) built once from every survey walk: each
    evaluated walk's fold removes its own share (leave-one-out)."""

    radio_map: RadioMap
    ap_table: AccessPointTable | None  # APs fitted on every walk (None when no method needs them)
    fix_sigma_by_floor_m: dict[str, float] | None = None  # several floors: calibrated once per floor
    # {source name: what it takes from the labelled walks} (``SourcePlugin.survey``)
    source_surveys: dict[str, Any] = dataclasses.field(default_factory=dict)
    # several floors, left out by group: calibrated once per floor for each group, without its walks
    fix_sigma_by_group: dict[str, dict[str, float]] | None = None

    def without(self, left_out: Sequence[str], one_floor: bool) -> RadioMap:
        """The radio map less the walks ``left_out`` (a walk, or every walk of its group), made once
        per set of walks in this process: the walks of one group share it, and with it all that is
        made from it once per radio map (the survey's own matches, the fix calibration, the
        radio-map likelihood's tables, the distance grids). One floor: APs no point hears dropped."""
        key = (frozenset(left_out), one_floor)
        cached = self.__dict__.setdefault("_without", {})
        if key not in cached:
            made = self.radio_map.without_traces(list(left_out))
            cached.clear()  # the walks come group by group: the last fold only is kept
            cached[key] = _drop_unheard_aps(made) if one_floor else made
        return cached[key]

    def fix_sigma_for(self, setup: EvaluationSetup, trace: str) -> dict[str, float] | None:
        """The per-floor fix sigma walk ``trace`` is tracked with (None: calibrate on its own map)."""
        if self.fix_sigma_by_group is not None and setup.groups is not None:
            return self.fix_sigma_by_group[setup.groups.group(trace)]
        return self.fix_sigma_by_floor_m


@dataclasses.dataclass(frozen=True)
class Growth:
    """The points the walks without labels grew (``selftrain``), and which of them a walk is
    scored with."""

    grown: tuple[RadioMap, ...]  # one per fold of the labelled walks (one in all without leave-one-out)
    fold_of: dict[str, int]  # trace -> its fold's index into ``grown`` (absent: 0)
    transductive: bool  # the evaluated walks grew points too: a walk's own are left out

    def for_walk(self, trace: str) -> RadioMap:
        points = self.grown[self.fold_of.get(trace, 0)]
        return points.without_traces([trace]) if self.transductive else points

    def describe(self) -> str:
        points = [len(g) for g in self.grown]
        span = f"{min(points)}" if min(points) == max(points) else f"{min(points)}-{max(points)}"
        how = span if len(points) == 1 else f"{span} per fold of the labelled walks ({len(points)} folds)"
        walks = {t for g in self.grown for t in np.array(g.source_traces)[np.unique(g.trace)]} if points[0] else set()
        return f"{how} grown points from {len(walks)} walks" + (" (transductive)" if self.transductive else "")


@dataclasses.dataclass(frozen=True)
class _Context:
    """What every walk's task shares (sent to each worker once)."""

    building: Building
    setup: EvaluationSetup
    methods: tuple[str, ...]
    paths: tuple[Walk, ...]
    all_walks: AllWalks | None
    true_floors: tuple[int | None, ...]  # per evaluated walk: its floor by the header (None: per waypoint or none)
    growth: Growth | None = None
    walk_files: Callable[[WalkOutcome, Recording, Building], dict[str, bytes]] | None = None


def evaluate(building: Building, log_paths: Sequence[str | os.PathLike | Recording], setup: EvaluationSetup,
             engine: Engine = Engine(), progress: Callable[[int, int, str], None] | None = None,
             on_walk: Callable[[WalkOutcome], None] | None = None,
             resumed: Sequence[WalkOutcome] = (),
             grow_progress: Callable[[int, int, str], None] | None = None,
             walk_files: Callable[[WalkOutcome, Recording, Building], dict[str, bytes]] | None = None) -> Evaluation:
    """Evaluate every method on every walk, one walk per task on ``engine``. Each walk seeds its
    own generators (``default_rng([seed, walk, method])``), so the numbers do not depend on the
    engine. A walk that fails is reported (``WalkOutcome.status``) and the others go on;
    ``on_walk`` sees each walk as it finishes (to write its results at once). ``resumed``: the
    outcomes of walks already done (``evaluation.store``): those walks are not run again.
    ``grow_progress`` follows the growing of the radio map (self-training), which comes first.
    ``walk_files(outcome, recording, building)`` makes a walk's files (its tracks, its picture)
    in the walk's own task, so that they are made in parallel; ``on_walk`` finds them in
    ``outcome.files``. A walk is a log's path or a ``Recording`` already read (as are the setup's
    survey and unlabelled walks)."""
    paths, survey, methods = validate_setup(building, log_paths, setup)
    if setup.groups is not None:
        setup = dataclasses.replace(setup, groups=setup.groups.checked(walk_name(p) for p in survey + paths))
    started = time.perf_counter()
    read_warnings: list[str] = []
    true_floors = tuple(_true_floor(building, p) for p in paths)
    with _collect_read_warnings(read_warnings):
        # left out by walk or group: the evaluated walks survey each other; one that cannot (unreadable, no
        # WiFi scan, no waypoint) lends nothing and fails in its own task, named, as the README
        # promises, while the others go on
        lent = [(rec, floor) for rec, floor in ((_surveying_walk(p, setup, building), f)
                                                for p, f in zip(paths, true_floors)) if rec is not None] \
            if setup.leaves_out else []
        survey_recordings = [read_walk(p, building, setup.strict) for p in survey]
    # the evaluated walks join the survey material only when left out by walk or group (``lent``)
    recordings = [rec for rec, _ in lent]
    all_walks = _all_walks(building, setup, methods, survey_recordings + recordings,
                           [_true_floor(building, p) for p in survey] + [floor for _, floor in lent])
    growth = None
    if setup.grows:
        with _collect_read_warnings(read_warnings):
            growth = _growth(building, setup, paths, survey_recordings + recordings, all_walks, engine,
                             grow_progress)
    context = _Context(building, setup, methods, tuple(paths), all_walks, true_floors, growth, walk_files)
    done = {o.index for o in resumed}
    todo = [i for i in range(len(paths)) if i not in done]
    outcomes: list[WalkOutcome] = list(resumed)
    for _, outcome in run_each(_evaluate_walk, todo, engine, common=(context,), progress=progress,
                               label=lambda index: walk_name(paths[index])):
        outcomes.append(outcome)
        read_warnings.extend(w for w in outcome.read_warnings if w not in read_warnings)
        if on_walk is not None:
            on_walk(outcome)
    evaluation = Evaluation.from_outcomes(outcomes, len(paths), time.perf_counter() - started, read_warnings)
    evaluation.grown = growth.describe() if growth is not None else ""
    evaluation.protocol = setup.protocol
    evaluation.radio_map_source = setup.radio_map_source(len(paths))
    evaluation.grouping = setup.groups
    evaluation.common_waypoints = setup.common_waypoints
    return evaluation


def validate_setup(building: Building, log_paths: Sequence[str | os.PathLike | Recording],
                   setup: EvaluationSetup) -> tuple[list[Walk], list[Walk], tuple[str, ...]]:
    """Check an evaluation before it runs: (the walks, the survey logs, the methods), or a
    ``MapfilterError`` for a missing log, a repeated trace name, an unknown method or a WiFi
    source that does not fit."""
    paths = checked_log_paths(log_paths)
    survey = checked_log_paths(setup.survey_paths) if setup.survey_paths else []
    overlap = {walk_name(p) for p in paths} & {walk_name(p) for p in survey}
    if overlap:
        raise MapfilterError(f"walk {sorted(overlap)[0]} is both a survey log and an evaluated walk: a walk is "
                             f"never scored against its own points (use --leave-one-out to let the evaluated "
                             f"walks survey each other)")
    methods = _checked_methods(building, setup)
    if setup.radio_map is not None and setup.radio_map_path is not None:
        raise MapfilterError("give the radio map as a file or as a RadioMap, not both")
    if setup.access_points is not None and setup.ap_table_path is not None:
        raise MapfilterError("give the access-point table as a file or as a table, not both")
    sources = sum([setup.has_radio_map, setup.has_access_points and building.is_single_floor,
                   bool(survey) or setup.leaves_out])
    if sources == 0:
        raise MapfilterError("no WiFi source: give a radio map, an access-point table, survey logs or --leave-one-out")
    if setup.has_radio_map and (survey or setup.leaves_out):
        raise MapfilterError("give a radio map, or survey logs / a leave-out protocol, not both (those build their "
                             "own)")
    if not building.is_single_floor and setup.has_access_points:
        raise MapfilterError("a building is evaluated with a building's radio map, not an access-point table")
    if setup.leaves_out and len(paths) + len(survey) < 2:
        raise MapfilterError("leave-one-out needs at least two logs")
    if setup.groups is not None:
        grouping = setup.groups.checked(walk_name(p) for p in survey + paths)
        if len(grouping.groups()) < 2:
            raise MapfilterError(f"{grouping.protocol} needs at least two groups: the walks are all in "
                                 f"{grouping.unit} {grouping.groups()[0]}, so no walk has a survey")
    unlabelled = checked_log_paths(setup.unlabelled_paths) if setup.unlabelled_paths else []
    named = {walk_name(p) for p in paths + survey}
    both = sorted(named & {walk_name(p) for p in unlabelled})
    if both:
        raise MapfilterError(f"walk {both[0]} is both unlabelled and labelled or scored: give it once "
                             f"(--transductive lets the scored walks grow the map without their labels)")
    return paths, survey, methods


def evaluate_trace(building: Building, log_paths: Sequence[str | os.PathLike | Recording], index: int,
                   setup: EvaluationSetup,
                   all_walks: AllWalks | None = None) -> list[MethodResult]:
    """Every method of ``setup`` on walk ``log_paths[index]``, for scripts that drive the walks
    themselves; ``all_walks``: the survey material (leave-one-out drops this walk's points).
    A walk that cannot be evaluated raises its ``MapfilterError``."""
    paths = checked_log_paths(log_paths)
    methods = _checked_methods(building, setup)
    context = _Context(building, setup, methods, tuple(paths), all_walks,
                       tuple(_true_floor(building, p) if i == index else None for i, p in enumerate(paths)))
    outcome = _evaluate_walk(context, index)
    if outcome.status != "ok":
        raise MapfilterError(outcome.reason)
    return outcome.results


def _checked_methods(building: Building, setup: EvaluationSetup) -> tuple[str, ...]:
    for name in setup.sources:
        plugin(name)  # a source that is not registered is one line
    known = methods_for(building, setup.sources)
    if setup.methods is None:
        return known
    every = methods_for(building, {name for name, _ in SOURCE_METHODS.values()})
    for method in setup.methods:
        if method in SOURCE_METHODS and method in every and SOURCE_METHODS[method][0] not in setup.sources:
            entry = plugin(SOURCE_METHODS[method][0])
            raise MapfilterError(f"method {method} weighs {entry.title}: give "
                                 f"{' '.join(f'{o.flag} {o.metavar}' for o in entry.options)}")
    unknown = [m for m in setup.methods if m not in ALL_METHODS + BUILDING_METHODS]
    if unknown:
        raise MapfilterError(f"unknown method(s) {', '.join(unknown)}: choose from {', '.join(known)}")
    other = [m for m in setup.methods if m not in every]
    if other:
        what = "one floor" if building.is_single_floor else "a building with several floors"
        raise MapfilterError(f"method(s) {', '.join(other)} are not evaluated on {what}: choose from "
                             f"{', '.join(known)}")
    return tuple(setup.methods)


def _true_floor(building: Building, path: Walk) -> int | None:
    """The walk's floor by its header (a building refuses a floor it does not have); None when it
    names none, as a walk over several floors does (a GetSensorData log whose POSI rows name
    several floors: the scoring takes each waypoint's own floor, the radio map each scan's)."""
    if isinstance(path, Recording):
        return building.floor_of_log(path.floor_name, path.path)
    try:
        header = read_log_header(path).get("FloorName") or None
    except MapfilterError:
        return None  # left to the walk, which fails as any unreadable log does
    return building.floor_of_log(header, path)


def _surveying_walk(walk: Walk, setup: EvaluationSetup, building: Building) -> Recording | None:
    """An evaluated walk as survey material for the others (leave-one-out), or None when it has
    nothing to lend (it cannot be read, or has no WiFi scan or no waypoint)."""
    try:
        recording = read_walk(walk, building, setup.strict)
    except MapfilterError:
        return None
    return recording if len(recording.wifi) and recording.has_ground_truth else None


def _all_walks(building: Building, setup: EvaluationSetup, methods: tuple[str, ...], recordings: list[Recording],
               floors: list[int | None]) -> AllWalks | None:
    """The survey material built once: the radio map of every survey walk (and fitted APs, and
    what each measurement source takes from them)."""
    if not recordings:
        return None
    used = {SOURCE_METHODS[m][0] for m in methods if m in SOURCE_METHODS}
    surveys = {name: plugin(name).survey(given, building, recordings) for name, given in setup.sources.items()
               if name in used}
    if building.is_single_floor:
        radio_map = build_radio_map(recordings, building.floors[0].plan)
        fit = not setup.has_access_points and (setup.fit_aps or "ls" in methods)
        return AllWalks(radio_map, estimate_access_points(radio_map) if fit else None, source_surveys=surveys)
    for rec, floor in zip(recordings, floors):
        if floor is None and not rec.waypoint_floor:
            raise MapfilterError("the log's header names no floor (FloorName): its points cannot join a building's "
                                 "radio map", rec.path)
    # a walk over several floors: each scan on the floor of its waypoints (sensors.floor_vote)
    radio_map = build_building_radio_map(recordings, floors, building.floor_names)
    sigma = by_group = None
    if setup.tracking.wifi.fix_sigma_m is None and setup.groups is not None:
        # a group (a route's repetitions) is a large share of the map: each group's without it
        by_group = {group: _radio_map_sigmas(radio_map.without_traces(setup.groups.members(group_walk)), building,
                                             setup.tracking)
                    for group, group_walk in _one_walk_per_group(setup.groups).items()}
    elif setup.tracking.wifi.fix_sigma_m is None:
        # once per floor from the whole radio map: cross-validating every floor again for every
        # walk costs tens of seconds a walk; the walk under test lends only its share to one number
        sigma = _radio_map_sigmas(radio_map, building, setup.tracking)
    return AllWalks(radio_map, None, sigma, surveys, by_group)


def _one_walk_per_group(grouping: Grouping) -> dict[str, str]:
    """group -> its first walk."""
    first: dict[str, str] = {}
    for trace, group in grouping.group_of.items():
        first.setdefault(group, trace)
    return first


def _walk_sources(context: _Context, recording: Recording) -> dict[str, Any]:
    """{source name: the input the walk is tracked with} of the sources the methods use: each
    source's input for this walk from the survey walks less the walks it is left out with (its
    own, or its group's; ``SourcePlugin.for_walk``), or as given without survey walks."""
    used = {SOURCE_METHODS[m][0] for m in context.methods if m in SOURCE_METHODS}
    surveys = context.all_walks.source_surveys if context.all_walks is not None else {}
    left_out = context.setup.left_out_with(recording.name)
    return {name: plugin(name).for_walk(given, surveys[name], left_out) if name in surveys else given
            for name, given in context.setup.sources.items() if name in used}


def _evaluate_walk(context: _Context, index: int) -> WalkOutcome:
    """One task: every method on walk ``index``; never raises (a failure is the outcome's status),
    with the reader's warnings brought back (a worker's would otherwise end in the worker's log)."""
    walk = context.paths[index]
    log_path = walk.path if isinstance(walk, Recording) else walk
    outcome = WalkOutcome(index, walk_name(walk), log_path, "ok")
    started = time.perf_counter()
    try:
        with _collect_read_warnings(outcome.read_warnings):
            recording = read_walk(walk, context.building, context.setup.strict)
        if not recording.has_ground_truth:
            raise MapfilterError("the log has no waypoints to evaluate against", log_path)
        if context.building.is_single_floor:
            outcome.results = _one_floor_methods(context, index, recording)
        else:
            outcome.results = _building_methods(context, index, recording)
        if context.walk_files is not None and outcome.results:
            outcome.files = context.walk_files(outcome, recording, context.building)
    except MapfilterError as exc:
        outcome.status, outcome.reason, outcome.results = "failed", str(exc), []
    except Exception as exc:  # noqa: BLE001 - a bug in one walk must not lose the other walks' work
        where = traceback.extract_tb(exc.__traceback__)[-1]
        outcome.status, outcome.results = "crashed", []
        outcome.reason = f"{type(exc).__name__}: {exc} (at {Path(where.filename).name}:{where.lineno})"
    outcome.runtime_s = time.perf_counter() - started
    return outcome


class _Scorer:
    """Scores each method's track on one walk into ``MethodResult`` rows."""

    def __init__(self, context: _Context, index: int, recording: Recording) -> None:
        self.building, self.recording = context.building, recording
        self.header_floor = context.true_floors[index]
        self.results: list[MethodResult] = []

    def add(self, method: str, track: Track, collapses: int, runtime_s: float, causal: bool = True) -> None:
        score = score_track(self.building, self.recording, track, self.header_floor, causal)
        errors = score.errors
        self.results.append(MethodResult(
            method, self.recording.name, track, errors.errors_m if errors else np.zeros(0),
            errors.missed if errors else int(self.recording.waypoint_t_s.size), score.wall_crossings, collapses,
            runtime_s, causal, floor_score=score.floor_score, phone=self.recording.phone_model))

    def add_run(self, method: str, outcome: TrackResult) -> None:
        """A particle filter run: its causal track as ``method`` and, when it made one, its offline
        track (``pf-smooth``, or ``pf-smooth+NAME`` for a run with source NAME)."""
        self.add(method, outcome.causal, len(outcome.collapses), outcome.causal_runtime_s)
        if outcome.offline is not None:
            offline = f"pf-smooth+{method.partition('+')[2]}" if "+" in method else "pf-smooth"
            self.add(offline, outcome.offline, len(outcome.collapses), outcome.offline_runtime_s, causal=False)

    def timed(self, method: str, make: Callable[[], Track], extra_s: float = 0.0) -> None:
        started = time.perf_counter()
        track = make()
        self.add(method, track, 0, time.perf_counter() - started + extra_s)


def _detected_steps(recording: Recording, tracking: TrackingConfig) -> Steps | None:
    try:
        return detect_steps(recording, tracking.steps)
    except MapfilterError:
        return None  # no usable IMU: the PDR methods are left out, kf and pdr-kwnn go without steps


def _one_floor_methods(context: _Context, index: int, recording: Recording) -> list[MethodResult]:
    setup, building, methods = context.setup, context.building, context.methods
    radio_map, ap_table = _wifi_sources(recording, setup, context.all_walks, building)
    if context.growth is not None and radio_map is not None:
        radio_map = merge_radio_maps([radio_map, context.growth.for_walk(recording.name)])
    scans = scans_of(recording)
    steps = _detected_steps(recording, setup.tracking)
    scan_t = np.array([s.t_s for s in scans])
    tracking = setup.tracking
    wifi = tracking.wifi
    if radio_map is not None and wifi.fix_sigma_m is None and wifi.fingerprint_model in ("fix", "blend"):
        # calibrate once for the three pf variants, not once each
        tracking = dataclasses.replace(tracking, wifi=dataclasses.replace(
            wifi, fix_sigma_m=calibrated_fix_sigma_m(radio_map, wifi.kwnn_k)))
    scorer = _Scorer(context, index, recording)
    sources = _walk_sources(context, recording)
    # the pf variants share one set of fingerprint evidence (fixes, radio-map likelihood: no
    # state); trilateration models may adapt during a run, so each run prepares its own
    motion = tracking.motion if steps is not None else dataclasses.replace(tracking.motion, model="cv")
    prepared = None
    if any(m in PF_VARIANTS for m in methods) and radio_map is not None:
        prepared = prepare_walk(building, recording, radio_map, None, dataclasses.replace(tracking, motion=motion),
                                steps=steps)
    fixes = None
    kwnn_xy = getattr(prepared.evidence, "kwnn_xy_m", None) if prepared is not None else None
    if kwnn_xy is not None and wifi.kwnn_min_rssi_dbm is None:
        fixes = kwnn_xy  # the same KWNN fixes the filter weighs: made once
    elif radio_map is not None:  # the baselines keep plain KWNN (Chang et al.) over every reading
        fixes = kwnn_fix_many(radio_map, radio_map.scan_matrix(scans), k=wifi.kwnn_k).xy_m
    elif ap_table is not None:
        fixes = _ls_fixes(ap_table, scans)

    for method in methods:
        if method in PF_VARIANTS:
            if radio_map is None and ap_table is None:
                continue
            config = PF_VARIANTS[method](dataclasses.replace(tracking, smooth=tracking.smooth and method == "pf"))
            if steps is None and config.motion.model == "pdr":
                continue
            rng = np.random.default_rng([tracking.seed, index, ALL_METHODS.index(method)])
            walk = prepared if prepared is not None else prepare_walk(building, recording, None, ap_table, config,
                                                                     steps=steps)
            outcome = track_prepared(walk, config, rng=rng, start=walk_start(setup.start, recording, building))
            scorer.add_run(method, outcome)
        elif method in SOURCE_METHODS:
            # a source with the WiFi (pf+NAME, and its offline track pf-smooth+NAME) or alone (pf-NAME)
            name, kind = SOURCE_METHODS[method]
            with_wifi = kind == "pf"
            config = dataclasses.replace(tracking, smooth=tracking.smooth and with_wifi)
            if (steps is None and config.motion.model == "pdr") or (with_wifi and radio_map is None
                                                                    and ap_table is None):
                continue
            rng = np.random.default_rng([tracking.seed, index, ALL_METHODS.index(method)])
            given = {name: sources[name]}
            if with_wifi and prepared is not None:
                walk = dataclasses.replace(prepared, inputs=dataclasses.replace(prepared.inputs, sources=given))
            else:
                walk = prepare_walk(building, recording, None, ap_table if with_wifi else None, config, steps=steps,
                                    sources=given)
            outcome = track_prepared(walk, config, rng=rng, start=walk_start(setup.start, recording, building))
            scorer.add_run(method, outcome)
        elif method == "kwnn" and radio_map is not None:
            scorer.timed(method, lambda: _fix_track(scan_t, fixes, "kwnn"))
        elif method == "pdr-kwnn" and radio_map is not None:
            scorer.timed(method, lambda: pdr_kwnn_track(radio_map, scans, steps))
        elif method == "kf" and fixes is not None:
            ok = np.all(np.isfinite(fixes), axis=1)
            scorer.timed(method, lambda: kalman_track(scan_t[ok], fixes[ok], steps))
        elif method == "pdr" and fixes is not None and steps is not None:
            ok = np.flatnonzero(np.all(np.isfinite(fixes), axis=1))
            if ok.size:
                scorer.timed(method, lambda: pdr_track(steps, scan_t[ok[0]], fixes[ok[0]]))
        elif method == "ls" and ap_table is not None:
            scorer.timed(method, lambda: _fix_track(scan_t, _ls_fixes(ap_table, scans), "ls"))
        elif method == "pdr-start" and steps is not None:
            scorer.timed(method, lambda: pdr_start_track(steps, recording))
    diagnostics = walk_diagnostics(recording, scan_t, fixes, radio_map, steps)
    for result in scorer.results:
        result.diagnostics = diagnostics
    return scorer.results


# each pf variant: the tracking config it runs with
PF_VARIANTS: dict[str, Callable[[TrackingConfig], TrackingConfig]] = {
    "pf": lambda c: c,
    "pf-nomap": lambda c: dataclasses.replace(c, use_map=False),
    "pf-nopdr": lambda c: dataclasses.replace(c, motion=dataclasses.replace(c.motion, model="cv")),
}


def _building_methods(context: _Context, index: int, recording: Recording) -> list[MethodResult]:
    setup, building = context.setup, context.building
    radio_map = _building_radio_map(recording, setup, context.all_walks, building)
    if context.growth is not None:
        radio_map = merge_radio_maps([radio_map, context.growth.for_walk(recording.name)])
    sigma = context.all_walks.fix_sigma_for(setup, recording.name) if context.all_walks is not None else None
    if sigma is None and setup.tracking.wifi.fix_sigma_m is None and context.all_walks is None:
        sigma = _radio_map_sigmas(radio_map, building, setup.tracking)
    header_floor = context.true_floors[index]
    truth = building.floor_names[header_floor] if header_floor is not None else None
    scorer = _Scorer(context, index, recording)
    tracking = setup.tracking
    steps = _detected_steps(recording, tracking)
    has_steps = tracking.motion.model != "pdr" or (steps is not None and len(steps) > 0)
    sources = _walk_sources(context, recording)
    fixes = None  # the KWNN fixes and floors, made once for kwnn, kf and pdr
    for method in context.methods:
        rng = np.random.default_rng([tracking.seed, index, BUILDING_METHODS.index(method)])
        if method in ("pf", "pf-floor"):
            if not has_steps or (method == "pf-floor" and truth is None):
                continue
            config = dataclasses.replace(tracking, smooth=tracking.smooth and method == "pf")
            walk = prepare_walk(building, recording, radio_map, None, config, steps=steps,
                                floor=truth if method == "pf-floor" else None, fix_sigma_by_floor_m=sigma)
            outcome = track_prepared(walk, config, rng=rng, start=walk_start(setup.start, recording, building))
            scorer.add_run(method, outcome)
        elif method in SOURCE_METHODS:
            # pf and pf-floor with a source too (pf+NAME's offline track: pf-smooth+NAME), and pf
            # on the source (and barometer) alone
            name, kind = SOURCE_METHODS[method]
            if not has_steps or (kind == "pf-floor" and truth is None):
                continue
            config = dataclasses.replace(tracking, smooth=tracking.smooth and kind == "pf")
            wifi = None if kind == "alone" else radio_map
            walk = prepare_walk(building, recording, wifi, None, config, steps=steps,
                                floor=truth if kind == "pf-floor" else None,
                                fix_sigma_by_floor_m=sigma if wifi is not None else None,
                                sources={name: sources[name]})
            outcome = track_prepared(walk, config, rng=rng, start=walk_start(setup.start, recording, building))
            scorer.add_run(method, outcome)
        elif method in ("kwnn", "kf", "pdr"):
            if fixes is None:
                started = time.perf_counter()
                fixes = kwnn_floor_fixes(radio_map, scans_of(recording), tracking.wifi.kwnn_k)
                fix_s = time.perf_counter() - started
            scan_t, xy, floor = fixes
            if method == "kwnn":
                scorer.timed(method, lambda: _floor_track(building, scan_t, xy, floor, "kwnn"), fix_s)
            elif method == "kf":
                scorer.timed(method, lambda: floor_path_baseline(
                    building, scan_t, xy, floor, lambda t, f: kalman_track(t, f, steps), "kf"))
            elif steps is not None and len(steps):
                scorer.timed(method, lambda: floor_path_baseline(
                    building, scan_t, xy, floor, lambda t, f: pdr_track(steps, t[0], f[0]), "pdr"))
        elif method == "pdr-start" and steps is not None and len(steps):
            # on the floor of the walk's first waypoint, in its frame (a walk that changes floor: wrong after it)
            first = recording.waypoint_floor[0] if recording.waypoint_floor else truth
            if first is not None:
                scorer.timed(method, lambda: _on_floor(pdr_start_track(steps, recording), first))
    return scorer.results


def _on_floor(track: Track, floor: str) -> Track:
    return dataclasses.replace(track, floor=[floor] * len(track))


def _radio_map_sigmas(radio_map: RadioMap, building: Building, tracking: TrackingConfig) -> dict[str, float]:
    return {name: calibrated_fix_sigma_m(radio_map.floor_map(i), tracking.wifi.kwnn_k)
            for i, name in enumerate(building.floor_names)}


def _building_radio_map(recording: Recording | None, setup: EvaluationSetup, all_walks: AllWalks | None,
                        building: Building) -> RadioMap:
    if all_walks is not None:
        return (all_walks.without(setup.left_out_with(recording.name), one_floor=False) if setup.leaves_out
                else all_walks.radio_map)
    from mapfilter.sensors.floor_vote import load_building_radio_map

    if setup.radio_map is not None:
        radio_map = setup.radio_map
        check_building_radio_map(radio_map, building.floor_names, "the radio map")
    else:
        radio_map = load_building_radio_map(setup.radio_map_path, building.floor_names)
    check_radio_map_on_map(radio_map, building, setup.radio_map_path, building.path)
    return radio_map


def _growth(building: Building, setup: EvaluationSetup, paths: list[Walk], labelled: list[Recording],
            all_walks: AllWalks | None, engine: Engine, progress: Callable[[int, int, str], None] | None) -> Growth:
    """The radio map's grown points (``Growth``): from the unlabelled walks (and, transductive,
    the evaluated ones), over the labelled material the walks are scored with."""
    read = [read_walk(p, building, setup.strict) for p in setup.unlabelled_paths]
    scored = [read_walk(p, building, setup.strict) for p in paths] if setup.transductive else []
    space = building.floors[0].plan if building.is_single_floor else building
    config = GrowConfig(tracking=setup.tracking, seed=setup.tracking.seed)
    if setup.leaves_out:
        # once per fold of the labelled walks: a scored walk's labels never place its grown points;
        # transductive: each fold's scored walks grow its points
        folds, fold = growth_folds(setup, [rec.name for rec in labelled])
        fold_of = {rec.name: int(f) for rec, f in zip(labelled, fold)}
        fold_walks = [[rec for rec in scored if fold_of.get(rec.name) == f] for f in range(folds)] if scored else None
        grown, _, _ = grown_by_fold(space, labelled, read, config, folds=folds, engine=engine, progress=progress,
                                    fold=fold, fold_walks=fold_walks)
        return Growth(tuple(grown), fold_of, setup.transductive)
    read += scored
    if all_walks is not None:  # the survey logs
        base = all_walks.radio_map
    elif building.is_single_floor:
        base = setup.load_radio_map()
    else:
        base = _building_radio_map(None, setup, None, building)
    result, _ = grow_radio_map(space, base, read, config, progress=progress, engine=engine)
    return Growth((result.select(result.source == GROWN),), {}, setup.transductive)


def growth_folds(setup: EvaluationSetup, labelled: Sequence[str], folds: int = 4) -> tuple[int, np.ndarray]:
    """The folds a left-out evaluation grows its points in: (number of folds, each labelled walk's
    fold). Walk i in fold i % ``folds``; left out by group, every walk of a group in its group's
    fold, so that no walk of a group helps place the points its group is scored with."""
    if setup.groups is not None:
        order = setup.groups.groups()
        folds = min(folds, len(order))
        return folds, np.array([order.index(setup.groups.group(name)) % folds for name in labelled], dtype=np.int64)
    if setup.transductive:
        folds = max(1, min(folds, len(labelled)))  # each fold grows from its own walks: none empty
    return folds, np.arange(len(labelled), dtype=np.int64) % folds


def kwnn_floor_fixes(radio_map: RadioMap, scans, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """KWNN across floors: (scan times (S,), fixes (S, 2) in each scan's floor frame, NaN where
    that floor's fingerprints give none, floor indices (S,)): each scan on the causal floor HMM's
    floor (the KWNN floor vote, ``sensors.floor_vote``), fixed from that floor's fingerprints."""
    scan_t = np.array([s.t_s for s in scans])
    path = floor_hmm(floor_vote_log_likelihood(radio_map, radio_map.scan_matrix(scans), k=k), scan_t)
    floor = path.causal_floor()
    xy = np.full((len(scans), 2), np.nan)
    for f in np.unique(floor):
        on = np.flatnonzero(floor == f)
        sub = radio_map.floor_map(int(f))
        if len(sub):
            xy[on] = kwnn_fix_many(sub, sub.scan_matrix([scans[i] for i in on]), k=k).xy_m
    return scan_t, xy, floor


def _floor_track(building: Building, scan_t: np.ndarray, xy: np.ndarray, floor: np.ndarray, name: str) -> Track:
    ok = np.all(np.isfinite(xy), axis=1)
    return Track(scan_t[ok], xy[ok], floor=[building.floor_names[f] for f in floor[ok]], name=name)


def floor_path_baseline(building: Building, scan_t: np.ndarray, xy: np.ndarray, floor: np.ndarray,
                        make: Callable[[np.ndarray, np.ndarray], Track], name: str) -> Track:
    """A one-floor baseline (``make(fix times, fixes)``: the Kalman filter, dead reckoning) over
    fixes on several floors (``kwnn_floor_fixes``): run in the frame of the first fix's floor
    (every fix moved there through the building frame; the rotation vector's heading is that
    floor's), each row then on the floor of the latest fix at or before it, in that floor's frame."""
    ok = np.flatnonzero(np.all(np.isfinite(xy), axis=1))
    if ok.size == 0:
        return Track(np.zeros(0), np.zeros((0, 2)), floor=[], name=name)
    floors = building.floors
    home = floors[int(floor[ok[0]])]
    local = np.empty((ok.size, 2))
    for f in np.unique(floor[ok]):
        on = floor[ok] == f
        local[on] = home.from_building(floors[int(f)].to_building(xy[ok][on]))
    track = make(scan_t[ok], local)
    row_floor = floor[ok][np.clip(np.searchsorted(scan_t[ok], track.t_s, side="right") - 1, 0, None)]
    out = np.empty_like(track.xy_m)
    for f in np.unique(row_floor):
        on = row_floor == f
        out[on] = floors[int(f)].from_building(home.to_building(track.xy_m[on]))
    return dataclasses.replace(track, xy_m=out, floor=[building.floor_names[f] for f in row_floor], name=name)


def _wifi_sources(recording: Recording, setup: EvaluationSetup, all_walks: AllWalks | None,
                  building: Building) -> tuple[RadioMap | None, AccessPointTable | None]:
    radio_map = setup.load_radio_map()
    ap_table = setup.load_access_points()
    if radio_map is not None:
        check_radio_map_on_map(radio_map, building, setup.radio_map_path, building.path)
    if ap_table is not None:
        check_access_points_on_map(ap_table, building.floors[0].plan, building.path)
    if all_walks is not None:
        # without the walk, or every walk of its group (and with survey logs alone, nothing to drop)
        radio_map = all_walks.without(setup.left_out_with(recording.name), one_floor=True)
        if len(radio_map) == 0:
            raise MapfilterError("no survey points left for this walk: it needs other walks with waypoints and WiFi",
                                 recording.path)
        if ap_table is None and all_walks.ap_table is not None:
            ap_table = _leave_one_out_aps(all_walks, radio_map, setup.left_out_with(recording.name))
    return radio_map, ap_table


def _leave_one_out_aps(all_walks: AllWalks, fold_map: RadioMap, traces: Sequence[str]) -> AccessPointTable:
    """The AP table fitted without the walks ``traces``: an AP's fit depends only on its own
    observations, so only the APs these walks heard are fitted again (on the fold's radio map);
    the others keep their all-walks fit, which is exactly what a fit without these walks gives them."""
    full = all_walks.radio_map
    mine = np.isin(full.trace, [i for i, name in enumerate(full.source_traces) if name in set(traces)])
    heard = set(np.array(full.ap_keys)[~np.all(np.isnan(full.rssi_dbm[mine]), axis=0)].tolist())
    columns = [j for j, key in enumerate(fold_map.ap_keys) if key in heard]
    table = all_walks.ap_table
    keep = [i for i, key in enumerate(table.keys) if key not in heard]
    parts = [_select_aps(table, keep)]
    if columns:
        subset = RadioMap(fold_map.xy_m, [fold_map.ap_keys[j] for j in columns], fold_map.rssi_dbm[:, columns],
                          fold_map.t_s, fold_map.trace, fold_map.source_traces, fold_map.floor_name)
        try:
            parts.append(estimate_access_points(subset))
        except MapfilterError:
            pass  # none of this walk's APs can be fitted from the other walks
    return _concat_aps(parts)


def _select_aps(table: AccessPointTable, rows: list[int]) -> AccessPointTable:
    return AccessPointTable([table.bssid[i] for i in rows], [table.band[i] for i in rows], table.xy_m[rows],
                            table.c_dbm[rows], table.n[rows], table.alpha_db_per_m[rows], table.d_max_m[rows])


def _concat_aps(tables: list[AccessPointTable]) -> AccessPointTable:
    return AccessPointTable(
        [b for t in tables for b in t.bssid], [b for t in tables for b in t.band],
        np.concatenate([t.xy_m for t in tables]).reshape(-1, 2),
        *(np.concatenate([getattr(t, f) for t in tables]) for f in ("c_dbm", "n", "alpha_db_per_m", "d_max_m")))


def _drop_unheard_aps(radio_map: RadioMap) -> RadioMap:
    """Without the walk under test, some APs are heard nowhere: drop them, as a radio map built
    from the other walks alone would never have had them."""
    return radio_map.select_aps(~np.all(np.isnan(radio_map.rssi_dbm), axis=0))


def _fix_track(scan_t: np.ndarray, fixes: np.ndarray, name: str) -> Track:
    ok = np.all(np.isfinite(fixes), axis=1)
    return Track(scan_t[ok], fixes[ok], name=name)


def _ls_fixes(ap_table: AccessPointTable, scans) -> np.ndarray:
    fixes = np.full((len(scans), 2), np.nan)
    for i, scan in enumerate(scans):
        if match_scan(ap_table, scan)[0].size >= 3:
            fixes[i] = least_squares_position(ap_table, scan)
    return fixes


# ---- many walks ------------------------------------------------------------------------------
def walk_name(walk: Walk) -> str:
    """A walk's trace name: its log file's (``trace_name``), or the ``Recording``'s own."""
    return walk.name if isinstance(walk, Recording) else trace_name(walk)


def read_walk(walk: Walk, building: Building, strict: bool = False) -> Recording:
    """A walk as a ``Recording``: its log read (latitude/longitude ground truth placed in the
    building), or the ``Recording`` given, placed likewise."""
    if isinstance(walk, Recording):
        return localise(walk, building) if walk.needs_georeference else walk
    return read_log(walk, strict=strict, building=building)


def checked_log_paths(log_paths: Sequence[str | os.PathLike | Recording]) -> list[Walk]:
    """The walks as paths (or ``Recording``s, kept as they are); ``MapfilterError`` for a missing
    file or two walks with one trace name (walks are told apart by name: leave-one-out drops a
    walk's points by it)."""
    paths = [p if isinstance(p, Recording) else Path(p) for p in log_paths]
    for path in paths:
        if isinstance(path, Path) and not path.is_file():
            raise missing_log(path)
    names = [walk_name(p) for p in paths]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise MapfilterError(f"two logs share the trace name {repeated[0]}: walks are told apart by name")
    return paths


@dataclasses.dataclass
class Evaluation:
    """All methods on all walks."""

    results: list[MethodResult]
    n_traces: int
    wall_time_s: float
    read_warnings: list[str] = dataclasses.field(default_factory=list)  # rows the log reader skipped, per log
    failed: list[WalkOutcome] = dataclasses.field(default_factory=list)  # walks without results, and why
    grown: str = ""  # self-training: what grew the radio map ("" without)
    protocol: str = ""  # what the walks were scored against (EvaluationSetup.protocol)
    radio_map_source: str = ""  # where the radio map came from, in words (EvaluationSetup.radio_map_source)
    grouping: Grouping | None = None  # left out by group: every walk's group (the per-group rows)
    common_waypoints: bool = True  # the tables score every method of a walk at the same waypoints

    def scored(self) -> list[MethodResult]:
        """The results as the tables score them: with ``common_waypoints``, each walk's at the
        waypoints every method on it has an estimate for (from the latest first estimate on; a
        method without any estimate on the walk is left out of that choice and counts them all as
        ``not_scored``), else each at its own."""
        if not self.common_waypoints:
            return self.results
        first: dict[str, int] = {}
        for r in self.results:
            if r.errors_m.size:
                first[r.trace] = max(first.get(r.trace, 0), r.missed)
        return [r.from_waypoint(first.get(r.trace, r.n_waypoints)) for r in self.results]

    def common_count(self) -> tuple[int, int]:
        """(waypoints every method is scored at, waypoints of the walks with results)."""
        by_trace: dict[str, list[MethodResult]] = {}
        for r in self.scored():
            by_trace.setdefault(r.trace, []).append(r)
        common = sum(max(r.errors_m.size + r.not_scored for r in mine) for mine in by_trace.values())
        return common, sum(mine[0].n_waypoints for mine in by_trace.values())

    def scoring_text(self) -> str:
        """One line on the waypoints the table scores each method at."""
        if not self.results:
            return ""
        if not self.common_waypoints:
            return "each method scored at its own waypoints, from its first estimate on (n, missed)"
        common, total = self.common_count()
        if common == total:
            return f"every method scored at all {total} waypoints"
        return (f"every method scored at the same {common} of the {total} waypoints: those after every method's "
                f"first estimate (--waypoints own: each at its own)")

    def not_scored_text(self) -> list[str]:
        """A line per method that has no estimate at some of the common waypoints."""
        lines, scored = [], self.scored()
        for method in self.methods():
            mine = [r for r in scored if r.method == method]
            short = sum(r.not_scored for r in mine)
            if short:
                walks = [r.trace for r in mine if r.not_scored]
                lines.append(f"{method}: no estimate at {short} of the common waypoints (walk"
                             f"{'s' if len(walks) != 1 else ''} {', '.join(walks[:3])}{', ...' if len(walks) > 3 else ''})"
                             f"; its row is scored at the others")
        return lines

    @classmethod
    def from_outcomes(cls, outcomes: Sequence[WalkOutcome], n_traces: int, wall_time_s: float,
                      read_warnings: Sequence[str] = ()) -> Evaluation:
        """The evaluation of these walks' outcomes, in the order of the walks."""
        ordered = sorted(outcomes, key=lambda o: o.index)
        return cls([r for o in ordered for r in o.results], n_traces, wall_time_s, list(read_warnings),
                   [o for o in ordered if o.status != "ok"])

    @property
    def has_floors(self) -> bool:
        """Several floors: the rows carry floor accuracy."""
        return any(r.floor_score is not None for r in self.results)

    def methods(self) -> list[str]:
        seen: list[str] = []
        for r in self.results:
            if r.method not in seen:
                seen.append(r.method)
        return seen

    def errors_by_method(self) -> dict[str, np.ndarray]:
        scored = self.scored()
        return {m: np.concatenate([r.errors_m for r in scored if r.method == m]) for m in self.methods()}

    def phones(self) -> list[str]:
        """The phone models the walks' logs name, in order of first appearance (GetSensorData logs)."""
        seen: list[str] = []
        for r in self.results:
            if r.phone and r.phone not in seen:
                seen.append(r.phone)
        return seen

    def group_of(self, trace: str) -> str:
        """The walk's group (left out by group), else its own name."""
        return self.grouping.group_of.get(trace, trace) if self.grouping is not None else trace

    def summary_rows(self, by_phone: bool = False, by_group: bool = False) -> list[dict]:
        """One row per method: error statistics over all waypoints of all walks (with CE95, the
        95th percentile), the availability (the share of waypoints with an estimate) and totals;
        in a building with several floors also the floor accuracy, the floor detection probability
        (right floor at all waypoints) and the IPIN score (the 75th percentile of the error plus
        15 m per storey off, over the same waypoints). docs/results.md describes every column.
        ``by_phone``: one row per phone model and method (a ``phone`` column first), the walks of
        that phone. ``by_group``: one row per group (a route, left out by group) and method (a
        ``group`` column first), the walks of that group."""
        scored = self.scored()
        if by_group:
            groups = list(dict.fromkeys(self.group_of(r.trace) for r in scored))
            return [{"group": group, **row} for group in groups
                    for row in self._rows([r for r in scored if self.group_of(r.trace) == group])]
        if by_phone:
            return [{"phone": phone, **row} for phone in self.phones()
                    for row in self._rows([r for r in scored if r.phone == phone])]
        return self._rows(scored)

    def _rows(self, results: list[MethodResult]) -> list[dict]:
        rows = []
        for method in self.methods():
            mine = [r for r in results if r.method == method]
            if not mine:
                continue
            stats = summarise_errors(np.concatenate([r.errors_m for r in mine]))
            missed = sum(r.missed for r in mine)  # before the method's own first estimate
            estimated = sum(r.n_waypoints - r.missed for r in mine)
            row = {"method": method, **stats, "missed": missed, "availability": availability(estimated, missed),
                   "not_scored": sum(r.not_scored for r in mine),
                   "wall_crossings": sum(r.wall_crossings for r in mine),
                   "collapses": sum(r.collapses for r in mine),
                   "runtime_s": sum(r.runtime_s for r in mine), "traces": len(mine), "causal": mine[0].causal}
            if self.has_floors:
                scores = [r.floor_score for r in mine if r.floor_score]
                judged = sum(s.n_judged for s in scores)
                row["floor_accuracy"] = sum(s.n_right for s in scores) / judged if judged else math.nan
                row["floor_detection"] = floor_detection([r.detection_score or r.floor_score for r in mine
                                                          if r.floor_score])
                row["ipin_score"] = ipin_score(np.concatenate([r.ipin_errors_m for r in mine]))
            rows.append(row)
        return rows

    def walk_rows(self) -> list[dict]:
        """One row per walk: why it went well or wrong (``evaluation.diagnostics``) and each
        method's mean error on it."""
        rows: dict[str, dict] = {}
        for r in self.scored():
            group = {"group": self.group_of(r.trace)} if self.grouping is not None else {}
            row = rows.setdefault(r.trace, {"trace": r.trace, **group, **{c: r.diagnostics.get(c, math.nan)
                                                                           for c in DIAGNOSTIC_COLUMNS}})
            row[f"{r.method} mean"] = float(r.errors_m.mean()) if r.errors_m.size else math.nan
        return list(rows.values())

    def trace_rows(self) -> list[dict]:
        """One row per walk and method."""
        rows = []
        for r in self.scored():
            row = {"trace": r.trace, "method": r.method, **summarise_errors(r.errors_m), "missed": r.missed,
                   "availability": availability(r.n_waypoints - r.missed, r.missed), "not_scored": r.not_scored,
                   "wall_crossings": r.wall_crossings, "collapses": r.collapses, "runtime_s": r.runtime_s}
            if self.has_floors:
                row["floor_accuracy"] = r.floor_score.accuracy if r.floor_score else math.nan
                row["floor_detection"] = r.floor_detection
                row["ipin_score"] = ipin_score(r.ipin_errors_m)
            if r.phone:
                row["phone"] = r.phone
            if self.grouping is not None:
                row["group"] = self.group_of(r.trace)
            rows.append(row)
        return rows


class _collect_read_warnings(warnings.catch_warnings):
    """Append the message of every ``LogReadWarning`` raised inside to ``into``; others pass."""

    def __init__(self, into: list[str]) -> None:
        super().__init__(record=True)
        self.into = into

    def __enter__(self):
        self.caught = super().__enter__()
        warnings.simplefilter("always", LogReadWarning)
        return self.caught

    def __exit__(self, *exc_info):
        super().__exit__(*exc_info)
        for w in self.caught:
            if issubclass(w.category, LogReadWarning):
                message = str(w.message)
                if message not in self.into:
                    self.into.append(message)
            else:
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)


def nan_to_none(value):
    """JSON has no NaN: write null."""
    if isinstance(value, float) and math.isnan(value):
        return None
    return value
