"""A log whose clock jumps (issue 53, probe case 2): the causal rows of a walk fed in any pieces are
those of the walk fed whole, and ``track MAP -`` gives, row for row, what ``track MAP FILE`` gives
on the same bytes. The probe: the IMU clock jumps back 20 s at 60 s; a live run printed 119 rows
against 182 from the file (a sensor 20 s behind the others was not waited for, and its records
came late), and at 64 KiB pieces 176 against 175 (a scan stamped before what the run had passed)."""

from __future__ import annotations

import gzip
import io
import sys

import numpy as np
import pytest

from mapfilter.cli import main
from mapfilter.config import TrackingConfig
from mapfilter.maps.building import Building
from mapfilter.pipeline.tracker import Tracker, TrackingInputs
from mapfilter.sensors.logs import LogStream
from mapfilter.sensors.radiomap import RadioMap
from tests.conftest import REPO

OFFICE = REPO / "maps" / "office.yaml"
WALK = REPO / "maps" / "office_walk.txt.gz"
RADIOMAP = REPO / "maps" / "office_radiomap.npz"
T0_MS = 1_600_000_000_000


def _shifted(after_s: float, by_s: float, only: tuple[str, ...] | None = None, first_only: bool = False) -> bytes:
    """The office walk with the rows after ``after_s`` (of the types ``only``) stamped ``by_s`` later."""
    out, done = [], False
    for line in gzip.decompress(WALK.read_bytes()).decode().splitlines(keepends=True):
        fields = line.rstrip("\n").split("\t")
        if line.startswith("#") or int(fields[0]) <= T0_MS + after_s * 1000 or (only and fields[1] not in only) \
                or (first_only and done):
            out.append(line)
            continue
        fields[0] = str(int(fields[0]) + int(by_s * 1000))
        if fields[1] == "TYPE_WIFI":
            fields[6] = str(int(fields[6]) + int(by_s * 1000))
        out.append("\t".join(fields) + "\n")
        done = True
    return "".join(out).encode()


IMU = ("TYPE_ACCELEROMETER", "TYPE_GYROSCOPE", "TYPE_MAGNETIC_FIELD", "TYPE_ROTATION_VECTOR")
JUMPS = {
    "the IMU clock 20 s back at 60 s": dict(after_s=60, by_s=-20, only=IMU),
    "the accelerometer's clock 20 s back": dict(after_s=60, by_s=-20, only=("TYPE_ACCELEROMETER",)),
    "every clock 20 s back": dict(after_s=60, by_s=-20),
    "the WiFi clock 20 s back": dict(after_s=60, by_s=-20, only=("TYPE_WIFI",)),
    "every clock 100 s ahead": dict(after_s=50, by_s=100),
    "one accelerometer row a day ahead": dict(after_s=50, by_s=86_400, only=("TYPE_ACCELEROMETER",), first_only=True),
}


def _rows(building, radio_map, data: bytes, cuts: list[int]) -> np.ndarray:
    tracker = Tracker(building, TrackingInputs(radio_map), TrackingConfig(seed=1).with_particles(300))
    stream = LogStream("walk")
    parts = [tracker.feed(stream.feed_bytes(data[a:b])) for a, b in zip(cuts[:-1], cuts[1:])]
    parts += [tracker.feed(stream.close()), tracker.close()]
    assert tracker.result().late_records == 0
    return np.concatenate([np.column_stack([p.t_s, p.xy_m, p.std_m]) for p in parts if len(p)])


@pytest.mark.parametrize("jump", list(JUMPS))
def test_a_clock_that_jumps_gives_the_same_rows_in_any_pieces(jump):
    building, radio_map = Building.load(OFFICE), RadioMap.load(RADIOMAP)
    data = _shifted(**JUMPS[jump])
    whole = _rows(building, radio_map, data, [0, len(data)])
    assert len(whole) > 50
    rng = np.random.default_rng(53)
    for cuts in (list(range(0, len(data), 65536)) + [len(data)], list(range(0, len(data), 3000)) + [len(data)],
                 np.unique(np.concatenate([[0, len(data)], rng.integers(0, len(data), 300)])).tolist()):
        np.testing.assert_array_equal(_rows(building, radio_map, data, cuts), whole, err_msg=jump)


def test_track_from_standard_input_is_track_of_the_file_row_for_row(tmp_path, capsys, monkeypatch):
    """The probe itself: the IMU clock 20 s back at 60 s, ``track FILE`` against ``track -``."""
    log = tmp_path / "clock_back.txt"
    log.write_bytes(_shifted(**JUMPS["the IMU clock 20 s back at 60 s"]))
    common = ["--radiomap", str(RADIOMAP), "--particles", "500"]
    assert main(["track", str(OFFICE), str(log), *common, "--out", str(tmp_path / "file.csv")]) == 0
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(log.read_bytes())))
    assert main(["track", str(OFFICE), "-", *common, "--out", str(tmp_path / "live.csv")]) == 0
    err = capsys.readouterr().err
    assert "went back in time" in err  # the IMU rows behind the log's clock, said once
    file_rows = (tmp_path / "file.csv").read_text().splitlines()
    assert len(file_rows) > 50 and (tmp_path / "live.csv").read_text().splitlines() == file_rows
