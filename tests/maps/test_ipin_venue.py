"""`mapfilter map import-ipin`: a calibration file and its plans -> a georeferenced building."""

import csv
import struct
import zlib

import cv2
import numpy as np
import pytest

from mapfilter.cli import main
from mapfilter.errors import MapfilterError
from mapfilter.maps.building import Building
from mapfilter.maps.georef import ImagePlacement, LocalFrame
from mapfilter.maps.ipin_venue import import_ipin_venue
from mapfilter.sensors.logs import read_log
from mapfilter.io.tracks import Track, read_track, write_track_csv

CENTRE = (49.46115181, 11.11114911)


def _cal(tmp_path, images=("plan_0.png", "plan_1.png"), floors=("0", "1"), rotation=30.0, scale=0.02):
    n = len(images)
    text = (f"% test venue\n{' '.join(images)}\n{' '.join(floors)}\n{' '.join(['7'] * n)}\n"
            f"{' '.join([str(CENTRE[0])] * n)}\n{' '.join([str(CENTRE[1])] * n)}\n"
            f"{' '.join([str(rotation)] * n)}\n{' '.join([str(scale)] * n)}\n")
    path = tmp_path / "calib_mapa_Test.cal"
    path.write_text(text)
    return path


def _plan():
    """2000 x 1000 px at 2 cm: a room with 0.3 m walls, a 1 px annotation line, a 0.4 m label."""
    image = np.full((1000, 2000), 255, np.uint8)
    cv2.rectangle(image, (500, 200), (1500, 800), 0, thickness=15)
    cv2.line(image, (100, 950), (1900, 950), 0, thickness=1)
    image[80:100, 100:120] = 0
    return image


def test_walls_land_where_the_calibration_places_them(tmp_path):
    cv2.imwrite(str(tmp_path / "plan_0.png"), _plan())
    warnings = []
    building, floors = import_ipin_venue(_cal(tmp_path), resolution_m=0.1, storey_height_m=3.5,
                                         warn=warnings.append)
    assert building.floor_names == ["0", "1"] and [f.elevation_m for f in building.floors] == [0.0, 3.5]
    assert building.georeference == LocalFrame(*CENTRE) and building.storey_height_m == 3.5
    assert len(warnings) == 1 and "plan of floor 1 (plan_1.png) is missing" in warnings[0]
    placement = ImagePlacement(*CENTRE, 30.0, 0.02, (2000, 1000))
    frame = building.georeference

    def free(floor, uv):
        return building.floors[floor].plan.is_free(placement.pixel_to_xy_m(np.asarray(uv, float), frame))

    wall_points = [[1000, 200], [500, 500], [1500, 350], [1000, 800]]  # on the room's walls
    assert not free(0, wall_points).any()
    assert free(0, [[1000, 500], [300, 950], [110, 90], [200, 500]]).all()  # room, thin line, label, outside
    assert not free(0, [[-100, 500], [1000, 1100]]).any()  # beyond the image: wall
    assert not free(1, [[-100, 500]]).any() and free(1, wall_points).all()  # the open floor: free inside
    assert floors[0].display is not None and floors[1].display is None


def test_no_image_at_all_and_a_huge_plan_are_refused_before_decoding(tmp_path):
    with pytest.raises(MapfilterError, match="none of the plan images"):
        import_ipin_venue(_cal(tmp_path))
    # a PNG whose header says 30000 x 30000 px (900 megapixels) is refused from its header
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 30000, 30000, 8, 0, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(b"")) + chunk(b"IEND", b""))
    (tmp_path / "plan_0.png").write_bytes(png)
    with pytest.raises(MapfilterError, match="30000x30000 px, more than 300 megapixels"):
        import_ipin_venue(_cal(tmp_path))
    cv2.imwrite(str(tmp_path / "plan_0.png"), _plan())
    with pytest.raises(MapfilterError, match="--resolution"):
        import_ipin_venue(_cal(tmp_path), resolution_m=1e-300)
    with pytest.raises(MapfilterError, match="floor numbers must be integers"):
        import_ipin_venue(_cal(tmp_path, floors=("G", "1")))


def test_the_real_venue_holds_every_ground_truth_point_on_free_space(ipin2023, tmp_path):
    out = tmp_path / "nuremberg.yaml"
    assert main(["map", "import-ipin", str(ipin2023 / "plans" / "calib_mapa_Nuremberg.cal"), "--out", str(out),
                 "--storey-height", "2.8"]) == 0
    building = Building.load(out)
    assert building.floor_names == ["-2", "-1", "0"]
    assert [f.elevation_m for f in building.floors] == pytest.approx([-5.6, -2.8, 0.0])
    assert building.georeference == LocalFrame(*CENTRE)
    assert building.floor("-1").plan.source_image.path == (tmp_path / "nuremberg_-1_plan.png").resolve()
    assert (tmp_path / "nuremberg_-1_preview.png").is_file()
    for path in sorted((ipin2023 / "logs").glob("*.txt.gz"))[::3]:
        rec = read_log(path, building=building)
        for name in set(rec.waypoint_floor):
            on = np.array([f == name for f in rec.waypoint_floor])
            assert building.floor(name).plan.is_free(rec.waypoint_xy_m[on]).all(), path
    # a track on it carries latitude and longitude, and reads back
    track = Track(t_s=rec.waypoint_t_s, xy_m=rec.waypoint_xy_m, floor=list(rec.waypoint_floor))
    write_track_csv(track, tmp_path / "track.csv", building=building)
    with open(tmp_path / "track.csv") as handle:
        assert next(csv.reader(handle)) == ["t_s", "x_m", "y_m", "floor", "latitude_deg", "longitude_deg"]
    back = read_track(tmp_path / "track.csv")
    np.testing.assert_allclose(back.latlon_deg, rec.waypoint_latlon_deg, atol=2e-8)  # 1e-8 deg ~ 1 mm
