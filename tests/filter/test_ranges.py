"""Ranges to known anchors (UWB, WiFi RTT): the plug-in written against the source registry
alone (filter/sources/ranges.py, filter/models/ranges.py, sensors/anchors.py).

The bundled office walk with four anchors in its corners (1.5 m above the phone) and the ranges
its ground truth would have given (tools/simulate_ranges.py: 2 per anchor per second, 0.1 m of
noise): used from ``mf.track``, ``mapfilter track`` (a file and a live stream), ``evaluate`` and
the offline track; fed in pieces; weighed by the kernel as the formula says."""

from __future__ import annotations

import csv
import sys

import numpy as np
import pytest

import mapfilter as mf
from mapfilter.cli import main
from mapfilter.config import TrackingConfig
from mapfilter.errors import MapfilterError
from mapfilter.filter.models.building import FloorStack
from mapfilter.filter.models.frame import StateFrame
from mapfilter.filter.models.ranges import RangeLikelihood, RangeSet
from mapfilter.filter.particles import Particles
from mapfilter.filter.sources.ranges import Ranges, RangesConfig
from mapfilter.sensors.anchors import AnchorTable, read_ranges, simulate_ranges
from mapfilter.sensors.logs import read_log
from tests.conftest import REPO

OFFICE = REPO / "maps" / "office.yaml"
WALK = REPO / "maps" / "office_walk.txt.gz"
RADIO_MAP = REPO / "maps" / "office_radiomap.npz"
ANCHORS = "anchor_id,x,y,height\nA1,3,3,1.5\nA2,35,3,1.5\nA3,3,35,1.5\nA4,35,35,1.5\n"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """(anchors.csv, ranges.csv) of the bundled walk, as tools/simulate_ranges.py writes them."""
    sys.path.insert(0, str(REPO / "tools"))
    import simulate_ranges as tool

    folder = tmp_path_factory.mktemp("ranges")
    anchors, ranges = folder / "anchors.csv", folder / "ranges.csv"
    anchors.write_text(ANCHORS)
    assert tool.main([str(OFFICE), str(WALK), "--anchors", str(anchors), "--out", str(ranges)]) == 0
    return anchors, ranges


def _config(**settings) -> TrackingConfig:
    return TrackingConfig(seed=1).override({"filter.n_particles": 2000, **settings})


def _mean_error(track, walk) -> float:
    """Mean error at the waypoints, as ``track`` and ``evaluate`` score it."""
    from mapfilter.evaluation.scoring import score_track

    score = score_track(mf.load_map(OFFICE), walk, track, None, track.name != "pf-smooth")
    return float(np.mean(score.errors.errors_m))


# ---- the model ----------------------------------------------------------------------------------
def _particles(xy_m: np.ndarray) -> Particles:
    state = np.zeros((6, len(xy_m)))
    state[:2] = np.asarray(xy_m, dtype=np.float64).T
    return Particles(state, np.zeros(len(xy_m)))


def test_the_kernel_is_the_gaussian_of_the_3d_distance_on_one_floor(tmp_path):
    (tmp_path / "a.csv").write_text(ANCHORS)
    building = mf.load_map(OFFICE)
    table = AnchorTable.read_csv(tmp_path / "a.csv", building)
    model = RangeLikelihood(table, StateFrame(building), sigma_m=0.3)
    xy = np.random.default_rng(1).uniform(-5, 45, (5000, 2))
    ranged = RangeSet(0.0, np.array([0, 2, 3]), np.array([10.0, 22.5, 31.0]))
    got = model.log_likelihood(_particles(xy), ranged)
    expected = np.zeros(len(xy))
    for row, r in zip(ranged.anchor, ranged.range_m):
        d = np.sqrt(np.sum((xy - table.xy_m[row]) ** 2, axis=1) + 1.5 ** 2)
        expected -= (r - d) ** 2 / (2 * 0.3 ** 2)
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-9)
    assert got.max() <= model.log_likelihood_peak


def test_in_a_stack_each_particle_ranges_the_anchors_from_its_own_floor(office3, tmp_path):
    building, _ = office3
    names = building.floor_names
    (tmp_path / "a.csv").write_text(f"anchor_id,x,y,floor,height\nA,5,5,{names[0]},1.5\nB,30,30,{names[2]},1.0\n")
    table = AnchorTable.read_csv(tmp_path / "a.csv", building)
    stack = FloorStack(building)
    model = RangeLikelihood(table, StateFrame(building, stack=stack), sigma_m=0.5)
    rng = np.random.default_rng(2)
    floor = rng.integers(0, len(names), 3000)
    local = rng.uniform(1, 37, (3000, 2))
    ranged = RangeSet(0.0, np.array([0, 1]), np.array([4.0, 12.0]))
    got = model.log_likelihood(_particles(stack.to_stack(local, floor)), ranged)
    anchor_xy, anchor_floor = table.building_xy_m(building)
    elevation = np.array([f.elevation_m for f in building.floors])
    walker = np.array([building.floors[f].to_building(p) for f, p in zip(floor, local)])
    expected = np.zeros(len(local))
    for row, r in zip(ranged.anchor, ranged.range_m):
        h = table.height_m[row] + elevation[anchor_floor[row]] - elevation[floor]
        d = np.sqrt(np.sum((walker - anchor_xy[row]) ** 2, axis=1) + h ** 2)
        expected -= (r - d) ** 2 / (2 * 0.5 ** 2)
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-7)


# ---- the files ----------------------------------------------------------------------------------
@pytest.mark.parametrize("name, text, message, line", [
    ("anchors", "id,x,y\nA,1,2\n", "needs an anchor_id column", 1),
    ("anchors", "anchor_id,x,y\nA,1,2\nA,3,4\n", "anchor A is listed twice (lines 2 and 3)", 3),
    ("anchors", "anchor_id,x,y,height\nA,1,2,tall\n", "column height is not a number: 'tall'", 2),
    ("anchors", "anchor_id,x,y\nA,500,2\n", "lies 462 m outside the map", 2),
    ("ranges", "t_s,anchor_id,range_m\n1600000001,Z,3.0\n", "anchor 'Z' is not in the anchor table", 2),
    ("ranges", "t_s,anchor_id,range_m\n1600000001,A1,-3\n", "column range_m is -3, outside", 2),
    ("ranges", "t_s,anchor,range_m\n1,A1,3\n", "needs the columns t_s,anchor_id,range_m", 1),
])
def test_a_bad_file_is_one_line_naming_it(files, tmp_path, capsys, name, text, message, line):
    anchors, ranges = files
    bad = tmp_path / f"bad_{name}.csv"
    bad.write_text(text)
    given = {"anchors": anchors, "ranges": ranges, name: bad}
    out = tmp_path / "t.csv"
    assert main(["track", str(OFFICE), str(WALK), "--anchors", str(given["anchors"]), "--ranges",
                 str(given["ranges"]), "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"mapfilter: error: {bad}:{line}: ") and message in err and "\n" not in err
    assert not out.exists()


def test_anchors_without_ranges_are_refused(files, tmp_path, capsys):
    anchors, _ = files
    assert main(["track", str(OFFICE), str(WALK), "--anchors", str(anchors)]) == 1
    assert "--anchors needs --ranges too (ranges to anchors)" in capsys.readouterr().err


# ---- used from the API, the command line, evaluate and a live stream ------------------------------
def test_mf_track_with_ranges_alone_and_with_the_wifi(files):
    anchors, ranges = files
    walk = read_log(WALK)
    source = {"ranges": {"anchors": anchors, "ranges": ranges}}
    wifi = mf.track(OFFICE, walk, radio_map=RADIO_MAP, config=_config())
    both = mf.track(OFFICE, walk, radio_map=RADIO_MAP, config=_config(), sources=source)
    alone = mf.track(OFFICE, walk, config=_config(), sources=source)
    assert both.n_measurements["ranges"] == alone.n_measurements["ranges"] > 900  # 2 Hz x 4 anchors, 120 s
    errors = {k: _mean_error(r.causal, walk) for k, r in (("wifi", wifi), ("both", both), ("alone", alone))}
    assert errors["both"] < 0.4 < 1.0 < errors["wifi"]  # measured 0.18 m against 1.30 m
    assert errors["alone"] < 0.4
    # the loaded input is taken as well as its files
    loaded = mf.load_sources(source, OFFICE)
    assert isinstance(loaded["ranges"], Ranges)
    again = mf.track(OFFICE, walk, radio_map=RADIO_MAP, config=_config(), sources=loaded)
    np.testing.assert_array_equal(again.causal.xy_m, both.causal.xy_m)


def test_the_offline_track_replays_the_ranges(files):
    """--smooth's second pass weighs the ranges too (replayed on the floor's map): its causal track
    is as good as the ranges make it. The offline track, the dead-reckoned shape placed through
    that pass's smoothed track, gains nothing over the WiFi's (0.57 m either way: the placed
    shape's own drift; docs/accuracy.md)."""
    from mapfilter.maps.walls import count_wall_crossings

    anchors, ranges = files
    walk = read_log(WALK)
    wifi = mf.track(OFFICE, walk, radio_map=RADIO_MAP, config=_config(smooth=True))
    both = mf.track(OFFICE, walk, radio_map=RADIO_MAP, config=_config(smooth=True),
                    sources={"ranges": {"anchors": anchors, "ranges": ranges}})
    assert _mean_error(both.restarted, walk) < 0.4 < 1.0 < _mean_error(wifi.restarted, walk)
    assert _mean_error(both.offline, walk) < _mean_error(wifi.offline, walk) + 0.05
    assert count_wall_crossings(mf.load_map(OFFICE).floors[0].plan, both.offline.xy_m) == 0


def test_only_the_walks_own_ranges_are_weighed(files, tmp_path):
    """A range log of a longer session (ranges before the walk's start and after its end): the
    walk weighs those of its own span, and tracks as with its ranges alone."""
    anchors, ranges = files
    table = AnchorTable.read_csv(anchors)
    log = read_ranges(ranges, table)
    longer = tmp_path / "longer.csv"
    shifted = [log.t_s - 1000.0, log.t_s, log.t_s + 1000.0]
    with longer.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["t_s", "anchor_id", "range_m"])
        for t in shifted:
            writer.writerows([f"{t[i]:.3f}", table.anchor_id[log.anchor[i]], f"{log.range_m[i]:.3f}"]
                             for i in range(len(log)))
    walk = read_log(WALK)
    own = mf.track(OFFICE, walk, config=_config(), sources={"ranges": {"anchors": anchors, "ranges": ranges}})
    session = mf.track(OFFICE, walk, config=_config(), sources={"ranges": {"anchors": anchors, "ranges": longer}})
    np.testing.assert_array_equal(own.causal.xy_m, session.causal.xy_m)


@pytest.mark.slow
def test_evaluate_names_the_ranges_methods(files, tmp_path, capsys):
    anchors, ranges = files
    out = tmp_path / "eval"
    assert main(["evaluate", str(OFFICE), str(WALK), "--radiomap", str(RADIO_MAP), "--anchors", str(anchors),
                 "--ranges", str(ranges), "--methods", "pf,pf+ranges,pf-ranges", "--smooth", "--particles", "2000",
                 "--out", str(out)]) == 0
    with (out / "summary.csv").open() as handle:
        summary = {row["method"]: row for row in csv.DictReader(handle)}
    assert {"pf", "pf-smooth", "pf+ranges", "pf-smooth+ranges", "pf-ranges"} <= set(summary)
    assert float(summary["pf+ranges"]["mean"]) < 0.5 * float(summary["pf"]["mean"])
    assert main(["evaluate", str(OFFICE), str(WALK), "--radiomap", str(RADIO_MAP), "--methods", "pf-ranges",
                 "--out", str(tmp_path / "eval2")]) == 1
    assert "method pf-ranges weighs ranges to anchors: give --anchors ANCHORS.csv --ranges RANGES.csv" in \
        capsys.readouterr().err


def test_the_settings_are_saved_and_reloaded():
    config = TrackingConfig().override({"sources.ranges.range_sigma_m": 0.5})
    assert "  ranges:" in config.to_yaml() and TrackingConfig.from_yaml(config.to_yaml()) == config
    assert config.sources.ranges == RangesConfig(range_sigma_m=0.5)
    with pytest.raises(MapfilterError, match="range_sigma_m"):
        TrackingConfig.from_yaml("sources: {ranges: {range_sigma_m: 0}}")


def test_simulated_ranges_are_the_distances_plus_noise():
    building = mf.load_map(OFFICE)
    table = AnchorTable(["A"], np.array([[10.0, 10.0]]), [None], np.array([2.0]))
    t = np.array([0.0, 100.0])
    xy = np.array([[10.0, 20.0], [10.0, 20.0]])  # standing 10 m from the anchor, 2 m below it
    log = simulate_ranges(table, building, t, xy, 0, np.random.default_rng(0), rate_hz=5.0, sigma_m=0.1)
    assert 400 < len(log) < 600 and np.all(np.diff(log.t_s) >= 0)
    assert abs(np.mean(log.range_m) - np.hypot(10.0, 2.0)) < 0.02 and abs(np.std(log.range_m) - 0.1) < 0.02
