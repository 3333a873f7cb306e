"""The simulator: routes stay off walls, the IMU has one bump per step, RSSI follows the model,
the file is an ILC trace that reads back, the same seed gives the same bytes, bad input is one line."""

from __future__ import annotations

import dataclasses
import gzip
import math

import numpy as np
import pytest
from scipy import signal

from mapfilter.cli import main
from mapfilter.errors import MapfilterError
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import crosses_wall, touched_pixels_reference
from mapfilter.sensors.ilc import read_ilc
from mapfilter.sensors.pathloss import AccessPointTable, path_loss_rssi_dbm
from mapfilter.simulate.ilc_writer import write_ilc
from mapfilter.simulate.walk import (
    CHANNELS_2G4_MHZ,
    CHANNELS_5G_MHZ,
    SimConfig,
    count_walls_crossed,
    segments_cross_wall,
    segments_min_clearance_m,
    simulate_walk,
)

RES_M = 0.1


def office_plan() -> FloorPlan:
    """20 m x 14 m: two rooms in a central block, three rooms on top, a corridor loop around the block.

    Walls are 0.2 m thick; doors 1.0 m wide.
    """
    w, h = int(20 / RES_M), int(14 / RES_M)
    mask = np.zeros((h, w), bool)

    def px(v: float) -> int:
        return int(round(v / RES_M))

    def wall_y(y, x0, x1):  # horizontal wall whose lower face is at world y
        mask[h - px(y) - 2:h - px(y), px(x0):px(x1)] = True

    def wall_x(x, y0, y1):  # vertical wall whose left face is at world x
        mask[h - px(y1):h - px(y0), px(x):px(x) + 2] = True

    def door_y(y, x0, x1):
        mask[h - px(y) - 2:h - px(y), px(x0):px(x1)] = False

    mask[:2, :] = mask[-2:, :] = True
    mask[:, :2] = mask[:, -2:] = True
    wall_y(4, 5, 15.2), wall_y(9, 5, 15.2), wall_x(5, 4, 9.2), wall_x(15, 4, 9.2), wall_x(10, 4, 9.2)
    door_y(4, 7, 8), door_y(9, 12, 13)
    wall_y(11, 0, 20), wall_x(7, 11, 14), wall_x(13, 11, 14)
    door_y(11, 3, 4), door_y(11, 9.5, 10.5), door_y(11, 16, 17)
    return FloorPlan(mask, RES_M, (0.0, 0.0), "F1")


def office_aps() -> AccessPointTable:
    """Eight dual-band boxes; thesis-like parameters, 5 GHz weaker and lossier."""
    boxes = np.array([[1, 1], [19, 1], [10, 12.5], [1, 8], [19, 8], [7.5, 6.5], [12.5, 6.5], [3, 13]], float)
    bands = np.array(["2.4", "5"] * len(boxes))
    k = bands.size
    return AccessPointTable(
        bssid=[f"02:00:00:00:00:{i // 2:02x}" for i in range(k)], band=list(bands),
        xy_m=np.repeat(boxes, 2, axis=0), c_dbm=np.where(bands == "5", -45.0, -38.0), n=np.full(k, 2.0),
        alpha_db_per_m=np.where(bands == "5", 0.5, 0.3), d_max_m=np.full(k, 30.0))


@pytest.fixture(scope="module")
def plan() -> FloorPlan:
    return office_plan()


@pytest.fixture(scope="module")
def aps() -> AccessPointTable:
    return office_aps()


@pytest.fixture(scope="module")
def long_walk(plan, aps):
    return simulate_walk(plan, aps, SimConfig(duration_s=600.0), np.random.default_rng(7))


@pytest.fixture(scope="module")
def survey(plan, aps):
    return simulate_walk(plan, aps, SimConfig(duration_s=None, survey=True), np.random.default_rng(3))


# ---- independent references -------------------------------------------------------------
def sampled_pixels(plan: FloorPlan, a_m: np.ndarray, b_m: np.ndarray, spacing_px: float = 0.02):
    """Pixels under densely sampled points of a->b (a plain reference, misses only corner clips)."""
    uv0, uv1 = plan.world_to_pixel(a_m), plan.world_to_pixel(b_m)
    n = int(math.ceil(np.linalg.norm(uv1 - uv0) / spacing_px)) + 1
    s = np.linspace(0.0, 1.0, n)[:, None]
    uv = uv0 + s * (uv1 - uv0)
    rows, cols = np.floor(uv[:, 1]).astype(int), np.floor(uv[:, 0]).astype(int)
    h, w = plan.shape_px
    inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    wall = np.ones(n, bool)
    wall[inside] = plan.wall_mask[rows[inside], cols[inside]]
    return wall


def sampled_min_clearance_m(plan: FloorPlan, a_m, b_m, spacing_px: float = 0.02) -> float:
    uv0, uv1 = plan.world_to_pixel(a_m), plan.world_to_pixel(b_m)
    n = int(math.ceil(np.linalg.norm(uv1 - uv0) / spacing_px)) + 1
    uv = uv0 + np.linspace(0.0, 1.0, n)[:, None] * (uv1 - uv0)
    rows, cols = np.floor(uv[:, 1]).astype(int), np.floor(uv[:, 0]).astype(int)
    h, w = plan.shape_px
    if not ((rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)).all():
        return 0.0
    return float(plan.wall_distance_px[rows, cols].min() * plan.resolution_m)


def plain_crosses(plan, a_m, b_m) -> bool:
    return bool(sampled_pixels(plan, a_m, b_m).any())


def plain_wall_runs(plan, a_m, b_m) -> int:
    wall = sampled_pixels(plan, a_m, b_m)
    return int(np.count_nonzero(wall[1:] & ~wall[:-1]))


def detect_steps(t_s: np.ndarray, acc_mps2: np.ndarray, rate_hz: float = 50.0) -> int:
    """Lund-thesis style detector: |acc| on a uniform grid, 4th-order Butterworth low-pass at 3 Hz,
    count rising crossings of +1 m/s^2 above the mean (re-armed below the mean)."""
    grid = np.arange(t_s[0], t_s[-1], 1.0 / rate_hz)
    magnitude = np.interp(grid, t_s, np.linalg.norm(acc_mps2, axis=1))
    b, a = signal.butter(4, 3.0, fs=rate_hz)
    smooth = signal.filtfilt(b, a, magnitude - magnitude.mean())
    steps, armed = 0, True
    for value in smooth:
        if armed and value > 1.0:
            steps, armed = steps + 1, False
        elif not armed and value < 0.0:
            armed = True
    return steps


# ---- the wall kernels against the plain references --------------------------------------
def test_wall_kernels_agree_with_dense_sampling(plan):
    rng = np.random.default_rng(0)
    a, b = plan.sample_free(400, rng), plan.sample_free(400, rng)
    clearance = segments_min_clearance_m(plan, a, b)
    fast = clearance <= 0.0
    plain = np.array([plain_crosses(plan, p, q) for p, q in zip(a, b)])
    assert plain.any() and (~plain).any()
    assert not np.any(plain & ~fast)  # the exact walk never misses what sampling sees
    assert np.count_nonzero(fast != plain) <= 2  # ...and differs only on exact corner clips
    np.testing.assert_array_equal(fast, crosses_wall(plan, a, b))  # and agrees with the filter's check
    plain_clearance = np.array([sampled_min_clearance_m(plan, p, q) for p, q in zip(a, b)])
    assert np.all(clearance <= plain_clearance + 1e-12)
    assert np.mean(np.isclose(clearance, plain_clearance)) > 0.98
    runs = count_walls_crossed(plan, a, b)
    plain_runs = np.array([plain_wall_runs(plan, p, q) for p, q in zip(a, b)])
    assert runs.max() >= 3
    assert np.count_nonzero(runs != plain_runs) <= 4


def _enter_exit(u0, v0, u1, v1, row, col):
    """Segment parameters (t_in, t_out) over which the segment is inside the closed square."""
    t_lo, t_hi = 0.0, 1.0
    for p0, dp, lo in ((u0, u1 - u0, col), (v0, v1 - v0, row)):
        if dp != 0.0:
            ta, tb = (lo - p0) / dp, (lo + 1 - p0) / dp
            t_lo, t_hi = max(t_lo, min(ta, tb)), min(t_hi, max(ta, tb))
    return t_lo, t_hi


def oracle_min_clearance_and_runs(plan: FloorPlan, a_m, b_m) -> tuple[float, int]:
    """Brute force, no grid walk: the pixels whose closed square the segment meets (maps/walls.py's
    oracle), clearance = their smallest ``wall_distance_px`` (outside = 0); walls = free->wall
    transitions over those pixels ordered by where the segment is inside them, pixels touched over
    the same parameter interval (the side pixels of a lattice corner: one point) being one
    position, wall if any is; outside = free; the start pixel's state is the initial state.
    Needs end points off grid lines and no segment along a grid line (true below)."""
    (u0, v0), (u1, v1) = plan.world_to_pixel(a_m), plan.world_to_pixel(b_m)
    h, w = plan.shape_px
    touched = touched_pixels_reference((u0, v0), (u1, v1))
    inside = [(r, c) for r, c in touched if 0 <= r < h and 0 <= c < w]
    clearance = 0.0 if len(inside) < len(touched) else min(plan.wall_distance_px[r, c] for r, c in inside)
    positions: dict[tuple[float, float], bool] = {}
    for r, c in touched:
        key = _enter_exit(u0, v0, u1, v1, r, c)
        positions[key] = positions.get(key, False) or (0 <= r < h and 0 <= c < w and bool(plan.wall_mask[r, c]))
    states = [positions[key] for key in sorted(positions)]
    runs = sum(1 for prev, cur in zip(states, states[1:]) if cur and not prev)
    return clearance * plan.resolution_m, runs


def test_wall_kernels_equal_a_brute_force_oracle_with_corner_passes():
    """Exact equality on a 1 m grid: pixel-centre to pixel-centre moves (many pass exactly through
    lattice corners: a corner clip touches all four pixels) and random ones, some leaving the map,
    over a mask with thick, thin and diagonal (8-connected) walls."""
    rng = np.random.default_rng(11)
    size = 30
    mask = rng.random((size, size)) < 0.05
    mask[10:13, 2:25] = True  # a thick wall: one wall
    mask[20, 5:28] = True
    idx = np.arange(4, 20)
    mask[idx + 2, idx] = True  # a diagonal wall, closed for corner passes
    plan_1m = FloorPlan(mask, 1.0)
    n = 600
    centres = rng.integers(0, size, (n, 4)) + 0.5
    a = np.concatenate([centres[:, :2], rng.uniform(-2.0, size + 2.0, (n, 2))])
    b = np.concatenate([centres[:, 2:], rng.uniform(-2.0, size + 2.0, (n, 2))])
    on_grid_line = (a == np.floor(a)).any(axis=1) | (b == np.floor(b)).any(axis=1)
    a, b = a[~on_grid_line], b[~on_grid_line]
    clearance = segments_min_clearance_m(plan_1m, a, b)
    runs = count_walls_crossed(plan_1m, a, b)
    expected = [oracle_min_clearance_and_runs(plan_1m, p, q) for p, q in zip(a, b)]
    np.testing.assert_array_equal(clearance, [e[0] for e in expected])
    np.testing.assert_array_equal(runs, [e[1] for e in expected])
    assert runs.max() >= 3 and (clearance <= 0).any() and (clearance > 0).any()
    # the test has corner passes whose side pixels differ (one wall, one free)
    corner_clips = [
        i for i in range(n) if abs(b[i, 0] - a[i, 0]) == abs(b[i, 1] - a[i, 1]) > 0
        and any(mask[int(r), int(c)] for r, c in touched_pixels_reference(
            plan_1m.world_to_pixel(a[i]), plan_1m.world_to_pixel(b[i])) if 0 <= r < size and 0 <= c < size)]
    assert len(corner_clips) > 5
    # a non-finite move touches a wall for the planner, and crosses none for the radio model
    assert segments_min_clearance_m(plan_1m, np.array([[np.nan, 1.0]]), np.array([[2.5, 2.5]]))[0] == 0.0
    assert count_walls_crossed(plan_1m, np.array([[np.nan, 1.0]]), np.array([[2.5, 2.5]]))[0] == 0


def test_wall_count_treats_a_lattice_corner_as_one_point():
    """A diagonal line through the corner between a wall pixel and a free one enters one wall
    (the corner point, then the wall pixel beyond), not two; on a diagonal wall, one wall."""
    mask = np.zeros((6, 6), bool)
    mask[2, 3] = True  # side pixel of the corner (3, 3) on the line (0.5, 0.5)->(5.5, 5.5) in (u, v)
    mask[3, 3] = True  # the diagonal pixel after that corner
    plan_1m = FloorPlan(mask, 1.0)

    def uv_to_xy(u, v):
        return plan_1m.pixel_to_world(np.array([[u, v]]))

    a, b = uv_to_xy(0.5, 0.5), uv_to_xy(5.5, 5.5)
    assert count_walls_crossed(plan_1m, a, b)[0] == 1
    assert segments_min_clearance_m(plan_1m, a, b)[0] == 0.0
    diagonal = np.zeros((6, 6), bool)
    diagonal[[1, 2, 3, 4], [4, 3, 2, 1]] = True  # an 8-connected wall across the line
    plan_diag = FloorPlan(diagonal, 1.0)
    assert count_walls_crossed(plan_diag, a, b)[0] == 1


def test_wall_count_of_a_known_line(plan):
    # y = 6.5 from x = 1 to 19 crosses the block's walls at x = 5, 10, 15
    assert count_walls_crossed(plan, np.array([[1.0, 6.5]]), np.array([[19.0, 6.5]]))[0] == 3
    # through the open door at x = 7.5 into the left room: no wall
    assert count_walls_crossed(plan, np.array([[7.5, 1.0]]), np.array([[7.5, 6.5]]))[0] == 0
    assert segments_cross_wall(plan, np.array([[7.5, 1.0]]), np.array([[7.5, 6.5]]))[0] == np.False_
    assert segments_cross_wall(plan, np.array([[6.0, 1.0]]), np.array([[6.0, 6.5]]))[0] == np.True_


# ---- routes -------------------------------------------------------------------------------
@pytest.mark.parametrize("which", ["long_walk", "survey"])
def test_routes_never_cross_walls(which, request, plan):
    walk = request.getfixturevalue(which)
    xy = walk.waypoint_xy_m
    assert xy.shape[0] > 100
    assert plan.is_free(xy).all()
    assert plan.distance_to_wall_m(xy).min() >= SimConfig().min_clearance_m - RES_M
    for p, q in zip(xy[:-1], xy[1:]):
        assert not plain_crosses(plan, p, q), (p, q)
    assert not segments_cross_wall(plan, xy[:-1], xy[1:]).any()
    assert segments_min_clearance_m(plan, xy[:-1], xy[1:]).min() > 0.0  # our own pixel walk agrees
    assert not crosses_wall(plan, xy[:-1], xy[1:]).any()


def test_route_visits_rooms_through_doors(long_walk):
    xy = long_walk.waypoint_xy_m
    in_block = (xy[:, 0] > 5.2) & (xy[:, 0] < 15) & (xy[:, 1] > 4.2) & (xy[:, 1] < 9)
    in_top = xy[:, 1] > 11.2
    assert in_block.any() and in_top.any() and (~in_block & ~in_top).any()


def test_steps_speed_and_ground_truth_at_every_step(long_walk):
    walk = long_walk
    assert walk.n_steps > 300
    # a waypoint at every step end, at the step's end position
    assert np.isin(walk.step_end_t_s, walk.waypoint_t_s).all()
    moves = np.linalg.norm(np.diff(walk.waypoint_xy_m, axis=0), axis=1)
    assert np.count_nonzero(moves > 1e-9) == walk.n_steps
    assert 0.55 < np.median(walk.step_length_m) < 0.85
    duration = walk.step_end_t_s - walk.step_start_t_s
    speed = walk.step_length_m / duration
    assert 1.0 <= np.median(speed) <= 1.5 and speed.max() <= 1.5 * 1.15  # 3 % step-length jitter
    # cadence: about 0.7 m at 1.0-1.5 m/s, even for the odd short step cut at a corner
    assert 1.0 < (1.0 / duration).min() and (1.0 / duration).max() < 2.6


# ---- IMU ----------------------------------------------------------------------------------
def test_imu_has_one_bump_per_step(long_walk):
    walk = long_walk
    rate = 1.0 / np.median(np.diff(walk.acc_t_s))
    assert 45 < rate < 55
    assert 0 < walk.acc_t_s.size < walk.heading_t_s.size  # some samples dropped
    assert np.diff(walk.acc_t_s).max() > 0.1  # and a stall or two
    assert np.all(np.diff(walk.acc_t_s) > 0)
    detected = detect_steps(walk.acc_t_s, walk.acc_mps2)
    assert abs(detected - walk.n_steps) <= max(2, 0.01 * walk.n_steps), (detected, walk.n_steps)
    # standing still: the accelerometer reads gravity
    still = walk.acc_t_s < walk.start_t_s + SimConfig().initial_still_s
    assert abs(np.linalg.norm(walk.acc_mps2[still].mean(axis=0)) - 9.81) < 0.1


def test_the_pdr_step_detector_counts_the_route_steps(tmp_path, long_walk):
    """The project's own PDR (thesis detector) on the written file finds the simulated steps."""
    from mapfilter.sensors import pdr

    write_ilc(long_walk, tmp_path / "walk.txt")
    steps = pdr.detect_steps(read_ilc(tmp_path / "walk.txt"))
    assert abs(len(steps) - long_walk.n_steps) <= 0.02 * long_walk.n_steps, (len(steps), long_walk.n_steps)
    # each detected step lies within a simulated step (give or take half a step)
    nearest = np.min(np.abs(steps.t_s[:, None] - 0.5 * (long_walk.step_start_t_s + long_walk.step_end_t_s)[None]),
                     axis=1)
    assert np.percentile(nearest, 95) < 0.3


def test_gyro_about_gravity_integrates_to_the_heading(long_walk):
    walk = long_walk
    gravity_dir = walk.acc_mps2.mean(axis=0)
    gravity_dir /= np.linalg.norm(gravity_dir)
    yaw_rate = (walk.gyro_radps - walk.gyro_bias_radps) @ gravity_dir
    dt = np.diff(walk.gyro_t_s, prepend=walk.gyro_t_s[0])
    yaw = np.cumsum(yaw_rate * dt)
    truth = np.interp(walk.gyro_t_s, walk.heading_t_s, walk.heading_rad)
    drift = (yaw - yaw[0]) - (truth - truth[0])
    assert abs(truth[-1] - truth[0]) > 0 or np.ptp(truth) > 3.0
    assert np.percentile(np.abs(drift), 95) < math.radians(10)


def test_rotation_vector_azimuth_is_the_android_convention(long_walk):
    walk = long_walk
    x, y, z = walk.rotvec_xyz.T
    w = np.sqrt(np.clip(1.0 - x * x - y * y - z * z, 0.0, None))
    # Android SensorManager.getRotationMatrixFromVector + getOrientation: azimuth = atan2(R[0][1], R[1][1])
    r01 = 2 * (x * y - z * w)
    r11 = 1 - 2 * (x * x + z * z)
    azimuth = np.arctan2(r01, r11)
    heading = np.pi / 2 - azimuth  # map heading (from +x east, counter-clockwise)
    truth = np.interp(walk.rotvec_t_s, walk.heading_t_s, walk.heading_rad)
    error = np.angle(np.exp(1j * (heading - truth)))
    assert np.median(np.abs(error)) < math.radians(15)
    assert np.percentile(np.abs(error - np.median(error)), 95) < math.radians(8)


# ---- WiFi ---------------------------------------------------------------------------------
def test_rssi_statistics_match_the_model(tmp_path, long_walk, plan, aps):
    """Read the file back, rebuild each row's model mean from the ground truth: residuals ~ N(0, sigma)."""
    config = SimConfig()
    path = tmp_path / "walk.txt"
    write_ilc(long_walk, path)
    rec = read_ilc(path, max_wifi_age_s=np.inf)
    key_index = {k: i for i, k in enumerate(aps.keys)}
    ap = np.array([key_index[k] for k in rec.wifi.ap_keys])[rec.wifi.row_ap]
    seen_t = rec.wifi.t_s[rec.wifi.row_scan] - rec.wifi.age_s
    xy = np.stack([np.interp(seen_t, rec.waypoint_t_s, rec.waypoint_xy_m[:, c]) for c in (0, 1)], axis=-1)
    walls = np.array([plain_wall_runs(plan, aps.xy_m[k], p) for k, p in zip(ap, xy)])
    loss = np.where(np.array(aps.band)[ap] == "5", config.wall_loss_5g_db, config.wall_loss_2g4_db)
    d = np.linalg.norm(xy - aps.xy_m[ap], axis=1)
    model = path_loss_rssi_dbm(d, aps.c_dbm[ap], aps.n[ap], aps.alpha_db_per_m[ap], aps.d_max_m[ap]) - loss * walls
    residual = rec.wifi.rssi_dbm - model
    assert rec.wifi.rssi_dbm.min() >= config.sensitivity_dbm
    strong = model > config.sensitivity_dbm + 3 * config.shadowing_sigma_db  # the floor does not bias these
    assert strong.sum() > 1500
    assert abs(residual[strong].mean()) < 0.4
    assert abs(residual[strong].std() - config.shadowing_sigma_db) < 0.3
    for n_walls in (0, 1, 2):  # the per-wall loss is right, not only the average
        group = strong & (walls == n_walls)
        assert group.sum() > 100 and abs(residual[group].mean()) < 1.0, n_walls
    # both bands on their channels; stale cached rows like real scans, dropped by the default reader
    freq = rec.wifi.freq_mhz
    assert set(freq[freq < 3000].astype(int)) <= set(CHANNELS_2G4_MHZ)
    assert set(freq[freq > 3000].astype(int)) <= set(CHANNELS_5G_MHZ) and (freq > 3000).any()
    assert 0.05 < long_walk.stale.mean() < 0.6
    assert rec.wifi.age_s.max() > 5.0
    assert read_ilc(path).wifi.row_ap.size < rec.wifi.row_ap.size
    gaps = np.diff(rec.wifi.t_s)
    assert gaps.min() >= 2.0 - 1e-3 and gaps.max() <= 4.0 + 1e-3


def test_shadowing_sigma_is_configurable(plan, aps):
    walk = simulate_walk(plan, aps, SimConfig(duration_s=200.0, shadowing_sigma_db=2.0, stale_probability=0.0,
                                              cache_probability=0.0), np.random.default_rng(11))
    strong = walk.expected_rssi_dbm > -80
    residual = walk.rssi_dbm[strong] - walk.expected_rssi_dbm[strong]
    assert not walk.stale.any()
    assert abs(residual.std() - math.sqrt(2.0 ** 2 + 1 / 12)) < 0.2  # integer dBm adds 1/12 dB^2


# ---- the file -----------------------------------------------------------------------------
def test_file_reads_back_with_every_record(tmp_path, plan, aps):
    walk = simulate_walk(plan, aps, SimConfig(duration_s=60.0), np.random.default_rng(5))
    for name in ("walk.txt", "walk.txt.gz"):
        write_ilc(walk, tmp_path / name)
        rec = read_ilc(tmp_path / name, max_wifi_age_s=np.inf)
        assert rec.floor_name == "F1"
        assert rec.start_t_s == pytest.approx(walk.start_t_s)
        assert rec.waypoint_t_s.size == walk.waypoint_t_s.size
        np.testing.assert_allclose(rec.waypoint_xy_m, walk.waypoint_xy_m, atol=1e-6)
        assert rec.acc_t_s.size == walk.acc_t_s.size and rec.gyro_t_s.size == walk.gyro_t_s.size
        assert rec.magnet_t_s.size == walk.magnet_t_s.size and rec.rotvec_t_s.size == walk.rotvec_t_s.size
        np.testing.assert_allclose(rec.acc_mps2, walk.acc_mps2, rtol=1e-6, atol=1e-6)
        assert len(rec.wifi) == walk.scan_t_s.size
        assert rec.wifi.row_ap.size == walk.row_ap.size
    text = (tmp_path / "walk.txt").read_text()
    assert text.startswith("#\tstartTime:1600000000000\n#\tSiteID:")
    assert text.rstrip("\n").splitlines()[-1] == f"#\tendTime:{round(walk.end_t_s * 1000)}"
    assert gzip.decompress((tmp_path / "walk.txt.gz").read_bytes()).decode() == text
    wifi_line = next(line for line in text.splitlines() if "\tTYPE_WIFI\t" in line).split("\t")
    assert len(wifi_line) == 7 and int(wifi_line[0]) >= int(wifi_line[6])


def test_same_seed_same_file_other_seed_other_file(tmp_path, plan, aps):
    config = SimConfig(duration_s=30.0)
    for i, seed in enumerate((4, 4, 5)):
        walk = simulate_walk(plan, aps, config, np.random.default_rng(seed))
        write_ilc(walk, tmp_path / f"{i}.txt.gz")
    first, again, other = ((tmp_path / f"{i}.txt.gz").read_bytes() for i in range(3))
    assert first == again
    assert first != other


def test_survey_scans_stand_on_reference_points(survey):
    walk = survey
    assert walk.reference_xy_m.shape[0] > 30
    scan_xy = walk.position_at(walk.scan_t_s)
    nearest = np.min(np.linalg.norm(scan_xy[:, None] - walk.reference_xy_m[None], axis=-1), axis=1)
    assert np.all(nearest < 1e-9)
    assert walk.scan_t_s.size == SimConfig().survey_scans_per_point * walk.reference_xy_m.shape[0]
    assert np.isin(walk.scan_t_s, walk.waypoint_t_s).all()
    # fresh rows were measured while standing there too
    fresh = ~walk.stale
    seen_xy = walk.position_at(walk.seen_t_s[fresh])
    np.testing.assert_allclose(seen_xy, scan_xy[walk.row_scan[fresh]], atol=1e-9)
    # reference points about 2 m apart
    d = np.linalg.norm(walk.reference_xy_m[:, None] - walk.reference_xy_m[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    assert 1.8 < np.median(d.min(axis=1)) < 2.2


# ---- bad inputs and the CLI ---------------------------------------------------------------
@pytest.mark.parametrize("bad", [dict(duration_s=-1.0), dict(duration_s=0.0), dict(duration_s=math.nan),
                                 dict(speed_mps=(1.5, 1.0)), dict(shadowing_sigma_db=-1.0)])
def test_bad_config_is_a_mapfilter_error(plan, aps, bad):
    with pytest.raises(MapfilterError):
        simulate_walk(plan, aps, dataclasses.replace(SimConfig(), **bad), np.random.default_rng(0))


def test_map_without_room_to_walk_is_a_mapfilter_error(aps):
    mask = np.ones((50, 50), bool)
    mask[20:23, 5:45] = False  # a 0.3 m slot: no point 0.25 m from a wall with room to move
    with pytest.raises(MapfilterError, match="no free space"):
        simulate_walk(FloorPlan(mask, RES_M), aps, SimConfig(), np.random.default_rng(0))


@pytest.fixture()
def map_files(tmp_path, plan, aps):
    aps.write_csv(tmp_path / "aps.csv")
    plan.save(tmp_path / "office.yaml")
    with_aps = dataclasses.replace(plan, access_points_csv=tmp_path / "aps.csv")
    with_aps.save(tmp_path / "office_with_aps.yaml")
    return tmp_path


def test_cli_writes_a_trace(map_files, capsys):
    out = map_files / "walk.txt.gz"
    code = main(["simulate", str(map_files / "office.yaml"), "--aps", str(map_files / "aps.csv"),
                 "--out", str(out), "--duration", "20", "--seed", "2"])
    assert code == 0
    rec = read_ilc(out)
    assert rec.waypoint_t_s.size > 10 and len(rec.wifi) >= 4
    assert rec.waypoint_t_s[-1] - rec.start_t_s == pytest.approx(20.0, abs=0.01)
    # the map's own access-point table when --aps is omitted; survey mode
    out2 = map_files / "survey.txt"
    assert main(["simulate", str(map_files / "office_with_aps.yaml"), "--out", str(out2), "--survey",
                 "--survey-spacing", "4", "--scans-per-point", "2"]) == 0
    assert len(read_ilc(out2, max_wifi_age_s=np.inf).wifi) > 10


@pytest.mark.parametrize("args, message", [
    (["{d}/missing.yaml", "--aps", "{d}/aps.csv"], "missing.yaml: file not found"),
    (["{d}/office.yaml", "--aps", "{d}/missing.csv"], "missing.csv: file not found"),
    (["{d}/office.yaml"], "no access points"),
])
def test_cli_bad_inputs_are_one_line(map_files, capsys, args, message):
    out = map_files / "never.txt"
    code = main(["simulate", *[a.format(d=map_files) for a in args], "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 1
    assert message in err and err.count("\n") == 1 and "Traceback" not in err


@pytest.mark.parametrize("args, message", [
    (["--duration", "-5"], "argument --duration: must be above 0"),
    (["--duration", "1e9"], "argument --duration: must be at most 14400"),
    (["--duration", "inf"], "argument --duration: must be a finite number"),
    (["--seed", "-1"], "argument --seed: must be at least 0, got -1"),
    (["--seed", "x"], "argument --seed: must be a whole number"),
    (["--survey", "--scans-per-point", "0"], "argument --scans-per-point: must be at least 1"),
    (["--survey", "--scans-per-point", "100000"], "argument --scans-per-point: must be at most 100"),
    (["--survey", "--survey-spacing", "0.001"], "argument --survey-spacing: must be at least 0.25"),
    (["--shadowing-db", "1e300"], "argument --shadowing-db: must be at most 100"),
    (["--start-time-ms", "-1"], "argument --start-time-ms: must be at least 0"),
    (["--start-time-ms", "99999999999999999"], "argument --start-time-ms: must be at most"),
    (["--segment-s", "1", "1e9"], "argument --segment-s: must be at most 14400"),
    (["--floor-changes", "1000000"], "argument --floor-changes: must be at most 1000"),
])
def test_cli_values_beyond_any_real_use_are_refused_by_argparse(map_files, capsys, args, message):
    out = map_files / "never.txt"
    with pytest.raises(SystemExit) as exit_info:
        main(["simulate", str(map_files / "office.yaml"), "--aps", str(map_files / "aps.csv"), *args, "--out", str(out)])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and message in err.strip().splitlines()[-1] and "Traceback" not in err
    assert not out.exists()


def test_library_limits_refuse_what_would_not_fit(map_files):
    from mapfilter.simulate.walk import MAX_DURATION_S, MAX_SURVEY_POINTS

    plan = FloorPlan.load(map_files / "office.yaml")
    aps = AccessPointTable.read_csv(map_files / "aps.csv")
    rng = np.random.default_rng(0)
    for config, message in ((SimConfig(duration_s=MAX_DURATION_S * 10), "duration must be at most"),
                            (SimConfig(survey=True, duration_s=None, survey_spacing_m=0.01), "at least the route grid"),
                            (SimConfig(imu_rate_hz=1e9), "imu_rate_hz must be at most"),
                            (SimConfig(blocking_episodes=((0.0, 1e12, 3.0),)), "blocking episode")):
        with pytest.raises(MapfilterError, match=message):
            simulate_walk(plan, aps, config, rng)
    # a survey grid with more points than MAX_SURVEY_POINTS is refused before the walk is planned
    big = FloorPlan(_border(170), 0.25)  # about 27 000 route-grid nodes, each a reference point at 0.25 m
    with pytest.raises(MapfilterError, match=f"more than {MAX_SURVEY_POINTS}"):
        simulate_walk(big, aps, SimConfig(survey=True, duration_s=None, survey_spacing_m=0.25), rng)


def _border(n: int) -> np.ndarray:
    wall = np.zeros((n, n), dtype=bool)
    wall[0, :] = wall[-1, :] = wall[:, 0] = wall[:, -1] = True
    return wall
