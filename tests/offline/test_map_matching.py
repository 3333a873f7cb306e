"""Map matching of a placed walk: forward-backward over the free cells of the plan."""

import math

import numpy as np
import pytest

from mapfilter.offline.map_matching import MapMatch, MapMatchConfig, _anchors_by_step, _Grid, _unit_moves, map_match
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import crosses_wall


def block_plan(free_cells: np.ndarray, cell_px: int = 4, resolution_m: float = 0.25) -> FloorPlan:
    """A plan whose walls fill whole 1 m cells: ``free_cells[row, col]`` with row 0 at y = 0."""
    wall = ~np.kron(free_cells, np.ones((cell_px, cell_px), dtype=bool))
    return FloorPlan(wall[::-1].copy(), resolution_m, (0.0, 0.0))  # mask row 0 is the top


def brute_force_means(free: np.ndarray, moves_x: list[int], step_var_cells2: float,
                      anchors: dict[int, tuple[float, float]], sigma_m: float) -> np.ndarray:
    """Posterior means by explicit transition matrices (an independent forward-backward)."""
    ny, nx = free.shape
    n = nx * ny
    m = np.diag(free.ravel().astype(float))
    shift_x = np.zeros((n, n))  # mass at (r, c) -> (r, c + 1)
    for r in range(ny):
        for c in range(nx - 1):
            shift_x[r * nx + c + 1, r * nx + c] = 1.0
    w = step_var_cells2 / 2.0
    tri_x, tri_y = (np.diag(np.full(k, 1 - 2 * w)) + np.diag(np.full(k - 1, w), 1) + np.diag(np.full(k - 1, w), -1)
                    for k in (nx, ny))
    blur = np.kron(tri_y, np.eye(nx)) @ np.kron(np.eye(ny), tri_x)
    xs, ys = np.meshgrid(np.arange(nx) + 0.5, np.arange(ny) + 0.5)
    X, Y = xs.ravel(), ys.ravel()

    def like(k):
        if k not in anchors:
            return np.ones(n)
        ax, ay = anchors[k]
        return np.exp(-0.5 * ((X - ax) ** 2 + (Y - ay) ** 2) / sigma_m ** 2)

    transitions = []
    for dx in moves_x:
        t = np.eye(n)
        for _ in range(dx):
            t = m @ shift_x @ t
        transitions.append(m @ blur @ t)
    alpha = [free.ravel() * like(0)]
    alpha[0] = alpha[0] / alpha[0].sum()
    for k, t in enumerate(transitions, start=1):
        a = like(k) * (t @ alpha[-1])
        alpha.append(a / a.sum())
    beta = free.ravel().astype(float)
    means = np.zeros((len(alpha), 2))
    for k in range(len(alpha) - 1, -1, -1):
        p = alpha[k] * beta
        p = p / p.sum()
        means[k] = [(p * X).sum(), (p * Y).sum()]
        if k:
            beta = transitions[k - 1].T @ (like(k) * beta)
            beta = beta / beta.max()
    return means



# ---- the plain numpy forward-backward that the numba kernels must repeat -----------------------
# (map_match as it was before its numba kernels: one numpy array per operation)
def _shift(a: np.ndarray, dx: int, dy: int) -> np.ndarray:
    """Move the content one cell along x (dx = +-1) or y (dy = +-1), zero-filled."""
    out = np.zeros_like(a)
    if dx == 1:
        out[:, 1:] = a[:, :-1]
    elif dx == -1:
        out[:, :-1] = a[:, 1:]
    elif dy == 1:
        out[1:, :] = a[:-1, :]
    elif dy == -1:
        out[:-1, :] = a[1:, :]
    return out


def _blur(a: np.ndarray, weight: float) -> np.ndarray:
    """Three-tap blur [w, 1 - 2w, w] along both axes: adds variance 2w (cells^2) per axis."""
    out = (1.0 - 2.0 * weight) * a
    out[:, 1:] += weight * a[:, :-1]
    out[:, :-1] += weight * a[:, 1:]
    both = (1.0 - 2.0 * weight) * out
    both[1:, :] += weight * out[:-1, :]
    both[:-1, :] += weight * out[1:, :]
    return both


def numpy_map_match(floorplan: FloorPlan, t_s: np.ndarray, xy_m: np.ndarray, anchor_t_s: np.ndarray,
                    config: MapMatchConfig = MapMatchConfig()) -> MapMatch:
    """``map_match`` in plain numpy, step by step as the kernels do it (same grid, moves, observations,
    checkpoints)."""
    t = np.asarray(t_s, dtype=np.float64).reshape(-1)
    xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
    grid = _Grid(floorplan, xy, config)
    free = grid.free
    if not free.any():
        return MapMatch(t, xy.copy(), 0)
    K = t.shape[0]
    X, Y = np.meshgrid(grid.x_m, grid.y_m)
    anchors_at = _anchors_by_step(t, xy, anchor_t_s)
    inv_var = 0.5 / config.anchor_sigma_m ** 2

    def likelihood(k: int) -> np.ndarray | None:
        if k not in anchors_at:
            return None
        out = free
        for ax, ay in anchors_at[k]:
            out = out * np.outer(np.exp(-inv_var * (grid.y_m - ay) ** 2), np.exp(-inv_var * (grid.x_m - ax) ** 2))
        return out

    units = _unit_moves(xy, config.cell_m)
    variance_cells2 = (config.step_sigma_m / config.cell_m) ** 2
    n_blur = int(math.ceil(variance_cells2 / 0.5 - 1e-9))
    blur_weight = variance_cells2 / (2.0 * n_blur)

    def predict(a: np.ndarray, k: int) -> np.ndarray:
        for dx, dy in units[k - 1]:
            a = _shift(a, dx, dy) * free
        for _ in range(n_blur):
            a = _blur(a, blur_weight) * free
        return a

    def forward(a: np.ndarray | None, k: int) -> tuple[np.ndarray, bool]:
        a = free.copy() if a is None else predict(a, k)
        observed = likelihood(k)
        if observed is not None:
            a = a * observed
        total = a.sum()
        restarted = False
        if not total > 1e-250:
            a, restarted = (free if observed is None else observed), k > 0
            total = a.sum()
            if not total > 0:
                a, total = np.ones_like(free), float(free.size)
        return a / total, restarted

    every = config.checkpoint_every
    checkpoints: dict[int, np.ndarray] = {}
    restarted_at = np.zeros(K, dtype=bool)
    a = None
    for k in range(K):
        a, restarted_at[k] = forward(a, k)
        if k % every == 0:
            checkpoints[k] = a

    out_xy = np.zeros((K, 2))
    out_std = np.zeros(K)
    beta = free.copy()
    for start in range(((K - 1) // every) * every, -1, -every):
        segment = [checkpoints[start]]
        for k in range(start + 1, min(start + every, K)):
            segment.append(forward(segment[-1], k)[0])
        for k in range(min(start + every, K) - 1, start - 1, -1):
            p = segment[k - start] * beta
            total = p.sum()
            if not total > 0:
                p, total = segment[k - start], segment[k - start].sum()
            p = p / total
            out_xy[k] = float((p * X).sum()), float((p * Y).sum())
            out_std[k] = np.sqrt(0.5 * ((p * (X - out_xy[k, 0]) ** 2).sum() + (p * (Y - out_xy[k, 1]) ** 2).sum()))
            if k == 0:
                break
            if restarted_at[k]:
                beta = free.copy()
                continue
            observed = likelihood(k)
            g = beta if observed is None else beta * observed
            for _ in range(n_blur):
                g = _blur(g * free, blur_weight)
            for dx, dy in reversed(units[k - 1]):
                g = _shift(g * free, -dx, -dy)
            beta = g * free
            peak = beta.max()
            beta = beta / peak if peak > 0 else free.copy()
    return MapMatch(t, out_xy, int(restarted_at.sum()), out_std)


def test_forward_backward_equals_explicit_transition_matrices():
    free = np.ones((5, 9), dtype=bool)
    free[2, 3:7] = False  # a wall bar in the middle: the cloud must go round it
    free[0, 0] = False
    plan = block_plan(free)
    moves_x = [1, 1, 2, 1, 0, 1]
    xy = np.column_stack([0.5 + np.concatenate([[0], np.cumsum(moves_x)]), np.full(7, 2.5)])
    t = np.arange(7.0)
    anchors_t = np.array([0.0, 2.0, 3.0, 6.0])
    config = MapMatchConfig(cell_m=1.0, step_sigma_m=0.5, anchor_sigma_m=1.5, window_margin_m=50.0)
    got = map_match(plan, t, xy, anchors_t, config)
    expected = brute_force_means(free, moves_x, 0.25, {int(k): tuple(xy[int(k)]) for k in anchors_t}, 1.5)
    assert got.restarts == 0
    np.testing.assert_allclose(got.xy_m, expected, atol=1e-9)


def test_checkpointed_backward_pass_equals_keeping_every_message():
    rng = np.random.default_rng(3)
    free = rng.random((20, 30)) > 0.15
    plan = block_plan(free)
    xy = np.column_stack([5 + np.cumsum(rng.normal(0.3, 0.4, 90)), 10 + np.cumsum(rng.normal(0, 0.4, 90))])
    t = np.arange(90.0)
    results = [map_match(plan, t, xy, t[::4], MapMatchConfig(cell_m=1.0, checkpoint_every=every)).xy_m
               for every in (1, 7, 32, 200)]
    for other in results[1:]:
        np.testing.assert_allclose(other, results[0], rtol=0, atol=1e-9)


def test_a_walk_placed_beside_its_corridor_is_pulled_into_it():
    wall = np.ones((200, 600), dtype=bool)  # 60 x 20 m at 0.1 m/px
    wall[100:125, :] = False  # a corridor, y in [7.5, 10] m
    wall[20:200, 280:305] = False  # and a side corridor north-south, x in [28, 30.5] m, y <= 18 m
    plan = FloorPlan(wall, 0.1, (0.0, 0.0))
    # the truth: east along y = 8.75, then north up the side corridor
    truth = np.vstack([np.column_stack([np.arange(5.0, 29.5, 0.7), np.full(35, 8.75)]),
                       np.column_stack([np.full(12, 29.25), 8.75 + 0.7 * np.arange(1, 13)])])
    placed = truth + [2.0, 2.5]  # the placement's bias: 3.2 m, most of it into the wall
    t = np.arange(len(truth), dtype=float)
    matched = map_match(plan, t, placed, t[::3])
    before = np.linalg.norm(placed - truth, axis=1).mean()
    after = np.linalg.norm(matched.xy_m - truth, axis=1).mean()
    assert after < 0.5 * before
    assert plan.is_free(matched.xy_m).mean() > 0.9 > plan.is_free(placed).mean()


def test_in_open_space_the_walk_keeps_its_shape():
    plan = FloorPlan(np.zeros((400, 400), dtype=bool), 0.25, (0.0, 0.0))  # 100 x 100 m, no wall
    k = np.arange(120)
    xy = np.column_stack([30 + 8 * np.cos(k / 20), 50 + 8 * np.sin(k / 20)]) + [0.0, 0.0]
    matched = map_match(plan, k * 0.5, xy, k[::5] * 0.5)
    assert np.abs(matched.xy_m - xy).max() < 0.35  # within the grid's own rounding of the moves
    assert matched.restarts == 0


def test_whole_walk_track_after_matching_crosses_no_wall():
    from mapfilter.offline.placement import WalkPlacement
    from mapfilter.offline.whole_walk import whole_walk_track

    wall = np.ones((200, 400), dtype=bool)
    wall[40:80, :] = False   # corridor y in [12, 16] m
    wall[120:160, :] = False  # corridor y in [4, 8] m, a wall between them
    plan = FloorPlan(wall, 0.1, (0.0, 0.0))
    xy = np.column_stack([np.linspace(3, 37, 50), np.full(50, 10.0)])  # placed on the wall between
    placement = WalkPlacement(np.arange(50.0), xy, 0.0, xy[0], 4.0, 20)
    track = whole_walk_track(plan, placement, np.arange(0.0, 50.0, 3.0))
    assert plan.is_free(track.xy_m).all()
    assert not crosses_wall(plan, track.xy_m[:-1], track.xy_m[1:]).any()


def test_bad_input_is_refused():
    plan = FloorPlan(np.zeros((40, 40), dtype=bool), 0.25, (0.0, 0.0))
    with pytest.raises(ValueError, match="one per time"):
        map_match(plan, np.arange(3.0), np.zeros((4, 2)), np.arange(3.0))
    with pytest.raises(ValueError, match="one per time"):
        map_match(plan, np.arange(2.0), np.array([[1.0, 1.0], [np.nan, 2.0]]), np.arange(2.0))
    with pytest.raises(ValueError, match="anchor_sigma_m"):
        MapMatchConfig(anchor_sigma_m=0.0)
    with pytest.raises(ValueError, match="checkpoint_every"):
        MapMatchConfig(checkpoint_every=0)


def test_a_walk_far_from_any_free_space_is_returned_as_it_is():
    wall = np.ones((80, 80), dtype=bool)
    wall[:8, :8] = False  # a little free room in one corner, 20 m x 20 m plan at 0.25 m/px
    plan = FloorPlan(wall, 0.25, (0.0, 0.0))
    xy = np.column_stack([np.linspace(60.0, 70.0, 15), np.full(15, 100.0)])  # off the plan
    matched = map_match(plan, np.arange(15.0), xy, np.arange(0.0, 15.0, 3.0))
    np.testing.assert_array_equal(matched.xy_m, xy)


@pytest.mark.parametrize("seed", range(6))
def test_numba_kernels_equal_the_plain_numpy_steps(seed):
    # random walls, a walk that wanders (several unit moves a step, both signs, along both
    # axes, steps with no move), scans at random steps (two on one step too), blurs 1 to 3
    rng = np.random.default_rng(seed)
    free = rng.random((rng.integers(8, 25), rng.integers(8, 25))) > rng.uniform(0.1, 0.4)
    plan = block_plan(free)
    n = int(rng.integers(2, 70))
    moves = rng.normal(0, rng.uniform(0.3, 2.5), (n - 1, 2)) * (rng.random((n - 1, 1)) > 0.1)
    xy = np.array([free.shape[1] / 2, free.shape[0] / 2]) + np.vstack([[0, 0], np.cumsum(moves, axis=0)])
    t = np.arange(n, dtype=float)
    anchors_t = np.sort(np.concatenate([rng.choice(t, size=max(1, n // 4)), t[-1:] + 0.0]))
    config = MapMatchConfig(cell_m=float(rng.choice([0.5, 1.0])), step_sigma_m=float(rng.uniform(0.2, 1.2)),
                            anchor_sigma_m=float(rng.uniform(0.5, 6.0)), window_margin_m=float(rng.uniform(0, 5)),
                            checkpoint_every=int(rng.integers(1, 12)))
    got = map_match(plan, t, xy, anchors_t, config)
    expected = numpy_map_match(plan, t, xy, anchors_t, config)
    assert got.restarts == expected.restarts
    np.testing.assert_allclose(got.xy_m, expected.xy_m, rtol=0, atol=1e-9)
    np.testing.assert_allclose(got.std_m, expected.std_m, rtol=0, atol=1e-6)


def test_numba_kernels_equal_the_plain_numpy_steps_through_restarts():
    # a walk that leaves its corridor: the plan blocks every path (restart), and an anchor too
    # far from every free cell for its Gaussian (the all-ones fallback, ones on the walls too),
    # where the walker then stands (steps without a move carry the ones into the blurs)
    wall = np.ones((12, 400), dtype=bool)  # 400 x 12 m at 1 m/px
    wall[4:8, :40] = False  # a corridor along the west end only
    wall[2:10, 8:12] = False  # a room across it
    plan = FloorPlan(wall, 1.0, (0.0, 0.0))
    x = np.concatenate([np.linspace(2, 35, 12), np.linspace(36, 395, 10), np.full(6, 395.0), np.linspace(390, 300, 6)])
    xy = np.column_stack([x, np.full(x.size, 6.0)])
    t = np.arange(float(x.size))
    config = MapMatchConfig(cell_m=1.0, step_sigma_m=1.2, anchor_sigma_m=2.0, window_margin_m=5.0, checkpoint_every=5)
    anchors_t = np.array([0.0, 5.0, 11.0, 21.0, 24.0, 31.0, 33.0])
    got = map_match(plan, t, xy, anchors_t, config)
    expected = numpy_map_match(plan, t, xy, anchors_t, config)
    assert got.restarts == expected.restarts >= 2
    np.testing.assert_allclose(got.xy_m, expected.xy_m, rtol=0, atol=1e-9)
    np.testing.assert_allclose(got.std_m, expected.std_m, rtol=0, atol=1e-6)
