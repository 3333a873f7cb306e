"""io/tables.py: beacon and access-point tables read within a bound, and the csv module's field
limit as one line naming the file and line (beacon tables, access-point tables, track files)."""

from __future__ import annotations

import csv

import pytest

from mapfilter.errors import MapfilterError
from mapfilter.io.tables import MAX_TABLE_BYTES
from mapfilter.io.tracks import read_track
from mapfilter.sensors.beacons import BeaconTable
from mapfilter.sensors.pathloss import AccessPointTable

LONG = "7" * (csv.field_size_limit() + 70_000)  # a 200 kB field


def test_a_table_over_the_bound_is_refused(tmp_path):
    """One row, then zeros to a byte past the bound (a sparse file): one line naming the file."""
    path = tmp_path / "beacons.csv"
    path.write_text("beacon_id,x,y\nbe:ac:01,1,2\n")
    with path.open("r+b") as handle:
        handle.truncate(MAX_TABLE_BYTES + 1)
    with pytest.raises(MapfilterError, match=f"beacon table larger than {MAX_TABLE_BYTES >> 20} MiB") as error:
        BeaconTable.read_csv(path)
    assert str(error.value).startswith(f"{path}: ")
    path.rename(tmp_path / "aps.csv")
    with pytest.raises(MapfilterError, match="access-point table larger than"):
        AccessPointTable.read_csv(tmp_path / "aps.csv")
    (tmp_path / "aps.csv").write_text("bssid,x,y\n02:00:00:00:00:01,1,2\n")
    with (tmp_path / "aps.csv").open("r+b") as handle:
        handle.truncate(MAX_TABLE_BYTES)  # at the bound: read (and refused for its zeros, not its size)
    with pytest.raises(MapfilterError, match="binary data"):
        AccessPointTable.read_csv(tmp_path / "aps.csv")


@pytest.mark.parametrize("row", [f"be:ac:01,{LONG},2\n", f'be:ac:01,"{LONG}",2\n'])
def test_a_beacon_field_over_the_csv_limit_is_one_line_with_its_line(tmp_path, row):
    path = tmp_path / "beacons.csv"
    path.write_text("beacon_id,x,y\nbe:ac:00,1,2\n" + row)
    with pytest.raises(MapfilterError, match="field longer than 131072 characters") as error:
        BeaconTable.read_csv(path)
    assert str(error.value).startswith(f"{path}:3: ")


def test_an_access_point_field_over_the_csv_limit_is_one_line_with_its_line(tmp_path):
    path = tmp_path / "aps.csv"
    path.write_text(f"bssid,x,y\n02:00:00:00:00:01,1,2\n02:00:00:00:00:02,{LONG},2\n")
    with pytest.raises(MapfilterError, match="field longer than") as error:
        AccessPointTable.read_csv(path)
    assert str(error.value).startswith(f"{path}:3: ")


def test_a_track_line_over_the_csv_limit_is_one_line_with_its_line(tmp_path, capsys):
    """`check --at` with a track of one long line: its file and line, no traceback."""
    from mapfilter.cli import main
    from tests.conftest import REPO

    path = tmp_path / "track.csv"
    path.write_text(f"t_s,x_m,y_m\n1.0,2.0,3.0\n{LONG},1,2\n")
    with pytest.raises(MapfilterError, match="field longer than") as error:
        read_track(path)
    assert str(error.value).startswith(f"{path}:3: ")
    assert main(["check", str(REPO / "maps" / "office_walk.txt.gz"), "--truth", str(tmp_path / "gt.csv"), "--at",
                 str(path)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{path}:3: " in err and not (tmp_path / "gt.csv").exists()
