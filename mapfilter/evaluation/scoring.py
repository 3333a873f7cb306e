"""One track of one walk scored as ``mapfilter track`` and ``mapfilter evaluate`` report it: the
floors it visits, its wall crossings, and (with ground truth) its errors and floor accuracy."""

from __future__ import annotations

import dataclasses

import numpy as np

from mapfilter.evaluation.metrics import FloorScore, WaypointErrors, errors_at_waypoints, floor_at_waypoints
from mapfilter.maps.building import Building
from mapfilter.maps.walls import count_wall_crossings
from mapfilter.sensors.recording import Recording
from mapfilter.io.tracks import Track


@dataclasses.dataclass(frozen=True)
class TrackScore:
    """One track of one walk."""

    floors: list[str]  # the floors the track visits, in the building's order
    wall_crossings: int  # moves through a wall, each stretch on a floor against that floor's walls
    true_floor: str | list[str] | None  # the walker's floor: per waypoint (simulated logs) or the header's
    errors: WaypointErrors | None  # at the waypoints; None without ground truth or a known floor for it
    floor_score: FloorScore | None  # on ``true_floor`` at the waypoints (a building with several floors)

    @property
    def off_floor(self) -> bool:
        """Some judged waypoint's estimate is on another floor (compared in its own floor's frame)."""
        return self.floor_score is not None and self.floor_score.n_right < self.floor_score.n_judged


def building_wall_crossings(building: Building, xy_m: np.ndarray, floor) -> int:
    """Moves of a track (rows ``xy_m`` on floors named ``floor``) through a wall: each unbroken
    stretch on one floor against that floor's walls; the move from one floor to the next is none."""
    floor = np.asarray(floor)
    if floor.size == 0:
        return 0
    change = np.flatnonzero(floor[1:] != floor[:-1]) + 1
    return sum(count_wall_crossings(building.floor(str(floor[start])).plan, xy_m[start:end])
               for start, end in zip(np.concatenate([[0], change]), np.concatenate([change, [floor.size]])))


def score_track(building: Building, recording: Recording, track: Track, header_floor: int | None,
                causal: bool = True) -> TrackScore:
    """Floors visited, wall crossings, and (with ground truth whose floor is known) the horizontal
    errors and, with several floors, the floor accuracy at the waypoints.

    ``track.floor`` names each row's floor (None: the building's only floor, or the header's).
    The walker's floor is each waypoint's own where the log has it (simulated walks that change
    floor, IPIN logs), else the header's (``header_floor``, an index into ``building.floors``;
    ILC walks keep one floor). Errors are horizontal, each row in its own floor's frame.
    """
    names = building.floor_names
    floor = np.array(track.floor if track.floor is not None else [names[header_floor or 0]] * len(track))
    visited = sorted(set(floor.tolist()), key=names.index)
    crossings = building_wall_crossings(building, track.xy_m, floor)
    true_floor: str | list[str] | None = None
    if recording.waypoint_floor is not None:
        true_floor = list(recording.waypoint_floor)
    elif header_floor is not None:
        true_floor = names[header_floor]
    errors = score = None
    if recording.has_ground_truth and (true_floor is not None or building.is_single_floor):
        errors = errors_at_waypoints(track.t_s, track.xy_m, recording.waypoint_t_s, recording.waypoint_xy_m, causal)
        if not building.is_single_floor:
            # storeys counted by elevation (floors at one elevation: in the file's order)
            order = [f.name for f in sorted(building.floors, key=lambda f: f.elevation_m)]
            score = floor_at_waypoints(track.t_s, list(floor), recording.waypoint_t_s, true_floor, causal, order)
    return TrackScore(visited, crossings, true_floor, errors, score)


def ground_truth_track(recording: Recording, at_t_s: np.ndarray | None = None) -> Track:
    """A walk's ground truth as a track (its waypoints, each on its own floor where the log names
    one), for trajectory tools such as evo. ``at_t_s``: instead, the ground truth at these times
    (a track's), linear between waypoints and only within their span, each row on the floor of
    the waypoint before it; then a tool that pairs rows by time pairs every row. The waypoints
    must be in the map's metres (``sensors.logs.localise`` places latitude/longitude ones)."""
    t_wp = recording.waypoint_t_s
    xy_wp = recording.waypoint_xy_m
    floors = recording.waypoint_floor
    if floors is None and recording.floor_name is not None:
        floors = [recording.floor_name] * t_wp.size
    if at_t_s is None:
        return Track(t_wp.copy(), xy_wp.copy(), floor=None if floors is None else list(floors),
                     name=f"{recording.name}_truth")
    t = np.asarray(at_t_s, dtype=np.float64)
    t = t[(t >= t_wp[0]) & (t <= t_wp[-1])]
    xy = np.column_stack([np.interp(t, t_wp, xy_wp[:, 0]), np.interp(t, t_wp, xy_wp[:, 1])])
    floor = None
    if floors is not None:
        before = np.clip(np.searchsorted(t_wp, t, side="right") - 1, 0, t_wp.size - 1)
        floor = [floors[i] for i in before]
    return Track(t, xy, floor=floor, name=f"{recording.name}_truth")
