"""The ISO/IEC 18305 and EvAAL figures of `evaluate`: CE95, availability, floor detection
probability (docs/results.md), on made-up results whose figures are known, and in the CLI's table."""

import csv
import math

import numpy as np
import pytest
from conftest import REPO

from mapfilter.cli import main
from mapfilter.evaluation.comparison import Evaluation, MethodResult, WalkOutcome
from mapfilter.evaluation.metrics import FloorScore, summarise_errors
from mapfilter.io.tracks import Track

MAPS = REPO / "maps"


def test_ce95_is_the_95th_percentile():
    errors = np.arange(1.0, 101.0)
    stats = summarise_errors(errors)
    assert stats["ce95"] == pytest.approx(95.05) and stats["p90"] < stats["ce95"] < stats["max"]
    assert math.isnan(summarise_errors([])["ce95"])


def test_availability_and_floor_detection():
    from mapfilter.evaluation.metrics import availability, floor_detection

    assert availability(90, 10) == 0.9 and math.isnan(availability(0, 0))
    scores = [FloorScore(n_right=8, n_judged=10, missed=2), FloorScore(n_right=5, n_judged=5, missed=3)]
    assert floor_detection(scores) == pytest.approx(13 / 20)  # a missed point is not detected


def _result(method, trace, errors, missed, right=None):
    track = Track(np.zeros(1), np.zeros((1, 2)))
    score = None if right is None else FloorScore(right, len(errors), missed, np.zeros(len(errors)))
    return MethodResult(method, trace, track, np.asarray(errors, dtype=float), missed, 0, 0, 0.1, floor_score=score)


def test_summary_rows_carry_the_figures():
    outcomes = [WalkOutcome(0, "a", None, "ok", results=[_result("pf", "a", [1.0, 2.0, 3.0], 1, right=2)]),
                WalkOutcome(1, "b", None, "ok", results=[_result("pf", "b", [4.0, 5.0], 0, right=2)])]
    (row,) = Evaluation.from_outcomes(outcomes, 2, 1.0).summary_rows()
    assert row["n"] == 5 and row["missed"] == 1 and row["availability"] == pytest.approx(5 / 6)
    assert row["ce95"] == pytest.approx(np.percentile([1, 2, 3, 4, 5], 95))
    assert row["floor_accuracy"] == pytest.approx(4 / 5) and row["floor_detection"] == pytest.approx(4 / 6)
    traces = Evaluation.from_outcomes(outcomes, 2, 1.0).trace_rows()
    assert [t["availability"] for t in traces] == [pytest.approx(0.75), 1.0]
    assert [t["floor_detection"] for t in traces] == [pytest.approx(0.5), 1.0]


def test_the_cli_table_and_summary_csv_have_the_columns(tmp_path, capsys):
    assert main(["evaluate", str(MAPS / "office.yaml"), str(MAPS / "office_walk.txt.gz"), "--radiomap",
                 str(MAPS / "office_radiomap.npz"), "--methods", "pf,kwnn", "--particles", "500",
                 "--out", str(tmp_path / "r")]) == 0
    table = capsys.readouterr().out
    assert "| method | mean | median | p75 | p90 | ce95 | max | rmse | n | missed | availability |" in table
    with (tmp_path / "r" / "summary.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    for row in rows:
        n, missed = int(row["n"]), int(row["missed"])
        assert float(row["availability"]) == pytest.approx(n / (n + missed), abs=1e-4)
        assert float(row["p90"]) <= float(row["ce95"]) <= float(row["max"])
    assert {row["method"] for row in rows} == {"pf", "kwnn"} and int(rows[0]["missed"]) > 0
