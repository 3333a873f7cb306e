"""Synthetic walks over several floors of a building: stairs, lifts, WiFi through floors, a barometer.

A walk is a list of floor changes (``FloorChange``: which connector, to which floor). Between
them the walker wanders on the current floor as ``simulate.walk`` does (random goals, routes
that keep off the walls), then walks to the connector:

- **stairs**: the walker walks across the stairs polygon (from the end nearest to where they
  entered to the far end on the destination floor), one step per stair of ``stair_rise_m``,
  the elevation rising evenly; the floor (ground truth) changes at the middle step;
- **lift**: the walker stands in the lift polygon (waiting, then riding
  ``lift_s_per_storey`` per storey, the elevation following the ride), no steps; the floor
  changes half-way through the ride.

Positions are planned in the building frame (the IMU sees one continuous walk) and written in
each floor's own frame with the floor's name in a fifth ``TYPE_WAYPOINT`` column. WiFi: every
access point belongs to a floor; the phone hears it with the Lund thesis path loss over the 3-D
distance, the multi-wall loss of ``simulate.walk`` on the same floor, and ``floor_loss_db`` per
floor between them (per-floor attenuation). The barometer (``TYPE_PRESSURE`` rows, hPa) follows
the international barometric formula of the elevation, plus a slow weather drift and noise.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import shapely

from mapfilter.errors import MapfilterError
from mapfilter.maps.building import Building
from mapfilter.maps.walls import crosses_wall
from mapfilter.sensors.pathloss import AccessPointTable, path_loss_rssi_dbm
from mapfilter.simulate.segments import count_walls_crossed
from mapfilter.simulate.walk import (
    MAX_DB,
    MAX_DURATION_S,
    SimConfig,
    SimulatedWalk,
    _build_route_graph,
    _cut_into_steps,
    _imu,
    _scan_times,
    _shortest_path,
    _step_and_sensor_fields,
    _string_pull,
    _wifi,
    _xy_at,
)

SEA_LEVEL_HPA = 1013.25


def pressure_hpa(height_m: np.ndarray, p0_hpa: float = SEA_LEVEL_HPA) -> np.ndarray:
    """International barometric formula: p = p0 (1 - 2.25577e-5 h)^5.25588 (about 0.12 hPa per metre)."""
    return p0_hpa * (1.0 - 2.25577e-5 * np.asarray(height_m, dtype=np.float64)) ** 5.25588


@dataclasses.dataclass(frozen=True)
class FloorChange:
    """Take connector ``connector`` (its name in the building) to floor ``to_floor``."""

    connector: str
    to_floor: str


@dataclasses.dataclass(frozen=True)
class BuildingSimConfig:
    """Knobs of a walk over several floors (the walking, IMU and WiFi knobs are ``walk``'s)."""

    walk: SimConfig = dataclasses.field(default_factory=SimConfig)  # its duration_s is not used here
    segment_s: tuple[float, float] = (25.0, 40.0)  # wandering on a floor before and after each change
    stair_rise_m: float = 0.17  # one step per stair
    stair_step_s: float = 0.6  # climbing is slower than walking
    lift_wait_s: tuple[float, float] = (4.0, 10.0)  # standing in the lift before it moves
    lift_s_per_storey: float = 3.0
    lift_exit_s: float = 1.5  # doors open, then the walker steps out
    floor_loss_db: float = 15.0  # per floor between access point and phone (a concrete slab)
    p0_hpa: float = SEA_LEVEL_HPA  # pressure at elevation 0 at the start
    pressure_rate_hz: float = 2.0
    pressure_noise_hpa: float = 0.03  # phone barometers: about 0.25 m of height noise per sample
    pressure_drift_hpa_per_h: float = 0.5  # weather

    def validate(self, n_changes: int = 0) -> None:
        """Raise ``MapfilterError`` for values that make no sense, or a walk of ``n_changes``
        floor changes that would wander longer than ``walk.MAX_DURATION_S``."""
        lo, hi = self.segment_s
        if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 <= lo <= hi):
            raise MapfilterError(f"segment_s needs 0 <= MIN <= MAX, got {lo:g} {hi:g}")
        if not (math.isfinite(self.floor_loss_db) and 0.0 <= self.floor_loss_db <= MAX_DB):
            raise MapfilterError(f"floor loss must be between 0 and {MAX_DB:g} dB, got {self.floor_loss_db:g}")
        if n_changes < 0:
            raise MapfilterError(f"the number of floor changes must be >= 0, got {n_changes}")
        if (n_changes + 1) * hi > MAX_DURATION_S:
            raise MapfilterError(f"{n_changes} floor changes with up to {hi:g} s of wandering before and after each "
                                 f"make a walk of up to {(n_changes + 1) * hi:g} s, more than {MAX_DURATION_S:g} s "
                                 f"({MAX_DURATION_S / 3600:g} h): fewer changes or a shorter --segment-s")


def building_rssi_dbm(building: Building, ap_table: AccessPointTable, ap_floor: np.ndarray, ap_index: np.ndarray,
                      floor: np.ndarray, xy_building_m: np.ndarray, elevation_m: np.ndarray,
                      config: BuildingSimConfig) -> tuple[np.ndarray, np.ndarray]:
    """Mean RSSI of AP ``ap_index[i]`` (building-frame ``ap_table``, on floor ``ap_floor``) at
    a phone on ``floor[i]`` at building-frame ``xy_building_m[i]`` and ``elevation_m[i]``, and
    the walls crossed (counted on the phone's floor when the AP is on it, else none)."""
    k = np.asarray(ap_index, dtype=np.int64)
    xy = np.atleast_2d(np.asarray(xy_building_m, dtype=np.float64))
    floor = np.asarray(floor, dtype=np.int64)
    ap_elevation = np.array([f.elevation_m for f in building.floors])[ap_floor[k]]
    d_m = np.sqrt(((xy - ap_table.xy_m[k]) ** 2).sum(axis=1) + (np.asarray(elevation_m) - ap_elevation) ** 2)
    walls = np.zeros(k.shape[0], dtype=np.int64)
    for f in np.unique(floor):
        same = (floor == f) & (ap_floor[k] == f)
        if same.any():
            fl = building.floors[f]
            walls[same] = count_walls_crossed(fl.plan, fl.from_building(ap_table.xy_m[k[same]]),
                                              fl.from_building(xy[same]))
    wall_db = np.where(np.array(ap_table.band)[k] == "5", config.walk.wall_loss_5g_db, config.walk.wall_loss_2g4_db)
    rssi = path_loss_rssi_dbm(d_m, ap_table.c_dbm[k], ap_table.n[k], ap_table.alpha_db_per_m[k], ap_table.d_max_m[k])
    return rssi - wall_db * walls - config.floor_loss_db * np.abs(floor - ap_floor[k]), walls


def building_access_points(building: Building, tables: dict[str, AccessPointTable]) -> tuple[AccessPointTable, np.ndarray]:
    """One building-frame table of every floor's access points (each table in its floor's frame)
    and the floor index of each AP."""
    parts, floors = [], []
    for name, table in tables.items():
        f = building.floor_index(name)
        parts.append(dataclasses.replace(table, xy_m=building.floors[f].to_building(table.xy_m)))
        floors.append(np.full(len(table), f, dtype=np.int64))
    if not parts:
        raise MapfilterError("no access points")
    bssids = [b for p in parts for b in p.bssid]
    keys = list(zip(bssids, [b for p in parts for b in p.band]))
    if len(set(keys)) != len(keys):
        raise MapfilterError("access points of different floors share a BSSID and band: give them their own")
    table = AccessPointTable(bssids, [b for p in parts for b in p.band], np.concatenate([p.xy_m for p in parts]),
                             np.concatenate([p.c_dbm for p in parts]), np.concatenate([p.n for p in parts]),
                             np.concatenate([p.alpha_db_per_m for p in parts]),
                             np.concatenate([p.d_max_m for p in parts]))
    return table, np.concatenate(floors)


@dataclasses.dataclass
class _Plan:
    wp_t: list = dataclasses.field(default_factory=list)
    wp_floor: list = dataclasses.field(default_factory=list)
    wp_xy_b: list = dataclasses.field(default_factory=list)  # building frame
    step_start: list = dataclasses.field(default_factory=list)
    step_end: list = dataclasses.field(default_factory=list)
    step_xy0: list = dataclasses.field(default_factory=list)
    step_xy1: list = dataclasses.field(default_factory=list)
    elev_t: list = dataclasses.field(default_factory=list)  # elevation knots
    elev_m: list = dataclasses.field(default_factory=list)
    changes: list = dataclasses.field(default_factory=list)  # (t_start, t_switch, t_end, from, to, kind)


class _BuildingWalker:
    """The walker's plan as it is made: where they are (floor, route-graph node), and the
    waypoints, steps and elevation knots so far, in the building frame."""

    def __init__(self, building: Building, start_floor: str, config: BuildingSimConfig, rng: np.random.Generator):
        self.building, self.config, self.walk_cfg, self.rng = building, config, config.walk, rng
        self.graphs = [_build_route_graph(f.plan, self.walk_cfg) for f in building.floors]
        self.members = [np.nonzero(g.component == g.main)[0] for g in self.graphs]
        self.floor = building.floor_index(start_floor)
        self.step_m = max(0.3, self.walk_cfg.step_length_m + self.walk_cfg.step_length_sigma_m * rng.standard_normal())
        self.plan = _Plan()
        self.current = int(rng.choice(self.members[self.floor]))
        self.elevation = [f.elevation_m for f in building.floors]
        self.waypoint(0.0, self.floor, self.here_b(self.floor, self.current))
        self.plan.elev_t.append(0.0)
        self.plan.elev_m.append(self.elevation[self.floor])

    def here_b(self, f: int, node) -> np.ndarray:
        """Route-graph node(s) of floor f in the building frame."""
        return self.building.floors[f].to_building(self.graphs[f].xy_m[node])

    def waypoint(self, t: float, f: int, xy_b: np.ndarray) -> None:
        self.plan.wp_t.append(t)
        self.plan.wp_floor.append(f)
        self.plan.wp_xy_b.append(np.asarray(xy_b, dtype=np.float64))

    def step(self, t0: float, t1: float, a_b: np.ndarray, b_b: np.ndarray, f: int) -> None:
        self.plan.step_start.append(t0)
        self.plan.step_end.append(t1)
        self.plan.step_xy0.append(a_b)
        self.plan.step_xy1.append(b_b)
        self.waypoint(t1, f, b_b)

    def elevation_knots(self, t: list[float], elevation_m: list[float]) -> None:
        self.plan.elev_t += t
        self.plan.elev_m += elevation_m

    def walk_to(self, goal: int, t: float) -> float:
        """Walk the route to node ``goal`` of the current floor, step by step; the time of arrival."""
        if goal == self.current:
            return t
        fl, graph = self.building.floors[self.floor], self.graphs[self.floor]
        nodes = _shortest_path(graph, self.current, goal)
        polyline = _string_pull(fl.plan, graph, nodes, self.walk_cfg.preferred_clearance_m)
        feet, leg_step_m = _cut_into_steps(fl.plan, polyline, self.step_m, self.rng)
        dt = leg_step_m / self.rng.uniform(*self.walk_cfg.speed_mps)
        feet_b = fl.to_building(feet)
        for k in range(1, feet.shape[0]):
            self.step(t, t + dt, feet_b[k - 1], feet_b[k], self.floor)
            t += dt
        self.current = goal
        return t

    def wander(self, t: float, until: float) -> float:
        """Walk to random goals on the current floor (pausing at each) until ``until``."""
        members = self.members[self.floor]
        while t < until:
            g = self.graphs[self.floor]
            far = members[np.linalg.norm(g.xy_m[members] - g.xy_m[self.current], axis=1)
                          >= self.walk_cfg.min_goal_distance_m]
            t = self.walk_to(int(self.rng.choice(far if far.size else members)), t)
            t += self.rng.uniform(*self.walk_cfg.pause_s)
            self.waypoint(t, self.floor, self.here_b(self.floor, self.current))
        return t

    def nodes_inside(self, f: int, polygon) -> np.ndarray:
        g, members = self.graphs[f], self.members[f]
        inside = shapely.contains_xy(polygon, g.xy_m[members, 0], g.xy_m[members, 1])
        return members[inside]

    def take(self, change: FloorChange, t: float) -> float:
        """Wander, walk into the connector and take it to the change's floor; the time it is done."""
        building, config = self.building, self.config
        connector = next((c for c in building.connectors if c.name == change.connector), None)
        if connector is None:
            raise MapfilterError(f"the building has no connector {change.connector!r}", building.path)
        here_name = building.floors[self.floor].name
        dest = building.floor_index(change.to_floor)
        if here_name not in connector.polygons or change.to_floor not in connector.polygons or dest == self.floor:
            raise MapfilterError(f"connector {connector.name!r} does not link {here_name} to {change.to_floor}",
                                 building.path)
        t = self.wander(t, t + self.rng.uniform(*config.segment_s))
        entries = self.nodes_inside(self.floor, connector.polygons[here_name])
        exits = self.nodes_inside(dest, connector.polygons[change.to_floor])
        if entries.size == 0 or exits.size == 0:
            raise MapfilterError(f"connector {connector.name!r} has no room to walk in on {here_name} or "
                                 f"{change.to_floor}", building.path)
        xy_m = self.graphs[self.floor].xy_m
        entry = int(entries[np.argmin(np.linalg.norm(xy_m[entries] - xy_m[self.current], axis=1))])
        t_enter = t = self.walk_to(entry, t)
        if connector.kind == "lift":
            t, t_switch, exit_node = self.ride_lift(t, entry, dest, exits)
        else:
            t, t_switch, exit_node = self.climb_stairs(t, entry, dest, exits, connector.name)
        self.plan.changes.append((t_enter, t_switch, t, self.floor, dest, connector.kind))
        self.floor = dest
        self.current = exit_node
        self.elevation_knots([t], [self.elevation[dest]])
        return t

    def ride_lift(self, t: float, entry: int, dest: int, exits: np.ndarray) -> tuple[float, float, int]:
        """Wait in the lift at node ``entry``, ride to floor ``dest``, step out to the exit
        nearest; (time done, time the floor switches, exit node)."""
        config, entry_b = self.config, self.here_b(self.floor, entry)
        rise = self.elevation[dest] - self.elevation[self.floor]
        exit_node = int(exits[np.argmin(np.linalg.norm(self.here_b(dest, exits) - entry_b, axis=1))])
        t += self.rng.uniform(*config.lift_wait_s)
        ride = config.lift_s_per_storey * abs(rise) / max(self.building.storey_height_m or 4.0, 1e-9)
        self.elevation_knots([t, t + ride], [self.elevation[self.floor], self.elevation[dest]])
        t_switch = t + ride / 2
        self.waypoint(t_switch - 1e-3, self.floor, entry_b)
        self.waypoint(t_switch, dest, entry_b)
        t += ride + config.lift_exit_s
        self.waypoint(t, dest, entry_b)
        exit_b = self.here_b(dest, exit_node)
        if np.linalg.norm(exit_b - entry_b) > 0.05:  # step out onto the destination floor's grid
            self.step(t, t + self.walk_cfg.step_length_m / 1.2, entry_b, exit_b, dest)
            t += self.walk_cfg.step_length_m / 1.2
        return t, t_switch, exit_node

    def climb_stairs(self, t: float, entry: int, dest: int, exits: np.ndarray,
                     name: str) -> tuple[float, float, int]:
        """Walk across the stairs from node ``entry`` to the far end of the polygon on floor
        ``dest``, one step per stair; (time done, time the floor switches, exit node)."""
        building, config, entry_b = self.building, self.config, self.here_b(self.floor, entry)
        rise = self.elevation[dest] - self.elevation[self.floor]
        far = np.linalg.norm(self.here_b(dest, exits) - entry_b, axis=1)
        exit_node = int(exits[np.argmax(far)])
        exit_b = self.here_b(dest, exit_node)
        n_steps = max(2, int(math.ceil(abs(rise) / config.stair_rise_m)))
        path = entry_b + np.linspace(0.0, 1.0, n_steps + 1)[:, None] * (exit_b - entry_b)
        for fl in (building.floors[self.floor], building.floors[dest]):
            local = fl.from_building(path)
            if crosses_wall(fl.plan, local[:-1], local[1:]).any():
                raise MapfilterError(f"connector {name!r}: the straight way across the stairs meets a "
                                     f"wall on floor {fl.name}", building.path)
        self.elevation_knots([t, t + n_steps * config.stair_step_s], [self.elevation[self.floor], self.elevation[dest]])
        t_switch = t + (n_steps // 2) * config.stair_step_s
        for k in range(1, n_steps + 1):  # the floor changes after the middle step
            self.step(t, t + config.stair_step_s, path[k - 1], path[k], dest if k > n_steps // 2 else self.floor)
            t += config.stair_step_s
        return t, t_switch, exit_node


def simulate_building_walk(building: Building, ap_tables: dict[str, AccessPointTable], start_floor: str,
                           changes: list[FloorChange], config: BuildingSimConfig, rng: np.random.Generator,
                           site_id: str = "mapfilter-sim") -> tuple[SimulatedWalk, list[tuple]]:
    """Simulate one walk that starts on ``start_floor`` and takes the connectors of ``changes``.

    Returns the walk (as ``write_ilc`` writes it: waypoints in their floor's frame with the
    floor's name, ``TYPE_PRESSURE`` rows) and the floor changes as they happened: tuples
    (t_enter_s, t_switch_s, t_leave_s, from_floor, to_floor, kind) in Unix seconds, where the
    ground truth's floor switches at ``t_switch_s``.
    """
    config.walk.validate()
    config.validate(len(changes))
    walker = _BuildingWalker(building, start_floor, config, rng)
    t = config.walk.initial_still_s
    for change in changes:
        t = walker.take(change, t)
    t = walker.wander(t, t + rng.uniform(*config.segment_s))
    walker.elevation_knots([t], [walker.elevation[walker.floor]])
    return _sensors(building, ap_tables, walker.plan, t, config, rng, site_id)


def _sensors(building: Building, ap_tables: dict[str, AccessPointTable], plan: _Plan, end_t: float,
             config: BuildingSimConfig, rng: np.random.Generator, site_id: str) -> tuple[SimulatedWalk, list[tuple]]:
    walk_cfg = config.walk
    wp_t = np.array(plan.wp_t)
    order = np.argsort(wp_t, kind="stable")
    wp_t = wp_t[order]
    wp_floor = np.array(plan.wp_floor, dtype=np.int64)[order]
    wp_b = np.array(plan.wp_xy_b).reshape(-1, 2)[order]
    step_start = np.array(plan.step_start)
    step_end = np.array(plan.step_end)
    xy0 = np.array(plan.step_xy0).reshape(-1, 2)
    xy1 = np.array(plan.step_xy1).reshape(-1, 2)
    imu = _imu(step_start, step_end, xy0, xy1, end_t, walk_cfg, rng)
    scan_t = _scan_times(end_t, walk_cfg, rng)
    elev_t, elev_m = np.array(plan.elev_t), np.array(plan.elev_m)
    order_e = np.argsort(elev_t, kind="stable")
    elev_t, elev_m = elev_t[order_e], elev_m[order_e]
    ap_table, ap_floor = building_access_points(building, ap_tables)

    def floor_at(t_rel: np.ndarray) -> np.ndarray:
        return wp_floor[np.clip(np.searchsorted(wp_t, t_rel, side="right") - 1, 0, wp_t.size - 1)]

    def position_at(t_rel: np.ndarray) -> np.ndarray:
        return _xy_at(t_rel, wp_t, wp_b)

    def rssi_at(seen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return building_rssi_dbm(building, ap_table, ap_floor, np.arange(len(ap_table)), floor_at(seen),
                                 position_at(seen), np.interp(seen, elev_t, elev_m), config)

    wifi = _wifi(building.floors[0].plan, ap_table, position_at, scan_t, walk_cfg, rng, rssi_at=rssi_at)
    p_t = np.arange(0.0, end_t, 1.0 / config.pressure_rate_hz)
    drift = config.pressure_drift_hpa_per_h * rng.uniform(-1.0, 1.0) * p_t / 3600.0
    p_hpa = pressure_hpa(np.interp(p_t, elev_t, elev_m), config.p0_hpa) + drift \
        + config.pressure_noise_hpa * rng.standard_normal(p_t.size)
    names = building.floor_names
    wp_local = np.empty_like(wp_b)
    for f in np.unique(wp_floor):
        on = wp_floor == f
        wp_local[on] = building.floors[f].from_building(wp_b[on])
    t0 = walk_cfg.start_time_ms / 1000.0
    walk = SimulatedWalk(
        floor_name=names[wp_floor[0]], site_id=site_id, start_t_s=t0, end_t_s=t0 + end_t,
        waypoint_t_s=t0 + wp_t, waypoint_xy_m=wp_local, reference_xy_m=np.zeros((0, 2)),
        waypoint_floor=[names[f] for f in wp_floor], pressure_t_s=t0 + p_t, pressure_hpa=p_hpa,
        **_step_and_sensor_fields(t0, step_start, step_end, xy0, xy1, imu, ap_table, scan_t, wifi),
    )
    changes = [(t0 + a, t0 + s, t0 + b, names[f], names[g], kind) for a, s, b, f, g, kind in plan.changes]
    return walk, changes


def simulate_building_survey(building: Building, ap_tables: dict[str, AccessPointTable], floor: str,
                             config: BuildingSimConfig, rng: np.random.Generator,
                             site_id: str = "mapfilter-sim") -> SimulatedWalk:
    """A radio-map survey of one floor (``SimConfig.survey``) hearing every floor's access points."""
    from mapfilter.simulate.walk import simulate_walk

    f = building.floor_index(floor)
    fl = building.floors[f]
    ap_table, ap_floor = building_access_points(building, ap_tables)

    def rssi_model(xy_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = xy_m.shape[0]
        return building_rssi_dbm(building, ap_table, ap_floor, np.arange(n) % len(ap_table), np.full(n, f),
                                 fl.to_building(xy_m), np.full(n, fl.elevation_m), config)

    survey_cfg = dataclasses.replace(config.walk, survey=True, duration_s=None)
    plan = dataclasses.replace(fl.plan, floor_name=floor)
    return simulate_walk(plan, ap_table, survey_cfg, rng, site_id=site_id, rssi_model=rssi_model)
