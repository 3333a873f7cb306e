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

from mapfilter.errors import MapfilterError
from mapfilter.filter.estimate import weighted_estimate, weighted_moments
from mapfilter.filter.models.interface import FloorModel, MeasurementModel
from mapfilter.filter.models.survey_reach import mixture_log_likelihood
from mapfilter.filter.particles import Particles
from mapfilter.maps.building import Building, connector_pixels
from mapfilter.maps.floorplan import FloorPlan

# wall pixels between two floors' tiles (and around the stack): wider than any jitter
_TILE_GAP_PX = 4


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
        shifts, starts = [], []
        col = gap
        for floor in building.floors:
            rows, cols = floor.plan.shape_px
            # bottom-aligned: the tile's lower-left pixel corner sits `gap` pixels above the stack's
            mask[height_px - gap - rows:height_px - gap, col:col + cols] = floor.plan.wall_mask
            x0, y0 = floor.plan.origin_m
            shifts.append((col * res - x0, gap * res - y0))
            starts.append((col - gap / 2.0) * res)
            col += cols + gap
        self.plan = FloorPlan(mask, res, (0.0, 0.0), None)
        self.shift_m = np.array(shifts, dtype=np.float64)
        self.tile_x_min_m = np.array(starts, dtype=np.float64)

    @property
    def n_floors(self) -> int:
        return len(self.building.floors)

    def floor_of(self, stack_xy_m: np.ndarray) -> np.ndarray:
        """(N,) floor index of stack positions (N, 2)."""
        x = np.asarray(stack_xy_m, dtype=np.float64)[..., 0]
        return np.clip(np.searchsorted(self.tile_x_min_m, x, side="right") - 1, 0, self.n_floors - 1)

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
        local, floor = self.to_floor(stack_xy_m)
        out = np.empty_like(local)
        for f, fl in enumerate(self.building.floors):
            on = floor == f
            if on.any():
                out[on] = fl.to_building(local[on])
        return out

    def floor_shares(self, stack_xy_m: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """(F,) share of the weight on each floor."""
        return np.bincount(self.floor_of(stack_xy_m), weights=weights, minlength=self.n_floors)

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

    def report(self, xy_m: np.ndarray, weights: np.ndarray, estimate_xy_m: np.ndarray) -> dict:
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
        self.changed_last_step = 0  # particles that changed floor in the last ``change_floors``

    @property
    def has_connectors(self) -> bool:
        return bool(self.connector_cells)

    @property
    def plan(self) -> FloorPlan:
        return self.stack.plan

    def estimate(self, xy_m: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, float, bool]:
        return self.stack.estimate(xy_m, weights)

    def covariance(self, xy_m: np.ndarray, weights: np.ndarray) -> np.ndarray:
        # the cloud's spread where the floors lie over each other (the building frame), not
        # across the stack's tiles, which would make the jitter as wide as the building
        return weighted_moments(self.stack.to_building(xy_m), weights)[1]

    def report(self, xy_m: np.ndarray, weights: np.ndarray, estimate_xy_m: np.ndarray) -> dict:
        return {"floor_shares": self.stack.floor_shares(xy_m, weights),
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
        if not self.on_stairs.any():
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
        local, floor = stack.to_floor(xy[movers])
        # another floor, alike: add 1..F-1 to the floor index modulo F
        dest = (floor + rng.integers(1, stack.n_floors, movers.size)) % stack.n_floors
        out = log_weight.copy()
        for f in np.unique(floor):
            on = floor == f
            building_xy = stack.building.floors[f].to_building(local[on])
            for d in np.unique(dest[on]):
                sel = dest[on] == d
                point = stack.building.floors[d].from_building(building_xy[sel])
                idx = movers[on][sel]
                free = stack.building.floors[d].plan.is_free(point)
                xy[idx[free]] = stack.to_stack(point[free], d)
                out[idx[~free]] = -np.inf  # no floor there: it dies where it stood
        self.changed_last_step = int(np.count_nonzero(np.isfinite(out[movers])))
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
    scan's in-survey probability and the particle's distance to the survey)

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

    def log_likelihood(self, particles: Particles, measurement: FloorFix) -> np.ndarray:
        floor = self.stack.floor_of(particles.xy_m)
        fix = measurement.xy_m[floor]
        sigma = np.asarray(self.sigma_m, dtype=np.float64)[floor]
        r2 = ((particles.xy_m - fix) ** 2).sum(axis=1)
        if self.grids is not None and measurement.in_survey is not None:
            floor_xy = particles.xy_m - self.stack.shift_m[floor]
            d2 = np.zeros(len(floor))
            for f, grid in enumerate(self.grids):
                on = floor == f
                if grid is not None and on.any():
                    d2[on] = grid.at(floor_xy[on]) ** 2
            w = float(measurement.in_survey)
            with np.errstate(invalid="ignore"):
                position = np.where(np.isfinite(r2), mixture_log_likelihood(r2, d2, sigma * sigma, w), -4.5)
        else:
            position = np.where(np.isfinite(r2), -0.5 * r2 / (sigma * sigma), -4.5)
        prior = np.asarray(particles.log_weight, dtype=np.float64)
        live = np.isfinite(prior)
        floor_ll = np.asarray(measurement.floor_log_likelihood, dtype=np.float64)
        if measurement.evidence_only:
            # floor evidence alone (the barometer between scans): it reweighs floors and never
            # collapses the cloud, whose re-draw needs a position; the next scan can
            return floor_ll[floor]
        if live.any() and floor_ll[floor[live]].max() < floor_ll.max() - self.floor_collapse_nats:
            return np.full(len(particles), -np.inf)
        out = floor_ll[floor] + position
        for f in np.unique(floor[live]):
            on = live & (floor == f)
            out[on] -= _logsumexp(prior[on] + position[on]) - _logsumexp(prior[on])
        return out


def _logsumexp(values: np.ndarray) -> float:
    m = float(values.max())
    return m + math.log(float(np.exp(values - m).sum()))
