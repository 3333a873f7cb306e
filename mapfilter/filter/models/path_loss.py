"""Trilateration: a WiFi scan weighed by the Lund thesis path-loss model (Karlsson & Karlsson,
ch. 6), R(d) = C - 10 n log10(d) - alpha min(d, d_max), with Gaussian RSSI noise.

:func:`path_loss_kernel` is the per-particle log-likelihood -sum_k (z_k - R_k(d_k))^2 / (2 var)
as a filter kernel; the BLE model (``filter.models.ble``) uses it too.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from mapfilter.errors import MapfilterError
from mapfilter.filter.kernels.draws import as_float, as_int
from mapfilter.filter.kernels.passes import BLOCK, LIKELIHOOD_SIGNATURE, X, Y
from mapfilter.filter.models.interface import LikelihoodKernel, MeasurementModel
from mapfilter.sensors.pathloss import MIN_DISTANCE_M, AccessPointTable, match_scan
from mapfilter.sensors.wifi import WifiScan

__all__ = ["TrilaterationLikelihood", "path_loss_kernel"]


@njit(LIKELIHOOD_SIGNATURE, cache=True, nogil=True, fastmath=True, error_model="numpy")
def _path_loss(params, state, lo, m, out):
    """params: 1 / (2 var), K, then x, y, C, 5 n, alpha, d_max, z of each of the K transmitters.

    float32 inside (RSSI is integer dBm); log10(d^2) from the float's exponent and a 5-term
    series of its mantissa, ln m = 2 atanh t = 2 (t + t^3/3 + ... + t^9/9), t = (m - 1)/(m + 1),
    m in [1, 2): |error| < 2e-6 in ln (1e-5 dB for n = 2), but unlike libm's log it vectorises."""
    inv_two_var = np.float32(params[0])
    k_aps = int(params[1])
    ln2 = np.float32(math.log(2.0))
    inv_ln10 = np.float32(1.0 / math.log(10.0))
    one = np.float32(MIN_DISTANCE_M * MIN_DISTANCE_M)
    xf = np.empty(BLOCK, dtype=np.float32)
    yf = np.empty(BLOCK, dtype=np.float32)
    acc = np.zeros(BLOCK, dtype=np.float32)
    for j in range(m):
        xf[j] = np.float32(state[X, lo + j])
        yf[j] = np.float32(state[Y, lo + j])
    for k in range(k_aps):
        base = 2 + 7 * k
        ax = np.float32(params[base])
        ay = np.float32(params[base + 1])
        ck = np.float32(params[base + 2])
        nk = np.float32(params[base + 3])
        ak = np.float32(params[base + 4])
        dk = np.float32(params[base + 5])
        zk = np.float32(params[base + 6])
        for j in range(m):
            dx = xf[j] - ax
            dy = yf[j] - ay
            dd = max(dx * dx + dy * dy, one)  # distance clamped at the 1 m reference
            bits = as_int(dd)
            mantissa = as_float(np.int32((bits & 0x007FFFFF) | 0x3F800000))  # same mantissa, exponent 0
            exponent = np.float32((bits >> 23) - 127)
            t = (mantissa - np.float32(1.0)) / (mantissa + np.float32(1.0))
            t2 = t * t
            ln_m = np.float32(2.0) * t * (np.float32(1.0) + t2 * (np.float32(1.0 / 3.0) + t2 * (
                np.float32(0.2) + t2 * (np.float32(1.0 / 7.0) + t2 * np.float32(1.0 / 9.0)))))
            log10_d2 = (exponent * ln2 + ln_m) * inv_ln10
            # R(d) = C - 10 n log10(d) - alpha min(d, d_max), with 10 n log10(d) = 5 n log10(d^2)
            r = zk - (ck - nk * log10_d2 - ak * min(math.sqrt(dd), dk))
            acc[j] += r * r
    for j in range(m):
        out[j] = -np.float64(acc[j] * inv_two_var)


def path_loss_kernel(xy_m: np.ndarray, c_dbm: np.ndarray, n: np.ndarray, alpha_db_per_m: np.ndarray,
                     d_max_m: np.ndarray, observed_rssi_dbm: np.ndarray, variance_db2: float) -> LikelihoodKernel:
    """The log-likelihood -sum_k (z_k - R_k(d_k))^2 / (2 var) of readings ``observed_rssi_dbm`` (K,)
    of transmitters at ``xy_m`` (K, 2) with path-loss parameters (K,) each (NaN readings left out:
    not heard)."""
    if not (math.isfinite(variance_db2) and variance_db2 > 0):
        raise ValueError(f"variance_db2 must be positive, got {variance_db2}")
    observed = np.asarray(observed_rssi_dbm, dtype=np.float64).ravel()
    heard = np.isfinite(observed)

    def per_ap(values):
        return np.broadcast_to(np.asarray(values, dtype=np.float64).ravel(), observed.shape)[heard]

    xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)[heard]
    table = np.stack([xy[:, 0], xy[:, 1], per_ap(c_dbm), 5.0 * per_ap(n), per_ap(alpha_db_per_m), per_ap(d_max_m),
                      observed[heard]], axis=1)
    return LikelihoodKernel(_path_loss, np.concatenate([[0.5 / variance_db2, float(table.shape[0])], table.ravel()]))


class TrilaterationLikelihood(MeasurementModel):
    """A scan weighed by the path-loss model of an access-point table.

    Each heard AP that the table knows (matched by BSSID *and* band) contributes N(r; R(d), var);
    APs the table does not know are ignored, and a scan sharing no AP with the table leaves the
    weights unchanged. ``variance_db2``: the RSSI noise (thesis: 25 dB^2).
    """

    def __init__(self, ap_table: AccessPointTable, variance_db2: float = 25.0):
        if not (math.isfinite(variance_db2) and variance_db2 > 0):
            raise MapfilterError(f"RSSI variance must be positive, got {variance_db2}")
        self.ap_table = ap_table
        self.variance_db2 = float(variance_db2)

    def heard_ap_xy_m(self, scan: WifiScan) -> np.ndarray:
        """(M, 2) positions of the scan's access points that the table knows (for the viewer)."""
        return self.ap_table.xy_m[match_scan(self.ap_table, scan)[0]]

    def kernel(self, measurement: WifiScan) -> LikelihoodKernel:
        rows, rssi = match_scan(self.ap_table, measurement)
        t = self.ap_table
        return path_loss_kernel(t.xy_m[rows], t.c_dbm[rows], t.n[rows], t.alpha_db_per_m[rows], t.d_max_m[rows],
                                rssi, self.variance_db2)
