"""Access-point tables that cannot be (bad columns, an AP a world away), and the AP fit and
trilateration on readings no phone reports (the cause of scipy's "Initial guess is outside of
provided bounds")."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from mapfilter.cli import main
from mapfilter.errors import MapfilterError
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.sensors.pathloss import (
    AccessPointTable,
    ApFitConfig,
    access_points_for_map,
    check_access_points_on_map,
    estimate_access_points,
    least_squares_position,
    rssi_weighted_centroid,
)
from mapfilter.sensors.radiomap import RadioMap
from mapfilter.sensors.wifi import WifiScan

MAPS = Path(__file__).resolve().parents[2] / "maps"


def _table_with(tmp_path: Path, line: int, column: str, value: str, name: str = "aps.csv") -> Path:
    rows = (MAPS / "office_aps.csv").read_text().splitlines()
    header = rows[0].split(",")
    fields = rows[line - 1].split(",")
    fields[header.index(column)] = value
    rows[line - 1] = ",".join(fields)
    path = tmp_path / name
    path.write_text("\n".join(rows) + "\n")
    return path


@pytest.mark.parametrize("column, value, message", [
    ("n", "0", "column n is 0, outside the 0.5 to 10"),
    ("d_max", "-1", "column d_max is -1, outside the 0 to 10000"),
    ("C", "1e9", "column C is 1e+09, outside the -120 to 20"),
    ("alpha", "-0.5", "column alpha is -0.5, outside the 0 to 10"),
    ("x", "1e300", "column x is 1e+300, outside"),
])
def test_columns_that_make_no_sense_are_refused_with_their_line(tmp_path, column, value, message):
    path = _table_with(tmp_path, 4, column, value)
    with pytest.raises(MapfilterError, match=re.escape(message)) as info:
        AccessPointTable.read_csv(path)
    assert info.value.path == str(path) and info.value.line == 4


def test_an_access_point_far_off_the_map_is_refused_where_table_and_map_meet(tmp_path, capsys):
    plan = FloorPlan.load(MAPS / "office.yaml")
    table = AccessPointTable.read_csv(MAPS / "office_aps.csv")
    check_access_points_on_map(table, plan)  # the bundled table belongs to the bundled map
    far = _table_with(tmp_path, 5, "x", "1000000")  # 1000 km east
    with pytest.raises(MapfilterError, match=r"lies 1e\+03 km outside the map .*office.yaml") as info:
        access_points_for_map(far, plan, MAPS / "office.yaml")
    assert info.value.path == str(far) and info.value.line == 5
    # 400 m off is an access point of the next building: allowed
    check_access_points_on_map(AccessPointTable.read_csv(_table_with(tmp_path, 5, "y", "-400", "near.csv")), plan)
    # the commands that read a table with a map refuse it in one line, before any work
    out = tmp_path / "walk.txt"
    assert main(["simulate", str(MAPS / "office.yaml"), "--aps", str(far), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"mapfilter: error: {far}:5: access point") and err.count("\n") == 1
    assert not out.exists()


def test_the_centroid_is_the_plain_formula_and_finite_for_any_finite_reading():
    rng = np.random.default_rng(3)
    xy, rssi = rng.uniform(0, 50, (4, 2)), rng.uniform(-95, -30, 4)
    weight = 10.0 ** (rssi / 20.0)
    np.testing.assert_array_equal(rssi_weighted_centroid(xy, rssi), (xy * weight[:, None]).sum(axis=0) / weight.sum())
    for absurd in (1e300, 1e30, -7000.0):
        rssi_bad = rssi.copy()
        rssi_bad[0] = absurd
        centre = rssi_weighted_centroid(xy, rssi_bad)
        assert np.all(np.isfinite(centre))
        if absurd > 0:  # the absurdly strong reading wins outright
            np.testing.assert_allclose(centre, xy[0])


def _survey():
    rng = np.random.default_rng(7)
    true_xy = np.array([[10.0, 10.0], [40.0, 12.0], [25.0, 35.0]])
    keys = [f"02:00:00:00:00:0{i}@2.4" for i in range(3)]
    xy = np.concatenate([np.column_stack([np.linspace(0, 50, 120), np.full(120, y)]) for y in (5.0, 20.0, 30.0)])
    d = np.maximum(np.linalg.norm(xy[:, None, :] - true_xy[None], axis=-1), 1.0)
    rssi = (-40.0 - 22.0 * np.log10(d) - 0.4 * np.minimum(d, 30.0) + rng.normal(0, 4.0, d.shape)).astype(np.float32)
    return xy, keys, rssi


@pytest.mark.parametrize("absurd", [np.inf, 1e30, -1e30])
def test_a_reading_no_phone_reports_does_not_break_the_ap_fit(absurd):
    """A log row of 1e300 dBm became an infinite RSSI, a NaN start, and scipy's "Initial guess is
    outside of provided bounds"; such readings are left out of the fit like unheard ones."""
    xy, keys, rssi = _survey()
    clean = RadioMap(xy, keys, rssi, np.arange(len(xy), dtype=float), np.zeros(len(xy)), ["syn"])
    bad_rssi = rssi.copy()
    strongest = int(np.nanargmax(bad_rssi[:, 0]))
    bad_rssi[strongest, 0] = absurd
    without = rssi.copy()
    without[strongest, 0] = np.nan
    bad = RadioMap(xy, keys, bad_rssi, clean.t_s, clean.trace, ["syn"])
    reference = RadioMap(xy, keys, without, clean.t_s, clean.trace, ["syn"])
    fitted, expected = estimate_access_points(bad, ApFitConfig()), estimate_access_points(reference, ApFitConfig())
    assert fitted.keys == expected.keys == keys
    np.testing.assert_array_equal(fitted.xy_m, expected.xy_m)
    np.testing.assert_array_equal(fitted.n, expected.n)


def test_trilateration_leaves_out_an_infinite_reading():
    table = AccessPointTable.read_csv(MAPS / "office_aps.csv")
    keys = table.keys[:6]
    expected = table.expected_rssi_dbm(np.array([[10.0, 8.0]]))[0, :6]
    scan = WifiScan(0.0, tuple(keys), expected.astype(np.float32))
    scan_bad = WifiScan(0.0, tuple(keys), np.concatenate([[np.inf], expected[1:]]).astype(np.float32))
    scan_rest = WifiScan(0.0, tuple(keys[1:]), expected[1:].astype(np.float32))
    assert np.linalg.norm(least_squares_position(table, scan) - [10.0, 8.0]) < 0.5
    np.testing.assert_array_equal(least_squares_position(table, scan_bad), least_squares_position(table, scan_rest))
