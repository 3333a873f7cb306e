"""The event layer: resampling and collapses in the text log, collapse and recovery markers on the map."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from mapfilter.viz.canvas import Canvas
from mapfilter.viz.style import RECOVERY_COLOUR, RED, Z_EVENTS

if TYPE_CHECKING:  # pragma: no cover
    from mapfilter.filter.events import CollapseEvent, StepReport


class EventLayer:
    """Draws ``events`` (text log), ``plots/particles/resampled`` and ``map/world/events/...``."""

    def __init__(self, canvas: Canvas) -> None:
        self.canvas = canvas
        self._collapse_xy: list[tuple[float, float]] = []
        self._recovery_xy: list[tuple[float, float]] = []
        self._collapse_labels: list[str] = []

    def draw(self, report: StepReport) -> None:
        rr = self.canvas.rr
        if report.resampled:
            self.canvas.log("plots/particles/resampled", rr.Scalars(float(report.ess)))
            self.canvas.log("events", rr.TextLog(
                f"step {report.step_index}: resampled (ESS {report.ess:.0f} of {report.n_particles})",
                level=rr.TextLogLevel.DEBUG))
        if report.collapse is not None:
            self._draw_collapse(report.collapse)

    def _draw_collapse(self, event: CollapseEvent) -> None:
        rr = self.canvas.rr
        log = self.canvas.log
        k = len(self._collapse_xy) + 1
        self._collapse_xy.append(tuple(map(float, event.xy_m)))
        self._recovery_xy.append(tuple(map(float, event.recovered_xy_m)))
        self._collapse_labels.append(f"collapse {k}")
        log("events", rr.TextLog(
            f"step {event.step_index}: collapse {k} ({event.cause}): {event.particles_lost} particles lost "
            f"near ({event.xy_m[0]:.1f}, {event.xy_m[1]:.1f}) m",
            level=rr.TextLogLevel.WARN))
        log("events", rr.TextLog(
            f"step {event.step_index}: recovery {k} ({event.recovery}) at "
            f"({event.recovered_xy_m[0]:.1f}, {event.recovered_xy_m[1]:.1f}) m",
            level=rr.TextLogLevel.WARN))
        # all markers so far, re-logged: collapses are rare, and latest-at shows the whole list
        collapse = np.array(self._collapse_xy)
        recovery = np.array(self._recovery_xy)
        log("map/world/events/collapses",
            rr.Points2D(collapse, colors=RED, radii=-8.0, labels=self._collapse_labels, draw_order=Z_EVENTS))
        log("map/world/events/recoveries",
            rr.Points2D(recovery, colors=RECOVERY_COLOUR, radii=-6.0, draw_order=Z_EVENTS))
        log("map/world/events/jumps",
            rr.Arrows2D(origins=collapse, vectors=recovery - collapse, colors=RECOVERY_COLOUR, radii=-1.0,
                        draw_order=Z_EVENTS))
