"""Ranges to known anchors (UWB, WiFi RTT) as a measurement model.

The likelihood of the ``ranges`` source (registered with its stream adapter in
``filter.sources.ranges``; the anchor table and the range log are ``sensors.anchors``).

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
from mapfilter.filter.kernels.passes import LIKELIHOOD_SIGNATURE, X, Y
from mapfilter.filter.models.frame import StateFrame, floor_block, particle_floor
from mapfilter.filter.models.interface import LikelihoodKernel, MeasurementModel

__all__ = ["RangeLikelihood", "RangeSet"]


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
