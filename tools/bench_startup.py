"""What a user waits for beyond the tracking: a command's start-up against its work, in one run.

    .venv/bin/python tools/bench_startup.py        # about 3 minutes on 2 cores

Prints one JSON document (and a line per measurement on stderr) with, on the machine as it is
(every time with the CPU time it used; compare ratios within the run, not times across runs):

- ``help``: ``mapfilter --help`` (median of 5);
- ``readme``: the README's first command (the bundled office walk, ``--smooth``) after the
  install's compile (``NUMBA_CACHE_DIR`` a new folder that ``python -m mapfilter.runtime.warmup``
  filled) and again (warm): the ratio of the first to the warm;
- ``f1_walk``: one ILC site1/F1 walk of a minute (not in the sparse set) at the default 10,000
  particles with the sparse (36 walks) and the dense (76 walks) radio maps, built here by
  ``mapfilter radiomap build``: the walk tracked twice in one process (``mapfilter.track``: the
  first walk with a radio map builds the tables of the APs it hears, the second reuses them)
  and the ``mapfilter track`` command in a fresh process; the command over the second walk, and
  the dense map's first walk over the sparse map's;
- ``breakdown``: where the command's time goes (sparse map), measured inside a fresh process:
  the interpreter and numpy, numba, the package's modules (with the kernels that load when
  their modules are imported), reading the log, the map and the radio map, the walk's evidence
  (the radio map's tables of the APs the walk hears, the fingerprint fixes, the steps), the
  filter's run, writing; kernels loaded on first call are counted apart.
"""

from __future__ import annotations

import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
F1 = REPO.parent / "shared" / "data" / "ilc20" / "site1" / "F1"
WALK = "5dd9e7d1c5b77e0006b17343"  # 58.6 s of WiFi, 123 filter steps; not in sparse_set.txt
README_TRACK = ["track", "maps/office.yaml", "maps/office_walk.txt.gz", "--radiomap", "maps/office_radiomap.npz",
                "--smooth"]

# Run in a fresh process: the command with its phases timed (wall and CPU), as JSON on stdout.
_BREAKDOWN = r"""
import json, sys, time
t0, c0 = time.perf_counter(), time.process_time()
marks, last = [], [t0, c0]
def mark(name):
    t, c = time.perf_counter(), time.process_time()
    marks.append((name, t - last[0], c - last[1])); last[0], last[1] = t, c
import numpy; mark("numpy")
import numba; mark("numba")
import mapfilter.cli.track_cmd, mapfilter.sensors.logs, mapfilter.config, mapfilter.pipeline.tracker, mapfilter.io.tracks
import mapfilter.viz
mark("mapfilter's modules (and the kernels loaded as they are imported)")
phases = {}
def timed(name, f):
    def g(*a, **k):
        t, c = time.perf_counter(), time.process_time()
        try:
            return f(*a, **k)
        finally:
            w, u = phases.get(name, (0.0, 0.0))
            phases[name] = (w + time.perf_counter() - t, u + time.process_time() - c)
    return g
import numba.core.dispatcher as dispatcher
import mapfilter.cli.track_cmd as track_cmd, mapfilter.pipeline.tracker as tracker, mapfilter.maps.building as building
dispatcher.Dispatcher._compile_for_args = timed("kernels loaded on first call", dispatcher.Dispatcher._compile_for_args)
building.Building.load = timed("the map", building.Building.load)
mapfilter.sensors.logs.read_log = timed("reading the log", mapfilter.sensors.logs.read_log)
track_cmd._wifi_source = timed("the radio map", track_cmd._wifi_source)
tracker.prepare_walk = timed("the walk's evidence", tracker.prepare_walk)
tracker.track_prepared = timed("the filter's run", tracker.track_prepared)
mapfilter.io.tracks.write_track = timed("writing", mapfilter.io.tracks.write_track)
import contextlib, io
with contextlib.redirect_stdout(io.StringIO()):
    code = mapfilter.cli.main(sys.argv[1:])
mark("the command")
print(json.dumps({"exit": code, "imports": marks[:-1], "command": marks[-1], "phases": phases,
                  "total": (time.perf_counter() - t0, time.process_time() - c0)}))
"""


def _children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _run(argv: list[str], env: dict | None = None) -> tuple[float, float, str]:
    """(wall s, CPU s, stdout) of a fresh process, as a user's shell starts it (Python writes its
    bytecode caches: PYTHONDONTWRITEBYTECODE, which some harnesses set, is left out); raises on failure."""
    t0, c0 = time.perf_counter(), _children_cpu_s()
    environment = {key: value for key, value in os.environ.items() if key != "PYTHONDONTWRITEBYTECODE"}
    done = subprocess.run(argv, cwd=REPO, env={**environment, **(env or {})}, capture_output=True, text=True)
    wall, cpu = time.perf_counter() - t0, _children_cpu_s() - c0
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)} failed: {done.stderr.strip()[-800:]}")
    return wall, cpu, done.stdout


def _mapfilter(args: list[str], env: dict | None = None) -> tuple[float, float, str]:
    return _run([sys.executable, "-m", "mapfilter", *args], env)


def _say(what: str, doc) -> None:
    print(f"{what}: {json.dumps(doc)}", file=sys.stderr, flush=True)


def bench_help(reps: int = 5) -> dict:
    runs = [_mapfilter(["--help"])[:2] for _ in range(reps)]
    return {"wall_s": statistics.median(r[0] for r in runs), "cpu_s": statistics.median(r[1] for r in runs)}


def bench_readme(tmp: Path) -> dict:
    env = {"NUMBA_CACHE_DIR": str(tmp / "numba_cache")}
    install_s, install_cpu_s, _ = _run([sys.executable, "-m", "mapfilter.runtime.warmup"], env)
    out = ["--out", str(tmp / "office_track.csv")]
    first_s, first_cpu_s, _ = _mapfilter(README_TRACK + out, env)
    warm_s, warm_cpu_s, _ = _mapfilter(README_TRACK + out, env)
    return {"install_compile_s": install_s, "install_compile_cpu_s": install_cpu_s, "first_s": first_s,
            "first_cpu_s": first_cpu_s, "warm_s": warm_s, "warm_cpu_s": warm_cpu_s,
            "first_over_warm": first_s / warm_s, "first_over_warm_cpu": first_cpu_s / warm_cpu_s}


def bench_f1(tmp: Path) -> dict:
    import warnings

    sys.path.insert(0, str(REPO))
    import mapfilter as mf

    logs = F1 / "path_data_files"
    sparse = [logs / f"{name}.txt.gz" for name in (F1 / "sparse_set.txt").read_text().split()]
    walk_path = logs / f"{WALK}.txt.gz"
    map_yaml = tmp / "F1.yaml"
    _mapfilter(["map", "import-ilc", str(F1), "--route", "geojson", "--out", str(map_yaml)])
    building = mf.load_map(map_yaml)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        walk = mf.read_log(walk_path)
    doc: dict = {"walk": WALK}
    for name, survey in (("sparse", sparse), ("dense", sorted(logs.glob("*.txt.gz")))):
        path = tmp / f"F1_{name}.npz"
        build_s, build_cpu_s, _ = _mapfilter(["radiomap", "build", str(map_yaml), *map(str, survey), "--out", str(path)])
        radio_map = mf.load_radio_map(path)
        runs = []
        for _ in range(2):  # the first walk with the map builds the tables of its APs; the second reuses them
            t0, c0 = time.perf_counter(), time.process_time()
            mf.track(building, walk, radio_map=radio_map)
            runs.append((time.perf_counter() - t0, time.process_time() - c0))
        command_s, command_cpu_s, _ = _mapfilter(["track", str(map_yaml), str(walk_path), "--radiomap", str(path),
                                                  "--out", str(tmp / f"track_{name}.csv")])
        doc[name] = {"survey_walks": len(survey), "reference_points": len(radio_map),
                     "radiomap_build_s": build_s, "radiomap_build_cpu_s": build_cpu_s,
                     "first_walk_s": runs[0][0], "first_walk_cpu_s": runs[0][1],
                     "second_walk_s": runs[1][0], "second_walk_cpu_s": runs[1][1],
                     "command_s": command_s, "command_cpu_s": command_cpu_s,
                     "command_over_second_walk": command_s / runs[1][0],
                     "command_over_second_walk_cpu": command_cpu_s / runs[1][1]}
        _say(f"F1 walk, {name} map", doc[name])
    doc["dense_over_sparse_first_walk_cpu"] = doc["dense"]["first_walk_cpu_s"] / doc["sparse"]["first_walk_cpu_s"]
    doc["dense_over_sparse_command_cpu"] = doc["dense"]["command_cpu_s"] / doc["sparse"]["command_cpu_s"]
    # where the sparse map's command spends its time
    wall, cpu, out = _run([sys.executable, "-c", _BREAKDOWN, "track", str(map_yaml), str(walk_path), "--radiomap",
                           str(tmp / "F1_sparse.npz"), "--out", str(tmp / "track_breakdown.csv")])
    inside = json.loads(out)
    doc["breakdown"] = {"process_s": wall, "process_cpu_s": cpu,
                        "before_python_code_s": wall - inside["total"][0],  # interpreter start, site, exit
                        **{name: {"s": w, "cpu_s": c} for name, w, c in inside["imports"]},
                        **{name: {"s": w, "cpu_s": c} for name, (w, c) in inside["phases"].items()}}
    _say("breakdown", doc["breakdown"])
    return doc


def main() -> int:
    if not F1.is_dir():
        raise SystemExit(f"ILC data absent: {F1} (python3 tools/get_data.py)")
    _mapfilter(["--help"])  # the package's bytecode caches written, as after a first command
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="bench_startup_") as tmp:
        doc = {"help": bench_help()}
        _say("--help", doc["help"])
        doc["readme"] = bench_readme(Path(tmp))
        _say("README", doc["readme"])
        doc["f1_walk"] = bench_f1(Path(tmp))
    doc["load_average_1min_before_after"] = [load_before, os.getloadavg()[0]]
    doc["cpus"] = os.cpu_count()
    print(json.dumps(doc, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
