"""Why a walk went wrong: per-walk diagnostics against its ground truth.

Measured on ILC site 1, most of a walk's error is one of three things, and each has a number:

- ``coverage_m``: median distance from the walk's waypoints to the nearest reference point of
  the radio map it was tracked with. Fingerprints cannot place a walk where nobody surveyed.
- ``signal_distance_db``: the same in signal space, with no ground truth needed: median over
  the walk's scans of the RMS difference per AP (strong readings, as the filter's fixes) to the
  nearest reference point. Large where the walk went beyond the survey, or the phone hears
  unlike the survey phones.
- ``fix_error_m``, ``fix_bias_m``, ``fix_scatter_m``: the WiFi fixes against the ground truth
  interpolated at the scan times: median error, the length of the median offset (one bias
  per walk: averaging more fixes cannot remove it) and the median scatter around that offset.
- ``heading_offset_error_deg``: the rotation vector's gyro-to-map heading offset (what the
  trackers start from) against the offset that best turns the dead-reckoned legs onto the
  waypoint legs; ``step_scale``: waypoint path length over dead-reckoned length between the
  first and last waypoint (1 = step lengths right).
"""

from __future__ import annotations

import math

import numpy as np

from mapfilter.offline.placement import pdr_shape, rotation_vector_heading_offset
from mapfilter.sensors.pdr import Steps
from mapfilter.sensors.radiomap import STRONG_MIN_RSSI_DBM, STRONG_MISSING_DBM, RadioMap, kwnn_fix_many
from mapfilter.sensors.recording import Recording
from mapfilter.sensors.wifi import iter_scans

DIAGNOSTIC_COLUMNS = ("coverage_m", "signal_distance_db", "fix_error_m", "fix_bias_m", "fix_scatter_m",
                      "heading_offset_error_deg", "step_scale")
MIN_LEG_M = 3.0  # waypoint legs shorter than this say little about the heading


def walk_diagnostics(recording: Recording, scan_t_s: np.ndarray, fix_xy_m: np.ndarray | None,
                     radio_map: RadioMap | None, steps: Steps | None) -> dict[str, float]:
    """The numbers of the module docstring for one walk (NaN where they cannot be had)."""
    out = {name: math.nan for name in DIAGNOSTIC_COLUMNS}
    wp_t, wp_xy = recording.waypoint_t_s, recording.waypoint_xy_m
    if wp_t.size == 0:
        return out
    if radio_map is not None and len(radio_map) > 0:
        from scipy.spatial import cKDTree

        out["coverage_m"] = float(np.median(cKDTree(radio_map.xy_m).query(wp_xy)[0]))
        scans = list(iter_scans(recording))
        if scans:
            nearest = kwnn_fix_many(radio_map, radio_map.scan_matrix(scans), k=1, missing_dbm=STRONG_MISSING_DBM,
                                    min_rssi_dbm=STRONG_MIN_RSSI_DBM, per_ap=True).distance_db[:, 0]
            if np.isfinite(nearest).any():
                out["signal_distance_db"] = float(np.nanmedian(nearest))
    if fix_xy_m is not None and wp_t.size >= 2:
        t = np.asarray(scan_t_s, dtype=np.float64)
        ok = np.all(np.isfinite(fix_xy_m), axis=1) & (t >= wp_t[0]) & (t <= wp_t[-1])
        if ok.any():
            truth = np.column_stack([np.interp(t[ok], wp_t, wp_xy[:, 0]), np.interp(t[ok], wp_t, wp_xy[:, 1])])
            offset = fix_xy_m[ok] - truth
            bias = np.median(offset, axis=0)
            out["fix_error_m"] = float(np.median(np.linalg.norm(offset, axis=1)))
            out["fix_bias_m"] = float(np.linalg.norm(bias))
            out["fix_scatter_m"] = float(np.median(np.linalg.norm(offset - bias, axis=1)))
    if steps is not None and len(steps) >= 2 and wp_t.size >= 2:
        shape_t, shape_xy = pdr_shape(steps, 0.0)
        at_wp = np.column_stack([np.interp(wp_t, shape_t, shape_xy[:, 0]), np.interp(wp_t, shape_t, shape_xy[:, 1])])
        legs_truth, legs_pdr = np.diff(wp_xy, axis=0), np.diff(at_wp, axis=0)
        long = (np.linalg.norm(legs_truth, axis=1) >= MIN_LEG_M) & (np.linalg.norm(legs_pdr, axis=1) > 0)
        rotation_vector = rotation_vector_heading_offset(steps)
        if long.any() and rotation_vector is not None:
            diff = np.arctan2(legs_truth[long, 1], legs_truth[long, 0]) - np.arctan2(legs_pdr[long, 1], legs_pdr[long, 0])
            weight = np.linalg.norm(legs_truth[long], axis=1)
            best = math.atan2(float((weight * np.sin(diff)).sum()), float((weight * np.cos(diff)).sum()))
            error = (rotation_vector - best + math.pi) % (2 * math.pi) - math.pi
            out["heading_offset_error_deg"] = float(np.degrees(error))
        walked = float(np.linalg.norm(legs_pdr, axis=1).sum())
        if walked > 0:
            out["step_scale"] = float(np.linalg.norm(legs_truth, axis=1).sum() / walked)
    return out
