"""A walk's WiFi (and barometer) as the filter weighs it: a measurement model and one measurement
per scan, made once per walk.

``WifiEvidence`` is one floor: fingerprinting against a radio map (``fix``: one KWNN fix per
scan, Chang et al., weighed with a Gaussian, Evennou & Marx, where the scan matches the survey
and flatter where it does not, ``filter.models.survey_reach``; ``blend``: the mean of that fix
and the radio-map likelihood's best cell, weighed the same way; ``likelihood``: the radio map's own probability of
the scan at each particle) or trilateration from an access-point table (the Lund thesis
path-loss likelihood, adaptive with ``TrilaterationConfig``). ``BuildingEvidence`` is several
floors: per floor the ``WifiEvidence`` of that floor's fingerprints, per scan the WiFi floor
vote, and the barometer between scans (without a radio map, the barometer alone).
``NoWifiEvidence`` is one floor without WiFi, where a measurement source (``filter.sources``)
weighs the particles alone. The stream filter
(``filter.causal.CausalFilter``) asks them the same questions (``WalkEvidence``).
"""

from __future__ import annotations

import copy
import dataclasses
from typing import Any, Protocol

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.filter.models.adaptive_path_loss import (THESIS_BLOCKING_DROP_DB, THESIS_RSSI_LIMIT_DBM,
                                                        AdaptiveTrilaterationLikelihood, check_adaptive_settings)
from mapfilter.filter.models.barometer import (STEADY_M, STEADY_WINDOW_S, BarometerConfig, BarometerReference,
                                               BarometricHeights)
from mapfilter.filter.events import StepReport
from mapfilter.filter.models.building import FloorFix, FloorFixLikelihood, FloorStack
from mapfilter.filter.models.path_loss import TrilaterationLikelihood
from mapfilter.filter.models.interface import MeasurementModel
from mapfilter.filter.models.radio_map import RadioMapLikelihood, RadioMapLikelihoodConfig, radio_map_likelihood
from mapfilter.filter.models.survey_reach import (DistanceGrid, ReachFix, ReachFixLikelihood, SurveyReach,
                                                  distance_grid, survey_reach)
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.sensors.floor_vote import check_building_radio_map, floor_vote_log_likelihood
from mapfilter.sensors.pathloss import AccessPointTable, least_squares_position, match_scan
from mapfilter.sensors.radiomap import (STRONG_MIN_RSSI_DBM, RadioMap, cross_validated_fix_errors, kwnn_fix_many,
                                       kwnn_fixes_by_floor, match_distance_by_floor_db, memo_of,
                                       plain_signal_distances, strong_kwnn_fixes)
from mapfilter.sensors.wifi import WifiScan

FINGERPRINT_MODELS = ("fix", "blend", "likelihood")
OWN_FLOOR_MIN_PROBABILITY = 0.5  # a building floor's own fingerprints give its fix where they reach the scan this well


@dataclasses.dataclass(frozen=True)
class WifiConfig:
    """How fingerprints (a radio map) weigh the particles."""

    # blend: two estimators that err differently where the survey is thin (docs/accuracy.md)
    fingerprint_model: str = "blend"  # fix: KWNN fix + Gaussian | blend: fix averaged with the radio-map likelihood's best cell | likelihood: per-particle radio map
    # a fix is as good as its radio map: calibrated per map, it lands where tuning would (docs/accuracy.md)
    fix_sigma_m: float | None = None  # Gaussian of the fix; null: calibrated per radio map (RMS of its cross-validated KWNN errors / sqrt 2)
    kwnn_k: int = 4  # neighbours of a KWNN fix (Chang et al.)
    # ``sensors.radiomap.strong_kwnn_fixes``: phones disagree most on weak APs
    kwnn_min_rssi_dbm: float | None = STRONG_MIN_RSSI_DBM  # the filter's KWNN fixes use readings at or above this; null: every reading
    radio_map_likelihood: RadioMapLikelihoodConfig = dataclasses.field(default_factory=RadioMapLikelihoodConfig)  # the per-particle radio-map model (likelihood, blend)

    def __post_init__(self) -> None:
        if self.fingerprint_model not in FINGERPRINT_MODELS:
            raise MapfilterError(f"unknown fingerprint model {self.fingerprint_model!r}: "
                                 f"choose one of {', '.join(FINGERPRINT_MODELS)}")
        if self.kwnn_k < 1:
            raise MapfilterError(f"kwnn_k must be at least 1, got {self.kwnn_k}")
        if self.fix_sigma_m is not None and not self.fix_sigma_m > 0:
            raise MapfilterError(f"fix_sigma_m must be positive (or null: calibrated), got {self.fix_sigma_m}")


@dataclasses.dataclass(frozen=True)
class TrilaterationConfig:
    """How an access-point table weighs the particles (Lund thesis chapters 6-7)."""

    rssi_variance_db2: float = 25.0  # RSSI noise variance of the path-loss likelihood (thesis: 25 dB^2)
    adapt_path_loss: bool = False  # adapt C per AP and alpha per band during the walk (thesis 7.1-7.2)
    adapt_rssi_limit_dbm: float = THESIS_RSSI_LIMIT_DBM  # with adapt_path_loss: a scan's strongest RSSI above this adapts (the phone is below that AP; thesis -36 dBm)
    blocking_compensation: bool = True  # take H dB off every AP while all drop together (thesis 7.3)
    blocking_drop_db: float = THESIS_BLOCKING_DROP_DB  # with blocking_compensation: blocked when the six strongest RSSI's mean falls this far (thesis 6 dB)

    def __post_init__(self) -> None:
        if not self.rssi_variance_db2 > 0:
            raise MapfilterError(f"rssi_variance_db2 must be positive, got {self.rssi_variance_db2}")
        check_adaptive_settings(self.adapt_rssi_limit_dbm, self.blocking_drop_db)


class WalkEvidence(Protocol):
    """What the tracker asks of a walk's evidence. Scans are added as they arrive (``add_scans``:
    the measurement of each depends on that scan and the radio map or table only)."""

    scans: list[WifiScan]
    usable: np.ndarray  # (S,) bool: scans that give a measurement
    model: MeasurementModel

    def add_scans(self, scans: list[WifiScan]) -> None:
        """Append scans (in time order) and make their measurements."""
        ...

    def measurement(self, index: int) -> Any:
        """The measurement the filter weighs for scan ``index`` (None when the scan is unusable)."""
        ...

    def between_scans(self, t_s: float) -> Any:
        """What the filter weighs at a step between scans (None: nothing)."""
        ...

    def has_evidence_between_scans(self) -> bool:
        """Whether ``between_scans`` can ever give something (a barometer in a building)."""
        ...

    def observe(self, report: StepReport) -> None:
        """After each filter step (the barometer's reference follows the filter's floor)."""
        ...


class WifiEvidence:
    """One floor's WiFi: the measurement model and each scan's measurement (``WalkEvidence``).

    Exactly one of ``radio_map`` (fingerprinting) and ``ap_table`` (trilateration). Scans come
    with ``add_scans``; each scan's fix depends on that scan and the radio map only, so adding
    them one by one or all at once gives the same numbers.
    """

    has_wifi = True

    def __init__(self, radio_map: RadioMap | None, ap_table: AccessPointTable | None, floorplan: FloorPlan,
                 wifi: WifiConfig = WifiConfig(), trilateration: TrilaterationConfig = TrilaterationConfig(),
                 log_name: str = "the log", reach: SurveyReach | None = None, grid: DistanceGrid | None = None):
        if (radio_map is None) == (ap_table is None):
            raise MapfilterError("give either a radio map (fingerprinting) or an access-point table (trilateration)")
        self.scans: list[WifiScan] = []
        self._radio_map, self._ap_table, self._floorplan = radio_map, ap_table, floorplan
        self._wifi = wifi
        self.log_name = log_name
        self._fix: list[np.ndarray] = []  # per scan: the fingerprint fix (NaN: none)
        self._kwnn: list[np.ndarray] = []  # per scan: the KWNN fix (NaN: none)
        self._best: list[np.ndarray] = []  # per scan: the radio-map likelihood's best cell (blend; NaN: none)
        self._usable: list[bool] = []
        self._in_survey: list[float] = []  # per scan: P(taken inside the survey) (fix, blend)
        self.reach: SurveyReach | None = None
        self._radio_map_model: RadioMapLikelihood | None = None
        self._pending_keys: set[str] = set()  # APs whose radio-map tables the walk needs (blend; ``prepare``)
        self.model: MeasurementModel
        if radio_map is not None:
            if wifi.fingerprint_model in ("fix", "blend"):
                sigma_m = wifi.fix_sigma_m if wifi.fix_sigma_m is not None else calibrated_fix_sigma_m(
                    radio_map, wifi.kwnn_k)
                # a building's floors get the building's reach (its points on every floor)
                self.reach = reach if reach is not None else survey_reach(radio_map)
                grid = grid if grid is not None else distance_grid(radio_map.xy_m, floorplan.extent_m)
                self.model = ReachFixLikelihood(sigma_m, grid)
            else:
                self.model = self.radio_map_model()
        else:
            self.model = trilateration_model(ap_table, trilateration)

    def prepare(self, scans: list[WifiScan]) -> None:
        """Check that the scans to come share access points with the radio map or table (one line
        naming the log if none does) and build the radio-map tables of the APs they hear in one go
        (the same numbers as building them scan by scan, faster); with the blend, when a scan first
        needs the likelihood's best cell."""
        if self._radio_map is not None:
            index = self._radio_map.key_index
            if not any(k in index for s in scans for k in s.ap_keys):
                raise MapfilterError(f"the radio map shares no access point with {self.log_name}")
            if self._wifi.fingerprint_model in ("blend", "likelihood"):
                keys = {key for scan in scans for key in scan.ap_keys}
                if self._wifi.fingerprint_model == "blend" and self._radio_map_model is None:
                    # built with the likelihood, when a scan first needs its best cell: a building
                    # floor's own fingerprints may never reach the walk's scans
                    self._pending_keys |= keys
                else:
                    self.radio_map_model().build_tables(keys)
        elif not any(match_scan(self._ap_table, s)[0].size for s in scans):
            raise MapfilterError(f"the access-point table shares no access point with {self.log_name}")

    def require_usable(self) -> None:
        if not any(self._usable):
            raise MapfilterError(f"no WiFi scan of {self.log_name} gives a fingerprint fix with this radio map")

    def add_scans(self, scans: list[WifiScan], kwnn_xy_m: np.ndarray | None = None, in_survey: np.ndarray | None = None,
                  wanted: np.ndarray | None = None) -> None:
        """The scans' measurements. A building (``BuildingEvidence``) gives what it computed for
        every floor at once: ``kwnn_xy_m`` (S, 2) the KWNN fixes on this floor's frame,
        ``in_survey`` (S,) the scans' in-survey probabilities, and ``wanted`` (S,) the scans whose
        fix it will read (the others get none)."""
        if not scans:
            return
        self.scans.extend(scans)
        nan2 = np.full((len(scans), 2), np.nan)
        radio_map, wifi = self._radio_map, self._wifi
        if radio_map is None:
            self._usable.extend(match_scan(self._ap_table, s)[0].size > 0 for s in scans)
            self._fix.extend(nan2)
            self._kwnn.extend(nan2)
            self._best.extend(nan2)
            return
        if wifi.fingerprint_model == "likelihood":  # a scan is usable when it hears an AP of the map
            index = radio_map.key_index
            self._usable.extend(any(k in index for k in s.ap_keys) for s in scans)
            self._fix.extend(nan2)
            self._kwnn.extend(nan2)
            self._best.extend(nan2)
            return
        matrix = radio_map.scan_matrix(scans) if kwnn_xy_m is None or in_survey is None else None
        if kwnn_xy_m is not None:
            kwnn = np.array(kwnn_xy_m, dtype=np.float64).reshape(-1, 2)
        elif wifi.kwnn_min_rssi_dbm is None:
            kwnn = kwnn_fix_many(radio_map, matrix, k=wifi.kwnn_k).xy_m
        else:
            kwnn = strong_kwnn_fixes(radio_map, matrix, wifi.kwnn_k, wifi.kwnn_min_rssi_dbm)
        if wanted is not None:
            kwnn[~np.asarray(wanted, dtype=bool)] = np.nan
        best = np.full((len(scans), 2), np.nan)
        if wifi.fingerprint_model == "blend":
            for i, scan in enumerate(scans):
                if np.isfinite(kwnn[i]).all():
                    best[i] = self.radio_map_model().best_position(scan)
        fix = np.where(np.isfinite(best), 0.5 * (kwnn + best), kwnn)
        self._in_survey.extend(self.reach.in_survey_probability(matrix) if in_survey is None else in_survey)
        self._kwnn.extend(kwnn)
        self._best.extend(best)
        self._fix.extend(fix)
        self._usable.extend(np.all(np.isfinite(fix), axis=1))

    @property
    def usable(self) -> np.ndarray:
        return np.array(self._usable, dtype=bool)

    @property
    def fix_xy_m(self) -> np.ndarray | None:
        """(S, 2) fingerprint fixes, one per scan (NaN: none); None for the other models."""
        return np.array(self._fix).reshape(-1, 2) if self._radio_map is not None and self._wifi.fingerprint_model != \
            "likelihood" else None

    def fix_xy_m_since(self, first: int) -> np.ndarray | None:
        """``fix_xy_m[first:]``, without making the whole walk's array (a live run adds scans all along)."""
        return np.array(self._fix[first:]).reshape(-1, 2) if self._radio_map is not None and \
            self._wifi.fingerprint_model != "likelihood" else None

    @property
    def kwnn_xy_m(self) -> np.ndarray | None:
        """(S, 2) KWNN fixes, one per scan (NaN: none); None for the other models."""
        return np.array(self._kwnn).reshape(-1, 2) if self.fix_xy_m is not None else None

    @property
    def fix_sigma_m(self) -> float | None:
        """The Gaussian of the fingerprint fixes (None for the other models)."""
        return self.model.sigma_m if isinstance(self.model, ReachFixLikelihood) else None

    @property
    def in_survey(self) -> np.ndarray:
        """(S,) each scan's probability of having been taken inside the survey (fix, blend; else empty)."""
        return np.array(self._in_survey, dtype=np.float64)

    def measurement(self, index: int) -> Any:
        if not self._usable[index]:
            return None
        if self._radio_map is not None and self._wifi.fingerprint_model != "likelihood":
            return ReachFix(self._fix[index], self._in_survey[index])
        return self.scans[index]

    def between_scans(self, t_s: float) -> None:
        return None  # one floor: nothing weighs the particles between scans

    def has_evidence_between_scans(self) -> bool:
        return False

    def observe(self, report: StepReport) -> None:
        return None

    def radio_map_model(self) -> RadioMapLikelihood:
        """The radio-map likelihood (needs a radio map): built once per radio map and shared with
        the other walks tracked with it; an AP's tables are built when a scan first hears it."""
        if self._radio_map_model is None:
            self._radio_map_model = radio_map_likelihood(self._radio_map, self._floorplan,
                                                         self._wifi.radio_map_likelihood,
                                                         heard_keys=self._pending_keys or None)
            self._pending_keys = set()
        return self._radio_map_model

    def best_cell_xy_m(self) -> np.ndarray:
        """(S, 2) the radio-map likelihood's best cell per scan (NaN: scan without a fix, or for
        the likelihood model without a known AP)."""
        if self._wifi.fingerprint_model == "blend":
            return np.array(self._best).reshape(-1, 2)
        model = self.radio_map_model()
        out = np.full((len(self.scans), 2), np.nan)
        kwnn = self.kwnn_xy_m
        for i, scan in enumerate(self.scans):
            if (self._usable[i] if kwnn is None else np.isfinite(kwnn[i]).all()):
                out[i] = model.best_position(scan)
        return out

    def position_fixes(self) -> list[np.ndarray]:
        """Position estimates per scan from each WiFi estimator at hand, each (S, 2), NaN where
        none: with a radio map the KWNN fixes (fix, blend) and the radio-map likelihood's best
        cell, with an access-point table the least-squares trilateration (3 APs or more)."""
        if self._radio_map is not None:
            return [f for f in (self.kwnn_xy_m, self.best_cell_xy_m()) if f is not None]
        table = self.access_points
        out = np.full((len(self.scans), 2), np.nan)
        for i, scan in enumerate(self.scans):
            if self._usable[i] and match_scan(table, scan)[0].size >= 3:
                out[i] = least_squares_position(table, scan)
        return [out]

    @property
    def access_points(self) -> AccessPointTable | None:
        """Trilateration: the access-point table as the model has it now (adapted during the walk
        with ``adapt_path_loss``); None for fingerprinting."""
        if isinstance(self.model, (TrilaterationLikelihood, AdaptiveTrilaterationLikelihood)):
            return self.model.ap_table
        return None


class NoWifiEvidence:
    """One floor without WiFi (``WalkEvidence``): a measurement source weighs the particles alone;
    every scan says nothing."""

    model = None
    access_points = None
    has_wifi = False

    def __init__(self, log_name: str = "the log") -> None:
        self.scans: list[WifiScan] = []
        self.log_name = log_name

    @property
    def usable(self) -> np.ndarray:
        return np.zeros(len(self.scans), dtype=bool)

    def prepare(self, scans: list[WifiScan]) -> None:
        return None

    def require_usable(self) -> None:
        return None

    def add_scans(self, scans: list[WifiScan]) -> None:
        self.scans.extend(scans)

    def measurement(self, index: int) -> None:
        return None

    def between_scans(self, t_s: float) -> None:
        return None

    def has_evidence_between_scans(self) -> bool:
        return False

    def observe(self, report: StepReport) -> None:
        return None


def _floor_map(radio_map: RadioMap, floor: int) -> RadioMap:
    """``radio_map.floor_map(floor)``, kept with the radio map: the radio-map likelihood built for
    it is then built once for every walk tracked with it."""
    memo = memo_of(radio_map)
    if ("floor", floor) not in memo:
        memo[("floor", floor)] = radio_map.floor_map(floor)
    return memo[("floor", floor)]


def _every_floor_on(radio_map: RadioMap, building, floor: int) -> tuple[RadioMap, DistanceGrid]:
    """Every floor's reference points in floor ``floor``'s frame, as one floor's radio map, and the
    3-D distance from each cell of that floor to the nearest of them (storeys apart by their
    elevations). Kept per radio map and building (the walks of an evaluation share them)."""
    memo = memo_of(radio_map)
    key = ("every floor", id(building), floor)
    if key in memo and memo[key][0] is building:
        return memo[key][1]
    floors = building.floors
    xy = np.zeros_like(radio_map.xy_m)
    for f, other in enumerate(floors):
        on = radio_map.floor == f
        xy[on] = floors[floor].from_building(other.to_building(radio_map.xy_m[on]))
    merged = dataclasses.replace(radio_map, xy_m=xy, floor=None, floor_names=None, floor_name=floors[floor].name,
                                 likelihood_tables={})
    elevation_m = np.array([f.elevation_m for f in floors])
    grid = distance_grid(np.column_stack([xy, elevation_m[radio_map.floor]]), floors[floor].plan.extent_m,
                         height_m=float(elevation_m[floor]))
    memo[key] = (building, (merged, grid))
    return merged, grid


def trilateration_model(ap_table: AccessPointTable, config: TrilaterationConfig = TrilaterationConfig()
                        ) -> MeasurementModel:
    """The path-loss likelihood, adaptive (Lund thesis ch. 7) when the config asks for adaptation or blocking."""
    if not (config.adapt_path_loss or config.blocking_compensation):
        return TrilaterationLikelihood(ap_table, variance_db2=config.rssi_variance_db2)
    return AdaptiveTrilaterationLikelihood(
        ap_table, variance_db2=config.rssi_variance_db2,
        adapt_rssi_limit_dbm=config.adapt_rssi_limit_dbm if config.adapt_path_loss else None,
        blocking_drop_db=config.blocking_drop_db if config.blocking_compensation else None)


def calibrated_fix_sigma_m(radio_map: RadioMap, k: int = 4, default_m: float = 5.0) -> float:
    """Fix sigma from the radio map's cross-validated KWNN errors: RMS / sqrt(2) (a 2-D Gaussian's
    E|d|^2 = 2 sigma^2), in [1, 50] m.

    ``default_m`` (Evennou & Marx's 5 m) when the map is too small to cross-validate.
    """
    errors = cross_validated_fix_errors(radio_map, k=k)
    if errors.size < 10:
        return default_m
    return float(np.clip(np.sqrt(np.mean(errors**2) / 2.0), 1.0, 50.0))


class BuildingEvidence:
    """A walk's scans as the multi-floor filter weighs them (``WalkEvidence``; a ``FloorFix`` per scan).

    Per floor, the fix of ``WifiEvidence`` made from every floor's fingerprints moved into that
    floor's frame (a scan's nearest fingerprints may lie a storey up or down: a floor nobody
    surveyed still gets the fix of the survey above or below it), weighed by each particle's 3-D
    distance to the survey (``filter.models.survey_reach``), moved into the stack frame; per scan,
    the floor vote of ``sensors.floor_vote.floor_vote_log_likelihood`` over the whole building's
    fingerprints. Scans come with ``add_scans``, the barometer's readings with
    ``add_pressure``.

    With a barometer, each scan, and each filter step between scans (``between_scans``), also
    weighs floors by height against a ``BarometerReference``: the scans so far weigh which floor
    its zero is on (each scan's match to each floor), ``observe`` follows the weather (and,
    without WiFi, the filter's floor), ``start_on`` takes a known start's floor.
    """

    def __init__(self, radio_map: RadioMap | None, stack: FloorStack, wifi: WifiConfig = WifiConfig(),
                 fix_sigma_by_floor_m: dict[str, float] | None = None, log_name: str = "the log",
                 use_barometer: bool = True, barometer: BarometerConfig = BarometerConfig(),
                 floor_evidence: np.ndarray | None = None):
        names = stack.building.floor_names
        if radio_map is not None:  # None: no WiFi (a measurement source alone), the barometer only
            check_building_radio_map(radio_map, names)
        self.scans: list[WifiScan] = []
        self.log_name = log_name
        self._radio_map, self._stack, self._wifi = radio_map, stack, wifi
        n_floors = len(names)
        self._fix: list[np.ndarray] = []  # per scan: (F, 2) stack positions
        self._floor_ll: list[np.ndarray] = []
        self._given_floor_ll = None if floor_evidence is None else np.asarray(floor_evidence, dtype=np.float64)
        # each floor's own evidence (None: its fingerprints share nothing with the walk)
        self.floor_wifi: list[WifiEvidence | None] = [None] * n_floors
        sigma = np.full(n_floors, 5.0)
        # per floor, the evidence of its own fingerprints too: their fix where they reach the scan
        self._own_floor: list[tuple[RadioMap, WifiEvidence] | None] = [None] * n_floors
        reach = None if radio_map is None else survey_reach(radio_map)  # one for every floor: all its points
        self._reach = reach
        # every reference point in the building's frame (the fix from every floor's points)
        self._points_in_building = None if radio_map is None else np.zeros_like(radio_map.xy_m)
        for f, floor in enumerate(stack.building.floors):
            if radio_map is not None:
                on = radio_map.floor == f
                self._points_in_building[on] = floor.to_building(radio_map.xy_m[on])
        for f, floor in enumerate(stack.building.floors):
            if radio_map is None:
                continue
            own_map = _floor_map(radio_map, f)
            if len(own_map) == 0:
                continue
            floor_config = wifi
            if fix_sigma_by_floor_m and floor.name in fix_sigma_by_floor_m:
                floor_config = dataclasses.replace(wifi, fix_sigma_m=fix_sigma_by_floor_m[floor.name])
            every_floor, grid = _every_floor_on(radio_map, stack.building, f)
            own = WifiEvidence(own_map, None, floor.plan, floor_config, log_name=log_name, reach=reach, grid=grid)
            if own.fix_sigma_m is None:
                raise MapfilterError("tracking across floors weighs fingerprint fixes: use the fingerprint "
                                     "model fix or blend")
            # every floor's fingerprints, the floor's own sigma: the floor's evidence (its fixes also
            # place the offline track), the floor's own fingerprints' fix where they reach the scan
            every_config = dataclasses.replace(floor_config, fix_sigma_m=own.fix_sigma_m)
            evidence = WifiEvidence(every_floor, None, floor.plan, every_config, log_name=log_name, reach=reach,
                                    grid=grid)
            self.floor_wifi[f] = evidence
            self._own_floor[f] = (own_map, own)
            sigma[f] = evidence.fix_sigma_m
        self.elevation_m = np.array([f.elevation_m for f in stack.building.floors])
        self.barometer = barometer
        self.use_barometer = use_barometer
        self._n_pressure_seen = 0
        self._heights = BarometricHeights()  # barometric_height of the readings so far
        self.reference = BarometerReference(self.elevation_m, barometer)
        self._in_survey: list[float] = []  # per scan: P(taken inside the survey)
        self._match_db: list[np.ndarray] = []  # per scan: (F,) its match distance to each floor
        self._n_weighed = 0  # scans the barometer's reference has weighed so far
        grids = None if radio_map is None else [None if e is None else e.model.grid for e in self.floor_wifi]
        self.model = FloorFixLikelihood(stack, sigma, grids)

    def prepare(self, scans: list[WifiScan]) -> None:
        """Build the per-floor radio-map tables of the APs the scans hear in one go (as ``WifiEvidence``)."""
        for evidence, own in zip(self.floor_wifi, self._own_floor):
            if evidence is not None and any(k in evidence._radio_map.key_index for s in scans for k in s.ap_keys):
                evidence.prepare(scans)
                own[1].prepare(scans)

    def require_usable(self) -> None:
        if self._radio_map is not None and not self.usable.any():
            raise MapfilterError(f"no WiFi scan of {self.log_name} gives a fingerprint fix with this radio map")

    def add_scans(self, scans: list[WifiScan]) -> None:
        if not scans:
            return
        first = len(self.scans)
        self.scans.extend(scans)
        n_floors = len(self.floor_wifi)
        fix = np.full((len(scans), n_floors, 2), np.nan)
        if self._radio_map is not None:
            # one matrix of signal distances for every floor: the fixes from every floor's points
            # (building frame), each floor's from its own, and each scan's match to each floor
            radio_map, floors = self._radio_map, self._stack.building.floors
            matrix = radio_map.scan_matrix(scans)
            plain = plain_signal_distances(radio_map, matrix)  # the floor vote's, and the fixes' fall-back
            every_xy, own_xy = kwnn_fixes_by_floor(radio_map, matrix, self._points_in_building, self._wifi.kwnn_k,
                                                   self._wifi.kwnn_min_rssi_dbm, plain)
            match = match_distance_by_floor_db(radio_map, matrix)
            reach = self._reach
            in_survey = reach.probability(match.min(axis=1, initial=np.inf))
            self._in_survey.extend(in_survey)
            self._match_db.extend(match)
            for f, evidence in enumerate(self.floor_wifi):
                if evidence is None:
                    continue
                # the floor's own fingerprints where they reach the scan (a surveyed route: as on one
                # floor), every floor's where they do not (a floor surveyed only above or below)
                own_reaches = reach.probability(match[:, f]) >= OWN_FLOOR_MIN_PROBABILITY
                evidence.add_scans(scans, floors[f].from_building(every_xy), in_survey)
                own = self._own_floor[f][1]
                own.add_scans(scans, own_xy[:, f], in_survey, wanted=own_reaches)
                fix[:, f] = self._stack.to_stack(np.where(own_reaches[:, None], own.fix_xy_m_since(first),
                                                          evidence.fix_xy_m_since(first)), f)
        self._fix.extend(fix)
        if self._given_floor_ll is not None:
            self._floor_ll.extend(self._given_floor_ll[first:first + len(scans)])
        elif self._radio_map is None:
            self._floor_ll.extend(np.zeros((len(scans), n_floors)))
        else:
            self._floor_ll.extend(floor_vote_log_likelihood(radio_map, matrix, k=self._wifi.kwnn_k, distances=plain))

    def add_pressure(self, t_s: np.ndarray, pressure_hpa: np.ndarray) -> None:
        """Barometer readings (in time order, after those already added)."""
        self._n_pressure_seen += len(t_s)
        if not self.use_barometer or len(t_s) == 0:
            return
        # each reading's height depends on the readings up to it only (windowed sums of a cumsum)
        self._heights.add(t_s, pressure_hpa)

    @property
    def has_wifi(self) -> bool:
        """False for the barometer alone (no radio map: a measurement source weighs the particles)."""
        return self._radio_map is not None

    @property
    def n_pressure(self) -> int:
        """Barometer readings added so far (those a log without a barometer or ``use_barometer`` off ignores count too)."""
        return self._n_pressure_seen

    @property
    def fix_xy_m(self) -> np.ndarray:
        """(S, F, 2) each scan's fix from each floor's fingerprints, stack frame (NaN: none)."""
        return np.array(self._fix).reshape(-1, len(self.floor_wifi), 2)

    @property
    def floor_log_likelihood(self) -> np.ndarray:
        return np.array(self._floor_ll).reshape(-1, len(self.floor_wifi))

    @property
    def usable(self) -> np.ndarray:
        return np.isfinite(self.fix_xy_m).all(axis=2).any(axis=1)

    @property
    def pressure(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The barometer readings so far (times, hPa), or None without a barometer."""
        if len(self._heights) < 2:
            return None
        return self._heights.t_s.copy(), self._heights.pressure_hpa.copy()

    def height_m(self, t_s: float) -> float:
        """The barometer's height at ``t_s`` (relative to its first sample), NaN without one."""
        if len(self._heights) < 2:
            return float("nan")
        # the last reading at or before t_s: nothing from the future
        i = int(np.searchsorted(self._heights.t_s, t_s, side="right")) - 1
        return float(self._heights.height_m[max(i, 0)])

    def observe(self, report: StepReport) -> None:
        """After each filter step: move the barometer's reference (``BarometerReference.update``);
        steady = less than ``STEADY_M`` of height change over ``STEADY_WINDOW_S``."""
        if len(self._heights) < 2 or report.floor_shares is None:
            return
        h = self.height_m(report.t_s)
        steady = abs(h - self.height_m(report.t_s - STEADY_WINDOW_S)) < STEADY_M
        self.reference.update(report.t_s, h, steady, report.floor_shares)

    def has_evidence_between_scans(self) -> bool:
        return self.use_barometer

    def start_on(self, floor: int) -> None:
        """The walk is known to start on ``floor`` (its first barometer reading's height)."""
        self.reference.start_on(floor, 0.0)

    def whole_walk_start_floor(self) -> int | None:
        """The floor every scan of the walk together puts its start on (the barometer's zero
        after weighing them all, at ``ANCHOR_SHARE`` or more; offline), None when they do not say."""
        if not self.use_barometer or len(self._heights) < 2:
            return None
        self._weigh_reference(len(self.scans) - 1)
        return self.reference.sure_floor_at(0.0)

    def restarted_on(self, floor: int) -> BuildingEvidence:
        """The same scans and barometer, its reference started on ``floor`` (a second run over the walk)."""
        again = copy.copy(self)
        again.reference = BarometerReference(self.elevation_m, self.barometer)
        again.reference.start_on(floor, 0.0)
        again._n_weighed = 0
        return again

    def _weigh_reference(self, last_index: int) -> None:
        """Let the barometer's reference weigh the scans up to ``last_index`` it has not yet, each
        at its own time's height: only scans the filter has reached (``measurement``), so a live
        run, whatever its chunks, weighs the same scans at every step as a whole log's."""
        if len(self._heights) < 2:
            return
        for i in range(self._n_weighed, min(last_index + 1, len(self._match_db))):
            self.reference.observe_scan(self.height_m(self.scans[i].t_s), self._match_db[i], self._in_survey[i])
        self._n_weighed = max(self._n_weighed, min(last_index + 1, len(self._match_db)))

    def between_scans(self, t_s: float) -> FloorFix | None:
        """The barometer alone at ``t_s`` (a step between scans): floors weighed by height as in
        ``measurement``, no position fix; None without a barometer or before a reference."""
        if len(self._heights) < 2:
            return None
        floor_ll = self.reference.floor_log_likelihood(self.height_m(t_s))
        if floor_ll is None:
            return None
        return FloorFix(np.full((len(self.elevation_m), 2), np.nan), floor_ll, int(np.argmax(floor_ll)))

    def measurement(self, index: int) -> FloorFix | None:
        """The scan ``index`` as a ``FloorFix`` (None when no floor gives it a fix)."""
        self._weigh_reference(index)
        fix = self._fix[index]
        if not np.isfinite(fix).all(axis=1).any():
            return None
        floor_ll = self._floor_ll[index]
        height_floor = None
        if len(self._heights) >= 2:
            height_ll = self.reference.floor_log_likelihood(self.height_m(self.scans[index].t_s))
            if height_ll is not None:
                floor_ll = floor_ll + height_ll
                height_floor = int(np.argmax(height_ll))
        return FloorFix(fix, floor_ll, height_floor, in_survey=self._in_survey[index] if self._in_survey else None)
