"""Map matching of a placed walk: an exact forward-backward pass over the free space.

The whole-walk placement (``offline.placement``) puts the walk's dead-reckoned shape where all
of its WiFi evidence says, as one rigid piece. A rigid shape still drifts (heading and step
length errors add up) and knows nothing of walls. This stage lets the walk bend where the walls say it must, as the 3rd place
of the ILC 2.0 competition did: a hidden Markov model on a grid of the floor's free cells whose
transition is the walk's own dead-reckoned move plus a little diffusion, with moves into wall
cells given probability zero, and whose observations are the placed shape's positions at the
scan times (a Gaussian of ``anchor_sigma_m``: the placement's typical error). The forward and
the backward pass make every point's estimate use the whole walk (no particle degeneracy).

Moves are done one cell at a time (the fractional remainder carried to the next step), with
the mass that lands in a wall cell dropped after each, so no mass jumps a wall. The forward
messages are kept at checkpoints only and recomputed per segment in the backward pass: memory
grows with the walk's length / ``checkpoint_every``, not with the length.

What it gains over the placed shape alone, and the variants measured: docs/accuracy.md
("Map matching the placed walk").
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numba import njit

from mapfilter.maps.floorplan import FloorPlan

__all__ = ["MapMatchConfig", "MapMatch", "map_match"]


@dataclasses.dataclass(frozen=True)
class MapMatchConfig:
    """Parameters of the forward-backward map matching (the same for every floor and walk):
    the values that gained on every ILC set, with cells small beside a door (docs/accuracy.md,
    "Map matching the placed walk")."""

    cell_m: float = 0.25  # grid cell; a cell is free when most of it is free on the plan
    step_sigma_m: float = 0.25  # diffusion per step (shape drift: heading and length errors)
    anchor_sigma_m: float = 6.0  # spread of the placed shape's position at each scan
    window_margin_m: float = 30.0  # the grid covers the placed shape's box plus this margin
    checkpoint_every: int = 32  # forward messages kept at every this-many steps

    def __post_init__(self) -> None:
        for name in ("cell_m", "step_sigma_m", "anchor_sigma_m"):
            if not (getattr(self, name) > 0 and math.isfinite(getattr(self, name))):
                raise ValueError(f"{name} must be a positive number, got {getattr(self, name)!r}")
        if not self.window_margin_m >= 0:
            raise ValueError(f"window_margin_m must be >= 0, got {self.window_margin_m!r}")
        if not (isinstance(self.checkpoint_every, int) and self.checkpoint_every >= 1):
            raise ValueError(f"checkpoint_every must be an integer >= 1, got {self.checkpoint_every!r}")


@dataclasses.dataclass(frozen=True)
class MapMatch:
    """The map-matched walk: posterior mean positions at the shape's times, and their spread."""

    t_s: np.ndarray  # (K,)
    xy_m: np.ndarray  # (K, 2) posterior mean (may sit in a wall between two likely corridors)
    restarts: int  # times every path was blocked (the plan closes where the walk went) and the pass restarted
    # (K,) the posterior's spread: sqrt of the mean of its two position variances, as the
    # causal filter's std_m (a cell's own width not counted)
    std_m: np.ndarray | None = None


class _Grid:
    """Free cells of a window of the plan, and the unit moves between them."""

    def __init__(self, floorplan: FloorPlan, xy_m: np.ndarray, config: MapMatchConfig):
        cell = config.cell_m
        x0, x1, y0, y1 = floorplan.extent_m
        lo = np.maximum(xy_m.min(axis=0) - config.window_margin_m, [x0, y0])
        hi = np.minimum(xy_m.max(axis=0) + config.window_margin_m, [x1, y1])
        hi = np.maximum(hi, lo + cell)
        nx, ny = (int(math.ceil(v)) for v in (hi - lo) / cell)
        self.x_m = lo[0] + (np.arange(nx) + 0.5) * cell
        self.y_m = lo[1] + (np.arange(ny) + 0.5) * cell
        # most of a 3 x 3 sample of the cell free: a wall thinner than the cell still blocks
        # the cells it crosses the middle of. A sample's plan column depends on its x alone and
        # its plan row on its y alone: each is looked up once per grid column or row.
        offsets = (np.arange(3) - 1) * cell / 3
        h, w = floorplan.wall_mask.shape
        free_px = ~floorplan.wall_mask
        free_count = np.zeros((ny, nx))
        for ox in offsets:
            cols = floorplan.pixel_index(np.column_stack([self.x_m + ox, np.zeros(nx)]))[1]
            col_inside = (cols >= 0) & (cols < w)
            for oy in offsets:
                rows = floorplan.pixel_index(np.column_stack([np.zeros(ny), self.y_m + oy]))[0]
                row_inside = (rows >= 0) & (rows < h)
                sample = free_px[np.ix_(np.clip(rows, 0, h - 1), np.clip(cols, 0, w - 1))]
                free_count += sample & row_inside[:, None] & col_inside[None, :]  # outside the plan: wall
        self.free = (free_count >= 5).astype(np.float64)


# The passes below are numba kernels. A forward step (moves, n_blur blurs and masks,
# observation, row sums) is one sweep down the rows: each blur's pass along x feeds a ring of
# three rows, from which its pass along y makes the row below the newest, so the step's
# intermediate grids never leave the cache; a backward step is such a sweep and the moves
# back. Element-wise the kernels repeat the numpy operations in numpy's order (a mask is 0.0
# or 1.0, an exact factor), except that a message's normalisation is multiplied out (by its
# reciprocal) where the message is read instead of dividing the array: messages differ from a
# plain numpy pass by rounding only, that product and the order of the sums (kept per row,
# added in row order). Loops run over 1-D row views indexed from 0: an index such as ``c - 1``,
# which numba cannot prove non-negative, gets a wrap-around branch that keeps LLVM from
# vectorising the loop (4-8x slower here). Serial: on row slices over two threads
# (``threads.for_slices``) a slice's hand-over costs more than its share of a 0.1-0.3 ms pass
# (docs/benchmarks.md); and ``mapfilter evaluate`` runs a walk per core. They allocate nothing:
# compiled without reference counting (see maps/walls.py). A first call with an empty numba
# cache takes about 3 s, compiling them (then cached); the plain numpy steps compiled nothing
# but ran about 4x slower (tools/bench_map_matching.py).


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _move_row(a, factor, free, path, r, lo, hi, out_row):
    """``out_row[lo:hi]`` = what a path of unit moves brings from ``a * factor`` to row r: 0 where
    the path leaves the grid or enters a wall. ``path[j] = (dy, dx, kind)``, the path's cells
    relative to the destination; kind 1: must be free, 2: read there, 3: both."""
    ny, nx = a.shape
    c_lo, c_hi = lo, hi  # the columns whose whole path lies in the grid
    src_r, src_dx = r, 0
    for j in range(path.shape[0]):
        if r + path[j, 0] < 0 or r + path[j, 0] >= ny:
            c_lo = nx
        c_lo = max(c_lo, -path[j, 1])
        c_hi = min(c_hi, nx - path[j, 1])
        if path[j, 2] & 2:
            src_r, src_dx = r + path[j, 0], path[j, 1]
    c_lo = min(c_lo, hi)
    c_hi = max(c_hi, c_lo)
    for c in range(lo, c_lo):
        out_row[c] = 0.0
    for c in range(c_hi, hi):
        out_row[c] = 0.0
    if c_hi == c_lo:
        return
    out = out_row[c_lo:c_hi]
    src = a[src_r, c_lo + src_dx:c_hi + src_dx]
    for i in range(c_hi - c_lo):
        out[i] = src[i] * factor
    for j in range(path.shape[0]):
        if path[j, 2] & 1:  # the mask is 0.0 or 1.0: multiplying by it is exact
            mask = free[r + path[j, 0], c_lo + path[j, 1]:c_hi + path[j, 1]]
            for i in range(c_hi - c_lo):
                out[i] = out[i] * mask[i]


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _observe_row(row, free, gy, gx, r, lo, hi):
    """row[lo:hi] = (row * free) * the product of the anchors' separable Gaussians at row r (numpy's order)."""
    n = gy.shape[0]
    part, mask = row[lo:hi], free[r, lo:hi]
    if n == 0:
        for c in range(hi - lo):
            part[c] = part[c] * mask[c]
    elif n == 1:
        g, gx0 = gy[0, r], gx[0, lo:hi]
        for c in range(hi - lo):
            part[c] = (part[c] * mask[c]) * (g * gx0[c])
    else:
        for c in range(hi - lo):
            o = gy[0, r] * gx[0, lo + c]
            for i in range(1, n):
                o = o * (gy[i, r] * gx[i, lo + c])
            part[c] = (part[c] * mask[c]) * o


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _blur_span(src, out, lo, hi, out_span, center, side):
    """out[lo:hi] = src[lo:hi] blurred along the row with [side, center, side] (numpy's order:
    centre, left, right; 0 outside the span), out = 0 outside it. ``out_span``: where ``out``
    may be non-zero, [lo, hi) when done (zeroing only the rest of it instead of the whole row
    saved a fifth of a sweep)."""
    n = hi - lo
    if n == 1:
        out[lo] = center * src[lo]
    elif n > 1:
        out[lo] = center * src[lo] + side * src[lo + 1]
        mid, left, right, inner = src[lo + 1:hi - 1], src[lo:hi - 2], src[lo + 2:hi], out[lo + 1:hi - 1]
        for i in range(n - 2):
            inner[i] = (center * mid[i] + side * left[i]) + side * right[i]
        out[hi - 1] = center * src[hi - 1] + side * src[hi - 2]
    for c in range(out_span[0], min(lo, out_span[1])):
        out[c] = 0.0
    for c in range(max(hi, out_span[0]), out_span[1]):
        out[c] = 0.0
    out_span[0], out_span[1] = lo, hi


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _blur_column(below, mid, above, center, side, mask, out):
    """out = (the middle of three rows blurred across them: centre, below, above) * mask. A row
    beyond the grid is passed as zeros: adding 0.0 changes nothing, as numpy added nothing."""
    for c in range(out.shape[0]):
        out[c] = ((center * mid[c] + side * below[c]) + side * above[c]) * mask[c]


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _sum(row):
    # four running sums: one would wait on each addition's latency
    s0 = s1 = s2 = s3 = 0.0
    n4 = row.shape[0] // 4 * 4
    for c in range(0, n4, 4):
        s0 += row[c]
        s1 += row[c + 1]
        s2 += row[c + 2]
        s3 += row[c + 3]
    for c in range(n4, row.shape[0]):
        s0 += row[c]
    return (s0 + s1) + (s2 + s3)


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _blur_sweep(a, factor, free, path, gy, gx, center, side, forward, spans, clear, ring, ring_spans, ring_edges,
                row, out, row_sums):
    """One step, forward (``forward``) or backward, into ``out``.

    Forward (transition k - 1 -> k, a * factor = alpha_{k-1}): the moves of ``path`` (masked after
    each unit move), n_blur blurs each masked, the observation of step k; ``row_sums`` of the result.
    Backward (a * factor = beta_k): (beta_k * observation_k) masked, then n_blur blurs each of a
    masked input; not masked at the end (the moves back do it), no sums.
    Only the columns ``spans[r, 0]:spans[r, 1]`` of row r are computed; the rest of ``out`` is set to
    0 with ``clear``, else left as it is (0 already: out of the spans, only the all-ones fallback writes).
    Scratch: ``ring`` (n_blur, 3, nx), blur b's pass along x at row r in ``ring[b, r % 3]``, zero
    outside ``ring_spans`` (n_blur, 3, 2) (zeros at first); ``ring_edges`` (2, nx): a row of zeros
    (beyond the grid) and a row of ones (no mask); ``row`` (nx,).
    """
    ny, nx = a.shape
    n_blur = ring.shape[0]
    zeros, ones = ring_edges[0], ring_edges[1]
    for i in range(ny + n_blur):
        if i < ny:  # the step's input at row i, blurred along x
            lo, hi = spans[i, 0], spans[i, 1]
            if forward:
                _move_row(a, factor, free, path, i, lo, hi, row)
            else:
                src, dst = a[i, lo:hi], row[lo:hi]
                for c in range(hi - lo):
                    dst[c] = src[c] * factor
                _observe_row(row, free, gy, gx, i, lo, hi)
            _blur_span(row, ring[0, i % 3], lo, hi, ring_spans[0, i % 3], center, side)
        for b in range(n_blur):  # blur b along y at row i - 1 - b: its rows up to i - b are made
            r = i - 1 - b
            if r < 0 or r >= ny:
                continue
            lo, hi = spans[r, 0], spans[r, 1]
            below = ring[b, (r + 2) % 3, lo:hi] if r > 0 else zeros[lo:hi]
            above = ring[b, (r + 1) % 3, lo:hi] if r < ny - 1 else zeros[lo:hi]
            if b < n_blur - 1:  # masked, then the next blur along x
                _blur_column(below, ring[b, r % 3, lo:hi], above, center, side, free[r, lo:hi], row[lo:hi])
                _blur_span(row, ring[b + 1, r % 3], lo, hi, ring_spans[b + 1, r % 3], center, side)
            else:
                _blur_column(below, ring[b, r % 3, lo:hi], above, center, side, ones[lo:hi], out[r, lo:hi])
                if clear:
                    out[r, :lo] = 0.0
                    out[r, hi:] = 0.0
                if forward:
                    _observe_row(out[r], free, gy, gx, r, lo, hi)
                    row_sums[r] = _sum(out[r, lo:hi])


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _move_back(g, free, path, spans, out, row_max):
    """Backward: the adjoint of a step's moves (mask, move back, mask, ...); row maxima; ``spans``
    as in ``_blur_sweep`` (the free cells' columns are enough: the last mask is the cell's own)."""
    for r in range(out.shape[0]):
        lo, hi = spans[r, 0], spans[r, 1]
        _move_row(g, 1.0, free, path, r, lo, hi, out[r])
        out[r, :lo] = 0.0
        out[r, hi:] = 0.0
        row = out[r, lo:hi]
        m0 = m1 = 0.0  # the values are >= 0
        n2 = row.shape[0] // 2 * 2
        for c in range(0, n2, 2):
            m0 = max(m0, row[c])
            m1 = max(m1, row[c + 1])
        for c in range(n2, row.shape[0]):
            m0 = max(m0, row[c])
        row_max[r] = max(m0, m1)


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _moments(alpha, alpha_factor, beta, beta_factor, x_m, spans, row_moments):
    """Per row: the sums of p = (alpha * alpha_factor) * (beta * beta_factor), p * x and p * x^2
    (alpha * alpha_factor alone when ``beta_factor`` is 0) over the columns ``spans[r, 0]:spans[r, 1]``."""
    for r in range(alpha.shape[0]):
        lo, hi = spans[r, 0], spans[r, 1]
        a, b, x_m_row = alpha[r, lo:hi], beta[r, lo:hi], x_m[lo:hi]
        s0 = s1 = x0 = x1 = q0 = q1 = 0.0
        n2 = a.shape[0] // 2 * 2
        use_beta = beta_factor != 0.0
        for c in range(0, n2, 2):
            p0 = a[c] * alpha_factor
            p1 = a[c + 1] * alpha_factor
            if use_beta:
                p0 = p0 * (b[c] * beta_factor)
                p1 = p1 * (b[c + 1] * beta_factor)
            s0 += p0
            s1 += p1
            x0 += p0 * x_m_row[c]
            x1 += p1 * x_m_row[c + 1]
            q0 += p0 * x_m_row[c] * x_m_row[c]
            q1 += p1 * x_m_row[c + 1] * x_m_row[c + 1]
        for c in range(n2, a.shape[0]):
            p0 = a[c] * alpha_factor
            if use_beta:
                p0 = p0 * (b[c] * beta_factor)
            s0 += p0
            x0 += p0 * x_m_row[c]
            q0 += p0 * x_m_row[c] * x_m_row[c]
        row_moments[r, 0] = s0 + s1
        row_moments[r, 1] = x0 + x1
        row_moments[r, 2] = q0 + q1


def _cell_paths(units: list[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
    """A step's unit moves as the cell paths of ``_move_row``: (forward, backward), relative to the
    destination cell. Forward: mass from the start moves one cell at a time and is dropped in
    a wall cell after each move. Backward (the adjoint): mask, move back, mask, ... mask."""
    dy_dx = np.zeros((len(units) + 1, 2), dtype=np.int64)  # cells of the path, start at (0, 0)
    for j, (dx, dy) in enumerate(units, start=1):
        dy_dx[j] = dy_dx[j - 1] + (dy, dx)
    forward = np.column_stack([dy_dx - dy_dx[-1], np.ones(len(dy_dx), dtype=np.int64)])
    forward[0, 2] = 2  # the start: read there, not masked (the message is masked already, or all ones)
    backward = np.column_stack([dy_dx, np.ones(len(dy_dx), dtype=np.int64)])
    backward[-1, 2] = 3
    return forward, backward


def _row_spans(mask: np.ndarray) -> np.ndarray:
    """(ny, 2): per row, the columns from its first True cell to its last ((0, 0) for none)."""
    any_true = mask.any(axis=1)
    lo = np.where(any_true, mask.argmax(axis=1), 0)
    hi = np.where(any_true, mask.shape[1] - mask[:, ::-1].argmax(axis=1), 0)
    return np.column_stack([lo, hi]).astype(np.int64)


def _unit_moves(xy_m: np.ndarray, cell_m: float) -> list[list[tuple[int, int]]]:
    """Per transition, the unit cell moves that follow the shape (remainders carried on)."""
    moves, carry = [], np.zeros(2)
    for d in np.diff(xy_m, axis=0) / cell_m:
        carry += d
        units = []
        while abs(carry[0]) > 0.5 or abs(carry[1]) > 0.5:  # strict: a remainder of exactly half a cell stays
            axis = 0 if abs(carry[0]) >= abs(carry[1]) else 1
            sign = int(np.sign(carry[axis]))
            units.append((sign, 0) if axis == 0 else (0, sign))
            carry[axis] -= sign
        moves.append(units)
    return moves


def _anchors_by_step(t_s: np.ndarray, xy_m: np.ndarray, anchor_t_s: np.ndarray) -> dict[int, list[np.ndarray]]:
    """The observations: step index -> the placed positions at the anchor times (within the
    shape's times) that land on it, each on the first shape time at or after it."""
    anchor_t = np.asarray(anchor_t_s, dtype=np.float64).reshape(-1)
    anchor_t = anchor_t[(anchor_t >= t_s[0]) & (anchor_t <= t_s[-1])]
    anchor_xy = np.column_stack([np.interp(anchor_t, t_s, xy_m[:, 0]), np.interp(anchor_t, t_s, xy_m[:, 1])])
    nearest = np.clip(np.searchsorted(t_s, anchor_t), 0, t_s.shape[0] - 1)
    anchors_at: dict[int, list[np.ndarray]] = {}
    for k, anchor in zip(nearest.tolist(), anchor_xy):
        anchors_at.setdefault(k, []).append(anchor)
    return anchors_at


def _observation_factors(grid: _Grid, anchors_at: dict[int, list[np.ndarray]],
                         anchor_sigma_m: float) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """The observations at each observed step as separable Gaussians, (anchors, ny) along y and
    (anchors, nx) along x: a grid per scan kept for the whole walk would cost more memory than
    the messages."""
    inv_var = 0.5 / anchor_sigma_m ** 2
    return {k: (np.array([np.exp(-inv_var * (grid.y_m - ay) ** 2) for _, ay in anchors]),
                np.array([np.exp(-inv_var * (grid.x_m - ax) ** 2) for ax, _ in anchors]))
            for k, anchors in anchors_at.items()}


def _blur_steps(config: MapMatchConfig) -> tuple[int, float, float]:
    """The step's diffusion as n_blur blurs of [w, 1 - 2 w, w] along each axis: (n_blur, w, 1 - 2 w)."""
    variance_cells2 = (config.step_sigma_m / config.cell_m) ** 2
    n_blur = int(math.ceil(variance_cells2 / 0.5 - 1e-9))  # one blur adds at most 0.5 cells^2
    blur_weight = variance_cells2 / (2.0 * n_blur)
    return n_blur, blur_weight, 1.0 - 2.0 * blur_weight


def _near_free(free: np.ndarray) -> np.ndarray:
    """The cells within one cell (diagonals too) of a free cell."""
    near = free > 0
    near[:, 1:] |= free[:, :-1] > 0
    near[:, :-1] |= free[:, 1:] > 0
    near[1:] |= near[:-1].copy()
    near[:-1] |= near[1:].copy()
    return near


_Message = tuple[np.ndarray, float]


class _ForwardBackward:
    """The hidden Markov model of one walk on the grid, with the buffers its passes reuse.

    A message is (array, factor), the message being array * factor: its normalisation
    (1 / sum forward, 1 / peak backward) is applied where the message is read.
    What a step keeps is its values on free cells (the forward result is masked; the moves back
    read free cells only), and a blur moves mass by at most one cell along each axis before
    the next mask: so a step needs only the cells within one cell (diagonals too) of a free
    cell. Each row is computed over the columns from its first such cell to its last
    (``support``), the rest set to 0: the same numbers, about a third fewer cells on ILC F1.
    Results that are masked need only the columns of their row's free cells (``free_spans``).
    """

    def __init__(self, grid: _Grid, t_s: np.ndarray, xy_m: np.ndarray, anchor_t_s: np.ndarray,
                 config: MapMatchConfig):
        self.grid, self.free = grid, grid.free
        ny, nx = self.free.shape
        self.observations = _observation_factors(grid, _anchors_by_step(t_s, xy_m, anchor_t_s), config.anchor_sigma_m)
        self.unobserved = (np.zeros((0, ny)), np.zeros((0, nx)))
        self.paths = [_cell_paths(u) for u in _unit_moves(xy_m, config.cell_m)]  # transition k - 1 -> k at k - 1
        n_blur, self.blur_weight, self.center = _blur_steps(config)
        self.support, self.free_spans = _row_spans(_near_free(self.free)), _row_spans(self.free > 0)
        self.full = np.tile(np.array([0, nx], dtype=np.int64), (ny, 1))
        self.row_sums = np.empty(ny)
        self.row_moments = np.empty((ny, 3))
        # a sweep leaves its output as it is outside the spans: its buffers start at zero, and are
        # cleared from the first all-ones fallback on (``ones_written``)
        self.g = np.zeros_like(self.free)  # a backward step before its moves back
        self.ring, self.ring_spans = np.zeros((n_blur, 3, nx)), np.zeros((n_blur, 3, 2), dtype=np.int64)
        self.row = np.empty(nx)
        self.ring_edges = np.array([np.zeros(nx), np.ones(nx)])
        self.ones_written = False

    def observe(self, gy: np.ndarray, gx: np.ndarray, out: np.ndarray) -> None:
        """out = the observation alone on the free cells (the free cells without one), as
        ``_observe_row`` makes it; row sums. (At the start and at restarts only: plain numpy.)"""
        out[:] = self.free * self.free
        if gy.shape[0]:
            observation = np.outer(gy[0], gx[0])
            for i in range(1, gy.shape[0]):
                observation = observation * np.outer(gy[i], gx[i])
            out *= observation
        self.row_sums[:] = out.sum(axis=1)

    def forward(self, a: _Message | None, k: int, out: np.ndarray) -> tuple[_Message, bool]:
        """alpha_k (in ``out``) from alpha_{k-1} (None at k = 0); True when the pass restarted here."""
        gy, gx = self.observations.get(k, self.unobserved)
        if a is None:
            self.observe(gy, gx, out)
        else:
            _blur_sweep(*a, self.free, self.paths[k - 1][0], gy, gx, self.center, self.blur_weight, True,
                        self.support, self.ones_written, self.ring, self.ring_spans, self.ring_edges, self.row, out,
                        self.row_sums)
        total, restarted = self.row_sums.sum(), False
        if not total > 1e-250:
            restarted = k > 0
            self.observe(gy, gx, out)
            total = self.row_sums.sum()
            if not total > 0:  # no free cell near the walk: nothing to match against
                out[:], total, self.ones_written = 1.0, float(self.free.size), True
        return (out, 1.0 / float(total)), restarted

    def backward(self, beta: np.ndarray, beta_factor: float, k: int) -> float:
        """beta_{k-1} from beta_k (``beta`` * ``beta_factor``), in place; returns its factor (1 / its peak)."""
        gy, gx = self.observations.get(k, self.unobserved)
        path = self.paths[k - 1][1]
        _blur_sweep(beta, beta_factor, self.free, path, gy, gx, self.center, self.blur_weight, False, self.support,
                    False, self.ring, self.ring_spans, self.ring_edges, self.row, self.g, self.row_sums)
        _move_back(self.g, self.free, path, self.free_spans, beta, self.row_sums)
        peak = self.row_sums.max()
        if peak > 0:
            return 1.0 / float(peak)
        beta[:] = self.free
        return 1.0

    def posterior_moments(self, alpha: _Message, beta: np.ndarray, beta_factor: float) -> tuple[np.ndarray, float]:
        """(posterior mean (2,), its spread in m)."""
        x_m, y_m, row_moments = self.grid.x_m, self.grid.y_m, self.row_moments
        _moments(alpha[0], alpha[1], beta, beta_factor, x_m, self.free_spans, row_moments)  # beta is masked
        total = row_moments[:, 0].sum()
        if not total > 0:  # alpha and beta share no cell: alpha alone (all ones after the fallback)
            _moments(alpha[0], alpha[1], beta, 0.0, x_m, self.full, row_moments)
            total = row_moments[:, 0].sum()
        mean = np.array([row_moments[:, 1].sum(), (row_moments[:, 0] * y_m).sum()]) / total
        var_x = row_moments[:, 2].sum() / total - mean[0] ** 2
        var_y = (row_moments[:, 0] * y_m * y_m).sum() / total - mean[1] ** 2
        return mean, math.sqrt(max(0.5 * (var_x + var_y), 0.0))

    def forward_pass(self, K: int, every: int, segment_buffer: np.ndarray
                     ) -> tuple[dict[int, _Message], list[_Message], np.ndarray]:
        """The forward messages: (checkpoints at every ``every`` steps before the last segment, the
        last segment's messages whole (in ``segment_buffer``), the steps where the pass restarted)."""
        last_start = ((K - 1) // every) * every
        checkpoints: dict[int, _Message] = {}
        restarted_at = np.zeros(K, dtype=bool)
        buffers = (np.zeros_like(self.free), np.zeros_like(self.free)) if last_start > 0 else ()
        segment: list[_Message] = []
        a = None
        for k in range(K):
            a, restarted_at[k] = self.forward(a, k, buffers[k % 2] if k < last_start else segment_buffer[k - last_start])
            if k >= last_start:
                segment.append(a)
            elif k % every == 0:
                checkpoints[k] = (a[0].copy(), a[1])
        return checkpoints, segment, restarted_at

    def backward_pass(self, K: int, every: int, segment_buffer: np.ndarray, checkpoints: dict[int, _Message],
                      segment: list[_Message], restarted_at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The backward pass, segment by segment from the last (each recomputed from its checkpoint):
        the posterior mean (K, 2) and spread (K,) at every step."""
        out_xy = np.zeros((K, 2))
        out_std = np.zeros(K)
        beta, beta_factor = self.free.copy(), 1.0
        last_start = ((K - 1) // every) * every
        for start in range(last_start, -1, -every):
            if start < last_start:  # recompute the segment's messages from its checkpoint
                segment = [checkpoints.pop(start)]
                for k in range(start + 1, start + every):
                    segment.append(self.forward(segment[-1], k, segment_buffer[k - start])[0])
            for k in range(start + len(segment) - 1, start - 1, -1):
                out_xy[k], out_std[k] = self.posterior_moments(segment[k - start], beta, beta_factor)
                if k == 0:
                    break
                if restarted_at[k]:  # the forward pass forgot everything before k: so does the backward one
                    beta[:], beta_factor = self.free, 1.0
                    continue
                beta_factor = self.backward(beta, beta_factor, k)
        return out_xy, out_std


def map_match(floorplan: FloorPlan, t_s: np.ndarray, xy_m: np.ndarray, anchor_t_s: np.ndarray,
              config: MapMatchConfig = MapMatchConfig()) -> MapMatch:
    """Map-match a placed walk (positions ``xy_m`` at times ``t_s``, one per step) on the plan.

    ``anchor_t_s``: the times at which the placed shape is observed (the scan times its
    placement came from); each observes the shape's position there with ``anchor_sigma_m``.
    Returns the smoothed posterior mean at every ``t_s``. Where the plan blocks every path the
    walk's moves allow, the pass restarts from the observation there (counted in ``restarts``).
    """
    t = np.asarray(t_s, dtype=np.float64).reshape(-1)
    xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
    if t.shape[0] != xy.shape[0] or t.shape[0] < 1 or not np.all(np.isfinite(xy)):
        raise ValueError("map_match needs finite positions, one per time")
    grid = _Grid(floorplan, xy, config)
    if not grid.free.any():  # the walk is nowhere near the plan's free space: nothing to match against
        return MapMatch(t, xy.copy(), 0)
    chain = _ForwardBackward(grid, t, xy, anchor_t_s, config)
    K, every = t.shape[0], config.checkpoint_every
    segment_buffer = np.zeros((min(every, K), *grid.free.shape))  # the forward messages of one segment
    checkpoints, segment, restarted_at = chain.forward_pass(K, every, segment_buffer)
    out_xy, out_std = chain.backward_pass(K, every, segment_buffer, checkpoints, segment, restarted_at)
    return MapMatch(t, out_xy, int(restarted_at.sum()), out_std)
