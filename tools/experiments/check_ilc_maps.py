#!/usr/bin/env python3
"""Check the ILC maps: do the waypoints of all shared traces lie on free, connected space?

For site1 F1 and F2, with both the image route and the GeoJSON route of `mapfilter map
import-ilc`, print the map size and resolution, the share of all waypoints (all traces) on
free pixels, whether all waypoints of the floor lie in one connected free component, and (for
the GeoJSON route) whether the outside of the building is wall.

    .venv/bin/python tools/experiments/check_ilc_maps.py [--site DIR]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy import ndimage

from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.prepare import import_ilc, read_geojson_floor
from mapfilter.sensors.ilc import read_ilc

DEFAULT_SITE = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "ilc20" / "site1"


def trace_waypoints_m(floor_dir: Path) -> list[np.ndarray]:
    """The waypoints (x, y) in metres of each trace of a floor, one (n_i, 2) array per trace."""
    traces = sorted((floor_dir / "path_data_files").glob("*.txt*"))
    return [read_ilc(p).waypoint_xy_m for p in traces]


def waypoint_figures(plan: FloorPlan, xy_m: np.ndarray) -> dict:
    """Share of waypoints on free pixels, and how many free components (8-connected) hold the
    free ones (1 = all in one component; waypoints on walls are not counted here)."""
    free = plan.is_free(xy_m)
    labels, _ = ndimage.label(~plan.wall_mask, structure=np.ones((3, 3)))
    rows, cols, _ = plan.pixel_index(xy_m[free])
    components = np.unique(labels[rows, cols])
    return {"free_share": float(free.mean()), "n": len(xy_m), "n_free": int(free.sum()),
            "components": int(len(components))}


def components_per_part(plan: FloorPlan, traces_xy_m: list[np.ndarray],
                        geojson_path: Path) -> tuple[int, float, bool, int]:
    """(parts of the outline holding waypoints, smallest gap between outline parts in metres,
    the free waypoints of every part lie in one free component, traces visiting > 1 part)."""
    import shapely

    outline = read_geojson_floor(geojson_path).outline
    parts = list(getattr(outline, "geoms", [outline]))
    crossing = sum(
        sum(bool(shapely.contains_xy(part, xy[:, 0], xy[:, 1]).any()) for part in parts) > 1 for xy in traces_xy_m
    )
    xy_m = np.concatenate(traces_xy_m)
    gap_m = min((a.distance(b) for i, a in enumerate(parts) for b in parts[i + 1:]), default=0.0)
    labels, _ = ndimage.label(~plan.wall_mask, structure=np.ones((3, 3)))
    free = plan.is_free(xy_m)
    used, one_each = 0, True
    for part in parts:
        inside = shapely.contains_xy(part, xy_m[:, 0], xy_m[:, 1]) & free
        if inside.any():
            used += 1
            rows, cols, _ = plan.pixel_index(xy_m[inside])
            one_each &= len(np.unique(labels[rows, cols])) == 1
    return used, gap_m, bool(one_each), int(crossing)


def outside_is_wall(plan: FloorPlan, geojson_path: Path) -> tuple[bool, int]:
    """(every pixel centre outside the floor outline is wall, number of outside pixels)."""
    import shapely

    outline = read_geojson_floor(geojson_path).outline
    rows, cols = np.indices(plan.shape_px)
    xy = plan.pixel_to_world(np.stack([cols + 0.5, rows + 0.5], axis=-1)).reshape(-1, 2)
    inside = shapely.contains_xy(outline, xy[:, 0], xy[:, 1]).reshape(plan.shape_px)
    outside = ~inside
    return bool(plan.wall_mask[outside].all()), int(outside.sum())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    parser.add_argument("--site", type=Path, default=DEFAULT_SITE, help="ILC site directory (default: %(default)s)")
    args = parser.parse_args(argv)
    ok = True
    for floor in ("F1", "F2"):
        floor_dir = args.site / floor
        traces_xy_m = trace_waypoints_m(floor_dir)
        xy_m = np.concatenate(traces_xy_m)
        n_traces = len(traces_xy_m)
        for route in ("image", "geojson"):
            plan = import_ilc(floor_dir, route)
            fig = waypoint_figures(plan, xy_m)
            rows, cols = plan.shape_px
            line = (f"{floor} {route:7s}: {cols}x{rows} px at {plan.resolution_m:.4f} m/px "
                    f"({plan.size_m[0]:.1f} x {plan.size_m[1]:.1f} m), free {plan.free_fraction:.1%}; "
                    f"waypoints on free pixels {fig['n_free']}/{fig['n']} = {fig['free_share']:.2%} "
                    f"({n_traces} traces); free waypoints in {fig['components']} connected component(s)")
            ok &= fig["free_share"] >= 0.99
            if route == "image":
                ok &= fig["components"] == 1
            else:
                # the GeoJSON outline may be several disjoint buildings: then no walkable path
                # joins them, and the check is one component per building part
                used, gap_m, one_each, crossing = components_per_part(plan, traces_xy_m,
                                                                      floor_dir / "geojson_map.json")
                if used > 1:
                    line += (f" = one per outline part ({used} parts with waypoints, {gap_m:.1f} m apart, "
                             f"traces visiting both: {crossing}): {one_each}")
                ok &= one_each and fig["components"] == used and crossing == 0
                wall_outside, n_outside = outside_is_wall(plan, floor_dir / "geojson_map.json")
                line += f"; outside of the outline all wall: {wall_outside} ({n_outside} px)"
                ok &= wall_outside
            print(line)
    print("PASS" if ok else "FAIL")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
