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


def test_every_method_of_a_walk_is_scored_at_the_same_waypoints():
    """Issue 53, friction 2: a causal method misses the waypoints before its first estimate, an
    offline track none; by default every method of a walk is scored at the waypoints all of them
    have an estimate for, and a method with none on a walk says how many it lacks."""
    walk_a = [_result("pf", "a", [9.0, 9.0, 1.0, 2.0], 1), _result("pf-smooth", "a", [7.0, 7.0, 7.0, 1.0, 1.0], 0),
              _result("kwnn", "a", [3.0, 3.0, 3.0], 2)]
    walk_b = [_result("pf", "b", [4.0, 5.0], 0), _result("pf-smooth", "b", [2.0, 2.0], 0),
              _result("kwnn", "b", [], 2)]  # no estimate at all on this walk
    outcomes = [WalkOutcome(0, "a", None, "ok", results=walk_a), WalkOutcome(1, "b", None, "ok", results=walk_b)]
    evaluation = Evaluation.from_outcomes(outcomes, 2, 1.0)
    rows = {row["method"]: row for row in evaluation.summary_rows()}
    # walk a: waypoints 2-4 (kwnn's first estimate is the latest); walk b: both, kwnn left out of the choice
    assert rows["pf"]["n"] == rows["pf-smooth"]["n"] == 5 and rows["kwnn"]["n"] == 3
    assert rows["pf"]["mean"] == pytest.approx((9 + 1 + 2 + 4 + 5) / 5)
    assert rows["pf-smooth"]["mean"] == pytest.approx((7 + 1 + 1 + 2 + 2) / 5)
    assert rows["kwnn"]["not_scored"] == 2 and rows["pf"]["not_scored"] == rows["pf-smooth"]["not_scored"] == 0
    # missed and availability stay the method's own
    assert rows["pf"]["missed"] == 1 and rows["pf-smooth"]["missed"] == 0 and rows["kwnn"]["missed"] == 4
    assert rows["pf-smooth"]["availability"] == 1.0 and rows["pf"]["availability"] == pytest.approx(6 / 7)
    assert evaluation.common_count() == (5, 7)
    assert "the same 5 of the 7 waypoints" in evaluation.scoring_text()
    (line,) = evaluation.not_scored_text()
    assert line.startswith("kwnn: no estimate at 2 of the common waypoints (walk b)")
    assert [len(e) for e in evaluation.errors_by_method().values()] == [5, 5, 3]
    # each at its own: the old table
    evaluation.common_waypoints = False
    rows = {row["method"]: row for row in evaluation.summary_rows()}
    assert rows["pf"]["n"] == 6 and rows["pf-smooth"]["n"] == 7 and rows["kwnn"]["n"] == 3
    assert evaluation.not_scored_text() == [] and "its own" in evaluation.scoring_text()


def test_the_floor_accuracy_is_scored_at_the_common_waypoints_and_the_detection_at_all():
    track = Track(np.zeros(1), np.zeros((1, 2)))
    causal = MethodResult("pf", "a", track, np.ones(3), 2, 0, 0, 0.1,
                          floor_score=FloorScore(2, 3, 2, np.array([0.0, 1.0, 0.0])))
    offline = MethodResult("pf-smooth", "a", track, np.ones(5), 0, 0, 0, 0.1, causal=False,
                           floor_score=FloorScore(3, 5, 0, np.array([1.0, 1.0, 0.0, 0.0, 1.0])))
    evaluation = Evaluation.from_outcomes([WalkOutcome(0, "a", None, "ok", results=[causal, offline])], 1, 1.0)
    rows = {row["method"]: row for row in evaluation.summary_rows()}
    assert rows["pf-smooth"]["floor_accuracy"] == pytest.approx(2 / 3)  # waypoints 2-4 only
    assert rows["pf-smooth"]["floor_detection"] == pytest.approx(3 / 5)  # every waypoint of the walk
    assert rows["pf"]["floor_accuracy"] == pytest.approx(2 / 3) and rows["pf"]["floor_detection"] == pytest.approx(2 / 5)
    assert rows["pf-smooth"]["ipin_score"] == pytest.approx(np.percentile([1.0, 1.0, 16.0], 75))
