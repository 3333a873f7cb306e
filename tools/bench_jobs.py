"""Many walks on many cores: `mapfilter evaluate` of 40 ILC site1/F1 walks at --jobs 1, 2 (and 4,
8, 16 where the machine has the cores), one command after the other in one run.

    .venv/bin/python tools/bench_jobs.py [--walks 40] [--repeats 2]     # about 3 minutes on 2 cores

The walks are tracked with the sparse F1 radio map (``radiomap build`` of the 36 walks of
``sparse_set.txt``, built here), method pf at the default 10,000 particles; each command runs in
a fresh process, as a user runs it, and its whole wall time counts (start-up, reading, writing).
Prints one JSON: per job count the best wall time of the repeats, walks per second and the
speed-up over --jobs 1, with the machine's load average before and after (docs/benchmarks.md).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
F1 = REPO.parent / "shared" / "data" / "ilc20" / "site1" / "F1"


def _mapfilter(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "mapfilter", *args], check=True, cwd=REPO, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--walks", type=int, default=40, help="F1 walks evaluated (default 40)")
    parser.add_argument("--repeats", type=int, default=2, help="runs of each job count; the best counts")
    args = parser.parse_args(argv)
    if not F1.is_dir():
        print(f"bench_jobs: the ILC data is not at {F1} (tools/get_data.py, docs/data.md)", file=sys.stderr)
        return 1
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    counts = [n for n in (1, 2, 4, 8, 16) if n <= cores]
    logs = sorted((F1 / "path_data_files").glob("*.txt.gz"))[:args.walks]
    sparse = [F1 / "path_data_files" / f"{name}.txt.gz" for name in (F1 / "sparse_set.txt").read_text().split()]
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        _mapfilter("map", "import-ilc", str(F1), "--out", str(work / "F1.yaml"))
        _mapfilter("radiomap", "build", str(work / "F1.yaml"), *map(str, sparse), "--out", str(work / "rm.npz"))
        best: dict[int, float] = {}
        for repeat in range(args.repeats):
            for jobs in counts:
                started = time.perf_counter()
                _mapfilter("evaluate", str(work / "F1.yaml"), *map(str, logs), "--radiomap", str(work / "rm.npz"),
                           "--methods", "pf", "--jobs", str(jobs), "--out", str(work / f"eval{jobs}_{repeat}"))
                wall = time.perf_counter() - started
                best[jobs] = min(best.get(jobs, wall), wall)
                print(f"--jobs {jobs}: {wall:.1f} s", file=sys.stderr, flush=True)
    rows = [{"jobs": n, "wall_s": round(best[n], 2), "walks_per_s": round(len(logs) / best[n], 3),
             "speedup": round(best[1] / best[n], 2)} for n in counts]
    print(json.dumps({"walks": len(logs), "cores": cores, "load_before": load_before,
                      "load_after": os.getloadavg()[0], "runs": rows}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
