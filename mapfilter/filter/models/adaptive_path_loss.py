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

__all__ = ["AdaptationConfig", "AdaptiveTrilaterationLikelihood", "BlockingConfig", "PathLossState"]


@dataclasses.dataclass(frozen=True)
class AdaptationConfig:
    """Online path-loss adaptation (Lund thesis 7.1-7.2); defaults in brackets."""

    rssi_limit_dbm: float = -36.0  # strongest RSSI above this: the phone is below that AP (thesis -36 dBm)
    # vertical distance phone-AP when "below" it. Our model's distances are horizontal and
    # clamped at the 1 m reference of C, and APs fitted in 2-D (``radiomap fit-aps``) absorb
    # their height into C: 1 m keeps C_obs in that frame. Use the real height difference
    # (thesis: ceiling APs, about 2 m) only with a table whose C means 1 m in 3-D.
    vertical_distance_m: float = 1.0  # phone-AP distance when the phone is below an AP
    c_gain: float = 0.5  # weight of a new C observation: C <- C + gain (C_obs - C)
    alpha_gain: float = 0.2  # weight of a new per-band alpha observation (median over the other APs)
    alpha_min_distance_m: float = 3.0  # other APs nearer than this say little about alpha (1/d)
    alpha_min_aps: int = 3  # an alpha observation needs at least this many other APs of the band
    alpha_bounds_db_per_m: tuple[float, float] = (0.0, 2.0)  # alpha stays within these
    # APs the walk never came close to take the median C correction of the adapted APs of
    # their band. Ours, not the thesis' (its walk passed below its few APs): a wrong table is
    # usually wrong the same way for every AP (the thesis' wrong start was one C, -25 dBm, for
    # all), and a walk past a few of 14 APs would otherwise leave most of them wrong.
    share_c_correction: bool = True  # APs never passed take their band's median C correction

    def validate(self) -> None:
        if not (math.isfinite(self.rssi_limit_dbm)):
            raise MapfilterError(f"the adaptation RSSI limit must be a number of dBm, got {self.rssi_limit_dbm}")
        if not (self.vertical_distance_m > 0 and math.isfinite(self.vertical_distance_m)):
            raise MapfilterError(f"the vertical distance must be positive, got {self.vertical_distance_m} m")
        for name in ("c_gain", "alpha_gain"):
            if not 0.0 < getattr(self, name) <= 1.0:
                raise MapfilterError(f"{name} must be in (0, 1], got {getattr(self, name)}")
        lo, hi = self.alpha_bounds_db_per_m
        if not 0.0 <= lo <= hi:
            raise MapfilterError(f"alpha bounds must be 0 <= low <= high, got {(lo, hi)}")


@dataclasses.dataclass(frozen=True)
class BlockingConfig:
    """Signal-blocking detection and compensation (Lund thesis 7.3); defaults in brackets."""

    top_k: int = 6  # the mean of the k strongest RSSI of a scan is watched (thesis: 6)
    drop_db: float = 6.0  # blocked when that mean falls this far below the reference (thesis: 6 dB)
    recover_db: float = 3.0  # ...and recovered when it is back within this (hysteresis)
    # "all or most APs drop together", checked per AP (ours; 0 = off, the thesis' rule alone):
    # at the onset at least this fraction of the APs heard in this scan and in the latest
    # unblocked one (with a changed reading: an unchanged one is a cached row) must read weaker.
    # Walking behind walls also drops the top-k mean, but some APs rise. Measured on the
    # simulated office (tools/papers/lund_thesis.py walks): 0.75 took the false detections'
    # cost in the walled office from +15 % to +6 % (PF WiFi only), but missed one onset of
    # five, whose rows were half cached (once-blocked walks +45 % instead of +5 %): off.
    min_fraction_dropped: float = 0.0  # share of APs that must drop together at an onset (0: off)
    # a scan that dropped but not together is ambiguous (an onset half in cached rows, or
    # walls): it leaves the reference alone, unless this many come in a row (the walker moved)
    max_ambiguous_scans: int = 3  # ambiguous drops in a row after which the reference follows
    reference_gain: float = 0.5  # unblocked scans pull the reference level: ref <- ref + gain (m - ref)
    # a "blocking" that lasts longer than this is taken as the walker having moved somewhere
    # weaker: the reference is reset to the current level and H to 0
    max_blocked_s: float = 60.0  # a longer blocking: the walker moved somewhere weaker (reset)
    # how big H is once blocking is detected. "residual" (ours): the median over the heard APs
    # of R_k(x) - z_k at the particles' weighted mean x before the scan, >= 0: the drop of the
    # top-k mean also holds the walker's own moves (measured on the simulated office: H 18-22 dB
    # for a 12 dB block, and a "block" that stayed after the walker turned away). "drop": the
    # fall of the top-k mean itself.
    h_source: str = "residual"  # residual: median model residual at the estimate | drop: the top-k mean's fall

    def validate(self) -> None:
        if self.top_k < 1:
            raise MapfilterError(f"blocking: top_k must be at least 1, got {self.top_k}")
        if not (0.0 <= self.recover_db <= self.drop_db):
            raise MapfilterError(f"blocking: need 0 <= recover_db <= drop_db, got {self.recover_db}, {self.drop_db}")
        if self.max_ambiguous_scans < 1:
            raise MapfilterError(f"blocking: max_ambiguous_scans must be at least 1, got {self.max_ambiguous_scans}")
        if not 0.0 <= self.min_fraction_dropped <= 1.0:
            raise MapfilterError(f"blocking: min_fraction_dropped must be in [0, 1], got {self.min_fraction_dropped}")
        if not 0.0 < self.reference_gain <= 1.0:
            raise MapfilterError(f"blocking: reference_gain must be in (0, 1], got {self.reference_gain}")
        if self.h_source not in ("residual", "drop"):
            raise MapfilterError(f"blocking: h_source must be residual or drop, got {self.h_source!r}")
        if not self.max_blocked_s > 0:
            raise MapfilterError(f"blocking: max_blocked_s must be positive, got {self.max_blocked_s}")


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
    adaptation : ``AdaptationConfig`` or None (no parameter adaptation).
    blocking : ``BlockingConfig`` or None (no blocking compensation).
    """

    kind = "trilateration"

    def __init__(self, ap_table: AccessPointTable, variance_db2: float = 25.0,
                 adaptation: AdaptationConfig | None = AdaptationConfig(),
                 blocking: BlockingConfig | None = BlockingConfig()):
        if not variance_db2 > 0:
            raise MapfilterError(f"RSSI variance must be positive, got {variance_db2}")
        if adaptation is not None:
            adaptation.validate()
        if blocking is not None:
            blocking.validate()
        self.ap_table = dataclasses.replace(ap_table, xy_m=ap_table.xy_m.copy(), c_dbm=ap_table.c_dbm.astype(float),
                                            n=ap_table.n.astype(float), d_max_m=ap_table.d_max_m.astype(float),
                                            alpha_db_per_m=ap_table.alpha_db_per_m.astype(float),
                                            bssid=list(ap_table.bssid), band=list(ap_table.band))
        self.variance_db2 = float(variance_db2)
        self.adaptation = adaptation
        self.blocking = blocking
        self._band = np.array(self.ap_table.band)
        # building alpha per band (thesis 7.2): starts at the table's mean for the band
        self.alpha_by_band_db_per_m = {b: float(self.ap_table.alpha_db_per_m[self._band == b].mean())
                                       for b in sorted(set(self.ap_table.band))}
        self._c_initial_dbm = self.ap_table.c_dbm.copy()
        self.c_adapted = np.zeros(len(self.ap_table), dtype=bool)  # C observed at least once
        self.blocking_db = 0.0
        self.blocked = False
        self._reference_dbm: float | None = None
        self._n_ambiguous = 0
        self._reference_rssi: dict[int, float] = {}  # table row -> RSSI in the latest unblocked scan
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
        if self.blocking is not None:
            self._update_blocking(t_s, rows, rssi)
            if self.blocked and self.blocking.h_source == "residual":
                self.blocking_db = self._residual_db(rows, rssi, particles)
        adapted = False
        nearest = None
        if rows.size:
            strongest = int(np.argmax(rssi))
            nearest = int(rows[strongest])
            # adapt only unblocked scans: a hand over the phone is not a weaker AP
            if self.adaptation is not None and not self.blocked and rssi[strongest] > self.adaptation.rssi_limit_dbm:
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

    def _fraction_dropped(self, rows: np.ndarray, rssi: np.ndarray) -> float:
        """Fraction of the APs heard now and in the latest unblocked scan, with a changed reading, that read weaker."""
        before = np.array([self._reference_rssi.get(int(r), np.nan) for r in rows])
        change = rssi - before
        changed = np.isfinite(change) & (change != 0.0)
        return float(np.mean(change[changed] < 0.0)) if changed.any() else 0.0

    def _update_blocking(self, t_s: float, rows: np.ndarray, rssi: np.ndarray) -> None:
        """Thesis 7.3: blocked when the top-k mean RSSI falls more than ``drop_db`` below its
        reference and most APs read weaker than in the latest unblocked scan; recovered when it is back."""
        cfg = self.blocking
        assert cfg is not None
        if rssi.size == 0:
            return
        fraction_dropped = self._fraction_dropped(rows, rssi)
        level = float(np.sort(rssi)[::-1][: cfg.top_k].mean())
        if self._reference_dbm is None:
            self._reference_dbm = level
            self._reference_rssi = {int(r): float(z) for r, z in zip(rows, rssi)}
            return
        drop = self._reference_dbm - level
        if self.blocked:
            if drop <= cfg.recover_db or t_s - self._blocked_since_s > cfg.max_blocked_s:
                self.blocked = False
                self.blocking_db = 0.0
                # back to normal: the reference restarts here (after a long episode it was stale)
                self._reference_dbm = level if drop > cfg.recover_db else self._reference_dbm
            else:
                self.blocking_db = drop
                return
        elif drop > cfg.drop_db:
            if fraction_dropped >= cfg.min_fraction_dropped:
                self.blocked = True
                self._blocked_since_s = float(t_s)
                self.blocking_db = drop
                self._n_ambiguous = 0
                return
            self._n_ambiguous += 1
            if self._n_ambiguous < cfg.max_ambiguous_scans:
                return
            self._reference_dbm = level  # the walker moved somewhere weaker: start again here
        self._n_ambiguous = 0
        self._reference_dbm += cfg.reference_gain * (level - self._reference_dbm)
        self._reference_rssi = {int(r): float(z) for r, z in zip(rows, rssi)}

    def _adapt(self, nearest: int, rows: np.ndarray, rssi: np.ndarray) -> None:
        """Thesis 7.1-7.2: C of the AP the phone is below (every band of it heard), then alpha per band."""
        cfg = self.adaptation
        assert cfg is not None
        t = self.ap_table
        d_v = max(cfg.vertical_distance_m, MIN_DISTANCE_M)
        below = [k for k, row in enumerate(rows) if t.bssid[row] == t.bssid[nearest]]  # same radio, any band
        for k in below:
            i = int(rows[k])
            # the model solved for C at the vertical distance, line of sight: C = z + 10 n log10(d_v) + alpha d_v
            c_obs = float(rssi[k]) + 10.0 * t.n[i] * math.log10(d_v) + t.alpha_db_per_m[i] * min(d_v, t.d_max_m[i])
            t.c_dbm[i] += cfg.c_gain * (c_obs - t.c_dbm[i])
            self.c_adapted[i] = True
        self.n_adaptations += 1
        if cfg.share_c_correction:
            for band in self.alpha_by_band_db_per_m:
                in_band = self._band == band
                done = in_band & self.c_adapted
                if done.any():
                    correction = float(np.median(t.c_dbm[done] - self._c_initial_dbm[done]))
                    t.c_dbm[in_band & ~self.c_adapted] = self._c_initial_dbm[in_band & ~self.c_adapted] + correction
        # an AP's alpha observation is only as good as its C: without sharing, only adapted APs count
        c_known = np.ones(len(t), dtype=bool) if cfg.share_c_correction else self.c_adapted.copy()
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
        far = d_ij >= cfg.alpha_min_distance_m
        lo, hi = cfg.alpha_bounds_db_per_m
        for band, alpha_band in self.alpha_by_band_db_per_m.items():
            use = far & (self._band[j] == band)
            if use.sum() < cfg.alpha_min_aps:
                continue
            jj, dd = j[use], d_ij[use]
            alpha_obs = (t.c_dbm[jj] - 10.0 * t.n[jj] * np.log10(dd) - z_j[use]) / np.minimum(dd, t.d_max_m[jj])
            observed = float(np.clip(np.median(alpha_obs), lo, hi))  # median: walls and noise hit single APs
            alpha_band += cfg.alpha_gain * (observed - alpha_band)
            self.alpha_by_band_db_per_m[band] = alpha_band
            t.alpha_db_per_m[self._band == band] = alpha_band
