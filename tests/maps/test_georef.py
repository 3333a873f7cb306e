"""Georeference: the east/north tangent plane, calibration files, and image placement."""

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapfilter.errors import MapfilterError
from mapfilter.maps.building import Building, Floor
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.georef import ImagePlacement, LocalFrame, read_cal

NUREMBERG = LocalFrame(49.46115181, 11.11114911)


@settings(max_examples=200, deadline=None)
@given(lat=st.floats(-80, 80), lon=st.floats(-179, 179), east=st.floats(-5000, 5000), north=st.floats(-5000, 5000))
def test_metres_to_latlon_and_back_is_exact(lat, lon, east, north):
    frame = LocalFrame(lat, lon)
    xy = np.array([east, north])
    np.testing.assert_allclose(frame.to_xy_m(frame.to_latlon_deg(xy)), xy, atol=1e-6)


def test_the_plane_matches_distances_on_the_ellipsoid_over_a_building():
    # along a meridian, 100 m north is 100 m / (meridian radius of curvature) of latitude
    a, f = 6378137.0, 1 / 298.257223563
    e2 = f * (2 - f)
    lat = math.radians(NUREMBERG.origin_lat_deg)
    meridian = a * (1 - e2) / (1 - e2 * math.sin(lat) ** 2) ** 1.5
    north = NUREMBERG.to_xy_m(np.array([NUREMBERG.origin_lat_deg + math.degrees(100.0 / meridian),
                                        NUREMBERG.origin_lon_deg]))
    assert north[0] == pytest.approx(0.0, abs=1e-6) and north[1] == pytest.approx(100.0, abs=0.01)
    # east along the parallel: the normal radius of curvature times cos(latitude)
    normal = a / math.sqrt(1 - e2 * math.sin(lat) ** 2)
    east = NUREMBERG.to_xy_m(np.array([NUREMBERG.origin_lat_deg,
                                       NUREMBERG.origin_lon_deg + math.degrees(100.0 / (normal * math.cos(lat)))]))
    assert east[0] == pytest.approx(100.0, abs=0.01) and abs(east[1]) < 0.01  # the parallel curves away by ~1 mm


def test_image_placement_turns_by_minus_the_rotation_and_round_trips():
    placement = ImagePlacement(49.46115181, 11.11114911, -20.736, 0.01232008, (10719, 5069))
    centre = placement.pixel_to_xy_m(np.array([10719 / 2, 5069 / 2]), NUREMBERG)
    np.testing.assert_allclose(centre, [0.0, 0.0], atol=1e-6)
    # the image's up axis points 20.736 deg west of north (counter-clockwise from north)
    up = placement.pixel_to_xy_m(np.array([10719 / 2, 5069 / 2 - 1000]), NUREMBERG) - centre
    assert math.degrees(math.atan2(up[1], up[0])) == pytest.approx(90 + 20.736, abs=1e-6)
    assert np.hypot(*up) == pytest.approx(12.32008, rel=1e-9)
    uv = np.array([[0.0, 0.0], [123.4, 4567.8], [10719.0, 5069.0]])
    np.testing.assert_allclose(placement.xy_m_to_pixel(placement.pixel_to_xy_m(uv, NUREMBERG), NUREMBERG), uv,
                               atol=1e-9)


@pytest.mark.slow
def test_the_calibration_places_the_plans_surveyed_points_within_60_cm(ipin2023):
    """The floor -1 plan draws the nine surveyed reference points (yellow dots): placed by the
    .cal, each lands within 0.6 m of its surveyed latitude/longitude."""
    plans = ipin2023 / "plans"
    (entry,) = [f for f in read_cal(plans / "calib_mapa_Nuremberg.cal") if f.floor == "-1"]
    colour = cv2.imread(str(plans / entry.image), cv2.IMREAD_REDUCED_COLOR_2)
    yellow = (np.abs(colour.astype(int) - [54, 182, 229]).max(axis=2) < 40).astype(np.uint8)
    count, _, stats, centroids = cv2.connectedComponentsWithStats(yellow, connectivity=8)
    dots = centroids[1:][stats[1:, cv2.CC_STAT_AREA] > 100]
    uv = (dots + 0.5) * 2.0  # reduced pixel centres -> full-size continuous pixel coordinates
    placement = entry.placement((10719, 5069))
    frame = LocalFrame(entry.centre_lat_deg, entry.centre_lon_deg)
    placed = placement.pixel_to_xy_m(uv, frame)
    rows = [line.split(",") for line in (plans / "references.csv").read_text().split()[1:]]
    surveyed = frame.to_xy_m(np.array([[float(r[1]), float(r[2])] for r in rows]))
    distance = np.linalg.norm(placed[:, None, :] - surveyed[None, :, :], axis=2)
    nearest = distance.argmin(axis=1)
    assert len(dots) == 9 and sorted(nearest.tolist()) == list(range(9))  # one dot per surveyed point
    assert distance.min(axis=1).max() < 0.6


def test_read_cal_and_its_errors(tmp_path, ipin2023):
    floors = read_cal(ipin2023 / "plans" / "calib_mapa_Nuremberg.cal")
    assert [f.floor for f in floors] == ["0", "-1", "-2"] and floors[1].image == "Map_Floor_-01.png"
    assert floors[2].rotation_deg == -20.736 and floors[0].scale_m_per_px == 0.01232008
    good = "% comment\na.png b.png\n0 -1\n1 1\n49.4 49.4\n11.1 11.1\n-20 -20\n0.01 0.01\n"
    cases = [(good.replace("-20 -20\n", ""), "has 7 rows"), (good.replace("11.1 11.1", "11.1"), ":6: 1 longitudes"),
             (good.replace("49.4 49.4", "49.4 north"), ":5: the latitudes must be numbers"),
             (good.replace("0.01 0.01", "0.01 -1"), ":8: scales out of range"),
             (good.replace("0 -1\n", "0 0\n"), "floor numbers repeat")]
    for text, message in cases:
        path = tmp_path / "bad.cal"
        path.write_text(text)
        with pytest.raises(MapfilterError, match=message):
            read_cal(path)


def test_a_building_with_a_georeference_round_trips_its_yaml_and_old_yamls_load(tmp_path):
    plan = FloorPlan(np.zeros((20, 20), bool), 0.5, (0.0, 0.0))
    plan.save(tmp_path / "f.yaml")
    building = Building([Floor("0", FloorPlan.load(tmp_path / "f.yaml"), map_path=tmp_path / "f.yaml")],
                        georeference=NUREMBERG)
    building.save(tmp_path / "b.yaml")
    loaded = Building.load(tmp_path / "b.yaml")
    assert loaded.georeference == NUREMBERG
    latlon = loaded.floor_xy_to_latlon(np.array([[3.0, 4.0]]), None)
    np.testing.assert_allclose(loaded.latlon_to_floor_xy(latlon, "0"), [[3.0, 4.0]], atol=1e-6)
    text = (tmp_path / "b.yaml").read_text()
    (tmp_path / "old.yaml").write_text(text.split("georeference:")[0] + "floors:" + text.split("floors:")[1])
    assert Building.load(tmp_path / "old.yaml").georeference is None
    (tmp_path / "bad.yaml").write_text(text.replace("origin_lat_deg: 49.46115181", "origin_lat_deg: 95"))
    with pytest.raises(MapfilterError, match="bad.yaml: a georeference origin must be a latitude"):
        Building.load(tmp_path / "bad.yaml")
