"""Door symbols in a floor-plan drawing: the swing arc round a hinge beside a wall, and its leaf.

A swing door is drawn as its leaf (a line, or a thin box, from the hinge at one jamb) and the
arc its free end sweeps to the other jamb: a circular arc of the door's width (0.45-1.3 m)
about the hinge, spanning the angle the leaf is drawn open at (up to a quarter turn). The arc
is drawn thin; the leaf sometimes heavy enough to pass for a short wall. :func:`find_door_symbols`
finds the arcs among the thin strokes (a circle fitted to each stroke by RANSAC), and
:func:`erase_leaves` removes the leaves from the walls so that no leaf blocks the opening.
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

DOOR_RADIUS_M = (0.45, 1.3)  # a door leaf's length: the arc's radius
ARC_SPAN_DEG = (15.0, 120.0)  # the angle a leaf is drawn open at
HINGE_TO_WALL_M = 0.15  # the hinge lies this close to a wall at most
ARC_COVER = 0.55  # share of the arc's length that must be drawn (dashed arcs too)
STRAIGHT_M = 0.5  # a thin line straight for this long is no arc
LEAF_SEARCH_DEG = 20.0  # the leaf is looked for this far beyond the arc's drawn ends
RANSAC_TRIES = 150
CANDIDATES = 6  # distinct circles tried per stroke, most inliers first
MAX_POINTS = 300  # points of a stroke the circle is fitted to


@dataclasses.dataclass
class DoorSymbol:
    """A door found in a drawing (pixels, column and row): hinge, the free jamb the arc ends at,
    the leaf's tip, the arc's radius and the leaf's angle."""

    hinge_px: tuple[float, float]
    jamb_px: tuple[float, float]
    leaf_tip_px: tuple[float, float]
    radius_px: float
    span_deg: float


def _circles(points: np.ndarray, triples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centres and radii of the circles through each triple of ``points`` (collinear: radius inf)."""
    a, b, c = points[triples[:, 0]], points[triples[:, 1]], points[triples[:, 2]]
    d = 2.0 * (a[:, 0] * (b[:, 1] - c[:, 1]) + b[:, 0] * (c[:, 1] - a[:, 1]) + c[:, 0] * (a[:, 1] - b[:, 1]))
    sa, sb, sc = (a ** 2).sum(1), (b ** 2).sum(1), (c ** 2).sum(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ux = (sa * (b[:, 1] - c[:, 1]) + sb * (c[:, 1] - a[:, 1]) + sc * (a[:, 1] - b[:, 1])) / d
        uy = (sa * (c[:, 0] - b[:, 0]) + sb * (a[:, 0] - c[:, 0]) + sc * (b[:, 0] - a[:, 0])) / d
    centres = np.stack([ux, uy], axis=1)
    radii = np.linalg.norm(a - centres, axis=1)
    radii[~np.isfinite(radii)] = np.inf
    return centres, radii


def _arc_extent(angles: np.ndarray) -> tuple[float, float, float]:
    """(start, span, covered share) of a set of angles on a circle: the arc left when the largest
    gap between neighbouring angles is cut out; the share of 3-degree bins of it that hold points."""
    ordered = np.sort(np.mod(angles, 2 * math.pi))
    gaps = np.diff(np.concatenate([ordered, [ordered[0] + 2 * math.pi]]))
    widest = int(np.argmax(gaps))
    start = ordered[(widest + 1) % len(ordered)]
    span = 2 * math.pi - gaps[widest]
    if span <= 0:
        return float(start), 0.0, 0.0
    bins = max(1, int(math.degrees(span) / 3))
    offsets = np.mod(ordered - start, 2 * math.pi)
    filled = np.unique(np.minimum((offsets / span * bins).astype(int), bins - 1)).size
    return float(start), float(span), filled / bins


def _fit_arcs(points: np.ndarray, radius_px: tuple[float, float], rng: np.random.Generator):
    """The best circles (RANSAC, the ``CANDIDATES`` with most inliers, each refined by least
    squares) through ``points`` with a radius in ``radius_px``: a list of (centre, radius,
    inlier mask). A door's arc shares its pixels with its leaf, so the circle with most inliers
    is not always the arc: each is tried in turn."""
    n = len(points)
    if n < 12:
        return []
    triples = rng.integers(0, n, size=(RANSAC_TRIES, 3))
    centres, radii = _circles(points, triples)
    ok = (radii >= radius_px[0]) & (radii <= radius_px[1])
    if not ok.any():
        return []
    centres, radii = centres[ok], radii[ok]
    distance = np.linalg.norm(points[None, :, :] - centres[:, None, :], axis=2)
    tolerance = max(1.5, 0.03 * radii.mean())
    inliers = np.abs(distance - radii[:, None]) <= tolerance
    counts = inliers.sum(1)
    found: list = []
    tried: list[np.ndarray] = []
    for best in np.argsort(-counts):
        if len(found) >= CANDIDATES or counts[best] < 10:
            break
        if tried and np.min(np.hypot(*(np.array(tried) - centres[best]).T)) < 3.0:  # the same circle again
            continue
        tried.append(centres[best])
        mask = inliers[best]
        # refine: least-squares circle through the inliers (algebraic fit)
        x, y = points[mask, 0], points[mask, 1]
        design = np.stack([x, y, np.ones_like(x)], axis=1)
        solution, *_ = np.linalg.lstsq(design, x ** 2 + y ** 2, rcond=None)
        cx, cy = solution[0] / 2, solution[1] / 2
        radius = math.sqrt(max(solution[2] + cx ** 2 + cy ** 2, 0.0))
        if radius_px[0] <= radius <= radius_px[1]:
            found.append((np.array([cx, cy]), radius,
                          np.abs(np.linalg.norm(points - [cx, cy], axis=1) - radius) <= tolerance))
    return found


def _ink_along(near_ink: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> float:
    """Share of the points on the segment p0-p1 (column, row) that are ink (``near_ink``: the
    ink grown by a pixel)."""
    length = float(np.linalg.norm(p1 - p0))
    steps = max(2, int(length))
    t = np.linspace(0.15, 0.95, steps)  # the hinge end sits on the wall: not counted
    xy = p0[None, :] + t[:, None] * (p1 - p0)[None, :]
    cols = np.clip(np.round(xy[:, 0]).astype(int), 0, near_ink.shape[1] - 1)
    rows = np.clip(np.round(xy[:, 1]).astype(int), 0, near_ink.shape[0] - 1)
    return float(near_ink[rows, cols].mean())


def _door_of_arc(points, centre, radius, mask, walls, to_wall, near_ink, resolution_m) -> DoorSymbol | None:
    """The door a fitted circle is, if its inliers are a drawn arc of a door's angle whose centre
    lies beside a wall and from one end of which a leaf is drawn; else None."""
    angles = np.arctan2(points[mask, 1] - centre[1], points[mask, 0] - centre[0])
    start, span, covered = _arc_extent(angles)
    if not (math.radians(ARC_SPAN_DEG[0]) <= span <= math.radians(ARC_SPAN_DEG[1])) or covered < ARC_COVER:
        return None
    hinge_r, hinge_c = int(round(centre[1])), int(round(centre[0]))
    if not (0 <= hinge_r < walls.shape[0] and 0 <= hinge_c < walls.shape[1]):
        return None
    if to_wall[hinge_r, hinge_c] * resolution_m > HINGE_TO_WALL_M:
        return None
    # the leaf: a radius drawn in ink near one end of the arc (whose drawn end may fall short)
    best, leaf_angle, leaf_end = 0.0, 0.0, 0
    for end, angle in enumerate((start, start + span)):
        outward = -1.0 if end == 0 else 1.0
        for turn in np.radians(np.arange(-LEAF_SEARCH_DEG, LEAF_SEARCH_DEG + 0.1, 4.0)):
            a = angle + outward * turn
            share = _ink_along(near_ink, centre, centre + radius * np.array([math.cos(a), math.sin(a)]))
            if share > best:
                best, leaf_angle, leaf_end = share, a, end
    if best < 0.7:
        return None
    other = start + span if leaf_end == 0 else start
    jamb = centre + radius * np.array([math.cos(other), math.sin(other)])
    tip = centre + radius * np.array([math.cos(leaf_angle), math.sin(leaf_angle)])
    return DoorSymbol((float(centre[0]), float(centre[1])), (float(jamb[0]), float(jamb[1])),
                      (float(tip[0]), float(tip[1])), float(radius), math.degrees(span))


def find_door_symbols(thin: np.ndarray, walls: np.ndarray, ink: np.ndarray, resolution_m: float,
                      seed: int = 0) -> list[DoorSymbol]:
    """The swing doors drawn in a plan: arcs among the ``thin`` strokes whose centre (the hinge)
    lies beside the ``walls`` and from which a leaf runs (in ``ink``) to one end of the arc.

    Every stroke is tried with the same seeded generator: the same drawing gives the same doors."""
    rng = np.random.default_rng(seed)
    low, high = DOOR_RADIUS_M[0] / resolution_m, DOOR_RADIUS_M[1] / resolution_m
    # long straight lines (axis and dimension lines, edges of furniture) would join arcs into
    # strokes too long to be a door: removed first; an arc keeps all but its ends
    run = max(5, int(STRAIGHT_M / resolution_m))
    strokes = thin.astype(np.uint8)
    straight = np.zeros_like(strokes)
    for kernel in (np.ones((1, run), np.uint8), np.ones((run, 1), np.uint8)):
        straight |= cv2.morphologyEx(strokes, cv2.MORPH_OPEN, kernel)
    strokes &= ~cv2.dilate(straight, np.ones((3, 3), np.uint8))
    count, labels, stats, _ = cv2.connectedComponentsWithStats(strokes, connectivity=8)
    to_wall = cv2.distanceTransform((~walls).astype(np.uint8), cv2.DIST_L2, 5)
    near_wall = to_wall * resolution_m <= HINGE_TO_WALL_M  # a door's strokes meet its wall at both jambs
    near_ink = cv2.dilate(ink.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    doors: list[DoorSymbol] = []
    longer = np.maximum(stats[:, cv2.CC_STAT_WIDTH], stats[:, cv2.CC_STAT_HEIGHT])
    candidates = np.nonzero((longer >= 0.6 * low) & (longer <= 2.2 * high))[0]
    for index in candidates:
        if index == 0:
            continue
        x, y, w, h, _ = stats[index]
        rows, cols = np.nonzero(labels[y:y + h, x:x + w] == index)
        if not near_wall[rows + y, cols + x].any():
            continue
        points = np.stack([cols + x, rows + y], axis=1).astype(np.float64)
        if len(points) > MAX_POINTS:
            points = points[rng.choice(len(points), MAX_POINTS, replace=False)]
        for centre, radius, mask in _fit_arcs(points, (low, high), rng):
            door = _door_of_arc(points, centre, radius, mask, walls, to_wall, near_ink, resolution_m)
            if door is not None:
                doors.append(door)
                break
    return doors


def erase_leaves(walls: np.ndarray, doors: list[DoorSymbol], half_width_px: float) -> np.ndarray:
    """``walls`` without the door leaves: the pixels within ``half_width_px`` of each leaf, away
    from its hinge (the jamb stays)."""
    if not doors:
        return walls
    leaves = np.zeros(walls.shape, dtype=np.uint8)
    keep_jamb = np.zeros(walls.shape, dtype=np.uint8)
    thickness = max(1, int(round(2 * half_width_px)))
    for door in doors:
        hinge = np.array(door.hinge_px)
        tip = np.array(door.leaf_tip_px)
        cv2.line(leaves, tuple(np.round(hinge).astype(int)), tuple(np.round(tip).astype(int)), 1, thickness)
        cv2.circle(keep_jamb, tuple(np.round(hinge).astype(int)), max(2, int(round(half_width_px * 2))), 1, -1)
    return walls & ~(leaves.astype(bool) & ~keep_jamb.astype(bool))
