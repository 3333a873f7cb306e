"""Measurement models (the ``MeasurementModel`` interface) and the fast RSSI likelihood kernel.

- :class:`GaussianFixLikelihood` weights particles by a position fix (a fingerprint/KWNN
  result) with an isotropic Gaussian, sigma = 5 m by default (Evennou & Marx).
- :func:`rssi_log_likelihood` is the per-particle Gaussian RSSI log-likelihood under the
  Lund thesis path-loss model; ``mapfilter.wifi`` wraps it into the trilateration model.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numba import njit, prange

from mapfilter.filter.particles import Particles
from mapfilter.wifi import MIN_DISTANCE_M

__all__ = ["GaussianFixLikelihood", "PositionFix", "rssi_log_likelihood"]


@dataclasses.dataclass(frozen=True)
class PositionFix:
    """A position measurement in world metres; ``sigma_m`` overrides the model's sigma."""

    xy_m: tuple[float, float] | np.ndarray
    sigma_m: float | None = None


@dataclasses.dataclass(frozen=True)
class GaussianFixLikelihood:
    """log p(fix | particle) = -|x - fix|^2 / (2 sigma^2) (constant dropped).

    The maximum is 0 at the fix, so the value is also a squared distance in sigmas
    (useful for ``FilterConfig.min_log_likelihood``).
    """

    sigma_m: float = 5.0
    kind: str = "fix"

    def log_likelihood(self, particles: Particles, measurement: PositionFix) -> np.ndarray:
        sigma = self.sigma_m if measurement.sigma_m is None else measurement.sigma_m
        if not (math.isfinite(sigma) and sigma > 0):
            raise ValueError(f"fix sigma must be a positive number of metres, got {sigma}")
        fx, fy = (float(v) for v in np.asarray(measurement.xy_m, dtype=np.float64).ravel()[:2])
        d2 = (particles.xy_m[:, 0] - fx) ** 2 + (particles.xy_m[:, 1] - fy) ** 2
        return -0.5 * d2 / (sigma * sigma)


@njit(cache=True, parallel=True, fastmath=True)
def _rssi_ll_kernel(x, y, ap_x, ap_y, c_dbm, five_n, alpha, d_max, observed, inv_two_var, out):
    k_ap = ap_x.shape[0]
    one = np.float32(MIN_DISTANCE_M * MIN_DISTANCE_M)
    for i in prange(x.shape[0]):
        xi = x[i]
        yi = y[i]
        acc = np.float32(0.0)
        for k in range(k_ap):
            dx = xi - ap_x[k]
            dy = yi - ap_y[k]
            d2 = max(dx * dx + dy * dy, one)  # distance clamped at the 1 m reference
            d = math.sqrt(d2)
            # R(d) = C - 10 n log10(d) - alpha min(d, d_max), with 10 n log10(d) = 5 n log10(d^2)
            r = observed[k] - (c_dbm[k] - five_n[k] * math.log10(d2) - alpha[k] * min(d, d_max[k]))
            acc += r * r
        out[i] = -acc * inv_two_var


def rssi_log_likelihood(xy_m: np.ndarray, ap_xy_m: np.ndarray, c_dbm: np.ndarray, n: np.ndarray,
                        alpha_db_per_m: np.ndarray, d_max_m: np.ndarray, observed_rssi_dbm: np.ndarray,
                        variance_db2: float = 25.0) -> np.ndarray:
    """Per-particle Gaussian RSSI log-likelihood -sum_k (z_k - R_k(d_ik))^2 / (2 var).

    R is the Lund thesis path-loss model (``mapfilter.wifi.path_loss_rssi_dbm``: distance
    clamped at 1 m). float32 inside (RSSI is integer dBm; float32 is ~7 significant digits),
    float64 out, parallel over particles. Access points whose observed RSSI is NaN are left
    out (not heard).

    Parameters
    ----------
    xy_m : (N, 2) particle positions.
    ap_xy_m : (K, 2) access-point positions.
    c_dbm, n, alpha_db_per_m, d_max_m : (K,) path-loss parameters per access point.
    observed_rssi_dbm : (K,) measured RSSI.
    variance_db2 : RSSI noise variance (thesis: 25 dB^2).

    Returns
    -------
    (N,) float64, constant dropped (0 = perfect agreement).
    """
    if not (math.isfinite(variance_db2) and variance_db2 > 0):
        raise ValueError(f"variance_db2 must be positive, got {variance_db2}")
    observed = np.asarray(observed_rssi_dbm, dtype=np.float64).ravel()
    heard = np.isfinite(observed)
    f32 = np.float32

    def per_ap(a):
        return np.ascontiguousarray(np.broadcast_to(np.asarray(a, dtype=np.float64).ravel(), observed.shape)[heard],
                                    dtype=f32)

    ap_xy = np.asarray(ap_xy_m, dtype=np.float64).reshape(-1, 2)[heard]
    xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
    out = np.empty(xy.shape[0], dtype=f32)
    _rssi_ll_kernel(xy[:, 0].astype(f32), xy[:, 1].astype(f32), ap_xy[:, 0].astype(f32), ap_xy[:, 1].astype(f32),
                    per_ap(c_dbm), 5.0 * per_ap(n), per_ap(alpha_db_per_m), per_ap(d_max_m),
                    np.ascontiguousarray(observed[heard], dtype=f32), f32(0.5 / float(variance_db2)), out)
    return out.astype(np.float64)
