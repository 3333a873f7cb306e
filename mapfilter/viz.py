"""Visual debugging with rerun: map, particles, wall kills, collapses, tracks and plots.

This is the only module of mapfilter that imports rerun, and it imports it lazily (inside the
logger), so ``import mapfilter.viz`` costs nothing when visualisation is off. The filter never
calls rerun: it returns a :class:`~mapfilter.filter.events.StepReport` per step and the caller
hands it to :meth:`RerunLogger.log_step`.

Coordinates
-----------
rerun's 2D views draw y pointing down (image convention); our world frame has y up. The map
view's origin is the entity ``map``; its child ``map/world`` carries one static
``Transform3D(scale=[1, -1, 1])`` and everything under ``map/world`` is logged in plain world
metres (x right, y up), so hovering a point in the viewer shows its true world coordinates.
Each image (the floor-plan picture, the wall mask) sits under its own parent entity whose
static transform maps pixel (u, v) (origin top-left, v down) to world metres:
``x = x0 + u * res``, ``y = y_top - v * res`` (translation ``(x0, y_top)``, scale
``(res, -res)``); composed with the flip above the image appears upright.

Timelines
---------
``trace_time``: the walk's own clock, a timestamp when the times look like Unix seconds
(>= 1e9, e.g. ILC traces), otherwise a duration (synthetic walks starting at 0); decided once,
by the first time seen. ``step``: the filter's step index (only on data logged by
:meth:`RerunLogger.log_step`). rerun's own ``log_time`` timeline (the wall clock at logging)
is switched off: it would only say how fast the filter ran, and its name is taken.

Entities (all under ``map/world`` are in world metres)
------------------------------------------------------
- ``map/world/floorplan/image`` source picture; ``map/world/walls/mask`` wall-mask overlay
  (semi-transparent; toggle its visibility in the viewer)
- ``map/world/ground_truth/{waypoints,path}`` (static), ``.../now`` (interpolated at each step)
- ``map/world/particles`` (weight-coloured, capped), ``map/world/killed`` (red old->new segments)
- ``map/world/estimate/{position,spread,error}``, ``map/world/estimate/trail/...``
- ``map/world/measurement/{fix,aps}``
- ``map/world/events/{collapses,recoveries,jumps}``
- ``map/world/tracks/<name>/{path,position}``
- ``plots/particles/{ess,alive,resampled}``, ``plots/kills``, ``plots/error_m/<name>``,
  ``plots/pdr/step_length_m``, ``plots/pdr/heading_deg/{filter,ground_truth}``
- ``events`` (text log: collapses and recoveries as WARN, resampling as DEBUG)
"""

from __future__ import annotations

import contextlib
import math
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mapfilter.atomic import atomic_paths
from mapfilter.errors import MapfilterError

if TYPE_CHECKING:  # pragma: no cover
    from mapfilter.filter.events import CollapseEvent, StepReport
    from mapfilter.floorplan import FloorPlan
    from mapfilter.logs.recording import Recording
    from mapfilter.trackio import Track

DEFAULT_MAX_PARTICLES = 5000
# A trail of the estimate is logged in finished pieces of this many steps plus the growing
# piece, so the data logged per step stays bounded (re-logging the whole trail each step
# would be quadratic in the walk length).
TRAIL_PIECE_STEPS = 100
# Ground-truth walking direction: over this window, and only if the walker moved this far in it.
_GT_HEADING_WINDOW_S = 1.0
_GT_HEADING_MIN_MOVE_M = 0.3
# Times at or above this are taken as Unix seconds (2001-09-09 onwards).
_UNIX_TIME_MIN_S = 1.0e9
# Particle colours: relative weight w / w_max shown over this many decades (log scale).
_WEIGHT_DECADES = 3.0

# Viridis anchor colours (dark purple = low weight, yellow = high weight).
_RAMP = np.array(
    [[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], dtype=np.float64
)
# finished tracks: none orange (the live estimate), green (ground truth), red or magenta (events)
_TRACK_COLOURS = [(31, 119, 180), (148, 103, 189), (23, 190, 207), (188, 189, 34), (140, 86, 75), (127, 127, 127)]
_RED = (230, 40, 40)
_BACKGROUND = (235, 235, 235)  # the map view's background, also under transparent plan pixels
_GT_COLOUR = (40, 200, 40)
_RECOVERY_COLOUR = (220, 0, 220)
_ESTIMATE_COLOUR = (255, 140, 0)

# Draw orders: pictures at the bottom, then paths, particles, the estimate, event markers on top.
# The ground truth (thin) lies over the tracks (wider), so both stay visible where they agree.
_Z_IMAGE, _Z_MASK, _Z_TRACK, _Z_GT, _Z_PARTICLES, _Z_KILLED, _Z_MEAS, _Z_ESTIMATE, _Z_EVENTS = (
    -20.0, -10.0, 5.0, 6.0, 10.0, 12.0, 15.0, 20.0, 30.0,
)


# ---- pure helpers (no rerun) ------------------------------------------------------------------
def weight_faithful_subsample(weight: np.ndarray, max_points: int) -> np.ndarray:
    """Indices of at most ``max_points`` particles whose density follows the weights.

    With no more live particles than ``max_points`` every particle of non-zero weight is
    kept. Otherwise ``max_points`` indices are drawn by systematic resampling with a fixed
    offset of one half (deterministic, no random draw) and duplicates are merged, so a heavy
    particle shows once and the spatial density of the shown points follows the posterior.

    Parameters
    ----------
    weight : (N,) non-negative weights (need not be normalised; NaN counts as zero).
    max_points : cap on the number of indices returned (>= 1).

    Returns
    -------
    (M,) int64 sorted unique indices, ``M <= max_points``; empty when no weight is positive.
    """
    if max_points < 1:
        raise ValueError(f"max_points must be at least 1, got {max_points}")
    w = np.nan_to_num(np.asarray(weight, dtype=np.float64), nan=0.0, posinf=0.0)
    w = np.where(w > 0.0, w, 0.0)
    alive = np.flatnonzero(w)
    if alive.size <= max_points:
        return alive.astype(np.int64)
    cumulative = np.cumsum(w[alive])
    cumulative /= cumulative[-1]
    cumulative[-1] = 1.0  # avoid round-off: the last bin must catch the last position
    positions = (np.arange(max_points) + 0.5) / max_points
    picks = np.searchsorted(cumulative, positions, side="left")
    return alive[np.unique(picks)].astype(np.int64)


def weight_colours(weight: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 colours: viridis over log10(w / w_max), spanning ``_WEIGHT_DECADES`` decades."""
    w = np.asarray(weight, dtype=np.float64)
    if w.size == 0:
        return np.zeros((0, 3), dtype=np.uint8)
    w_max = float(np.max(w))
    if not w_max > 0.0:
        return np.tile(_RAMP[0].astype(np.uint8), (w.size, 1))
    with np.errstate(divide="ignore"):
        level = 1.0 + np.log10(np.maximum(w, 0.0) / w_max) / _WEIGHT_DECADES
    level = np.clip(np.nan_to_num(level, nan=0.0, neginf=0.0), 0.0, 1.0) * (len(_RAMP) - 1)
    lower = np.minimum(level.astype(np.int64), len(_RAMP) - 2)
    frac = (level - lower)[:, None]
    rgb = _RAMP[lower] * (1.0 - frac) + _RAMP[lower + 1] * frac
    return np.round(rgb).astype(np.uint8)


def circle_xy(centre_xy: np.ndarray, radius: float, n_vertices: int = 48) -> np.ndarray:
    """(n_vertices + 1, 2) closed polyline of a circle."""
    angle = np.linspace(0.0, 2.0 * math.pi, n_vertices + 1)
    return np.column_stack([centre_xy[0] + radius * np.cos(angle), centre_xy[1] + radius * np.sin(angle)])


def interpolate_ground_truth(wp_t_s: np.ndarray, wp_xy_m: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """Ground-truth positions at ``t_s`` by linear interpolation between waypoints.

    The walker went roughly straight between waypoints (ILC README). Times outside the
    waypoints' time span get NaN: no extrapolation.
    """
    t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
    out = np.full((t.size, 2), np.nan)
    if wp_t_s.size == 0:
        return out
    inside = (t >= wp_t_s[0]) & (t <= wp_t_s[-1])
    out[inside, 0] = np.interp(t[inside], wp_t_s, wp_xy_m[:, 0])
    out[inside, 1] = np.interp(t[inside], wp_t_s, wp_xy_m[:, 1])
    return out


def _entity_name(name: str) -> str:
    """A track name as one entity-path part (rerun paths split on '/', and spaces need escaping)."""
    cleaned = re.sub(r"[^A-Za-z0-9_.\-]+", "_", name).strip("_")
    return cleaned or "track"


def _wrap_deg(angle_rad: float) -> float:
    return (math.degrees(angle_rad) + 180.0) % 360.0 - 180.0


# ---- loggers ----------------------------------------------------------------------------------
class NullLogger:
    """The logger used when visualisation is off: every method does nothing."""

    enabled = False

    def log_map(self) -> None:
        pass

    def log_ground_truth(self, t_s: np.ndarray, xy_m: np.ndarray) -> None:
        pass

    def log_step(self, report: StepReport) -> None:
        pass

    def log_track(self, name: str, t_s: np.ndarray, xy_m: np.ndarray) -> None:
        pass

    def close(self) -> None:
        pass

    def abort(self) -> None:
        pass

    def __enter__(self) -> NullLogger:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        pass


class RerunLogger:
    """Draws a FloorPlan, filter steps and finished tracks into one rerun recording.

    Parameters
    ----------
    floorplan : the map everything is drawn on.
    rrd_path : write the recording to this ``.rrd`` file (atomically: it appears on
        :meth:`close`; :meth:`abort` or an exception in a ``with`` block leaves nothing).
    spawn : open a rerun viewer and stream to it instead (never in tests: with no display
        it blocks for seconds and drops data).
    max_particles : cap on the particles drawn per step (weight-faithful subsample, see
        :func:`weight_faithful_subsample`); the killed moves drawn per step share this cap.
    application_id : rerun application id (the viewer groups recordings by it).
    recording_name : shown in the viewer's recording list.
    filter_plots : lay out the filter's plots (particles, kills, PDR, events); off for
        looking at finished tracks only, which leaves the map and the error plot.

    Exactly one of ``rrd_path`` and ``spawn`` must be given. Call :meth:`log_map` first
    (:func:`make_logger` does), then :meth:`log_ground_truth` if there is ground truth, then
    :meth:`log_step` per filter step and :meth:`log_track` for finished tracks.
    """

    enabled = True

    def __init__(
        self,
        floorplan: FloorPlan,
        rrd_path: str | os.PathLike | None = None,
        spawn: bool = False,
        max_particles: int = DEFAULT_MAX_PARTICLES,
        application_id: str = "mapfilter",
        recording_name: str | None = None,
        filter_plots: bool = True,
    ) -> None:
        import rerun as rr  # lazy: only a live logger pays for importing rerun

        if (rrd_path is None) == (not spawn):
            raise ValueError("give exactly one of rrd_path and spawn=True")
        if max_particles < 1:
            raise MapfilterError(f"the particle cap must be at least 1, got {max_particles}")
        self._rr = rr
        self.floorplan = floorplan
        self.max_particles = int(max_particles)
        self.filter_plots = filter_plots
        self._time_is_unix: bool | None = None
        self._gt_t_s = np.zeros(0)
        self._gt_xy_m = np.zeros((0, 2))
        self._shown: set[str] = set()  # temporal entities currently showing something
        self._trail_xy: list[tuple[float, float]] = []
        self._trail_pieces = 0
        self._collapse_xy: list[tuple[float, float]] = []
        self._recovery_xy: list[tuple[float, float]] = []
        self._collapse_labels: list[str] = []
        self._n_tracks = 0
        self._picture: np.ndarray | None = None
        self._closed = False
        self._stack = contextlib.ExitStack()

        self.rec = rr.RecordingStream(application_id)
        self.rec.set_log_time_enabled(False)  # our clock is the walk's: see the module docstring
        if recording_name:
            self.rec.send_recording_name(recording_name)
        blueprint = self.blueprint()
        self.rrd_path: Path | None = None if rrd_path is None else Path(rrd_path)
        try:
            if self.rrd_path is not None:
                (tmp,) = self._stack.enter_context(atomic_paths(self.rrd_path))
                self.rec.save(tmp, default_blueprint=blueprint)
            else:
                self.rec.spawn(default_blueprint=blueprint)
            self._log_styles()
        except BaseException:
            self.abort()  # leave no temporary file behind
            raise

    # ---- layout ---------------------------------------------------------------------------
    def blueprint(self) -> Any:
        """The default layout: the map large on the left; plots and the event log beside it."""
        import rerun.blueprint as rrb

        x_min, x_max, y_min, y_max = self.floorplan.extent_m
        if self.floorplan.source_image is not None:
            sx_min, sx_max, sy_min, sy_max = self._source_extent_m()
            x_min, x_max = min(x_min, sx_min), max(x_max, sx_max)
            y_min, y_max = min(y_min, sy_min), max(y_max, sy_max)
        map_view = rrb.Spatial2DView(
            name="Floor",
            origin="map",
            # view coordinates are (x, -y): see the module docstring
            visual_bounds=rrb.VisualBounds2D(x_range=[x_min, x_max], y_range=[-y_max, -y_min]),
            background=rrb.Background(color=_BACKGROUND),
        )
        error_view = rrb.TimeSeriesView(name="Position error (m)", origin="plots/error_m")
        if not self.filter_plots:
            return rrb.Blueprint(
                rrb.Horizontal(map_view, error_view, column_shares=[3, 1]),
                rrb.TimePanel(timeline="trace_time", state="expanded"),
                collapse_panels=True,
            )
        plots = rrb.Vertical(
            rrb.TimeSeriesView(name="Particles: ESS, alive", origin="plots/particles"),
            rrb.TimeSeriesView(name="Killed by walls per step", origin="plots/kills"),
            error_view,
            rrb.Tabs(
                rrb.TimeSeriesView(name="PDR heading (deg)", origin="plots/pdr/heading_deg"),
                rrb.TimeSeriesView(name="PDR step length (m)", origin="plots/pdr/step_length_m"),
            ),
            rrb.TextLogView(name="Events", origin="events"),
            row_shares=[1, 1, 1, 1, 1.2],
        )
        return rrb.Blueprint(
            rrb.Horizontal(map_view, plots, column_shares=[3, 2]),
            rrb.TimePanel(timeline="trace_time", state="expanded"),
            collapse_panels=True,
        )

    def _log_styles(self) -> None:
        rr = self._rr
        log = self.rec.log
        # the flip that lets everything below map/world be logged in y-up metres
        log("map/world", rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
        if not self.filter_plots:
            return
        log("plots/particles/ess", rr.SeriesLines(colors=[(31, 119, 180)], names=["ESS"], widths=[1.5]), static=True)
        log("plots/particles/alive", rr.SeriesLines(colors=[(44, 160, 44)], names=["alive"], widths=[1.5]), static=True)
        log(
            "plots/particles/resampled",
            rr.SeriesPoints(colors=[(214, 39, 40)], names=["resampled (ESS before)"], markers=["cross"],
                            marker_sizes=[3.0]),
            static=True,
        )
        log("plots/error_m/filter", rr.SeriesLines(colors=[_ESTIMATE_COLOUR], names=["filter"], widths=[1.5]),
            static=True)
        log("plots/kills", rr.SeriesLines(colors=[_RED], names=["killed by walls"], widths=[1.5]), static=True)
        log("plots/pdr/step_length_m", rr.SeriesLines(colors=[(148, 103, 189)], names=["step length (m)"]), static=True)
        log("plots/pdr/heading_deg/filter", rr.SeriesLines(colors=[_ESTIMATE_COLOUR], names=["filter"]), static=True)
        log("plots/pdr/heading_deg/ground_truth",
            rr.SeriesPoints(colors=[_GT_COLOUR], names=["walking direction (ground truth)"], marker_sizes=[1.5]),
            static=True)

    # ---- time -----------------------------------------------------------------------------
    def _set_time(self, t_s: float, step: int | None = None) -> None:
        if self._time_is_unix is None:
            self._time_is_unix = t_s >= _UNIX_TIME_MIN_S
        if self._time_is_unix:
            self.rec.set_time("trace_time", timestamp=float(t_s))
        else:
            self.rec.set_time("trace_time", duration=float(t_s))
        if step is not None:
            self.rec.set_time("step", sequence=int(step))

    def _time_column(self, t_s: np.ndarray) -> Any:
        if self._time_is_unix is None:
            self._time_is_unix = bool(t_s.size) and float(t_s[0]) >= _UNIX_TIME_MIN_S
        kind = "timestamp" if self._time_is_unix else "duration"
        return self._rr.TimeColumn("trace_time", **{kind: np.asarray(t_s, dtype=np.float64)})

    # ---- map ------------------------------------------------------------------------------
    def _source_extent_m(self) -> tuple[float, float, float, float]:
        source = self.floorplan.source_image
        height, width = self._source_picture().shape[:2]
        x0, y0 = source.origin_m
        return x0, x0 + width * source.resolution_m, y0, y0 + height * source.resolution_m

    def _source_picture(self) -> np.ndarray:
        """The floor-plan picture as OpenCV reads it (read once)."""
        import cv2

        if self._picture is None:
            source = self.floorplan.source_image
            if not Path(source.path).is_file():
                raise MapfilterError("file not found", source.path)
            self._picture = cv2.imread(str(source.path), cv2.IMREAD_UNCHANGED)
            if self._picture is None:
                raise MapfilterError("not a readable image", source.path)
        return self._picture

    def _image_transform(self, height_px: int, resolution_m: float, origin_m: tuple[float, float]) -> Any:
        # pixel (u, v) -> world (x0 + u res, y_top - v res): rows grow downwards, world y upwards
        y_top = origin_m[1] + height_px * resolution_m
        return self._rr.Transform3D(
            translation=[origin_m[0], y_top, 0.0], scale=[resolution_m, -resolution_m, 1.0]
        )

    def log_map(self) -> None:
        """Log the floor-plan picture (if any) and the wall mask overlay, both static."""
        import cv2

        rr = self._rr
        fp = self.floorplan
        source = fp.source_image
        if source is not None:
            image = self._source_picture()
            self.rec.log("map/world/floorplan",
                         self._image_transform(image.shape[0], source.resolution_m, source.origin_m), static=True)
            # rerun 0.41 draws transparent image pixels with their RGB (black in ILC plans), so
            # flatten onto the view's background colour; PNG-encode to keep the recording small
            ok, png = cv2.imencode(".png", _flatten_bgr(image, _BACKGROUND))
            if not ok:
                raise MapfilterError("could not re-encode the floor-plan picture", source.path)
            self.rec.log("map/world/floorplan/image",
                         rr.EncodedImage(contents=png.tobytes(), media_type="image/png", draw_order=_Z_IMAGE),
                         static=True)
        self.rec.log("map/world/walls", self._image_transform(fp.shape_px[0], fp.resolution_m, fp.origin_m),
                     static=True)
        self.rec.log(
            "map/world/walls",
            rr.AnnotationContext([
                rr.AnnotationInfo(id=0, label="free", color=(0, 0, 0, 0)),
                rr.AnnotationInfo(id=1, label="wall", color=(200, 30, 30, 255)),
            ]),
            static=True,
        )
        # with a picture underneath the mask is a light overlay; alone it is the map itself
        opacity = 0.35 if source is not None else 0.8
        self.rec.log("map/world/walls/mask",
                     rr.SegmentationImage(fp.wall_mask.astype(np.uint8), opacity=opacity, draw_order=_Z_MASK),
                     static=True)

    # ---- ground truth ---------------------------------------------------------------------
    def log_ground_truth(self, t_s: np.ndarray, xy_m: np.ndarray) -> None:
        """Log the ground-truth waypoints and the path through them (static).

        Later steps and tracks are compared with the path interpolated at their times
        (``plots/error_m/...``); times outside the waypoints' span get no error value.
        """
        rr = self._rr
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        if t.size != xy.shape[0]:
            raise ValueError(f"{t.size} ground-truth times but {xy.shape[0]} positions")
        order = np.argsort(t, kind="stable")
        self._gt_t_s, self._gt_xy_m = t[order], xy[order]
        if t.size == 0:
            return
        labels = [f"wp{i}" for i in range(t.size)]
        radius = -5.0 if t.size <= 50 else -2.5  # a simulated walk has a waypoint per step
        self.rec.log("map/world/ground_truth/waypoints",
                     rr.Points2D(self._gt_xy_m, radii=radius, colors=_GT_COLOUR, labels=labels, show_labels=False,
                                 draw_order=_Z_GT),
                     static=True)
        self.rec.log("map/world/ground_truth/path",
                     rr.LineStrips2D([self._gt_xy_m], radii=-1.0, colors=_GT_COLOUR, draw_order=_Z_GT),
                     static=True)

    def _ground_truth_at(self, t_s: np.ndarray) -> np.ndarray:
        return interpolate_ground_truth(self._gt_t_s, self._gt_xy_m, t_s)

    def _ground_truth_heading_rad(self, t_s: float) -> float | None:
        """Direction of walking on the ground-truth path around ``t_s`` (None when standing or unknown).

        Points only (no line) in the plot: the interpolated path turns abruptly at waypoints.
        """
        if self._gt_t_s.size < 2:
            return None
        half_s = 0.5 * _GT_HEADING_WINDOW_S
        a, b = self._ground_truth_at(np.array([t_s - half_s, t_s + half_s]))
        delta = b - a
        if not np.all(np.isfinite(delta)) or np.hypot(*delta) < _GT_HEADING_MIN_MOVE_M:
            return None
        return math.atan2(delta[1], delta[0])

    # ---- one filter step ------------------------------------------------------------------
    def _show(self, path: str, archetype: Any | None) -> None:
        """Log ``archetype`` at ``path``, or clear ``path`` if it showed something before."""
        if archetype is not None:
            self.rec.log(path, archetype)
            self._shown.add(path)
        elif path in self._shown:
            self.rec.log(path, self._rr.Clear(recursive=False))
            self._shown.discard(path)

    def log_step(self, report: StepReport) -> None:
        """Draw one filter step on both timelines (``trace_time`` and ``step``)."""
        rr = self._rr
        log = self.rec.log
        self._set_time(report.t_s, report.step_index)

        # particles: weight-faithful subsample, coloured by weight
        xy = np.asarray(report.particles_xy_m, dtype=np.float64).reshape(-1, 2)
        weight = np.asarray(report.particles_weight, dtype=np.float64).reshape(-1)
        keep = weight_faithful_subsample(weight, self.max_particles)
        log("map/world/particles",
            rr.Points2D(xy[keep], colors=weight_colours(weight[keep]), radii=-2.0, draw_order=_Z_PARTICLES))

        # moves the wall check rejected, old -> new, strided down to the cap
        killed_from = np.asarray(report.killed_from_xy_m, dtype=np.float64).reshape(-1, 2)
        killed_to = np.asarray(report.killed_to_xy_m, dtype=np.float64).reshape(-1, 2)
        segments = None
        if killed_from.shape[0]:
            stride = max(1, math.ceil(killed_from.shape[0] / self.max_particles))
            strips = np.stack([killed_from[::stride], killed_to[::stride]], axis=1)
            segments = rr.LineStrips2D(strips, colors=_RED, radii=-1.0, draw_order=_Z_KILLED)
        self._show("map/world/killed", segments)

        # the estimate, its spread, and the trail so far
        # (a filter with no live particle may report a NaN estimate: show nothing then)
        est = np.asarray(report.estimate_xy_m, dtype=np.float64).reshape(2)
        std = float(report.estimate_std_m)
        has_estimate = bool(np.all(np.isfinite(est)))
        self._show("map/world/estimate/position",
                   rr.Points2D([est], colors=_ESTIMATE_COLOUR, radii=-6.0, draw_order=_Z_ESTIMATE)
                   if has_estimate else None)
        spread = None
        if has_estimate and math.isfinite(std) and std > 0.0:
            spread = rr.LineStrips2D([circle_xy(est, std)], colors=_ESTIMATE_COLOUR, radii=-1.0,
                                     draw_order=_Z_ESTIMATE)
        self._show("map/world/estimate/spread", spread)
        if has_estimate:
            self._extend_trail(est)

        # the measurement of this step
        fix = None
        if report.fix_xy_m is not None:
            fix = rr.Points2D(np.asarray(report.fix_xy_m, dtype=np.float64).reshape(-1, 2), colors=(0, 120, 255),
                              radii=-5.0, labels=["WiFi fix"], draw_order=_Z_MEAS)
        self._show("map/world/measurement/fix", fix)
        aps = None
        if report.heard_ap_xy_m is not None and len(report.heard_ap_xy_m):
            aps = rr.Points2D(np.asarray(report.heard_ap_xy_m, dtype=np.float64).reshape(-1, 2),
                              colors=(0, 180, 255), radii=-4.0, draw_order=_Z_MEAS)
        self._show("map/world/measurement/aps", aps)

        # ground truth now, and the error
        error_m = math.nan
        if self._gt_t_s.size:
            gt = self._ground_truth_at(np.array([report.t_s]))[0]
            gt_now = bool(np.all(np.isfinite(gt)))
            if gt_now and has_estimate:
                error_m = float(np.hypot(*(est - gt)))
            self._show("map/world/ground_truth/now",
                       rr.Points2D([gt], colors=_GT_COLOUR, radii=-6.0, draw_order=_Z_GT) if gt_now else None)
            self._show("map/world/estimate/error",
                       rr.LineStrips2D([[est, gt]], colors=(120, 120, 120), radii=-0.75, draw_order=_Z_GT)
                       if math.isfinite(error_m) else None)

        # plots
        log("plots/particles/ess", rr.Scalars(float(report.ess)))
        log("plots/particles/alive", rr.Scalars(float(report.n_alive)))
        log("plots/kills", rr.Scalars(float(report.n_killed)))
        if math.isfinite(error_m):
            log("plots/error_m/filter", rr.Scalars(error_m))
        if report.step_length_m is not None:
            log("plots/pdr/step_length_m", rr.Scalars(float(report.step_length_m)))
        if report.heading_rad is not None:
            log("plots/pdr/heading_deg/filter", rr.Scalars(_wrap_deg(float(report.heading_rad))))
            true_heading = self._ground_truth_heading_rad(report.t_s)
            if true_heading is not None:
                log("plots/pdr/heading_deg/ground_truth", rr.Scalars(_wrap_deg(true_heading)))

        # events
        if report.resampled:
            log("plots/particles/resampled", rr.Scalars(float(report.ess)))
            log("events", rr.TextLog(
                f"step {report.step_index}: resampled (ESS {report.ess:.0f} of {report.n_particles})",
                level=rr.TextLogLevel.DEBUG))
        if report.collapse is not None:
            self._log_collapse(report.collapse)

    def _extend_trail(self, xy: np.ndarray) -> None:
        rr = self._rr
        self._trail_xy.append((float(xy[0]), float(xy[1])))
        strip = rr.LineStrips2D([self._trail_xy], colors=_ESTIMATE_COLOUR, radii=-1.5, draw_order=_Z_TRACK)
        self.rec.log("map/world/estimate/trail/current", strip)
        if len(self._trail_xy) > TRAIL_PIECE_STEPS:
            # freeze this piece under its own entity (visible from now on) and restart the
            # growing piece at its last point so the trail stays connected
            self.rec.log(f"map/world/estimate/trail/piece{self._trail_pieces:05d}", strip)
            self._trail_pieces += 1
            self._trail_xy = self._trail_xy[-1:]

    def _log_collapse(self, event: CollapseEvent) -> None:
        rr = self._rr
        k = len(self._collapse_xy) + 1
        self._collapse_xy.append(tuple(map(float, event.xy_m)))
        self._recovery_xy.append(tuple(map(float, event.recovered_xy_m)))
        self._collapse_labels.append(f"collapse {k}")
        self.rec.log("events", rr.TextLog(
            f"step {event.step_index}: collapse {k} ({event.cause}): {event.particles_lost} particles lost "
            f"near ({event.xy_m[0]:.1f}, {event.xy_m[1]:.1f}) m",
            level=rr.TextLogLevel.WARN))
        self.rec.log("events", rr.TextLog(
            f"step {event.step_index}: recovery {k} ({event.recovery}) at "
            f"({event.recovered_xy_m[0]:.1f}, {event.recovered_xy_m[1]:.1f}) m",
            level=rr.TextLogLevel.WARN))
        # all markers so far, re-logged: collapses are rare, and latest-at shows the whole list
        collapse = np.array(self._collapse_xy)
        recovery = np.array(self._recovery_xy)
        self.rec.log("map/world/events/collapses",
                     rr.Points2D(collapse, colors=_RED, radii=-8.0, labels=self._collapse_labels, draw_order=_Z_EVENTS))
        self.rec.log("map/world/events/recoveries",
                     rr.Points2D(recovery, colors=_RECOVERY_COLOUR, radii=-6.0, draw_order=_Z_EVENTS))
        self.rec.log("map/world/events/jumps",
                     rr.Arrows2D(origins=collapse, vectors=recovery - collapse, colors=_RECOVERY_COLOUR, radii=-1.0,
                                 draw_order=_Z_EVENTS))

    # ---- finished tracks ------------------------------------------------------------------
    def log_track(self, name: str, t_s: np.ndarray, xy_m: np.ndarray) -> None:
        """Log a finished track: its path (static) and its position over ``trace_time``.

        With ground truth logged before, its error over time goes to ``plots/error_m/<name>``.
        """
        rr = self._rr
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        if t.size != xy.shape[0]:
            raise ValueError(f"{t.size} track times but {xy.shape[0]} positions")
        if t.size == 0:
            return
        entity = _entity_name(name)
        colour = _TRACK_COLOURS[self._n_tracks % len(_TRACK_COLOURS)]
        self._n_tracks += 1
        base = f"map/world/tracks/{entity}"
        self.rec.log(f"{base}/path", rr.LineStrips2D([xy], colors=colour, radii=-2.0, labels=[name],
                                                     draw_order=_Z_TRACK), static=True)
        time_column = self._time_column(t)
        self.rec.send_columns(f"{base}/position", indexes=[time_column], columns=rr.Points2D.columns(positions=xy))
        self.rec.log(f"{base}/position", rr.Points2D.from_fields(colors=colour, radii=-5.0, draw_order=_Z_ESTIMATE),
                     static=True)
        if self._gt_t_s.size:
            gt = self._ground_truth_at(t)
            ok = np.all(np.isfinite(gt), axis=1)
            if ok.any():
                error = np.hypot(*(xy[ok] - gt[ok]).T)
                self.rec.log(f"plots/error_m/{entity}", rr.SeriesLines(colors=[colour], names=[name]), static=True)
                self.rec.send_columns(f"plots/error_m/{entity}", indexes=[self._time_column(t[ok])],
                                      columns=rr.Scalars.columns(scalars=error))

    # ---- end ------------------------------------------------------------------------------
    def close(self) -> None:
        """Flush and finish the recording; the ``.rrd`` file (if any) appears now."""
        if self._closed:
            return
        self._closed = True
        self.rec.flush()
        self.rec.disconnect()
        self._stack.close()

    def abort(self) -> None:
        """Finish without keeping the ``.rrd`` file (e.g. the run failed)."""
        if self._closed:
            return
        self._closed = True
        self.rec.disconnect()
        self._stack.__exit__(RuntimeError, RuntimeError("aborted"), None)

    def __enter__(self) -> RerunLogger:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def _flatten_bgr(image: np.ndarray, background_rgb: tuple[int, int, int]) -> np.ndarray:
    """An OpenCV image (grey, BGR or BGRA, any depth) as 8-bit BGR, alpha blended onto a colour."""
    import cv2

    if image.dtype != np.uint8:
        image = cv2.convertScaleAbs(image, alpha=255.0 / max(float(image.max()), 1.0))
    if image.ndim == 2:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    if image.shape[2] == 4:
        alpha = image[..., 3:4].astype(np.float32) / 255.0
        background = np.array(background_rgb[::-1], dtype=np.float32)
        return np.round(image[..., :3] * alpha + background * (1.0 - alpha)).astype(np.uint8)
    return image[..., :3]


def make_logger(
    floorplan: FloorPlan,
    rrd_path: str | os.PathLike | None = None,
    spawn: bool = False,
    max_particles: int = DEFAULT_MAX_PARTICLES,
    recording_name: str | None = None,
    filter_plots: bool = True,
) -> RerunLogger | NullLogger:
    """A :class:`RerunLogger` with the map already logged, or a :class:`NullLogger`.

    Parameters
    ----------
    floorplan : the map.
    rrd_path : write a ``.rrd`` file here (appears on ``close()``).
    spawn : stream to a newly spawned viewer instead.
    max_particles : cap on particles drawn per step (default 5,000).
    recording_name : name shown in the viewer (e.g. the trace's name).
    filter_plots : lay out the filter's plots (off when only showing finished tracks).

    Returns a NullLogger (no rerun import) when neither ``rrd_path`` nor ``spawn`` is given.
    Giving both is an error (one sink per run).
    """
    if rrd_path is None and not spawn:
        return NullLogger()
    if rrd_path is not None and spawn:
        raise MapfilterError("give either an .rrd file to write or spawn a viewer, not both")
    logger = RerunLogger(floorplan, rrd_path=rrd_path, spawn=spawn, max_particles=max_particles,
                         recording_name=recording_name, filter_plots=filter_plots)
    try:
        logger.log_map()
    except BaseException:
        logger.abort()
        raise
    return logger


def view_map(
    floorplan: FloorPlan,
    tracks: Sequence[Track] = (),
    recording: Recording | None = None,
    rrd_path: str | os.PathLike | None = None,
    spawn: bool = False,
    recording_name: str | None = None,
) -> None:
    """Show a map, finished tracks and a recording's ground truth (no filtering).

    Parameters
    ----------
    floorplan : the map.
    tracks : finished tracks (:class:`mapfilter.trackio.Track`), each drawn under
        ``map/world/tracks/<name>`` (names made unique).
    recording : a walk whose waypoints are drawn as ground truth (if it has any); tracks
        then get an error plot against them.
    rrd_path, spawn : where to send the recording (exactly one).
    recording_name : name shown in the viewer.
    """
    if rrd_path is None and not spawn:
        raise MapfilterError("give an .rrd file to write or spawn a viewer")
    logger = make_logger(floorplan, rrd_path=rrd_path, spawn=spawn, recording_name=recording_name,
                         filter_plots=False)
    with logger:
        if recording is not None and recording.has_ground_truth:
            logger.log_ground_truth(recording.waypoint_t_s, recording.waypoint_xy_m)
        used: dict[str, int] = {}
        for track in tracks:
            name = track.name
            if name in used:  # two files with the same stem: keep both
                used[name] += 1
                name = f"{name}_{used[name]}"
            else:
                used[name] = 1
            logger.log_track(name, track.t_s, track.xy_m)
