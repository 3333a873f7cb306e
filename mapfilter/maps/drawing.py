"""Reading a floor-plan drawing: which ink is wall, where the building is, what is walkable.

A drawing (a scan, a CAD export, a real-estate plan) draws walls as the heaviest ink: solid or
grey fills, or two heavier lines with the wall between them (empty or hatched). Everything else
is drawn thinner or smaller: door leaves and swing arcs, windows, furniture and fixtures, text,
dimension, axis and hatch lines, the sheet's frame and title block. :func:`read_drawing` turns
a grey image and its pixel size into a wall mask in these steps:

1. the paper is made even: the image is divided by its background (a closing far wider than any
   wall, on a reduced copy), so grey, yellowed or unevenly lit paper becomes white;
2. ink is what is darker than a threshold (Otsu's on the evened image, or a number);
3. strokes are split by width: the widths of the ink's ridges (twice the distance to paper)
   fall into the thin lines of annotation and the heavier walls; the thin are not walls, nor
   (at a low resolution, where a thin line is as wide as a wall's) a stroke mostly of light ink;
4. wall cavities are filled: a narrow, elongated gap enclosed by heavy ink is the inside of a
   double-line or hatched wall, or a window in a wall;
5. door symbols are found among the thin strokes (a quarter circle round a hinge beside a wall,
   its leaf a radius of it); a leaf drawn heavy enough to pass for a wall is removed;
6. the building is found on a copy of the walls with door-wide gaps closed (so an open
   entrance, whose symbol was thin, never lets the outside in), and with the thin strokes that
   touch the walls (so windows drawn thin, a run of them or a bay's glazing, close the outline;
   what they alone enclose is the building's only where it is bounded mostly by walls, not a
   terrace behind its rails); outside it is wall, and so are the windows; a sheet's frame (a
   ring of ink round everything near the image border) is no building;
7. small wall blobs inside the building that are not solid columns are text: removed;
8. the learned segmenter (:mod:`mapfilter.maps.segmenter`, trained on generated plans) reads the
   walls too; a wall of the strokes is kept where the network has one within 3 px.

Pixel sizes come from the plan's scale, so the rules are in metres where a rule is about
buildings (wall thickness, door width) and in pixels where it is about the drawing (line
weights).
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.maps.doors import DoorSymbol, erase_leaves, find_door_symbols

# what a building's walls and doors measure (metres); the rules below hold for any drawing
MIN_WALL_M = 0.075  # the thinnest partition a plan draws
MAX_LINE_M = 0.04  # the widest annotation line (a 0.2 mm pen at 1:200)
MIN_RUN_M = 0.3  # a wall end that bounds a gap runs at least this far
MIN_BAND_RUN_M = 0.8  # a wall's line runs straight at least this far (a door arc does not)
MAX_BAND_M = 0.5  # a wall's two lines are at most this far apart (a kitchen counter is 0.6 m deep)
SPECK_M = 0.1  # a blob of wall this small on a thin line is a speck the line left
LEAF_HALF_M = 0.04  # half a door leaf's drawn width (a leaf drawn as a box is about 4 cm thick)
MAX_WALL_M = 0.6
HATCH_M = 0.1  # enclosed gaps narrower than this, side by side, are between hatch lines
HATCH_CELLS = 8  # hatching has at least this many cells together (a word has a few letter eyes)
HEAVY_RATIO = 1.3  # ink this many times a thin line's (width times darkness) is drawn heavy
WALL_OUTLINE_SHARE = 0.7  # a wall's inside is drawn round in heavy lines along this share at least  # thicker than any wall: a gap this wide between wall lines is a room or a corridor
PAPER_KERNEL_M = 1.2  # the background closing spans this: wider than any wall or column
TEXT_BLOB_M = 1.0  # a wall blob shorter than this, not a solid column, is a label
TEXT_LINE_M = 0.6  # a line of letters is no taller than this
COLUMN_MIN_M = 0.2  # a column is at least this wide each way (and COLUMN_MIN_PX)
COLUMN_MIN_PX = 6  # smaller than this a column cannot be told from a letter
FRAME_BAND = 0.02  # a sheet frame's lines lie within this share of its box's size from the box's edges ...
FRAME_ALONG_EDGES = 0.5  # ... with at least this share of its ink
WORK_M = 0.03  # the outline is found at about this many metres per pixel
STROKE_REACH_M = 0.5  # thin strokes close the outline this far beyond the walls' rough outline at most
OPEN_SHARE = 0.45  # a piece enclosed by thin strokes is outside when this share of its edge is thin with the outside beyond
LEAK_SHARE = 0.7  # the outline leaked when it holds less than this share of the rough outline's free space
SMALL_GAP_M = 0.3  # scan breaks in the outer wall once its windows and doors are filled
NETWORK_OUTLINE_M = 0.06  # the outline of the segmenter's walls is found at about this many metres per pixel
NETWORK_MARGIN_M = 1.0  # the segmenter sees the building's outline and this much round it (not the sheet's margins)
SLIVER_M2 = 1.0  # free space touching the outside and smaller than this is a gap's or a corner's sliver  # a sheet frame is a ring of ink at most this thick on average (area / perimeter)


@dataclasses.dataclass(frozen=True)
class DrawingOptions:
    """How :func:`read_drawing` reads a drawing (pixel sizes are plan pixels).

    ``threshold``: ``"auto"`` (Otsu on the paper-evened image), ``"adaptive"`` (a mean over
    ``adaptive_block_px``) or a grey level 1-254 of the evened image (paper = 255): darker is ink.
    ``thin_lines_px``: strokes at most this wide are annotation, not walls (None: from the
    drawing's own line weights; 0: every stroke is a wall, as in a plan drawn with one pen).
    ``outline_gap_m``: openings in the outer wall up to this wide are closed when the building's
    outline is found. ``remove_text_px``: wall blobs whose longer side is below this many pixels
    are dropped (None: ``TEXT_BLOB_M``, keeping solid columns). ``close_gaps_px``: a closing of
    the ink first (scan breaks); ``thicken_px``: a dilation of the walls at the end.
    """

    threshold: str | int = "auto"
    adaptive_block_px: int = 51
    close_gaps_px: int = 0
    thin_lines_px: int | None = None
    remove_text_px: int | None = None
    outline_gap_m: float = 3.0
    find_doors: bool = True
    thicken_px: int = 0
    outside_is_wall: bool = True
    segmenter: bool = True


@dataclasses.dataclass
class DrawingReading:
    """What :func:`read_drawing` found; ``wall`` is the mask (outside the building included)."""

    wall: np.ndarray
    inside: np.ndarray  # the building's footprint (None when the outside is kept)
    threshold: float  # grey level of the evened image below which a pixel is ink
    thin_width_px: float  # strokes up to this wide were taken for annotation (0: none)
    doors: list[DoorSymbol]
    text_blobs: int  # wall blobs dropped as text


def even_paper(gray: np.ndarray, resolution_m: float) -> np.ndarray:
    """The drawing divided by its background, so paper reads 255 wherever it is grey or shaded.

    The background is a grey-level closing (the ink removed) with a kernel of
    ``PAPER_KERNEL_M``, computed on a copy reduced to about 12 pixels per kernel."""
    rows, cols = gray.shape
    kernel_px = max(15.0, PAPER_KERNEL_M / resolution_m)
    factor = max(1, int(kernel_px // 12))
    small = cv2.resize(gray, (max(1, cols // factor), max(1, rows // factor)), interpolation=cv2.INTER_AREA)
    side = int(kernel_px / factor) | 1
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (side, side))
    background = cv2.morphologyEx(small, cv2.MORPH_CLOSE, disc, borderType=cv2.BORDER_REPLICATE)
    background = cv2.blur(background, (side, side))
    background = cv2.resize(background, (cols, rows), interpolation=cv2.INTER_LINEAR).astype(np.float32)
    evened = gray.astype(np.float32) * (255.0 / np.maximum(background, 1.0))
    return np.clip(evened, 0, 255).astype(np.uint8)


def ink_threshold(evened: np.ndarray) -> float:
    """Otsu's threshold of the evened image between paper and ink."""
    level, _ = cv2.threshold(evened, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    return float(level)


def half_darkness(evened: np.ndarray, ink: np.ndarray) -> np.ndarray:
    """The ink at half its own darkness or darker: each stroke at its full width at half maximum.

    Blur widens a thin line's threshold mask but lowers its peak; measured against its own peak
    (the darkest pixel within 3 pixels) a stroke stays close to its drawn width, whatever its
    grey."""
    darkness = 255.0 - evened.astype(np.float32)
    peak = cv2.dilate(darkness, _disc(7))
    return ink & (darkness >= 0.5 * peak)


def stroke_widths(ink: np.ndarray) -> np.ndarray:
    """The widths (pixels) at the ridge pixels of the ink: twice the distance to paper, minus one."""
    distance = cv2.distanceTransform(ink.astype(np.uint8), cv2.DIST_L2, 5)
    ridge = (distance > 0) & (distance >= cv2.dilate(distance, np.ones((3, 3), np.uint8)) - 1e-3)
    return 2.0 * distance[ridge] - 1.0


def thin_line_width(widths: np.ndarray, resolution_m: float) -> float:
    """The widest stroke (pixels) that is annotation rather than wall, from the ridge widths.

    Widths come in odd steps (a line of ridge width w is w or w + 1 pixels wide). The thin lines
    are the most common width; the split lies above it, and below ``MIN_WALL_M`` unless the
    thin lines are wider still; of those splits the widest that leaves the walls a fifth of the
    ink's area at least (a drawing whose walls are two heavy lines has nothing heavier than
    those lines: the split then falls between them and the thin lines). None fits (one pen for
    everything): 0, nothing is thin."""
    if widths.size < 50:
        return 0.0
    classes = np.floor(np.clip(widths, 0, 1000) / 2.0).astype(np.int64)  # class k: widths 2k+1 and 2k+2
    length = np.bincount(classes).astype(np.float64)
    area = length * (2 * np.arange(len(length)) + 1)
    widest_thin = max(1, int(MAX_LINE_M / resolution_m) // 2)
    thin_mode = int(np.argmax(length[:widest_thin + 1]))
    mode_width = 2 * thin_mode + 1
    upper = max(mode_width + 1, int(MIN_WALL_M / resolution_m))
    for split in range(upper - upper % 2, mode_width, -2):  # even splits, widest first
        if area[(2 * np.arange(len(area)) + 1) > split].sum() >= 0.2 * area.sum():
            return float(split)
    return 0.0


def _disc(diameter_px: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (diameter_px, diameter_px))


def _widest(labels: np.ndarray, count: int, mask: np.ndarray) -> np.ndarray:
    """Per label, the largest distance from inside it to its edge (half its inscribed width)."""
    # (a mask without any zero pixel has no edge: its distances are capped at the image's size)
    distance = np.minimum(cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 5), float(sum(mask.shape)))
    # a component's largest distance lies on a local maximum: only those are compared
    ridge = (distance > 0) & (distance >= cv2.dilate(distance, np.ones((3, 3), np.uint8)))
    widest = np.zeros(count, dtype=np.float32)
    np.maximum.at(widest, labels[ridge], distance[ridge])
    return widest


def ink_mass(evened: np.ndarray, ink: np.ndarray, window_px: int = 7) -> np.ndarray:
    """At each pixel, the ink across a line through it: the darkness of ``ink`` summed over a
    disc of ``window_px`` divided by its diameter, in pixels of full black. It is a line's drawn
    width times its darkness, nearly whatever the blur (light fills beside it are not ink, so do
    not count); a wall wider than the disc reads about ``window_px``."""
    darkness = np.where(ink, (255.0 - evened.astype(np.float32)) / 255.0, 0.0).astype(np.float32)
    disc = _disc(window_px).astype(np.float32)
    return cv2.filter2D(darkness, -1, disc, borderType=cv2.BORDER_REPLICATE) / window_px


def _enclosed_gaps(lines: np.ndarray, resolution_m: float):
    """(labels, count, inscribed width in metres, elongation, enclosed) of the gaps between ``lines``."""
    free = (~lines).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(free, connectivity=4)
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    width_m = 2.0 * _widest(labels, count, free) * resolution_m
    area_m2 = stats[:, cv2.CC_STAT_AREA] * resolution_m ** 2
    elongation = area_m2 / np.maximum(width_m, resolution_m) ** 2
    enclosed = np.ones(count, dtype=bool)
    enclosed[0] = False
    enclosed[border] = False
    return labels, count, width_m, elongation, enclosed


def fill_hatching(ink: np.ndarray, resolution_m: float) -> np.ndarray:
    """The cells of hatching: enclosed gaps narrower than ``HATCH_M``, ``HATCH_CELLS`` or more side
    by side (a door leaf drawn as a thin box, a sliding door's panels, a letter's eye stand alone)."""
    labels, count, width_m, _, enclosed = _enclosed_gaps(ink, resolution_m)
    tiny = enclosed & (width_m <= HATCH_M)
    tiny &= _in_clusters(labels, tiny, resolution_m)
    return tiny[labels]


def fill_between_lines(lines: np.ndarray, resolution_m: float) -> np.ndarray:
    """The insides of walls drawn as two parallel heavy lines: between two lines that run the same
    way (0, 45, 90 or 135 degrees; each longer than ``MIN_BAND_RUN_M``) at most ``MAX_WALL_M``
    apart. No enclosure is needed, so a break in a wall's line (a scan, a crossing) does not
    open it; door arcs and furniture are no such pair."""
    across = max(3, int(MAX_BAND_M / resolution_m)) | 1
    shortest = MIN_BAND_RUN_M / resolution_m
    run = max(3, int(shortest)) | 1
    fills = np.zeros_like(lines)
    for angle in (0.0, 45.0):
        turned = (lines if angle == 0 else _rotate(lines, angle)).astype(np.uint8)
        between = np.zeros(turned.shape, dtype=bool)
        # a pixel lies on a run at least `run` long exactly when an opening by that line keeps it
        for along, kernel in ((np.ones((1, run), np.uint8), np.ones((across, 1), np.uint8)),
                              (np.ones((run, 1), np.uint8), np.ones((1, across), np.uint8))):
            running = cv2.morphologyEx(turned, cv2.MORPH_OPEN, along)
            between |= cv2.morphologyEx(running, cv2.MORPH_CLOSE, kernel).astype(bool) & ~turned.astype(bool)
        fills |= between if angle == 0 else _rotate(between, -angle, lines.shape)
    return fills & ~lines


def fill_wall_bands(lines: np.ndarray, resolution_m: float) -> np.ndarray:
    """The insides of walls drawn as two lines, and of windows: enclosed gaps between ``lines``
    (heavy lines only: a room's furniture and a window's glass are drawn thin) narrower than
    ``MAX_WALL_M``, at least 2.5 times as long as wide and ``MIN_RUN_M`` long (a letter's eye is
    shorter)."""
    labels, count, width_m, elongation, enclosed = _enclosed_gaps(lines, resolution_m)
    length_m = elongation * width_m  # area / width
    band = enclosed & (width_m <= MAX_WALL_M) & (elongation >= 2.5) & (length_m >= MIN_RUN_M)
    return band[labels]


def _in_clusters(labels: np.ndarray, tiny: np.ndarray, resolution_m: float) -> np.ndarray:
    """Of the very narrow gaps, those side by side with at least ``HATCH_CELLS`` - 1 others
    (within ``HATCH_M``): the cells of hatching. A door leaf drawn as a thin box, a sliding
    door's panels or a letter's eye stand alone."""
    cells = tiny[labels]
    if not cells.any():
        return tiny
    reach = max(3, int(round(HATCH_M / resolution_m)) | 1)
    groups, group_labels = cv2.connectedComponents(cv2.dilate(cells.astype(np.uint8), _disc(reach)), connectivity=8)
    # how many cells each group holds: each cell counted once, at its own label
    cell_ids = np.nonzero(tiny)[0]
    flat_labels = labels.ravel()
    order = np.flatnonzero(cells.ravel())
    _, where = np.unique(flat_labels[order], return_index=True)
    group_of_cell = np.zeros(len(tiny), dtype=np.int64)
    group_of_cell[flat_labels[order[where]]] = group_labels.ravel()[order[where]]
    per_group = np.bincount(group_of_cell[cell_ids], minlength=groups)
    keep = np.zeros(len(tiny), dtype=bool)
    keep[cell_ids] = per_group[group_of_cell[cell_ids]] >= HATCH_CELLS
    return keep


def heavy_lines(evened: np.ndarray, ink: np.ndarray, core: np.ndarray) -> tuple[np.ndarray, float]:
    """(the ink drawn heavier than the drawing's thin lines, the ink mass that splits them).

    The split is Otsu's on the log ink mass along the ink's ridges (a drawing's thin lines and
    its heavier wall lines or fills), at least ``HEAVY_RATIO`` times the lightest tenth."""
    mass = ink_mass(evened, ink)
    distance = cv2.distanceTransform(core.astype(np.uint8), cv2.DIST_L2, 5)
    ridge = (distance > 0) & (distance >= cv2.dilate(distance, np.ones((3, 3), np.uint8)) - 1e-3)
    values = mass[ridge]
    values = values[values > 0.05]
    if values.size < 50:
        return core, 0.0
    logs = np.log(values)
    counts, edges = np.histogram(logs, bins=64)
    centres = 0.5 * (edges[1:] + edges[:-1])
    weight = np.cumsum(counts)
    moment = np.cumsum(counts * centres)
    total, total_moment = weight[-1], moment[-1]
    with np.errstate(divide="ignore", invalid="ignore"):
        between = (total_moment * weight - total * moment) ** 2 / (weight * (total - weight))
    split = float(np.exp(edges[int(np.nanargmax(between[:-1])) + 1]))
    split = max(split, HEAVY_RATIO * float(np.percentile(values, 10)))
    return core & (mass >= split), split


def _drop_frames(heavy: np.ndarray, resolution_m: float) -> np.ndarray:
    """Remove a sheet frame: ink reaching near all four edges of the image, round another large
    piece of ink (the building), lying mostly along the edges of its own box (a frame is a
    rectangle with a title block in a corner; a building's outer wall carries its partitions)."""
    count, labels, stats, _ = cv2.connectedComponentsWithStats(heavy.astype(np.uint8), connectivity=8)
    rows, cols = heavy.shape
    drop = np.zeros(count, dtype=bool)
    for i in range(1, count):
        x, y, w, h, area = stats[i]
        if not (x < 0.1 * cols and y < 0.1 * rows and x + w > 0.9 * cols and y + h > 0.9 * rows):
            continue
        # other ink inside its box, spanning together at least 5 % of the image (a building,
        # whose walls windows and doors may have cut into many pieces)
        sx, sy, sw, sh = (stats[:, k] for k in range(4))
        inner = (sx > x) & (sy > y) & (sx + sw < x + w) & (sy + sh < y + h)
        inner[[0, i]] = False
        if not inner.any() or ((sx + sw)[inner].max() - sx[inner].min()) * \
                ((sy + sh)[inner].max() - sy[inner].min()) < 0.05 * rows * cols:
            continue
        # its long straight lines only (a title block's text is no frame's, nor a building's)
        piece = (labels[y:y + h, x:x + w] == i).astype(np.uint8)
        run = max(5, int(0.05 * min(w, h)))
        lines = cv2.morphologyEx(piece, cv2.MORPH_OPEN, np.ones((1, run), np.uint8)) | \
            cv2.morphologyEx(piece, cv2.MORPH_OPEN, np.ones((run, 1), np.uint8))
        ys, xs = np.nonzero(lines)
        if ys.size == 0:
            continue
        band = FRAME_BAND * min(w, h)
        along_edges = (xs < band) | (ys < band) | (xs >= w - band) | (ys >= h - band)
        if along_edges.mean() >= FRAME_ALONG_EDGES:
            drop[i] = True
    # a frame's side left alone (the others drawn lighter): a bare straight line along an edge,
    # across most of the sheet (a building's outer wall carries its partitions)
    x, y, w, h = (stats[:, k] for k in range(4))
    across = ((w >= 0.8 * cols) & (h <= np.maximum(3, 0.01 * rows)) & ((y < 0.05 * rows) | (y + h > 0.95 * rows))) | \
        ((h >= 0.8 * rows) & (w <= np.maximum(3, 0.01 * cols)) & ((x < 0.05 * cols) | (x + w > 0.95 * cols)))
    across[0] = False
    drop |= across
    return heavy & ~drop[labels] if drop.any() else heavy


def _close_by_distance(mask: np.ndarray, radius_px: float) -> np.ndarray:
    """Morphological closing by a disc of ``radius_px``, as two distance transforms (any radius, one cost)."""
    to_mask = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, 5)
    dilated = to_mask <= radius_px
    to_outside = cv2.distanceTransform(dilated.astype(np.uint8), cv2.DIST_L2, 5)
    # the image border is not a wall: pad so that the erosion does not eat in from it
    return to_outside > radius_px


def _small_blobs(mask: np.ndarray, below_px: float) -> np.ndarray:
    """The 8-connected blobs of ``mask`` whose bounding box's longer side is under ``below_px``."""
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    small = np.maximum(stats[:, cv2.CC_STAT_WIDTH], stats[:, cv2.CC_STAT_HEIGHT]) < below_px
    small[0] = False
    return small[labels]


def _drop_text_blobs(wall: np.ndarray, resolution_m: float, below_px: int | None) -> tuple[np.ndarray, int]:
    """Remove the wall blobs that are labels: shorter than ``below_px``; by default shorter than
    ``TEXT_BLOB_M`` and not a column (compact and solid: as thick as it is wide), or a line of
    letters (a blob no taller than ``TEXT_LINE_M`` whose strokes are under a third of its height:
    a free-standing piece of wall is as thick as it is tall)."""
    count, labels, stats, _ = cv2.connectedComponentsWithStats(wall.astype(np.uint8), connectivity=8)
    if count <= 1:
        return wall, 0
    x, y, w, h, area = (stats[1:, i] for i in range(5))
    longer, shorter = np.maximum(w, h), np.minimum(w, h)
    if below_px is None:
        small = longer * resolution_m < TEXT_BLOB_M
        stroke = 2.0 * _widest(labels, count, wall)[1:]
        # a column is solid: as thick as it is wide (a bold letter's strokes are a third of its size)
        column = ((stroke >= 0.7 * shorter) & (longer <= 2.5 * shorter)
                  & (shorter >= max(COLUMN_MIN_M / resolution_m, COLUMN_MIN_PX)))
        words = (shorter * resolution_m <= TEXT_LINE_M) & (shorter >= 3.0 * stroke)
        drop = (small & ~column) | words
    else:
        drop = longer < below_px
    keep = np.ones(count, dtype=bool)
    keep[1:] = ~drop
    return wall & keep[labels], int(drop.sum())


def _rotate(mask: np.ndarray, angle_deg: float, shape: tuple[int, int] | None = None) -> np.ndarray:
    """``mask`` turned by ``angle_deg`` about its centre onto a canvas big enough for it (or back
    onto ``shape``), nearest pixel."""
    rows, cols = mask.shape
    if shape is None:
        side = int(math.ceil(math.hypot(rows, cols))) + 2
        out_rows, out_cols = side, side
        matrix = cv2.getRotationMatrix2D((cols / 2, rows / 2), angle_deg, 1.0)
        matrix[:, 2] += [out_cols / 2 - cols / 2, out_rows / 2 - rows / 2]
    else:
        out_rows, out_cols = shape
        matrix = cv2.getRotationMatrix2D((cols / 2, rows / 2), angle_deg, 1.0)
        matrix[:, 2] += [out_cols / 2 - cols / 2, out_rows / 2 - rows / 2]
    return cv2.warpAffine(mask.astype(np.uint8), matrix, (out_cols, out_rows), flags=cv2.INTER_NEAREST).astype(bool)


def _thin_enough(fills: np.ndarray, resolution_m: float) -> np.ndarray:
    """The pieces of ``fills`` as thick as a wall: no thicker than ``MAX_WALL_M``, and no thinner
    than half ``MIN_WALL_M`` (a closing between specks)."""
    box = _ink_box(fills)
    if box is None:
        return fills
    piece = fills[box]  # (the fills are sparse: measured in their box, paper round it)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(piece.astype(np.uint8), connectivity=4)
    if count <= 1:
        return fills
    widest = _widest(labels, count, piece)
    thickness_m = 2 * widest * resolution_m
    keep = (thickness_m <= MAX_WALL_M) & (thickness_m >= 0.5 * MIN_WALL_M) & (widest >= 1.0)
    keep[0] = False
    kept = np.zeros_like(fills)
    kept[box] = keep[labels]
    return kept


def _ink_box(mask: np.ndarray, margin_px: int = 3) -> tuple[slice, slice] | None:
    """The bounding box of ``mask``'s pixels grown by ``margin_px`` within the image (None: no
    pixel). Pieces, their distances to paper and their dilations by up to ``margin_px`` are the
    same in it as in the whole image (the margin is paper, or the image's own edge)."""
    x, y, w, h = cv2.boundingRect(np.ascontiguousarray(mask).view(np.uint8))
    if w == 0 or h == 0:
        return None
    rows, cols = mask.shape
    return (slice(max(0, y - margin_px), min(rows, y + h + margin_px)),
            slice(max(0, x - margin_px), min(cols, x + w + margin_px)))


def _run_lengths(mask: np.ndarray) -> np.ndarray:
    """At each pixel of ``mask``, the length of the horizontal run of mask pixels it lies in (int32)."""
    rows, cols = mask.shape
    padded = np.zeros((rows, cols + 1), dtype=np.int8)  # a blank column: runs never cross rows
    padded[:, :cols] = mask
    flat = padded.ravel()
    edges = np.diff(flat, prepend=np.int8(0))  # +1 where a run starts, -1 just past its end
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    lengths = (ends - starts).astype(np.int32)
    out = np.zeros(flat.shape, dtype=np.int32)
    out[flat.view(bool)] = np.repeat(lengths, lengths)  # the mask's pixels are its runs' in order
    return out.reshape(rows, cols + 1)[:, :cols]


def wall_gap_fills(wall: np.ndarray, resolution_m: float, max_gap_m: float) -> list[np.ndarray]:
    """The gaps between wall ends in line, up to ``max_gap_m`` wide: doors, passages, windows
    drawn in thin lines, entrances, each filled exactly between the two ends.

    For each of the four directions of a plan's walls (0, 45, 90 and 135 degrees) the walls that
    run that way (a pixel whose run of wall along the direction is longer than across it; twice
    as long for the diagonals, whose runs across an upright wall are long too) are closed along
    it; a filled piece is kept when it is no thicker than a wall (``MAX_WALL_M``). One mask per
    direction."""
    length = int(max_gap_m / resolution_m) | 1
    shortest = MIN_RUN_M / resolution_m
    fills = []
    for angle, dominance in ((0.0, 1), (45.0, 2)):
        turned = wall if angle == 0 else _rotate(wall, angle)
        # worked in the walls' box and a gap's length round it (a closing reaches half of it
        # beyond the walls, and looks half of it further): the same as over the whole canvas
        box = _ink_box(turned, length)
        if box is None:
            fills += [np.zeros_like(wall), np.zeros_like(wall)]
            continue
        near = np.ascontiguousarray(turned[box])
        along_x = _run_lengths(near)
        along_y = np.ascontiguousarray(_run_lengths(near.T).T)
        # (off the walls both lengths are 0, below `shortest`)
        for running, kernel in (((along_x >= dominance * along_y) & (along_x >= shortest), np.ones((1, length), np.uint8)),
                                ((along_y >= dominance * along_x) & (along_y >= shortest), np.ones((length, 1), np.uint8))):
            closed = np.zeros_like(turned)
            closed[box] = cv2.morphologyEx(running.view(np.uint8), cv2.MORPH_CLOSE, kernel).view(bool) & ~near
            if angle:
                closed = _rotate(closed, -angle, wall.shape) & ~wall
            fills.append(_thin_enough(closed, resolution_m))
    return fills


def building_footprint(wall: np.ndarray, resolution_m: float, max_gap_m: float,
                       strokes: np.ndarray | None = None, about_m: float = WORK_M) -> tuple[np.ndarray, np.ndarray]:
    """(inside the building, the filled gaps of its outer wall).

    The walls with every gap between wall ends in line closed (:func:`wall_gap_fills`) enclose
    the rooms; the holes filled, the pieces of at least a quarter of the largest one's area are
    the building (a title block, a scale bar or a north arrow is no building). The gaps filled on
    the outline are windows and entrances: wall, as the outside is.

    ``strokes`` (all the ink, thin lines too): the thin strokes that touch a wall close the
    outline as well, so that windows drawn in thin lines (a run of them over several metres, a
    curved bay's glazing) do not let the outside in. What they enclose beyond the walls' own
    outline is taken in only where it is bounded mostly by walls (rooms behind a window run); a
    terrace or a balcony, bounded by a façade and thin rails, is not.

    It is found on a copy of the walls reduced to about ``about_m`` metres per pixel (a whole
    number of pixels to one)."""
    # at about WORK_M per pixel: walls stay two pixels thick, and it is many times faster
    factor = max(1, int(about_m / resolution_m))
    work, ratio = _reduce(wall, factor, 0.3)
    work_m = resolution_m * ratio
    barrier = work
    # the walls closed over door-wide gaps (a disc a little wider than max_gap_m cannot pass them)
    rough = _enclosed(work, 0.625 * max_gap_m / work_m)
    if strokes is not None:
        # thin strokes touching the building's walls (not a sheet frame's or a title block's)
        thin = _reduce(strokes, factor, 0.2)[0] & ~work
        count, labels = cv2.connectedComponents(thin.astype(np.uint8), connectivity=8)
        touching = np.zeros(count, dtype=bool)
        near_walls = cv2.dilate((work & rough).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        touching[np.unique(labels[near_walls & thin])] = True
        touching[0] = False
        # ... and near it: windows lie in the wall's line, a bay's glazing within the rough outline
        # (an axis line or a terrace's rail running off to the sheet's frame closes nothing)
        reach = int(STROKE_REACH_M / work_m)
        near_rough = np.zeros_like(rough)
        box = _ink_box(rough, reach + 1)
        if box is not None:
            near_rough[box] = cv2.dilate(rough[box].astype(np.uint8), _disc(2 * reach + 1)).astype(bool)
        barrier = work | (touching[labels] & near_rough)
    fills = wall_gap_fills(barrier, work_m, max_gap_m)
    gaps = np.zeros_like(work)
    for fill in fills:
        gaps |= fill
    closed = barrier | gaps
    inside = _enclosed(closed, 0.5 * SMALL_GAP_M / work_m)
    if strokes is not None:
        wall_fills = wall_gap_fills(work, work_m, max_gap_m)
        walls_closed = work.copy()
        for fill in wall_fills:
            walls_closed |= fill
        own = _enclosed(walls_closed, 0.5 * SMALL_GAP_M / work_m)
        # thin strokes with the outside beyond them: windows, rails (furniture has rooms round it)
        strokes_only = closed & ~(work | gaps)
        count, labels = cv2.connectedComponents(strokes_only.astype(np.uint8), connectivity=8)
        open_ = np.zeros(count, dtype=bool)
        outside_near = cv2.dilate((~inside).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        open_[np.unique(labels[outside_near & strokes_only])] = True
        open_[0] = False
        open_strokes = open_[labels]
        inside = own | _walled_pieces(inside & ~own & ~closed, closed, open_strokes, SLIVER_M2 / work_m ** 2)
    else:
        open_strokes = np.zeros_like(work)
    # a gap the fills missed lets the outside in: then the rough outline
    if (inside & ~work).sum() < LEAK_SHARE * (rough & ~work).sum():
        inside = rough
    # gap fills on the outline: the pieces (of each direction) touching the outside, or the thin
    # strokes with the outside beyond them (a window's glass lines)
    open_strokes &= inside
    outside_near = cv2.dilate((~inside | open_strokes).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    outer_fills = open_strokes.copy()
    for fill in fills:
        box = _ink_box(fill)
        if box is None:
            continue
        count, labels = cv2.connectedComponents(fill[box].astype(np.uint8), connectivity=4)
        outer = np.zeros(count, dtype=bool)
        outer[np.unique(labels[outside_near[box] & fill[box]])] = True
        outer[0] = False
        outer_fills[box] |= outer[labels]
    return _resize_mask(inside, wall.shape), _resize_mask(outer_fills, wall.shape) & ~wall


def _reduce(mask: np.ndarray, factor: int, share: float) -> tuple[np.ndarray, float]:
    """``mask`` reduced ``factor`` times (a pixel set where at least ``share`` of it was)."""
    if factor <= 1:
        return mask, 1.0
    rows, cols = mask.shape
    small = cv2.resize(mask.astype(np.float32), (max(1, cols // factor), max(1, rows // factor)),
                       interpolation=cv2.INTER_AREA) >= share
    return small, cols / small.shape[1]


def _walled_pieces(pieces: np.ndarray, barrier: np.ndarray, open_edge: np.ndarray, min_px: float) -> np.ndarray:
    """The 4-connected ``pieces`` of at least ``min_px`` pixels whose edge (the ``barrier`` pixels
    beside them) is less than ``OPEN_SHARE`` thin strokes with the outside beyond them
    (``open_edge``): rooms behind a run of thin windows; a terrace or a balcony behind thin rails
    is not, nor a pocket between strokes."""
    count, labels = cv2.connectedComponents(pieces.astype(np.uint8), connectivity=4)
    if count <= 1:
        return np.zeros_like(pieces)
    grown = cv2.dilate(labels.astype(np.float32), np.ones((3, 3), np.uint8)).astype(np.int32)  # a label's ring
    ring = barrier & (grown > 0)
    edge = np.bincount(grown[ring], minlength=count).astype(np.float64)
    open_ = np.bincount(grown[ring & open_edge], minlength=count)
    keep = (open_ < OPEN_SHARE * np.maximum(edge, 1)) & (np.bincount(labels.ravel(), minlength=count) >= min_px)
    keep[0] = False
    return keep[labels]


def _enclosed(wall: np.ndarray, radius_px: float) -> np.ndarray:
    """The building: ``wall`` closed by a disc of ``radius_px``, its holes filled, the pieces of at
    least a quarter of the largest one's area (a title block, a scale bar, a north arrow is none)."""
    pad = int(math.ceil(radius_px)) + 2
    filled = np.zeros_like(wall)
    # in the walls' box and the closing's reach round it (beyond it, paper all round the walls:
    # the outside): the same as over the whole image
    near = _ink_box(wall, pad)
    if near is None:
        return filled
    padded = cv2.copyMakeBorder(wall[near].astype(np.uint8), pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=0).astype(bool)
    closed = _close_by_distance(padded, radius_px)[pad:-pad, pad:-pad]
    count, labels = cv2.connectedComponents((~closed).astype(np.uint8), connectivity=4)
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    outer = np.zeros(count, dtype=bool)
    outer[border[border > 0]] = True
    filled[near] = ~outer[labels]  # closed walls and their holes
    box = _ink_box(filled)
    if box is None:
        return filled
    count, labels, stats, _ = cv2.connectedComponentsWithStats(filled[box].astype(np.uint8), connectivity=8)
    if count <= 1:
        return filled
    areas = stats[1:, cv2.CC_STAT_AREA]
    keep = np.zeros(count, dtype=bool)
    keep[1:] = areas >= 0.25 * areas.max()
    kept = np.zeros_like(filled)
    kept[box] = keep[labels]
    return kept


def _resize_mask(mask: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    if mask.shape == shape:
        return mask
    return cv2.resize(mask.astype(np.uint8), (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST).astype(bool)


def _drop_outer_slivers(wall: np.ndarray, inside: np.ndarray, resolution_m: float) -> np.ndarray:
    """Free pieces that touch the outside and are smaller than a room (the corners and bays the
    outline's closing took in, the ends of filled gaps) become wall."""
    free = ~wall
    count, labels, stats, _ = cv2.connectedComponentsWithStats(free.astype(np.uint8), connectivity=4)
    if count <= 1:
        return wall
    outside_near = cv2.dilate((~inside).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    touching = np.zeros(count, dtype=bool)
    touching[np.unique(labels[outside_near & free])] = True
    area_m2 = stats[:, cv2.CC_STAT_AREA] * resolution_m ** 2
    drop = (touching & (area_m2 < SLIVER_M2)) | (area_m2 < (2 * MIN_WALL_M) ** 2)  # and pinholes in a wall
    drop[0] = False
    return wall | drop[labels]


def _with_segmenter(wall: np.ndarray, inside: np.ndarray | None, evened: np.ndarray, ink: np.ndarray,
                    resolution_m: float, options: DrawingOptions) -> tuple[np.ndarray, np.ndarray | None]:
    """The learned segmenter's walls (:mod:`mapfilter.maps.segmenter`), read on as the strokes
    are (a frame and text dropped, the outline from every stroke, found at ``NETWORK_OUTLINE_M``
    per pixel, the outside walled), kept where the network has a wall within 3 px: the network
    tells furniture, fixtures, stairs and tiles from walls better, the strokes find the doors open
    and the walls' exact edges. (It misses faint grey walls on shaded paper:
    tests/maps/test_drawing.py, test 4.) The outside is what both take for outside. Unchanged
    when the drawing is too large for the network. The network sees the strokes' outline of the
    building and ``NETWORK_MARGIN_M`` round it (the walls' box when the outside is kept): beyond
    it is the outside, or no wall."""
    from mapfilter.maps.segmenter import network_walls

    region = _ink_box(wall if inside is None else inside, int(NETWORK_MARGIN_M / resolution_m))
    learned = network_walls(evened, resolution_m, region)
    if learned is None:
        return wall, inside
    learned = _drop_frames(learned, resolution_m)
    learned, _ = _drop_text_blobs(learned, resolution_m, None)
    if inside is not None:
        learned_inside, outer_gaps = building_footprint(learned, resolution_m, options.outline_gap_m, ink, NETWORK_OUTLINE_M)
        learned = _drop_outer_slivers(learned | outer_gaps | ~learned_inside, learned_inside, resolution_m)
        inside = inside | learned_inside
    near = cv2.dilate(learned.astype(np.uint8), _disc(7)).astype(bool)
    return wall & near, inside


def read_drawing(gray: np.ndarray, resolution_m: float, options: DrawingOptions = DrawingOptions(),
                 path=None) -> DrawingReading:
    """Wall mask of a drawing (``gray``: 8-bit, paper light; ``resolution_m``: metres per pixel)."""
    evened = even_paper(gray, resolution_m)
    if options.threshold == "adaptive":
        block = max(3, options.adaptive_block_px | 1)
        # a pixel is ink when it is 10 grey levels darker than its neighbourhood's mean
        ink = cv2.adaptiveThreshold(evened, 1, cv2.ADAPTIVE_THRESH_MEAN_C, cv2.THRESH_BINARY_INV, block, 10).astype(bool)
        level = float("nan")
    else:
        if options.threshold == "auto":
            if int(evened.max()) - int(evened.min()) < 16:
                if gray.mean() < 128:
                    raise MapfilterError("the plan has no free space (it is dark all over)", path)
                raise MapfilterError("no walls found in the plan (it is blank)", path)
            level = ink_threshold(evened)
        else:
            level = float(options.threshold)
        ink = evened <= level  # Otsu returns the darker class's top (0 for a pure black-and-white plan)
    if not ink.any():
        raise MapfilterError("no walls found in the plan (no ink darker than the threshold)", path)
    if options.close_gaps_px > 0:
        ink = cv2.morphologyEx(ink.astype(np.uint8), cv2.MORPH_CLOSE, _disc(options.close_gaps_px)).astype(bool)

    # strokes thinner than a wall are annotation: widths measured at half each stroke's darkness
    core = half_darkness(evened, ink)
    if options.thin_lines_px is None:
        thin_px = max(1.0, MAX_LINE_M / resolution_m)
    else:
        thin_px = float(options.thin_lines_px)
    diameter = int(math.ceil(thin_px)) + 1  # an opening by this disc removes strokes up to thin_px wide
    # walls drawn in two heavier lines, hatched walls: filled where their lines are heavier than
    # the thin ones (high resolution: their lines may be thinner than MAX_LINE_M), then where
    # their lines outlast the thin ones (low resolution)
    # hatched walls, then walls drawn in two heavier lines (their lines may be thinner than
    # MAX_LINE_M at high resolution, so they are told by their ink mass), then at low
    # resolution the bands whose lines outlast the thin ones
    clean = core & ~_small_blobs(core, SPECK_M / resolution_m)  # dust, the crossings of faint tile lines
    hatching = fill_hatching(clean, resolution_m)
    outlines, _ = heavy_lines(evened, ink, core)
    outlines = cv2.morphologyEx((outlines | hatching).astype(np.uint8), cv2.MORPH_CLOSE, _disc(3)).astype(bool)
    fills = hatching | fill_wall_bands(outlines, resolution_m) | fill_between_lines(outlines, resolution_m)
    body = core | fills
    if thin_px > 0:
        heavy = cv2.morphologyEx(body.astype(np.uint8), cv2.MORPH_OPEN, _disc(diameter)).astype(bool)
        # at low resolution a thin line is as wide as a wall's line: it is told by its lighter ink
        # (a plan drawn with one pen has no heavier ink: then nothing is told this way)
        if (outlines | fills).sum() >= 0.1 * core.sum():
            heavy &= cv2.dilate((outlines | fills).astype(np.uint8), _disc(5)).astype(bool)  # (wall ends too)
        heavy |= fill_wall_bands(heavy, resolution_m)
    else:
        heavy = body
    doors: list[DoorSymbol] = []
    if options.find_doors and thin_px > 0:
        # the thin strokes at the ink threshold (a faint arc's core may break), joined over a
        # pixel; the bits of a thin line the opening left (its diagonal stretches) do not break it
        network, _ = _drop_text_blobs(heavy, resolution_m, None)
        thin = ink & ~cv2.dilate(network.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        thin = cv2.morphologyEx(thin.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8)).astype(bool)
        doors = find_door_symbols(thin, network, ink, resolution_m)
        heavy = erase_leaves(heavy, doors, LEAF_HALF_M / resolution_m + 1.0)
    heavy = _drop_frames(heavy, resolution_m)
    wall, n_text = _drop_text_blobs(heavy, resolution_m, options.remove_text_px)
    inside = None
    if options.outside_is_wall:
        inside, outer_gaps = building_footprint(wall, resolution_m, options.outline_gap_m, ink)
        wall = _drop_outer_slivers(wall | outer_gaps | ~inside, inside, resolution_m)
    if options.segmenter and options.remove_text_px is None:  # (blobs kept on purpose stay)
        wall, inside = _with_segmenter(wall, inside, evened, ink, resolution_m, options)
    if options.thicken_px > 0:
        wall = cv2.dilate(wall.astype(np.uint8), _disc(2 * options.thicken_px + 1)).astype(bool)
    return DrawingReading(wall, inside, level, thin_px, doors, n_text)
