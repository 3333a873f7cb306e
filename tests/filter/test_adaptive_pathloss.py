"""Adaptive trilateration (Lund thesis ch. 7): parameter adaptation, blocking compensation,
the simulator's blocking episodes and wrong tables, the CLI flags and bad inputs."""

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO

from mapfilter.cli import main
from mapfilter.errors import MapfilterError
from mapfilter.filter.models import adaptive_path_loss
from mapfilter.filter.models.adaptive_path_loss import AdaptiveTrilaterationLikelihood
from mapfilter.filter.models.path_loss import TrilaterationLikelihood
from mapfilter.filter.particles import Particles
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.sensors.ilc import read_ilc
from mapfilter.sensors.pathloss import AccessPointTable, path_loss_rssi_dbm
from mapfilter.sensors.wifi import WifiScan, ap_key, scans_of
from mapfilter.simulate.walk import SimConfig, blocking_db, offset_access_points, simulate_walk
from conftest import tracking_config

from mapfilter.pipeline.tracker import track

OFFICE = REPO / "maps" / "office.yaml"
OFFICE_APS = REPO / "maps" / "office_aps.csv"


def _scan(table: AccessPointTable, rssi_dbm: np.ndarray, t_s: float) -> WifiScan:
    keys = table.keys
    return WifiScan(t_s=t_s, ap_keys=tuple(keys), rssi_dbm=np.asarray(rssi_dbm, dtype=np.float64))


def _model_scan(table: AccessPointTable, xy_m, t_s: float, offset_db: float = 0.0) -> WifiScan:
    """A noise-free scan of every AP of ``table`` at ``xy_m`` (minus ``offset_db``)."""
    return _scan(table, table.expected_rssi_dbm(np.asarray(xy_m, dtype=np.float64)[None])[0] - offset_db, t_s)


@pytest.fixture(scope="module")
def office_aps() -> AccessPointTable:
    return AccessPointTable.read_csv(OFFICE_APS)


def _one_particle(xy_m=(10.0, 10.0)) -> Particles:
    return Particles.at(np.array([xy_m], dtype=np.float64))


# ---- adaptation ------------------------------------------------------------------------------
@pytest.fixture
def full_gains(monkeypatch):
    """The adaptation's gains at 1: one observation replaces the parameter (the equations' oracle)."""
    monkeypatch.setattr(adaptive_path_loss, "C_GAIN", 1.0)
    monkeypatch.setattr(adaptive_path_loss, "ALPHA_GAIN", 1.0)


@pytest.mark.parametrize("c_offset_db, alpha_offset_db_per_m", [(13.0, 0.0), (-6.0, 0.0)])
def test_noise_free_scan_below_an_ap_recovers_c_exactly(office_aps, c_offset_db, alpha_offset_db_per_m, full_gains):
    """Oracle: the model solved for C (at 1 m) gives the truth back from one noise-free scan when
    alpha is right; alpha, solved from the other APs with those C, stays right."""
    wrong = offset_access_points(office_aps, c_offset_db, alpha_offset_db_per_m)
    model = AdaptiveTrilaterationLikelihood(wrong, adapt_rssi_limit_dbm=-45.0, blocking_drop_db=None)
    below = office_aps.xy_m[0]  # the phone directly below AP 0 (horizontal distance 0: clamped to 1 m)
    model.log_likelihood(_one_particle(), _model_scan(office_aps, below, 0.0))
    adapted = model.ap_table
    np.testing.assert_allclose(adapted.c_dbm, office_aps.c_dbm, atol=1e-9)  # both bands of AP 0, the rest shared
    np.testing.assert_allclose(adapted.alpha_db_per_m, office_aps.alpha_db_per_m, atol=1e-9)
    assert model.state.adapted and model.n_adaptations == 1
    np.testing.assert_array_equal(wrong.c_dbm, office_aps.c_dbm + c_offset_db)  # the given table is not touched


def test_noise_free_scans_with_both_wrong_converge(office_aps, full_gains):
    """C is solved with the current alpha and alpha with the current C: repeated scans converge."""
    wrong = offset_access_points(office_aps, 13.0, -0.2)
    model = AdaptiveTrilaterationLikelihood(wrong, adapt_rssi_limit_dbm=-45.0, blocking_drop_db=None)
    errors = []
    for t in range(6):
        model.log_likelihood(_one_particle(), _model_scan(office_aps, office_aps.xy_m[4 * (t % 2)], float(t)))
        errors.append(np.abs(model.ap_table.c_dbm - office_aps.c_dbm).max())
    assert errors[0] == pytest.approx(0.2)  # 1 m times the alpha error
    assert errors[-1] < 1e-3 and all(b <= a + 1e-12 for a, b in zip(errors, errors[1:]))


def test_adaptation_moves_c_towards_the_truth_on_noisy_synthetic_scans(office_aps):
    rng = np.random.default_rng(4)
    wrong = offset_access_points(office_aps, c_offset_db=13.0, alpha_offset_db_per_m=-0.2)
    model = AdaptiveTrilaterationLikelihood(wrong, adapt_rssi_limit_dbm=-45.0, blocking_drop_db=None)
    particles = _one_particle()
    for i in range(40):  # walking past APs 0, 3, 6 at 0-1 m, 5 dB noise
        ap = (0, 3, 6)[i % 3] * 2
        xy = office_aps.xy_m[ap] + rng.uniform(-0.7, 0.7, 2)
        scan = _model_scan(office_aps, xy, float(i))
        model.log_likelihood(particles, dataclasses.replace(scan, rssi_dbm=scan.rssi_dbm + 5.0 * rng.standard_normal(
            len(office_aps))))
    start = np.abs(wrong.c_dbm - office_aps.c_dbm).mean()
    end = np.abs(model.ap_table.c_dbm - office_aps.c_dbm).mean()
    assert start == pytest.approx(13.0)
    assert end < 0.4 * start
    alpha_start = np.abs(wrong.alpha_db_per_m - office_aps.alpha_db_per_m).mean()
    alpha_end = np.abs(model.ap_table.alpha_db_per_m - office_aps.alpha_db_per_m).mean()
    assert alpha_end < alpha_start


def test_no_adaptation_below_the_limit_or_while_blocked(office_aps):
    wrong = offset_access_points(office_aps, c_offset_db=13.0)
    model = AdaptiveTrilaterationLikelihood(wrong, adapt_rssi_limit_dbm=-30.0, blocking_drop_db=None)
    model.log_likelihood(_one_particle(), _model_scan(office_aps, office_aps.xy_m[0], 0.0))  # strongest -38.3
    assert model.n_adaptations == 0 and not model.state.adapted
    np.testing.assert_array_equal(model.ap_table.c_dbm, wrong.c_dbm)

    blocked = AdaptiveTrilaterationLikelihood(wrong, adapt_rssi_limit_dbm=-60.0)
    xy = office_aps.xy_m[0] + 0.5
    blocked.log_likelihood(_one_particle(xy), _model_scan(office_aps, xy, 0.0))  # first scan: the reference
    c_after_first = blocked.ap_table.c_dbm.copy()
    blocked.log_likelihood(_one_particle(xy), _model_scan(office_aps, xy, 2.0, offset_db=15.0))
    assert blocked.state.blocked and blocked.state.blocking_db > 6.0
    np.testing.assert_array_equal(blocked.ap_table.c_dbm, c_after_first)


def test_state_updates_once_per_scan_however_often_the_filter_asks(office_aps):
    model = AdaptiveTrilaterationLikelihood(office_aps, adapt_rssi_limit_dbm=-45.0)
    particles = Particles.at(np.random.default_rng(0).uniform(0, 30, (50, 2)))
    scan = _model_scan(office_aps, office_aps.xy_m[2], 0.0)
    first = model.log_likelihood(particles, scan)
    second = model.log_likelihood(particles, scan)
    np.testing.assert_array_equal(first, second)
    assert len(model.history) == 1 and model.n_adaptations == 1


def test_without_adaptation_or_blocking_it_is_the_plain_likelihood(office_aps):
    plain = TrilaterationLikelihood(office_aps)
    wrapped = AdaptiveTrilaterationLikelihood(office_aps, adapt_rssi_limit_dbm=None, blocking_drop_db=None)
    particles = Particles.at(np.random.default_rng(1).uniform(0, 30, (200, 2)))
    for t, xy in enumerate(([3.0, 3.0], [20.0, 15.0], [30.0, 5.0])):
        scan = _model_scan(office_aps, xy, float(t), offset_db=np.random.default_rng(t).normal(0, 5, len(office_aps)))
        np.testing.assert_array_equal(wrapped.log_likelihood(particles, scan), plain.log_likelihood(particles, scan))


def test_bad_settings_are_mapfilter_errors(office_aps):
    from mapfilter.filter.evidence import TrilaterationConfig

    with pytest.raises(MapfilterError, match="RSSI limit"):
        AdaptiveTrilaterationLikelihood(office_aps, adapt_rssi_limit_dbm=float("nan"))
    with pytest.raises(MapfilterError, match="blocking drop must be at least the 3 dB"):
        AdaptiveTrilaterationLikelihood(office_aps, blocking_drop_db=2.0)
    with pytest.raises(MapfilterError, match="blocking drop"):
        TrilaterationConfig(blocking_drop_db=float("inf"))
    with pytest.raises(MapfilterError, match="variance"):
        AdaptiveTrilaterationLikelihood(office_aps, variance_db2=0.0)


# ---- blocking ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def blocked_walk(office_aps):
    floorplan = FloorPlan.load(OFFICE)
    config = SimConfig(duration_s=120.0, wall_loss_2g4_db=0.0, wall_loss_5g_db=0.0,
                       blocking_episodes=((40.0, 70.0, 12.0),))
    walk = simulate_walk(floorplan, office_aps, config, np.random.default_rng(7))
    return floorplan, walk, config


def test_blocking_is_detected_in_a_simulated_episode_and_h_is_near_its_size(office_aps, blocked_walk, tmp_path):
    from mapfilter.simulate.ilc_writer import write_ilc

    _, walk, _ = blocked_walk
    path = tmp_path / "walk.txt"
    write_ilc(walk, path)
    model = AdaptiveTrilaterationLikelihood(office_aps, adapt_rssi_limit_dbm=None)
    inside, outside = [], []
    for scan in scans_of(read_ilc(path)):
        # the particles at the true position: H is then the blocking alone (plus noise)
        truth = walk.position_at(np.array([scan.t_s]))[0]
        model.log_likelihood(_one_particle(truth), scan)
        t_rel = scan.t_s - walk.start_t_s
        if 44.0 <= t_rel < 70.0:  # a few seconds in: cached rows from before have aged
            inside.append(model.state)
        elif t_rel < 38.0 or t_rel > 80.0:
            outside.append(model.state)
    assert np.mean([s.blocked for s in inside]) >= 0.7
    assert 8.0 <= np.median([s.blocking_db for s in inside if s.blocked]) <= 16.0
    assert np.mean([s.blocked for s in outside]) <= 0.15
    assert np.mean([s.blocking_db for s in outside]) < 2.0


def test_the_blocking_drop_setting_is_the_threshold(office_aps, blocked_walk, tmp_path):
    """The simulated 12 dB episode is blocking at the thesis' 6 dB and not at 20 dB."""
    from mapfilter.simulate.ilc_writer import write_ilc

    _, walk, _ = blocked_walk
    path = tmp_path / "walk.txt"
    write_ilc(walk, path)
    scans = scans_of(read_ilc(path))
    blocked = {}
    for drop_db in (6.0, 20.0):
        model = AdaptiveTrilaterationLikelihood(office_aps, adapt_rssi_limit_dbm=None, blocking_drop_db=drop_db)
        for scan in scans:
            model.log_likelihood(_one_particle(walk.position_at(np.array([scan.t_s]))[0]), scan)
        blocked[drop_db] = sum(state.blocked for state in model.history)
    assert blocked[6.0] > 5 and blocked[20.0] == 0


def test_simulated_blocking_weakens_every_fresh_reading_by_h(office_aps, blocked_walk):
    floorplan, blocked, config = blocked_walk
    clear = simulate_walk(floorplan, office_aps, dataclasses.replace(config, blocking_episodes=()),
                          np.random.default_rng(7))
    np.testing.assert_array_equal(clear.scan_t_s, blocked.scan_t_s)
    diffs = []
    for s in range(clear.scan_t_s.size):
        t_rel = clear.scan_t_s[s] - clear.start_t_s
        a = {ap: r for ap, r, st in zip(clear.row_ap[clear.row_scan == s], clear.rssi_dbm[clear.row_scan == s],
                                        clear.stale[clear.row_scan == s]) if not st}
        b = {ap: r for ap, r, st in zip(blocked.row_ap[blocked.row_scan == s], blocked.rssi_dbm[blocked.row_scan == s],
                                        blocked.stale[blocked.row_scan == s]) if not st}
        for ap in a.keys() & b.keys():
            if 42.0 <= t_rel < 70.0 or t_rel < 38.0:
                diffs.append((t_rel < 38.0, a[ap] - b[ap]))
    before = [d for early, d in diffs if early]
    during = [d for early, d in diffs if not early]
    assert before and all(d == 0 for d in before)
    assert during and np.median(during) == 12


def test_blocking_db_sums_the_episodes_that_cover_a_time():
    loss = blocking_db(np.array([0.0, 5.0, 9.99, 10.0, 12.0, 30.0]), ((5.0, 10.0, 8.0), (9.0, 15.0, 4.0)))
    np.testing.assert_array_equal(loss, [0.0, 8.0, 12.0, 4.0, 4.0, 0.0])


@pytest.mark.parametrize("episode", [(5.0, 3.0, 10.0), (-1.0, 3.0, 10.0), (1.0, 3.0, -2.0), (1.0, float("nan"), 2.0)])
def test_bad_blocking_episodes_are_rejected(episode):
    with pytest.raises(MapfilterError, match="blocking episode"):
        SimConfig(blocking_episodes=(episode,)).validate()


def test_offset_table_shifts_c_and_clips_alpha(office_aps):
    wrong = offset_access_points(office_aps, 13.0, -0.4)
    np.testing.assert_allclose(wrong.c_dbm, office_aps.c_dbm + 13.0)
    np.testing.assert_allclose(wrong.alpha_db_per_m, np.maximum(office_aps.alpha_db_per_m - 0.4, 0.0))
    np.testing.assert_array_equal(wrong.xy_m, office_aps.xy_m)
    with pytest.raises(MapfilterError, match="C offset"):
        offset_access_points(office_aps, float("inf"))


# ---- tracking ----------------------------------------------------------------------------------
def test_tracking_with_adaptation_is_deterministic_and_returns_the_adapted_table(office_aps, blocked_walk, tmp_path):
    from mapfilter.simulate.ilc_writer import write_ilc

    floorplan, walk, _ = blocked_walk
    path = tmp_path / "walk.txt"
    write_ilc(walk, path)
    recording = read_ilc(path)
    wrong = offset_access_points(office_aps, 13.0, -0.2)
    config = tracking_config(motion="rw", n_particles=500, adapt_path_loss=True, adapt_rssi_limit_dbm=-45.0)
    runs = [track(floorplan, recording, access_points=wrong, config=config, rng=np.random.default_rng(3))
            for _ in range(2)]
    np.testing.assert_array_equal(runs[0].causal.xy_m, runs[1].causal.xy_m)
    np.testing.assert_array_equal(runs[0].access_points.c_dbm, runs[1].access_points.c_dbm)
    assert np.abs(runs[0].access_points.c_dbm - office_aps.c_dbm).mean() < 13.0 - 3.0
    np.testing.assert_array_equal(wrong.c_dbm, office_aps.c_dbm + 13.0)  # the caller's table is not touched


def test_path_loss_state_reaches_the_step_reports(office_aps, blocked_walk, tmp_path):
    from mapfilter.simulate.ilc_writer import write_ilc

    floorplan, walk, _ = blocked_walk
    path = tmp_path / "walk.txt"
    write_ilc(walk, path)
    reports = []
    track(floorplan, read_ilc(path), access_points=office_aps,
                    config=tracking_config(motion="rw", n_particles=300), rng=np.random.default_rng(0),
                    on_step=reports.append)
    states = [r.path_loss for r in reports if r.path_loss is not None]
    assert states and max(s.blocking_db for s in states) > 6.0  # blocking compensation is on by default
    assert all(np.isfinite(s.nearest_c_dbm) for s in states)
    plain = []
    track(floorplan, read_ilc(path), access_points=office_aps,
                    config=tracking_config(motion="rw", n_particles=300, blocking_compensation=False),
                    rng=np.random.default_rng(0), on_step=plain.append)
    assert all(r.path_loss is None for r in plain)


def test_rerun_shows_h_and_the_nearest_c(office_aps, blocked_walk, tmp_path):
    sys.path.insert(0, str(Path(__file__).parents[1] / "viz"))
    from test_viz import read_rrd, rows

    from mapfilter.simulate.ilc_writer import write_ilc
    from mapfilter.viz import make_logger

    floorplan, walk, _ = blocked_walk
    path = tmp_path / "walk.txt"
    write_ilc(walk, path)
    out = tmp_path / "run.rrd"
    with make_logger(floorplan, rrd_path=out) as logger:
        track(floorplan, read_ilc(path), access_points=office_aps,
                        config=tracking_config(motion="rw", n_particles=300, adapt_path_loss=True,
                                              adapt_rssi_limit_dbm=-45.0),
                        rng=np.random.default_rng(0), on_step=logger.log_step)
    entities = read_rrd(out)
    h = [v[0] for v in rows(entities["/plots/path_loss/blocking_H_db"], "Scalars:scalars")]
    c = [v[0] for v in rows(entities["/plots/path_loss/nearest_C_dbm"], "Scalars:scalars")]
    assert len(h) > 10 and max(h) > 6.0 and min(h) == 0.0
    assert len(c) > 10 and all(-60.0 < v < -20.0 for v in c)


# ---- CLI -----------------------------------------------------------------------------------------
def test_cli_simulate_wrong_table_then_track_with_adapt(tmp_path, capsys):
    walk, wrong, adapted = tmp_path / "w.txt", tmp_path / "wrong.csv", tmp_path / "adapted.csv"
    assert main(["simulate", str(OFFICE), "--out", str(walk), "--duration", "60", "--seed", "1",
                 "--blocking", "20", "35", "12", "--write-aps", str(wrong), "--aps-c-offset", "13",
                 "--aps-alpha-offset", "-0.2", "--wall-loss-db", "0", "0"]) == 0
    truth = AccessPointTable.read_csv(OFFICE_APS)
    table = AccessPointTable.read_csv(wrong)
    np.testing.assert_allclose(table.c_dbm, truth.c_dbm + 13.0)
    assert main(["track", str(OFFICE), str(walk), "--aps", str(wrong), "--adapt", "--adapt-rssi-limit", "-45",
                 "--adapted-aps", str(adapted), "--particles", "500", "--motion", "rw"]) == 0
    assert "adapted access-point table" in capsys.readouterr().out
    result = AccessPointTable.read_csv(adapted)
    assert result.keys == table.keys
    assert np.abs(result.c_dbm - truth.c_dbm).mean() < np.abs(table.c_dbm - truth.c_dbm).mean()
    assert main(["track", str(OFFICE), str(walk), "--aps", str(wrong), "--no-blocking-compensation",
                 "--particles", "300", "--motion", "rw"]) == 0


@pytest.mark.parametrize("args, message", [
    (["--adapted-aps", "{tmp}/a.csv"], "give --adapt too"),
    (["--radiomap", str(REPO / "maps" / "office_radiomap.npz"), "--adapt"], "need trilateration"),
])
def test_cli_track_bad_adaptation_flags_are_one_line(args, message, tmp_path, capsys):
    walk = REPO / "maps" / "office_walk.txt.gz"
    argv = ["track", str(OFFICE), str(walk), "--particles", "100"] + [a.replace("{tmp}", str(tmp_path)) for a in args]
    assert main(argv) != 0
    err = capsys.readouterr().err.strip()
    assert message in err and "Traceback" not in err and len(err.splitlines()) == 1


def test_cli_track_a_nan_rssi_limit_is_refused_by_the_option(tmp_path, capsys):
    walk = REPO / "maps" / "office_walk.txt.gz"
    with pytest.raises(SystemExit) as stop:
        main(["track", str(OFFICE), str(walk), "--aps", str(OFFICE_APS), "--adapt", "--adapt-rssi-limit", "nan"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "--adapt-rssi-limit" in err and "finite" in err and "Traceback" not in err


def test_cli_simulate_offsets_need_write_aps(tmp_path, capsys):
    assert main(["simulate", str(OFFICE), "--out", str(tmp_path / "w.txt"), "--aps-c-offset", "5"]) != 0
    assert "--write-aps" in capsys.readouterr().err


def test_ap_key_of_the_wrong_table_matches(office_aps):
    # the wrong table keeps bssid and band, so every key of the true table matches it
    assert offset_access_points(office_aps, 1.0).keys == office_aps.keys == [
        ap_key(b, band) for b, band in zip(office_aps.bssid, office_aps.band)]
    assert path_loss_rssi_dbm(1.0, -38.0, 2.0, 0.3, 30.0) == pytest.approx(-38.3)


def test_cli_evaluate_takes_the_adaptation_flags(tmp_path):
    """`evaluate` passes --adapt / --no-blocking-compensation to the trilateration pf: the flags change its track."""
    import csv

    means = {}
    for name, extra in (("plain", ["--no-blocking-compensation"]), ("adapt", ["--adapt", "--adapt-rssi-limit", "-50"])):
        out = tmp_path / name
        assert main(["evaluate", str(OFFICE), str(REPO / "maps" / "office_walk.txt.gz"), "--aps", str(OFFICE_APS),
                     "--methods", "pf-nopdr,ls", "--particles", "500", "--out", str(out), *extra]) == 0
        with (out / "summary.csv").open() as handle:
            means[name] = {row["method"]: float(row["mean"]) for row in csv.DictReader(handle)}
    assert means["plain"]["ls"] == means["adapt"]["ls"]  # LS has no adaptation
    assert means["plain"]["pf-nopdr"] != means["adapt"]["pf-nopdr"]
