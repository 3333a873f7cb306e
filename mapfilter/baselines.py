"""Baselines the particle filter is compared with: same inputs, same output (a ``Track``).

- ``kalman_track``: Kalman filter on WiFi fixes (Evennou & Marx), with PDR steps as the
  inertial input when available (an EKF in the spirit of Seitz et al., gating bad fixes).
- ``pdr_kwnn_track``: PDR-KWNN (Chang et al.): the fingerprint distance plus the distance and
  angle to the PDR-predicted position.
- ``pdr_track``: dead reckoning from the first fix.
KWNN fixes and LS trilateration come from ``mapfilter.radiomap`` / ``mapfilter.wifi``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from mapfilter.pdr import Steps, wrap_angle
from mapfilter.trackio import Track

# chi-square 2-dof quantile at 99.9 %: a fix farther than this (Mahalanobis) is an outlier
_GATE_CHI2_2DOF = 13.82


@dataclasses.dataclass(frozen=True)
class KalmanConfig:
    fix_sigma_m: float = 5.0  # WiFi fix noise (Evennou & Marx use 5 m for their fix likelihood)
    accel_sigma_mps2: float = 0.5  # constant-velocity model: random acceleration (no PDR)
    step_position_sigma_m: float = 0.15  # PDR model: position noise per step
    step_heading_sigma_rad: float = np.deg2rad(2.0)  # PDR model: heading-offset drift per step
    initial_heading_sigma_rad: float = np.deg2rad(30.0)  # prior on the gyro-to-map heading offset
    gate: bool = True  # reject fixes beyond the 99.9 % Mahalanobis gate (Seitz et al.)
    max_consecutive_rejections: int = 3  # then accept anyway: the filter, not the fixes, is lost


def heading_offset_prior(steps: Steps, until_t_s: float) -> float | None:
    """Gyro-to-map heading offset from the rotation vector's absolute heading (circular mean),
    using only steps up to ``until_t_s`` (causal); None when there is no absolute heading."""
    if steps.abs_heading_rad is None or len(steps) == 0:
        return None
    upto = max(1, int(np.searchsorted(steps.t_s, until_t_s, side="right")))
    diff = steps.abs_heading_rad[:upto] - steps.heading_rad[:upto]
    return float(np.arctan2(np.sin(diff).mean(), np.cos(diff).mean()))


def kalman_track(fix_t_s: np.ndarray, fix_xy_m: np.ndarray, steps: Steps | None = None,
                 config: KalmanConfig = KalmanConfig()) -> Track:
    """Kalman-filtered track from WiFi fixes, one estimate per event (fix or step).

    Without steps: constant-velocity KF, state [x, y, vx, vy], updated at each fix. With steps:
    EKF, state [x, y, psi] where psi is the offset from the gyro heading to the map heading;
    each step moves the state by L (cos(psi + h_k), sin(psi + h_k)) (Seitz et al.'s inertial
    prediction), each fix corrects it.
    """
    fix_t = np.asarray(fix_t_s, dtype=np.float64)
    fix_xy = np.asarray(fix_xy_m, dtype=np.float64).reshape(-1, 2)
    if fix_t.size == 0:
        return Track(np.zeros(0), np.zeros((0, 2)), np.zeros(0), name="kf")
    if steps is None or len(steps) == 0:
        return _cv_kalman(fix_t, fix_xy, config)
    return _pdr_ekf(fix_t, fix_xy, steps, config)


def _cv_kalman(fix_t: np.ndarray, fix_xy: np.ndarray, config: KalmanConfig) -> Track:
    state = np.array([fix_xy[0, 0], fix_xy[0, 1], 0.0, 0.0])
    cov = np.diag([config.fix_sigma_m**2] * 2 + [1.0, 1.0])
    measurement = np.hstack([np.eye(2), np.zeros((2, 2))])
    noise_r = np.eye(2) * config.fix_sigma_m**2
    out_xy, out_std = [state[:2].copy()], [np.sqrt(np.trace(cov[:2, :2]) / 2)]
    rejected = 0
    for k in range(1, fix_t.size):
        dt = fix_t[k] - fix_t[k - 1]
        transition = np.eye(4)
        transition[0, 2] = transition[1, 3] = dt
        # white random acceleration: G q G^T with G = [dt^2/2, dt]
        g = np.array([[dt**2 / 2, 0], [0, dt**2 / 2], [dt, 0], [0, dt]])
        state = transition @ state
        cov = transition @ cov @ transition.T + g @ g.T * config.accel_sigma_mps2**2
        state, cov, rejected = _update(state, cov, fix_xy[k], measurement, noise_r, config, rejected)
        out_xy.append(state[:2].copy())
        out_std.append(np.sqrt(np.trace(cov[:2, :2]) / 2))
    return Track(fix_t.copy(), np.array(out_xy), np.array(out_std), name="kf")


def _pdr_ekf(fix_t: np.ndarray, fix_xy: np.ndarray, steps: Steps, config: KalmanConfig) -> Track:
    psi0 = heading_offset_prior(steps, fix_t[0])
    psi_sigma = config.initial_heading_sigma_rad if psi0 is not None else np.pi
    state = np.array([fix_xy[0, 0], fix_xy[0, 1], psi0 or 0.0])
    cov = np.diag([config.fix_sigma_m**2, config.fix_sigma_m**2, psi_sigma**2])
    measurement = np.hstack([np.eye(2), np.zeros((2, 1))])
    noise_r = np.eye(2) * config.fix_sigma_m**2
    noise_q = np.diag([config.step_position_sigma_m**2] * 2 + [config.step_heading_sigma_rad**2])
    # events after the first fix, in time order; fixes after steps at equal times
    step_i = int(np.searchsorted(steps.t_s, fix_t[0], side="right"))
    fix_i = 1
    out_t, out_xy, out_std = [fix_t[0]], [state[:2].copy()], [config.fix_sigma_m]
    rejected = 0
    while step_i < len(steps) or fix_i < fix_t.size:
        take_step = fix_i >= fix_t.size or (step_i < len(steps) and steps.t_s[step_i] < fix_t[fix_i])
        if take_step:
            length = steps.step_length_m[step_i]
            theta = state[2] + steps.heading_rad[step_i]
            state = state + np.array([length * np.cos(theta), length * np.sin(theta), 0.0])
            jacobian = np.eye(3)
            jacobian[0, 2] = -length * np.sin(theta)
            jacobian[1, 2] = length * np.cos(theta)
            cov = jacobian @ cov @ jacobian.T + noise_q
            t = steps.t_s[step_i]
            step_i += 1
        else:
            state, cov, rejected = _update(state, cov, fix_xy[fix_i], measurement, noise_r, config, rejected)
            state[2] = float(wrap_angle(state[2]))
            t = fix_t[fix_i]
            fix_i += 1
        out_t.append(t)
        out_xy.append(state[:2].copy())
        out_std.append(np.sqrt(np.trace(cov[:2, :2]) / 2))
    return Track(np.array(out_t), np.array(out_xy), np.array(out_std), name="kf")


def _update(state, cov, z, measurement, noise_r, config: KalmanConfig, rejected: int):
    innovation = z - measurement @ state
    s = measurement @ cov @ measurement.T + noise_r
    if config.gate and rejected < config.max_consecutive_rejections:
        if innovation @ np.linalg.solve(s, innovation) > _GATE_CHI2_2DOF:
            return state, cov, rejected + 1
    gain = cov @ measurement.T @ np.linalg.inv(s)
    state = state + gain @ innovation
    # Joseph form keeps the covariance symmetric positive definite
    identity_kh = np.eye(state.size) - gain @ measurement
    cov = identity_kh @ cov @ identity_kh.T + gain @ noise_r @ gain.T
    return state, cov, 0


def pdr_track(steps: Steps, start_t_s: float, start_xy_m: np.ndarray, step_length_m: float | None = None) -> Track:
    """Dead reckoning from a start fix: heading offset from the rotation vector (if any, else 0),
    positions at each step after ``start_t_s``."""
    from mapfilter.pdr import dead_reckon

    first = int(np.searchsorted(steps.t_s, start_t_s, side="right"))
    later = Steps(
        t_s=steps.t_s[first:], heading_change_rad=steps.heading_change_rad[first:],
        heading_rad=steps.heading_rad[first:],
        abs_heading_rad=None if steps.abs_heading_rad is None else steps.abs_heading_rad[first:],
        step_length_m=steps.step_length_m[first:], weinberg_unit=steps.weinberg_unit[first:], t0_s=steps.t0_s,
    )
    if len(later) == 0:
        return Track(np.array([start_t_s]), np.asarray(start_xy_m, dtype=np.float64).reshape(1, 2), name="pdr")
    offset = heading_offset_prior(steps, start_t_s) or 0.0
    t_s, xy_m = dead_reckon(later, start_xy_m, offset + later.heading_rad[0], step_length_m)
    # dead_reckon starts at the first step's time; the start fix is known from start_t_s
    t_s = t_s.copy()
    t_s[0] = start_t_s
    return Track(t_s, xy_m, name="pdr")
