"""Measurement models (the ``MeasurementModel`` interface) and the fast RSSI likelihood kernel.

- :class:`GaussianFixLikelihood` weights particles by a position fix (a fingerprint/KWNN
  result) with an isotropic Gaussian, sigma = 5 m by default (Evennou & Marx).
- :func:`rssi_log_likelihood` is the per-particle Gaussian RSSI log-likelihood under the
  Lund thesis path-loss model; :class:`TrilaterationLikelihood` weighs a WiFi scan with it.
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import numpy as np
from numba import njit

from mapfilter.errors import MapfilterError
from mapfilter.filter import fused
from mapfilter.filter.models import MeasurementModel
from mapfilter.filter.particles import Particles
from mapfilter.sensors.pathloss import MIN_DISTANCE_M, AccessPointTable, match_scan
from mapfilter.sensors.wifi import WifiScan
from mapfilter.threads import MIN_PER_THREAD, for_slices

__all__ = ["GaussianFixLikelihood", "PositionFix", "TrilaterationLikelihood", "rssi_log_likelihood"]


@dataclasses.dataclass(frozen=True)
class PositionFix:
    """A position measurement in world metres; ``sigma_m`` overrides the model's sigma."""

    xy_m: tuple[float, float] | np.ndarray
    sigma_m: float | None = None


@dataclasses.dataclass(frozen=True)
class GaussianFixLikelihood(MeasurementModel):
    """log p(fix | particle) = -|x - fix|^2 / (2 sigma^2) (constant dropped).

    The maximum is 0 at the fix, so the value is also a squared distance in sigmas
    (useful for ``FilterConfig.min_log_likelihood``).
    """

    sigma_m: float = 5.0
    kind: ClassVar[str] = "fix"
    log_likelihood_peak: ClassVar[float] = 0.0  # at the fix: lets the filter tell a hopeless fix (weights underflow)

    def fix_xy_m(self, measurement: PositionFix) -> np.ndarray:
        return np.asarray(measurement.xy_m, dtype=np.float64)

    def _sigma_m(self, measurement: PositionFix) -> float:
        sigma = self.sigma_m if measurement.sigma_m is None else measurement.sigma_m
        if not (math.isfinite(sigma) and sigma > 0):
            raise ValueError(f"fix sigma must be a positive number of metres, got {sigma}")
        return sigma

    def kernel_likelihood(self, measurement: PositionFix) -> fused.Likelihood:
        return fused.gaussian_fix(measurement.xy_m, self._sigma_m(measurement))

    def log_likelihood(self, particles: Particles, measurement: PositionFix) -> np.ndarray:
        sigma = self._sigma_m(measurement)
        fx, fy = (float(v) for v in np.asarray(measurement.xy_m, dtype=np.float64).ravel()[:2])
        d2 = (particles.xy_m[:, 0] - fx) ** 2 + (particles.xy_m[:, 1] - fy) ** 2
        return -0.5 * d2 / (sigma * sigma)


_CHUNK = 512  # particles per block: the per-AP loops over a block vectorise (SIMD)


@njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def _rssi_ll_kernel(first_block, end_block, x, y, ap_x, ap_y, c_dbm, five_n, alpha, d_max, observed, inv_two_var,
                    out):
    """-sum_k (z_k - R_k)^2 / (2 var) per particle, in blocks of particles, float32.

    log10(d^2) comes from the float's exponent and a 5-term series of the mantissa,
    ln m = 2 atanh t = 2 (t + t^3/3 + ... + t^9/9), t = (m - 1)/(m + 1), m in [1, 2):
    |error| < 2e-6 in ln (1e-5 dB for n = 2), but unlike libm's log it vectorises, which
    made the kernel 5x faster.
    """
    n_particles = x.shape[0]
    k_ap = ap_x.shape[0]
    ln2 = np.float32(math.log(2.0))
    inv_ln10 = np.float32(1.0 / math.log(10.0))
    one = np.float32(MIN_DISTANCE_M * MIN_DISTANCE_M)
    for block in range(first_block, end_block):  # blocks of _CHUNK particles
        lo = block * _CHUNK
        m = min(n_particles, lo + _CHUNK) - lo
        acc = np.zeros(_CHUNK, dtype=np.float32)
        d2 = np.ones(_CHUNK, dtype=np.float32)
        mantissa_bits = np.empty(_CHUNK, dtype=np.int32)
        log10_d2 = np.empty(_CHUNK, dtype=np.float32)
        for k in range(k_ap):
            ax = ap_x[k]
            ay = ap_y[k]
            for j in range(m):
                dx = x[lo + j] - ax
                dy = y[lo + j] - ay
                d2[j] = max(dx * dx + dy * dy, one)  # distance clamped at the 1 m reference
            bits = d2.view(np.int32)
            for j in range(m):
                mantissa_bits[j] = (bits[j] & 0x007FFFFF) | 0x3F800000  # same mantissa, exponent 0
            mantissa = mantissa_bits.view(np.float32)
            for j in range(m):
                exponent = np.float32((bits[j] >> 23) - 127)
                t = (mantissa[j] - np.float32(1.0)) / (mantissa[j] + np.float32(1.0))
                t2 = t * t
                ln_m = np.float32(2.0) * t * (np.float32(1.0) + t2 * (np.float32(1.0 / 3.0) + t2 * (
                    np.float32(0.2) + t2 * (np.float32(1.0 / 7.0) + t2 * np.float32(1.0 / 9.0)))))
                log10_d2[j] = (exponent * ln2 + ln_m) * inv_ln10
            ck = c_dbm[k]
            nk = five_n[k]
            ak = alpha[k]
            dk = d_max[k]
            zk = observed[k]
            for j in range(m):
                # R(d) = C - 10 n log10(d) - alpha min(d, d_max), with 10 n log10(d) = 5 n log10(d^2)
                r = zk - (ck - nk * log10_d2[j] - ak * min(math.sqrt(d2[j]), dk))
                acc[j] += r * r
        for j in range(m):
            out[lo + j] = -acc[j] * inv_two_var


def rssi_log_likelihood(xy_m: np.ndarray, ap_xy_m: np.ndarray, c_dbm: np.ndarray, n: np.ndarray,
                        alpha_db_per_m: np.ndarray, d_max_m: np.ndarray, observed_rssi_dbm: np.ndarray,
                        variance_db2: float = 25.0) -> np.ndarray:
    """Per-particle Gaussian RSSI log-likelihood -sum_k (z_k - R_k(d_ik))^2 / (2 var).

    R is the Lund thesis path-loss model (``mapfilter.sensors.pathloss.path_loss_rssi_dbm``: distance
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
    n_blocks = (xy.shape[0] + _CHUNK - 1) // _CHUNK
    for_slices(_rssi_ll_kernel, n_blocks, xy[:, 0].astype(f32), xy[:, 1].astype(f32), ap_xy[:, 0].astype(f32),
               ap_xy[:, 1].astype(f32), per_ap(c_dbm), 5.0 * per_ap(n), per_ap(alpha_db_per_m), per_ap(d_max_m),
               np.ascontiguousarray(observed[heard], dtype=f32), f32(0.5 / float(variance_db2)), out,
               min_per_thread=max(MIN_PER_THREAD // _CHUNK, 1))
    return out.astype(np.float64)


class TrilaterationLikelihood(MeasurementModel):
    """Per-particle Gaussian RSSI likelihood of the Lund path-loss model (a ``MeasurementModel``).

    Each heard AP that the table knows (matched by bssid *and* band) contributes
    N(r; R(d), variance); APs the table does not know are ignored, and a scan sharing no AP
    with the table leaves the weights unchanged (log-likelihood 0 everywhere).

    Parameters
    ----------
    ap_table : positions and path-loss parameters of the access points.
    variance_db2 : RSSI noise variance; 25 dB^2 is the thesis value.
    """

    kind = "trilateration"

    def __init__(self, ap_table: AccessPointTable, variance_db2: float = 25.0):
        if not variance_db2 > 0:
            raise MapfilterError(f"RSSI variance must be positive, got {variance_db2}")
        self.ap_table = ap_table
        self.variance_db2 = float(variance_db2)

    def heard_ap_xy_m(self, scan: WifiScan) -> np.ndarray:
        """(M, 2) positions of the scan's access points that the table knows (for the viewer)."""
        return self.ap_table.xy_m[match_scan(self.ap_table, scan)[0]]

    def kernel_likelihood(self, measurement: WifiScan) -> fused.Likelihood:
        rows, rssi = match_scan(self.ap_table, measurement)
        if rows.size == 0:
            return fused.flat()
        t = self.ap_table
        return fused.rssi_path_loss(t.xy_m[rows], t.c_dbm[rows], t.n[rows], t.alpha_db_per_m[rows], t.d_max_m[rows],
                                    rssi, self.variance_db2)

    def log_likelihood(self, particles, measurement: WifiScan) -> np.ndarray:
        rows, rssi = match_scan(self.ap_table, measurement)
        if rows.size == 0:
            return np.zeros(len(particles))
        t = self.ap_table
        return rssi_log_likelihood(particles.xy_m, t.xy_m[rows], t.c_dbm[rows], t.n[rows], t.alpha_db_per_m[rows],
                                   t.d_max_m[rows], rssi, self.variance_db2)
