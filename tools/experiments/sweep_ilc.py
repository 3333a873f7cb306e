"""Every walk of the ILC 2.0 sample: read them all, track every walk with IMU, report.

For each floor of ``--data`` (default ../shared/data/ilc20/site1): every log is read as
``mapfilter check`` reads it (refused, rows skipped, IMU or WiFi-only); every walk with IMU
and waypoints is evaluated with a leave-one-out radio map (built from every *other* readable
walk of its floor, WiFi-only walks included) on the floor's GeoJSON map; failures are
reported with their reason (``failed``: the input's fault, ``crashed``: a bug) and never stop
the sweep.

``--fix-sigma per-floor`` (the default) calibrates the fingerprint fix's Gaussian once per
floor from the floor's whole radio map instead of once per walk from its leave-one-out map
(what ``mapfilter evaluate`` does): the per-walk calibration cross-validates the whole radio
map and is about 90 % of a walk's run time on F1 (27 s of 30 s). One walk's share in that
one number is the only thing the walk under test lends to its own run; ``per-walk`` gives
``mapfilter evaluate``'s numbers exactly. Prints the read table, the error table per floor and walks per minute; writes
``--out`` (JSON) if given.

``--engines serial,jobs2,cluster`` runs the same tracking on each engine in one run (cluster:
a Dask scheduler and two single-threaded workers started here, on 127.0.0.1 only) and checks
that every engine gives the same numbers. Example (the README's table):

    .venv/bin/python tools/experiments/sweep_ilc.py --engines serial,jobs2,cluster --out results/sweep.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import socket
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from mapfilter.io.atomic import atomic_paths  # noqa: E402
from mapfilter.runtime.dispatch import Engine, run_each  # noqa: E402
from mapfilter.errors import MapfilterError  # noqa: E402
from mapfilter.evaluation.comparison import AllWalks, EvaluationSetup, evaluate_trace  # noqa: E402
from mapfilter.evaluation.metrics import format_table, summarise_errors  # noqa: E402
from mapfilter.maps.prepare import import_ilc  # noqa: E402
from mapfilter.sensors.ilc import read_ilc  # noqa: E402
from mapfilter.sensors.radiomap import build_radio_map  # noqa: E402
from mapfilter.config import TrackingConfig  # noqa: E402
from mapfilter.filter.evidence import calibrated_fix_sigma_m  # noqa: E402
from mapfilter.maps.building import Building  # noqa: E402

ILC = REPO.parent / "shared" / "data" / "ilc20" / "site1"
LOOPBACK = "127.0.0.1"


@dataclasses.dataclass
class FloorLogs:
    """What reading one floor's logs gave."""

    name: str
    paths: list[Path]
    refused: dict[str, str]  # log name -> reason
    skipped: dict[str, str]  # log name -> the reader's one-line warning
    imu_walks: list[Path]  # readable, with IMU and waypoints: these are tracked
    survey: list  # every readable recording with waypoints and WiFi (the leave-one-out radio map's source)


def read_floor(floor_dir: Path) -> FloorLogs:
    paths = sorted((floor_dir / "path_data_files").glob("*.txt*"))
    floor = FloorLogs(floor_dir.name, paths, {}, {}, [], [])
    for path in paths:
        warned: list[str] = []
        try:
            recording = read_ilc(path, warn=warned.append)
        except MapfilterError as exc:
            floor.refused[path.name] = str(exc)
            continue
        if warned:
            floor.skipped[path.name] = warned[0]
        if recording.has_ground_truth and len(recording.wifi):
            floor.survey.append(recording)
        if recording.has_ground_truth and recording.acc_t_s.size >= 2 and recording.gyro_t_s.size >= 2:
            floor.imu_walks.append(path)
    return floor


def sweep_walk(buildings: dict, all_walks: dict, setups: dict, walks: dict, item: tuple[str, int]) -> dict:
    """One task: every method of ``setup`` on one walk; a failure is returned, never raised."""
    floor, index = item
    started = time.perf_counter()
    outcome = {"floor": floor, "trace": walks[floor][index].name, "status": "ok", "reason": "", "methods": {}}
    try:
        results = evaluate_trace(buildings[floor], walks[floor], index, setups[floor], all_walks[floor])
    except MapfilterError as exc:
        outcome.update(status="failed", reason=str(exc))
    except Exception as exc:  # noqa: BLE001 - a bug in one walk is counted, the sweep goes on
        outcome.update(status="crashed", reason="".join(traceback.format_exception_only(exc)).strip())
    else:
        outcome["methods"] = {r.method: {"errors_m": r.errors_m.tolist(), "missed": r.missed,
                                         "track_xy_m": r.track.xy_m.tolist()} for r in results}
    outcome["runtime_s"] = time.perf_counter() - started
    return outcome


class LoopbackCluster:
    """A Dask scheduler and ``n_workers`` single-threaded workers as separate processes on 127.0.0.1
    (the README's two commands)."""

    def __init__(self, n_workers: int = 2) -> None:
        with socket.socket() as sock:
            sock.bind((LOOPBACK, 0))
            port = sock.getsockname()[1]
        self.address = f"tcp://{LOOPBACK}:{port}"
        self.tmp = tempfile.TemporaryDirectory(prefix="sweep-dask-")
        dask = [sys.executable, "-m", "dask"]
        # the HTTP (health) server too: --no-dashboard alone still listens on every interface
        common = ["--host", LOOPBACK, "--no-dashboard", "--dashboard-address", f"{LOOPBACK}:0"]
        log = open(Path(self.tmp.name) / "dask.log", "w")
        self.processes = [subprocess.Popen(dask + ["scheduler", "--port", str(port), *common], stdout=log,
                                           stderr=subprocess.STDOUT)]
        for i in range(n_workers):
            self.processes.append(subprocess.Popen(
                dask + ["worker", self.address, "--nthreads", "1", *common, "--local-directory",
                        str(Path(self.tmp.name) / f"w{i}")], stdout=log, stderr=subprocess.STDOUT))
        self._wait(n_workers)

    def _wait(self, n_workers: int) -> None:
        import distributed

        deadline = time.monotonic() + 120
        while True:
            try:
                with distributed.Client(self.address, timeout="5s") as client:
                    client.wait_for_workers(n_workers, timeout=max(deadline - time.monotonic(), 1))
                return
            except OSError:
                if time.monotonic() > deadline:
                    self.close()
                    raise
                time.sleep(1)

    def close(self) -> None:
        for process in reversed(self.processes):
            process.terminate()
        for process in self.processes:
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                process.kill()
        self.tmp.cleanup()


def main() -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, default=ILC, help="folder of floor folders (default: %(default)s)")
    parser.add_argument("--floors", default="", help="comma-separated floor names (default: every floor)")
    parser.add_argument("--methods", default="pf,kwnn,kf", help="methods per walk (default: %(default)s)")
    parser.add_argument("--particles", type=int, default=TrackingConfig().filter.n_particles)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--fix-sigma", choices=("per-floor", "per-walk"), default="per-floor",
                        help="calibrate the fix Gaussian once per floor (fast) or per walk (as evaluate does)")
    parser.add_argument("--limit", type=int, default=0, help="track only the first N IMU walks of each floor (0 = all)")
    parser.add_argument("--engines", default="jobs2",
                        help="comma-separated: serial, jobsN (N local Dask workers), cluster (a scheduler and two "
                             "workers started on 127.0.0.1), or tcp://HOST:PORT (default: %(default)s)")
    parser.add_argument("--out", type=Path, help="write everything measured here (JSON)")
    args = parser.parse_args()

    floors = [d for d in sorted(args.data.iterdir()) if (d / "path_data_files").is_dir()]
    if args.floors:
        floors = [d for d in floors if d.name in args.floors.split(",")]
    started = time.perf_counter()
    read = {d.name: read_floor(d) for d in floors}
    read_s = time.perf_counter() - started
    read_rows = [{"floor": f.name, "logs": len(f.paths), "refused": len(f.refused), "rows skipped": len(f.skipped),
                  "with IMU (tracked)": len(f.imu_walks), "WiFi only": len(f.paths) - len(f.refused) - len(f.imu_walks)}
                 for f in read.values()]
    print(f"read {sum(len(f.paths) for f in read.values())} logs in {read_s:.1f} s")
    print(format_table(read_rows, list(read_rows[0])))
    for f in read.values():
        for name, reason in f.refused.items():
            print(f"  refused {f.name}/{name}: {reason}")
        for name, warning in f.skipped.items():
            print(f"  skipped rows {f.name}/{name}: {warning}")

    walks = {name: f.imu_walks[: args.limit or None] for name, f in read.items() if f.imu_walks}
    floorplans = {name: import_ilc(args.data / name, route="geojson") for name in walks}
    all_walks = {name: AllWalks(build_radio_map(read[name].survey, floorplans[name]), None) for name in walks}
    buildings = {name: Building.from_plan(plan) for name, plan in floorplans.items()}
    setup = EvaluationSetup(methods=tuple(args.methods.split(",")), leave_one_out=True,
                            tracking=TrackingConfig(seed=args.seed).with_particles(args.particles))
    setups = {name: setup for name in walks}
    if args.fix_sigma == "per-floor":
        setups = {name: dataclasses.replace(setup, tracking=setup.tracking.override({"wifi.fix_sigma_m": (
            calibrated_fix_sigma_m(all_walks[name].radio_map, setup.tracking.wifi.kwnn_k))})) for name in walks}
        print("fix sigma per floor: " + ", ".join(f"{n} {s.tracking.wifi.fix_sigma_m:.1f} m" for n, s in setups.items()))
    items = [(name, i) for name, paths in walks.items() for i in range(len(paths))]
    print(f"tracking {len(items)} walks ({', '.join(f'{n}: {len(p)}' for n, p in walks.items())}), "
          f"{args.particles} particles, methods {args.methods}; radio maps: "
          + ", ".join(f"{n} {len(all_walks[n].radio_map)} points from {len(read[n].survey)} walks" for n in walks))

    runs = {}
    for engine_name in args.engines.split(","):
        cluster = None
        if engine_name == "serial":
            engine = Engine()
        elif engine_name.startswith("jobs"):
            engine = Engine(jobs=int(engine_name[4:]))
        elif engine_name == "cluster":
            cluster = LoopbackCluster(2)
            engine = Engine(scheduler=cluster.address)
        else:
            engine = Engine(scheduler=engine_name)
        try:
            started = time.perf_counter()
            outcomes = [None] * len(items)
            for i, outcome in run_each(sweep_walk, items, engine, common=(buildings, all_walks, setups, walks)):
                outcomes[i] = outcome
            wall_s = time.perf_counter() - started
        finally:
            if cluster is not None:
                cluster.close()
        runs[engine_name] = {"engine": engine.describe(), "wall_s": wall_s, "walks_per_min": 60 * len(items) / wall_s,
                             "outcomes": outcomes}
        print(f"{engine_name} ({engine.describe()}): {len(items)} walks in {wall_s:.1f} s = "
              f"{60 * len(items) / wall_s:.1f} walks/min", flush=True)

    first = next(iter(runs.values()))["outcomes"]
    statuses = {s: sum(o["status"] == s for o in first) for s in ("ok", "failed", "crashed")}
    print(f"\n{len(items)} walks: {statuses['ok']} tracked, {statuses['failed']} failed, {statuses['crashed']} crashed")
    for outcome in first:
        if outcome["status"] != "ok":
            print(f"  {outcome['status']} {outcome['floor']}/{outcome['trace']}: {outcome['reason']}")
    same = all(run["outcomes"][i]["methods"] == first[i]["methods"] and
               run["outcomes"][i]["status"] == first[i]["status"] for run in runs.values() for i in range(len(items)))
    if len(runs) > 1:
        print(f"every engine gave the same numbers and tracks: {'yes' if same else 'NO'}")
    error_rows = []
    for name in walks:
        mine = [o for o in first if o["floor"] == name and o["status"] == "ok"]
        for method in setup.methods:
            per_walk = [o["methods"][method] for o in mine if method in o["methods"]]
            if not per_walk:
                continue
            stats = summarise_errors(np.concatenate([np.asarray(m["errors_m"]) for m in per_walk]))
            error_rows.append({"floor": name, "method": method, "walks": len(per_walk), **stats,
                               "missed": sum(m["missed"] for m in per_walk)})
    print("\nerrors at the waypoints (causal, leave-one-out radio map), m:")
    print(format_table(error_rows, ("floor", "method", "walks", "mean", "median", "p75", "p90", "max", "n", "missed")))
    speed_rows = [{"engine": k, "what": r["engine"], "walks": len(items), "wall s": r["wall_s"],
                   "walks/min": r["walks_per_min"]} for k, r in runs.items()]
    print("\n" + format_table(speed_rows, list(speed_rows[0])))
    if args.out is not None:
        with atomic_paths(args.out) as (tmp,):
            tmp.write_text(json.dumps({
                "read": read_rows, "refused": {f.name: f.refused for f in read.values()},
                "skipped": {f.name: f.skipped for f in read.values()}, "errors": error_rows, "speed": speed_rows,
                "same_numbers_on_every_engine": same, "particles": args.particles, "seed": args.seed,
                "fix_sigma": args.fix_sigma, "fix_sigma_m": {n: s.tracking.fix_sigma_m for n, s in setups.items()},
                "per_walk": [{k: v for k, v in o.items() if k != "methods"} | {
                    "mean_m": {m: float(np.mean(r["errors_m"])) if r["errors_m"] else None
                               for m, r in o["methods"].items()}} for o in first],
            }, indent=1))
        print(f"wrote {args.out}")
    return 0 if statuses["crashed"] == 0 and statuses["failed"] == 0 and same else 1


if __name__ == "__main__":
    sys.exit(main())
