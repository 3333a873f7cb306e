"""A building's floors in the filter's state (the ``FloorModel``s): the floors as one state space,
floor changes, and a WiFi measurement that weighs floors.

The particle filter works on one ``FloorPlan``. A building becomes one by :class:`FloorStack`:
every floor's wall mask is laid side by side in a "stack" plan, each in its own tile,
separated by wall. A particle's tile *is* its floor (``FloorStack.floor_of``), so

- the existing wall check (one call of the numba kernel for all particles) checks each move
  on the particle's own floor's mask: a move can never leave its tile, because the tiles are
  fenced by wall; this is the same as grouping the particles by floor and calling the kernel
  once per floor, without the grouping;
- the regularisation jitter stays on the particle's floor for the same reason;
- a floor change is a jump from one tile to another, made by :class:`FloorChanges` after the
  wall check (so the jump itself is not a wall crossing), only inside a connector (stairs,
  escalator, lift) or, when the building has none, anywhere at a small rate.

Positions in the stack plan are ``floor-frame position + FloorStack.shift_m[floor]``; every
output goes back to the floor's own frame (``FloorStack.to_floor``).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numba import njit

from mapfilter.errors import MapfilterError
from mapfilter.filter.estimate import weighted_estimate, weighted_moments, writable, xy_moments
from mapfilter.filter.models.interface import FloorModel, MeasurementModel
from mapfilter.filter.models.survey_reach import EMPTY_LOG_LIKELIHOOD, heading_log_likelihood, heading_term
from mapfilter.filter.particles import HEADING, Particles, X, Y
from mapfilter.maps.building import Building, connector_pixels
from mapfilter.maps.floorplan import FloorPlan

# wall pixels between two floors' tiles (and around the stack): wider than any jitter
_TILE_GAP_PX = 4
# a fix's position term for a particle on a floor without a fix: a fix 3 sigma away
_NO_FIX_LOG_LIKELIHOOD = -4.5


# The building's per-particle bookkeeping in numba (the step weighs floors every step: in numpy
# each of these was a dozen passes over the cloud). Each is the same arithmetic as the numpy it
# replaced, element by element, and sums in the same order where numpy's does (np.bincount's);
# tests/filter/test_floor_kernels.py holds them to numpy.

@njit(cache=True, nogil=True)
def _floor_index(x, tile_x_min, out):
    # np.searchsorted(tile_x_min, x, side="right") - 1 clipped to the floors (NaN: the last, as there)
    n_floors = tile_x_min.shape[0]
    for i in range(x.shape[0]):
        xi = x[i]
        if xi != xi:
            out[i] = n_floors - 1
            continue
        f = 0
        for k in range(1, n_floors):
            if tile_x_min[k] <= xi:
                f = k
            else:
                break
        out[i] = f


@njit(cache=True, nogil=True)
def _floor_sums(x, weights, tile_x_min, out):
    # np.bincount(floor, weights): each floor's weight, summed in particle order
    floor = np.empty(x.shape[0], dtype=np.int64)
    _floor_index(x, tile_x_min, floor)
    out[:] = 0.0
    for i in range(x.shape[0]):
        out[floor[i]] += weights[i]
    return floor


@njit(cache=True, nogil=True)
def _main_floor_moments(x, y, weights, tile_x_min, w_out, shares):
    # the weights of the floor with most weight (w_out, zero elsewhere) and their moments; each
    # floor's weight (_floor_sums) into shares
    floor = _floor_sums(x, weights, tile_x_min, shares)
    best = 0
    for f in range(1, shares.shape[0]):
        if shares[f] > shares[best]:  # np.argmax: the first of equal shares
            best = f
    for i in range(x.shape[0]):
        w_out[i] = weights[i] if floor[i] == best else 0.0
    mx, my, sxx, sxy, syy = xy_moments(x, y, w_out)
    return best, mx, my, sxx, sxy, syy


@njit(cache=True, nogil=True, inline="always")
def _point_to_building(x, y, f, shift, frame):
    # a stack position on floor f -> its floor's frame -> the building's (Floor.to_building's
    # arithmetic); frame[f] = (offset x, offset y, cos, sin) of floor f
    lx = x - shift[f, 0]
    ly = y - shift[f, 1]
    return frame[f, 0] + frame[f, 2] * lx - frame[f, 3] * ly, frame[f, 1] + frame[f, 3] * lx + frame[f, 2] * ly


@njit(cache=True, nogil=True)
def _stack_to_building(x, y, tile_x_min, shift, frame, out):
    # every stack position -> the building's frame (_point_to_building)
    floor = np.empty(x.shape[0], dtype=np.int64)
    _floor_index(x, tile_x_min, floor)
    for i in range(x.shape[0]):
        out[i, 0], out[i, 1] = _point_to_building(x[i], y[i], floor[i], shift, frame)


@njit(cache=True, nogil=True)
def _change_anywhere(state, movers, step, tile_x_min, shift, frame, origin, tiles, mask, out):
    # FloorChanges.change_floors without connectors, after the draws: mover j goes from its floor
    # f to floor (f + step[j]) mod F at the same building-frame point (_point_to_building, then
    # the destination's Floor.from_building's arithmetic), moved there (FloorStack.to_stack) where
    # that point is free on the destination's plan (FloorPlan.is_free's arithmetic, read off its
    # tile of the stack's mask), else killed where it stood (out = -inf); returns how many landed
    n_floors = tile_x_min.shape[0]
    where = np.empty(1, dtype=np.int64)
    landed = 0
    for j in range(movers.shape[0]):
        i = movers[j]
        _floor_index(state[X, i:i + 1], tile_x_min, where)
        f = where[0]
        bx, by = _point_to_building(state[X, i], state[Y, i], f, shift, frame)
        d = (f + step[j]) % n_floors
        dx = bx - frame[d, 0]
        dy = by - frame[d, 1]
        px = frame[d, 2] * dx + frame[d, 3] * dy
        py = -frame[d, 3] * dx + frame[d, 2] * dy
        u = (px - origin[d, 0]) / origin[d, 2]
        v = tiles[d, 2] - (py - origin[d, 1]) / origin[d, 2]
        if 0.0 <= u < tiles[d, 3] and 0.0 <= v < tiles[d, 2] and \
                not mask[tiles[d, 0] + int(math.floor(v)), tiles[d, 1] + int(math.floor(u))]:
            state[X, i] = px + shift[d, 0]
            state[Y, i] = py + shift[d, 1]
            landed += 1
        else:
            out[i] = -math.inf  # no floor there: it dies where it stood
    return landed


@njit(cache=True, nogil=True)
def _log_add_exp(a, b):
    # np.logaddexp
    if a == b:
        return a + math.log(2.0)
    d = a - b
    if d > 0:
        return a + math.log1p(math.exp(-d))
    if d <= 0:
        return b + math.log1p(math.exp(d))
    return d


@njit(cache=True, nogil=True)
def _mixture_tables(distance_m, var):
    # the terms of survey_reach.mixture_log_likelihood that depend on the cell only: per cell of a
    # floor's distance grid, log u(x) + log(sigma^2 / s^2) (-inf where u(x) = 0) and s^2
    base = np.empty(distance_m.shape[0])
    spread = np.empty(distance_m.shape[0])
    for k in range(distance_m.shape[0]):
        d2 = distance_m[k] * distance_m[k]
        spread[k] = var + d2
        uncovered = -math.expm1(-0.5 * d2 / var)
        base[k] = math.log(max(uncovered, 1e-300)) + math.log(var / spread[k]) if uncovered > 0 else -math.inf
    return base, spread


def _grid_tables(grid, distance_m: np.ndarray, var_m2: float) -> tuple[np.ndarray, np.ndarray]:
    """``_mixture_tables`` of a floor's distance grid, kept with the grid (a building's grids are
    kept with its radio map: every walk tracked in it shares them)."""
    if grid is None:
        return _mixture_tables(distance_m.ravel(), var_m2)
    kept = grid.__dict__.setdefault("_mixture_tables", {})
    if var_m2 not in kept:
        kept[var_m2] = _mixture_tables(distance_m.ravel(), var_m2)
    return kept[var_m2]


@njit(cache=True, nogil=True)
def _floor_fix_kernel(x, y, heading, prior, tile_x_min, shift, fix, var, grid_head, grid_base, grid_spread, mixture,
                      in_survey, rotation_vector_rad, heading_weight, floor_ll, collapse_nats, out):
    # FloorFixLikelihood.log_likelihood (its docstring) in two passes over the cloud and one over
    # its live particles; grid_head[f] = (x0, y0, cell, rows, cols, first index in grid_base and
    # grid_spread: _mixture_tables of floor f's grid; a floor without one: one cell at distance 0)
    n = x.shape[0]
    n_floors = tile_x_min.shape[0]
    floor = np.empty(n, dtype=np.int64)
    _floor_index(x, tile_x_min, floor)
    top = -math.inf  # the best floor's evidence
    for f in range(n_floors):
        top = max(top, floor_ll[f])
    # survey_reach.mixture_log_likelihood: the in-survey and the outside component's weights
    log_in = math.log(max(in_survey, 1e-300)) if in_survey > 0 else -math.inf
    log_out = math.log(max(1.0 - in_survey, 1e-300)) if in_survey < 1 else -math.inf
    v_max = np.full(n_floors, -math.inf)  # per floor: max of prior + position, of prior (live particles)
    p_max = np.full(n_floors, -math.inf)
    has_live = np.zeros(n_floors, dtype=np.bool_)
    for i in range(n):
        f = floor[i]
        dx = x[i] - fix[f, 0]
        dy = y[i] - fix[f, 1]
        r2 = dx * dx + dy * dy
        if not math.isfinite(r2):
            position = _NO_FIX_LOG_LIKELIHOOD
        elif mixture:
            rows = int(grid_head[f, 3])
            cols = int(grid_head[f, 4])
            c = min(max(int((x[i] - shift[f, 0] - grid_head[f, 0]) / grid_head[f, 2]), 0), cols - 1)
            r = min(max(int((y[i] - shift[f, 1] - grid_head[f, 1]) / grid_head[f, 2]), 0), rows - 1)
            k = int(grid_head[f, 5]) + r * cols + c
            inside = log_in - 0.5 * r2 / var[f]
            outside = log_out + grid_base[k] - 0.5 * r2 / grid_spread[k]
            both = _log_add_exp(inside, outside)
            position = both if math.isfinite(both) else EMPTY_LOG_LIKELIHOOD
        else:
            position = -0.5 * r2 / var[f]
        # survey_reach's heading term: a reweighting within the floor too
        position += heading_log_likelihood(heading[i], rotation_vector_rad, heading_weight)
        out[i] = position
        if math.isfinite(prior[i]):
            has_live[f] = True
            v_max[f] = max(v_max[f], prior[i] + position)
            p_max[f] = max(p_max[f], prior[i])
    any_live = False
    live_top = -math.inf
    for f in range(n_floors):
        if has_live[f]:
            any_live = True
            live_top = max(live_top, floor_ll[f])
    if any_live and live_top < top - collapse_nats:
        out[:] = -math.inf
        return
    v_sum = np.zeros(n_floors)
    p_sum = np.zeros(n_floors)
    for i in range(n):
        if math.isfinite(prior[i]):
            f = floor[i]
            v_sum[f] += math.exp(prior[i] + out[i] - v_max[f])
            p_sum[f] += math.exp(prior[i] - p_max[f])
    # each floor's position term a reweighting within the floor: minus log(sum w e^pos / sum w)
    normaliser = np.zeros(n_floors)
    for f in range(n_floors):
        if has_live[f]:
            normaliser[f] = (v_max[f] + math.log(v_sum[f])) - (p_max[f] + math.log(p_sum[f]))
    for i in range(n):
        f = floor[i]
        out[i] = floor_ll[f] + out[i]
        if math.isfinite(prior[i]):
            out[i] -= normaliser[f]


def floor_stack(building: Building) -> FloorStack:
    """The building's ``FloorStack``, made once per building: its stack plan carries the wall
    check's tables, which every walk tracked in the building shares."""
    stack = getattr(building, "_floor_stack", None)
    if stack is None or stack.building is not building:
        stack = FloorStack(building)
        building._floor_stack = stack
    return stack


class FloorStack:
    """A building's floors side by side in one wall mask (the filter's state space).

    Attributes
    ----------
    building : the building.
    plan : the stack plan (origin (0, 0); each floor in its tile, walls between).
    shift_m : (F, 2) stack position = floor-frame position + shift_m[floor].
    tile_x_min_m : (F,) x where each floor's tile starts in the stack (tiles ordered by x).
    """

    def __init__(self, building: Building) -> None:
        resolutions = {round(f.plan.resolution_m, 9) for f in building.floors}
        if len(resolutions) != 1:
            raise MapfilterError(f"the floors' maps have different resolutions ({', '.join(map(str, sorted(resolutions)))} "
                                 f"m/px): make them at one resolution to track across floors", building.path)
        self.building = building
        res = building.floors[0].plan.resolution_m
        gap = _TILE_GAP_PX
        height_px = max(f.plan.shape_px[0] for f in building.floors) + 2 * gap
        width_px = sum(f.plan.shape_px[1] for f in building.floors) + gap * (len(building.floors) + 1)
        mask = np.ones((height_px, width_px), dtype=bool)
        shifts, starts, tiles = [], [], []
        col = gap
        for floor in building.floors:
            rows, cols = floor.plan.shape_px
            # bottom-aligned: the tile's lower-left pixel corner sits `gap` pixels above the stack's
            mask[height_px - gap - rows:height_px - gap, col:col + cols] = floor.plan.wall_mask
            x0, y0 = floor.plan.origin_m
            shifts.append((col * res - x0, gap * res - y0))
            starts.append((col - gap / 2.0) * res)
            tiles.append((height_px - gap - rows, col, rows, cols))
            col += cols + gap
        self.plan = FloorPlan(mask, res, (0.0, 0.0), None)
        # per floor: (first row, first column, rows, columns) of its tile in the stack's mask, and
        # (x0, y0, resolution) of its own plan: its ``is_free`` read off the stack's mask
        self._tiles = np.array(tiles, dtype=np.int64)
        self._plan_origins = np.array([(*f.plan.origin_m, f.plan.resolution_m) for f in building.floors],
                                      dtype=np.float64)
        self.shift_m = np.array(shifts, dtype=np.float64)
        self.tile_x_min_m = np.array(starts, dtype=np.float64)
        # per floor (offset x, offset y, cos, sin) of its frame in the building's (Floor.to_building)
        self._frames = np.array([(f.offset_m[0], f.offset_m[1], math.cos(f.rotation_rad), math.sin(f.rotation_rad))
                                 for f in building.floors], dtype=np.float64)

    @property
    def n_floors(self) -> int:
        return len(self.building.floors)

    def floor_of(self, stack_xy_m: np.ndarray) -> np.ndarray:
        """(N,) floor index of stack positions (N, 2)."""
        x = np.asarray(stack_xy_m, dtype=np.float64)[..., 0]
        out = np.empty(x.shape, dtype=np.int64)
        _floor_index(np.ascontiguousarray(x).reshape(-1), self.tile_x_min_m, out.reshape(-1))
        return out

    def to_stack(self, xy_m: np.ndarray, floor: np.ndarray | int) -> np.ndarray:
        """Floor-frame positions (N, 2) on ``floor`` (index or (N,) indices) -> stack positions."""
        return np.asarray(xy_m, dtype=np.float64) + self.shift_m[floor]

    def to_floor(self, stack_xy_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Stack positions (N, 2) -> (floor-frame positions (N, 2), floor indices (N,))."""
        xy = np.asarray(stack_xy_m, dtype=np.float64)
        floor = self.floor_of(xy)
        return xy - self.shift_m[floor], floor

    def to_building(self, stack_xy_m: np.ndarray) -> np.ndarray:
        """Stack positions (N, 2) -> building-frame positions (N, 2) (floors placed as the file says)."""
        given = np.asarray(stack_xy_m, dtype=np.float64)
        xy = given.reshape(-1, 2)
        out = np.empty(xy.shape)
        _stack_to_building(np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1]), self.tile_x_min_m,
                           self.shift_m, self._frames, out)
        return out.reshape(given.shape)

    def floor_shares(self, stack_xy_m: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """(F,) share of the weight on each floor."""
        out = np.empty(self.n_floors)
        _floor_sums(np.ascontiguousarray(np.asarray(stack_xy_m, dtype=np.float64)[:, 0]),
                    writable(weights), self.tile_x_min_m, out)
        return out

    def main_floor_moments(self, stack_xy_m: np.ndarray, weights: np.ndarray, shares: np.ndarray | None = None
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(the weights of the floor holding most of the weight, zero on the others (N,); their
        weighted mean (2,) and covariance (2, 2), as ``weighted_moments`` gives them), in one go;
        ``shares`` (F,), if given, gets ``floor_shares`` of the same cloud."""
        xy = np.asarray(stack_xy_m, dtype=np.float64)
        w = np.empty(len(xy))
        _, mx, my, sxx, sxy, syy = _main_floor_moments(np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1]),
                                                       writable(weights), self.tile_x_min_m, w,
                                                       np.empty(self.n_floors) if shares is None else shares)
        return w, np.array([mx, my]), np.array([[sxx, sxy], [sxy, syy]])

    def estimate(self, stack_xy_m: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, float, bool]:
        """The estimate on the floor holding most of the weight: ``weighted_estimate`` of that
        floor's particles (a mean over several floors would lie between tiles, in a wall)."""
        floor = self.floor_of(stack_xy_m)
        best = int(np.argmax(np.bincount(floor, weights=weights, minlength=self.n_floors)))
        w = np.where(floor == best, weights, 0.0)
        total = w.sum()
        return weighted_estimate(self.plan, stack_xy_m, w / total if total > 0 else weights)



class OneFloor(FloorModel):
    """A single map (``filter.models.FloorModel``): no floor in the state, nothing happens
    between floors, and not a single random draw."""

    changes_floors = False

    def __init__(self, plan: FloorPlan) -> None:
        self.plan = plan

    def step_on_stairs(self, from_xy_m: np.ndarray, to_xy_m: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        return to_xy_m

    def change_floors(self, particles: Particles, log_weight: np.ndarray, dt_s: float, rng: np.random.Generator,
                      measurement: object = None) -> np.ndarray:
        return log_weight

    def estimate(self, xy_m: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, float, bool]:
        return weighted_estimate(self.plan, xy_m, weights)

    def covariance(self, xy_m: np.ndarray, weights: np.ndarray) -> np.ndarray:
        return weighted_moments(xy_m, weights)[1]

    def report(self, xy_m: np.ndarray, weights: np.ndarray, estimate_xy_m: np.ndarray,
               floor_shares: np.ndarray | None = None) -> dict:
        return {}

    def change_probability(self, xy_m: np.ndarray, dt_s: float) -> np.ndarray:
        return np.zeros((len(xy_m), 1))


@dataclasses.dataclass
class FloorChangeConfig:
    """How particles change floor (defaults in comments)."""

    # inside a connector, the rate at which a particle takes it: a walker standing 10 s in a
    # lift or on stairs has changed floor with probability 1 - exp(-1) = 63 %
    connector_rate_per_s: float = 0.1  # rate at which a particle in a connector takes it
    # a building without connectors: a particle changes floor anywhere at this rate (to the same
    # building-frame point of another floor; where that is no floor, it dies); the WiFi floor
    # vote then keeps or kills it. 1 / 300 s puts about 0.3 % of the cloud on other floors
    # per second: enough to follow a real change within a few scans, too few to matter otherwise
    anywhere_rate_per_s: float = 1.0 / 300.0  # without connectors: rate of a floor change anywhere

    def __post_init__(self) -> None:
        for name in ("connector_rate_per_s", "anywhere_rate_per_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise MapfilterError(f"floor change setting {name} must be a rate >= 0 per second, got {value}")


# on stairs a step advances one tread, not a stride: building codes ask 0.22-0.30 m of going
# (tread depth) and most stairs have 0.25-0.30 m; a particle starting a step on a stairs polygon
# moves this far instead (drawn per step), so the cloud stays on the stairs while the climber
# does and can take them when the height says so (a stride walks it off the flight)
STAIRS_TREAD_M = (0.22, 0.32)


class FloorChanges(FloorModel):
    """A building's floors in the filter's state (``filter.models.FloorModel``): particles live on
    the stack plan and move between floors; the filter calls ``change_floors`` after the wall check.

    With connectors: a live particle on a free pixel of a connector changes floor at
    ``connector_rate_per_s`` to another floor the connector links (chosen alike), landing at
    the same building-frame point when that is inside the connector there, else on a random
    free pixel of the connector's polygon on that floor; with a barometer, every particle in a
    connector to the floor the height is nearest goes there at once: a climber's or rider's floor
    flips where their height passes half a storey, and the memoryless rate has only a few per
    cent of the cloud on the new floor then.
    Without connectors (ILC plans mark none): anywhere at ``anywhere_rate_per_s``, to the same
    building-frame point of another floor (chosen alike), dying (where it stood) where that
    point is no free space.
    """

    changes_floors = True

    def __init__(self, stack: FloorStack, config: FloorChangeConfig = FloorChangeConfig()) -> None:
        self.stack = stack
        self.config = config
        plan = stack.plan
        self.connector_id = np.full(plan.shape_px, -1, dtype=np.int32)  # stack pixel -> connector
        # per connector: {floor index: stack positions of its free pixel centres on that floor}
        self.connector_cells: list[dict[int, np.ndarray]] = []
        self.connector_polygons: list[dict] = []  # shapely polygons
        for c, connector in enumerate(stack.building.connectors):
            cells, polygons = {}, {}
            for name, polygon in connector.polygons.items():
                f = stack.building.floor_index(name)
                fplan = stack.building.floors[f].plan
                rows, cols = connector_pixels(fplan, polygon)
                centres = stack.to_stack(fplan.pixel_to_world(np.stack([cols + 0.5, rows + 0.5], axis=-1)), f)
                srows, scols, _ = plan.pixel_index(centres)
                self.connector_id[srows, scols] = c
                cells[f] = centres
                polygons[f] = polygon
            self.connector_cells.append(cells)
            self.connector_polygons.append(polygons)
        self.on_stairs = np.zeros(plan.shape_px, dtype=bool)  # stack pixel -> inside a flight of stairs
        for c, connector in enumerate(stack.building.connectors):
            if connector.kind == "stairs":
                self.on_stairs |= self.connector_id == c
        self._has_stairs = bool(self.on_stairs.any())  # asked every step: once here
        self.changed_last_step = 0  # particles that changed floor in the last ``change_floors``

    @property
    def has_connectors(self) -> bool:
        return bool(self.connector_cells)

    @property
    def has_stairs(self) -> bool:
        return self._has_stairs

    @property
    def plan(self) -> FloorPlan:
        return self.stack.plan

    def estimate(self, xy_m: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, float, bool]:
        return self.stack.estimate(xy_m, weights)

    def covariance(self, xy_m: np.ndarray, weights: np.ndarray) -> np.ndarray:
        # the cloud's spread where the floors lie over each other (the building frame), not
        # across the stack's tiles, which would make the jitter as wide as the building
        return weighted_moments(self.stack.to_building(xy_m), weights)[1]

    def report(self, xy_m: np.ndarray, weights: np.ndarray, estimate_xy_m: np.ndarray,
               floor_shares: np.ndarray | None = None) -> dict:
        return {"floor_shares": self.stack.floor_shares(xy_m, weights) if floor_shares is None else floor_shares,
                "floor_index": int(self.stack.floor_of(estimate_xy_m[None, :])[0]),
                "floor_changes": self.changed_last_step}

    def change_probability(self, xy_m: np.ndarray, dt_s: float) -> np.ndarray:
        """(M, F) the probability of moving to each floor over ``dt_s`` (the smoother's transition):
        in a connector, to each floor it links; without connectors, anywhere to every other floor.
        The barometer decides in connectors (the filter moves every particle of a connector when
        the height says so), so a connector's particle may take it at once: there, one half."""
        stack = self.stack
        out = np.zeros((len(xy_m), stack.n_floors))
        if stack.n_floors < 2 or dt_s <= 0.0:
            return out
        if not self.has_connectors:
            out[:] = -math.expm1(-self.config.anywhere_rate_per_s * dt_s) / (stack.n_floors - 1)
            return out
        p = max(-math.expm1(-self.config.connector_rate_per_s * dt_s), 0.5)
        rows, cols, inside = stack.plan.pixel_index(np.asarray(xy_m, dtype=np.float64))
        conn = np.full(len(xy_m), -1)
        conn[inside] = self.connector_id[rows[inside], cols[inside]]
        for i in np.flatnonzero(conn >= 0):
            linked = list(self.connector_cells[conn[i]])
            out[i, linked] = p / max(len(linked) - 1, 1)
        return out

    def step_on_stairs(self, from_xy_m: np.ndarray, to_xy_m: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """One PDR step's end points, with every step that starts on stairs shortened to a tread
        (``STAIRS_TREAD_M``) along its own direction; the rest as given (a new array)."""
        out = np.array(to_xy_m, dtype=np.float64, copy=True)
        if not self._has_stairs:
            return out
        rows, cols, inside = self.stack.plan.pixel_index(from_xy_m)
        stairs = np.zeros(len(out), dtype=bool)
        stairs[inside] = self.on_stairs[rows[inside], cols[inside]]
        idx = np.flatnonzero(stairs)
        if idx.size == 0:
            return out
        move = out[idx] - from_xy_m[idx]
        length = np.linalg.norm(move, axis=1)
        tread = rng.uniform(*STAIRS_TREAD_M, idx.size)
        scale = np.where(length > tread, tread / np.maximum(length, 1e-12), 1.0)
        out[idx] = from_xy_m[idx] + scale[:, None] * move
        return out

    def change_floors(self, particles: Particles, log_weight: np.ndarray, dt_s: float,
                      rng: np.random.Generator, measurement: object = None) -> np.ndarray:
        """Change the floor of some live particles in place (``particles.xy_m``); returns the
        log weights with particles that landed on no floor killed. ``measurement``: the step's
        measurement; a ``FloorFix`` with a ``height_floor`` moves the connectors' particles there."""
        self.changed_last_step = 0
        particles.log_weight = log_weight  # the weights after the wall check, for the measurement
        stack = self.stack
        if stack.n_floors < 2 or dt_s <= 0.0:
            return log_weight
        live = np.isfinite(log_weight)
        xy = particles.xy_m
        if self.has_connectors:
            rows, cols, inside = stack.plan.pixel_index(xy)
            conn = np.full(len(particles), -1, dtype=np.int32)
            conn[inside] = self.connector_id[rows[inside], cols[inside]]
            in_connector = live & (conn >= 0)
            p = -math.expm1(-self.config.connector_rate_per_s * dt_s)
            movers = np.flatnonzero(in_connector & (rng.random(len(particles)) < p))
            floor = stack.floor_of(xy[movers])
            dest = np.empty(movers.size, dtype=np.int64)
            for i, m in enumerate(movers):
                choices = [f for f in self.connector_cells[conn[m]] if f != floor[i]]
                dest[i] = choices[int(rng.integers(0, len(choices)))]
            height_floor = measurement.height_floor if isinstance(measurement, FloorFix) else None
            if height_floor is not None:
                # the height's floor wins over the random choice, for every particle in a connector to it
                leads = np.array([height_floor in cells for cells in self.connector_cells])
                follow = np.flatnonzero(in_connector & leads[np.maximum(conn, 0)]
                                        & (stack.floor_of(xy) != height_floor))
                keep = ~np.isin(movers, follow)
                movers = np.concatenate([movers[keep], follow])
                dest = np.concatenate([dest[keep], np.full(follow.size, height_floor, dtype=np.int64)])
            if movers.size == 0:
                return log_weight
            self._land(xy, movers, conn[movers], dest, rng)
            self.changed_last_step = int(movers.size)
            return log_weight
        p = -math.expm1(-self.config.anywhere_rate_per_s * dt_s)
        movers = np.flatnonzero(live & (rng.random(len(particles)) < p))
        if movers.size == 0:
            return log_weight
        # another floor, alike: add 1..F-1 to the floor index modulo F
        step = rng.integers(1, stack.n_floors, movers.size)
        out = log_weight.copy()
        self.changed_last_step = int(_change_anywhere(particles.state, movers, step, stack.tile_x_min_m,
                                                      stack.shift_m, stack._frames, stack._plan_origins,
                                                      stack._tiles, stack.plan.wall_mask, out))
        particles.log_weight = out
        return out

    def _land(self, xy: np.ndarray, movers: np.ndarray, conn: np.ndarray, dest: np.ndarray,
              rng: np.random.Generator) -> None:
        """Move ``xy[movers]`` through connectors ``conn`` to floors ``dest``: the same building-frame
        point when that is inside the connector there and free, else a random free pixel of it."""
        stack = self.stack
        local, floor = stack.to_floor(xy[movers])
        building_xy = np.empty_like(local)
        for f in np.unique(floor):
            on = floor == f
            building_xy[on] = stack.building.floors[f].to_building(local[on])
        for i, m in enumerate(movers):
            cells = self.connector_cells[conn[i]]
            dest_floor = stack.building.floors[dest[i]]
            point = dest_floor.from_building(building_xy[i])
            import shapely  # only a building with connectors needs it

            inside_polygon = shapely.contains_xy(self.connector_polygons[conn[i]][dest[i]], point[0], point[1])
            if inside_polygon and dest_floor.plan.is_free(point[None, :])[0]:
                xy[m] = stack.to_stack(point, dest[i])
            else:
                xy[m] = cells[dest[i]][int(rng.integers(0, cells[dest[i]].shape[0]))]


@dataclasses.dataclass(frozen=True)
class FloorFix:
    """A scan as the multi-floor filter weighs it: a position fix per floor (stack frame, NaN =
    none from that floor's fingerprints) and the scan's log-likelihood of each floor."""

    xy_m: np.ndarray  # (F, 2) stack positions
    floor_log_likelihood: np.ndarray  # (F,)
    height_floor: int | None = None  # the floor the barometer's height is nearest (None: no barometer)
    in_survey: float | None = None  # P(the scan was taken inside the survey) (None: a plain Gaussian fix)
    heading_rad: float = math.nan  # the rotation vector's heading at the scan (NaN: none; survey_reach's heading term)
    heading_sigma_rad: float = math.nan  # ... and its spread

    @property
    def evidence_only(self) -> bool:
        """No position fix on any floor (the barometer between scans): floors only."""
        return not np.isfinite(self.xy_m).any()


@dataclasses.dataclass(frozen=True)
class FloorFixLikelihood(MeasurementModel):
    """The WiFi floor vote weighs the floors; within a floor, the fix weighs positions.

    For a particle i on floor f with prior weight w_i:

        log L_i = vote_f + pos_i - log( sum_{j on f} w_j exp(pos_j) / sum_{j on f} w_j )
        pos_i   = -|x_i - fix_f|^2 / (2 sigma_f^2)

    (with ``grids``, pos_i is ``survey_reach.mixture_log_likelihood``: the fix weighed by the
    scan's in-survey probability and the particle's distance to the survey, plus, with the
    rotation vector's heading, ``survey_reach``'s heading term)

    where ``vote_f`` is the scan's floor log-likelihood (``sensors.floor_vote.
    floor_vote_log_likelihood``) and ``fix_f`` the fix made from floor f's fingerprints only
    (a floor without a fix gives every particle there the value of a fix 3 sigma away). The
    normaliser makes the position term a reweighting *within* each floor: the weight of a
    whole floor changes by exp(vote_f) only, as in the floor HMM's forward step, while
    positions are weighed as on one floor (Evennou & Marx). Without it a wrong floor whose
    fingerprints happen to agree with its particles (a self-consistent wrong fix) could
    outweigh the right floor where the walk's fixes are poor and the cloud disagrees with them.
    """

    stack: FloorStack
    sigma_m: np.ndarray  # (F,) fix sigma per floor
    grids: list | None = None  # (F,) survey_reach.DistanceGrid of each floor (None: none; all None: a Gaussian)
    # When the floor evidence puts every live particle's floor this far (nats) below the best
    # floor, no particle is where the walker can be: every value is -inf, and the filter
    # collapses and re-draws its particles from this measurement over every floor. The WiFi
    # vote alone never gets there (its pseudo-count keeps floors within log(k + 1) = 1.6 nats
    # for k = 4); a barometer 2.6 m up a 4 m storey, 0.6 m past its half-way (-(4 m - h)^2 / 2
    # against -h^2 / 2 at 1 m sigma), or a given floor does. With connectors the height moves
    # their particles first (``FloorChanges.change_floors``), so this is
    # for a cloud that is nowhere near one.
    floor_collapse_nats: float = 2.5

    def locates(self, measurement: FloorFix) -> bool:
        return not measurement.evidence_only

    def __post_init__(self) -> None:
        # the floors' distance grids as the kernel reads them (``_floor_fix_kernel``'s grid_head,
        # grid_base, grid_spread): per cell, the mixture's terms that only the distance decides
        sigma = np.asarray(self.sigma_m, dtype=np.float64)
        head, base, spread, first = np.zeros((self.stack.n_floors, 6)), [], [], 0
        for f in range(self.stack.n_floors):
            grid = self.grids[f] if self.grids is not None else None
            distance = np.zeros(1) if grid is None else np.asarray(grid.distance_m, dtype=np.float64)
            rows, cols = (1, 1) if grid is None else distance.shape
            x0, y0, cell = (0.0, 0.0, 1.0) if grid is None else (*grid.origin_m, grid.cell_m)
            head[f] = (x0, y0, cell, rows, cols, first)
            b, s = _grid_tables(grid, distance, float(sigma[f] * sigma[f]))
            base.append(b)
            spread.append(s)
            first += rows * cols
        object.__setattr__(self, "_grid_head", head)
        object.__setattr__(self, "_grid_base", np.concatenate(base))
        object.__setattr__(self, "_grid_spread", np.concatenate(spread))

    def log_likelihood(self, particles: Particles, measurement: FloorFix) -> np.ndarray:
        floor_ll = np.ascontiguousarray(measurement.floor_log_likelihood, dtype=np.float64)
        if measurement.evidence_only:
            # floor evidence alone (the barometer between scans): it reweighs floors and never
            # collapses the cloud, whose re-draw needs a position; the next scan can
            return floor_ll[self.stack.floor_of(particles.xy_m)]
        sigma = np.asarray(self.sigma_m, dtype=np.float64)
        out = np.empty(len(particles))
        mixture = self.grids is not None and measurement.in_survey is not None
        heading, turn = heading_term(measurement.in_survey if mixture else None, measurement.heading_rad,
                                     measurement.heading_sigma_rad)
        _floor_fix_kernel(particles.state[X], particles.state[Y], particles.state[HEADING],
                          np.ascontiguousarray(particles.log_weight, dtype=np.float64),
                          self.stack.tile_x_min_m, self.stack.shift_m,
                          np.ascontiguousarray(measurement.xy_m, dtype=np.float64), sigma * sigma, self._grid_head,
                          self._grid_base, self._grid_spread, mixture,
                          0.0 if measurement.in_survey is None else float(measurement.in_survey),
                          heading, turn, floor_ll, float(self.floor_collapse_nats), out)
        return out
