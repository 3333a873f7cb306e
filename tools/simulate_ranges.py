"""Ranges to anchors that a walk with ground truth would have measured (UWB, WiFi RTT), for trying
the ``ranges`` measurement source (docs/models.md) where no anchors were ranged.

The walk's waypoints are its truth (between them, a straight line in time); each anchor of the
table is ranged ``--rate`` times a second at random times, its true 3-D distance (the anchor's
height above the phone, the floors' elevations) plus Gaussian noise of ``--sigma`` metres,
anchors beyond ``--max-range`` unheard. Writes ``t_s,anchor_id,range_m`` (docs/formats.md).

``--corners`` first writes ``--anchors``: four anchors, one at the free space nearest each corner
of the first floor's map, 1.5 m above the phone (a ceiling at 2.7 m, a phone held at 1.2 m).

Usage: ``.venv/bin/python tools/simulate_ranges.py MAP LOG --anchors ANCHORS.csv --out RANGES.csv
[--corners] [--sigma 0.1] [--rate 2] [--max-range 40] [--seed 0]``
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.maps.building import Building
from mapfilter.sensors.anchors import AnchorTable, simulate_ranges
from mapfilter.sensors.logs import read_log


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("map", type=Path, help="map or building YAML")
    parser.add_argument("log", type=Path, help="a walk with waypoints")
    parser.add_argument("--anchors", type=Path, required=True, help="anchor table (anchor_id,x,y[,floor][,height])")
    parser.add_argument("--out", type=Path, required=True, help="the range log to write (t_s,anchor_id,range_m)")
    parser.add_argument("--sigma", type=float, default=0.1, help="range noise in metres (default 0.1)")
    parser.add_argument("--rate", type=float, default=2.0, help="ranges per anchor per second (default 2)")
    parser.add_argument("--max-range", type=float, default=40.0, help="anchors further off are unheard (default 40 m)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--corners", action="store_true", help="first write --anchors: four anchors in the corners")
    args = parser.parse_args(argv)
    try:
        if args.out.resolve() in {p.resolve() for p in (args.map, args.log, args.anchors)}:
            raise MapfilterError("--out would overwrite an input", args.out)
        building = Building.load(args.map)
        if args.corners:
            if args.anchors.exists():
                raise MapfilterError("--corners writes the anchors, but the file exists: give a new name",
                                     args.anchors)
            corner_anchors(building).write_csv(args.anchors)
        table = AnchorTable.read_csv(args.anchors, building)
        table.check_on(building, args.map)
        walk = read_log(args.log, building=building)
        if walk.waypoint_t_s.size < 2:
            raise MapfilterError("the walk needs at least two waypoints (its ground truth)", args.log)
        names = walk.waypoint_floor or [walk.floor_name or building.floor_names[0]] * walk.waypoint_t_s.size
        floor = np.array([0 if building.is_single_floor else building.floor_of_log(n, args.log) for n in names])
        log = simulate_ranges(table, building, walk.waypoint_t_s, walk.waypoint_xy_m, floor,
                              np.random.default_rng(args.seed), rate_hz=args.rate, sigma_m=args.sigma,
                              max_range_m=args.max_range)
        log.write_csv(args.out, table)
    except MapfilterError as exc:
        print(f"simulate_ranges: error: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {args.out}: {len(log)} ranges to {len(table)} anchors over {walk.waypoint_t_s[-1] - walk.waypoint_t_s[0]:.0f} s")
    return 0


def corner_anchors(building: Building) -> AnchorTable:
    """Four anchors, each on the free pixel nearest a corner of the first floor's map."""
    floor = building.floors[0]
    plan = floor.plan
    rows, cols = np.nonzero(~plan.wall_mask)
    free = plan.pixel_to_world(np.column_stack([cols + 0.5, rows + 0.5]))
    x0, x1, y0, y1 = plan.extent_m
    corners = np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1]])
    xy = np.array([free[np.argmin(np.sum((free - c) ** 2, axis=1))] for c in corners])
    name = None if building.is_single_floor else floor.name
    return AnchorTable([f"A{i + 1}" for i in range(4)], xy, [name] * 4, np.full(4, 1.5))


if __name__ == "__main__":
    sys.exit(main())
