import numpy as np

from mapfilter.evaluation.baselines import kalman_track, pdr_track
from mapfilter.sensors.pdr import Steps


def _square_walk(n_steps=120, step_m=0.7, dt_s=0.5):
    """A walk around a square, 30 steps a side, with the true heading known."""
    heading = np.repeat(np.arange(4) * np.pi / 2, n_steps // 4)
    moves = step_m * np.column_stack([np.cos(heading), np.sin(heading)])
    xy = np.vstack([[0.0, 0.0], np.cumsum(moves, axis=0)])
    t = np.arange(n_steps + 1) * dt_s
    return t, xy, heading


def _steps(t, heading, gyro_offset_rad, step_m=0.7):
    gyro = heading - gyro_offset_rad  # the gyro heading has an unknown zero
    return Steps(t_s=t[1:], heading_change_rad=np.diff(np.concatenate([[gyro[0]], gyro])), heading_rad=gyro,
                 abs_heading_rad=heading + 0.1, step_length_m=np.full(heading.size, step_m),
                 weinberg_unit=np.ones(heading.size), t0_s=0.0)


def test_pdr_ekf_beats_the_noisy_fixes_it_fuses():
    rng = np.random.default_rng(3)
    t, xy, heading = _square_walk()
    fix_idx = np.arange(0, t.size, 4)
    fixes = xy[fix_idx] + rng.normal(0, 4.0, (fix_idx.size, 2))
    track = kalman_track(t[fix_idx], fixes, _steps(t, heading, gyro_offset_rad=1.0))
    est = np.column_stack([np.interp(t, track.t_s, track.xy_m[:, 0]), np.interp(t, track.t_s, track.xy_m[:, 1])])
    kf_error = np.linalg.norm(est[fix_idx] - xy[fix_idx], axis=1).mean()
    fix_error = np.linalg.norm(fixes - xy[fix_idx], axis=1).mean()
    assert kf_error < 0.6 * fix_error
    assert np.all(np.diff(track.t_s) >= 0)


def test_constant_velocity_kalman_smooths_fixes_without_steps():
    rng = np.random.default_rng(4)
    t, xy, _ = _square_walk()
    fixes = xy + rng.normal(0, 3.0, xy.shape)
    track = kalman_track(t, fixes)
    assert track.xy_m.shape == xy.shape
    assert np.linalg.norm(track.xy_m - xy, axis=1).mean() < np.linalg.norm(fixes - xy, axis=1).mean()


def test_pdr_track_follows_the_square_with_the_absolute_heading_offset():
    t, xy, heading = _square_walk()
    steps = _steps(t, heading, gyro_offset_rad=0.7)
    track = pdr_track(steps, start_t_s=0.0, start_xy_m=xy[0])
    # heading offset is off by 0.1 rad (abs heading bias): end error ~ 0.1 * path length / 2 at most
    assert np.linalg.norm(track.xy_m - xy, axis=1).max() < 0.1 * 84 / 1.5
    np.testing.assert_allclose(track.t_s, t)


# ---- PDR-KWNN (Chang et al.) ---------------------------------------------------------------
def _grid_radio_map_and_scans(seed=5, noise_db=5.0):
    """A 1 m grid of reference points heard from 8 APs (log-distance model), the square walk,
    and one noisy scan every 4 steps at the walker's position."""
    from mapfilter.sensors.radiomap import RadioMap
    from mapfilter.sensors.wifi import WifiScan

    rng = np.random.default_rng(seed)
    t, xy, heading = _square_walk()
    xy = xy + 2.0  # the square spans [2, 23] m
    gx, gy = np.meshgrid(np.arange(0.0, 26.0, 1.0), np.arange(0.0, 26.0, 1.0))
    ref = np.column_stack([gx.ravel(), gy.ravel()])
    ap_xy = np.array([[0, 0], [25, 0], [25, 25], [0, 25], [12, 0], [25, 12], [12, 25], [0, 12]], dtype=float)
    keys = [f"02:00:00:00:00:{i:02x}@2.4" for i in range(len(ap_xy))]

    def model(points):
        d = np.maximum(np.linalg.norm(points[:, None, :] - ap_xy[None], axis=-1), 1.0)
        return -38.0 - 20.0 * np.log10(d) - 0.3 * d

    radio_map = RadioMap(ref, keys, model(ref) + rng.normal(0, 1.0, (len(ref), len(keys))), np.zeros(len(ref)),
                         np.zeros(len(ref), np.int64), ["survey"])
    scan_idx = np.arange(0, t.size, 4)
    rssi = model(xy[scan_idx]) + rng.normal(0, noise_db, (scan_idx.size, len(keys)))
    scans = [WifiScan(float(t[i]), tuple(keys), rssi[j].astype(np.float32)) for j, i in enumerate(scan_idx)]
    return radio_map, scans, t, xy, heading, scan_idx


def test_pdr_kwnn_beats_plain_kwnn_on_a_synthetic_walk():
    from mapfilter.evaluation.baselines import pdr_kwnn_track
    from mapfilter.sensors.radiomap import kwnn_fix_many

    radio_map, scans, t, xy, heading, scan_idx = _grid_radio_map_and_scans()
    rng = np.random.default_rng(11)
    steps = _steps(t, heading + rng.normal(0, np.deg2rad(1.0), heading.size), gyro_offset_rad=0.8)
    steps.step_length_m = 0.7 + rng.normal(0, 0.07, heading.size)  # Weinberg lengths are noisy too
    track = pdr_kwnn_track(radio_map, scans, steps)
    kwnn = kwnn_fix_many(radio_map, radio_map.scan_matrix(scans)).xy_m
    np.testing.assert_allclose(track.t_s, t[scan_idx])
    np.testing.assert_allclose(track.xy_m[0], kwnn[0])  # the first fix is plain KWNN
    err_pdr = np.linalg.norm(track.xy_m - xy[scan_idx], axis=1).mean()
    err_kwnn = np.linalg.norm(kwnn - xy[scan_idx], axis=1).mean()
    assert err_pdr < 0.8 * err_kwnn, (err_pdr, err_kwnn)


def test_pdr_kwnn_without_steps_is_plain_kwnn():
    from mapfilter.evaluation.baselines import pdr_kwnn_track
    from mapfilter.sensors.radiomap import kwnn_fix_many

    radio_map, scans, t, _, heading, _ = _grid_radio_map_and_scans()
    kwnn = kwnn_fix_many(radio_map, radio_map.scan_matrix(scans)).xy_m
    no_steps = _steps(t, heading, 0.0)
    no_steps = Steps(t_s=np.zeros(0), heading_change_rad=np.zeros(0), heading_rad=np.zeros(0), abs_heading_rad=None,
                     step_length_m=np.zeros(0), weinberg_unit=np.zeros(0), t0_s=0.0)
    for steps in (None, no_steps):
        track = pdr_kwnn_track(radio_map, scans, steps)
        np.testing.assert_allclose(track.xy_m, kwnn)
    assert len(pdr_kwnn_track(radio_map, [], None)) == 0


def test_pdr_kwnn_dead_reckons_through_a_scan_with_no_candidate():
    from mapfilter.evaluation.baselines import pdr_kwnn_track
    from mapfilter.sensors.wifi import WifiScan

    radio_map, scans, t, xy, heading, scan_idx = _grid_radio_map_and_scans()
    steps = _steps(t, heading, gyro_offset_rad=0.3)
    # scan 3 hears only two APs: no reference point shares the 3 needed, PDR carries the estimate
    s = scans[3]
    scans[3] = WifiScan(s.t_s, s.ap_keys[:2], s.rssi_dbm[:2])
    track = pdr_kwnn_track(radio_map, scans, steps)
    assert len(track) == len(scans)
    moved = np.linalg.norm(track.xy_m[3] - track.xy_m[2])
    assert abs(moved - np.linalg.norm(xy[scan_idx[3]] - xy[scan_idx[2]])) < 0.3  # 4 steps of 0.7 m, straight
