"""Pedestrian dead reckoning: step detection, heading and step length from the phone's IMU.

Follows the Lund thesis (Karlsson & Karlsson, ch. 8): the magnitude of the specific force
|a| is differentiated (which removes the constant gravity offset), low-passed with a
4th-order Butterworth filter at 3 Hz, and a step is counted at each upward crossing of a
threshold, at most one per minimum step interval. The threshold is the thesis's fixed level
where the signal is strong and follows the signal's running RMS where it is weak (a phone held
more softly, ``step_threshold``), so that other phones' steps are counted too. The heading change is the gyroscope rate
projected on the gravity direction (gravity from the low-passed accelerometer), integrated.
Step length is fixed or from the Weinberg formula L = K (a_max - a_min)^(1/4); the
per-particle adaptive step length (thesis eq. 8.23) belongs to the filter's ``PDRMotion``,
which gets its prior from ``PDRConfig.step_length_m`` / ``step_length_std_m``.

All filtering here is offline and zero-phase (``sosfiltfilt``): the whole recording is
known before the filter runs, so step times carry no filter delay. An online version would
use ``sosfilt`` and accept a delay of a few samples.

A recording whose IMU stops for longer than ``PDRConfig.max_gap_s`` (the phone slept, the log
was paused, or its timestamps jump) is handled in stretches: each continuous stretch is
resampled, filtered and searched for steps on its own, and nothing is interpolated across the
gap, so memory follows the samples, not the span of the timestamps (a 30-day gap once asked
for 23 GB). The gyro heading carries over a gap unchanged (the turn during it is unknown).

The map frame of the ILC data has x east and y north; headings are counter-clockwise from +x.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import signal
from scipy.ndimage import uniform_filter1d

from mapfilter.errors import MapfilterError
from mapfilter.sensors.recording import Recording


@dataclasses.dataclass(frozen=True)
class PDRConfig:
    """Parameters of step detection, heading and step length, with the defaults we use.

    Defaults were tuned on the 48 ILC site1 traces (``tools/report_pdr.py``).
    """

    sample_rate_hz: float = 50.0  # uniform grid the irregular IMU samples are resampled onto
    lowpass_hz: float = 3.0  # Butterworth cut-off of the step signal (thesis: 3 Hz)
    lowpass_order: int = 4  # Butterworth order (thesis: 4)
    # a step = upward crossing of this level by the filtered d|a|/dt; walking on the ILC phone
    # gives peaks of 50-120 m/s^3; of 2, 5, 10, 12, 15, 17, 20, 25, 30 on the 48 ILC site1
    # traces, 12-20 fit the waypoint distances best, 2-5 count sway as steps
    step_threshold_mps3: float = 15.0  # a step: an upward crossing of this level by the filtered d|a|/dt
    # a phone held more softly (the IPIN 2023 phones: d|a|/dt peaks of 20-55 m/s^3, a third of
    # ILC's) crosses 15 at a fraction of its steps: where the signal is weaker the level is this
    # share of its running RMS, not below min_step_threshold_mps3 (a phone at rest); 0 keeps the
    # fixed level. At 1, ILC site 1's F1 walks give 0.3 % more steps and the IPIN ones 2.1 times
    # as many (0.78-1.4 steps/s instead of 0.1-1.1); at 0.5, 3 % more on ILC
    step_threshold_rms_fraction: float = 1.0  # where the signal is weak the step level is this share of d|a|/dt's running RMS
    step_threshold_window_s: float = 4.0  # the running RMS of d|a|/dt is taken over this window (centred)
    min_step_threshold_mps3: float = 5.0  # the step level never goes below this (a phone at rest: hand tremor)
    # no two steps closer than this: brisk walking is ~0.45-0.5 s per step; with 0.3 some
    # steps of ILC site1 cross the threshold twice, 0.5 drops the fastest steps
    min_step_interval_s: float = 0.4  # no two steps closer than this
    gravity_lowpass_hz: float = 0.3  # gravity direction = accelerometer low-passed below the step rhythm
    step_length_m: float = 0.7  # fixed step length; also the prior mean of the adaptive per-particle state
    step_length_std_m: float = 0.1  # prior spread of the per-particle step length (for PDRMotion)
    # Weinberg K for |a| (m/s^2) low-passed at lowpass_hz: sum of waypoint polyline lengths over
    # sum of (a_max - a_min)^(1/4) on all 48 ILC site1 traces (leave-one-out K varies by < 1 %)
    weinberg_k: float = 0.39  # Weinberg step length = K (a_max - a_min)^(1/4)
    max_step_window_s: float = 1.0  # Weinberg min/max window before a step when the previous one is older
    # added to pi/2 - azimuth: the angle from magnetic north to the map's +y axis; measured
    # -2.4 deg on ILC site1 (median leg deviation 8.8 deg), so 0 there
    abs_heading_offset_rad: float = 0.0  # magnetic north to the map's +y axis, added to the rotation vector's heading
    # (module docstring); the 191 ILC site1 logs never stop for more than 0.11 s, the
    # simulator's stalls last 0.1-0.3 s
    max_gap_s: float = 3.0  # the IMU stopping longer than this splits the walk into stretches not interpolated across

    def __post_init__(self) -> None:
        positive = ("sample_rate_hz", "lowpass_hz", "gravity_lowpass_hz", "step_length_m", "weinberg_k",
                    "max_step_window_s", "max_gap_s", "step_threshold_mps3", "step_threshold_window_s",
                    "min_step_threshold_mps3")
        for name in positive:
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise MapfilterError(f"PDR setting {name} must be a positive number, got {value}")
        if not 0.0 <= self.step_threshold_rms_fraction <= 10.0:
            raise MapfilterError(f"PDR setting step_threshold_rms_fraction must be between 0 and 10, "
                                 f"got {self.step_threshold_rms_fraction}")
        if self.min_step_interval_s < 0 or self.step_length_std_m < 0 or self.lowpass_order < 1:
            raise MapfilterError("PDR settings min_step_interval_s and step_length_std_m must be >= 0, "
                                 "lowpass_order >= 1")
        if self.sample_rate_hz <= 2 * max(self.lowpass_hz, self.gravity_lowpass_hz):
            raise MapfilterError(f"PDR setting sample_rate_hz {self.sample_rate_hz} must exceed twice "
                                 f"lowpass_hz {self.lowpass_hz}")


@dataclasses.dataclass
class ImuGrid:
    """IMU resampled onto a uniform time grid (linear interpolation per axis)."""

    t_s: np.ndarray  # (M,) uniform, Unix seconds
    acc_mps2: np.ndarray  # (M, 3) phone frame, with gravity
    gyro_radps: np.ndarray  # (M, 3) phone frame
    rotvec_xyzw: np.ndarray | None  # (M, 4) unit quaternion device -> world (ENU), or None
    dt_s: float  # grid step (t_s differences carry ~2e-7 s of float64 round-off at Unix times)


@dataclasses.dataclass
class Steps:
    """Detected steps, one row each, sorted by time."""

    t_s: np.ndarray  # (S,) step times, Unix seconds
    heading_change_rad: np.ndarray  # (S,) gyro heading change since the previous step (first: since the start)
    heading_rad: np.ndarray  # (S,) integrated gyro heading at the step, arbitrary zero, unwrapped
    abs_heading_rad: np.ndarray | None  # (S,) map-frame heading from the rotation vector, or None
    step_length_m: np.ndarray  # (S,) Weinberg step length
    weinberg_unit: np.ndarray  # (S,) (a_max - a_min)^(1/4), so that step_length_m = K * weinberg_unit
    t0_s: float  # start of the IMU grid (the zero of heading_rad's integration)

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def between(self, t0_s: float, t1_s: float) -> "Steps":
        """The steps with t0_s < t_s <= t1_s (a new object; heading changes kept as detected)."""
        sel = (self.t_s > t0_s) & (self.t_s <= t1_s)
        return Steps(t_s=self.t_s[sel], heading_change_rad=self.heading_change_rad[sel],
                     heading_rad=self.heading_rad[sel],
                     abs_heading_rad=None if self.abs_heading_rad is None else self.abs_heading_rad[sel],
                     step_length_m=self.step_length_m[sel], weinberg_unit=self.weinberg_unit[sel], t0_s=self.t0_s)


# --------------------------------------------------------------------------------------------
# resampling


MIN_STRETCH_S = 2.0  # shorter stretches of IMU (or a shorter recording) give no steps


def resample_imu(recording: Recording, config: PDRConfig = PDRConfig()) -> ImuGrid:
    """Resample accelerometer, gyroscope (and rotation vector) onto one uniform grid.

    The phone's sensors tick irregularly (19-20 ms here, with occasional gaps) and not in
    lockstep; the Butterworth filter and the integration assume a uniform step. The grid spans
    the time all of accelerometer and gyroscope cover.

    Raises
    ------
    MapfilterError
        If the recording has fewer than 2 s of accelerometer or gyroscope data, or if its IMU
        stops for longer than ``config.max_gap_s`` between usable stretches (one grid over the
        gap would hold the gap's samples: ``resample_imu_stretches`` gives a grid per stretch).
    """
    grids = resample_imu_stretches(recording, config)
    if len(grids) > 1:
        raise MapfilterError(f"the IMU stops for more than {config.max_gap_s:g} s between {len(grids)} stretches: "
                             "resample them one by one (resample_imu_stretches)", recording.path)
    return grids[0]


def resample_imu_stretches(recording: Recording, config: PDRConfig = PDRConfig()) -> list[ImuGrid]:
    """``resample_imu`` on each continuous stretch of the IMU (``imu_stretches``), in time order.

    Stretches shorter than 2 s are left out. A recording without gaps gives one grid, the
    same as ``resample_imu``'s.

    Raises
    ------
    MapfilterError
        If the recording has fewer than 2 s of accelerometer or gyroscope data, or no stretch
        of 2 s where both tick.
    """
    where = recording.path
    for name, t_s in (("accelerometer", recording.acc_t_s), ("gyroscope", recording.gyro_t_s)):
        if t_s.shape[0] < 2 or t_s[-1] - t_s[0] < MIN_STRETCH_S:
            raise MapfilterError(f"no usable {name} data for PDR (need at least 2 s; "
                                 "a WiFi-only log tracks with --motion cv)", where)
    spans = [(t0_s, t1_s) for t0_s, t1_s in imu_stretches(recording, config) if t1_s - t0_s >= MIN_STRETCH_S]
    if not spans:
        raise MapfilterError("accelerometer and gyroscope overlap by less than 2 s"
                             + (f" without a gap of more than {config.max_gap_s:g} s" if _has_gap(recording, config)
                                else ""), where)
    quaternion = None
    if recording.rotvec_t_s.shape[0] >= 2:
        quaternion = _rotvec_to_quaternion(recording.rotvec_xyz)
    return [_resample_span(recording, quaternion, t0_s, t1_s, config) for t0_s, t1_s in spans]


def imu_stretches(recording: Recording, config: PDRConfig = PDRConfig()) -> list[tuple[float, float]]:
    """(start, end) times of the stretches where accelerometer and gyroscope both tick with no
    gap longer than ``config.max_gap_s``; without gaps, the one span both cover."""
    acc = _runs(recording.acc_t_s, config.max_gap_s)
    gyro = _runs(recording.gyro_t_s, config.max_gap_s)
    spans, i, j = [], 0, 0
    while i < len(acc) and j < len(gyro):  # intersection of two sorted lists of intervals
        t0_s, t1_s = max(acc[i][0], gyro[j][0]), min(acc[i][1], gyro[j][1])
        if t1_s > t0_s:
            spans.append((t0_s, t1_s))
        if acc[i][1] < gyro[j][1]:
            i += 1
        else:
            j += 1
    return spans


def _runs(t_s: np.ndarray, max_gap_s: float) -> list[tuple[float, float]]:
    """(first, last) sample times of the runs of ``t_s`` with no step longer than ``max_gap_s``."""
    if t_s.shape[0] == 0:
        return []
    breaks = np.nonzero(np.diff(t_s) > max_gap_s)[0]
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks, [t_s.shape[0] - 1]])
    return [(t_s[a], t_s[b]) for a, b in zip(starts, ends)]


def _has_gap(recording: Recording, config: PDRConfig) -> bool:
    return any(t.shape[0] > 1 and np.diff(t).max() > config.max_gap_s for t in (recording.acc_t_s, recording.gyro_t_s))


def _resample_span(recording: Recording, quaternion: np.ndarray | None, t0_s: float, t1_s: float,
                   config: PDRConfig) -> ImuGrid:
    dt_s = 1.0 / config.sample_rate_hz
    t_s = t0_s + dt_s * np.arange(int(np.floor((t1_s - t0_s) / dt_s)) + 1)
    acc = _interp_columns(t_s, *_around(t_s, recording.acc_t_s, recording.acc_mps2))
    gyro = _interp_columns(t_s, *_around(t_s, recording.gyro_t_s, recording.gyro_radps))
    rot = None
    if quaternion is not None:
        rot = _interp_columns(t_s, *_around(t_s, recording.rotvec_t_s, quaternion))
        rot /= np.linalg.norm(rot, axis=1, keepdims=True)
    return ImuGrid(t_s=t_s, acc_mps2=acc, gyro_radps=gyro, rotvec_xyzw=rot, dt_s=dt_s)


def _around(t_new_s: np.ndarray, t_s: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    # the samples of a stretch and a few on each side: interpolation inside it reads only those,
    # and a walk of many stretches must not interpolate over all of its samples for each
    lo = max(int(np.searchsorted(t_s, t_new_s[0], side="left")) - 3, 0)
    hi = int(np.searchsorted(t_s, t_new_s[-1], side="right")) + 3
    return t_s[lo:hi], values[lo:hi]


def _interp_columns(t_new_s: np.ndarray, t_s: np.ndarray, values: np.ndarray) -> np.ndarray:
    # duplicate timestamps would make np.interp pick arbitrarily: keep the last of each
    keep = np.append(np.diff(t_s) > 0, True)
    t_s, values = t_s[keep], values[keep]
    return np.stack([np.interp(t_new_s, t_s, values[:, j]) for j in range(values.shape[1])], axis=1)


def _rotvec_to_quaternion(xyz: np.ndarray) -> np.ndarray:
    """Android rotation vector (x, y, z of a unit quaternion, w >= 0 implied) -> (x, y, z, w).

    q and -q are the same rotation; Android's w >= 0 convention flips the sign of x, y, z
    whenever w passes 0 (e.g. a flat phone turning through 180 deg). The signs are made
    continuous so that interpolating between neighbours never passes through zero.
    """
    w = np.sqrt(np.clip(1.0 - np.sum(xyz * xyz, axis=1), 0.0, None))
    q = np.column_stack([xyz, w])
    if q.shape[0] > 1:
        flips = np.sum(q[1:] * q[:-1], axis=1) < 0
        sign = np.concatenate([[1.0], np.where(np.cumsum(flips) % 2 == 1, -1.0, 1.0)])
        q *= sign[:, None]
    return q


# --------------------------------------------------------------------------------------------
# signals


def _lowpass(x: np.ndarray, cutoff_hz: float, fs_hz: float, order: int) -> np.ndarray:
    # zero-phase (forward-backward) so that detected step times are not delayed
    sos = signal.butter(order, cutoff_hz, btype="low", fs=fs_hz, output="sos")
    return signal.sosfiltfilt(sos, x, axis=0)


def step_signal(grid: ImuGrid, config: PDRConfig = PDRConfig()) -> tuple[np.ndarray, np.ndarray]:
    """The thesis's step-detection signal: low-passed d|a|/dt (m/s^3), and low-passed |a| (m/s^2)."""
    fs_hz = 1.0 / grid.dt_s
    magnitude = np.linalg.norm(grid.acc_mps2, axis=1)
    smooth = _lowpass(magnitude, config.lowpass_hz, fs_hz, config.lowpass_order)
    # differentiate after the low-pass: both are linear and time-invariant, so away from the
    # ends this equals the thesis's "differentiate, then filter", but the filter's edge padding
    # then never sees the raw derivative's amplified noise (which made false steps at the start)
    return np.gradient(smooth, grid.dt_s), smooth


def step_threshold(step_signal_mps3: np.ndarray, dt_s: float, config: PDRConfig = PDRConfig()) -> np.ndarray:
    """(N,) the step level at each sample: ``step_threshold_mps3``, lowered where the signal is
    weak to ``step_threshold_rms_fraction`` of its running RMS (centred window of
    ``step_threshold_window_s``), never below ``min_step_threshold_mps3``.

    A fixed level in m/s^3 counts the steps of the phones it was set on; another phone, or the
    same one held more softly, moves less at each step and crosses it at a fraction of them.
    Relative to the signal's own strength, the level follows the phone; where the walker walks
    as with the ILC phones it is the fixed level of the Lund thesis's detector.
    """
    level = np.full(step_signal_mps3.shape, float(config.step_threshold_mps3))
    if config.step_threshold_rms_fraction <= 0.0 or step_signal_mps3.size == 0:
        return level
    window = max(1, int(round(config.step_threshold_window_s / dt_s)))
    rms = np.sqrt(uniform_filter1d(step_signal_mps3 * step_signal_mps3, window, mode="nearest"))
    return np.clip(config.step_threshold_rms_fraction * rms, config.min_step_threshold_mps3, level)


def detect_step_times(t_s: np.ndarray, step_signal_mps3: np.ndarray, threshold: float | np.ndarray,
                      min_interval_s: float) -> np.ndarray:
    """Times of upward crossings of ``threshold`` (one level, or one per sample) at least
    ``min_interval_s`` apart.

    The crossing time is interpolated linearly between the two samples around it.
    """
    level = np.broadcast_to(np.asarray(threshold, dtype=np.float64), step_signal_mps3.shape)
    over = step_signal_mps3 - level
    idx = np.nonzero((over[:-1] < 0) & (over[1:] >= 0))[0]
    s0, s1 = over[idx], over[idx + 1]
    crossing_s = t_s[idx] - s0 / (s1 - s0) * (t_s[idx + 1] - t_s[idx])
    accepted: list[float] = []
    for t in crossing_s:  # greedy: a crossing within the refractory time of the last step is ignored
        if not accepted or t - accepted[-1] >= min_interval_s:
            accepted.append(float(t))
    return np.array(accepted, dtype=np.float64)


def gyro_heading(grid: ImuGrid, config: PDRConfig = PDRConfig()) -> np.ndarray:
    """Integrated heading (rad, counter-clockwise seen from above, arbitrary zero) on the grid.

    The yaw rate is the gyroscope rate about the vertical: gyro . g_hat, with g_hat the unit
    accelerometer vector low-passed at ``gravity_lowpass_hz`` (it points up: an accelerometer at
    rest reads +g along up). Android gyro rates are counter-clockwise positive, so a left turn
    increases the heading, as in the map frame (x east, y north). Trapezoidal integration.
    """
    fs_hz = 1.0 / grid.dt_s
    gravity = _lowpass(grid.acc_mps2, config.gravity_lowpass_hz, fs_hz, 2)
    norm = np.linalg.norm(gravity, axis=1, keepdims=True)
    up = gravity / np.where(norm > 0, norm, 1.0)
    yaw_rate_radps = np.sum(grid.gyro_radps * up, axis=1)
    heading = np.zeros_like(yaw_rate_radps)
    heading[1:] = np.cumsum(0.5 * (yaw_rate_radps[1:] + yaw_rate_radps[:-1]) * grid.dt_s)
    return heading


def rotation_vector_heading(grid: ImuGrid, config: PDRConfig = PDRConfig()) -> np.ndarray | None:
    """Map-frame heading of the phone's forward (+y) axis from the rotation vector, or None.

    Android's rotation vector rotates device coordinates into East-North-Up. The device y axis
    in ENU is the second column of R; its azimuth (clockwise from north) is atan2(e, n), so the
    map heading is pi/2 - azimuth = atan2(n, e), plus ``abs_heading_offset_rad`` for the angle
    between magnetic north and the floor plan's y axis.
    """
    if grid.rotvec_xyzw is None:
        return None
    x, y, z, w = grid.rotvec_xyzw.T
    # second column of the rotation matrix of quaternion (x, y, z, w)
    east = 2.0 * (x * y - z * w)
    north = 1.0 - 2.0 * (x * x + z * z)
    return np.arctan2(north, east) + config.abs_heading_offset_rad


def weinberg_units(t_s: np.ndarray, magnitude_mps2: np.ndarray, step_t_s: np.ndarray,
                   max_window_s: float) -> np.ndarray:
    """(a_max - a_min)^(1/4) of low-passed |a| over each step's window (Weinberg 2002).

    The window of step k runs from step k-1 (at most ``max_window_s`` back) to step k + half of
    that span, so that it holds one full bounce whatever phase the detector triggers at.
    """
    units = np.zeros(step_t_s.shape[0])
    for k, t in enumerate(step_t_s):
        t_prev = step_t_s[k - 1] if k > 0 else -np.inf
        start = max(t_prev, t - max_window_s)
        end = t + 0.5 * (t - start)
        i0, i1 = np.searchsorted(t_s, [start, end])
        seg = magnitude_mps2[i0:max(i1, i0 + 1)]
        units[k] = (seg.max() - seg.min()) ** 0.25
    return units


# --------------------------------------------------------------------------------------------
# public API


def detect_steps(recording: Recording, config: PDRConfig = PDRConfig()) -> Steps:
    """Detect steps in a recording and attach heading and Weinberg length to each.

    Parameters
    ----------
    recording
        A walk with accelerometer and gyroscope (rotation vector optional).
    config
        Thresholds and step-length parameters.

    Returns
    -------
    Steps
        ``t_s``, ``heading_change_rad`` (since the previous step), ``heading_rad`` (gyro,
        arbitrary zero), ``abs_heading_rad`` (rotation vector, map frame, or None),
        ``step_length_m`` (Weinberg, K = ``config.weinberg_k``).

    Raises
    ------
    MapfilterError
        If the recording has no usable accelerometer or gyroscope data.
    """
    return detect_steps_on_grids(resample_imu_stretches(recording, config), config)


def detect_steps_on_grid(grid: ImuGrid, config: PDRConfig = PDRConfig()) -> Steps:
    """``detect_steps`` on an already resampled IMU grid."""
    return detect_steps_on_grids([grid], config)


def detect_steps_on_grids(grids: list[ImuGrid], config: PDRConfig = PDRConfig()) -> Steps:
    """``detect_steps`` on the resampled stretches of a walk (``resample_imu_stretches``).

    Each stretch is filtered and searched for steps on its own; the gyro heading of a stretch
    starts where the previous one ended (no turn across a gap).
    """
    times, headings, abs_headings, units = [], [], [], []
    start_heading = end_heading = 0.0
    for k, grid in enumerate(grids):
        d_mag, mag = step_signal(grid, config)
        step_t = detect_step_times(grid.t_s, d_mag, step_threshold(d_mag, grid.dt_s, config), config.min_step_interval_s)
        heading = gyro_heading(grid, config)
        if k == 0:
            start_heading = heading[0]
        else:
            heading = heading + end_heading  # continue from the previous stretch
        end_heading = heading[-1]
        times.append(step_t)
        headings.append(np.interp(step_t, grid.t_s, heading))
        abs_heading = rotation_vector_heading(grid, config)
        if abs_heading is not None:
            # interpolate the unwrapped angle, then wrap back to (-pi, pi]
            abs_headings.append(wrap_angle(np.interp(step_t, grid.t_s, np.unwrap(abs_heading))))
        units.append(weinberg_units(grid.t_s, mag, step_t, config.max_step_window_s))
    step_t, heading_at, units_all = (parts[0] if len(parts) == 1 else np.concatenate(parts)
                                     for parts in (times, headings, units))
    change = np.diff(np.concatenate([[start_heading], heading_at]))
    abs_at = None
    if abs_headings:
        abs_at = abs_headings[0] if len(abs_headings) == 1 else np.concatenate(abs_headings)
    return Steps(t_s=step_t, heading_change_rad=change, heading_rad=heading_at, abs_heading_rad=abs_at,
                 step_length_m=config.weinberg_k * units_all, weinberg_unit=units_all, t0_s=float(grids[0].t_s[0]))


def wrap_angle(angle_rad: np.ndarray | float) -> np.ndarray | float:
    """Wrap to [-pi, pi)."""
    return (np.asarray(angle_rad) + np.pi) % (2 * np.pi) - np.pi


def dead_reckon(steps: Steps, start_xy_m: np.ndarray, start_heading_rad: float | None,
                step_length_m: float | None = None, start_t_s: float | None = None,
                use_abs_heading: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """PDR-only track: each step moves ``step_length_m`` (or its Weinberg length) along the heading.

    Parameters
    ----------
    steps
        Detected steps.
    start_xy_m
        Position at the start.
    start_heading_rad
        Walking direction of the first step (map frame); the heading at step k adds the gyro
        heading change since the first step. Ignored (may be None) with ``use_abs_heading``.
    step_length_m
        Fixed step length; None uses each step's Weinberg length.
    start_t_s
        Time of ``start_xy_m``; steps at or before it are not walked. Default: the first step's time.
    use_abs_heading
        Walk along the rotation-vector heading of each step instead of the gyro heading.

    Returns
    -------
    t_s : (S + 1,) the start time, then each walked step's time
    xy_m : (S + 1, 2) positions
    """
    start_xy_m = np.asarray(start_xy_m, dtype=np.float64).reshape(2)
    if start_t_s is not None:
        steps = steps.between(start_t_s, np.inf)
    t_start = start_t_s if start_t_s is not None else (float(steps.t_s[0]) if len(steps) else steps.t0_s)
    if len(steps) == 0:
        return np.array([t_start]), start_xy_m[None, :].copy()
    if use_abs_heading:
        if steps.abs_heading_rad is None:
            raise MapfilterError("absolute heading requested but the recording has no rotation vector")
        heading = steps.abs_heading_rad
    else:
        if start_heading_rad is None:
            raise ValueError("start_heading_rad is needed for gyro dead reckoning")
        heading = start_heading_rad + (steps.heading_rad - steps.heading_rad[0])
    length = steps.step_length_m if step_length_m is None else np.full(len(steps), float(step_length_m))
    moves = length[:, None] * np.column_stack([np.cos(heading), np.sin(heading)])
    xy = np.vstack([start_xy_m, start_xy_m + np.cumsum(moves, axis=0)])
    return np.concatenate([[t_start], steps.t_s]), xy
