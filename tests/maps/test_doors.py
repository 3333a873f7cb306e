"""Door symbols (maps/doors.py): circles through three points against the plain formula, the arc
a set of angles spans, a drawn door found with its hinge, jamb and leaf, and its leaf erased."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from mapfilter.maps import doors


def test_circles_through_three_points_match_the_plain_formula():
    rng = np.random.default_rng(1)
    centre, radius = np.array([40.0, -12.0]), 23.0
    angles = rng.uniform(0, 2 * math.pi, 30)
    points = centre + radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    triples = rng.integers(0, 30, size=(20, 3))
    distinct = (triples[:, 0] != triples[:, 1]) & (triples[:, 1] != triples[:, 2]) & (triples[:, 0] != triples[:, 2])
    centres, radii = doors._circles(points, triples[distinct])
    np.testing.assert_allclose(centres, np.broadcast_to(centre, centres.shape), atol=1e-6)
    np.testing.assert_allclose(radii, radius, rtol=1e-9)
    collinear = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]])
    assert np.isinf(doors._circles(collinear, np.array([[0, 1, 2]]))[1][0])


def test_arc_extent_across_zero():
    angles = np.radians(np.concatenate([np.arange(350, 360, 1.0), np.arange(0, 60, 1.0)]))
    start, span, covered = doors._arc_extent(angles)
    assert math.degrees(start) == pytest.approx(350) and math.degrees(span) == pytest.approx(69)
    assert covered == pytest.approx(1.0)
    start, span, covered = doors._arc_extent(np.radians(np.arange(0, 90, 9.0)))
    assert covered < 0.5  # a few dots on a quarter circle are no drawn arc


def _door_picture(leaf_angle_deg: float):
    """A 0.02 m/px picture: a wall with a 0.9 m opening, the leaf hinged at its left jamb and
    open by ``leaf_angle_deg`` into the room below, and the swing arc to the other jamb."""
    wall = np.zeros((200, 300), np.uint8)
    wall[50:56, :100] = 1
    wall[50:56, 145:] = 1  # the opening: columns 100..144 (0.9 m)
    ink = wall.copy()
    hinge = (100, 56)
    radius = 45
    angle = math.radians(leaf_angle_deg)
    tip = (int(round(hinge[0] + radius * math.cos(angle))), int(round(hinge[1] + radius * math.sin(angle))))
    cv2.line(ink, hinge, tip, 1, 1)
    cv2.ellipse(ink, hinge, (radius, radius), 0, 0, leaf_angle_deg, 1, 1)
    thin = ink.astype(bool) & ~cv2.dilate(wall, np.ones((3, 3), np.uint8)).astype(bool)
    return wall.astype(bool), ink.astype(bool), thin, hinge, tip


@pytest.mark.parametrize("angle", [90.0, 40.0])
def test_a_drawn_door_is_found_and_its_leaf_erased(angle):
    wall, ink, thin, hinge, tip = _door_picture(angle)
    (door,) = doors.find_door_symbols(thin, wall, ink, 0.02)
    assert door.hinge_px == pytest.approx(hinge, abs=2.0)
    assert door.radius_px == pytest.approx(45, abs=2.5)
    assert door.jamb_px == pytest.approx((145, 56), abs=3.0)
    assert door.leaf_tip_px == pytest.approx(tip, abs=4.0)
    heavy_leaf = wall.copy()
    cv2.line(heavy_leaf.view(np.uint8), hinge, tip, 1, 3)  # the leaf as heavy as a thin wall
    erased = doors.erase_leaves(heavy_leaf, [door], 2.5)
    mid = (np.array(hinge) + np.array(tip)) // 2
    assert not erased[mid[1], mid[0]] and erased[53, 50] and erased[53, 99]  # leaf gone, the wall and jamb kept


def test_a_round_table_and_a_lone_line_are_no_doors():
    wall = np.zeros((200, 300), bool)
    wall[50:56] = True
    ink = wall.copy()
    cv2.circle(ink.view(np.uint8), (150, 130), 30, 1, 1)  # a table: a full circle
    cv2.line(ink.view(np.uint8), (20, 100), (60, 140), 1, 1)
    thin = ink & ~wall
    assert doors.find_door_symbols(thin, wall, ink, 0.02) == []
