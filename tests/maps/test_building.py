"""The building format: floors placed in one frame, connectors, validation, ILC site import."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path


import numpy as np
import pytest
import yaml

from mapfilter.cli import main
from mapfilter.errors import MapfilterError
from mapfilter.maps.building import Building, Floor, import_ilc_site, storey_of_floor_name
from mapfilter.maps.floorplan import FloorPlan

MAPS = Path(__file__).resolve().parents[2] / "maps"


def _floor_map(path: Path, size_px: int = 40, resolution_m: float = 0.5, wall_box=None) -> Path:
    """A square floor with a wall border (and optionally a wall box (r0, r1, c0, c1) inside)."""
    mask = np.zeros((size_px, size_px), dtype=bool)
    mask[0, :] = mask[-1, :] = mask[:, 0] = mask[:, -1] = True
    if wall_box is not None:
        r0, r1, c0, c1 = wall_box
        mask[r0:r1, c0:c1] = True
    FloorPlan(mask, resolution_m, (0.0, 0.0)).save(path)
    return path


def _building_yaml(tmp_path: Path, offsets=((0, 0), (0, 0)), connectors=None, extra=None) -> Path:
    _floor_map(tmp_path / "g.yaml")
    _floor_map(tmp_path / "u.yaml")
    meta = {"building": "test", "floors": [
        {"name": "G", "map": "g.yaml", "elevation_m": 0.0, "offset_m": list(offsets[0])},
        {"name": "U", "map": "u.yaml", "elevation_m": 4.0, "offset_m": list(offsets[1])}]}
    if connectors is not None:
        meta["connectors"] = connectors
    meta.update(extra or {})
    path = tmp_path / "building.yaml"
    path.write_text(yaml.safe_dump(meta))
    return path


STAIRS = {"name": "stairs", "kind": "stairs",
          "floors": {"G": [[2, 2], [5, 2], [5, 5], [2, 5]], "U": [[2, 2], [5, 2], [5, 5], [2, 5]]}}


def test_a_map_yaml_is_a_one_floor_building():
    building = Building.load(MAPS / "office.yaml")
    plan = FloorPlan.load(MAPS / "office.yaml")
    assert building.floor_names == ["office"] and building.is_single_floor
    assert np.array_equal(building.floors[0].plan.wall_mask, plan.wall_mask)
    # a map that names its floor refuses a log of another floor (a walk of floor F7 tracked on this
    # plan goes wrong by the floors' distance), unless the user gives the floor; a map that names
    # no floor takes every log
    assert building.floor_of_log("office", "walk.txt") == 0 and building.floor_of_log(None, "walk.txt") == 0
    with pytest.raises(MapfilterError, match=r"walk\.txt: floor 'F7' is not in the building .*--floor NAME"):
        building.floor_of_log("F7", "walk.txt")
    assert building.floor_of_log("F7", "walk.txt", given="office") == 0
    unnamed = Building.from_plan(dataclasses.replace(plan, floor_name=None))
    assert unnamed.floor_of_log("F7", "walk.txt") == 0


def test_building_round_trips_with_connectors(tmp_path):
    path = _building_yaml(tmp_path, offsets=((0, 0), (1.5, -2.0)), connectors=[STAIRS])
    building = Building.load(path)
    assert building.floor_names == ["G", "U"]
    assert building.floors[1].elevation_m == 4.0 and building.floors[1].offset_m == (1.5, -2.0)
    assert [c.name for c in building.connectors] == ["stairs"]
    building.save(tmp_path / "again.yaml")
    again = Building.load(tmp_path / "again.yaml")
    assert again.floor_names == building.floor_names and again.floors[1].offset_m == (1.5, -2.0)
    assert again.connectors[0].polygons["U"].equals(building.connectors[0].polygons["U"])


def test_floor_frame_and_building_frame_are_inverse():
    floor = Floor("F", FloorPlan(np.zeros((4, 4), bool), 1.0), 0.0, (3.0, -1.0), math.radians(30.0))
    xy = np.random.default_rng(0).uniform(-50, 50, (100, 2))
    assert np.allclose(floor.from_building(floor.to_building(xy)), xy)
    # the floor frame's x axis points 30 degrees counter-clockwise in the building frame
    assert np.allclose(floor.to_building(np.array([1.0, 0.0])) - floor.offset_m,
                       [math.cos(math.radians(30)), math.sin(math.radians(30))])


def test_connectors_from_geojson(tmp_path):
    features = [{"type": "Feature", "properties": {"name": "lift", "kind": "lift", "floor": name},
                 "geometry": {"type": "Polygon", "coordinates": [[[10, 10], [12, 10], [12, 12], [10, 12], [10, 10]]]}}
                for name in ("G", "U")]
    (tmp_path / "conn.geojson").write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    building = Building.load(_building_yaml(tmp_path, extra={"connectors_geojson": "conn.geojson"}))
    assert [(c.name, c.kind, sorted(c.polygons)) for c in building.connectors] == [("lift", "lift", ["G", "U"])]


@pytest.mark.parametrize("case, message", [
    ("apart", "overlaps no other floor"),
    ("outside", "lies outside floor"),
    ("unknown", "unknown floor"),
    ("one_floor", "at least two"),
    ("kind", "kind must be one of"),
])
def test_bad_buildings_are_one_line_naming_the_file(tmp_path, case, message):
    offsets, connectors = ((0, 0), (0, 0)), [STAIRS]
    if case == "apart":
        offsets = ((0, 0), (500, 0))  # the floors are 20 m wide
    elif case == "outside":
        connectors = [dict(STAIRS, floors={"G": STAIRS["floors"]["G"], "U": [[100, 100], [103, 100], [103, 103]]})]
    elif case == "unknown":
        connectors = [dict(STAIRS, floors={"G": STAIRS["floors"]["G"], "F9": STAIRS["floors"]["U"]})]
    elif case == "one_floor":
        connectors = [dict(STAIRS, floors={"G": STAIRS["floors"]["G"]})]
    elif case == "kind":
        connectors = [dict(STAIRS, kind="slide")]
    path = _building_yaml(tmp_path, offsets=offsets, connectors=connectors)
    with pytest.raises(MapfilterError) as info:
        Building.load(path)
    text = str(info.value)
    assert message in text and str(path) in text and "\n" not in text


def test_a_log_floor_not_in_the_building_is_refused(tmp_path):
    building = Building.load(_building_yaml(tmp_path))
    assert building.floor_of_log("U", "w.txt") == 1 and building.floor_of_log(None, "w.txt") is None
    with pytest.raises(MapfilterError, match=r"w\.txt: floor 'F3' is not in the building"):
        building.floor_of_log("F3", "w.txt")


def test_storeys_from_floor_names():
    assert [storey_of_floor_name(n) for n in ("B2", "B1", "F1", "F2", "L3", "G", "3F", "roof")] == \
        [-2, -1, 0, 1, 2, 0, 2, None]


def test_ilc_site_floors_are_placed_by_their_longitudes_and_latitudes(ilc_site1):
    building = import_ilc_site(ilc_site1, resolution_m=1.0)
    assert building.floor_names == ["B1", "F1", "F2", "F3", "F4"]
    offsets = {f.name: f.offset_m for f in building.floors}
    # the data README: B1 starts about 68 m west and 54 m south of F1, F3 and F4 2.8 m south
    assert offsets["F1"] == (0.0, 0.0)
    assert abs(offsets["B1"][0] + 68) < 1.0 and abs(offsets["B1"][1] + 54) < 1.0
    for name in ("F3", "F4"):
        assert abs(offsets[name][0]) < 0.5 and abs(offsets[name][1] + 2.8) < 0.5
    assert [f.elevation_m for f in building.floors] == [-5.0, 0.0, 5.0, 10.0, 15.0]


def test_import_ilc_site_cli_writes_a_building_and_a_map_per_floor(ilc_site1, tmp_path, capsys):
    out = tmp_path / "site1.yaml"
    assert main(["map", "import-ilc", str(ilc_site1), "--resolution", "1.0", "--out", str(out)]) == 0
    building = Building.load(out)
    assert building.floor_names == ["B1", "F1", "F2", "F3", "F4"]
    assert all((tmp_path / f"site1_{n}.yaml").is_file() and (tmp_path / f"site1_{n}.png").is_file()
               for n in building.floor_names)


def test_import_ilc_site_bad_storey_height_writes_nothing(ilc_site1, tmp_path, capsys):
    out = tmp_path / "site1.yaml"
    with pytest.raises(SystemExit) as exited:  # argparse refuses it: its usage line, then the error
        main(["map", "import-ilc", str(ilc_site1), "--storey-height", "-1", "--out", str(out)])
    assert exited.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "argument --storey-height: must be above 0, got -1" in err.splitlines()[-1]
    assert list(tmp_path.iterdir()) == []
