"""`mapfilter check LOG --truth GT.csv|GT.tum [--at TRACK]`: a log's ground truth as a track
file, so that a track and its truth go into trajectory tools (evo pairs rows by time)."""

import numpy as np
import pytest
from conftest import REPO

from mapfilter.cli import main
from mapfilter.sensors.logs import read_log
from mapfilter.io.tracks import read_track

MAPS = REPO / "maps"
WALK = MAPS / "office_walk.txt.gz"


def test_truth_as_tum_and_csv_is_the_waypoints(tmp_path, capsys):
    recording = read_log(WALK)
    for name in ("gt.tum", "gt.csv"):
        assert main(["check", str(WALK), "--truth", str(tmp_path / name)]) == 0
        truth = read_track(tmp_path / name)
        np.testing.assert_allclose(truth.t_s, recording.waypoint_t_s, atol=1e-3)
        np.testing.assert_allclose(truth.xy_m, recording.waypoint_xy_m, atol=1e-3)
    assert f"wrote {tmp_path / 'gt.csv'}: the ground truth of office_walk, {recording.waypoint_t_s.size} rows" in (
        capsys.readouterr().out)
    assert read_track(tmp_path / "gt.csv").floor == ["office"] * recording.waypoint_t_s.size


def test_truth_at_a_tracks_times_pairs_every_row(tmp_path, capsys):
    track_path = tmp_path / "track.tum"
    assert main(["track", str(MAPS / "office.yaml"), str(WALK), "--radiomap", str(MAPS / "office_radiomap.npz"),
                 "--particles", "300", "--out", str(track_path)]) == 0
    assert main(["check", str(WALK), "--truth", str(tmp_path / "gt.tum"), "--at", str(track_path)]) == 0
    track, truth = read_track(track_path), read_track(tmp_path / "gt.tum")
    recording = read_log(WALK)
    inside = (track.t_s >= recording.waypoint_t_s[0]) & (track.t_s <= recording.waypoint_t_s[-1])
    assert inside.sum() > 100
    np.testing.assert_allclose(truth.t_s, track.t_s[inside], atol=1e-5)  # evo pairs every row
    expected = np.column_stack([np.interp(truth.t_s, recording.waypoint_t_s, recording.waypoint_xy_m[:, i])
                                for i in (0, 1)])
    np.testing.assert_allclose(truth.xy_m, expected, atol=1e-3)


@pytest.mark.parametrize("args, needle", [
    ([str(WALK), "--truth", "{tmp}/gt.tum"], "--truth writes one log's ground truth: 2 logs given"),
    (["--at", "{tmp}/track.tum"], "--at is for --truth"),
    (["--truth", "{tmp}/gt.tum", "--at", "{tmp}/none.tum"], "none.tum: file not found"),
    (["--truth", str(WALK)], "--truth: is an input of this run"),
])
def test_truth_mistakes_are_one_line(args, needle, tmp_path, capsys):
    assert main(["check", str(WALK), *[a.format(tmp=tmp_path) for a in args]]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and needle in err, err
    assert not (tmp_path / "gt.tum").exists()


def test_truth_never_writes_over_the_at_track_the_map_or_its_image(tmp_path, capsys):
    """The output policy: --truth is refused in one line, before any work, when it is the --at
    track, the --map YAML or the image that map names; each is left byte-identical."""
    import shutil

    for name in ("office.yaml", "office.png"):
        shutil.copy(MAPS / name, tmp_path / name)
    track = tmp_path / "track.csv"
    track.write_text("t_s,x_m,y_m\n1600000000.0,1.0,2.0\n")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    for truth in (track, tmp_path / "office.yaml", tmp_path / "office.png"):
        code = main(["check", str(WALK), "--map", str(tmp_path / "office.yaml"), "--truth", str(truth), "--at",
                     str(track)])
        captured = capsys.readouterr()
        assert code == 1 and captured.out == "", captured.out  # refused before the log is read
        err = captured.err.strip()
        assert len(err.splitlines()) == 1 and f"{truth}: --truth: is an input of this run" in err, err
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_latlon_truth_needs_a_georeferenced_map_and_is_placed_by_it(ipin2023, ipin_venue, tmp_path, capsys):
    log = ipin2023 / "logs" / "IPIN2023_T3_TrainingTrial52_repetition01.txt.gz"
    assert main(["check", str(log), "--truth", str(tmp_path / "gt.csv")]) == 1
    err = capsys.readouterr().err
    assert "its ground truth is latitude/longitude (POSI rows): give --map BUILDING.yaml" in err
    assert not (tmp_path / "gt.csv").exists()
    assert main(["check", str(log), "--map", str(ipin_venue), "--truth", str(tmp_path / "gt.csv")]) == 0
    truth = read_track(tmp_path / "gt.csv")
    recording = read_log(log)
    assert truth.floor == list(recording.waypoint_floor) and {"0", "-2"} <= set(truth.floor)
    np.testing.assert_allclose(truth.latlon_deg, recording.waypoint_latlon_deg, atol=1e-7)  # metres and back
