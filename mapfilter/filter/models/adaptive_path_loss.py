"""Trilateration that adapts: online path-loss adaptation and signal-blocking compensation.

Lund thesis (Karlsson & Karlsson), chapter 7, on top of the chapter 6 model
R(d) = C - 10 n log10(d) - alpha min(d, d_max) (``mapfilter.sensors.pathloss``):

- **Adaptation (7.1-7.2)**: when the strongest RSSI of a scan is above a limit (thesis
  -36 dBm) the phone is taken as standing below that access point, at the vertical distance
  d_v, in line of sight. Its C is then observed as C_obs = z_i + 10 n log10(d_v) + alpha d_v
  (the model solved for C), and from the same position the other APs j of the scan give
  alpha_obs_j = (C_j - 10 n_j log10(d_ij) - z_j) / min(d_ij, d_max) (the model solved for
  alpha, d_ij = distance between the two APs). C is adapted per AP and band, alpha per band
  for the whole building (the thesis' "alpha per building"); each observation moves the
  parameter by a gain (an exponential average), so one noisy reading cannot throw it.
- **Blocking compensation (7.3)**: when the signals of all or most APs drop together
  (thesis: the mean of the six strongest RSSI falls by more than 6 dB), a term H (dB) is
  subtracted from every AP's model, R(d) - H, until they recover.

The state lives in the measurement model (:class:`AdaptiveTrilaterationLikelihood`), never
in the filter: the filter calls ``log_likelihood`` only, and may call it more than once for
the same scan (start, recovery); the state is updated once per scan, when a new scan
arrives. Nothing here draws random numbers: same scans, same parameters.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.filter.kernels.passes import run_likelihood
from mapfilter.filter.models.interface import MeasurementModel
from mapfilter.filter.models.path_loss import path_loss_kernel
from mapfilter.sensors.pathloss import MIN_DISTANCE_M, AccessPointTable, match_scan, path_loss_rssi_dbm
from mapfilter.sensors.wifi import WifiScan

__all__ = ["AdaptiveTrilaterationLikelihood", "PathLossState", "THESIS_BLOCKING_DROP_DB", "THESIS_RSSI_LIMIT_DBM"]

THESIS_RSSI_LIMIT_DBM = -36.0  # strongest RSSI above this: the phone is below that AP (thesis 7.1)
THESIS_BLOCKING_DROP_DB = 6.0  # blocked when the top-k mean falls this far below its reference (thesis 7.3)

# ---- adaptation (thesis 7.1-7.2): the update's shape
# vertical distance phone-AP when "below" it. Our model's distances are horizontal and clamped
# at the 1 m reference of C, and APs fitted in 2-D (``radiomap fit-aps``) absorb their height
# into C: 1 m keeps C_obs in that frame (the thesis' ceiling APs, about 2 m, would need a table
# whose C means 1 m in 3-D)
VERTICAL_DISTANCE_M = 1.0
C_GAIN = 0.5  # weight of a new C observation: C <- C + gain (C_obs - C); one noisy reading cannot throw C
ALPHA_GAIN = 0.2  # weight of a new per-band alpha observation (median over the other APs)
ALPHA_MIN_DISTANCE_M = 3.0  # other APs nearer than this say little about alpha (1/d)
ALPHA_MIN_APS = 3  # an alpha observation needs at least this many other APs of the band
ALPHA_BOUNDS_DB_PER_M = (0.0, 2.0)  # alpha stays within these
# APs the walk never came close to take the median C correction of the adapted APs of their band
# (ours, not the thesis'): a wrong table is usually wrong the same way for every AP, and a walk
# past a few of 14 APs would otherwise leave most of them wrong

# ---- blocking (thesis 7.3)
BLOCKING_TOP_K = 6  # the mean of the k strongest RSSI of a scan is watched (thesis: 6)
BLOCKING_RECOVER_DB = 3.0  # recovered when that mean is back within this of the reference (hysteresis)
BLOCKING_REFERENCE_GAIN = 0.5  # unblocked scans pull the reference level: ref <- ref + gain (m - ref)
# a "blocking" that lasts longer than this is the walker having moved somewhere weaker: the
# reference is reset to the current level and H to 0
MAX_BLOCKED_S = 60.0
# H once blocking is detected: the median over the heard APs of R_k(x) - z_k at the particles'
# weighted mean x before the scan, >= 0 (ours): the top-k mean's fall also holds the walker's
# own moves (docs/accuracy.md)


@dataclasses.dataclass(frozen=True)
class PathLossState:
    """What the adaptive model holds after a scan (for the viewer and diagnostics)."""

    t_s: float
    blocking_db: float  # H: subtracted from every AP's model (0 when not blocked)
    blocked: bool
    nearest_ap: str | None  # key "bssid@band" of the strongest AP of the scan (known to the table)
    nearest_c_dbm: float  # its C now (NaN without a nearest AP)
    adapted: bool  # this scan adapted the parameters
    n_adaptations: int  # scans that adapted so far


class AdaptiveTrilaterationLikelihood(MeasurementModel):
    """The Lund path-loss likelihood with online adaptation and blocking compensation.

    A ``MeasurementModel``: ``log_likelihood(particles, scan)`` is
    ``TrilaterationLikelihood``'s with the current table and C lowered by the current H.
    The table given is copied, never changed; ``ap_table`` is the adapted copy.

    Parameters
    ----------
    ap_table : initial positions and path-loss parameters (positions are never adapted).
    variance_db2 : RSSI noise variance (thesis 25 dB^2).
    adapt_rssi_limit_dbm : a scan whose strongest RSSI is above this adapts the parameters (the
        phone is below that AP); None: no parameter adaptation.
    blocking_drop_db : blocked when the mean of the strongest RSSI falls this far below its
        reference; None: no blocking compensation.
    """

    def __init__(self, ap_table: AccessPointTable, variance_db2: float = 25.0,
                 adapt_rssi_limit_dbm: float | None = THESIS_RSSI_LIMIT_DBM,
                 blocking_drop_db: float | None = THESIS_BLOCKING_DROP_DB):
        if not variance_db2 > 0:
            raise MapfilterError(f"RSSI variance must be positive, got {variance_db2}")
        check_adaptive_settings(adapt_rssi_limit_dbm, blocking_drop_db)
        self.ap_table = dataclasses.replace(ap_table, xy_m=ap_table.xy_m.copy(), c_dbm=ap_table.c_dbm.astype(float),
                                            n=ap_table.n.astype(float), d_max_m=ap_table.d_max_m.astype(float),
                                            alpha_db_per_m=ap_table.alpha_db_per_m.astype(float),
                                            bssid=list(ap_table.bssid), band=list(ap_table.band))
        self.variance_db2 = float(variance_db2)
        self.adapt_rssi_limit_dbm = adapt_rssi_limit_dbm
        self.blocking_drop_db = blocking_drop_db
        self._band = np.array(self.ap_table.band)
        # building alpha per band (thesis 7.2): starts at the table's mean for the band
        self.alpha_by_band_db_per_m = {b: float(self.ap_table.alpha_db_per_m[self._band == b].mean())
                                       for b in sorted(set(self.ap_table.band))}
        self._c_initial_dbm = self.ap_table.c_dbm.copy()
        self.c_adapted = np.zeros(len(self.ap_table), dtype=bool)  # C observed at least once
        self.blocking_db = 0.0
        self.blocked = False
        self._reference_dbm: float | None = None
        self._blocked_since_s = math.nan
        self._last_scan: WifiScan | None = None
        self.n_adaptations = 0
        self.history: list[PathLossState] = []  # one entry per scan seen

    # ---- the MeasurementModel interface --------------------------------------------------
    def heard_ap_xy_m(self, scan: WifiScan) -> np.ndarray:
        """(M, 2) positions of the scan's access points that the table knows (for the viewer)."""
        return self.ap_table.xy_m[match_scan(self.ap_table, scan)[0]]

    def log_likelihood(self, particles, measurement: WifiScan) -> np.ndarray:
        rows, rssi = match_scan(self.ap_table, measurement)
        if measurement is not self._last_scan:  # once per scan, however often the filter asks
            self._last_scan = measurement
            self._observe(measurement.t_s, rows, rssi, particles)
        if rows.size == 0:
            return np.zeros(len(particles))
        t = self.ap_table
        # blocking: R(d) - H for every AP (thesis 7.3)
        kernel = path_loss_kernel(t.xy_m[rows], t.c_dbm[rows] - self.blocking_db, t.n[rows], t.alpha_db_per_m[rows],
                                  t.d_max_m[rows], rssi, self.variance_db2)
        return run_likelihood(kernel.function, kernel.params, particles.state)

    @property
    def state(self) -> PathLossState | None:
        """The state after the latest scan (None before the first)."""
        return self.history[-1] if self.history else None

    def viewer_state(self) -> PathLossState | None:
        return self.state

    # ---- the updates ---------------------------------------------------------------------
    def _observe(self, t_s: float, rows: np.ndarray, rssi: np.ndarray, particles) -> None:
        if self.blocking_drop_db is not None:
            self._update_blocking(t_s, rssi)
            if self.blocked:
                self.blocking_db = self._residual_db(rows, rssi, particles)
        adapted = False
        nearest = None
        if rows.size:
            strongest = int(np.argmax(rssi))
            nearest = int(rows[strongest])
            # adapt only unblocked scans: a hand over the phone is not a weaker AP
            if (self.adapt_rssi_limit_dbm is not None and not self.blocked
                    and rssi[strongest] > self.adapt_rssi_limit_dbm):
                self._adapt(nearest, rows, rssi)
                adapted = True
        self.history.append(PathLossState(
            t_s=float(t_s), blocking_db=self.blocking_db, blocked=self.blocked,
            nearest_ap=None if nearest is None else self.ap_table.keys[nearest],
            nearest_c_dbm=math.nan if nearest is None else float(self.ap_table.c_dbm[nearest]),
            adapted=adapted, n_adaptations=self.n_adaptations))

    def _residual_db(self, rows: np.ndarray, rssi: np.ndarray, particles) -> float:
        """median_k (R_k(x) - z_k) at the particles' weighted mean x, at least 0 (how much weaker than the model)."""
        w = np.exp(np.asarray(particles.log_weight, dtype=np.float64))
        if rows.size == 0 or not np.isfinite(w).all() or w.sum() <= 0:
            return 0.0
        xy = (np.asarray(particles.xy_m, dtype=np.float64) * w[:, None]).sum(axis=0) / w.sum()
        t = self.ap_table
        d = np.hypot(*(t.xy_m[rows] - xy).T)
        expected = path_loss_rssi_dbm(d, t.c_dbm[rows], t.n[rows], t.alpha_db_per_m[rows], t.d_max_m[rows])
        return max(float(np.median(expected - rssi)), 0.0)

    def _update_blocking(self, t_s: float, rssi: np.ndarray) -> None:
        """Thesis 7.3: blocked when the top-k mean RSSI falls more than ``blocking_drop_db`` below its
        reference; recovered when it is back."""
        if rssi.size == 0:
            return
        level = float(np.sort(rssi)[::-1][:BLOCKING_TOP_K].mean())
        if self._reference_dbm is None:
            self._reference_dbm = level
            return
        drop = self._reference_dbm - level
        if self.blocked:
            if drop <= BLOCKING_RECOVER_DB or t_s - self._blocked_since_s > MAX_BLOCKED_S:
                self.blocked = False
                self.blocking_db = 0.0
                # back to normal: the reference restarts here (after a long episode it was stale)
                self._reference_dbm = level if drop > BLOCKING_RECOVER_DB else self._reference_dbm
            else:
                return
        elif drop > self.blocking_drop_db:
            self.blocked = True
            self._blocked_since_s = float(t_s)
            return
        self._reference_dbm += BLOCKING_REFERENCE_GAIN * (level - self._reference_dbm)

    def _adapt(self, nearest: int, rows: np.ndarray, rssi: np.ndarray) -> None:
        """Thesis 7.1-7.2: C of the AP the phone is below (every band of it heard), then alpha per band."""
        t = self.ap_table
        d_v = max(VERTICAL_DISTANCE_M, MIN_DISTANCE_M)
        below = [k for k, row in enumerate(rows) if t.bssid[row] == t.bssid[nearest]]  # same radio, any band
        for k in below:
            i = int(rows[k])
            # the model solved for C at the vertical distance, line of sight: C = z + 10 n log10(d_v) + alpha d_v
            c_obs = float(rssi[k]) + 10.0 * t.n[i] * math.log10(d_v) + t.alpha_db_per_m[i] * min(d_v, t.d_max_m[i])
            t.c_dbm[i] += C_GAIN * (c_obs - t.c_dbm[i])
            self.c_adapted[i] = True
        self.n_adaptations += 1
        # APs never passed take the median C correction of their band's adapted APs
        for band in self.alpha_by_band_db_per_m:
            in_band = self._band == band
            done = in_band & self.c_adapted
            if done.any():
                correction = float(np.median(t.c_dbm[done] - self._c_initial_dbm[done]))
                t.c_dbm[in_band & ~self.c_adapted] = self._c_initial_dbm[in_band & ~self.c_adapted] + correction
        # an AP's alpha observation is only as good as its C: a band counts once one of its APs adapted
        c_known = np.ones(len(t), dtype=bool)
        for band in self.alpha_by_band_db_per_m:
            in_band = self._band == band
            c_known[in_band] &= self.c_adapted[in_band].any()

        # alpha per band from the other APs, seen from the nearest AP's position:
        # alpha_j = (C_j - 10 n_j log10(d_ij) - z_j) / min(d_ij, d_max_j)
        others = (np.array([t.bssid[r] != t.bssid[nearest] for r in rows], dtype=bool) & c_known[rows]
                  if rows.size else np.zeros(0, dtype=bool))
        j = rows[others]
        z_j = rssi[others]
        # horizontal, as everywhere in our model (the phone stands below the nearest AP)
        d_ij = np.maximum(np.hypot(*(t.xy_m[j] - t.xy_m[nearest]).T), MIN_DISTANCE_M)
        far = d_ij >= ALPHA_MIN_DISTANCE_M
        lo, hi = ALPHA_BOUNDS_DB_PER_M
        for band, alpha_band in self.alpha_by_band_db_per_m.items():
            use = far & (self._band[j] == band)
            if use.sum() < ALPHA_MIN_APS:
                continue
            jj, dd = j[use], d_ij[use]
            alpha_obs = (t.c_dbm[jj] - 10.0 * t.n[jj] * np.log10(dd) - z_j[use]) / np.minimum(dd, t.d_max_m[jj])
            observed = float(np.clip(np.median(alpha_obs), lo, hi))  # median: walls and noise hit single APs
            alpha_band += ALPHA_GAIN * (observed - alpha_band)
            self.alpha_by_band_db_per_m[band] = alpha_band
            t.alpha_db_per_m[self._band == band] = alpha_band


def check_adaptive_settings(adapt_rssi_limit_dbm: float | None, blocking_drop_db: float | None) -> None:
    """``MapfilterError`` for an RSSI limit that is no number or a drop below the recovery level."""
    if adapt_rssi_limit_dbm is not None and not math.isfinite(adapt_rssi_limit_dbm):
        raise MapfilterError(f"the adaptation RSSI limit must be a number of dBm, got {adapt_rssi_limit_dbm}")
    if blocking_drop_db is not None and not (BLOCKING_RECOVER_DB <= blocking_drop_db < math.inf):
        raise MapfilterError(f"the blocking drop must be at least the {BLOCKING_RECOVER_DB:g} dB the signals recover "
                             f"within, got {blocking_drop_db} dB")
