"""Errors against ground truth and the summary tables.

Error = horizontal distance from the estimate to the ground truth at the ground-truth
(waypoint) times. A causal method is judged by its latest estimate at or before each
waypoint time; waypoints before a method's first estimate are counted as ``missed`` and
left out of the statistics (reported, never hidden).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

SUMMARY_FIELDS = ("mean", "median", "p75", "p90", "ce95", "max", "rmse")
# the IPIN competitions' floor penalty: 15 m for each floor the estimate is off by (EvAAL
# framework; the IPIN 2023 Track 3 rules), added to the horizontal error before the 75th percentile
IPIN_FLOOR_PENALTY_M = 15.0


@dataclasses.dataclass
class WaypointErrors:
    """Per-waypoint errors of one track against one walk's ground truth."""

    errors_m: np.ndarray  # (W',) errors of the waypoints that had an estimate
    waypoint_index: np.ndarray  # (W',) which waypoints those are
    missed: int  # waypoints before the first estimate


def errors_at_waypoints(
    track_t_s: np.ndarray,
    track_xy_m: np.ndarray,
    waypoint_t_s: np.ndarray,
    waypoint_xy_m: np.ndarray,
    causal: bool = True,
) -> WaypointErrors:
    """Error of a track at every waypoint time.

    ``causal=True``: the latest estimate at or before the waypoint time (what a live system
    would have shown). ``causal=False`` (smoothed tracks): the track linearly interpolated
    at the waypoint time, clamped to its ends.
    """
    track_t = np.asarray(track_t_s, dtype=np.float64)
    track_xy = np.asarray(track_xy_m, dtype=np.float64).reshape(-1, 2)
    wp_t = np.asarray(waypoint_t_s, dtype=np.float64)
    wp_xy = np.asarray(waypoint_xy_m, dtype=np.float64).reshape(-1, 2)
    if track_t.size == 0:
        return WaypointErrors(np.zeros(0), np.zeros(0, dtype=np.int64), int(wp_t.size))
    if causal:
        latest = np.searchsorted(track_t, wp_t, side="right") - 1
        have = latest >= 0
        estimate = track_xy[latest[have]]
    else:
        have = np.ones(wp_t.shape, dtype=bool)
        estimate = np.column_stack([np.interp(wp_t, track_t, track_xy[:, 0]), np.interp(wp_t, track_t, track_xy[:, 1])])
    index = np.nonzero(have)[0]
    errors = np.linalg.norm(estimate - wp_xy[index], axis=1)
    return WaypointErrors(errors, index, int((~have).sum()))


def summarise_errors(errors_m: Sequence[float] | np.ndarray) -> dict[str, float]:
    """mean, median, p75 (the IPIN/EvAAL score), p90, CE95 (the 95th percentile, ISO/IEC 18305's
    circular error at 95 %), max and RMSE of errors (NaN when empty)."""
    errors = np.asarray(errors_m, dtype=np.float64)
    if errors.size == 0:
        return {name: math.nan for name in SUMMARY_FIELDS} | {"n": 0}
    return {
        "mean": float(errors.mean()),
        "median": float(np.median(errors)),
        "p75": float(np.percentile(errors, 75)),
        "p90": float(np.percentile(errors, 90)),
        "ce95": float(np.percentile(errors, 95)),
        "max": float(errors.max()),
        "rmse": float(np.sqrt(np.mean(errors**2))),
        "n": int(errors.size),
    }


def format_table(rows: list[dict], columns: Sequence[str], float_format: str = "{:.2f}") -> str:
    """A markdown table of ``rows`` (dicts) over ``columns``."""
    def cell(value) -> str:
        if isinstance(value, float):
            return "-" if math.isnan(value) else float_format.format(value)
        return str(value)

    lines = ["| " + " | ".join(columns) + " |", "|" + "|".join(" --- " for _ in columns) + "|"]
    lines += ["| " + " | ".join(cell(row.get(c, "")) for c in columns) + " |" for row in rows]
    return "\n".join(lines)


@dataclasses.dataclass
class FloorScore:
    """How often a track with a floor column is on the right floor at the waypoints."""

    n_right: int  # waypoints where the track's floor is the true one
    n_judged: int  # waypoints that had an estimate
    missed: int  # waypoints before the first estimate (left out, as for the errors)
    # (n_judged,) storeys between the track's floor and the true one at each judged waypoint, in
    # waypoint order (NaN where a floor is not in the building's order; None: no order given)
    storeys_off: np.ndarray | None = None

    @property
    def accuracy(self) -> float:
        """Share of the judged waypoints on the right floor (NaN with none judged)."""
        return self.n_right / self.n_judged if self.n_judged else math.nan


def floor_at_waypoints(track_t_s: np.ndarray, track_floor: Sequence[str], waypoint_t_s: np.ndarray,
                       true_floor: str | Sequence[str], causal: bool = True,
                       floor_order: Sequence[str] | None = None) -> FloorScore:
    """Is the track on the right floor at each waypoint time? ``true_floor``: one name for the
    whole walk (an ILC log's header) or one per waypoint. Causal: the latest row at or before
    the waypoint, as ``errors_at_waypoints``; else the nearest row in time (smoothed tracks).
    ``floor_order``: the building's floors bottom to top, to count the storeys a wrong floor is off by."""
    track_t = np.asarray(track_t_s, dtype=np.float64)
    wp_t = np.asarray(waypoint_t_s, dtype=np.float64)
    truth = [true_floor] * wp_t.size if isinstance(true_floor, str) else list(true_floor)
    if track_t.size == 0:
        return FloorScore(0, 0, int(wp_t.size), None if floor_order is None else np.zeros(0))
    if causal:
        row = np.searchsorted(track_t, wp_t, side="right") - 1
    else:
        after = np.clip(np.searchsorted(track_t, wp_t), 0, track_t.size - 1)
        before = np.clip(after - 1, 0, track_t.size - 1)
        row = np.where(np.abs(track_t[before] - wp_t) <= np.abs(track_t[after] - wp_t), before, after)
    have = row >= 0
    judged = np.flatnonzero(have)
    right = sum(1 for i in judged if track_floor[row[i]] == truth[i])
    storeys = None
    if floor_order is not None:
        level = {name: float(k) for k, name in enumerate(floor_order)}
        storeys = np.array([abs(level.get(track_floor[row[i]], math.nan) - level.get(truth[i], math.nan))
                            for i in judged], dtype=np.float64)
    return FloorScore(int(right), int(have.sum()), int((~have).sum()), storeys)


def availability(n_estimated: int, n_missed: int) -> float:
    """ISO/IEC 18305's availability at the ground-truth points: the share of them for which the
    method had an estimate (at or before the point, for a causal method); NaN without points."""
    total = n_estimated + n_missed
    return n_estimated / total if total else math.nan


def floor_detection(scores: Sequence[FloorScore]) -> float:
    """ISO/IEC 18305's floor detection probability: the share of all ground-truth points at which
    the estimate was on the right floor (a point without an estimate is not detected; the floor
    accuracy leaves those out); NaN without points."""
    total = sum(s.n_judged + s.missed for s in scores)
    return sum(s.n_right for s in scores) / total if total else math.nan


def ipin_errors_m(errors_m: np.ndarray, storeys_off: np.ndarray | None,
                  penalty_m: float = IPIN_FLOOR_PENALTY_M) -> np.ndarray:
    """Each waypoint's error as the IPIN competitions count it: the horizontal error plus
    ``penalty_m`` for each storey the estimate's floor is off by (``storeys_off``, the same
    waypoints in the same order; None: one floor, the horizontal error alone)."""
    errors = np.asarray(errors_m, dtype=np.float64)
    if storeys_off is None:
        return errors
    storeys = np.asarray(storeys_off, dtype=np.float64)
    if storeys.shape != errors.shape:
        raise ValueError("one storey count per error")
    return errors + penalty_m * storeys


def ipin_score(errors_m: np.ndarray, storeys_off: np.ndarray | None = None,
               penalty_m: float = IPIN_FLOOR_PENALTY_M) -> float:
    """The IPIN competitions' score (lower is better): the 75th percentile of each waypoint's
    horizontal error plus ``penalty_m`` per storey off (``ipin_errors_m``); NaN without waypoints."""
    errors = ipin_errors_m(errors_m, storeys_off, penalty_m)
    return float(np.percentile(errors, 75)) if errors.size else math.nan
