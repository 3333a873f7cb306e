"""WiFi: access points, path-loss models, radio maps, fingerprint and trilateration models.

Access points are keyed by BSSID *and* band (``"aa:bb:cc:dd:ee:ff@2.4"`` / ``"...@5"``):
one physical box often serves both bands with one BSSID, at different power and loss.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import os
from pathlib import Path

import numpy as np

from mapfilter.atomic import atomic_paths
from mapfilter.errors import MapfilterError

# Lund thesis (Karlsson & Karlsson) defaults for R(d) = C - 10 n log10(d) - alpha min(d, d_max).
DEFAULT_C_DBM = -38.0
DEFAULT_PATH_LOSS_EXPONENT = 2.0
DEFAULT_ALPHA_DB_PER_M = 0.4
DEFAULT_D_MAX_M = 30.0
MIN_DISTANCE_M = 1.0  # C is the RSSI at the 1 m reference distance; closer is not modelled


def band_of_frequency(freq_mhz: float) -> str:
    """"2.4" for 2.4 GHz channels, "5" for 5 GHz (and 6 GHz) channels."""
    return "2.4" if freq_mhz < 3000 else "5"


def ap_key(bssid: str, band: str) -> str:
    return f"{bssid.lower()}@{band}"


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

    COLUMNS = ("bssid", "x", "y", "band", "C", "n", "alpha", "d_max")

    def __len__(self) -> int:
        return len(self.bssid)

    @property
    def keys(self) -> list[str]:
        return [ap_key(b, band) for b, band in zip(self.bssid, self.band)]

    def expected_rssi_dbm(self, xy_m: np.ndarray) -> np.ndarray:
        """Expected RSSI of every AP at every point: shape (P, K) for points (P, 2)."""
        d = np.linalg.norm(np.asarray(xy_m, dtype=np.float64)[:, None, :] - self.xy_m[None, :, :], axis=-1)
        return path_loss_rssi_dbm(d, self.c_dbm, self.n, self.alpha_db_per_m, self.d_max_m)

    @classmethod
    def read_csv(cls, path: str | os.PathLike) -> AccessPointTable:
        """Read ``bssid,x,y,band,C,n,alpha,d_max`` (band, C, n, alpha, d_max optional: thesis defaults)."""
        path = Path(path)
        if not path.is_file():
            raise MapfilterError("file not found", path)
        rows: dict[str, list] = {c: [] for c in cls.COLUMNS}
        with path.open(newline="") as handle:
            reader = csv.DictReader(handle)
            if reader.fieldnames is None or not {"bssid", "x", "y"} <= set(reader.fieldnames):
                raise MapfilterError("an access-point table needs the columns bssid,x,y", path, 1)
            defaults = {"band": "2.4", "C": DEFAULT_C_DBM, "n": DEFAULT_PATH_LOSS_EXPONENT,
                        "alpha": DEFAULT_ALPHA_DB_PER_M, "d_max": DEFAULT_D_MAX_M}
            for line_no, row in enumerate(reader, start=2):
                bssid = (row.get("bssid") or "").strip()
                if not bssid:
                    raise MapfilterError("empty bssid", path, line_no)
                rows["bssid"].append(bssid.lower())
                band = (row.get("band") or defaults["band"]).strip()
                if band not in ("2.4", "5"):
                    raise MapfilterError(f"band must be 2.4 or 5, got {band!r}", path, line_no)
                rows["band"].append(band)
                for column in ("x", "y", "C", "n", "alpha", "d_max"):
                    text = row.get(column)
                    if text in (None, "") and column in defaults:
                        value = float(defaults[column])
                    else:
                        try:
                            value = float(text)  # type: ignore[arg-type]
                        except (TypeError, ValueError):
                            raise MapfilterError(f"column {column} is not a number: {text!r}", path, line_no) from None
                    if not math.isfinite(value):
                        raise MapfilterError(f"column {column} is not finite: {text!r}", path, line_no)
                    rows[column].append(value)
        if not rows["bssid"]:
            raise MapfilterError("the access-point table has no rows", path)
        return cls(
            bssid=rows["bssid"], band=rows["band"],
            xy_m=np.column_stack([rows["x"], rows["y"]]).astype(np.float64),
            c_dbm=np.array(rows["C"]), n=np.array(rows["n"]),
            alpha_db_per_m=np.array(rows["alpha"]), d_max_m=np.array(rows["d_max"]),
        )

    def write_csv(self, path: str | os.PathLike) -> None:
        with atomic_paths(path) as (tmp,):
            with tmp.open("w", newline="") as handle:
                writer = csv.writer(handle)
                writer.writerow(self.COLUMNS)
                for i in range(len(self)):
                    writer.writerow([self.bssid[i], f"{self.xy_m[i, 0]:.3f}", f"{self.xy_m[i, 1]:.3f}", self.band[i],
                                     f"{self.c_dbm[i]:.2f}", f"{self.n[i]:.3f}", f"{self.alpha_db_per_m[i]:.3f}",
                                     f"{self.d_max_m[i]:.1f}"])
