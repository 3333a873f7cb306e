"""WiFi models: path loss, scans, trilateration likelihood, LS baseline, AP estimation."""

import numpy as np
import pytest

from mapfilter.errors import MapfilterError
from mapfilter.filter.models.path_loss import TrilaterationLikelihood, path_loss_kernel
from mapfilter.filter.particle_filter import evaluate_log_likelihood
from mapfilter.filter.kernels.passes import run_likelihood
from mapfilter.filter.particles import Particles
from mapfilter.sensors.ilc import read_ilc
from mapfilter.sensors.pathloss import (
    AccessPointTable,
    ApFitConfig,
    estimate_access_points,
    least_squares_position,
    path_loss_rssi_dbm,
)
from mapfilter.sensors.radiomap import RadioMap
from mapfilter.sensors.wifi import WifiScan, iter_scans, scans_of


def _table(xy, c=-38.0, n=2.0, alpha=0.4, d_max=30.0):
    k = len(xy)
    return AccessPointTable(bssid=[f"02:00:00:00:00:{i:02x}" for i in range(k)], band=["2.4"] * k,
                            xy_m=np.asarray(xy, float), c_dbm=np.full(k, c), n=np.full(k, n),
                            alpha_db_per_m=np.full(k, alpha), d_max_m=np.full(k, d_max))


def _scan(table, xy, rng=None, noise_db=0.0):
    r = table.expected_rssi_dbm(np.asarray(xy, float)[None])[0]
    if rng is not None:
        r = r + rng.normal(0, noise_db, r.shape)
    return WifiScan(0.0, tuple(table.keys), r.astype(np.float32))


def test_path_loss_against_hand_computed_values():
    # R(10) = -38 - 10*2*1 - 0.4*10 = -62 ; R(100) with d_max 30: -38 - 40 - 12 = -90
    assert path_loss_rssi_dbm(10.0, -38.0, 2.0, 0.4, 30.0) == pytest.approx(-62.0)
    assert path_loss_rssi_dbm(100.0, -38.0, 2.0, 0.4, 30.0) == pytest.approx(-90.0)
    # n = 3, alpha 0.5, d = 2: -40 - 30*log10(2) - 1 = -50.0309
    assert path_loss_rssi_dbm(2.0, -40.0, 3.0, 0.5, 30.0) == pytest.approx(-41.0 - 30 * np.log10(2.0))
    # below 1 m the model is clamped at the reference distance
    assert path_loss_rssi_dbm(0.1, -38.0, 2.0, 0.4, 30.0) == pytest.approx(-38.4)


def test_path_loss_kernel_matches_the_formula():
    table = _table([[0, 0], [10, 0]])
    xy = np.array([[3.0, 4.0], [20.0, 5.0]])
    obs = np.array([-55.0, -60.0])
    kernel = path_loss_kernel(table.xy_m, table.c_dbm, table.n, table.alpha_db_per_m, table.d_max_m, obs, 25.0)
    ll = run_likelihood(kernel.function, kernel.params, Particles.at(xy).state)
    expected = -0.5 * ((obs[None] - table.expected_rssi_dbm(xy)) ** 2).sum(axis=1) / 25.0
    np.testing.assert_allclose(ll, expected, rtol=1e-4)


def test_trilateration_likelihood_peaks_at_the_true_position():
    table = _table([[0, 0], [30, 0], [0, 20], [30, 20], [15, 10]])
    truth = np.array([8.0, 13.0])
    xs, ys = np.meshgrid(np.arange(0, 30.01, 0.5), np.arange(0, 20.01, 0.5))
    grid = np.column_stack([xs.ravel(), ys.ravel()])
    model = TrilaterationLikelihood(table)
    ll = evaluate_log_likelihood(model, _scan(table, truth), Particles.at(grid))
    assert ll.shape == (grid.shape[0],)
    assert np.linalg.norm(grid[np.argmax(ll)] - truth) < 0.5
    # keys of both bands are distinct APs: the same BSSID on 5 GHz is not matched
    other_band = WifiScan(0.0, tuple(k.replace("@2.4", "@5") for k in table.keys), np.full(5, -50, np.float32))
    assert np.all(evaluate_log_likelihood(model, other_band, Particles.at(grid)) == 0)


def test_least_squares_position_on_noisy_synthetic_scans():
    rng = np.random.default_rng(1)
    table = _table(rng.uniform(0, 50, (12, 2)))
    errors = []
    for _ in range(30):
        truth = rng.uniform(5, 45, 2)
        errors.append(np.linalg.norm(least_squares_position(table, _scan(table, truth, rng, 2.0)) - truth))
    assert np.median(errors) < 2.0
    with pytest.raises(MapfilterError, match="shares 0 access points"):
        least_squares_position(table, WifiScan(0.0, ("aa:aa:aa:aa:aa:aa@2.4",), np.array([-50.0], np.float32)))


def test_estimate_access_points_recovers_known_positions():
    rng = np.random.default_rng(7)
    true_xy = np.array([[10.0, 10.0], [40.0, 12.0], [25.0, 35.0]])
    table = _table(true_xy, c=-40.0, n=2.2)
    # survey: reference points along a few corridors, RSSI from the model + 4 dB noise
    xy = np.concatenate([np.column_stack([np.linspace(0, 50, 120), np.full(120, y)]) for y in (5.0, 20.0, 30.0)]
                        + [np.column_stack([np.full(60, 20.0), np.linspace(0, 40, 60)])])
    rssi = table.expected_rssi_dbm(xy) + rng.normal(0, 4.0, (xy.shape[0], 3))
    rssi[rssi < -90] = np.nan  # too weak to be heard
    radio_map = RadioMap(xy, table.keys, rssi, np.arange(xy.shape[0], dtype=float), np.zeros(xy.shape[0]), ["syn"])
    fitted = estimate_access_points(radio_map, ApFitConfig(min_observations=8))
    assert fitted.keys == table.keys
    assert np.all(np.linalg.norm(fitted.xy_m - true_xy, axis=1) < 3.0)
    assert np.all(np.abs(fitted.n - 2.2) < 0.5)
    with pytest.raises(MapfilterError, match="nothing to fit"):
        estimate_access_points(radio_map, ApFitConfig(min_observations=10_000))


def test_ap_table_csv_round_trip(tmp_path):
    table = _table([[1.5, 2.25], [3.0, 4.0]], c=-41.5)
    table.write_csv(tmp_path / "aps.csv")
    back = AccessPointTable.read_csv(tmp_path / "aps.csv")
    assert back.keys == table.keys
    np.testing.assert_allclose(back.xy_m, table.xy_m, atol=1e-3)
    np.testing.assert_allclose(back.c_dbm, table.c_dbm)


def test_iter_scans_on_a_real_trace(ilc_site1):
    path = sorted((ilc_site1 / "F1" / "path_data_files").glob("*.txt.gz"))[0]
    rec = read_ilc(path)
    scans = list(iter_scans(rec))
    assert len(scans) == len(rec.wifi) > 0
    assert np.all(np.diff([s.t_s for s in scans]) > 0)
    for i in (0, len(scans) - 1):
        keys, rssi = rec.wifi.scan(i)
        assert list(scans[i].ap_keys) == keys
        np.testing.assert_array_equal(scans[i].rssi_dbm, rssi)


def test_a_log_without_wifi_is_a_clear_error(tmp_path):
    log = tmp_path / "nowifi.txt"
    log.write_text("1000\tTYPE_WAYPOINT\t1.0\t2.0\n1500\tTYPE_ACCELEROMETER\t0\t0\t9.8\t3\n3000\tTYPE_WAYPOINT\t3.0\t2.0\n")
    with pytest.raises(MapfilterError, match="no usable WiFi"):
        scans_of(read_ilc(log))


def test_trilateration_uses_a_kernel_equal_to_the_plain_formula():
    rng = np.random.default_rng(2)
    table = _table(rng.uniform(0, 60, (7, 2)), c=-41.0, n=2.4)
    xy = rng.uniform(-5, 65, (500, 2))
    scan = _scan(table, [20.0, 30.0], rng, 3.0)
    ll = evaluate_log_likelihood(TrilaterationLikelihood(table, variance_db2=16.0), scan, Particles.at(xy))
    plain = -0.5 * ((scan.rssi_dbm[None].astype(float) - table.expected_rssi_dbm(xy)) ** 2).sum(axis=1) / 16.0
    np.testing.assert_allclose(ll - ll.max(), plain - plain.max(), rtol=1e-3, atol=1e-2)
    with pytest.raises(MapfilterError, match="variance"):
        TrilaterationLikelihood(table, variance_db2=0.0)


@pytest.mark.slow
def test_estimate_access_points_from_real_logs(ilc_site1):
    recs = [read_ilc(p) for p in sorted((ilc_site1 / "F1" / "path_data_files").glob("*.txt.gz"))[:4]]
    table = estimate_access_points(recs, ApFitConfig(min_observations=10))
    assert len(table) > 20
    # every fitted AP lies near the surveyed area (bounded fit) with a plausible exponent
    wp = np.concatenate([r.waypoint_xy_m for r in recs])
    lo, hi = wp.min(axis=0) - 15.0 - 1e-6, wp.max(axis=0) + 15.0 + 1e-6
    assert np.all((table.xy_m >= lo) & (table.xy_m <= hi))
    assert np.all((table.n >= 1.5) & (table.n <= 5.0)) and np.all(table.c_dbm <= -15.0)


def test_estimate_access_points_with_alpha_fitted_stays_close():
    rng = np.random.default_rng(8)
    true_xy = np.array([[12.0, 8.0], [33.0, 25.0]])
    table = _table(true_xy, c=-39.0, n=2.0, alpha=0.4)
    xs, ys = np.meshgrid(np.arange(0, 50, 2.5), np.arange(0, 35, 2.5))
    xy = np.column_stack([xs.ravel(), ys.ravel()])
    rssi = table.expected_rssi_dbm(xy) + rng.normal(0, 3.0, (xy.shape[0], 2))
    radio_map = RadioMap(xy, table.keys, rssi, np.zeros(xy.shape[0]), np.zeros(xy.shape[0]), ["syn"])
    fitted = estimate_access_points(radio_map, ApFitConfig(fit_alpha=True))
    assert np.all(np.linalg.norm(fitted.xy_m - true_xy, axis=1) < 2.0)
    assert np.all((fitted.alpha_db_per_m >= 0) & (fitted.alpha_db_per_m <= 2.0))
