"""`mapfilter track` end to end: the bundled example, a real ILC trace, and bad inputs."""

import gzip

import numpy as np
import pytest
from conftest import REPO

from mapfilter.cli import main
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.prepare import import_ilc
from mapfilter.maps.walls import count_wall_crossings
from mapfilter.sensors.ilc import read_ilc
from mapfilter.sensors.radiomap import build_radio_map
from mapfilter.io.tracks import read_track

MAPS = REPO / "maps"
OFFICE = MAPS / "office.yaml"
WALK = MAPS / "office_walk.txt.gz"
RADIOMAP = MAPS / "office_radiomap.npz"


def _errors(track, recording):
    gt = np.column_stack([np.interp(track.t_s, recording.waypoint_t_s, recording.waypoint_xy_m[:, i]) for i in (0, 1)])
    return np.linalg.norm(track.xy_m - gt, axis=1)


def test_bundled_example_tracks_within_a_few_metres(tmp_path, capsys):
    out = tmp_path / "track.csv"
    assert main(["track", str(OFFICE), str(WALK), "--radiomap", str(RADIOMAP), "--particles", "3000",
                 "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "error at" in printed and "wall crossings" in printed
    track = read_track(out)
    recording = read_ilc(WALK)
    assert np.median(_errors(track, recording)) < 3.0
    assert track.std_m is not None and np.all(track.std_m >= 0)


def test_smoothed_track_never_crosses_a_wall_and_tum_parses(tmp_path):
    out = tmp_path / "track.tum"
    assert main(["track", str(OFFICE), str(WALK), "--aps", str(MAPS / "office_fitted_aps.csv"),
                 "--particles", "2000", "--smooth", "--format", "tum", "--out", str(out)]) == 0
    track = read_track(out)
    assert len(track) > 50
    assert count_wall_crossings(FloorPlan.load(OFFICE), track.xy_m) == 0
    assert np.median(_errors(track, read_ilc(WALK))) < 4.0


def test_same_seed_same_track(tmp_path):
    paths = [tmp_path / "a.csv", tmp_path / "b.csv"]
    for path in paths:
        assert main(["track", str(OFFICE), str(WALK), "--radiomap", str(RADIOMAP), "--particles", "500",
                     "--seed", "3", "--out", str(path)]) == 0
    assert paths[0].read_text() == paths[1].read_text()


@pytest.mark.slow
def test_real_ilc_trace_with_a_leave_one_out_radio_map(ilc_site1, tmp_path, capsys):
    floor = ilc_site1 / "F1"
    import_ilc(floor, route="geojson").save(tmp_path / "F1.yaml")
    logs = sorted((floor / "path_data_files").glob("*.txt.gz"))
    test_log, survey = logs[1], logs[:1] + logs[2:]
    build_radio_map([read_ilc(p) for p in survey]).save(tmp_path / "rm.npz")
    out = tmp_path / "track.csv"
    assert main(["track", str(tmp_path / "F1.yaml"), str(test_log), "--radiomap", str(tmp_path / "rm.npz"),
                 "--particles", "5000", "--out", str(out)]) == 0
    recording = read_ilc(test_log)
    track = read_track(out)
    causal = np.searchsorted(track.t_s, recording.waypoint_t_s, side="right") - 1
    have = causal >= 0
    errors = np.linalg.norm(track.xy_m[causal[have]] - recording.waypoint_xy_m[have], axis=1)
    assert np.mean(errors) < 12.0  # KWNN alone is about 6 m on this trace, a lost filter 30+ m


def _run_expect_error(args, capsys, *needles):
    assert main(args) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    for needle in needles:
        assert needle in err
    return err


def test_missing_map_or_log_is_one_line(tmp_path, capsys):
    out = tmp_path / "t.csv"
    _run_expect_error(["track", str(tmp_path / "nope.yaml"), str(WALK), "--radiomap", str(RADIOMAP),
                       "--out", str(out)], capsys, "nope.yaml", "not found")
    _run_expect_error(["track", str(OFFICE), str(tmp_path / "nope.txt"), "--radiomap", str(RADIOMAP),
                       "--out", str(out)], capsys, "nope.txt")
    assert not out.exists()


def test_log_without_wifi_is_one_line(tmp_path, capsys):
    log = tmp_path / "nowifi.txt"
    with gzip.open(WALK, "rt") as handle:
        log.write_text("".join(line for line in handle if "TYPE_WIFI" not in line))
    out = tmp_path / "t.csv"
    _run_expect_error(["track", str(OFFICE), str(log), "--radiomap", str(RADIOMAP), "--out", str(out)], capsys,
                      "nowifi.txt", "WiFi")
    assert not out.exists()


def test_radio_map_sharing_no_access_point_is_one_line(tmp_path, capsys):
    log = tmp_path / "other_aps.txt"
    with gzip.open(WALK, "rt") as handle:
        # same walk, but every BSSID renamed: nothing in common with the radio map
        log.write_text(handle.read().replace("02:00:00:00:00:", "0a:bb:cc:dd:ee:"))
    out = tmp_path / "t.csv"
    _run_expect_error(["track", str(OFFICE), str(log), "--radiomap", str(RADIOMAP), "--out", str(out)], capsys,
                      "other_aps.txt", "shares no access point")
    assert not out.exists()


def test_waypoints_in_walls_warn_but_track(tmp_path, capsys):
    log = tmp_path / "wall_wp.txt"
    with gzip.open(WALK, "rt") as handle:
        lines = handle.readlines()
    first_wp = next(i for i, line in enumerate(lines) if "TYPE_WAYPOINT" in line)
    t = lines[first_wp].split("\t")[0]
    lines[first_wp] = f"{t}\tTYPE_WAYPOINT\t0.05\t0.05\n"  # the map's corner: outer wall
    log.write_text("".join(lines))
    out = tmp_path / "t.csv"
    assert main(["track", str(OFFICE), str(log), "--radiomap", str(RADIOMAP), "--particles", "500",
                 "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "warning" in err and "1 of" in err and "waypoints lie in walls" in err
    assert out.exists()


def _config(**changes):
    import dataclasses

    from mapfilter.config import TrackingConfig

    particles = changes.pop("particles", None)
    config = dataclasses.replace(TrackingConfig(), **changes)
    return config.with_particles(particles) if particles else config


def test_smoothing_does_not_change_the_causal_track():
    from mapfilter.sensors.radiomap import RadioMap
    from mapfilter.pipeline.tracker import track

    recording, radio_map, floorplan = read_ilc(WALK), RadioMap.load(RADIOMAP), FloorPlan.load(OFFICE)
    tracks = [track(floorplan, recording, radio_map, config=_config(particles=500, smooth=smooth, seed=1)).causal
              for smooth in (False, True)]
    np.testing.assert_array_equal(tracks[0].xy_m, tracks[1].xy_m)


def test_whole_walk_track_beats_the_causal_one_and_crosses_no_wall():
    from mapfilter.evaluation.metrics import errors_at_waypoints
    from mapfilter.sensors.radiomap import RadioMap
    from mapfilter.pipeline.tracker import track

    recording, radio_map, floorplan = read_ilc(WALK), RadioMap.load(RADIOMAP), FloorPlan.load(OFFICE)
    result = track(floorplan, recording, radio_map, config=_config(particles=1000, smooth=True, seed=2))
    causal = errors_at_waypoints(result.causal.t_s, result.causal.xy_m, recording.waypoint_t_s,
                                 recording.waypoint_xy_m, causal=True).errors_m
    smoothed = errors_at_waypoints(result.offline.t_s, result.offline.xy_m, recording.waypoint_t_s,
                                   recording.waypoint_xy_m, causal=False)
    # the whole walk covers every waypoint, also those before the first scan
    assert smoothed.missed == 0 and smoothed.errors_m.size == recording.waypoint_t_s.size
    assert smoothed.errors_m.mean() < 0.8 * causal.mean()
    assert count_wall_crossings(floorplan, result.offline.xy_m) == 0
    assert np.all(np.diff(result.offline.t_s) >= 0)
    # the offline track has the documented columns: its spread (the map matching's posterior)
    # and the walker's heading, as the causal one
    assert result.offline.std_m.shape == result.offline.t_s.shape and (result.offline.std_m >= 0).all()
    assert np.isfinite(result.offline.heading_rad).all()
    assert result.runtime_s == result.causal_runtime_s + result.offline_runtime_s


def test_the_offline_track_restarts_the_filter_where_the_whole_walk_puts_the_start():
    """A first fix 35 m off starts the causal filter there; the offline track's second forward
    pass starts half its particles where the whole walk places the start, and stays closer for
    the first minute; the causal track is the first run, as without --smooth."""
    from mapfilter.sensors.radiomap import RadioMap
    from mapfilter.pipeline.offline import RESTART_RADIUS_M
    from mapfilter.pipeline.tracker import prepare_walk, track_prepared

    recording, radio_map, floorplan = read_ilc(WALK), RadioMap.load(RADIOMAP), FloorPlan.load(OFFICE)
    results = {}
    for smooth in (False, True):
        config = _config(particles=1000, smooth=smooth)
        walk = prepare_walk(floorplan, recording, radio_map, config=config)
        wifi = walk.evidence
        first = int(np.argmax(wifi.usable))
        t0 = wifi.scans[first].t_s
        truth0 = np.array([np.interp(t0, recording.waypoint_t_s, recording.waypoint_xy_m[:, i]) for i in (0, 1)])
        free = floorplan.sample_free(2000, np.random.default_rng(0))
        wifi._fix[first] = free[np.argmax(np.linalg.norm(free - truth0, axis=1))]  # noqa: SLF001 - the far side of the office
        results[smooth] = track_prepared(walk, config)
    assert results[False].restarted is None and results[False].offline is None
    result = results[True]
    np.testing.assert_array_equal(result.causal.xy_m, results[False].causal.xy_m)  # the causal track is the first run
    assert np.linalg.norm(result.causal.xy_m[0] - truth0) > 20.0
    early = result.causal.t_s < t0 + 60.0
    assert _errors(result.restarted, recording)[early].mean() < 0.5 * _errors(result.causal, recording)[early].mean()
    assert np.linalg.norm(result.offline.xy_m[0] - truth0) < RESTART_RADIUS_M
    assert count_wall_crossings(floorplan, result.offline.xy_m) == 0


def test_a_map_and_its_one_floor_building_track_alike():
    """A map is the one-floor building: a FloorPlan and the building loaded from its YAML give the
    same causal and offline tracks (no floor column on one floor)."""
    from mapfilter.maps.building import Building
    from mapfilter.sensors.radiomap import RadioMap
    from mapfilter.pipeline.tracker import track

    recording, radio_map, floorplan = read_ilc(WALK), RadioMap.load(RADIOMAP), FloorPlan.load(OFFICE)
    config = _config(particles=500, smooth=True, seed=3)
    plain = track(floorplan, recording, radio_map, config=config)
    built = track(Building.load(OFFICE), recording, radio_map, config=config)
    np.testing.assert_array_equal(plain.causal.xy_m, built.causal.xy_m)
    np.testing.assert_array_equal(plain.offline.xy_m, built.offline.xy_m)
    assert built.offline.floor is None and built.causal.floor is None


def test_kwnn_min_rssi_option_reaches_the_filter(tmp_path, capsys):
    from mapfilter.sensors.radiomap import RadioMap
    from mapfilter.pipeline.tracker import track

    paths = {}
    for value in ("none", "-85", "-60"):
        paths[value] = tmp_path / f"{value}.csv"
        assert main(["track", str(OFFICE), str(WALK), "--radiomap", str(RADIOMAP), "--particles", "2000",
                     "--kwnn-min-rssi", value, "--out", str(paths[value])]) == 0
    tracks = {value: read_track(path) for value, path in paths.items()}
    # the library with the same setting gives the CLI's track; a different floor a different one
    from mapfilter.filter.evidence import WifiConfig

    plain = track(FloorPlan.load(OFFICE), read_ilc(WALK), RadioMap.load(RADIOMAP),
                  config=_config(particles=2000, wifi=WifiConfig(kwnn_min_rssi_dbm=None)))
    np.testing.assert_allclose(tracks["none"].xy_m, plain.causal.xy_m, atol=1e-3)  # CSV: mm
    assert not np.allclose(tracks["-60"].xy_m, tracks["none"].xy_m)
    with pytest.raises(SystemExit) as exit_info:
        main(["track", str(OFFICE), str(WALK), "--radiomap", str(RADIOMAP), "--kwnn-min-rssi", "loud"])
    assert exit_info.value.code == 2 and "dBm value such as -90, or none" in capsys.readouterr().err


def test_progress_runs_to_the_end_once_over_both_filter_runs(tmp_path, monkeypatch):
    """The bar follows the walk's time; with --smooth the second filter run (the offline track's)
    is its second half, so the bar does not sit at 100 % while that run works."""
    import mapfilter.cli.track_cmd as track_cmd

    seen = {}

    for smooth in (False, True):
        values = seen[smooth] = []

        class Recorder:
            def __init__(self, *args, **kwargs):
                pass

            def update_to(self, value, values=values):
                values.append(value)

            def close(self):
                pass

        monkeypatch.setattr(track_cmd, "ProgressBar", Recorder)
        args = ["track", str(OFFICE), str(WALK), "--radiomap", str(RADIOMAP), "--particles", "300",
                "--out", str(tmp_path / "t.csv")]
        assert main(args + (["--smooth"] if smooth else [])) == 0
        assert values and np.all(np.diff(values) >= 0) and values[-1] == 100
    # one update per filter step (and a last one at the end): twice as many steps with --smooth,
    # the first run's within 0-50 %
    one_run, two_runs = seen[False][:-1], seen[True][:-1]
    assert len(two_runs) == 2 * len(one_run)
    assert max(two_runs[:len(one_run)]) == 50 and min(two_runs[len(one_run):]) >= 50


def test_progress_ends_at_100_when_smoothing_has_no_second_run(tmp_path, monkeypatch):
    """--smooth with constant-velocity motion smooths the one filter run (no dead-reckoned shape
    to place, no second run): the run fills the whole bar, which ends at 100 %."""
    import mapfilter.cli.track_cmd as track_cmd

    values = []

    class Recorder:
        def __init__(self, *args, **kwargs):
            pass

        def update_to(self, value):
            values.append(value)

        def close(self):
            pass

    monkeypatch.setattr(track_cmd, "ProgressBar", Recorder)
    assert main(["track", str(OFFICE), str(WALK), "--radiomap", str(RADIOMAP), "--particles", "300", "--smooth",
                 "--motion", "cv", "--out", str(tmp_path / "t.csv")]) == 0
    assert values == sorted(values) and values[-1] == 100 and max(values[:-1]) > 50


def test_a_row_stamped_years_ahead_costs_nothing_and_is_reported(tmp_path, capsys):
    """A WiFi scan stamped three years after the walk: nothing is made for the gap (prediction
    ticks go on for at most ``max_gap_s`` after the last record, as a live tracker waiting for
    the next one would), the filter starts afresh at that scan and the printout names the gap."""
    from mapfilter.sensors.pdr import detect_steps
    from mapfilter.sensors.wifi import scans_of

    with gzip.open(WALK, "rt") as handle:
        lines = handle.readlines()
    last_scan_t = max(line.split("\t")[0] for line in lines if "TYPE_WIFI" in line)
    later = int(last_scan_t) + 3 * 365 * 86400 * 1000
    future = []
    for line in lines:  # the walk's last scan once more, three years on
        fields = line.rstrip("\n").split("\t")
        if "TYPE_WIFI" in line and fields[0] == last_scan_t:
            future.append("\t".join([str(later), *fields[1:-1], str(later)]) + "\n")
    log = tmp_path / "future.txt"
    log.write_text("".join(lines) + "".join(future))
    recording = read_ilc(log)
    n_events = len(scans_of(recording)) + len(detect_steps(recording))
    out = tmp_path / "t.csv"
    for motion in ("pdr", "cv"):
        assert main(["track", str(OFFICE), str(log), "--radiomap", str(RADIOMAP), "--particles", "500",
                     "--motion", motion, "--out", str(out)]) == 0
        printed = capsys.readouterr().out
        assert "gap in the log from" in printed and "the filter started afresh" in printed
        track = read_track(out)
        assert track.t_s[-1] == pytest.approx(later / 1000.0, abs=1e-3)
        # a row per step or scan (cv: a tick a second of the two-minute walk), none for the gap
        assert len(track) < 2 * n_events


def test_plot_draws_the_tracks_truth_and_walls_into_a_png(tmp_path, capsys):
    import cv2

    picture = tmp_path / "track.png"
    assert main(["track", str(OFFICE), str(WALK), "--radiomap", str(RADIOMAP), "--particles", "500", "--smooth",
                 "--plot", str(picture)]) == 0
    assert f"wrote {picture} (picture of the tracks)" in capsys.readouterr().out
    image = cv2.imread(str(picture))
    assert image is not None and min(image.shape[:2]) >= 400
    colours = {tuple(int(c) for c in px) for px in image.reshape(-1, 3)[::7]}
    blue, orange = (180, 119, 31), (14, 127, 255)  # matplotlib's first two line colours (BGR): causal, offline
    assert blue in colours and orange in colours
    assert (image.reshape(-1, 3) == 0).all(axis=1).any()  # the ground truth, in black


@pytest.mark.parametrize("args, needle", [
    (["--plot", "{tmp}/track.jpg"], "must end in .png"),
    (["--plot", "{tmp}/track.png", "--out-dir", "{tmp}/tracks"], "--plot is for one walk"),
])
def test_plot_mistakes_are_one_line(args, needle, tmp_path, capsys):
    assert main(["track", str(OFFICE), str(WALK), "--radiomap", str(RADIOMAP),
                 *[a.format(tmp=tmp_path) for a in args]]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and needle in err
    assert not list(tmp_path.iterdir())


def test_the_summary_names_the_wifi_source_and_a_radio_map_left_unused(tmp_path, capsys):
    """Forgetting --radiomap on the office map tracked with the map's access-point table and said
    nothing; the summary names the source, and the radio map beside the map that was not used."""
    assert main(["track", str(OFFICE), str(WALK), "--particles", "300"]) == 0
    out = capsys.readouterr().out
    assert "WiFi: trilateration from the map's own access-point table" in out and "office_aps.csv (28 APs)" in out
    assert f"not used: the radio map {OFFICE.parent / 'office_radiomap.npz'} beside the map" in out
    assert main(["track", str(OFFICE), str(WALK), "--radiomap", str(RADIOMAP), "--particles", "300"]) == 0
    out = capsys.readouterr().out
    assert f"WiFi: fingerprints of the radio map {RADIOMAP}" in out and "not used" not in out


def test_a_map_without_free_space_is_refused_before_tracking(tmp_path, capsys):
    """Issue 45 friction 5: an all-wall map was tracked with a collapse line per step."""
    office = FloorPlan.load(OFFICE)
    FloorPlan(np.ones(office.shape_px, bool), office.resolution_m, office.origin_m).save(tmp_path / "walls.yaml")
    out = tmp_path / "t.csv"
    _run_expect_error(["track", str(tmp_path / "walls.yaml"), str(WALK), "--radiomap", str(RADIOMAP), "--out", str(out)],
                      capsys, "walls.yaml", "no free space", "map prepare")
    assert not out.exists()


def test_repeated_collapses_are_summarised_in_one_line():
    from types import SimpleNamespace

    from mapfilter.cli.track_cmd import MAX_COLLAPSE_LINES, _collapse_lines

    events = [SimpleNamespace(t_s=100.0 + i, cause="walls" if i % 5 else "measurement", particles_lost=3000,
                              recovery="jitter") for i in range(175)]
    (line,) = _collapse_lines(events, 100.0)
    assert "175 collapses from t=+0.0 s to t=+174.0 s" in line and "walls 140" in line and "measurement 35" in line
    few = _collapse_lines(events[:MAX_COLLAPSE_LINES], 100.0)
    assert len(few) == MAX_COLLAPSE_LINES and few[1].startswith("  collapse at t=+1.0 s (walls")
