"""Map preparation: each kind of plan on small synthetic plans, the ILC floors, the bundled
example, and bad inputs (one-line errors naming the file, nothing written)."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from scipy import ndimage

from mapfilter.cli import main as cli_main
from mapfilter.errors import MapfilterError
from mapfilter.maps import prepare as mapprep
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.drawing import DrawingOptions
from mapfilter.maps.prepare import PlanScale, RegionOptions
from mapfilter.sensors.ilc import read_ilc

REPO = Path(__file__).resolve().parents[2]


def _free_components(plan: FloorPlan) -> int:
    return ndimage.label(~plan.wall_mask, structure=np.ones((3, 3)))[1]


# ---- synthetic line drawing -----------------------------------------------------------------
def _two_rooms_png(path: Path) -> None:
    """200x100 px, 0.1 m/px: two rooms side by side (walls 3 px, anti-aliased), a 12 px door
    between them, a 2 px scan break in the bottom wall, a text label and specks."""
    image = np.full((100, 200), 255, dtype=np.uint8)
    cv2.rectangle(image, (10, 10), (189, 89), 0, 3, cv2.LINE_AA)
    cv2.line(image, (100, 10), (100, 89), 0, 3, cv2.LINE_AA)
    image[44:56, 97:104] = 255  # the door: rows 44..55 of the partition
    image[87:93, 60:62] = 255  # a 2 px break in the bottom wall (scan defect)
    cv2.putText(image, "Lab", (30, 55), cv2.FONT_HERSHEY_SIMPLEX, 0.4, 30, 1, cv2.LINE_AA)
    for u, v in [(150, 30), (160, 70), (40, 75)]:
        cv2.circle(image, (u, v), 1, 0, -1)
    cv2.imwrite(str(path), image)


def test_lines_two_rooms(tmp_path: Path):
    _two_rooms_png(tmp_path / "rooms.png")
    plan = mapprep.prepare_lines(tmp_path / "rooms.png", PlanScale(resolution_m=0.1))
    assert plan.shape_px == (100, 200) and plan.resolution_m == 0.1 and plan.origin_m == (0.0, 0.0)
    wall = plan.wall_mask
    assert wall[10, 50] and wall[89, 150] and wall[30, 100] and wall[70, 100]  # walls, partition
    assert not wall[50, 55] and not wall[50, 150]  # room interiors
    assert not wall[50, 95:106].any()  # the door (rows 44..55 of the partition) is open
    assert wall[90, 61]  # the break in the bottom wall was closed...
    assert wall[0, 0] and wall[95, 100] and wall[50, 5]  # ...so the outside is wall
    assert not wall[40:60, 28:65].any()  # the label is gone
    assert not wall[70, 160] and not wall[30, 150]  # and the specks
    assert _free_components(plan) == 1  # two rooms joined by the door
    assert plan.source_image.path == (tmp_path / "rooms.png").resolve()


def test_lines_keep_outside_leaves_the_outside_and_the_break_free(tmp_path: Path):
    _two_rooms_png(tmp_path / "rooms.png")
    plan = mapprep.prepare_lines(tmp_path / "rooms.png", PlanScale(resolution_m=0.1),
                                 DrawingOptions(outside_is_wall=False))
    assert not plan.wall_mask[0, 0] and not plan.wall_mask[95, 100] and not plan.wall_mask[90, 61]
    assert plan.wall_mask[10, 50] and plan.wall_mask[30, 100]


def test_lines_thicken_and_keep_text(tmp_path: Path):
    _two_rooms_png(tmp_path / "rooms.png")
    thin = mapprep.prepare_lines(tmp_path / "rooms.png", PlanScale(resolution_m=0.1))
    thick = mapprep.prepare_lines(tmp_path / "rooms.png", PlanScale(resolution_m=0.1), DrawingOptions(thicken_px=2))
    assert thick.wall_mask.sum() > thin.wall_mask.sum() and (thick.wall_mask | ~thin.wall_mask).all()
    texty = mapprep.prepare_lines(tmp_path / "rooms.png", PlanScale(resolution_m=0.1), DrawingOptions(remove_text_px=0))
    assert texty.wall_mask[40:60, 28:65].any()


def test_lines_adaptive_threshold_on_uneven_scan(tmp_path: Path):
    """A scan darkening to one side: the adaptive threshold still finds the walls."""
    _two_rooms_png(tmp_path / "rooms.png")
    image = cv2.imread(str(tmp_path / "rooms.png"), cv2.IMREAD_GRAYSCALE).astype(np.float64)
    shade = np.linspace(1.0, 0.45, image.shape[1])[None, :]  # paper from 255 down to ~115
    cv2.imwrite(str(tmp_path / "shaded.png"), (image * shade).round().astype(np.uint8))
    plan = mapprep.prepare_lines(tmp_path / "shaded.png", PlanScale(resolution_m=0.1),
                                 DrawingOptions(threshold="adaptive", adaptive_block_px=31))
    assert plan.wall_mask[10, 180] and plan.wall_mask[30, 100] and not plan.wall_mask[50, 150]
    assert not plan.wall_mask[50, 55] and _free_components(plan) == 1


def test_lines_map_resolution_resamples(tmp_path: Path):
    _two_rooms_png(tmp_path / "rooms.png")
    plan = mapprep.prepare_lines(tmp_path / "rooms.png", PlanScale(resolution_m=0.1), map_resolution_m=0.2)
    assert plan.shape_px == (50, 100) and plan.resolution_m == 0.2
    assert plan.source_image.resolution_m == 0.1
    assert _free_components(plan) == 1 and plan.wall_mask[15, 50]  # door open, partition kept


def _resample_plain(wall: np.ndarray, r_in: float, r_out: float) -> np.ndarray:
    """Oracle: an output cell is wall if any input wall pixel square overlaps its square."""
    rows_in, cols_in = wall.shape
    rows_out, cols_out = round(rows_in * r_in / r_out), round(cols_in * r_in / r_out)
    out = np.zeros((rows_out, cols_out), dtype=bool)
    height_in = rows_in * r_in
    for r in range(rows_out):
        for c in range(cols_out):
            x0, x1 = c * r_out, (c + 1) * r_out
            y0, y1 = (rows_out - r - 1) * r_out, (rows_out - r) * r_out  # metres from the bottom
            for i, j in zip(*np.nonzero(wall)):
                px0, px1 = j * r_in, (j + 1) * r_in
                py0, py1 = height_in - (i + 1) * r_in, height_in - i * r_in
                if px0 < x1 - 1e-9 and px1 > x0 + 1e-9 and py0 < y1 - 1e-9 and py1 > y0 + 1e-9:
                    out[r, c] = True
                    break
    return out


@pytest.mark.parametrize("r_out", [0.2, 0.25, 0.3])
def test_resample_wall_mask_matches_plain_overlap(r_out: float):
    wall = np.random.default_rng(5).random((13, 17)) < 0.08
    np.testing.assert_array_equal(mapprep.resample_wall_mask(wall, 0.1, r_out), _resample_plain(wall, 0.1, r_out))


# ---- scale ----------------------------------------------------------------------------------
def test_scale_sources_agree_and_disagree():
    shape = (100, 200)
    assert PlanScale(resolution_m=0.05).resolve(shape) == 0.05
    assert PlanScale(size_m=(10.0, 5.0)).resolve(shape) == pytest.approx(0.05)
    assert PlanScale(size_m=(10.0, None)).resolve(shape) == pytest.approx(0.05)
    points = PlanScale(points_px=((10, 10), (40, 50)), points_distance_m=5.0)  # 50 px apart
    assert points.resolve(shape) == pytest.approx(0.1)
    assert PlanScale(0.1, (20.0, 10.0), ((10, 10), (40, 50)), 5.0).resolve(shape) == pytest.approx(0.1)
    with pytest.raises(MapfilterError, match="no scale"):
        PlanScale().resolve(shape)
    with pytest.raises(MapfilterError, match="contradictory"):
        PlanScale(resolution_m=0.1, size_m=(10.0, 5.0)).resolve(shape)
    with pytest.raises(MapfilterError, match="contradictory"):
        PlanScale(size_m=(10.0, 8.0)).resolve(shape)  # non-square pixels
    with pytest.raises(MapfilterError, match="distance"):
        PlanScale(points_px=((0, 0), (1, 1))).resolve(shape)
    with pytest.raises(MapfilterError, match="coincide"):
        PlanScale(points_px=((3, 3), (3, 3)), points_distance_m=1.0).resolve(shape)
    with pytest.raises(MapfilterError, match="positive"):
        PlanScale(resolution_m=-0.1).resolve(shape)


# ---- filled regions -------------------------------------------------------------------------
def _regions_png(path: Path) -> None:
    """120x80 px RGBA: transparent corridor, a light-blue shop with a 2 px darker outline, a
    second shop in pale yellow, grey text in the corridor."""
    image = np.zeros((80, 120, 4), dtype=np.uint8)  # all transparent
    blue, outline, yellow, grey = (245, 235, 195, 255), (177, 167, 117, 255), (180, 240, 250, 255), (102, 102, 102, 255)
    image[10:50, 10:60] = outline
    image[12:48, 12:58] = blue
    image[10:50, 70:110] = yellow
    cv2.putText(image, "ab", (30, 70), cv2.FONT_HERSHEY_SIMPLEX, 0.4, grey, 1, cv2.LINE_8)
    cv2.imwrite(str(path), image)


def test_regions_transparent_walkable(tmp_path: Path):
    _regions_png(tmp_path / "mall.png")  # the corridor reaches the image's edge: the outside kept free
    plan = mapprep.prepare_regions(tmp_path / "mall.png", PlanScale(size_m=(36.0, 24.0)),
                                   RegionOptions(remove_below_px=0, open_outlines_px=0, outside_is_wall=False))
    assert plan.resolution_m == pytest.approx(0.3)
    wall = plan.wall_mask
    assert not wall[5, 5] and not wall[60, 5]  # corridor
    assert wall[30, 30] and wall[10, 30] and wall[30, 90]  # shop, its outline, the other shop
    assert wall[60:75, 25:50].any()  # text kept without clean-up
    for options in (RegionOptions(remove_below_px=100, open_outlines_px=2, outside_is_wall=False),
                    RegionOptions(outside_is_wall=False)):  # given, and measured by default
        cleaned = mapprep.prepare_regions(tmp_path / "mall.png", PlanScale(size_m=(36.0, 24.0)), options)
        wall = cleaned.wall_mask
        assert not wall[60:75, 25:50].any()  # text in the corridor removed
        assert not wall[10, 30] and not wall[11, 30] and not wall[30, 10]  # outline walkable
        assert wall[13, 30] and wall[30, 30] and wall[30, 90]  # shops stay walls
        assert _free_components(cleaned) == 1
    assert mapprep.outline_width_px(mapprep.read_plan_image(tmp_path / "mall.png"), ~wall) in (0, 2)


def test_regions_colour_list_with_tolerance(tmp_path: Path):
    _regions_png(tmp_path / "mall.png")
    # the yellow shop walkable too (given as #rrggbb a few levels off), plus transparent
    plan = mapprep.prepare_regions(tmp_path / "mall.png", PlanScale(resolution_m=0.3),
                                   RegionOptions(walkable=("transparent", "#f8eeb8"), tolerance=10,
                                                 outside_is_wall=False))
    assert not plan.wall_mask[30, 90] and plan.wall_mask[30, 30]
    plan = mapprep.prepare_regions(tmp_path / "mall.png", PlanScale(resolution_m=0.3),
                                   RegionOptions(walkable=("195,235,245",), tolerance=0,
                                                 outside_is_wall=False))  # only the blue
    assert not plan.wall_mask[30, 30] and plan.wall_mask[5, 5]
    with pytest.raises(MapfilterError, match="bad colour"):
        mapprep.prepare_regions(tmp_path / "mall.png", PlanScale(resolution_m=0.3), RegionOptions(walkable=("blue",)))


# ---- GeoJSON --------------------------------------------------------------------------------
LAT0, LON0 = 30.0, 120.0


def _lonlat(x_m: float, y_m: float) -> list[float]:
    """Inverse of the ILC projection around (LON0, LAT0) with scale cos(LAT0) (near enough:
    the test floor is small, so cos(mean latitude) differs from cos(LAT0) by < 1e-6)."""
    k = math.cos(math.radians(LAT0))
    r = mapprep.EARTH_RADIUS_M * k
    lon = LON0 + math.degrees(x_m / r)
    y0 = math.log(math.tan(math.pi / 4 + math.radians(LAT0) / 2))
    lat = math.degrees(2 * math.atan(math.exp(y0 + y_m / r)) - math.pi / 2)
    return [lon, lat]


def _square(x0, y0, x1, y1, f=_lonlat):
    return [[f(x0, y0), f(x1, y0), f(x1, y1), f(x0, y1), f(x0, y0)]]


def _floor_geojson(path: Path, f=_lonlat) -> None:
    """A 40 m x 20 m floor with one 10 m x 6 m shop in the middle."""
    features = [
        {"type": "Feature", "properties": {"type": "floor"},
         "geometry": {"type": "MultiPolygon", "coordinates": [_square(0, 0, 40, 20, f)]}},
        {"type": "Feature", "properties": {"name": "shop"},
         "geometry": {"type": "Polygon", "coordinates": _square(15, 7, 25, 13, f)}},
        {"type": "Feature", "properties": {"name": "a door"},
         "geometry": {"type": "LineString", "coordinates": [f(0, 0), f(1, 1)]}},
    ]
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))


def test_geojson_lonlat_floor(tmp_path: Path):
    _floor_geojson(tmp_path / "floor.json")
    floor = mapprep.read_geojson_floor(tmp_path / "floor.json")
    x0, y0, x1, y1 = floor.outline.bounds
    assert (x0, y0) == (0.0, 0.0) and x1 == pytest.approx(40.0, abs=1e-3) and y1 == pytest.approx(20.0, abs=1e-3)
    plan = mapprep.prepare_geojson(tmp_path / "floor.json", 0.5, margin_m=2.0)
    assert plan.shape_px == (48, 88) and plan.origin_m == pytest.approx((-2.0, -2.0))
    free = plan.is_free(np.array([[5.0, 5.0], [20.0, 10.0], [-1.0, 10.0], [41.0, 10.0], [20.0, 21.0], [14.8, 10.0]]))
    assert free.tolist() == [True, False, False, False, False, True]  # corridor, shop, outside x3, beside the shop
    assert plan.wall_mask[:4].all() and plan.wall_mask[:, :4].all()  # the margin is outside: wall
    inset = mapprep.prepare_geojson(tmp_path / "floor.json", 0.5, obstacle_inset_m=1.0)
    assert inset.is_free(np.array([[15.5, 10.0], [20.0, 10.0]])).tolist() == [True, False]


def test_geojson_metres(tmp_path: Path):
    _floor_geojson(tmp_path / "floor.json", f=lambda x, y: [x + 1000.0, y + 500.0])
    plan = mapprep.prepare_geojson(tmp_path / "floor.json", 0.25, units="m")
    assert plan.origin_m == (1000.0, 500.0) and plan.shape_px == (80, 160)
    assert plan.is_free(np.array([[1005.0, 505.0], [1020.0, 510.0]])).tolist() == [True, False]
    with pytest.raises(MapfilterError, match="longitude"):
        mapprep.prepare_geojson(tmp_path / "floor.json", 0.25, units="lonlat")


def test_geojson_without_a_resolution_takes_the_default_and_needs_polygons(tmp_path: Path):
    _floor_geojson(tmp_path / "floor.json")
    plan = mapprep.prepare_geojson(tmp_path / "floor.json", None)
    assert plan.resolution_m == mapprep.DEFAULT_GEOJSON_RESOLUTION_M == 0.1
    assert plan.shape_px == mapprep.prepare_geojson(tmp_path / "floor.json", 0.1).shape_px
    (tmp_path / "lines.json").write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {}, "geometry": {"type": "LineString", "coordinates": [[0, 0], [1, 1]]}}]}))
    with pytest.raises(MapfilterError, match="no polygons"):
        mapprep.prepare_geojson(tmp_path / "lines.json", 0.5)
    (tmp_path / "broken.json").write_text('{"type": "FeatureCollection", "features": [')
    with pytest.raises(MapfilterError, match="not valid GeoJSON") as info:
        mapprep.prepare_geojson(tmp_path / "broken.json", 0.5)
    assert info.value.path.endswith("broken.json")


# ---- edits ----------------------------------------------------------------------------------
def test_edits_yaml_and_geojson(tmp_path: Path):
    _floor_geojson(tmp_path / "floor.json", f=lambda x, y: [x, y])
    plan = mapprep.prepare_geojson(tmp_path / "floor.json", 0.5, units="m")
    # a door 0.2 m wide (less than a pixel) through the shop, and a closed-off corner
    (tmp_path / "edits.yaml").write_text(yaml.safe_dump({
        "free": [[[19.9, 6.0], [20.1, 6.0], [20.1, 14.0], [19.9, 14.0]]],
        "wall": [[[0.0, 0.0], [3.0, 0.0], [3.0, 3.0], [0.0, 3.0]]],
    }))
    edited = mapprep.apply_edits(plan, mapprep.read_edits(tmp_path / "edits.yaml"))
    assert edited.is_free(np.array([[20.0, 10.0], [20.0, 8.0]])).all()  # the door opens through the shop
    assert not edited.is_free(np.array([[1.0, 1.0]]))[0] and plan.is_free(np.array([[1.0, 1.0]]))[0]
    assert not plan.is_free(np.array([[20.0, 10.0]]))[0]  # the input plan is not mutated
    geo = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"set": "free"},
         "geometry": {"type": "Polygon", "coordinates": [[[16, 9], [24, 9], [24, 11], [16, 11], [16, 9]]]}}]}
    (tmp_path / "edits.geojson").write_text(json.dumps(geo))
    edited = mapprep.apply_edits(plan, mapprep.read_edits(tmp_path / "edits.geojson"))
    assert edited.is_free(np.array([[17.0, 10.0], [23.0, 10.0]])).all()


@pytest.mark.parametrize("content, message", [
    ("free: [[[0, 0], [1, 0]]]\n", "at least three"),
    ("doors: []\n", "keys 'free' and/or 'wall'"),
    ("free: [[[0, 0], [1, 0], [1, 1]]\n", "not valid YAML"),
    ('{"type": "FeatureCollection", "features": [{"properties": {}, "geometry": null}]}', "'free' or 'wall'"),
])
def test_bad_edits(tmp_path: Path, content: str, message: str):
    (tmp_path / "edits.yaml").write_text(content)
    with pytest.raises(MapfilterError, match=message) as info:
        mapprep.read_edits(tmp_path / "edits.yaml")
    assert info.value.path.endswith("edits.yaml")


# ---- output ---------------------------------------------------------------------------------
def test_write_map_files_and_preview(tmp_path: Path):
    _two_rooms_png(tmp_path / "rooms.png")
    plan = mapprep.prepare_lines(tmp_path / "rooms.png", PlanScale(resolution_m=0.1), map_resolution_m=0.2)
    written = mapprep.write_map(plan, tmp_path / "out" / "rooms.yaml")
    assert sorted(p.name for p in written) == ["rooms.png", "rooms.yaml", "rooms_preview.png"]
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["rooms.png", "rooms.yaml", "rooms_preview.png"]
    loaded = FloorPlan.load(tmp_path / "out" / "rooms.yaml")
    np.testing.assert_array_equal(loaded.wall_mask, plan.wall_mask)
    assert loaded.source_image.path == (tmp_path / "rooms.png").resolve()
    preview = cv2.imread(str(tmp_path / "out" / "rooms_preview.png"))
    assert preview.shape[:2] == (100, 200)  # drawn at the plan's finer pixel size
    # walls tinted red, free space shows the white paper
    assert preview[50, 150].tolist() == [255, 255, 255]
    b, g, r = preview[0, 0].tolist()
    assert r > 200 and g < 160 and b < 160


def test_write_map_leaves_nothing_when_saving_fails(tmp_path: Path, monkeypatch):
    _two_rooms_png(tmp_path / "rooms.png")
    plan = mapprep.prepare_lines(tmp_path / "rooms.png", PlanScale(resolution_m=0.1))

    def failing_save(self, yaml_path, image_name=None):
        raise MapfilterError("disk full", yaml_path)

    monkeypatch.setattr(FloorPlan, "save", failing_save)
    (tmp_path / "out").mkdir()
    with pytest.raises(MapfilterError, match="disk full"):
        mapprep.write_map(plan, tmp_path / "out" / "rooms.yaml")
    assert list((tmp_path / "out").iterdir()) == []


# ---- the real ILC floors --------------------------------------------------------------------
def _waypoints(floor_dir: Path) -> list[np.ndarray]:
    return [read_ilc(p).waypoint_xy_m for p in sorted((floor_dir / "path_data_files").glob("*.txt.gz"))]


@pytest.fixture(scope="module")
def ilc_waypoints(ilc_site1) -> dict[str, list[np.ndarray]]:
    return {floor: _waypoints(ilc_site1 / floor) for floor in ("F1", "F2")}


@pytest.mark.slow
@pytest.mark.parametrize("floor", ["F1", "F2"])
def test_ilc_image_route(ilc_site1, ilc_waypoints, floor):
    """The floor image's transparent pixels are walkable, and outside the floor's outline is wall,
    as on the GeoJSON route and as `map prepare` walls a plan's outside (it was walkable here)."""
    import shapely

    plan = mapprep.import_ilc(ilc_site1 / floor, "image")
    xy = np.concatenate(ilc_waypoints[floor])
    assert len(xy) >= 100
    assert plan.floor_name == floor and plan.resolution_m == pytest.approx(0.3, abs=0.001)
    assert plan.size_m[0] == pytest.approx(239.8, abs=0.2)
    free = plan.is_free(xy)
    assert free.mean() >= 0.99
    outline = mapprep.read_geojson_floor(ilc_site1 / floor / "geojson_map.json").outline
    rows, cols = np.indices(plan.shape_px)
    centres = plan.pixel_to_world(np.stack([cols + 0.5, rows + 0.5], axis=-1)).reshape(-1, 2)
    grown = outline.buffer(mapprep.ILC_OUTLINE_MARGIN_M)
    outside = ~shapely.contains_xy(grown, centres[:, 0], centres[:, 1]).reshape(plan.shape_px)
    assert outside.sum() > 0.2 * outside.size and plan.wall_mask[outside].all()
    # the waypoints in at most two connected parts: the outline holds two buildings on F1
    labels, _ = ndimage.label(~plan.wall_mask, structure=np.ones((3, 3)))
    rows, cols, _ = plan.pixel_index(xy[free])
    _, counts = np.unique(labels[rows, cols], return_counts=True)
    assert counts.max() >= 0.5 * free.sum() and len(counts) <= 2
    assert 0.1 < plan.free_fraction < 0.5


@pytest.mark.slow
@pytest.mark.parametrize("floor", ["F1", "F2"])
def test_ilc_geojson_route(ilc_site1, ilc_waypoints, floor):
    import shapely

    plan = mapprep.import_ilc(ilc_site1 / floor, "geojson", 0.5)
    assert plan.resolution_m == 0.5 and plan.origin_m == (0.0, 0.0)
    assert plan.size_m[0] == pytest.approx(239.8, abs=0.5) and plan.size_m[1] == pytest.approx(176.5, abs=0.6)
    traces = ilc_waypoints[floor]
    xy = np.concatenate(traces)
    assert plan.is_free(xy).mean() >= 0.99
    outline = mapprep.read_geojson_floor(ilc_site1 / floor / "geojson_map.json").outline
    rows, cols = np.indices(plan.shape_px)
    centres = plan.pixel_to_world(np.stack([cols + 0.5, rows + 0.5], axis=-1)).reshape(-1, 2)
    outside = ~shapely.contains_xy(outline, centres[:, 0], centres[:, 1]).reshape(plan.shape_px)
    assert outside.sum() > 0.3 * outside.size and plan.wall_mask[outside].all()
    # the outline is two buildings 14.7 m apart; no trace crosses, and each building's
    # waypoints lie in one connected free component
    labels, _ = ndimage.label(~plan.wall_mask, structure=np.ones((3, 3)))
    for part in outline.geoms:
        inside = shapely.contains_xy(part, xy[:, 0], xy[:, 1])
        r, c, _ = plan.pixel_index(xy[inside])
        assert len(np.unique(labels[r, c])) <= 1
    for trace in traces:
        assert sum(shapely.contains_xy(p, trace[:, 0], trace[:, 1]).any() for p in outline.geoms) == 1


def test_ilc_geojson_projection_matches_floor_info(ilc_site1):
    for floor in ("F1", "F2"):
        width_m, height_m = mapprep.read_ilc_floor_info(ilc_site1 / floor)
        bounds = mapprep.read_geojson_floor(ilc_site1 / floor / "geojson_map.json").outline.bounds
        assert bounds[:2] == (0.0, 0.0)
        assert bounds[2] == pytest.approx(width_m, abs=0.01) and bounds[3] == pytest.approx(height_m, abs=0.01)


# ---- the bundled example --------------------------------------------------------------------
def test_bundled_office_map():
    plan = FloorPlan.load(REPO / "maps" / "office.yaml")
    assert plan.resolution_m == 0.1 and plan.size_m == pytest.approx((38.0, 38.0))
    assert _free_components(plan) == 1  # every room reachable through its door
    assert plan.wall_mask[0].all() and plan.wall_mask[:, 0].all()  # outside is wall
    assert 0.6 < plan.free_fraction < 0.85
    from mapfilter.sensors.pathloss import AccessPointTable

    aps = AccessPointTable.read_csv(plan.access_points_csv)
    assert len(aps) >= 24 and set(aps.band) == {"2.4", "5"}
    assert plan.is_free(aps.xy_m).all()
    # the committed mask is what the README's command makes from the committed plan
    remade = mapprep.prepare_lines(REPO / "maps" / "office_plan.png", PlanScale(resolution_m=0.05),
                                   map_resolution_m=0.1)
    np.testing.assert_array_equal(remade.wall_mask, plan.wall_mask)


# ---- the command line -----------------------------------------------------------------------
def _run(argv: list[str], capsys) -> tuple[int, str, str]:
    code = cli_main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_prepare_and_import(tmp_path: Path, capsys, ilc_site1):
    _two_rooms_png(tmp_path / "rooms.png")
    code, out, err = _run(["map", "prepare", tmp_path / "rooms.png", "--resolution", "0.1",
                           "--out", tmp_path / "m" / "rooms.yaml"], capsys)
    assert code == 0 and err == "" and "rooms_preview.png" in out
    assert FloorPlan.load(tmp_path / "m" / "rooms.yaml").shape_px == (100, 200)
    # scale from two points 100 px apart that are 5 m apart: 0.05 m/px
    code, out, err = _run(["map", "prepare", tmp_path / "rooms.png", "--scale-points", 10, 10, 110, 10,
                           "--scale-distance", 5, "--out", tmp_path / "m" / "pts.yaml"], capsys)
    assert code == 0 and FloorPlan.load(tmp_path / "m" / "pts.yaml").resolution_m == pytest.approx(0.05)
    # regions with two walkable colours, and an edit closing a corner
    _regions_png(tmp_path / "mall.png")
    (tmp_path / "edits.yaml").write_text("wall:\n  - [[0, 0], [3, 0], [3, 3], [0, 3]]\n")
    code, out, err = _run(["map", "prepare", tmp_path / "mall.png", "--kind", "regions", "--size", 36, 24,
                           "--walkable", "transparent", "--walkable", "250,240,180", "--edits", tmp_path / "edits.yaml",
                           "--keep-outside", "--out", tmp_path / "m" / "mall.yaml"], capsys)
    assert code == 0, err
    assert "free space reaches the edge of the map" in err and "(you gave --outside none)" in err
    mall = FloorPlan.load(tmp_path / "m" / "mall.yaml")
    assert mall.is_free(np.array([[27.0, 15.0], [10.0, 23.0], [1.0, 1.0], [9.0, 15.0]])).tolist() == [
        True, True, False, False]  # yellow shop, corridor, closed corner, blue shop
    # a GeoJSON plan is recognised by its suffix
    _floor_geojson(tmp_path / "floor.json")
    code, out, err = _run(["map", "prepare", tmp_path / "floor.json", "--resolution", 0.5, "--inset", 0.2,
                           "--out", tmp_path / "m" / "floor.yaml"], capsys)
    assert code == 0 and FloorPlan.load(tmp_path / "m" / "floor.yaml").shape_px == (40, 80)
    code, out, err = _run(["map", "import-ilc", ilc_site1 / "F2", "--route", "geojson", "--resolution", "1.0",
                           "--out", tmp_path / "m" / "f2.yaml"], capsys)
    assert code == 0, err
    plan = FloorPlan.load(tmp_path / "m" / "f2.yaml")
    assert plan.floor_name == "F2" and plan.source_image.path.name == "floor_image.png"


def _bad_inputs(tmp: Path) -> list[tuple[list, str, str]]:
    """(arguments, file the message must name, words it must contain)."""
    (tmp / "text.png").write_text("this is not an image\n")
    cv2.imwrite(str(tmp / "blank.png"), np.full((50, 50), 255, np.uint8))
    cv2.imwrite(str(tmp / "black.png"), np.zeros((50, 50), np.uint8))
    all_shop = np.zeros((50, 50, 4), np.uint8)
    all_shop[...] = (245, 235, 195, 255)
    cv2.imwrite(str(tmp / "allshop.png"), all_shop)
    _two_rooms_png(tmp / "rooms.png")
    (tmp / "edits.yaml").write_text("free: [[[0, 0], [1, 0]\n")
    _floor_geojson(tmp / "floor.json")
    rooms = tmp / "rooms.png"
    return [
        (["map", "prepare", tmp / "missing.png", "--resolution", "0.1"], "missing.png", "not found"),
        (["map", "prepare", rooms, "--kind", "regions", "--resolution", "0.1", "--walkable", "pink"], "", "colour"),
        (["map", "prepare", tmp / "text.png", "--resolution", "0.1"], "text.png", "not a readable image"),
        (["map", "prepare", tmp / "blank.png", "--resolution", "0.1"], "blank.png", "no walls"),
        (["map", "prepare", tmp / "black.png", "--resolution", "0.1"], "black.png", "no free space"),
        (["map", "prepare", tmp / "allshop.png", "--kind", "regions", "--resolution", "0.1"], "allshop.png",
         "no free space"),
        (["map", "prepare", rooms], "rooms.png", "no scale"),
        (["map", "prepare", rooms, "--resolution", "0.1", "--size", "30", "10"], "rooms.png", "contradictory"),
        (["map", "prepare", rooms, "--resolution", "0.1", "--edits", tmp / "edits.yaml"], "edits.yaml", "not valid YAML"),
        (["map", "prepare", tmp / "floor.json", "--check-logs", tmp / "nolog.txt"], "nolog.txt", "not found"),
        (["map", "prepare", tmp / "floor.json", "--keep-outside"], "", "outside a GeoJSON floor's outline is wall"),
        (["map", "import-ilc", tmp / "nofloor"], "nofloor", "not an ILC floor"),
        (["map", "prepare", rooms, "--resolution", "0.1", "--access-points", tmp / "aps.csv"], "aps.csv", "not found"),
    ]


def test_cli_bad_inputs_one_line_no_output(tmp_path: Path, capsys):
    inputs = tmp_path / "in"
    inputs.mkdir()
    for argv, names, words in _bad_inputs(inputs):
        out_dir = tmp_path / "out"
        out_dir.mkdir(exist_ok=True)
        code, out, err = _run([*argv, "--out", out_dir / "map.yaml"], capsys)
        assert code == 1, (argv, err)
        lines = err.strip().splitlines()
        assert len(lines) == 1 and names in lines[0] and words in lines[0], (argv, err)
        assert lines[0].startswith("mapfilter: error: ")
        assert list(out_dir.iterdir()) == [], argv  # nothing written, no temporaries left


def test_cli_malformed_floor_info(tmp_path: Path, capsys, ilc_site1):
    floor = tmp_path / "F9"
    floor.mkdir()
    (floor / "floor_info.json").write_text('{"map_info": {"width": 10}}')
    code, _, err = _run(["map", "import-ilc", floor, "--out", tmp_path / "o.yaml"], capsys)
    assert code == 1 and len(err.strip().splitlines()) == 1 and "floor_info.json" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["F9"]


def test_cli_never_overwrites_the_plan_with_its_mask(tmp_path: Path, capsys):
    plan = tmp_path / "plan.png"
    _two_rooms_png(plan)
    before = plan.read_bytes()
    code, out, err = _run(["map", "prepare", plan, "--resolution", "0.1", "--out", tmp_path / "plan.yaml"], capsys)
    assert code == 1 and "is an input of this run" in err and len(err.strip().splitlines()) == 1
    assert plan.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plan.png"]


def test_a_map_resolution_that_would_not_fit_is_refused_before_resampling(tmp_path: Path):
    plan = tmp_path / "plan.png"
    image = np.full((200, 300), 255, np.uint8)
    cv2.rectangle(image, (20, 20), (280, 180), 0, 3)
    cv2.imwrite(str(plan), image)
    with pytest.raises(MapfilterError, match=r"gives a 15000x10000 mask, more than 120 M pixels"):
        mapprep.prepare_lines(plan, PlanScale(resolution_m=0.05), DrawingOptions(), map_resolution_m=0.001)
    assert mapprep.prepare_lines(plan, PlanScale(resolution_m=0.05), DrawingOptions(), map_resolution_m=0.1).shape_px \
        == (100, 150)
    with pytest.raises(MapfilterError, match="'resolution' 1e-300 m/px is not a floor plan's"):
        mapprep.prepare_lines(plan, PlanScale(resolution_m=1e-300), DrawingOptions())


# ---- a plan that turns into a useless mask says so ---------------------------------------------
def _framed_png(path: Path, text: bool = False, inside: bool = True) -> None:
    """300x200 px RGBA: transparent outside, a building with a 3 px outline and a transparent
    inside (a corridor), a filled shop, and (``text``) a label in the corridor."""
    image = np.zeros((200, 300, 4), dtype=np.uint8)
    cv2.rectangle(image, (20, 20), (279, 179), (90, 90, 90, 255), 3)
    if inside:
        image[60:140, 120:200] = (245, 235, 195, 255)  # a shop
    if text:
        cv2.putText(image, "exit", (40, 165), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (102, 102, 102, 255), 1, cv2.LINE_8)
    cv2.imwrite(str(path), image)


def _warnings(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("mapfilter: warning: ")]


def test_regions_wall_the_outside_by_default(tmp_path: Path, capsys):
    _framed_png(tmp_path / "plan.png")
    code, out, err = _run(["map", "prepare", tmp_path / "plan.png", "--kind", "regions", "--resolution", 0.1,
                           "--out", tmp_path / "walled.yaml"], capsys)
    assert code == 0 and _warnings(err) == [], err
    walled = FloorPlan.load(tmp_path / "walled.yaml")
    assert walled.is_free(np.array([[5.0, 5.0], [1.0, 1.0]])).tolist() == [True, False]  # inside, outside
    code, out, err = _run(["map", "prepare", tmp_path / "plan.png", "--kind", "regions", "--resolution", 0.1,
                           "--keep-outside", "--out", tmp_path / "open.yaml"], capsys)
    assert code == 0 and FloorPlan.load(tmp_path / "open.yaml").is_free(np.array([[1.0, 1.0]])).all()
    (line,) = _warnings(err)
    assert "open.yaml: free space reaches the edge of the map" in line and "you gave --outside none" in line


def test_regions_open_outlines_never_let_the_outside_in(tmp_path: Path):
    _framed_png(tmp_path / "plan.png")
    plan = mapprep.prepare_regions(tmp_path / "plan.png", PlanScale(resolution_m=0.1), RegionOptions(open_outlines_px=2))
    # the shop's edge opened, the building's outline still closed: the outside stays wall
    assert plan.is_free(np.array([[5.0, 5.0], [12.0, 10.0]])).tolist() == [True, True]
    assert not plan.is_free(np.array([[1.0, 1.0], [29.0, 19.0]])).any()


def test_text_in_a_corridor_is_dropped_by_default_and_warned_about_when_kept(tmp_path: Path, capsys):
    _framed_png(tmp_path / "plan.png", text=True)
    args = ["map", "prepare", tmp_path / "plan.png", "--kind", "regions", "--resolution", 0.1]
    code, out, err = _run([*args, "--remove-below", 0, "--out", tmp_path / "text.yaml"], capsys)
    (line,) = _warnings(err)
    assert code == 0 and "small wall blobs inside free space" in line and "--remove-below PX" in line
    for extra in ([], ["--remove-below", 60]):
        code, out, err = _run([*args, *extra, "--out", tmp_path / "clean.yaml"], capsys)
        assert code == 0 and _warnings(err) == [], err


def test_a_nearly_empty_plan_warns_almost_no_walls(tmp_path: Path, capsys):
    _framed_png(tmp_path / "empty_plan.png", inside=False)
    code, out, err = _run(["map", "prepare", tmp_path / "empty_plan.png", "--kind", "regions", "--resolution", 0.1,
                           "--out", tmp_path / "empty.yaml"], capsys)
    (line,) = _warnings(err)
    assert code == 0 and "empty.yaml: almost no walls" in line and "nearly empty" in line
    # a drawing of nothing but a thin mark: no building, so no free space (refused in one line), or
    # with the outside kept, no walls at all (refused too); nothing is written
    image = np.full((200, 300), 255, np.uint8)
    cv2.rectangle(image, (100, 100), (121, 121), 0, 1)  # a small closed mark (the IPIN plan's reference points)
    cv2.imwrite(str(tmp_path / "dot_plan.png"), image)
    for extra, words in (([], "no free space"), (["--outside", "none"], "no walls")):
        code, out, err = _run(["map", "prepare", tmp_path / "dot_plan.png", "--resolution", 0.1, *extra, "--out",
                               tmp_path / "dot.yaml"], capsys)
        assert code == 1 and len(err.strip().splitlines()) == 1 and words in err, err
        assert not (tmp_path / "dot.yaml").exists()


def test_mask_warnings_say_nothing_about_good_maps():
    office = FloorPlan.load(REPO / "maps" / "office.yaml")
    assert mapprep.mask_warnings(office) == []


def test_the_ipin_floor_minus_1_plan_is_nearly_empty_and_says_so(ipin2023, tmp_path: Path, capsys):
    code, out, err = _run(["map", "import-ipin", ipin2023 / "plans" / "calib_mapa_Nuremberg.cal", "--out",
                           tmp_path / "venue.yaml"], capsys)
    assert code == 0
    assert any("venue_-1.yaml (floor -1): almost no walls" in line for line in _warnings(err)), err


def test_check_logs_warns_about_waypoints_in_walls(tmp_path: Path, capsys):
    walk = REPO / "maps" / "office_walk.txt.gz"
    args = ["map", "prepare", REPO / "maps" / "office_plan.png", "--kind", "lines", "--map-resolution", 0.1,
            "--remove-text", 60, "--check-logs", walk]
    code, out, err = _run([*args, "--resolution", 0.05, "--out", tmp_path / "office.yaml"], capsys)
    assert code == 0 and _warnings(err) == [], err  # the plan's own scale: every waypoint free
    code, out, err = _run([*args, "--resolution", 0.04, "--out", tmp_path / "small.yaml"], capsys)
    (line,) = _warnings(err)  # a wrong scale
    assert code == 0 and f"{walk}: " in line and "waypoints fall in walls or outside the map" in line
    # mapfilter check says the same against a map
    code, out, err = _run(["check", walk, "--map", tmp_path / "small.yaml"], capsys)
    assert code == 0 and "waypoints fall in walls" in err
    code, out, err = _run(["check", walk, "--map", tmp_path / "office.yaml"], capsys)
    assert code == 0 and err == ""


def test_check_says_latlon_waypoints_need_a_georeferenced_map(ipin2023, capsys):
    log = sorted((ipin2023 / "logs").glob("*.txt.gz"))[0]
    code, out, err = _run(["check", log, "--map", REPO / "maps" / "office.yaml"], capsys)
    assert code == 0 and "its waypoints cannot be checked" in err and "georeference" in err


def test_the_outside_warning_blames_keep_outside_only_when_it_was_given(tmp_path: Path, capsys):
    """Issue 45 friction 4: free space at the map's edge was blamed on --outside none (once --keep-outside), given or not."""
    _two_rooms_png(tmp_path / "rooms.png")
    # an edit frees a strip along the bottom edge (metres, origin at the lower-left corner)
    (tmp_path / "edits.yaml").write_text("free:\n  - [[2, 0], [8, 0], [8, 0.3], [2, 0.3]]\n")
    code, out, err = _run(["map", "prepare", tmp_path / "rooms.png", "--resolution", 0.1, "--edits",
                           tmp_path / "edits.yaml", "--out", tmp_path / "edited.yaml"], capsys)
    (line,) = [w for w in _warnings(err) if "edge of the map" in w]
    assert code == 0 and "--outside none" not in line and "--edits" in line
    code, out, err = _run(["map", "prepare", tmp_path / "rooms.png", "--resolution", 0.1, "--outside", "none",
                           "--out", tmp_path / "open.yaml"], capsys)
    (line,) = [w for w in _warnings(err) if "edge of the map" in w]
    assert "you gave --outside none" in line


def test_the_report_names_the_rooms_cut_off(tmp_path: Path, capsys):
    image = np.full((100, 200), 255, np.uint8)
    cv2.rectangle(image, (10, 10), (189, 89), 0, 3)
    cv2.line(image, (100, 10), (100, 89), 0, 3)  # two rooms, no door between them
    cv2.imwrite(str(tmp_path / "shut_plan.png"), image)
    code, out, err = _run(["map", "prepare", tmp_path / "shut_plan.png", "--resolution", 0.1, "--out",
                           tmp_path / "shut.yaml"], capsys)
    assert code == 0 and re.search(r"free space \d+\.\d% of the map, 5\d\.\d% of it in one connected region \(1 room of 1 m2 or more cut off\)", out), out
    (line,) = [w for w in _warnings(err) if "cut off" in w]
    assert "1 room is cut off from the largest free region" in line and "at px " in line and "--edits" in line
