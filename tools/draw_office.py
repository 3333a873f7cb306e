#!/usr/bin/env python3
"""Draw the bundled example: a synthetic 35 m x 35 m office floor as a bitmap line drawing.

A corridor loop (2 m wide) runs around a central block of four rooms, with a ring of offices
along the outer walls, every room with a 1 m door (like the building of Evennou & Marx). The
picture imitates a scanned plan so that `mapfilter map prepare --kind lines` has work to do:
anti-aliased 0.15 m walls, room labels (also inside the corridor), specks, a few 0.1 m breaks
in the walls, a slight blur and grey noise. The outer wall is closed (no entrance), so the
outside can be told from the inside.

Also writes the access-point table of the example (four APs at the corners, ten more spread
over the floor, each a dual-band box: one row per band with the Lund thesis path-loss model).

    .venv/bin/python tools/draw_office.py --out maps/office_plan.png --aps maps/office_aps.csv
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import cv2
import numpy as np

PLAN_RESOLUTION_M = 0.05  # metres per plan pixel
MARGIN_M = 1.5  # paper around the building
BUILDING_M = 35.0
WALL_M = 0.15
DOOR_M = 1.0
# the ring corridor between the outer offices and the central block
RING_OUT_M = 6.0  # offset of the corridor's outer wall from the building's outer wall
RING_IN_M = 8.0  # offset of the corridor's inner wall (central block boundary)


def _px(x_m: float, y_m: float, size_px: int) -> tuple[int, int]:
    """Plan pixel (col, row) of a world point (world origin = plan's lower-left corner), with
    4 fractional bits for cv2's sub-pixel drawing."""
    u = x_m / PLAN_RESOLUTION_M
    v = size_px - y_m / PLAN_RESOLUTION_M
    return int(round(u * 16)), int(round(v * 16))


def office_walls_m() -> tuple[list[tuple[float, float, float, float]], list[tuple[float, float, float, float]],
                               list[tuple[str, float, float]]]:
    """(walls, doors, labels) in world metres. Walls and doors are segments (x1, y1, x2, y2);
    a door is a 1 m piece of a wall that is left open."""
    b0 = MARGIN_M
    b1 = MARGIN_M + BUILDING_M
    o0, o1 = b0 + RING_OUT_M, b1 - RING_OUT_M  # corridor outer wall
    i0, i1 = b0 + RING_IN_M, b1 - RING_IN_M  # corridor inner wall
    mid = 0.5 * (b0 + b1)
    walls = [
        # outer wall, corridor outer and inner walls (rectangles)
        (b0, b0, b1, b0), (b1, b0, b1, b1), (b1, b1, b0, b1), (b0, b1, b0, b0),
        (o0, o0, o1, o0), (o1, o0, o1, o1), (o1, o1, o0, o1), (o0, o1, o0, o0),
        (i0, i0, i1, i0), (i1, i0, i1, i1), (i1, i1, i0, i1), (i0, i1, i0, i0),
        # the central block split into four rooms
        (mid, i0, mid, i1), (i0, mid, i1, mid),
    ]
    doors = []
    labels = []
    # offices along the outer walls: partitions at these positions along each side
    cuts = [o0, o0 + 5.0, mid, o1 - 5.0, o1]
    room = 101
    for side in range(4):
        for a, b in zip(cuts[:-1], cuts[1:]):
            centre = 0.5 * (a + b)
            labels.append((f"R{room}", *_side_point(side, centre, b0 + 0.5 * RING_OUT_M, b0, b1)))
            room += 1
            doors.append(_side_segment(side, centre - DOOR_M / 2, centre + DOOR_M / 2, o0, b0, b1))
        for c in cuts:
            walls.append(_side_segment(side, c, c, b0, b0, b1, depth_to=o0))
        # the corner office (between two sides) opens into its neighbour on this side
        corner_label = _side_point(side, b0 + 0.5 * RING_OUT_M, b0 + 0.5 * RING_OUT_M, b0, b1)
        labels.append((f"R{room}", *corner_label))
        room += 1
        doors.append(_side_segment(side, o0, o0, b0, b0, b1, depth_to=o0, door_at=b0 + 3.0))
    # central rooms: one door each onto the corridor
    lab_centres = [(0.5 * (i0 + mid), 0.5 * (i0 + mid)), (0.5 * (mid + i1), 0.5 * (i0 + mid)),
                   (0.5 * (mid + i1), 0.5 * (mid + i1)), (0.5 * (i0 + mid), 0.5 * (mid + i1))]
    half = DOOR_M / 2
    lab_doors = [(lab_centres[0][0] - half, i0, lab_centres[0][0] + half, i0),  # LAB 1: bottom wall
                 (i1, lab_centres[1][1] - half, i1, lab_centres[1][1] + half),  # LAB 2: right wall
                 (lab_centres[2][0] - half, i1, lab_centres[2][0] + half, i1),  # LAB 3: top wall
                 (i0, lab_centres[3][1] - half, i0, lab_centres[3][1] + half)]  # LAB 4: left wall
    for k, (cx, cy) in enumerate(lab_centres):
        labels.append((f"LAB {k + 1}", cx, cy))
    doors += lab_doors
    # labels inside the corridor: the clean-up must remove them, not leave walls in the corridor
    ring = 0.5 * (o0 + i0)
    labels += [("CORRIDOR", mid - 2.0, ring), ("EXIT ->", b0 + b1 - ring, mid + 4.0)]
    return walls, doors, labels


def _side_point(side: int, along: float, depth: float, b0: float, b1: float) -> tuple[float, float]:
    """World point at ``along`` on side ``side`` (0 bottom, 1 right, 2 top, 3 left), ``depth``
    measured from the bottom/left for sides 0/3 and mirrored for sides 1/2."""
    mirror = b0 + b1
    if side == 0:
        return along, depth
    if side == 1:
        return mirror - depth, along
    if side == 2:
        return mirror - along, mirror - depth
    return depth, mirror - along


def _side_segment(side: int, a: float, b: float, depth: float, b0: float, b1: float,
                  depth_to: float | None = None, door_at: float | None = None) -> tuple[float, float, float, float]:
    """A segment on side ``side``: along the side from a to b at ``depth`` (depth_to None), or
    across it from ``depth`` to ``depth_to`` at position a (a partition); ``door_at`` turns a
    partition into a 1 m door on it centred at that depth."""
    if depth_to is None:
        p, q = _side_point(side, a, depth, b0, b1), _side_point(side, b, depth, b0, b1)
    elif door_at is not None:
        p = _side_point(side, a, door_at - DOOR_M / 2, b0, b1)
        q = _side_point(side, a, door_at + DOOR_M / 2, b0, b1)
    else:
        p, q = _side_point(side, a, depth, b0, b1), _side_point(side, a, depth_to, b0, b1)
    return (*p, *q)


def draw_office(rng: np.random.Generator) -> np.ndarray:
    """The plan as an 8-bit grey image (white paper, black walls)."""
    size_px = int(round((BUILDING_M + 2 * MARGIN_M) / PLAN_RESOLUTION_M))
    image = np.full((size_px, size_px), 255, dtype=np.uint8)
    walls, doors, labels = office_walls_m()
    wall_px = max(1, int(round(WALL_M / PLAN_RESOLUTION_M)))
    for x1, y1, x2, y2 in walls:
        cv2.line(image, _px(x1, y1, size_px), _px(x2, y2, size_px), 0, wall_px, cv2.LINE_AA, shift=4)
    for x1, y1, x2, y2 in doors:  # cut the openings: paper drawn over the wall, a bit wider than it
        cv2.line(image, _px(x1, y1, size_px), _px(x2, y2, size_px), 255, wall_px + 4, cv2.LINE_8, shift=4)
    font = cv2.FONT_HERSHEY_SIMPLEX
    for text, x, y in labels:
        (w, h), _ = cv2.getTextSize(text, font, 0.45, 1)
        u, v = x / PLAN_RESOLUTION_M - w / 2, size_px - y / PLAN_RESOLUTION_M + h / 2
        cv2.putText(image, text, (int(u), int(v)), font, 0.45, 40, 1, cv2.LINE_AA)
    cv2.putText(image, "OFFICE FLOOR 1  (scale 1:500)", (20, 20), font, 0.45, 40, 1, cv2.LINE_AA)
    # scan defects: short breaks in walls (closed by the preparation), specks of dust
    for x1, y1, x2, y2 in walls[4:8]:
        t = rng.uniform(0.2, 0.8)
        x, y = x1 + t * (x2 - x1), y1 + t * (y2 - y1)
        dx, dy = (0.05, 0.0) if y1 == y2 else (0.0, 0.05)
        cv2.line(image, _px(x - dx, y - dy, size_px), _px(x + dx, y + dy, size_px), 255, 1, cv2.LINE_8, shift=4)
    for _ in range(120):
        cv2.circle(image, (int(rng.integers(0, size_px)), int(rng.integers(0, size_px))),
                   int(rng.integers(0, 3)), int(rng.integers(0, 120)), -1, cv2.LINE_AA)
    image = cv2.GaussianBlur(image, (3, 3), 0.6)
    noisy = image.astype(np.float64) + rng.normal(0.0, 6.0, image.shape)
    return np.clip(noisy, 0, 255).round().astype(np.uint8)


def office_access_points() -> list[dict]:
    """Dual-band APs: four at the building corners and ten spread over rooms and corridor."""
    b0, b1 = MARGIN_M, MARGIN_M + BUILDING_M
    mid = 0.5 * (b0 + b1)
    inset = 1.0
    sites = [(b0 + inset, b0 + inset), (b1 - inset, b0 + inset), (b1 - inset, b1 - inset), (b0 + inset, b1 - inset)]
    ring = b0 + 0.5 * (RING_OUT_M + RING_IN_M)
    sites += [(mid, ring), (b0 + b1 - ring, mid), (mid, b0 + b1 - ring), (ring, mid)]  # corridor mid-sides
    sites += [(mid - 4.5, mid - 4.5), (mid + 4.5, mid + 4.5)]  # two labs
    sites += [(b0 + 3.0, mid + 6.0), (b1 - 3.0, mid - 6.0), (mid - 6.0, b0 + 3.0), (mid + 6.0, b1 - 3.0)]  # offices
    rows = []
    for k, (x, y) in enumerate(sites):
        bssid = f"02:00:00:00:00:{k + 1:02x}"
        # Lund thesis: n = 2, C about -38 dBm; 5 GHz loses more per metre through walls
        rows.append({"bssid": bssid, "x": x, "y": y, "band": "2.4", "C": -38.0, "n": 2.0, "alpha": 0.3, "d_max": 30.0})
        rows.append({"bssid": bssid, "x": x, "y": y, "band": "5", "C": -40.0, "n": 2.0, "alpha": 0.5, "d_max": 30.0})
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description="Draw the bundled synthetic office plan and its access points.")
    parser.add_argument("--out", type=Path, default=Path("maps/office_plan.png"), help="plan PNG (default: %(default)s)")
    parser.add_argument("--aps", type=Path, default=Path("maps/office_aps.csv"), help="AP CSV (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=7, help="seed of the scan defects (default: %(default)s)")
    args = parser.parse_args(argv)
    image = draw_office(np.random.default_rng(args.seed))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(args.out), image):
        raise SystemExit(f"could not write {args.out}")
    with args.aps.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=["bssid", "x", "y", "band", "C", "n", "alpha", "d_max"])
        writer.writeheader()
        for row in office_access_points():
            writer.writerow({**row, "x": f"{row['x']:.2f}", "y": f"{row['y']:.2f}"})
    print(f"wrote {args.out} ({image.shape[1]}x{image.shape[0]} px at {PLAN_RESOLUTION_M} m/px) and {args.aps}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
