"""Synthetic walks over a FloorPlan, written in the ILC trace format.

A simulated walk has what a real phone log has, plus the truth behind it:

- a **route**: shortest paths on a coarse grid of free cells that keep a clearance from
  the walls (``FloorPlan.wall_distance_px``), between random goal points, string-pulled
  into straight legs and cut into steps of about 0.7 m walked at 1.0-1.5 m/s; every step
  is a ground-truth ``TYPE_WAYPOINT``; every move (grid edge, shortcut, step) is checked
  against the mask with an exact pixel walk, so no route ever crosses a wall;
- an **IMU** at 50 Hz: accelerometer with gravity and one vertical bump per step, gyroscope
  from the route's turns (about the gravity axis, seen in the tilted phone frame) with bias
  and noise, rotation vector (Android convention), a simple magnetometer; timestamp jitter
  and dropped samples;
- **WiFi scans** every 2-4 s from a multi-wall path-loss model: the Lund thesis model
  ``mapfilter.sensors.pathloss.path_loss_rssi_dbm`` plus a loss per wall crossed on the AP->phone line
  (Motley-Keenan), log-normal shadowing, a sensitivity floor, and stale cached rows;
- a **survey mode**: stand at reference points on a grid for a few scans each (radio-map
  collection, as in Evennou & Marx), with a waypoint at every scan.

Frames: the world frame is the floor frame (x east, y north, metres). The phone is held
flat-ish, screen up, its top (+y of the device) pointing where the walker goes. Android's
azimuth is measured from north, clockwise, so the map heading is ``pi/2 - azimuth``; the
rotation vector is the quaternion of the device->world (ENU) rotation with ``w >= 0``.

Everything random comes from one ``numpy.random.Generator``: the same seed gives the same
file, byte for byte.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy import sparse
from scipy.ndimage import gaussian_filter1d
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial.transform import Rotation

from mapfilter.errors import MapfilterError
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import crosses_wall
from mapfilter.sensors.pathloss import AccessPointTable, path_loss_rssi_dbm
from mapfilter.simulate.segments import count_walls_crossed, segments_cross_wall, segments_min_clearance_m

GRAVITY_MPS2 = 9.80665
# Channel centre frequencies: 2.4 GHz channels 1-13, 5 GHz UNII-1..3 (36-165).
CHANNELS_2G4_MHZ = tuple(2412 + 5 * k for k in range(13))
CHANNELS_5G_MHZ = tuple(5000 + 5 * ch for ch in (36, 40, 44, 48, 52, 56, 60, 64, 100, 104, 108, 112, 116, 120,
                                                  124, 128, 132, 136, 140, 149, 153, 157, 161, 165))
# Earth's field in the floor frame (east, north, up), microtesla: a mid-latitude value.
EARTH_FIELD_ENU_UT = (0.0, 28.0, -38.0)

# Limits no real use meets, so that a typo cannot ask for more memory or time than the machine
# has: a walk (or a survey) of 4 h is about 1.2 GB while it is made (about 70 kB per simulated
# second) and 50 MB gzipped; ILC walks last 1-3 minutes.
MAX_DURATION_S = 4 * 3600.0
MAX_SURVEY_POINTS = 20_000  # reference points of one survey (a 2 m grid over 80 000 m^2)
MAX_SCANS_PER_POINT = 100
MAX_IMU_RATE_HZ = 1000.0
MAX_DB = 100.0  # shadowing sigma, loss per wall, blocking: 100 dB drowns any signal
MAX_START_TIME_MS = 4_102_444_800_000  # 2100-01-01: Unix milliseconds of a phone log


@dataclasses.dataclass(frozen=True)
class SimConfig:
    """Every knob of the simulator, with defaults that look like a phone walk in an office."""

    # --- route ---
    duration_s: float | None = 120.0  # walk length; in survey mode None = visit every reference point
    start_time_ms: int = 1_600_000_000_000  # Unix time of the first record (fixed: same seed, same file)
    initial_still_s: float = 1.0  # standing still before the first step (lets a PDR estimate gyro bias)
    grid_m: float = 0.25  # spacing of the route-planning grid (rounded to whole pixels)
    min_clearance_m: float = 0.25  # routes never come closer to a wall pixel centre than this (doors!)
    preferred_clearance_m: float = 0.5  # ...and prefer to keep at least this far off walls
    clearance_penalty: float = 4.0  # extra cost factor for grid edges closer to walls than preferred
    min_goal_distance_m: float = 3.0  # a new goal is at least this far (straight line) from the walker
    speed_mps: tuple[float, float] = (1.0, 1.5)  # walking speed, uniform per leg
    step_length_m: float = 0.7  # mean step length of this walker
    step_length_sigma_m: float = 0.05  # spread of the walker's mean step length between walks
    pause_s: tuple[float, float] = (0.5, 3.0)  # standing at each goal, uniform
    # --- IMU ---
    imu_rate_hz: float = 50.0
    step_bump_mps2: float = 4.0  # peak vertical acceleration of a step: |a| swings about +-4 m/s^2 in hand
    step_bump_sigma: float = 0.15  # relative spread of the bump amplitude between steps
    forward_sway_mps2: float = 1.0  # forward acceleration swing within a step
    acc_noise_mps2: float = 0.15  # white noise per axis per sample
    acc_bias_sigma_mps2: float = 0.05  # constant bias per axis per walk
    tilt_deg: tuple[float, float] = (15.0, 5.0)  # phone pitch (top raised) mean, sigma; roll ~ N(0, sigma)
    gyro_noise_radps: float = 0.01  # white noise per axis per sample
    gyro_bias_sigma_radps: float = 0.001  # constant bias per axis per walk (Android's calibrated gyroscope)
    heading_smoothing_s: float = 0.1  # a walker turns over about a step, not instantly
    turn_on_spot_s: float = 0.8  # after standing, the turn to the next goal takes this long
    rotvec_heading_sigma_deg: float = 5.0  # constant azimuth error of the rotation vector (indoor magnetism)
    rotvec_noise_deg: float = 0.3  # per-sample azimuth noise of the rotation vector
    magnet_noise_ut: float = 0.6
    magnet_offset_sigma_ut: float = 5.0  # hard-iron offset per axis per walk
    drop_probability: float = 0.01  # each sample of each sensor is lost with this probability
    gaps_per_minute: float = 0.5  # ...and now and then all sensors stall together (Poisson)
    gap_s: tuple[float, float] = (0.1, 0.3)  # length of such a stall, uniform
    timestamp_jitter_ms: float = 1.0  # sigma of the timestamp error
    # --- WiFi ---
    scan_interval_s: tuple[float, float] = (2.0, 4.0)  # uniform
    fresh_age_s: tuple[float, float] = (0.1, 1.9)  # scan time minus last-seen time of a fresh row
    wall_loss_2g4_db: float = 3.5  # Motley-Keenan loss per wall crossed, 2.4 GHz
    wall_loss_5g_db: float = 5.0  # ... 5 GHz (loses more through walls)
    shadowing_sigma_db: float = 5.0  # Lund thesis: RSSI noise N(0, 25 dB^2)
    sensitivity_dbm: float = -95.0  # weaker readings are not heard
    miss_probability: float = 0.05  # an audible AP is missing from a scan anyway
    stale_probability: float = 0.2  # an audible AP repeats its cached (older) row instead
    cache_probability: float = 0.5  # an AP not heard now still shows its cached row
    cache_max_age_s: float = 30.0  # cached rows older than this are gone
    ssid: str = "mapfilter-sim"
    # signal blocking (a hand over the phone, Lund thesis 7.3): (start_s, end_s, H_db) since the
    # walk's start; every AP reads H_db weaker while a reading's time is in [start_s, end_s)
    blocking_episodes: tuple[tuple[float, float, float], ...] = ()
    # --- survey (radio-map collection) ---
    survey: bool = False
    survey_spacing_m: float = 2.0  # reference points on a grid with this spacing
    survey_scans_per_point: int = 3

    def validate(self) -> None:
        """Raise ``MapfilterError`` for values a user could pass that make no sense."""
        if self.duration_s is not None and not (math.isfinite(self.duration_s) and self.duration_s > 0):
            raise MapfilterError(f"duration must be a positive number of seconds, got {self.duration_s}")
        if self.duration_s is not None and self.duration_s > MAX_DURATION_S:
            raise MapfilterError(f"duration must be at most {MAX_DURATION_S:g} s ({MAX_DURATION_S / 3600:g} h), "
                                 f"got {self.duration_s:g}")
        if not 0 <= self.start_time_ms <= MAX_START_TIME_MS:
            raise MapfilterError(f"start time must be Unix milliseconds between 0 and {MAX_START_TIME_MS} "
                                 f"(the year 2100), got {self.start_time_ms}")
        if not self.imu_rate_hz <= MAX_IMU_RATE_HZ:
            raise MapfilterError(f"imu_rate_hz must be at most {MAX_IMU_RATE_HZ:g}, got {self.imu_rate_hz}")
        if not self.survey_spacing_m >= self.grid_m:
            raise MapfilterError(f"survey spacing must be at least the route grid's {self.grid_m:g} m (the finest "
                                 f"grid a survey can walk), got {self.survey_spacing_m:g}")
        if self.survey_scans_per_point > MAX_SCANS_PER_POINT:
            raise MapfilterError(f"scans per point must be at most {MAX_SCANS_PER_POINT}, "
                                 f"got {self.survey_scans_per_point}")
        for name in ("shadowing_sigma_db", "wall_loss_2g4_db", "wall_loss_5g_db"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0 <= value <= MAX_DB):
                raise MapfilterError(f"{name} must be between 0 and {MAX_DB:g} dB, got {value}")
        if not self.survey and self.duration_s is None:
            raise MapfilterError("a walk needs a duration")
        for name in ("grid_m", "min_clearance_m", "step_length_m", "imu_rate_hz", "survey_spacing_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise MapfilterError(f"{name} must be positive, got {value}")
        for name in ("speed_mps", "scan_interval_s", "pause_s", "fresh_age_s"):
            lo, hi = getattr(self, name)
            if not (0 <= lo <= hi) or (name in ("speed_mps", "scan_interval_s") and lo <= 0):
                raise MapfilterError(f"{name} must be a range 0 < low <= high, got {(lo, hi)}")
        for episode in self.blocking_episodes:
            if len(episode) != 3 or not all(math.isfinite(v) for v in episode):
                raise MapfilterError(f"a blocking episode is (start_s, end_s, H_db), got {episode}")
            start, end, h_db = episode
            if not (0 <= start < end <= MAX_DURATION_S) or not 0 <= h_db <= MAX_DB:
                raise MapfilterError(f"a blocking episode needs 0 <= start < end <= {MAX_DURATION_S:g} s and "
                                     f"0 <= H <= {MAX_DB:g} dB, got {episode}")
        if self.shadowing_sigma_db < 0:
            raise MapfilterError(f"shadowing sigma must be >= 0 dB, got {self.shadowing_sigma_db}")
        if self.survey_scans_per_point < 1:
            raise MapfilterError(f"scans per point must be >= 1, got {self.survey_scans_per_point}")
        if self.gaps_per_minute < 0 or not 0 <= self.gap_s[0] <= self.gap_s[1]:
            raise MapfilterError(f"gaps_per_minute must be >= 0 and gap_s a range, got {self.gaps_per_minute}, {self.gap_s}")
        for name in ("drop_probability", "miss_probability", "stale_probability", "cache_probability"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise MapfilterError(f"{name} must be in [0, 1), got {getattr(self, name)}")


@dataclasses.dataclass
class SimulatedWalk:
    """A simulated phone log (what gets written) and its truth (what does not).

    Times are Unix seconds (float64), positions floor-frame metres.
    """

    floor_name: str | None
    site_id: str
    start_t_s: float
    end_t_s: float
    # ground truth
    waypoint_t_s: np.ndarray  # (W,) written as TYPE_WAYPOINT: every step end, leg starts, survey scans
    waypoint_xy_m: np.ndarray  # (W, 2)
    step_start_t_s: np.ndarray  # (K,) one entry per step (one accelerometer bump each)
    step_end_t_s: np.ndarray  # (K,)
    step_length_m: np.ndarray  # (K,) chord length of each step
    heading_t_s: np.ndarray  # (M,) the nominal IMU grid
    heading_rad: np.ndarray  # (M,) true walking heading, map frame (from +x, counter-clockwise)
    reference_xy_m: np.ndarray  # (P, 2) survey reference points (empty for a walk)
    # sensors (phone frame), as written
    acc_t_s: np.ndarray
    acc_mps2: np.ndarray
    gyro_t_s: np.ndarray
    gyro_radps: np.ndarray
    magnet_t_s: np.ndarray
    magnet_ut: np.ndarray
    rotvec_t_s: np.ndarray
    rotvec_xyz: np.ndarray
    gyro_bias_radps: np.ndarray  # (3,) the constant bias added to the gyroscope
    # WiFi rows, grouped by scan
    ap_bssid: list[str]  # (K_ap,) per access point (bssid, band) of the table
    ap_band: list[str]
    ap_freq_mhz: np.ndarray  # (K_ap,) channel of each access point
    scan_t_s: np.ndarray  # (S,)
    row_scan: np.ndarray  # (R,) index into scan_t_s
    row_ap: np.ndarray  # (R,) index into the access-point table
    rssi_dbm: np.ndarray  # (R,) int, as written
    seen_t_s: np.ndarray  # (R,) last-seen time (when that RSSI was measured)
    stale: np.ndarray  # (R,) bool: a cached row repeated from an earlier scan
    expected_rssi_dbm: np.ndarray  # (R,) model mean (path loss + walls) at the position at seen_t_s
    walls_crossed: np.ndarray  # (R,) walls on the AP->phone line at seen_t_s
    # a walk over several floors (``simulate.building``): each waypoint's floor (written as a
    # fifth TYPE_WAYPOINT column) and a barometer (TYPE_PRESSURE rows); None for one floor
    waypoint_floor: list[str] | None = None
    pressure_t_s: np.ndarray | None = None
    pressure_hpa: np.ndarray | None = None

    @property
    def n_steps(self) -> int:
        return int(self.step_end_t_s.shape[0])

    def position_at(self, t_s: np.ndarray) -> np.ndarray:
        """True position at any time: the walker moves straight between waypoints."""
        t = np.asarray(t_s, dtype=np.float64)
        return np.stack([np.interp(t, self.waypoint_t_s, self.waypoint_xy_m[:, 0]),
                         np.interp(t, self.waypoint_t_s, self.waypoint_xy_m[:, 1])], axis=-1)


def model_rssi_dbm(floorplan: FloorPlan, ap_table: AccessPointTable, ap_index: np.ndarray, xy_m: np.ndarray,
                   config: SimConfig = SimConfig()) -> tuple[np.ndarray, np.ndarray]:
    """Multi-wall model mean RSSI of AP ``ap_index[i]`` at point ``xy_m[i]``, and the walls crossed.

    R = C - 10 n log10(d) - alpha min(d, d_max)   (Lund thesis, per AP and band)
        - L_wall(band) * walls                     (Motley-Keenan: walls on the AP->phone line)

    Returns
    -------
    rssi_dbm : (N,) float64
    walls : (N,) int64
    """
    k = np.asarray(ap_index, dtype=np.int64)
    xy = np.atleast_2d(np.asarray(xy_m, dtype=np.float64))
    walls = count_walls_crossed(floorplan, ap_table.xy_m[k], xy)
    d_m = np.linalg.norm(xy - ap_table.xy_m[k], axis=-1)
    loss_db = np.where(np.array(ap_table.band)[k] == "5", config.wall_loss_5g_db, config.wall_loss_2g4_db)
    rssi = path_loss_rssi_dbm(d_m, ap_table.c_dbm[k], ap_table.n[k], ap_table.alpha_db_per_m[k], ap_table.d_max_m[k])
    return rssi - loss_db * walls, walls


def blocking_db(t_s: np.ndarray, episodes) -> np.ndarray:
    """Blocking loss (dB, >= 0) at times ``t_s`` (since the walk's start): the sum of the
    episodes (start_s, end_s, H_db) that cover each time."""
    t = np.asarray(t_s, dtype=np.float64)
    loss = np.zeros_like(t)
    for start, end, h_db in episodes:
        loss += np.where((t >= start) & (t < end), float(h_db), 0.0)
    return loss


def offset_access_points(ap_table: AccessPointTable, c_offset_db: float = 0.0,
                         alpha_offset_db_per_m: float = 0.0) -> AccessPointTable:
    """A deliberately wrong copy of ``ap_table``: C + ``c_offset_db`` and alpha +
    ``alpha_offset_db_per_m`` (clipped at 0) on every AP; positions, n and d_max unchanged.
    The Lund thesis started its adaptation from such a table (C = -25 dBm, alpha = 0.3 dB/m)."""
    for name, value in (("C offset", c_offset_db), ("alpha offset", alpha_offset_db_per_m)):
        if not math.isfinite(value):
            raise MapfilterError(f"the {name} must be a finite number, got {value}")
    return dataclasses.replace(ap_table, xy_m=ap_table.xy_m.copy(), c_dbm=ap_table.c_dbm + float(c_offset_db),
                               alpha_db_per_m=np.maximum(ap_table.alpha_db_per_m + float(alpha_offset_db_per_m), 0.0),
                               n=ap_table.n.copy(), d_max_m=ap_table.d_max_m.copy(),
                               bssid=list(ap_table.bssid), band=list(ap_table.band))


# ---------------------------------------------------------------------------------------
# route planning
# ---------------------------------------------------------------------------------------
@dataclasses.dataclass
class _RouteGraph:
    xy_m: np.ndarray  # (V, 2) node positions
    clearance_m: np.ndarray  # (V,)
    graph: sparse.csr_matrix
    component: np.ndarray  # (V,) label; the walker lives in `main`
    main: int
    stride_px: int
    rc: np.ndarray  # (V, 2) grid (row, col) index of every node


def _build_route_graph(floorplan: FloorPlan, config: SimConfig) -> _RouteGraph:
    """Grid of cells with clearance >= min_clearance; 8-connected edges that stay off walls."""
    res = floorplan.resolution_m
    stride = max(1, int(round(config.grid_m / res)))
    h, w = floorplan.shape_px
    rows = np.arange(stride // 2, h, stride)
    cols = np.arange(stride // 2, w, stride)
    clearance_grid = floorplan.wall_distance_px[np.ix_(rows, cols)] * res
    ok = clearance_grid >= config.min_clearance_m
    node_of = np.full(ok.shape, -1, dtype=np.int64)
    gr, gc = np.nonzero(ok)
    if gr.size < 2:
        raise MapfilterError(
            f"the map has no free space at least {config.min_clearance_m} m from walls to walk in")
    node_of[gr, gc] = np.arange(gr.size)
    uv = np.stack([cols[gc] + 0.5, rows[gr] + 0.5], axis=-1)
    xy = floorplan.pixel_to_world(uv)
    clearance = clearance_grid[gr, gc]
    src, dst = [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        r2, c2 = gr + dr, gc + dc
        inside = (r2 >= 0) & (r2 < ok.shape[0]) & (c2 >= 0) & (c2 < ok.shape[1])
        j = np.full(gr.size, -1, dtype=np.int64)
        j[inside] = node_of[r2[inside], c2[inside]]
        keep = j >= 0
        src.append(np.nonzero(keep)[0])
        dst.append(j[keep])
    src_a, dst_a = np.concatenate(src), np.concatenate(dst)
    edge_clear = segments_min_clearance_m(floorplan, xy[src_a], xy[dst_a])
    keep = edge_clear > 0.0  # exact pixel walk: an edge never touches a wall pixel
    src_a, dst_a, edge_clear = src_a[keep], dst_a[keep], edge_clear[keep]
    length = np.linalg.norm(xy[src_a] - xy[dst_a], axis=1)
    # Prefer to stay `preferred_clearance_m` off the walls: edges closer cost more.
    shortfall = np.clip((config.preferred_clearance_m - edge_clear) / config.preferred_clearance_m, 0.0, 1.0)
    cost = length * (1.0 + config.clearance_penalty * shortfall)
    n = gr.size
    graph = sparse.coo_matrix((np.concatenate([cost, cost]), (np.concatenate([src_a, dst_a]),
                                                               np.concatenate([dst_a, src_a]))), shape=(n, n)).tocsr()
    n_comp, labels = connected_components(graph, directed=False)
    main = int(np.argmax(np.bincount(labels)))
    return _RouteGraph(xy, clearance, graph, labels, main, stride, np.stack([gr, gc], axis=-1))


def _shortest_path(graph: _RouteGraph, source: int, target: int, predecessors: np.ndarray | None = None) -> list[int]:
    if predecessors is None:
        _, predecessors = dijkstra(graph.graph, indices=source, return_predecessors=True)
    path = [target]
    while path[-1] != source:
        prev = int(predecessors[path[-1]])
        if prev < 0:
            raise MapfilterError("no route between two points of the same free region (internal)")
        path.append(prev)
    return path[::-1]


def _string_pull(floorplan: FloorPlan, graph: _RouteGraph, nodes: list[int], preferred_m: float) -> np.ndarray:
    """Straighten a grid path: jump to the farthest node in sight that keeps the clearance.

    A shortcut must keep at least the clearance the grid path had there (capped at the
    preferred clearance), so straightening never pulls the walker against a wall.
    """
    xy = graph.xy_m[nodes]
    clear = graph.clearance_m[nodes]
    tolerance_m = floorplan.resolution_m
    out = [0]
    i = 0
    while i < len(nodes) - 1:
        j = i + 1  # the next grid node is always reachable (a checked edge)
        cand = np.arange(i + 2, len(nodes))
        if cand.size:
            seg_clear = segments_min_clearance_m(floorplan, np.repeat(xy[i:i + 1], cand.size, axis=0), xy[cand])
            path_clear = np.minimum.accumulate(clear[i:])[cand - i]  # grid path's clearance up to each node
            needed = np.minimum(path_clear, preferred_m) - tolerance_m
            good = (seg_clear > 0.0) & (seg_clear >= needed)
            bad = np.nonzero(~good)[0]
            last_good = (bad[0] if bad.size else cand.size) - 1  # longest all-visible prefix
            if last_good >= 0:
                j = int(cand[last_good])
        out.append(j)
        i = j
    return xy[out]


@dataclasses.dataclass
class _Timeline:
    """The planned walk before sensors: steps, waypoints, survey scan times."""

    waypoint_t: list[float]
    waypoint_xy: list[np.ndarray]
    step_start: list[float]
    step_end: list[float]
    step_xy0: list[np.ndarray]
    step_xy1: list[np.ndarray]
    survey_scan_t: list[float]


def _cut_into_steps(floorplan: FloorPlan, polyline: np.ndarray, step_m: float,
                    rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """Positions of the feet along a polyline: equal arc-length steps of about ``step_m``.

    A step's chord cuts a corner; if a chord would touch a wall the corner vertex itself
    becomes a (shorter) step, so the ground truth never crosses a wall.

    Returns the positions (first = start) and the nominal step length of this leg.
    """
    seg = np.diff(polyline, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    total = float(seg_len.sum())
    if total < 1e-9:
        return polyline[:1], step_m
    n = max(1, int(round(total / step_m)))
    lengths = (total / n) * (1.0 + 0.03 * rng.standard_normal(n))  # 3 % step-to-step variation
    lengths = np.clip(lengths, 0.2 * total / n, None)
    s = np.concatenate([[0.0], np.cumsum(lengths)])
    s *= total / s[-1]
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    pts = np.stack([np.interp(s, cum, polyline[:, 0]), np.interp(s, cum, polyline[:, 1])], axis=-1)
    pts[-1] = polyline[-1]
    bad = set(np.nonzero(segments_cross_wall(floorplan, pts[:-1], pts[1:]))[0].tolist())
    if not bad:
        return pts, total / n
    out = [pts[0]]
    for k in range(1, pts.shape[0]):
        if k - 1 in bad:
            inner = np.nonzero((cum > s[k - 1]) & (cum < s[k]))[0]
            out.extend(polyline[inner])
        out.append(pts[k])
    return np.asarray(out), total / n


def _plan(floorplan: FloorPlan, config: SimConfig, rng: np.random.Generator) -> tuple[_Timeline, np.ndarray, float]:
    graph = _build_route_graph(floorplan, config)
    members = np.nonzero(graph.component == graph.main)[0]
    step_m = max(0.3, config.step_length_m + config.step_length_sigma_m * rng.standard_normal())
    tl = _Timeline([], [], [], [], [], [], [])
    current = int(rng.choice(members))
    t = 0.0
    tl.waypoint_t.append(t)
    tl.waypoint_xy.append(graph.xy_m[current])
    t = config.initial_still_s
    limit = math.inf if config.duration_s is None else float(config.duration_s)
    todo = _survey_points(floorplan, graph, members, config) if config.survey else set()
    reference = []
    while t < limit:
        dist, pred = dijkstra(graph.graph, indices=current, return_predecessors=True)
        if config.survey:
            if not todo:
                break
            cand = np.fromiter(todo, dtype=np.int64)
            goal = int(cand[np.argmin(dist[cand])]) if len(cand) else current
            todo.discard(goal)
        else:
            far = members[np.linalg.norm(graph.xy_m[members] - graph.xy_m[current], axis=1) >= config.min_goal_distance_m]
            goal = int(rng.choice(far if far.size else members))
        if goal != current:
            t = _walk_leg(floorplan, graph, tl, current, goal, pred, step_m, t, config, rng)
        current = goal
        if config.survey and t > MAX_DURATION_S:  # a walk stops at its duration
            raise MapfilterError(f"the survey would last more than {MAX_DURATION_S / 3600:g} h: raise the survey "
                                 "spacing or lower the scans per point")
        if config.survey:
            reference.append(graph.xy_m[goal])
            t = _survey_scans(tl, graph.xy_m[goal], t, config, rng)
        else:
            t += rng.uniform(*config.pause_s)
        # the walker leaves the goal now: a waypoint pins the standing time
        tl.waypoint_t.append(t)
        tl.waypoint_xy.append(graph.xy_m[goal])
    end_t = min(t, limit)
    return tl, np.asarray(reference).reshape(-1, 2), end_t


def _survey_points(floorplan: FloorPlan, graph, members: np.ndarray, config: SimConfig) -> set[int]:
    """The survey's reference points: grid nodes on a lattice of survey_spacing_m (Evennou &
    Marx: a fingerprint every 2 m), to be visited nearest-first along the walking routes."""
    every = max(1, int(round(config.survey_spacing_m / (graph.stride_px * floorplan.resolution_m))))
    on_lattice = (graph.rc[members, 0] % every == 0) & (graph.rc[members, 1] % every == 0)
    todo = set(members[on_lattice].tolist())
    if not todo:
        raise MapfilterError("no survey reference point fits the map: lower the survey spacing")
    if len(todo) > MAX_SURVEY_POINTS:
        raise MapfilterError(f"a survey at {config.survey_spacing_m:g} m spacing has {len(todo)} reference points "
                             f"here, more than {MAX_SURVEY_POINTS}: raise the survey spacing")
    return todo


def _walk_leg(floorplan: FloorPlan, graph, tl: _Timeline, current: int, goal: int, pred: np.ndarray, step_m: float,
              t: float, config: SimConfig, rng: np.random.Generator) -> float:
    """Walk the route from node ``current`` to ``goal`` step by step (steps and waypoints into
    ``tl``); the time of arrival."""
    nodes = _shortest_path(graph, current, goal, pred)
    polyline = _string_pull(floorplan, graph, nodes, config.preferred_clearance_m)
    feet, leg_step_m = _cut_into_steps(floorplan, polyline, step_m, rng)
    speed = rng.uniform(*config.speed_mps)
    dt = leg_step_m / speed  # cadence is steady within a leg; a short corner step is slower
    for k in range(1, feet.shape[0]):
        tl.step_start.append(t)
        tl.step_xy0.append(feet[k - 1])
        t += dt
        tl.step_end.append(t)
        tl.step_xy1.append(feet[k])
        tl.waypoint_t.append(t)
        tl.waypoint_xy.append(feet[k])
    return t


def _survey_scans(tl: _Timeline, xy_m: np.ndarray, t: float, config: SimConfig, rng: np.random.Generator) -> float:
    """Stand still at a reference point and scan; a waypoint at each scan labels it for the radio
    map. The time the walker leaves."""
    t += config.fresh_age_s[1] + 0.1  # so the first scan's fresh rows are measured here
    for i_scan in range(config.survey_scans_per_point):
        if i_scan:
            t += rng.uniform(*config.scan_interval_s)
        tl.survey_scan_t.append(t)
        tl.waypoint_t.append(t)
        tl.waypoint_xy.append(xy_m)
    return t + 0.5


# ---------------------------------------------------------------------------------------
# sensors
# ---------------------------------------------------------------------------------------
def _imu(tl_start: np.ndarray, tl_end: np.ndarray, xy0: np.ndarray, xy1: np.ndarray, end_t: float,
         config: SimConfig, rng: np.random.Generator) -> dict[str, np.ndarray]:
    dt_s = 1.0 / config.imu_rate_hz
    t = np.arange(0.0, end_t, dt_s)
    heading = _step_heading(t, tl_start, tl_end, xy0, xy1, config)
    heading = gaussian_filter1d(heading, config.heading_smoothing_s / dt_s, mode="nearest")
    yaw_rate = np.gradient(heading, dt_s)
    vert, fwd = _step_bumps(t, tl_start, tl_end, config, rng)
    sensors, gyro_bias = _phone_sensors(heading, yaw_rate, vert, fwd, config, rng)
    t_rep, stalled = _reported_times(t, end_t, config, rng)
    out: dict[str, np.ndarray] = {"t_nominal": t, "heading": heading, "gyro_bias": gyro_bias}
    for name, values in sensors:
        keep = (rng.random(t.shape[0]) >= config.drop_probability) & ~stalled
        out[name + "_t"] = t_rep[keep]
        out[name] = values[keep]
    return out


def _step_heading(t: np.ndarray, tl_start: np.ndarray, tl_end: np.ndarray, xy0: np.ndarray, xy1: np.ndarray,
                  config: SimConfig) -> np.ndarray:
    """The walking heading at times t: step chord directions, unwrapped, held during pauses."""
    if not tl_start.shape[0]:
        return np.zeros(t.shape[0])
    chord = xy1 - xy0
    heading_steps = np.unwrap(np.arctan2(chord[:, 1], chord[:, 0]))
    # knots at mid-step: a turn between two steps takes about one step period
    knot_t = list(0.5 * (tl_start + tl_end))
    knot_h = list(heading_steps)
    # after a pause the walker turns on the spot just before setting off, not all along
    for i in np.nonzero(tl_start[1:] > tl_end[:-1] + 1e-6)[0]:
        knot_t.append(max(tl_end[i], tl_start[i + 1] - config.turn_on_spot_s))
        knot_h.append(heading_steps[i])
    order = np.argsort(knot_t, kind="stable")
    return np.interp(t, np.asarray(knot_t)[order], np.asarray(knot_h)[order])


def _step_bumps(t: np.ndarray, tl_start: np.ndarray, tl_end: np.ndarray, config: SimConfig,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(vertical, forward) acceleration of the steps at times t. The body bobs once per step,
    vertical acceleration -A cos(2 pi s) with s the phase within the step (peak +A mid-step, zero
    mean over a step). The first half of the first step of a bout and the last half of its last
    step are faded in/out with sin^2(pi s), so standing is exactly still and every step, even a
    lone one, has its single peak."""
    m, k = t.shape[0], tl_start.shape[0]
    vert = np.zeros(m)
    fwd = np.zeros(m)
    if k:
        amp_steps = config.step_bump_mps2 * np.clip(1.0 + config.step_bump_sigma * rng.standard_normal(k), 0.5, 1.5)
        first = np.ones(k, bool)
        first[1:] = tl_start[1:] > tl_end[:-1] + 1e-6
        last = np.ones(k, bool)
        last[:-1] = first[1:]
        j = np.searchsorted(tl_start, t, side="right") - 1
        inside = (j >= 0) & (t < tl_end[np.clip(j, 0, k - 1)])
        jj = j[inside]
        s = (t[inside] - tl_start[jj]) / (tl_end[jj] - tl_start[jj])
        taper = np.where((first[jj] & (s < 0.5)) | (last[jj] & (s >= 0.5)), np.sin(np.pi * s) ** 2, 1.0)
        # amplitude varies smoothly from step to step (no jumps at step boundaries)
        amp = np.interp(t[inside], 0.5 * (tl_start + tl_end), amp_steps)
        vert[inside] = -amp * np.cos(2 * np.pi * s) * taper
        fwd[inside] = config.forward_sway_mps2 * np.sin(2 * np.pi * s) * taper
    return vert, fwd


def _phone_sensors(heading: np.ndarray, yaw_rate: np.ndarray, vert: np.ndarray, fwd: np.ndarray, config: SimConfig,
                   rng: np.random.Generator) -> tuple[list[tuple[str, np.ndarray]], np.ndarray]:
    """What the tilted phone's accelerometer, magnetometer, gyroscope and rotation vector read at
    each sample (with bias and noise), and the gyroscope's bias."""
    m = heading.shape[0]
    # phone orientation: device->world R = Rz(yaw) Rx(pitch) Ry(roll); device +y is forward,
    # so yaw = heading - pi/2 (Android azimuth = pi/2 - heading).
    pitch = math.radians(config.tilt_deg[0] + config.tilt_deg[1] * rng.standard_normal())
    roll = math.radians(config.tilt_deg[1] * rng.standard_normal())
    yaw = heading - np.pi / 2
    rot = Rotation.from_euler("ZXY", np.column_stack([yaw, np.full(m, pitch), np.full(m, roll)]))
    # specific force in the world frame: motion minus gravity (gravity points down)
    f_world = np.column_stack([fwd * np.cos(heading), fwd * np.sin(heading), GRAVITY_MPS2 + vert])
    acc = rot.inv().apply(f_world)
    acc += config.acc_bias_sigma_mps2 * rng.standard_normal(3) + config.acc_noise_mps2 * rng.standard_normal((m, 3))
    # body rate = R^T (0, 0, yaw rate): the yaw axis is the gravity axis, tilted in the phone frame
    gyro_true = rot.inv().apply(np.column_stack([np.zeros(m), np.zeros(m), yaw_rate]))
    gyro_bias = config.gyro_bias_sigma_radps * rng.standard_normal(3)
    gyro = gyro_true + gyro_bias + config.gyro_noise_radps * rng.standard_normal((m, 3))
    magnet = rot.inv().apply(np.array(EARTH_FIELD_ENU_UT))
    magnet += config.magnet_offset_sigma_ut * rng.standard_normal(3) + config.magnet_noise_ut * rng.standard_normal((m, 3))
    # rotation vector: the phone's own (magnetically disturbed) azimuth estimate
    azimuth_err = math.radians(config.rotvec_heading_sigma_deg) * rng.standard_normal() \
        + math.radians(config.rotvec_noise_deg) * rng.standard_normal(m)
    rot_est = Rotation.from_euler("ZXY", np.column_stack([yaw + azimuth_err, np.full(m, pitch), np.full(m, roll)]))
    quat = rot_est.as_quat()  # x, y, z, w
    quat[quat[:, 3] < 0] *= -1.0  # Android's rotation vector keeps w >= 0 (it writes only x, y, z)
    return [("acc", acc), ("magnet", magnet), ("gyro", gyro), ("rotvec", quat[:, :3])], gyro_bias


def _reported_times(t: np.ndarray, end_t: float, config: SimConfig,
                    rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(the samples' reported times: jittered, kept strictly increasing; the samples in a stall,
    where no sensor reports)."""
    m = t.shape[0]
    t_rep = t + config.timestamp_jitter_ms * 1e-3 * rng.standard_normal(m)
    t_rep = np.maximum.accumulate(np.round(t_rep * 1000.0)) / 1000.0
    stalled = np.zeros(m, bool)
    n_gaps = rng.poisson(config.gaps_per_minute * end_t / 60.0)
    gap_start = rng.uniform(0.0, end_t, size=n_gaps)
    gap_end = gap_start + rng.uniform(*config.gap_s, size=n_gaps)
    for a, b in zip(gap_start, gap_end):
        stalled |= (t >= a) & (t < b)
    return t_rep, stalled


def _wifi(floorplan: FloorPlan, ap_table: AccessPointTable, position_at, scan_t: np.ndarray,
          config: SimConfig, rng: np.random.Generator, rssi_at=None) -> dict:
    """WiFi rows of every scan; ``rssi_at(seen_t_s (K,)) -> (expected dBm (K,), walls (K,))``
    replaces the one-floor multi-wall model (a building: ``simulate.building``)."""
    k_ap = len(ap_table)
    freq = np.array([rng.choice(CHANNELS_5G_MHZ) if band == "5" else rng.choice(CHANNELS_2G4_MHZ)
                     for band in ap_table.band], dtype=np.int64)
    cache_rssi = np.full(k_ap, np.nan)
    cache_seen = np.full(k_ap, -np.inf)
    cache_expected = np.full(k_ap, np.nan)
    cache_walls = np.zeros(k_ap, dtype=np.int64)
    rows: dict[str, list] = {key: [] for key in ("scan", "ap", "rssi", "seen", "stale", "expected", "walls")}
    for s, t_scan in enumerate(scan_t):
        seen = t_scan - rng.uniform(*config.fresh_age_s, size=k_ap)
        if rssi_at is None:
            expected, walls = model_rssi_dbm(floorplan, ap_table, np.arange(k_ap), position_at(seen), config)
        else:
            expected, walls = rssi_at(seen)
        expected = expected - blocking_db(seen, config.blocking_episodes)
        measured = np.round(expected + config.shadowing_sigma_db * rng.standard_normal(k_ap))
        audible = (measured >= config.sensitivity_dbm) & (rng.random(k_ap) >= config.miss_probability)
        cached_ok = np.isfinite(cache_rssi) & (t_scan - cache_seen <= config.cache_max_age_s)
        use_cache = cached_ok & np.where(audible, rng.random(k_ap) < config.stale_probability,
                                         rng.random(k_ap) < config.cache_probability)
        fresh = audible & ~use_cache
        cache_rssi[fresh] = measured[fresh]
        cache_seen[fresh] = seen[fresh]
        cache_expected[fresh] = expected[fresh]
        cache_walls[fresh] = walls[fresh]
        emit = fresh | use_cache
        idx = np.nonzero(emit)[0]
        order = idx[np.argsort(-cache_rssi[idx], kind="stable")]  # scans list the strongest first
        rows["scan"].extend([s] * order.size)
        rows["ap"].extend(order.tolist())
        rows["rssi"].extend(cache_rssi[order].astype(np.int64).tolist())
        rows["seen"].extend(cache_seen[order].tolist())
        rows["stale"].extend(use_cache[order].tolist())
        rows["expected"].extend(cache_expected[order].tolist())
        rows["walls"].extend(cache_walls[order].tolist())
    return {
        "freq": freq,
        "row_scan": np.array(rows["scan"], dtype=np.int64),
        "row_ap": np.array(rows["ap"], dtype=np.int64),
        "rssi": np.array(rows["rssi"], dtype=np.int64),
        "seen": np.array(rows["seen"], dtype=np.float64),
        "stale": np.array(rows["stale"], dtype=bool),
        "expected": np.array(rows["expected"], dtype=np.float64),
        "walls": np.array(rows["walls"], dtype=np.int64),
    }


def simulate_walk(floorplan: FloorPlan, ap_table: AccessPointTable, config: SimConfig,
                  rng: np.random.Generator, site_id: str = "mapfilter-sim", rssi_model=None) -> SimulatedWalk:
    """Simulate one phone walk (or a radio-map survey with ``config.survey``) over a floor plan.

    Parameters
    ----------
    floorplan : the map; routes keep ``config.min_clearance_m`` off its walls.
    ap_table : access points with their path-loss parameters (thesis model per AP and band).
    config : every knob; see ``SimConfig``.
    rng : the only source of randomness.
    site_id : written into the header.
    rssi_model : ``rssi_model(xy_m (K, 2)) -> (expected dBm (K,), walls (K,))``, AP i heard at
        ``xy_m[i]``, instead of the one-floor multi-wall model (``simulate.building``: APs of
        other floors).

    Returns
    -------
    SimulatedWalk : the sensors as written, and the truth.
    """
    config.validate()
    if len(ap_table) == 0:
        raise MapfilterError("the access-point table is empty")
    tl, reference, end_t = _plan(floorplan, config, rng)
    step_start = np.array(tl.step_start, dtype=np.float64)
    step_end = np.array(tl.step_end, dtype=np.float64)
    xy0 = np.array(tl.step_xy0, dtype=np.float64).reshape(-1, 2)
    xy1 = np.array(tl.step_xy1, dtype=np.float64).reshape(-1, 2)
    keep = step_end <= end_t  # a step cut by the end of the walk is not taken
    step_start, step_end, xy0, xy1 = step_start[keep], step_end[keep], xy0[keep], xy1[keep]
    wp_t = np.array(tl.waypoint_t, dtype=np.float64)
    wp_xy = np.array(tl.waypoint_xy, dtype=np.float64).reshape(-1, 2)
    wk = wp_t <= end_t
    wp_t, wp_xy = wp_t[wk], wp_xy[wk]
    if wp_t[-1] < end_t:  # the walker stands where the last step left him
        wp_t = np.append(wp_t, end_t)
        wp_xy = np.vstack([wp_xy, wp_xy[-1:]])
    # the filter's own wall rule must find no crossing in the ground truth
    if crosses_wall(floorplan, wp_xy[:-1], wp_xy[1:]).any():
        raise AssertionError("simulate: a planned step crosses a wall (bug in the route planner)")

    imu = _imu(step_start, step_end, xy0, xy1, end_t, config, rng)

    if config.survey:
        scan_t = np.array([t for t in tl.survey_scan_t if t <= end_t], dtype=np.float64)
    else:
        scan_t = _scan_times(end_t, config, rng)

    def position_at(t_rel: np.ndarray) -> np.ndarray:
        return _xy_at(t_rel, wp_t, wp_xy)

    wifi = _wifi(floorplan, ap_table, position_at, scan_t, config, rng,
                 rssi_at=None if rssi_model is None else (lambda seen: rssi_model(position_at(seen))))
    t0 = config.start_time_ms / 1000.0
    return SimulatedWalk(
        floor_name=floorplan.floor_name, site_id=site_id, start_t_s=t0, end_t_s=t0 + end_t,
        waypoint_t_s=t0 + wp_t, waypoint_xy_m=wp_xy, reference_xy_m=reference,
        **_step_and_sensor_fields(t0, step_start, step_end, xy0, xy1, imu, ap_table, scan_t, wifi),
    )


def _scan_times(end_t: float, config: SimConfig, rng: np.random.Generator) -> np.ndarray:
    """A walk's WiFi scan times (s from its start): gaps drawn from ``scan_interval_s``, up to end_t."""
    gaps = rng.uniform(*config.scan_interval_s, size=int(end_t / config.scan_interval_s[0]) + 2)
    scan_t = np.cumsum(gaps)
    return scan_t[scan_t <= end_t]


def _xy_at(t_rel: np.ndarray, wp_t: np.ndarray, wp_xy: np.ndarray) -> np.ndarray:
    """Positions at times ``t_rel``, interpolated between the waypoints."""
    return np.stack([np.interp(t_rel, wp_t, wp_xy[:, 0]), np.interp(t_rel, wp_t, wp_xy[:, 1])], axis=-1)


def _step_and_sensor_fields(t0: float, step_start: np.ndarray, step_end: np.ndarray, xy0: np.ndarray,
                            xy1: np.ndarray, imu: dict[str, np.ndarray], ap_table: AccessPointTable,
                            scan_t: np.ndarray, wifi: dict[str, np.ndarray]) -> dict:
    """The ``SimulatedWalk`` fields of its steps, IMU and WiFi, in Unix seconds from ``t0``."""
    return dict(
        step_start_t_s=t0 + step_start, step_end_t_s=t0 + step_end, step_length_m=np.linalg.norm(xy1 - xy0, axis=1),
        heading_t_s=t0 + imu["t_nominal"], heading_rad=imu["heading"],
        acc_t_s=t0 + imu["acc_t"], acc_mps2=imu["acc"], gyro_t_s=t0 + imu["gyro_t"], gyro_radps=imu["gyro"],
        magnet_t_s=t0 + imu["magnet_t"], magnet_ut=imu["magnet"],
        rotvec_t_s=t0 + imu["rotvec_t"], rotvec_xyz=imu["rotvec"], gyro_bias_radps=imu["gyro_bias"],
        ap_bssid=list(ap_table.bssid), ap_band=list(ap_table.band), ap_freq_mhz=wifi["freq"],
        scan_t_s=t0 + scan_t, row_scan=wifi["row_scan"], row_ap=wifi["row_ap"], rssi_dbm=wifi["rssi"],
        seen_t_s=t0 + wifi["seen"], stale=wifi["stale"], expected_rssi_dbm=wifi["expected"],
        walls_crossed=wifi["walls"],
    )
