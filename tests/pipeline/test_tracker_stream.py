"""The tracker is causal and streams: a log cut at any time gives the whole log's rows up to the
cut, and records fed in chunks of any size give the rows of the whole log fed at once.

Real walks: 3 ILC site 1 walks (F1 radio map from 30 other walks) and 2 IPIN 2023 walks (one per
phone; the venue's building and a radio map from 6 other logs), plus the bundled office walk."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mapfilter.config import TrackingConfig
from mapfilter.maps.building import Building
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.sensors.logs import read_log
from mapfilter.sensors.radiomap import RadioMap
from mapfilter.sensors.recording import Beacons, Recording, WifiScans
from mapfilter.pipeline.tracker import Tracker, TrackingInputs, track
from tests.conftest import REPO

_STREAMS = (("acc_t_s", ("acc_mps2",)), ("gyro_t_s", ("gyro_radps",)), ("rotvec_t_s", ("rotvec_xyz",)),
            ("magnet_t_s", ("magnet_ut",)), ("pressure_t_s", ("pressure_hpa",)))


def _between(rec: Recording, t0: float, t1: float) -> Recording:
    """The records with t0 < t <= t1 of every sensor (a chunk of the stream)."""
    fields = {}
    for time_name, value_names in _STREAMS:
        t = getattr(rec, time_name)
        keep = (t > t0) & (t <= t1)
        fields[time_name] = t[keep]
        for name in value_names:
            fields[name] = getattr(rec, name)[keep]
    wifi = rec.wifi
    scans = np.flatnonzero((wifi.t_s > t0) & (wifi.t_s <= t1))
    rows = np.isin(wifi.row_scan, scans)
    renumber = np.full(len(wifi), -1)
    renumber[scans] = np.arange(scans.size)
    fields["wifi"] = WifiScans(wifi.t_s[scans], wifi.ap_keys, renumber[wifi.row_scan[rows]], wifi.row_ap[rows],
                               wifi.rssi_dbm[rows], wifi.freq_mhz[rows], wifi.age_s[rows])
    beacons = rec.beacons
    keep = (beacons.t_s > t0) & (beacons.t_s <= t1)
    fields["beacons"] = Beacons(beacons.t_s[keep], [b for b, k in zip(beacons.beacon_id, keep) if k],
                                beacons.rssi_dbm[keep], beacons.distance_m[keep])
    return dataclasses.replace(rec, **fields)


def _span(rec: Recording) -> tuple[float, float]:
    times = np.concatenate([rec.acc_t_s, rec.wifi.t_s])
    return float(times.min()), float(times.max())


def _rows(tracker: Tracker):
    track_ = tracker.causal
    heading = track_.heading_rad if track_.heading_rad is not None else np.zeros(len(track_))
    return track_.t_s, track_.xy_m, track_.std_m, heading


def _run(space, rec, radio_map, config, chunks=None) -> Tracker:
    tracker = Tracker(space, TrackingInputs(radio_map), config=config)
    if chunks is None:
        tracker.feed(rec)
    else:
        bounds = [-np.inf, *chunks, np.inf]
        for t0, t1 in zip(bounds[:-1], bounds[1:]):
            tracker.feed(_between(rec, t0, t1))
    tracker.close()
    return tracker


def _check_causal_and_chunked(space, rec, radio_map, config, rng):
    whole = _rows(_run(space, rec, radio_map, config))
    start, end = _span(rec)
    for share in (0.5, 0.75):
        cut = start + share * (end - start)
        cut_rows = _rows(_run(space, _between(rec, -np.inf, cut), radio_map, config))
        before = whole[0] <= cut
        assert before.sum() == len(cut_rows[0]) > 10
        for a, b in zip(whole, cut_rows):
            np.testing.assert_array_equal(a[before], b)  # to the bit
    # random chunks: from a few records to many seconds
    chunks = np.sort(rng.uniform(start, end, 60))
    chunks = np.concatenate([chunks, start + np.cumsum(rng.exponential(0.05, 40))])
    chunked = _rows(_run(space, rec, radio_map, config, np.sort(chunks)))
    for a, b in zip(whole, chunked):
        np.testing.assert_array_equal(a, b)


def test_the_bundled_walk_is_causal_and_streams():
    space = FloorPlan.load(REPO / "maps" / "office.yaml")
    rec = read_log(REPO / "maps" / "office_walk.txt.gz")
    radio_map = RadioMap.load(REPO / "maps" / "office_radiomap.npz")
    for motion in ("pdr", "cv"):
        config = TrackingConfig(seed=4).override({"motion.model": motion, "filter.n_particles": 2000})
        _check_causal_and_chunked(space, rec, radio_map, config, np.random.default_rng(1))


@pytest.fixture(scope="module")
def ilc_f1_survey(ilc_site1, ilc_f1_plan):
    """(F1's logs, a radio map of F1 from 30 of them: not the first three, which are tracked)."""
    from mapfilter.api import build_radio_map

    logs = sorted((ilc_site1 / "F1" / "path_data_files").glob("*.txt.gz"))
    return logs, build_radio_map(Building.from_plan(ilc_f1_plan), [read_log(p) for p in logs[3:33]])


# the first walk in the fast tier (its live path on real data), the other two in the slow one
@pytest.mark.parametrize("k", [0, pytest.param(1, marks=pytest.mark.slow), pytest.param(2, marks=pytest.mark.slow)])
def test_real_ilc_walks_are_causal_and_stream(ilc_f1_plan, ilc_f1_survey, k):
    logs, radio_map = ilc_f1_survey
    config = TrackingConfig().override({"filter.n_particles": 3000})
    _check_causal_and_chunked(ilc_f1_plan, read_log(logs[k]), radio_map, config, np.random.default_rng(k))


@pytest.mark.slow
def test_real_ipin_walks_are_causal_and_stream(ipin2023, ipin_venue):
    from mapfilter.api import build_radio_map

    building = Building.load(ipin_venue)
    logs = sorted((ipin2023 / "logs").glob("*.txt.gz"))
    walks = [p for p in logs if "Trial01_repetition01" in p.name or "Trial01_repetition03" in p.name]
    survey = [read_log(p, building=building) for p in logs if "Trial02" in p.name or "Trial03_repetition0" in p.name][:6]
    radio_map = build_radio_map(building, survey)
    config = TrackingConfig().override({"filter.n_particles": 3000})
    models = set()
    for k, path in enumerate(walks):
        rec = read_log(path, building=building)
        models.add(rec.phone_model)
        _check_causal_and_chunked(building, rec, radio_map, config, np.random.default_rng(k))
    assert len(models) == 2  # one walk per phone


def test_track_is_the_replay_of_the_stream():
    space = FloorPlan.load(REPO / "maps" / "office.yaml")
    rec = read_log(REPO / "maps" / "office_walk.txt.gz")
    radio_map = RadioMap.load(REPO / "maps" / "office_radiomap.npz")
    config = TrackingConfig(seed=2).override({"filter.n_particles": 1000})
    result = track(space, rec, radio_map, config=config)
    streamed = _run(space, rec, radio_map, config, np.linspace(*_span(rec), 25))
    np.testing.assert_array_equal(result.causal.xy_m, streamed.causal.xy_m)
    np.testing.assert_array_equal(result.causal.t_s, streamed.causal.t_s)


def test_a_live_run_prints_estimates_while_its_log_is_still_being_written(tmp_path):
    """``mapfilter track MAP -``: rows come out before the log's end is written, and the whole
    stream gives the file's track to the byte."""
    import gzip
    import subprocess
    import sys

    lines = gzip.open(REPO / "maps" / "office_walk.txt.gz", "rt").readlines()
    out = tmp_path / "live.csv"
    process = subprocess.Popen([sys.executable, "-m", "mapfilter", "track", "maps/office.yaml", "-", "--radiomap",
                                "maps/office_radiomap.npz", "--particles", "2000", "--out", str(out)],
                               stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=REPO, bufsize=1)
    half = len(lines) // 2
    process.stdin.writelines(lines[:half])
    process.stdin.flush()
    first = process.stdout.readline()  # blocks until the tracker prints: the log is half written
    assert first.startswith("t_s,x_m,y_m")
    row = process.stdout.readline().split(",")
    assert float(row[0]) <= float(lines[half - 1].split("\t")[0]) / 1000.0  # stamped within what was written
    process.stdin.writelines(lines[half:])
    process.stdin.close()
    rest = process.stdout.read()
    assert process.wait(timeout=120) == 0
    from mapfilter.cli import main

    whole = tmp_path / "file.csv"
    assert main(["track", str(REPO / "maps" / "office.yaml"), str(REPO / "maps" / "office_walk.txt.gz"),
                 "--radiomap", str(REPO / "maps" / "office_radiomap.npz"), "--particles", "2000",
                 "--out", str(whole)]) == 0
    assert out.read_bytes() == whole.read_bytes()
    assert len(rest.splitlines()) + 2 == len(whole.read_text().splitlines())
