"""The ground-truth and finished-track layers: waypoints, the true path now, tracks and their errors."""

from __future__ import annotations

import math

import numpy as np

from mapfilter.viz.canvas import Canvas
from mapfilter.viz.style import (
    GT_COLOUR,
    GT_HEADING_MIN_MOVE_M,
    GT_HEADING_WINDOW_S,
    TRACK_COLOURS,
    Z_ESTIMATE,
    Z_GT,
    Z_TRACK,
    entity_name,
    interpolate_ground_truth,
)


def runs(on: np.ndarray) -> list[slice]:
    """The stretches of consecutive True rows of ``on`` (a track's rows on one floor)."""
    edges = np.flatnonzero(np.diff(np.concatenate([[False], np.asarray(on, dtype=bool), [False]]).astype(np.int8)))
    return [slice(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]


class GroundTruthLayer:
    """Draws ``map/world/ground_truth/{waypoints,path}`` (static) and ``.../now`` per step.

    ``draw(..., on=...)`` draws each waypoint under the root of its floor instead
    (``<root>/world/ground_truth/...``, a building seen whole: ``viz.building.FloorPlansLayer``).
    """

    def __init__(self, canvas: Canvas) -> None:
        self.canvas = canvas
        self.t_s = np.zeros(0)
        self.xy_m = np.zeros((0, 2))

    def __bool__(self) -> bool:
        return bool(self.t_s.size)

    def draw(self, t_s: np.ndarray, xy_m: np.ndarray, on: dict[str, np.ndarray] | None = None) -> None:
        """Log the ground-truth waypoints and the path through them (static).

        ``on``: entity root -> (W,) bool, the waypoints drawn under that root (the path through
        each stretch of consecutive ones); default: every waypoint under ``map``. All of them
        are the truth that errors are measured against.
        """
        rr = self.canvas.rr
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        if t.size != xy.shape[0]:
            raise ValueError(f"{t.size} ground-truth times but {xy.shape[0]} positions")
        order = np.argsort(t, kind="stable")
        self.t_s, self.xy_m = t[order], xy[order]
        if t.size == 0:
            return
        radius = -5.0 if t.size <= 50 else -2.5  # a simulated walk has a waypoint per step
        on = {"map": np.ones(t.size, dtype=bool)} if on is None else {r: np.asarray(m)[order] for r, m in on.items()}
        for root, mine in on.items():
            if not mine.any():
                continue
            labels = [f"wp{i}" for i in np.flatnonzero(mine)]
            self.canvas.log(f"{root}/world/ground_truth/waypoints",
                            rr.Points2D(self.xy_m[mine], radii=radius, colors=GT_COLOUR, labels=labels,
                                        show_labels=False, draw_order=Z_GT),
                            static=True)
            self.canvas.log(f"{root}/world/ground_truth/path",
                            rr.LineStrips2D([self.xy_m[r] for r in runs(mine)], radii=-1.0, colors=GT_COLOUR,
                                            draw_order=Z_GT), static=True)

    def at(self, t_s: np.ndarray) -> np.ndarray:
        return interpolate_ground_truth(self.t_s, self.xy_m, t_s)

    def heading_rad(self, t_s: float) -> float | None:
        """Direction of walking on the ground-truth path around ``t_s`` (None when standing or unknown).

        Points only (no line) in the plot: the interpolated path turns abruptly at waypoints.
        """
        if self.t_s.size < 2:
            return None
        half_s = 0.5 * GT_HEADING_WINDOW_S
        a, b = self.at(np.array([t_s - half_s, t_s + half_s]))
        delta = b - a
        if not np.all(np.isfinite(delta)) or np.hypot(*delta) < GT_HEADING_MIN_MOVE_M:
            return None
        return math.atan2(delta[1], delta[0])

    def draw_now(self, t_s: float, estimate_xy_m: np.ndarray, has_estimate: bool) -> float:
        """The true position at ``t_s`` and the line to the estimate; returns the error (NaN if unknown)."""
        rr = self.canvas.rr
        error_m = math.nan
        gt = self.at(np.array([t_s]))[0]
        gt_now = bool(np.all(np.isfinite(gt)))
        if gt_now and has_estimate:
            error_m = float(np.hypot(*(estimate_xy_m - gt)))
        self.canvas.show("map/world/ground_truth/now",
                         rr.Points2D([gt], colors=GT_COLOUR, radii=-6.0, draw_order=Z_GT) if gt_now else None)
        self.canvas.show("map/world/estimate/error",
                         rr.LineStrips2D([[estimate_xy_m, gt]], colors=(120, 120, 120), radii=-0.75, draw_order=Z_GT)
                         if math.isfinite(error_m) else None)
        return error_m


class TrackLayer:
    """Draws finished tracks under ``map/world/tracks/<name>`` (or, row by row, under the root of
    the floor each row is on: ``<root>/world/tracks/<name>``) and their errors under ``plots/error_m``."""

    def __init__(self, canvas: Canvas, truth: GroundTruthLayer) -> None:
        self.canvas = canvas
        self.truth = truth
        self._n_tracks = 0

    def draw(self, name: str, t_s: np.ndarray, xy_m: np.ndarray, on: dict[str, np.ndarray] | None = None) -> None:
        """Log a finished track: its path (static) and its position over ``trace_time``.

        ``on``: entity root -> (T,) bool, the rows drawn under that root (the path through each
        stretch of consecutive ones; the position shown there only while the track is on it);
        default: every row under ``map``.
        """
        rr = self.canvas.rr
        rec = self.canvas.rec
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        if t.size != xy.shape[0]:
            raise ValueError(f"{t.size} track times but {xy.shape[0]} positions")
        if t.size == 0:
            return
        entity = entity_name(name)
        colour = TRACK_COLOURS[self._n_tracks % len(TRACK_COLOURS)]
        self._n_tracks += 1
        for root, mine in ({"map": np.ones(t.size, dtype=bool)} if on is None else on).items():
            mine = np.asarray(mine, dtype=bool)
            if not mine.any():
                continue
            base = f"{root}/world/tracks/{entity}"
            rec.log(f"{base}/path", rr.LineStrips2D([xy[r] for r in runs(mine)], colors=colour, radii=-2.0,
                                                    labels=[name], draw_order=Z_TRACK),
                    static=True)
            # a row on another floor: no position here at that time (an empty batch clears it)
            positions = rr.Points2D.columns(positions=xy[mine])
            rec.send_columns(f"{base}/position", indexes=[self.canvas.time_column(t)],
                             columns=positions if mine.all() else positions.partition(mine.astype(np.int64)))
            rec.log(f"{base}/position", rr.Points2D.from_fields(colors=colour, radii=-5.0, draw_order=Z_ESTIMATE),
                    static=True)
        if self.truth:
            gt = self.truth.at(t)
            ok = np.all(np.isfinite(gt), axis=1)
            if ok.any():
                error = np.hypot(*(xy[ok] - gt[ok]).T)
                rec.log(f"plots/error_m/{entity}", rr.SeriesLines(colors=[colour], names=[name]), static=True)
                rec.send_columns(f"plots/error_m/{entity}", indexes=[self.canvas.time_column(t[ok])],
                                 columns=rr.Scalars.columns(scalars=error))
