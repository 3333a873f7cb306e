import numpy as np
import pytest

from mapfilter.errors import MapfilterError
from mapfilter.io.tracks import Track, read_track, track_csv_bytes, write_track_csv, write_track_tum


def _track(n=5):
    rng = np.random.default_rng(1)
    return Track(t_s=1.6e9 + np.arange(n) * 0.5, xy_m=rng.uniform(0, 50, (n, 2)),
                 std_m=rng.uniform(0, 3, n), heading_rad=rng.uniform(-3, 3, n))


def test_csv_round_trip(tmp_path):
    track = _track()
    write_track_csv(track, tmp_path / "t.csv")
    back = read_track(tmp_path / "t.csv")
    np.testing.assert_allclose(back.t_s, track.t_s, atol=1e-3)
    np.testing.assert_allclose(back.xy_m, track.xy_m, atol=1e-3)
    np.testing.assert_allclose(back.std_m, track.std_m, atol=1e-3)
    np.testing.assert_allclose(back.heading_rad, track.heading_rad, atol=1e-4)


def test_a_csv_made_in_memory_is_the_file_write_track_csv_writes(tmp_path):
    """evaluate's workers make each walk's track files in memory for the parent to write."""
    import dataclasses

    track = dataclasses.replace(_track(), floor=["F1", "F1", "F2", "F2", "F2"], floor_p=np.linspace(0.5, 1.0, 5))
    for t in (_track(), track):
        write_track_csv(t, tmp_path / "t.csv")
        assert track_csv_bytes(t) == (tmp_path / "t.csv").read_bytes()


def test_tum_parses_back_with_heading_as_yaw_quaternion(tmp_path):
    track = _track()
    write_track_tum(track, tmp_path / "t.tum")
    lines = (tmp_path / "t.tum").read_text().splitlines()
    assert len(lines) == 5 and all(len(line.split()) == 8 for line in lines)
    q = np.array([[float(v) for v in line.split()[4:]] for line in lines])
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-5)
    back = read_track(tmp_path / "t.tum")
    np.testing.assert_allclose(back.xy_m, track.xy_m, atol=1e-4)
    np.testing.assert_allclose(np.angle(np.exp(1j * (back.heading_rad - track.heading_rad))), 0, atol=1e-5)


def test_malformed_track_names_file_and_line(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text("t_s,x_m,y_m\n1,2,3\n2,nan,3\n")
    with pytest.raises(MapfilterError, match=r"bad.csv:3: column x_m"):
        read_track(path)


def test_latitude_longitude_columns_only_in_a_georeferenced_building(tmp_path):
    from mapfilter.maps.building import Building, Floor
    from mapfilter.maps.floorplan import FloorPlan
    from mapfilter.maps.georef import LocalFrame

    track = _track()
    track.floor = ["0", "1", "1", "0", "0"]
    plan = FloorPlan(np.zeros((10, 10), bool), 1.0)
    plain = Building([Floor("0", plan), Floor("1", plan, 4.0)])
    write_track_csv(track, tmp_path / "before.csv")
    write_track_csv(track, tmp_path / "plain.csv", building=plain)
    before = (tmp_path / "before.csv").read_bytes()
    assert before.splitlines()[0] == b"t_s,x_m,y_m,floor,std_m,heading_rad"
    assert (tmp_path / "plain.csv").read_bytes() == before  # no georeference: the file as it always was
    # floor 1 is shifted 10 m east of floor 0 in the building frame
    geo = Building([Floor("0", plan), Floor("1", plan, 4.0, offset_m=(10.0, 0.0))],
                   georeference=LocalFrame(49.46, 11.11))
    write_track_csv(track, tmp_path / "geo.csv", building=geo)
    back = read_track(tmp_path / "geo.csv")
    assert (tmp_path / "geo.csv").read_text().splitlines()[0] == \
        "t_s,x_m,y_m,floor,latitude_deg,longitude_deg,std_m,heading_rad"
    shifted = track.xy_m + np.where(np.array(track.floor)[:, None] == "1", [10.0, 0.0], 0.0)
    np.testing.assert_allclose(LocalFrame(49.46, 11.11).to_xy_m(back.latlon_deg), shifted, atol=2e-3)
    np.testing.assert_allclose(back.xy_m, track.xy_m, atol=1e-3)
    assert back.floor == track.floor
