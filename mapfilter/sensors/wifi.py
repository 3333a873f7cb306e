"""WiFi scans: the measurement type every WiFi model weighs, and the access-point keys.

Access points are keyed by BSSID *and* band (``"aa:bb:cc:dd:ee:ff@2.4"`` / ``"...@5"``):
one physical box often serves both bands with one BSSID, at different power and loss.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from mapfilter.errors import MapfilterError

if TYPE_CHECKING:  # only for annotations
    from mapfilter.sensors.recording import Recording


def band_of_frequency(freq_mhz: float) -> str:
    """"2.4" for 2.4 GHz channels, "5" for 5 GHz (and 6 GHz) channels."""
    return "2.4" if freq_mhz < 3000 else "5"


def ap_key(bssid: str, band: str) -> str:
    return f"{bssid.lower()}@{band}"



@dataclasses.dataclass(frozen=True, eq=False)
class WifiScan:
    """One WiFi scan: the measurement the WiFi models weigh particles with.

    ``ap_keys[i]`` ("bssid@2.4" / "bssid@5") was heard at ``rssi_dbm[i]``; APs not heard are
    simply absent. ``t_s`` is the scan time (Unix seconds).
    """

    t_s: float
    ap_keys: tuple[str, ...]
    rssi_dbm: np.ndarray  # (M,) float32

    def __len__(self) -> int:
        return len(self.ap_keys)


def iter_scans(recording: Recording) -> Iterator[WifiScan]:
    """Yield the WiFi scans of a recording in time order, as ``WifiScan`` objects."""
    wifi = recording.wifi
    if len(wifi) == 0:
        return
    # rows are grouped by scan (the reader's contract), so scan s spans bounds[s]:bounds[s + 1]
    bounds = np.searchsorted(wifi.row_scan, np.arange(len(wifi) + 1))
    for s in range(len(wifi)):
        rows = slice(bounds[s], bounds[s + 1])
        yield WifiScan(float(wifi.t_s[s]), tuple(wifi.ap_keys[a] for a in wifi.row_ap[rows]),
                       np.asarray(wifi.rssi_dbm[rows], dtype=np.float32))


def scans_of(recording: Recording) -> list[WifiScan]:
    """All scans of a recording; ``MapfilterError`` if it has none (a log with no usable WiFi)."""
    scans = list(iter_scans(recording))
    if not scans:
        raise MapfilterError("the log has no usable WiFi scans", recording.path)
    return scans


def scans_recording(scans: list[WifiScan]) -> Recording:
    """A recording holding only these scans (e.g. to run the filter again over a walk's scans)."""
    from mapfilter.sensors.recording import Recording, WifiScans

    keys: dict[str, int] = {}
    row_scan, row_ap, rssi = [], [], []
    for s, scan in enumerate(scans):
        for key, value in zip(scan.ap_keys, scan.rssi_dbm):
            row_scan.append(s)
            row_ap.append(keys.setdefault(key, len(keys)))
            rssi.append(value)
    n = len(rssi)
    wifi = WifiScans(np.array([s.t_s for s in scans], dtype=np.float64), list(keys), np.array(row_scan, dtype=np.int64),
                     np.array(row_ap, dtype=np.int64), np.array(rssi, dtype=np.float32), np.zeros(n, np.float32),
                     np.zeros(n, np.float32))
    return dataclasses.replace(Recording.empty(), wifi=wifi)
