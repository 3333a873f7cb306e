"""FloorPlan: the wall mask every other part of mapfilter uses.

Conventions (ROS map_server): the mask is an image, row 0 at the top; ``origin_m`` is the
world position of the lower-left corner of the lower-left pixel; the world frame is metres,
x right, y up. Continuous pixel coordinates ``(u, v)`` put pixel ``(row, col)`` over
``col <= u < col + 1`` and ``row <= v < row + 1``, so ``u = (x - x0) / res`` and
``v = H - (y - y0) / res``.

Files: ``NAME.yaml`` with ``image``, ``resolution``, ``origin``, ``occupied_thresh``,
``free_thresh``, ``negate``, ``mode``, plus our own keys under ``mapfilter:`` (the source
floor-plan image for display and its placement, the floor name, an access-point table).
Any map_server-compatible tool reads the files we write; we read theirs.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml
from numba import njit

from mapfilter.io.atomic import atomic_paths
from mapfilter.errors import MapfilterError, not_a_file
from mapfilter.io.yamlio import load_yaml, path_for_yaml, path_in_yaml

# map_server's defaults; pixel values we write: 0 = occupied, 254 = free.
DEFAULT_OCCUPIED_THRESH = 0.65
DEFAULT_FREE_THRESH = 0.196
_FREE_VALUE = 254
_WALL_VALUE = 0

# What a floor plan can be. A pixel from 1 mm to 10 m (real plans: 1-50 cm); an origin within
# 10 000 km (any projected frame on Earth, e.g. UTM); an image of at most 120 M pixels (the IPIN
# 2023 plans are 54 M): tracking on a mask of that size takes about 2 GB (its wall-distance
# transform is 8 bytes a pixel). A 20000 x 20000 PNG can be a 434 kB file: its size is read
# from the header, before anything is decoded.
MIN_RESOLUTION_M = 1e-3
MAX_RESOLUTION_M = 10.0
MAX_ORIGIN_M = 1e7
MAX_IMAGE_PIXELS = 120_000_000


@njit(cache=True, nogil=True)
def _free_at(xy, wall_mask, x0, y0, resolution, out):
    # FloorPlan.is_free: world_to_pixel's arithmetic, a pixel floor(u), floor(v) inside the mask
    # (u in [0, width) and v in [0, height): NaN and infinities are outside, as there) and free
    height, width = wall_mask.shape
    for i in range(xy.shape[0]):
        u = (xy[i, 0] - x0) / resolution
        v = height - (xy[i, 1] - y0) / resolution
        out[i] = 0.0 <= u < width and 0.0 <= v < height and not wall_mask[int(math.floor(v)), int(math.floor(u))]


@dataclasses.dataclass(frozen=True, eq=False)
class SourceImage:
    """A floor-plan picture shown under the mask, placed in the world like the mask is."""

    path: Path  # absolute
    resolution_m: float  # metres per pixel of the picture
    origin_m: tuple[float, float]  # world position of the picture's lower-left corner


@dataclasses.dataclass(eq=False)
class FloorPlan:
    """A wall mask in the world frame.

    Attributes
    ----------
    wall_mask : (H, W) bool array, True = wall (or unknown: not walkable). Row 0 is the top.
    resolution_m : metres per pixel.
    origin_m : (x, y) world position of the lower-left corner of the image.
    floor_name : optional floor label (e.g. "F1").
    source_image : optional floor-plan picture for display.
    access_points_csv : optional path of an access-point table for this floor.
    """

    wall_mask: np.ndarray
    resolution_m: float
    origin_m: tuple[float, float] = (0.0, 0.0)
    floor_name: str | None = None
    source_image: SourceImage | None = None
    access_points_csv: Path | None = None

    def __post_init__(self) -> None:
        mask = np.asarray(self.wall_mask)
        if mask.ndim != 2 or mask.size == 0:
            raise MapfilterError(f"wall mask must be a non-empty 2-D array, got shape {mask.shape}")
        self.wall_mask = np.ascontiguousarray(mask, dtype=bool)
        if not (math.isfinite(self.resolution_m) and self.resolution_m > 0):
            raise MapfilterError(f"resolution must be a positive number of metres per pixel, got {self.resolution_m}")
        problem = plan_geometry_problem(self.resolution_m, self.origin_m)
        if problem:
            raise MapfilterError(problem)
        self.resolution_m = float(self.resolution_m)
        self.origin_m = (float(self.origin_m[0]), float(self.origin_m[1]))

    # ---- geometry -------------------------------------------------------------------------
    @property
    def shape_px(self) -> tuple[int, int]:
        """(rows, cols) of the mask."""
        return self.wall_mask.shape  # type: ignore[return-value]

    @property
    def size_m(self) -> tuple[float, float]:
        """(width, height) of the map in metres."""
        rows, cols = self.wall_mask.shape
        return cols * self.resolution_m, rows * self.resolution_m

    @property
    def extent_m(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) of the map in metres."""
        width_m, height_m = self.size_m
        x0, y0 = self.origin_m
        return x0, x0 + width_m, y0, y0 + height_m

    def world_to_pixel(self, xy_m: np.ndarray) -> np.ndarray:
        """Continuous pixel coordinates ``(u, v)`` = (column, row) of world points.

        ``floor(v), floor(u)`` index the mask; pixel centres sit at half-integers.
        """
        xy = np.asarray(xy_m, dtype=np.float64)
        u = (xy[..., 0] - self.origin_m[0]) / self.resolution_m
        v = self.wall_mask.shape[0] - (xy[..., 1] - self.origin_m[1]) / self.resolution_m
        return np.stack([u, v], axis=-1)

    def pixel_to_world(self, uv_px: np.ndarray) -> np.ndarray:
        """World points of continuous pixel coordinates ``(u, v)`` (inverse of world_to_pixel).

        For the centre of pixel (row, col) pass ``(col + 0.5, row + 0.5)``.
        """
        uv = np.asarray(uv_px, dtype=np.float64)
        x = self.origin_m[0] + uv[..., 0] * self.resolution_m
        y = self.origin_m[1] + (self.wall_mask.shape[0] - uv[..., 1]) * self.resolution_m
        return np.stack([x, y], axis=-1)

    def pixel_index(self, xy_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rows, cols, inside) integer pixel indices of world points; ``inside`` marks in-bounds."""
        uv = self.world_to_pixel(xy_m)
        cols = np.floor(uv[..., 0]).astype(np.int64)
        rows = np.floor(uv[..., 1]).astype(np.int64)
        h, w = self.wall_mask.shape
        inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
        return rows, cols, inside

    def is_free(self, xy_m: np.ndarray) -> np.ndarray:
        """True where a world point lies on a free pixel (outside the map counts as wall)."""
        xy = np.asarray(xy_m, dtype=np.float64)
        free = np.empty(xy.shape[:-1], dtype=bool)
        flat = np.ascontiguousarray(xy).reshape(-1, 2)
        # one compiled loop: the filter asks this of a point or a few many times a step, where
        # pixel_index's numpy calls cost tens of microseconds
        _free_at(flat, self.wall_mask, float(self.origin_m[0]), float(self.origin_m[1]), float(self.resolution_m),
                 free.reshape(-1))
        return free

    @functools.cached_property
    def free_pixels(self) -> tuple[np.ndarray, np.ndarray]:
        """(rows, cols) of every free pixel."""
        return np.nonzero(~self.wall_mask)

    @property
    def free_fraction(self) -> float:
        return float(np.count_nonzero(~self.wall_mask)) / self.wall_mask.size

    def sample_free(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` world points drawn uniformly over free space, shape (n, 2)."""
        rows, cols = self.free_pixels
        if rows.size == 0:
            raise MapfilterError("the map has no free space to place positions in")
        pick = rng.integers(0, rows.size, size=n)
        uv = np.stack([cols[pick] + rng.random(n), rows[pick] + rng.random(n)], axis=-1)
        return self.pixel_to_world(uv)

    @functools.cached_property
    def wall_distance_px(self) -> np.ndarray:
        """Per pixel: Euclidean distance (pixels) from its centre to the nearest wall pixel centre."""
        if not self.wall_mask.any():
            return np.full(self.wall_mask.shape, np.inf)
        # OpenCV's exact Euclidean transform (Felzenszwalb): scipy.ndimage takes 0.3 s to import
        return cv2.distanceTransform((~self.wall_mask).astype(np.uint8), cv2.DIST_L2,
                                     cv2.DIST_MASK_PRECISE).astype(np.float64)

    def distance_to_wall_m(self, xy_m: np.ndarray) -> np.ndarray:
        """Distance in metres from world points to the nearest wall pixel (0 on walls / outside)."""
        rows, cols, inside = self.pixel_index(xy_m)
        dist = np.zeros(rows.shape, dtype=np.float64)
        dist[inside] = self.wall_distance_px[rows[inside], cols[inside]] * self.resolution_m
        return dist

    # ---- files ----------------------------------------------------------------------------
    @classmethod
    def load(cls, yaml_path: str | os.PathLike) -> FloorPlan:
        """Read a ROS map_server map (``NAME.yaml`` + image) with our optional extra keys."""
        yaml_path = Path(yaml_path)
        meta = read_yaml_mapping(yaml_path)
        for key in ("image", "resolution", "origin"):
            if key not in meta:
                raise MapfilterError(f"map YAML lacks the required key '{key}'", yaml_path)
        resolution, origin = _map_geometry(meta, yaml_path)
        free_thresh, negate, mode = _occupancy_rule(meta, yaml_path)
        gray = read_gray_image(path_in_yaml(yaml_path, meta["image"]))
        wall = _wall_of_gray(gray, free_thresh, negate, mode)
        ours = meta.get("mapfilter") or {}
        if not isinstance(ours, dict):
            raise MapfilterError("'mapfilter' must be a mapping of our extra keys", yaml_path)
        source = _source_image(ours, origin, resolution, yaml_path) if ours.get("source_image") else None
        aps = path_in_yaml(yaml_path, ours["access_points"]) if ours.get("access_points") else None
        floor = ours.get("floor")
        return cls(wall, resolution, (float(origin[0]), float(origin[1])),
                   None if floor is None else str(floor), source, aps)

    def save(self, yaml_path: str | os.PathLike, image_name: str | None = None) -> None:
        """Write ``NAME.yaml`` and the mask image (PNG by default) beside it, atomically.

        Walls are written as 0 and free space as 254 with map_server's default thresholds,
        so the mask round-trips exactly.
        """
        yaml_path = Path(yaml_path)
        image_path = yaml_path.with_name(image_name or (yaml_path.stem + ".png"))
        pixels = np.where(self.wall_mask, _WALL_VALUE, _FREE_VALUE).astype(np.uint8)
        meta: dict[str, Any] = {
            "image": image_path.name,
            "resolution": self.resolution_m,
            "origin": [self.origin_m[0], self.origin_m[1], 0.0],
            "occupied_thresh": DEFAULT_OCCUPIED_THRESH,
            "free_thresh": DEFAULT_FREE_THRESH,
            "negate": 0,
            "mode": "trinary",
        }
        ours: dict[str, Any] = {}
        if self.floor_name is not None:
            ours["floor"] = self.floor_name
        if self.source_image is not None:
            ours["source_image"] = path_for_yaml(self.source_image.path, yaml_path.parent)
            ours["source_resolution"] = self.source_image.resolution_m
            ours["source_origin"] = list(self.source_image.origin_m)
        if self.access_points_csv is not None:
            ours["access_points"] = path_for_yaml(self.access_points_csv, yaml_path.parent)
        if ours:
            meta["mapfilter"] = ours
        with atomic_paths(yaml_path, image_path) as (tmp_yaml, tmp_image):
            # the temporary keeps the final suffix, so OpenCV picks the same encoder
            if not cv2.imwrite(str(tmp_image), pixels):
                raise MapfilterError("could not write the mask image", image_path)
            tmp_yaml.write_text(yaml.safe_dump(meta, sort_keys=False))


def plan_geometry_problem(resolution_m: float, origin_m, resolution_key: str = "resolution",
                          origin_key: str = "origin") -> str | None:
    """Why a plan's resolution (m/px) and origin (m) cannot be a floor plan, or None if they can
    (the ranges ``MIN_RESOLUTION_M``..``MAX_RESOLUTION_M`` and ``MAX_ORIGIN_M``)."""
    if not (math.isfinite(resolution_m) and MIN_RESOLUTION_M <= resolution_m <= MAX_RESOLUTION_M):
        return (f"'{resolution_key}' {resolution_m!r} m/px is not a floor plan's: it must be between "
                f"{MIN_RESOLUTION_M:g} and {MAX_RESOLUTION_M:g} metres per pixel")
    for value in origin_m:
        if not (math.isfinite(float(value)) and abs(float(value)) <= MAX_ORIGIN_M):
            return (f"'{origin_key}' {list(origin_m)!r} is not a floor plan's: each coordinate must be within "
                    f"{MAX_ORIGIN_M:g} m of 0")
    return None


def image_size_px(path: str | os.PathLike) -> tuple[int, int]:
    """(width, height) of an image file read from its header, without decoding it.

    ``MapfilterError`` if the file is missing or not an image format we read.
    """
    path = Path(path)
    if not path.is_file():
        raise not_a_file(path)
    with path.open("rb") as handle:
        head = handle.read(26)
    # PNG: the signature, then the IHDR chunk (length, type, width, height: big-endian)
    if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
        return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    import warnings

    from PIL import Image, UnidentifiedImageError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(path) as image:  # reads the header only
                return image.size
    except Image.DecompressionBombError:  # Pillow's own limit, above ours
        return (2 * Image.MAX_IMAGE_PIXELS, 1)
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError):
        raise MapfilterError("not a readable image (PNG, PGM, JPEG, BMP, TIFF, ...)", path) from None


def _check_source_image_size(path: Path, yaml_path: Path) -> None:
    # the picture drawn under the mask must fit in memory too; a missing or unreadable one is
    # simply not drawn (viz), as before
    try:
        width, height = image_size_px(path)
    except MapfilterError:
        return
    if width * height > MAX_IMAGE_PIXELS:
        raise MapfilterError(f"the source image {path} is {width} x {height} pixels, more than the "
                             f"{MAX_IMAGE_PIXELS / 1e6:.0f} M a floor plan may have", yaml_path)


def check_image_size(path: str | os.PathLike, max_pixels: int = MAX_IMAGE_PIXELS) -> tuple[int, int]:
    """``image_size_px``, refused with one line if the image has more than ``max_pixels``."""
    width, height = image_size_px(path)
    if width * height > max_pixels:
        raise MapfilterError(f"the image is {width} x {height} pixels ({width * height / 1e6:.0f} M), more than the "
                             f"{max_pixels / 1e6:.0f} M a floor plan may have: scale it down (and its resolution "
                             f"up by the same factor)", path)
    if width == 0 or height == 0:
        raise MapfilterError("the image is empty (0 pixels)", path)
    return width, height


def read_gray_image(path: str | os.PathLike) -> np.ndarray:
    """Read an image as 8-bit grey (colour channels averaged, as map_server does).

    The size is checked from the file's header first (``check_image_size``)."""
    path = Path(path)
    check_image_size(path)
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise MapfilterError("not a readable image", path)
    if image.dtype != np.uint8:
        image = cv2.convertScaleAbs(image, alpha=255.0 / max(float(image.max()), 1.0))
    if image.ndim == 3:
        # in bands of rows: the float64 mean of a whole large plan would take 8 bytes a pixel
        gray = np.empty(image.shape[:2], dtype=np.uint8)
        for top in range(0, image.shape[0], 1024):
            gray[top:top + 1024] = image[top:top + 1024, :, :3].mean(axis=2).round().astype(np.uint8)
        image = gray
    return image


def read_yaml_mapping(path: Path, what: str = "a map YAML") -> dict:
    """The mapping of keys in a YAML file (also JSON), read by ``mapfilter.io.yamlio`` (size and
    alias limits, duplicate keys refused); ``MapfilterError`` naming the file (and the line)
    when it is missing, a directory, malformed or not a mapping."""
    meta = load_yaml(Path(path), what)
    if not isinstance(meta, dict):
        raise MapfilterError(f"{what} must be a mapping of keys", path)
    return meta


def is_number(value: Any) -> bool:
    """A finite int or float (not a bool; an int too large for a float, e.g. 400 digits, is not)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:
        return False


def _map_geometry(meta: dict, yaml_path: Path) -> tuple[float, list]:
    """(resolution, origin [x, y(, yaw)]) of a map YAML: numbers, a plan of a sane size, no rotation."""
    resolution = _positive_float(meta["resolution"], "resolution", yaml_path)
    origin = meta["origin"]
    if not (isinstance(origin, list) and len(origin) in (2, 3) and all(is_number(v) for v in origin)):
        raise MapfilterError(f"'origin' must be [x, y, yaw] numbers, got {origin!r}", yaml_path)
    problem = plan_geometry_problem(resolution, origin[:2])
    if problem:
        raise MapfilterError(problem, yaml_path)
    if len(origin) == 3 and abs(float(origin[2])) > 1e-9:
        raise MapfilterError(f"a rotated map (origin yaw {origin[2]}) is not supported", yaml_path)
    return resolution, origin


def _occupancy_rule(meta: dict, yaml_path: Path) -> tuple[float, object, str]:
    """(free_thresh, negate, mode) of a map YAML, map_server's defaults where absent (occupied_thresh
    checked: a cell between the thresholds is unknown, which counts as wall)."""
    occupied_thresh = meta.get("occupied_thresh", DEFAULT_OCCUPIED_THRESH)
    free_thresh = meta.get("free_thresh", DEFAULT_FREE_THRESH)
    if not (is_number(occupied_thresh) and is_number(free_thresh)):
        raise MapfilterError(f"thresholds must be numbers, got occupied_thresh {occupied_thresh!r}, "
                             f"free_thresh {free_thresh!r}", yaml_path)
    occupied_thresh, free_thresh = float(occupied_thresh), float(free_thresh)
    if not 0.0 <= free_thresh <= occupied_thresh <= 1.0:
        raise MapfilterError(
            f"thresholds must satisfy 0 <= free_thresh ({free_thresh}) <= occupied_thresh ({occupied_thresh}) <= 1",
            yaml_path,
        )
    negate = meta.get("negate", 0)
    if negate not in (0, 1, True, False):
        raise MapfilterError(f"'negate' must be 0 or 1, got {negate!r}", yaml_path)
    mode = meta.get("mode", "trinary")
    if mode not in ("trinary", "scale", "raw"):
        raise MapfilterError(f"'mode' must be trinary, scale or raw, got {mode!r}", yaml_path)
    return free_thresh, negate, mode


def _wall_of_gray(gray: np.ndarray, free_thresh: float, negate, mode: str) -> np.ndarray:
    """The wall mask of a map image. The rule for each of the 256 grey values, looked up per pixel:
    the same numbers as computing it per pixel, without (H, W) float64 temporaries."""
    values = np.arange(256, dtype=np.uint8)
    if mode == "raw":
        # raw: the pixel value is the occupancy in percent (0 = free)
        occupancy = values.astype(np.float64) / 100.0
    else:
        occupancy = values.astype(np.float64) / 255.0 if negate else (255.0 - values) / 255.0
    # Unknown cells (between the thresholds) are not walkable: they count as wall.
    return (~(occupancy < free_thresh) if mode != "raw" else occupancy > 0.0)[gray]


def _source_image(ours: dict, origin: list, resolution: float, yaml_path: Path) -> SourceImage:
    """The source floor-plan image our keys name (for display), its geometry checked."""
    src_origin = ours.get("source_origin", origin[:2])
    if not (isinstance(src_origin, list) and len(src_origin) >= 2 and all(is_number(v) for v in src_origin[:2])):
        raise MapfilterError(f"'source_origin' must be [x, y] numbers, got {src_origin!r}", yaml_path)
    source = SourceImage(
        path=path_in_yaml(yaml_path, ours["source_image"]),
        resolution_m=_positive_float(ours.get("source_resolution", resolution), "source_resolution", yaml_path),
        origin_m=(float(src_origin[0]), float(src_origin[1])),
    )
    problem = plan_geometry_problem(source.resolution_m, source.origin_m, "source_resolution", "source_origin")
    if problem:
        raise MapfilterError(problem, yaml_path)
    _check_source_image_size(source.path, yaml_path)
    return source


def _positive_float(value: Any, key: str, path: Path) -> float:
    if not is_number(value) or value <= 0:
        raise MapfilterError(f"'{key}' must be a positive number, got {value!r}", path)
    return float(value)
