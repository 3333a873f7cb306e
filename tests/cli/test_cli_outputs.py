"""Outputs: paths checked before the work, a full disk in one line, a closed pipe quietly,
SIGTERM like Ctrl-C (temporaries removed), argument types with limits."""

from __future__ import annotations

import argparse
import errno
import os
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mapfilter.cli import main
from mapfilter.cli.common import bounded_float, check_output_path, non_negative_int
from mapfilter.errors import MapfilterError

REPO = Path(__file__).resolve().parents[2]
MAPS = REPO / "maps"
# a directory nobody may write in, root included (sysfs); tests that need one skip elsewhere
UNWRITABLE = Path("/sys")


def _unwritable() -> Path:
    if not UNWRITABLE.is_dir():
        pytest.skip("no /sys here: no directory that even root cannot write in")
    try:
        fd = os.open(UNWRITABLE / ".mapfilter-test", os.O_CREAT | os.O_WRONLY)
    except OSError:
        return UNWRITABLE
    os.close(fd)
    os.unlink(UNWRITABLE / ".mapfilter-test")
    pytest.skip("/sys is writable here")


def test_check_output_path(tmp_path):
    check_output_path(None)  # not given
    check_output_path(tmp_path / "track.csv")
    check_output_path(tmp_path / "new" / "deeper" / "track.csv")  # missing parents are made when writing
    check_output_path(tmp_path / "new-dir", directory=True)
    (tmp_path / "file.csv").write_text("x")
    with pytest.raises(MapfilterError, match="--out: is a directory; give a file name") as info:
        check_output_path(tmp_path)
    assert info.value.path == str(tmp_path)
    with pytest.raises(MapfilterError, match="--out-dir: exists and is not a directory"):
        check_output_path(tmp_path / "file.csv", "--out-dir", directory=True)
    with pytest.raises(MapfilterError, match=f"cannot be made, {tmp_path / 'file.csv'} is not a directory"):
        check_output_path(tmp_path / "file.csv" / "sub" / "track.csv")
    with pytest.raises(MapfilterError, match=f"--rerun: cannot write in {_unwritable()}"):
        check_output_path(_unwritable() / "run.rrd", "--rerun")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file.csv"]  # the probe left nothing


def _commands(tmp_path: Path, out: str) -> list[list[str]]:
    """Every command this module owns, each with a log that does not exist: a refusal that names the
    output shows that the output was checked before any input was read."""
    missing = str(tmp_path / "missing.txt")
    return [
        ["simulate", str(MAPS / "office.yaml"), "--out", out],
        ["radiomap", "build", str(MAPS / "office.yaml"), missing, "--out", out],
        ["radiomap", "fit-aps", str(MAPS / "office.yaml"), missing, "--out", out],
        ["map", "prepare", str(tmp_path / "missing.png"), "--resolution", "0.05", "--out", out],
        ["map", "import-ilc", str(tmp_path / "missing-floor"), "--out", out],
        ["view", str(tmp_path / "missing.yaml"), "--rerun", out],
    ]


@pytest.mark.parametrize("kind", ["directory", "unwritable", "parent-is-a-file"])
def test_every_command_checks_its_output_before_the_work(tmp_path, capsys, kind):
    (tmp_path / "a-file").write_text("x")
    (tmp_path / "a-dir.rrd").mkdir()
    out = {"directory": str(tmp_path / "a-dir.rrd"),
           "unwritable": str(_unwritable() / "out.rrd") if kind == "unwritable" else "",
           "parent-is-a-file": str(tmp_path / "a-file" / "out.rrd")}[kind]
    for argv in _commands(tmp_path, out):
        assert main(argv) == 1, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith(f"mapfilter: error: {out}: --"), (argv, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-dir.rrd", "a-file"]
    assert list((tmp_path / "a-dir.rrd").iterdir()) == []


def _limited(fsize_bytes: int):
    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (fsize_bytes, fsize_bytes))
    return limit


def test_a_full_disk_is_one_line_naming_the_file_and_leaves_nothing(tmp_path):
    """A file-size limit makes every write past 100 kB fail (EFBIG), as a full disk (ENOSPC) does."""
    out = tmp_path / "walk.txt"
    done = subprocess.run([sys.executable, "-m", "mapfilter", "simulate", str(MAPS / "office.yaml"), "--out", str(out)],
                          preexec_fn=_limited(100_000), capture_output=True, text=True, timeout=300)
    assert done.returncode == 1, done.stderr
    assert done.stderr == f"mapfilter: error: {out}: could not write: File too large\n"
    assert list(tmp_path.iterdir()) == []  # no temporary, no half file


def test_an_os_error_anywhere_is_one_line(monkeypatch, capsys):
    from mapfilter.cli import simulate_cmd

    def full(args):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(simulate_cmd, "run", full)
    assert main(["simulate", str(MAPS / "office.yaml"), "--out", "x.txt"]) == 1
    assert capsys.readouterr().err == "mapfilter: error: No space left on device\n"


def test_atomic_writes_leave_nothing_on_a_disk_error(tmp_path):
    from mapfilter.io.atomic import atomic_paths

    with pytest.raises(MapfilterError, match="could not write: No space left on device") as info:
        with atomic_paths(tmp_path / "new" / "a.csv") as (tmp,):
            tmp.write_text("half")
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    assert info.value.path == str(tmp_path / "new" / "a.csv")
    assert list(tmp_path.iterdir()) == []  # the directory made for it is gone too


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _disk_full(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_a_failed_evaluation_leaves_the_earlier_one_whole(tmp_path, monkeypatch, capsys):
    """A full disk at the last file of a second evaluation (its cdf.png): the earlier evaluation's
    files are all there, byte for byte, and no temporary is left."""
    from mapfilter.evaluation import plots

    out = tmp_path / "eval"
    argv = ["evaluate", str(MAPS / "office.yaml"), str(MAPS / "office_walk.txt.gz"), "--radiomap",
            str(MAPS / "office_radiomap.npz"), "--methods", "kwnn", "--out", str(out)]
    assert main(argv) == 0
    earlier = _snapshot(out)
    assert "cdf.png" in earlier and "summary.csv" in earlier
    monkeypatch.setattr(plots, "plot_error_cdf", _disk_full)
    assert main([*argv[:-3], "kwnn,kf", "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "No space left on device" in err and err.strip().count("\n") == 0, err
    assert _snapshot(out) == earlier


def test_track_smooth_writes_both_tracks_or_neither(tmp_path, monkeypatch, capsys):
    """The causal track (t.causal.csv) fails to write: t.csv is not replaced either."""
    from mapfilter.io import tracks

    out = tmp_path / "t.csv"
    out.write_text("t_s,x_m,y_m\n0,1,2\n")
    real_write, calls = tracks.write_track, []

    def second_fails(track, path, *args, **kwargs):
        calls.append(path)
        if len(calls) == 2:
            _disk_full()
        real_write(track, path, *args, **kwargs)

    monkeypatch.setattr(tracks, "write_track", second_fails)
    code = main(["track", str(MAPS / "office.yaml"), str(MAPS / "office_walk.txt.gz"), "--radiomap",
                 str(MAPS / "office_radiomap.npz"), "--smooth", "--particles", "300", "--out", str(out)])
    assert code == 1 and len(calls) == 2 and "No space left on device" in capsys.readouterr().err
    assert out.read_text() == "t_s,x_m,y_m\n0,1,2\n" and sorted(p.name for p in tmp_path.iterdir()) == ["t.csv"]


def test_a_closed_pipe_is_quiet(tmp_path):
    """`mapfilter check LOG... | head -1`: the reader has gone; no traceback, no 'Exception ignored'."""
    logs = [str(MAPS / "office_walk.txt.gz")] * 3
    for argv in (["check", *logs],):
        read, write = os.pipe()
        os.close(read)  # every write to stdout now fails with EPIPE
        done = subprocess.run([sys.executable, "-m", "mapfilter", *argv], stdout=write, stderr=subprocess.PIPE,
                              text=True, timeout=300)
        os.close(write)
        assert done.returncode == 128 + signal.SIGPIPE and done.stderr == "", done.stderr


def test_sigterm_cleans_up_like_ctrl_c(tmp_path):
    """A terminated `track --rerun` left its multi-megabyte temporary .rrd; now SIGTERM runs the
    clean-up that Ctrl-C runs."""
    rrd = tmp_path / "run.rrd"
    process = subprocess.Popen([sys.executable, "-m", "mapfilter", "track", str(MAPS / "office.yaml"),
                                str(MAPS / "office_walk.txt.gz"), "--radiomap", str(MAPS / "office_radiomap.npz"),
                                "--smooth", "--rerun", str(rrd), "--out", str(tmp_path / "t.csv")],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not any(p.name.startswith(".run.") and p.stat().st_size > 100_000 for p in tmp_path.iterdir()):
            assert process.poll() is None and time.monotonic() < deadline, "no temporary .rrd appeared"
            time.sleep(0.05)
        process.send_signal(signal.SIGTERM)
        _, err = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 128 + signal.SIGTERM and err.strip().splitlines()[-1] == "mapfilter: terminated"
    assert "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_argument_types_with_limits():
    assert non_negative_int("0") == 0 and non_negative_int("12") == 12
    for text, message in (("-1", "must be at least 0, got -1"), ("1.5", "must be a whole number"),
                          ("", "must be a whole number")):
        with pytest.raises(argparse.ArgumentTypeError, match=message):
            non_negative_int(text)
    duration = bounded_float(0.0, 10.0, low_open=True)
    assert duration("10") == 10.0
    for text, message in (("0", "must be above 0"), ("nan", "finite"), ("11", "at most 10"), ("x", "a number")):
        with pytest.raises(argparse.ArgumentTypeError, match=message):
            duration(text)
