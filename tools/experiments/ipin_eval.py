"""The barometer on real data: when the IPIN 2023 walk that changes floor (Training trial 52,
floors 0 and -2) is found on its new floor, by the causal filter and by the offline track,
against its POSI points and its barometer (docs/ipin.md).

The venue first (the museum's storey is 2.8 m by this walk's barometer, docs/formats.md):

    mapfilter map import-ipin ../shared/data/ipin2023/plans/calib_mapa_Nuremberg.cal \\
        --out venue.yaml --storey-height 2.8
    .venv/bin/python tools/experiments/ipin_eval.py venue.yaml --out results/ipin_trial52.json

The radio map is every other log of ``--logs`` (leave-one-out, as ``mapfilter evaluate
--leave-one-out`` makes it for this walk; trial 52's own points are never in it), the settings
are the defaults (``TrackingConfig(smooth=True)``: the barometer as on the simulated walks,
``config.floors.barometer``), seed 0. For every floor change between two POSI points of
different floors the table gives: the two points' times, the time the barometer's height
(centred, ``filter.barometer.barometric_height``, zero at the first point's floor) comes within
half a storey of the new floor's elevation, and the first row of the causal track and of the offline track on the new floor
after the last point of the old floor, with its ``floor_p``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from mapfilter.io.atomic import atomic_paths  # noqa: E402
from mapfilter.config import TrackingConfig  # noqa: E402
from mapfilter.evaluation.metrics import floor_at_waypoints  # noqa: E402
from mapfilter.filter.models.barometer import barometric_height  # noqa: E402
from mapfilter.maps.building import Building  # noqa: E402
from mapfilter.sensors.floor_vote import build_building_radio_map  # noqa: E402
from mapfilter.sensors.logs import read_log  # noqa: E402
from mapfilter.pipeline.tracker import track  # noqa: E402

LOGS = REPO.parent / "shared" / "data" / "ipin2023" / "logs"
TRIAL = "IPIN2023_T3_TrainingTrial52_repetition01"


def floor_changes(building: Building, walk, result) -> list[dict]:
    """One row per change of the POSI floor: when the barometer, pf and the offline track saw it."""
    elevation = {f.name: f.elevation_m for f in building.floors}
    baro_t, baro_h = barometric_height(walk.pressure_t_s, walk.pressure_hpa, centred=True)
    wp_t, wp_floor = walk.waypoint_t_s, walk.waypoint_floor
    # the barometer's zero: the walk's first POSI point is on its floor
    baro_h = baro_h - np.interp(wp_t[0], baro_t, baro_h) + elevation[wp_floor[0]]
    levels = np.unique([f.elevation_m for f in building.floors])
    storey = float(np.min(np.diff(levels))) if levels.size > 1 else np.inf
    rows = []
    for k in np.flatnonzero(np.array(wp_floor[1:]) != np.array(wp_floor[:-1])):
        t0, t1, old, new = float(wp_t[k]), float(wp_t[k + 1]), wp_floor[k], wp_floor[k + 1]
        # the height is on the new floor once within half a storey of its elevation (a change of
        # two storeys passes the floor between on the way)
        inside = (baro_t >= t0) & (baro_t <= t1)
        there = np.abs(baro_h[inside] - elevation[new]) < 0.5 * storey
        crossing = float(baro_t[inside][np.argmax(there)]) if there.any() else None
        row = {"from": old, "to": new, "last_point_s": t0, "first_point_s": t1, "barometer_on_new_floor_s": crossing}
        for label, tr in (("pf", result.causal), ("offline", result.offline)):
            floor = np.array(tr.floor)
            after = np.flatnonzero((tr.t_s > t0) & (floor == new))
            row[f"{label}_s"] = float(tr.t_s[after[0]]) if after.size else None
            row[f"{label}_floor_p"] = float(tr.floor_p[after[0]]) if after.size and tr.floor_p is not None else None
        rows.append(row)
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    parser.add_argument("venue", type=Path, help="the venue's building YAML (mapfilter map import-ipin)")
    parser.add_argument("--logs", type=Path, default=LOGS)
    parser.add_argument("--trial", default=TRIAL, help="the walk that changes floor (its trace name)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, help="write the numbers (JSON)")
    args = parser.parse_args()
    started = time.perf_counter()
    building = Building.load(args.venue)
    paths = sorted(args.logs.glob("*.txt.gz"))
    walk_path = next(p for p in paths if p.name.startswith(args.trial))
    others = [read_log(p, building=building) for p in paths if p != walk_path]
    walk = read_log(walk_path, building=building)
    floors = [building.floor_of_log(r.floor_name, r.path) for r in others]
    radio_map = build_building_radio_map(others, floors, building.floor_names)
    config = TrackingConfig(smooth=True, seed=args.seed)
    result = track(building, walk, radio_map, config=config)
    rows = floor_changes(building, walk, result)
    causal = floor_at_waypoints(result.causal.t_s, result.causal.floor, walk.waypoint_t_s, walk.waypoint_floor)
    offline = floor_at_waypoints(result.offline.t_s, result.offline.floor, walk.waypoint_t_s, walk.waypoint_floor,
                                 causal=False)
    start = float(walk.waypoint_t_s[0])
    print(f"{walk.name}: {walk.waypoint_t_s.size} POSI points; floor right at {causal.n_right}/{causal.n_judged} "
          f"(pf), {offline.n_right}/{offline.n_judged} (offline); times in s after the first POSI point")
    print("| change | last point on the old floor | first point on the new | barometer on the new floor "
          "| pf on the new floor (floor_p) | offline on the new floor (floor_p) |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")

    def when(t, p=None):
        if t is None:
            return "never"
        return f"{t - start:.1f}" + ("" if p is None else f" ({p:.2f})")

    for r in rows:
        print(f"| {r['from']} -> {r['to']} | {when(r['last_point_s'])} | {when(r['first_point_s'])} "
              f"| {when(r['barometer_on_new_floor_s'])} | {when(r['pf_s'], r['pf_floor_p'])} "
              f"| {when(r['offline_s'], r['offline_floor_p'])} |")
    report = {"trial": walk.name, "start_s": start, "changes": rows,
              "pf_floor_right": [causal.n_right, causal.n_judged],
              "offline_floor_right": [offline.n_right, offline.n_judged],
              "config": config.to_dict(), "runtime_s": time.perf_counter() - started}
    print(f"\n{report['runtime_s']:.0f} s")
    if args.out is not None:
        with atomic_paths(args.out) as (tmp,):
            tmp.write_text(json.dumps(report, indent=1))
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
