"""`--spawn` where no viewer can start, and a viewer that never takes the data: one line, the
work done, and an exit (SIGTERM honoured). No test here spawns a viewer: without a display
``rr.spawn()`` blocks and its caller can hang; every spawn is replaced by a stand-in."""

import os
import signal
import socket
import subprocess
import sys
import textwrap
import time

import pytest
from conftest import REPO

from mapfilter.cli import main
from mapfilter.io.tracks import read_track

MAPS = REPO / "maps"
TRACK_ARGS = ["track", str(MAPS / "office.yaml"), str(MAPS / "office_walk.txt.gz"), "--radiomap",
              str(MAPS / "office_radiomap.npz"), "--particles", "300"]


@pytest.fixture
def no_spawning(monkeypatch):
    """Any attempt to spawn a viewer fails the test at once (instead of blocking it)."""
    import rerun

    def refuse(*args, **kwargs):
        raise AssertionError("a viewer was spawned")

    monkeypatch.setattr(rerun, "spawn", refuse)
    monkeypatch.setattr(rerun.RecordingStream, "spawn", refuse)


@pytest.fixture
def no_display(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")


def test_track_spawn_without_a_display_says_so_in_one_line_and_tracks(no_display, no_spawning, tmp_path, capsys):
    out = tmp_path / "track.csv"
    assert main([*TRACK_ARGS, "--spawn", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert len(captured.err.strip().splitlines()) == 1, captured.err
    assert "--spawn: no rerun viewer can start here: no display" in captured.err
    assert "--rerun FILE.rrd" in captured.err
    assert len(read_track(out)) > 100 and f"wrote {out}" in captured.out


def test_view_spawn_without_a_display_is_a_one_line_error(no_display, no_spawning, capsys):
    assert main(["view", str(MAPS / "office.yaml"), "--spawn"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no display" in err and "--rerun FILE.rrd" in err


def test_spawn_without_the_viewer_installed_says_so(monkeypatch, no_spawning, tmp_path, capsys):
    import shutil

    monkeypatch.setenv("DISPLAY", ":0")  # a display, but no viewer to put on it
    monkeypatch.setattr(shutil, "which", lambda name, *args, **kwargs: None)
    monkeypatch.setattr(sys, "executable", str(tmp_path / "python"))
    assert main([*TRACK_ARGS, "--spawn", "--out", str(tmp_path / "t.csv")]) == 0
    assert "the rerun viewer is not installed" in capsys.readouterr().err
    assert (tmp_path / "t.csv").is_file()


def test_viewer_problem_is_none_where_a_viewer_can_start(monkeypatch):
    from mapfilter.viz import viewer_problem

    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.setenv("WAYLAND_DISPLAY", "wayland-0")
    monkeypatch.delenv("DISPLAY", raising=False)
    assert viewer_problem() is None  # the venv has the viewer: rerun-sdk installs it
    monkeypatch.delenv("WAYLAND_DISPLAY")
    assert "no display" in viewer_problem()


# a "viewer" that never takes data: the spawn connects the stream to a port where nobody listens
_STUCK_VIEWER = """
import sys
import rerun
import mapfilter.viz.recorder as recorder

recorder.VIEWER_FLUSH_LIMIT_S = {limit_s}


def stuck_viewer(*, recording, default_blueprint=None, **kwargs):
    recording.connect_grpc("rerun+http://127.0.0.1:{port}/proxy", default_blueprint=default_blueprint)


rerun.spawn = stuck_viewer
from mapfilter.cli import main

sys.exit(main({args!r}))
"""


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _run_stuck(tmp_path, limit_s: float) -> tuple[subprocess.Popen, object]:
    out = tmp_path / "track.csv"
    code = _STUCK_VIEWER.format(limit_s=limit_s, port=_free_port(), args=[*TRACK_ARGS, "--spawn", "--out", str(out)])
    env = dict(os.environ, DISPLAY=":99")  # a display is claimed: the stand-in viewer "starts"
    process = subprocess.Popen([sys.executable, "-c", textwrap.dedent(code)], cwd=tmp_path, env=env,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return process, out


@pytest.mark.slow
def test_sigterm_ends_a_run_whose_viewer_never_takes_the_data(tmp_path):
    process, out = _run_stuck(tmp_path, limit_s=600.0)
    try:
        deadline = time.monotonic() + 120
        while not out.exists() and process.poll() is None and time.monotonic() < deadline:
            time.sleep(0.2)  # the track is written before the recording is closed
        assert out.exists(), process.communicate(timeout=5)
        time.sleep(1.0)  # now waiting for the viewer
        process.send_signal(signal.SIGTERM)
        _, err = process.communicate(timeout=30)  # a hang fails here
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    assert process.returncode == 128 + signal.SIGTERM, err
    assert "mapfilter: terminated" in err


@pytest.mark.slow
def test_a_viewer_that_never_takes_the_data_is_given_up_with_one_line(tmp_path):
    process, out = _run_stuck(tmp_path, limit_s=1.0)
    try:
        stdout, err = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    assert process.returncode == 0, err
    ours = [line for line in err.splitlines() if line.startswith("mapfilter:")]
    assert len(ours) == 1 and "the rerun viewer did not take the last data in 1 s" in ours[0], err
    assert len(read_track(out)) > 100 and "wrote" in stdout
