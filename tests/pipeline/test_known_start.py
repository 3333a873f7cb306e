"""A walk's known start (issue 53, friction 1): ``track --start X,Y[,FLOOR]``, ``evaluate --start``,
``mf.track(..., start=)``, ``mf.evaluate(..., start=)`` and ``Tracker(start=)`` give the filter
where the walk began; a start in a wall, outside the map or on a floor the building lacks is one
line; ``evaluate`` offers dead reckoning from the true start (``pdr-start``)."""

from __future__ import annotations

import dataclasses
import inspect
import json
import io
import sys

import numpy as np
import pytest

import mapfilter as mf
from mapfilter.cli import main
from mapfilter.errors import MapfilterError
from mapfilter.pipeline.tracker import KNOWN_START_RADIUS_M, Tracker, TrackingInputs, WalkStart
from mapfilter.sensors.logs import LogStream
from tests.conftest import REPO

OFFICE = REPO / "maps" / "office.yaml"
WALK = REPO / "maps" / "office_walk.txt.gz"
RADIOMAP = REPO / "maps" / "office_radiomap.npz"
CONFIG = mf.TrackingConfig(seed=2).with_particles(1000)
STEP_M = 1.0  # more than one stride: the first row is the start moved by the first step


@pytest.fixture(scope="module")
def office():
    return mf.load_map(OFFICE), mf.read_log(WALK), mf.load_radio_map(RADIOMAP)


def test_the_filter_starts_at_the_known_start_at_the_first_step(office):
    building, walk, radio_map = office
    truth_xy = walk.waypoint_xy_m[0]
    unknown = mf.track(building, walk, radio_map, config=CONFIG)
    known = mf.track(building, walk, radio_map, config=CONFIG, start=tuple(truth_xy))
    first_scan_s = unknown.causal.t_s[0]
    # the first row: at the first step, before the first usable scan, the start moved by one step
    assert known.causal.t_s[0] < first_scan_s
    assert np.linalg.norm(known.causal.xy_m[0] - truth_xy) < KNOWN_START_RADIUS_M + STEP_M
    # a start the walk never saw (across the office) is where the track begins: the filter uses it
    far = np.array([5.0, 30.0])
    assert building.floors[0].plan.is_free(far[None, :])[0] and np.linalg.norm(far - truth_xy) > 15
    elsewhere = mf.track(building, walk, radio_map, config=CONFIG, start=(float(far[0]), float(far[1])))
    assert np.linalg.norm(elsewhere.causal.xy_m[0] - far) < KNOWN_START_RADIUS_M + STEP_M
    # the known start helps where the unknown one is still looking: the first ten seconds' error
    def early_error(result) -> float:
        first = walk.waypoint_t_s <= walk.waypoint_t_s[0] + 10
        t = walk.waypoint_t_s[first]
        row = np.searchsorted(result.causal.t_s, t, side="right") - 1
        ok = row >= 0
        return float(np.linalg.norm(result.causal.xy_m[row[ok]] - walk.waypoint_xy_m[first][ok], axis=1).mean())

    assert early_error(known) < early_error(unknown)


def test_a_known_start_keeps_the_rows_independent_of_the_chunks(office):
    """A live run with --start: the rows of the walk fed in pieces are those of it fed whole."""
    building, _, radio_map = office
    data = WALK.read_bytes()
    import gzip

    text = gzip.decompress(data)
    rows = []
    for size in (len(text), 5000):
        tracker = Tracker(building, TrackingInputs(radio_map), CONFIG, start=(14.95, 10.25))
        stream = LogStream("walk")
        parts = []
        for lo in range(0, len(text), size):
            parts.append(tracker.feed(stream.feed_bytes(text[lo:lo + size])))
        parts.append(tracker.feed(stream.close()))
        parts.append(tracker.close())
        rows.append(np.concatenate([np.column_stack([p.t_s, p.xy_m]) for p in parts if len(p)]))
    np.testing.assert_array_equal(rows[0], rows[1])


@pytest.mark.parametrize("start, words", [
    ((1.0, 1.0), "is not on the free space of the map"),
    ((-50.0, 3.0), "outside the map"),
    ((14.95, 10.25, "F9"), "the building has no floor 'F9'"),
    ("14.95", "expected X,Y or X,Y,FLOOR"),
    ("a,b", "must be numbers"),
    ((float("nan"), 1.0), "finite"),
])
def test_a_bad_start_is_one_line(office, start, words):
    building, walk, radio_map = office
    with pytest.raises(MapfilterError, match=words) as caught:
        mf.track(building, walk, radio_map, config=CONFIG, start=start)
    assert "\n" not in str(caught.value)


def test_a_start_of_the_wrong_type_names_the_argument(office):
    building, walk, radio_map = office
    for wrong in ([1.0], {"x": 1}, (1.0, 2.0, 3)):
        with pytest.raises(TypeError, match=r"^start: expected \(x, y\)"):
            mf.track(building, walk, radio_map, config=CONFIG, start=wrong)


def test_in_a_building_the_start_names_a_floor_it_has(office3, office3_radio_map, tmp_path):
    building, _ = office3
    plan = building.floors[1].plan
    free = plan.pixel_to_world(np.array([[c + 0.5, r + 0.5] for r, c in zip(*plan.free_pixels)][:1]))[0]
    start = WalkStart((float(free[0]), float(free[1])))
    with pytest.raises(MapfilterError, match="give the start's floor too"):
        start.place(building)
    assert start.place(building, building.floor_names[1])[0] == 1
    with pytest.raises(MapfilterError, match="has no floor 'B7'"):
        WalkStart(start.xy_m, "B7").place(building)
    index, xy = WalkStart(start.xy_m, building.floor_names[1]).place(building)
    assert index == 1 and np.allclose(xy, free)
    # the filter's plan is the building's stack: the start goes on its floor's tile
    tracker = Tracker(building, TrackingInputs(office3_radio_map), CONFIG,
                      start=(start.xy_m[0], start.xy_m[1], building.floor_names[1]))
    placed = tracker.stream._start_at.xy_m
    assert tracker.stack.floor_of(placed[None, :])[0] == 1


def test_one_name_everywhere():
    """track, evaluate, the API and the tracker call it start."""
    for function in (mf.track, mf.evaluate, mf.Tracker):
        assert "start" in inspect.signature(function).parameters, function
    for command in ("track", "evaluate"):
        stdout = io.StringIO()
        with pytest.raises(SystemExit):
            sys.stdout, saved = stdout, sys.stdout
            try:
                main([command, "--help"])
            finally:
                sys.stdout = saved
        text = stdout.getvalue()
        assert "--start X,Y[,FLOOR]" in text, command
    assert "starting position is unknown" not in text.replace("\n", " ")


def test_evaluate_starts_the_pf_methods_there_and_offers_dead_reckoning_from_the_true_start(office):
    building, walk, _ = office
    common = dict(radio_map=RADIOMAP, methods=["pf", "pdr", "pdr-start"], config=CONFIG)
    given = mf.evaluate(building, [walk], start=(5.0, 30.0), **common)
    plain = mf.evaluate(building, [walk], **common)
    first = {r.method: r.track for r in given.results}
    assert np.linalg.norm(first["pf"].xy_m[0] - [5.0, 30.0]) < KNOWN_START_RADIUS_M + STEP_M
    assert {r.method: r.track.xy_m[0].tolist() for r in plain.results}["pf"] != first["pf"].xy_m[0].tolist()
    # pdr-start: from the first waypoint at its time, whatever --start says
    np.testing.assert_allclose(first["pdr-start"].xy_m[0], walk.waypoint_xy_m[0])
    assert first["pdr-start"].t_s[0] == walk.waypoint_t_s[0]
    rows = {row["method"]: row for row in plain.summary_rows()}
    assert rows["pdr-start"]["mean"] < rows["pdr"]["mean"]  # the true start beats the first fix's
    with pytest.raises(MapfilterError, match="not on the free space"):
        mf.evaluate(building, [walk], start=(1.0, 1.0), **common)


def test_the_offline_track_passes_through_a_known_start(office):
    """The known start anchors the offline track's placement (``offline.placement.Anchor``): its
    first row is within the start's radius of it, wherever the fixes would put the shape; without
    a start the placement is by the fixes alone, and the walk's first row follows them."""
    building, walk, radio_map = office
    config = dataclasses.replace(CONFIG, smooth=True)
    far = (5.0, 30.0)  # across the office from the true start: the fixes never put the walk there
    given = mf.track(building, walk, radio_map, config=config, start=far)
    plain = mf.track(building, walk, radio_map, config=config)
    assert given.offline is not None and plain.offline is not None
    assert np.linalg.norm(given.offline.xy_m[0] - far) < KNOWN_START_RADIUS_M + STEP_M
    assert np.linalg.norm(plain.offline.xy_m[0] - far) > 3 * KNOWN_START_RADIUS_M
    truth = tuple(float(v) for v in walk.waypoint_xy_m[0])
    at_truth = mf.track(building, walk, radio_map, config=config, start=truth)
    assert np.linalg.norm(at_truth.offline.xy_m[0] - walk.waypoint_xy_m[0]) < KNOWN_START_RADIUS_M + STEP_M


def test_evaluate_start_truth_starts_each_walk_at_its_first_waypoint(office, tmp_path, capsys):
    """``evaluate --start truth``: each walk's pf methods from its own first waypoint (a
    competition's initial position), named in the summary."""
    building, walk, radio_map = office
    result = mf.evaluate(building, [walk], radio_map=RADIOMAP, methods=["pf"], config=CONFIG, start="truth")
    (pf,) = [r.track for r in result.results if r.method == "pf"]
    assert np.linalg.norm(pf.xy_m[0] - walk.waypoint_xy_m[0]) < KNOWN_START_RADIUS_M + STEP_M
    assert main(["evaluate", str(OFFICE), str(WALK), "--radiomap", str(RADIOMAP), "--methods", "pf",
                 "--particles", "1000", "--start", "truth", "--out", str(tmp_path / "e")]) == 0
    assert json.loads((tmp_path / "e" / "summary.json").read_text())["start"] == "truth"
    assert "the pf methods started at each walk's first waypoint (--start truth)" in capsys.readouterr().out
    # on track, a walk's start is a place: "truth" is not one
    with pytest.raises(MapfilterError, match="X,Y"):
        mf.track(building, walk, radio_map, config=CONFIG, start="truth")
