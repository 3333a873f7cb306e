"""The numba wall check against the plain-Python oracle, and its touching rule."""

import numpy as np
import pytest

from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import (
    _bands,
    _box_is_free,
    clearance_px,
    count_wall_crossings,
    crosses_wall,
    crosses_wall_uv,
    look_move,
    look_two_moves,
    touched_pixels,
    touched_pixels_capacity,
    touched_pixels_into,
    touched_pixels_reference,
    wall_grid,
)


def _random_segments(rng, n, size):
    """A mix: random floats, lattice/half-lattice points (corner hits), axis-aligned along grid lines."""
    a = rng.uniform(-1.0, size + 1.0, (n, 2))
    b = rng.uniform(-1.0, size + 1.0, (n, 2))
    kind = rng.integers(0, 5, n)
    grid = kind == 1  # end points on the half-integer lattice: many exact corner passes
    a[grid] = rng.integers(-2, 2 * size + 2, (grid.sum(), 2)) * 0.5
    b[grid] = rng.integers(-2, 2 * size + 2, (grid.sum(), 2)) * 0.5
    diag = kind == 2  # exact diagonals through lattice corners
    a[diag] = rng.integers(0, size, (diag.sum(), 2)) + 0.5
    b[diag] = a[diag] + rng.integers(-4, 5, (diag.sum(), 1)) * np.array([1.0, 1.0])
    along = kind == 3  # along a grid line (u or v integer and constant)
    u = rng.integers(0, size, along.sum()).astype(float)
    a[along, 0] = u
    b[along, 0] = u
    short = kind == 4  # short moves, like particle steps
    b[short] = a[short] + rng.normal(0.0, 1.5, (short.sum(), 2))
    return a, b


def test_walk_touches_exactly_the_oracle_pixels():
    rng = np.random.default_rng(0)
    a, b = _random_segments(rng, 3000, 12)
    for i in range(a.shape[0]):
        assert touched_pixels(a[i], b[i]) == touched_pixels_reference(a[i], b[i]), (a[i], b[i])


def test_recording_walk_fits_its_capacity_and_walks_in_order():
    """touched_pixels_into: the oracle's pixels, within touched_pixels_capacity, and in walk order
    (start pixel first; edge neighbours, except the two side pixels of a lattice corner, which
    are diagonal to each other; the end pixel closes the walk), as simulate/segments.py relies on."""
    rng = np.random.default_rng(5)
    a, b = _random_segments(rng, 3000, 12)
    n_corners = 0
    for i in range(a.shape[0]):
        (u0, v0), (u1, v1) = a[i], b[i]
        cap = touched_pixels_capacity(u0, v0, u1, v1)
        rows, cols = np.full(cap + 8, -99, np.int64), np.full(cap + 8, -99, np.int64)
        k = touched_pixels_into(u0, v0, u1, v1, rows, cols)
        assert 0 < k <= cap and (rows[k:] == -99).all()
        assert set(zip(rows[:k].tolist(), cols[:k].tolist())) == touched_pixels_reference(a[i], b[i])
        start, end = (int(np.floor(v0)), int(np.floor(u0))), (int(np.floor(v1)), int(np.floor(u1)))
        assert (rows[0], cols[0]) == start
        j = 0
        while (rows[j], cols[j]) != end:
            dr, dc = abs(rows[j + 1] - rows[j]), abs(cols[j + 1] - cols[j])
            if dr == 1 and dc == 1:  # corner side pixels: both are edge neighbours of the one before
                n_corners += 1
                assert abs(rows[j + 1] - rows[j - 1]) + abs(cols[j + 1] - cols[j - 1]) == 1
            else:
                assert dr + dc == 1
            j += 1
        assert j + 1 <= k
    assert n_corners > 100  # the mix has many exact corner passes
    nan_rows = np.empty(0, np.int64)
    assert touched_pixels_capacity(np.nan, 0.0, 1.0, 1.0) == 0
    assert touched_pixels_into(np.nan, 0.0, 1.0, 1.0, nan_rows, nan_rows) == 0


def test_crosses_wall_agrees_with_oracle_on_masks():
    rng = np.random.default_rng(1)
    size = 24
    mask = rng.random((size, size)) < 0.08
    mask[5, 3:20] = True  # a wall line: segments along it and clipping its ends
    mask[[8, 9, 10], [8, 9, 10]] = True  # a diagonal (8-connected) wall
    a, b = _random_segments(rng, 5000, size)
    fast = crosses_wall_uv(mask, a, b)
    h, w = mask.shape
    expected = np.array([
        any(not (0 <= r < h and 0 <= c < w) or mask[r, c] for r, c in touched_pixels_reference(a[i], b[i]))
        for i in range(a.shape[0])
    ])
    assert np.array_equal(fast, expected)
    assert 0.2 < expected.mean() < 0.95  # the test exercises both outcomes


def test_world_check_with_clearance_shortcut_agrees_with_oracle():
    # a map with wide free areas so that the clearance shortcut is taken for most moves
    rng = np.random.default_rng(2)
    mask = np.zeros((60, 80), dtype=bool)
    mask[[0, -1], :] = True
    mask[:, [0, -1]] = True
    mask[30, 10:70] = True
    mask[10:25, 40] = True
    fp = FloorPlan(mask, 0.25, origin_m=(-3.0, 2.0))
    a_xy = fp.sample_free(4000, rng)
    b_xy = a_xy + rng.normal(0.0, 1.0, a_xy.shape)
    b_xy[::4] = a_xy[::4] + rng.normal(0.0, 6.0, (1000, 2))  # long moves: several clearance jumps
    fast = crosses_wall(fp, a_xy, b_xy)
    ua, ub = fp.world_to_pixel(a_xy), fp.world_to_pixel(b_xy)
    h, w = mask.shape
    expected = np.array([
        any(not (0 <= r < h and 0 <= c < w) or mask[r, c] for r, c in touched_pixels_reference(ua[i], ub[i]))
        for i in range(a_xy.shape[0])
    ])
    assert np.array_equal(fast, expected)
    assert 0.02 < expected.mean() < 0.6
    rows, cols, _ = fp.pixel_index(a_xy)
    length_px = np.linalg.norm(ub - ua, axis=1)
    assert (length_px < clearance_px(fp)[rows, cols]).mean() > 0.3  # the shortcut really is exercised


def test_corner_rule_closes_diagonal_walls():
    mask = np.zeros((4, 4), dtype=bool)
    mask[1, 1] = mask[2, 2] = True  # diagonal wall; (1, 2) and (2, 1) free
    # from the free pixel (row 1, col 2) to the free pixel (row 2, col 1), exactly through the corner (2, 2)
    assert crosses_wall_uv(mask, np.array([[2.5, 1.5]]), np.array([[1.5, 2.5]]))[0]
    # the same move clipping only the corner point of one wall pixel
    touched = touched_pixels((2.5, 1.5), (1.5, 2.5))
    assert {(1, 1), (2, 2), (1, 2), (2, 1)} <= touched


def test_segment_along_a_wall_edge_touches_it_but_a_parallel_one_does_not():
    mask = np.zeros((6, 6), dtype=bool)
    mask[:, 2] = True  # wall column u in [2, 3)
    # along the wall's left edge u = 2: touches the wall (closed pixels)
    assert crosses_wall_uv(mask, np.array([[2.0, 0.5]]), np.array([[2.0, 5.5]]))[0]
    # parallel, inside the free column next to it: no contact
    assert not crosses_wall_uv(mask, np.array([[1.5, 0.5]]), np.array([[1.5, 5.5]]))[0]
    assert not crosses_wall_uv(mask, np.array([[1.999, 0.5]]), np.array([[1.999, 5.5]]))[0]


def test_leaving_the_map_and_non_finite_count_as_crossing():
    fp = FloorPlan(np.zeros((10, 10), dtype=bool), 1.0)
    a = np.array([[5.0, 5.0], [5.0, 5.0], [5.0, 5.0]])
    b = np.array([[5.0, 11.0], [np.nan, 5.0], [6.0, 6.0]])
    assert crosses_wall(fp, a, b).tolist() == [True, True, False]


def test_count_wall_crossings_of_a_track():
    mask = np.zeros((10, 10), dtype=bool)
    mask[:, 5] = True
    fp = FloorPlan(mask, 1.0)
    track = np.array([[1.5, 1.5], [3.5, 1.5], [7.5, 1.5], [8.5, 2.5], [2.5, 2.5], [np.nan, np.nan], [2.5, 8.5]])
    assert count_wall_crossings(fp, track) == 2
    assert count_wall_crossings(fp, track[:1]) == 0


def test_shape_mismatch_is_an_error():
    fp = FloorPlan(np.zeros((4, 4), dtype=bool), 1.0)
    with pytest.raises(ValueError):
        crosses_wall(fp, np.zeros((3, 2)), np.zeros((2, 2)))


def test_long_segment_visits_a_connected_chain():
    # every pixel step of the walk is 4- or corner-connected: no gaps along a long segment
    touched = touched_pixels((0.3, 0.7), (57.9, 23.1))
    assert len(touched) >= 58 + 23
    assert touched == touched_pixels_reference((0.3, 0.7), (57.9, 23.1))


def test_world_check_agrees_with_oracle_on_the_bundled_office_map():
    """Small rooms at 0.1 m: most moves alternate exact walking and clearance jumps."""
    from pathlib import Path

    fp = FloorPlan.load(Path(__file__).resolve().parents[2] / "maps" / "office.yaml")
    rng = np.random.default_rng(3)
    a_xy = fp.sample_free(2500, rng)
    b_xy = a_xy + rng.normal(0.0, 1.5, a_xy.shape)
    fast = crosses_wall(fp, a_xy, b_xy)
    ua, ub = fp.world_to_pixel(a_xy), fp.world_to_pixel(b_xy)
    mask = fp.wall_mask
    h, w = mask.shape
    expected = np.array([
        any(not (0 <= r < h and 0 <= c < w) or mask[r, c] for r, c in touched_pixels_reference(ua[i], ub[i]))
        for i in range(a_xy.shape[0])
    ])
    assert np.array_equal(fast, expected)
    assert 0.1 < expected.mean() < 0.6


def test_clearance_is_conservative_and_refreshable():
    mask = np.zeros((30, 30), dtype=bool)
    fp = FloorPlan(mask, 1.0)
    a, b = np.array([[15.5, 15.5]]), np.array([[16.0, 20.5]])  # not axis-aligned: uses the clearance
    assert not crosses_wall(fp, a, b)[0]
    fp.wall_mask[10, :] = True  # edit in place: row 10 is y in [19, 20)
    from mapfilter.maps.walls import forget_clearance

    forget_clearance(fp)
    assert crosses_wall(fp, a, b)[0]
    c = clearance_px(fp)
    rows, cols = np.nonzero(~fp.wall_mask)
    # brute force: every segment shorter than the clearance from a pixel centre stays clear
    rng = np.random.default_rng(0)
    pick = rng.integers(0, rows.size, 300)
    for r, col in zip(rows[pick], cols[pick]):
        for angle in np.linspace(0, 2 * np.pi, 16, endpoint=False):
            start = (col + rng.random(), r + rng.random())
            length = 0.999 * c[r, col]
            end = (start[0] + length * np.cos(angle), start[1] + length * np.sin(angle))
            touched = touched_pixels_reference(start, end)
            assert not any(not (0 <= rr < 30 and 0 <= cc < 30) or fp.wall_mask[rr, cc] for rr, cc in touched)


def test_the_filters_check_is_the_exact_walk_on_lattice_points_and_near_pixel_edges():
    """``crosses_wall`` (clearance, then the band check) against the exact walk of the same segments,
    with many end points on the lattice, on half pixels and a hair off them: the band check's
    undecided moves (the walk decides them) are exercised and agree."""
    rng = np.random.default_rng(11)
    size = 40
    mask = rng.random((size, size)) < 0.05
    mask[12, 5:30] = True
    mask[5:35, 20] = True
    fp = FloorPlan(mask, 1.0)
    a, b = _random_segments(rng, 20_000, size)
    hair = rng.random(a.shape) < 0.2
    a[hair] += rng.choice([-1e-7, 1e-7, -1e-12, 1e-12], hair.sum())
    a_xy, b_xy = fp.pixel_to_world(a), fp.pixel_to_world(b)
    a, b = fp.world_to_pixel(a_xy), fp.world_to_pixel(b_xy)  # the check's own pixel coordinates (1 m pixels)
    assert np.array_equal(crosses_wall(fp, a_xy, b_xy), crosses_wall_uv(mask, a, b))
    # the band check itself leaves the near-edge moves to the walk, and decides the others
    grid = wall_grid(fp)
    found = np.array([_bands(grid.wall_ahead_in_row, size, size, *a[i], *b[i]) if abs(b[i, 1] - a[i, 1]) <=
                      abs(b[i, 0] - a[i, 0]) else _bands(grid.wall_ahead_in_column, size, size, a[i, 1], a[i, 0],
                                                         b[i, 1], b[i, 0]) for i in range(len(a))])
    assert 0.02 < (found == 2).mean() < 0.5
    decided = found != 2
    assert np.array_equal(found[decided] == 1, crosses_wall_uv(mask, a[decided], b[decided]))


def test_the_clearance_is_the_distance_from_any_point_of_the_pixel_to_the_nearest_wall_square():
    rng = np.random.default_rng(5)
    mask = rng.random((23, 31)) < 0.04
    fp = FloorPlan(mask, 0.5)
    table = clearance_px(fp)
    # brute force: the gap between two unit squares along each axis, over every wall pixel and the
    # ring of pixels just outside the map
    padded = np.pad(mask, 1, constant_values=True)
    walls = np.argwhere(padded) - 1
    rows, cols = np.mgrid[0:23, 0:31]
    gap_r = np.maximum(np.abs(rows[..., None] - walls[:, 0]) - 1, 0)
    gap_c = np.maximum(np.abs(cols[..., None] - walls[:, 1]) - 1, 0)
    exact = np.sqrt(gap_r ** 2 + gap_c ** 2).min(axis=-1)
    assert np.all(table <= exact) and np.all(table >= exact - 2e-3)  # the margin: float32 and a shave


def test_moves_shorter_than_the_clearance_never_cross_and_the_clearance_decides_many():
    from pathlib import Path

    fp = FloorPlan.load(Path(__file__).resolve().parents[2] / "maps" / "office.yaml")
    rng = np.random.default_rng(8)
    a_xy = fp.sample_free(4000, rng)
    b_xy = a_xy + rng.normal(0.0, 0.6, a_xy.shape)
    ua, ub = fp.world_to_pixel(a_xy), fp.world_to_pixel(b_xy)
    rows, cols, _ = fp.pixel_index(a_xy)
    short = np.linalg.norm(ub - ua, axis=1) < clearance_px(fp)[rows, cols]
    assert 0.2 < short.mean() < 0.9
    mask = fp.wall_mask
    h, w = mask.shape
    for i in np.flatnonzero(short)[:600]:
        assert not any(not (0 <= r < h and 0 <= c < w) or mask[r, c] for r, c in touched_pixels_reference(ua[i], ub[i]))
    assert not crosses_wall(fp, a_xy[short], b_xy[short]).any()


def test_a_run_longer_than_the_table_can_count_is_left_to_the_walk():
    width = 140_000
    ahead = np.full((3, width), 65_535, dtype=np.uint16)  # no wall within the table's reach
    assert _bands(ahead, 3, width, 10.5, 1.2, 100_000.5, 1.8) == 2  # a run of 100,000 pixels: undecided
    assert _bands(ahead, 3, width, 10.5, 1.2, 30_000.5, 1.8) == 0


def _world_segments(rng, n, size, mask):
    fp = FloorPlan(mask, 0.5, origin_m=(-2.0, 1.0))
    a, b = _random_segments(rng, n, size)
    a_xy, b_xy = fp.pixel_to_world(a), fp.pixel_to_world(b)
    return fp, a_xy, b_xy


def test_the_look_at_a_move_is_the_exact_check_whenever_it_answers():
    """look_move (a few table reads, no branch) says free or wall only where the exact walk says the
    same, on lattice points, half pixels and moves off the map, and answers most moves."""
    rng = np.random.default_rng(12)
    size = 30
    mask = rng.random((size, size)) < 0.04
    mask[10, 3:25] = True
    fp, a_xy, b_xy = _world_segments(rng, 6000, size, mask)
    grid = wall_grid(fp)
    looks = np.array([look_move(grid, *a_xy[i], *b_xy[i]) for i in range(len(a_xy))])
    free, wall = looks[:, 0], looks[:, 1]
    exact = crosses_wall_uv(mask, fp.world_to_pixel(a_xy), fp.world_to_pixel(b_xy))
    assert not (free & wall).any()
    assert not exact[free].any() and exact[wall].all()
    assert free.mean() > 0.2 and wall.mean() > 0.1 and (free | wall).mean() > 0.4  # the look decides many


def test_one_look_at_two_moves_to_one_end_is_the_exact_check_of_both_whenever_it_answers():
    rng = np.random.default_rng(13)
    size = 30
    mask = rng.random((size, size)) < 0.03
    mask[5:25, 15] = True
    fp, a_xy, c_xy = _world_segments(rng, 4000, size, mask)
    b_xy = c_xy + rng.normal(0.0, 0.8, c_xy.shape)  # a second start near the end, like a jitter's
    grid = wall_grid(fp)
    looks = np.array([look_two_moves(grid, *a_xy[i], *b_xy[i], *c_xy[i]) for i in range(len(a_xy))])
    free, wall = looks[:, 0], looks[:, 1]
    uv = fp.world_to_pixel
    either = crosses_wall_uv(mask, uv(a_xy), uv(c_xy)) | crosses_wall_uv(mask, uv(b_xy), uv(c_xy))
    assert not (free & wall).any()
    assert not either[free].any() and either[wall].all()
    assert free.mean() > 0.15 and wall.mean() > 0.1  # both answers are exercised


def test_a_box_is_free_exactly_when_no_wall_and_no_outside_pixel_meets_it():
    """The summed-area table's count of the pixels whose closed squares meet a box, against counting
    them one by one; boxes on pixel edges, partly or wholly off the map (the outside is wall)."""
    rng = np.random.default_rng(14)
    h, w = 17, 23
    mask = rng.random((h, w)) < 0.05
    grid = wall_grid(FloorPlan(mask, 1.0))
    corners = rng.uniform(-3.0, 26.0, (3000, 4))
    corners[::3] = np.round(corners[::3])  # on pixel edges
    for u_a, u_b, v_a, v_b in corners:
        u_min, u_max, v_min, v_max = min(u_a, u_b), max(u_a, u_b), min(v_a, v_b), max(v_a, v_b)
        cols = range(int(np.ceil(u_min)) - 1, int(np.floor(u_max)) + 1)
        rows = range(int(np.ceil(v_min)) - 1, int(np.floor(v_max)) + 1)
        expected = not any(not (0 <= r < h and 0 <= c < w) or mask[r, c] for r in rows for c in cols)
        assert _box_is_free(grid, u_min, u_max, v_min, v_max) == expected, (u_min, u_max, v_min, v_max)
