"""The EvaalAPI client's pieces without a server or real data: the state line, floor numbers, the
estimates files, the competition's times and score, the commands' errors
(tests/evaal/test_evaal_server.py: the real server and the IPIN 2023 logs)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mapfilter.errors import MapfilterError
from mapfilter.evaal.client import EvaalClient
from mapfilter.evaal.protocol import (Estimates, TrialState, competition_times, floor_number, offline_estimates,
                                      read_estimates, score_estimates)
from mapfilter.maps.georef import LocalFrame
from mapfilter.io.tracks import Track
from tests.conftest import REPO


# ---- the state line ---------------------------------------------------------------------------------
def test_state_lines_as_the_api_documents_them():
    online = TrialState.parse("0.000,-1.000,3.000,15.000,0.000,0.000,0.000,11.1,49.4,0\n")
    assert not online.started and not online.finished and not online.offline and online.position == "11.1,49.4,0"
    offline = TrialState.parse("0.000,-2.000,0.000,60.000,0.000,0.000,0.000,10.422057;43.718278;1")
    assert offline.offline and not offline.started and offline.position == "10.422057;43.718278;1"
    running = TrialState.parse("1.553,16.463,3.000,15.000,1795671027.3,0.500,1.053,11.1,49.4,0")
    assert running.started and not running.finished and running.trial_s == 1.553 and running.slack_s == 15.0
    done = TrialState.parse("-1.000,0.000,3.000,15.000,1795671027.3,0.500,232.053,11.1,49.4,0")
    assert done.finished and done.started and not done.timed_out
    late = TrialState.parse("-1.000,-0.569,3.000,15.000,1795671027.3,0.500,1.053,11.1,49.4,0")
    assert late.timed_out


@pytest.mark.parametrize("text", ["", "Trial does not exist", "1,2,3,4,5,6,pos", "1,2,3,4,5,6,x,pos",
                                  "nan,2,3,4,5,6,7,pos", "<html>404</html>"])
def test_a_reply_that_is_no_state_line_is_refused(text):
    with pytest.raises(MapfilterError, match="not a trial state"):
        TrialState.parse(text)


# ---- floors and positions ---------------------------------------------------------------------------
def test_floor_numbers():
    assert [floor_number(n) for n in ("-2", "-1", "0", "00", "3", "+1")] == [-2, -1, 0, 0, 3, 1]
    assert [floor_number(n) for n in ("F1", "F3", "B1", "G")] == [0, 2, -1, 0]
    with pytest.raises(MapfilterError, match="'lobby' has no floor number"):
        floor_number("lobby")


# ---- estimates files ----------------------------------------------------------------------------------
def _estimates():
    return Estimates(np.array([0.0527, 0.5527, 61.423]), np.array([11.1109644, 11.1109650, 11.1110]),
                     np.array([49.4613164, 49.4613160, 49.4612]), np.array([0, 0, -2]))


def test_estimates_are_written_as_the_server_takes_them_and_read_back(tmp_path):
    path = tmp_path / "est.csv"
    _estimates().write(path)
    lines = path.read_text().splitlines()
    assert lines[0] == "0.053,11.110964400,49.461316400,0"  # pts to the ms, no header: the file can be posted
    assert lines[2].endswith(",-2")
    back = read_estimates(path)
    np.testing.assert_allclose(back.t_s, [0.053, 0.553, 61.423])
    np.testing.assert_allclose(back.lon_deg, _estimates().lon_deg, atol=1e-9)
    assert back.floor.tolist() == [0, 0, -2]


def test_the_servers_own_list_is_read(tmp_path):
    path = tmp_path / "server.csv"
    path.write_text("pts,c,h,s,pos\n0.053,0.000,0.000,15.000,11.110964442580,49.461316433032,0\n"
                    "0.553,1795680817.588,0.500,14.981,11.110964443,49.461316433,-1\n")
    est = read_estimates(path)
    assert est.t_s.tolist() == [0.053, 0.553] and est.floor.tolist() == [0, -1]


@pytest.mark.parametrize("text, message", [
    ("", "no estimates"),
    ("0.5,11.1,49.4\n", ":1: .*4 comma-separated fields"),
    ("0.5,11.1,49.4,0\n0.4,11.1,49.4,0\n", ":2: .*time goes back"),
    ("x,11.1,49.4,0\n", ":1: .*not a number"),
    ("0.5,11.1,49.4,ground\n", ":1: .*longitude,latitude,floor"),
    ("0.5,200,49.4,0\n", ":1: .*longitude,latitude,floor"),
    ("0.5,11.1,49.4,0.5\n", ":1: .*whole floor number"),
    ("inf,11.1,49.4,0\n", ":1: .*not finite"),
    ("pts,c,h,s,pos\n0.5,11.1,49.4,0\n", ":2: .*7 comma-separated fields"),
])
def test_bad_estimates_files_are_refused_with_the_line(tmp_path, text, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(MapfilterError, match=message) as error:
        read_estimates(path)
    assert str(path) in str(error.value)


def test_a_missing_estimates_file_is_named(tmp_path):
    with pytest.raises(MapfilterError, match="file not found"):
        read_estimates(tmp_path / "none.csv")


# ---- the competition's times and score ------------------------------------------------------------
def test_offline_times_are_every_half_second_and_each_posi_time_not_after_it():
    times = competition_times(0.0527, 2.0, np.array([1.0001, 1.05019999, 0.5527]))
    # the grid from the first line (to the ms, as the server keeps times) and the POSI times rounded down
    assert times.tolist() == [0.053, 0.552, 0.553, 1.0, 1.05, 1.053, 1.553]
    assert competition_times(3.0, 3.0).tolist() == [3.0]
    with pytest.raises(ValueError):
        competition_times(2.0, 1.0)


def test_the_score_takes_the_latest_estimate_at_or_before_each_point_and_adds_15_m_per_floor():
    frame = LocalFrame(49.4612, 11.1111)
    posi_xy = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [30.0, 0.0]])
    posi_latlon = frame.to_latlon_deg(posi_xy)
    est_xy = posi_xy + np.array([[3.0, 4.0], [0.0, 1.0], [0.0, 2.0], [6.0, 8.0]])  # 5, 1, 2, 10 m off
    est_latlon = frame.to_latlon_deg(est_xy)
    est = Estimates(np.array([10.0, 20.0, 30.0, 40.0]), est_latlon[:, 1], est_latlon[:, 0], np.array([0, 0, -2, 0]))
    # the points at 5 s (before any estimate), 10 s, 20 s and 1 ms before the last estimate
    score = score_estimates(est, np.array([5.0, 10.0, 20.0, 39.999]), posi_latlon, ["0", "0", "0", "0"])
    assert score.missed == 1 and score.n_points == 4
    # points 1-3 get estimates 0-2 (the one at 40 s is after the last point)
    expected = np.linalg.norm(est_xy[:3] - posi_xy[1:], axis=1)
    np.testing.assert_allclose(score.errors_m, expected, atol=1e-3)
    assert score.floors_off.tolist() == [0, 0, 2]
    np.testing.assert_allclose(score.score_m, np.percentile(expected + [0, 0, 30], 75), atol=1e-3)
    assert math.isclose(score.floor_accuracy, 2 / 3)


def test_scoring_needs_posi_points():
    with pytest.raises(MapfilterError, match="no POSI points"):
        score_estimates(_estimates(), np.zeros(0), np.zeros((0, 2)), [])


def test_offline_estimates_interpolate_the_track_and_take_the_nearest_rows_floor():
    from mapfilter.maps.building import Building
    from mapfilter.maps.floorplan import FloorPlan

    plan = FloorPlan(np.zeros((100, 100), dtype=bool), 0.5, (0.0, 0.0), "0")
    building = Building.from_plan(plan)
    building = Building(building.floors, georeference=LocalFrame(49.4612, 11.1111))
    track = Track(np.array([100.0, 101.0, 103.0]), np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 4.0]]),
                  floor=["0", "0", "0"])
    est = offline_estimates(track, building, np.array([0.0, 0.5, 2.0, 9.0]), offset_s=100.0)
    xy = LocalFrame(49.4612, 11.1111).to_xy_m(np.column_stack([est.lat_deg, est.lon_deg]))
    np.testing.assert_allclose(xy, [[0, 0], [1, 0], [2, 2], [2, 4]], atol=1e-6)  # clamped at the ends
    assert est.floor.tolist() == [0, 0, 0, 0]


# ---- the client's errors --------------------------------------------------------------------------
@pytest.mark.parametrize("url, trial, message", [
    ("ftp://host/evaalapi/", "t", "server URL"), ("127.0.0.1:5000", "t", "server URL"),
    ("http://127.0.0.1/evaalapi/", "a/b", "trial name"), ("http://127.0.0.1/evaalapi/", "", "trial name")])
def test_bad_server_urls_and_trial_names_are_refused(url, trial, message):
    with pytest.raises(MapfilterError, match=message):
        EvaalClient(url, trial)


def _free_port() -> int:
    import socket

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def test_no_server_is_one_line_after_the_retries():
    client = EvaalClient(f"http://127.0.0.1:{_free_port()}/evaalapi/", "t", timeout_s=1.0, retry_s=0.5,
                         sleep=lambda s: None)
    with pytest.raises(MapfilterError, match="no answer from .*/t/state.*run the command again"):
        client.state()
    assert client.dropped >= 1  # it did try again


def _georeferenced_office(tmp_path):
    """The bundled office as a georeferenced building with floor '0'."""
    (tmp_path / "venue.yaml").write_text(
        f"floors:\n- name: '0'\n  map: {REPO / 'maps' / 'office.yaml'}\n  elevation_m: 0.0\n"
        "georeference:\n  origin_lat_deg: 49.46\n  origin_lon_deg: 11.11\n")
    return tmp_path / "venue.yaml"


def test_the_command_refuses_a_map_without_georeference_and_names_it(tmp_path, capsys):
    from mapfilter.cli import main

    code = main(["evaal", "http://127.0.0.1:9/evaalapi/", "t", str(REPO / "maps" / "office.yaml"), "--radiomap",
                 str(REPO / "maps" / "office_radiomap.npz"), "--out", str(tmp_path / "e.csv")])
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1 and "office.yaml" in err and "georeference" in err


def test_the_command_says_when_there_is_no_server(tmp_path, capsys):
    from mapfilter.cli import main

    code = main(["evaal", f"http://127.0.0.1:{_free_port()}/evaalapi/", "t", str(_georeferenced_office(tmp_path)),
                 "--radiomap", str(REPO / "maps" / "office_radiomap.npz"), "--retry", "0",
                 "--out", str(tmp_path / "e.csv")])
    err = capsys.readouterr().err
    assert code == 1 and "no answer from" in err and err.strip().count("\n") == 0
    assert not (tmp_path / "e.csv").exists()


def test_the_command_reads_the_beacon_table_before_the_server(tmp_path, capsys):
    """--beacons: a bad table is refused in one line naming it, before any request; the beacons
    alone (no --radiomap) are a source too."""
    from mapfilter.cli import main

    venue = str(_georeferenced_office(tmp_path))
    table = tmp_path / "beacons.csv"
    table.write_text("beacon_id,x,y\nAA:BB,1.0\n")
    code = main(["evaal", "http://127.0.0.1:9/evaalapi/", "t", venue, "--beacons", str(table),
                 "--out", str(tmp_path / "e.csv")])
    err = capsys.readouterr().err
    assert code == 1 and "beacons.csv" in err and err.strip().count("\n") == 0
    assert main(["evaal", "http://127.0.0.1:9/evaalapi/", "t", venue, "--beacons", venue]) == 1
    assert "venue.yaml" in capsys.readouterr().err  # a table that is the map: refused, nothing sent
    from mapfilter.cli import build_parser

    args = build_parser().parse_args(["evaal", "http://h/evaalapi/", "t", venue, "--beacons", "b.csv", "--phone",
                                      "SM-A520F"])
    assert args.phone == "SM-A520F"  # the trial's phone: the server sends no header to name it


def test_the_command_refuses_smooth_online_and_a_trial_name_without_a_file_name(tmp_path, capsys):
    from mapfilter.cli import main

    venue = str(_georeferenced_office(tmp_path))
    rm = str(REPO / "maps" / "office_radiomap.npz")
    assert main(["evaal", "http://127.0.0.1:9/evaalapi/", "t", venue, "--radiomap", rm, "--smooth"]) == 1
    assert "--smooth needs the whole walk" in capsys.readouterr().err
    assert main(["evaal", "http://127.0.0.1:9/evaalapi/", "..", venue, "--radiomap", rm]) == 1
    assert "give --out" in capsys.readouterr().err
    assert main(["evaal", "http://127.0.0.1:9/evaalapi/", "t", venue, "--radiomap", rm, "--out", venue]) == 1
    assert "venue.yaml" in capsys.readouterr().err  # never over an input


def test_score_and_evaal_out_refuse_other_inputs(tmp_path, capsys):
    from mapfilter.cli import main

    est = tmp_path / "e.csv"
    _estimates().write(est)
    # the bundled walk is an ILC trace: it has no POSI points
    assert main(["score", str(REPO / "maps" / "office_walk.txt.gz"), str(est)]) == 1
    assert "no POSI points" in capsys.readouterr().err
    # --evaal-out needs a georeferenced map, before any tracking
    assert main(["track", str(REPO / "maps" / "office.yaml"), str(REPO / "maps" / "office_walk.txt.gz"),
                 "--radiomap", str(REPO / "maps" / "office_radiomap.npz"), "--evaal-out", str(tmp_path / "x.csv")]) == 1
    assert "georeference" in capsys.readouterr().err and not (tmp_path / "x.csv").exists()
    # and a GetSensorData log: the competition's logs
    assert main(["track", str(_georeferenced_office(tmp_path)), str(REPO / "maps" / "office_walk.txt.gz"),
                 "--radiomap", str(REPO / "maps" / "office_radiomap.npz"), "--floor", "0",
                 "--evaal-out", str(tmp_path / "x.csv")]) == 1
    assert "GetSensorData" in capsys.readouterr().err and not (tmp_path / "x.csv").exists()


# ---- bad inputs of score and --evaal-out (issue 45) -----------------------------------------------
LOG01 = "IPIN2023_T3_TrainingTrial01_repetition01.txt.gz"


def _posi_estimates(log, path, swapped: bool = False):
    """The log's own POSI points as an estimates file (latitude and longitude swapped if asked)."""
    from mapfilter.evaal.protocol import log_clock_s
    from mapfilter.sensors.logs import read_log

    recording = read_log(log)
    latlon = recording.waypoint_latlon_deg
    lon, lat = (latlon[:, 0], latlon[:, 1]) if swapped else (latlon[:, 1], latlon[:, 0])
    t_s = np.floor(log_clock_s(recording.waypoint_t_s, recording) * 1000.0 + 1e-6) / 1000.0  # kept to the ms
    Estimates(t_s, lon, lat,
              np.array([floor_number(f) for f in recording.waypoint_floor])).write(path)
    return path


def test_score_names_latitude_and_longitude_swapped(ipin2023, tmp_path, capsys):
    from mapfilter.cli import main

    log = ipin2023 / "logs" / LOG01
    assert main(["score", str(log), str(_posi_estimates(log, tmp_path / "right.csv"))]) == 0
    captured = capsys.readouterr()
    assert "IPIN score 0.00 m" in captured.out and "warning" not in captured.err
    swapped = _posi_estimates(log, tmp_path / "swapped.csv", swapped=True)
    assert main(["score", str(log), str(swapped)]) == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{swapped}: the estimates lie " in err
    assert "and 0.0 m with latitude and longitude swapped: the file has them swapped" in err


def test_score_refuses_more_estimates_than_a_trial_holds(tmp_path, monkeypatch):
    from mapfilter.evaal import protocol

    monkeypatch.setattr(protocol, "MAX_ESTIMATES", 10)
    path = tmp_path / "many.csv"
    path.write_text("".join(f"{i}.0,11.1,49.4,0\n" for i in range(11)))
    with pytest.raises(MapfilterError, match="more than 10 estimates") as error:
        read_estimates(path)
    assert str(error.value).startswith(f"{path}:11: ")


def _without_posi(log, path, seconds: float = 8.0):
    """The log's header and first seconds, without its POSI rows (as a scoring trial's log)."""
    import gzip

    with gzip.open(log, "rt") as source, open(path, "w") as target:
        for line in source:
            fields = line.split(";")
            if len(fields) > 1 and fields[1].replace(".", "", 1).isdigit() and float(fields[1]) >= seconds:
                break
            if not line.startswith("POSI;"):
                target.write(line)
    return path


def test_evaal_out_on_a_log_without_posi_names_evaal_start(ipin2023, ipin_venue, tmp_path, capsys):
    """Online --evaal-out needs the trial's initial position: without a POSI row, the one line
    names --evaal-start, before any tracking; with it, the replay starts there."""
    from mapfilter.cli import main
    from mapfilter.config import TrackingConfig
    from mapfilter.evaal.replay import replay_online
    from mapfilter.maps.building import Building
    from mapfilter.pipeline.tracker import Tracker, TrackingInputs
    from mapfilter.sensors.logs import read_log
    from mapfilter.api import build_radio_map

    venue = ipin_venue
    log = _without_posi(ipin2023 / "logs" / LOG01, tmp_path / "no_posi.txt")
    capsys.readouterr()
    assert main(["track", str(venue), str(log), "--floor", "0", "--evaal-out", str(tmp_path / "e.csv")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{log}: the log has no POSI point" in err and "--evaal-start LON,LAT,FLOOR" in err
    assert not (tmp_path / "e.csv").exists()
    assert main(["track", str(venue), str(log), "--floor", "0", "--evaal-start", "11.1,49.4,0"]) == 1
    assert "give --evaal-out FILE too" in capsys.readouterr().err

    building = Building.load(venue)
    other = read_log(ipin2023 / "logs" / "IPIN2023_T3_TrainingTrial01_repetition02.txt.gz", building=building)
    tracker = Tracker(building, TrackingInputs(build_radio_map(building, [other])), floor="0",
                      config=TrackingConfig().override({"filter.n_particles": 300}))
    start = (11.110964442580, 49.461316433032, 0)
    run = replay_online(tracker, log, initial=start)
    assert (run.estimates.lon_deg[0], run.estimates.lat_deg[0], run.estimates.floor[0]) == start
    assert len(run.estimates) > 10
