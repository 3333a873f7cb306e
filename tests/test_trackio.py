import numpy as np
import pytest

from mapfilter.errors import MapfilterError
from mapfilter.trackio import Track, read_track, write_track_csv, write_track_tum


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
