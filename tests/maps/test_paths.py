"""Shortest wall-free paths and tracks made wall-free with them."""

import numpy as np
import pytest

from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.paths import detour_wall_crossings, free_path, nearest_free
from mapfilter.maps.walls import count_wall_crossings


def two_rooms() -> FloorPlan:
    """20 x 10 m at 0.1 m/px: a wall at x = 10 m with a door at y in [7, 8] m, outer walls."""
    wall = np.zeros((100, 200), dtype=bool)
    wall[[0, -1], :] = wall[:, [0, -1]] = True
    wall[:, 99:101] = True
    wall[20:30, 99:101] = False  # rows 20-29 from the top: y in (7, 8] m
    return FloorPlan(wall, 0.1, (0.0, 0.0))


def test_free_path_goes_through_the_door():
    plan = two_rooms()
    a, b = np.array([5.0, 2.0]), np.array([15.0, 2.0])
    assert count_wall_crossings(plan, np.stack([a, b])) == 1
    path = free_path(plan, a, b)
    assert path is not None and np.allclose(path[0], a) and np.allclose(path[-1], b)
    assert count_wall_crossings(plan, path) == 0
    at_wall = path[np.abs(path[:, 0] - 10.0) < 0.2]
    assert np.all((at_wall[:, 1] > 7.0) & (at_wall[:, 1] < 8.0))
    # about the length of the two straight legs via the door, not much more
    length = np.linalg.norm(np.diff(path, axis=0), axis=1).sum()
    direct = np.linalg.norm([5.0, 5.5]) * 2
    assert direct - 0.5 < length < direct * 1.1


def test_no_path_into_a_closed_room_or_from_a_wall():
    plan = two_rooms()
    closed = plan.wall_mask.copy()
    closed[20:30, 99:101] = True
    sealed = FloorPlan(closed, 0.1, (0.0, 0.0))
    assert free_path(sealed, [5.0, 2.0], [15.0, 2.0]) is None
    assert free_path(plan, [10.0, 2.0], [15.0, 2.0]) is None  # starts inside the wall


def test_detour_removes_every_crossing_and_keeps_time_order():
    plan = two_rooms()
    t = np.array([0.0, 1.0, 2.0, 3.0])
    xy = np.array([[3.0, 2.0], [5.0, 2.0], [15.0, 2.0], [16.0, 3.0]])
    t2, xy2 = detour_wall_crossings(plan, t, xy)
    assert count_wall_crossings(plan, xy2) == 0
    assert np.all(np.diff(t2) >= 0) and t2[0] == 0.0 and t2[-1] == 3.0
    for ti, p in zip(t, xy):  # every original point is kept at its time
        k = np.flatnonzero(np.isclose(t2, ti))
        assert k.size and np.allclose(xy2[k[0]], p)
    free_track = np.array([[3.0, 2.0], [5.0, 2.0]])
    t3, xy3 = detour_wall_crossings(plan, t[:2], free_track)
    assert np.array_equal(xy3, free_track) and np.array_equal(t3, t[:2])


def test_nearest_free_moves_only_blocked_points_and_lands_next_to_the_wall():
    plan = two_rooms()
    xy = np.array([[5.0, 2.0], [10.02, 2.0], [-3.0, 5.0]])  # free, inside the wall, off the map
    out = nearest_free(plan, xy)
    assert np.array_equal(out[0], xy[0])
    assert plan.is_free(out[1:]).all()
    assert abs(out[1, 0] - 10.0) < 0.2 and abs(out[1, 1] - 2.0) < 0.1  # beside the wall, not through the door
    assert 0.0 < out[2, 0] < 0.25 and abs(out[2, 1] - 5.0) < 0.1


def test_wall_free_track_of_a_track_through_a_wall():
    from mapfilter.maps.paths import wall_free_track

    plan = two_rooms()
    t = np.linspace(0.0, 10.0, 21)
    xy = np.column_stack([np.linspace(6.0, 14.0, 21), np.full(21, 3.0)])  # straight through the wall
    t2, xy2 = wall_free_track(plan, t, xy)
    assert count_wall_crossings(plan, xy2) == 0 and plan.is_free(xy2).all()
    assert np.all(np.diff(t2) >= 0) and t2[0] == t[0] and t2[-1] == t[-1]
    assert xy2[:, 1].max() > 7.0  # it went round by the door


def test_wall_free_track_keeps_the_walk_in_one_free_area():
    from mapfilter.maps.paths import wall_free_track

    wall = two_rooms().wall_mask.copy()
    wall[60:80, 40:42] = wall[60:80, 58:60] = True  # a closed 1.6 x 1.8 m cell in the left room
    wall[60:62, 40:60] = wall[78:80, 40:60] = True
    plan = FloorPlan(wall, 0.1, (0.0, 0.0))
    t = np.arange(6.0)
    xy = np.array([[2.0, 5.0], [3.0, 4.0], [5.0, 3.0], [6.0, 3.0], [7.0, 4.0], [8.0, 5.0]])  # [5, 3] is in the cell
    assert not free_path(plan, xy[1], xy[2])
    t2, xy2 = wall_free_track(plan, t, xy)
    assert count_wall_crossings(plan, xy2) == 0 and plan.is_free(xy2).all()


def test_a_search_over_too_many_pixels_runs_on_coarser_cells_and_still_crosses_no_wall():
    """free_path(max_cells=): a fine plan's window searched on k x k cells, a cell free only where
    all its pixels are: the path crosses no wall, is about as long as the native one, and goes
    through the one door; an end whose cell is not free is searched at the native pixels."""
    from mapfilter.maps.floorplan import FloorPlan
    from mapfilter.maps.paths import free_path
    from mapfilter.maps.walls import crosses_wall

    res = 0.05
    wall = np.zeros((int(20 / res), int(30 / res)), dtype=bool)  # 20 m x 30 m, two rooms, a door at the far end
    wall[:2, :] = wall[-2:, :] = wall[:, :2] = wall[:, -2:] = True
    wall[wall.shape[0] // 2 - 2:wall.shape[0] // 2 + 2, :-int(2 / res)] = True
    plan = FloorPlan(wall, res)
    a, b = np.array([3.0, 8.0]), np.array([4.0, 12.0])
    native = free_path(plan, a, b)
    coarse = free_path(plan, a, b, max_cells=20_000)
    for path in (native, coarse):
        assert path is not None and not crosses_wall(plan, path[:-1], path[1:]).any()
        assert path[:, 0].max() > 27.0  # round the wall's far end, through the door
    length = [float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) for p in (native, coarse)]
    assert length[1] == pytest.approx(length[0], rel=0.05)
    assert len(coarse) < len(native) / 2  # the coarser cells: fewer of them on the way
    near = np.array([3.0, 9.85])  # 5 cm from the wall: its coarse cell holds wall pixels
    path = free_path(plan, near, b, max_cells=20_000)
    assert path is not None and not crosses_wall(plan, path[:-1], path[1:]).any()


def _numpy_grid_graph(free: np.ndarray):
    """The search's graph as scipy was given it (the oracle of ``paths._grid_search``): every
    pixel pair as a COO entry both ways, to scipy's CSR (sorted, no duplicates)."""
    import math

    from scipy.sparse import coo_matrix

    h, w = free.shape
    index = np.full(free.shape, -1, dtype=np.int64)
    index[free] = np.arange(int(free.sum()))
    src, dst, cost = [], [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        r = np.arange(max(0, -dr), h - max(0, dr))
        c = np.arange(max(0, -dc), w - max(0, dc))
        rr, cc = np.meshgrid(r, c, indexing="ij")
        ok = free[rr, cc] & free[rr + dr, cc + dc]
        if dr and dc:  # diagonal: through a lattice corner, the two other pixels must be free too
            ok &= free[rr + dr, cc] & free[rr, cc + dc]
        src.append(index[rr[ok], cc[ok]])
        dst.append(index[rr[ok] + dr, cc[ok] + dc])
        cost.append(np.full(int(ok.sum()), math.hypot(dr, dc)))
    n = int(free.sum())
    s, d, c = np.concatenate(src), np.concatenate(dst), np.concatenate(cost)
    return coo_matrix((np.concatenate([c, c]), (np.concatenate([s, d]), np.concatenate([d, s]))), shape=(n, n)).tocsr()


def _masks(rng: np.random.Generator):
    """Random masks (thin walls with a gap, lone wall pixels, free borders), an open one (ties
    everywhere: equal-length paths in every direction) and one room with a wall across."""
    h, w = rng.integers(5, 60, 2)
    free = rng.random((h, w)) > rng.uniform(0.05, 0.4)
    free[rng.integers(0, h), :] = False  # a wall across, with a gap
    free[:, rng.integers(0, w)] = True
    yield free
    yield np.ones(rng.integers(20, 90, 2), dtype=bool)
    room = np.ones((70, 50), dtype=bool)
    room[35, 3:] = False
    yield room


@pytest.mark.parametrize("seed", range(4))
def test_the_search_finds_scipys_path_pixel_for_pixel(seed):
    """paths._grid_search (Dijkstra stopped at its goal) against scipy's dijkstra over the whole
    graph, the search it replaced: the same shortest path between random free pixels, pixel for
    pixel, ties broken alike (an open grid has many equal paths), None where scipy finds none.
    (an older scipy, whose Fibonacci heap may break ties otherwise: the path's length only.)"""
    import scipy
    from scipy.sparse.csgraph import dijkstra

    from mapfilter.maps.paths import _grid_path

    queue_order = tuple(int(p) for p in scipy.__version__.split(".")[:2]) >= (1, 15)

    rng = np.random.default_rng(seed)
    found = 0
    for free in _masks(rng):
        oracle = _numpy_grid_graph(free)
        rows, cols = np.nonzero(free)
        n = rows.size
        for _ in range(25):
            a, b = rng.integers(0, n, 2)
            path = _grid_path(free, (rows[a], cols[a]), (rows[b], cols[b]))
            dist, pred = dijkstra(oracle, indices=int(a), return_predecessors=True)
            if not np.isfinite(dist[b]):
                assert path is None
                continue
            moves = np.diff(path, axis=0)
            assert np.abs(moves).max(initial=0) <= 1 and free[path[:, 0], path[:, 1]].all()
            corner = (moves != 0).all(axis=1)  # a diagonal move past two free pixels
            assert free[path[1:, 0][corner], path[:-1, 1][corner]].all()
            assert free[path[:-1, 0][corner], path[1:, 1][corner]].all()
            assert np.hypot(moves[:, 0], moves[:, 1]).sum() == pytest.approx(dist[b], rel=1e-12)
            chain = [int(b)]
            while chain[-1] != a:
                chain.append(int(pred[chain[-1]]))
            if queue_order:
                np.testing.assert_array_equal(path, np.column_stack([rows[chain[::-1]], cols[chain[::-1]]]))
            found += 1
    assert found > 50
