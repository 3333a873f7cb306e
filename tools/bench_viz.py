"""Benchmark: how long the rerun logger takes to log a walk of synthetic filter steps.

    python tools/bench_viz.py [--steps 250] [--particles 10000] [--out /tmp/bench.rrd]

Builds a 60 m x 40 m floor with a few rooms, a walk along its corridor, and StepReports with
``--particles`` weighted particles, about 2 % wall kills per step, resampling every third step
and one forced collapse; prints the time spent in the logger (map, steps, close) and the size
of the written .rrd.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from mapfilter.filter.events import CollapseEvent, StepReport
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.viz import make_logger


def synthetic_floor(resolution_m: float = 0.1) -> FloorPlan:
    """60 m x 40 m: outer walls, a horizontal corridor wall with doors, two rooms."""
    h, w = int(40 / resolution_m), int(60 / resolution_m)
    mask = np.zeros((h, w), dtype=bool)
    mask[:3, :] = mask[-3:, :] = True
    mask[:, :3] = mask[:, -3:] = True
    mid = h // 2
    mask[mid:mid + 3, :] = True
    for door_col in (w // 4, w // 2, 3 * w // 4):
        mask[mid:mid + 3, door_col - 8:door_col + 8] = False
    mask[:mid, w // 2:w // 2 + 3] = True
    return FloorPlan(mask, resolution_m, (0.0, 0.0), floor_name="F1")


def synthetic_reports(floor: FloorPlan, n_steps: int, n_particles: int, rng: np.random.Generator,
                      collapse_steps: tuple[int, ...] = (), t0_s: float = 1.6e9, dt_s: float = 0.5):
    """StepReports of a walk along y = 10 m from x = 5 m to 55 m; yields (report, truth_xy)."""
    particles = floor.sample_free(n_particles, rng)[:, :]
    for i in range(n_steps):
        truth = np.array([5.0 + 50.0 * i / max(n_steps - 1, 1), 10.0])
        xy = truth + rng.normal(0.0, 1.5, size=(n_particles, 2))
        moved = xy + rng.normal(0.0, 0.3, size=(n_particles, 2))
        killed = ~floor.is_free(moved)
        logw = -0.5 * np.sum((moved - truth) ** 2, axis=1) / 2.0**2
        logw[killed] = -np.inf
        w = np.exp(logw - logw.max())
        w /= w.sum()
        est = w @ moved
        collapse = None
        if i in collapse_steps:
            collapse = CollapseEvent(t_s=t0_s + i * dt_s, step_index=i, xy_m=(float(est[0]), float(est[1])),
                                     cause="all_killed_by_walls", particles_lost=n_particles,
                                     recovery="around_fix", recovered_xy_m=(float(truth[0]), float(truth[1] + 1)))
        yield StepReport(
            t_s=t0_s + i * dt_s, step_index=i, estimate_xy_m=est,
            estimate_std_m=float(np.sqrt(np.mean(w @ (moved - est) ** 2))),
            ess=float(1.0 / np.sum(w**2)), n_particles=n_particles, n_alive=int(np.count_nonzero(w)),
            n_killed=int(killed.sum()), resampled=(i % 3 == 0), particles_xy_m=moved, particles_weight=w,
            killed_from_xy_m=xy[killed], killed_to_xy_m=moved[killed], collapse=collapse,
            heading_rad=0.0, step_length_m=0.7,
            fix_xy_m=truth + rng.normal(0, 2.0, 2) if i % 4 == 0 else None,
        ), truth


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=250)
    parser.add_argument("--particles", type=int, default=10_000)
    parser.add_argument("--max-particles", type=int, default=5000)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(1)
    floor = synthetic_floor()
    # the synthetic filter is not what we time: make its reports first
    steps = list(synthetic_reports(floor, args.steps, args.particles, rng, collapse_steps=(args.steps // 2,)))
    reports = [r for r, _ in steps]
    truth_t = np.array([r.t_s for r in reports])
    truth_xy = np.array([xy for _, xy in steps])
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp) / "bench.rrd"
        start = time.perf_counter()
        logger = make_logger(floor, rrd_path=out, max_particles=args.max_particles, recording_name="bench")
        logger.log_ground_truth(truth_t[::10], truth_xy[::10])
        t_map = time.perf_counter()
        for report in reports:
            logger.log_step(report)
        t_steps = time.perf_counter()
        logger.log_track("estimate", truth_t, np.array([r.estimate_xy_m for r in reports]))
        logger.close()
        t_end = time.perf_counter()
        size_mb = out.stat().st_size / 1e6
    print(f"{args.steps} steps x {args.particles} particles (cap {args.max_particles}): "
          f"map {t_map - start:.2f} s, steps {t_steps - t_map:.2f} s "
          f"({1e3 * (t_steps - t_map) / args.steps:.1f} ms/step), close {t_end - t_steps:.2f} s, "
          f"total {t_end - start:.2f} s, rrd {size_mb:.1f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
