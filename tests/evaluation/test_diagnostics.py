"""Per-walk diagnostics: coverage, fix bias and scatter, heading-offset error, step scale."""

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import pytest
sys.path[:0] = [str(Path(__file__).parents[1] / "sensors"), str(Path(__file__).parents[1] / "offline")]
from test_pdr import make_recording  # noqa: E402
from test_placement import l_shaped_steps, truth_at  # noqa: E402

from mapfilter.evaluation.diagnostics import DIAGNOSTIC_COLUMNS, walk_diagnostics
from mapfilter.sensors.radiomap import RadioMap


def test_a_biased_walk_far_from_the_survey_says_so():
    offset = 0.5
    steps = l_shaped_steps(offset + math.radians(10))  # rotation vector 10 deg off the truth
    wp_t = 1000.0 + 5.0 * np.arange(9)
    recording = dataclasses.replace(make_recording(None, None), waypoint_t_s=wp_t,
                                    waypoint_xy_m=truth_at(steps, offset, [0.0, 0.0], wp_t) * 1.1)  # steps 10 % short
    scan_t = 1000.0 + 2.0 * np.arange(1, 20)
    truth = np.column_stack([np.interp(scan_t, wp_t, recording.waypoint_xy_m[:, 0]),
                             np.interp(scan_t, wp_t, recording.waypoint_xy_m[:, 1])])
    rng = np.random.default_rng(0)
    scatter = rng.normal(0.0, 1.0, truth.shape)
    fixes = truth + [6.0, -8.0] + scatter  # one 10 m bias per walk
    survey = RadioMap(np.array([[100.0, 100.0], [100.0, 130.0]]), ["a"], np.full((2, 1), -60.0, np.float32),
                      np.zeros(2), np.zeros(2, np.int64), ["s"])
    d = walk_diagnostics(recording, scan_t, fixes, survey, steps)
    assert set(d) == set(DIAGNOSTIC_COLUMNS)
    assert abs(d["fix_bias_m"] - 10.0) < 1.0 and d["fix_scatter_m"] < 2.0
    assert d["fix_error_m"] > 8.0
    assert d["coverage_m"] > 80.0
    assert abs(d["heading_offset_error_deg"] - 10.0) < 1.0
    assert abs(d["step_scale"] - 1.1) < 0.02


def test_signal_distance_is_small_for_a_walk_that_hears_like_the_survey_and_large_otherwise():
    from mapfilter.sensors.recording import WifiScans

    keys = [f"02:00:00:00:03:{j:02x}@5" for j in range(4)]
    survey = RadioMap(np.array([[0.0, 0.0], [10.0, 0.0]]), keys,
                      np.array([[-50, -60, -70, -80], [-80, -70, -60, -50]], np.float32), np.zeros(2),
                      np.zeros(2, np.int64), ["s"])

    def walk(levels):
        n = len(levels)
        wifi = WifiScans(t_s=np.arange(n, dtype=float), ap_keys=keys, row_scan=np.repeat(np.arange(n), 4),
                         row_ap=np.tile(np.arange(4), n), rssi_dbm=np.array(levels, np.float32).ravel(),
                         freq_mhz=np.full(4 * n, 5180.0, np.float32), age_s=np.zeros(4 * n, np.float32))
        return dataclasses.replace(make_recording(None, None), wifi=wifi, waypoint_t_s=np.array([0.0, 1.0]),
                                   waypoint_xy_m=np.zeros((2, 2)))

    like = walk([[-51, -60, -70, -79], [-80, -71, -60, -51]])  # 0.7 dB RMS from a reference point
    unlike = walk([[-65, -65, -65, -65], [-65, -66, -64, -65]])  # 11 dB from both
    near = walk_diagnostics(like, like.wifi.t_s, None, survey, None)["signal_distance_db"]
    far = walk_diagnostics(unlike, unlike.wifi.t_s, None, survey, None)["signal_distance_db"]
    assert near == pytest.approx(math.sqrt(2 / 4), rel=1e-6) and 10.0 < far < 12.0


def test_without_fixes_radio_map_or_steps_the_numbers_are_nan():
    recording = dataclasses.replace(make_recording(None, None), waypoint_t_s=np.array([0.0, 1.0]),
                                    waypoint_xy_m=np.zeros((2, 2)))
    d = walk_diagnostics(recording, np.zeros(0), None, None, None)
    assert all(math.isnan(v) for v in d.values())
