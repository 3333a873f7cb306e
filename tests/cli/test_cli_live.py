"""`mapfilter track MAP -`: a live run's --out grows with the rows it prints, and holds every one of
them whatever stops the run (Ctrl-C, SIGTERM, the end of its input); --rerun and --plot work live."""

from __future__ import annotations

import contextlib
import csv
import gzip
import os
import random
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from rerun.chunk import RrdReader

from mapfilter.cli import main
from tests.conftest import REPO, ctrl_c_as_a_terminal_gives_it

OFFICE = REPO / "maps" / "office.yaml"
WALK = REPO / "maps" / "office_walk.txt.gz"
RADIOMAP = REPO / "maps" / "office_radiomap.npz"
PARTICLES = "300"


class LiveRun:
    """``mapfilter track office -`` in a subprocess: its standard input written by the test, its
    printed lines collected as they come."""

    def __init__(self, out, *extra: str) -> None:
        env = dict(os.environ, MAPFILTER_THREADS="1")
        self.process = subprocess.Popen(
            [sys.executable, "-m", "mapfilter", "track", str(OFFICE), "-", "--radiomap", str(RADIOMAP), "--particles",
             PARTICLES, "--out", str(out), *extra], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
            stderr=subprocess.PIPE, cwd=REPO, env=env, preexec_fn=ctrl_c_as_a_terminal_gives_it)
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for raw in self.process.stdout:
            self.lines.append(raw.decode())

    def write(self, data: bytes) -> None:
        try:
            self.process.stdin.write(data)
            self.process.stdin.flush()
        except (BrokenPipeError, ValueError):  # it has ended (a signal the test sent)
            pass

    def feed(self, pieces: list[bytes], pause_s: float = 0.0) -> threading.Thread:
        """Write ``pieces`` from a thread of its own (a pause after each); the input stays open."""
        def write_all() -> None:
            for piece in pieces:
                if self.process.poll() is not None:
                    return
                self.write(piece)
                time.sleep(pause_s)

        writer = threading.Thread(target=write_all, daemon=True)
        writer.start()
        return writer

    def wait_for_rows(self, n: int, timeout_s: float = 300.0) -> None:
        """Until ``n`` rows (and the header) are printed, or the run has ended."""
        deadline = time.monotonic() + timeout_s
        while len(self.lines) < n + 1 and self.process.poll() is None:
            assert time.monotonic() < deadline, f"{len(self.lines)} lines printed in {timeout_s} s"
            time.sleep(0.01)

    def finish(self) -> tuple[int, list[str], str]:
        """(exit code, the lines printed, stderr) once it has ended."""
        code = self.process.wait(timeout=300)
        self._reader.join(timeout=60)
        with contextlib.suppress(BrokenPipeError):
            self.process.stdin.close()
        return code, self.lines, self.process.stderr.read().decode()


def _file_rows(path) -> list[list[str]]:
    """The rows of a track CSV, each line checked whole (its CRLF end, every column)."""
    data = path.read_bytes()
    assert data.endswith(b"\r\n")  # no part of a line
    rows = list(csv.reader(data.decode().splitlines()))
    assert rows[0][:3] == ["t_s", "x_m", "y_m"]
    assert all(len(row) == len(rows[0]) for row in rows)
    return rows


def _walk_bytes() -> bytes:
    return gzip.open(WALK, "rb").read()


@pytest.fixture(scope="module")
def whole_track(tmp_path_factory):
    """The track the file run writes: the rows a live run of the whole walk must end with."""
    out = tmp_path_factory.mktemp("whole") / "whole.csv"
    assert main(["track", str(OFFICE), str(WALK), "--radiomap", str(RADIOMAP), "--particles", PARTICLES,
                 "--out", str(out)]) == 0
    return out.read_bytes()


@pytest.mark.slow
def test_a_live_run_killed_at_ten_random_points_keeps_every_row_it_printed(tmp_path, whole_track):
    """SIGINT or SIGTERM after a random number of printed rows, while the run waits for its
    input (the log fed line by line) or while it works through a large piece: the exit code is
    the signal's, and --out holds the header and every row printed (whole lines), each row as
    the file run writes it; a --rerun recording is in place and readable."""
    data = _walk_bytes()
    lines = data.splitlines(keepends=True)
    whole_rows = list(csv.reader(whole_track.decode().splitlines()))
    rng = random.Random(45)
    for point in range(10):
        out = tmp_path / f"live{point}.csv"
        sent = rng.choice([signal.SIGINT, signal.SIGTERM])
        busy = point % 2 == 1  # the walk written at once: the signal finds the run working
        after_rows = rng.randint(1, 180)
        rrd = tmp_path / f"live{point}.rrd" if point % 3 == 0 else None  # a recording grows alike
        run = LiveRun(out, *(["--rerun", str(rrd)] if rrd else []))
        if busy:
            run.feed([data])
        else:  # 50 lines at a time: the run mostly waits for the next ones
            run.feed([b"".join(lines[k:k + 50]) for k in range(0, len(lines), 50)], pause_s=0.005)
        run.wait_for_rows(after_rows)
        run.process.send_signal(sent)
        code, printed, err = run.finish()
        assert code == 128 + sent, (point, code, err)
        assert "Traceback" not in err, err
        printed_rows = list(csv.reader(printed))
        assert len(printed_rows) > after_rows  # the header and the rows seen before the signal
        rows = _file_rows(out)
        assert rows[:len(printed_rows)] == printed_rows  # every row printed, in the file
        assert rows == whole_rows[:len(rows)]  # the file run's rows, to the last digit
        if rrd is not None:  # what was drawn until the signal, in place
            assert any(c.entity_path == "/map/world/particles" for c in RrdReader(str(rrd)).stream().to_chunks())
        assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left


def test_ctrl_c_after_the_whole_walk_while_the_input_stays_open_keeps_the_whole_track(tmp_path, whole_track):
    """`tail -f walk | mapfilter track MAP - --out live.csv`, Ctrl-C once the walk is written: the
    records read are tracked to the end, as if the input had ended, and the file is the file
    run's track byte for byte."""
    out = tmp_path / "live.csv"
    run = LiveRun(out)
    run.feed([_walk_bytes()])  # and the input stays open, as tail -f keeps it
    n_whole = len(whole_track.decode().splitlines()) - 1
    run.wait_for_rows(n_whole - 3)  # the last rows wait for records that never come
    time.sleep(0.5)
    run.process.send_signal(signal.SIGINT)
    code, printed, err = run.finish()
    assert code == 130
    assert out.read_bytes() == whole_track
    assert len(printed) == n_whole + 1
    assert "ended by Ctrl-C" in err and f"{n_whole} rows" in err


def test_a_run_ending_before_its_first_row_leaves_an_earlier_file_as_it_was(tmp_path, capsys, monkeypatch):
    """An earlier live.csv is replaced only once the new run has a row: a log of no known format
    ends the run first, with one line, and the earlier file is untouched."""
    import io

    out = tmp_path / "live.csv"
    out.write_text("an earlier session\n")
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(b"not a phone log\n" * 300)))
    assert main(["track", str(OFFICE), "-", "--radiomap", str(RADIOMAP), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "unknown log format" in err
    assert out.read_text() == "an earlier session\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["live.csv"]


def test_a_live_run_never_writes_over_the_file_it_reads(tmp_path, capsys, monkeypatch):
    out = tmp_path / "walk.txt"
    out.write_bytes(_walk_bytes())
    with out.open("rb") as handle:
        monkeypatch.setattr(sys, "stdin", type("Stdin", (), {"buffer": handle, "fileno": handle.fileno})())
        assert main(["track", str(OFFICE), "-", "--radiomap", str(RADIOMAP), "--out", str(out)]) == 1
    assert "--out is the file standard input reads" in capsys.readouterr().err
    assert out.read_bytes() == _walk_bytes()


def test_a_live_run_writes_a_rerun_recording_and_a_picture_at_the_end(tmp_path, capsys, monkeypatch):
    """--rerun and --plot (the causal track and the walk's ground truth) with a live run."""
    import io

    rrd, picture, out = tmp_path / "live.rrd", tmp_path / "live.png", tmp_path / "live.csv"
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(_walk_bytes())))
    assert main(["track", str(OFFICE), "-", "--radiomap", str(RADIOMAP), "--particles", PARTICLES, "--out", str(out),
                 "--rerun", str(rrd), "--plot", str(picture)]) == 0
    err = capsys.readouterr().err
    assert f"wrote {rrd}" in err and f"wrote {picture}" in err
    entities = {chunk.entity_path for chunk in RrdReader(str(rrd)).stream().to_chunks()}
    assert "/map/world/particles" in entities and "/plots/particles/ess" in entities
    from PIL import Image

    image = np.asarray(Image.open(picture).convert("RGB"))
    assert (image.reshape(-1, 3) == 0).all(axis=1).any()  # the ground truth, in black
    assert sorted(p.name for p in tmp_path.iterdir()) == ["live.csv", "live.png", "live.rrd"]


def test_a_live_run_streams_to_a_viewer_with_spawn(tmp_path, capsys, monkeypatch):
    """--spawn: the live run's steps go to the viewer as they happen (a stand-in here: no test
    spawns one), and the rows are printed as without it."""
    import io

    import rerun

    import mapfilter.viz.recorder as recorder

    spawned, drawn = [], []

    def stand_in(**kwargs):  # the viewer: the recording goes to memory instead
        spawned.append(kwargs["recording"].memory_recording())

    draw = recorder.RerunLogger.log_step
    import mapfilter.viz

    monkeypatch.setattr(recorder, "viewer_problem", lambda: None)
    monkeypatch.setattr(mapfilter.viz, "viewer_problem", lambda: None)
    monkeypatch.setattr(rerun, "spawn", stand_in)
    monkeypatch.setattr(recorder.RerunLogger, "log_step", lambda self, report: (drawn.append(report.t_s),
                                                                                 draw(self, report)))
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(_walk_bytes())))
    assert main(["track", str(OFFICE), "-", "--radiomap", str(RADIOMAP), "--particles", PARTICLES, "--spawn"]) == 0
    printed = capsys.readouterr().out.splitlines()
    # every filter step drawn: a row each, but for the header and the start's row
    assert len(spawned) == 1 and len(drawn) == len(printed) - 2 > 100


@pytest.mark.parametrize("how", ["context", "context of a context", "noted only"])
@pytest.mark.parametrize("interrupt, code", [("Terminated", 143), ("KeyboardInterrupt", 130)])
def test_a_signal_inside_a_numba_call_ends_as_the_signal(monkeypatch, capsys, interrupt, code, how):
    """A signal whose handler runs while numba's dispatcher is in Python code reaches the command
    as a SystemError ("returned a result with an exception set"): with the interrupt as its
    context (a live run killed at a random point, about 1 time in 20), further down (the handler
    ran while the dispatcher loaded the kernel from its cache, which made the interrupt an error of
    its own first), or not in the chain at all but noted by the handler: it ends as the signal does."""
    import signal as signals

    import mapfilter.cli as cli
    from mapfilter.cli import track_cmd
    from mapfilter.runtime.interrupts import note_signal

    def run(args):
        exception = getattr(cli, interrupt, KeyboardInterrupt)
        try:
            if how == "noted only":
                note_signal(signals.SIGTERM if exception is cli.Terminated else signals.SIGINT)
                raise ValueError("a cached kernel's data could not be read")
            try:
                raise exception()
            except KeyboardInterrupt:
                if how == "context":
                    raise
                raise ValueError("a cached kernel's data could not be read")  # noqa: B904
        except BaseException:
            raise SystemError("CPUDispatcher(<function _weighted_sums>) returned a result with an exception set")  # noqa: B904

    monkeypatch.setattr(track_cmd, "run", run)
    assert main(["track", str(OFFICE), str(WALK), "--radiomap", str(RADIOMAP)]) == code
    assert "Traceback" not in capsys.readouterr().err


def test_an_error_without_a_signal_is_not_taken_for_one(monkeypatch):
    """The same SystemError with no interrupt behind it and no signal noted is a bug: it is raised."""
    from mapfilter.cli import track_cmd

    def run(args):
        raise SystemError("CPUDispatcher(<function _weighted_sums>) returned a result with an exception set")

    monkeypatch.setattr(track_cmd, "run", run)
    with pytest.raises(SystemError):
        main(["track", str(OFFICE), str(WALK), "--radiomap", str(RADIOMAP)])


def test_a_signal_a_finalizer_swallowed_ends_the_live_run_before_it_waits_on_its_input(monkeypatch, capsys):
    """Ctrl-C whose KeyboardInterrupt a finalizer swallowed while a chunk was tracked is noted
    (``runtime.interrupts``): the live loop raises it before it reads again, and ends the walk as
    Ctrl-C does, instead of waiting on an input that stays open (``tail -f``)."""
    import argparse
    import io

    from mapfilter.cli.track_cmd import _follow_standard_input
    from mapfilter.config import TrackingConfig
    from mapfilter.maps.building import Building
    from mapfilter.maps.floorplan import FloorPlan
    from mapfilter.pipeline.tracker import Tracker, TrackingInputs
    from mapfilter.runtime.interrupts import clear, note_signal
    from mapfilter.sensors.radiomap import RadioMap

    walk = gzip.open(WALK, "rb").read()
    first_chunk = walk[:walk.index(b"\n", len(walk) // 2) + 1]  # the first half of the walk, whole lines

    class OpenInput(io.RawIOBase):
        """Standard input that gives one chunk, then would wait forever (the writer keeps it open)."""

        def __init__(self) -> None:
            self.reads = 0

        def read1(self, size: int = -1) -> bytes:
            self.reads += 1
            if self.reads > 1:
                raise AssertionError("read again with a signal pending: a live run would wait here for good")
            return first_chunk

    source = OpenInput()

    def swallowed_while_tracking(*args, **kwargs):
        note_signal(signal.SIGINT)  # the handler ran inside a finalizer: noted, its exception lost
        return original_feed(*args, **kwargs)

    monkeypatch.setattr(sys, "stdin", type("Stdin", (), {"buffer": source})())
    config = TrackingConfig(seed=0).override({"filter.n_particles": 300})
    building = Building.from_plan(FloorPlan.load(OFFICE))
    tracker = Tracker(building, TrackingInputs(radio_map=RadioMap.load(RADIOMAP)), config=config,
                      log_name="standard input")
    original_feed = tracker.feed
    monkeypatch.setattr(tracker, "feed", swallowed_while_tracking)
    clear()
    printed, _, interrupted = _follow_standard_input(argparse.Namespace(strict=False, out=None), building, tracker,
                                                       None)
    clear()
    assert isinstance(interrupted, KeyboardInterrupt) and source.reads == 1
    assert printed > 0  # the rows of what was read are printed, as at the input's end
