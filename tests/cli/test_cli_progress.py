"""Progress where the output is a pipe (a plain line every few seconds, not a bar), and the rough
time of a long run said before it starts."""

import time

import pytest
from conftest import REPO

from mapfilter.cli import common, main

MAPS = REPO / "maps"


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def clock(monkeypatch):
    clock = Clock()
    monkeypatch.setattr(common.time, "monotonic", clock)
    return clock


def _lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.startswith("mapfilter: ")]


def test_a_pipe_gets_a_line_every_few_seconds_with_the_time_left(clock, capsys):
    with common.ProgressBar("evaluate", 4) as progress:
        assert progress.bar is None  # stderr is not a terminal here
        clock.now += 2
        progress(1, 4, "walk_a")
        assert _lines(capsys.readouterr().err) == []  # too soon for a line
        clock.now += 4
        progress(2, 4, "walk_b")
        clock.now += 1
        progress(3, 4, "walk_c")
    assert _lines(capsys.readouterr().err) == ["mapfilter: evaluate: 2 of 4 walks (walk_b), 6 s, about 6 s left"]


def test_percent_progress_in_a_pipe(clock, capsys):
    progress = common.ProgressBar("tracking", 100, unit="%")
    for step in range(1, 41):
        clock.now += 0.5
        progress.update_to(step)
    assert _lines(capsys.readouterr().err) == ["mapfilter: tracking: 10 %, 5 s, about 45 s left",
                                               "mapfilter: tracking: 20 %, 10 s, about 40 s left",
                                               "mapfilter: tracking: 30 %, 15 s, about 35 s left",
                                               "mapfilter: tracking: 40 %, 20 s, about 30 s left"]


def test_a_terminal_gets_the_bar_and_no_lines(clock, capsys, monkeypatch):
    monkeypatch.setattr(common.sys.stderr, "isatty", lambda: True, raising=False)
    progress = common.ProgressBar("evaluate", 4)
    assert progress.bar is not None
    for i in range(1, 5):
        clock.now += 10
        progress(i, 4, "walk")
    progress.close()
    assert _lines(capsys.readouterr().err) == []


def test_track_in_a_pipe_prints_progress_lines(monkeypatch, capsys, tmp_path):
    monkeypatch.setattr(common, "PIPE_PROGRESS_INTERVAL_S", 0.0)
    assert main(["track", str(MAPS / "office.yaml"), str(MAPS / "office_walk.txt.gz"), "--radiomap",
                 str(MAPS / "office_radiomap.npz"), "--particles", "300", "--out", str(tmp_path / "t.csv")]) == 0
    lines = [line for line in _lines(capsys.readouterr().err) if line.startswith("mapfilter: tracking: ")]
    assert len(lines) > 10 and lines[-1].startswith("mapfilter: tracking: 100 %")


def test_duration_text():
    assert [common.duration_text(s) for s in (4.2, 59.6, 200, 3725)] == ["4 s", "60 s", "3 min 20 s", "1 h 02 min"]


def test_a_long_run_is_announced_before_it_starts(capsys):
    spans = [120.0] * 50  # 50 two-minute walks
    seconds = common.estimate_tracking_s(spans, 10_000, 3, workers=2)
    assert seconds == pytest.approx(50 * 120 * 1.8 * 10_000 * 3 / common.PARTICLE_STEPS_PER_S / 2)
    assert common.estimate_tracking_s(spans, 10_000, 3, workers=1) == pytest.approx(2 * seconds)
    common.announce_estimate("evaluating 50 walks", seconds, "detail")
    assert capsys.readouterr().err == f"mapfilter: evaluating 50 walks: about {common.duration_text(seconds)} by a " \
                                      "rough estimate (detail)\n"
    common.announce_estimate("tracking", 59.0, "short")
    assert capsys.readouterr().err == ""


def test_evaluate_announces_a_long_run(tmp_path, capsys, monkeypatch):
    # the bundled walk with a million particles: minutes by the model; stopped before any walk runs
    from mapfilter.cli import evaluate_cmd

    def stop(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("mapfilter.evaluation.comparison.evaluate", stop)
    monkeypatch.setattr(evaluate_cmd, "_write_summary", lambda *args, **kwargs: None)
    code = main(["evaluate", str(MAPS / "office.yaml"), str(MAPS / "office_walk.txt.gz"), "--radiomap",
                 str(MAPS / "office_radiomap.npz"), "--particles", "1000000", "--out", str(tmp_path / "r")])
    assert code == 130
    err = capsys.readouterr().err
    assert "mapfilter: evaluating 1 walk: about 10 min 48 s by a rough estimate (2 min 00 s of walks, 3 particle " \
           "filter methods of 1000000 particles, 1 worker)" in err


def test_a_large_recording_is_announced(capsys, tmp_path):
    common.announce_recording_size(3600.0, 5000, tmp_path / "run.rrd")
    assert "the recording will be about 421 MB" in capsys.readouterr().err
    common.announce_recording_size(120.0, 5000, tmp_path / "run.rrd")
    assert capsys.readouterr().err == ""


def test_the_span_of_a_log_is_read_from_its_time_stamps(ipin2023):
    from mapfilter.sensors.logs import log_time_span_s, read_log

    assert log_time_span_s(MAPS / "office_walk.txt.gz") == pytest.approx(120.0, abs=0.1)
    log = ipin2023 / "logs" / "IPIN2023_T3_TrainingTrial52_repetition01.txt.gz"
    report = read_log(log).read_report
    assert log_time_span_s(log) == pytest.approx(report.time_span_s[1] - report.time_span_s[0], abs=1.0)


def test_a_gap_in_a_log_is_no_walking_time(tmp_path):
    import gzip

    from mapfilter.sensors.logs import log_time_span_s

    lines = gzip.decompress((MAPS / "office_walk.txt.gz").read_bytes()).decode().splitlines(keepends=True)
    t_last = int(lines[-2].split("\t")[0])
    lines.insert(-1, f"{t_last + 3 * 365 * 86400 * 1000}\tTYPE_ACCELEROMETER\t0.1\t0.2\t9.8\t3\n")  # years ahead
    (tmp_path / "gap.txt").write_text("".join(lines))
    assert log_time_span_s(tmp_path / "gap.txt") == pytest.approx(120.0, abs=0.1)


def test_many_logs_spans_are_read_from_a_sample_and_scaled_by_size(tmp_path, monkeypatch):
    """Reading a log's span reads the whole log: of many, SPAN_SAMPLE_LOGS are read and the
    others scaled by their file size (a rough run time; a 500-walk run spent 20 s reading)."""
    import gzip

    from mapfilter.sensors import logs

    text = gzip.decompress((MAPS / "office_walk.txt.gz").read_bytes()).decode()
    paths = []
    for i in range(3 * common.SPAN_SAMPLE_LOGS):
        path = tmp_path / f"walk{i}.txt"
        path.write_text(text + "#\n" * i)  # the same walk, each file a little longer
        paths.append(path)
    read = []
    real = logs.log_time_span_s
    monkeypatch.setattr(logs, "log_time_span_s", lambda p: read.append(p) or real(p))
    spans = common.walk_spans_s(paths)
    assert len(read) == common.SPAN_SAMPLE_LOGS and paths[0] in read and paths[-1] in read
    per_byte = sum(real(p) for p in read) / sum(p.stat().st_size for p in read)
    for path, span in zip(paths, spans):  # those read: their span; the others: their size at the sample's rate
        assert span == pytest.approx(real(path) if path in read else path.stat().st_size * per_byte)
        assert span == pytest.approx(120.0, rel=0.01)
    read.clear()
    assert common.walk_spans_s(paths[:2]) == pytest.approx([120.0, 120.0], abs=0.1) and len(read) == 2


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")  # the swallowed exception
def test_an_interrupt_a_callback_swallowed_still_stops_the_run_at_the_next_task():
    """Ctrl-C whose KeyboardInterrupt is raised inside a weakref callback is only printed by
    Python ("Exception ignored in ..."): an interrupted evaluate once ran on to the end with exit
    code 0. The signal is noted, and the progress callback between two tasks raises it again."""
    import contextlib
    import os
    import signal
    import weakref

    import mapfilter.cli as cli

    class Thing:
        pass

    # the command's handler replaces Python's own only (an application's stays): whatever an earlier
    # test in this process left, start from Python's own
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    with contextlib.ExitStack() as stack:
        stack.callback(signal.signal, signal.SIGINT, previous)
        stack.enter_context(cli._sigterm_as_interrupt())
        thing = Thing()
        ref = weakref.ref(thing, lambda _: os.kill(os.getpid(), signal.SIGINT) or time.sleep(0.5))
        del thing  # the callback runs, the signal's KeyboardInterrupt is raised in it and swallowed
        assert ref() is None  # and no KeyboardInterrupt came out here
        progress = common.ProgressBar("evaluate", 3)
        with pytest.raises(KeyboardInterrupt):
            progress(1, 3, "walk1")
        progress(2, 3, "walk2")  # raised once
