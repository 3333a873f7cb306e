"""Pedestrian dead reckoning: step detection, heading and step length from the phone's IMU, online.

Follows the Lund thesis (Karlsson & Karlsson, ch. 8): the magnitude of the specific force |a|
is low-passed with a 4th-order Butterworth filter at 3 Hz and differentiated (which removes
the constant gravity offset), and a step is counted at each upward crossing of a level, at most
one per minimum step interval. The level is the thesis's fixed one where the signal is strong
and follows the signal's running RMS where it is weak (a phone held more softly), so that other
phones' steps are counted too. The heading change is the gyroscope rate projected on the
gravity direction (gravity from the low-passed accelerometer), integrated. Step length is the
Weinberg formula L = K (a_max - a_min)^(1/4).

Everything is causal and streaming (``OnlinePDR``): records are fed in time order in chunks of
any size, and a step is reported as soon as the sample that shows it has arrived, computed
only from what came before. ``Steps.available_s`` says when that was. ``detect_steps`` is a
replay of a recording's records through ``OnlinePDR``; its steps are those a live system would
have had. The chain, per grid sample:

1. resampling: accelerometer and gyroscope are interpolated linearly onto a uniform grid of
   ``SAMPLE_RATE_HZ``; the grid sample at g is made once both sensors have a sample at or after
   g (so a grid sample waits for the slower sensor);
2. the step filter (Butterworth, designed here: ``butter_lowpass_sos``) runs on |a|, the step
   signal is its backward difference, the step level ``STEP_THRESHOLD_RMS_FRACTION`` times the
   RMS of the step signal over the trailing ``STEP_THRESHOLD_WINDOW_S``, clipped to
   [``MIN_STEP_THRESHOLD_MPS3``, ``step_threshold_mps3``];
3. an upward crossing is placed by linear interpolation between the two grid samples around
   it, and kept if the previous kept step is at least ``min_step_interval_s`` older;
4. gravity is the accelerometer low-passed by a 2nd-order Butterworth at
   ``GRAVITY_LOWPASS_HZ``, the yaw rate the gyroscope rate about it, integrated (trapezoid);
5. the step's rotation-vector heading is interpolated between the rotation-vector samples
   around the step if one at or after it has arrived, else taken from the latest (NaN before
   the first); its Weinberg length uses the low-passed |a| from the previous step (at most
   ``MAX_STEP_WINDOW_S`` back) to this one.

Stretches. Where the accelerometer or the gyroscope stops for longer than ``IMU_GAP_S`` (the
phone slept, the log was paused, its clock jumped), the stretch ends: nothing is interpolated
across the gap, the filters start again, and the gyro heading carries over unchanged (the turn
during the gap is unknown). Memory follows the samples, not the span of the timestamps. A
sample stamped earlier than the previous one of its own sensor (a clock that jumps back) is
dropped and counted (``OnlinePDR.n_late_samples``): the jump behaves as a gap.

Start-up. At a stretch's first grid sample each filter starts in its steady state for that
sample (no step from 0 to g in |a|), and no crossing counts during the step filter's settling
time (``OnlinePDR.settle_samples``: until its slowest pole has decayed to 1 %, 0.66 s at 3 Hz
and 50 Hz), so a stretch never starts with a phantom step.

The map frame of the ILC data has x east and y north; headings are counter-clockwise from +x.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numba import njit

from mapfilter.errors import MapfilterError
from mapfilter.sensors.recording import Recording

ACC, GYRO, ROTVEC = 0, 1, 2  # stream codes of OnlinePDR.feed; ties in time are fed in this order

# The detector's design (the Lund thesis' filter, and what made other phones' steps count; the
# measurements behind each: docs/pdr.md, docs/accuracy.md)
SAMPLE_RATE_HZ = 50.0  # uniform grid the irregular IMU samples are resampled onto
LOWPASS_HZ = 3.0  # Butterworth cut-off of the step signal (thesis: 3 Hz)
LOWPASS_ORDER = 4  # Butterworth order (thesis: 4)
# a phone held softly (IPIN 2023: d|a|/dt peaks a third of ILC's) crosses a fixed level at a
# fraction of its steps: where the signal is weak the level follows this share of its RMS
STEP_THRESHOLD_RMS_FRACTION = 0.9  # share of d|a|/dt's running RMS that is the step level where the signal is weak
STEP_THRESHOLD_WINDOW_S = 4.0  # the running RMS of d|a|/dt is taken over this trailing window
MIN_STEP_THRESHOLD_MPS3 = 5.0  # the step level never goes below this (a phone at rest: hand tremor)
GRAVITY_LOWPASS_HZ = 0.3  # gravity direction = accelerometer low-passed below the step rhythm
MAX_STEP_WINDOW_S = 1.0  # Weinberg min/max window before a step when the previous one is older
# the ILC site1 logs never stop for more than 0.11 s, the simulator's stalls last 0.1-0.3 s
IMU_GAP_S = 3.0  # accelerometer or gyroscope silent longer than this: the stretch ends, the filters restart


@dataclasses.dataclass(frozen=True)
class PDRConfig:
    """The step detector's and step length's settings a user may change (tuned on the ILC site1
    traces, ``tools/experiments/report_pdr.py``)."""

    # walking gives peaks of 50-120 m/s^3, sway a few: a level between (docs/accuracy.md)
    step_threshold_mps3: float = 15.0  # a step: an upward crossing of this level by the filtered d|a|/dt
    # brisk walking is ~0.45-0.5 s per step: shorter counts a step twice, longer drops the fastest
    min_step_interval_s: float = 0.4  # no two steps closer than this
    # Weinberg K for |a| (m/s^2) low-passed at LOWPASS_HZ, fitted to the ILC site1 waypoint
    # distances (tools/experiments/report_pdr.py: 0.402, leave-one-out 0.401-0.403)
    weinberg_k: float = 0.40  # Weinberg step length = K (a_max - a_min)^(1/4)
    # added to pi/2 - azimuth: the angle from magnetic north to the map's +y axis (0 on ILC site 1,
    # docs/accuracy.md)
    abs_heading_offset_rad: float = 0.0  # magnetic north to the map's +y axis, added to the rotation vector's heading

    def __post_init__(self) -> None:
        for name in ("weinberg_k", "step_threshold_mps3"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise MapfilterError(f"PDR setting {name} must be a positive number, got {value}")
        if not (np.isfinite(self.min_step_interval_s) and self.min_step_interval_s >= 0):
            raise MapfilterError(f"PDR setting min_step_interval_s must be >= 0, got {self.min_step_interval_s}")
        if not np.isfinite(self.abs_heading_offset_rad):
            raise MapfilterError(f"PDR setting abs_heading_offset_rad must be a number, got {self.abs_heading_offset_rad}")


@dataclasses.dataclass
class Steps:
    """Detected steps, one row each, sorted by time."""

    t_s: np.ndarray  # (S,) step times, Unix seconds
    heading_change_rad: np.ndarray  # (S,) gyro heading change since the previous step (first: since the start)
    heading_rad: np.ndarray  # (S,) integrated gyro heading at the step, arbitrary zero, unwrapped
    abs_heading_rad: np.ndarray | None  # (S,) map-frame heading from the rotation vector (NaN: none yet), or None
    step_length_m: np.ndarray  # (S,) Weinberg step length
    weinberg_unit: np.ndarray  # (S,) (a_max - a_min)^(1/4), so that step_length_m = K * weinberg_unit
    t0_s: float  # start of the IMU grid (the zero of heading_rad's integration)
    # (S,) when a live system had the step: the time of the latest IMU sample it depended on
    # (>= t_s); None (steps made by hand) means each at its own time
    available_s: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.available_s is None:
            self.available_s = np.array(self.t_s, dtype=np.float64, copy=True)

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def between(self, t0_s: float, t1_s: float) -> "Steps":
        """The steps with t0_s < t_s <= t1_s (a new object; heading changes kept as detected)."""
        sel = (self.t_s > t0_s) & (self.t_s <= t1_s)
        return Steps(t_s=self.t_s[sel], heading_change_rad=self.heading_change_rad[sel],
                     heading_rad=self.heading_rad[sel],
                     abs_heading_rad=None if self.abs_heading_rad is None else self.abs_heading_rad[sel],
                     step_length_m=self.step_length_m[sel], weinberg_unit=self.weinberg_unit[sel], t0_s=self.t0_s,
                     available_s=self.available_s[sel])

    @staticmethod
    def concatenate(parts: list["Steps"], t0_s: float) -> "Steps":
        """The steps of consecutive parts (e.g. ``OnlinePDR.feed``'s answers) as one."""
        def cat(name: str) -> np.ndarray:
            arrays = [getattr(p, name) for p in parts]
            return np.concatenate(arrays) if arrays else np.zeros(0)
        has_abs = [p.abs_heading_rad is not None for p in parts]
        if any(has_abs) and not all(has_abs):
            raise ValueError("Steps.concatenate: some parts have a rotation-vector heading and some do not")
        return Steps(t_s=cat("t_s"), heading_change_rad=cat("heading_change_rad"), heading_rad=cat("heading_rad"),
                     abs_heading_rad=cat("abs_heading_rad") if parts and all(has_abs) else None,
                     step_length_m=cat("step_length_m"), weinberg_unit=cat("weinberg_unit"), t0_s=float(t0_s),
                     available_s=cat("available_s"))


@dataclasses.dataclass
class ImuTrace:
    """The signals of ``OnlinePDR`` at each grid sample (``OnlinePDR(keep_trace=True)``), for
    checks and plots: what the step detector saw, when it saw it."""

    t_s: np.ndarray  # (M,) grid times, Unix seconds (uniform within a stretch)
    available_s: np.ndarray  # (M,) time of the later of the two IMU samples that made the grid sample
    magnitude_mps2: np.ndarray  # (M,) low-passed |a|
    step_signal_mps3: np.ndarray  # (M,) its backward difference (0 at a stretch's first sample)
    step_level_mps3: np.ndarray  # (M,) the step level
    heading_rad: np.ndarray  # (M,) integrated gyro heading, unwrapped
    abs_heading_rad: np.ndarray  # (M,) rotation-vector heading from the samples received by then (NaN: none)


# --------------------------------------------------------------------------------------------
# Butterworth low-pass, designed here (scipy.signal costs 0.5-2 s of start-up)


def butter_lowpass_sos(order: int, cutoff_hz: float, fs_hz: float) -> np.ndarray:
    """(ceil(order / 2), 6) second-order sections [b0 b1 b2 a0 a1 a2] of a digital Butterworth
    low-pass: the analog prototype's poles, the cut-off pre-warped, the bilinear transform.

    The sections are those of ``scipy.signal.butter(order, cutoff_hz, fs=fs_hz, output="sos")``
    (its "nearest" pairing: sections ordered by pole radius, the gain in the first; for an odd
    order the real pole shares its section with a pole at the origin) for cut-offs below a
    quarter of the sample rate; above, the same filter may be split into sections differently.
    """
    if order < 1 or not 0 < cutoff_hz < fs_hz / 2:
        raise ValueError(f"Butterworth order {order} at {cutoff_hz} Hz needs order >= 1 and 0 < cut-off < fs/2")
    # analog prototype poles on the unit circle's left half (scipy.signal.buttap)
    prototype = -np.exp(1j * np.pi * np.arange(-order + 1, order, 2) / (2 * order))
    warped = 2.0 * fs_hz * math.tan(math.pi * cutoff_hz / fs_hz)  # pre-warping: the cut-off lands exactly
    analog = warped * prototype
    poles = (2.0 * fs_hz + analog) / (2.0 * fs_hz - analog)  # bilinear transform; the zeros all go to z = -1
    gain = float(np.real(np.prod(1.0 - poles))) / 2.0 ** order  # unit gain at DC: H(1) = 1
    pairs = sorted((p for p in poles if p.imag > 0), key=abs)  # one of each conjugate pair
    sections = []
    if order % 2:
        real = float(np.real(poles[np.argmin(np.abs(poles.imag))]))
        sections.append((abs(real), [1.0, 2.0, 1.0] if pairs else [1.0, 1.0, 0.0], [1.0, -real, 0.0]))
    for i, p in enumerate(pairs):
        # with an odd order, the pole pair nearest the unit circle takes the zero at the origin
        b = [1.0, 1.0, 0.0] if order % 2 and i == len(pairs) - 1 else [1.0, 2.0, 1.0]
        sections.append((abs(p), b, [1.0, -2.0 * p.real, abs(p) ** 2]))
    sections.sort(key=lambda s: s[0])
    sos = np.array([b + a for _, b, a in sections], dtype=np.float64)
    sos[0, :3] *= gain
    return sos


def sos_steady_state(sos: np.ndarray) -> np.ndarray:
    """(n_sections, 2) transposed-direct-form-II states of ``sos`` after a unit input held forever
    (``scipy.signal.sosfilt_zi``): times the first input, a filter that starts there."""
    zi = np.zeros((sos.shape[0], 2))
    scale = 1.0
    for s, (b0, b1, b2, _, a1, a2) in enumerate(sos):
        out = scale * (b0 + b1 + b2) / (1.0 + a1 + a2)  # the section's steady output
        zi[s, 1] = b2 * scale - a2 * out
        zi[s, 0] = b1 * scale - a1 * out + zi[s, 1]
        scale = out
    return zi


def settle_samples(sos: np.ndarray, fraction: float = 0.01) -> int:
    """Samples until the slowest pole of ``sos`` has decayed to ``fraction`` (at least 1)."""
    radius = 0.0
    for a1, a2 in sos[:, 4:6]:
        radius = max(radius, float(np.max(np.abs(np.roots([1.0, a1, a2])))) if a2 != 0 else abs(a1))
    return max(1, int(math.ceil(math.log(fraction) / math.log(radius)))) if 0 < radius < 1 else 1


@njit(cache=True, nogil=True)
def _sos_step(sos, z, x):
    """One sample through the cascade (transposed direct form II, as scipy's sosfilt), state in z."""
    y = x
    for s in range(sos.shape[0]):
        x = y
        y = sos[s, 0] * x + z[s, 0]
        z[s, 0] = sos[s, 1] * x - sos[s, 4] * y + z[s, 1]
        z[s, 1] = sos[s, 2] * x - sos[s, 5] * y
    return y


# --------------------------------------------------------------------------------------------
# the streaming kernel: one record at a time, every bit of state in the arrays passed in, so the
# answer is the same whatever the chunking

# float state
_F_LAST_T = 0  # 0, 1, 2: last kept sample time of acc, gyro, rotvec (across stretches)
_F_LAST_V = 3  # 3-5 acc, 6-8 gyro: last kept sample values
_F_STRETCH_T = 9  # time of the stretch's first record
_F_G0 = 10  # grid origin of the stretch
_F_HEADING = 11  # gyro heading at the last grid sample (carried over gaps)
_F_YAW = 12  # yaw rate at the last grid sample
_F_SMOOTH = 13  # low-passed |a| at the last grid sample
_F_OVER = 14  # step signal minus level at the last grid sample
_F_STEP_T = 15  # time of the stretch's last step (NaN: none yet)
_F_STEP_HEADING = 16  # gyro heading at the last step (0 before the first: the heading's zero)
_F_T0 = 17  # first grid time of the walk (NaN: none yet)
_F_KEEP_T = 18  # no later question about the rotation vector asks about an earlier time
_N_FLOAT = 19
# int state
_I_HAS = 0  # 0, 1: acc, gyro have a sample in this stretch
_I_EVER = 2  # 2, 3, 4: acc, gyro, rotvec have ever had a kept sample
_I_STARTED = 5  # the stretch has begun (an acc or gyro record since the last reset)
_I_GRID = 6  # the stretch's grid origin is set
_I_NEXT_K = 7  # 7, 8: next grid index whose acc, gyro value is still to be made
_I_K_DONE = 9  # grid samples of the stretch processed
_I_N_LATE = 10  # samples dropped: earlier than the previous sample of their sensor
_I_ROT_HEAD = 11  # rotation-vector buffer: first kept entry
_I_ROT_N = 12  # rotation-vector buffer: entries kept
_I_N_STRETCHES = 13  # stretches whose grid has begun
_N_INT = 14
# float parameters
_P_DT = 0
_P_GAP = 1
_P_FRACTION = 2
_P_MIN_LEVEL = 3
_P_MAX_LEVEL = 4
_P_MIN_INTERVAL = 5
_P_MAX_WINDOW = 6
_P_OFFSET = 7
_N_PARAM = 8
# what the kernel stopped for
_DONE, _FLUSH, _GROW_ROTVEC = 0, 1, 2
_STEP_COLUMNS = 6  # t, heading change, heading, abs heading, Weinberg unit, available
_TRACE_COLUMNS = 7  # t, available, magnitude, step signal, level, heading, abs heading


@njit(cache=True, nogil=True)
def _wrap(angle):
    return angle - 2.0 * math.pi * math.floor((angle + math.pi) / (2.0 * math.pi))


@njit(cache=True, nogil=True)
def _rotvec_heading(rot_t, rot_q, ist, t, offset):
    """Map heading of the phone's +y axis at time t from the kept rotation-vector samples:
    interpolated between the samples around t, else the nearest one; NaN without any.

    Android's rotation vector rotates device coordinates into East-North-Up; the device y axis
    in ENU is the rotation matrix's second column, whose azimuth (clockwise from north) is
    atan2(e, n): the map heading is pi/2 - azimuth = atan2(n, e).
    """
    head, n = ist[_I_ROT_HEAD], ist[_I_ROT_N]
    if n == 0:
        return np.nan
    j = head
    while j < head + n and rot_t[j] < t:
        j += 1
    if j == head + n:
        j -= 1
        x, y, z, w = rot_q[j, 0], rot_q[j, 1], rot_q[j, 2], rot_q[j, 3]
    elif j == head or rot_t[j] == t:
        x, y, z, w = rot_q[j, 0], rot_q[j, 1], rot_q[j, 2], rot_q[j, 3]
    else:
        f = (t - rot_t[j - 1]) / (rot_t[j] - rot_t[j - 1])
        x = rot_q[j - 1, 0] + f * (rot_q[j, 0] - rot_q[j - 1, 0])
        y = rot_q[j - 1, 1] + f * (rot_q[j, 1] - rot_q[j - 1, 1])
        z = rot_q[j - 1, 2] + f * (rot_q[j, 2] - rot_q[j - 1, 2])
        w = rot_q[j - 1, 3] + f * (rot_q[j, 3] - rot_q[j - 1, 3])
        norm = math.sqrt(x * x + y * y + z * z + w * w)
        x, y, z, w = x / norm, y / norm, z / norm, w / norm
    east = 2.0 * (x * y - z * w)
    north = 1.0 - 2.0 * (x * x + z * z)
    return _wrap(math.atan2(north, east) + offset)


@njit(cache=True, nogil=True)
def _prune_rotvec(rot_t, ist, keep_t):
    # keep the last sample at or before keep_t: every later question is about keep_t or after
    while ist[_I_ROT_N] >= 2 and rot_t[ist[_I_ROT_HEAD] + 1] <= keep_t:
        ist[_I_ROT_HEAD] += 1
        ist[_I_ROT_N] -= 1


@njit(cache=True, nogil=True)
def _reset_stretch(fs, ist, t):
    ist[_I_HAS] = 0
    ist[_I_HAS + 1] = 0
    ist[_I_STARTED] = 1
    ist[_I_GRID] = 0
    ist[_I_NEXT_K] = 0
    ist[_I_NEXT_K + 1] = 0
    ist[_I_K_DONE] = 0
    fs[_F_STRETCH_T] = t
    fs[_F_STEP_T] = np.nan


# The kernel's steps. They allocate nothing and are compiled without numba's reference counting
# (_nrt=False, as in maps/walls.py: counting every array argument in and out of each step made
# the kernel about twice as slow); the three run for every record or grid sample are inlined
# into it (forceinline: a call that passes some twenty arrays field by field is not free), so
# the steps run as fast as the one long loop they replaced.


@njit(cache=True, nogil=True, _nrt=False, forceinline=True)
def _keep_rotvec_sample(t, x, y, z, fs, ist, rot_t, rot_q):
    """Keep a rotation-vector sample for the headings of later steps; False (nothing changed but
    pruning) when the buffer is full from its first slot and must grow first."""
    w = math.sqrt(max(1.0 - (x * x + y * y + z * z), 0.0))  # Android: unit quaternion, w >= 0
    replace = ist[_I_EVER + ROTVEC] == 1 and t == fs[_F_LAST_T + ROTVEC] and ist[_I_ROT_N] > 0
    if not replace:
        _prune_rotvec(rot_t, ist, fs[_F_KEEP_T])
        head, n = ist[_I_ROT_HEAD], ist[_I_ROT_N]
        if head + n == rot_t.shape[0]:
            if head == 0:
                return False
            for j in range(n):
                rot_t[j] = rot_t[head + j]
                for c in range(4):  # element by element: a row copy would allocate
                    rot_q[j, c] = rot_q[head + j, c]
            ist[_I_ROT_HEAD] = 0
            head = 0
        slot = head + n
        ist[_I_ROT_N] = n + 1
    else:
        slot = ist[_I_ROT_HEAD] + ist[_I_ROT_N] - 1
    # q and -q are one rotation; Android's w >= 0 flips x, y, z when w passes 0: keep the
    # signs continuous so that interpolating between neighbours never passes through zero
    if slot > ist[_I_ROT_HEAD]:
        p = rot_q[slot - 1]
        if p[0] * x + p[1] * y + p[2] * z + p[3] * w < 0.0:
            x, y, z, w = -x, -y, -z, -w
    rot_t[slot] = t
    rot_q[slot, 0] = x
    rot_q[slot, 1] = y
    rot_q[slot, 2] = z
    rot_q[slot, 3] = w
    fs[_F_LAST_T + ROTVEC] = t
    ist[_I_EVER + ROTVEC] = 1
    return True


@njit(cache=True, nogil=True, _nrt=False)
def _end_stretch_after_gap(s, t, gap, fs, ist):
    """Start a new stretch at t when either sensor has been silent longer than ``gap`` (or
    nothing has started one since the last reset)."""
    o = 1 - s
    if ist[_I_STARTED]:
        own = fs[_F_LAST_T + s] if ist[_I_HAS + s] else fs[_F_STRETCH_T]
        other = fs[_F_LAST_T + o] if ist[_I_HAS + o] else fs[_F_STRETCH_T]
        if t - own > gap or t - other > gap:
            _reset_stretch(fs, ist, t)
    else:
        _reset_stretch(fs, ist, t)


@njit(cache=True, nogil=True, _nrt=False)
def _grid_streams_to_fill(s, fs, ist):
    """Bit x set: make sensor x's grid values now. Starts the stretch's grid once both sensors
    have a sample, at the later of their latest samples."""
    if ist[_I_GRID]:
        return 1 << s
    if ist[_I_HAS + 1 - s]:
        fs[_F_G0] = max(fs[_F_LAST_T], fs[_F_LAST_T + 1])
        ist[_I_GRID] = 1
        ist[_I_N_STRETCHES] += 1
        return 3
    return 0


@njit(cache=True, nogil=True, _nrt=False)
def _fill_grid_values(x_s, interpolate, t_prev, vp0, vp1, vp2, v0, v1, v2, dt, fs, ist, q_val, q_src):
    """Sensor x_s's values at every grid time up to its latest sample: interpolated between its
    previous sample (t_prev, vp) and its latest (v), or, at the grid's origin, the latest."""
    cap = q_src.shape[1]
    t_new = fs[_F_LAST_T + x_s]
    k = ist[_I_NEXT_K + x_s]
    while True:
        g = fs[_F_G0] + k * dt
        if g > t_new:
            break
        if k - ist[_I_K_DONE] >= cap:  # cannot happen: a sensor further ahead ends the stretch
            raise RuntimeError("OnlinePDR: grid values overran their buffer")
        slot = k % cap
        if interpolate and t_new > t_prev:
            f = (g - t_prev) / (t_new - t_prev)
            q_val[x_s, slot, 0] = vp0 + f * (v0 - vp0)
            q_val[x_s, slot, 1] = vp1 + f * (v1 - vp1)
            q_val[x_s, slot, 2] = vp2 + f * (v2 - vp2)
        else:  # the grid's origin: this stream's latest sample is at it
            q_val[x_s, slot, 0] = fs[_F_LAST_V + 3 * x_s]
            q_val[x_s, slot, 1] = fs[_F_LAST_V + 3 * x_s + 1]
            q_val[x_s, slot, 2] = fs[_F_LAST_V + 3 * x_s + 2]
        q_src[x_s, slot] = t_new
        k += 1
    ist[_I_NEXT_K + x_s] = k


@njit(cache=True, nogil=True, _nrt=False, forceinline=True)
def _take_imu_sample(s, t, v0, v1, v2, gap, dt, fs, ist, q_val, q_src):
    """Keep an accelerometer (s = ACC) or gyroscope (s = GYRO) sample and make the grid values it
    completes; False for a repeated time stamp (its values stand for the grid samples to come)."""
    _end_stretch_after_gap(s, t, gap, fs, ist)
    if not ist[_I_GRID] and t > fs[_F_KEEP_T]:
        fs[_F_KEEP_T] = t  # the grid, when it starts, starts at or after now
    first = ist[_I_HAS + s] == 0
    t_prev = fs[_F_LAST_T + s]
    vp0, vp1, vp2 = fs[_F_LAST_V + 3 * s], fs[_F_LAST_V + 3 * s + 1], fs[_F_LAST_V + 3 * s + 2]
    fs[_F_LAST_T + s] = t
    fs[_F_LAST_V + 3 * s] = v0
    fs[_F_LAST_V + 3 * s + 1] = v1
    fs[_F_LAST_V + 3 * s + 2] = v2
    ist[_I_EVER + s] = 1
    ist[_I_HAS + s] = 1
    if not first and t == t_prev:
        return False
    streams_to_fill = _grid_streams_to_fill(s, fs, ist)
    for x_s in range(2):
        if streams_to_fill & (1 << x_s):
            _fill_grid_values(x_s, x_s == s and not first, t_prev, vp0, vp1, vp2, v0, v1, v2, dt, fs, ist,
                              q_val, q_src)
    return True


@njit(cache=True, nogil=True, _nrt=False)
def _start_filters(magnitude, ax, ay, az, zi_step, zi_grav, z_step, z_grav):
    """The step and gravity filters in their steady state for a stretch's first grid sample."""
    for sec in range(z_step.shape[0]):
        z_step[sec, 0] = zi_step[sec, 0] * magnitude
        z_step[sec, 1] = zi_step[sec, 1] * magnitude
    for c, a in enumerate((ax, ay, az)):
        for sec in range(z_grav.shape[1]):
            z_grav[c, sec, 0] = zi_grav[sec, 0] * a
            z_grav[c, sec, 1] = zi_grav[sec, 1] * a


@njit(cache=True, nogil=True, _nrt=False)
def _yaw_rate(ax, ay, az, wx, wy, wz, sos_grav, z_grav):
    """The gyroscope rate about gravity (the accelerometer low-passed): yaw rate = gyro . up (an
    accelerometer at rest reads +g along up); Android gyro rates are counter-clockwise
    positive, as the map heading."""
    gx = _sos_step(sos_grav, z_grav[0], ax)
    gy = _sos_step(sos_grav, z_grav[1], ay)
    gz = _sos_step(sos_grav, z_grav[2], az)
    norm = math.sqrt(gx * gx + gy * gy + gz * gz)
    if norm == 0.0:
        norm = 1.0
    return (wx * gx + wy * gy + wz * gz) / norm


@njit(cache=True, nogil=True, _nrt=False)
def _step_level(k, params, level_ring):
    """The step level at grid sample k: a share of the step signal's RMS over the trailing
    window, clipped to [min, max]; the max alone when the share is 0."""
    level = params[_P_MAX_LEVEL]
    if params[_P_FRACTION] > 0.0:
        n = min(k, level_ring.shape[0])
        total = 0.0
        for j in range(n):
            total += level_ring[j]
        level = params[_P_FRACTION] * math.sqrt(total / n) if n > 0 else 0.0
        level = min(max(level, params[_P_MIN_LEVEL]), params[_P_MAX_LEVEL])
    return level


@njit(cache=True, nogil=True, _nrt=False)
def _step_time(k, g, over, dt, settle, fs, params):
    """The time of a step at the grid interval (g - dt, g]: the upward crossing of the level,
    placed linearly, once the filter has settled and the previous step is old enough; NaN if
    there is none."""
    over_prev = fs[_F_OVER]
    if k - 1 >= settle and over_prev < 0.0 <= over:
        g_prev = g - dt
        t_step = g_prev - over_prev / (over - over_prev) * dt
        step_t = fs[_F_STEP_T]
        if math.isnan(step_t) or t_step - step_t >= params[_P_MIN_INTERVAL]:
            return t_step
    return np.nan


@njit(cache=True, nogil=True, _nrt=False)
def _weinberg_unit(k, t_step, dt, fs, params, mag_ring):
    """(a_max - a_min)^(1/4) of the low-passed |a| from the previous step (at most
    MAX_STEP_WINDOW_S back) to the step at t_step."""
    cap_mag = mag_ring.shape[0]
    begin = t_step - params[_P_MAX_WINDOW]
    step_t = fs[_F_STEP_T]
    if not math.isnan(step_t) and step_t > begin:
        begin = step_t
    lo, hi = np.inf, -np.inf
    for j in range(k, max(-1, k - cap_mag), -1):
        g_j = fs[_F_G0] + j * dt
        if g_j < begin:
            break
        if g_j <= t_step:
            value = mag_ring[j % cap_mag]
            lo = min(lo, value)
            hi = max(hi, value)
    return (hi - lo) ** 0.25 if hi >= lo else 0.0


@njit(cache=True, nogil=True, _nrt=False)
def _write_step(k, g, t_step, heading, available, fs, ist, params, mag_ring, rot_t, rot_q, row):
    """A step at t_step in the grid interval (g - dt, g] of sample k into its row: time, gyro
    heading change and heading (interpolated in the interval), rotation-vector heading, Weinberg
    unit, when it was available; it is the last step now."""
    dt = params[_P_DT]
    g_prev = g - dt
    at = fs[_F_HEADING] + (t_step - g_prev) / dt * (heading - fs[_F_HEADING])
    row[0] = t_step
    row[1] = at - fs[_F_STEP_HEADING]
    row[2] = at
    row[3] = _rotvec_heading(rot_t, rot_q, ist, t_step, params[_P_OFFSET])
    row[4] = _weinberg_unit(k, t_step, dt, fs, params, mag_ring)
    row[5] = available
    fs[_F_STEP_T] = t_step
    fs[_F_STEP_HEADING] = at


@njit(cache=True, nogil=True, _nrt=False, forceinline=True)
def _grid_sample(params, sos_step, zi_step, sos_grav, zi_grav, settle, fs, ist, z_step, z_grav, q_val, q_src,
                 level_ring, mag_ring, rot_t, rot_q, out_steps, n_steps, trace, n_trace, keep_trace):
    """The next grid sample both sensors have reached through the chain: filters, gyro heading,
    step signal and level, a step at an upward crossing (a row of out_steps), a trace row.
    Returns the new counts of steps and trace rows."""
    dt = params[_P_DT]
    k = ist[_I_K_DONE]
    slot = k % q_src.shape[1]
    g = fs[_F_G0] + k * dt
    available = max(q_src[0, slot], q_src[1, slot])
    ax, ay, az = q_val[0, slot, 0], q_val[0, slot, 1], q_val[0, slot, 2]
    magnitude = math.sqrt(ax * ax + ay * ay + az * az)
    if k == 0:
        _start_filters(magnitude, ax, ay, az, zi_step, zi_grav, z_step, z_grav)
        if math.isnan(fs[_F_T0]):
            fs[_F_T0] = g
    smooth = _sos_step(sos_step, z_step, magnitude)
    yaw = _yaw_rate(ax, ay, az, q_val[1, slot, 0], q_val[1, slot, 1], q_val[1, slot, 2], sos_grav, z_grav)
    mag_ring[k % mag_ring.shape[0]] = smooth
    heading = fs[_F_HEADING]
    d = 0.0
    if k > 0:
        heading += 0.5 * (fs[_F_YAW] + yaw) * dt  # trapezoid
        d = (smooth - fs[_F_SMOOTH]) / dt  # backward difference: the step signal d|a|/dt
        level_ring[(k - 1) % level_ring.shape[0]] = d * d
    level = _step_level(k, params, level_ring)
    if k > 0:
        over = d - level
        t_step = _step_time(k, g, over, dt, settle, fs, params)
        if not math.isnan(t_step):
            _write_step(k, g, t_step, heading, available, fs, ist, params, mag_ring, rot_t, rot_q, out_steps[n_steps])
            n_steps += 1
        fs[_F_OVER] = over
    if keep_trace:
        row = trace[n_trace]
        row[0], row[1], row[2], row[3], row[4], row[5] = g, available, smooth, d, level, heading
        row[6] = _rotvec_heading(rot_t, rot_q, ist, g, params[_P_OFFSET])
        n_trace += 1
    fs[_F_HEADING] = heading
    fs[_F_YAW] = yaw
    fs[_F_SMOOTH] = smooth
    if g > fs[_F_KEEP_T]:
        fs[_F_KEEP_T] = g
    ist[_I_K_DONE] = k + 1
    return n_steps, n_trace


@njit(cache=True, nogil=True)
def _feed_kernel(t_s, stream, values, start, params, sos_step, zi_step, sos_grav, zi_grav, settle,
                 fs, ist, z_step, z_grav, q_val, q_src, level_ring, mag_ring, rot_t, rot_q,
                 out_steps, trace, keep_trace):
    """Process records start.. in order; returns (next record, steps written, trace rows written,
    why it stopped). It stops before a record when the outputs might overflow (_FLUSH) or the
    rotation-vector buffer is full (_GROW_ROTVEC); the caller makes room and calls again."""
    cap = q_src.shape[1]
    n_steps = 0
    n_trace = 0
    for i in range(start, t_s.shape[0]):
        if n_steps + cap + 2 > out_steps.shape[0] or (keep_trace and n_trace + cap + 2 > trace.shape[0]):
            return i, n_steps, n_trace, _FLUSH
        s = stream[i]
        t = t_s[i]
        if ist[_I_EVER + s] and t < fs[_F_LAST_T + s]:  # earlier than its sensor's previous sample
            ist[_I_N_LATE] += 1
            continue
        if s == ROTVEC:  # kept for the headings of later steps
            if not _keep_rotvec_sample(t, values[i, 0], values[i, 1], values[i, 2], fs, ist, rot_t, rot_q):
                return i, n_steps, n_trace, _GROW_ROTVEC
            continue
        if not _take_imu_sample(s, t, values[i, 0], values[i, 1], values[i, 2], params[_P_GAP], params[_P_DT],
                                fs, ist, q_val, q_src):
            continue  # a repeated time stamp: its values stand for the grid samples still to come
        while ist[_I_K_DONE] < min(ist[_I_NEXT_K], ist[_I_NEXT_K + 1]):  # every grid sample both reached
            n_steps, n_trace = _grid_sample(params, sos_step, zi_step, sos_grav, zi_grav, settle, fs, ist, z_step,
                                            z_grav, q_val, q_src, level_ring, mag_ring, rot_t, rot_q, out_steps,
                                            n_steps, trace, n_trace, keep_trace)
        _prune_rotvec(rot_t, ist, fs[_F_KEEP_T])
    return t_s.shape[0], n_steps, n_trace, _DONE


# --------------------------------------------------------------------------------------------
# the streaming detector


class OnlinePDR:
    """Steps from IMU records fed in time order, in chunks of any size.

    ``feed(t_s, stream, values)`` takes records in global nondecreasing time order across the
    three sensors (ties in the order ACC, GYRO, ROTVEC) and returns the steps they completed.
    The answers depend only on the sequence of records, never on how it was cut into chunks:
    every step is computed from the records before it, one record at a time (a numba kernel
    with all of its state carried between calls). ``close()`` ends the stream; nothing is ever
    pending (no look-ahead), so it returns no steps.

    Parameters
    ----------
    config
        Step detection, heading and step length settings.
    keep_trace
        Also keep the signals at every grid sample (``trace()``; memory grows with the walk).
    """

    def __init__(self, config: PDRConfig = PDRConfig(), keep_trace: bool = False) -> None:
        self.config = config
        dt_s = 1.0 / SAMPLE_RATE_HZ
        self._params = np.zeros(_N_PARAM)
        self._params[[_P_DT, _P_GAP, _P_FRACTION, _P_MIN_LEVEL, _P_MAX_LEVEL, _P_MIN_INTERVAL, _P_MAX_WINDOW,
                      _P_OFFSET]] = (dt_s, IMU_GAP_S, STEP_THRESHOLD_RMS_FRACTION,
                                     MIN_STEP_THRESHOLD_MPS3, config.step_threshold_mps3, config.min_step_interval_s,
                                     MAX_STEP_WINDOW_S, config.abs_heading_offset_rad)
        self._sos_step = butter_lowpass_sos(LOWPASS_ORDER, LOWPASS_HZ, SAMPLE_RATE_HZ)
        self._sos_grav = butter_lowpass_sos(2, GRAVITY_LOWPASS_HZ, SAMPLE_RATE_HZ)
        self._zi_step, self._zi_grav = sos_steady_state(self._sos_step), sos_steady_state(self._sos_grav)
        self.settle_samples = settle_samples(self._sos_step)  # no step counts in a stretch's first samples
        self._fs = np.zeros(_N_FLOAT)
        self._fs[[_F_STEP_T, _F_T0, _F_KEEP_T]] = (np.nan, np.nan, -np.inf)
        self._ist = np.zeros(_N_INT, dtype=np.int64)
        self._z_step = np.zeros((self._sos_step.shape[0], 2))
        self._z_grav = np.zeros((3, self._sos_grav.shape[0], 2))
        # grid values of one sensor waiting for the other: never more than IMU_GAP_S of them (a
        # sensor further ahead ends the stretch)
        cap = int(math.ceil(IMU_GAP_S / dt_s)) + 4
        self._q_val = np.zeros((2, cap, 3))
        self._q_src = np.zeros((2, cap))
        self._level_ring = np.zeros(max(1, int(round(STEP_THRESHOLD_WINDOW_S / dt_s))))
        self._mag_ring = np.zeros(int(math.ceil(MAX_STEP_WINDOW_S / dt_s)) + 3)
        self._rot_t = np.zeros(64)
        self._rot_q = np.zeros((64, 4))
        self._out_steps = np.zeros((4 * cap + 64, _STEP_COLUMNS))
        self._keep_trace = bool(keep_trace)
        self._trace_buffer = np.zeros((4 * cap + 64 if keep_trace else 1, _TRACE_COLUMNS))
        self._trace_parts: list[np.ndarray] = []
        self._closed = False

    @property
    def n_late_samples(self) -> int:
        """Samples dropped for a time earlier than the previous sample of their sensor."""
        return int(self._ist[_I_N_LATE])

    @property
    def n_stretches(self) -> int:
        """Stretches whose grid has begun (both sensors ticking; a new one after each gap of more
        than ``IMU_GAP_S``)."""
        return int(self._ist[_I_N_STRETCHES])

    @property
    def t0_s(self) -> float:
        """The walk's first grid time (the zero of the gyro heading); NaN before it."""
        return float(self._fs[_F_T0])

    def feed(self, t_s: np.ndarray, stream: np.ndarray, values: np.ndarray) -> Steps:
        """Take the next records; return the steps they completed (possibly none).

        Parameters
        ----------
        t_s
            (n,) record times, Unix seconds.
        stream
            (n,) the sensor of each record: ``ACC``, ``GYRO`` or ``ROTVEC``.
        values
            (n, 3) m/s^2 with gravity, rad/s, or the rotation vector's x, y, z (phone frame).
        """
        if self._closed:
            raise ValueError("OnlinePDR.feed after close()")
        t_s = np.ascontiguousarray(t_s, dtype=np.float64).reshape(-1)
        stream = np.ascontiguousarray(stream, dtype=np.int64).reshape(-1)
        values = np.ascontiguousarray(values, dtype=np.float64)
        if values.ndim != 2 or values.shape[1] != 3 or not t_s.shape[0] == stream.shape[0] == values.shape[0]:
            raise ValueError(f"OnlinePDR.feed: t_s {t_s.shape}, stream {stream.shape} and values {values.shape} "
                             "must be (n,), (n,) and (n, 3)")
        bad = ~(np.isfinite(t_s) & np.isfinite(values).all(axis=1) & (stream >= ACC) & (stream <= ROTVEC))
        if bad.any():
            i = int(np.argmax(bad))
            raise ValueError(f"OnlinePDR.feed: record {i} (t {t_s[i]}, stream {stream[i]}, values {values[i]}) "
                             "needs a finite time and values and a stream of ACC, GYRO or ROTVEC")
        rows = []
        start = 0
        while True:
            start, n_steps, n_trace, why = _feed_kernel(
                t_s, stream, values, start, self._params, self._sos_step, self._zi_step, self._sos_grav,
                self._zi_grav, self.settle_samples, self._fs, self._ist, self._z_step,
                self._z_grav, self._q_val, self._q_src, self._level_ring, self._mag_ring, self._rot_t, self._rot_q,
                self._out_steps, self._trace_buffer, self._keep_trace)
            if n_steps:
                rows.append(self._out_steps[:n_steps].copy())
            if n_trace:
                self._trace_parts.append(self._trace_buffer[:n_trace].copy())
            if why == _DONE:
                break
            if why == _GROW_ROTVEC:  # twice the room; the kept samples stay where they are
                size = 2 * self._rot_t.shape[0]
                self._rot_t = np.resize(self._rot_t, size)
                self._rot_q = np.resize(self._rot_q, (size, 4))
        return self._steps(np.concatenate(rows) if rows else np.zeros((0, _STEP_COLUMNS)))

    def close(self) -> Steps:
        """End of the stream: the steps still pending (none: nothing waits for later samples)."""
        self._closed = True
        return self._steps(np.zeros((0, _STEP_COLUMNS)))

    def trace(self) -> ImuTrace:
        """The signals at every grid sample so far (``keep_trace=True``)."""
        if not self._keep_trace:
            raise ValueError("OnlinePDR.trace needs keep_trace=True")
        rows = np.concatenate(self._trace_parts) if self._trace_parts else np.zeros((0, _TRACE_COLUMNS))
        self._trace_parts = [rows]
        return ImuTrace(*(np.ascontiguousarray(rows[:, j]) for j in range(_TRACE_COLUMNS)))

    def _steps(self, rows: np.ndarray) -> Steps:
        unit = np.ascontiguousarray(rows[:, 4])
        return Steps(t_s=np.ascontiguousarray(rows[:, 0]), heading_change_rad=np.ascontiguousarray(rows[:, 1]),
                     heading_rad=np.ascontiguousarray(rows[:, 2]), abs_heading_rad=np.ascontiguousarray(rows[:, 3]),
                     step_length_m=self.config.weinberg_k * unit, weinberg_unit=unit, t0_s=self.t0_s,
                     available_s=np.ascontiguousarray(rows[:, 5]))


# --------------------------------------------------------------------------------------------
# a recording as a stream


MIN_STRETCH_S = 2.0  # a recording needs this much accelerometer and gyroscope data, in one stretch


def imu_records(recording: Recording) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The recording's accelerometer, gyroscope and rotation-vector samples as one stream of
    records (t_s, stream, values) in the order ``OnlinePDR.feed`` takes: by time, ties in the
    order ACC, GYRO, ROTVEC, then as in the recording."""
    parts = [(recording.acc_t_s, recording.acc_mps2), (recording.gyro_t_s, recording.gyro_radps),
             (recording.rotvec_t_s, recording.rotvec_xyz)]
    t_s = np.concatenate([np.asarray(t, dtype=np.float64) for t, _ in parts])
    stream = np.concatenate([np.full(t.shape[0], code, dtype=np.int64) for code, (t, _) in enumerate(parts)])
    values = np.concatenate([np.asarray(v, dtype=np.float64).reshape(-1, 3) for _, v in parts])
    order = np.argsort(t_s, kind="stable")  # stable: ties keep the stream order, then the index
    return t_s[order], stream[order], values[order]


def _check_imu(recording: Recording) -> None:
    where = recording.path
    for name, t_s in (("accelerometer", recording.acc_t_s), ("gyroscope", recording.gyro_t_s)):
        if t_s.shape[0] < 2 or t_s[-1] - t_s[0] < MIN_STRETCH_S:
            raise MapfilterError(f"no usable {name} data for PDR (need at least 2 s; "
                                 "a WiFi-only log tracks with --motion cv)", where)
    if not any(t1_s - t0_s >= MIN_STRETCH_S for t0_s, t1_s in imu_stretches(recording)):
        gap = any(t.shape[0] > 1 and np.diff(t).max() > IMU_GAP_S
                  for t in (recording.acc_t_s, recording.gyro_t_s))
        raise MapfilterError("accelerometer and gyroscope overlap by less than 2 s"
                             + (f" without a gap of more than {IMU_GAP_S:g} s" if gap else ""), where)


def imu_stretches(recording: Recording) -> list[tuple[float, float]]:
    """(start, end) times of the stretches where accelerometer and gyroscope both tick with no
    gap longer than ``IMU_GAP_S``; without gaps, the one span both cover."""
    acc = _runs(recording.acc_t_s, IMU_GAP_S)
    gyro = _runs(recording.gyro_t_s, IMU_GAP_S)
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


def _runs(t_s: np.ndarray, gap_s: float) -> list[tuple[float, float]]:
    """(first, last) sample times of the runs of ``t_s`` with no step longer than ``gap_s``."""
    if t_s.shape[0] == 0:
        return []
    breaks = np.nonzero(np.diff(t_s) > gap_s)[0]
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks, [t_s.shape[0] - 1]])
    return [(t_s[a], t_s[b]) for a, b in zip(starts, ends)]


def detect_steps(recording: Recording, config: PDRConfig = PDRConfig()) -> Steps:
    """The steps of a recording as a live system would have had them: its IMU records replayed
    through ``OnlinePDR`` in time order.

    Parameters
    ----------
    recording
        A walk with accelerometer and gyroscope (rotation vector optional).
    config
        Thresholds and step-length parameters.

    Returns
    -------
    Steps
        ``t_s``, ``available_s``, ``heading_change_rad`` (since the previous step),
        ``heading_rad`` (gyro, arbitrary zero), ``abs_heading_rad`` (rotation vector, map frame;
        None when the recording has none, NaN for steps before its first sample),
        ``step_length_m`` (Weinberg, K = ``config.weinberg_k``).

    Raises
    ------
    MapfilterError
        If the recording has less than 2 s of accelerometer or gyroscope data, or no stretch of
        2 s where both tick.
    """
    _check_imu(recording)
    online = OnlinePDR(config)
    steps = online.feed(*imu_records(recording))
    if recording.rotvec_t_s.shape[0] == 0:
        steps.abs_heading_rad = None
    return steps


def imu_trace(recording: Recording, config: PDRConfig = PDRConfig()) -> ImuTrace:
    """The signals ``detect_steps`` saw at each grid sample of the recording (gyro heading,
    rotation-vector heading, step signal and level), for checks and plots."""
    _check_imu(recording)
    online = OnlinePDR(config, keep_trace=True)
    online.feed(*imu_records(recording))
    return online.trace()


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
