"""Ranges to known anchors (UWB, WiFi RTT) as a measurement model and its stream adapter.

The model and stream adapter of the ``ranges`` source (registered in ``filter.sources.ranges``;
the anchor table and the range log are ``sensors.anchors``).

Measurements. The ranges stamped at one time (a tag's ranging round) are one measurement, at
that time: it depends on nothing later, and a range weighs the particles where they are when it
was measured (a window of ranges, as BLE's readings are grouped, would lag a walker by half a
window). The ranges come from a file beside the log, handed over as the log's chunks reach their
times (a source never runs ahead of its chunk), and only those of the walk: from its log's start
(the header's, where it gives one) to its newest record.

Likelihood. A range r to anchor a is Gaussian around the 3-D distance from the particle to the
anchor, sqrt(d^2 + h^2), d horizontal, h the anchor's height above the phone plus the elevation
between the anchor's floor and the particle's: log p = -sum (r - sqrt(d^2 + h^2))^2 / (2 sigma^2).
In a building's stack plan each particle takes its own floor's block of anchors (the frame
helper, ``filter.models.frame``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from mapfilter.errors import MapfilterError
from mapfilter.filter.causal import MeasurementSource
from mapfilter.filter.kernels.passes import LIKELIHOOD_SIGNATURE, X, Y
from mapfilter.filter.models.frame import StateFrame, floor_block, particle_floor
from mapfilter.filter.models.interface import LikelihoodKernel, MeasurementModel
from mapfilter.sensors.recording import Recording

__all__ = ["RangeLikelihood", "RangeSet", "RangeSource"]


class RangeSet:
    """One measurement: the anchors ranged at one time (table rows) and the range to each."""

    def __init__(self, t_s: float, anchor: np.ndarray, range_m: np.ndarray) -> None:
        self.t_s, self.anchor, self.range_m = float(t_s), anchor, range_m


@njit(LIKELIHOOD_SIGNATURE, cache=True, nogil=True, error_model="numpy")
def _ranges(params, state, lo, m, out):
    """params: a ``StateFrame.pack`` of one block per floor: 1 / (2 sigma^2), M, then x, y, h^2 and
    the measured range of each of the M anchors as that floor sees them."""
    for j in range(m):
        x = state[X, lo + j]
        y = state[Y, lo + j]
        start, _ = floor_block(params, particle_floor(params, x))
        inv_two_var = params[start]
        total = 0.0
        for k in range(int(params[start + 1])):
            base = start + 2 + 4 * k
            dx = x - params[base]
            dy = y - params[base + 1]
            residual = params[base + 3] - math.sqrt(dx * dx + dy * dy + params[base + 2])
            total += residual * residual
        out[j] = -total * inv_two_var


class RangeLikelihood(MeasurementModel):
    """Particles weighed by a set of ranges (module docstring): ``table`` (``sensors.anchors``)
    seen from each floor of ``frame``, Gaussian ranges of spread ``sigma_m``."""

    kind = "ranges"
    log_likelihood_peak = 0.0  # -sum residual^2 / (2 sigma^2), without its constant

    def __init__(self, table, frame: StateFrame, sigma_m: float) -> None:
        if not (math.isfinite(sigma_m) and sigma_m > 0):
            raise MapfilterError(f"range sigma must be positive, got {sigma_m}")
        self.table, self.frame, self.sigma_m = table, frame, float(sigma_m)
        anchor_xy, anchor_floor = table.building_xy_m(frame.building)
        self._xy_m = frame.place(anchor_xy)  # per state floor: each anchor above or below, in the state's frame
        height = np.asarray(table.height_m, dtype=np.float64)
        self._h2 = [(height + rise) ** 2 for rise in frame.rise_m(anchor_floor)]
        index = {b: f for f, b in enumerate(frame.floors)}
        own = [self._xy_m[index.get(int(b), 0)][i] for i, b in enumerate(anchor_floor)]
        self._own_xy_m = np.array(own).reshape(-1, 2)  # each anchor on its own floor, for the viewer

    def heard_ap_xy_m(self, measurement: RangeSet) -> np.ndarray:
        """(M, 2) the anchors ranged (on their own floors), for the viewer."""
        return self._own_xy_m[measurement.anchor]

    def kernel(self, measurement: RangeSet) -> LikelihoodKernel:
        rows = measurement.anchor
        blocks = []
        for f in range(self.frame.n_floors):
            table = np.column_stack([self._xy_m[f][rows], self._h2[f][rows], measurement.range_m])
            blocks.append(np.concatenate([[0.5 / self.sigma_m ** 2, float(rows.size)], table.ravel()]))
        return LikelihoodKernel(_ranges, self.frame.pack(blocks))


class RangeSource(MeasurementSource):
    """The ranges of a range log as measurements (module docstring)."""

    stream = "ranges"
    written_behind_s = 0.0  # the ranges up to the chunk's newest record are handed over

    def __init__(self, ranges, frame: StateFrame, config) -> None:
        super().__init__()
        self.ranges, self.config = ranges, config
        self.model = self.model_on(frame)
        self._given = 0  # ranges of the log handed over (or passed over, before the walk)
        self._start_s: float | None = None  # the walk's start by its log's header, if it gives one

    def model_on(self, frame: StateFrame) -> RangeLikelihood:
        return RangeLikelihood(self.ranges.table, frame, self.config.range_sigma_m)

    def records_of(self, records: Recording) -> tuple:
        """(t_s, anchor row, range) of the log's ranges the chunk's records reached."""
        log = self.ranges.log
        if self._start_s is None and records.start_t_s is not None:
            self._start_s = float(records.start_t_s)
            self._given = max(self._given, int(np.searchsorted(log.t_s, self._start_s, side="left")))
        stop = int(np.searchsorted(log.t_s, records.newest_t_s, side="right"))
        start, self._given = self._given, max(self._given, stop)
        return log.t_s[start:stop], log.anchor[start:stop], log.range_m[start:stop]

    def measure(self, records: tuple, final: bool) -> list[tuple[float, RangeSet]]:
        """The ranges stamped at one time, a measurement each (all of one time come in one chunk)."""
        t_s, anchor, range_m = records
        cuts = np.flatnonzero(np.diff(t_s)) + 1
        return [(float(t_s[a]), RangeSet(float(t_s[a]), anchor[a:b], range_m[a:b]))
                for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(t_s)])]
