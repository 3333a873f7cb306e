"""The rerun recorder: one recording stream, its layout, and the layers that draw into it.

:class:`RerunLogger` owns the stream (an ``.rrd`` file written atomically, or a spawned
viewer) and hands each call to the layer that draws it: :class:`~mapfilter.viz.map.MapLayer`,
:class:`~mapfilter.viz.particles.ParticleLayer`, :class:`~mapfilter.viz.plots.PlotLayer`,
:class:`~mapfilter.viz.events.EventLayer` and the ground-truth and track layers
(:mod:`mapfilter.viz.tracks`). :class:`NullLogger` does nothing, for runs without a viewer.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sys
import threading
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mapfilter.io.atomic import atomic_paths
from mapfilter.io.live import GrowingFile
from mapfilter.errors import MapfilterError
from mapfilter.viz.canvas import Canvas
from mapfilter.viz.events import EventLayer
from mapfilter.viz.map import MapLayer
from mapfilter.viz.particles import ParticleLayer
from mapfilter.viz.plots import PlotLayer
from mapfilter.viz.style import BACKGROUND, DEFAULT_MAX_PARTICLES
from mapfilter.viz.tracks import GroundTruthLayer, TrackLayer

if TYPE_CHECKING:  # pragma: no cover
    from mapfilter.filter.events import StepReport
    from mapfilter.maps.building import Building
    from mapfilter.maps.floorplan import FloorPlan
    from mapfilter.sensors.recording import Recording
    from mapfilter.io.tracks import Track


# How long closing waits for a spawned viewer to take the last data, in slices short enough that
# Ctrl-C and SIGTERM are handled between them (a flush without a timeout never returns when
# the viewer cannot draw, and no signal handler runs while it waits).
VIEWER_FLUSH_LIMIT_S = 20.0
VIEWER_FLUSH_SLICE_S = 0.25


# rerun writes an .rrd file from a thread of its own. On a full disk that thread stops, and a
# ``save`` that is waiting for it then never returns (rerun 0.41: about half the tries on a full
# file system) while SIGTERM and Ctrl-C wait behind it: every call that writes the file runs
# with this deadline.
RECORDING_WRITE_LIMIT_S = 10.0


class WriterHung(MapfilterError):
    """A rerun call that writes the recording did not return in time (``bounded_write``)."""


def bounded_write(call: Callable[[], Any], path: Path | None, limit_s: float | None = None) -> Any:
    """``call()`` (a rerun call that writes the recording file) within ``limit_s`` (default
    ``RECORDING_WRITE_LIMIT_S``): its result, or ``MapfilterError`` naming ``path`` when it
    fails or does not return in time (a full disk). A call that never returns is left to its
    thread, and rerun's exit handler, which would wait for it too, is dropped."""
    import rerun as rr

    limit_s = RECORDING_WRITE_LIMIT_S if limit_s is None else limit_s
    outcome: list = []

    def run() -> None:
        try:
            outcome.append((True, call()))
        except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread
            outcome.append((False, exc))

    worker = threading.Thread(target=run, name="mapfilter-rrd-write", daemon=True)
    worker.start()
    deadline = time.monotonic() + limit_s
    while worker.is_alive() and time.monotonic() < deadline:
        worker.join(VIEWER_FLUSH_SLICE_S)  # in slices: Ctrl-C and SIGTERM are handled between them
    if worker.is_alive():
        rr.unregister_shutdown()  # at exit it would flush the stream that hangs
        raise WriterHung(f"could not write the recording (rerun's file writer did not answer in {limit_s:g} s): is "
                         "the disk full?", path)
    ok, value = outcome[0]
    if ok:
        return value
    if isinstance(value, RuntimeError):
        # "File-writer thread shut down prematurely", "Failed to write: No space left on device"
        raise MapfilterError(f"could not write the recording ({value}): is the disk full?", path) from None
    raise value


def viewer_executable() -> str | None:
    """The rerun viewer's executable: on PATH, or beside this Python (a virtual environment
    that was not activated); None when it is not installed."""
    found = shutil.which("rerun")
    if found:
        return found
    beside = os.path.join(os.path.dirname(sys.executable), "rerun")
    return beside if os.access(beside, os.X_OK) else None


def viewer_problem() -> str | None:
    """Why no rerun viewer can start here, or None when one can: no viewer executable, or (on
    Linux and the BSDs) no display to open a window on. Nothing is spawned to find out: a
    viewer spawned without a display blocks for seconds and its caller can hang."""
    if viewer_executable() is None:
        return "the rerun viewer is not installed (no `rerun` on PATH)"
    if sys.platform.startswith(("linux", "freebsd", "openbsd", "netbsd")) and not (
            os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return "no display (DISPLAY and WAYLAND_DISPLAY are unset)"
    return None


def flush_bounded(rec: Any, limit_s: float | None = None, slice_s: float = VIEWER_FLUSH_SLICE_S) -> bool:
    """Flush a recording stream within ``limit_s`` (default ``VIEWER_FLUSH_LIMIT_S``), in slices
    of ``slice_s`` so that signal handlers run between them; True when everything was sent."""
    deadline = time.monotonic() + (VIEWER_FLUSH_LIMIT_S if limit_s is None else limit_s)
    while True:
        try:
            rec.flush(timeout_sec=slice_s)
            return True
        except RuntimeError:  # "Flush timed out - not all log messages were sent"
            if time.monotonic() >= deadline:
                return False


class NullLogger:
    """The logger used when visualisation is off: every method does nothing."""

    enabled = False

    def log_map(self) -> None:
        pass

    def log_ground_truth(self, t_s: np.ndarray, xy_m: np.ndarray, floor: Sequence[str] | None = None) -> None:
        pass

    def log_step(self, report: StepReport) -> None:
        pass

    def log_track(self, name: str, t_s: np.ndarray, xy_m: np.ndarray, floor: Sequence[str] | None = None) -> None:
        pass

    def log_smoothed(self, t_s: float, xy_m: np.ndarray, weight: np.ndarray) -> None:
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
    growing : with ``rrd_path``, a live run's recording (``io.live.GrowingFile``): the file is
        in place from the first filter step on and grows as the run goes; an abort after that
        keeps what was drawn (flushed), one before it leaves nothing.
    spawn : open a rerun viewer and stream to it instead (never in tests: with no display
        it blocks for seconds and drops data; :func:`viewer_problem` says whether one can start).
    max_particles : cap on the particles drawn per step (weight-faithful subsample, see
        :func:`weight_faithful_subsample`); the killed moves drawn per step share this cap.
    application_id : rerun application id (the viewer groups recordings by it).
    recording_name : shown in the viewer's recording list.
    filter_plots : lay out the filter's plots (particles, kills, PDR, events); off for
        looking at finished tracks only, which leaves the map and the error plot.
    stack : a building's ``filter.floors.FloorStack`` when the filter runs across floors: the
        current floor's plan is drawn (again at each floor change), steps are drawn in that
        floor's frame, and a plot shows the weight on each floor (``viz.building``).
    building : a building with several floors whose finished tracks are shown (``view_map``):
        every floor's plan at once, each in its own view under ``floors/<floor>``
        (``viz.building.FloorPlansLayer``); tracks and ground truth are then logged with the floor
        of each row (instead of ``floorplan``, unused; no filter steps).
    warn : where a spawned viewer that did not take the last data is reported (one line;
        default: a Python warning).

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
        stack: Any = None,
        building: Any = None,
        warn: Callable[[str], None] | None = None,
        growing: bool = False,
    ) -> None:
        # rerun's own log lines (a full disk's ERROR and WARN) would come before the run's one line
        # that says what happened; a RUST_LOG the user set wins
        os.environ.setdefault("RUST_LOG", "off")
        import rerun as rr  # lazy: only a live logger pays for importing rerun

        if (rrd_path is None) == (not spawn):
            raise ValueError("give exactly one of rrd_path and spawn=True")
        if max_particles < 1:
            raise MapfilterError(f"the particle cap must be at least 1, got {max_particles}")
        self.floorplan = floorplan
        self.max_particles = int(max_particles)
        self.filter_plots = filter_plots
        self._closed = False
        self._stack = contextlib.ExitStack()
        self._spawned = spawn
        self._hung = False  # a call that writes the file did not return: no more calls into the stream
        self._warn = warn
        self._growing = GrowingFile(rrd_path) if growing and rrd_path is not None else None
        self.rrd_path: Path | None = None if rrd_path is None else Path(rrd_path)

        self.rec = rr.RecordingStream(application_id)
        self.rec.set_log_time_enabled(False)  # our clock is the walk's: see the package docstring
        if recording_name:
            self.rec.send_recording_name(recording_name)
        self.canvas = Canvas(rr, self.rec)
        self._add_layers(floorplan, stack, building)
        self._steps_drawn: list[tuple[float, int, int]] = []  # (t_s, step index, floor shown) of each step
        blueprint = self.blueprint()
        try:
            self._start_output(rr, blueprint)
            # the flip that lets everything below map/world be logged in y-up metres
            if self.plans is None:
                self.canvas.log("map/world", rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
            if self.filter_plots:
                self.plots.style()
            if self.floors is not None:
                self.floors.style()
        except BaseException:
            self.abort()  # leave no temporary file behind
            raise

    def _add_layers(self, floorplan: FloorPlan, stack: Any, building: Any) -> None:
        """What the recording draws: map, particles, plots, events, truth and tracks; the floors of
        a ``stack`` the filter runs across; the floor plans of a ``building``'s finished tracks."""
        canvas = self.canvas
        self.map = MapLayer(canvas, floorplan)
        self.particles = ParticleLayer(canvas, self.max_particles)
        self.plots = PlotLayer(canvas)
        self.events = EventLayer(canvas)
        self.truth = GroundTruthLayer(canvas)
        self.tracks = TrackLayer(canvas, self.truth)
        self.floors = None
        if stack is not None:
            from mapfilter.viz.building import FloorLayer

            self.floors = FloorLayer(canvas, stack)
        self.plans = None
        if building is not None:
            from mapfilter.viz.building import FloorPlansLayer

            self.plans = FloorPlansLayer(canvas, building)

    def _start_output(self, rr, blueprint: Any) -> None:
        """Where the recording goes: a live run's growing file, a .rrd that appears on close, or a
        viewer spawned now (refused in one line where none can start). A save runs under
        ``_write``'s deadline: on a full disk rerun's writer stops and the save never returns."""
        if self._growing is not None:
            file = self._growing.create()
            self._write(lambda: self.rec.save(file, default_blueprint=blueprint))
        elif self.rrd_path is not None:
            (tmp,) = self._stack.enter_context(atomic_paths(self.rrd_path))
            self._write(lambda: self.rec.save(tmp, default_blueprint=blueprint))
        else:
            problem = viewer_problem()
            if problem is not None:
                raise MapfilterError(f"no rerun viewer can start here: {problem}")
            rr.spawn(default_blueprint=blueprint, executable_path=viewer_executable(), recording=self.rec)

    # ---- layout ---------------------------------------------------------------------------
    def blueprint(self) -> Any:
        """The default layout: the map large on the left; plots and the event log beside it."""
        import rerun.blueprint as rrb

        if self.plans is not None:  # a building's finished tracks: a view per floor
            return rrb.Blueprint(
                rrb.Horizontal(rrb.Grid(*self.plans.views()),
                               rrb.TimeSeriesView(name="Position error (m)", origin="plots/error_m"),
                               column_shares=[3, 1]),
                rrb.TimePanel(timeline="trace_time", state="expanded"),
                collapse_panels=True,
            )
        x_min, x_max, y_min, y_max = (self.floors or self.map).extent_m()
        map_view = rrb.Spatial2DView(
            name="Floor",
            origin="map",
            # view coordinates are (x, -y): see the module docstring
            visual_bounds=rrb.VisualBounds2D(x_range=[x_min, x_max], y_range=[-y_max, -y_min]),
            background=rrb.Background(color=BACKGROUND),
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
                rrb.TimeSeriesView(name="Blocking H (dB)", origin="plots/path_loss/blocking_H_db"),
                rrb.TimeSeriesView(name="Nearest AP's C (dBm)", origin="plots/path_loss/nearest_C_dbm"),
                *([rrb.TimeSeriesView(name="Weight per floor", origin="plots/floors")] if self.floors else []),
            ),
            rrb.TextLogView(name="Events", origin="events"),
            row_shares=[1, 1, 1, 1, 1.2],
        )
        return rrb.Blueprint(
            rrb.Horizontal(map_view, plots, column_shares=[3, 2]),
            rrb.TimePanel(timeline="trace_time", state="expanded"),
            collapse_panels=True,
        )

    # ---- what callers draw -----------------------------------------------------------------
    def log_map(self) -> None:
        """Log the floor-plan picture (if any) and the wall mask overlay, both static (a
        building's floors are drawn as they become current, see ``viz.building``; a building
        seen whole draws every floor)."""
        if self.plans is not None:
            self.plans.draw()
        elif self.floors is None:
            self.map.draw()

    def log_ground_truth(self, t_s: np.ndarray, xy_m: np.ndarray, floor: Sequence[str] | None = None) -> None:
        """Log the ground-truth waypoints and the path through them (static).

        Later steps and tracks are compared with the path interpolated at their times
        (``plots/error_m/...``); times outside the waypoints' span get no error value.
        ``floor``: a building seen whole: each waypoint's floor (drawn on that floor's plan).
        """
        self.truth.draw(t_s, xy_m, on=self._on(floor, len(t_s)))

    def log_step(self, report: StepReport) -> None:
        """Draw one filter step on both timelines (``trace_time`` and ``step``)."""
        self.canvas.set_time(report.t_s, report.step_index)
        self._steps_drawn.append((float(report.t_s), int(report.step_index), int(report.floor_index or 0)))
        if self.floors is not None:
            report = self.floors.draw(report)  # the current floor's plan and frame
        estimate_xy_m, has_estimate = self.particles.draw(report)
        error_m = self.truth.draw_now(report.t_s, estimate_xy_m, has_estimate) if self.truth else float("nan")
        true_heading = self.truth.heading_rad(report.t_s) if report.heading_rad is not None else None
        self.plots.draw(report, error_m, true_heading)
        self.events.draw(report)
        if self._growing is not None and not self._growing.published:
            self._flush()  # the map and the first step in the file before it is in place
            self._growing.publish()

    def log_smoothed(self, t_s: float, xy_m: np.ndarray, weight: np.ndarray) -> None:
        """The smoother's cloud at a step already drawn (``pipeline.tracker.Tracker.result``'s ``on_smoothed``;
        a building's stack frame: the particles on the floor shown at that step)."""
        if not self._steps_drawn:
            return
        times = [t for t, _, _ in self._steps_drawn]
        _, step, floor = self._steps_drawn[max(int(np.searchsorted(times, t_s, side="right")) - 1, 0)]
        self.canvas.set_time(t_s, step)
        xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        weight = np.asarray(weight, dtype=np.float64).reshape(-1)
        if self.floors is not None:
            xy, on = self.floors.stack.to_floor(xy)
            xy, weight = xy[on == floor], weight[on == floor]
        self.particles.draw_smoothed(xy, weight)

    def log_track(self, name: str, t_s: np.ndarray, xy_m: np.ndarray, floor: Sequence[str] | None = None) -> None:
        """Log a finished track: its path (static) and its position over ``trace_time``.

        With ground truth logged before, its error over time goes to ``plots/error_m/<name>``.
        ``floor``: a building seen whole: each row's floor (drawn on that floor's plan).
        """
        self.tracks.draw(name, t_s, xy_m, on=self._on(floor, len(t_s)))

    def _on(self, floor: Sequence[str] | None, n_rows: int) -> dict[str, np.ndarray] | None:
        """Which rows go on which floor's plan (None: all on the one map)."""
        if self.plans is None:
            return None
        if floor is None or len(floor) != n_rows:
            raise ValueError("a building seen whole needs the floor of every row")
        return self.plans.on(list(floor))

    # ---- end ------------------------------------------------------------------------------
    def close(self) -> None:
        """Flush and finish the recording; the ``.rrd`` file (if any) appears now."""
        if self._closed:
            return
        if self._spawned:
            if not flush_bounded(self.rec):
                message = (f"the rerun viewer did not take the last data in {VIEWER_FLUSH_LIMIT_S:g} s: closed "
                           "without it (write a recording with --rerun FILE.rrd instead)")
                (self._warn or (lambda text: warnings.warn(text, stacklevel=2)))(message)
            self._closed = True
            self.rec.disconnect()
            self._stack.close()
            return
        self._flush()
        try:
            self._write(self.rec.disconnect)  # the file's last bytes
        except MapfilterError:
            self.abort()
            raise
        self._closed = True
        if self._growing is not None:
            self._growing.publish()
        self._stack.close()

    def _flush(self) -> None:
        """Everything logged so far into the file, within the deadline (``bounded_write``); on
        failure (a full disk) the run is aborted: no temporary file is left."""
        try:
            self._write(self.rec.flush)
        except MapfilterError:
            self.abort()  # remove the temporary
            raise

    def _write(self, call: Callable[[], Any]) -> None:
        """A rerun call that writes the file, bounded (``bounded_write``); after one hung, none."""
        if self._hung:
            raise WriterHung("could not write the recording: is the disk full?", self.rrd_path)
        try:
            bounded_write(call, self.rrd_path)
        except WriterHung:
            self._hung = True
            raise

    def abort(self) -> None:
        """Finish without keeping the ``.rrd`` file (e.g. the run failed)."""
        if self._closed:
            return
        self._closed = True
        if self._growing is not None and self._growing.published:
            with contextlib.suppress(MapfilterError):  # a live run's recording keeps what was drawn
                self._write(self.rec.flush)
        with contextlib.suppress(MapfilterError):
            self._write(self.rec.disconnect)
        if self._growing is not None:
            self._growing.discard()  # only when it was never in place
        self._stack.__exit__(RuntimeError, RuntimeError("aborted"), None)

    def __enter__(self) -> RerunLogger:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def make_logger(
    floorplan: FloorPlan,
    rrd_path: str | os.PathLike | None = None,
    spawn: bool = False,
    max_particles: int = DEFAULT_MAX_PARTICLES,
    recording_name: str | None = None,
    filter_plots: bool = True,
    stack: Any = None,
    building: Any = None,
    warn: Callable[[str], None] | None = None,
    growing: bool = False,
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
    stack : a building's ``FloorStack`` when the filter runs across floors (``RerunLogger``).
    building : a several-floor building whose finished tracks are shown (``RerunLogger``).
    warn : where a spawned viewer that did not take the last data is reported (``RerunLogger``).
    growing : a live run's ``.rrd``: in place from the first step on, growing (``RerunLogger``).

    Returns a NullLogger (no rerun import) when neither ``rrd_path`` nor ``spawn`` is given.
    Giving both is an error (one sink per run).
    """
    if rrd_path is None and not spawn:
        return NullLogger()
    if rrd_path is not None and spawn:
        raise MapfilterError("give either an .rrd file to write or spawn a viewer, not both")
    logger = RerunLogger(floorplan, rrd_path=rrd_path, spawn=spawn, max_particles=max_particles,
                         recording_name=recording_name, filter_plots=filter_plots, stack=stack,
                         building=building, warn=warn, growing=growing)
    try:
        logger.log_map()
    except BaseException:
        logger.abort()
        raise
    return logger


def view_map(
    floorplan: FloorPlan | Building,
    tracks: Sequence[Track] = (),
    recording: Recording | None = None,
    rrd_path: str | os.PathLike | None = None,
    spawn: bool = False,
    recording_name: str | None = None,
    truth_floor: str | Sequence[str] | None = None,
    warn: Callable[[str], None] | None = None,
) -> None:
    """Show a map, finished tracks and a recording's ground truth (no filtering).

    Parameters
    ----------
    floorplan : the map; or a building with several floors: every floor is drawn in its own
        view (``floors/<floor>/...``), each track row on the plan of its floor (``Track.floor``,
        which every track then needs) and the ground truth on ``truth_floor``.
    tracks : finished tracks (:class:`mapfilter.io.tracks.Track`), each drawn under
        ``map/world/tracks/<name>`` (names made unique).
    recording : a walk whose waypoints are drawn as ground truth (if it has any); tracks
        then get an error plot against them.
    rrd_path, spawn : where to send the recording (exactly one).
    recording_name : name shown in the viewer.
    truth_floor : a building: the floor of the waypoints, one name or one per waypoint; None
        leaves the ground truth out (its floor unknown).
    warn : where a spawned viewer that did not take the last data is reported.
    """
    if rrd_path is None and not spawn:
        raise MapfilterError("give an .rrd file to write or spawn a viewer")
    building = floorplan if hasattr(floorplan, "floors") and len(floorplan.floors) > 1 else None
    if building is not None:
        for track in tracks:
            if track.floor is None or len(track.floor) != len(track):
                raise MapfilterError(f"track {track.name!r} has no floor for every row: a building needs one")
        plan = building.floors[0].plan
    else:
        plan = floorplan.floors[0].plan if hasattr(floorplan, "floors") else floorplan
    logger = make_logger(plan, rrd_path=rrd_path, spawn=spawn, recording_name=recording_name,
                         filter_plots=False, building=building, warn=warn)
    with logger:
        if recording is not None and recording.has_ground_truth:
            if building is None:
                logger.log_ground_truth(recording.waypoint_t_s, recording.waypoint_xy_m)
            elif truth_floor is not None:
                n = recording.waypoint_t_s.size
                floors = [truth_floor] * n if isinstance(truth_floor, str) else list(truth_floor)
                logger.log_ground_truth(recording.waypoint_t_s, recording.waypoint_xy_m, floors)
        used: dict[str, int] = {}
        for track in tracks:
            name = track.name
            if name in used:  # two files with the same stem: keep both
                used[name] += 1
                name = f"{name}_{used[name]}"
            else:
                used[name] = 1
            logger.log_track(name, track.t_s, track.xy_m, track.floor if building is not None else None)
