"""Leave-a-group-out protocols: groupings by IPIN trial, regex and CSV, their refusals, and that a
fold's survey material holds nothing of its group."""

from pathlib import Path

import numpy as np
import pytest
from conftest import REPO
from hypothesis import given, settings
from hypothesis import strategies as st

from mapfilter.errors import MapfilterError
from mapfilter.evaluation import comparison
from mapfilter.evaluation.groups import Grouping, by_ipin_trial, by_regex, each_walk, from_csv
from mapfilter.sensors.recording import Beacons, Recording, WifiScans

IPIN_LOGS = [Path(f"logs/IPIN2023_T3_TrainingTrial{t}_repetition{r}.txt.gz")
             for t in ("01", "02", "21", "52") for r in ("01", "02") if (t, r) != ("52", "02")]


def test_ipin_trial_names_group_every_repetition_of_a_trial():
    grouping = by_ipin_trial(IPIN_LOGS)
    assert grouping.group("IPIN2023_T3_TrainingTrial01_repetition02") == "T01"
    assert grouping.members("IPIN2023_T3_TrainingTrial21_repetition01") == [
        "IPIN2023_T3_TrainingTrial21_repetition01", "IPIN2023_T3_TrainingTrial21_repetition02"]
    assert grouping.groups() == ["T01", "T02", "T21", "T52"]
    assert grouping.describe() == "leave-one-route-out (IPIN trials): 4 routes of 1-2 walks"


def test_route_grouping_refuses_in_one_line_a_walk_it_cannot_place():
    with pytest.raises(MapfilterError) as error:
        by_ipin_trial([*IPIN_LOGS, Path("walks/5dd9e7aac5b77e0006b1732b.txt.gz")])
    message = str(error.value)
    assert "\n" not in message and "5dd9e7aac5b77e0006b1732b.txt.gz" in message and "--leave-out-group" in message


def test_regex_groups_by_its_first_group_or_whole_match():
    assert by_regex(IPIN_LOGS, r"Trial(\d+)").group_of == {k: v.replace("T", "") for k, v in
                                                           by_ipin_trial(IPIN_LOGS).group_of.items()}
    whole = by_regex(IPIN_LOGS, r"repetition0[12]")
    assert whole.group("IPIN2023_T3_TrainingTrial02_repetition01") == "repetition01"
    assert len(whole.groups()) == 2 and "groups by" in whole.protocol


@pytest.mark.parametrize("pattern, words", [(r"Trial(\d+", "not a regular expression"),
                                            (r"nowhere(\d)", "does not match"),
                                            (r"Trial()\d", "empty group")])
def test_regex_refusals_are_one_line(pattern, words):
    with pytest.raises(MapfilterError) as error:
        by_regex(IPIN_LOGS, pattern)
    assert words in str(error.value) and "\n" not in str(error.value)


def test_csv_groups_by_file_or_trace_name(tmp_path):
    table = tmp_path / "groups.csv"
    table.write_text("log,group\nwalk0.txt.gz,left\nwalk1,left\n\n/elsewhere/walk2.txt.gz,right\n")
    grouping = from_csv(table, [Path("a/walk0.txt.gz"), Path("walk1.txt.gz"), Path("walk2.txt.gz")])
    assert grouping.group_of == {"walk0": "left", "walk1": "left", "walk2": "right"}
    assert grouping.protocol == "leave-one-group-out (groups from groups.csv)"


@pytest.mark.parametrize("text, words, line", [
    ("trace,group\nwalk0,a\n", "header 'log,group'", 1),
    ("log,group\nwalk0,a\nwalk1\n", "expected 'log,group'", 3),
    ("log,group\nwalk0,a\nwalk1, \n", "expected 'log,group'", 3),
    ("log,group\nwalk0,a\nwalk1,b\nwalk0.txt.gz,b\n", "two groups", 4),
    ("log,group\nwalk0,a\n", "names no group for the log walk1.txt.gz", None),
])
def test_csv_refusals_name_the_file_and_line(tmp_path, text, words, line):
    table = tmp_path / "groups.csv"
    table.write_text(text)
    with pytest.raises(MapfilterError) as error:
        from_csv(table, [Path("walk0.txt.gz"), Path("walk1.txt.gz")])
    assert words in str(error.value) and error.value.path == str(table) and error.value.line == line
    with pytest.raises(MapfilterError, match="cannot read"):
        from_csv(tmp_path / "missing.csv", [Path("walk0.txt.gz")])


def test_a_grouping_refuses_a_walk_it_does_not_name():
    grouping = each_walk([Path("a.txt"), Path("b.txt")])
    assert grouping.members("a") == ["a"] and grouping.unit == "walk"
    with pytest.raises(MapfilterError, match="no group for walk c"):
        grouping.checked(["a", "c"])


# ---- the survey material of a fold --------------------------------------------------------------
MAPS = REPO / "maps"
AP_XY_M = np.array([[3.0, 3.0], [20.0, 4.0], [12.0, 14.0], [30.0, 12.0], [6.0, 16.0], [25.0, 2.0]])


def _walk(name: str, rng: np.random.Generator, ap_ids: np.ndarray) -> Recording:
    """A straight synthetic walk across the office with a scan every 2 s of the APs ``ap_ids``
    (path loss with noise: enough for radio maps and fitted access points)."""
    start, end = rng.uniform([2.0, 2.0], [30.0, 16.0], size=(2, 2))
    wp_t = np.array([0.0, 20.0])
    scan_t = np.arange(1.0, 20.0, 2.0)
    xy = start + (end - start) * (scan_t[:, None] / 20.0)
    rows_scan, rows_ap, rssi = [], [], []
    for s, p in enumerate(xy):
        for a in ap_ids:
            d = max(1.0, float(np.linalg.norm(p - AP_XY_M[a])))
            rows_scan.append(s), rows_ap.append(int(a))
            rssi.append(-40.0 - 20.0 * np.log10(d) + rng.normal(0.0, 2.0))
    keys = [f"aa:bb:cc:dd:ee:{a:02x}@2.4" for a in range(len(AP_XY_M))]
    n = len(rows_scan)
    wifi = WifiScans(scan_t, keys, np.array(rows_scan), np.array(rows_ap), np.array(rssi, np.float32),
                     np.full(n, 2412, np.float32), np.zeros(n, np.float32))
    empty = np.empty((0, 3))
    return Recording(Path(f"{name}.txt"), None, 0.0, wp_t, np.stack([start, end]), np.empty(0), empty, np.empty(0),
                     empty, np.empty(0), empty, np.empty(0), empty, wifi, Beacons(np.empty(0), [], np.empty(0),
                                                                                  np.empty(0)))


@pytest.fixture(scope="module")
def office_building():
    from mapfilter.maps.building import Building

    return Building.load(MAPS / "office.yaml")


@settings(max_examples=15, deadline=None)
@given(groups=st.lists(st.integers(0, 3), min_size=3, max_size=7).filter(lambda g: len(set(g)) >= 2),
       seed=st.integers(0, 2**16))
def test_a_folds_radio_map_and_access_points_hold_nothing_of_its_group(office_building, groups, seed):
    """For any grouping of a few walks: each walk's radio map holds every point of the walks
    outside its group and none of its group's, and its fitted access points are those a fit on
    exactly that map gives (the oracle: fitted again from scratch)."""
    from mapfilter.sensors.pathloss import estimate_access_points
    from mapfilter.sensors.radiomap import build_radio_map

    rng = np.random.default_rng(seed)
    walks = [_walk(f"w{i}", rng, np.sort(rng.choice(len(AP_XY_M), size=4, replace=False)))
             for i in range(len(groups))]
    grouping = Grouping("test", {w.name: f"g{g}" for w, g in zip(walks, groups)})
    setup = comparison.EvaluationSetup(methods=("kwnn", "ls"), groups=grouping)
    plan = office_building.floors[0].plan
    all_walks = comparison._all_walks(office_building, setup, ("kwnn", "ls"), walks, [None] * len(walks))
    for walk, group in zip(walks, groups):
        radio_map, aps = comparison._wifi_sources(walk, setup, all_walks, office_building)
        held = set(np.array(radio_map.source_traces)[np.unique(radio_map.trace)])
        others = [w for w, g in zip(walks, groups) if g != group]
        assert held == {w.name for w in others}
        assert len(radio_map) == len(build_radio_map(others, plan))
        try:
            oracle = estimate_access_points(build_radio_map(others, plan))
        except MapfilterError:
            continue  # too few points to fit any AP without the group: nothing to compare
        fitted = dict(zip(zip(aps.bssid, aps.band), aps.xy_m))
        for key, xy in zip(zip(oracle.bssid, oracle.band), oracle.xy_m):
            np.testing.assert_allclose(fitted[key], xy, atol=1e-6)


@given(groups=st.lists(st.integers(0, 9), min_size=2, max_size=30).filter(lambda g: len(set(g)) >= 2))
def test_a_groups_walks_grow_in_one_fold(groups):
    """Self-training left out by group: every walk of a group in one fold (the fold whose grown
    points it is scored with was grown over a survey without any walk of its group)."""
    names = [f"w{i}" for i in range(len(groups))]
    setup = comparison.EvaluationSetup(groups=Grouping("test", {n: str(g) for n, g in zip(names, groups)}))
    folds, fold = comparison.growth_folds(setup, names)
    assert folds == min(4, len(set(groups))) and fold.min() >= 0 and fold.max() < folds
    for g in set(groups):
        assert len({int(f) for f, h in zip(fold, groups) if h == g}) == 1
    assert len(set(fold.tolist())) == folds  # no fold without walks
