"""A full disk under ``--rerun`` (issue 53, probe case 1): rerun writes the ``.rrd`` file from a
thread of its own, which a full disk stops; a ``save`` waiting for it then never returned (about
half the tries) and SIGTERM waited behind it. Every try must end with the one line and leave no
temporary ``.r.*.rrd``.

The full disk without root: the child's file-size limit (``RLIMIT_FSIZE``, SIGXFSZ ignored) makes
every write past 4 KiB fail as a full disk does, and rerun's writer thread stops the same two
ways (an error, or a ``save`` that never returns). Each try runs with a 1 s deadline instead of
the 10 s the command waits, so that the many tries stay quick."""

from __future__ import annotations

import os
import resource
import signal
import subprocess
import sys

import pytest

from tests.conftest import REPO

OFFICE = REPO / "maps" / "office.yaml"
WALK = REPO / "maps" / "office_walk.txt.gz"
RADIOMAP = REPO / "maps" / "office_radiomap.npz"
TRIES = 6  # a try hung about half the time: six catch it 98 times in 100
# far above a try's own time (a few seconds, plus the 1 s deadline): a try that outlives it hung
HUNG_S = 120

_CHILD = """
import sys
from mapfilter.viz import recorder
recorder.RECORDING_WRITE_LIMIT_S = 1.0
from mapfilter.cli import main
sys.exit(main(sys.argv[1:]))
"""


def _full_disk() -> None:
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails (EFBIG) instead of killing
    resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))


def _try(argv: list[str], folder) -> tuple[int, str]:
    env = dict(os.environ, MAPFILTER_THREADS="1")
    env.pop("RUST_LOG", None)
    process = subprocess.Popen([sys.executable, "-c", _CHILD, *argv], cwd=folder, env=env, preexec_fn=_full_disk,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _, err = process.communicate(timeout=HUNG_S)
    except subprocess.TimeoutExpired:
        process.kill()
        process.communicate()
        pytest.fail(f"{' '.join(argv[:1])} --rerun on a full disk hung")
    return process.returncode, err


@pytest.mark.parametrize("command", ["track", "view"])
def test_a_full_disk_under_rerun_ends_every_try_with_one_line_and_no_temporary(tmp_path, command):
    if command == "track":
        argv = ["track", str(OFFICE), str(WALK), "--radiomap", str(RADIOMAP), "--particles", "300", "--rerun"]
    else:
        (tmp_path / "t.csv").write_text("t_s,x_m,y_m,std_m,heading_rad\n0,15,10,1,0\n1,16,10,1,0\n")
        argv = ["view", str(OFFICE), str(tmp_path / "t.csv"), "--log", str(WALK), "--rerun"]
    out = tmp_path / "full"
    out.mkdir()
    for attempt in range(TRIES):
        code, err = _try(argv + [str(out / "r.rrd")], tmp_path)
        # a slow run prints its progress on stderr too (a loaded machine): every other line is the one
        lines = [line for line in err.strip().splitlines() if not line.startswith("mapfilter: tracking:")]
        assert code == 1 and len(lines) == 1, (attempt, err)
        assert lines[0].startswith(f"mapfilter: error: {out / 'r.rrd'}: could not write the recording (")
        assert lines[0].endswith("): is the disk full?"), lines[0]
        assert list(out.iterdir()) == [], (attempt, list(out.iterdir()))  # no temporary, no file


def test_a_write_that_never_returns_ends_within_the_deadline(tmp_path, monkeypatch):
    """The bounded write itself: a call that blocks for good is left to its thread, and the
    logger says so in one line and removes its temporary."""
    import threading

    import rerun as rr

    from mapfilter.errors import MapfilterError
    from mapfilter.maps.floorplan import FloorPlan
    from mapfilter.viz import recorder

    never = threading.Event()
    monkeypatch.setattr(recorder, "RECORDING_WRITE_LIMIT_S", 0.5)
    monkeypatch.setattr(rr.RecordingStream, "save", lambda self, *args, **kwargs: never.wait())
    unregistered = []
    monkeypatch.setattr(rr, "unregister_shutdown", lambda: unregistered.append(True))
    with pytest.raises(MapfilterError, match=r"did not answer in 0.5 s\): is the disk full\?"):
        recorder.make_logger(FloorPlan.load(OFFICE), rrd_path=tmp_path / "r.rrd")
    assert list(tmp_path.iterdir()) == [] and unregistered  # the exit does not wait for it either
    never.set()
