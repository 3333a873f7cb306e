"""An IPIN venue as a georeferenced building: a calibration file and its raster plans -> Building.

The IPIN competitions give each venue's floors as raster plans and a calibration file
(``.cal``, maps/georef.py) placing each image on the Earth by its centre's latitude and
longitude, its rotation to north and its scale. :func:`import_ipin_venue` makes a
:class:`~mapfilter.maps.building.Building` of it whose frame is the east/north tangent plane at
the first floor's image centre (the building's ``georeference``), so that a position in any
floor's map converts to latitude/longitude and back:

- every floor's map is axis-aligned with east/north at ``resolution_m``: the plan, rotated,
  lands in it, and the cells outside the image are wall (the map's border is walled);
- a plan is decoded reduced (OpenCV's ``IMREAD_REDUCED_GRAYSCALE_2/4/8``) to the coarsest
  scale that still gives two decoded pixels per map cell: the 10719 x 5069 px plan of
  IPIN 2023's floor -1 decodes as 2680 x 1267 px (4.9 cm) for 0.1 m cells; a plan larger than
  :data:`MAX_PLAN_PIXELS` is refused before it is decoded;
- walls are the dark strokes (:data:`INK_BELOW` on the decoded grey, in which the 1-2 px
  annotation lines of a CAD plan, axes, dimensions, dashed outlines of the floor above, have
  faded to light grey, while walls drawn as thick strokes stay dark); ink blobs shorter than
  :data:`TEXT_BELOW_M` (labels, markers) are dropped; a map cell is wall if any wall pixel falls
  in it, so walls stay closed;
- a floor whose image is missing becomes an open floor (free space, walled border) over the
  extent its image would have (the size of the venue's other images), with a warning;
- floors are named by the venue's ids ("0", "-1", "-2") and stand ``storey_height_m`` apart
  (elevation = id x storey height; the calibration file has no heights).
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.maps.building import Building, Floor
from mapfilter.maps.floorplan import FloorPlan, SourceImage
from mapfilter.maps.georef import CalFloor, ImagePlacement, LocalFrame, read_cal

DEFAULT_RESOLUTION_M = 0.1  # map cells: a door (0.8 m) is 8 cells, a 145 m x 105 m venue 1.5 Mpx
# No storey height is in a calibration file. 4 m is the default (an office or museum storey is
# 3-5 m); pass the venue's own (IPIN 2023 Nuremberg: 2.8 m, measured from trial 52's barometer,
# docs/formats.md).
DEFAULT_STOREY_HEIGHT_M = 4.0
DISPLAY_RESOLUTION_M = 0.05  # the rotated plan written beside each map, shown under the mask
MAX_PLAN_PIXELS = 300_000_000  # a plan this large decodes to 300 MB of grey before reduction
MAX_MAP_CELLS = 50_000_000  # as prepare_geojson: a map larger than this is a wrong resolution
INK_BELOW = 128  # decoded grey below this is wall
TEXT_BELOW_M = 1.5  # ink blobs whose longer side is shorter are labels (1.1 m for "9004" on IPIN 2023 -1), not walls


@dataclasses.dataclass
class VenueFloor:
    """One imported floor: the map, and the plan turned into its frame for display (or None)."""

    name: str
    plan: FloorPlan  # source_image unset: the caller writes ``display`` and points the map at it
    display: np.ndarray | None  # grey plan image axis-aligned with the map, DISPLAY_RESOLUTION_M per px
    display_origin_m: tuple[float, float] | None  # the display image's lower-left corner in the map frame
    image_path: Path | None  # the source plan, None for an open floor

    def with_display_file(self, path: Path) -> FloorPlan:
        """The map with ``path`` (where ``display`` was written) as its picture."""
        if self.display_origin_m is None:
            return self.plan
        return dataclasses.replace(self.plan, source_image=SourceImage(Path(path).resolve(), DISPLAY_RESOLUTION_M,
                                                                        self.display_origin_m))


def plan_size_px(path: Path) -> tuple[int, int]:
    """(width, height) of an image from its header, without decoding it."""
    from PIL import Image  # Pillow comes with matplotlib; it reads only the header here

    limit, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None  # the size is checked by the caller
    try:
        with Image.open(path) as image:
            return int(image.size[0]), int(image.size[1])
    except (OSError, ValueError, Image.DecompressionBombError) as exc:
        raise MapfilterError(f"not a readable image ({exc})", path) from None
    finally:
        Image.MAX_IMAGE_PIXELS = limit


def import_ipin_venue(cal_path: str | os.PathLike, resolution_m: float = DEFAULT_RESOLUTION_M,
                      storey_height_m: float = DEFAULT_STOREY_HEIGHT_M,
                      warn: Callable[[str], None] | None = None) -> tuple[Building, list[VenueFloor]]:
    """The building of an IPIN calibration file (maps not yet written; see the module docstring).

    Returns the building (floors bottom to top, georeferenced) and per floor its map and
    display picture. Images are looked for next to the ``.cal``. ``MapfilterError`` when no
    image is found at all (the extent is unknown), for floor ids that are not integers, or
    for a bad resolution or storey height.
    """
    cal_path = Path(cal_path)
    if not (math.isfinite(resolution_m) and 0.01 <= resolution_m <= 5.0):
        raise MapfilterError(f"--resolution must be between 0.01 and 5 m per cell, got {resolution_m}")
    if not (math.isfinite(storey_height_m) and 0.0 < storey_height_m <= 100.0):
        raise MapfilterError(f"--storey-height must be a positive number of metres, got {storey_height_m}")
    cal = read_cal(cal_path)
    try:
        storeys = {f.floor: int(f.floor) for f in cal}
    except ValueError:
        raise MapfilterError("floor numbers must be integers to place the floors by storey", cal_path) from None
    images = {f.floor: (cal_path.parent / f.image) for f in cal}
    sizes = {name: plan_size_px(path) for name, path in images.items() if path.is_file()}
    if not sizes:
        raise MapfilterError(f"none of the plan images ({', '.join(f.image for f in cal)}) is next to the "
                             f"calibration file: the venue's extent is unknown", cal_path)
    frame = LocalFrame(cal[0].centre_lat_deg, cal[0].centre_lon_deg)
    known_size = next(iter(sizes.values()))
    floors: list[VenueFloor] = []
    for entry in sorted(cal, key=lambda f: storeys[f.floor]):
        if entry.floor in sizes:
            floors.append(_floor_from_image(entry, images[entry.floor], sizes[entry.floor], frame, resolution_m))
        else:
            if warn is not None:
                warn(f"{cal_path}: the plan of floor {entry.floor} ({entry.image}) is missing: floor "
                     f"{entry.floor} is an open floor (free space, walled border) over the image's extent")
            floors.append(_open_floor(entry, known_size, frame, resolution_m))
    building = Building([Floor(f.name, f.plan, storeys[f.name] * storey_height_m) for f in floors], [],
                        _venue_name(cal_path), None, storey_height_m, frame)
    building.validate()
    return building, floors


def _venue_name(cal_path: Path) -> str:
    stem = cal_path.stem
    return stem.removeprefix("calib_mapa_").removeprefix("calib_") or stem


@dataclasses.dataclass(frozen=True)
class _Grid:
    """An axis-aligned map grid: ``rows`` x ``cols`` cells of ``resolution_m``, lower-left corner ``origin_m``."""

    origin_m: tuple[float, float]
    rows: int
    cols: int
    resolution_m: float

    def centres_xy_m(self, cols: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Map-frame centres of the cells (col, row), row 0 at the top."""
        return np.stack([self.origin_m[0] + (np.asarray(cols, float) + 0.5) * self.resolution_m,
                         self.origin_m[1] + (self.rows - np.asarray(rows, float) - 0.5) * self.resolution_m], axis=-1)


def _map_grid(placement: ImagePlacement, frame: LocalFrame, resolution_m: float, where: Path) -> _Grid:
    """The grid covering the placed image with a one-cell margin, its edges on multiples of the cell."""
    corners = placement.corners_xy_m(frame)
    x_min, y_min = np.floor(corners.min(axis=0) / resolution_m) * resolution_m - resolution_m
    x_max, y_max = np.ceil(corners.max(axis=0) / resolution_m) * resolution_m + resolution_m
    cols = int(round((x_max - x_min) / resolution_m))
    rows = int(round((y_max - y_min) / resolution_m))
    if rows * cols > MAX_MAP_CELLS:
        raise MapfilterError(f"resolution {resolution_m} m gives a {cols}x{rows} map: too large", where)
    return _Grid((float(x_min), float(y_min)), rows, cols, resolution_m)


def _sample(image: np.ndarray, placement: ImagePlacement, frame: LocalFrame, grid: _Grid,
            interpolation: int, outside: int) -> np.ndarray:
    """``image`` (the whole plan, possibly reduced) read at the grid's cell centres, ``outside``
    beyond its edges. Cell -> pixel is affine, so one warpAffine does it without coordinate grids."""
    sx = image.shape[1] / placement.size_px[0]
    sy = image.shape[0] / placement.size_px[1]
    cells = np.array([[0, 0], [1, 0], [0, 1]], dtype=np.float64)  # (col, row)
    uv = placement.xy_m_to_pixel(grid.centres_xy_m(cells[:, 0], cells[:, 1]), frame)
    # continuous pixel coordinates of the full plan -> pixel-centre coordinates of ``image``
    src = np.column_stack([uv[:, 0] * sx - 0.5, uv[:, 1] * sy - 0.5])
    matrix = np.array([[src[1, 0] - src[0, 0], src[2, 0] - src[0, 0], src[0, 0]],
                       [src[1, 1] - src[0, 1], src[2, 1] - src[0, 1], src[0, 1]]])
    return cv2.warpAffine(image, matrix, (grid.cols, grid.rows), flags=interpolation | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=outside)


def _floor_from_image(entry: CalFloor, image_path: Path, size_px: tuple[int, int], frame: LocalFrame,
                      resolution_m: float) -> VenueFloor:
    width, height = size_px
    if width * height > MAX_PLAN_PIXELS:
        raise MapfilterError(f"the plan is {width}x{height} px, more than {MAX_PLAN_PIXELS // 1_000_000} "
                             f"megapixels: reduce it first", image_path)
    placement = entry.placement(size_px)
    # the coarsest reduced decoding with at least two decoded pixels per map cell
    factor = 1
    for k in (2, 4, 8):
        if entry.scale_m_per_px * k <= 0.5 * resolution_m:
            factor = k
    flag = {1: cv2.IMREAD_GRAYSCALE, 2: cv2.IMREAD_REDUCED_GRAYSCALE_2, 4: cv2.IMREAD_REDUCED_GRAYSCALE_4,
            8: cv2.IMREAD_REDUCED_GRAYSCALE_8}[factor]
    grey = cv2.imread(str(image_path), flag)
    if grey is None or grey.size == 0:
        raise MapfilterError("not a readable image", image_path)
    decoded_m = entry.scale_m_per_px * width / grey.shape[1]
    ink = (grey < INK_BELOW).astype(np.uint8)
    # drop labels and markers: ink blobs whose bounding box's longer side is short
    count, labels, stats, _ = cv2.connectedComponentsWithStats(ink, connectivity=8)
    longer = np.maximum(stats[:, cv2.CC_STAT_WIDTH], stats[:, cv2.CC_STAT_HEIGHT]) * decoded_m
    keep = (longer >= TEXT_BELOW_M).astype(np.uint8)
    keep[0] = 0
    ink = keep[labels]
    # a map cell is wall if any wall pixel falls in it: grow the ink by the cell's half diagonal,
    # then read it at the cell centre
    radius = int(math.ceil(0.5 * math.sqrt(2.0) * resolution_m / decoded_m))
    kernel = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    grown = cv2.dilate(ink, kernel)
    grid = _map_grid(placement, frame, resolution_m, image_path)
    wall = _sample(grown, placement, frame, grid, cv2.INTER_NEAREST, outside=1).astype(bool)
    if wall.all():
        raise MapfilterError("the plan has no free space (everything came out as wall)", image_path)
    # the plan turned into the map frame, for display under the mask
    shown = _map_grid(placement, frame, DISPLAY_RESOLUTION_M, image_path)
    display = _sample(grey, placement, frame, shown, cv2.INTER_LINEAR, outside=255)
    return VenueFloor(entry.floor, FloorPlan(wall, resolution_m, grid.origin_m, entry.floor), display, shown.origin_m,
                      image_path)


def _open_floor(entry: CalFloor, size_px: tuple[int, int], frame: LocalFrame, resolution_m: float) -> VenueFloor:
    placement = entry.placement(size_px)
    grid = _map_grid(placement, frame, resolution_m, Path(entry.image))
    blank = np.zeros((size_px[1] // 64 + 1, size_px[0] // 64 + 1), np.uint8)  # a free image of that extent
    wall = _sample(blank, placement, frame, grid, cv2.INTER_NEAREST, outside=1).astype(bool)
    return VenueFloor(entry.floor, FloorPlan(wall, resolution_m, grid.origin_m, entry.floor), None, None, None)
