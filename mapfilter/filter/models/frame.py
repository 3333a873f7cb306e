"""The filter's state space as a measurement model sees it: one floor, or a building's floors side by side.

The particles live on one plan: a floor's own map (a single map, or a building's floor given),
or a building's stack plan (``filter.models.building.FloorStack``: every floor in its own tile,
so a particle's floor is the tile its x falls in). A model of transmitters at known places
(radio transmitters, anchors) needs each one as seen from each floor of the state: the point of
that floor directly above or below it, in the state's frame, and how many floors (or metres)
lie between. ``StateFrame`` gives those, and packs one parameter block per floor into one
vector that a kernel reads with ``particle_floor`` and ``floor_block``: each particle takes its
own floor's block.

The packed layout: ``S`` (the state's floors), the x where each floor's tile starts (``S``;
``-inf`` for the only one), the start and stop of each floor's block in the vector (``2 S``),
then the blocks.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numba import njit

from mapfilter.filter.models.building import FloorStack
from mapfilter.maps.building import Building

__all__ = ["StateFrame", "floor_block", "particle_floor"]


class StateFrame:
    """One floor of ``building`` (``floor``: its index), or with ``stack`` all its floors side by side."""

    def __init__(self, building: Building, floor: int = 0, stack: FloorStack | None = None) -> None:
        self.building = building
        self.stack = stack
        self.floor = int(floor)
        # the building's floor index of each floor of the state, in the state's order
        self.floors: tuple[int, ...] = tuple(range(len(building.floors))) if stack is not None else (self.floor,)

    @property
    def n_floors(self) -> int:
        """Floors in the state (1 unless the building's floors are stacked)."""
        return len(self.floors)

    def on_floor(self, floor: int) -> StateFrame:
        """The frame of one floor of the same building (the offline track's second pass)."""
        return StateFrame(self.building, floor)

    def to_state(self, xy_m: np.ndarray, floor: np.ndarray | int) -> np.ndarray:
        """Positions (N, 2) in the frame of building floor ``floor`` (one index or (N,)) -> the state's
        frame. On one floor the floor's own frame is the state's (whatever ``floor`` says)."""
        xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        return self.stack.to_stack(xy, floor) if self.stack is not None else xy

    def place(self, building_xy_m: np.ndarray) -> list[np.ndarray]:
        """Points (K, 2) of the building frame as each floor of the state sees them: per state floor,
        (K, 2) the point of that floor directly above or below each one, in the state's frame."""
        xy = np.asarray(building_xy_m, dtype=np.float64).reshape(-1, 2)
        out = []
        for index in self.floors:
            local = self.building.floors[index].from_building(xy)
            out.append(self.to_state(local, index))
        return out

    def floors_apart(self, point_floor: np.ndarray) -> list[np.ndarray]:
        """Per state floor, (K,) the number of floors between it and each point's floor (building
        floor indices, ``point_floor``)."""
        point_floor = np.asarray(point_floor, dtype=np.int64)
        return [np.abs(index - point_floor) for index in self.floors]

    def rise_m(self, point_floor: np.ndarray) -> list[np.ndarray]:
        """Per state floor, (K,) how far each point's floor (building floor indices) lies above it,
        in metres (negative below; the building's ``elevation_m``)."""
        elevation = np.array([f.elevation_m for f in self.building.floors], dtype=np.float64)
        point_floor = np.asarray(point_floor, dtype=np.int64)
        return [elevation[point_floor] - elevation[index] for index in self.floors]

    def pack(self, blocks: Sequence[np.ndarray]) -> np.ndarray:
        """One parameter vector of one block per state floor (module docstring), for a kernel that
        reads the particle's own floor's block (``particle_floor``, ``floor_block``)."""
        if len(blocks) != self.n_floors:
            raise ValueError(f"{len(blocks)} parameter blocks for a state of {self.n_floors} floors")
        n = self.n_floors
        starts = self.stack.tile_x_min_m if self.stack is not None else np.array([-math.inf])
        bounds, start = [], 1 + 3 * n
        for block in blocks:
            bounds += [start, start + np.asarray(block).size]
            start += np.asarray(block).size
        return np.ascontiguousarray(np.concatenate([[float(n)], starts, bounds, *[np.ravel(b) for b in blocks]]),
                                    dtype=np.float64)


@njit(cache=True, nogil=True)
def particle_floor(params, x):
    """The state floor (0 .. S - 1) of a particle at ``x``, by the tiles of a packed vector."""
    n_floors = int(params[0])
    floor = 0
    for f in range(1, n_floors):
        if x >= params[1 + f]:
            floor = f
    return floor


@njit(cache=True, nogil=True)
def floor_block(params, floor):
    """(start, stop) of state floor ``floor``'s block in a packed vector."""
    n_floors = int(params[0])
    return int(params[1 + n_floors + 2 * floor]), int(params[2 + n_floors + 2 * floor])
