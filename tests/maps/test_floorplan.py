"""FloorPlan: ROS map_server files, world <-> pixel, free-space sampling, distance to walls."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mapfilter.errors import MapfilterError
from mapfilter.maps.floorplan import FloorPlan, SourceImage


def _plan_5x5() -> FloorPlan:
    """A 5x5 room: border walls, one interior wall pixel at (row 1, col 3)."""
    wall = np.zeros((5, 5), dtype=bool)
    wall[0, :] = wall[-1, :] = wall[:, 0] = wall[:, -1] = True
    wall[1, 3] = True
    return FloorPlan(wall, 0.5, (10.0, -2.0))


# ---- world <-> pixel ------------------------------------------------------------------------
def test_world_to_pixel_5x5_hand_computed():
    plan = _plan_5x5()  # 0.5 m/px, lower-left corner at (10, -2): extent x 10..12.5, y -2..0.5
    assert plan.extent_m == (10.0, 12.5, -2.0, 0.5)
    # u = (x - 10) / 0.5 ; v = 5 - (y + 2) / 0.5
    xy = np.array([[10.0, -2.0], [12.5, 0.5], [11.25, -0.75], [10.2, 0.4]])
    expected_uv = np.array([[0.0, 5.0], [5.0, 0.0], [2.5, 2.5], [0.4, 0.2]])
    np.testing.assert_allclose(plan.world_to_pixel(xy), expected_uv, atol=1e-12)
    np.testing.assert_allclose(plan.pixel_to_world(expected_uv), xy, atol=1e-12)
    # the centre of pixel (row 1, col 3) is (u, v) = (3.5, 1.5):
    # x = 10 + 3.5 * 0.5 = 11.75, y = -2 + (5 - 1.5) * 0.5 = -0.25
    np.testing.assert_allclose(plan.pixel_to_world(np.array([3.5, 1.5])), [11.75, -0.25])
    rows, cols, inside = plan.pixel_index(np.array([[11.75, -0.25], [10.2, 0.4], [9.9, 0.0], [11.0, 0.6]]))
    assert rows.tolist()[:2] == [1, 0] and cols.tolist()[:2] == [3, 0]
    assert inside.tolist() == [True, True, False, False]
    # (11.75, -0.25) is the interior wall pixel, (11.25, -0.75) the free centre, outside = wall
    assert plan.is_free(np.array([[11.75, -0.25], [11.25, -0.75], [9.0, -1.0]])).tolist() == [False, True, False]


def test_world_pixel_round_trip_random():
    plan = _plan_5x5()
    rng = np.random.default_rng(1)
    xy = rng.uniform([-5, -5], [20, 20], size=(200, 2))
    np.testing.assert_allclose(plan.pixel_to_world(plan.world_to_pixel(xy)), xy, atol=1e-9)


def test_sample_free_lands_on_free_pixels():
    plan = _plan_5x5()
    rng = np.random.default_rng(2)
    xy = plan.sample_free(5000, rng)
    assert xy.shape == (5000, 2)
    assert plan.is_free(xy).all()
    # uniform over the 8 free pixels: each gets about 1/8
    rows, cols, _ = plan.pixel_index(xy)
    counts = np.bincount(rows * 5 + cols, minlength=25)[~plan.wall_mask.ravel()]
    assert counts.size == 8 and counts.min() > 500
    # same seed, same points
    np.testing.assert_array_equal(plan.sample_free(10, np.random.default_rng(3)),
                                  plan.sample_free(10, np.random.default_rng(3)))


def test_sample_free_on_all_wall_map_raises():
    plan = FloorPlan(np.ones((3, 3), dtype=bool), 1.0)
    with pytest.raises(MapfilterError, match="no free space"):
        plan.sample_free(1, np.random.default_rng(0))


def test_distance_to_wall():
    wall = np.zeros((9, 9), dtype=bool)
    wall[:, 0] = True  # a wall along the left edge
    plan = FloorPlan(wall, 0.25)
    # centre of pixel (row 4, col c) is c pixel centres away from the wall column
    cols = np.arange(9)
    xy = plan.pixel_to_world(np.stack([cols + 0.5, np.full(9, 4.5)], axis=-1))
    np.testing.assert_allclose(plan.distance_to_wall_m(xy), cols * 0.25)
    assert plan.distance_to_wall_m(np.array([[100.0, 100.0]]))[0] == 0.0  # outside the map
    # a single wall pixel: Euclidean, not city-block, distance (3-4-5 triangle)
    single = np.zeros((9, 9), dtype=bool)
    single[0, 0] = True
    plan = FloorPlan(single, 0.5)
    centre = plan.pixel_to_world(np.array([[4.5, 3.5]]))  # pixel (row 3, col 4)
    np.testing.assert_allclose(plan.distance_to_wall_m(centre), [5 * 0.5])


# ---- files ----------------------------------------------------------------------------------
def test_yaml_round_trip_exact(tmp_path: Path):
    rng = np.random.default_rng(4)
    wall = rng.random((37, 53)) < 0.3
    plan_png = tmp_path / "plans" / "plan.png"
    plan_png.parent.mkdir()
    plan_png.write_bytes(b"placeholder")  # the source image only needs a path here
    aps = tmp_path / "aps.csv"
    aps.write_text("bssid,x,y\n")
    plan = FloorPlan(wall, 0.137, (-3.25, 7.5), "F7", SourceImage(plan_png.resolve(), 0.0685, (-3.0, 7.0)), aps)
    plan.save(tmp_path / "out" / "m.yaml")
    loaded = FloorPlan.load(tmp_path / "out" / "m.yaml")
    np.testing.assert_array_equal(loaded.wall_mask, wall)
    assert loaded.resolution_m == 0.137
    assert loaded.origin_m == (-3.25, 7.5)
    assert loaded.floor_name == "F7"
    assert loaded.source_image.path == plan_png.resolve()
    assert loaded.source_image.resolution_m == 0.0685
    assert loaded.source_image.origin_m == (-3.0, 7.0)
    assert loaded.access_points_csv == aps.resolve()
    # extra keys sit under 'mapfilter', paths relative to the YAML; the rest is map_server's
    text = (tmp_path / "out" / "m.yaml").read_text()
    assert "source_image: ../plans/plan.png" in text and "image: m.png" in text
    # saving the loaded map again gives the same files
    loaded.save(tmp_path / "again" / "m.yaml")
    assert (tmp_path / "again" / "m.png").read_bytes() == (tmp_path / "out" / "m.png").read_bytes()


def _write_pgm(path: Path, pixels: np.ndarray) -> None:
    """Binary PGM (P5) by hand, as other tools write it."""
    h, w = pixels.shape
    path.write_bytes(f"P5\n# made by hand\n{w} {h}\n255\n".encode() + pixels.astype(np.uint8).tobytes())


@pytest.mark.parametrize("negate", [0, 1])
def test_standard_map_server_pgm_loads(tmp_path: Path, negate: int):
    # map_server trinary: p = (255 - v) / 255 (negate 0) or v / 255 (negate 1);
    # p > occupied_thresh: occupied, p < free_thresh: free, between: unknown (we say wall)
    occupied, free, unknown = (0, 254, 205) if negate == 0 else (255, 1, 50)
    pixels = np.array([[occupied, free, unknown],
                       [free, free, occupied]])
    _write_pgm(tmp_path / "lab.pgm", pixels)
    (tmp_path / "lab.yaml").write_text(
        "image: lab.pgm\nresolution: 0.050000\norigin: [-1.0, -2.0, 0.0]\n"
        f"negate: {negate}\noccupied_thresh: 0.65\nfree_thresh: 0.196\n")
    plan = FloorPlan.load(tmp_path / "lab.yaml")
    assert plan.wall_mask.tolist() == [[True, False, True], [False, False, True]]
    assert plan.resolution_m == 0.05 and plan.origin_m == (-1.0, -2.0)
    assert plan.floor_name is None and plan.source_image is None


@pytest.mark.parametrize("content, message", [
    ("image: m.png\nresolution: [0.1\n", "not valid YAML"),
    ("- just\n- a list\n", "mapping"),
    ("image: m.png\norigin: [0, 0, 0]\n", "resolution"),
    ("image: m.png\nresolution: -1\norigin: [0, 0, 0]\n", "positive"),
    ("image: m.png\nresolution: 0.1\norigin: [0, zero, 0]\n", "origin"),
    ("image: m.png\nresolution: 0.1\norigin: [0, 0, 0.5]\n", "rotated"),
    ("image: m.png\nresolution: 0.1\norigin: [0, 0, 0]\nfree_thresh: 0.9\n", "thresholds"),
    ("image: m.png\nresolution: 0.1\norigin: [0, 0, 0]\nfree_thresh: low\n", "thresholds"),
    ("image: m.png\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 3\n", "negate"),
    ("image: missing.png\nresolution: 0.1\norigin: [0, 0, 0]\n", "file not found"),
])
def test_bad_map_yaml_raises_naming_the_file(tmp_path: Path, content: str, message: str):
    FloorPlan(np.eye(4, dtype=bool), 0.1).save(tmp_path / "m.yaml")
    (tmp_path / "m.yaml").write_text(content)
    with pytest.raises(MapfilterError, match=message) as info:
        FloorPlan.load(tmp_path / "m.yaml")
    assert "m.yaml" in str(info.value) or "missing.png" in str(info.value)
    assert "\n" not in str(info.value)


def test_malformed_yaml_reports_the_line(tmp_path: Path):
    (tmp_path / "bad.yaml").write_text("image: m.png\nresolution: 0.1\norigin: [0, 0\nnegate: 0\n")
    with pytest.raises(MapfilterError) as info:
        FloorPlan.load(tmp_path / "bad.yaml")
    assert info.value.path.endswith("bad.yaml") and info.value.line is not None


def test_mask_image_that_is_not_an_image(tmp_path: Path):
    (tmp_path / "m.png").write_text("not a png")
    (tmp_path / "m.yaml").write_text("image: m.png\nresolution: 0.1\norigin: [0, 0, 0]\n")
    with pytest.raises(MapfilterError, match="not a readable image"):
        FloorPlan.load(tmp_path / "m.yaml")


def test_bad_constructor_values():
    with pytest.raises(MapfilterError):
        FloorPlan(np.zeros((0, 3), dtype=bool), 0.1)
    with pytest.raises(MapfilterError):
        FloorPlan(np.zeros((3, 3), dtype=bool), 0.0)
    with pytest.raises(MapfilterError):
        FloorPlan(np.zeros(3, dtype=bool), 0.1)


# ---- inputs larger than memory, values that are no floor plan -----------------------------------
REPO = Path(__file__).resolve().parents[2]


def write_flat_png(path: Path, width: int, height: int, value: int = 254) -> Path:
    """A valid 8-bit grey PNG of one colour, streamed row by row: a 20000 x 20000 plan is a
    0.4 MB file made in seconds without holding its 400 MB of pixels."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    packer = zlib.compressobj(9)
    row = b"\x00" + bytes([value]) * width  # filter byte 0, then the pixels
    data = b"".join(packer.compress(row) for _ in range(height)) + packer.flush()
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
                     + chunk(b"IDAT", data) + chunk(b"IEND", b""))
    return path


def test_a_huge_plan_is_refused_from_its_header_in_bounded_memory(tmp_path: Path):
    """A 20000 x 20000 PNG (0.4 MB) took 20 GB: its size is read before anything is decoded."""
    import resource
    import subprocess
    import sys

    png = write_flat_png(tmp_path / "big.png", 20000, 20000)
    assert png.stat().st_size < 1_000_000
    (tmp_path / "big.yaml").write_text("image: big.png\nresolution: 0.05\norigin: [0, 0, 0]\n")
    limit = 1536 << 20

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    for argv in (["simulate", str(tmp_path / "big.yaml"), "--aps", str(REPO / "maps" / "office_aps.csv"),
                  "--out", str(tmp_path / "walk.txt")],
                 ["map", "prepare", str(png), "--resolution", "0.05", "--out", str(tmp_path / "m.yaml")]):
        done = subprocess.run([sys.executable, "-m", "mapfilter", *argv], preexec_fn=cap, capture_output=True,
                              text=True, timeout=300)
        assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr[-500:]
        assert done.stderr.strip() == (f"mapfilter: error: {png}: the image is 20000 x 20000 pixels (400 M), more "
                                       "than the 120 M a floor plan may have: scale it down (and its resolution up "
                                       "by the same factor)")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["big.png", "big.yaml"]


def test_image_size_comes_from_the_header(tmp_path: Path):
    import cv2

    from mapfilter.maps.floorplan import image_size_px

    for suffix in (".png", ".pgm", ".jpg", ".bmp", ".tif"):
        path = tmp_path / f"plan{suffix}"
        cv2.imwrite(str(path), np.full((37, 53), 200, np.uint8))
        assert image_size_px(path) == (53, 37)
    (tmp_path / "noise.png").write_bytes(np.random.default_rng(0).bytes(1000))
    with pytest.raises(MapfilterError, match="not a readable image"):
        image_size_px(tmp_path / "noise.png")


@pytest.mark.parametrize("key, value, message", [
    ("resolution", "1.0e-300", "'resolution' 1e-300 m/px is not a floor plan's"),
    ("resolution", "1.0e+300", "'resolution' 1e+300 m/px is not a floor plan's"),
    ("resolution", "-0.05", "'resolution' must be a positive number"),
    ("resolution", ".nan", "'resolution' must be a positive number"),
    ("origin", "[1.0e+300, 0, 0]", "'origin' [1e+300, 0] is not a floor plan's"),
    ("origin", "[0, -2.0e+7, 0]", "is not a floor plan's: each coordinate must be within 1e+07 m"),
])
def test_absurd_map_values_are_refused_at_once(tmp_path: Path, key, value, message):
    write_flat_png(tmp_path / "m.png", 20, 10)
    meta = {"image": "m.png", "resolution": "0.05", "origin": "[0, 0, 0]", key: value}
    (tmp_path / "m.yaml").write_text("".join(f"{k}: {v}\n" for k, v in meta.items()))
    with pytest.raises(MapfilterError, match=message.replace("[", r"\[").replace("+", r"\+")) as info:
        FloorPlan.load(tmp_path / "m.yaml")
    assert info.value.path == str(tmp_path / "m.yaml")
    with pytest.raises(MapfilterError, match="not a floor plan's"):
        FloorPlan(np.zeros((3, 3), bool), 1e-300)


def test_grey_lookup_gives_the_per_pixel_rule(tmp_path: Path):
    """The mask comes from a 256-entry table of the thresholds: the same as the rule per pixel."""
    import cv2

    gray = np.arange(256, dtype=np.uint8).reshape(16, 16)
    cv2.imwrite(str(tmp_path / "g.png"), gray)
    for extra, expected in (("", ~((255.0 - gray) / 255.0 < 0.196)), ("negate: 1\n", ~(gray / 255.0 < 0.196)),
                            ("mode: raw\n", gray / 100.0 > 0.0)):
        (tmp_path / "g.yaml").write_text("image: g.png\nresolution: 0.1\norigin: [0, 0, 0]\n" + extra)
        np.testing.assert_array_equal(FloorPlan.load(tmp_path / "g.yaml").wall_mask, expected)


def test_is_free_is_the_pixel_index_lookup_for_every_point():
    """Oracle: the compiled is_free against pixel_index and the mask, on points inside, on pixel
    edges, off every side, NaN and infinite, in the shapes callers pass ((N, 2), (2,), (A, B, 2))."""
    rng = np.random.default_rng(8)
    mask = rng.random((37, 53)) < 0.3
    plan = FloorPlan(mask, 0.25, (-1.5, 2.0))

    def oracle(xy):
        rows, cols, inside = plan.pixel_index(xy)
        free = np.zeros(rows.shape, dtype=bool)
        free[inside] = ~mask[rows[inside], cols[inside]]
        return free

    x0, x1, y0, y1 = plan.extent_m
    points = np.concatenate([rng.uniform([x0 - 2, y0 - 2], [x1 + 2, y1 + 2], (5000, 2)),
                             np.column_stack([x0 + 0.25 * rng.integers(-2, 56, 500), y0 + 0.25 * rng.integers(-2, 40, 500)]),
                             [[np.nan, 3.0], [0.0, np.nan], [np.inf, 3.0], [-np.inf, 3.0], [x1, y0], [x0, y1]]])
    got = plan.is_free(points)
    assert got.any() and not got.all()
    np.testing.assert_array_equal(got, oracle(points))
    np.testing.assert_array_equal(plan.is_free(points[:12].reshape(3, 4, 2)), oracle(points[:12].reshape(3, 4, 2)))
    assert plan.is_free(points[0]).shape == () and plan.is_free(points[0]) == oracle(points[0])
    np.testing.assert_array_equal(plan.is_free(points[::2].T.copy().T), oracle(points[::2]))  # a strided view
