import numpy as np

from mapfilter.baselines import kalman_track, pdr_track
from mapfilter.pdr import Steps


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
