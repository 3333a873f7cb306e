"""``mapfilter track BUILDING.yaml LOG... --out-dir DIR`` and ``mapfilter view BUILDING.yaml TRACK...``
on a simulated three-floor office: files, floor columns, summary rows, and bad input refused
with one line naming the file and nothing written."""

from __future__ import annotations

import contextlib
import csv
import io
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from mapfilter.io.outputs import MANIFEST
from mapfilter.cli import main
from mapfilter.sensors.ilc import read_ilc
from mapfilter.io.tracks import read_track

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "tools"))
from floor_sim import FLOORS, make_office_building_with_ap_files  # noqa: E402

PARTICLES = ["--particles", "300"]


@pytest.fixture(scope="module")
def office3(tmp_path_factory) -> SimpleNamespace:
    """Three stacked office floors (stairs, lift), a coarse survey per floor in one radio map, and
    two walks that change floor once (walk1: F1 -> F0 by lift, walk2: F2 -> F1 by stairs)."""
    out = tmp_path_factory.mktemp("office3")
    building = make_office_building_with_ap_files(out)
    surveys = [out / f"survey_{name}.txt" for name in FLOORS]
    for name, survey in zip(FLOORS, surveys):
        assert main(["simulate", str(building), "--out", str(survey), "--survey", "--floor", name,
                     "--survey-spacing", "8", "--scans-per-point", "1"]) == 0
    radiomap = out / "rm.npz"
    assert main(["radiomap", "build", str(building), *map(str, surveys), "--out", str(radiomap)]) == 0
    walks = [out / f"walk{seed}.txt" for seed in (1, 2)]
    for seed, walk in zip((1, 2), walks):
        assert main(["simulate", str(building), "--out", str(walk), "--seed", str(seed), "--floor-changes", "1",
                     "--segment-s", "4", "6"]) == 0
    return SimpleNamespace(dir=out, building=building, radiomap=radiomap, walks=walks)


@pytest.fixture(scope="module")
def tracked(office3, tmp_path_factory) -> SimpleNamespace:
    """Both walks tracked with --out-dir (floor found), and what the command printed."""
    out = tmp_path_factory.mktemp("batch") / "tracks"
    printed = io.StringIO()  # capsys is for one test only
    with contextlib.redirect_stdout(printed):
        code = main(["track", str(office3.building), *map(str, office3.walks), "--radiomap", str(office3.radiomap),
                     *PARTICLES, "--out-dir", str(out)])
    return SimpleNamespace(code=code, out=out, stdout=printed.getvalue())


def _summary(out_dir: Path) -> dict[str, dict]:
    with (out_dir / "summary.csv").open() as handle:
        return {row["trace"]: row for row in csv.DictReader(handle)}


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("mapfilter: error: "), err
    return err


# ---- track --out-dir ------------------------------------------------------------------------
def test_out_dir_writes_a_track_with_floors_per_walk_and_a_summary_row_per_walk(office3, tracked):
    assert tracked.code == 0
    assert "2 walks (serial): 2 tracked, 0 failed, 0 crashed" in tracked.stdout
    assert "on the walker's floor at" in tracked.stdout
    assert sorted(p.name for p in tracked.out.iterdir() if p.name != MANIFEST) == ["config.yaml", "summary.csv", "summary.json",
                                                              "walk1.csv", "walk2.csv"]
    rows = _summary(tracked.out)
    assert list(rows) == ["walk1", "walk2"]
    for walk, (start, end) in zip(office3.walks, (("F1", "F0"), ("F2", "F1"))):
        trace = walk.name.split(".")[0]
        track = read_track(tracked.out / f"{trace}.csv")
        recording = read_ilc(walk)
        assert recording.waypoint_floor[0] == start and recording.waypoint_floor[-1] == end
        # every row names a floor of the building; the walk's floor change is in the track
        assert set(track.floor) <= set(FLOORS) and {start, end} <= set(track.floor)
        row = rows[trace]
        assert row["status"] == "ok" and row["track_file"] == f"{trace}.csv"
        assert row["header_floor"] == recording.floor_name == start
        assert row["floors"] == ";".join(sorted(set(track.floor), key=FLOORS.index))
        assert int(row["waypoints"]) > 30 and float(row["floor_accuracy"]) > 0.8
        assert float(row["mean_m"]) < 10.0


def test_a_walk_of_a_batch_is_the_walk_tracked_alone(office3, tracked, tmp_path, capsys):
    single = tmp_path / "walk1.csv"
    assert main(["track", str(office3.building), str(office3.walks[0]), "--radiomap", str(office3.radiomap),
                 *PARTICLES, "--out", str(single)]) == 0
    assert single.read_bytes() == (tracked.out / "walk1.csv").read_bytes()


def test_out_dir_smoothed_tum_tracks_on_a_given_floor(office3, tmp_path, capsys):
    out = tmp_path / "tracks"
    assert main(["track", str(office3.building), *map(str, office3.walks), "--radiomap", str(office3.radiomap),
                 *PARTICLES, "--smooth", "--format", "tum", "--floor", "F1", "--out-dir", str(out)]) == 0
    # the offline track per walk, the causal one beside it (--smooth), and the config that ran
    assert sorted(p.name for p in out.iterdir() if p.name != MANIFEST) == ["config.yaml", "summary.csv", "summary.json", "walk1.causal.tum",
                                                     "walk1.tum", "walk2.causal.tum", "walk2.tum"]
    rows = _summary(out)
    for trace in ("walk1", "walk2"):
        assert len(read_track(out / f"{trace}.tum")) > 30
        # TUM rotations carry the heading (not the identity on every row)
        assert np.ptp(read_track(out / f"{trace}.tum").heading_rad) > 1.0
        assert rows[trace]["floors"] == "F1"  # the floor given
        # judged against the walker's floor at each waypoint: both walks leave or reach F1 half-way
        assert 0.0 < float(rows[trace]["floor_accuracy"]) < 1.0


def test_a_walk_that_fails_is_reported_and_the_others_are_tracked(office3, tmp_path, capsys):
    lines = office3.walks[0].read_text().splitlines(keepends=True)
    no_wifi = tmp_path / "nowifi.txt"
    no_wifi.write_text("".join(line for line in lines if "\tTYPE_WIFI\t" not in line))
    out = tmp_path / "tracks"
    assert main(["track", str(office3.building), str(no_wifi), str(office3.walks[1]), "--radiomap",
                 str(office3.radiomap), *PARTICLES, "--out-dir", str(out)]) == 1
    captured = capsys.readouterr()
    assert "2 walks (serial): 1 tracked, 1 failed" in captured.out
    assert "mapfilter: failed: " in captured.err and str(no_wifi) in captured.err
    rows = _summary(out)
    assert rows["nowifi"]["status"] == "failed" and rows["nowifi"]["track_file"] == ""
    assert rows["walk2"]["status"] == "ok"
    assert sorted(p.name for p in out.iterdir() if p.name != MANIFEST) == ["config.yaml", "summary.csv", "summary.json", "walk2.csv"]


@pytest.mark.parametrize("problem", ["log_floor", "radiomap_without_floors", "floor_option"])
def test_bad_input_is_one_line_naming_the_file_and_nothing_is_written(office3, tmp_path, capsys, problem):
    walks = [str(w) for w in office3.walks]
    radiomap = str(office3.radiomap)
    extra: list[str] = []
    if problem == "log_floor":  # the second log of another building: refused before any walk runs
        bad = tmp_path / "walk_f9.txt"
        bad.write_text(office3.walks[0].read_text().replace("FloorName:F1", "FloorName:F9"))
        walks.append(str(bad))
        named, message = str(bad), "'F9' is not in the building"
    elif problem == "radiomap_without_floors":
        radiomap = str(REPO / "maps" / "office_radiomap.npz")
        named, message = radiomap, "no floor labels"
    else:
        extra = ["--floor", "F9"]
        named, message = str(office3.building), "'F9' is not in the building"
    out = tmp_path / "tracks"
    assert main(["track", str(office3.building), *walks, "--radiomap", radiomap, *PARTICLES, *extra,
                 "--out-dir", str(out)]) == 1
    err = _one_error_line(capsys)
    assert named in err and message in err
    assert not out.exists()


def test_out_dir_on_two_local_workers_writes_the_serial_tracks(office3, tracked, tmp_path, capsys):
    out = tmp_path / "jobs2"
    assert main(["track", str(office3.building), *map(str, office3.walks), "--radiomap", str(office3.radiomap),
                 *PARTICLES, "--jobs", "2", "--out-dir", str(out)]) == 0
    assert "2 walks (2 local worker processes): 2 tracked" in capsys.readouterr().out
    for name in ("walk1.csv", "walk2.csv"):
        assert (out / name).read_bytes() == (tracked.out / name).read_bytes()
    assert _summary(out)["walk1"]["floors"] == _summary(tracked.out)["walk1"]["floors"]


# ---- view -----------------------------------------------------------------------------------
def _entities(rrd: Path) -> dict:
    sys.path.insert(0, str(Path(__file__).parents[1] / "viz"))
    from test_viz import read_rrd, verify

    verify(rrd)
    return read_rrd(rrd)


def _points_per_row(batches) -> list[int]:
    """How many points each logged row of a Points2D entity holds (its static row left out)."""
    counts = []
    for batch in batches:
        if "Points2D:positions" in batch.schema.names and "trace_time" in batch.schema.names:
            counts += [len(v) for v in batch.column("Points2D:positions").to_pylist()]
    return counts


def test_view_draws_every_floor_and_each_track_row_and_waypoint_on_its_floor(office3, tracked, tmp_path, capsys):
    rrd = tmp_path / "view.rrd"
    tracks = [tracked.out / "walk1.csv", tracked.out / "walk2.csv"]
    assert main(["view", str(office3.building), *map(str, tracks), "--log", str(office3.walks[0]),
                 "--rerun", str(rrd)]) == 0
    assert f"wrote {rrd}" in capsys.readouterr().out
    assert rrd.stat().st_size > 0
    entities = _entities(rrd)
    assert not any(e.startswith("/map") for e in entities)  # no single map: a view per floor
    for floor in FLOORS:
        assert f"/floors/{floor}/world/walls/mask" in entities and f"/floors/{floor}/world/floorplan/image" in entities
    for path in tracks:
        track = read_track(path)
        for floor in FLOORS:
            on_floor = sum(f == floor for f in track.floor)
            entity = f"/floors/{floor}/world/tracks/{path.stem}"
            assert (f"{entity}/path" in entities) == (on_floor > 0)
            if on_floor:
                # one row per track row: a point while the track is on this floor, none elsewhere
                counts = _points_per_row(entities[f"{entity}/position"])
                assert len(counts) == len(track) and sum(counts) == on_floor
        assert f"/plots/error_m/{path.stem}" in entities
    # the ground truth of walk1 (F1, then F0 by lift): each waypoint on its own floor
    recording = read_ilc(office3.walks[0])
    for floor in FLOORS:
        n = sum(f == floor for f in recording.waypoint_floor)
        entity = f"/floors/{floor}/world/ground_truth/waypoints"
        assert (entity in entities) == (n > 0)
        if n:
            batch = next(b for b in entities[entity] if "Points2D:positions" in b.schema.names)
            assert len(batch.column("Points2D:positions").to_pylist()[0]) == n


def test_track_smooth_in_a_building_draws_the_smoothed_cloud_on_the_floor_shown(office3, tmp_path):
    """`track --smooth --rerun` in a building (a walk that changes floor): the smoother's cloud at
    every filter step, each on the floor the viewer shows then (never more points than kept)."""
    rrd = tmp_path / "walk1.rrd"
    assert main(["track", str(office3.building), str(office3.walks[0]), "--radiomap", str(office3.radiomap),
                 *PARTICLES, "--smooth", "--rerun", str(rrd)]) == 0
    entities = _entities(rrd)
    counts = _points_per_row(entities["/map/world/smoothed_particles"])
    steps = len(_points_per_row(entities["/map/world/particles"]))
    assert len(counts) == steps + 1 and 0 < max(counts) <= 256
    assert "/map/world/tracks/smoothed/path" in entities


def test_view_puts_a_track_without_floors_on_the_logs_header_floor(office3, tmp_path, capsys):
    """A TUM track has no floor column: it is drawn on the floor the log's header names."""
    out = tmp_path / "tracks"
    assert main(["track", str(office3.building), str(office3.walks[1]), "--radiomap", str(office3.radiomap),
                 *PARTICLES, "--format", "tum", "--out", str(out / "walk2.tum")]) == 0
    rrd = tmp_path / "view.rrd"
    assert main(["view", str(office3.building), str(out / "walk2.tum"), "--log", str(office3.walks[1]),
                 "--rerun", str(rrd)]) == 0
    entities = _entities(rrd)
    assert [f for f in FLOORS if f"/floors/{f}/world/tracks/walk2/path" in entities] == ["F2"]


@pytest.mark.parametrize("problem", ["track_floor", "no_floor_no_log", "log_floor"])
def test_view_bad_input_is_one_line_naming_the_file_and_writes_nothing(office3, tracked, tmp_path, capsys, problem):
    track = tmp_path / "walk.csv"
    lines = (tracked.out / "walk1.csv").read_text().splitlines(keepends=True)
    track.write_text("".join(lines))
    extra = ["--log", str(office3.walks[0])]
    if problem == "track_floor":  # the third row (line 4) on a floor the building does not have
        header = lines[0].strip().split(",")
        fields = lines[3].strip().split(",")
        fields[header.index("floor")] = "F9"
        lines[3] = ",".join(fields) + "\n"
        track.write_text("".join(lines))
        named, message = f"{track}:4", "'F9' is not in the building"
    elif problem == "no_floor_no_log":
        track.write_text("t_s,x_m,y_m\n1.0,20.0,8.5\n2.0,21.0,8.5\n")
        extra = []
        named, message = str(track), "no floor column"
    else:
        bad = tmp_path / "walk_f9.txt"
        bad.write_text(office3.walks[0].read_text().replace("FloorName:F1", "FloorName:F9"))
        extra = ["--log", str(bad)]
        named, message = str(bad), "'F9' is not in the building"
    rrd = tmp_path / "view.rrd"
    assert main(["view", str(office3.building), str(track), *extra, "--rerun", str(rrd)]) == 1
    err = _one_error_line(capsys)
    assert named in err and message in err
    assert not rrd.exists() and not list(tmp_path.glob("*.rrd"))


def test_view_of_a_one_floor_map_ignores_a_floor_column(tracked, tmp_path, capsys):
    """A one-floor map draws as it always did (under map/world), whatever the track's floor says."""
    rrd = tmp_path / "view.rrd"
    assert main(["view", str(REPO / "maps" / "office.yaml"), str(tracked.out / "walk1.csv"), "--rerun",
                 str(rrd)]) == 0
    entities = _entities(rrd)
    assert "/map/world/walls/mask" in entities and "/map/world/tracks/walk1/path" in entities
    assert not any(e.startswith("/floors") for e in entities)
    counts = _points_per_row(entities["/map/world/tracks/walk1/position"])
    assert len(counts) == len(read_track(tracked.out / "walk1.csv")) and set(counts) == {1}


def test_smooth_in_a_building_smooths_the_floor_with_the_track(office3, tmp_path):
    """--smooth in a building: the smoother over the filter's own run, a floor per row with its
    posterior share, for a walk that changes floor; a walk the smoother keeps on F1 is tracked
    offline as on F1's map (a second forward pass there); the causal track is the same as
    without --smooth."""
    import numpy as np

    from mapfilter.pipeline.tracker import track
    from mapfilter.maps.building import Building
    from mapfilter.maps.walls import count_wall_crossings
    from mapfilter.sensors.radiomap import RadioMap
    from conftest import tracking_config

    one_floor = tmp_path / "walk_f1.txt"
    assert main(["simulate", str(office3.building), "--out", str(one_floor), "--seed", "3", "--floor-changes", "0",
                 "--start-floor", "F1"]) == 0
    building, radio_map = Building.load(office3.building), RadioMap.load(office3.radiomap)
    runs = {smooth: track(building, read_ilc(one_floor), radio_map,
                          config=tracking_config(n_particles=500, smooth=smooth), rng=np.random.default_rng(0))
            for smooth in (False, True)}
    np.testing.assert_array_equal(runs[True].causal.xy_m, runs[False].causal.xy_m)
    smoothed = runs[True].offline
    assert set(runs[True].restarted.floor) == set(smoothed.floor) == {"F1"}
    # the smoother's floor probability goes with the one-floor track
    assert smoothed.floor_p is not None and np.all((smoothed.floor_p >= 0) & (smoothed.floor_p <= 1))
    assert count_wall_crossings(building.floors[building.floor_index("F1")].plan, smoothed.xy_m) == 0
    changes_floor = track(building, read_ilc(office3.walks[0]), radio_map,
                          config=tracking_config(n_particles=2000, smooth=True), rng=np.random.default_rng(0))
    offline = changes_floor.offline
    assert changes_floor.restarted is None and len(set(offline.floor)) == 2
    assert offline.floor_p is not None and np.all((offline.floor_p >= 0) & (offline.floor_p <= 1))
    assert np.median(offline.floor_p) > 0.9


def test_evaluate_a_building_with_survey_walks(office3, tmp_path, capsys):
    """Survey logs (not leave-one-out) in a building: the survey alone makes the radio map."""
    surveys = [str(office3.dir / f"survey_{name}.txt") for name in FLOORS]
    assert main(["evaluate", str(office3.building), *map(str, office3.walks), "--survey", *surveys,
                 "--methods", "kwnn", "--out", str(tmp_path / "r")]) == 0, capsys.readouterr().err
    with (tmp_path / "r" / "summary.csv").open() as handle:
        (row,) = list(csv.DictReader(handle))
    assert row["method"] == "kwnn" and int(row["n"]) > 10 and 0.0 <= float(row["floor_detection"]) <= 1.0
