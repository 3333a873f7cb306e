"""Map preparation: floor plans (line drawings, filled-region images, GeoJSON) -> FloorPlan.

One function per kind of plan, each returning a :class:`~mapfilter.maps.floorplan.FloorPlan`:

- :func:`prepare_lines`: drawings, dark walls on light paper (scans, CAD exports, real-estate
  plans): the reader of :mod:`mapfilter.maps.drawing` (paper evened, walls told from annotation,
  door symbols, the building's outline with its entrances closed).
- :func:`prepare_regions`: filled-region plans such as the ILC ``floor_image.png`` (transparent
  corridors, filled shops, outlines, text): the walkable colours (transparent by default), the
  drawn outlines of the filled regions opened and small blobs in corridors dropped.

:func:`detect_kind` tells a drawing from a filled-region plan, and :func:`prepare_plan` does
either kind chosen from the image.
- :func:`prepare_geojson`: vector floors (outline + shop polygons, lon/lat or metres) rasterised
  at a chosen resolution with shapely; outside the outline is wall.

:func:`apply_edits` forces polygons (in metres) free or wall, :func:`write_map` writes the
map YAML + mask + a preview PNG atomically, :func:`import_ilc` does an ILC floor in one call.
The plan's scale comes from a :class:`PlanScale` (metres per pixel, real size, or two points
and their distance); a missing or contradictory scale is a :class:`MapfilterError`.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import shapely
from shapely.geometry import shape as geojson_shape

from mapfilter.io.atomic import atomic_paths
from mapfilter.errors import MapfilterError, not_a_file
from mapfilter.io.yamlio import load_yaml
from mapfilter.maps.drawing import DrawingOptions, DrawingReading, even_paper, read_drawing
from mapfilter.maps.floorplan import MAX_IMAGE_PIXELS, FloorPlan, SourceImage, check_image_size, plan_geometry_problem

EARTH_RADIUS_M = 6378137.0  # Web Mercator sphere (ILC README)
# Two scale sources that disagree by more than this (relative) are contradictory; ILC floors
# give width/height that imply pixel sizes 0.1 % apart, a hand-measured distance is rarely better
# than 1 %.
SCALE_TOLERANCE = 0.02


# ---- scale ----------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class PlanScale:
    """How big a plan pixel is. Give one or more; they must agree (within ``SCALE_TOLERANCE``).

    Attributes
    ----------
    resolution_m : metres per plan pixel.
    size_m : (width, height) of the whole plan image in metres (ILC floor_info.json); either may
        be None to use only the other one.
    points_px : two image points ((u1, v1), (u2, v2)) in pixels (column, row).
    points_distance_m : the real distance between ``points_px`` in metres.
    """

    resolution_m: float | None = None
    size_m: tuple[float | None, float | None] | None = None
    points_px: tuple[tuple[float, float], tuple[float, float]] | None = None
    points_distance_m: float | None = None

    def resolve(self, shape_px: tuple[int, int], path: str | os.PathLike | None = None) -> float:
        """Metres per pixel of a plan of ``shape_px`` = (rows, cols); error if missing/contradictory."""
        candidates: list[tuple[str, float]] = []
        if self.resolution_m is not None:
            candidates.append(("--resolution", _positive(self.resolution_m, "resolution", path)))
        if self.size_m is not None:
            width_m, height_m = self.size_m
            if width_m is not None:
                candidates.append(("width", _positive(width_m, "width", path) / shape_px[1]))
            if height_m is not None:
                candidates.append(("height", _positive(height_m, "height", path) / shape_px[0]))
        if (self.points_px is None) != (self.points_distance_m is None):
            raise MapfilterError("two scale points need their distance, and a distance needs two points", path)
        if self.points_px is not None:
            (u1, v1), (u2, v2) = self.points_px
            span_px = math.hypot(u2 - u1, v2 - v1)
            if span_px <= 0:
                raise MapfilterError("the two scale points coincide", path)
            candidates.append(("two points", _positive(self.points_distance_m, "distance", path) / span_px))
        if not candidates:
            raise MapfilterError(
                "no scale given: use --resolution M, --size W H, or --scale-points U1 V1 U2 V2 --scale-distance M", path
            )
        reference_name, reference = candidates[0]
        for name, value in candidates[1:]:
            if abs(value - reference) > SCALE_TOLERANCE * reference:
                raise MapfilterError(
                    f"contradictory scale: {reference_name} gives {reference:.4g} m/px but {name} gives {value:.4g} m/px",
                    path,
                )
        return float(np.mean([value for _, value in candidates]))


def _positive(value: Any, name: str, path: str | os.PathLike | None) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise MapfilterError(f"{name} must be a number, got {value!r}", path) from None
    if not (math.isfinite(number) and number > 0):
        raise MapfilterError(f"{name} must be a positive number, got {value!r}", path)
    return number


def _check_pixel_counts(options: Any, names: tuple[str, ...]) -> None:
    for name in names:
        value = getattr(options, name)
        if not isinstance(value, (int, np.integer)) or value < 0:
            raise MapfilterError(f"{name} must be a whole number >= 0, got {value!r}")


# ---- reading plans --------------------------------------------------------------------------
def read_plan_image(path: str | os.PathLike) -> np.ndarray:
    """Read a plan as 8-bit BGRA (grey and BGR images get an opaque alpha channel).

    The size is checked from the file's header first (``floorplan.check_image_size``)."""
    path = Path(path)
    check_image_size(path)
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None or image.size == 0:
        raise MapfilterError("not a readable image", path)
    if image.dtype != np.uint8:
        image = cv2.convertScaleAbs(image, alpha=255.0 / max(float(image.max()), 1.0))
    if image.ndim == 2:
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGRA)
    elif image.shape[2] == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2BGRA)
    return image


def _flatten_on_white(bgra: np.ndarray) -> np.ndarray:
    """BGR picture of a BGRA plan composited over white (transparent = paper)."""
    if bgra[..., 3].min() == 255:  # opaque: nothing to composite
        return np.ascontiguousarray(bgra[..., :3])
    alpha = bgra[..., 3:4].astype(np.float32) / 255.0
    return (bgra[..., :3] * alpha + 255.0 * (1.0 - alpha)).round().astype(np.uint8)


# ---- line drawings --------------------------------------------------------------------------
def prepare_lines(
    plan_path: str | os.PathLike,
    scale: PlanScale,
    options: DrawingOptions = DrawingOptions(),
    map_resolution_m: float | None = None,
    floor_name: str | None = None,
) -> FloorPlan:
    """Wall mask of a drawing (dark walls on light paper): see :mod:`mapfilter.maps.drawing`.

    Parameters
    ----------
    plan_path : the plan image (PNG, JPEG, PGM, ...; transparent pixels count as paper).
    scale : the plan's scale.
    options : see :class:`~mapfilter.maps.drawing.DrawingOptions`.
    map_resolution_m : metres per pixel of the output mask (default: the plan's own); a coarser
        mask marks a cell wall if any plan wall pixel falls in it, so walls stay closed.
    floor_name : optional floor label.
    """
    return read_lines(plan_path, scale, options, map_resolution_m, floor_name)[0]


def read_lines(plan_path: str | os.PathLike, scale: PlanScale, options: DrawingOptions = DrawingOptions(),
               map_resolution_m: float | None = None, floor_name: str | None = None) -> tuple[FloorPlan, DrawingReading]:
    """:func:`prepare_lines` and what the reader found (doors, threshold, text blobs dropped)."""
    plan_path = Path(plan_path)
    bgra = read_plan_image(plan_path)
    resolution_m = scale.resolve(bgra.shape[:2], plan_path)
    problem = plan_geometry_problem(resolution_m, (0.0, 0.0), "resolution")
    if problem:  # the reader's sizes are in metres: checked before any is turned into pixels
        raise MapfilterError(problem, plan_path)
    if options.close_gaps_px > 0:
        _check_morphology_fits(bgra, options.close_gaps_px, "--close-gaps")
    if options.thicken_px > 0:
        _check_morphology_fits(bgra, options.thicken_px, "dilating walls by")
    gray = cv2.cvtColor(_flatten_on_white(bgra), cv2.COLOR_BGR2GRAY)
    reading = read_drawing(gray, resolution_m, options, plan_path)
    return _finish(reading.wall, resolution_m, map_resolution_m, plan_path, floor_name), reading


def _check_morphology_fits(mask: np.ndarray, radius_px: int, what: str) -> None:
    """A kernel of ``radius_px`` and the image padded by it, refused before cv2 allocates them."""
    from mapfilter.runtime.memory import check_fits

    side = 2 * int(radius_px) + 1
    rows, cols = mask.shape[:2]
    check_fits(float(side) ** 2 + 3.0 * (rows + 2 * side) * (cols + 2 * side), f"{what} {radius_px} px",
               "wall gaps are a few pixels wide")


def _dilate(mask: np.ndarray, radius_px: int) -> np.ndarray:
    _check_morphology_fits(mask, radius_px, "dilating walls by")
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius_px + 1, 2 * radius_px + 1))
    return cv2.dilate(mask.astype(np.uint8), kernel).astype(bool)


def _erode(mask: np.ndarray, radius_px: int) -> np.ndarray:
    _check_morphology_fits(mask, radius_px, "eroding walls by")
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius_px + 1, 2 * radius_px + 1))
    # border value 1: the image edge does not eat into walls that touch it
    return cv2.erode(mask.astype(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=1).astype(bool)


def _remove_small_areas(mask: np.ndarray, below_px: int) -> np.ndarray:
    """Drop 8-connected components of fewer than ``below_px`` pixels."""
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    keep = stats[:, cv2.CC_STAT_AREA] >= below_px
    keep[0] = False
    return keep[labels]


def _fill_outside(wall: np.ndarray, path: Path | None = None, keep_free_option: str = "--outside none") -> np.ndarray:
    """Mark free space 4-connected to the image border as wall (outside the building).
    ``keep_free_option``: how the user's kind of plan keeps the outside free (for the message)."""
    count, labels = cv2.connectedComponents((~wall).astype(np.uint8), connectivity=4)
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    outside = np.isin(labels, border[border > 0])
    filled = wall | outside
    if filled.all() and not wall.all():
        raise MapfilterError(
            "all free space is connected to the image border, so it all counts as outside: the outer wall has "
            f"an opening (close it with --edits, or keep the outside free: {keep_free_option})", path)
    return filled


def _finish(
    wall_plan: np.ndarray,
    plan_resolution_m: float,
    map_resolution_m: float | None,
    plan_path: Path,
    floor_name: str | None,
) -> FloorPlan:
    """Resample the plan-pixel wall mask, check it, and wrap it with the plan as source image."""
    wall = wall_plan
    resolution_m = plan_resolution_m
    if map_resolution_m is not None:
        resolution_m = _positive(map_resolution_m, "map resolution", plan_path)
    problem = plan_geometry_problem(resolution_m, (0.0, 0.0), "map resolution" if map_resolution_m else "resolution")
    if problem:
        raise MapfilterError(problem, plan_path)
    if map_resolution_m is not None:
        ratio = plan_resolution_m / resolution_m
        rows_out, cols_out = round(wall_plan.shape[0] * ratio), round(wall_plan.shape[1] * ratio)
        if rows_out * cols_out > MAX_IMAGE_PIXELS:
            raise MapfilterError(f"map resolution {resolution_m:g} m gives a {cols_out}x{rows_out} mask, more than "
                                 f"{MAX_IMAGE_PIXELS / 1e6:.0f} M pixels: choose a coarser one", plan_path)
        wall = resample_wall_mask(wall_plan, plan_resolution_m, resolution_m)
    _check_mask(wall, plan_path)
    source = SourceImage(path=plan_path.resolve(), resolution_m=plan_resolution_m, origin_m=(0.0, 0.0))
    return FloorPlan(wall, resolution_m, (0.0, 0.0), floor_name, source)


def _check_mask(wall: np.ndarray, path: Path | None) -> None:
    if wall.all():
        raise MapfilterError("the plan has no free space (everything came out as wall)", path)
    if not wall.any():
        raise MapfilterError("no walls found in the plan (everything came out free)", path)


def resample_wall_mask(wall: np.ndarray, from_resolution_m: float, to_resolution_m: float) -> np.ndarray:
    """Resample a wall mask to another pixel size; both share the lower-left corner as origin.

    Going coarser, an output cell is wall if any input wall pixel overlaps it (walls never get
    holes; they may thicken by up to one output pixel). Going finer, nearest pixel.
    """
    rows_in, cols_in = wall.shape
    ratio = to_resolution_m / from_resolution_m  # input pixels per output pixel
    rows_out = max(1, int(round(rows_in / ratio)))
    cols_out = max(1, int(round(cols_in / ratio)))
    # output pixel (r, c) covers input columns [c*ratio, (c+1)*ratio) and, counted from the
    # bottom (shared lower-left origin), input rows [rows_in - (rows_out - r) * ratio, ...)
    col_lo = np.floor(np.arange(cols_out) * ratio + 1e-9).astype(np.int64)
    col_hi = np.ceil((np.arange(cols_out) + 1) * ratio - 1e-9).astype(np.int64)
    row_lo = np.floor(rows_in - (rows_out - np.arange(rows_out)) * ratio + 1e-9).astype(np.int64)
    row_hi = np.ceil(rows_in - (rows_out - np.arange(rows_out) - 1) * ratio - 1e-9).astype(np.int64)
    # summed-area table: any wall in a block <=> block sum > 0 (outside the plan is not wall)
    # int32 holds any count of a mask within floorplan.MAX_IMAGE_PIXELS, at half int64's memory
    count = np.int32 if wall.size < 2**31 else np.int64
    table = np.zeros((rows_in + 1, cols_in + 1), dtype=count)
    table[1:, 1:] = np.cumsum(np.cumsum(wall, axis=0, dtype=count), axis=1, dtype=count)
    r0 = np.clip(row_lo, 0, rows_in)[:, None]
    r1 = np.clip(row_hi, 0, rows_in)[:, None]
    c0 = np.clip(col_lo, 0, cols_in)[None, :]
    c1 = np.clip(col_hi, 0, cols_in)[None, :]
    total = table[r1, c1] - table[r0, c1] - table[r1, c0] + table[r0, c0]
    return total > 0


# ---- filled-region plans --------------------------------------------------------------------
TRANSPARENT = "transparent"


@dataclasses.dataclass(frozen=True)
class RegionOptions:
    """Options of :func:`prepare_regions` (pixel sizes are plan pixels).

    ``walkable`` holds colour specs: ``"transparent"`` (alpha <= ``alpha_max``), ``"#rrggbb"`` or
    ``"r,g,b"`` (opaque pixels within ``tolerance`` per channel). Everything else is wall, then:
    wall blobs smaller than ``remove_below_px`` pixels become free (text and marks inside
    corridors; None: blobs under ``REGION_BLOB_M2`` lying wholly in free space), free space
    connected to the image border is outside, so wall (``outside_is_wall``, as a floor plan
    needs), and walls are eroded by ``open_outlines_px`` where they meet free space (the
    outlines drawn around filled regions are walkable: ILC waypoints lie on them; None: the
    outlines' own width, measured; the outside is walled first, so opening the building's own
    outline never lets the outside in).
    """

    walkable: tuple[str, ...] = (TRANSPARENT,)
    tolerance: int = 24  # max per-channel difference to a walkable colour (0-255)
    alpha_max: int = 127  # pixels at most this opaque count as transparent
    remove_below_px: int | None = None  # wall blobs (8-connected) with fewer pixels become free (0 = off)
    open_outlines_px: int | None = None  # erode walls by this many pixels along free space (0 = off)
    outside_is_wall: bool = True  # free space connected to the image border is outside: wall

    def __post_init__(self) -> None:
        _check_pixel_counts(self, ("tolerance", "alpha_max"))  # an empty walkable is refused by prepare_regions
        for name in ("remove_below_px", "open_outlines_px"):
            if getattr(self, name) is not None:
                _check_pixel_counts(self, (name,))


def parse_colour(spec: str) -> tuple[int, int, int] | str:
    """``"transparent"``, ``"#rrggbb"`` or ``"r,g,b"`` -> ``"transparent"`` or an (r, g, b) tuple."""
    text = spec.strip().lower()
    if text == TRANSPARENT:
        return TRANSPARENT
    match = re.fullmatch(r"#?([0-9a-f]{6})", text)
    if match:
        value = match.group(1)
        return int(value[0:2], 16), int(value[2:4], 16), int(value[4:6], 16)
    parts = text.split(",")
    if len(parts) == 3 and all(p.strip().isdigit() and int(p) <= 255 for p in parts):
        return int(parts[0]), int(parts[1]), int(parts[2])
    raise MapfilterError(f"bad colour {spec!r}: use 'transparent', '#rrggbb' or 'r,g,b'")


def prepare_regions(
    plan_path: str | os.PathLike,
    scale: PlanScale,
    options: RegionOptions = RegionOptions(),
    map_resolution_m: float | None = None,
    floor_name: str | None = None,
) -> FloorPlan:
    """Wall mask of a filled-region plan: the ``options.walkable`` colours are free, the rest wall.

    Parameters are as for :func:`prepare_lines`; see :class:`RegionOptions` for the clean-up.
    """
    return read_regions(plan_path, scale, options, map_resolution_m, floor_name)[0]


def read_regions(plan_path: str | os.PathLike, scale: PlanScale, options: RegionOptions = RegionOptions(),
                 map_resolution_m: float | None = None, floor_name: str | None = None
                 ) -> tuple[FloorPlan, list[str], np.ndarray | None]:
    """:func:`prepare_regions`, what it did, one line each (outlines opened, blobs dropped), and
    the pixels it took for the outside (on the map's grid; None when the outside is kept)."""
    plan_path = Path(plan_path)
    bgra = read_plan_image(plan_path)
    resolution_m = scale.resolve(bgra.shape[:2], plan_path)
    colours = [parse_colour(c) for c in options.walkable]
    if not colours:
        raise MapfilterError("name at least one walkable colour")
    alpha = bgra[..., 3]
    opaque = alpha > options.alpha_max
    free = np.zeros(alpha.shape, dtype=bool)
    for colour in colours:
        if colour == TRANSPARENT:
            free |= ~opaque
        else:
            bgr = np.array(colour[::-1], dtype=np.int16)
            diff = np.abs(bgra[..., :3].astype(np.int16) - bgr).max(axis=2)
            free |= opaque & (diff <= options.tolerance)
    wall = ~free
    notes = []
    outside = None
    if options.remove_below_px is None:
        wall, dropped = _drop_region_blobs(wall, resolution_m)
        if dropped:
            notes.append(f"{dropped} small blob{'s' if dropped != 1 else ''} in free space dropped (text, marks)")
    elif options.remove_below_px > 0:
        wall = _remove_small_areas(wall, options.remove_below_px)
    if options.outside_is_wall:
        walled = _fill_outside(wall, plan_path, keep_free_option="--outside none")
        outside = walled & ~wall
        wall = walled
    outline_px = options.open_outlines_px
    if outline_px is None:
        outline_px = outline_width_px(bgra, ~free)
        if outline_px:
            notes.append(f"the filled regions' outlines ({outline_px} px) opened")
    if outline_px > 0:
        wall = _erode(wall, outline_px)
    plan = _finish(wall, resolution_m, map_resolution_m, plan_path, floor_name)
    return plan, notes, _on_grid(outside, plan)


def _on_grid(mask: np.ndarray | None, plan: FloorPlan) -> np.ndarray | None:
    """A plan-pixel mask on the map's own grid (nearest pixel; the same when the grids are one)."""
    if mask is None or mask.shape == plan.shape_px:
        return mask
    rows, cols = plan.shape_px
    return cv2.resize(mask.astype(np.uint8), (cols, rows), interpolation=cv2.INTER_NEAREST).astype(bool)


OUTLINE_RING_SHARE = 0.11
REGION_BLOB_M2 = 0.5  # a wall blob in free space smaller than this is text or a mark, not a pillar


def _drop_region_blobs(wall: np.ndarray, resolution_m: float) -> tuple[np.ndarray, int]:
    """Wall blobs (8-connected) under ``REGION_BLOB_M2`` that touch no other wall: free."""
    count, labels, stats, _ = cv2.connectedComponentsWithStats(wall.astype(np.uint8), connectivity=8)
    small = stats[:, cv2.CC_STAT_AREA] * resolution_m ** 2 < REGION_BLOB_M2
    small[0] = False
    return wall & ~small[labels], int(small.sum())


def outline_width_px(bgra: np.ndarray, wall: np.ndarray) -> int:
    """The width of the outlines drawn round a filled-region plan's filled regions, in pixels (0:
    none): the wall pixels along free space whose colour is not the fill's, measured inward.

    A region's fill is the mean colour of its wall pixels at least four pixels from free space
    (within 15 pixels); the outline pixels are wall pixels within six pixels of free space that
    differ by more than 40 levels in some channel from it and from the plan's commonest fill; the width is the number of rings (pixels from
    free space), one after another from the edge, that hold at least ``OUTLINE_RING_SHARE`` as
    many outline pixels as the first (the ILC floors: 2 px)."""
    distance = cv2.distanceTransform(wall.astype(np.uint8), cv2.DIST_L2, 3)
    deep = (wall & (distance >= 4)).astype(np.float32)
    if deep.sum() < 100:
        return 0
    # each region's own fill: the mean colour of the deep pixels around (within 15 pixels)
    window = (31, 31)
    weight = cv2.boxFilter(deep, -1, window, normalize=False)
    colour = bgra[..., :3].astype(np.float32)
    fill = cv2.boxFilter(colour * deep[..., None], -1, window, normalize=False) / np.maximum(weight, 1.0)[..., None]
    edge = wall & (distance <= 6) & (weight > 0)
    deep_colours = (bgra[..., :3][deep > 0] // 8).astype(np.int32)
    key = int(np.bincount(deep_colours[:, 0] * 1024 + deep_colours[:, 1] * 32 + deep_colours[:, 2]).argmax())
    commonest = np.array([key // 1024, (key // 32) % 32, key % 32], dtype=np.float32) * 8 + 4
    differs = (np.abs(colour - fill).max(axis=2) > 40) & (np.abs(colour - commonest).max(axis=2) > 40)
    outline = edge & differs & (bgra[..., 3] > 127)
    if outline.sum() < 0.2 * (edge & (distance <= 1)).sum():
        return 0
    counts = np.bincount(np.round(distance[outline]).astype(np.int64), minlength=8)[1:7]
    # the outline reaches as deep as the rings that, one after another from the edge, still hold
    # a ninth of the first ring's pixels (text across a region's edge adds a flat tail)
    held = counts >= OUTLINE_RING_SHARE * counts[0]
    return int(np.argmin(held)) if not held.all() else len(held)


# ---- the kind of plan, told from the image ----------------------------------------------------
FILLED_M = 0.75  # a region this far from its own edge (1.5 m across) is a filled room or shop, never a wall
FILLED_SHARE = 0.3  # a plan whose marked area is this much filled regions is a filled-region plan
DETECT_SIDE_PX = 800


@dataclasses.dataclass(frozen=True)
class KindChoice:
    """The kind of plan :func:`detect_kind` chose, the walkable colour for a filled-region plan,
    and why (one line)."""

    kind: str  # "lines" or "regions"
    walkable: str  # "transparent" or "#rrggbb"
    reason: str


def detect_kind(bgra: np.ndarray, resolution_m: float) -> KindChoice:
    """Drawing or filled-region plan, from the image.

    What a plan marks on its background (the opaque pixels of a plan with a transparent
    background; elsewhere the pixels that differ from the paper, channel by channel, after the
    paper is evened) is, in a drawing, lines and walls, none more than ``MAX_WALL_M`` across; in a
    filled-region plan mostly filled rooms or shops metres across. The share of the marked area
    lying deeper than ``FILLED_M`` inside it decides."""
    # the kind is a coarse property: told on a copy of at most DETECT_SIDE_PX a side
    factor = max(1, int(math.ceil(max(bgra.shape[:2]) / DETECT_SIDE_PX)))
    if factor > 1:
        bgra = cv2.resize(bgra, (bgra.shape[1] // factor, bgra.shape[0] // factor), interpolation=cv2.INTER_AREA)
        resolution_m *= factor
    alpha = bgra[..., 3]
    transparent = alpha <= 127
    if transparent.mean() >= 0.05:
        marked, walkable, background = ~transparent, TRANSPARENT, "transparent"
    else:
        bgr = bgra[..., :3]
        gray = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
        dark = even_paper(gray, resolution_m) < 200  # ink, on paper evened however it is lit
        light = bgr[gray >= np.percentile(gray, 90)]  # the paper is the lightest thing on the sheet
        paper_bgr = np.median(light, axis=0) if light.size else np.array([255.0, 255.0, 255.0])
        # colour against the paper's own (a yellowed or tinted sheet is no colour)
        balanced = bgr.astype(np.float32) * (255.0 / np.maximum(paper_bgr, 1.0))
        coloured = (balanced.max(axis=2) - balanced.min(axis=2)) > 25
        marked = dark | coloured
        b, g, r = (int(round(v)) for v in paper_bgr)
        walkable, background = f"#{r:02x}{g:02x}{b:02x}", f"the paper ({f'#{r:02x}{g:02x}{b:02x}'})"
    if not marked.any():
        return KindChoice("lines", walkable, "the image is blank: read as a drawing")
    depth = cv2.distanceTransform(marked.astype(np.uint8), cv2.DIST_L2, 3) * resolution_m
    share = float((depth >= FILLED_M).sum()) / float(marked.sum())
    if share >= FILLED_SHARE:
        return KindChoice("regions", walkable, f"filled regions ({share:.0%} of what is marked lies over "
                                               f"{FILLED_M:g} m inside a filled area); walkable: {background}")
    return KindChoice("lines", walkable, f"a drawing (lines and walls: {share:.0%} of the ink lies over "
                                         f"{FILLED_M:g} m inside a filled area)")


@dataclasses.dataclass
class PreparedPlan:
    """A plan read by :func:`prepare_plan`: the map, its kind, what the reader did (one line each)
    and the pixels it took for the outside of the building (on the map's grid; None: kept free)."""

    plan: FloorPlan
    kind: str
    notes: list[str]
    outside: np.ndarray | None = None


def prepare_plan(plan_path: str | os.PathLike, scale: PlanScale, kind: str | None = None,
                 drawing: DrawingOptions = DrawingOptions(), regions: RegionOptions = RegionOptions(walkable=()),
                 map_resolution_m: float | None = None, floor_name: str | None = None) -> PreparedPlan:
    """A drawing or a filled-region plan, its kind chosen from the image unless given (``kind``:
    "lines" or "regions"). ``regions.walkable`` empty: transparent, or, when the kind was chosen
    from the image, the paper of an opaque plan."""
    plan_path = Path(plan_path)
    notes = []
    if kind is None:
        bgra = read_plan_image(plan_path)
        if bgra[..., 3].min() > 127:
            gray = cv2.cvtColor(bgra[..., :3], cv2.COLOR_BGR2GRAY)
            if int(gray.max()) - int(gray.min()) < 16:  # one flat tone: all paper or all ink
                if gray.mean() < 128:
                    raise MapfilterError("the plan has no free space (it is dark all over)", plan_path)
                raise MapfilterError("no walls found in the plan (it is blank)", plan_path)
        choice = detect_kind(bgra, scale.resolve(bgra.shape[:2], plan_path))
        kind = choice.kind
        notes.append(f"kind: {choice.kind}, chosen from the image: {choice.reason}")
        if not regions.walkable:
            regions = dataclasses.replace(regions, walkable=(choice.walkable,))
    if not regions.walkable:
        regions = dataclasses.replace(regions, walkable=(TRANSPARENT,))
    if kind == "lines":
        plan, reading = read_lines(plan_path, scale, drawing, map_resolution_m, floor_name)
        notes.append(f"ink darker than grey {reading.threshold:.0f} of the evened paper; "
                     + (f"strokes up to {reading.thin_width_px:.1f} px taken for annotation; "
                        if reading.thin_width_px else "every stroke taken for a wall; ")
                     + f"{len(reading.doors)} door symbol{'s' if len(reading.doors) != 1 else ''} found, "
                     f"{reading.text_blobs} small blob{'s' if reading.text_blobs != 1 else ''} dropped (text, marks)")
        outside = None if reading.inside is None else _on_grid(~reading.inside, plan)
        return PreparedPlan(plan, kind, notes, outside)
    if kind == "regions":
        plan, region_notes, outside = read_regions(plan_path, scale, regions, map_resolution_m, floor_name)
        return PreparedPlan(plan, kind, notes + region_notes, outside)
    raise MapfilterError(f"unknown kind of plan {kind!r} (lines or regions)")


# ---- GeoJSON floors -------------------------------------------------------------------------
DEFAULT_GEOJSON_RESOLUTION_M = 0.1  # a door (about 0.8 m) is eight cells wide
@dataclasses.dataclass
class VectorFloor:
    """A vector floor in metres: outline (walkable area) and obstacles (shops), both shapely."""

    outline: shapely.Geometry
    obstacles: list[shapely.Geometry]
    origin_lonlat: tuple[float, float] | None  # lon/lat of the metre frame's origin, if projected


def read_geojson_floor(path: str | os.PathLike, units: str = "lonlat") -> VectorFloor:
    """Read a floor GeoJSON: the feature typed ``floor`` (else the first) is the outline.

    ``units="lonlat"`` projects with Web Mercator scaled by cos(mean outline latitude) and puts
    the origin at the lower-left of the outline's bounding box (the ILC convention; its README
    checks this against floor_info.json to 0.01 m). ``units="m"`` takes coordinates as metres.
    """
    path = Path(path)
    if not path.is_file():
        raise not_a_file(path)
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        line = getattr(exc, "lineno", None)
        raise MapfilterError(f"not valid GeoJSON: {getattr(exc, 'msg', exc)}", path, line) from None
    features = data.get("features") if isinstance(data, dict) else None
    if not isinstance(features, list) or not features:
        raise MapfilterError("GeoJSON has no 'features' list", path)
    geometries = []
    for index, feature in enumerate(features):
        try:
            geometry = geojson_shape(feature["geometry"])
        except Exception as exc:  # shapely raises several types for bad geometry
            raise MapfilterError(f"feature {index} has no valid geometry ({exc})", path) from None
        if geometry.geom_type not in ("Polygon", "MultiPolygon"):
            continue
        geometries.append((feature.get("properties") or {}, shapely.make_valid(geometry)))
    if not geometries:
        raise MapfilterError("GeoJSON has no polygons", path)
    floor_index = next((i for i, (props, _) in enumerate(geometries) if props.get("type") == "floor"), 0)
    outline = geometries[floor_index][1]
    obstacles = [g for i, (_, g) in enumerate(geometries) if i != floor_index]
    if units == "m":
        return VectorFloor(outline, obstacles, None)
    if units != "lonlat":
        raise MapfilterError(f"unknown GeoJSON units {units!r} (lonlat or m)")
    coords = shapely.get_coordinates(outline)
    if np.abs(coords[:, 0]).max() > 180 or np.abs(coords[:, 1]).max() > 85:
        raise MapfilterError("coordinates are not longitude/latitude degrees (use units 'm')", path)
    lat_mean_rad = math.radians(float(coords[:, 1].mean()))
    k = math.cos(lat_mean_rad)

    def mercator(xy: np.ndarray) -> np.ndarray:
        lon = np.radians(xy[:, 0])
        lat = np.radians(xy[:, 1])
        return np.stack([EARTH_RADIUS_M * lon * k, EARTH_RADIUS_M * np.log(np.tan(np.pi / 4 + lat / 2)) * k], axis=1)

    projected = mercator(coords)
    x0, y0 = projected.min(axis=0)
    lon0, lat0 = coords[:, 0].min(), coords[:, 1].min()

    def to_metres(geometry: shapely.Geometry) -> shapely.Geometry:
        return shapely.transform(geometry, lambda xy: mercator(xy) - [x0, y0])

    return VectorFloor(to_metres(outline), [to_metres(g) for g in obstacles], (float(lon0), float(lat0)))


def prepare_geojson(
    path: str | os.PathLike,
    resolution_m: float | None,
    units: str = "lonlat",
    obstacle_inset_m: float = 0.0,
    margin_m: float = 0.0,
    floor_name: str | None = None,
    source_image: SourceImage | None = None,
) -> FloorPlan:
    """Rasterise a GeoJSON floor: a pixel is free if its centre is inside the outline and not
    inside an obstacle. Outside the outline is wall.

    Parameters
    ----------
    path : the GeoJSON file (see :func:`read_geojson_floor`).
    resolution_m : metres per output pixel (None: ``DEFAULT_GEOJSON_RESOLUTION_M``).
    units : "lonlat" (project, ILC convention) or "m".
    obstacle_inset_m : shrink every obstacle by this much first, so that a walker brushing a
        shop front (ILC waypoints lie on shop outlines) stays on free space.
    margin_m : wall margin added around the outline's bounding box.
    floor_name, source_image : passed to the FloorPlan.
    """
    path = Path(path)
    resolution_m = _positive(DEFAULT_GEOJSON_RESOLUTION_M if resolution_m is None else resolution_m, "resolution",
                             path)
    floor = read_geojson_floor(path, units)
    x_min, y_min, x_max, y_max = floor.outline.bounds
    x_min, y_min, x_max, y_max = x_min - margin_m, y_min - margin_m, x_max + margin_m, y_max + margin_m
    cols = int(math.ceil((x_max - x_min) / resolution_m - 1e-9))
    rows = int(math.ceil((y_max - y_min) / resolution_m - 1e-9))
    if rows * cols > 50_000_000:
        raise MapfilterError(f"resolution {resolution_m} m gives a {cols}x{rows} map: too large", path)
    obstacles = shapely.union_all(floor.obstacles) if floor.obstacles else shapely.Polygon()
    if obstacle_inset_m > 0:
        obstacles = obstacles.buffer(-obstacle_inset_m)
    walkable = floor.outline.difference(obstacles)
    # pixel centres; row 0 is the top of the map
    x_c = x_min + (np.arange(cols) + 0.5) * resolution_m
    y_c = y_min + (rows - np.arange(rows) - 0.5) * resolution_m
    xx, yy = np.meshgrid(x_c, y_c)
    shapely.prepare(walkable)
    free = shapely.contains_xy(walkable, xx.ravel(), yy.ravel()).reshape(rows, cols)
    wall = ~free
    _check_mask(wall, path)
    return FloorPlan(wall, resolution_m, (x_min, y_min), floor_name, source_image)


# ---- edits ----------------------------------------------------------------------------------
@dataclasses.dataclass
class MapEdits:
    """Polygons in world metres forced free (doors) or wall (closed-off areas); wall wins."""

    free: list[shapely.Geometry]
    wall: list[shapely.Geometry]


def read_edits(path: str | os.PathLike) -> MapEdits:
    """Read edits from YAML ``{free: [[[x, y], ...], ...], wall: [...]}`` or GeoJSON in metres
    whose features carry ``properties: {"set": "free" | "wall"}``."""
    path = Path(path)
    if not path.is_file():
        raise not_a_file(path)
    data = load_yaml(path, "an edits file", max_bytes=64 << 20)  # YAML is a superset of JSON: reads both
    edits = MapEdits([], [])
    if isinstance(data, dict) and data.get("type") == "FeatureCollection":
        for index, feature in enumerate(data.get("features") or []):
            kind = ((feature or {}).get("properties") or {}).get("set")
            if kind not in ("free", "wall"):
                raise MapfilterError(f"feature {index}: properties.set must be 'free' or 'wall'", path)
            try:
                geometry = shapely.make_valid(geojson_shape(feature["geometry"]))
            except Exception as exc:
                raise MapfilterError(f"feature {index} has no valid geometry ({exc})", path) from None
            getattr(edits, kind).append(geometry)
        return edits
    if not isinstance(data, dict) or not set(data) <= {"free", "wall"}:
        raise MapfilterError("edits must be a mapping with keys 'free' and/or 'wall' (or GeoJSON)", path)
    for kind in ("free", "wall"):
        for index, ring in enumerate(data.get(kind) or []):
            try:
                points = np.asarray(ring, dtype=np.float64)
                if points.ndim != 2 or points.shape[1] != 2 or len(points) < 3 or not np.isfinite(points).all():
                    raise ValueError
            except (TypeError, ValueError):
                raise MapfilterError(f"{kind}[{index}] must be a list of at least three [x, y] points", path) from None
            getattr(edits, kind).append(shapely.make_valid(shapely.Polygon(points)))
    return edits


def apply_edits(plan: FloorPlan, edits: MapEdits) -> FloorPlan:
    """A new FloorPlan with every pixel touched by a ``free`` polygon free, then every pixel
    touched by a ``wall`` polygon wall (so a door narrower than a pixel still opens)."""
    wall = plan.wall_mask.copy()
    for kind, value in (("free", False), ("wall", True)):
        touched = np.zeros(wall.shape, dtype=np.uint8)
        for geometry in getattr(edits, kind):
            for polygon in getattr(geometry, "geoms", [geometry]):
                if polygon.geom_type != "Polygon" or polygon.is_empty:
                    continue
                rings = [polygon.exterior, *polygon.interiors]
                # 4 fractional bits: pixel coordinates with sub-pixel accuracy
                pts = [np.round(plan.world_to_pixel(np.asarray(r.coords)[:, :2]) * 16 - 8).astype(np.int32) for r in rings]
                cv2.fillPoly(touched, pts, 1, lineType=cv2.LINE_8, shift=4)
                cv2.polylines(touched, pts, True, 1, lineType=cv2.LINE_8, shift=4)
        wall[touched.astype(bool)] = value
    _check_mask(wall, None)
    return dataclasses.replace(plan, wall_mask=wall)


# ---- checks of a finished mask ---------------------------------------------------------------
# A plan can turn into a useless mask without an error; these say so (one line each).
# The wall edge (wall pixels beside free ones) against the edge of a square of the same free
# area: a nearly empty plan (IPIN 2023 floor -1) is one open area walled round its edge, 1.00;
# an empty 2:1 rectangle 1.08; two rooms and a door 1.23; the office 5.3; ILC floors 5.6-14.5.
MIN_WALL_EDGE_RATIO = 1.1
MIN_WALL_FRACTION = 0.005  # fewer wall pixels than this: the plan drew (almost) nothing
MIN_FREE_FRACTION = 0.01  # less free space than this is a plan the outside fill (or the ink) took
SMALL_BLOB_M2 = 1.0  # a wall blob inside free space smaller than this is text, a mark or a pillar


def mask_warnings(plan: FloorPlan, outside_hint: str | None = "", blob_hint: str | None = "") -> list[str]:
    """What looks wrong with a finished mask, one line each (empty when nothing does): almost no
    free space; almost no walls (the free space one open area); free space reaching the map's
    edge (the outside walkable: ``outside_hint`` says why or how to wall it; None: not checked,
    the kind of plan walls the outside, as a GeoJSON outline does); small wall blobs inside free
    space (text in corridors: ``blob_hint`` says how to remove them; None: not checked, a vector
    floor's small polygons are obstacles drawn on purpose)."""
    wall = plan.wall_mask
    free = ~wall
    found = []
    if free.mean() < MIN_FREE_FRACTION:
        found.append(f"almost no free space ({free.mean():.1%} of the map): a nearly empty plan, or an outer wall "
                     "with an opening, lets the outside fill take everything (look at the preview)")
        return found
    edge = np.zeros_like(wall)  # wall pixels with a free 4-neighbour
    edge[1:] |= wall[1:] & free[:-1]
    edge[:-1] |= wall[:-1] & free[1:]
    edge[:, 1:] |= wall[:, 1:] & free[:, :-1]
    edge[:, :-1] |= wall[:, :-1] & free[:, 1:]
    ratio = edge.sum() / (4.0 * math.sqrt(free.sum()))
    if ratio < MIN_WALL_EDGE_RATIO or wall.mean() < MIN_WALL_FRACTION:
        found.append(f"almost no walls: the free space ({free.mean():.0%} of the map) is one open area; is the plan "
                     "nearly empty, or its lines too faint? (look at the preview)")
    border = np.concatenate([free[0], free[-1], free[1:-1, 0], free[1:-1, -1]])
    if outside_hint is not None and border.any():
        found.append(f"free space reaches the edge of the map ({border.sum() * plan.resolution_m:.0f} m of its border): "
                     "the outside of the building is walkable" + (f" ({outside_hint})" if outside_hint else ""))
    if blob_hint is None:
        return found
    count, _, stats, _ = cv2.connectedComponentsWithStats(wall.astype(np.uint8), connectivity=8)
    x, y, w, h, area = (stats[1:, i] for i in range(5))
    inside = (x > 0) & (y > 0) & (x + w < wall.shape[1]) & (y + h < wall.shape[0])
    small = inside & (area * plan.resolution_m ** 2 < SMALL_BLOB_M2)
    if small.any():
        n = int(small.sum())
        found.append(f"{n} small wall blob{'s' if n != 1 else ''} inside free space (under {SMALL_BLOB_M2:g} m2 each: "
                     "text, marks or pillars? look at the preview)" + (f"; {blob_hint}" if blob_hint else ""))
    return found


# ---- output ---------------------------------------------------------------------------------
def preview_image(plan: FloorPlan, max_side_px: int = 2000, outside: np.ndarray | None = None,
                  cut_off: np.ndarray | None = None) -> np.ndarray:
    """BGR picture of the mask (walls in red, half transparent) over the source plan; the pixels
    taken for the outside of the building (``outside``, on the mask's grid) shaded grey, the
    rooms cut off from the largest free region (``cut_off``) in orange, each boxed.

    Drawn at the finer of the plan's and the mask's pixel sizes (at most ``max_side_px``).
    """
    x_min, x_max, y_min, y_max = plan.extent_m
    source = None
    res = plan.resolution_m
    if plan.source_image is not None and plan.source_image.path.is_file():
        source = read_plan_image(plan.source_image.path)
        res = min(res, plan.source_image.resolution_m)
    res = max(res, max(x_max - x_min, y_max - y_min) / max_side_px)
    cols = int(math.ceil((x_max - x_min) / res - 1e-9))  # (a rounding error adds no column)
    rows = int(math.ceil((y_max - y_min) / res - 1e-9))
    if (source is not None and (rows, cols) == plan.shape_px == source.shape[:2] and res == plan.resolution_m
            and plan.source_image.resolution_m == res and tuple(plan.source_image.origin_m) == tuple(plan.origin_m)):
        # the plan's own grid: no resampling
        return _tint_walls(_flatten_on_white(source), plan.wall_mask, outside, cut_off)
    # world coordinates of the preview's pixel centres
    x_c = x_min + (np.arange(cols) + 0.5) * res
    y_c = y_max - (np.arange(rows) + 0.5) * res
    xx, yy = np.meshgrid(x_c, y_c)
    canvas = np.full((rows, cols, 3), 255, dtype=np.uint8)
    if source is not None:
        src = plan.source_image
        picture = _flatten_on_white(source)
        h_src = picture.shape[0]
        u = (xx - src.origin_m[0]) / src.resolution_m
        v = h_src - (yy - src.origin_m[1]) / src.resolution_m
        canvas = cv2.remap(picture, u.astype(np.float32), v.astype(np.float32), cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_CONSTANT, borderValue=(255, 255, 255))
    # the mask's cell under each preview pixel (pixel centres; outside the mask counts as wall)
    mask_rows = np.floor((plan.extent_m[3] - y_c) / plan.resolution_m).astype(np.int64)
    mask_cols = np.floor((x_c - plan.extent_m[0]) / plan.resolution_m).astype(np.int64)
    inside = ((mask_rows >= 0) & (mask_rows < plan.shape_px[0]))[:, None] & \
        ((mask_cols >= 0) & (mask_cols < plan.shape_px[1]))[None, :]
    wall = np.ones((rows, cols), dtype=bool)
    rr = np.clip(mask_rows, 0, plan.shape_px[0] - 1)
    cc = np.clip(mask_cols, 0, plan.shape_px[1] - 1)
    wall[inside] = plan.wall_mask[np.ix_(rr, cc)][inside]
    marks = [None if m is None else m[np.ix_(rr, cc)] & inside for m in (outside, cut_off)]
    return _tint_walls(canvas, wall, *marks)


def _tint_walls(canvas: np.ndarray, wall: np.ndarray, outside: np.ndarray | None = None,
                cut_off: np.ndarray | None = None) -> np.ndarray:
    """``canvas`` with the wall pixels half red, the outside's darker grey over that, and the
    cut-off rooms half orange, each in an orange box."""
    tinted = canvas.copy()
    for mask, colour, weight in ((wall, (40, 40, 230), 0.5), (outside, (90, 90, 90), 0.45),
                                 (cut_off, (0, 140, 255), 0.5)):  # BGR
        if mask is not None and mask.any():
            # each channel's 256 blends, looked up (faster than blending every masked pixel)
            blend = np.arange(256, dtype=np.float32)[:, None] * (1 - weight) + np.array(colour, np.float32) * weight
            table = np.round(blend).astype(np.uint8)
            tinted = cv2.copyTo(cv2.LUT(tinted, table[None]), np.ascontiguousarray(mask).view(np.uint8), tinted)
    if cut_off is not None and cut_off.any():
        count, _, stats, _ = cv2.connectedComponentsWithStats(cut_off.astype(np.uint8), connectivity=4)
        for x, y, w, h, _ in stats[1:]:
            cv2.rectangle(tinted, (int(x) - 2, int(y) - 2), (int(x + w) + 1, int(y + h) + 1), (0, 140, 255), 2)
    return tinted


def preview_path_for(yaml_path: str | os.PathLike) -> Path:
    """Where :func:`write_map` puts the preview: ``NAME_preview.png`` beside ``NAME.yaml``."""
    yaml_path = Path(yaml_path)
    return yaml_path.with_name(yaml_path.stem + "_preview.png")


def write_map(plan: FloorPlan, yaml_path: str | os.PathLike, preview: bool = True,
              outside: np.ndarray | None = None, cut_off: np.ndarray | None = None) -> list[Path]:
    """Write ``NAME.yaml`` + ``NAME.png`` (mask) and ``NAME_preview.png`` (with ``outside`` and
    ``cut_off`` marked: :func:`preview_image`); all or nothing.

    Returns the written paths.
    """
    yaml_path = Path(yaml_path)
    if yaml_path.suffix not in (".yaml", ".yml"):
        raise MapfilterError("the output map must be a .yaml file", yaml_path)
    written = [yaml_path, yaml_path.with_name(yaml_path.stem + ".png")]
    if plan.source_image is not None:
        source = Path(plan.source_image.path).resolve()
        for path in [*written, preview_path_for(yaml_path)]:
            if path.resolve() == source:
                raise MapfilterError(f"writing the map would overwrite the plan {source.name}: "
                                     "choose another --out name", yaml_path)
    if not preview:
        plan.save(yaml_path)
        return written
    picture = preview_image(plan, outside=outside, cut_off=cut_off)  # computed before anything is written
    preview_path = preview_path_for(yaml_path)
    with atomic_paths(preview_path) as (tmp_preview,):
        if not cv2.imwrite(str(tmp_preview), picture):
            raise MapfilterError("could not write the preview image", preview_path)
        plan.save(yaml_path)  # atomic itself; if it fails the preview is not kept either
    return [*written, preview_path]


# ---- ILC in one step ------------------------------------------------------------------------
# The ILC floor images: transparent corridors, light-blue shops with ~2 px darker outlines that
# the walkers brush along, grey shop names, a few marks in the corridors. Eroding the walls by
# 2 px along free space opens the outlines and also removes 1-2 px text strokes and marks in
# the corridors, leaving every waypoint on free space in one piece (docs/accuracy.md).
# The transparent outside reaches the corridors through the entrances, so no flood from the
# image's border can tell it from them: the floor's outline (geojson_map.json) walls it instead,
# as on the GeoJSON route and as `map prepare` walls a plan's outside.
ILC_REGION_OPTIONS = RegionOptions(walkable=(TRANSPARENT,), alpha_max=127, remove_below_px=0, open_outlines_px=2,
                                   outside_is_wall=False)
# the outline grown by this much first: the image and the GeoJSON outline differ by up to about a
# metre, and corridor ends on the outline were cut off from the rest (F1: 34 of 544 waypoints)
ILC_OUTLINE_MARGIN_M = 1.0
# GeoJSON shop polygons are the outlines themselves: shrink them by 0.6 m (about two image
# pixels) so that waypoints on a shop front stay free.
ILC_OBSTACLE_INSET_M = 0.6
ILC_GEOJSON_RESOLUTION_M = 0.25
MAX_FLOOR_SIZE_M = 10_000.0  # width and height of an ILC floor_info.json: far beyond any building


def read_ilc_floor_info(floor_dir: str | os.PathLike) -> tuple[float, float]:
    """(width, height) in metres from an ILC ``floor_info.json``."""
    path = Path(floor_dir) / "floor_info.json"
    if not path.is_file():
        raise not_a_file(path)
    try:
        info = load_yaml(path, "floor_info.json")["map_info"]  # YAML reads JSON, within its limits
        size_m = _positive(info["width"], "width", path), _positive(info["height"], "height", path)
    except (KeyError, TypeError):
        raise MapfilterError("expected {\"map_info\": {\"width\": .., \"height\": ..}}", path) from None
    if max(size_m) > MAX_FLOOR_SIZE_M:
        raise MapfilterError(f"a floor of {size_m[0]:g} x {size_m[1]:g} m: no floor is wider than "
                             f"{MAX_FLOOR_SIZE_M:g} m (a unit other than metres?)", path)
    return size_m


def import_ilc(floor_dir: str | os.PathLike, route: str = "image", resolution_m: float | None = None) -> FloorPlan:
    """FloorPlan of an ILC floor directory (floor_image.png, floor_info.json, geojson_map.json).

    ``route="image"``: the floor image, transparent = walkable, scaled by floor_info.json
    (``resolution_m`` resamples the mask), outside the outline of geojson_map.json (when the
    folder has one; grown by ``ILC_OUTLINE_MARGIN_M``) = wall. ``route="geojson"``: the vector floor rasterised at ``resolution_m``
    (default 0.25 m), outside the outline = wall. Both share the ILC metre frame (origin at the
    floor's lower-left corner) and show floor_image.png underneath.
    """
    floor_dir = Path(floor_dir)
    if not floor_dir.is_dir():
        raise MapfilterError("not an ILC floor directory", floor_dir)
    width_m, height_m = read_ilc_floor_info(floor_dir)
    image_path = floor_dir / "floor_image.png"
    floor_name = floor_dir.name
    if route == "image":
        plan = prepare_regions(image_path, PlanScale(size_m=(width_m, height_m)), ILC_REGION_OPTIONS,
                               resolution_m, floor_name)
        if (floor_dir / "geojson_map.json").is_file():
            outline = read_geojson_floor(floor_dir / "geojson_map.json").outline.buffer(ILC_OUTLINE_MARGIN_M)
            rows, cols = np.indices(plan.shape_px)
            centres = plan.pixel_to_world(np.stack([cols + 0.5, rows + 0.5], axis=-1)).reshape(-1, 2)
            shapely.prepare(outline)
            outside = ~shapely.contains_xy(outline, centres[:, 0], centres[:, 1]).reshape(plan.shape_px)
            plan = dataclasses.replace(plan, wall_mask=plan.wall_mask | outside)
        return plan
    if route == "geojson":
        source = None
        if image_path.is_file():
            rows, cols = read_plan_image(image_path).shape[:2]
            source = SourceImage(image_path.resolve(), 0.5 * (width_m / cols + height_m / rows), (0.0, 0.0))
        return prepare_geojson(floor_dir / "geojson_map.json", resolution_m or ILC_GEOJSON_RESOLUTION_M, "lonlat",
                               ILC_OBSTACLE_INSET_M, 0.0, floor_name, source)
    raise MapfilterError(f"unknown route {route!r} (image or geojson)")
