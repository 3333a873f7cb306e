"""Simulated walks written as ILC 2.0 trace files (plain or gzip), byte for byte the same for a seed."""

from __future__ import annotations

import gzip
import os
from pathlib import Path

import numpy as np

from mapfilter.io.atomic import atomic_paths
from mapfilter.simulate.walk import SimConfig, SimulatedWalk


def _ms(t_s: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(t_s, dtype=np.float64) * 1000.0).astype(np.int64)


def format_ilc(walk: SimulatedWalk, ssid: str = SimConfig.ssid) -> str:
    """The whole trace as ILC text (header, records sorted by time, end line)."""
    times: list[np.ndarray] = []
    ranks: list[np.ndarray] = []
    lines: list[str] = []

    def add(t_s: np.ndarray, rank: int, texts: list[str]) -> None:
        times.append(_ms(t_s))
        ranks.append(np.full(len(texts), rank, dtype=np.int64))
        lines.extend(texts)

    wp_ms = _ms(walk.waypoint_t_s)
    if walk.waypoint_floor is None:
        add(walk.waypoint_t_s, 0, [f"{t}\tTYPE_WAYPOINT\t{x:.6f}\t{y:.6f}"
                                   for t, (x, y) in zip(wp_ms.tolist(), walk.waypoint_xy_m.tolist())])
    else:  # several floors: the waypoint's floor in a fifth column (floor frame x, y)
        add(walk.waypoint_t_s, 0, [f"{t}\tTYPE_WAYPOINT\t{x:.6f}\t{y:.6f}\t{floor}"
                                   for t, (x, y), floor in zip(wp_ms.tolist(), walk.waypoint_xy_m.tolist(),
                                                               walk.waypoint_floor)])
    # same order within one millisecond as the real logs: acc, magnet, gyro, rotation vector
    for rank, (kind, t_s, values, accuracy) in enumerate((
            ("TYPE_ACCELEROMETER", walk.acc_t_s, walk.acc_mps2, 2),
            ("TYPE_MAGNETIC_FIELD", walk.magnet_t_s, walk.magnet_ut, 3),
            ("TYPE_GYROSCOPE", walk.gyro_t_s, walk.gyro_radps, 3),
            ("TYPE_ROTATION_VECTOR", walk.rotvec_t_s, walk.rotvec_xyz, 3)), start=1):
        add(t_s, rank, [f"{t}\t{kind}\t{a:.7g}\t{b:.7g}\t{c:.7g}\t{accuracy}"
                        for t, (a, b, c) in zip(_ms(t_s).tolist(), values.tolist())])
    if walk.pressure_t_s is not None:
        add(walk.pressure_t_s, 6, [f"{t}\tTYPE_PRESSURE\t{p:.4f}\t3"
                                   for t, p in zip(_ms(walk.pressure_t_s).tolist(), walk.pressure_hpa.tolist())])
    scan_ms = _ms(walk.scan_t_s)[walk.row_scan]
    seen_ms = _ms(walk.seen_t_s)
    add(walk.scan_t_s[walk.row_scan], 5, [
        f"{t}\tTYPE_WIFI\t{ssid}\t{walk.ap_bssid[a]}\t{r}\t{walk.ap_freq_mhz[a]}\t{seen}"
        for t, a, r, seen in zip(scan_ms.tolist(), walk.row_ap.tolist(), walk.rssi_dbm.tolist(), seen_ms.tolist())])
    t_all = np.concatenate(times)
    r_all = np.concatenate(ranks)
    order = np.lexsort((np.arange(t_all.size), r_all, t_all))
    floor = walk.floor_name or ""
    head = [f"#\tstartTime:{_ms(walk.start_t_s)}",
            f"#\tSiteID:{walk.site_id}\tSiteName:{walk.site_id}\tFloorId:{walk.site_id}-{floor}\tFloorName:{floor}"]
    tail = [f"#\tendTime:{_ms(walk.end_t_s)}"]
    return "\n".join(head + [lines[i] for i in order.tolist()] + tail) + "\n"


def write_ilc(walk: SimulatedWalk, path: str | os.PathLike, ssid: str = SimConfig.ssid) -> None:
    """Write the walk as an ILC trace, gzip-compressed if ``path`` ends in ``.gz``, atomically.

    The gzip header carries no time stamp or name, so the same walk gives the same bytes.
    """
    path = Path(path)
    data = format_ilc(walk, ssid).encode("utf-8")
    with atomic_paths(path) as (tmp,):
        if path.suffix == ".gz":
            with tmp.open("wb") as raw, gzip.GzipFile(filename="", mode="wb", fileobj=raw, mtime=0) as handle:
                handle.write(data)
        else:
            tmp.write_bytes(data)
