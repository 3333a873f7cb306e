"""Where the survey reaches: a fingerprint fix weighed by how likely its scan was taken inside the
survey, and how far each particle is from it.

A KWNN fix can only land on a surveyed reference point. Inside the survey it errs by about the
fix's own scatter sigma; for a walker d metres from the nearest reference point it lands near the
survey's edge, d metres off or more, and a Gaussian around it pulls the cloud into surveyed space
however wrong that is (docs/accuracy.md, "Beyond the survey"). Two things tell the cases apart:

- the scan: a scan taken inside the survey matches some reference point about as well as the
  survey's own scans match each other. Its match distance (the RMS over the APs either side hears
  at -85 dBm or more, 3 shared APs at least) is ranked among the survey's own, each survey walk
  matched against the others: those of points within 3 m of another walk's (inside) and those of
  points over 10 m from every other walk's (outside). p, the share of inside matches at least as
  poor, and q, the share of outside matches at least as good, give w = p / (p + q), the
  probability that the scan was taken inside (equal priors; AUC 0.95 between walkers under 3 m
  and over 6 m from the survey on the IPIN 2023 logs);
- the particle: its distance d(x) to the nearest reference point (a 1 m grid over the floor).

The likelihood of the fix at a particle is a two-component mixture,

    p(fix | x) = w N(fix; x, sigma^2) + (1 - w) u(x) (sigma^2 / s^2) N(fix; x, s^2) (2 pi sigma^2),
    s^2 = sigma^2 + d(x)^2,  u(x) = 1 - exp(-d(x)^2 / (2 sigma^2)),

(the Gaussians scaled to peak 1 at the fix inside the survey): inside, the usual fix (Evennou &
Marx); outside, a fix off by about the distance to the survey, where u(x) keeps that component to
the particles away from the survey. A scan that matches the survey well (w near 1) weighs as
before; a poorly matching one flattens towards the steps and the walls where nobody surveyed,
instead of pulling the cloud into surveyed space.

Where the WiFi says little of the place, it can still bend the walk: the particles whose
heading follows the fixes' drift survive. With the rotation vector's heading h_rv at the scan
(PDR; ``filter.causal``), each particle's heading h_i is weighed too, as far as the scan is
outside the survey:

    + (1 - w) (cos(h_i - h_rv) - 1) / sigma_h^2

(a von Mises term of spread sigma_h: the rotation vector is biased by the building's steel, by
tens of degrees in places), so that the walk keeps its shape's direction where nobody surveyed.
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import numpy as np
from numba import njit

from mapfilter.filter.kernels.passes import HEADING, LIKELIHOOD_SIGNATURE, X, Y
from mapfilter.filter.models.interface import LikelihoodKernel, MeasurementModel
from mapfilter.sensors.radiomap import match_distance_db, survey_match_distances_db

__all__ = ["DistanceGrid", "ReachFix", "ReachFixLikelihood", "SurveyReach", "distance_grid", "heading_log_likelihood",
           "heading_term", "mixture_log_likelihood", "survey_reach"]

GRID_CELL_M = 1.0  # the distance-to-survey grid's cell
NO_COMPONENT = -1e300  # a mixture component that is absent (no infinities: the kernels use fastmath)
EMPTY_LOG_LIKELIHOOD = math.log(1e-300)  # neither component: as good as impossible
MIN_SURVEY_MATCHES = 10  # fewer inside or outside matches: the survey cannot tell, every matching scan counts as inside


@dataclasses.dataclass(frozen=True)
class DistanceGrid:
    """The distance (m) from each cell of a floor's extent to the nearest reference point."""

    origin_m: tuple[float, float]  # the lower-left corner of cell (0, 0)
    cell_m: float
    distance_m: np.ndarray  # (rows, cols), row 0 at the bottom (y up)

    def at(self, xy_m: np.ndarray) -> np.ndarray:
        """The distance to the survey at each point (the grid's edge value beyond it)."""
        xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        rows, cols = self.distance_m.shape
        col = np.clip(((xy[:, 0] - self.origin_m[0]) / self.cell_m).astype(np.int64), 0, cols - 1)
        row = np.clip(((xy[:, 1] - self.origin_m[1]) / self.cell_m).astype(np.int64), 0, rows - 1)
        return self.distance_m[row, col]


def distance_grid(reference_xyz_m: np.ndarray, extent_m: tuple[float, float, float, float], height_m: float = 0.0,
                  cell_m: float = GRID_CELL_M) -> DistanceGrid:
    """The distance-to-survey grid over ``extent_m`` (x0, x1, y0, y1) at ``height_m`` from reference
    points (P, 2) on this floor or (P, 3) with their heights (a building's points, storeys apart)."""
    x0, x1, y0, y1 = extent_m
    cols = max(math.ceil((x1 - x0) / cell_m), 1)
    rows = max(math.ceil((y1 - y0) / cell_m), 1)
    yy, xx = np.mgrid[0:rows, 0:cols]
    centres = np.column_stack([x0 + (xx.ravel() + 0.5) * cell_m, y0 + (yy.ravel() + 0.5) * cell_m])
    refs = np.asarray(reference_xyz_m, dtype=np.float64)
    if refs.ndim == 2 and refs.shape[1] == 3:
        centres = np.column_stack([centres, np.full(len(centres), float(height_m))])
    if len(refs):
        refs = np.ascontiguousarray(refs[np.argsort(refs[:, 0], kind="stable")])
        distance = _nearest_distances(np.ascontiguousarray(centres), refs)
    else:
        distance = np.full(len(centres), np.inf)
    return DistanceGrid((float(x0), float(y0)), float(cell_m), distance.reshape(rows, cols))


@njit(cache=True, nogil=True)
def _nearest_distances(centres, refs):
    """(C,) each centre's distance to the nearest of ``refs`` (sorted by x): a sweep out from the
    centre's x both ways that stops where the x distance alone exceeds the best so far. The
    squared distance is summed as scipy's cKDTree sums it (0, then each axis' square in order)
    and rooted at the end, so the numbers are cKDTree.query's to the last bit, without importing
    scipy.spatial for a walk (a tenth of a second)."""
    n_refs = refs.shape[0]
    dims = refs.shape[1]
    out = np.empty(centres.shape[0])
    for c in range(centres.shape[0]):
        cx = centres[c, 0]
        lo = 0
        hi = n_refs
        while lo < hi:  # the first ref with x >= cx
            mid = (lo + hi) // 2
            if refs[mid, 0] < cx:
                lo = mid + 1
            else:
                hi = mid
        best = math.inf
        for step in (1, -1):
            j = lo if step == 1 else lo - 1
            while 0 <= j < n_refs:
                dx = refs[j, 0] - cx
                if dx * dx > best:
                    break
                d2 = 0.0
                for k in range(dims):
                    d = centres[c, k] - refs[j, k]
                    d2 += d * d
                if d2 < best:
                    best = d2
                j += step
        out[c] = math.sqrt(best)
    return out


@dataclasses.dataclass(frozen=True, eq=False)
class SurveyReach:
    """What a radio map says about where its survey reaches: the match distances (sorted, dB) of
    scans taken inside it and outside it, and the radio map to match new scans against."""

    radio_map: object  # sensors.radiomap.RadioMap
    in_survey_match_db: np.ndarray
    outside_match_db: np.ndarray

    def in_survey_probability(self, scan_rssi_dbm: np.ndarray, against=None) -> np.ndarray:
        """(S,) each scan's probability of having been taken inside the survey, its match distance
        against the radio map (or ``against``, a part of it: one floor's points) ranked among the
        survey's own: p / (p + q), p the share of inside matches at least as poor, q the share of
        outside matches at least as good (equal priors). 0 for a scan that matches no reference
        point; 1 for every scan that matches where the survey shows fewer than ``MIN_SURVEY_MATCHES``
        inside or outside scans (a survey of one walk, or of routes that all overlap: it cannot
        tell, and the fix weighs as a plain Gaussian; the p-value alone flattened surveyed walks)."""
        return self.probability(match_distance_db(self.radio_map if against is None else against, scan_rssi_dbm))

    def probability(self, match_db: np.ndarray) -> np.ndarray:
        """``in_survey_probability`` of scans whose match distances (dB) are known already."""
        match = np.asarray(match_db, dtype=np.float64)
        matched = np.isfinite(match)
        inside, outside = self.in_survey_match_db, self.outside_match_db
        if inside.size < MIN_SURVEY_MATCHES:
            return np.where(matched, 1.0, 0.0)
        if outside.size < MIN_SURVEY_MATCHES:  # the survey shows no scan from outside: the plain fix
            return np.where(matched, 1.0, 0.0)
        p = (inside.size - np.searchsorted(inside, match, side="left") + 0.5) / (inside.size + 1.0)
        q = (np.searchsorted(outside, match, side="right") + 0.5) / (outside.size + 1.0)
        return np.where(matched, p / (p + q), 0.0)


def survey_reach(radio_map) -> SurveyReach:
    """The ``SurveyReach`` of a radio map (one floor's or a building's, its floors kept apart)."""
    return SurveyReach(radio_map, *survey_match_distances_db(radio_map))


@dataclasses.dataclass(frozen=True)
class ReachFix:
    """A fingerprint fix (world metres) with the probability that its scan was taken inside the survey."""

    xy_m: np.ndarray
    in_survey: float
    sigma_m: float | None = None  # overrides the model's sigma
    heading_rad: float = math.nan  # the rotation vector's heading at the scan (NaN: none; the module docstring)
    heading_sigma_rad: float = math.nan  # ... and its spread


def heading_term(in_survey: float | None, heading_rad: float, heading_sigma_rad: float) -> tuple[float, float]:
    """The module docstring's heading term as a kernel takes it: the rotation vector's heading
    and the weight (1 - w) / sigma_h^2; (0, 0) without a heading (or for a plain Gaussian fix:
    ``in_survey`` None)."""
    if in_survey is None or not (math.isfinite(heading_rad) and heading_sigma_rad > 0):
        return 0.0, 0.0
    return float(heading_rad), (1.0 - float(in_survey)) / (heading_sigma_rad * heading_sigma_rad)


@njit(cache=True, nogil=True, inline="always")
def heading_log_likelihood(heading_rad, rotation_vector_rad, weight):
    """A particle's heading term: weight * (cos(h_i - h_rv) - 1) (module docstring); 0 at weight 0."""
    if weight > 0.0:
        return weight * (math.cos(heading_rad - rotation_vector_rad) - 1.0)
    return 0.0


def mixture_log_likelihood(r2_m2: np.ndarray, d2_m2: np.ndarray, var_m2: np.ndarray | float,
                           in_survey: np.ndarray | float) -> np.ndarray:
    """log p(fix | x) of the module docstring from each particle's squared distance to the fix
    (r2), to the survey (d2), the fix variance sigma^2 and the scan's w (numpy; the kernel's twin).
    In log space: at w = 1 exactly the Gaussian's -r2 / (2 sigma^2), however far the particle."""
    w = np.broadcast_to(np.asarray(in_survey, dtype=np.float64), np.shape(r2_m2))
    spread = var_m2 + d2_m2
    with np.errstate(divide="ignore"):
        inside = np.where(w > 0, np.log(np.maximum(w, 1e-300)) - 0.5 * r2_m2 / var_m2, -np.inf)
        uncovered = -np.expm1(-0.5 * d2_m2 / var_m2)
        outside = np.where((w < 1) & (uncovered > 0), np.log(np.maximum(1.0 - w, 1e-300))
                           + np.log(np.maximum(uncovered, 1e-300)) + np.log(var_m2 / spread) - 0.5 * r2_m2 / spread,
                           -np.inf)
    both = np.logaddexp(inside, outside)
    return np.where(np.isfinite(both), both, EMPTY_LOG_LIKELIHOOD)


@njit(LIKELIHOOD_SIGNATURE, cache=True, nogil=True, fastmath=True)
def _reach_fix(params, state, lo, m, out):
    # params: fix x, fix y, sigma^2, w, the rotation vector's heading, the heading term's weight,
    # grid x0, y0, 1 / cell, rows, cols, then d^2 of every cell row by row
    fx = params[0]
    fy = params[1]
    var0 = params[2]
    w = params[3]
    heading = params[4]
    heading_weight = params[5]
    x0 = params[6]
    y0 = params[7]
    inv_cell = params[8]
    rows = int(params[9])
    cols = int(params[10])
    for j in range(m):
        x = state[X, lo + j]
        y = state[Y, lo + j]
        c = min(max(int((x - x0) * inv_cell), 0), cols - 1)
        r = min(max(int((y - y0) * inv_cell), 0), rows - 1)
        d2 = params[11 + r * cols + c]
        dx = x - fx
        dy = y - fy
        r2 = dx * dx + dy * dy
        # log(w N_in + (1 - w) u (sigma^2 / s^2) N_out), in log space (w = 1: the Gaussian exactly)
        inside = math.log(w) - 0.5 * r2 / var0 if w > 0.0 else NO_COMPONENT
        spread = var0 + d2
        uncovered = -math.expm1(-0.5 * d2 / var0)
        if w < 1.0 and uncovered > 0.0:
            outside = math.log(1.0 - w) + math.log(uncovered) + math.log(var0 / spread) - 0.5 * r2 / spread
        else:
            outside = NO_COMPONENT
        high = max(inside, outside)
        if high <= NO_COMPONENT:  # neither component (w = 0 inside the survey): as good as impossible
            out[j] = EMPTY_LOG_LIKELIHOOD
        else:
            out[j] = high + math.log(math.exp(inside - high) + math.exp(outside - high))
        out[j] += heading_log_likelihood(state[HEADING, lo + j], heading, heading_weight)


@dataclasses.dataclass(frozen=True, eq=False)
class ReachFixLikelihood(MeasurementModel):
    """A fingerprint fix weighed by its scan's in-survey probability and each particle's distance
    to the survey (the module docstring's mixture); peak 0 at the fix inside the survey."""

    sigma_m: float
    grid: DistanceGrid
    log_likelihood_peak: ClassVar[float] = 0.0

    def __post_init__(self) -> None:
        head = [self.grid.origin_m[0], self.grid.origin_m[1], 1.0 / self.grid.cell_m, *self.grid.distance_m.shape]
        object.__setattr__(self, "_grid_params", np.concatenate([head, (self.grid.distance_m ** 2).ravel()]))

    def fix_xy_m(self, measurement: ReachFix) -> np.ndarray:
        return np.asarray(measurement.xy_m, dtype=np.float64)

    def kernel(self, measurement: ReachFix) -> LikelihoodKernel:
        sigma = self.sigma_m if measurement.sigma_m is None else measurement.sigma_m
        if not (math.isfinite(sigma) and sigma > 0):
            raise ValueError(f"fix sigma must be a positive number of metres, got {sigma}")
        fx, fy = (float(v) for v in np.asarray(measurement.xy_m, dtype=np.float64).ravel()[:2])
        w = float(measurement.in_survey)
        heading, turn = heading_term(w, measurement.heading_rad, measurement.heading_sigma_rad)
        return LikelihoodKernel(_reach_fix, np.concatenate([[fx, fy, sigma * sigma, w, heading, turn],
                                                            self._grid_params]))
