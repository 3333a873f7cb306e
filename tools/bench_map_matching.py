"""Map-matching benchmark: walk steps per second, numba kernels vs the plain-numpy steps.

Times ``mapfilter.offline.map_matching.map_match`` (the offline whole-walk track's forward-
backward pass over a 0.25 m grid of the plan's free cells) on real ILC site1/F1 walks, against
the same steps in plain numpy, one numpy array per operation: ``numpy_map_match`` of
tests/offline/test_map_matching.py (map_match as it was before its numba kernels, on the same grid),
or with ``--git REV`` the module ``mapfilter/offline/map_matching.py`` as it was at git
revision REV (its own grid code too). The two alternate, walk by walk, so that both see the
same load on a shared machine; each result is the median of ``--reps`` runs.

Input of a walk: its dead-reckoned shape (``sensors.pdr.detect_steps``) placed at its
ground-truth waypoints (``offline.placement.place_walk`` with the waypoints as the fixes, then
``shift_onto_free_space``), observed at its WiFi scan times, as ``tracking.whole_walk_track``
observes a placement made from the filter's fixes.

Prints one JSON document: per walk the steps, the grid, wall and CPU seconds of both, steps
per second, the speed-up (reference / numba, CPU time) and the largest distance between the
two tracks. Usage: ``.venv/bin/python tools/bench_map_matching.py [--walks ID,ID] [--reps 3]
[--git REV]``
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from mapfilter.offline.map_matching import MapMatchConfig, _Grid, map_match  # noqa: E402
from mapfilter.offline.placement import place_walk, shift_onto_free_space  # noqa: E402
from mapfilter.maps.floorplan import FloorPlan  # noqa: E402
from mapfilter.maps.prepare import import_ilc  # noqa: E402
from mapfilter.sensors.ilc import read_ilc  # noqa: E402
from mapfilter.sensors.pdr import detect_steps  # noqa: E402

ILC_FLOOR = REPO.parent / "shared" / "data" / "ilc20" / "site1" / "F1"
# bench_filter.py's real walk (98 shape points), and the three F1 walks with the most
# cell-steps (grid cells x shape points: 0.1-0.2 s each in numpy before the kernels)
WALKS = ["5dd9e7d1c5b77e0006b17343", "5dd9fd3a9191710006b570d2", "5dd9ef979191710006b57086",
         "5dd9ef829191710006b5707a"]


def load_module(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def reference_map_match(git_rev: str | None, tmp: Path):
    """(function, description) of the plain-numpy map matching to compare with."""
    if git_rev is None:
        tests = load_module(REPO / "tests" / "test_map_matching.py", "_bench_test_map_matching")
        return tests.numpy_map_match, "tests/offline/test_map_matching.py numpy_map_match (same grid)"
    source = subprocess.run(["git", "show", f"{git_rev}:mapfilter/offline/map_matching.py"], cwd=REPO,
                            check=True, capture_output=True, text=True).stdout
    path = tmp / "map_matching_reference.py"
    path.write_text(source)
    module = load_module(path, "_bench_map_matching_reference")
    return module.map_match, f"git {git_rev}:mapfilter/offline/map_matching.py"


def walk_input(floorplan: FloorPlan, walk_id: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t_s, xy_m, anchor_t_s) of a walk: its shape placed at its waypoints, its scan times."""
    recording = read_ilc(ILC_FLOOR / "path_data_files" / f"{walk_id}.txt.gz")
    placement = place_walk(detect_steps(recording), recording.waypoint_t_s, recording.waypoint_xy_m)
    placement = shift_onto_free_space(floorplan, placement)
    return placement.t_s, placement.xy_m, recording.wifi.t_s


def timed_cpu(fn):
    """(result, wall s, CPU s of this process) of one call."""
    t0, c0 = time.perf_counter(), time.process_time()
    result = fn()
    return result, time.perf_counter() - t0, time.process_time() - c0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.splitlines()[0])
    parser.add_argument("--walks", default=",".join(WALKS), help="comma list of site1/F1 walk ids")
    parser.add_argument("--reps", type=int, default=3, help="runs of each (the median is reported)")
    parser.add_argument("--git", metavar="REV", help="compare with map_matching.py at this git revision")
    args = parser.parse_args(argv)

    load_before = os.getloadavg()[0]
    floorplan = import_ilc(ILC_FLOOR, route="geojson")
    t0 = time.perf_counter()  # numba: compile or load from cache before any timing
    map_match(FloorPlan(np.zeros((8, 8), dtype=bool), 1.0), np.arange(3.0), np.full((3, 2), 4.0), np.arange(3.0))
    warmup_s = time.perf_counter() - t0
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_map_matching_") as tmp:
        reference, reference_name = reference_map_match(args.git, Path(tmp))
        for walk_id in args.walks.split(","):
            t_s, xy_m, anchor_t_s = walk_input(floorplan, walk_id)
            grid = _Grid(floorplan, xy_m, MapMatchConfig())
            runs: dict[str, list[tuple[float, float]]] = {"numba": [], "reference": []}
            for _ in range(args.reps):
                new, wall, cpu = timed_cpu(lambda: map_match(floorplan, t_s, xy_m, anchor_t_s))
                runs["numba"].append((wall, cpu))
                old, wall, cpu = timed_cpu(lambda: reference(floorplan, t_s, xy_m, anchor_t_s))
                runs["reference"].append((wall, cpu))
            row: dict = {"walk": walk_id, "steps": int(t_s.size), "scans": int(anchor_t_s.size),
                         "grid_cells": list(grid.free.shape), "free_share": round(float(grid.free.mean()), 3)}
            for name, times in runs.items():
                wall, cpu = (float(np.median(v)) for v in zip(*times))
                row[f"{name}_s"], row[f"{name}_cpu_s"] = wall, cpu
                row[f"{name}_steps_per_s"] = t_s.size / cpu
            row["speedup_cpu"] = row["reference_cpu_s"] / row["numba_cpu_s"]
            row["speedup_wall"] = row["reference_s"] / row["numba_s"]
            row["max_difference_m"] = float(np.abs(new.xy_m - old.xy_m).max())
            row["restarts"] = [new.restarts, old.restarts]
            rows.append(row)
            print(f"{walk_id}: " + ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                                             for k, v in row.items() if k != "walk"), file=sys.stderr, flush=True)
    import numba

    total = {name: sum(r[f"{name}_cpu_s"] for r in rows) for name in ("numba", "reference")}
    steps = sum(r["steps"] for r in rows)
    doc = {
        "unit": "walk steps (shape points) per second of CPU time; *_s wall, *_cpu_s CPU of the process, "
                "median of the runs",
        "reference": reference_name,
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "numpy": np.__version__,
                    "numba": numba.__version__},
        "numba_warmup_s": warmup_s,
        "load_average_1min_before_after": [load_before, os.getloadavg()[0]],
        "reps": args.reps,
        "walks": rows,
        "all_walks": {"steps": steps, "numba_steps_per_s": steps / total["numba"],
                      "reference_steps_per_s": steps / total["reference"],
                      "speedup_cpu": total["reference"] / total["numba"],
                      "max_difference_m": max(r["max_difference_m"] for r in rows)},
    }
    print(json.dumps(doc, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
