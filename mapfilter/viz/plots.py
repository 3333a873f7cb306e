"""The plot layer: ESS and live particles, wall kills, the error, PDR step length and heading, and
for adaptive trilateration the blocking term H and the nearest AP's C (Lund thesis ch. 7)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from mapfilter.viz.canvas import Canvas
from mapfilter.viz.style import ESTIMATE_COLOUR, GT_COLOUR, RED, wrap_deg

if TYPE_CHECKING:  # pragma: no cover
    from mapfilter.filter.events import StepReport


class PlotLayer:
    """Draws the time series under ``plots/``; :meth:`style` logs their static colours and names once."""

    def __init__(self, canvas: Canvas) -> None:
        self.canvas = canvas

    def style(self) -> None:
        rr = self.canvas.rr
        log = self.canvas.log
        log("plots/particles/ess", rr.SeriesLines(colors=[(31, 119, 180)], names=["ESS"], widths=[1.5]), static=True)
        log("plots/particles/alive", rr.SeriesLines(colors=[(44, 160, 44)], names=["alive"], widths=[1.5]), static=True)
        log(
            "plots/particles/resampled",
            rr.SeriesPoints(colors=[(214, 39, 40)], names=["resampled (ESS before)"], markers=["cross"],
                            marker_sizes=[3.0]),
            static=True,
        )
        log("plots/error_m/filter", rr.SeriesLines(colors=[ESTIMATE_COLOUR], names=["filter"], widths=[1.5]),
            static=True)
        log("plots/kills", rr.SeriesLines(colors=[RED], names=["killed by walls"], widths=[1.5]), static=True)
        log("plots/pdr/step_length_m", rr.SeriesLines(colors=[(148, 103, 189)], names=["step length (m)"]), static=True)
        log("plots/pdr/heading_deg/filter", rr.SeriesLines(colors=[ESTIMATE_COLOUR], names=["filter"]), static=True)
        log("plots/pdr/heading_deg/ground_truth",
            rr.SeriesPoints(colors=[GT_COLOUR], names=["walking direction (ground truth)"], marker_sizes=[1.5]),
            static=True)
        log("plots/path_loss/blocking_H_db", rr.SeriesLines(colors=[RED], names=["blocking H (dB)"]), static=True)
        log("plots/path_loss/nearest_C_dbm",
            rr.SeriesPoints(colors=[(31, 119, 180)], names=["C of the nearest AP (dBm)"], marker_sizes=[2.0]),
            static=True)

    def draw(self, report: StepReport, error_m: float, true_heading_rad: float | None) -> None:
        """One step's values; ``error_m`` NaN and ``true_heading_rad`` None when there is no ground truth."""
        rr = self.canvas.rr
        log = self.canvas.log
        log("plots/particles/ess", rr.Scalars(float(report.ess)))
        log("plots/particles/alive", rr.Scalars(float(report.n_alive)))
        log("plots/kills", rr.Scalars(float(report.n_killed)))
        if math.isfinite(error_m):
            log("plots/error_m/filter", rr.Scalars(error_m))
        if report.step_length_m is not None:
            log("plots/pdr/step_length_m", rr.Scalars(float(report.step_length_m)))
        if report.heading_rad is not None:
            log("plots/pdr/heading_deg/filter", rr.Scalars(wrap_deg(float(report.heading_rad))))
            if true_heading_rad is not None:
                log("plots/pdr/heading_deg/ground_truth", rr.Scalars(wrap_deg(true_heading_rad)))
        state = report.path_loss  # adaptive trilateration only (filter.adaptive_pathloss.PathLossState)
        if state is not None:
            log("plots/path_loss/blocking_H_db", rr.Scalars(float(state.blocking_db)))
            if math.isfinite(state.nearest_c_dbm):
                log("plots/path_loss/nearest_C_dbm", rr.Scalars(float(state.nearest_c_dbm)))
            if state.adapted:
                log("events", rr.TextLog(f"path loss adapted at {state.nearest_ap}: C = {state.nearest_c_dbm:.1f} dBm",
                                         level=rr.TextLogLevel.INFO))
