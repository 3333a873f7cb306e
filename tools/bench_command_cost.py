"""What a one-walk ``mapfilter track`` costs besides its tracking: one real ILC site1/F1 walk of
about a minute (5dd9e7d1, not in the sparse set) with the sparse F1 radio map, the command run in
a fresh process as a user runs it, and in that same process ``mf.track`` of the walk a second time
(the tracking alone: the walk's evidence and filter, nothing loaded or imported any more).

    .venv/bin/python tools/bench_command_cost.py [--runs 5] [--repo PATH]     # about a minute

The map and radio map are made here (``map import-ilc``, ``radiomap build``). Each run is a child
process; its CPU time (``time.process_time``: all its threads, from the interpreter's start) is
split into the imports a track needs, the command's parts (reading the log, the radio-map
likelihood's tables of the APs the walk hears, the tracking, the rest) and the numba kernels
loaded from their cache during the command. Python's own compiled modules (``.pyc``) are used as
after an install (``PYTHONDONTWRITEBYTECODE`` is dropped for the child). ``--repo PATH``: import
mapfilter from another checkout (e.g. ``git worktree add /tmp/main main``), to compare revisions
in one session. Prints one JSON with each part's median over the runs (docs/benchmarks.md).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ILC_FLOOR = REPO.parent / "shared" / "data" / "ilc20" / "site1" / "F1"
WALK = "5dd9e7d1c5b77e0006b17343"

# the child: timed parts of one command, then the tracking alone (JSON on its last line)
CHILD = r"""
import time
cpu_start = time.process_time()
import sys, json, functools, io, contextlib, warnings
repo, map_yaml, walk, radio_map, out = sys.argv[1:6]
if repo:  # mapfilter from that checkout, not the installed one
    sys.path.insert(0, repo)
    sys.meta_path[:] = [m for m in sys.meta_path if "editable" not in type(m).__module__.lower()
                        and "editable" not in getattr(m, "__name__", "").lower()]
warnings.simplefilter("ignore")
from mapfilter.cli import main
try:  # main() runs a command, its imports too, collecting cyclic garbage rarely
    from mapfilter.runtime.collector import rare_collections
except ImportError:  # a revision before it
    rare_collections = contextlib.nullcontext
with rare_collections():
    import mapfilter.config, mapfilter.pipeline.tracker, mapfilter.sensors.logs, mapfilter.filter.evidence  # what a track imports
cpu_imported = time.process_time()
parts = {}

def timed(owner, name, label):
    original = getattr(owner, name)

    @functools.wraps(original)
    def wrapper(*args, **kwargs):
        t0 = time.process_time()
        try:
            return original(*args, **kwargs)
        finally:
            parts[label] = parts.get(label, 0.0) + time.process_time() - t0
    setattr(owner, name, wrapper)

import numba.core.dispatcher as dispatcher
import mapfilter.cli.track_cmd as track_cmd
timed(mapfilter.sensors.logs, "read_log", "read_log_s")
import mapfilter.filter.models.radio_map
timed(mapfilter.filter.models.radio_map.RadioMapLikelihood, "_build_tables", "radio_map_tables_s")
timed(track_cmd, "_track_walk", "tracking_s")
timed(dispatcher.Dispatcher, "compile", "kernels_loaded_s")
with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
    code = main(["track", map_yaml, walk, "--radiomap", radio_map, "--out", out])
cpu_command = time.process_time()
command_parts = dict(parts)  # the command's own (the tracking below reads the log and builds tables again)
import mapfilter as mf
from mapfilter.config import TrackingConfig
plan, rm, recording = mf.load_map(map_yaml), mf.load_radio_map(radio_map), mf.read_log(walk)
with rare_collections():  # as the command tracked
    t0 = time.process_time()
    mf.track(plan, recording, radio_map=rm, config=TrackingConfig())
    again = time.process_time() - t0
print(json.dumps({"exit": code, "mapfilter": mapfilter.__file__, "imports_s": cpu_imported,
                  "command_s": cpu_command, "after_imports_s": cpu_command - cpu_imported,
                  "tracking_again_s": again, **command_parts}))
"""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--repo", default="", help="import mapfilter from this checkout (default: the installed one)")
    args = parser.parse_args(argv)
    logs_dir = ILC_FLOOR / "path_data_files"
    if not (logs_dir / f"{WALK}.txt.gz").is_file():
        print(f"bench_command_cost: the ILC data is not at {ILC_FLOOR} (tools/get_data.py, docs/data.md)",
              file=sys.stderr)
        return 1
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        sparse = [str(logs_dir / f"{name}.txt.gz") for name in (ILC_FLOOR / "sparse_set.txt").read_text().split()]
        mapfilter = [sys.executable, "-m", "mapfilter"]
        subprocess.run([*mapfilter, "map", "import-ilc", str(ILC_FLOOR), "--route", "geojson", "--out",
                        str(work / "F1.yaml")], check=True, capture_output=True, env=env)
        subprocess.run([*mapfilter, "radiomap", "build", str(work / "F1.yaml"), *sparse, "--out",
                        str(work / "F1_sparse.npz")], check=True, capture_output=True, env=env)
        child = [sys.executable, "-c", CHILD, args.repo, str(work / "F1.yaml"), str(logs_dir / f"{WALK}.txt.gz"),
                 str(work / "F1_sparse.npz"), str(work / "track.csv")]
        subprocess.run(child, check=True, capture_output=True, env=env)  # writes the .pyc files once
        runs = []
        for _ in range(args.runs):
            done = subprocess.run(child, check=True, capture_output=True, text=True, env=env)
            runs.append(json.loads(done.stdout.strip().splitlines()[-1]))
            print(f"command {runs[-1]['command_s']:.3f} s CPU, tracking again {runs[-1]['tracking_again_s']:.3f} s",
                  file=sys.stderr)
    median = {key: round(statistics.median(r.get(key, 0.0) for r in runs), 3)
              for key in runs[0] if key not in ("exit", "mapfilter")}
    ratios = [r["command_s"] / r["tracking_again_s"] for r in runs]
    print(json.dumps({"walk": WALK, "mapfilter": runs[0]["mapfilter"], "runs": len(runs), "load_before": load_before,
                      "load_after": os.getloadavg()[0], "median_cpu_s": median,
                      "command_over_tracking_again": {"median": round(statistics.median(ratios), 2),
                                                      "min": round(min(ratios), 2), "max": round(max(ratios), 2)}},
                     indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
