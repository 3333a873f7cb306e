"""BLE beacons: the beacon table, the fit, the measurement model and source, tracking with them.

Simulated walks on the bundled office carry beacon readings drawn from the path-loss model
(TYPE_BEACON rows appended to the simulated ILC log); the IPIN 2023 logs carry real ones."""

from __future__ import annotations

import csv
import dataclasses

import numpy as np
import pytest

from mapfilter.cli import main
from mapfilter.config import TrackingConfig
from mapfilter.errors import MapfilterError
from mapfilter.evaluation.metrics import errors_at_waypoints, summarise_errors
from mapfilter.evaluation.scoring import score_track
from mapfilter.filter.models.ble import BeaconLikelihood, BeaconWindow
from mapfilter.filter.models.building import FloorStack
from mapfilter.filter.models.frame import StateFrame
from mapfilter.filter.sources.ble import BeaconSource, BleConfig
from mapfilter.filter.particles import Particles
from mapfilter.maps.building import Building
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.sensors.beacons import (BeaconFitConfig, BeaconTable, beacon_rssi_dbm, fit_beacons, labelled_readings,
                                      parse_beacon_ids)
from mapfilter.sensors.ilc import read_ilc
from mapfilter.sensors.radiomap import RadioMap
from mapfilter.sensors.recording import Beacons
from mapfilter.pipeline.tracker import Tracker, TrackingInputs, track
from tests.conftest import REPO
from tests.pipeline.test_tracker_stream import _between, _span

OFFICE = REPO / "maps" / "office.yaml"
UUID = "fda50693-a4e2-4fb1-afcf-c6eb07647825"
# eight beacons around the 38 m x 38 m office, each on free space
BEACON_XY = np.array([[5.0, 5.0], [19.0, 4.0], [33.0, 6.0], [4.0, 19.0], [34.0, 20.0], [6.0, 33.0], [19.0, 34.0],
                      [32.0, 32.0]])
TRUE_C, TRUE_N = -62.0, 2.1


def _mac(i: int) -> str:
    """The MAC the simulated log gives beacon i (row i of the table), as the log writes it."""
    return f"00:ab:cd:ef:01:0{i}"


def _office_table(c_dbm=TRUE_C, n=TRUE_N) -> BeaconTable:
    k = len(BEACON_XY)
    return BeaconTable([_mac(i).upper() for i in range(k)], BEACON_XY.copy(), [None] * k,
                       np.full(k, c_dbm), np.full(k, n), np.full(k, 10.0))


def _beacon_rows(walk, rng: np.random.Generator, noise_db: float = 4.0, rate_hz: float = 1.0) -> list[str]:
    """TYPE_BEACON rows of the walk: each beacon reported at random times (``rate_hz``), its RSSI
    from the path-loss model at the true position plus Gaussian noise, unheard below -100 dBm."""
    rows = []
    for i, xy in enumerate(BEACON_XY):
        t = walk.start_t_s + np.cumsum(rng.exponential(1.0 / rate_hz, int(3 * rate_hz * (walk.end_t_s - walk.start_t_s))))
        t = t[t < walk.end_t_s]
        d = np.linalg.norm(walk.position_at(t) - xy, axis=1)
        rssi = np.round(beacon_rssi_dbm(d, TRUE_C, TRUE_N) + noise_db * rng.standard_normal(t.size))
        for ms, r in dict(zip(np.round(t * 1000).astype(np.int64), rssi)).items():  # one reading per ms
            if r >= -100:
                rows.append((ms, f"{ms}\tTYPE_BEACON\t{UUID}\t1\t{i + 1}\t-59\t{int(r)}\t1.0\t{_mac(i)}\t{ms}\n"))
    return [line for _, line in sorted(rows)]


def _with_beacons(plain_text: str, rows: list[str]) -> str:
    """An ILC log with beacon rows in time order among its records, as a phone writes them (a
    reading stamped minutes before records already written went back with the log's clock:
    sensors/logread.LogClock)."""
    lines = plain_text.splitlines(keepends=True)
    header = [line for line in lines if line.startswith("#")]
    records = sorted([line for line in lines if not line.startswith("#")] + rows,
                     key=lambda line: int(line.split("\t", 1)[0]))
    return "".join(header + records)


@pytest.fixture(scope="module")
def office_walk(tmp_path_factory):
    """(plan, the simulated walk with beacon readings as read back, the walk's truth, log path)."""
    from mapfilter.sensors.pathloss import AccessPointTable
    from mapfilter.simulate.ilc_writer import write_ilc
    from mapfilter.simulate.walk import SimConfig, simulate_walk

    plan = FloorPlan.load(OFFICE)
    aps = AccessPointTable.read_csv(REPO / "maps" / "office_aps.csv")
    walk = simulate_walk(plan, aps, SimConfig(duration_s=150.0), np.random.default_rng(11))
    folder = tmp_path_factory.mktemp("ble_walk")
    plain = folder / "plain.txt"
    write_ilc(walk, plain)
    path = folder / "walk.txt"
    path.write_text(_with_beacons(plain.read_text(), _beacon_rows(walk, np.random.default_rng(12))))
    recording = read_ilc(path)
    assert len(recording.beacons.t_s) > 500
    return plan, recording, walk, path


def _mean_error(plan, recording, result) -> float:
    score = score_track(Building.from_plan(plan), recording, result.causal, None, True)
    return summarise_errors(score.errors.errors_m)["mean"]


# ---- the likelihood -----------------------------------------------------------------------------
def _particles(xy_m: np.ndarray) -> Particles:
    state = np.zeros((6, len(xy_m)))
    state[:2] = np.asarray(xy_m, dtype=np.float64).T
    return Particles(state, np.zeros(len(xy_m)))


def test_the_kernel_is_the_path_loss_formula_on_one_floor():
    table = _office_table().with_parameters(np.linspace(-70, -55, 8), np.linspace(1.5, 3.0, 8), 10.0)
    plan = FloorPlan.load(OFFICE)
    model = BeaconLikelihood(table, StateFrame(Building.from_plan(plan)), variance_db2=30.0)
    rng = np.random.default_rng(3)
    xy = np.vstack([rng.uniform(-5, 45, (3000, 2)), BEACON_XY[2] + [0.3, 0.2]])  # one inside the 1 m clamp
    window = BeaconWindow(0.0, np.array([1, 2, 6]), np.array([-75.0, -61.0, -90.0]))
    got = model.log_likelihood(_particles(xy), window)
    expected = np.zeros(len(xy))
    for row, z in zip(window.beacon, window.rssi_dbm):
        d = np.linalg.norm(xy - BEACON_XY[row], axis=1)
        expected -= (z - beacon_rssi_dbm(d, table.c_dbm[row], table.n[row])) ** 2 / (2 * 30.0)
    np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-4)  # float32 inside the kernel
    assert got.max() <= model.log_likelihood_peak


def test_the_kernel_in_a_stack_plan_weighs_each_particle_on_its_own_floor(office3):
    building, _ = office3
    stack = FloorStack(building)
    k = 5
    rng = np.random.default_rng(4)
    floors = [building.floor_names[i] for i in (0, 1, 2, 2, 0)]
    table = BeaconTable([f"B{i}" for i in range(k)], rng.uniform(3, 35, (k, 2)), floors, rng.uniform(-70, -55, k),
                        rng.uniform(1.5, 3.0, k), np.full(k, 12.0))
    model = BeaconLikelihood(table, StateFrame(building, stack=stack), variance_db2=25.0)
    n = 4000
    particle_floor = rng.integers(0, len(building.floors), n)
    local = rng.uniform(0, 38, (n, 2))
    window = BeaconWindow(0.0, np.array([0, 2, 3]), np.array([-70.0, -82.0, -60.0]))
    got = model.log_likelihood(_particles(stack.to_stack(local, particle_floor)), window)
    beacon_xy, beacon_floor = table.building_xy_m(building)
    walker = np.array([building.floors[f].to_building(p) for f, p in zip(particle_floor, local)])
    expected = np.zeros(n)
    for row, z in zip(window.beacon, window.rssi_dbm):
        d = np.linalg.norm(walker - beacon_xy[row], axis=1)
        r = beacon_rssi_dbm(d, table.c_dbm[row], table.n[row], 12.0, np.abs(particle_floor - beacon_floor[row]))
        expected -= (z - r) ** 2 / 50.0
    np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-4)
    # a strong reading of a beacon on floor 2 favours floor 2 at the point above it over floor 0 there
    strong = BeaconWindow(0.0, np.array([2]), np.array([-58.0]))
    below = table.xy_m[2]
    values = model.log_likelihood(_particles(stack.to_stack(np.array([below, below]), np.array([2, 0]))), strong)
    assert values[0] > values[1]


# ---- the source ---------------------------------------------------------------------------------
def _source(window_s=2.0) -> BeaconSource:
    frame = StateFrame(Building.from_plan(FloorPlan.load(OFFICE)))
    return BeaconSource(_office_table(), frame, BleConfig(window_s=window_s, rssi_variance_db2=16.0))


def _readings(t, ids, rssi) -> Beacons:
    return Beacons(np.array(t, dtype=np.float64), list(ids), np.array(rssi, dtype=np.float32),
                   np.full(len(t), np.nan, dtype=np.float32))


def test_windows_take_the_trailing_readings_median_each_reading_once():
    source = _source(2.0)
    b = [_mac(i).lower() for i in (0, 1, 2)]  # the table's ids matched in any case
    readings = _readings([0.0, 0.5, 1.0, 1.9, 2.1, 2.1, 2.5, 3.0, 4.2, 9.0, 9.5, 12.0],
                         [b[0], b[1], b[0], b[0], b[1], "unknown:1:1", b[2], b[2], b[2], b[0], b[1], b[1]],
                         [-70, -80, -72, -90, -81, -50, -60, -64, -66, -75, -85, -95])
    rec = dataclasses.replace(_empty_recording(), beacons=readings)
    records = source.records_of(rec)
    assert len(records[0]) == 11  # the unknown beacon is left out
    times = source.add(records, final=True)
    # first at the first reading a full window after the first one (2.1), then the first reading
    # at least 2 s after the previous measurement: 4.2, 9.0, 12.0
    assert times == [2.1, 4.2, 9.0, 12.0]
    first, second, third, fourth = (source.measurement(i) for i in range(4))
    assert first.beacon.tolist() == [0, 1] and first.rssi_dbm.tolist() == [-81.0, -80.5]  # (0.1, 2.1]: 1.0, 1.9; 0.5, 2.1
    assert second.beacon.tolist() == [2] and second.rssi_dbm.tolist() == [-64.0]  # (2.2, 4.2]: 2.5, 3.0, 4.2
    assert third.beacon.tolist() == [0] and third.rssi_dbm.tolist() == [-75.0]  # 7.0 < t <= 9.0
    assert fourth.beacon.tolist() == [1] and fourth.rssi_dbm.tolist() == [-95.0]  # 9.5 is older than 2 s


def test_windows_do_not_depend_on_how_the_readings_arrive():
    rng = np.random.default_rng(5)
    t = np.sort(rng.uniform(0, 60, 300))
    ids = [_mac(k) for k in rng.integers(0, 8, 300)]
    rssi = rng.integers(-95, -50, 300).astype(float)
    whole = _source()
    whole_t = whole.add((t, np.array([whole._index[i.upper()] for i in ids]), rssi), final=True)
    pieces = _source()
    pieces_t = []
    rows = np.array([pieces._index[i.upper()] for i in ids])
    for lo, hi in zip([0, 7, 8, 150, 151, 299], [7, 8, 150, 151, 299, 300]):
        pieces_t += pieces.add((t[lo:hi], rows[lo:hi], rssi[lo:hi]), final=hi == 300)
    assert whole_t == pieces_t and len(whole_t) > 20
    for i in range(len(whole_t)):
        a, b = whole.measurement(i), pieces.measurement(i)
        assert a.beacon.tolist() == b.beacon.tolist() and a.rssi_dbm.tolist() == b.rssi_dbm.tolist()


def _empty_recording():
    from tests.sensors.test_pdr import make_recording

    return make_recording(None, None)


# ---- tracking ----------------------------------------------------------------------------------
def _config(**settings) -> TrackingConfig:
    return TrackingConfig(seed=1).override({"filter.n_particles": 3000, **settings})


def test_beacons_alone_track_a_simulated_walk_and_add_to_the_wifi(office_walk):
    plan, recording, _, _ = office_walk
    radio_map = RadioMap.load(REPO / "maps" / "office_radiomap.npz")
    table = _office_table()
    errors = {}
    for label, kwargs in (("wifi", {"radio_map": radio_map}),
                          ("both", {"radio_map": radio_map, "sources": {"ble": table}}),
                          ("ble", {"sources": {"ble": table}})):
        runs = [_mean_error(plan, recording, track(plan, recording, config=_config(seed=seed), **kwargs))
                for seed in (1, 2)]
        errors[label] = float(np.mean(runs))
    assert errors["ble"] < 2.5  # eight beacons, 4 dB of noise: the beacons alone track
    assert errors["both"] <= errors["wifi"]
    # the WiFi alone weighs no beacon: the same track with the readings removed
    bare = dataclasses.replace(recording, beacons=_readings([], [], []))
    a = track(plan, recording, radio_map, config=_config())
    b = track(plan, bare, radio_map, config=_config())
    np.testing.assert_array_equal(a.causal.xy_m, b.causal.xy_m)
    assert a.n_measurements == {}


def _cut(rec, t0, t1):
    return _between(rec, t0, t1)  # every sensor's records, the beacons' too


def _stream_rows(plan, rec, config, table, radio_map, chunks=None):
    tracker = Tracker(plan, TrackingInputs(radio_map, sources={"ble": table}), config=config)
    bounds = [-np.inf, *(chunks if chunks is not None else []), np.inf]
    for t0, t1 in zip(bounds[:-1], bounds[1:]):
        tracker.feed(_cut(rec, t0, t1))
    tracker.close()
    causal = tracker.causal
    return causal.t_s, causal.xy_m, causal.std_m


@pytest.mark.parametrize("with_wifi", [False, True])
def test_the_beacon_source_is_causal_and_streams(office_walk, with_wifi):
    plan, recording, _, _ = office_walk
    radio_map = RadioMap.load(REPO / "maps" / "office_radiomap.npz") if with_wifi else None
    config, table = _config(), _office_table()
    whole = _stream_rows(plan, recording, config, table, radio_map)
    start, end = _span(recording)
    cut = start + 0.5 * (end - start)
    cut_rows = _stream_rows(plan, _cut(recording, -np.inf, cut), config, table, radio_map)
    before = whole[0] <= cut
    assert before.sum() == len(cut_rows[0]) > 10
    for a, b in zip(whole, cut_rows):
        np.testing.assert_array_equal(a[before], b)  # to the bit
    chunks = np.sort(np.random.default_rng(6).uniform(start, end, 40))
    for a, b in zip(whole, _stream_rows(plan, recording, config, table, radio_map, chunks)):
        np.testing.assert_array_equal(a, b)


def test_a_live_run_weighs_each_beacon_reading_once(office_walk, tmp_path, monkeypatch, capsys):
    """``track MAP - --beacons``: the log on standard input in pieces, each chunk of the log
    stream carrying its own beacon readings (a chunk repeating earlier ones would bring them
    back as late readings): the file run's track to the byte."""
    import io
    import sys

    _, recording, _, path = office_walk
    table = tmp_path / "beacons.csv"
    _office_table().write_csv(table)
    options = ["--beacons", str(table), "--particles", "2000", "--seed", "3"]  # the beacons alone
    whole = tmp_path / "file.csv"
    assert main(["track", str(OFFICE), str(path), *options, "--out", str(whole)]) == 0
    # as a phone streams it: the records in time order (the fixture appended the beacon rows)
    lines = path.read_text().splitlines(keepends=True)
    records = sorted((line for line in lines if not line.startswith("#")), key=lambda line: int(line.split("\t")[0]))
    data = "".join([*(line for line in lines if line.startswith("#")), *records]).encode()
    assert len(data) > 20 * 65536  # many pieces
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BufferedReader(io.BytesIO(data))))
    live = tmp_path / "live.csv"
    assert main(["track", str(OFFICE), "-", *options, "--out", str(live)]) == 0
    assert live.read_bytes() == whole.read_bytes()
    assert "beacon windows" in capsys.readouterr().err


def test_beacons_alone_smooth_their_track_and_need_a_source(office_walk):
    """Without WiFi the offline track is the smoother's alone (no scans to place the shape by):
    wall-free and closer to the truth than the causal track."""
    from mapfilter.maps.walls import count_wall_crossings

    plan, recording, _, _ = office_walk
    result = track(plan, recording, config=_config(smooth=True), sources={"ble": _office_table()})
    assert result.restarted is None and count_wall_crossings(plan, result.offline.xy_m) == 0
    causal = errors_at_waypoints(result.causal.t_s, result.causal.xy_m, recording.waypoint_t_s,
                                 recording.waypoint_xy_m, True).errors_m
    offline = errors_at_waypoints(result.offline.t_s, result.offline.xy_m, recording.waypoint_t_s,
                                  recording.waypoint_xy_m, False).errors_m
    assert offline.mean() < causal.mean()  # measured: 1.40 -> 0.61 m
    with pytest.raises(MapfilterError, match=r"BLE beacons \(--beacons\)"):
        track(plan, recording, config=_config())


def test_ble_settings_are_saved_and_reloaded():
    config = TrackingConfig().override({"sources.ble.window_s": 3.5, "sources.ble.rssi_variance_db2": 20.0})
    text = config.to_yaml()
    assert "  ble:" in text and "window_s: 3.5" in text and "rssi_variance_db2: 20.0" in text
    assert TrackingConfig.from_yaml(text).sources.ble == BleConfig(3.5, 20.0)
    with pytest.raises(MapfilterError, match="window_s"):
        TrackingConfig.from_yaml("sources: {ble: {window_s: 0}}")
    with pytest.raises(MapfilterError, match=r"line 1: unknown setting 'ble' .*docs/changelog.md"):
        TrackingConfig.from_yaml("ble: {window_s: 3}")


# ---- the table ----------------------------------------------------------------------------------
def _write(tmp_path, text, name="beacons.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_a_table_round_trips(tmp_path):
    table = _office_table().with_parameters(np.linspace(-70, -55, 8), 1.8, 7.5)
    path = tmp_path / "t.csv"
    table.write_csv(path)
    back = BeaconTable.read_csv(path)
    assert back.beacon_id == table.beacon_id and back.floor == table.floor
    np.testing.assert_allclose(back.xy_m, table.xy_m)
    np.testing.assert_allclose(back.c_dbm, table.c_dbm, atol=0.005)
    np.testing.assert_allclose(back.floor_loss_db, 7.5)
    # optional columns: the defaults; ids in any case match the logs'
    minimal = BeaconTable.read_csv(_write(tmp_path, "Beacon_ID,X,Y\nbe:ac:01,1,2\n"))
    assert minimal.beacon_id == ["BE:AC:01"] and minimal.c_dbm[0] == -59.0 and minimal.n[0] == 2.0


@pytest.mark.parametrize("text, message, line", [
    ("id,x,y\nA,1,2\n", "needs a beacon_id column", 1),
    ("beacon_id,east,north\nA,1,2\n", "x,y (metres) or latitude,longitude", 1),
    ("beacon_id,x,y\nA,1,2\nB,one,2\n", "column x is not a number: 'one'", 3),
    ("beacon_id,x,y,C\nA,1,2,-200\n", "column C is -200, outside", 2),
    ("beacon_id,x,y,n\nA,1,2,nan\n", "column n is not finite", 2),
    ("beacon_id,x,y\nA,1,2\n\nA,3,4\n", "beacon A is listed twice (lines 2 and 4)", 4),
    ("beacon_id,x,y\n,1,2\n", "empty beacon id", 2),
    ("beacon_id,x,y\nA,1\n", "2 fields, the header has 3", 2),
    ("beacon_id,latitude,longitude\nA,49.4,11.1\n", "need a georeferenced building", 1),
    ("bleID,Lat,Lon,floor\n\"BLE1\",49.4,11.1,00\n", "names its beacons by bleID", 1),
    ("beacon_id,x,y\n", "has no rows", None),
    ("", "empty: it needs a header line", 1),
])
def test_a_bad_table_is_one_line_naming_the_file_and_line(tmp_path, text, message, line):
    path = _write(tmp_path, text)
    with pytest.raises(MapfilterError) as caught:
        BeaconTable.read_csv(path)
    assert message in str(caught.value)
    assert str(caught.value).startswith(f"{path}:{line}: " if line is not None else f"{path}: ")
    assert "\n" not in str(caught.value)


def test_a_table_against_the_building(tmp_path, office3):
    building, _ = office3
    path = _write(tmp_path, "beacon_id,x,y,floor\nA,1,2,F9\n")
    with pytest.raises(MapfilterError, match=rf"{path}:2: floor 'F9' is not in the building"):
        BeaconTable.read_csv(path, building)
    with pytest.raises(MapfilterError, match=rf"{path}:2: no floor"):
        BeaconTable.read_csv(_write(tmp_path, "beacon_id,x,y\nA,1,2\n"), building)
    far = BeaconTable.read_csv(_write(tmp_path, f"beacon_id,x,y,floor\nA,1,2,{building.floor_names[0]}\n"
                                                f"B,5000,2,{building.floor_names[1]}\n"), building)
    from mapfilter.sensors.beacons import check_beacons_on_map

    with pytest.raises(MapfilterError, match=r"beacons.csv:3: beacon B at \(5000, 2\) m lies 4962 m outside"):
        check_beacons_on_map(far, building)


def test_ids_map_a_venue_files_names(tmp_path):
    text = "beacon_id,x,y\nBLE1,1,2\nBLE2,3,4\n"
    table = BeaconTable.read_csv(_write(tmp_path, text), ids={"BLE1": "aa:01", "BLE2": "AA:02"})
    assert table.beacon_id == ["AA:01", "AA:02"]
    with pytest.raises(MapfilterError, match="beacon BLE2 has no id among the ids given"):
        BeaconTable.read_csv(_write(tmp_path, text), ids={"BLE1": "aa:01"})
    with pytest.raises(MapfilterError, match="the ids name BLE7, which the table does not have"):
        BeaconTable.read_csv(_write(tmp_path, text), ids={"BLE1": "a", "BLE2": "b", "BLE7": "c"})
    assert parse_beacon_ids("BLE1=BE:AC:01, BLE2=BE:AC:02") == {"BLE1": "BE:AC:01", "BLE2": "BE:AC:02"}
    for bad in ("BLE1", "BLE1=", "=x", "BLE1=a,BLE1=b", " , "):
        with pytest.raises(ValueError):
            parse_beacon_ids(bad)


# ---- the fit ------------------------------------------------------------------------------------
def test_the_fit_recovers_the_parameters_and_finds_swapped_ids(office_walk):
    plan, recording, _, _ = office_walk
    building = Building.from_plan(plan)
    # a walk's ground truth: the simulated waypoints are every step end, so the labels are exact
    guess = _office_table(c_dbm=-50.0, n=3.0)
    fit = fit_beacons(guess, labelled_readings(guess, building, [recording]))
    heard = [row.own_fit for row in fit.rows]
    assert sum(heard) >= 6
    # C and n trade off against each other (a line through readings from a few metres to tens):
    # the fitted model's RSSI is the truth's over the distances each beacon was heard from
    readings = labelled_readings(guess, building, [recording])
    for row in np.flatnonzero(heard):
        distance_m = np.percentile(readings.distance_m[readings.beacon == row], [10, 50, 90])
        np.testing.assert_allclose(beacon_rssi_dbm(distance_m, fit.table.c_dbm[row], fit.table.n[row]),
                                   beacon_rssi_dbm(distance_m, TRUE_C, TRUE_N), atol=1.5)
    assert all(row.best_position == row.beacon_id for row in fit.rows if row.own_fit)
    assert not fit.floor_loss_fitted  # one floor: the table's floor loss kept
    # two ids swapped: each one's readings fit the other's position better
    swapped = dataclasses.replace(guess, beacon_id=[guess.beacon_id[i] for i in (7, 1, 2, 3, 4, 5, 6, 0)])
    rows = fit_beacons(swapped, labelled_readings(swapped, building, [recording])).rows
    assert rows[0].best_position == swapped.beacon_id[7] and rows[7].best_position == swapped.beacon_id[0]
    assert rows[0].best_position_rmse_db < rows[0].rmse_db - 1.0
    # a beacon with too few readings takes the shared values; too few in all is one line
    readings = labelled_readings(guess, building, [recording])
    most = int(np.bincount(readings.beacon).max())
    few = fit_beacons(guess, readings, BeaconFitConfig(min_readings=most + 1))
    assert not any(row.own_fit for row in few.rows)
    np.testing.assert_allclose(few.table.c_dbm, few.shared_c_dbm)
    assert abs(few.shared_c_dbm - TRUE_C) < 2.5 and abs(few.shared_n - TRUE_N) < 0.3
    with pytest.raises(MapfilterError, match="labelled readings of the table's beacons"):
        fit_beacons(guess, labelled_readings(guess, building, [dataclasses.replace(
            recording, beacons=_readings([], [], []))]))


# ---- the command line ---------------------------------------------------------------------------
@pytest.mark.slow
def test_cli_fit_beacons_track_and_evaluate_with_beacons(office_walk, tmp_path, capsys):
    plan, recording, _, log = office_walk
    positions = tmp_path / "positions.csv"
    _office_table(c_dbm=-50.0, n=3.0).write_csv(positions)
    fitted = tmp_path / "fitted.csv"
    assert main(["radiomap", "fit-beacons", str(OFFICE), str(log), "--positions", str(positions),
                 "--out", str(fitted)]) == 0
    out = capsys.readouterr().out
    assert "beacons: 8 fitted from" in out and "wrong position" not in out
    table = BeaconTable.read_csv(fitted)
    assert abs(np.median(table.c_dbm) - TRUE_C) < 2.5
    track_csv = tmp_path / "track.csv"
    common = ["--particles", "2000", "--seed", "1"]
    assert main(["track", str(OFFICE), str(log), "--beacons", str(fitted), "--out", str(track_csv)] + common) == 0
    out = capsys.readouterr().out
    assert "0 WiFi scans used" in out and "beacon windows" in out and track_csv.is_file()
    assert main(["track", str(OFFICE), str(log), "--beacons", str(fitted), "--radiomap",
                 str(REPO / "maps" / "office_radiomap.npz"), "--out", str(track_csv)] + common) == 0
    assert "beacon windows" in capsys.readouterr().out
    # many walks (--out-dir): the same track as one walk tracked alone
    assert main(["track", str(OFFICE), str(log), "--beacons", str(fitted), "--radiomap",
                 str(REPO / "maps" / "office_radiomap.npz"), "--out-dir", str(tmp_path / "batch")] + common) == 0
    assert "1 tracked" in capsys.readouterr().out
    assert (tmp_path / "batch" / "walk.csv").read_bytes() == track_csv.read_bytes()
    # a bad table: one line naming it, exit 1, nothing written
    bad = _write(tmp_path, "beacon_id,x,y\nA,1,zz\n", "bad.csv")
    other = tmp_path / "other.csv"
    assert main(["track", str(OFFICE), str(log), "--beacons", str(bad), "--out", str(other)] + common) == 1
    err = capsys.readouterr().err
    assert err.strip() == f"mapfilter: error: {bad}:2: column y is not a number: 'zz'" and not other.exists()
    # evaluate: the beacon methods beside the others, pf+ble's offline track too
    assert main(["evaluate", str(OFFICE), str(log), "--radiomap", str(REPO / "maps" / "office_radiomap.npz"),
                 "--beacons", str(fitted), "--methods", "pf,pf+ble,pf-ble", "--smooth", "--out", str(tmp_path / "eval")]
                + common) == 0
    out = capsys.readouterr().out
    assert "| pf+ble |" in out and "| pf-ble |" in out and "| pf-smooth+ble |" in out
    with (tmp_path / "eval" / "summary.csv").open() as handle:
        summary = {row["method"]: row for row in csv.DictReader(handle)}
    assert int(summary["pf-smooth+ble"]["wall_crossings"]) == 0 and int(summary["pf-smooth+ble"]["missed"]) == 0
    assert float(summary["pf-smooth+ble"]["mean"]) < float(summary["pf+ble"]["mean"])
    assert main(["evaluate", str(OFFICE), str(log), "--radiomap", str(REPO / "maps" / "office_radiomap.npz"),
                 "--methods", "pf-ble", "--out", str(tmp_path / "eval2")]) == 1
    assert "method pf-ble weighs BLE beacons: give --beacons TABLE.csv" in capsys.readouterr().err


def test_cli_fit_beacons_refuses_bad_ids_and_tables(office_walk, tmp_path, capsys):
    _, _, _, log = office_walk
    positions = _write(tmp_path, "bleID,x,y\nBLE1,1,2\n", "p.csv")
    out = tmp_path / "fitted.csv"
    assert main(["radiomap", "fit-beacons", str(OFFICE), str(log), "--positions", str(positions), "--out",
                 str(out)]) == 1
    assert "names its beacons by bleID" in capsys.readouterr().err
    assert main(["radiomap", "fit-beacons", str(OFFICE), str(log), "--positions", str(positions), "--ids", "BLE1",
                 "--out", str(out)]) == 1
    assert "mapfilter: error: --ids: expected NAME=ID pairs" in capsys.readouterr().err
    assert not out.exists()


# ---- the IPIN 2023 logs ---------------------------------------------------------------------------
IPIN_IDS = ("BLE1=BE:AC:20:23:00:01,BLE2=BE:AC:20:23:00:03,BLE3=BE:AC:20:23:00:02,BLE4=BE:AC:20:23:00:04,"
            "BLE5=BE:AC:20:23:00:05,BLE6=BE:AC:20:23:00:06")


@pytest.fixture(scope="module")
def ipin_building(ipin_venue):
    return Building.load(ipin_venue)


@pytest.mark.slow
def test_ipin_beacons_minor_n_is_ble_n_but_for_2_and_3(ipin2023, ipin_building):
    """The natural reading (BLEn the beacon with minor n, MAC ...:0n) checked against the POSI
    points: the readings of minors 2 and 3 fit each other's positions (and floors) better."""
    from mapfilter.sensors.logs import read_log

    logs = sorted((ipin2023 / "logs").glob("*.txt.gz"))
    recordings = [read_log(p, building=ipin_building) for p in logs[::2]]
    natural = ",".join(f"BLE{i}=BE:AC:20:23:00:0{i}" for i in range(1, 7))
    positions = ipin2023 / "BLE_Locations.csv"
    for ids, swapped in ((natural, True), (IPIN_IDS, False)):
        table = BeaconTable.read_csv(positions, ipin_building, parse_beacon_ids(ids))
        assert table.floor == ["0", "0", "-2", "-2", "-2", "-2"]
        fit = fit_beacons(table, labelled_readings(table, ipin_building, recordings))
        elsewhere = {row.beacon_id: row.best_position for row in fit.rows
                     if row.best_position_rmse_db < row.rmse_db - 1.0}
        if swapped:
            assert elsewhere == {"BE:AC:20:23:00:02": "BE:AC:20:23:00:03", "BE:AC:20:23:00:03": "BE:AC:20:23:00:02"}
        else:
            assert elsewhere == {}
            assert 1.0 < fit.floor_loss_db < 10.0 and fit.floor_loss_fitted


@pytest.mark.slow
def test_ipin_walk_with_beacons(ipin2023, ipin_building):
    from mapfilter.api import build_radio_map
    from mapfilter.sensors.logs import read_log

    logs = sorted((ipin2023 / "logs").glob("*.txt.gz"))
    walk = read_log(next(p for p in logs if "Trial21_repetition03" in p.name), building=ipin_building)
    others = [read_log(p, building=ipin_building) for p in logs if "Trial2" in p.name and "Trial21_repetition03"
              not in p.name]
    table = BeaconTable.read_csv(ipin2023 / "BLE_Locations.csv", ipin_building, parse_beacon_ids(IPIN_IDS))
    fitted = fit_beacons(table, labelled_readings(table, ipin_building, others)).table
    radio_map = build_radio_map(ipin_building, others)
    config = TrackingConfig().override({"filter.n_particles": 3000})
    both = track(ipin_building, walk, radio_map, config=config, sources={"ble": fitted})
    alone = track(ipin_building, walk, config=config, sources={"ble": fitted})
    assert both.n_measurements["ble"] == alone.n_measurements["ble"] > 30
    for result in (both, alone):
        score = score_track(ipin_building, walk, result.causal, None, True)
        assert score.errors.errors_m.size == walk.waypoint_t_s.size
        assert np.median(score.errors.errors_m) < (5.0 if result is both else 25.0)


def test_leave_one_out_fits_each_walks_beacons_without_it(office_walk, tmp_path):
    """evaluate --leave-one-out --beacons: a walk's table is fitted on the other walks' readings
    only (never its own)."""
    from mapfilter.evaluation import comparison
    from mapfilter.sensors.pathloss import AccessPointTable
    from mapfilter.simulate.ilc_writer import write_ilc
    from mapfilter.simulate.walk import SimConfig, simulate_walk

    plan, first, _, first_path = office_walk
    aps = AccessPointTable.read_csv(REPO / "maps" / "office_aps.csv")
    walk = simulate_walk(plan, aps, SimConfig(duration_s=80.0), np.random.default_rng(21))
    plain = tmp_path / "plain.txt"
    write_ilc(walk, plain)
    second_path = tmp_path / "second.txt"
    rows = _beacon_rows(walk, np.random.default_rng(22), noise_db=6.0)
    second_path.write_text(_with_beacons(plain.read_text(), rows))
    second = read_ilc(second_path)
    positions = tmp_path / "positions.csv"
    _office_table(c_dbm=-50.0, n=3.0).write_csv(positions)
    building = Building.from_plan(plan)
    table = BeaconTable.read_csv(positions, building)
    setup = comparison.EvaluationSetup(leave_one_out=True, sources={"ble": table})
    methods = comparison.methods_for(building, {"ble"})
    all_walks = comparison._all_walks(building, setup, methods, [first, second], [0, 0])
    context = comparison._Context(building, setup, methods, (first_path, second_path), all_walks, (0, 0))
    for scored, other in ((first, second), (second, first)):
        got = comparison._walk_sources(context, scored)["ble"]
        assert got.phone_offsets_db == {}  # no phone model named
        alone = fit_beacons(table, labelled_readings(table, building, [other])).table
        np.testing.assert_allclose(got.c_dbm, alone.c_dbm, atol=1e-6)
        np.testing.assert_allclose(got.n, alone.n, atol=1e-6)
        with_own = fit_beacons(table, labelled_readings(table, building, [first, second])).table
        assert np.abs(got.c_dbm - with_own.c_dbm).max() > 0.01  # the walk's own readings would change it


def test_the_fit_finds_each_phones_rssi_offset(office_walk, tmp_path):
    plan, first, walk, _ = office_walk
    building = Building.from_plan(plan)
    low = dataclasses.replace(first, beacons=dataclasses.replace(first.beacons, rssi_dbm=first.beacons.rssi_dbm - 9.0),
                              phone_model="QUIET")
    loud = dataclasses.replace(first, phone_model="LOUD")
    guess = _office_table(c_dbm=-50.0, n=3.0)
    fit = fit_beacons(guess, labelled_readings(guess, building, [loud, low]))
    assert fit.phone_offsets_db["LOUD"] - fit.phone_offsets_db["QUIET"] == pytest.approx(9.0, abs=0.5)
    assert fit.phone_offsets_db["LOUD"] + fit.phone_offsets_db["QUIET"] == pytest.approx(0.0, abs=0.5)  # equal shares
    np.testing.assert_allclose(np.median(fit.table.c_dbm), TRUE_C - 4.5, atol=2.5)
    # the model adds a phone's offset to every beacon's C
    offset = fit.phone_offsets_db["QUIET"]
    frame = StateFrame(building)
    shifted = BeaconLikelihood(fit.table, frame, 25.0, rssi_offset_db=offset)
    moved = BeaconLikelihood(fit.table.with_parameters(fit.table.c_dbm + offset, fit.table.n, fit.table.floor_loss_db),
                             frame, 25.0)
    particles = _particles(np.random.default_rng(8).uniform(0, 38, (500, 2)))
    window = BeaconWindow(0.0, np.array([0, 3, 5]), np.array([-80.0, -70.0, -90.0]))
    np.testing.assert_array_equal(shifted.log_likelihood(particles, window), moved.log_likelihood(particles, window))
    with pytest.raises(MapfilterError, match="rssi_offset_db"):
        TrackingConfig().override({"sources.ble.rssi_offset_db": 55.0})
    # the fitted table carries each phone's offset, and the source applies the log's phone's
    assert {p: v.tolist() for p, v in fit.table.phone_offsets_db.items()} == {
        p: [v] * len(guess) for p, v in fit.phone_offsets_db.items()}
    source = BeaconSource(fit.table, frame, BleConfig(rssi_offset_db=-30.0))
    source.records_of(low)
    assert np.all(source.offset_db == offset) and np.all(source.model.rssi_offset_db == offset)
    other = BeaconSource(fit.table, frame, BleConfig(rssi_offset_db=-30.0))
    other.records_of(dataclasses.replace(low, phone_model="UNKNOWN"))  # no offset for it: the config's
    assert np.all(other.model.rssi_offset_db == -30.0)


def test_the_table_carries_the_phones_offsets_to_track_and_a_replay(office_walk, tmp_path):
    """fit-beacons writes each phone's offset as a column offset_db:MODEL; read back, the BLE
    source applies the log's phone's (the log names it, or the TrackingInputs do, as a competition
    server sends no header), and tracks as the config's offset does."""
    plan, first, _, _ = office_walk
    building = Building.from_plan(plan)
    low = dataclasses.replace(first, beacons=dataclasses.replace(first.beacons, rssi_dbm=first.beacons.rssi_dbm - 9.0),
                              phone_model="QUIET")
    loud = dataclasses.replace(first, phone_model="LOUD")
    guess = _office_table(c_dbm=-50.0, n=3.0)
    table = fit_beacons(guess, labelled_readings(guess, building, [loud, low])).table
    path = tmp_path / "fitted.csv"
    table.write_csv(path)
    header = path.read_text().splitlines()[0]
    assert header.endswith(",offset_db:LOUD,offset_db:QUIET")
    back = BeaconTable.read_csv(path)
    np.testing.assert_allclose(back.phone_offsets_db["QUIET"], table.phone_offsets_db["QUIET"], atol=0.005)
    quiet = float(back.phone_offsets_db["QUIET"][0])
    config = _config()
    by_table = track(plan, low, config=config, sources={"ble": back})
    by_config = track(plan, dataclasses.replace(low, phone_model=None),
                      config=config.override({"sources.ble.rssi_offset_db": quiet}), sources={"ble": back})
    np.testing.assert_array_equal(by_table.causal.xy_m, by_config.causal.xy_m)
    unnamed = Tracker(plan, TrackingInputs(sources={"ble": back}, phone_model="QUIET"), config)
    unnamed.feed(dataclasses.replace(low, phone_model=None))
    unnamed.close()
    np.testing.assert_array_equal(unnamed.causal.xy_m, by_table.causal.xy_m)
    assert BeaconTable.read_csv(_write(tmp_path, "beacon_id,x,y,offset_db:P\nA,1,2,\nB,3,4,-2.5\n")
                                ).phone_offsets_db["P"].tolist() == [0.0, -2.5]
    with pytest.raises(MapfilterError, match="column offset_db is 55, outside"):
        BeaconTable.read_csv(_write(tmp_path, "beacon_id,x,y,offset_db:P\nA,1,2,55\n"))
