"""Whole-walk placement: the dead-reckoned shape placed by every fix, robust to far-off fixes."""

import math

import numpy as np
import pytest

from mapfilter.errors import MapfilterError
from mapfilter.offline.placement import (Anchor, pdr_shape, place_walk, robust_offset, rotation_vector_heading_offset,
                                         shift_onto_free_space)
from mapfilter.sensors.pdr import Steps


def l_shaped_steps(heading_offset_rad: float, with_rotation_vector: bool = True) -> Steps:
    """40 steps east (in the gyro's frame), a left turn, 40 steps north; 0.7 m, 0.5 s apart."""
    n = 80
    t = 1000.0 + 0.5 * np.arange(1, n + 1)
    gyro = np.where(np.arange(n) < 40, 0.0, math.pi / 2) + 0.3  # arbitrary gyro zero
    change = np.diff(np.concatenate([[gyro[0]], gyro]))
    absolute = gyro - gyro[0] + heading_offset_rad if with_rotation_vector else None
    return Steps(t_s=t, heading_change_rad=change, heading_rad=gyro, abs_heading_rad=absolute,
                 step_length_m=np.full(n, 0.7), weinberg_unit=np.full(n, 0.7 / 0.39), t0_s=999.0)


def truth_at(steps: Steps, heading_offset_rad: float, start_xy_m, t_s):
    shape_t, shape_xy = pdr_shape(steps, heading_offset_rad)
    xy = shape_xy + np.asarray(start_xy_m)
    return np.column_stack([np.interp(t_s, shape_t, xy[:, 0]), np.interp(t_s, shape_t, xy[:, 1])])


def test_robust_offset_minimises_the_huber_cost():
    rng = np.random.default_rng(0)
    d = np.vstack([rng.normal([3.0, -2.0], 2.0, (40, 2)), rng.normal([40.0, 30.0], 3.0, (8, 2))])
    m = robust_offset(d, huber_m=5.0)
    grid = np.stack(np.meshgrid(np.linspace(-5, 10, 151), np.linspace(-10, 5, 151)), -1).reshape(-1, 2)
    r = np.linalg.norm(d[None] - grid[:, None], axis=2)
    cost = np.where(r <= 5.0, 0.5 * r**2, 5.0 * r - 12.5).sum(1)
    assert np.linalg.norm(m - grid[np.argmin(cost)]) < 0.15  # the grid's own spacing
    assert np.linalg.norm(m - [3.0, -2.0]) < 1.5 < np.linalg.norm(d.mean(0) - [3.0, -2.0])


def test_placement_recovers_the_walk_despite_far_off_fixes():
    rng = np.random.default_rng(1)
    offset = 0.8
    steps = l_shaped_steps(offset)
    fix_t = 1000.0 + 2.0 * np.arange(1, 21)
    truth = truth_at(steps, offset, [50.0, 20.0], fix_t)
    fixes = truth + rng.normal(0, 3.0, truth.shape)
    fixes[:5] += [35.0, -25.0]  # an unsurveyed stretch: five fixes far off in one direction
    fixes[7] = np.nan  # a scan without a fix is skipped
    placed = place_walk(steps, fix_t, fixes)
    assert placed.n_fixes == 19
    assert placed.heading_offset_rad == pytest.approx(offset)
    error = np.linalg.norm(placed.position_at(fix_t) - truth, axis=1)
    plain = np.nanmean(fixes - truth, axis=0)  # what a least-squares placement would be off by
    # Huber bounds each far fix's pull: a third of the plain mean's bias remains, not all of it
    assert error.max() < 5.0 and error.max() < 0.4 * np.linalg.norm(plain)


def test_a_known_start_places_the_shape_whatever_the_fixes_say():
    """Fixes all biased 30 m (a walk where nobody surveyed): without an anchor the shape sits
    there; through the known start it is where it was. Without a rotation vector the fixes
    still choose the heading."""
    rng = np.random.default_rng(3)
    fix_t = 1000.0 + 2.0 * np.arange(1, 21)
    steps = l_shaped_steps(0.8)
    truth = truth_at(steps, 0.8, [50.0, 20.0], fix_t)
    biased = truth + [30.0, 0.0] + rng.normal(0, 2.0, truth.shape)
    start = truth_at(steps, 0.8, [50.0, 20.0], [999.0])[0]
    assert np.linalg.norm(place_walk(steps, fix_t, biased).position_at(fix_t) - truth, axis=1).mean() > 25.0
    anchored = place_walk(steps, fix_t, biased, anchor=Anchor(999.0, start, 2.0))
    assert np.linalg.norm(anchored.position_at(fix_t) - truth, axis=1).max() < 1e-9 and anchored.max_shift_m == 2.0
    no_vector = l_shaped_steps(0.8, with_rotation_vector=False)
    noisy = truth + rng.normal(0, 3.0, truth.shape)
    searched = place_walk(no_vector, fix_t, noisy, anchor=Anchor(999.0, start, 2.0))
    assert abs((searched.heading_offset_rad - 0.8 + math.pi) % (2 * math.pi) - math.pi) < math.radians(6)


def test_the_walls_move_an_anchored_placement_no_farther_than_its_anchor_allows():
    from mapfilter.maps.floorplan import FloorPlan

    wall = np.zeros((200, 200), dtype=bool)
    wall[:, 100:] = True  # free x < 10 m only
    plan = FloorPlan(wall, 0.1)
    steps = l_shaped_steps(0.0)
    fix_t = 1000.0 + 2.0 * np.arange(1, 21)
    fixes = truth_at(steps, 0.0, [-20.0, 2.0], fix_t) + 8.0  # residuals of ~11 m: a free shift of 5.6 m
    placed = place_walk(steps, fix_t, fixes, anchor=Anchor(999.0, np.array([-19.0, 2.0]), 1.0))
    shifted = shift_onto_free_space(plan, placed)
    assert np.linalg.norm(shifted.offset_xy_m - placed.offset_xy_m) <= 1.0 + 1e-9


def test_without_rotation_vector_the_heading_is_searched():
    rng = np.random.default_rng(2)
    steps = l_shaped_steps(2.0, with_rotation_vector=False)
    assert rotation_vector_heading_offset(steps) is None
    fix_t = 1000.0 + 2.0 * np.arange(1, 21)
    truth = truth_at(steps, 2.0, [0.0, 0.0], fix_t)
    placed = place_walk(steps, fix_t, truth + rng.normal(0, 2.0, truth.shape))
    assert abs((placed.heading_offset_rad - 2.0 + math.pi) % (2 * math.pi) - math.pi) < math.radians(6)
    assert np.linalg.norm(placed.position_at(fix_t) - truth, axis=1).mean() < 2.0


def test_no_fix_or_no_step_is_an_error():
    steps = l_shaped_steps(0.0)
    with pytest.raises(MapfilterError):
        place_walk(steps, np.array([1001.0]), np.full((1, 2), np.nan))
    empty = Steps(np.zeros(0), np.zeros(0), np.zeros(0), None, np.zeros(0), np.zeros(0), 0.0)
    with pytest.raises(MapfilterError):
        pdr_shape(empty, 0.0)


def test_the_map_moves_a_placement_into_the_corridor_within_its_radius():
    from mapfilter.offline.placement import WalkPlacement, shift_onto_free_space
    from mapfilter.maps.floorplan import FloorPlan

    wall = np.ones((200, 400), dtype=bool)  # 40 x 20 m at 0.1 m/px, one corridor y in [8, 10] m
    wall[100:120, :] = False
    plan = FloorPlan(wall, 0.1, (0.0, 0.0))
    xy = np.column_stack([np.linspace(5.0, 35.0, 61), np.full(61, 12.0)])  # placed 3 m north of it

    def placed(residual_m):
        return WalkPlacement(np.arange(61.0), xy, 0.0, np.array([5.0, 12.0]), residual_m, 20)

    moved = shift_onto_free_space(plan, placed(8.0))  # radius 4 m reaches the corridor
    assert plan.is_free(moved.xy_m).all() and np.allclose(moved.xy_m[:, 0], xy[:, 0])
    assert 2.0 <= 12.0 - moved.xy_m[0, 1] <= 3.5  # the shortest shift that gets it all in
    assert np.allclose(moved.offset_xy_m - [5.0, 12.0], moved.xy_m[0] - xy[0])
    kept = shift_onto_free_space(plan, placed(2.0))  # radius 1 m: the corridor is out of reach
    assert np.array_equal(kept.xy_m, xy)
