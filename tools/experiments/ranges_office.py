"""The ranges source on the bundled office walk: four anchors in the corners (1.5 m above the
phone), the ranges its ground truth gives (2 per anchor per second, Gaussian noise), against the
WiFi alone; mean error at the waypoints over seeds (docs/models.md).

Usage: ``.venv/bin/python tools/experiments/ranges_office.py [--particles 2000] [--seeds 0 1 2 3 4]
[--sigma 0.1] [--smooth]``
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

import mapfilter as mf
from mapfilter.evaluation.scoring import score_track
from mapfilter.sensors.anchors import AnchorTable, simulate_ranges

REPO = Path(__file__).resolve().parents[2]
ANCHORS = "anchor_id,x,y,height\nA1,3,3,1.5\nA2,35,3,1.5\nA3,3,35,1.5\nA4,35,35,1.5\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--particles", type=int, default=2000)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--sigma", type=float, default=0.1, help="the simulated ranges' noise (m)")
    parser.add_argument("--smooth", action="store_true", help="also the offline track")
    args = parser.parse_args()
    building = mf.load_map(REPO / "maps" / "office.yaml")
    walk = mf.read_log(REPO / "maps" / "office_walk.txt.gz")
    radio_map = mf.load_radio_map(REPO / "maps" / "office_radiomap.npz")
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "anchors.csv"
        path.write_text(ANCHORS)
        table = AnchorTable.read_csv(path, building)
    log = simulate_ranges(table, building, walk.waypoint_t_s, walk.waypoint_xy_m, 0, np.random.default_rng(0),
                          sigma_m=args.sigma)
    from mapfilter.filter.sources.ranges import Ranges

    ranges = {"ranges": Ranges(table, log)}
    runs = {"WiFi": {"radio_map": radio_map}, "WiFi + ranges": {"radio_map": radio_map, "sources": ranges},
            "ranges alone": {"sources": ranges}}
    print(f"{args.particles} particles, seeds {' '.join(map(str, args.seeds))}: mean (lowest-highest seed)")
    print(f"| inputs | causal mean (m) |{' offline mean (m) |' if args.smooth else ''}")
    print(f"| --- | --- |{' --- |' if args.smooth else ''}")
    for label, inputs in runs.items():
        causal, offline = [], []
        for seed in args.seeds:
            config = mf.TrackingConfig(seed=seed, smooth=args.smooth).with_particles(args.particles)
            result = mf.track(building, walk, config=config, **inputs)
            causal.append(np.mean(score_track(building, walk, result.causal, None, True).errors.errors_m))
            if result.offline is not None:
                offline.append(np.mean(score_track(building, walk, result.offline, None, False).errors.errors_m))
        cells = f"{np.mean(causal):.2f} ({min(causal):.2f}-{max(causal):.2f})"
        if args.smooth:
            cells += f" | {np.mean(offline):.2f} ({min(offline):.2f}-{max(offline):.2f})"
        print(f"| {label} | {cells} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
