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
    _shortest_path,
    _string_pull,
    _wifi,
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


def simulate_building_walk(building: Building, ap_tables: dict[str, AccessPointTable], start_floor: str,
                           changes: list[FloorChange], config: BuildingSimConfig, rng: np.random.Generator,
                           site_id: str = "mapfilter-sim") -> tuple[SimulatedWalk, list[tuple]]:
    """Simulate one walk that starts on ``start_floor`` and takes the connectors of ``changes``.

    Returns the walk (as ``write_ilc`` writes it: waypoints in their floor's frame with the
    floor's name, ``TYPE_PRESSURE`` rows) and the floor changes as they happened: tuples
    (t_enter_s, t_switch_s, t_leave_s, from_floor, to_floor, kind) in Unix seconds, where the
    ground truth's floor switches at ``t_switch_s``.
    """
    walk_cfg = config.walk
    walk_cfg.validate()
    config.validate(len(changes))
    graphs = [_build_route_graph(f.plan, walk_cfg) for f in building.floors]
    members = [np.nonzero(g.component == g.main)[0] for g in graphs]
    floor = building.floor_index(start_floor)
    step_m = max(0.3, walk_cfg.step_length_m + walk_cfg.step_length_sigma_m * rng.standard_normal())
    plan = _Plan()
    current = int(rng.choice(members[floor]))
    elevation = [f.elevation_m for f in building.floors]

    def here_b(f: int, node: int) -> np.ndarray:
        return building.floors[f].to_building(graphs[f].xy_m[node])

    def waypoint(t: float, f: int, xy_b: np.ndarray) -> None:
        plan.wp_t.append(t)
        plan.wp_floor.append(f)
        plan.wp_xy_b.append(np.asarray(xy_b, dtype=np.float64))

    def step(t0: float, t1: float, a_b: np.ndarray, b_b: np.ndarray, f: int) -> None:
        plan.step_start.append(t0)
        plan.step_end.append(t1)
        plan.step_xy0.append(a_b)
        plan.step_xy1.append(b_b)
        waypoint(t1, f, b_b)

    t = walk_cfg.initial_still_s
    waypoint(0.0, floor, here_b(floor, current))
    plan.elev_t.append(0.0)
    plan.elev_m.append(elevation[floor])

    def walk_to(goal: int, t: float) -> float:
        nonlocal current
        if goal == current:
            return t
        fl = building.floors[floor]
        nodes = _shortest_path(graphs[floor], current, goal)
        polyline = _string_pull(fl.plan, graphs[floor], nodes, walk_cfg.preferred_clearance_m)
        feet, leg_step_m = _cut_into_steps(fl.plan, polyline, step_m, rng)
        dt = leg_step_m / rng.uniform(*walk_cfg.speed_mps)
        feet_b = fl.to_building(feet)
        for k in range(1, feet.shape[0]):
            step(t, t + dt, feet_b[k - 1], feet_b[k], floor)
            t += dt
        current = goal
        return t

    def wander(t: float, until: float) -> float:
        while t < until:
            g = graphs[floor]
            far = members[floor][np.linalg.norm(g.xy_m[members[floor]] - g.xy_m[current], axis=1)
                                 >= walk_cfg.min_goal_distance_m]
            t = walk_to(int(rng.choice(far if far.size else members[floor])), t)
            t += rng.uniform(*walk_cfg.pause_s)
            waypoint(t, floor, here_b(floor, current))
        return t

    def nodes_inside(f: int, polygon) -> np.ndarray:
        g = graphs[f]
        inside = shapely.contains_xy(polygon, g.xy_m[members[f], 0], g.xy_m[members[f], 1])
        return members[f][inside]

    for change in changes:
        connector = next((c for c in building.connectors if c.name == change.connector), None)
        if connector is None:
            raise MapfilterError(f"the building has no connector {change.connector!r}", building.path)
        here_name = building.floors[floor].name
        dest = building.floor_index(change.to_floor)
        if here_name not in connector.polygons or change.to_floor not in connector.polygons or dest == floor:
            raise MapfilterError(f"connector {connector.name!r} does not link {here_name} to {change.to_floor}",
                                 building.path)
        t = wander(t, t + rng.uniform(*config.segment_s))
        entries = nodes_inside(floor, connector.polygons[here_name])
        exits = nodes_inside(dest, connector.polygons[change.to_floor])
        if entries.size == 0 or exits.size == 0:
            raise MapfilterError(f"connector {connector.name!r} has no room to walk in on {here_name} or "
                                 f"{change.to_floor}", building.path)
        entry = int(entries[np.argmin(np.linalg.norm(graphs[floor].xy_m[entries] - graphs[floor].xy_m[current],
                                                     axis=1))])
        t = walk_to(entry, t)
        t_enter = t
        entry_b = here_b(floor, entry)
        rise = elevation[dest] - elevation[floor]
        if connector.kind == "lift":
            exit_node = int(exits[np.argmin(np.linalg.norm(here_b(dest, exits) - entry_b, axis=1))])
            t += rng.uniform(*config.lift_wait_s)
            ride = config.lift_s_per_storey * abs(rise) / max(building.storey_height_m or 4.0, 1e-9)
            plan.elev_t += [t, t + ride]
            plan.elev_m += [elevation[floor], elevation[dest]]
            t_switch = t + ride / 2
            waypoint(t_switch - 1e-3, floor, entry_b)
            waypoint(t_switch, dest, entry_b)
            t += ride + config.lift_exit_s
            waypoint(t, dest, entry_b)
            exit_b = here_b(dest, exit_node)
            if np.linalg.norm(exit_b - entry_b) > 0.05:  # step out onto the destination floor's grid
                step(t, t + walk_cfg.step_length_m / 1.2, entry_b, exit_b, dest)
                t += walk_cfg.step_length_m / 1.2
        else:
            # across the stairs: to the far end of the polygon on the destination floor
            far = np.linalg.norm(here_b(dest, exits) - entry_b, axis=1)
            exit_node = int(exits[np.argmax(far)])
            exit_b = here_b(dest, exit_node)
            n_steps = max(2, int(math.ceil(abs(rise) / config.stair_rise_m)))
            path = entry_b + np.linspace(0.0, 1.0, n_steps + 1)[:, None] * (exit_b - entry_b)
            here_fl, dest_fl = building.floors[floor], building.floors[dest]
            for fl in (here_fl, dest_fl):
                local = fl.from_building(path)
                if crosses_wall(fl.plan, local[:-1], local[1:]).any():
                    raise MapfilterError(f"connector {connector.name!r}: the straight way across the stairs meets a "
                                         f"wall on floor {fl.name}", building.path)
            plan.elev_t += [t, t + n_steps * config.stair_step_s]
            plan.elev_m += [elevation[floor], elevation[dest]]
            t_switch = t + (n_steps // 2) * config.stair_step_s
            for k in range(1, n_steps + 1):  # the floor changes after the middle step
                step(t, t + config.stair_step_s, path[k - 1], path[k], dest if k > n_steps // 2 else floor)
                t += config.stair_step_s
        plan.changes.append((t_enter, t_switch, t, floor, dest, connector.kind))
        floor = dest
        current = exit_node
        plan.elev_t.append(t)
        plan.elev_m.append(elevation[floor])
    t = wander(t, t + rng.uniform(*config.segment_s))
    end_t = t
    plan.elev_t.append(end_t)
    plan.elev_m.append(elevation[floor])
    return _sensors(building, ap_tables, plan, end_t, config, rng, site_id)


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
    gaps = rng.uniform(*walk_cfg.scan_interval_s, size=int(end_t / walk_cfg.scan_interval_s[0]) + 2)
    scan_t = np.cumsum(gaps)
    scan_t = scan_t[scan_t <= end_t]
    elev_t, elev_m = np.array(plan.elev_t), np.array(plan.elev_m)
    order_e = np.argsort(elev_t, kind="stable")
    elev_t, elev_m = elev_t[order_e], elev_m[order_e]
    ap_table, ap_floor = building_access_points(building, ap_tables)

    def floor_at(t_rel: np.ndarray) -> np.ndarray:
        return wp_floor[np.clip(np.searchsorted(wp_t, t_rel, side="right") - 1, 0, wp_t.size - 1)]

    def position_at(t_rel: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(t_rel, wp_t, wp_b[:, 0]), np.interp(t_rel, wp_t, wp_b[:, 1])], axis=-1)

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
        waypoint_t_s=t0 + wp_t, waypoint_xy_m=wp_local,
        step_start_t_s=t0 + step_start, step_end_t_s=t0 + step_end, step_length_m=np.linalg.norm(xy1 - xy0, axis=1),
        heading_t_s=t0 + imu["t_nominal"], heading_rad=imu["heading"], reference_xy_m=np.zeros((0, 2)),
        acc_t_s=t0 + imu["acc_t"], acc_mps2=imu["acc"], gyro_t_s=t0 + imu["gyro_t"], gyro_radps=imu["gyro"],
        magnet_t_s=t0 + imu["magnet_t"], magnet_ut=imu["magnet"],
        rotvec_t_s=t0 + imu["rotvec_t"], rotvec_xyz=imu["rotvec"], gyro_bias_radps=imu["gyro_bias"],
        ap_bssid=list(ap_table.bssid), ap_band=list(ap_table.band), ap_freq_mhz=wifi["freq"],
        scan_t_s=t0 + scan_t, row_scan=wifi["row_scan"], row_ap=wifi["row_ap"], rssi_dbm=wifi["rssi"],
        seen_t_s=t0 + wifi["seen"], stale=wifi["stale"], expected_rssi_dbm=wifi["expected"],
        walls_crossed=wifi["walls"], waypoint_floor=[names[f] for f in wp_floor],
        pressure_t_s=t0 + p_t, pressure_hpa=p_hpa,
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
