"""``--start X,Y[,FLOOR]`` on ``mapfilter track`` (one walk, many, live) and ``evaluate`` (issue 53,
friction 1): the summary says the walk started there; a bad start is one line and nothing is
written."""

from __future__ import annotations

import io
import json
import sys

import pytest

from mapfilter.cli import main
from tests.conftest import REPO

OFFICE = REPO / "maps" / "office.yaml"
WALK = REPO / "maps" / "office_walk.txt.gz"
RADIOMAP = REPO / "maps" / "office_radiomap.npz"
COMMON = ["--radiomap", str(RADIOMAP), "--particles", "500"]


def test_track_says_where_the_walk_started(tmp_path, capsys):
    assert main(["track", str(OFFICE), str(WALK), *COMMON, "--start", "14.95,10.25", "--out",
                 str(tmp_path / "t.csv")]) == 0
    assert "started at 14.95,10.25 as given (--start" in capsys.readouterr().out


@pytest.mark.parametrize("start, words", [("1,1", "is not on the free space of the map (a wall there)"),
                                          ("14.95,10.25,F9", "has no floor 'F9'"),
                                          ("14.95;10.25", "expected X,Y or X,Y,FLOOR")])
def test_a_bad_start_is_one_line_and_nothing_is_written(tmp_path, capsys, start, words):
    out = tmp_path / "t.csv"
    for command in (["track", str(OFFICE), str(WALK), *COMMON, "--out", str(out)],
                    ["track", str(OFFICE), str(WALK), str(WALK), *COMMON, "--out-dir", str(tmp_path / "d")],
                    ["evaluate", str(OFFICE), str(WALK), *COMMON, "--out", str(tmp_path / "e")]):
        assert main(command + ["--start", start]) == 1
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and words in err, err
    assert list(tmp_path.iterdir()) == []


def test_a_live_run_takes_the_start(tmp_path, capsys, monkeypatch):
    import gzip

    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(gzip.decompress(WALK.read_bytes()))))
    assert main(["track", str(OFFICE), "-", *COMMON, "--start", "14.95,10.25", "--out", str(tmp_path / "l.csv")]) == 0
    assert "started at 14.95,10.25 as given" in capsys.readouterr().err


def test_evaluate_names_the_start_and_keeps_it_in_its_summary(tmp_path, capsys):
    assert main(["evaluate", str(OFFICE), str(WALK), *COMMON, "--methods", "pf,pdr-start", "--start", "14.95,10.25",
                 "--out", str(tmp_path / "e")]) == 0
    printed = capsys.readouterr().out
    assert "the pf methods started at 14.95,10.25 (--start)" in printed and "| pdr-start |" in printed
    assert json.loads((tmp_path / "e" / "summary.json").read_text())["start"] == "14.95,10.25"
