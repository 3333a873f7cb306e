"""Can a map be walked (maps/walkable.py): the free share, the largest connected region, the rooms
cut off, the refusal of a map without free space and the warning about a map mostly cut off."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from mapfilter.errors import MapfilterError
from mapfilter.maps import walkable
from mapfilter.maps.building import Building
from mapfilter.maps.floorplan import FloorPlan


def _rooms() -> np.ndarray:
    """60 x 100 cells at 0.1 m: walled round, a big room (4 x 4.8 m) joined to a corridor, and two
    rooms (1.8 x 1.8 m and 0.8 x 0.8 m) with no door."""
    wall = np.ones((60, 100), bool)
    wall[5:55, 5:45] = False  # the big room
    wall[25:30, 45:95] = False  # a corridor off it
    wall[5:23, 60:78] = False  # a room cut off
    wall[40:48, 80:88] = False  # a closet cut off, under a square metre... 0.64 m2
    return wall


def test_assess_matches_a_plain_labelling():
    wall = _rooms()
    walk = walkable.assess(wall, 0.1)
    labels, count = ndimage.label(~wall)  # 4-connected, as the wall walk is
    sizes = np.bincount(labels.ravel())[1:]
    assert walk.free_share == pytest.approx((~wall).mean())
    assert walk.largest_share == pytest.approx(sizes.max() / sizes.sum())
    assert [r.area_m2 for r in walk.cut_off] == pytest.approx([18 * 18 * 0.01])  # the closet is no room
    assert walk.cut_off[0].box_px == (60, 5, 77, 22)


def test_a_diagonal_touch_is_no_passage():
    wall = np.ones((20, 20), bool)
    wall[2:10, 2:10] = False
    wall[10:18, 10:18] = False  # touches the first room at a corner only
    walk = walkable.assess(wall, 0.5)
    assert walk.largest_share == pytest.approx(0.5) and len(walk.cut_off) == 1


def test_the_outside_kept_free_is_no_region():
    wall = _rooms()
    wall[0, :] = False  # free space along the map's edge: a plan prepared with --outside none
    walk = walkable.assess(wall, 0.1)
    assert [r.box_px for r in walk.cut_off] == [(60, 5, 77, 22)]


def test_messages_name_the_rooms_by_their_box():
    walk = walkable.assess(_rooms(), 0.1)
    line = walkable.cut_off_message(walk, "open their doors")
    assert "1 room is cut off" in line and "3.2 m2 at px 60,5-77,22" in line and line.endswith("open their doors")
    assert "\n" not in line
    assert "cut off" in walkable.summary(walk)
    assert walkable.cut_off_message(walkable.assess(np.pad(np.zeros((5, 5), bool), 1, constant_values=True), 1.0),
                                    "x") is None


def test_before_tracking_a_map_without_free_space_is_refused_and_one_mostly_cut_off_warned():
    empty = Building.from_plan(FloorPlan(np.ones((10, 10), bool), 0.1))
    with pytest.raises(MapfilterError, match="no free space"):
        walkable.check_before_tracking(empty, "walls.yaml")
    good = Building.from_plan(FloorPlan(np.pad(np.zeros((8, 8), bool), 1, constant_values=True), 0.1))
    assert walkable.check_before_tracking(good, "good.yaml") == []
    split = np.ones((40, 40), bool)
    for r0 in (2, 14, 26):
        split[r0:r0 + 10, 2:38] = False  # three rooms alike, none joined
    (line,) = walkable.check_before_tracking(Building.from_plan(FloorPlan(split, 0.2)), "split.yaml")
    assert line.startswith("split.yaml: only 33% of the free space is one connected region") and "2 rooms" in line
