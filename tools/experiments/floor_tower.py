"""Ambiguous floors in a simulated tower (issue 26): floors the WiFi can hardly tell apart, whose
walls can.

The tower: ``--floors`` copies of the bundled office 4 m apart, every other one mirrored (so a
walk's shape fits the corridors of half the floors only), the office's access points on every
floor (mirrored with it; each floor its own BSSIDs) and ``--floor-loss`` dB per slab (3 dB: the
phone hears access points two and more floors away). One survey per floor (a point every 2 m);
the middle floor's survey is thinned to the share ``--thin`` of its points (a negative value:
only the points west of x = -THIN m), so its walks' WiFi floor vote backs other floors. Each
walk stays on the middle floor (no barometer: as the ILC building). Reported per walk and in
all: the share of scans whose vote is right, and the share of waypoints at which the causal
track and the offline (``--smooth``) track are on the right floor. Example (docs/ipin.md):

    .venv/bin/python tools/experiments/floor_tower.py --walks 4 --thin 0.03
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from mapfilter.config import FloorsConfig, TrackingConfig  # noqa: E402
from mapfilter.evaluation.metrics import floor_at_waypoints  # noqa: E402
from mapfilter.maps.building import Building  # noqa: E402
from mapfilter.maps.floorplan import FloorPlan  # noqa: E402
from mapfilter.sensors.floor_vote import build_building_radio_map, floor_vote_log_likelihood  # noqa: E402
from mapfilter.sensors.ilc import read_ilc  # noqa: E402
from mapfilter.sensors.pathloss import AccessPointTable  # noqa: E402
from mapfilter.sensors.wifi import scans_of  # noqa: E402
from mapfilter.simulate.building import BuildingSimConfig, simulate_building_survey, simulate_building_walk  # noqa: E402
from mapfilter.simulate.ilc_writer import write_ilc  # noqa: E402
from mapfilter.pipeline.tracker import track  # noqa: E402

STOREY_M = 4.0


def make_tower(out_dir: Path, n_floors: int) -> tuple[Building, dict[str, AccessPointTable]]:
    """The office stacked ``n_floors`` times, every other floor mirrored left to right."""
    plan = FloorPlan.load(REPO / "maps" / "office.yaml")
    aps = AccessPointTable.read_csv(REPO / "maps" / "office_aps.csv")
    width_m = plan.wall_mask.shape[1] * plan.resolution_m
    floors, tables = [], {}
    for i in range(n_floors):
        name, mirrored = f"F{i}", i % 2 == 1
        mask = plan.wall_mask[:, ::-1].copy() if mirrored else plan.wall_mask
        FloorPlan(mask, plan.resolution_m, plan.origin_m, name, None).save(out_dir / f"{name}.yaml")
        floors.append({"name": name, "map": f"{name}.yaml", "elevation_m": STOREY_M * i, "offset_m": [0.0, 0.0]})
        xy = aps.xy_m.copy()
        if mirrored:
            xy[:, 0] = 2 * plan.origin_m[0] + width_m - xy[:, 0]
        tables[name] = AccessPointTable([b[:9] + f"{i:02x}" + b[11:] for b in aps.bssid], list(aps.band), xy,
                                        aps.c_dbm.copy(), aps.n.copy(), aps.alpha_db_per_m.copy(), aps.d_max_m.copy())
    (out_dir / "tower.yaml").write_text(yaml.safe_dump({"building": "tower", "floors": floors}))
    return Building.load(out_dir / "tower.yaml"), tables


def main() -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    parser.add_argument("--floors", type=int, default=5)
    parser.add_argument("--floor-loss", type=float, default=3.0, help="dB per slab")
    parser.add_argument("--thin", type=float, default=0.03, help="share of the middle floor's survey kept")
    parser.add_argument("--walks", type=int, default=4)
    parser.add_argument("--particles", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    sim = BuildingSimConfig(floor_loss_db=args.floor_loss)
    mid = args.floors // 2
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        building, tables = make_tower(tmp, args.floors)
        surveys = []
        for i, name in enumerate(building.floor_names):
            write_ilc(simulate_building_survey(building, tables, name, sim, np.random.default_rng([args.seed, 99, i])),
                      tmp / f"survey_{name}.txt")
            surveys.append(read_ilc(tmp / f"survey_{name}.txt"))
        radio_map = build_building_radio_map(surveys, list(range(args.floors)), building.floor_names)
        rng = np.random.default_rng([args.seed, 5])
        keep = (radio_map.floor != mid) | ((rng.random(len(radio_map)) < args.thin) if args.thin > 0
                                           else (radio_map.xy_m[:, 0] < -args.thin))
        radio_map = radio_map.select(keep)
        print("radio map points per floor:", np.bincount(radio_map.floor).tolist(), flush=True)
        config = TrackingConfig(smooth=True, seed=args.seed, floors=FloorsConfig(use_barometer=False))
        config = config.with_particles(args.particles)
        total = {"vote": [0, 0], "causal": [0, 0], "offline": [0, 0]}
        start = building.floor_names[mid]
        for w in range(args.walks):
            walk_rng = np.random.default_rng([args.seed, 1, w])
            walk, _ = simulate_building_walk(building, tables, start, [],
                                             dataclasses.replace(sim, segment_s=(90.0, 120.0)), walk_rng)
            write_ilc(walk, tmp / "walk.txt")
            rec = read_ilc(tmp / "walk.txt")
            scans = scans_of(rec)
            vote = np.argmax(floor_vote_log_likelihood(radio_map, radio_map.scan_matrix(scans)), axis=1)
            result = track(building, rec, radio_map, config=config, rng=np.random.default_rng([args.seed, 2, w]))
            causal = floor_at_waypoints(result.causal.t_s, result.causal.floor, rec.waypoint_t_s, rec.waypoint_floor)
            offline = floor_at_waypoints(result.offline.t_s, result.offline.floor, rec.waypoint_t_s,
                                         rec.waypoint_floor, causal=False)
            for key, (right, judged) in (("vote", (int(np.sum(vote == mid)), len(scans))),
                                         ("causal", (causal.n_right, causal.n_judged)),
                                         ("offline", (offline.n_right, offline.n_judged))):
                total[key][0] += right
                total[key][1] += judged
            print(f"walk {w} on {start}: vote right {np.mean(vote == mid):.2f}, causal {causal.accuracy:.2f}, "
                  f"offline {offline.accuracy:.2f} (offline floors {sorted(set(result.offline.floor))})", flush=True)
    print("in all: " + ", ".join(f"{k} {100 * r / max(j, 1):.1f} %" for k, (r, j) in total.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
