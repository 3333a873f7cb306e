"""Random floor plans drawn the way drawings look, with their exact truth.

A layout (metres) is drawn at random: a building outline (rectangle, L, U, cut corners, round or
bowed, angled façades or a wing turned, a courtyard; sometimes curved or angled bays), rooms (an office's corridor with rooms along it, or an apartment split room by room), walls on
every room boundary (exterior walls thicker), doors between rooms chosen so that every room can
be reached (swing doors, double doors, sliding doors and open passages), one or two entrances,
windows (single ones, or runs of panes over several metres, and the glazing of bays), sometimes
terraces and balconies outside a door, columns, stairs and a closed shaft. The drawing of it then varies as drawings do:

- walls solid (black, dark or faint grey, with or without an outline), double-line (two heavier
  lines, sometimes a light fill) or hatched (outline and 45-degree hatching, sometimes crossed);
- door leaves (a line or a thin rectangle) and swing arcs (sometimes dashed), sliding doors,
  lintel lines over passages, windows as two or three thin lines in the wall (their faces thin or
  the walls' heavy lines); terraces' rails thin, doubled or dashed, sometimes paved;
- room names and areas in several fonts, sizes and weights, furniture and fixtures by room
  (beds, wardrobes, sofas, tables and chairs, kitchen counters with sink and hob, baths,
  showers, toilets, basins, desks, shelves, plants; against the walls, touching them), stairs,
  tiled wet rooms, light grey fills;
- dimension chains with extension lines, ticks and values, interior dimensions, a dash-dot axis
  grid with labelled bubbles, a sheet frame with a title block, a north arrow and a scale bar;
- paper white, grey, uneven or scanned (gradients, blotches, blur, noise, JPEG, a slight skew,
  a scanner's dark edge; JPEG on any paper), from 0.2 to 9 megapixels (a web page's plan to an
  architect's scan).

The truth, rasterised on the image's own pixel grid: the walls (windows and columns included:
nothing walks through them), the free space (inside the building, not wall: furniture, text and
door symbols are free; a courtyard, a terrace or a balcony is outside), and each room's pixels. Everything is drawn from one
``numpy.random.Generator``: the same seed gives the same plans.

Used by ``generate.py`` (plans to files) and ``benchmark.py`` (``mapfilter map prepare`` scored
against the truth), and by the tests.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import cv2
import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import LineString, MultiLineString, Point, Polygon, box
from shapely.ops import linemerge, unary_union

WALL_STYLES = ("solid", "double", "hatched")
PAPER_STYLES = ("white", "grey", "uneven", "scan")
MEGAPIXELS = (0.2, 9.0)  # the images' sizes
SUPERSAMPLE = 2  # drawn at twice the final size, then area-averaged: anti-aliased like a print

ROOM_NAMES = {
    "living": ["LIVING", "Living room", "LIVING / DINING", "Lounge", "SEJOUR", "Wohnen"],
    "bedroom": ["BEDROOM", "Bedroom", "BED 2", "Master bedroom", "CHAMBRE", "Schlafen"],
    "kitchen": ["KITCHEN", "Kitchen", "CUISINE", "Kueche"],
    "bath": ["BATH", "Bathroom", "SDB", "Bad"],
    "wc": ["WC", "W.C.", "Toilet"],
    "hall": ["HALL", "Entrance", "ENTRY", "Flur"],
    "store": ["STORE", "Storage", "Cupboard", "Abstellraum"],
    "office": ["OFFICE", "Office", "Buero", "Room"],
    "meeting": ["MEETING", "Conference", "Meeting room"],
    "corridor": ["CORRIDOR", "Corridor", "HALLWAY", "Circulation"],
    "stairs": ["STAIRS", "Stair", "UP"],
    "shaft": ["", "DUCT", "SHAFT"],
}
FONTS = (cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_COMPLEX, cv2.FONT_HERSHEY_TRIPLEX,
         cv2.FONT_HERSHEY_PLAIN, cv2.FONT_HERSHEY_COMPLEX_SMALL)


# ---- layout -----------------------------------------------------------------------------------
@dataclasses.dataclass
class Room:
    """A room: its polygon (wall centre lines; the exterior wall lies inside it), kind and name."""

    polygon: Polygon
    kind: str
    name: str = ""


@dataclasses.dataclass
class Opening:
    """A door, passage or window in a wall: jambs ``a`` and ``b`` on the wall's reference line
    (its centre line; an exterior wall's outer face), ``inward`` the unit normal pointing across the
    wall from that line (into the building for an exterior wall), ``thickness_m`` the wall's."""

    a: np.ndarray
    b: np.ndarray
    inward: np.ndarray
    thickness_m: float
    exterior: bool
    kind: str  # swing, double, sliding, passage, window
    rooms: tuple[int, int]  # the rooms on the two sides (-1 = outside)
    swing_side: int = 1  # +1: the leaf swings towards +inward, -1 the other way
    hinge_at_a: bool = True
    leaf_angle_deg: float = 90.0

    @property
    def width_m(self) -> float:
        return float(np.linalg.norm(self.b - self.a))

    def cut(self, extra_m: float = 0.02) -> Polygon:
        """The opening's rectangle through the whole wall."""
        if self.exterior:
            # a door on a curved face: its chord lies inside the face, the cut reaches past it
            near, far = -extra_m - (0.1 if self.kind != "window" else 0.0), self.thickness_m + extra_m
        else:
            near, far = -self.thickness_m / 2 - extra_m, self.thickness_m / 2 + extra_m
        n = self.inward
        return Polygon([self.a + n * near, self.b + n * near, self.b + n * far, self.a + n * far])

    def face_points(self, side: int) -> tuple[np.ndarray, np.ndarray]:
        """The jambs on the wall face towards ``side`` (+1 = inward)."""
        if self.exterior:
            offset = self.thickness_m if side > 0 else 0.0
        else:
            offset = side * self.thickness_m / 2
        return self.a + self.inward * offset, self.b + self.inward * offset


@dataclasses.dataclass
class Window:
    """A window (or a run of glazing) in the outer wall, straight or curved: the piece of wall it
    replaces and its outer and inner face lines (the outer face on the outline)."""

    polygon: Polygon
    outer: LineString
    inner: LineString
    room: int
    thickness_m: float
    exterior: bool = True
    kind: str = "window"

    @property
    def a(self) -> np.ndarray:
        return np.asarray(self.outer.coords[0])

    @property
    def b(self) -> np.ndarray:
        return np.asarray(self.outer.coords[-1])

    def cut(self, extra_m: float = 0.0) -> Polygon:
        return self.polygon if extra_m == 0 else self.polygon.buffer(extra_m)


@dataclasses.dataclass
class Layout:
    footprint: Polygon
    rooms: list[Room]
    walls: shapely.Geometry  # drawn wall bodies with the openings cut (no windows, no columns)
    windows: list[Opening]
    openings: list[Opening]
    columns: list[Polygon]
    exterior_m: float
    interior_m: float
    terraces: list = dataclasses.field(default_factory=list)  # outside areas with rails (not the building)
    features: dict = dataclasses.field(default_factory=dict)  # outline shape, bays, window runs, terraces

    @property
    def solid(self) -> shapely.Geometry:
        """Everything nobody walks through: walls, windows, columns."""
        return unary_union([self.walls, *[w.cut(0.0) for w in self.windows], *self.columns])


def _straight_pieces(geometry: shapely.Geometry, min_length_m: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """The straight segments of a (multi)line geometry that are at least ``min_length_m`` long."""
    pieces = []
    if geometry.is_empty:
        return pieces
    merged = linemerge(geometry) if geometry.geom_type == "MultiLineString" else geometry
    lines = getattr(merged, "geoms", [merged])
    for line in lines:
        if line.geom_type != "LineString":
            continue
        coords = np.asarray(line.coords)
        # join consecutive collinear segments
        start = coords[0]
        for i in range(1, len(coords)):
            end = coords[i]
            nxt = coords[i + 1] if i + 1 < len(coords) else None
            if nxt is not None:
                d1 = (end - start) / max(np.linalg.norm(end - start), 1e-12)
                d2 = (nxt - end) / max(np.linalg.norm(nxt - end), 1e-12)
                if abs(d1[0] * d2[1] - d1[1] * d2[0]) < 1e-6 and float(d1 @ d2) > 0:
                    continue
            if np.linalg.norm(end - start) >= min_length_m:
                pieces.append((start.copy(), end.copy()))
            start = end
    return pieces


OUTLINES = ("rect", "L", "U", "chamfer", "round", "angled", "courtyard")


def _footprint(rng: np.random.Generator, kind: str) -> tuple[Polygon, str, list[Polygon]]:
    """(outline, its shape's name, the bays added to it): a rectangle, L, U, cut corners, a round
    or bowed house, angled façades or wings, a courtyard; sometimes curved or angled bays."""
    if kind == "office":
        width, height = rng.uniform(18, 40), rng.uniform(11, 22)
    elif kind == "house":
        width, height = rng.uniform(9, 16), rng.uniform(8, 13)
    else:
        width, height = rng.uniform(8, 18), rng.uniform(7, 13)
    if rng.random() < 0.5:
        width, height = height, width
    shape = str(rng.choice(OUTLINES, p=[0.2, 0.17, 0.1, 0.13, 0.13, 0.15, 0.12]))
    if shape == "courtyard" and min(width, height) < 11:
        width, height = width * 1.4, height * 1.4
    outline = box(0, 0, width, height)
    if shape == "L":
        cw, ch = width * rng.uniform(0.25, 0.5), height * rng.uniform(0.25, 0.5)
        corner = rng.integers(4)
        x0 = 0 if corner in (0, 3) else width - cw
        y0 = 0 if corner in (0, 1) else height - ch
        outline = outline.difference(box(x0, y0, x0 + cw, y0 + ch))
    elif shape == "U":
        if width >= height:
            nw, nd = width * rng.uniform(0.25, 0.4), height * rng.uniform(0.2, 0.35)
            x0 = rng.uniform(0.25, 0.75) * (width - nw)
            y0 = 0 if rng.random() < 0.5 else height - nd
            outline = outline.difference(box(x0, y0, x0 + nw, y0 + nd))
        else:
            nw, nd = height * rng.uniform(0.25, 0.4), width * rng.uniform(0.2, 0.35)
            y0 = rng.uniform(0.25, 0.75) * (height - nw)
            x0 = 0 if rng.random() < 0.5 else width - nd
            outline = outline.difference(box(x0, y0, x0 + nd, y0 + nw))
    elif shape == "chamfer":
        for corner in rng.choice(4, size=rng.integers(1, 3), replace=False):
            leg = rng.uniform(1.5, 0.35 * min(width, height))
            cx, cy = [(0, 0), (width, 0), (width, height), (0, height)][corner]
            sx, sy = (1 if cx == 0 else -1), (1 if cy == 0 else -1)
            outline = outline.difference(Polygon([(cx, cy), (cx + sx * leg, cy), (cx, cy + sy * leg)]))
    elif shape == "round":
        roll = rng.random()
        if roll < 0.3:  # a round house
            outline = affinity.scale(Point(width / 2, height / 2).buffer(1.0, quad_segs=32), width / 2,
                                     min(height, width) / 2 if rng.random() < 0.5 else height / 2)
        elif roll < 0.6:  # a stadium: two round ends
            r = min(width, height) / 2
            outline = unary_union([box(r, 0, width - r, height) if width >= height else box(0, r, width, height - r),
                                   *(Point(c).buffer(r, quad_segs=24) for c in
                                     ([(r, r), (width - r, r)] if width >= height else [(r, r), (r, height - r)]))])
        else:  # one side bowed out
            bulge = rng.uniform(1.0, 0.3 * min(width, height))
            side = rng.integers(4)
            chord = width if side in (0, 2) else height
            radius = (chord ** 2 / 4 + bulge ** 2) / (2 * bulge)
            centre_in = radius - bulge
            if side == 0:
                centre = (width / 2, centre_in)
            elif side == 2:
                centre = (width / 2, height - centre_in)
            elif side == 1:
                centre = (width - centre_in, height / 2)
            else:
                centre = (centre_in, height / 2)
            disc = Point(centre).buffer(radius, quad_segs=48)
            outline = unary_union([outline, disc.intersection(_side_band(side, width, height, bulge))])
    elif shape == "angled":
        if rng.random() < 0.5:  # one or two façades at an angle
            for corner in rng.choice(4, size=rng.integers(1, 3), replace=False):
                cx, cy = [(0, 0), (width, 0), (width, height), (0, height)][corner]
                sx, sy = (1 if cx == 0 else -1), (1 if cy == 0 else -1)
                a, b = rng.uniform(0.3, 0.6) * width, rng.uniform(0.15, 0.35) * height
                if rng.random() < 0.5:
                    a, b = rng.uniform(0.15, 0.35) * width, rng.uniform(0.3, 0.6) * height
                outline = outline.difference(Polygon([(cx, cy), (cx + sx * a, cy), (cx, cy + sy * b)]))
        else:  # a wing turned by 30-60 degrees
            wing_w, wing_l = min(width, height) * rng.uniform(0.4, 0.6), max(width, height) * rng.uniform(0.4, 0.7)
            turn = float(rng.uniform(30, 60)) * (1 if rng.random() < 0.5 else -1)
            wing = box(-wing_w / 2, 0, wing_w / 2, wing_l)
            wing = affinity.rotate(wing, turn, origin=(0, 0))
            corner = [(0, height), (width, height)][int(rng.integers(2))]
            wing = affinity.translate(wing, corner[0] + (wing_w / 2 if corner[0] == 0 else -wing_w / 2), corner[1] - 1.0)
            outline = unary_union([outline, wing])
    elif shape == "courtyard":
        cw, ch = width * rng.uniform(0.25, 0.4), height * rng.uniform(0.25, 0.4)
        cx, cy = rng.uniform(0.3, 0.7) * (width - cw), rng.uniform(0.3, 0.7) * (height - ch)
        courtyard = box(cx, cy, cx + cw, cy + ch)
        if rng.random() < 0.3:
            courtyard = Point(cx + cw / 2, cy + ch / 2).buffer(min(cw, ch) / 2, quad_segs=24)
        outline = outline.difference(courtyard)
    outline = shapely.normalize(outline.buffer(0))
    if outline.geom_type != "Polygon":
        outline = max(outline.geoms, key=lambda g: g.area)
    bays = []
    if shape in ("rect", "L", "U", "chamfer", "angled", "courtyard") and rng.random() < 0.45:
        for _ in range(int(rng.integers(1, 3))):
            bay = _bay(rng, outline)
            if bay is not None:
                grown = shapely.normalize(unary_union([outline, bay.buffer(1e-3, join_style="mitre")]).buffer(0))
                if grown.geom_type == "Polygon":
                    bays.append(bay)
                    outline = grown
    return outline, shape, bays


def _side_band(side: int, width: float, height: float, bulge: float) -> Polygon:
    """The rectangle grown outward on ``side`` only (0 top, 1 right, 2 bottom, 3 left; y down)."""
    x0, y0, x1, y1 = 0.0, 0.0, width, height
    if side == 0:
        y0 -= bulge + 0.2
    elif side == 1:
        x1 += bulge + 0.2
    elif side == 2:
        y1 += bulge + 0.2
    else:
        x0 -= bulge + 0.2
    return box(x0, y0, x1, y1)


def _bay(rng: np.random.Generator, outline: Polygon) -> Polygon | None:
    """A curved or angled bay on a straight façade of ``outline``: 1.8-4.5 m wide, 0.6-1.6 m deep."""
    pieces = _straight_pieces(LineString(outline.exterior.coords), 3.0)
    if not pieces:
        return None
    p, q = pieces[rng.integers(len(pieces))]
    length = float(np.linalg.norm(q - p))
    width = rng.uniform(1.8, min(4.5, length - 1.2))
    if width < 1.8:
        return None
    depth = rng.uniform(0.6, min(1.6, 0.6 * width))
    d = (q - p) / length
    n = np.array([-d[1], d[0]])
    centre = p + d * rng.uniform(0.6 + width / 2, length - 0.6 - width / 2)
    if outline.contains(Point(*(centre + n * 0.05))):
        n = -n  # outward
    a, b = centre - d * width / 2, centre + d * width / 2
    if rng.random() < 0.5:  # angled: 45-degree cheeks
        side = min(depth, width / 3)
        bay = Polygon([a, a + n * side + d * side, b + n * side - d * side, b])
    else:  # curved: a circle's segment
        radius = (width ** 2 / 4 + depth ** 2) / (2 * depth)
        disc = Point(*(centre + n * (depth - radius))).buffer(radius, quad_segs=32)
        bay = disc.intersection(Polygon([a, a + n * (depth + 1), b + n * (depth + 1), b]))
    bay = bay.buffer(0)
    if bay.is_empty or bay.intersection(outline).area > 0.05 * bay.area:
        return None
    return bay


def _bsp(rect: tuple[float, float, float, float], rng: np.random.Generator, max_side: float,
         min_side: float) -> list[tuple[float, float, float, float]]:
    x0, y0, x1, y1 = rect
    w, h = x1 - x0, y1 - y0
    if max(w, h) <= max_side * rng.uniform(0.8, 1.3) or max(w, h) < 2 * min_side:
        return [rect]
    if w >= h:
        cut = x0 + w * rng.uniform(0.3, 0.7)
        cut = min(max(cut, x0 + min_side), x1 - min_side)
        return _bsp((x0, y0, cut, y1), rng, max_side, min_side) + _bsp((cut, y0, x1, y1), rng, max_side, min_side)
    cut = y0 + h * rng.uniform(0.3, 0.7)
    cut = min(max(cut, y0 + min_side), y1 - min_side)
    return _bsp((x0, y0, x1, cut), rng, max_side, min_side) + _bsp((x0, cut, x1, y1), rng, max_side, min_side)


def _partition(rng: np.random.Generator, kind: str, outline: Polygon) -> list[Room]:
    x0, y0, x1, y1 = outline.bounds
    w, h = x1 - x0, y1 - y0
    rects: list[tuple[tuple[float, float, float, float], str]] = []
    if kind == "office":
        horizontal = w >= h
        span, depth = (w, h) if horizontal else (h, w)
        corridor_m = rng.uniform(1.4, 2.4)
        at = depth * rng.uniform(0.35, 0.6) - corridor_m / 2
        bands = [(0.0, at), (at + corridor_m, depth)]
        corridors = [(0.0, at, span, at + corridor_m)]
        cross = None
        if span > 24 and rng.random() < 0.6:
            cross = span * rng.uniform(0.35, 0.65)
            corridors.append((cross, 0.0, cross + corridor_m, depth))
        for lo, hi in bands:
            if hi - lo < 2.2:
                continue
            s = 0.0
            while s < span - 0.5:
                room_w = rng.uniform(2.8, 6.5)
                end = span if span - (s + room_w) < 2.5 else s + room_w
                if cross is not None and s < cross + corridor_m and end > cross:
                    # rooms stop at the cross corridor
                    if s < cross:
                        end = cross
                    else:
                        s = cross + corridor_m
                        continue
                pieces = [(lo, hi)]
                if hi - lo > 7.5 and rng.random() < 0.5:
                    mid = lo + (hi - lo) * rng.uniform(0.4, 0.6)
                    pieces = [(lo, mid), (mid, hi)]
                for a, b in pieces:
                    rects.append(((s, a, end, b), "room"))
                s = end
        for c in corridors:
            rects.append((c, "corridor"))
        if not horizontal:
            rects = [((b0, a0, b1, a1), k) for (a0, b0, a1, b1), k in rects]
        rects = [((a + x0, b + y0, c + x0, d + y0), k) for (a, b, c, d), k in rects]
    else:
        for r in _bsp((x0, y0, x1, y1), rng, rng.uniform(3.8, 5.8), 1.8):
            rects.append((r, "room"))
    # clip to the outline; pieces too small to be a room join a neighbour
    polygons: list[tuple[Polygon, str]] = []
    corridor_union = []
    for r, k in rects:
        piece = box(*r).intersection(outline)
        if k == "corridor":
            corridor_union.append(piece)
            continue
        for part in getattr(piece, "geoms", [piece]):
            if part.geom_type == "Polygon" and part.area > 1e-6:
                polygons.append((part, k))
    if corridor_union:
        merged = unary_union(corridor_union)
        for part in getattr(merged, "geoms", [merged]):
            if part.geom_type == "Polygon" and part.area > 1e-6:
                polygons.append((part, "corridor"))
    # rooms minus corridor overlap
    corridor_geom = unary_union([p for p, k in polygons if k == "corridor"]) if corridor_union else Polygon()
    cleaned = []
    for p, k in polygons:
        if k != "corridor" and not corridor_geom.is_empty:
            p = p.difference(corridor_geom)
        for part in getattr(p, "geoms", [p]):
            if part.geom_type == "Polygon" and part.area > 1e-6:
                cleaned.append([shapely.normalize(part), k])
    changed = True
    while changed:
        changed = False
        for i, (p, k) in enumerate(cleaned):
            narrow = p.buffer(-0.8).is_empty
            if p.area < 3.0 or narrow:
                best, best_len = None, 0.0
                for j, (q, kq) in enumerate(cleaned):
                    if j != i:
                        shared = p.boundary.intersection(q.boundary).length
                        if shared > best_len:
                            best, best_len = j, shared
                if best is not None and best_len > 0.3:
                    cleaned[best][0] = shapely.normalize(unary_union([cleaned[best][0], p]).buffer(0))
                    del cleaned[i]
                    changed = True
                    break
    return [Room(p if p.geom_type == "Polygon" else max(p.geoms, key=lambda g: g.area), k) for p, k in cleaned]


def _name_rooms(rng: np.random.Generator, rooms: list[Room], kind: str) -> None:
    order = sorted(range(len(rooms)), key=lambda i: -rooms[i].polygon.area)
    if kind == "office":
        big = [i for i in order if rooms[i].kind == "room"]
        for rank, i in enumerate(big):
            area = rooms[i].polygon.area
            if rank == 0 and area > 25:
                rooms[i].kind = "meeting"
            elif area < 7:
                rooms[i].kind = rng.choice(["wc", "store"])
            else:
                rooms[i].kind = rng.choice(["office", "office", "office", "meeting", "kitchen"])
    else:
        free = [i for i in order if rooms[i].kind == "room"]
        for rank, i in enumerate(free):
            area = rooms[i].polygon.area
            if rank == 0:
                rooms[i].kind = "living"
            elif area < 4.5:
                rooms[i].kind = rng.choice(["bath", "wc", "store"])
            elif area < 7.5:
                rooms[i].kind = rng.choice(["bath", "kitchen", "hall"])
            else:
                rooms[i].kind = rng.choice(["bedroom", "bedroom", "kitchen", "bath"])
    if rng.random() < 0.35 and len(rooms) > 3:
        candidates = [r for r in rooms if r.kind not in ("corridor", "living", "meeting") and 5 < r.polygon.area < 16]
        if candidates:
            candidates[rng.integers(len(candidates))].kind = "stairs"
    number = 1
    for room in rooms:
        names = ROOM_NAMES[room.kind]
        room.name = str(names[rng.integers(len(names))])
        if room.kind in ("office", "bedroom") and rng.random() < 0.5:
            room.name = f"{room.name} {number}" if room.kind == "bedroom" else f"{room.name} {rng.integers(1, 4)}.{number:02d}"
            number += 1


def _place_opening(rng: np.random.Generator, p: np.ndarray, q: np.ndarray, width_m: float, margin_m: float,
                   taken: list[tuple[float, float]]) -> tuple[np.ndarray, np.ndarray] | None:
    """Jambs of an opening of ``width_m`` on segment p-q, ``margin_m`` from its ends, clear of ``taken``
    (intervals along the segment)."""
    length = float(np.linalg.norm(q - p))
    lo, hi = margin_m + width_m / 2, length - margin_m - width_m / 2
    if hi < lo:
        return None
    d = (q - p) / length
    for _ in range(12):
        centre = rng.uniform(lo, hi)
        interval = (centre - width_m / 2 - 0.3, centre + width_m / 2 + 0.3)
        if all(interval[1] < t0 or interval[0] > t1 for t0, t1 in taken):
            taken.append(interval)
            return p + d * (centre - width_m / 2), p + d * (centre + width_m / 2)
    return None


def make_layout(rng: np.random.Generator) -> Layout:
    """A random building: outline, rooms, walls, doors, windows, columns (metres, y down)."""
    kind = str(rng.choice(["apartment", "house", "office"], p=[0.4, 0.2, 0.4]))
    outline, shape, bays = _footprint(rng, kind)
    rooms = _partition(rng, kind, outline)
    _name_rooms(rng, rooms, kind)
    exterior_m = rng.uniform(0.22, 0.45)
    interior_m = rng.uniform(0.08, 0.2)
    margin_m = exterior_m + 0.12
    inner = outline.buffer(-exterior_m, join_style="mitre")
    exterior_band = outline.difference(inner)

    # a closed shaft: a small square room with no door
    if rng.random() < 0.2:
        hosts = [i for i, r in enumerate(rooms) if r.kind in ("office", "living", "bedroom", "meeting", "corridor")
                 and r.polygon.area > 14]
        if hosts:
            host = rooms[hosts[rng.integers(len(hosts))]]
            side = rng.uniform(0.8, 1.4)
            hx0, hy0, hx1, hy1 = host.polygon.bounds
            for _ in range(10):
                cx = hx0 if rng.random() < 0.5 else hx1 - side
                cy = hy0 if rng.random() < 0.5 else hy1 - side
                square = box(cx, cy, cx + side, cy + side)
                if host.polygon.buffer(1e-6).contains(square):
                    host.polygon = shapely.normalize(host.polygon.difference(square))
                    if host.polygon.geom_type != "Polygon":
                        host.polygon = max(host.polygon.geoms, key=lambda g: g.area)
                    rooms.append(Room(square, "shaft", str(ROOM_NAMES["shaft"][rng.integers(3)])))
                    break

    # interior walls on every shared boundary
    shared: dict[tuple[int, int], list[tuple[np.ndarray, np.ndarray]]] = {}
    boundary_lines = []
    for i in range(len(rooms)):
        for j in range(i + 1, len(rooms)):
            common = rooms[i].polygon.boundary.intersection(rooms[j].polygon.boundary)
            if common.is_empty or common.length < 0.05:
                continue
            lines = [g for g in getattr(common, "geoms", [common]) if g.geom_type in ("LineString", "MultiLineString")]
            if not lines:
                continue
            boundary_lines.extend(lines)
            shared[(i, j)] = _straight_pieces(unary_union(lines), 0.5)
    partitions = unary_union(boundary_lines).buffer(interior_m / 2, cap_style="square", join_style="mitre")
    walls = unary_union([exterior_band, partitions.intersection(outline)])

    # doors: a spanning tree of the room graph from the corridor / living room, and a few more
    openings: list[Opening] = []
    taken: dict[tuple[int, int], list] = {}
    reachable_rooms = [i for i, r in enumerate(rooms) if r.kind != "shaft"]
    start = next((i for i in reachable_rooms if rooms[i].kind in ("corridor", "hall", "living")), reachable_rooms[0])
    edges = [(i, j) for (i, j), pieces in shared.items()
             if rooms[i].kind != "shaft" and rooms[j].kind != "shaft" and any(
                 np.linalg.norm(q - p) >= 0.75 + 2 * margin_m for p, q in pieces)]
    rng.shuffle(edges)
    connected = {start}
    chosen = []
    grew = True
    while grew:
        grew = False
        for i, j in edges:
            if (i in connected) != (j in connected):
                chosen.append((i, j))
                connected |= {i, j}
                grew = True
    extra = 0.2 if kind != "office" else 0.05
    chosen += [e for e in edges if e not in chosen and rng.random() < extra]
    for i, j in chosen:
        pieces = [pq for pq in shared[(i, j)] if np.linalg.norm(pq[1] - pq[0]) >= 0.75 + 2 * margin_m]
        p, q = pieces[rng.integers(len(pieces))]
        length = float(np.linalg.norm(q - p)) - 2 * margin_m
        roll = rng.random()
        open_plan = {rooms[i].kind, rooms[j].kind} <= {"living", "kitchen", "hall", "corridor"}
        if roll < 0.1 or (open_plan and roll < 0.4):
            door_kind, width = "passage", rng.uniform(min(0.9, length), min(2.8 if open_plan else 1.8, length))
        elif roll < 0.18:
            door_kind, width = "sliding", rng.uniform(0.75, min(1.6, length))
        elif roll < 0.23 and length >= 1.3:
            door_kind, width = "double", rng.uniform(1.2, min(1.7, length))
        else:
            door_kind, width = "swing", rng.uniform(0.7, min(1.0, length))
        jambs = _place_opening(rng, p, q, width, margin_m, taken.setdefault((i, j), []))
        if jambs is None:
            continue
        a, b = jambs
        d = (b - a) / np.linalg.norm(b - a)
        openings.append(Opening(a, b, np.array([-d[1], d[0]]), interior_m, False, door_kind, (i, j),
                                int(rng.choice([-1, 1])), bool(rng.random() < 0.5),
                                90.0 if rng.random() < 0.75 else float(rng.uniform(25, 60))))

    # entrances and windows on the outer faces (straight or curved pieces between corners)
    outer_pieces: list[tuple[int, LineString]] = []
    for i, room in enumerate(rooms):
        if room.kind == "shaft":
            continue
        common = room.polygon.boundary.intersection(outline.boundary)
        for piece in _facade_pieces(common, 1.0):
            outer_pieces.append((i, piece))
    order = rng.permutation(len(outer_pieces))
    entrances = 0
    wanted = 1 + int(rng.random() < 0.3)
    ext_taken: dict[int, list] = {}
    preferred = ("corridor", "hall", "living", "office", "meeting")
    for rank in sorted(order, key=lambda k: rooms[outer_pieces[k][0]].kind not in preferred):
        if entrances >= wanted:
            break
        i, piece = outer_pieces[rank]
        roll = rng.random()
        door_kind, width = (("swing", rng.uniform(0.9, 1.1)) if roll < 0.6 else
                            ("double", rng.uniform(1.4, 1.8)) if roll < 0.85 else ("passage", rng.uniform(1.2, 2.0)))
        span = _place_along(rng, piece, width, margin_m + 0.2, ext_taken.setdefault(rank, []))
        if span is None:
            continue
        jambs = (np.asarray(piece.interpolate(span[0]).coords[0]), np.asarray(piece.interpolate(span[1]).coords[0]))
        openings.append(_exterior_opening(jambs, outline, exterior_m, door_kind, i, rng))
        entrances += 1
    # terraces and balconies: outside, behind a door in the outer wall, drawn with rails
    terraces = []
    if rng.random() < 0.35:
        terraces = _terraces(rng, outline, rooms, outer_pieces, openings, ext_taken, exterior_m, margin_m)
    # windows: single ones, runs of panes with thin piers between over several metres, and the
    # glazing of bays and curved façades
    runs = bool(rng.random() < 0.45)
    windows = []
    for rank, (i, piece) in enumerate(outer_pieces):
        length = piece.length
        in_bay = any(piece.intersection(bay.buffer(0.01)).length > 0.5 * length for bay in bays)
        if in_bay or (runs and length > 3.0 and rng.random() < 0.6):
            # a run: panes and piers over most of the piece
            span = _place_along(rng, piece, length * rng.uniform(0.6, 0.95) - 2 * margin_m, margin_m,
                                ext_taken.setdefault(rank, []), clear_m=0.0)
            if span is None:
                continue
            s, end = span
            pier = rng.uniform(0.1, 0.3)
            pane = rng.uniform(0.8, 2.2)
            while s < end - 0.3:
                stop = min(end, s + pane)
                windows.append(_window_on(piece, s, stop, outline, exterior_m, i))
                s = stop + pier
            continue
        for _ in range(1 + int(length > 5.5)):
            if rng.random() > 0.65:
                continue
            width = rng.uniform(0.6, min(2.4, max(0.6, length - 2 * margin_m - 0.4)))
            span = _place_along(rng, piece, width, margin_m + 0.1, ext_taken.setdefault(rank, []))
            if span is not None:
                windows.append(_window_on(piece, span[0], span[1], outline, exterior_m, i))
    windows = [w for w in windows if not w.polygon.is_empty]

    walls = walls.difference(unary_union([o.cut() for o in openings] + [w.cut(0.0) for w in windows]))

    columns = []
    if kind == "office" and rng.random() < 0.4:
        side = rng.uniform(0.3, 0.55)
        sx, sy = rng.uniform(5, 8), rng.uniform(5, 8)
        ox, oy = rng.uniform(0, sx), rng.uniform(0, sy)
        x0, y0, x1, y1 = outline.bounds
        keep_clear = unary_union([o.cut(0.9).buffer(0.9) for o in openings] + [w.cut(0.0) for w in windows])
        for cx in np.arange(x0 + ox, x1, sx):
            for cy in np.arange(y0 + oy, y1, sy):
                column = box(cx - side / 2, cy - side / 2, cx + side / 2, cy + side / 2)
                if inner.buffer(-0.05).contains(column) and not column.intersects(keep_clear) \
                        and not column.intersects(walls):
                    columns.append(column)
    features = {"outline": shape, "bay": bool(bays), "window_run": runs and len(windows) > 0,
                "terrace": bool(terraces)}
    return Layout(outline, rooms, walls, windows, openings, columns, exterior_m, interior_m, terraces, features)


def _facade_pieces(geometry: shapely.Geometry, min_length_m: float) -> list[LineString]:
    """The pieces of a façade line between its corners (a turn of more than 50 degrees; a curve or
    a bay's 45-degree cheeks stay one piece), each at least ``min_length_m`` long."""
    if geometry.is_empty:
        return []
    merged = linemerge(geometry) if geometry.geom_type == "MultiLineString" else geometry
    pieces = []
    for line in getattr(merged, "geoms", [merged]):
        if line.geom_type != "LineString":
            continue
        coords = np.asarray(line.coords)
        start = 0
        for k in range(1, len(coords) - 1):
            d1, d2 = coords[k] - coords[k - 1], coords[k + 1] - coords[k]
            cos = float(d1 @ d2) / max(np.linalg.norm(d1) * np.linalg.norm(d2), 1e-12)
            if cos < math.cos(math.radians(50)):
                pieces.append(LineString(coords[start:k + 1]))
                start = k
        pieces.append(LineString(coords[start:]))
    return [p for p in pieces if p.length >= min_length_m]


def _place_along(rng: np.random.Generator, line: LineString, width_m: float, margin_m: float,
                 taken: list[tuple[float, float]], clear_m: float = 0.3) -> tuple[float, float] | None:
    """(start, end) distances along ``line`` of an opening of ``width_m``, ``margin_m`` from its ends
    and ``clear_m`` clear of the intervals in ``taken`` (which it joins)."""
    length = line.length
    lo, hi = margin_m + width_m / 2, length - margin_m - width_m / 2
    if hi < lo or width_m <= 0.3:
        return None
    for _ in range(12):
        centre = rng.uniform(lo, hi)
        interval = (centre - width_m / 2 - clear_m, centre + width_m / 2 + clear_m)
        if all(interval[1] < t0 or interval[0] > t1 for t0, t1 in taken):
            taken.append(interval)
            return centre - width_m / 2, centre + width_m / 2
    return None


def _window_on(piece: LineString, start_m: float, end_m: float, outline: Polygon, exterior_m: float,
               room: int) -> Window:
    """The window between ``start_m`` and ``end_m`` along the façade ``piece`` (the outer face)."""
    outer = shapely.ops.substring(piece, start_m, end_m)
    inner = None
    for sign in (1.0, -1.0):
        candidate = outer.offset_curve(sign * exterior_m, join_style="mitre")
        if candidate.geom_type == "LineString" and not candidate.is_empty and \
                outline.contains(candidate.interpolate(0.5, normalized=True)):
            inner = candidate
            break
    if inner is None:
        return Window(Polygon(), outer, outer, room, exterior_m)
    if np.linalg.norm(np.asarray(inner.coords[0]) - np.asarray(outer.coords[0])) > \
            np.linalg.norm(np.asarray(inner.coords[-1]) - np.asarray(outer.coords[0])):
        inner = LineString(np.asarray(inner.coords)[::-1])
    polygon = Polygon(list(outer.coords) + list(inner.coords)[::-1]).buffer(0)
    band = outline.difference(outline.buffer(-exterior_m, join_style="mitre"))
    polygon = polygon.intersection(band.buffer(0.001))
    if polygon.geom_type != "Polygon":
        parts = [g for g in getattr(polygon, "geoms", []) if g.geom_type == "Polygon"]
        polygon = max(parts, key=lambda g: g.area) if parts else Polygon()
    return Window(polygon, outer, inner, room, exterior_m)


def _terraces(rng, outline: Polygon, rooms: list[Room], outer_pieces, openings: list[Opening], ext_taken,
              exterior_m: float, margin_m: float) -> list[Polygon]:
    """One or two terraces or balconies on straight façades of living rooms, bedrooms and offices
    (in an L's or U's notch when there is one), each behind a door in the outer wall."""
    terraces = []
    hull_notch = outline.envelope.difference(outline.buffer(0.01))
    for rank in rng.permutation(len(outer_pieces)):
        if len(terraces) >= 1 + int(rng.random() < 0.3):
            break
        i, piece = outer_pieces[rank]
        if rooms[i].kind not in ("living", "bedroom", "office", "meeting", "kitchen") or len(piece.coords) != 2 \
                or piece.length < 2.5:
            continue
        p, q = (np.asarray(c) for c in piece.coords)
        d = (q - p) / piece.length
        n = np.array([-d[1], d[0]])
        mid = (p + q) / 2
        if outline.contains(Point(*(mid + n * 0.05))):
            n = -n  # outward
        width = rng.uniform(2.0, min(7.0, piece.length))
        depth = rng.uniform(1.2, 3.0)
        s0 = rng.uniform(0.0, piece.length - width)
        a, b = p + d * s0, p + d * (s0 + width)
        terrace = Polygon([a, b, b + n * depth, a + n * depth])
        if not hull_notch.is_empty and hull_notch.intersection(terrace).area > 0.5 * terrace.area:
            terrace = terrace.intersection(hull_notch.buffer(0.01)).buffer(0)  # in the notch
        if terrace.is_empty or terrace.geom_type != "Polygon" or terrace.intersection(outline).area > 0.01 \
                or any(terrace.intersects(t.buffer(0.3)) for t in terraces):
            continue
        door_w = rng.uniform(0.8, min(2.4, width - 0.4))
        local: list = ext_taken.setdefault(rank, [])
        span = _place_along(rng, piece, door_w, margin_m, local)
        if span is None or not (s0 <= span[0] and span[1] <= s0 + width):
            if span is not None:
                local.remove((span[0] - 0.3, span[1] + 0.3))
            continue
        jambs = (np.asarray(piece.interpolate(span[0]).coords[0]), np.asarray(piece.interpolate(span[1]).coords[0]))
        kind = str(rng.choice(["swing", "sliding", "double"], p=[0.5, 0.3, 0.2])) if door_w >= 1.2 else "swing"
        openings.append(_exterior_opening(jambs, outline, exterior_m, kind, i, rng))
        terraces.append(terrace)
    return terraces


def _exterior_opening(jambs, outline: Polygon, exterior_m: float, kind: str, room: int,
                      rng: np.random.Generator) -> Opening:
    a, b = jambs
    d = (b - a) / np.linalg.norm(b - a)
    n = np.array([-d[1], d[0]])
    mid = (a + b) / 2
    if not outline.contains(Point(*(mid + n * 0.05))):
        n = -n
    return Opening(a, b, n, exterior_m, True, kind, (room, -1), 1 if rng.random() < 0.85 else -1,
                   bool(rng.random() < 0.5), 90.0 if rng.random() < 0.7 else float(rng.uniform(25, 60)))


def house_layout(exterior_m: float = 0.3, interior_m: float = 0.12, door_m: float = 0.9,
                 entrance: str = "swing", glazing: str = "single", terrace: bool = False) -> Layout:
    """A fixed small building for tests and pictures: 12 x 8 m, two rooms on a corridor, a door
    from each room to the corridor and from one room to the other, an entrance (``entrance``:
    swing, double or passage) at the corridor's end, two windows (``glazing="run"``: the rooms'
    whole façade glazed, panes between thin piers; ``"bay"``: a glazed curved bay on each room
    besides), and with ``terrace`` a 5 x 2 m terrace behind a sliding door off the corridor."""
    outline = box(0, 0, 12, 8)
    if glazing == "bay":
        for x in (1.5, 7.5):
            disc = Point(x + 1.5, 1.2 - 1.9).buffer(1.9, quad_segs=32)
            outline = unary_union([outline, disc.intersection(box(x, -1.0, x + 3.0, 0.0)).buffer(1e-3)])
        outline = shapely.normalize(outline.buffer(0))
    rooms = [Room(box(0, 0, 6, 5), "office", "OFFICE 1"), Room(box(6, 0, 12, 5), "office", "OFFICE 2"),
             Room(box(0, 5, 12, 8), "corridor", "CORRIDOR")]
    inner = outline.buffer(-exterior_m, join_style="mitre")
    partitions = MultiLineString([[(6, 0), (6, 5)], [(0, 5), (12, 5)]]).buffer(
        interior_m / 2, cap_style="square", join_style="mitre").intersection(outline)
    walls = unary_union([outline.difference(inner), partitions])

    def interior(a, b, rooms_ab, hinge_at_a=True, side=1):
        a, b = np.array(a, float), np.array(b, float)
        d = (b - a) / np.linalg.norm(b - a)
        return Opening(a, b, np.array([-d[1], d[0]]), interior_m, False, "swing", rooms_ab, side, hinge_at_a, 90.0)

    openings = [interior((2.0, 5.0), (2.0 + door_m, 5.0), (0, 2)),
                interior((8.0, 5.0), (8.0 + door_m, 5.0), (1, 2), False),
                interior((6.0, 3.0), (6.0, 3.0 + door_m), (0, 1), True, -1)]
    width = {"swing": 1.0, "double": 1.6, "passage": 1.6}[entrance]
    openings.append(Opening(np.array([0.0, 6.5 - width / 2]), np.array([0.0, 6.5 + width / 2]), np.array([1.0, 0.0]),
                            exterior_m, True, entrance, (2, -1), 1, True, 90.0))
    windows = [Opening(np.array([2.0, 0.0]), np.array([4.0, 0.0]), np.array([0.0, 1.0]), exterior_m, True, "window",
                       (0, -1)),
               Opening(np.array([8.0, 0.0]), np.array([10.0, 0.0]), np.array([0.0, 1.0]), exterior_m, True, "window",
                       (1, -1))]
    if glazing == "run":
        face = LineString([(0.0, 0.0), (12.0, 0.0)])
        windows = [_window_on(face, s, s + 1.5, outline, exterior_m, 0 if s < 6 else 1)
                   for s in np.arange(0.6, 11.0, 1.65) if s + 1.5 <= 11.5 and not (5.5 < s + 1.5 and s < 6.5)]
    elif glazing == "bay":
        faces = _facade_pieces(LineString(outline.exterior.coords), 1.0)
        windows = [_window_on(f, 0.25, f.length - 0.25, outline, exterior_m, 0) for f in faces
                   if len(f.coords) > 3]  # the curved pieces
    inner = outline.buffer(-exterior_m, join_style="mitre")
    partitions = MultiLineString([[(6, 0), (6, 5)], [(0, 5), (12, 5)]]).buffer(
        interior_m / 2, cap_style="square", join_style="mitre").intersection(outline)
    walls = unary_union([outline.difference(inner), partitions])
    if glazing == "bay":
        rooms[0].polygon = shapely.normalize(unary_union([rooms[0].polygon, outline.intersection(box(0, -2, 6, 0))]))
        rooms[1].polygon = shapely.normalize(unary_union([rooms[1].polygon, outline.intersection(box(6, -2, 12, 0))]))
    terraces = []
    if terrace:
        terraces = [box(3.0, 8.0, 8.0, 10.0)]
        openings.append(Opening(np.array([4.5, 8.0]), np.array([6.3, 8.0]), np.array([0.0, -1.0]), exterior_m, True,
                                "sliding", (2, -1)))
    walls = walls.difference(unary_union([o.cut() for o in openings] + [w.cut(0.0) for w in windows]))
    return Layout(outline, rooms, walls, windows, openings, [], exterior_m, interior_m, terraces,
                  {"outline": "rect" if glazing != "bay" else "bay", "bay": glazing == "bay",
                   "window_run": glazing == "run", "terrace": terrace})


def plain_style(wall: str = "solid", paper: str = "white", px_per_m: float = 50.0, **changes) -> Style:
    """A drawing style with nothing but walls, doors and windows (each feature switched on by
    ``changes``): 50 px per metre, thin lines 1 px, heavy 2.5 px, black ink on white paper."""
    base = Style(wall=wall, paper=paper, px_per_m=px_per_m, thin_px=1.0, heavy_px=2.5, wall_level=0,
                 wall_outline=False, wall_fill_level=255, hatch_spacing_px=4.0, cross_hatch=False, ink_level=0,
                 leaf_as_rect=False, dashed_arcs=False, furniture=False, furniture_fill=255, room_names=False,
                 room_areas=False, bold_names=False, dimensions=False, interior_dimensions=False, axes=False,
                 title_block=False, north_arrow=False, scale_bar=False, tiles=False, colour=False, jpeg_quality=0,
                 blur_sigma_px=0.0, noise_sigma=0.0, skew_deg=0.0, dark_edge_px=0)
    return dataclasses.replace(base, **changes)


# ---- drawing ----------------------------------------------------------------------------------
@dataclasses.dataclass
class Style:
    """How a layout is drawn (all randomly chosen by :func:`random_style`)."""

    wall: str
    paper: str
    px_per_m: float
    thin_px: float  # annotation line weight
    heavy_px: float  # wall outline weight
    wall_level: int  # grey level of solid walls
    wall_outline: bool
    wall_fill_level: int  # double-line walls: band fill (255 = none)
    hatch_spacing_px: float
    cross_hatch: bool
    ink_level: int  # text and lines
    leaf_as_rect: bool
    dashed_arcs: bool
    furniture: bool
    furniture_fill: int  # 255 = none
    room_names: bool
    room_areas: bool
    bold_names: bool
    dimensions: bool
    interior_dimensions: bool
    axes: bool
    title_block: bool
    north_arrow: bool
    scale_bar: bool
    tiles: bool
    colour: bool
    jpeg_quality: int  # 0 = PNG
    blur_sigma_px: float
    noise_sigma: float
    skew_deg: float
    dark_edge_px: int


def random_style(rng: np.random.Generator, sheet_m: tuple[float, float], wall: str | None = None,
                 paper: str | None = None, megapixels: float | None = None) -> Style:
    """A drawing style for a sheet of ``sheet_m`` (width, height) metres: the image's size (0.2 to 9
    megapixels, log-uniform: from a web page's real-estate plan to an architect's scan), a print
    scale and the scan resolution it implies, pen widths in pixels from them."""
    wall = wall or str(rng.choice(WALL_STYLES))
    paper = paper or str(rng.choice(PAPER_STYLES))
    drawn = float(np.exp(rng.uniform(np.log(MEGAPIXELS[0]), np.log(MEGAPIXELS[1]))))
    megapixels = drawn if megapixels is None else megapixels
    px_per_m = math.sqrt(megapixels * 1e6 / (sheet_m[0] * sheet_m[1]))
    # the print scale whose scan resolution is nearest 200 dpi
    scale = min((50, 100, 200), key=lambda s: abs(math.log(px_per_m * s / 1000 * 25.4 / 200)))
    dpi = px_per_m * scale / 1000 * 25.4
    px_per_mm_paper = dpi / 25.4
    # pens as drafters choose them: finer at smaller scales
    pen_mm = rng.uniform(0.13, 0.25) if scale < 150 else rng.uniform(0.1, 0.18)
    thin_px = max(0.8, pen_mm * px_per_mm_paper)
    heavy_px = max(thin_px * rng.uniform(1.8, 3.0), 1.8)
    roll = rng.random()
    wall_level = int(rng.uniform(0, 40) if roll < 0.5 else rng.uniform(60, 110) if roll < 0.75 else rng.uniform(120, 170))
    scan = paper == "scan"
    return Style(
        wall=wall, paper=paper, px_per_m=px_per_m, thin_px=thin_px, heavy_px=heavy_px, wall_level=wall_level,
        wall_outline=bool(rng.random() < 0.5 or wall_level > 110),
        wall_fill_level=255 if rng.random() < 0.7 else int(rng.uniform(200, 235)),
        hatch_spacing_px=max(3.0, rng.uniform(0.04, 0.1) * px_per_m), cross_hatch=bool(rng.random() < 0.25),
        ink_level=int(rng.uniform(0, 30) if rng.random() < 0.8 else rng.uniform(60, 110)),
        leaf_as_rect=bool(rng.random() < 0.5), dashed_arcs=bool(rng.random() < 0.12),
        furniture=bool(rng.random() < 0.8), furniture_fill=255 if rng.random() < 0.7 else int(rng.uniform(205, 235)),
        room_names=bool(rng.random() < 0.9), room_areas=bool(rng.random() < 0.6), bold_names=bool(rng.random() < 0.3),
        dimensions=bool(rng.random() < 0.7), interior_dimensions=bool(rng.random() < 0.3), axes=bool(rng.random() < 0.35),
        title_block=bool(rng.random() < 0.6), north_arrow=bool(rng.random() < 0.3), scale_bar=bool(rng.random() < 0.3),
        tiles=bool(rng.random() < 0.2), colour=bool(rng.random() < 0.35),
        jpeg_quality=int(rng.uniform(35, 92)) if rng.random() < (0.7 if paper in ("uneven", "scan") else 0.4) else 0,
        blur_sigma_px=float(rng.uniform(0.5, 1.2) if scan else rng.uniform(0.0, 0.7)),
        noise_sigma=float(rng.uniform(3, 8) if scan else rng.uniform(0, 4) if paper != "white" else 0.0),
        skew_deg=float(rng.uniform(-0.8, 0.8)) if scan and rng.random() < 0.4 else 0.0,
        dark_edge_px=int(rng.uniform(3, 15)) if scan and rng.random() < 0.3 else 0,
    )


class Canvas:
    """A grey canvas (255 = paper) in metres: shapes are drawn darker-wins at ``SUPERSAMPLE`` times
    the final size."""

    def __init__(self, size_px: tuple[int, int], px_per_m: float, origin_m: tuple[float, float]):
        self.k = SUPERSAMPLE
        self.rows, self.cols = size_px[1] * self.k, size_px[0] * self.k
        self.scale = px_per_m * self.k
        self.origin = np.asarray(origin_m, dtype=float)
        self.image = np.full((self.rows, self.cols), 255, dtype=np.uint8)

    def px(self, xy_m) -> np.ndarray:
        return (np.asarray(xy_m, dtype=float) - self.origin) * self.scale

    def _composite(self, layer: np.ndarray, r0: int, c0: int, level: int) -> None:
        r1, c1 = r0 + layer.shape[0], c0 + layer.shape[1]
        rr0, cc0, rr1, cc1 = max(r0, 0), max(c0, 0), min(r1, self.rows), min(c1, self.cols)
        if rr1 <= rr0 or cc1 <= cc0:
            return
        cover = layer[rr0 - r0:rr1 - r0, cc0 - c0:cc1 - c0].astype(np.uint16)
        shade = (255 - (cover * (255 - level) + 127) // 255).astype(np.uint8)
        target = self.image[rr0:rr1, cc0:cc1]
        np.minimum(target, shade, out=target)

    def _layer(self, coords_px: list[np.ndarray], pad: float):
        allpts = np.concatenate(coords_px)
        c0, r0 = np.floor(allpts.min(axis=0) - pad).astype(int)
        c1, r1 = np.ceil(allpts.max(axis=0) + pad).astype(int)
        c0, r0 = max(c0, -1), max(r0, -1)
        c1, r1 = min(c1, self.cols + 1), min(r1, self.rows + 1)
        if c1 <= c0 or r1 <= r0:
            return None, 0, 0
        return np.zeros((r1 - r0, c1 - c0), dtype=np.uint8), r0, c0

    def fill(self, geometry: shapely.Geometry, level: int) -> None:
        """Fill polygons (holes stay unfilled)."""
        for polygon in getattr(geometry, "geoms", [geometry]):
            if polygon.geom_type != "Polygon" or polygon.is_empty:
                continue
            rings = [self.px(np.asarray(r.coords)[:, :2]) for r in [polygon.exterior, *polygon.interiors]]
            layer, r0, c0 = self._layer(rings, 2)
            if layer is None:
                continue
            pts = [np.round((ring - [c0, r0]) * 16).astype(np.int32) for ring in rings]
            cv2.fillPoly(layer, pts, 255, lineType=cv2.LINE_AA, shift=4)
            self._composite(layer, r0, c0, level)

    def stroke(self, geometry: shapely.Geometry, width_px: float, level: int, dash_m: tuple[float, ...] | None = None,
               closed: bool = True) -> None:
        """Draw lines (a polygon's rings) ``width_px`` final pixels wide; ``dash_m`` (on, off, ...)
        dashes them."""
        lines = []
        for g in getattr(geometry, "geoms", [geometry]):
            if g.is_empty:
                continue
            if g.geom_type == "Polygon":
                lines += [g.exterior, *g.interiors]
            elif g.geom_type in ("LineString", "LinearRing"):
                lines.append(g)
            elif g.geom_type == "MultiLineString":
                lines += list(g.geoms)
        if dash_m:
            dashed = []
            for line in lines:
                s, k, length = 0.0, 0, line.length
                while s < length:
                    step = dash_m[k % len(dash_m)]
                    if k % 2 == 0:
                        dashed.append(shapely.ops.substring(line, s, min(s + step, length)))
                    s += step
                    k += 1
            lines = [d for d in dashed if d.geom_type == "LineString" and d.length > 0]
        if not lines:
            return
        thickness = max(1, int(round(width_px * self.k)))
        coords = [self.px(np.asarray(line.coords)[:, :2]) for line in lines]
        layer, r0, c0 = self._layer(coords, thickness + 2)
        if layer is None:
            return
        pts = [np.round((c - [c0, r0]) * 16).astype(np.int32) for c in coords]
        cv2.polylines(layer, pts, False, 255, thickness=thickness, lineType=cv2.LINE_AA, shift=4)
        self._composite(layer, r0, c0, level)

    def hatch(self, geometry: shapely.Geometry, spacing_px: float, width_px: float, level: int,
              angles_deg: tuple[float, ...]) -> None:
        """Parallel lines ``spacing_px`` apart at each of ``angles_deg``, inside the polygons only."""
        polygons = [g for g in getattr(geometry, "geoms", [geometry]) if g.geom_type == "Polygon" and not g.is_empty]
        if not polygons:
            return
        rings = [self.px(np.asarray(r.coords)[:, :2]) for g in polygons for r in [g.exterior, *g.interiors]]
        inside, r0, c0 = self._layer(rings, 2)
        if inside is None:
            return
        for g in polygons:
            pts = [np.round((self.px(np.asarray(r.coords)[:, :2]) - [c0, r0]) * 16).astype(np.int32)
                   for r in [g.exterior, *g.interiors]]
            cv2.fillPoly(inside, pts, 255, lineType=cv2.LINE_8, shift=4)
        lines = np.zeros_like(inside)
        rows, cols = lines.shape
        step = spacing_px * self.k
        thickness = max(1, int(round(width_px * self.k)))
        for angle in angles_deg:
            direction = np.array([math.cos(math.radians(angle)), math.sin(math.radians(angle))])
            normal = np.array([-direction[1], direction[0]])
            reach = rows + cols
            offsets = normal @ np.array([[0, cols, 0, cols], [0, 0, rows, rows]])
            for t in np.arange(offsets.min(), offsets.max() + step, step):
                p0, p1 = normal * t - direction * reach, normal * t + direction * reach
                cv2.line(lines, tuple(np.round(p0 * 16).astype(int)), tuple(np.round(p1 * 16).astype(int)), 255,
                         thickness, cv2.LINE_AA, shift=4)
        self._composite(np.minimum(lines, inside), r0, c0, level)

    def text(self, text: str, centre_m, height_m: float, level: int, font: int, weight_px: float,
             angle_deg: float = 0.0, max_width_m: float | None = None) -> Polygon | None:
        """Text centred at ``centre_m``, ``height_m`` tall (capital height, smaller if it would be wider
        than ``max_width_m``), turned by ``angle_deg``; returns its box in metres (None when nothing
        was drawn)."""
        if not text:
            return None
        height_px = height_m * self.scale
        base = cv2.getTextSize("H", font, 1.0, 1)[0][1]
        font_scale = height_px / max(base, 1)
        thickness = max(1, int(round(weight_px * self.k)))
        (tw, th), baseline = cv2.getTextSize(text, font, font_scale, thickness)
        if max_width_m is not None and tw > max_width_m * self.scale:
            shrink = max_width_m * self.scale / tw
            if shrink * height_m < 0.08:  # too small to print: no label
                return None
            font_scale *= shrink
            thickness = max(1, int(round(thickness * shrink)))
            (tw, th), baseline = cv2.getTextSize(text, font, font_scale, thickness)
        pad = thickness + 2
        patch = np.zeros((th + baseline + 2 * pad, tw + 2 * pad), dtype=np.uint8)
        cv2.putText(patch, text, (pad, pad + th), font, font_scale, 255, thickness, cv2.LINE_AA)
        if angle_deg:
            h, w = patch.shape
            rot = cv2.getRotationMatrix2D((w / 2, h / 2), angle_deg, 1.0)
            cos, sin = abs(rot[0, 0]), abs(rot[0, 1])
            nw, nh = int(h * sin + w * cos) + 2, int(h * cos + w * sin) + 2
            rot[0, 2] += nw / 2 - w / 2
            rot[1, 2] += nh / 2 - h / 2
            patch = cv2.warpAffine(patch, rot, (nw, nh), flags=cv2.INTER_LINEAR)
        cx, cy = self.px(centre_m)
        r0, c0 = int(round(cy - patch.shape[0] / 2)), int(round(cx - patch.shape[1] / 2))
        self._composite(patch, r0, c0, level)
        half_w, half_h = patch.shape[1] / 2 / self.scale, patch.shape[0] / 2 / self.scale
        x, y = centre_m
        return box(x - half_w, y - half_h, x + half_w, y + half_h)


def _between(outer: LineString, inner: LineString, share: float) -> LineString:
    """The line ``share`` of the way from ``outer`` to ``inner`` (same number of points or resampled)."""
    n = max(len(outer.coords), len(inner.coords), 2)
    steps = np.linspace(0.0, 1.0, n)
    po = np.array([outer.interpolate(t, normalized=True).coords[0] for t in steps])
    pi = np.array([inner.interpolate(t, normalized=True).coords[0] for t in steps])
    return LineString(po + share * (pi - po))


def _arc(centre: np.ndarray, radius: float, start_rad: float, sweep_rad: float, n: int = 24) -> LineString:
    angles = start_rad + np.linspace(0.0, sweep_rad, n)
    return LineString(np.stack([centre[0] + radius * np.cos(angles), centre[1] + radius * np.sin(angles)], axis=1))


def _rotate(v: np.ndarray, angle_rad: float) -> np.ndarray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def _door_symbols(opening: Opening, style: Style) -> tuple[list, list, Polygon]:
    """(leaves as geometries, arcs, the swept area) of a door; nothing for a passage."""
    leaves, arcs = [], []
    side = opening.swing_side
    fa, fb = opening.face_points(side)
    swept = Polygon()
    if opening.kind in ("swing", "double"):
        hinges = [(fa, fb), (fb, fa)] if opening.kind == "double" else [((fa, fb) if opening.hinge_at_a else (fb, fa))]
        sweeps = []
        for hinge, other in hinges:
            if opening.kind == "double":
                other = (fa + fb) / 2
            radius = float(np.linalg.norm(other - hinge))
            towards = (other - hinge) / radius
            normal = opening.inward * side
            # the leaf turns from the closed position (along the opening) towards the swing side
            angle = math.radians(opening.leaf_angle_deg)
            sign = 1.0 if towards[0] * normal[1] - towards[1] * normal[0] > 0 else -1.0
            leaf_dir = _rotate(towards, sign * angle)
            tip = hinge + leaf_dir * radius
            start = math.atan2(towards[1], towards[0])
            arcs.append(_arc(hinge, radius, start, sign * angle))
            if style.leaf_as_rect:
                thick = 0.04
                perp = np.array([-leaf_dir[1], leaf_dir[0]]) * (-sign)
                leaves.append(Polygon([hinge, tip, tip + perp * thick, hinge + perp * thick]))
            else:
                leaves.append(LineString([hinge, tip]))
            sector = Polygon([hinge, *np.asarray(_arc(hinge, radius * 1.05, start, sign * angle).coords)])
            sweeps.append(sector.buffer(0))
        swept = unary_union(sweeps)
    elif opening.kind == "sliding":
        d = (opening.b - opening.a) / opening.width_m
        centre_offset = opening.face_points(1)[0] * 0 + (opening.a + opening.b) / 2
        if opening.exterior:
            centre_offset = centre_offset + opening.inward * opening.thickness_m / 2
        thick = min(0.04, opening.thickness_m / 4)
        half = opening.width_m / 2 + 0.06
        for k, shift in enumerate((-1, 1)):
            across = opening.inward * shift * thick * 0.6
            start = centre_offset - d * opening.width_m / 2 + (d * (half - 0.12) if k else 0)
            p0 = start + across
            p1 = p0 + d * half
            n = opening.inward * thick / 2
            leaves.append(Polygon([p0 - n, p1 - n, p1 + n, p0 + n]))
    return leaves, arcs, swept


def _furniture_for(kind: str, rng: np.random.Generator) -> list[tuple[str, float, float]]:
    """(piece, width, depth) of the furniture a room of ``kind`` gets (placed against its walls)."""
    u = rng.uniform
    table = {
        "bedroom": [("bed", u(1.4, 1.8) if rng.random() < 0.6 else 0.9, 2.0), ("nightstand", 0.45, 0.4),
                    ("wardrobe", u(1.0, 2.4), 0.6), ("desk", 1.2, 0.6)],
        "living": [("sofa", u(1.8, 2.6), 0.9), ("table_round", 1.1, 1.1), ("tv", u(1.2, 1.8), 0.45),
                   ("armchair", 0.8, 0.8), ("dining", u(1.4, 1.9), 0.9), ("plant", 0.5, 0.5)],
        "kitchen": [("counter", u(1.8, 3.6), 0.6), ("fridge", 0.6, 0.65), ("dining", u(1.0, 1.4), 0.8)],
        "bath": [("bathtub", 0.75, u(1.6, 1.8)) if rng.random() < 0.6 else ("shower", 0.9, 0.9),
                 ("toilet", 0.4, 0.65), ("basin", 0.55, 0.45)],
        "wc": [("toilet", 0.4, 0.65), ("basin", 0.45, 0.35)],
        "office": [("desk", u(1.4, 1.6), 0.75), ("desk", u(1.4, 1.6), 0.75), ("shelf", u(1.0, 2.0), 0.4),
                   ("plant", 0.5, 0.5)],
        "meeting": [("meeting_table", u(2.4, 4.0), u(1.0, 1.4)), ("shelf", u(1.0, 2.0), 0.4)],
        "store": [("shelf", u(1.0, 2.0), 0.5)],
        "hall": [("wardrobe", u(0.8, 1.6), 0.5), ("plant", 0.45, 0.45)],
        "corridor": [("plant", 0.5, 0.5)] if rng.random() < 0.3 else [],
    }
    return table.get(kind, [])


def _piece_geometry(piece: str, w: float, d: float, rng: np.random.Generator) -> tuple[list, Polygon]:
    """The lines of a furniture piece in local metres (x along the wall, y into the room from the
    wall at y = 0) and its outline."""
    outline = box(0, 0, w, d)
    lines: list = []
    if piece == "bed":
        lines = [outline, box(0.08, 0.06, w / 2 - 0.04 if w > 1.2 else w - 0.08, 0.45),
                 LineString([(0, 0.75), (w, 0.6)])]
        if w > 1.2:
            lines.append(box(w / 2 + 0.04, 0.06, w - 0.08, 0.45))
    elif piece == "nightstand":
        lines = [outline, Point(w / 2, d / 2).buffer(0.1)]
    elif piece == "wardrobe":
        lines = [outline, LineString([(0, d / 2), (w, d / 2)])]
        if rng.random() < 0.5:
            lines += [LineString([(x, d / 2 - 0.12), (x + 0.1, d / 2 + 0.12)]) for x in np.arange(0.15, w - 0.1, 0.25)]
    elif piece == "sofa":
        lines = [outline, box(0.2, 0.25, w - 0.2, d), LineString([(0.2, 0.25), (0.2, d)]),
                 LineString([(w / 2, 0.25), (w / 2, d)])]
    elif piece == "armchair":
        lines = [outline, box(0.15, 0.2, w - 0.15, d)]
    elif piece in ("table_round", "plant"):
        circle = Point(w / 2, d / 2).buffer(min(w, d) / 2 - 0.05, quad_segs=12)
        lines = [circle]
        outline = circle
        if piece == "plant":
            c = np.array([w / 2, d / 2])
            lines += [LineString([c, c + 0.2 * np.array([math.cos(a), math.sin(a)])]) for a in np.arange(0, 6.28, 0.9)]
        else:
            for a in np.arange(0, 6.28, 6.28 / 4):
                p = np.array([w / 2, d / 2]) + (min(w, d) / 2 + 0.05) * np.array([math.cos(a), math.sin(a)])
                lines.append(box(p[0] - 0.2, p[1] - 0.2, p[0] + 0.2, p[1] + 0.2))
    elif piece == "tv":
        lines = [outline, box(0.2, 0.1, w - 0.2, 0.2)]
    elif piece in ("dining", "meeting_table"):
        top = box(0, 0.5, w, 0.5 + d) if piece == "dining" else box(0, 0.5, w, 0.5 + d)
        if piece == "meeting_table" and rng.random() < 0.5:
            top = affinity.scale(Point(w / 2, 0.5 + d / 2).buffer(1.0, quad_segs=16), w / 2, d / 2)
        lines = [top]
        for x in np.arange(0.3, w - 0.2, 0.6):
            lines += [box(x - 0.2, 0.1, x + 0.2, 0.45), box(x - 0.2, 0.55 + d, x + 0.2, 0.9 + d)]
        outline = box(0, 0, w, 1.0 + d)
    elif piece == "counter":
        lines = [outline, box(0.3, 0.1, 0.9, d - 0.1), affinity.scale(box(0.35, 0.15, 0.85, d - 0.15), 1, 1)]
        hob = w - 0.9
        if hob > 1.0:
            lines.append(box(hob, 0.05, hob + 0.6, d - 0.05))
            lines += [Point(hob + x, y).buffer(0.09, quad_segs=8) for x in (0.15, 0.45) for y in (0.15, 0.45)]
    elif piece == "fridge":
        lines = [outline, LineString([(0, 0), (w, d)]), LineString([(w, 0), (0, d)])]
    elif piece == "bathtub":
        inner = box(0.08, 0.08, w - 0.08, d - 0.08).buffer(0.06).buffer(-0.06)
        lines = [outline, inner, Point(w / 2, d - 0.25).buffer(0.04)]
    elif piece == "shower":
        lines = [outline, LineString([(0, 0), (w, d)]), LineString([(w, 0), (0, d)]), Point(w / 2, d / 2).buffer(0.05)]
    elif piece == "toilet":
        lines = [box(0, 0, w, 0.18), affinity.scale(Point(w / 2, 0.42).buffer(1.0, quad_segs=12), 0.18, 0.24)]
        outline = box(0, 0, w, d)
    elif piece == "basin":
        lines = [outline, affinity.scale(Point(w / 2, d / 2).buffer(1.0, quad_segs=12), w / 2 - 0.07, d / 2 - 0.07)]
    elif piece == "desk":
        lines = [outline, Point(w / 2, d + 0.3).buffer(0.25, quad_segs=10)]
        outline = box(0, 0, w, d + 0.55)
    elif piece == "shelf":
        lines = [outline] + [LineString([(x, 0), (x, d)]) for x in np.arange(0.4, w - 0.1, 0.4)]
    return lines, outline


def _place_furniture(rng: np.random.Generator, room: Room, free: shapely.Geometry, blocked: shapely.Geometry,
                     pieces: list[tuple[str, float, float]]) -> list[tuple[list, Polygon]]:
    """Pieces placed against the room's walls (or free-standing), inside ``free``, clear of ``blocked``."""
    placed = []
    if free.is_empty:
        return placed
    x0, y0, x1, y1 = free.bounds
    for piece, w, d in pieces:
        lines, outline = _piece_geometry(piece, w, d, rng)
        for _ in range(25):
            side = rng.integers(4)
            angle = [0, 90, 180, 270][side]
            shape = affinity.rotate(outline, angle, origin=(0, 0))
            bx0, by0, bx1, by1 = shape.bounds
            if piece in ("table_round", "meeting_table", "dining") and rng.random() < 0.6:
                tx = rng.uniform(x0 - bx0, max(x0 - bx0, x1 - bx1)) if x1 - x0 > bx1 - bx0 else None
                ty = rng.uniform(y0 - by0, max(y0 - by0, y1 - by1)) if y1 - y0 > by1 - by0 else None
            else:
                # against the wall of that side: y = 0 of the piece on the wall
                gap = 0.0  # touching the wall ("free" is the room less the walls)
                if side == 0:  # wall at the top (small y), piece grows down
                    tx, ty = rng.uniform(x0 - bx0, max(x0 - bx0, x1 - bx1)), y0 + gap - by0
                elif side == 1:  # rotated 90: the piece grows to -x; wall on the right
                    tx, ty = x1 - gap - bx1, rng.uniform(y0 - by0, max(y0 - by0, y1 - by1))
                elif side == 2:
                    tx, ty = rng.uniform(x0 - bx0, max(x0 - bx0, x1 - bx1)), y1 - gap - by1
                else:
                    tx, ty = x0 + gap - bx0, rng.uniform(y0 - by0, max(y0 - by0, y1 - by1))
            if tx is None or ty is None:
                continue
            moved = affinity.translate(shape, tx, ty)
            if free.contains(moved) and not moved.intersects(blocked):
                placed.append(([affinity.translate(affinity.rotate(g, angle, origin=(0, 0)), tx, ty) for g in lines],
                               moved))
                blocked = blocked.union(moved.buffer(0.15))
                break
    return placed


def _format_length(length_m: float, rng_style: int) -> str:
    if rng_style == 0:
        return f"{length_m:.2f}"
    if rng_style == 1:
        return f"{round(length_m * 1000):d}"
    return f"{round(length_m * 100):d}"


@dataclasses.dataclass
class GeneratedPlan:
    """A drawn plan and its truth on the same pixel grid."""

    image: np.ndarray  # uint8, grey (rows, cols) or BGR (rows, cols, 3)
    walls: np.ndarray  # bool: walls, windows, columns
    free: np.ndarray  # bool: inside the building and not wall
    rooms: np.ndarray  # uint16 labels: room i + 1 on its free pixels, 0 elsewhere
    room_info: list[dict]
    resolution_m: float
    style: Style
    n_doors: int
    jpeg: bytes | None = None  # the JPEG file's bytes when the plan is a JPEG (``image`` is them decoded)
    features: dict = dataclasses.field(default_factory=dict)  # the layout's outline shape, bays, runs, terraces
    origin_m: tuple[float, float] = (0.0, 0.0)  # the layout's metres at the image's top-left corner


def draw_plan(rng: np.random.Generator, layout: Layout, wall: str | None = None, paper: str | None = None,
              style: Style | None = None, megapixels: float | None = None) -> GeneratedPlan:
    """Draw ``layout`` in a random style (``wall``, ``paper`` and the sheet's ``megapixels`` before
    its title block fix those; ``style`` all of it) with its truth."""
    bx0, by0, bx1, by1 = layout.footprint.bounds
    margin_dim = rng.uniform(2.2, 4.5)
    left, top, right, bottom = (margin_dim + rng.uniform(0, 1.5) for _ in range(4))
    title_h = 0.0
    sheet_w = (bx1 - bx0) + left + right
    sheet_h = (by1 - by0) + top + bottom
    style0 = style if style is not None else random_style(rng, (sheet_w, sheet_h), wall, paper, megapixels)
    if style0.title_block:
        title_h = max(2.5, 0.14 * sheet_h)
        sheet_h += title_h
    style = style0
    ppm = style.px_per_m
    size_px = (int(math.ceil(sheet_w * ppm)), int(math.ceil(sheet_h * ppm)))
    origin = (bx0 - left, by0 - top)
    canvas = Canvas(size_px, ppm, origin)
    thin, heavy, ink = style.thin_px, style.heavy_px, style.ink_level
    medium = (thin + heavy) / 2

    # ---- walls
    solid_walls = unary_union([layout.walls, *layout.columns])
    window_cuts = [w.cut(0.0) for w in layout.windows]
    thin_faces = style.wall == "solid" or rng.random() < 0.5  # else the windows' faces are the walls' heavy lines
    if style.wall == "solid":
        canvas.fill(layout.walls, style.wall_level)
        if style.wall_outline:
            canvas.stroke(layout.walls, medium, min(ink, style.wall_level))
    else:
        band = unary_union([layout.walls, *([] if thin_faces else window_cuts)])
        if style.wall_fill_level < 255:
            canvas.fill(layout.walls, style.wall_fill_level)
        if style.wall == "hatched":
            angles = (45.0, 135.0) if style.cross_hatch else (45.0,)
            canvas.hatch(layout.walls, style.hatch_spacing_px, thin, ink, angles)
        canvas.stroke(band, heavy, ink)
    for column in layout.columns:
        canvas.fill(column, min(style.wall_level, 60))
        canvas.stroke(column, medium, ink)
    # windows: lines along the opening (faces and glass: double or triple thin lines) and the jambs
    for window in layout.windows:
        if isinstance(window, Opening):
            t = window.thickness_m
            outer = LineString([window.a, window.b])
            inner = LineString([window.a + window.inward * t, window.b + window.inward * t])
        else:
            outer, inner = window.outer, window.inner
        lines = [outer, inner] if thin_faces else []
        glass = [0.45, 0.55] if rng.random() < 0.5 else [0.5] if rng.random() < 0.6 else []
        lines += [_between(outer, inner, f) for f in glass]
        for line in lines:
            canvas.stroke(line, thin, ink)
        if thin_faces:
            for end in (0, -1):
                canvas.stroke(LineString([outer.coords[end], inner.coords[end]]), thin, ink)
    # terraces and balconies: rails (thin, doubled or dashed), sometimes paved
    for terrace in layout.terraces:
        rail = terrace.boundary.difference(layout.footprint.buffer(0.02))
        roll = rng.random()
        if roll < 0.4:
            canvas.stroke(rail, thin, ink)
        elif roll < 0.7:
            canvas.stroke(rail, thin, ink)
            canvas.stroke(terrace.buffer(-0.06, join_style="mitre").boundary.difference(layout.footprint.buffer(0.08)),
                          thin, ink)
        else:
            canvas.stroke(rail, thin, ink, dash_m=(0.2, 0.1))
        if rng.random() < 0.4:
            x0, y0, x1, y1 = terrace.bounds
            step = rng.uniform(0.3, 0.6)
            grid = [LineString([(x, y0), (x, y1)]) for x in np.arange(x0 + step, x1, step)]
            grid += [LineString([(x0, y), (x1, y)]) for y in np.arange(y0 + step, y1, step)]
            canvas.stroke(MultiLineString(grid).intersection(terrace.buffer(-0.08)), thin * 0.8, min(255, ink + 120))

    # ---- doors
    swept_all = []
    for opening in layout.openings:
        leaves, arcs, swept = _door_symbols(opening, style)
        for leaf in leaves:
            if leaf.geom_type == "Polygon":
                canvas.fill(leaf, 255 if opening.kind == "sliding" else 245)
            canvas.stroke(leaf, medium if opening.kind != "sliding" else thin, ink)
        for arc in arcs:
            canvas.stroke(arc, thin, ink, dash_m=(0.08, 0.05) if style.dashed_arcs else None)
        if opening.kind == "passage" and rng.random() < 0.3:
            for side in (-1, 1):
                fa, fb = opening.face_points(side)
                canvas.stroke(LineString([fa, fb]), thin, ink, dash_m=(0.12, 0.06))
        if not swept.is_empty:
            swept_all.append(swept)
        swept_all.append(opening.cut(0.0).buffer(0.7))

    # ---- room contents
    inner_free = layout.footprint.difference(layout.solid.buffer(0.02))
    blocked = unary_union(swept_all) if swept_all else Polygon()
    text_boxes = []
    for room in layout.rooms:
        free = room.polygon.intersection(inner_free).buffer(-0.05)
        if free.is_empty:
            continue
        if room.kind == "shaft":
            rb = room.polygon.buffer(-layout.interior_m / 2)
            if not rb.is_empty:
                x0, y0, x1, y1 = rb.bounds
                canvas.stroke(MultiLineString([[(x0, y0), (x1, y1)], [(x1, y0), (x0, y1)]]), thin, ink)
            continue
        if room.kind == "stairs":
            x0, y0, x1, y1 = free.bounds
            horizontal = (x1 - x0) >= (y1 - y0)
            tread = rng.uniform(0.25, 0.3)
            treads = []
            if horizontal:
                treads = [LineString([(x, y0), (x, y1)]) for x in np.arange(x0 + 0.3, x1 - 0.2, tread)]
                arrow = LineString([(x0 + 0.3, (y0 + y1) / 2), (x1 - 0.4, (y0 + y1) / 2)])
            else:
                treads = [LineString([(x0, y), (x1, y)]) for y in np.arange(y0 + 0.3, y1 - 0.2, tread)]
                arrow = LineString([((x0 + x1) / 2, y0 + 0.3), ((x0 + x1) / 2, y1 - 0.4)])
            canvas.stroke(MultiLineString(treads).intersection(free), thin, ink)
            canvas.stroke(arrow, thin, ink)
        if style.tiles and room.kind in ("bath", "wc", "kitchen"):
            x0, y0, x1, y1 = free.bounds
            step = rng.uniform(0.2, 0.35)
            grid = [LineString([(x, y0), (x, y1)]) for x in np.arange(x0, x1, step)]
            grid += [LineString([(x0, y), (x1, y)]) for y in np.arange(y0, y1, step)]
            canvas.stroke(MultiLineString(grid).intersection(room.polygon.intersection(inner_free)), thin * 0.8,
                          min(255, ink + 110))
        if style.furniture:
            # pieces stand against the walls' faces, touching them
            against = room.polygon.intersection(layout.footprint.difference(layout.solid)).buffer(-0.003)
            for lines, outline in _place_furniture(rng, room, against, blocked, _furniture_for(room.kind, rng)):
                if style.furniture_fill < 255:
                    canvas.fill(outline, style.furniture_fill)
                for g in lines:
                    canvas.stroke(g, thin, ink)
        # the label: name and area
        if style.room_names and room.name:
            point = free.representative_point() if not free.centroid.within(free) else free.centroid
            x0, y0, x1, y1 = free.bounds
            height = rng.uniform(0.16, 0.4)
            angle = 90.0 if (y1 - y0) > 1.6 * (x1 - x0) and rng.random() < 0.5 else 0.0
            font = FONTS[rng.integers(len(FONTS))]
            weight = max(thin, height * ppm * (0.16 if style.bold_names else 0.08))
            room_w = (x1 - x0) if angle == 0 else (y1 - y0)
            box_m = canvas.text(room.name, (point.x, point.y), height, ink, font, weight, angle, 0.85 * room_w)
            if box_m is not None:
                text_boxes.append(box_m)
            if style.room_areas:
                area_text = f"{room.polygon.area:.1f} m2" if rng.random() < 0.6 else f"{room.polygon.area:.2f}"
                offset = np.array([0.0, height * 1.8]) if angle == 0 else np.array([height * 1.8, 0.0])
                canvas.text(area_text, (point.x + offset[0], point.y + offset[1]), height * 0.75, ink, font,
                            max(thin, height * ppm * 0.07), angle, 0.85 * room_w)

    # ---- annotations
    fmt = int(rng.integers(3))
    x0, y0, x1, y1 = layout.footprint.bounds
    if style.dimensions:
        text_h = rng.uniform(0.14, 0.3)
        tick_kind = rng.integers(3)
        xs = sorted({round(v, 3) for v in np.asarray(layout.footprint.exterior.coords)[:, 0]})
        ys = sorted({round(v, 3) for v in np.asarray(layout.footprint.exterior.coords)[:, 1]})
        xs_detail = sorted(set(xs) | {round(float(p), 3) for o in layout.openings + layout.windows
                                      if o.exterior for p in (o.a[0], o.b[0])})
        ys_detail = sorted(set(ys) | {round(float(p), 3) for o in layout.openings + layout.windows
                                      if o.exterior for p in (o.a[1], o.b[1])})
        sides = [s for s in range(4) if rng.random() < 0.75] or [0]
        for side in sides:
            levels = [rng.uniform(0.8, 1.4)] + ([rng.uniform(1.7, 2.2)] if rng.random() < 0.5 else [])
            for level, marks in zip(levels, [xs_detail if side in (0, 2) else ys_detail, xs if side in (0, 2) else ys]):
                marks = [m for m in marks]
                if len(marks) < 2:
                    continue
                if side in (0, 2):
                    y = y0 - level if side == 0 else y1 + level
                    canvas.stroke(LineString([(marks[0] - 0.3, y), (marks[-1] + 0.3, y)]), thin, ink)
                    for m in marks:
                        edge = y0 if side == 0 else y1
                        direction = -1 if side == 0 else 1
                        canvas.stroke(LineString([(m, edge + direction * 0.25), (m, y + direction * 0.15)]), thin, ink)
                        _tick(canvas, (m, y), tick_kind, thin, heavy, ink, 0.12)
                    for a, b in zip(marks[:-1], marks[1:]):
                        if b - a > 0.5:
                            canvas.text(_format_length(b - a, fmt), ((a + b) / 2, y - text_h * 0.9), text_h, ink,
                                        cv2.FONT_HERSHEY_SIMPLEX, thin)
                else:
                    x = x0 - level if side == 3 else x1 + level
                    canvas.stroke(LineString([(x, marks[0] - 0.3), (x, marks[-1] + 0.3)]), thin, ink)
                    for m in marks:
                        edge = x0 if side == 3 else x1
                        direction = -1 if side == 3 else 1
                        canvas.stroke(LineString([(edge + direction * 0.25, m), (x + direction * 0.15, m)]), thin, ink)
                        _tick(canvas, (x, m), tick_kind, thin, heavy, ink, 0.12)
                    for a, b in zip(marks[:-1], marks[1:]):
                        if b - a > 0.5:
                            canvas.text(_format_length(b - a, fmt), (x - text_h * 0.9, (a + b) / 2), text_h, ink,
                                        cv2.FONT_HERSHEY_SIMPLEX, thin, 90.0)
    if style.interior_dimensions:
        for room in layout.rooms:
            if room.kind in ("shaft", "corridor") or rng.random() < 0.5:
                continue
            rx0, ry0, rx1, ry1 = room.polygon.bounds
            t = layout.interior_m / 2
            y = ry0 + (ry1 - ry0) * rng.uniform(0.25, 0.75)
            line = LineString([(rx0 + t, y), (rx1 - t, y)]).intersection(inner_free.buffer(0.01))
            if line.is_empty or line.geom_type != "LineString":
                continue
            canvas.stroke(line, thin, ink)
            (ax, ay), (bx, by) = line.coords[0], line.coords[-1]
            _tick(canvas, (ax, ay), 0, thin, heavy, ink, 0.1)
            _tick(canvas, (bx, by), 0, thin, heavy, ink, 0.1)
            canvas.text(_format_length(bx - ax, fmt), ((ax + bx) / 2, y - 0.2), 0.16, ink, cv2.FONT_HERSHEY_SIMPLEX, thin)
    if style.axes:
        spacing = rng.uniform(3.5, 7.5)
        bubble = rng.uniform(0.3, 0.5)
        labels_x = "ABCDEFGHJKLMN"
        for k, x in enumerate(np.arange(x0 + rng.uniform(0, 1.0), x1 + 0.01, spacing)):
            end = y0 - rng.uniform(2.2, 3.2)
            canvas.stroke(LineString([(x, end + bubble), (x, y1 + 1.5)]), thin, ink, dash_m=(0.6, 0.12, 0.05, 0.12))
            canvas.stroke(Point(x, end).buffer(bubble, quad_segs=12), thin, ink)
            canvas.text(labels_x[k % len(labels_x)], (x, end), bubble * 0.9, ink, cv2.FONT_HERSHEY_SIMPLEX, thin)
        for k, y in enumerate(np.arange(y0 + rng.uniform(0, 1.0), y1 + 0.01, spacing)):
            end = x0 - rng.uniform(2.2, 3.2)
            canvas.stroke(LineString([(end + bubble, y), (x1 + 1.5, y)]), thin, ink, dash_m=(0.6, 0.12, 0.05, 0.12))
            canvas.stroke(Point(end, y).buffer(bubble, quad_segs=12), thin, ink)
            canvas.text(str(k + 1), (end, y), bubble * 0.9, ink, cv2.FONT_HERSHEY_SIMPLEX, thin)
    sx0, sy0 = origin
    sx1, sy1 = sx0 + size_px[0] / ppm, sy0 + size_px[1] / ppm
    if style.title_block:
        m = rng.uniform(0.15, 0.5)
        frame = box(sx0 + m, sy0 + m, sx1 - m, sy1 - m)
        canvas.stroke(frame, rng.uniform(thin, heavy * 1.3), ink)
        tw = (sx1 - sx0) * rng.uniform(0.3, 0.45)
        th = title_h * 0.85
        tb = box(sx1 - m - tw, sy1 - m - th, sx1 - m, sy1 - m)
        canvas.stroke(tb, medium, ink)
        rows_n = int(rng.integers(3, 5))
        for r in range(1, rows_n):
            yy = sy1 - m - th + th * r / rows_n
            canvas.stroke(LineString([(sx1 - m - tw, yy), (sx1 - m, yy)]), thin, ink)
        canvas.stroke(LineString([(sx1 - m - tw * 0.4, sy1 - m - th), (sx1 - m - tw * 0.4, sy1 - m)]), thin, ink)
        texts = ["PROJECT: " + str(rng.choice(["Residence", "Office building", "Block B", "Unit 4"])),
                 f"FLOOR PLAN  {int(rng.integers(0, 5))}", f"SCALE 1:{rng.choice([50, 100, 200])}",
                 f"DWG No. A-{int(rng.integers(100, 400))}", "DATE 2024-03-1" + str(int(rng.integers(0, 9)))]
        for r in range(rows_n):
            yy = sy1 - m - th + th * (r + 0.5) / rows_n
            canvas.text(texts[r % len(texts)], (sx1 - m - tw * 0.7, yy), th / rows_n * 0.35, ink,
                        FONTS[rng.integers(len(FONTS))], thin)
    if style.north_arrow:
        c = np.array([sx0 + 1.5, sy0 + 1.5]) if rng.random() < 0.5 else np.array([sx1 - 1.5, sy0 + 1.5])
        r = 0.6
        canvas.stroke(Point(*c).buffer(r, quad_segs=12), thin, ink)
        canvas.fill(Polygon([c + [0, -r], c + [0.2, 0.3], c + [0, 0.1]]), ink)
        canvas.stroke(Polygon([c + [0, -r], c + [-0.2, 0.3], c + [0, 0.1]]), thin, ink)
        canvas.text("N", c + [0, -r - 0.3], 0.25, ink, cv2.FONT_HERSHEY_SIMPLEX, thin)
    if style.scale_bar:
        start = np.array([sx0 + 1.0, sy1 - 1.0 - title_h * 0.2])
        for k in range(5):
            seg = box(start[0] + k, start[1], start[0] + k + 1, start[1] + 0.15)
            if k % 2 == 0:
                canvas.fill(seg, ink)
            canvas.stroke(seg, thin, ink)
            canvas.text(str(k), (start[0] + k, start[1] + 0.4), 0.18, ink, cv2.FONT_HERSHEY_SIMPLEX, thin)

    # ---- to pixels: area average, paper, blur, noise, skew, JPEG
    grey = cv2.resize(canvas.image, size_px, interpolation=cv2.INTER_AREA).astype(np.float32)
    rows, cols = grey.shape
    paper = _paper(rng, style.paper, (rows, cols))
    image = grey / 255.0 * paper
    if style.dark_edge_px:
        side = rng.integers(4)
        e = style.dark_edge_px
        shade = rng.uniform(20, 70)
        if side == 0:
            image[:e] = shade
        elif side == 1:
            image[-e:] = shade
        elif side == 2:
            image[:, :e] = shade
        else:
            image[:, -e:] = shade
    if style.blur_sigma_px > 0.05:
        image = cv2.GaussianBlur(image, (0, 0), style.blur_sigma_px)
    if style.noise_sigma > 0:
        image = image + rng.normal(0.0, style.noise_sigma, image.shape).astype(np.float32)
    if style.paper == "scan":
        # dust: a few dark specks
        for _ in range(int(rng.integers(5, 40))):
            r, c = rng.integers(rows), rng.integers(cols)
            cv2.circle(image, (int(c), int(r)), int(rng.integers(0, 2)), float(rng.uniform(40, 140)), -1)

    # truth on the same grid (pixel centres)
    truth_canvas = np.zeros((rows, cols), dtype=np.uint8)
    walls = _raster(layout.solid, (rows, cols), ppm, origin)
    footprint = _raster(layout.footprint, (rows, cols), ppm, origin)
    free = footprint & ~walls
    room_labels = np.zeros((rows, cols), dtype=np.uint16)
    info = []
    for index, room in enumerate(layout.rooms):
        mask = _raster(room.polygon, (rows, cols), ppm, origin) & free & (room_labels == 0)
        room_labels[mask] = index + 1
        info.append({"label": index + 1, "kind": room.kind, "name": room.name, "area_m2": round(room.polygon.area, 2)})
    del truth_canvas
    if style.skew_deg:
        rot = cv2.getRotationMatrix2D((cols / 2, rows / 2), style.skew_deg, 1.0)
        image = cv2.warpAffine(image, rot, (cols, rows), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        walls = cv2.warpAffine(walls.astype(np.uint8), rot, (cols, rows), flags=cv2.INTER_NEAREST,
                               borderValue=0).astype(bool)
        free = cv2.warpAffine(free.astype(np.uint8), rot, (cols, rows), flags=cv2.INTER_NEAREST,
                              borderValue=0).astype(bool)
        room_labels = cv2.warpAffine(room_labels, rot, (cols, rows), flags=cv2.INTER_NEAREST, borderValue=0)
    image = np.clip(image, 0, 255)
    if style.colour:
        tint = np.array([rng.uniform(0.86, 0.97), rng.uniform(0.93, 1.0), 1.0], dtype=np.float32)  # BGR: yellowish
        image = np.clip(image[..., None] * tint[None, None, :] + (255 - image[..., None]) * 0.0, 0, 255)
    image = image.round().astype(np.uint8)
    jpeg = None
    if style.jpeg_quality:
        ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, style.jpeg_quality])
        jpeg = data.tobytes()
        image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    return GeneratedPlan(image, walls, free, room_labels, info, 1.0 / ppm, style,
                         sum(o.kind in ("swing", "double", "sliding") for o in layout.openings), jpeg,
                         dict(layout.features), origin)


def _tick(canvas: Canvas, xy, kind: int, thin: float, heavy: float, ink: int, size_m: float) -> None:
    x, y = xy
    if kind == 0:
        canvas.stroke(LineString([(x - size_m, y + size_m), (x + size_m, y - size_m)]), heavy, ink)
    elif kind == 1:
        canvas.fill(Point(x, y).buffer(size_m * 0.4), ink)
    else:
        canvas.stroke(LineString([(x - size_m, y - size_m * 0.5), (x, y), (x - size_m, y + size_m * 0.5)]), thin, ink)


def _paper(rng: np.random.Generator, kind: str, shape: tuple[int, int]) -> np.ndarray:
    rows, cols = shape
    if kind == "white":
        return np.full(shape, rng.uniform(245, 255), dtype=np.float32)
    if kind == "grey":
        return np.full(shape, rng.uniform(195, 235), dtype=np.float32)
    base = rng.uniform(215, 250)
    yy, xx = np.mgrid[0:rows, 0:cols].astype(np.float32)
    angle = rng.uniform(0, 2 * math.pi)
    ramp = (math.cos(angle) * xx / cols + math.sin(angle) * yy / rows)
    paper = base + rng.uniform(15, 45) * (ramp - ramp.mean())
    coarse = rng.normal(0, 1, (6, 8)).astype(np.float32)
    blotches = cv2.resize(coarse, (cols, rows), interpolation=cv2.INTER_CUBIC)
    paper += rng.uniform(5, 18) * blotches
    if kind == "scan":
        # vignetting: darker towards one edge, as a flatbed's lid shadow
        paper -= rng.uniform(0, 30) * np.clip(1 - xx / (0.15 * cols), 0, 1) ** 2
    return np.clip(paper, 150, 255).astype(np.float32)


def _raster(geometry: shapely.Geometry, shape: tuple[int, int], px_per_m: float, origin) -> np.ndarray:
    """Pixels whose centre lies in ``geometry``."""
    out = np.zeros(shape, dtype=np.uint8)
    for polygon in getattr(geometry, "geoms", [geometry]):
        if polygon.geom_type != "Polygon" or polygon.is_empty:
            continue
        rings = [np.asarray(r.coords)[:, :2] for r in [polygon.exterior, *polygon.interiors]]
        # pixel centre (c + 0.5) covers metres origin + (c + 0.5) / ppm: shift by half a pixel
        pts = [np.round(((ring - origin) * px_per_m - 0.5) * 16).astype(np.int32) for ring in rings]
        cv2.fillPoly(out, pts, 1, lineType=cv2.LINE_8, shift=4)
    return out.astype(bool)


# ---- plans to files ----------------------------------------------------------------------------
def generate_plan(seed_sequence: np.random.SeedSequence | int, wall: str | None = None,
                  paper: str | None = None, megapixels: float | None = None) -> GeneratedPlan:
    """One plan from its own seed (a ``SeedSequence`` child or an int); ``megapixels`` fixes its size."""
    rng = np.random.default_rng(seed_sequence)
    for _ in range(20):
        layout = make_layout(rng)
        if len(layout.rooms) >= 2 and layout.openings:
            return draw_plan(rng, layout, wall, paper, megapixels=megapixels)
    raise RuntimeError("no usable layout in 20 draws")


def outline_of(seed_sequence: np.random.SeedSequence | int) -> str:
    """The outline's shape of the plan :func:`generate_plan` draws from this seed (its layout
    only, not drawn: a quick way to pick the plans of one shape)."""
    rng = np.random.default_rng(seed_sequence)
    for _ in range(20):
        layout = make_layout(rng)
        if len(layout.rooms) >= 2 and layout.openings:
            return layout.features["outline"]
    raise RuntimeError("no usable layout in 20 draws")


def write_plan(plan: GeneratedPlan, folder: Path, name: str) -> Path:
    """Write NAME.png or NAME.jpg (the drawing), NAME_walls.png and NAME_free.png (255 = wall / free),
    NAME_rooms.png (16-bit room labels) and NAME.json (pixel size, style, rooms); returns the image path."""
    folder.mkdir(parents=True, exist_ok=True)
    image_path = folder / f"{name}.{'jpg' if plan.style.jpeg_quality else 'png'}"
    if plan.jpeg is not None:
        image_path.write_bytes(plan.jpeg)
    else:
        cv2.imwrite(str(image_path), plan.image)
    cv2.imwrite(str(folder / f"{name}_walls.png"), plan.walls.astype(np.uint8) * 255)
    cv2.imwrite(str(folder / f"{name}_free.png"), plan.free.astype(np.uint8) * 255)
    cv2.imwrite(str(folder / f"{name}_rooms.png"), plan.rooms)
    meta = {"image": image_path.name, "resolution_m": plan.resolution_m, "style": dataclasses.asdict(plan.style),
            "rooms": plan.room_info, "doors": plan.n_doors, "features": plan.features}
    (folder / f"{name}.json").write_text(json.dumps(meta, indent=1))
    return image_path


# the set the reader is measured on and never tuned on; tuning uses other seeds (1, 3, ...)
HELD_OUT_SEED = 2


def plan_seeds(seed: int, count: int) -> list[np.random.SeedSequence]:
    """The per-plan seeds of a set: plan i of seed s is the same whatever the count."""
    return np.random.SeedSequence(seed).spawn(count)


def style_of(index: int) -> str:
    """The wall style of plan ``index`` of a set: the three in turn, so each has a third."""
    return WALL_STYLES[index % len(WALL_STYLES)]
