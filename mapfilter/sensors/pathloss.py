"""Access points and the path-loss model: the table, trilateration, fitting APs from surveys.

The Lund thesis (Karlsson & Karlsson) model R(d) = C - 10 n log10(d) - alpha min(d, d_max)
per access point and band; an ``AccessPointTable`` holds its parameters (CSV on disk),
``least_squares_position`` is the trilateration baseline and ``estimate_access_points`` fits
the table from waypoint-labelled scans. The per-particle likelihood of this model lives with
the other measurement models in ``mapfilter.filter.models``.
"""

from __future__ import annotations

import dataclasses
import functools
import io
import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from mapfilter.io.atomic import write_csv_atomically
from mapfilter.errors import MapfilterError, not_a_file
from mapfilter.sensors.radiomap import RSSI_RANGE_DBM, RadioMap, build_radio_map, map_extents_m, metres_outside
from mapfilter.sensors.wifi import WifiScan, ap_key

if TYPE_CHECKING:  # only for annotations
    from mapfilter.sensors.recording import Recording

# Lund thesis (Karlsson & Karlsson) defaults for R(d) = C - 10 n log10(d) - alpha min(d, d_max).
DEFAULT_C_DBM = -38.0
DEFAULT_PATH_LOSS_EXPONENT = 2.0
DEFAULT_ALPHA_DB_PER_M = 0.4
DEFAULT_D_MAX_M = 30.0
MIN_DISTANCE_M = 1.0  # C is the RSSI at the 1 m reference distance; closer is not modelled

# What an access-point table's columns can be (a row outside is refused, naming its line): the
# thesis has C about -38 dBm, n about 2, alpha 0.3-0.5 dB/m, d_max 30 m; fitted exponents lie in
# 1.5-5 (ApFitConfig.n_bounds). Positions: within 10 000 km of the origin (any projected frame),
# and, where the table meets a map, within MAX_AP_OFF_MAP_M of it (WiFi reaches about 100 m
# indoors; an access point further off cannot be heard on the floor).
COLUMN_RANGES = {"x": (-1e7, 1e7), "y": (-1e7, 1e7), "C": (-120.0, 20.0), "n": (0.5, 10.0),
                 "alpha": (0.0, 10.0), "d_max": (0.0, 10_000.0)}
MAX_AP_OFF_MAP_M = 500.0


def path_loss_rssi_dbm(distance_m, c_dbm, n, alpha_db_per_m, d_max_m):
    """Expected RSSI (dBm) at ``distance_m``: R(d) = C - 10 n log10(d) - alpha min(d, d_max).

    Lund thesis path-loss model; broadcasts over numpy arrays. Distances below 1 m are
    clamped to 1 m, the reference distance of C.
    """
    d = np.maximum(distance_m, MIN_DISTANCE_M)
    return c_dbm - 10.0 * n * np.log10(d) - alpha_db_per_m * np.minimum(d, d_max_m)



@dataclasses.dataclass
class AccessPointTable:
    """Access points with positions and per-AP path-loss parameters (arrays of length K)."""

    bssid: list[str]
    band: list[str]  # "2.4" or "5"
    xy_m: np.ndarray  # (K, 2)
    c_dbm: np.ndarray
    n: np.ndarray
    alpha_db_per_m: np.ndarray
    d_max_m: np.ndarray
    source_path: Path | None = None  # the CSV it was read from (for messages), or None
    source_lines: list[int] | None = None  # the CSV line of each row, or None

    COLUMNS = ("bssid", "x", "y", "band", "C", "n", "alpha", "d_max")

    def __len__(self) -> int:
        return len(self.bssid)

    @property
    def keys(self) -> list[str]:
        return [ap_key(b, band) for b, band in zip(self.bssid, self.band)]

    @functools.cached_property
    def key_index(self) -> dict[str, int]:
        """Row of each AP key ("bssid@band")."""
        return {key: i for i, key in enumerate(self.keys)}

    def expected_rssi_dbm(self, xy_m: np.ndarray) -> np.ndarray:
        """Expected RSSI of every AP at every point: shape (P, K) for points (P, 2)."""
        d = np.linalg.norm(np.asarray(xy_m, dtype=np.float64)[:, None, :] - self.xy_m[None, :, :], axis=-1)
        return path_loss_rssi_dbm(d, self.c_dbm, self.n, self.alpha_db_per_m, self.d_max_m)

    @classmethod
    def read_csv(cls, path: str | os.PathLike) -> AccessPointTable:
        """Read ``bssid,x,y,band,C,n,alpha,d_max`` (band, C, n, alpha, d_max optional: thesis defaults)."""
        path = Path(path)
        if not path.is_file():
            raise not_a_file(path)
        rows: dict[str, list] = {c: [] for c in cls.COLUMNS}
        lines: list[int] = []
        first_line: dict[tuple[str, str], int] = {}  # (bssid, band) -> its line
        from mapfilter.io.tables import finite_number, read_table_text, table_dict_reader

        # UTF-8 with or without the byte-order mark Excel writes; another encoding, or a file over
        # the bound, is one line
        text = read_table_text(path, "an access-point table")
        with io.StringIO(text, newline="") as handle:
            reader = table_dict_reader(handle, path)
            if reader.fieldnames is None or not {"bssid", "x", "y"} <= set(reader.fieldnames):
                raise MapfilterError("an access-point table needs the columns bssid,x,y", path, 1)
            defaults = {"band": "2.4", "C": DEFAULT_C_DBM, "n": DEFAULT_PATH_LOSS_EXPONENT,
                        "alpha": DEFAULT_ALPHA_DB_PER_M, "d_max": DEFAULT_D_MAX_M}
            for row in reader:
                line_no = reader.line_num  # the row's (last) line in the file: blank lines are skipped
                lines.append(line_no)
                bssid = (row.get("bssid") or "").strip()
                if not bssid:
                    raise MapfilterError("empty bssid", path, line_no)
                rows["bssid"].append(bssid.lower())
                band = (row.get("band") or defaults["band"]).strip()
                if band not in ("2.4", "5"):
                    raise MapfilterError(f"band must be 2.4 or 5, got {band!r}", path, line_no)
                rows["band"].append(band)
                if (bssid.lower(), band) in first_line:
                    raise MapfilterError(f"access point {bssid} ({band} GHz) is listed twice (lines "
                                         f"{first_line[bssid.lower(), band]} and {line_no}): keep one", path, line_no)
                first_line[bssid.lower(), band] = line_no
                for column in ("x", "y", "C", "n", "alpha", "d_max"):
                    text = row.get(column)
                    if text in (None, "") and column in defaults:
                        value = float(defaults[column])
                    else:
                        value = finite_number(text, column, path, line_no)
                    low, high = COLUMN_RANGES[column]
                    if not low <= value <= high:
                        raise MapfilterError(f"column {column} is {value:g}, outside the {low:g} to {high:g} an "
                                             "access point's can be", path, line_no)
                    rows[column].append(value)
        if not rows["bssid"]:
            raise MapfilterError("the access-point table has no rows", path)
        return cls(
            bssid=rows["bssid"], band=rows["band"],
            xy_m=np.column_stack([rows["x"], rows["y"]]).astype(np.float64),
            c_dbm=np.array(rows["C"]), n=np.array(rows["n"]),
            alpha_db_per_m=np.array(rows["alpha"]), d_max_m=np.array(rows["d_max"]),
            source_path=path, source_lines=lines,
        )

    def write_csv(self, path: str | os.PathLike) -> None:
        write_csv_atomically(path, self.COLUMNS, (
            [self.bssid[i], f"{self.xy_m[i, 0]:.3f}", f"{self.xy_m[i, 1]:.3f}", self.band[i], f"{self.c_dbm[i]:.2f}",
             f"{self.n[i]:.3f}", f"{self.alpha_db_per_m[i]:.3f}", f"{self.d_max_m[i]:.1f}"] for i in range(len(self))))


def access_points_for_map(aps_path: str | os.PathLike | None, floorplan, map_path: str | os.PathLike,
                          hint: str = "pass --aps APS.csv") -> AccessPointTable:
    """The access-point table at ``aps_path``, else the map's own (``mapfilter: access_points``
    in its YAML); ``MapfilterError`` naming the map if there is neither."""
    path = aps_path if aps_path is not None else floorplan.access_points_csv
    if path is None:
        raise MapfilterError(f"no access points: {hint}, or name a table in the map (mapfilter: access_points)",
                             map_path)
    table = AccessPointTable.read_csv(path)
    check_access_points_on_map(table, floorplan, map_path)
    return table


def check_access_points_on_map(table: AccessPointTable, plan, map_path: str | os.PathLike | None = None) -> None:
    """Refuse an access-point table that cannot belong to ``plan`` (a ``FloorPlan``, or a
    ``Building``: each floor in its own frame): an access point more than
    ``MAX_AP_OFF_MAP_M`` outside the map. ``MapfilterError`` naming the table's file and line
    (when it was read from one) and the map."""
    off_m = np.min([metres_outside(table.xy_m, extent) for extent in map_extents_m(plan)], axis=0)
    far = np.nonzero(off_m > MAX_AP_OFF_MAP_M)[0]
    if far.size == 0:
        return
    i = int(far[0])
    x, y = table.xy_m[i]
    line = table.source_lines[i] if table.source_lines is not None else None
    on = f" {map_path}" if map_path is not None else ""
    raise MapfilterError(f"access point {table.bssid[i]} at ({x:.6g}, {y:.6g}) m lies {off_m[i] / 1000:.3g} km outside "
                         f"the map{on} (at most {MAX_AP_OFF_MAP_M:g} m): is the table in the map's frame?"
                         + (f" ({far.size} such rows)" if far.size > 1 else ""), table.source_path, line)


# ---- trilateration ---------------------------------------------------------------------------
def match_scan(ap_table: AccessPointTable, scan: WifiScan) -> tuple[np.ndarray, np.ndarray]:
    """(table rows, RSSI in dBm) of the scan's APs that the table knows (by key bssid@band)."""
    index = ap_table.key_index
    rows, rssi = [], []
    for key, value in zip(scan.ap_keys, scan.rssi_dbm):
        j = index.get(key)
        if j is not None:
            rows.append(j)
            rssi.append(value)
    return np.array(rows, dtype=np.int64), np.array(rssi, dtype=np.float64)



def least_squares_position(ap_table: AccessPointTable, scan: WifiScan, min_aps: int = 3,
                           f_scale_db: float = 5.0) -> np.ndarray:
    """Least-squares trilateration baseline: the position whose model RSSI best fits the scan.

    Fits the RSSI residuals r_k - R_k(|x - a_k|) directly (no inversion to distances, which
    amplifies the noise of weak APs) with a soft-L1 robust loss, starting from the
    RSSI-weighted centroid of the strongest APs. Returns ``xy_m`` of shape (2,).
    ``MapfilterError`` if fewer than ``min_aps`` APs of the scan are in the table.
    """
    from scipy.optimize import least_squares

    rows, rssi = match_scan(ap_table, scan)
    if rows.size < min_aps:
        raise MapfilterError(f"the scan at t={scan.t_s:.3f} s shares {rows.size} access points with the table, "
                             f"trilateration needs {min_aps}")
    t = ap_table
    finite = np.isfinite(rssi)  # the reader's job, but an infinite RSSI must not make the start NaN
    rows, rssi = rows[finite], rssi[finite]
    if rows.size < min_aps:
        raise MapfilterError(f"the scan at t={scan.t_s:.3f} s shares {rows.size} access points with finite RSSI "
                             f"with the table, trilateration needs {min_aps}")
    ap_xy = t.xy_m[rows]
    strongest = np.argsort(-rssi)[:3]
    start = rssi_weighted_centroid(ap_xy[strongest], rssi[strongest])
    lo = ap_xy.min(axis=0) - 10.0
    hi = ap_xy.max(axis=0) + 10.0
    c, n, alpha, d_max = t.c_dbm[rows], t.n[rows], t.alpha_db_per_m[rows], t.d_max_m[rows]

    def residual(xy):
        d = np.hypot(ap_xy[:, 0] - xy[0], ap_xy[:, 1] - xy[1])
        return path_loss_rssi_dbm(d, c, n, alpha, d_max) - rssi

    fit = least_squares(residual, np.clip(start, lo + 1e-6, hi - 1e-6), bounds=(lo, hi), loss="soft_l1",
                        f_scale=f_scale_db)
    return fit.x


def rssi_weighted_centroid(xy_m: np.ndarray, rssi_dbm: np.ndarray) -> np.ndarray:
    """Centroid of points weighted by linear amplitude 10^(RSSI/20): nearer (stronger) dominate.

    RSSI so far from 0 dBm that the amplitudes overflow or all underflow (a reading of 1e300
    dBm, or -7000) would make the centroid NaN, and a NaN start is what made scipy's bounded
    fits fail with "Initial guess is outside of provided bounds"; those get the same weights
    relative to the strongest reading instead. ``rssi_dbm`` must be finite.
    """
    with np.errstate(over="ignore", under="ignore"):
        weight = 10.0 ** (rssi_dbm / 20.0)
        total = weight.sum()
        if not (np.isfinite(total) and total > 0):
            weight = 10.0 ** ((rssi_dbm - rssi_dbm.max()) / 20.0)
            total = weight.sum()
    return (xy_m * weight[:, None]).sum(axis=0) / total


# ---- access-point estimation -----------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class ApFitConfig:
    """How ``estimate_access_points`` fits each AP (defaults in brackets)."""

    min_observations: int = 8  # labelled scans that heard the AP; fewer: the AP is skipped
    fit_alpha: bool = False  # alpha is poorly identifiable next to n from one walk set: fixed
    alpha_db_per_m: float = DEFAULT_ALPHA_DB_PER_M
    d_max_m: float = DEFAULT_D_MAX_M
    n_bounds: tuple[float, float] = (1.5, 5.0)  # physically plausible path-loss exponents
    c_bounds_dbm: tuple[float, float] = (-75.0, -15.0)
    margin_m: float = 15.0  # the AP may sit this far outside its observations' bounding box
    strongest: int = 3  # start at the RSSI-weighted centroid of this many strongest observations
    f_scale_db: float = 5.0  # soft-L1 scale: residuals beyond it count linearly (robust)
    max_rmse_db: float = 12.0  # fits worse than this are dropped


def estimate_access_points(labelled: RadioMap | Sequence[Recording],
                           config: ApFitConfig = ApFitConfig()) -> AccessPointTable:
    """Fit each AP's position and path-loss parameters from waypoint-labelled scans.

    ``labelled`` is a radio map (labelled scans) or survey logs with waypoints (labelled
    here by ``mapfilter.sensors.radiomap.build_radio_map``). For every AP heard in at least
    ``config.min_observations`` labelled scans, bounded robust least squares fits
    (x, y, C, n) (and alpha if ``config.fit_alpha``) of the Lund model to the observed RSSI,
    starting at the RSSI-weighted centroid of the strongest observations; fits with an RMS
    residual above ``config.max_rmse_db`` are dropped. ``MapfilterError`` if no AP can be fitted.
    """
    radio_map = labelled if isinstance(labelled, RadioMap) else build_radio_map(list(labelled))

    xy_ref = radio_map.xy_m
    bssids, bands, rows = [], [], []
    tried = 0  # APs heard often enough to fit
    # readings outside what a phone reports (1e300 dBm in a hostile log: infinite in float32) are
    # not WiFi: they would make the start, and so the bounded fit, fail
    heard = (radio_map.rssi_dbm >= RSSI_RANGE_DBM[0]) & (radio_map.rssi_dbm <= RSSI_RANGE_DBM[1])
    for k, key in enumerate(radio_map.ap_keys):
        seen = np.nonzero(heard[:, k])[0]
        if seen.size < config.min_observations:
            continue
        tried += 1
        params = _fit_access_point(xy_ref[seen], radio_map.rssi_dbm[seen, k].astype(np.float64), config)
        if params is None:
            continue
        bssid, _, band = key.rpartition("@")
        bssids.append(bssid)
        bands.append(band)
        rows.append([params[0], params[1], params[2], params[3],
                     params[4] if config.fit_alpha else config.alpha_db_per_m, config.d_max_m])
    if not rows:
        if tried == 0:
            raise MapfilterError(f"no access point was heard in at least {config.min_observations} labelled scans: "
                                 "nothing to fit")
        raise MapfilterError(f"{tried} access points were heard often enough, but none fitted the path-loss model "
                             f"within {config.max_rmse_db} dB RMS")
    table = np.array(rows, dtype=np.float64)
    return AccessPointTable(bssid=bssids, band=bands, xy_m=table[:, :2].copy(), c_dbm=table[:, 2].copy(),
                            n=table[:, 3].copy(), alpha_db_per_m=table[:, 4].copy(), d_max_m=table[:, 5].copy())


def _fit_access_point(obs_xy: np.ndarray, obs_rssi: np.ndarray, config: ApFitConfig) -> np.ndarray | None:
    """(x, y, C, n[, alpha]) of one AP fitted to its observations (RSSI at positions), or None
    when the fit failed or its RMS residual is over ``max_rmse_db``."""
    from scipy.optimize import least_squares

    start, lo, hi = _fit_start_and_bounds(obs_xy, obs_rssi, config)

    def residual(p):
        alpha = p[4] if config.fit_alpha else config.alpha_db_per_m
        d = np.hypot(obs_xy[:, 0] - p[0], obs_xy[:, 1] - p[1])
        return path_loss_rssi_dbm(d, p[2], p[3], alpha, config.d_max_m) - obs_rssi

    def jacobian(p):
        # analytic: d R / d d = -10 n / (d ln 10) - alpha [d < d_max], zero where d is clamped at 1 m
        alpha = p[4] if config.fit_alpha else config.alpha_db_per_m
        dx, dy = p[0] - obs_xy[:, 0], p[1] - obs_xy[:, 1]
        d_raw = np.hypot(dx, dy)
        d = np.maximum(d_raw, MIN_DISTANCE_M)
        dr_dd = np.where(d_raw > MIN_DISTANCE_M, -10.0 * p[3] / (d * np.log(10.0)) - alpha * (d < config.d_max_m), 0.0)
        columns = [dr_dd * dx / d, dr_dd * dy / d, np.ones_like(d), -10.0 * np.log10(d)]
        if config.fit_alpha:
            columns.append(-np.minimum(d, config.d_max_m))
        return np.column_stack(columns)

    fit = least_squares(residual, start, jac=jacobian, bounds=(lo, hi), loss="soft_l1", f_scale=config.f_scale_db)
    rmse = float(np.sqrt(np.mean(fit.fun ** 2)))
    return fit.x if fit.success and rmse <= config.max_rmse_db else None


def _fit_start_and_bounds(obs_xy: np.ndarray, obs_rssi: np.ndarray,
                          config: ApFitConfig) -> tuple[np.ndarray, list[float], list[float]]:
    """Where an AP's fit starts (the RSSI-weighted centroid of the strongest observations, C
    from the strongest), within its bounds (the observations' box plus a margin)."""
    strongest = np.argsort(-obs_rssi)[: config.strongest]
    start_xy = rssi_weighted_centroid(obs_xy[strongest], obs_rssi[strongest])
    lo_xy = obs_xy.min(axis=0) - config.margin_m
    hi_xy = obs_xy.max(axis=0) + config.margin_m
    # C at the start: the strongest observation put back to 1 m with the default exponent
    d0 = np.maximum(np.linalg.norm(obs_xy[strongest[0]] - start_xy), MIN_DISTANCE_M)
    start_c = obs_rssi[strongest[0]] + 10.0 * DEFAULT_PATH_LOSS_EXPONENT * np.log10(d0)
    start = [start_xy[0], start_xy[1], start_c, DEFAULT_PATH_LOSS_EXPONENT]
    lo = [lo_xy[0], lo_xy[1], config.c_bounds_dbm[0], config.n_bounds[0]]
    hi = [hi_xy[0], hi_xy[1], config.c_bounds_dbm[1], config.n_bounds[1]]
    if config.fit_alpha:
        start.append(config.alpha_db_per_m)
        lo.append(0.0)
        hi.append(2.0)
    return np.clip(np.array(start), np.array(lo) + 1e-6, np.array(hi) - 1e-6), lo, hi
