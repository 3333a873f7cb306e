"""Radio map: building from real logs, file round trip, KWNN against brute force, likelihood, CLI."""

from pathlib import Path

import dataclasses
import numpy as np
import pytest
from conftest import ILC_SITE1

from mapfilter.cli import main
from mapfilter.errors import MapfilterError
from mapfilter.filter.particles import Particles
from mapfilter.filter.models.radio_map import RadioMapLikelihood, RadioMapLikelihoodConfig
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.sensors.ilc import read_ilc
from mapfilter.sensors.pathloss import AccessPointTable
from mapfilter.sensors.radiomap import (RadioMap, build_radio_map, check_radio_map_on_map, kwnn_fix_many,
                                       label_scans, strong_kwnn_fixes)
from mapfilter.sensors.wifi import WifiScan, iter_scans

REPO = Path(__file__).resolve().parents[2]
F1_LOGS = sorted((ILC_SITE1 / "F1" / "path_data_files").glob("*.txt.gz"))


def _random_map(rng, p=40, k=12, heard=0.6):
    rssi = rng.uniform(-95, -40, (p, k)).astype(np.float32)
    rssi[rng.random((p, k)) > heard] = np.nan
    keys = [f"02:00:00:00:01:{j:02x}@{'2.4' if j % 2 else '5'}" for j in range(k)]
    return RadioMap(rng.uniform(0, 50, (p, 2)), keys, rssi, np.arange(p, dtype=float), np.zeros(p, int), ["t0"])


def _kwnn_brute(radio_map, scan_row, k, p, q, missing, min_shared, per_ap=False):
    """Plain loops: the reference KWNN (``per_ap``: the power mean over the APs either side heard)."""
    dists = []
    for i in range(len(radio_map)):
        total, shared, either = 0.0, 0, 0
        for j in range(len(radio_map.ap_keys)):
            a, b = float(scan_row[j]), float(radio_map.rssi_dbm[i, j])
            if np.isnan(a) and np.isnan(b):
                continue
            either += 1
            shared += int(not np.isnan(a) and not np.isnan(b))
            total += abs((missing if np.isnan(a) else a) - (missing if np.isnan(b) else b)) ** p
        if shared >= min_shared:
            dists.append(((total / either if per_ap else total) ** (1 / p), i))
    nearest = sorted(dists)[:k]
    w = np.array([1 / d ** q for d, _ in nearest])
    return (w[:, None] * radio_map.xy_m[[i for _, i in nearest]]).sum(axis=0) / w.sum()


@pytest.mark.parametrize("k,p,q", [(4, 2, 2), (1, 1, 1), (3, 1.5, 0), (6, 3, 2)])
def test_per_ap_kwnn_matches_brute_force(k, p, q):
    rng = np.random.default_rng(k * 7 + int(p * 5))
    radio_map = _random_map(rng)
    scans = radio_map.rssi_dbm[10:18].copy() + rng.normal(0, 3, (8, len(radio_map.ap_keys))).astype(np.float32)
    scans[rng.random(scans.shape) > 0.7] = np.nan
    fixes = kwnn_fix_many(radio_map, scans, k=k, p=p, q=q, missing_dbm=-100, min_shared_aps=2, per_ap=True)
    plain = kwnn_fix_many(radio_map, scans, k=k, p=p, q=q, missing_dbm=-100, min_shared_aps=2)
    for s in range(scans.shape[0]):
        expected = _kwnn_brute(radio_map, scans[s], k, p, q, -100.0, 2, per_ap=True)
        np.testing.assert_allclose(fixes.xy_m[s], expected, rtol=1e-9, atol=1e-9)
    # the mean is not the sum: on these maps (APs heard 40-100 % of the time) some fix moves
    assert np.nanmax(np.abs(fixes.xy_m - plain.xy_m)) > 0.1


def test_per_ap_distance_does_not_favour_references_that_heard_few_aps():
    """A reference that heard the scan's APs at its levels plus four more (just heard, -84 dBm)
    is the right one; plain KWNN takes a far one that heard only the scan's three APs, 6 dB off,
    because it pays for fewer APs."""
    keys = [f"02:00:00:00:02:{j:02x}@5" for j in range(7)]
    rssi = np.full((2, 7), np.nan, np.float32)
    rssi[0, :3] = [-50.0, -60.0, -70.0]
    rssi[0, 3:] = -84.0
    rssi[1, :3] = [-56.0, -66.0, -76.0]
    radio_map = RadioMap(np.array([[0.0, 0.0], [30.0, 0.0]]), keys, rssi, np.zeros(2), np.zeros(2, int), ["t0"])
    scan = np.full((1, 7), np.nan)
    scan[0, :3] = [-50.0, -60.0, -70.0]
    args = dict(k=1, missing_dbm=-90.0, min_rssi_dbm=-85.0)
    assert kwnn_fix_many(radio_map, scan, **args).xy_m[0, 0] == pytest.approx(30.0)  # plain: 12.0 dB against 10.4 dB
    assert kwnn_fix_many(radio_map, scan, per_ap=True, **args).xy_m[0, 0] == pytest.approx(0.0)  # per AP: 4.5 against 6.0 dB


@pytest.mark.parametrize("k,p,q", [(4, 2, 2), (1, 1, 1), (3, 1.5, 0), (6, 3, 2)])
def test_kwnn_matches_brute_force_with_missing_aps(k, p, q):
    rng = np.random.default_rng(k * 10 + int(p * 3))
    radio_map = _random_map(rng)
    scans = radio_map.rssi_dbm[:8].copy() + rng.normal(0, 3, (8, len(radio_map.ap_keys))).astype(np.float32)
    scans[rng.random(scans.shape) > 0.7] = np.nan  # APs heard on one side only
    fixes = kwnn_fix_many(radio_map, scans, k=k, p=p, q=q, missing_dbm=-100, min_shared_aps=2)
    for s in range(scans.shape[0]):
        expected = _kwnn_brute(radio_map, scans[s], k, p, q, -100.0, 2)
        np.testing.assert_allclose(fixes.xy_m[s], expected, rtol=1e-9, atol=1e-9)
        # the scan as keys, including an AP the map has never seen (ignored)
        heard = ~np.isnan(scans[s])
        keys = tuple(key for key, h in zip(radio_map.ap_keys, heard) if h) + ("ff:ff:ff:ff:ff:ff@5",)
        scan = WifiScan(0.0, keys, np.append(scans[s][heard], -30.0).astype(np.float32))
        one = kwnn_fix_many(radio_map, radio_map.scan_matrix([scan]), k=k, p=p, q=q, min_shared_aps=2)
        np.testing.assert_allclose(one.xy_m[0], expected, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("floor_dbm", [-85.0, -70.0])
def test_strong_kwnn_is_plain_kwnn_on_the_strong_readings(floor_dbm):
    rng = np.random.default_rng(int(-floor_dbm))
    radio_map = _random_map(rng, heard=0.9)
    scans = radio_map.rssi_dbm[:8].copy() + rng.normal(0, 3, (8, len(radio_map.ap_keys))).astype(np.float32)
    fixes = kwnn_fix_many(radio_map, scans, k=4, missing_dbm=floor_dbm - 5, min_shared_aps=2, min_rssi_dbm=floor_dbm)
    # the oracle: readings below the floor removed by hand from both sides, then plain KWNN
    strong_map = RadioMap(radio_map.xy_m, radio_map.ap_keys,
                          np.where(radio_map.rssi_dbm < floor_dbm, np.nan, radio_map.rssi_dbm), radio_map.t_s,
                          radio_map.trace, radio_map.source_traces)
    strong_scans = np.where(scans < floor_dbm, np.nan, scans)
    for s in range(scans.shape[0]):
        expected = _kwnn_brute(strong_map, strong_scans[s], 4, 2.0, 2.0, floor_dbm - 5, 2)
        np.testing.assert_allclose(fixes.xy_m[s], expected, rtol=1e-9, atol=1e-9)
    # the map's own arrays are untouched, and plain KWNN on it afterwards is unchanged
    assert np.sum(radio_map.rssi_dbm < floor_dbm) > 0
    plain = kwnn_fix_many(radio_map, scans, k=4, min_shared_aps=2)
    np.testing.assert_allclose(plain.xy_m[0], _kwnn_brute(radio_map, scans[0], 4, 2.0, 2.0, -100.0, 2), rtol=1e-9)


def test_strong_kwnn_ignores_how_a_phone_reports_weak_aps_and_falls_back_without_strong_ones():
    rng = np.random.default_rng(7)
    radio_map = _random_map(rng, p=60, k=20, heard=1.0)
    scans = radio_map.rssi_dbm[:6].copy()
    quiet = scans.copy()
    quiet[quiet < -85] -= 12.0  # a phone that reports weak APs 12 dB lower (or drops them)
    np.testing.assert_array_equal(strong_kwnn_fixes(radio_map, scans), strong_kwnn_fixes(radio_map, quiet))
    # a scan with fewer than three strong APs has no strong fix: it takes the plain one
    weak = np.full((1, 20), np.nan, np.float32)
    weak[0, :6] = [-60.0, -88.0, -90.0, -91.0, -93.0, -95.0]
    plain = kwnn_fix_many(radio_map, weak, k=4).xy_m
    assert np.all(np.isnan(kwnn_fix_many(radio_map, weak, k=4, min_rssi_dbm=-85.0).xy_m))
    np.testing.assert_array_equal(strong_kwnn_fixes(radio_map, weak), plain)


def test_kwnn_exact_fingerprint_returns_its_position():
    radio_map = _random_map(np.random.default_rng(3), heard=1.0)
    fix = kwnn_fix_many(radio_map, radio_map.rssi_dbm[[5]], k=4)
    np.testing.assert_allclose(fix.xy_m[0], radio_map.xy_m[5], atol=1e-6)


def test_kwnn_scan_sharing_no_ap_has_no_fix():
    radio_map = _random_map(np.random.default_rng(4))
    unknown = WifiScan(0.0, ("aa:bb:cc:dd:ee:ff@2.4",), np.array([-50.0], np.float32))
    assert np.all(np.isnan(kwnn_fix_many(radio_map, radio_map.scan_matrix([unknown])).xy_m))
    none = np.full((1, len(radio_map.ap_keys)), np.nan, np.float32)
    assert np.all(np.isnan(kwnn_fix_many(radio_map, none).xy_m))


def test_radio_map_save_load_round_trip(tmp_path):
    radio_map = _random_map(np.random.default_rng(5))
    radio_map.floor_name = "F9"
    radio_map.save(tmp_path / "rm.npz")
    back = RadioMap.load(tmp_path / "rm.npz")
    assert back.ap_keys == radio_map.ap_keys and back.source_traces == ["t0"] and back.floor_name == "F9"
    np.testing.assert_array_equal(back.xy_m, radio_map.xy_m)
    np.testing.assert_array_equal(back.rssi_dbm, radio_map.rssi_dbm)  # NaN positions too
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(MapfilterError, match="not a mapfilter radio map"):
        RadioMap.load(tmp_path / "bad.npz")
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(MapfilterError, match="no format key"):
        RadioMap.load(tmp_path / "other.npz")


def test_radio_map_from_real_traces_is_labelled_inside_the_waypoints(ilc_site1):
    recs = [read_ilc(p) for p in F1_LOGS[:2]]
    radio_map = build_radio_map(recs)
    assert radio_map.floor_name == "F1" and radio_map.source_traces == [r.name for r in recs]
    for t, rec in enumerate(recs):
        mine = radio_map.trace == t
        _, inside = label_scans(rec)
        assert mine.sum() == inside.sum() > 0
        lo, hi = rec.waypoint_xy_m.min(axis=0), rec.waypoint_xy_m.max(axis=0)
        assert np.all((radio_map.xy_m[mine] >= lo - 1e-9) & (radio_map.xy_m[mine] <= hi + 1e-9))
        assert np.all((radio_map.t_s[mine] >= rec.waypoint_t_s[0]) & (radio_map.t_s[mine] <= rec.waypoint_t_s[-1]))
    # each reference point holds what its scan heard, nothing else
    scan = next(s for s in iter_scans(recs[0]) if recs[0].waypoint_t_s[0] <= s.t_s <= recs[0].waypoint_t_s[-1])
    row = radio_map.rssi_dbm[np.nonzero(radio_map.t_s == scan.t_s)[0][0]]
    assert np.count_nonzero(~np.isnan(row)) == len(scan)
    assert len(radio_map.without_traces([recs[0].name])) == (radio_map.trace == 1).sum()


@pytest.mark.slow
def test_leave_one_out_kwnn_on_real_traces_beats_chance(ilc_site1):
    recs = [read_ilc(p) for p in F1_LOGS]
    radio_map = build_radio_map(recs)
    errors = []
    for test in recs[::9]:
        xy, inside = label_scans(test)
        others = radio_map.without_traces([test.name])
        scans = [s for s, ok in zip(iter_scans(test), inside) if ok]
        fix = kwnn_fix_many(others, others.scan_matrix(scans))
        errors.extend(np.linalg.norm(fix.xy_m - xy[inside], axis=1))
    # measured ~9 m median over all 36 traces; the floor is 240 m x 176 m
    assert np.nanmedian(errors) < 15.0


def test_build_needs_waypoints(tmp_path):
    log = tmp_path / "nowp.txt"
    log.write_text("1000\tTYPE_WIFI\tx\taa:bb:cc:dd:ee:01\t-50\t2412\t1000\n")
    with pytest.raises(MapfilterError, match="fewer than two waypoints"):
        build_radio_map([read_ilc(log)])
    nowifi = tmp_path / "nowifi.txt"
    nowifi.write_text("1000\tTYPE_WAYPOINT\t1.0\t2.0\n3000\tTYPE_WAYPOINT\t3.0\t2.0\n")
    with pytest.raises(MapfilterError, match="nowifi.txt: the log has no usable WiFi"):
        build_radio_map([read_ilc(nowifi)])


def _synthetic_radio_map():
    """Reference points on a 40 m x 20 m grid, RSSI from the path-loss model of 6 APs."""
    rng = np.random.default_rng(11)
    aps = AccessPointTable(bssid=[f"02:00:00:00:02:{i:02x}" for i in range(6)], band=["2.4"] * 6,
                           xy_m=np.array([[0, 0], [40, 0], [0, 20], [40, 20], [20, 10], [10, 15.0]]),
                           c_dbm=np.full(6, -38.0), n=np.full(6, 2.0), alpha_db_per_m=np.full(6, 0.4),
                           d_max_m=np.full(6, 30.0))
    xs, ys = np.meshgrid(np.arange(1, 40, 2.0), np.arange(1, 20, 2.0))
    xy = np.column_stack([xs.ravel(), ys.ravel()])
    rssi = aps.expected_rssi_dbm(xy) + rng.normal(0, 2.0, (xy.shape[0], 6))
    return aps, RadioMap(xy, aps.keys, rssi, np.zeros(len(xy)), np.zeros(len(xy), int), ["syn"])


def test_radio_map_likelihood_peaks_near_the_truth_and_is_consistent():
    aps, radio_map = _synthetic_radio_map()
    model = RadioMapLikelihood(radio_map, config=RadioMapLikelihoodConfig(cell_m=1.0, bandwidth_m=2.0))
    truth = np.array([13.3, 6.6])
    scan = WifiScan(0.0, tuple(aps.keys), aps.expected_rssi_dbm(truth[None])[0].astype(np.float32))
    assert np.linalg.norm(model.best_position(scan) - truth) < 2.5
    # particles read their cell's value; far off the map they get the prior cell's
    xy = np.array([truth, model.best_position(scan), [500.0, 500.0]])
    ll = model.log_likelihood(Particles.at(xy), scan)
    grid = model.grid_log_likelihood(scan)
    assert ll[1] == grid[:-1].max() >= ll[0] > ll[2] == grid[-1]
    # the sparse evaluation equals the dense formula at one cell
    c = model.cell_index(truth[None])[0]
    h, mu, var = _dense_cell_stats(radio_map, model, model.cell_xy_m[c])
    r = scan.rssi_dbm.astype(float)
    dense = np.sum(np.log(h) - 0.5 * np.log(2 * np.pi * var) - 0.5 * (r - mu) ** 2 / var)
    assert grid[c] == pytest.approx(dense, rel=1e-4)
    # an unknown AP only: no information
    assert np.all(model.log_likelihood(Particles.at(xy), WifiScan(0.0, ("aa:aa:aa:aa:aa:aa@5",),
                                                                  np.array([-40.0], np.float32))) == 0)


def _dense_cell_stats(radio_map, model, centre):
    from mapfilter.filter.models import radio_map as rm

    cfg = model.config
    d2 = ((radio_map.xy_m - centre) ** 2).sum(axis=1)
    w = np.where(d2 <= (cfg.bandwidth_m * rm.SUPPORT_SIGMAS) ** 2, np.exp(-0.5 * d2 / cfg.bandwidth_m ** 2), 0)
    r = radio_map.rssi_dbm.astype(float)
    pw = rm.PRIOR_WEIGHT
    mu = ((w[:, None] * r).sum(0) + pw * rm.PRIOR_RSSI_DBM) / (w.sum() + pw)
    var = ((w[:, None] * (r - mu) ** 2).sum(0) + pw * rm.PRIOR_SIGMA_DB ** 2) / (w.sum() + pw) + rm.SIGMA_FLOOR_DB ** 2
    h = np.clip((w.sum() + pw * rm.PRIOR_HEARD) / (w.sum() + pw), rm.HEARD_CLIP, 1 - rm.HEARD_CLIP)
    return h, mu, var


# ---- CLI ------------------------------------------------------------------------------------------
@pytest.fixture()
def f1_map(tmp_path, ilc_site1):
    """An all-free map covering ILC site1 F1 (240 m x 177 m at 1 m/px)."""
    path = tmp_path / "f1.yaml"
    FloorPlan(np.zeros((177, 240), bool), 1.0, (0.0, 0.0), "F1").save(path)
    return path


@pytest.mark.slow
def test_cli_build_and_fit_aps(tmp_path, f1_map, capsys):
    out = tmp_path / "rm.npz"
    logs = [str(p) for p in F1_LOGS[:4]]
    assert main(["radiomap", "build", str(f1_map), *logs, "--out", str(out), "--exclude", F1_LOGS[0].name]) == 0
    radio_map = RadioMap.load(out)
    assert radio_map.source_traces == [p.name.removesuffix(".txt.gz") for p in F1_LOGS[1:4]]
    aps = tmp_path / "aps.csv"
    assert main(["radiomap", "fit-aps", str(f1_map), *logs, "--out", str(aps), "--min-observations", "6"]) == 0
    table = AccessPointTable.read_csv(aps)
    assert len(table) > 10 and np.all((table.n >= 1.5) & (table.n <= 5.0))


@pytest.mark.parametrize("extra,message", [
    (["--exclude", "nosuchtrace"], "matches none"),
    (["--nowp"], "fewer than two waypoints"),
    (["--missing"], "file not found"),
])
def test_cli_errors_are_one_line_and_write_nothing(tmp_path, f1_map, capsys, extra, message):
    out = tmp_path / "rm.npz"
    logs = [str(F1_LOGS[0])]
    if extra == ["--nowp"]:
        nowp = tmp_path / "nowp.txt"
        nowp.write_text("1000\tTYPE_WIFI\tx\taa:bb:cc:dd:ee:01\t-50\t2412\t1000\n")
        logs.append(str(nowp))
        extra = []
    if extra == ["--missing"]:
        logs.append(str(tmp_path / "missing.txt.gz"))
        extra = []
    assert main(["radiomap", "build", str(f1_map), *logs, "--out", str(out), *extra]) == 1
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert list(tmp_path.glob("rm*")) == [] and not list(tmp_path.glob(".rm*"))


def test_tracker_weighs_the_kwnn_fix_with_a_gaussian():
    from mapfilter.filter.evidence import WifiConfig, WifiEvidence

    aps, radio_map = _synthetic_radio_map()
    scan = WifiScan(0.0, tuple(aps.keys), aps.expected_rssi_dbm(np.array([[21.0, 9.0]]))[0].astype(np.float32))
    unknown = WifiScan(1.0, ("aa:aa:aa:aa:aa:aa@5",), np.array([-40.0], np.float32))
    plan = FloorPlan(np.zeros((200, 400), dtype=bool), 0.1, (0.0, 0.0))
    wifi = WifiEvidence(radio_map, None, plan, WifiConfig(fix_sigma_m=5.0, fingerprint_model="fix"))
    wifi.add_scans([scan, unknown])
    assert wifi.measurement(1) is None  # no AP the radio map knows: no fix
    fix = kwnn_fix_many(radio_map, radio_map.scan_matrix([scan])).xy_m[0]
    measurement = wifi.measurement(0)
    np.testing.assert_allclose(measurement.xy_m, fix)
    xy = fix[None] + np.array([[0.0, 0.0], [5.0, 0.0], [0.0, -10.0]])
    np.testing.assert_allclose(wifi.model.log_likelihood(Particles.at(xy), measurement), [0.0, -0.5, -2.0], atol=1e-9)
    assert np.linalg.norm(fix - [21.0, 9.0]) < 2.0
    assert wifi.measurement(1) is None  # no fix from a scan of unknown APs: the filter skips it


def test_step_labelling_follows_the_steps_not_the_clock():
    from mapfilter.sensors.pdr import Steps
    from mapfilter.sensors.recording import Beacons, Recording, WifiScans

    empty = np.empty((0, 3))
    scan_t = np.array([2.0, 5.0, 7.5, 9.0])
    wifi = WifiScans(scan_t, ["aa:bb:cc:dd:ee:01@2.4"], np.arange(4), np.zeros(4, int), np.full(4, -50, np.float32),
                     np.full(4, 2412, np.float32), np.zeros(4, np.float32))
    rec = Recording(None, "F1", 0.0, np.array([0.0, 10.0]), np.array([[0.0, 0.0], [10.0, 0.0]]), np.empty(0), empty,
                    np.empty(0), empty, np.empty(0), empty, np.empty(0), empty, wifi,
                    Beacons(np.empty(0), [], np.empty(0), np.empty(0)))
    # the walker stood still for 5 s, then took 9 steps of 1 m, one per 0.5 s, plus one into the waypoint
    step_t = 5.0 + 0.5 * np.arange(1, 10)
    steps = Steps(step_t, np.zeros(9), np.zeros(9), None, np.ones(9), np.ones(9), 0.0)
    by_time, _ = label_scans(rec)
    by_steps, inside = label_scans(rec, steps)
    assert inside.all()
    np.testing.assert_allclose(by_time[:, 0], [2.0, 5.0, 7.5, 9.0])
    np.testing.assert_allclose(by_steps[:, 0], [0.0, 0.0, 5.0, 8.0])


def test_cross_validated_fix_errors_grow_with_rssi_noise():
    from mapfilter.sensors.radiomap import RadioMap, cross_validated_fix_errors

    rng = np.random.default_rng(5)
    # a 20 m x 20 m grid of points, 3 scans each, 12 APs with a log-distance model
    grid = np.stack(np.meshgrid(np.arange(0, 20, 2.0), np.arange(0, 20, 2.0)), axis=-1).reshape(-1, 2)
    xy = np.repeat(grid, 3, axis=0)
    aps = rng.uniform(0, 20, (12, 2))
    clean = -40 - 20 * np.log10(np.maximum(np.linalg.norm(xy[:, None] - aps[None], axis=2), 1.0))

    def sigma(noise_db):
        rssi = (clean + rng.normal(0, noise_db, clean.shape)).astype(np.float32)
        rm = RadioMap(xy, [f"ap{i}@2.4" for i in range(12)], rssi, np.zeros(len(xy)), np.zeros(len(xy), int), ["s"])
        errors = cross_validated_fix_errors(rm)
        assert errors.size == len(xy)  # every point fixed once, without its own location
        return np.sqrt(np.mean(errors**2) / 2)

    quiet, noisy = sigma(1.0), sigma(8.0)
    assert 0.5 < quiet < 3.0  # neighbours 2 m away: about a grid step
    assert noisy > 1.5 * quiet


def _traced_map(seed=11, p=60, k=16, traces=5):
    rm = _random_map(np.random.default_rng(seed), p, k)
    rm.rssi_dbm = np.round(rm.rssi_dbm)  # integer dBm, as phones report
    rm.trace = np.arange(p) % traces
    rm.source_traces = [f"t{i}" for i in range(traces)]
    return rm


def test_cross_validation_equals_kwnn_on_the_map_without_each_walk():
    """Oracle: the masked all-points distances give the fixes of select(~walk) to the last bit."""
    from mapfilter.sensors.radiomap import cross_validated_fix_errors

    rm = _traced_map()
    expected = []
    for g in range(5):
        inside = rm.trace == g
        fixes = kwnn_fix_many(rm.select(~inside), rm.rssi_dbm[inside], k=4).xy_m
        ok = np.all(np.isfinite(fixes), axis=1)
        expected.append(np.linalg.norm(fixes[ok] - rm.xy_m[inside][ok], axis=1))
    np.testing.assert_array_equal(cross_validated_fix_errors(rm, 4), np.concatenate(expected))


def test_radio_map_file_keeps_the_cross_validation_and_old_files_load(tmp_path, monkeypatch):
    import mapfilter.sensors.radiomap as radiomap_module
    from mapfilter.sensors.radiomap import cross_validated_fix_errors
    from mapfilter.filter.evidence import calibrated_fix_sigma_m

    rm = _traced_map()
    errors = cross_validated_fix_errors(rm, 4)
    sigma = calibrated_fix_sigma_m(rm, 4)
    rm.save(tmp_path / "v2.npz")
    with np.load(tmp_path / "v2.npz") as data:
        assert int(data["version"]) == 2
        np.testing.assert_array_equal(data["cv_fix_errors_m"], errors)
    # a version 1 file: the same arrays without the stored cross-validation
    with np.load(tmp_path / "v2.npz") as data:
        v1 = {key: data[key] for key in data.files if not key.startswith("cv_")}
    v1["version"] = np.array(1, dtype=np.int64)
    np.savez_compressed(tmp_path / "v1.npz", **v1)
    old = RadioMap.load(tmp_path / "v1.npz")
    np.testing.assert_array_equal(old.rssi_dbm, rm.rssi_dbm)
    assert calibrated_fix_sigma_m(old, 4) == sigma  # computed on first use
    # the version 2 file is not cross-validated again: its stored errors are used
    monkeypatch.setattr(radiomap_module, "_cross_validated_fix_errors",
                        lambda *a: pytest.fail("cross-validated again despite the stored errors"))
    new = RadioMap.load(tmp_path / "v2.npz")
    assert calibrated_fix_sigma_m(new, 4) == sigma
    # a changed map is not answered from the memo of the old one
    new.rssi_dbm = new.rssi_dbm + np.float32(1.0)
    with pytest.raises(pytest.fail.Exception):
        calibrated_fix_sigma_m(new, 4)
    v1["version"] = np.array(5, dtype=np.int64)  # 3: a building's radio map, 4: a grown one
    np.savez_compressed(tmp_path / "v5.npz", **v1)
    with pytest.raises(MapfilterError, match="version 5 is not supported"):
        RadioMap.load(tmp_path / "v5.npz")


def test_blend_fix_is_the_mean_of_the_kwnn_fix_and_the_best_cell():
    from mapfilter.filter.models.radio_map import RadioMapLikelihood
    from mapfilter.filter.evidence import WifiConfig, WifiEvidence

    aps, radio_map = _synthetic_radio_map()
    scan = WifiScan(0.0, tuple(aps.keys), aps.expected_rssi_dbm(np.array([[21.0, 9.0]]))[0].astype(np.float32))
    plan = FloorPlan(np.zeros((200, 400), dtype=bool), 0.1, (0.0, 0.0))
    wifi = WifiEvidence(radio_map, None, plan, WifiConfig(fix_sigma_m=5.0, fingerprint_model="blend"))
    wifi.add_scans([scan])
    kwnn = strong_kwnn_fixes(radio_map, radio_map.scan_matrix([scan]))[0]  # the default: strong readings only
    best = RadioMapLikelihood(radio_map, plan).best_position(scan)
    np.testing.assert_allclose(wifi.measurement(0).xy_m, 0.5 * (kwnn + best))
    fixes = wifi.position_fixes()  # the whole-walk placement sees both estimators separately
    assert len(fixes) == 2 and np.allclose(fixes[0][0], kwnn) and np.allclose(fixes[1][0], best)
    assert np.linalg.norm(wifi.measurement(0).xy_m - [21.0, 9.0]) < 2.0


# ---- files that are not radio maps, radio maps that are not of this map -------------------------
def _forged_npz(path, arrays: dict, declared: dict | None = None):
    """A zip of .npy members; ``declared``: name -> (shape, dtype) written in a header with no data."""
    import io
    import zipfile

    from numpy.lib import format as npy

    with zipfile.ZipFile(path, "w") as archive:
        for name, value in arrays.items():
            buffer = io.BytesIO()
            npy.write_array(buffer, np.asarray(value), allow_pickle=True)
            archive.writestr(f"{name}.npy", buffer.getvalue())
        for name, (shape, dtype) in (declared or {}).items():
            buffer = io.BytesIO()
            npy.write_array_header_1_0(buffer, {"descr": npy.dtype_to_descr(np.dtype(dtype)), "fortran_order": False,
                                                "shape": shape})
            archive.writestr(f"{name}.npy", buffer.getvalue() + b"\0" * 64)
    return path


def test_a_header_declaring_a_huge_array_is_refused_before_numpy_allocates(tmp_path):
    path = _forged_npz(tmp_path / "huge.npz", {"format": np.array("mapfilter-radiomap"), "version": np.array(2)},
                       {"rssi_dbm": ((100_000, 100_000), np.float32)})
    with pytest.raises(MapfilterError, match=r"declares shape \(100000, 100000\) \(37.3 GiB\): more than the 1 GiB"):
        RadioMap.load(path)


@pytest.mark.parametrize("make, message", [
    (lambda p: p.write_bytes(np.random.default_rng(1).bytes(5000)), "not a mapfilter radio map (make one with: "
     "mapfilter radiomap build"),
    (lambda p: _forged_npz(p, {"format": np.array("mapfilter-radiomap"), "xy_m": np.array([object()])}),
     "holds Python objects"),
    (lambda p: _forged_npz(p, {"format": np.array("mapfilter-radiomap")}, {"xy_m": ((1000, 2), np.float64)}),
     "declares 16000 bytes but holds 192"),
    (lambda p: p.write_bytes(b"PK\x03\x04" + b"\0" * 100), "not a mapfilter radio map"),
])
def test_a_file_that_is_not_a_radio_map_is_one_line_without_numpys_advice(tmp_path, capsys, make, message):
    path = tmp_path / "rm.npz"
    make(path)
    with pytest.raises(MapfilterError) as info:
        RadioMap.load(path)
    assert message in str(info.value) and "allow_pickle" not in str(info.value) and info.value.path == str(path)
    maps = REPO / "maps"
    assert main(["track", str(maps / "office.yaml"), str(maps / "office_walk.txt.gz"), "--radiomap", str(path)]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"mapfilter: error: {path}: not a mapfilter radio map") and err.count("\n") == 1


def test_values_no_radio_map_holds_are_refused(tmp_path):
    rng = np.random.default_rng(2)
    radio_map = _random_map(rng)
    radio_map.rssi_dbm[3, 4] = 1e30
    radio_map.save(tmp_path / "loud.npz")
    with pytest.raises(MapfilterError, match="RSSI from .* to 1e\\+30 dBm, outside"):
        RadioMap.load(tmp_path / "loud.npz")
    far = _random_map(rng)
    far.xy_m[5] = [3e7, 0.0]
    far.save(tmp_path / "far.npz")
    with pytest.raises(MapfilterError, match="reference point 5 at .* is more than 1e\\+07 m from the origin"):
        RadioMap.load(tmp_path / "far.npz")


def test_a_radio_map_off_the_floor_is_refused_where_it_meets_the_map(tmp_path, ilc_site1):
    plan = FloorPlan(np.zeros((100, 100), bool), 0.5, (0.0, 0.0))  # 50 m x 50 m
    radio_map = _random_map(np.random.default_rng(4))  # points in 0-50 m
    check_radio_map_on_map(radio_map, plan, "rm.npz")
    radio_map.xy_m[7] = [1e6, 25.0]  # a million metres east
    radio_map.xy_m[9] = [-60.0, 25.0]  # 60 m west
    with pytest.raises(MapfilterError, match=r"reference point 7 \(trace t0\) at \(1e\+06, 25\) m lies 1e\+03 km "
                                             r"outside the map .*\(2 such points\)") as info:
        check_radio_map_on_map(radio_map, plan, "rm.npz", "office.yaml")
    assert info.value.path == "rm.npz"
    # real data: ILC F1's radio map lies on ILC F1's map
    from mapfilter.maps.prepare import import_ilc

    real = build_radio_map([read_ilc(p) for p in F1_LOGS[:4]])
    check_radio_map_on_map(real, import_ilc(ilc_site1 / "F1", route="geojson"))


# ---- grown maps (per-point source and position sigma, format version 4) -------------------------
def _grown_map(seed=5, p=30, k=10):
    from mapfilter.sensors.radiomap import GROWN, SURVEYED

    rm = _traced_map(seed, p, k, traces=3)
    rm.source = np.where(rm.trace == 2, GROWN, SURVEYED).astype(np.int8)
    rm.xy_sigma_m = np.where(rm.trace == 2, np.linspace(1.0, 9.0, p), 0.0)
    return rm


def test_grown_radio_map_round_trip_keeps_source_and_sigma(tmp_path):
    rm = _grown_map()
    rm.save(tmp_path / "grown.npz")
    with np.load(tmp_path / "grown.npz") as data:
        assert int(data["version"]) == 4
    back = RadioMap.load(tmp_path / "grown.npz")
    np.testing.assert_array_equal(back.source, rm.source)
    np.testing.assert_array_equal(back.xy_sigma_m, rm.xy_sigma_m)
    np.testing.assert_array_equal(back.xy_m, rm.xy_m)
    np.testing.assert_array_equal(back.rssi_dbm, rm.rssi_dbm)
    assert back.is_grown and back.source_traces == rm.source_traces
    # selecting points and access points keeps each point's source and sigma
    sub = back.select(back.trace != 0).select_aps(np.arange(len(back.ap_keys)) % 2 == 0)
    np.testing.assert_array_equal(sub.xy_sigma_m, rm.xy_sigma_m[rm.trace != 0])
    assert len(sub.ap_keys) == (len(rm.ap_keys) + 1) // 2


def test_surveyed_maps_stay_version_2_and_old_files_load_as_surveyed(tmp_path):
    rm = _traced_map()
    rm.save(tmp_path / "v2.npz")
    with np.load(tmp_path / "v2.npz") as data:
        assert int(data["version"]) == 2 and "source" not in data.files
    back = RadioMap.load(tmp_path / "v2.npz")
    assert not back.is_grown
    assert np.all(back.source == 0) and np.all(back.xy_sigma_m == 0)


@pytest.mark.parametrize("change,message", [
    ({"source": None}, "needs the arrays source and xy_sigma_m"),
    ({"source": np.zeros(3, np.int8)}, "one entry per point"),
    ({"source": np.full(30, 7, np.int8)}, "source codes"),
    ({"xy_sigma_m": np.full(30, -1.0)}, "finite and >= 0"),
    ({"xy_sigma_m": np.full(30, np.nan)}, "finite and >= 0"),
])
def test_bad_grown_radio_map_files_are_refused(tmp_path, change, message):
    _grown_map().save(tmp_path / "grown.npz")
    with np.load(tmp_path / "grown.npz") as data:
        arrays = {key: data[key] for key in data.files}
    for key, value in change.items():
        if value is None:
            del arrays[key]
        else:
            arrays[key] = value
    np.savez_compressed(tmp_path / "bad.npz", **arrays)
    with pytest.raises(MapfilterError, match=message):
        RadioMap.load(tmp_path / "bad.npz")


def test_a_point_with_a_huge_sigma_moves_a_kwnn_fix_less_than_a_surveyed_one():
    """Two reference points equally near the scan in signal space: surveyed, the fix is their
    midpoint; with one of them grown at sigma 100 m, the fix sits nearly on the other one."""
    from mapfilter.sensors.radiomap import GROWN

    keys = [f"02:00:00:00:03:{j:02x}@5" for j in range(4)]
    rssi = np.array([[-50, -60, -70, -80], [-54, -60, -70, -80]], np.float32)
    scan = np.array([[-52, -60, -70, -80]], np.float64)
    rm = RadioMap(np.array([[0.0, 0.0], [10.0, 0.0]]), keys, rssi, np.zeros(2), np.array([0, 1]), ["a", "b"])
    both = kwnn_fix_many(rm, scan, k=2).xy_m[0]
    assert both[0] == pytest.approx(5.0)
    rm.source = np.array([0, GROWN], np.int8)
    rm.xy_sigma_m = np.array([0.0, 100.0])
    weighed = kwnn_fix_many(rm, scan, k=2).xy_m[0]
    assert weighed[0] < 0.2  # weight 100 / (100 + 10,000) of the surveyed point's: 10 m x 0.0098
    # a grown point with sigma 0 counts as a surveyed one
    rm.xy_sigma_m = np.array([0.0, 0.0])
    assert kwnn_fix_many(rm, scan, k=2).xy_m[0, 0] == pytest.approx(5.0)


def test_radio_map_likelihood_weighs_an_uncertain_point_less():
    """A lone reference point: as a surveyed point its AP's mean at its cell is its own reading;
    grown with a large sigma, the prior (-95 dBm) keeps more of the say there."""
    keys = ["02:00:00:00:04:00@5", "02:00:00:00:04:01@5"]
    xy = np.array([[5.0, 5.0], [5.2, 5.0], [15.0, 5.0], [15.2, 5.0]])
    rssi = np.array([[-40, -80], [-40, -80], [-80, -40], [-80, -40]], np.float32)
    rm = RadioMap(xy, keys, rssi, np.zeros(4), np.zeros(4, int), ["t"])
    scan = WifiScan(0.0, tuple(keys), np.array([-40.0, -80.0], np.float32))
    model = RadioMapLikelihood(rm)
    ll = model.grid_log_likelihood(scan)
    at = model.cell_index(np.array([[5.0, 5.0], [15.0, 5.0]]))
    sure = ll[at[0]] - ll[at[1]]
    rm.source = np.array([0, 0, 1, 1], np.int8)  # the two points at x = 15 m: grown, sigma 20 m
    rm.xy_sigma_m = np.array([0.0, 0.0, 20.0, 20.0])
    grown = RadioMapLikelihood(rm)
    ll_g = grown.grid_log_likelihood(scan)
    assert sure > 0 and ll_g[at[0]] - ll_g[at[1]] < sure  # the uncertain points claim their cells less


def test_cross_validation_of_a_grown_map_scores_the_surveyed_points_only():
    from mapfilter.sensors.radiomap import cross_validated_fix_errors

    rm = _grown_map()
    errors = cross_validated_fix_errors(rm, 4)
    assert errors.size == np.count_nonzero(rm.trace != 2)
    # the grown trace still serves as references: without it the surveyed errors differ
    assert not np.array_equal(errors, cross_validated_fix_errors(rm.select(rm.trace != 2), 4))


def test_merged_radio_maps_unite_access_points_and_keep_sources():
    from mapfilter.sensors.radiomap import merge_radio_maps

    a = _traced_map(1, 10, 6, traces=2)
    b = _grown_map(2, 30, 8)
    b.ap_keys = [f"02:00:00:00:09:{j:02x}@5" for j in range(4)] + b.ap_keys[:4]
    m = merge_radio_maps([a, b])
    assert len(m) == 40 and len(m.ap_keys) == 6 + 4 + 0  # b's last four keys are a's first four
    assert m.source_traces == a.source_traces + b.source_traces
    np.testing.assert_array_equal(m.trace[10:], b.trace + 2)
    np.testing.assert_array_equal(m.xy_sigma_m[10:], b.xy_sigma_m)
    col = m.ap_keys.index(b.ap_keys[5])
    np.testing.assert_array_equal(m.rssi_dbm[10:, col], b.rssi_dbm[:, 5])
    np.testing.assert_array_equal(m.rssi_dbm[:10, col], a.rssi_dbm[:, 1])
    assert np.all(np.isnan(m.rssi_dbm[:10, m.ap_keys.index(b.ap_keys[0])]))


@pytest.mark.parametrize("floor_dbm,missing,per_ap", [(None, -100.0, False), (-85.0, -90.0, False),
                                                     (None, -95.0, False), (-85.0, -100.0, True), (None, -90.0, True)])
def test_distances_by_matrix_products_equal_the_pairwise_merge_to_the_last_bit(floor_dbm, missing, per_ap):
    """Oracle: on whole dBm the p = 2 fast path (matrix products) gives the merge kernel's
    distances and shared counts exactly; readings below the floor and missing APs included, and
    with ``per_ap`` (the match distance's mean over the APs either side heard) a scan and a point
    that hear nothing."""
    from mapfilter.sensors.radiomap import (_below_floor_unheard, _distances_to_references, _reference_rows,
                                           _signal_distances, _sparse_rows)

    rng = np.random.default_rng(3)
    rm = _random_map(rng, p=80, k=40, heard=0.3)
    rm.rssi_dbm = np.round(rm.rssi_dbm)
    rm.rssi_dbm[5] = np.nan  # a point that heard nothing
    scans = np.round(rm.rssi_dbm[::2] + rng.normal(0, 4, (40, 40))).astype(np.float64)
    scans[7] = np.nan  # a scan that heard nothing
    fast = _distances_to_references(rm, scans, 2.0, missing, floor_dbm, per_ap=per_ap)
    refs, rows = _reference_rows(rm, floor_dbm), _sparse_rows(_below_floor_unheard(scans, floor_dbm))
    dist, shared = np.empty_like(fast[0]), np.empty_like(fast[1])
    _signal_distances(rows.ptr, rows.col, rows.val, refs.ptr, refs.col, refs.val, 2.0, missing, per_ap, dist, shared)
    np.testing.assert_array_equal(fast[0], dist)
    np.testing.assert_array_equal(fast[1], shared)
    assert fast[0][7, 5] == 0.0 and np.all(fast[0][7] >= 0)


def test_a_buildings_fixes_and_matches_from_one_distance_matrix_are_each_floors(office3, office3_radio_map):
    """kwnn_fixes_by_floor and match_distance_by_floor_db (BuildingEvidence computes them once for
    every floor) against strong_kwnn_fixes and match_distance_db of the whole map and of each floor's."""
    from mapfilter.sensors.radiomap import (kwnn_fixes_by_floor, match_distance_by_floor_db, match_distance_db,
                                            strong_kwnn_fixes)

    building, _ = office3
    radio_map = office3_radio_map
    rng = np.random.default_rng(4)
    points = rng.choice(len(radio_map), 40, replace=False)
    scans = radio_map.rssi_dbm[points].astype(np.float64) + rng.normal(0.0, 3.0, (40, len(radio_map.ap_keys)))
    scans = np.where(np.isnan(radio_map.rssi_dbm[points]), np.nan, np.round(scans))
    scans[:3, :] = np.where(scans[:3, :] > -80, -88.0, scans[:3, :])  # too few strong APs: the plain fix
    in_building = np.zeros_like(radio_map.xy_m)
    for f, floor in enumerate(building.floors):
        on = radio_map.floor == f
        in_building[on] = floor.to_building(radio_map.xy_m[on])
    every, own = kwnn_fixes_by_floor(radio_map, scans, in_building, k=4)
    moved = dataclasses.replace(radio_map, xy_m=in_building, floor=None, floor_names=None)
    np.testing.assert_allclose(every, strong_kwnn_fixes(moved, scans, 4), atol=1e-9)
    match = match_distance_by_floor_db(radio_map, scans)
    np.testing.assert_array_equal(match.min(axis=1), match_distance_db(radio_map, scans))
    for f in range(len(building.floors)):
        floor_map = radio_map.floor_map(f)
        np.testing.assert_allclose(own[:, f], strong_kwnn_fixes(floor_map, scans, 4), atol=1e-9)
        np.testing.assert_array_equal(match[:, f], match_distance_db(floor_map, scans))
    assert np.isfinite(own).all(axis=2).mean() > 0.5 and np.isfinite(every).all()


def test_a_building_builds_a_floors_own_radio_map_likelihood_only_when_a_scan_needs_it(office3, office3_radio_map):
    """A floor's own fingerprints give a scan's fix (with the blend's best cell of their radio-map
    likelihood) only where they reach the scan: the likelihood of a floor they never reach is not
    built (a building's first walk builds it otherwise), and the fixes are those of evidence whose
    every likelihood was built first."""
    from mapfilter.filter.evidence import BuildingEvidence
    from mapfilter.filter.models.building import FloorStack
    from mapfilter.sensors.wifi import WifiScan

    building, _ = office3
    top = len(building.floors) - 1
    # the top floor's survey hears none of the first half of the APs, and the scans (of floor 0's
    # survey) hear only those: the top floor's own fingerprints share no AP with them
    half = np.arange(len(office3_radio_map.ap_keys)) < len(office3_radio_map.ap_keys) // 2
    rssi = office3_radio_map.rssi_dbm.copy()
    rssi[np.ix_(office3_radio_map.floor == top, half)] = np.nan
    radio_map = dataclasses.replace(office3_radio_map, rssi_dbm=rssi, likelihood_tables={})
    scans = []
    for i, point in enumerate(np.flatnonzero(radio_map.floor == 0)[:12]):
        heard = np.flatnonzero(~np.isnan(rssi[point]) & half)
        scans.append(WifiScan(float(i), tuple(radio_map.ap_keys[j] for j in heard),
                              rssi[point, heard].astype(np.float32)))
    stack = FloorStack(building)
    lazy, eager = BuildingEvidence(radio_map, stack), BuildingEvidence(radio_map, stack)
    for evidence in (lazy, eager):
        evidence.prepare(scans)
    for own in eager._own_floor:  # noqa: SLF001
        own[1].radio_map_model()
    lazy.add_scans(scans)
    eager.add_scans(scans)
    built = [own[1]._radio_map_model is not None for own in lazy._own_floor]  # noqa: SLF001
    used = [bool(np.isfinite(own[1].kwnn_xy_m).all(axis=1).any()) for own in lazy._own_floor]  # noqa: SLF001
    assert built == used and built[0] and not built[top]
    np.testing.assert_array_equal(lazy.fix_xy_m, eager.fix_xy_m)
    assert np.isfinite(lazy.fix_xy_m).all(axis=2).any(axis=1).all()


@pytest.mark.parametrize("seed", range(3))
def test_the_k_nearest_are_numpys_stable_argsort_head(seed):
    """Oracle: ``_k_smallest`` (the KWNN fix's k nearest points, one pass) against
    ``np.argsort(kind="stable")[:, :k]``: many equal distances (whole-dB values), infinities (too
    few shared APs), NaN, and k up to the row's length."""
    from mapfilter.sensors.radiomap import _k_smallest

    rng = np.random.default_rng(seed)
    values = np.round(rng.uniform(0.0, 12.0, (60, 40)))
    values[rng.random(values.shape) < 0.2] = np.inf
    values[rng.random(values.shape) < 0.05] = np.nan
    values[3] = np.inf
    values[4] = 7.0
    values[5] = np.nan
    for k in (1, 4, 11, 40):
        want = np.argsort(values, axis=1, kind="stable")[:, :k]
        np.testing.assert_array_equal(_k_smallest(values, k), want)
    assert _k_smallest(np.zeros((0, 5)), 3).shape == (0, 3)
