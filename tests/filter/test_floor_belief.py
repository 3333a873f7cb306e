"""How sure a building track is of its floor (floor_p), the offline floor from the filter's own
belief, walks over several floors in a building's radio map, and the IPIN competitions' score."""

from __future__ import annotations

import csv
import dataclasses
import math

import numpy as np
import pytest

from mapfilter.errors import MapfilterError
from mapfilter.evaluation.metrics import FloorScore, floor_at_waypoints, ipin_errors_m, ipin_score
from mapfilter.sensors.floor_vote import build_building_radio_map
from mapfilter.sensors.ilc import read_ilc
from mapfilter.simulate.building import BuildingSimConfig, FloorChange, simulate_building_walk
from mapfilter.simulate.ilc_writer import write_ilc
from mapfilter.io.tracks import Track, read_track, write_track_csv

FAST = BuildingSimConfig(segment_s=(12.0, 15.0))


@pytest.fixture(scope="module")
def stairs_walk(office3, tmp_path_factory):
    building, tables = office3
    sim, happened = simulate_building_walk(building, tables, "F0", [FloorChange("stairs", "F1")], FAST,
                                           np.random.default_rng(5))
    path = tmp_path_factory.mktemp("walk") / "walk.txt"
    write_ilc(sim, path)
    return read_ilc(path), happened


# ---- floor_p -----------------------------------------------------------------------------------
def test_floor_p_is_a_probability_higher_on_the_right_floor_and_round_trips(office3, office3_radio_map, stairs_walk,
                                                                             tmp_path):
    """Without the barometer the filter is unsure around the change: floor_p is in [0, 1] on every
    row of both tracks, on average higher at rows on the right floor than on a wrong one, and
    the CSV writes and reads it."""
    from conftest import tracking_config
    from mapfilter.config import FloorsConfig
    from mapfilter.pipeline.tracker import track

    building, _ = office3
    rec, _ = stairs_walk
    config = dataclasses.replace(tracking_config(n_particles=1000, smooth=True),
                                 floors=FloorsConfig(use_barometer=False))
    result = track(building, rec, office3_radio_map, config=config, rng=np.random.default_rng(3))
    truth_t, truth = rec.waypoint_t_s, np.array(rec.waypoint_floor)
    for tr in (result.causal, result.offline):
        assert tr.floor_p is not None and tr.floor_p.shape == (len(tr),)
        assert np.all((tr.floor_p >= 0.0) & (tr.floor_p <= 1.0))
        true_at = truth[np.clip(np.searchsorted(truth_t, tr.t_s, side="right") - 1, 0, None)]
        right = np.array(tr.floor) == true_at
        assert right.mean() > 0.8
        if (~right).any():
            assert tr.floor_p[right].mean() > tr.floor_p[~right].mean()
        else:
            assert tr.floor_p.mean() > 0.5
    # the causal floor_p is the weight share of the estimate's floor: never below 1 / floors
    assert result.causal.floor_p.min() >= 1.0 / 3.0 - 1e-9
    write_track_csv(result.causal, tmp_path / "t.csv")
    with open(tmp_path / "t.csv") as handle:
        assert next(csv.reader(handle))[:5] == ["t_s", "x_m", "y_m", "floor", "floor_p"]
    back = read_track(tmp_path / "t.csv")
    assert np.allclose(back.floor_p, result.causal.floor_p, atol=1e-4)


def test_one_floor_tracks_have_no_floor_p_and_their_csv_is_unchanged(tmp_path):
    track = Track(np.array([0.0, 1.0]), np.array([[0.0, 0.0], [1.0, 1.0]]), std_m=np.array([0.5, 0.5]))
    write_track_csv(track, tmp_path / "t.csv")
    assert (tmp_path / "t.csv").read_text().splitlines()[0] == "t_s,x_m,y_m,std_m"
    assert read_track(tmp_path / "t.csv").floor_p is None


def test_a_floor_p_outside_0_1_is_refused_with_its_line(tmp_path):
    (tmp_path / "t.csv").write_text("t_s,x_m,y_m,floor,floor_p\n0,0,0,F1,0.5\n1,0,0,F1,1.5\n")
    with pytest.raises(MapfilterError, match=r"t\.csv:3: column floor_p is a probability"):
        read_track(tmp_path / "t.csv")


# ---- a walk over several floors in a building's radio map ---------------------------------------
def test_a_walk_over_two_floors_labels_each_scan_by_its_waypoints_floor(office3, stairs_walk):
    """Each scan between two waypoints of one floor is on that floor; scans between a waypoint on
    F0 and one on F1 (on the stairs) are left out; a log without waypoint floors needs its floor."""
    building, _ = office3
    rec, happened = stairs_walk
    assert len(set(rec.waypoint_floor)) == 2
    radio_map = build_building_radio_map([rec], [None], building.floor_names)
    assert set(np.unique(radio_map.floor)) == {0, 1}
    wp_floor = np.array([building.floor_index(f) for f in rec.waypoint_floor])
    k = np.searchsorted(rec.waypoint_t_s, radio_map.t_s, side="right") - 1
    assert np.all(radio_map.floor == wp_floor[k])
    assert np.all(wp_floor[np.minimum(k + 1, wp_floor.size - 1)] == wp_floor[k])
    # the stairs: the time between the last F0 and the first F1 waypoint holds no point
    last_f0 = rec.waypoint_t_s[np.flatnonzero(wp_floor == 0)[-1]]
    first_f1 = rec.waypoint_t_s[np.flatnonzero(wp_floor == 1)[0]]
    assert not np.any((radio_map.t_s > last_f0) & (radio_map.t_s < first_f1))
    one_floor = dataclasses.replace(rec, waypoint_floor=None, floor_name=None)
    with pytest.raises(MapfilterError, match="names no floor"):
        build_building_radio_map([one_floor], [None], building.floor_names)


# ---- the IPIN score ---------------------------------------------------------------------------
def test_the_ipin_score_by_hand():
    """Errors 1, 2, 3, 4 m with the floor off by 0, 1, 0, 2 storeys: 1, 17, 3, 34 m, whose 75th
    percentile (linear between order statistics: 17 + 0.25 (34 - 17)) is 21.25 m."""
    errors = np.array([1.0, 2.0, 3.0, 4.0])
    storeys = np.array([0.0, 1.0, 0.0, 2.0])
    assert list(ipin_errors_m(errors, storeys)) == [1.0, 17.0, 3.0, 34.0]
    assert ipin_score(errors, storeys) == pytest.approx(21.25)
    assert ipin_score(errors) == pytest.approx(np.percentile(errors, 75))
    assert math.isnan(ipin_score(np.zeros(0)))
    # the storeys come from the floors' order, bottom to top
    score = floor_at_waypoints(np.array([0.0, 1.0, 2.0, 3.0]), ["-2", "-1", "0", "-2"], np.array([0.0, 1.0, 2.0, 3.0]),
                               ["-2", "0", "0", "0"], floor_order=["-2", "-1", "0"])
    assert isinstance(score, FloorScore) and (score.n_right, score.n_judged) == (2, 4)
    assert list(score.storeys_off) == [0.0, 1.0, 0.0, 2.0]


def test_evaluate_reports_the_ipin_score_per_method_and_per_phone():
    from mapfilter.evaluation.comparison import Evaluation, MethodResult

    def result(method, phone, errors, storeys):
        return MethodResult(method, f"walk-{phone}", Track(np.zeros(0), np.zeros((0, 2))), np.array(errors), 0, 0,
                            0, 0.0, floor_score=FloorScore(sum(s == 0 for s in storeys), len(storeys), 0,
                                                           np.array(storeys, dtype=float)), phone=phone)

    evaluation = Evaluation([result("kwnn", "A", [1.0, 2.0], [0, 1]), result("kwnn", "B", [3.0, 4.0], [0, 2])], 2, 0.0)
    (row,) = evaluation.summary_rows()
    assert row["ipin_score"] == pytest.approx(21.25) and row["floor_accuracy"] == pytest.approx(0.5)
    by_phone = evaluation.summary_rows(by_phone=True)
    assert [(r["phone"], r["method"]) for r in by_phone] == [("A", "kwnn"), ("B", "kwnn")]
    assert by_phone[0]["ipin_score"] == pytest.approx(np.percentile([1.0, 17.0], 75))


# ---- IPIN 2023, end to end --------------------------------------------------------------------
@pytest.mark.slow
def test_ipin_evaluate_end_to_end_on_real_logs(ipin2023, ipin_venue):
    """Four real logs of both phones and both floors, and the walk from -2 to 0 and back,
    leave-one-out: every building method runs on every walk, the walk over two floors joins
    the radio map and is scored per waypoint, and the numbers are sane (thresholds well above
    what the full evaluation in docs/ipin.md measures)."""
    from conftest import tracking_config
    from mapfilter.evaluation.comparison import EvaluationSetup, evaluate
    from mapfilter.maps.building import Building

    building = Building.load(ipin_venue)
    logs = [ipin2023 / "logs" / f"IPIN2023_T3_TrainingTrial{n}.txt.gz"
            for n in ("01_repetition01", "01_repetition03", "21_repetition02", "21_repetition04", "52_repetition01")]
    # 2,000 particles: at 500 the walk over two floors (12 points) is lost 50-65 m off on most
    # seeds and found once (19 m, seed 0), and that one walk decided the comparison below
    setup = EvaluationSetup(leave_one_out=True, tracking=tracking_config(n_particles=2000, smooth=True))
    evaluation = evaluate(building, logs, setup)
    assert not evaluation.failed
    rows = {r["method"]: r for r in evaluation.summary_rows()}
    assert set(rows) == {"pf", "pf-smooth", "pf-floor", "kwnn", "kf", "pdr", "pdr-start"}
    assert rows["pf-floor"]["traces"] == 4  # the walk over two floors has no one floor to give
    for method in ("pf", "pf-smooth", "kwnn"):
        assert rows[method]["floor_accuracy"] >= 0.8, rows[method]
        assert rows[method]["ipin_score"] >= rows[method]["p75"] - 1e-9
    assert rows["kwnn"]["median"] < 10.0
    # on these open floors (no plan: nothing for the walls to bend) the offline track is the
    # smoothed filter, which uses every scan of the walk: better than the causal track at p75; on
    # the mean within 2 % (five walks, 2,000 particles, seeds 0 and 1: mean 18.8 and 19.4 against
    # 21.6 m, p75 25.1 and 25.5 against 33.2 and 32.9 m)
    assert rows["pf-smooth"]["p75"] < rows["pf"]["p75"], (rows["pf-smooth"], rows["pf"])
    assert rows["pf-smooth"]["mean"] < 1.02 * rows["pf"]["mean"], (rows["pf-smooth"], rows["pf"])
    assert {r["phone"] for r in evaluation.summary_rows(by_phone=True)} == {"SM-A520F", "SM-G930F"}
    trial52 = [r for r in evaluation.results if r.trace.endswith("Trial52_repetition01") and r.method == "pf"]
    assert trial52 and trial52[0].floor_score.n_judged == 12


@pytest.mark.real_data
@pytest.mark.slow
@pytest.mark.parametrize("reach_sigmas", [None, 1e9])
def test_on_an_open_floor_the_offline_track_is_the_smoothed_filter(ipin2023, ipin_venue, reach_sigmas, monkeypatch):
    """IPIN 2023 trial 03 (floor 0, no plan: an open floor): the walk's smoothed track stays far
    from every wall, so the offline track is the smoothed filter, not the dead-reckoned shape
    placed rigidly (its gyro drifts over the 3-minute walk, and no wall bends it back): better than
    the causal track. ``reach_sigmas=1e9`` places the shape anyway, and is worse (the check
    that the test can fail)."""
    import mapfilter.pipeline.offline as tracking
    from mapfilter.api import build_radio_map, read_log, track
    from mapfilter.config import TrackingConfig
    from mapfilter.evaluation.scoring import score_track
    from mapfilter.maps.building import Building

    if reach_sigmas is not None:
        monkeypatch.setattr(tracking, "WALL_REACH_SIGMAS", reach_sigmas)
    building = Building.load(ipin_venue)
    logs = [ipin2023 / "logs" / f"IPIN2023_T3_TrainingTrial0{t}_repetition0{r}.txt.gz"
            for t in (2, 3) for r in (1, 2, 3, 4)]
    walk = read_log(logs[5], building=building)  # trial 03, repetition 02
    radio_map = build_radio_map(building, [path for path in logs if path != logs[5]])
    result = track(building, walk, radio_map, config=TrackingConfig(smooth=True, seed=0).with_particles(5000))
    causal, offline = (score_track(building, walk, tr, None, causal=c).errors.errors_m.mean()
                       for tr, c in ((result.causal, True), (result.offline, False)))
    if reach_sigmas is None:
        assert offline < causal and offline < 4.0, (offline, causal)
    else:
        assert offline > causal, (offline, causal)
