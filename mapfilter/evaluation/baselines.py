"""Baselines the particle filter is compared with: same inputs, same output (a ``Track``).

- ``kalman_track``: Kalman filter on WiFi fixes (Evennou & Marx), with PDR steps as the
  inertial input when available (an EKF in the spirit of Seitz et al., gating bad fixes).
- ``pdr_kwnn_track``: PDR-KWNN (Chang et al.): the fingerprint distance plus the distance and
  angle to the PDR-predicted position.
- ``pdr_track``: dead reckoning from the first fix; ``pdr_start_track`` from the walk's true start.
KWNN fixes and LS trilateration come from ``mapfilter.sensors.radiomap`` / ``mapfilter.sensors.pathloss``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from mapfilter.sensors.pdr import Steps, wrap_angle
from mapfilter.io.tracks import Track

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
    """Gyro-to-map heading offset from the rotation vector's absolute heading (circular mean)
    over the steps up to ``until_t_s`` (at least the first step, even if it comes later);
    None when there is no absolute heading."""
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
        take_step = fix_i >= fix_t.size or (step_i < len(steps) and steps.t_s[step_i] <= fix_t[fix_i])
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
    from mapfilter.sensors.pdr import dead_reckon

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


def pdr_start_track(steps: Steps, recording) -> Track:
    """Dead reckoning from the walk's true start (its first waypoint, time and place: ground truth
    the other methods never see): what the steps alone give, the baseline that shows what WiFi
    adds or costs."""
    track = pdr_track(steps, float(recording.waypoint_t_s[0]), recording.waypoint_xy_m[0])
    return dataclasses.replace(track, name="pdr-start")


@dataclasses.dataclass(frozen=True)
class PdrKwnnConfig:
    """PDR-KWNN (Chang et al.): eps_i = D_rss,i + lambda D_loc,i + gamma D_agl,i, k nearest by eps.

    The three terms carry different units (dB, m, rad). Each is divided by a scale first so
    that one unit of each means "about as unlikely as the others":

    - ``D_rss`` by the scan's best (smallest) signal distance over all reference points: what
      a perfect match still costs with RSSI noise (about sqrt(#APs) x sigma), so 1 = as good
      as the best match, 2 = twice as far in signal space;
    - ``D_loc`` by ``loc_scale_m``: the PDR prediction is trusted to about this many metres
      (reference-point spacing plus PDR drift over one scan interval);
    - ``D_agl`` by pi: 1 = the reference point lies straight behind the walker.

    With ``lambda = 1`` a reference point 2 m (= loc_scale_m) from the PDR prediction costs as
    much as one twice as far in signal space as the best match. The defaults were set by
    reasoning on these scales, not fitted to any paper's figure.
    """

    k: int = 4  # Chang et al.: k = 4
    p: float = 2.0  # Minkowski exponent of the signal distance (Euclidean)
    q: float = 2.0  # weights 1 / eps^q
    lambda_loc: float = 1.0  # weight of D_loc / loc_scale_m
    gamma_agl: float = 0.5  # weight of D_agl / pi
    loc_scale_m: float = 2.0
    min_move_for_angle_m: float = 0.5  # below this PDR displacement the heading is meaningless: no angle term
    missing_dbm: float = -100.0  # an AP heard on one side only counts as this on the other (as in KWNN)
    min_shared_aps: int = 3  # reference points sharing fewer heard APs with the scan are no candidates
    use_abs_heading: bool = True  # gyro-to-map heading offset from the rotation vector (if the steps have it)


def pdr_kwnn_track(radio_map, scans, steps: Steps | None, config: PdrKwnnConfig = PdrKwnnConfig()) -> Track:
    """PDR-KWNN track (Chang et al., "Wi-Fi fingerprint positioning updated by PDR"), one
    estimate per WiFi scan.

    The first scan (with any candidate reference point) is a plain KWNN fix. For every later
    scan the PDR prediction is ``p = previous estimate + sum of the steps since the previous
    scan``, each step ``L_i (cos(h_i + psi), sin(h_i + psi))`` with the Weinberg length
    ``steps.step_length_m``, the gyro heading ``steps.heading_rad`` and the gyro-to-map
    offset ``psi`` from the rotation vector (``heading_offset_prior``, causal). Then over the
    reference points RP_i:

        eps_i = D_rss,i / s_rss + lambda |RP_i - p| / loc_scale_m + gamma D_agl,i / pi

    with D_agl,i the wrapped angle between RP_i - previous estimate and the PDR displacement,
    and the estimate is sum w_i RP_i / sum w_i over the k smallest eps, w_i = 1 / eps_i^q.
    Without steps (or without any heading) it is plain KWNN on every scan.

    Parameters
    ----------
    radio_map : ``mapfilter.sensors.radiomap.RadioMap``.
    scans : sequence of ``WifiScan`` in time order.
    steps : PDR steps (``mapfilter.sensors.pdr.detect_steps``) or None.
    config : ``PdrKwnnConfig``.

    Returns
    -------
    Track named "pdr-kwnn": one row per scan from the first one with a fix on (scans before
    that, or without a fix and without a previous estimate, give no row).
    """
    scans = list(scans)
    name = "pdr-kwnn"
    if not scans or len(radio_map) == 0:
        return Track(np.zeros(0), np.zeros((0, 2)), name=name)
    d_rss, plain = _signal_distances_and_fixes(radio_map, scans, config)
    scan_t = np.array([s.t_s for s in scans], dtype=np.float64)
    use_pdr = steps is not None and len(steps) > 0
    out_t: list[float] = []
    out_xy: list[np.ndarray] = []
    previous: np.ndarray | None = None
    for j in range(len(scans)):
        if previous is None:
            if np.all(np.isfinite(plain[j])):
                previous = plain[j].copy()
                out_t.append(scan_t[j])
                out_xy.append(previous.copy())
            continue
        if not use_pdr:
            estimate = plain[j] if np.all(np.isfinite(plain[j])) else previous
        else:
            estimate = _pdr_kwnn_estimate(radio_map.xy_m, d_rss[j], previous,
                                          _pdr_displacement(steps, scan_t[j - 1], scan_t[j], config), config)
        previous = np.asarray(estimate, dtype=np.float64).copy()
        out_t.append(scan_t[j])
        out_xy.append(previous.copy())
    if not out_t:
        return Track(np.zeros(0), np.zeros((0, 2)), name=name)
    return Track(np.array(out_t), np.array(out_xy), name=name)


def _signal_distances_and_fixes(radio_map, scans: list, config: PdrKwnnConfig) -> tuple[np.ndarray, np.ndarray]:
    """((scans, reference points) signal distance of each scan to every reference point (KWNN's own
    kernel; inf where too few shared APs), (scans, 2) the plain KWNN fix of each scan)."""
    from mapfilter.sensors.radiomap import kwnn_fix_many

    n_refs = len(radio_map)
    every = kwnn_fix_many(radio_map, radio_map.scan_matrix(scans), k=n_refs, p=config.p, q=config.q,
                          missing_dbm=config.missing_dbm, min_shared_aps=config.min_shared_aps)
    d_rss = np.full((len(scans), n_refs), np.inf)
    rows = np.repeat(np.arange(len(scans))[:, None], every.neighbours.shape[1], axis=1)
    ok = every.neighbours >= 0
    d_rss[rows[ok], every.neighbours[ok]] = every.distance_db[ok]
    plain = kwnn_fix_many(radio_map, radio_map.scan_matrix(scans), k=config.k, p=config.p, q=config.q,
                          missing_dbm=config.missing_dbm, min_shared_aps=config.min_shared_aps).xy_m
    return d_rss, plain


def _pdr_kwnn_estimate(ref_xy_m: np.ndarray, d_rss: np.ndarray, previous: np.ndarray, displacement: np.ndarray,
                       config: PdrKwnnConfig) -> np.ndarray:
    """A later scan's estimate: the PDR-KWNN fix around the previous estimate plus the steps'
    displacement, or that prediction alone where no reference point is a candidate."""
    candidates = np.isfinite(d_rss)
    predicted = previous + displacement
    if not candidates.any():
        return predicted  # no fingerprint: dead-reckon to the next scan
    return _pdr_kwnn_fix(ref_xy_m, d_rss, candidates, previous, predicted, displacement, config)


def _pdr_displacement(steps: Steps, t0_s: float, t1_s: float, config: PdrKwnnConfig) -> np.ndarray:
    """Sum of the step vectors with t0 < t <= t1 in the map frame (gyro heading + offset)."""
    i0 = int(np.searchsorted(steps.t_s, t0_s, side="right"))
    i1 = int(np.searchsorted(steps.t_s, t1_s, side="right"))
    if i1 <= i0:
        return np.zeros(2)
    offset = heading_offset_prior(steps, t1_s) if config.use_abs_heading else None
    heading = steps.heading_rad[i0:i1] + (offset or 0.0)
    length = steps.step_length_m[i0:i1]
    return np.array([np.sum(length * np.cos(heading)), np.sum(length * np.sin(heading))])


def _pdr_kwnn_fix(ref_xy_m: np.ndarray, d_rss_db: np.ndarray, candidates: np.ndarray, previous_xy_m: np.ndarray,
                  predicted_xy_m: np.ndarray, displacement_m: np.ndarray, config: PdrKwnnConfig) -> np.ndarray:
    """One PDR-KWNN estimate (Chang et al.'s eps with normalised terms; see ``PdrKwnnConfig``)."""
    idx = np.flatnonzero(candidates)
    xy = ref_xy_m[idx]
    rss_scale = max(float(d_rss_db[idx].min()), 1e-6)
    eps = d_rss_db[idx] / rss_scale
    eps = eps + config.lambda_loc * np.linalg.norm(xy - predicted_xy_m, axis=1) / config.loc_scale_m
    if np.hypot(*displacement_m) >= config.min_move_for_angle_m:
        heading = math.atan2(displacement_m[1], displacement_m[0])
        to_ref = xy - previous_xy_m
        angle = np.arctan2(to_ref[:, 1], to_ref[:, 0])
        d_agl = np.abs(wrap_angle(angle - heading))
        # a reference point on the previous estimate itself has no direction: no angle cost
        d_agl = np.where(np.hypot(to_ref[:, 0], to_ref[:, 1]) > 1e-9, d_agl, 0.0)
        eps = eps + config.gamma_agl * d_agl / math.pi
    kk = min(config.k, idx.size)
    nearest = np.argsort(eps, kind="stable")[:kk]
    weight = 1.0 / np.maximum(eps[nearest], 1e-9) ** config.q
    return (weight[:, None] * xy[nearest]).sum(axis=0) / weight.sum()
