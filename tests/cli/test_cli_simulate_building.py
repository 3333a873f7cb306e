"""``mapfilter simulate`` over a building: walks that change floor (with a barometer), a
one-floor survey, the same file for a seed, and bad input refused without writing anything."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from mapfilter.cli import main, simulate_cmd
from mapfilter.sensors.ilc import read_ilc
from mapfilter.simulate.building import BuildingSimConfig

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "tools"))
from floor_sim import make_office_building_with_ap_files  # noqa: E402

FAST = ["--segment-s", "4", "6"]


@pytest.fixture(scope="module")
def office3(tmp_path_factory) -> Path:
    """Three stacked office floors (stairs, lift), each map naming its own access-point table."""
    return make_office_building_with_ap_files(tmp_path_factory.mktemp("office3"))


def test_cli_defaults_are_the_librarys():
    config = BuildingSimConfig()
    assert simulate_cmd._BUILDING_DEFAULTS == {"segment_s": config.segment_s, "floor_loss_db": config.floor_loss_db}


def test_a_walk_changes_floor_with_a_barometer_and_reads_back(office3, tmp_path, capsys):
    out = tmp_path / "walk.txt"
    assert main(["simulate", str(office3), "--out", str(out), "--seed", "4", "--floor-changes", "2", *FAST]) == 0
    rec = read_ilc(out)
    floors = rec.waypoint_floor
    assert floors is not None and len(floors) == rec.waypoint_t_s.size
    assert set(floors) <= {"F0", "F1", "F2"}
    assert sum(a != b for a, b in zip(floors, floors[1:])) == 2  # two floor changes
    assert rec.floor_name == floors[0]
    assert rec.pressure_t_s is not None and rec.pressure_t_s.size > 0
    assert np.all((rec.pressure_hpa > 1000.0) & (rec.pressure_hpa < 1014.0))
    assert "TYPE_PRESSURE" in out.read_text()
    assert "pressure rows" in capsys.readouterr().err

    again = tmp_path / "again.txt"
    assert main(["simulate", str(office3), "--out", str(again), "--seed", "4", "--floor-changes", "2", *FAST]) == 0
    assert again.read_bytes() == out.read_bytes()


def test_given_changes_one_table_for_all_floors_and_no_barometer(office3, tmp_path):
    out = tmp_path / "walk.txt.gz"
    assert main(["simulate", str(office3), "--out", str(out), "--seed", "1", "--start-floor", "F0",
                 "--change", "stairs", "F1", "--change", "lift", "F0", "--aps", str(REPO / "maps" / "office_aps.csv"),
                 "--no-barometer", *FAST]) == 0
    rec = read_ilc(out)
    changes = [(a, b) for a, b in zip(rec.waypoint_floor, rec.waypoint_floor[1:]) if a != b]
    assert rec.waypoint_floor[0] == "F0" and changes == [("F0", "F1"), ("F1", "F0")]
    assert rec.pressure_t_s is None or rec.pressure_t_s.size == 0
    # every floor's copy of the table has its own BSSIDs (fourth octet = the floor's number)
    assert {key.split(":")[3] for key in rec.wifi.ap_keys} == {"00", "01", "02"}


def test_a_survey_of_one_floor(office3, tmp_path):
    out = tmp_path / "survey.txt"
    assert main(["simulate", str(office3), "--out", str(out), "--survey", "--floor", "F1", "--survey-spacing", "8",
                 "--scans-per-point", "1"]) == 0
    rec = read_ilc(out)
    assert rec.floor_name == "F1"


@pytest.mark.parametrize("extra, message", [
    (["--start-floor", "F9"], "'F9' is not in the building"),
    (["--change", "stairs", "F9"], "'F9' is not in the building"),
    (["--change", "escalator", "F1"], "no connector 'escalator'"),
    (["--survey", "--floor", "F9"], "'F9' is not in the building"),
    (["--survey"], "pass --floor NAME"),
    (["--duration", "30"], "--duration"),
])
def test_bad_input_is_one_line_naming_the_file_and_writes_nothing(office3, tmp_path, capsys, extra, message):
    out = tmp_path / "walk.txt"
    assert main(["simulate", str(office3), "--out", str(out), *extra]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(office3) in err and message in err
    assert not out.exists()


def test_a_building_without_connectors_cannot_change_floor(office3, tmp_path, capsys):
    meta = yaml.safe_load(office3.read_text())
    del meta["connectors"]
    bare = office3.parent / "no_connectors.yaml"
    bare.write_text(yaml.safe_dump(meta, sort_keys=False))
    out = tmp_path / "walk.txt"
    assert main(["simulate", str(bare), "--out", str(out), "--floor-changes", "1"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(bare) in err and "no connectors" in err
    assert not out.exists()
    # ...but a walk on one floor of it is fine
    assert main(["simulate", str(bare), "--out", str(out), "--floor-changes", "0", "--start-floor", "F2", *FAST]) == 0
    assert set(read_ilc(out).waypoint_floor) == {"F2"}


def test_building_options_with_a_one_floor_map_are_refused(tmp_path, capsys):
    out = tmp_path / "walk.txt"
    assert main(["simulate", str(REPO / "maps" / "office.yaml"), "--out", str(out), "--start-floor", "F1"]) == 1
    assert "one floor" in capsys.readouterr().err
    assert not out.exists()
