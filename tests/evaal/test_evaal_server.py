"""`mapfilter evaal` against the official EvaalAPI server (../shared/third_party/evaalapi, run on
127.0.0.1 by tools/evaal_server.py) with two IPIN 2023 logs (one per phone) as reloadable online
trials and as offline trials; and the same estimates from the log files (`track --evaal-out`).

Skipped, with the reason, without ../shared (the server, the logs) or without a Python holding the
server's requirements (.venv-evaalapi, which .ci/run makes; EVAALAPI_PYTHON names another)."""

from __future__ import annotations

import socket
import socketserver
import sys
import threading

import numpy as np
import pytest

from tests.conftest import REPO

sys.path.insert(0, str(REPO / "tools"))
from evaal_server import LocalServer, Trial, missing  # noqa: E402

pytestmark = pytest.mark.slow

WALKS = ("IPIN2023_T3_TrainingTrial01_repetition01", "IPIN2023_T3_TrainingTrial01_repetition03")  # SM-A520F, SM-G930F
PARTICLES = "3000"
BATCH_LAG_M = 0.5 * 1.5  # an online estimate is up to one 0.5 s batch old: at 1.5 m/s, this far behind
SHORT_S = 12.0  # the scoring trial: the first seconds of a walk (a scoring trial runs at least in real time)


@pytest.fixture(scope="module")
def venue(ipin2023, ipin_venue, tmp_path_factory):
    """(venue YAML, building, radio map path, {walk: log}): the radio map from the other 27 logs
    (leave the walks out, as docs/ipin.md does)."""
    from mapfilter.api import build_radio_map
    from mapfilter.maps.building import Building
    from mapfilter.sensors.logs import read_log

    folder = tmp_path_factory.mktemp("evaal_venue")
    building = Building.load(ipin_venue)
    logs = sorted((ipin2023 / "logs").glob("*.txt.gz"))
    radio_map = build_radio_map(building, [read_log(p, building=building) for p in logs
                                          if p.name.removesuffix(".txt.gz") not in WALKS])
    radio_map.save(folder / "rm.npz")
    return ipin_venue, building, folder / "rm.npz", {w: ipin2023 / "logs" / f"{w}.txt.gz" for w in WALKS}


@pytest.fixture(scope="module")
def server(venue, tmp_path_factory):
    reason = missing()
    if reason is not None:
        pytest.skip(reason)
    _, _, _, logs = venue
    folder = tmp_path_factory.mktemp("evaal_run")
    short = folder / "short.txt"  # the header and the first SHORT_S seconds of walk 0
    import gzip

    with gzip.open(logs[WALKS[0]], "rt") as source, open(short, "w") as target:
        for line in source:
            fields = line.split(";")
            if len(fields) > 1 and fields[1].replace(".", "", 1).isdigit() and float(fields[1]) >= SHORT_S:
                break
            target.write(line)
    trials = []
    for k, walk in enumerate(WALKS):
        trials += [Trial(f"on{k}", logs[walk]), Trial(f"off{k}", logs[walk], offline=True, slack_s=60.0)]
    trials.append(Trial("scoring", short, reloadable=False, initial="11.110964442580,49.461316433032,0"))
    with LocalServer(folder, trials) as running:
        yield running


def _evaal(server, venue, trial, out, *extra):
    from mapfilter.cli import main

    venue_yaml, _, rm, _ = venue
    return main(["evaal", server.url, trial, str(venue_yaml), "--radiomap", str(rm), "--particles", PARTICLES,
                 "--out", str(out), *extra])


def _server_estimates(server, trial, tmp_path):
    from mapfilter.evaal.client import EvaalClient
    from mapfilter.evaal.protocol import read_estimates

    reply = EvaalClient(server.url, trial).estimates()
    assert reply.status == 200
    path = tmp_path / f"{trial}_server.csv"
    path.write_text(reply.text)
    return read_estimates(path)


@pytest.fixture(scope="module")
def file_runs(venue):
    """{walk: (recording, the file's causal and offline tracks)}: `mapfilter track --smooth` in the API."""
    from mapfilter.config import TrackingConfig
    from mapfilter.sensors.floor_vote import load_building_radio_map
    from mapfilter.sensors.logs import read_log
    from mapfilter.pipeline.tracker import track

    _, building, rm, logs = venue
    radio_map = load_building_radio_map(rm, building.floor_names)
    config = TrackingConfig().override({"filter.n_particles": int(PARTICLES), "smooth": True})
    runs = {}
    for walk, log in logs.items():
        rec = read_log(log, building=building)
        result = track(building, rec, radio_map, config=config)
        runs[walk] = (rec, result.causal, result.offline)
    return runs


def _file_ipin_score(building, rec, track, causal):
    from mapfilter.evaluation.metrics import ipin_score
    from mapfilter.evaluation.scoring import score_track

    score = score_track(building, rec, track, None, causal)
    return ipin_score(score.errors.errors_m, score.floor_score.storeys_off)


def _same(a, b):
    """Two estimate lists are the same: times to the ms, positions to 1e-9 degrees, floors."""
    assert len(a) == len(b)
    np.testing.assert_allclose(a.t_s, b.t_s, atol=5e-4)
    np.testing.assert_allclose(a.lon_deg, b.lon_deg, atol=1.5e-9)
    np.testing.assert_allclose(a.lat_deg, b.lat_deg, atol=1.5e-9)
    assert a.floor.tolist() == b.floor.tolist()


@pytest.mark.parametrize("k", range(len(WALKS)))
def test_an_online_trial(server, venue, file_runs, tmp_path, capsys, k):
    """One estimate per request, every 0.5 s of the log's clock, on the POSI rows' floor; the IPIN
    score within 0.5 m of the file's causal track's, plus up to a batch's lag (the server's lines
    carry no date: the same filter over times rounded apart, which moves the score as a seed does,
    1.39-1.73 m over seeds 0-5 on walk 1; and each estimate is up to a batch, 0.5 s, old: 0.75 m
    at a brisk walk); the local file is what the server keeps, and `track --evaal-out` makes it
    from the log file to the byte."""
    from mapfilter.cli import main
    from mapfilter.evaal.protocol import read_estimates, score_against_log

    walk = WALKS[k]
    venue_yaml, building, rm, logs = venue
    out = tmp_path / "online.csv"
    assert _evaal(server, venue, f"on{k}", out, "--reload") == 0
    printed = capsys.readouterr().out
    requests = int(printed.split(" requests in ")[0].rsplit(" ", 1)[1])
    kept = _server_estimates(server, f"on{k}", tmp_path)
    assert len(kept) == requests  # one per request (the first: the initial position the server holds)
    np.testing.assert_allclose(np.diff(kept.t_s), 0.5, atol=1.1e-3)  # the server keeps pts to the ms
    _same(read_estimates(out), kept)
    rec, causal, _ = file_runs[walk]
    score = score_against_log(kept, rec)
    assert score.missed == 0 and score.n_points == rec.waypoint_t_s.size >= 10
    assert np.all(score.floors_off == 0)  # the floor of every POSI row
    assert -0.5 < score.score_m - _file_ipin_score(building, rec, causal, True) < 0.5 + BATCH_LAG_M
    # the same estimates from the log file, without a server
    practice = tmp_path / "practice.csv"
    assert main(["track", str(venue_yaml), str(logs[walk]), "--radiomap", str(rm), "--particles", PARTICLES,
                 "--evaal-out", str(practice)]) == 0
    assert practice.read_bytes() == out.read_bytes()
    assert "slack left at the end" in printed


@pytest.mark.parametrize("k", range(len(WALKS)))
def test_an_offline_trial(server, venue, file_runs, tmp_path, capsys, k):
    """Every estimate accepted: every 0.5 s from the first line and at each POSI time; `track --smooth
    --evaal-out` makes the same file from the log, and its score is the server's to 0.01 m; the IPIN
    score within 0.5 m of the file's offline track's (another run: the server's lines are timed
    apart to the millisecond, and two runs of the smoothed filter differ by about what two seeds do,
    0.2 m per walk at the median over the IPIN 2023 logs)."""
    from mapfilter.cli import main
    from mapfilter.evaal.protocol import log_clock_s, read_estimates, score_against_log

    walk = WALKS[k]
    venue_yaml, building, rm, logs = venue
    out = tmp_path / "offline.csv"
    assert _evaal(server, venue, f"off{k}", out, "--reload", "--offline") == 0
    printed = capsys.readouterr().out
    sent = read_estimates(out)
    assert f"the server: {len(sent)} estimates accepted, none rejected" in printed
    kept = _server_estimates(server, f"off{k}", tmp_path)
    _same(kept.__class__(kept.t_s[1:], kept.lon_deg[1:], kept.lat_deg[1:], kept.floor[1:]), sent)  # after the initial
    rec, _, offline = file_runs[walk]
    posi_ms = np.floor(log_clock_s(rec.waypoint_t_s, rec) * 1000 + 1e-6) / 1000
    assert np.isin(np.round(posi_ms, 3), np.round(sent.t_s, 3)).all()  # an estimate at every POSI time
    grid = np.setdiff1d(np.round(sent.t_s, 3), np.round(posi_ms, 3))
    np.testing.assert_allclose(np.diff(grid), 0.5, atol=1.1e-3)
    score = score_against_log(kept, rec)
    assert score.missed == 0 and np.all(score.floors_off == 0)
    assert abs(score.score_m - _file_ipin_score(building, rec, offline, False)) < 0.5
    practice = tmp_path / "practice.csv"
    assert main(["track", str(venue_yaml), str(logs[walk]), "--radiomap", str(rm), "--particles", PARTICLES,
                 "--smooth", "--evaal-out", str(practice)]) == 0
    assert practice.read_bytes() == out.read_bytes()
    assert abs(score_against_log(read_estimates(practice), rec).score_m - score.score_m) < 0.01


class _DroppingProxy(socketserver.ThreadingTCPServer):
    """Between the client and the server: the ``nextdata`` requests numbered in ``before`` are
    dropped unsent, those in ``after`` are sent and their answer dropped (the server took them)."""

    daemon_threads = True
    allow_reuse_address = True

    def __init__(self, server_port: int, before: set[int], after: set[int]) -> None:
        super().__init__(("127.0.0.1", 0), _ProxyHandler)
        self.server_port, self.before, self.after = server_port, before, after
        self.nextdata = 0
        self.lock = threading.Lock()


class _ProxyHandler(socketserver.BaseRequestHandler):
    def handle(self) -> None:
        data = b""
        while b"\r\n\r\n" not in data:
            chunk = self.request.recv(65536)
            if not chunk:
                return
            data += chunk
        head, _, body = data.partition(b"\r\n\r\n")
        length = next((int(line.split(b":")[1]) for line in head.split(b"\r\n")
                       if line.lower().startswith(b"content-length:")), 0)
        while len(body) < length:
            body += self.request.recv(65536)
        proxy = self.server
        number = None
        if b"/nextdata" in head.split(b"\r\n")[0]:
            with proxy.lock:
                proxy.nextdata += 1
                number = proxy.nextdata
        if number in proxy.before:
            return  # closed unsent
        with socket.create_connection(("127.0.0.1", proxy.server_port)) as upstream:
            upstream.sendall(head + b"\r\n\r\n" + body)
            answer = b""
            while chunk := upstream.recv(65536):
                answer += chunk
        if number in proxy.after:
            return  # taken by the server, the answer lost
        self.request.sendall(answer)


def test_dropped_connections_lose_no_batch(server, venue):
    """Requests dropped before and after the server took them are sent again with their label: the
    run's estimates are those of the log replayed without a server, to the bit."""
    from mapfilter.config import TrackingConfig
    from mapfilter.evaal.client import EvaalClient, run_online
    from mapfilter.evaal.replay import replay_online
    from mapfilter.sensors.floor_vote import load_building_radio_map
    from mapfilter.pipeline.tracker import Tracker, TrackingInputs

    _, building, rm, logs = venue
    radio_map = load_building_radio_map(rm, building.floor_names)
    config = TrackingConfig().override({"filter.n_particles": int(PARTICLES)})
    proxy = _DroppingProxy(server.port, before={30, 200}, after={31, 120, 121})
    thread = threading.Thread(target=proxy.serve_forever, daemon=True)
    thread.start()
    try:
        client = EvaalClient(f"http://127.0.0.1:{proxy.server_address[1]}/evaalapi/", "on1", timeout_s=5.0)
        client.reload()
        notes = []
        client.on_retry = notes.append
        run = run_online(client, Tracker(building, TrackingInputs(radio_map), config=config))
    finally:
        proxy.shutdown()
        proxy.server_close()
    assert run.dropped == 5 and len(notes) == 5 and not run.timed_out
    replay = replay_online(Tracker(building, TrackingInputs(radio_map), config=config), logs[WALKS[1]])
    np.testing.assert_array_equal(run.estimates.t_s, replay.estimates.t_s)
    np.testing.assert_array_equal(run.estimates.lon_deg, replay.estimates.lon_deg)
    np.testing.assert_array_equal(run.estimates.floor, replay.estimates.floor)
    assert run.requests == len(replay.estimates)


def test_a_client_that_stopped_is_continued_from_the_trials_state(server, venue, tmp_path):
    """A run stopped after a minute of trial time; the next run takes the trial over where it
    stands (a fresh tracker): the server keeps one estimate per request of both, 0.5 s apart."""
    from mapfilter.config import TrackingConfig
    from mapfilter.evaal.client import EvaalClient, run_online
    from mapfilter.sensors.floor_vote import load_building_radio_map
    from mapfilter.pipeline.tracker import Tracker, TrackingInputs

    _, building, rm, _ = venue
    radio_map = load_building_radio_map(rm, building.floor_names)
    config = TrackingConfig().override({"filter.n_particles": int(PARTICLES)})
    client = EvaalClient(server.url, "on0")
    client.reload()

    class Stop(Exception):
        pass

    def stop_after_a_minute(message: str) -> None:
        if float(message.split()[2]) > 60.0:
            raise Stop

    with pytest.raises(Stop):
        run_online(client, Tracker(building, TrackingInputs(radio_map), config=config), progress=stop_after_a_minute,
                   progress_every_s=5.0)
    stood = client.state()
    assert stood.started and not stood.finished and stood.trial_s > 60.0
    second = run_online(EvaalClient(server.url, "on0"), Tracker(building, TrackingInputs(radio_map), config=config))
    assert second.resumed_at_s == stood.trial_s and not second.timed_out
    kept = _server_estimates(server, "on0", tmp_path)
    np.testing.assert_allclose(np.diff(kept.t_s), 0.5, atol=1.1e-3)  # none missing, none twice
    assert kept.t_s[-len(second.estimates):].tolist() == pytest.approx(second.estimates.t_s.tolist(), abs=5e-4)


def test_a_scoring_trial_is_not_asked_faster_than_real_time(server, venue, tmp_path, capsys):
    """A non-reloadable trial with V = 3 refuses requests that come faster than real time (423):
    the client waits for them and finishes within the slack."""
    assert _evaal(server, venue, "scoring", tmp_path / "scoring.csv") == 0
    printed = capsys.readouterr().out
    refused = int(printed.split(" refused as faster than real time")[0].rsplit(", ", 1)[1].split()[0])
    assert refused >= 1
    kept = _server_estimates(server, "scoring", tmp_path)
    requests = int(printed.split(" requests in ")[0].rsplit(" ", 1)[1])
    assert len(kept) == requests >= 2 * SHORT_S
    # a scoring trial cannot be reloaded: the command says so, in one line
    assert _evaal(server, venue, "scoring", tmp_path / "again.csv", "--reload") == 1
    err = capsys.readouterr().err
    assert "cannot be reloaded" in err and err.count("\n") == 1


def test_the_wrong_mode_and_an_unknown_trial_are_refused_before_any_data(server, venue, tmp_path, capsys):
    from mapfilter.evaal.client import EvaalClient

    assert EvaalClient(server.url, "off0").reload().started is False
    assert _evaal(server, venue, "off0", tmp_path / "x.csv") == 1
    assert "off0 is an offline trial: enter it with --offline" in capsys.readouterr().err
    assert _evaal(server, venue, "on0", tmp_path / "x.csv", "--reload", "--offline") == 1
    assert "on0 is an online trial" in capsys.readouterr().err
    # neither trial was started (the server's pitfall: a refused first nextdata opens its log)
    assert not EvaalClient(server.url, "off0").state().started
    assert not EvaalClient(server.url, "on0").state().started
    # the API refuses the same before any data
    import mapfilter as mf
    from mapfilter.errors import MapfilterError

    _, building, _, _ = venue
    with pytest.raises(MapfilterError, match="on0 is an online trial"):
        mf.enter_trial(server.url, "on0", building, radio_map=venue[2], offline=True)  # a path or a RadioMap
    assert not EvaalClient(server.url, "on0").state().started
    assert _evaal(server, venue, "nosuchtrial", tmp_path / "x.csv") == 1
    assert "no trial 'nosuchtrial' (404)" in capsys.readouterr().err
    assert not (tmp_path / "x.csv").exists()


def test_each_estimate_is_the_latest_row_given_and_rows_come_within_a_batch(venue):
    """The estimate for trial time T is the latest row the tracker gave from the lines before T, and
    every row is given by the first request at least one batch (0.5 s) and a sensor interval after its
    stamp: the tracker no longer waits for the next WiFi scan (which held rows up to 3.4 s)."""
    from mapfilter.config import TrackingConfig
    from mapfilter.evaal.replay import replay_online
    from mapfilter.sensors.floor_vote import load_building_radio_map
    from mapfilter.pipeline.tracker import Tracker, TrackingInputs

    _, building, rm, logs = venue
    radio_map = load_building_radio_map(rm, building.floor_names)
    config = TrackingConfig().override({"filter.n_particles": int(PARTICLES)})
    for walk in WALKS:
        run = replay_online(Tracker(building, TrackingInputs(radio_map), config=config), logs[walk])
        est, given = run.estimates, run.rows_given
        np.testing.assert_allclose(np.diff(est.t_s), 0.5, atol=1e-6)
        assert (est.lon_deg[0], est.lat_deg[0], est.floor[0]) == pytest.approx(
            (11.110964442580, 49.461316433032, 0))  # the first POSI point: the trial's initial position
        causal = run.result.causal  # on the log's clock: the lines come without the header's date
        latlon = building.floor_xy_to_latlon(causal.xy_m, causal.floor)
        sent = np.flatnonzero(given > 0)
        np.testing.assert_allclose(est.lat_deg[sent], latlon[given[sent] - 1, 0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(est.lon_deg[sent], latlon[given[sent] - 1, 1], rtol=0, atol=1e-12)
        # when each row was first sent: the first request with more rows given than its index
        first_sent = np.searchsorted(given, np.arange(len(causal)) + 1, side="left")
        on_time = first_sent < len(est)  # the last rows: given when the log ended, after the last request
        delay_s = est.t_s[first_sent[on_time]] - causal.t_s[on_time]
        assert on_time.mean() > 0.99 and delay_s.min() > 0 and delay_s.max() < 1.0


def test_the_servers_banner_says_how_to_stop_it_in_the_background(monkeypatch, capsys, tmp_path):
    """Started with `&`, the server never sees the shell's Ctrl-C: the banner said "Ctrl-C stops
    it"; it names its PID for kill (the server itself a stand-in here)."""
    import os

    import evaal_server

    class StandIn:
        url = "http://127.0.0.1:54321/evaalapi/"

        def __init__(self, run_dir, trials, port):
            self.process = self

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def wait(self):
            raise KeyboardInterrupt

    monkeypatch.setattr(evaal_server, "LocalServer", StandIn)
    monkeypatch.setattr(evaal_server.signal, "signal", lambda *args: None)  # this process keeps its SIGTERM
    assert evaal_server.main([str(tmp_path / "walk.txt"), "--dir", str(tmp_path / "run")]) == 0
    banner = capsys.readouterr().out
    assert f"kill {os.getpid()} in the background" in banner and "walk_online" in banner
