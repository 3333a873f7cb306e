"""A position fix weighed with an isotropic Gaussian (Evennou & Marx: a fingerprint's KWNN fix,
sigma = 5 m)."""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import numpy as np
from numba import njit

from mapfilter.filter.kernels.passes import LIKELIHOOD_SIGNATURE, X, Y
from mapfilter.filter.models.interface import LikelihoodKernel, MeasurementModel

__all__ = ["GaussianFixLikelihood", "PositionFix"]


@dataclasses.dataclass(frozen=True)
class PositionFix:
    """A position measurement in world metres; ``sigma_m`` overrides the model's sigma."""

    xy_m: tuple[float, float] | np.ndarray
    sigma_m: float | None = None


@njit(LIKELIHOOD_SIGNATURE, cache=True, nogil=True, fastmath=True)
def _gaussian_fix(params, state, lo, m, out):
    # -|x - fix|^2 / (2 sigma^2); params: fix x, fix y, 1 / (2 sigma^2)
    fx = params[0]
    fy = params[1]
    scale = params[2]
    for j in range(m):
        dx = state[X, lo + j] - fx
        dy = state[Y, lo + j] - fy
        out[j] = -(dx * dx + dy * dy) * scale


@dataclasses.dataclass(frozen=True)
class GaussianFixLikelihood(MeasurementModel):
    """log p(fix | particle) = -|x - fix|^2 / (2 sigma^2) (constant dropped).

    The maximum is 0 at the fix, so the value is also minus half a squared distance in sigmas
    (what ``FilterConfig.min_log_likelihood`` compares with)."""

    sigma_m: float = 5.0
    log_likelihood_peak: ClassVar[float] = 0.0  # at the fix: lets the filter tell a hopeless fix (weights underflow)

    def fix_xy_m(self, measurement: PositionFix) -> np.ndarray:
        return np.asarray(measurement.xy_m, dtype=np.float64)

    def kernel(self, measurement: PositionFix) -> LikelihoodKernel:
        sigma = self.sigma_m if measurement.sigma_m is None else measurement.sigma_m
        if not (math.isfinite(sigma) and sigma > 0):
            raise ValueError(f"fix sigma must be a positive number of metres, got {sigma}")
        fx, fy = (float(v) for v in np.asarray(measurement.xy_m, dtype=np.float64).ravel()[:2])
        return LikelihoodKernel(_gaussian_fix, np.array([fx, fy, 0.5 / (sigma * sigma)]))
