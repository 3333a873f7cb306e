"""The particle layer: the cloud coloured by weight, the moves walls killed, the estimate, the measurement."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from mapfilter.viz.canvas import Canvas
from mapfilter.viz.style import (
    ESTIMATE_COLOUR,
    RED,
    SMOOTHED_COLOUR,
    TRAIL_PIECE_STEPS,
    Z_ESTIMATE,
    Z_KILLED,
    Z_MEAS,
    Z_PARTICLES,
    Z_TRACK,
    circle_xy,
    weight_colours,
    weight_faithful_subsample,
)

if TYPE_CHECKING:  # pragma: no cover
    from mapfilter.filter.events import StepReport


class ParticleLayer:
    """Draws ``map/world/{particles,killed}``, ``map/world/estimate/...`` and ``map/world/measurement/...``.

    ``max_particles`` caps the particles drawn per step (a weight-faithful subsample) and the
    killed moves (strided down to it).
    """

    def __init__(self, canvas: Canvas, max_particles: int) -> None:
        self.canvas = canvas
        self.max_particles = int(max_particles)
        self._trail_xy: list[tuple[float, float]] = []
        self._trail_pieces = 0

    def draw_smoothed(self, xy_m: np.ndarray, weight: np.ndarray) -> None:
        """The smoother's cloud of a step (``map/world/smoothed_particles``): the kept particles under
        their weights given the whole walk, one colour, sized by weight, beside the filter's cloud."""
        keep = weight_faithful_subsample(weight, self.max_particles)
        w = weight[keep]
        radii = -(1.0 + 3.0 * np.sqrt(w / w.max())) if w.size and w.max() > 0 else -1.0
        self.canvas.log("map/world/smoothed_particles",
                        self.canvas.rr.Points2D(xy_m[keep], colors=SMOOTHED_COLOUR, radii=radii,
                                                draw_order=Z_PARTICLES + 1.0))

    def draw(self, report: StepReport) -> tuple[np.ndarray, bool]:
        """Draw one step; returns the estimate (2,) and whether it is finite."""
        rr = self.canvas.rr
        show = self.canvas.show

        # particles: weight-faithful subsample, coloured by weight
        xy = np.asarray(report.particles_xy_m, dtype=np.float64).reshape(-1, 2)
        weight = np.asarray(report.particles_weight, dtype=np.float64).reshape(-1)
        keep = weight_faithful_subsample(weight, self.max_particles)
        self.canvas.log("map/world/particles",
                        rr.Points2D(xy[keep], colors=weight_colours(weight[keep]), radii=-2.0,
                                    draw_order=Z_PARTICLES))

        # moves the wall check rejected, old -> new, strided down to the cap
        killed_from = np.asarray(report.killed_from_xy_m, dtype=np.float64).reshape(-1, 2)
        killed_to = np.asarray(report.killed_to_xy_m, dtype=np.float64).reshape(-1, 2)
        segments = None
        if killed_from.shape[0]:
            stride = max(1, math.ceil(killed_from.shape[0] / self.max_particles))
            strips = np.stack([killed_from[::stride], killed_to[::stride]], axis=1)
            segments = rr.LineStrips2D(strips, colors=RED, radii=-1.0, draw_order=Z_KILLED)
        show("map/world/killed", segments)

        # the estimate, its spread, and the trail so far
        # (a filter with no live particle may report a NaN estimate: show nothing then)
        est = np.asarray(report.estimate_xy_m, dtype=np.float64).reshape(2)
        std = float(report.estimate_std_m)
        has_estimate = bool(np.all(np.isfinite(est)))
        show("map/world/estimate/position",
             rr.Points2D([est], colors=ESTIMATE_COLOUR, radii=-6.0, draw_order=Z_ESTIMATE) if has_estimate else None)
        spread = None
        if has_estimate and math.isfinite(std) and std > 0.0:
            spread = rr.LineStrips2D([circle_xy(est, std)], colors=ESTIMATE_COLOUR, radii=-1.0, draw_order=Z_ESTIMATE)
        show("map/world/estimate/spread", spread)
        if has_estimate:
            self._extend_trail(est)

        # the measurement of this step
        fix = None
        if report.fix_xy_m is not None:
            fix = rr.Points2D(np.asarray(report.fix_xy_m, dtype=np.float64).reshape(-1, 2), colors=(0, 120, 255),
                              radii=-5.0, labels=["WiFi fix"], draw_order=Z_MEAS)
        show("map/world/measurement/fix", fix)
        aps = None
        if report.heard_ap_xy_m is not None and len(report.heard_ap_xy_m):
            aps = rr.Points2D(np.asarray(report.heard_ap_xy_m, dtype=np.float64).reshape(-1, 2),
                              colors=(0, 180, 255), radii=-4.0, draw_order=Z_MEAS)
        show("map/world/measurement/aps", aps)
        return est, has_estimate

    def _extend_trail(self, xy: np.ndarray) -> None:
        rr = self.canvas.rr
        self._trail_xy.append((float(xy[0]), float(xy[1])))
        strip = rr.LineStrips2D([self._trail_xy], colors=ESTIMATE_COLOUR, radii=-1.5, draw_order=Z_TRACK)
        self.canvas.log("map/world/estimate/trail/current", strip)
        if len(self._trail_xy) > TRAIL_PIECE_STEPS:
            # freeze this piece under its own entity (visible from now on) and restart the
            # growing piece at its last point so the trail stays connected
            self.canvas.log(f"map/world/estimate/trail/piece{self._trail_pieces:05d}", strip)
            self._trail_pieces += 1
            self._trail_xy = self._trail_xy[-1:]
