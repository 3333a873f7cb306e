"""Can a map be walked? Its free share, how much of the free space is one connected region, and
the rooms cut off from that region (named by their pixel box), for ``map prepare``'s report and
for the check before a track runs: a map with no free space is refused in one line, a map whose
largest connected region holds less than half its free space is warned about."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np

from mapfilter.errors import MapfilterError

MIN_ROOM_M2 = 1.0  # free pieces smaller than this are slivers, not rooms: not listed as cut off
MOST_CUT_OFF = 0.5  # before a track: warn when the largest region holds less than this share of the free space
LISTED = 3  # cut-off rooms named in one line


@dataclasses.dataclass(frozen=True)
class FreeRegion:
    """A connected piece of free space: its area and its box in mask pixels (column, row; the
    last column and row included)."""

    area_m2: float
    box_px: tuple[int, int, int, int]


@dataclasses.dataclass(frozen=True)
class Walkability:
    """How walkable a mask is (4-connected free space: the wall walk never slips through a corner)."""

    free_share: float  # of the map
    largest_share: float  # of the free space, in the largest connected region
    cut_off: tuple[FreeRegion, ...]  # regions of at least MIN_ROOM_M2 apart from the largest, biggest first

    @property
    def walkable(self) -> bool:
        return self.free_share > 0.0


def assess(wall_mask: np.ndarray, resolution_m: float) -> Walkability:
    """The free share, the largest region's share of the free space and the regions cut off.

    Free space reaching the map's edge is the outside of the building (a map prepared with
    --outside none): it is left out of the regions, unless all free space reaches the edge."""
    free = ~np.asarray(wall_mask, dtype=bool)
    total = int(free.sum())
    if total == 0:
        return Walkability(0.0, 0.0, ())
    count, labels, stats, _ = cv2.connectedComponentsWithStats(free.astype(np.uint8), connectivity=4)
    areas = stats[1:, cv2.CC_STAT_AREA].copy()
    edge = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    edge = edge[edge > 0] - 1
    if edge.size < len(areas):
        areas[edge] = 0  # the outside
    total = int(areas.sum())
    largest = int(np.argmax(areas)) + 1
    cut = []
    for index in np.argsort(-areas) + 1:
        if index == largest:
            continue
        area_m2 = float(areas[index - 1]) * resolution_m ** 2
        if area_m2 < MIN_ROOM_M2:
            break
        x, y, w, h = (int(v) for v in stats[index, :4])
        cut.append(FreeRegion(area_m2, (x, y, x + w - 1, y + h - 1)))
    return Walkability(float(free.mean()), float(areas.max()) / total, tuple(cut))


def cut_off_mask(wall_mask: np.ndarray, resolution_m: float) -> np.ndarray:
    """The free pixels of the regions :func:`assess` lists as cut off (for the preview)."""
    free = ~np.asarray(wall_mask, dtype=bool)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(free.astype(np.uint8), connectivity=4)
    if count <= 2:
        return np.zeros_like(free)
    areas = stats[:, cv2.CC_STAT_AREA].copy()
    areas[0] = 0
    edge = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    edge = edge[edge > 0]
    if edge.size < count - 1:
        areas[edge] = 0  # the outside, as in assess
    cut = areas * resolution_m ** 2 >= MIN_ROOM_M2
    cut[int(np.argmax(areas))] = False
    return cut[labels]


def summary(walk: Walkability) -> str:
    """One line: the free share and the share in one connected region."""
    return (f"free space {walk.free_share:.1%} of the map, {walk.largest_share:.1%} of it in one connected region"
            + (f" ({len(walk.cut_off)} room{'s' if len(walk.cut_off) != 1 else ''} of {MIN_ROOM_M2:g} m2 or more "
               "cut off)" if walk.cut_off else ""))


def cut_off_message(walk: Walkability, how_to_open: str) -> str | None:
    """One line naming the rooms cut off from the largest region (the biggest ``LISTED``), or None."""
    if not walk.cut_off:
        return None
    named = "; ".join(f"{r.area_m2:.1f} m2 at px {r.box_px[0]},{r.box_px[1]}-{r.box_px[2]},{r.box_px[3]}"
                      for r in walk.cut_off[:LISTED])
    more = len(walk.cut_off) - LISTED
    n = len(walk.cut_off)
    return (f"{n} room{'s are' if n != 1 else ' is'} cut off from the largest free region ({named}"
            + (f"; and {more} more" if more > 0 else "") + f"): nobody can walk into {'them' if n != 1 else 'it'}; "
            + how_to_open)


def check_before_tracking(building, path: str | Path) -> list[str]:
    """Refuse a map (or a building floor) with no free space; one warning for each floor whose
    largest connected free region holds less than ``MOST_CUT_OFF`` of its free space."""
    found = []
    for floor in building.floors:
        plan = floor.plan
        walk = assess(plan.wall_mask, plan.resolution_m)
        where = "" if building.is_single_floor else f"floor {floor.name}: "
        if not walk.walkable:
            raise MapfilterError(f"{where}the map has no free space (every pixel is wall): nothing can be tracked on "
                                 "it; prepare it again (mapfilter map prepare) and look at its preview", path)
        if walk.largest_share < MOST_CUT_OFF:
            message = cut_off_message(walk, "the track stays in the region it starts in; open the doors the map closed "
                                            "(map prepare --edits) or prepare the plan again")
            found.append(f"{path}: {where}only {walk.largest_share:.0%} of the free space is one connected region; "
                         + (message or ""))
    return found
