"""A rerun recording of the real ParticleFilter on a real floor, for screenshots and a first look.

    python tools/experiments/viz_demo.py MAP.yaml LOG.txt.gz OUT.rrd [--particles 10000] [--seed 3]

The measurements are NOT WiFi: every 2 s a position fix is the log's ground truth (waypoints
interpolated) plus 3 m Gaussian noise, and at step 80 one deliberately wrong fix 40 m away
(sigma 1 m) forces the filter to collapse and recover, so every layer of the viewer has
something to show. Motion: the random walk on a circle (Lund thesis). For real tracking runs
use ``mapfilter track ... --rerun OUT.rrd``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from mapfilter.filter.models.position_fix import GaussianFixLikelihood, PositionFix
from mapfilter.filter.models.motion import RandomWalkMotion
from mapfilter.filter.particle_filter import FilterConfig, ParticleFilter
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.sensors.ilc import read_ilc
from mapfilter.viz import interpolate_ground_truth, make_logger

DT_S = 0.5
FIX_EVERY = 4  # steps: a fix every 2 s, like a WiFi scan
WRONG_FIX_STEP = 80


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n")[0])
    parser.add_argument("map", type=Path)
    parser.add_argument("log", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--particles", type=int, default=10_000)
    parser.add_argument("--seed", type=int, default=3)
    args = parser.parse_args(argv)
    floor = FloorPlan.load(args.map)
    recording = read_ilc(args.log)
    if not recording.has_ground_truth:
        print(f"viz_demo: error: {args.log}: no waypoints", file=sys.stderr)
        return 1
    rng = np.random.default_rng(args.seed)
    pf = ParticleFilter(floor, RandomWalkMotion(),
                        FilterConfig(n_particles=args.particles, min_log_likelihood=-8.0), rng=rng)
    model = GaussianFixLikelihood(sigma_m=5.0)
    t_s = np.arange(recording.waypoint_t_s[0], recording.waypoint_t_s[-1], DT_S)
    truth = interpolate_ground_truth(recording.waypoint_t_s, recording.waypoint_xy_m, t_s)
    pf.initialise_uniform()
    reports = []
    for i, (t, xy) in enumerate(zip(t_s, truth)):
        fix = PositionFix(xy + rng.normal(0.0, 3.0, 2)) if i % FIX_EVERY == 0 else None
        if i == WRONG_FIX_STEP:
            fix = PositionFix(xy + np.array([40.0, 0.0]), sigma_m=1.0)
        reports.append(pf.step(float(t), DT_S, None, model if fix is not None else None, fix))
    start = time.perf_counter()
    with make_logger(floor, rrd_path=args.out, recording_name=f"{recording.name} (demo)") as logger:
        logger.log_ground_truth(recording.waypoint_t_s, recording.waypoint_xy_m)
        for report in reports:
            logger.log_step(report)
    n_collapses = sum(r.collapse is not None for r in reports)
    print(f"wrote {args.out}: {len(reports)} steps x {args.particles} particles, {n_collapses} collapses, "
          f"logged in {time.perf_counter() - start:.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
