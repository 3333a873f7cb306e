"""PDR: the online step detector on synthetic ground truth (against scipy where it filters), its
chunking and causality on real walks, heading, step length, gaps and bad input."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from mapfilter.errors import MapfilterError
from mapfilter.sensors import pdr
from mapfilter.sensors.ilc import read_ilc
from mapfilter.sensors.recording import Beacons, Recording, WifiScans

G_MPS2 = 9.81
EMPTY = np.zeros(0)


def make_recording(acc_t_s, acc_mps2, gyro_t_s=None, gyro_radps=None, rotvec_t_s=None, rotvec_xyz=None):
    """A Recording holding only the given IMU arrays."""
    def arr(t, v):
        return (EMPTY.copy(), np.zeros((0, 3))) if t is None else (np.asarray(t, float), np.asarray(v, float))
    acc_t, acc = arr(acc_t_s, acc_mps2)
    gyro_t, gyro = arr(gyro_t_s, gyro_radps)
    rot_t, rot = arr(rotvec_t_s, rotvec_xyz)
    return Recording(
        path=None, floor_name=None, start_t_s=None,
        waypoint_t_s=EMPTY.copy(), waypoint_xy_m=np.zeros((0, 2)),
        acc_t_s=acc_t, acc_mps2=acc, gyro_t_s=gyro_t, gyro_radps=gyro,
        magnet_t_s=EMPTY.copy(), magnet_ut=np.zeros((0, 3)), rotvec_t_s=rot_t, rotvec_xyz=rot,
        wifi=WifiScans(t_s=EMPTY.copy(), ap_keys=[], row_scan=np.zeros(0, np.int64), row_ap=np.zeros(0, np.int64),
                       rssi_dbm=np.zeros(0, np.float32), freq_mhz=np.zeros(0, np.float32),
                       age_s=np.zeros(0, np.float32)),
        beacons=Beacons(t_s=EMPTY.copy(), beacon_id=[], rssi_dbm=EMPTY.copy(), distance_m=EMPTY.copy()),
    )


def irregular_times(rng: np.random.Generator, duration_s: float, t0_s: float = 1.6e9) -> np.ndarray:
    """Phone-like sensor times: 18-22 ms apart, a few 60-100 ms gaps, some duplicate stamps."""
    dt = rng.uniform(0.018, 0.022, size=int(duration_s / 0.02) + 10)
    dt[rng.choice(dt.size, size=5, replace=False)] = rng.uniform(0.06, 0.1, size=5)
    dt[rng.choice(dt.size, size=5, replace=False)] = 0.0  # duplicate timestamps happen in real logs
    t = np.cumsum(dt)
    return t0_s + t[t <= duration_s]


def tilted_up(tilt_deg: float = 35.0) -> np.ndarray:
    """A unit 'up' vector in the phone frame of a phone held tilted (not flat, not upright)."""
    up = np.array([np.sin(np.radians(tilt_deg)) * 0.6, np.sin(np.radians(tilt_deg)) * 0.8, np.cos(np.radians(tilt_deg))])
    return up / np.linalg.norm(up)


def walking_acc(t_s: np.ndarray, step_t_s: np.ndarray, amplitude_mps2: float, up: np.ndarray,
                rng: np.random.Generator, noise_mps2: float = 0.3) -> np.ndarray:
    """Specific force of a walker: gravity along ``up`` plus one bounce per step, plus noise.

    Each step is one period of a raised-cosine bounce |a| = g + A (1 - cos(2 pi (t - t_k) / T_k))
    between consecutive step times (peak to peak 2 A, continuous with standing at g), so d|a|/dt
    rises through the detector's threshold once per bounce, early in it.
    """
    bounce = np.zeros_like(t_s)
    for k in range(step_t_s.size - 1):
        t0, t1 = step_t_s[k], step_t_s[k + 1]
        sel = (t_s >= t0) & (t_s < t1)
        bounce[sel] = amplitude_mps2 * (1.0 - np.cos(2 * np.pi * (t_s[sel] - t0) / (t1 - t0)))
    return (G_MPS2 + bounce)[:, None] * up[None, :] + rng.normal(0.0, noise_mps2, size=(t_s.size, 3))


def trace_of(rec, config=pdr.PDRConfig()):
    return pdr.imu_trace(rec, config)


def feed_in_chunks(records, rng: np.random.Generator | None, config=pdr.PDRConfig(),
                   sizes=(1, 1, 2, 3, 17, 64, 500, 4000)):
    """Feed (t_s, stream, values) to one OnlinePDR in chunks (random sizes; None: one record each)."""
    t_s, stream, values = records
    online = pdr.OnlinePDR(config)
    parts, i = [], 0
    while i < t_s.size:
        size = 1 if rng is None else int(rng.choice(sizes))
        parts.append(online.feed(t_s[i:i + size], stream[i:i + size], values[i:i + size]))
        i += size
    parts.append(online.close())
    return pdr.Steps.concatenate(parts, online.t0_s), online


STEP_FIELDS = ("t_s", "heading_change_rad", "heading_rad", "abs_heading_rad", "step_length_m", "weinberg_unit",
               "available_s")


def assert_same_steps(a, b):
    for name in STEP_FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=True), name
    assert a.t0_s == b.t0_s


# --------------------------------------------------------------------------------------------
# the Butterworth design and the import cost


@pytest.mark.parametrize("fs_hz", [50.0, 100.0])
def test_butterworth_sections_are_scipys(fs_hz):
    signal = pytest.importorskip("scipy.signal")
    for order in range(1, 9):
        for cutoff_hz in (0.1, 0.3, 1.0, 3.0, 7.0, 0.24 * fs_hz):
            ours = pdr.butter_lowpass_sos(order, cutoff_hz, fs_hz)
            theirs = signal.butter(order, cutoff_hz, btype="low", fs=fs_hz, output="sos")
            np.testing.assert_allclose(ours, theirs, rtol=1e-10, atol=1e-15, err_msg=f"order {order} at {cutoff_hz} Hz")
            zi = signal.sosfilt_zi(theirs)
            np.testing.assert_allclose(pdr.sos_steady_state(ours), zi, rtol=1e-9, atol=1e-13)
    # above a quarter of the sample rate scipy may split the sections otherwise: the same filter
    for order in (3, 5):
        ours = pdr.butter_lowpass_sos(order, 0.45 * fs_hz, fs_hz)
        theirs = signal.butter(order, 0.45 * fs_hz, fs=fs_hz, output="sos")
        _, h_ours = signal.sosfreqz(ours, worN=256, fs=fs_hz)
        _, h_theirs = signal.sosfreqz(theirs, worN=256, fs=fs_hz)
        np.testing.assert_allclose(h_ours, h_theirs, atol=1e-9)
    with pytest.raises(ValueError, match="cut-off"):
        pdr.butter_lowpass_sos(4, fs_hz / 2, fs_hz)


def test_importing_pdr_loads_no_scipy_signal_or_ndimage():
    import subprocess
    import sys

    code = ("import sys\nimport mapfilter.sensors.pdr\n"
            "print(','.join(m for m in sys.modules if m.startswith(('scipy.signal', 'scipy.ndimage'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == ""


# --------------------------------------------------------------------------------------------
# resampling and filtering, against scipy on the same grid


def test_the_grid_waits_for_both_sensors_and_says_when_it_could():
    rng = np.random.default_rng(4)
    t_acc = irregular_times(rng, 10.0)
    t_gyro = np.unique(irregular_times(rng, 10.0, t0_s=1.6e9 + 0.013))
    rel_gyro = t_gyro - 1.6e9
    acc = np.tile([0.0, 0.0, G_MPS2], (t_acc.size, 1)) + rng.normal(0.0, 0.2, (t_acc.size, 3))
    # a yaw rate linear in time about a vertical phone's up axis: linear interpolation is exact,
    # and so is the trapezoid on a linear rate: heading = 0.05 t^2 / 2 + 0.1 t from the grid's start
    gyro = np.column_stack([np.zeros_like(rel_gyro), np.zeros_like(rel_gyro), 0.05 * rel_gyro + 0.1])
    trace = trace_of(make_recording(t_acc, acc, t_gyro, gyro))
    assert trace.t_s[0] == max(t_acc[0], t_gyro[0])
    assert np.allclose(np.diff(trace.t_s), 0.02, atol=1e-6) and trace.t_s[-1] <= min(t_acc[-1], t_gyro[-1])
    # each grid sample was made by the first acc and gyro samples at or after it
    first_acc = t_acc[np.searchsorted(t_acc, trace.t_s, side="left")]
    first_gyro = t_gyro[np.searchsorted(t_gyro, trace.t_s, side="left")]
    np.testing.assert_array_equal(trace.available_s, np.maximum(first_acc, first_gyro))
    rel = trace.t_s - 1.6e9
    expected = 0.025 * (rel ** 2 - rel[0] ** 2) + 0.1 * (rel - rel[0])
    # the yaw rate is the gyro about low-passed gravity: its noise tilts "up" by < 0.1 %
    assert np.allclose(trace.heading_rad, expected, rtol=2e-3, atol=1e-6)


def test_filters_and_level_are_the_causal_butterworth_and_trailing_rms():
    signal = pytest.importorskip("scipy.signal")
    rng = np.random.default_rng(8)
    step_t = 2.0 + np.cumsum(rng.uniform(0.45, 0.6, 30))
    t = irregular_times(rng, 20.0)
    t = t[np.append(np.diff(t) > 0, True)]  # no repeated stamps: one value per time for np.interp
    acc = walking_acc(t - 1.6e9, step_t, 2.0, tilted_up(), rng)
    config = pdr.PDRConfig()
    trace = trace_of(make_recording(t, acc, t, np.zeros((t.size, 3))), config)
    magnitude = np.linalg.norm(np.column_stack([np.interp(trace.t_s, t, acc[:, j]) for j in range(3)]), axis=1)
    sos = signal.butter(4, 3.0, fs=50.0, output="sos")
    smooth, _ = signal.sosfilt(sos, magnitude, zi=signal.sosfilt_zi(sos) * magnitude[0])
    np.testing.assert_allclose(trace.magnitude_mps2, smooth, rtol=1e-12)
    d = np.concatenate([[0.0], np.diff(smooth) / 0.02])
    np.testing.assert_allclose(trace.step_signal_mps3, d, rtol=1e-6, atol=1e-9)
    window = 200  # 4 s at 50 Hz, trailing: the samples up to and including this one
    squares = np.concatenate([[0.0], np.cumsum(d[1:] ** 2)])
    k = np.arange(1, d.size)
    n = np.minimum(k, window)
    rms = np.sqrt((squares[k] - squares[k - n]) / n)
    level = np.clip(pdr.STEP_THRESHOLD_RMS_FRACTION * rms, pdr.MIN_STEP_THRESHOLD_MPS3, config.step_threshold_mps3)
    np.testing.assert_allclose(trace.step_level_mps3[1:], level, rtol=1e-9)


def test_step_times_are_the_crossings_of_the_level_after_the_filter_settled():
    rng = np.random.default_rng(9)
    step_t = 2.0 + np.cumsum(rng.uniform(0.45, 0.6, 30))
    t = irregular_times(rng, 20.0)
    rec = make_recording(t, walking_acc(t - 1.6e9, step_t, 2.0, tilted_up(), rng), t, np.zeros((t.size, 3)))
    trace, steps = trace_of(rec), pdr.detect_steps(rec)
    over = trace.step_signal_mps3 - trace.step_level_mps3
    settle = pdr.OnlinePDR().settle_samples
    assert settle == 33  # the 3 Hz Butterworth's slowest pole at 50 Hz falls to 1 % in 0.66 s
    idx = np.nonzero((over[:-1] < 0) & (over[1:] >= 0))[0]
    idx = idx[idx >= settle]
    crossing = trace.t_s[idx] - over[idx] / (over[idx + 1] - over[idx]) * 0.02
    kept = []
    for c in crossing:  # greedy, with the minimum interval
        if not kept or c - kept[-1] >= 0.4:
            kept.append(c)
    np.testing.assert_allclose(steps.t_s, kept, rtol=0, atol=1e-6)
    # a step is available when the grid sample after its crossing was
    np.testing.assert_array_equal(steps.available_s, trace.available_s[np.searchsorted(trace.t_s, steps.t_s - 1e-9)])
    assert np.all(steps.available_s >= steps.t_s)
    # the level is crossed where the step is put
    assert np.allclose(np.interp(steps.t_s, trace.t_s, over), 0.0, atol=0.05)


# --------------------------------------------------------------------------------------------
# step detection


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_step_count_on_synthetic_walk_with_noise_and_irregular_times(seed):
    rng = np.random.default_rng(seed)
    # stand 3 s, walk 40 bounces with varying cadence (0.45-0.65 s per step), stand 3 s
    periods_s = rng.uniform(0.45, 0.65, size=40)
    step_t = 3.0 + np.concatenate([[0.0], np.cumsum(periods_s)])
    duration_s = step_t[-1] + 3.0
    t = irregular_times(rng, duration_s)
    acc = walking_acc(t - 1.6e9, step_t, amplitude_mps2=2.5, up=tilted_up(), rng=rng)
    gyro = rng.normal(0.0, 0.01, size=(t.size, 3))
    steps = pdr.detect_steps(make_recording(t, acc, t, gyro))
    assert len(steps) == periods_s.size  # one bounce = one step; standing adds none
    # each detection lies inside its own bounce, after the filter's delay
    bounce_index = np.searchsorted(step_t + 1.6e9, steps.t_s) - 1
    assert np.array_equal(bounce_index, np.arange(periods_s.size))
    assert np.all(steps.available_s >= steps.t_s) and np.all(steps.available_s - steps.t_s < 0.15)


@pytest.mark.parametrize("seed", [5, 6, 7])
def test_standing_still_gives_no_steps(seed):
    rng = np.random.default_rng(seed)
    t = irregular_times(rng, 20.0)
    acc = G_MPS2 * tilted_up()[None, :] + rng.normal(0.0, 0.3, size=(t.size, 3))
    steps = pdr.detect_steps(make_recording(t, acc, t, np.zeros((t.size, 3))))
    assert len(steps) == 0


@pytest.mark.parametrize("seed", [1, 2])
def test_a_phone_held_softly_counts_every_step(seed, monkeypatch):
    # the same walk at a third of the bounce (the IPIN 2023 phones' d|a|/dt is a third of ILC's):
    # the fixed level of 15 m/s^3 misses most steps, the level relative to the signal none
    rng = np.random.default_rng(seed)
    periods_s = rng.uniform(0.5, 0.7, size=40)
    step_t = 3.0 + np.concatenate([[0.0], np.cumsum(periods_s)])
    t = irregular_times(rng, step_t[-1] + 3.0)
    acc = walking_acc(t - 1.6e9, step_t, amplitude_mps2=1.0, up=tilted_up(), rng=rng)
    rec = make_recording(t, acc, t, rng.normal(0.0, 0.01, size=(t.size, 3)))
    relative = pdr.detect_steps(rec)
    monkeypatch.setattr(pdr, "STEP_THRESHOLD_RMS_FRACTION", 0.0)  # the fixed level alone
    fixed = pdr.detect_steps(rec)
    assert len(fixed) < periods_s.size // 2
    assert len(relative) == periods_s.size
    bounce_index = np.searchsorted(step_t + 1.6e9, relative.t_s) - 1
    assert np.array_equal(bounce_index, np.arange(periods_s.size))


def test_the_step_level_stays_between_its_bounds(monkeypatch):
    rng = np.random.default_rng(3)
    # stand 8 s, walk hard 16 s, stand 8 s
    step_t = 8.0 + 0.5 * np.arange(33)
    t = 1.6e9 + np.arange(0, 32, 0.02)
    acc = walking_acc(t - 1.6e9, step_t, 6.0, tilted_up(), rng, noise_mps2=0.05)
    rec = make_recording(t, acc, t, np.zeros((t.size, 3)))
    config = pdr.PDRConfig()
    trace = trace_of(rec, config)
    level, rel = trace.step_level_mps3, trace.t_s - 1.6e9
    assert level.min() >= pdr.MIN_STEP_THRESHOLD_MPS3 and level.max() <= config.step_threshold_mps3
    assert np.all(level[rel < 7.9] == pdr.MIN_STEP_THRESHOLD_MPS3)  # at rest: the floor
    assert np.all(level[(rel > 10) & (rel < 24)] == config.step_threshold_mps3)  # a strong walk: the fixed level
    # trailing: the walk raises the level only once it has begun
    assert np.all(level[rel < 8.0] < config.step_threshold_mps3)
    monkeypatch.setattr(pdr, "STEP_THRESHOLD_RMS_FRACTION", 0.0)  # the fixed level alone
    fixed = trace_of(rec, config)
    assert np.all(fixed.step_level_mps3 == 15.0)


def test_min_interval_keeps_one_crossing_per_interval():
    rng = np.random.default_rng(12)
    step_t = 2.0 + 0.35 * np.arange(50)  # 2.9 bounces per second: faster than any walk
    t = 1.6e9 + np.arange(0, 20, 0.02)
    rec = make_recording(t, walking_acc(t - 1.6e9, step_t, 3.0, tilted_up(), rng, noise_mps2=0.02), t,
                         np.zeros((t.size, 3)))
    every = pdr.detect_steps(rec, pdr.PDRConfig(min_step_interval_s=0.1))
    other = pdr.detect_steps(rec, pdr.PDRConfig(min_step_interval_s=0.5))
    assert len(every) == 49
    assert np.all(np.diff(other.t_s) >= 0.5)
    assert len(other) == 25  # every other crossing survives the 0.5 s refractory time
    np.testing.assert_array_equal(other.t_s, every.t_s[::2])


# --------------------------------------------------------------------------------------------
# heading


def test_gyro_heading_about_tilted_gravity_axis():
    rng = np.random.default_rng(3)
    up = tilted_up(50.0)
    t = irregular_times(rng, 20.0)
    rel = t - t[0]
    # yaw rate: +90 deg over 2 s starting at 4 s, -135 deg over 3 s starting at 10 s
    yaw_rate = np.zeros_like(rel)
    yaw_rate[(rel >= 4) & (rel < 6)] = np.radians(90) / 2
    yaw_rate[(rel >= 10) & (rel < 13)] = -np.radians(135) / 3
    # a rotation about the vertical shows up in the phone frame as rate * up; add a rate about a
    # horizontal axis that must be ignored, and noise
    side = np.cross(up, [1.0, 0.0, 0.0])
    side /= np.linalg.norm(side)
    gyro = yaw_rate[:, None] * up + 0.5 * np.sin(2 * np.pi * 1.8 * rel)[:, None] * side
    gyro += rng.normal(0.0, 0.02, size=gyro.shape)
    step_t = np.arange(0.5, 19.5, 0.55)
    acc = walking_acc(rel, step_t, 1.5, up, rng)
    rec = make_recording(t, acc, t, gyro)
    trace = trace_of(rec)
    heading = trace.heading_rad
    assert heading[0] == 0.0
    at = np.interp(t[0] + np.array([3.5, 8.0, 16.0]), trace.t_s, heading)
    assert np.degrees(at) == pytest.approx([0.0, 90.0, -45.0], abs=3.0)
    steps = pdr.detect_steps(rec)
    assert steps.t0_s == trace.t_s[0]
    # (np.interp's slopes carry the grid times' round-off at Unix times, 2e-7 s in 0.02 s)
    np.testing.assert_allclose(steps.heading_rad, np.interp(steps.t_s, trace.t_s, heading), atol=1e-6)
    assert np.sum(steps.heading_change_rad) == pytest.approx(steps.heading_rad[-1], abs=1e-9)


def _quaternion_xyzw(axis, angle_rad):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.concatenate([np.sin(angle_rad / 2) * axis, [np.cos(angle_rad / 2)]])


def _quat_mul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz])


@pytest.mark.parametrize("azimuth_deg", [0.0, 30.0, 100.0, -150.0])
def test_rotation_vector_heading_is_half_pi_minus_azimuth(azimuth_deg):
    # phone pitched 30 deg up about its x axis, then turned so its y axis points azimuth_deg
    # clockwise from north: the map heading (counter-clockwise from east) is 90 - azimuth
    yaw = _quaternion_xyzw([0, 0, 1], -np.radians(azimuth_deg))  # yaw about up is counter-clockwise
    pitch = _quaternion_xyzw([1, 0, 0], np.radians(30.0))
    q = _quat_mul(yaw, pitch)
    q = q if q[3] >= 0 else -q  # Android reports w >= 0
    t = 1.6e9 + np.arange(0, 5, 0.02)
    rot = np.repeat(q[None, :3], t.size, axis=0)
    rec = make_recording(t, np.tile([0, 0, G_MPS2], (t.size, 1)), t, np.zeros((t.size, 3)), t, rot)
    heading = trace_of(rec).abs_heading_rad
    # the first grid sample is made by the gyroscope's first sample, which comes before the
    # rotation vector's of the same time: it has none yet
    assert np.isnan(heading[0])
    expected = np.radians(90.0 - azimuth_deg)
    assert np.allclose(pdr.wrap_angle(heading[1:] - expected), 0.0, atol=1e-6)
    assert np.all((heading[1:] >= -np.pi) & (heading[1:] < np.pi))
    offset = pdr.PDRConfig(abs_heading_offset_rad=0.25)
    shifted = trace_of(rec, offset).abs_heading_rad
    assert np.allclose(pdr.wrap_angle(shifted[1:] - expected - 0.25), 0.0, atol=1e-6)


def test_rotation_vector_heading_is_continuous_through_the_w_sign_flip():
    # a flat phone turning at constant rate through azimuth 180 deg: Android's w >= 0 flips
    # the sign of (x, y, z) there; the heading must still turn smoothly
    t = 1.6e9 + np.arange(0, 4, 0.02)
    t_rot = t[::3] + 0.007  # rotation vector on its own, coarser clock
    azimuth = np.radians(150.0 + 15.0 * (t_rot - 1.6e9))  # 150 -> 210 deg
    q = np.array([_quaternion_xyzw([0, 0, 1], -a) for a in azimuth])
    q[q[:, 3] < 0] *= -1.0
    rec = make_recording(t, np.tile([0, 0, G_MPS2], (t.size, 1)), t, np.zeros((t.size, 3)), t_rot, q[:, :3])
    trace = trace_of(rec)
    expected = np.pi / 2 - np.radians(150.0 + 15.0 * (trace.t_s - 1.6e9))
    # a grid sample has the rotation vector up to the sample before it was made: 60 ms at most
    inside = (trace.t_s >= t_rot[0]) & (trace.t_s <= t_rot[-1])
    assert np.all(np.abs(pdr.wrap_angle(trace.abs_heading_rad - expected)[inside]) < np.radians(1.0))
    assert np.isnan(trace.abs_heading_rad[0])  # made at t[0] + 0.02, before the first rotation vector


def _nlerp_heading(t_rot, q_xyzw, t):
    """The map heading at t between two quaternion samples (the test's own formula)."""
    j = np.searchsorted(t_rot, t, side="left")
    if j == 0 or t_rot[j] == t:
        q = q_xyzw[j]
    else:
        f = (t - t_rot[j - 1]) / (t_rot[j] - t_rot[j - 1])
        q = q_xyzw[j - 1] + f * (q_xyzw[j] - q_xyzw[j - 1])
        q = q / np.linalg.norm(q)
    x, y, z, w = q
    return np.arctan2(1 - 2 * (x * x + z * z), 2 * (x * y - z * w))


def test_a_steps_rotation_vector_heading_uses_only_the_samples_received_before_it():
    rng = np.random.default_rng(21)
    step_t = 2.0 + 0.55 * np.arange(25)
    t = 1.6e9 + np.arange(0, 16, 0.02)
    acc = walking_acc(t - 1.6e9, step_t, 2.5, tilted_up(), rng, noise_mps2=0.05)
    t_rot = 1.6e9 + np.arange(0.3, 16, 0.37)  # a slow rotation vector: often none yet after a step
    azimuth = np.radians(10.0 * (t_rot - 1.6e9))  # turning 10 deg/s
    q = np.array([_quaternion_xyzw([0, 0, 1], -a) for a in azimuth])
    rec = make_recording(t, acc, t, np.zeros((t.size, 3)), t_rot, q[:, :3])
    steps = pdr.detect_steps(rec)
    assert len(steps) >= 20
    interpolated = latest = 0
    for t_step, available, heading in zip(steps.t_s, steps.available_s, steps.abs_heading_rad):
        received = t_rot < available  # at equal times the rotation vector comes after the IMU
        if t_rot[received][-1] >= t_step:
            expected = _nlerp_heading(t_rot[received], q[received], t_step)
            interpolated += 1
        else:
            expected = _nlerp_heading(t_rot[received], q[received], t_rot[received][-1])
            latest += 1
        assert abs(pdr.wrap_angle(heading - expected)) < 1e-9
    assert interpolated > 0 and latest > 0


# --------------------------------------------------------------------------------------------
# step length


@pytest.mark.parametrize("amplitude_mps2", [1.0, 2.5, 4.0])
def test_weinberg_length_on_synthetic_bounce(amplitude_mps2):
    rng = np.random.default_rng(7)
    step_t = 2.0 + 0.55 * np.arange(31)
    t = 1.6e9 + np.arange(0, 22, 0.02)
    acc = walking_acc(t - 1.6e9, step_t, amplitude_mps2, tilted_up(), rng, noise_mps2=0.02)
    config = pdr.PDRConfig(step_threshold_mps3=min(15.0, 0.5 * amplitude_mps2 * 2 * np.pi / 0.55))
    steps = pdr.detect_steps(make_recording(t, acc, t, np.zeros((t.size, 3))), config)
    assert len(steps) == 30
    # a 1.8 Hz bounce passes the causal 3 Hz Butterworth with gain |H| = 1 / sqrt(1 + 0.6^8) = 0.992
    gain = 1.0 / np.sqrt(1.0 + (1.0 / 0.55 / 3.0) ** 8)
    expected_m = config.weinberg_k * (2 * amplitude_mps2 * gain) ** 0.25  # Weinberg: K (a_max - a_min)^(1/4)
    # the first detection's window is cut by the 1 s cap, not by a previous step: skip it
    assert steps.step_length_m[1:] == pytest.approx(expected_m, rel=0.02)
    assert steps.step_length_m == pytest.approx(config.weinberg_k * steps.weinberg_unit)


# --------------------------------------------------------------------------------------------
# streaming: chunks, causality, clocks


def test_feeding_in_chunks_of_any_size_gives_the_same_steps_on_a_synthetic_walk():
    rng = np.random.default_rng(30)
    step_t = 3.0 + np.cumsum(rng.uniform(0.45, 0.65, 30))
    t = irregular_times(rng, 22.0)
    t_gyro = irregular_times(rng, 22.0, t0_s=1.6e9 + 0.004)
    t_rot = irregular_times(rng, 22.0, t0_s=1.6e9 + 0.011)
    azimuth = np.radians(5.0 * (t_rot - 1.6e9))
    q = np.array([_quaternion_xyzw([0, 0, 1], -a) for a in azimuth])
    rec = make_recording(t, walking_acc(t - 1.6e9, step_t, 2.0, tilted_up(), rng), t_gyro,
                         rng.normal(0.0, 0.05, (t_gyro.size, 3)), t_rot, q[:, :3])
    whole = pdr.detect_steps(rec)
    assert len(whole) == 29  # one per bounce
    records = pdr.imu_records(rec)
    assert np.all(np.diff(records[0]) >= 0)
    assert_same_steps(feed_in_chunks(records, None)[0], whole)
    for seed in range(3):
        assert_same_steps(feed_in_chunks(records, np.random.default_rng(seed))[0], whole)


def _real_logs(ilc_site1, ipin2023):
    from mapfilter.sensors.logs import read_log

    return [read_ilc(ilc_site1 / "F1" / "path_data_files" / "5dd9e7b29191710006b5705b.txt.gz"),
            read_log(ipin2023 / "logs" / "IPIN2023_T3_TrainingTrial02_repetition01.txt.gz")]


def test_feeding_real_walks_in_random_chunks_gives_the_same_steps_to_the_byte(ilc_site1, ipin2023):
    for rec, one_by_one in zip(_real_logs(ilc_site1, ipin2023), (True, False)):
        whole = pdr.detect_steps(rec)
        assert len(whole) > 90 and np.all(whole.available_s >= whole.t_s)
        records = pdr.imu_records(rec)
        chunked, online = feed_in_chunks(records, np.random.default_rng(len(whole)))
        assert_same_steps(chunked, whole)
        assert online.n_late_samples == 0 and online.n_stretches == 1
        if one_by_one:  # every record on its own (36 thousand calls on the IPIN walk: the ILC one will do)
            assert_same_steps(feed_in_chunks(records, None)[0], whole)


@pytest.mark.parametrize("share", [0.5, 0.75])
def test_the_steps_of_a_cut_walk_are_those_the_whole_walk_had_by_then(ilc_site1, ipin2023, share):
    for rec in _real_logs(ilc_site1, ipin2023):
        whole = pdr.detect_steps(rec)
        t0 = min(rec.acc_t_s[0], rec.gyro_t_s[0])
        cut_s = t0 + share * (max(rec.acc_t_s[-1], rec.gyro_t_s[-1]) - t0)
        keep = {name: getattr(rec, f"{name}_t_s") <= cut_s for name in ("acc", "gyro", "rotvec")}
        cut = dataclasses.replace(rec, acc_t_s=rec.acc_t_s[keep["acc"]], acc_mps2=rec.acc_mps2[keep["acc"]],
                                  gyro_t_s=rec.gyro_t_s[keep["gyro"]], gyro_radps=rec.gyro_radps[keep["gyro"]],
                                  rotvec_t_s=rec.rotvec_t_s[keep["rotvec"]], rotvec_xyz=rec.rotvec_xyz[keep["rotvec"]])
        early = whole.available_s <= cut_s
        assert 0 < early.sum() < len(whole)
        known = pdr.Steps.concatenate([pdr.Steps(
            t_s=whole.t_s[early], heading_change_rad=whole.heading_change_rad[early],
            heading_rad=whole.heading_rad[early], abs_heading_rad=whole.abs_heading_rad[early],
            step_length_m=whole.step_length_m[early], weinberg_unit=whole.weinberg_unit[early], t0_s=whole.t0_s,
            available_s=whole.available_s[early])], whole.t0_s)
        assert_same_steps(pdr.detect_steps(cut), known)


def _stream(rng, duration_s=20.0, t0_s=1.6e9):
    """A synthetic walk's records in feed order: 30 steps from 3 s on, 50 Hz acc and gyro."""
    step_t = 3.0 + 0.55 * np.arange(31)
    t = t0_s + np.arange(0, duration_s, 0.02)
    acc = walking_acc(t - t0_s, step_t, 2.0, tilted_up(), rng, noise_mps2=0.1)
    return pdr.imu_records(make_recording(t, acc, t, rng.normal(0.0, 0.05, (t.size, 3))))


def test_samples_from_a_clock_that_jumps_back_are_dropped_and_counted():
    t, stream, values = _stream(np.random.default_rng(40))
    # 60 records (30 acc, 30 gyro) stamped 5 s too early, inside the walk: a clock that jumps back
    at = np.searchsorted(t, 1.6e9 + 9.0)
    late_t = t[at - 60:at] - 5.0
    jumped = (np.concatenate([t[:at], late_t, t[at:]]), np.concatenate([stream[:at], stream[at - 60:at], stream[at:]]),
              np.concatenate([values[:at], values[at - 60:at], values[at:]]))
    clean, online_clean = feed_in_chunks((t, stream, values), np.random.default_rng(1))
    dropped, online = feed_in_chunks(jumped, np.random.default_rng(2))
    assert online.n_late_samples == 60 and online_clean.n_late_samples == 0
    assert_same_steps(dropped, clean)
    # a clock that jumps back 5 s and runs on from there: its samples are dropped until their
    # time passes the last one kept (5 s of motion lost), then taken again in the same stretch
    back = (np.concatenate([t[:at], t[at:] - 5.0]), stream, values)
    steps, online = feed_in_chunks(back, np.random.default_rng(3))
    last_kept = {pdr.ACC: -np.inf, pdr.GYRO: -np.inf}
    kept = np.ones(t.size, bool)
    for i, (t_i, s_i) in enumerate(zip(back[0], stream)):  # the rule, record by record
        kept[i] = t_i >= last_kept[s_i]
        last_kept[s_i] = max(last_kept[s_i], t_i)
    assert online.n_late_samples == (~kept).sum() > 400 and online.n_stretches == 1
    assert_same_steps(steps, feed_in_chunks(tuple(a[kept] for a in back), np.random.default_rng(4))[0])
    assert len(steps) > len(clean) - 12  # the 5 s of walking lost hold 9 steps


def test_a_stretch_never_starts_with_a_phantom_step():
    rng = np.random.default_rng(41)
    # ten stretches of a phone at rest in ten attitudes, 5 s apart, each starting with a jolt
    parts = []
    for k in range(10):
        t0 = 1.6e9 + 10.0 * k
        t = t0 + np.arange(0, 5, 0.02)
        up = tilted_up(9.0 * k)
        acc = G_MPS2 * up[None, :] + rng.normal(0.0, 0.2, (t.size, 3))
        acc[:2] += rng.normal(0.0, 3.0, (2, 3))
        parts.append((t, acc))
    t = np.concatenate([p[0] for p in parts])
    acc = np.concatenate([p[1] for p in parts])
    online = pdr.OnlinePDR()
    steps = online.feed(*pdr.imu_records(make_recording(t, acc, t, np.zeros((t.size, 3)))))
    assert online.n_stretches == 10 and len(steps) == 0


def test_a_long_walk_with_a_lagging_gyroscope_loses_nothing():
    # 400 s of walking (more steps than one call's output buffer holds), a rotation vector at
    # 100 Hz, and a gyroscope that pauses 2.5 s every minute: meanwhile the grid waits and the
    # rotation-vector samples pile up (more than its first buffer holds)
    rng = np.random.default_rng(43)
    step_t = 1.0 + 0.55 * np.arange(725)
    t = 1.6e9 + np.arange(0, 400, 0.02)
    t_gyro = t[~(((t - 1.6e9) % 60.0 > 30.0) & ((t - 1.6e9) % 60.0 < 32.5))]
    t_rot = 1.6e9 + np.arange(0.003, 400, 0.01)
    q = np.array([_quaternion_xyzw([0, 0, 1], -a) for a in np.radians(3.0 * (t_rot - 1.6e9))])
    q[q[:, 3] < 0] *= -1.0
    rec = make_recording(t, walking_acc(t - 1.6e9, step_t, 2.0, tilted_up(), rng, noise_mps2=0.05), t_gyro,
                         rng.normal(0.0, 0.02, (t_gyro.size, 3)), t_rot, q[:, :3])
    whole = pdr.detect_steps(rec)
    assert len(whole) > 700
    assert_same_steps(feed_in_chunks(pdr.imu_records(rec), np.random.default_rng(5))[0], whole)
    waited = whole.available_s - whole.t_s > 1.0  # steps found once the gyroscope came back
    assert waited.sum() >= 6
    q_cont = q * np.where(np.cumsum(np.r_[False, np.sum(q[1:] * q[:-1], axis=1) < 0]) % 2, -1.0, 1.0)[:, None]
    for t_step, available, heading in zip(whole.t_s, whole.available_s, whole.abs_heading_rad):
        received = t_rot < available
        expected = _nlerp_heading(t_rot[received], q_cont[received], min(t_step, t_rot[received][-1]))
        assert abs(pdr.wrap_angle(heading - expected)) < 1e-9


def test_bad_records_are_refused():
    online = pdr.OnlinePDR()
    ok_t, ok_stream, ok_values = np.array([1.0, 1.0]), np.array([pdr.ACC, pdr.GYRO]), np.zeros((2, 3))
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        online.feed(ok_t, ok_stream, np.zeros((2, 2)))
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        online.feed(ok_t[:1], ok_stream, ok_values)
    with pytest.raises(ValueError, match="record 1 .*stream of ACC, GYRO or ROTVEC"):
        online.feed(ok_t, np.array([pdr.ACC, 3]), ok_values)
    with pytest.raises(ValueError, match="record 0 .*finite"):
        online.feed(np.array([np.nan, 1.0]), ok_stream, ok_values)
    with pytest.raises(ValueError, match="finite"):
        online.feed(ok_t, ok_stream, np.array([[0.0, np.inf, 0.0], [0.0, 0.0, 0.0]]))
    assert len(online.feed(ok_t, ok_stream, ok_values)) == 0  # nothing was taken from the bad calls
    assert len(online.close()) == 0
    with pytest.raises(ValueError, match="after close"):
        online.feed(ok_t, ok_stream, ok_values)
    with pytest.raises(ValueError, match="keep_trace"):
        pdr.OnlinePDR().trace()


def test_a_long_lag_between_the_sensors_ends_the_stretch_not_the_memory():
    # the gyroscope stops for 5 s while the accelerometer runs on: the waiting grid values never
    # exceed IMU_GAP_S, the stretch ends, and the walk goes on after it
    rng = np.random.default_rng(42)
    t, stream, values = _stream(rng, duration_s=30.0)
    hole = (stream == pdr.GYRO) & (t > 1.6e9 + 10.0) & (t < 1.6e9 + 15.0)
    steps, online = feed_in_chunks((t[~hole], stream[~hole], values[~hole]), np.random.default_rng(0))
    assert online.n_stretches == 2
    assert np.all(np.diff(steps.t_s) >= 0.4)
    in_hole = (steps.t_s > 1.6e9 + 10.0) & (steps.t_s < 1.6e9 + 15.0)
    assert not in_hole.any() and (steps.t_s < 1.6e9 + 10.0).sum() >= 10 and (steps.t_s > 1.6e9 + 15.0).sum() >= 5
# --------------------------------------------------------------------------------------------
# filter inputs and dead reckoning


def _fake_steps(t_s, heading_rad, length_m=0.7):
    t_s, heading_rad = np.asarray(t_s, float), np.asarray(heading_rad, float)
    return pdr.Steps(t_s=t_s, heading_change_rad=np.diff(np.concatenate([[0.0], heading_rad])),
                     heading_rad=heading_rad, abs_heading_rad=heading_rad + 1.0,
                     step_length_m=np.full(t_s.size, length_m), weinberg_unit=np.full(t_s.size, length_m / 0.39),
                     t0_s=0.0)


def test_step_length_prior_lies_within_the_filter_bounds():
    # the per-particle step length the filter starts from is within PDRMotion's bounds
    from mapfilter.filter.models.motion import PDRMotion
    from mapfilter.filter.particle_filter import FilterConfig

    model, start_m = PDRMotion(), FilterConfig().initial_step_length_m
    assert model.step_length_min_m < start_m < model.step_length_max_m


def test_steps_made_by_hand_are_available_at_their_own_time_and_keep_it_when_cut():
    steps = _fake_steps([1.0, 2.0, 3.0], [0.0, 0.1, 0.2])
    np.testing.assert_array_equal(steps.available_s, steps.t_s)
    late = dataclasses.replace(steps, available_s=steps.t_s + 0.05)
    np.testing.assert_array_equal(late.between(1.5, 3.0).available_s, [2.05, 3.05])
    both = pdr.Steps.concatenate([late.between(0.0, 1.5), late.between(1.5, 9.0)], late.t0_s)
    for name in STEP_FIELDS:
        np.testing.assert_array_equal(getattr(both, name), getattr(late, name))
    with pytest.raises(ValueError, match="rotation-vector"):
        pdr.Steps.concatenate([late, dataclasses.replace(late, abs_heading_rad=None)], 0.0)


def test_dead_reckon_walks_a_square():
    # 4 legs of 10 steps, turning left 90 deg at the first step of each new leg
    heading = np.repeat(np.radians([0.0, 90.0, 180.0, 270.0]), 10)
    steps = _fake_steps(np.arange(40) * 0.5 + 1.0, heading + 0.3, length_m=0.5)  # arbitrary gyro zero
    t, xy = pdr.dead_reckon(steps, start_xy_m=[2.0, 3.0], start_heading_rad=0.0)
    assert t.shape == (41,) and xy.shape == (41, 2)
    assert xy[10] == pytest.approx([7.0, 3.0])
    assert xy[20] == pytest.approx([7.0, 8.0])
    assert xy[-1] == pytest.approx([2.0, 3.0], abs=1e-9)
    _, xy_fixed = pdr.dead_reckon(steps, [0.0, 0.0], np.pi / 2, step_length_m=1.0)
    assert xy_fixed[10] == pytest.approx([0.0, 10.0])


# --------------------------------------------------------------------------------------------
# real data and bad input


def test_real_trace_step_count_matches_waypoint_distance(ilc_site1):
    rec = read_ilc(ilc_site1 / "F1" / "path_data_files" / "5dd9e7b29191710006b5705b.txt.gz")
    steps = pdr.detect_steps(rec)
    t0, t1 = rec.waypoint_t_s[0], rec.waypoint_t_s[-1]
    in_span = (steps.t_s > t0) & (steps.t_s <= t1)
    polyline_m = np.sum(np.linalg.norm(np.diff(rec.waypoint_xy_m, axis=0), axis=1))
    n = int(np.sum(in_span))
    assert 0.8 * polyline_m / 0.7 <= n <= 1.4 * polyline_m / 0.7
    cadence_hz = n / (t1 - t0)
    assert 1.4 <= cadence_hz <= 2.4  # walking pace
    weinberg_m = np.sum(steps.step_length_m[in_span])
    assert abs(weinberg_m / polyline_m - 1.0) <= 0.15
    assert steps.abs_heading_rad is not None and np.all(np.abs(steps.abs_heading_rad) <= np.pi)


@pytest.mark.parametrize("repetition", [1, 2, 3, 4])
def test_steps_of_the_ipin_phones_match_their_route(ipin2023, repetition):
    # two phones held more softly than ILC's: every repetition of one 102 m route gives about
    # the same steps, 0.5-0.75 m each against the POSI polyline (a lower bound on the walked
    # distance); the fixed 15 m/s^3 level found 17-47 steps on three of these four walks
    import math

    from mapfilter.sensors.logs import read_log

    rec = read_log(ipin2023 / "logs" / f"IPIN2023_T3_TrainingTrial01_repetition0{repetition}.txt.gz")
    lat, lon = rec.waypoint_latlon_deg[:, 0], rec.waypoint_latlon_deg[:, 1]
    north_m, east_m = np.diff(lat) * 111_320.0, np.diff(lon) * 111_320.0 * math.cos(math.radians(lat[0]))
    polyline_m = float(np.sum(np.hypot(north_m, east_m)))
    steps = pdr.detect_steps(rec)
    t0, t1 = rec.waypoint_t_s[0], rec.waypoint_t_s[-1]
    n = int(np.sum((steps.t_s > t0) & (steps.t_s <= t1)))
    assert 0.5 <= polyline_m / n <= 0.75
    assert 0.8 <= n / (t1 - t0) <= 2.0  # a museum visitor's pace


def test_recording_without_imu_raises():
    rec = make_recording(None, None)
    with pytest.raises(MapfilterError, match="accelerometer"):
        pdr.detect_steps(rec)
    t = 1.6e9 + np.arange(0, 10, 0.02)
    no_gyro = make_recording(t, np.tile([0, 0, G_MPS2], (t.size, 1)))
    with pytest.raises(MapfilterError, match="gyroscope"):
        pdr.detect_steps(no_gyro)
    short = make_recording(t[:50], np.tile([0, 0, G_MPS2], (50, 1)), t[:50], np.zeros((50, 3)))
    with pytest.raises(MapfilterError, match="at least 2 s"):
        pdr.detect_steps(short)


def test_bad_config_raises():
    t = 1.6e9 + np.arange(0, 10, 0.02)
    rec = make_recording(t, np.tile([0, 0, G_MPS2], (t.size, 1)), t, np.zeros((t.size, 3)))
    assert len(pdr.detect_steps(rec)) == 0  # a phone at rest: the defaults are fine
    for bad in ({"weinberg_k": 0.0}, {"step_threshold_mps3": float("nan")}, {"min_step_interval_s": -1.0},
                {"abs_heading_offset_rad": float("inf")}, {"step_threshold_mps3": -1.0}):
        with pytest.raises(MapfilterError, match="PDR setting"):
            pdr.PDRConfig(**bad)


def test_the_old_names_of_pdr_settings_are_refused_in_a_config_file():
    from mapfilter.config import TrackingConfig

    assert TrackingConfig.from_yaml("steps:\n  weinberg_k: 0.45\n").steps.weinberg_k == 0.45
    for old in ("max_gap_s: 3.0", "imu_gap_s: 2.5", "sample_rate_hz: 100", "step_length_m: 0.7",
                "step_length_std_m: 0.1"):
        with pytest.raises(MapfilterError, match=f"line 2: unknown setting 'steps.{old.split(':')[0]}'"):
            TrackingConfig.from_yaml(f"steps:\n  {old}\n")


def test_dead_reckon_from_a_start_time_and_along_the_absolute_heading():
    heading = np.radians(np.r_[np.zeros(5), np.full(5, 90.0)])
    steps = _fake_steps(np.arange(10) + 1.0, heading, length_m=1.0)  # abs heading = gyro + 1 rad
    t, xy = pdr.dead_reckon(steps, [0.0, 0.0], 0.0, start_t_s=2.0)  # steps at t = 1, 2 are not walked
    assert t[0] == 2.0 and t.size == 9
    assert xy[-1] == pytest.approx([3.0, 5.0])
    _, xy_abs = pdr.dead_reckon(steps, [0.0, 0.0], None, use_abs_heading=True)
    expected = np.cumsum(np.column_stack([np.cos(heading + 1.0), np.sin(heading + 1.0)]), axis=0)
    assert xy_abs[1:] == pytest.approx(expected)
    no_rotvec = dataclasses.replace(steps, abs_heading_rad=None)
    with pytest.raises(MapfilterError, match="rotation vector"):
        pdr.dead_reckon(no_rotvec, [0.0, 0.0], None, use_abs_heading=True)


def test_per_step_inputs_through_pdr_motion_reproduce_dead_reckoning(ilc_site1, monkeypatch):
    """The filter's PDRMotion, noise off (its noise constants at 0: the test is about the model's
    kinematics), fed one StepInput per detected step (as the tracker does) walks the dead-reckoned
    track of a fixed step length."""
    from mapfilter.filter.models import motion
    from mapfilter.filter.models.motion import PDRMotion, StepInput
    from mapfilter.filter.particle_filter import FilterConfig, ParticleFilter
    from mapfilter.maps.floorplan import FloorPlan

    rec = read_ilc(ilc_site1 / "F1" / "path_data_files" / "5dd9e7c29191710006b57061.txt.gz")
    steps = pdr.detect_steps(rec)
    monkeypatch.setattr(motion, "POSITION_SIGMA_M", 0.0)
    monkeypatch.setattr(motion, "STEP_LENGTH_WALK_SIGMA_M", 0.0)
    model = PDRMotion(heading_sigma_rad=0.0, false_turn_fraction=0.0)
    start_xy, start_heading = np.array([500.0, 500.0]), 0.4
    plan = FloorPlan(np.pad(np.zeros((998, 998), dtype=bool), 1, constant_values=True), 1.0)  # 1 km, no walls
    pf = ParticleFilter(plan, model, FilterConfig(n_particles=1, resample_ess_fraction=0.0, initial_step_length_m=0.7),
                        np.random.default_rng(0))
    # dead_reckon walks the first step along start_heading; the filter adds that step's change
    pf.initialise_around(start_xy, 0.01, heading_rad=start_heading - steps.heading_change_rad[0])
    pf.particles.xy_m = start_xy[None, :]
    for k in range(len(steps)):
        pf.step(float(steps.t_s[k]), 0.5, StepInput(1, float(steps.heading_change_rad[k])))
    _, xy = pdr.dead_reckon(steps, start_xy, start_heading, step_length_m=0.7)
    assert pf.particles.xy_m[0] == pytest.approx(xy[-1], abs=1e-3)


def test_report_tool_on_real_ilc_and_ipin_walks(ilc_site1, ipin2023, tmp_path, capsys):
    import importlib.util
    import json

    spec = importlib.util.spec_from_file_location("report_pdr", Path(__file__).parents[2] / "tools" / "experiments" / "report_pdr.py")
    report = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(report)
    traces = sorted((ilc_site1 / "F1" / "path_data_files").glob("*.txt.gz"))[:2]
    traces.append(ipin2023 / "logs" / "IPIN2023_T3_TrainingTrial01_repetition01.txt.gz")
    no_imu = ilc_site1 / "F3" / "path_data_files" / "5dda057d9191710006b5713d.txt.gz"  # WiFi only
    out = tmp_path / "pdr.json"
    assert report.main([str(t) for t in [*traces, no_imu]] + ["--json", str(out)]) == 0
    numbers = json.loads(out.read_text())
    assert numbers["summary"]["n_traces"] == 3 and len(numbers["traces"]) == 3
    assert [row["trace"].split("/")[0] for row in numbers["traces"]] == ["F1", "F1", "IPIN2023"]
    for row in numbers["traces"][:2]:
        assert 0.7 < row["ratio_weinberg"] < 1.4
    ipin = numbers["traces"][2]
    assert 0.8 < ipin["steps_per_s"] < 2.0 and 90 < ipin["polyline_m"] < 130  # the 102 m route
    assert all(0.0 < delay < 0.1 for delay in ipin["delay_s"])
    printed = capsys.readouterr()
    assert "| step length |" in printed.out and "skipped 1 log (first:" in printed.err
    assert report.main([str(no_imu)]) == 1
    assert report.main([str(tmp_path / "missing.txt")]) == 1


# ---- gaps in the IMU ---------------------------------------------------------------------------
GAP_MS = 30 * 86_400_000  # 30 days
OFFICE_WALK = Path(__file__).resolve().parents[2] / "maps" / "office_walk.txt.gz"


def _walk_with_gap(path: Path, split_ms: int = 1_600_000_060_000, gap_ms: int = GAP_MS,
                   keep: str = "both") -> Path:
    """The bundled walk with every record after ``split_ms`` moved ``gap_ms`` later (``keep``:
    "both" halves, or only the "first" or "second")."""
    import gzip

    out = []
    with gzip.open(OFFICE_WALK, "rt") as handle:
        for line in handle:
            fields = line.rstrip("\n").split("\t")
            if line.startswith("#"):
                out.append(line)
                continue
            late = int(fields[0]) > split_ms
            if (keep == "first" and late) or (keep == "second" and not late):
                continue
            if late:
                fields[0] = str(int(fields[0]) + gap_ms)
                if fields[1] == "TYPE_WIFI":
                    fields[6] = str(int(fields[6]) + gap_ms)
            out.append("\t".join(fields) + "\n")
    path.write_text("".join(out))
    return path


def test_a_gap_splits_the_walk_into_stretches_each_detected_as_alone(tmp_path):
    both = read_ilc(_walk_with_gap(tmp_path / "gap.txt"))
    first = read_ilc(_walk_with_gap(tmp_path / "first.txt", keep="first"))
    second = read_ilc(_walk_with_gap(tmp_path / "second.txt", keep="second"))
    spans = pdr.imu_stretches(both)
    assert len(spans) == 2 and spans[1][0] - spans[0][1] > 29 * 86_400
    online = pdr.OnlinePDR(keep_trace=True)
    steps = online.feed(*pdr.imu_records(both))
    assert online.n_stretches == 2
    # memory follows the samples: about 50 Hz over 2 minutes of data, not over 30 days
    assert online.trace().t_s.size < 2 * both.acc_t_s.size
    steps, a, b = pdr.detect_steps(both), pdr.detect_steps(first), pdr.detect_steps(second)
    assert len(a) > 20 and len(b) > 20
    # the oracle: each stretch gives the steps it gives alone
    for name in ("t_s", "step_length_m", "abs_heading_rad", "available_s"):
        np.testing.assert_array_equal(getattr(steps, name), np.concatenate([getattr(a, name), getattr(b, name)]))
    # turns within each stretch as alone; the heading carries over the gap
    np.testing.assert_array_equal(steps.heading_change_rad[: len(a)], a.heading_change_rad)
    np.testing.assert_allclose(steps.heading_change_rad[len(a) + 1:], b.heading_change_rad[1:], atol=1e-12)
    np.testing.assert_allclose(np.diff(steps.heading_rad[len(a):]), np.diff(b.heading_rad), atol=1e-12)


def test_a_30_day_gap_tracks_in_bounded_memory(tmp_path):
    """Resampling over the whole span took 23 GB for a 30-day gap: step detection must run in
    1.5 GB of address space (numpy, scipy and numba loaded)."""
    import resource
    import subprocess
    import sys

    log = _walk_with_gap(tmp_path / "gap.txt")
    limit = 1536 << 20

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    code = ("import sys\nfrom mapfilter.sensors.ilc import read_ilc\nfrom mapfilter.sensors.pdr import detect_steps\n"
            "print(len(detect_steps(read_ilc(sys.argv[1]))))")
    done = subprocess.run([sys.executable, "-c", code, str(log)], preexec_fn=cap, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-500:]
    assert int(done.stdout) == len(pdr.detect_steps(read_ilc(log)))


def test_a_recording_needs_two_seconds_of_imu_in_one_stretch():
    t = np.arange(0.0, 1.5, 0.02) + 1.6e9
    late = np.arange(0.0, 10.0, 0.02) + 1.6e9 + 100.0
    times = np.concatenate([t, late])
    acc = np.tile([0.0, 0.0, G_MPS2], (times.size, 1))
    rec = make_recording(times, acc, times, np.zeros((times.size, 3)))
    assert len(pdr.detect_steps(rec)) == 0  # a short stretch at rest, then a long one: no steps, no error
    assert pdr.imu_trace(rec).t_s[0] == t[0]  # the short stretch is filtered too (nothing waits for its end)
    short = make_recording(np.concatenate([t, t + 50]), acc[: 2 * t.size], np.concatenate([t, t + 50]),
                           np.zeros((2 * t.size, 3)))
    with pytest.raises(MapfilterError, match="without a gap of more than 3 s"):
        pdr.detect_steps(short)
