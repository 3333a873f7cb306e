"""ILC site 1, the half-floor split: tracking scored where the survey never was (issue 41).

A fixed protocol (``mapfilter.evaluation.area_split``), the same for every floor: the floor is cut
across the longer side of its waypoints' bounding box at their median; the survey is every walk
whose waypoints all lie in one half, the test walks are the others (each has a waypoint in the
other half). Each test walk is tracked with the survey's radio map and scored at its waypoints in
the surveyed half and, apart, in the unsurveyed half; then the other half is surveyed, so every
walk is scored and every waypoint is scored once unsurveyed. Methods: the causal particle filter
(``pf``), its offline track (``pf-smooth``), KWNN, and dead reckoning alone from the true start
(the first waypoint's position and time; the heading from the rotation vector, as ``evaluate``'s
``pdr``). ``coverage`` is the distance from a scored waypoint to the nearest survey point.

    .venv/bin/python tools/experiments/split_ilc.py --floors F1 F2 --seeds 1 --jobs 2 --out results/split
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from mapfilter.config import TrackingConfig  # noqa: E402
from mapfilter.evaluation.area_split import errors_by_half, half_split, split_directions  # noqa: E402
from mapfilter.evaluation.baselines import pdr_start_track  # noqa: E402
from mapfilter.evaluation.comparison import EvaluationSetup, evaluate, read_walk  # noqa: E402
from mapfilter.evaluation.metrics import format_table  # noqa: E402
from mapfilter.maps.building import Building  # noqa: E402
from mapfilter.maps.prepare import import_ilc  # noqa: E402
from mapfilter.runtime.dispatch import Engine  # noqa: E402
from mapfilter.sensors.pdr import detect_steps  # noqa: E402
from mapfilter.sensors.radiomap import build_radio_map  # noqa: E402

SITE1 = REPO.parent / "shared" / "data" / "ilc20" / "site1"
FLOORS = {"F1": None, "F2": "full_set.txt"}  # F2: the 12 walks with IMU
METHODS = ("pf", "kwnn")  # with smooth: pf-smooth too
PDR = "pdr (true start)"
HALVES = ("surveyed", "unsurveyed")


def floor_walks(floor: str) -> list[Path]:
    """The floor's walks: every F1 walk, the F2 walks with IMU."""
    folder = SITE1 / floor / "path_data_files"
    listing = FLOORS[floor]
    if listing is None:
        return sorted(folder.glob("*.txt.gz"))
    return [folder / f"{name}.txt.gz" for name in (SITE1 / floor / listing).read_text().split()]


def run_split(floor: str, tracking: TrackingConfig, jobs: int, work: Path, every: int = 1,
              log=lambda message: print(message, file=sys.stderr, flush=True), start=None,
              transductive: bool = False) -> dict:
    """One floor, both directions: the errors of every method per half (pooled over both
    directions), per direction, and the survey's coverage. ``every``: score every n-th test walk
    only (a quick look; the survey is whole); ``start``: evaluate's (``"truth"``: each walk from
    its first waypoint); ``transductive``: the test walks grow the survey's radio map (without
    their labels; a walk's own grown points are left out of its radio map)."""
    plan = import_ilc(SITE1 / floor, route="geojson")
    map_path = work / f"{floor}.yaml"
    plan.save(map_path)
    building = Building.from_plan(plan, map_path)
    started = time.perf_counter()
    walks = [read_walk(p, building) for p in floor_walks(floor)]
    split = half_split([w.waypoint_xy_m for w in walks])
    log(f"{floor}: {len(walks)} walks read in {time.perf_counter() - started:.0f} s; cut at {split.describe()}")
    errors: dict[tuple[str, str], list[np.ndarray]] = {}
    coverage: dict[str, list[np.ndarray]] = {h: [] for h in HALVES}
    directions = []
    for direction in split_directions(split, [w.waypoint_xy_m for w in walks]):
        survey = [walks[i] for i in direction.survey]
        test = [walks[i] for i in direction.test][::every]
        by_name = {w.name: w for w in test}
        started = time.perf_counter()
        evaluation = evaluate(building, test, EvaluationSetup(methods=METHODS, survey_paths=tuple(survey),
                                                              tracking=tracking, start=start,
                                                              transductive=transductive), Engine(jobs=jobs),
                              progress=progress(f"{floor} {split.describe(direction.surveyed_side)} surveyed"))
        failed = [{"trace": o.trace, "reason": o.reason} for o in evaluation.failed]
        for item in failed:  # e.g. a walk that hears none of the survey's access points: no WiFi track
            log(f"{floor}: {item['trace']} not tracked: {item['reason']}")
        mine: dict[tuple[str, str], list[np.ndarray]] = {}
        for result in evaluation.results:
            walk = by_name[result.trace]
            halves = errors_by_half(split, direction.surveyed_side, result.track, walk.waypoint_t_s,
                                    walk.waypoint_xy_m, result.causal)
            for half, e in zip(HALVES, halves):
                mine.setdefault((result.method, half), []).append(e)
        survey_xy = build_radio_map(survey, plan).xy_m
        for walk in test:
            steps = detect_steps(walk, tracking.steps)
            track = pdr_start_track(steps, walk)  # evaluate's pdr-start
            halves = errors_by_half(split, direction.surveyed_side, track, walk.waypoint_t_s, walk.waypoint_xy_m)
            for half, e in zip(HALVES, halves):
                mine.setdefault((PDR, half), []).append(e)
            side = split.side(walk.waypoint_xy_m)
            distance = np.min(np.linalg.norm(walk.waypoint_xy_m[:, None, :] - survey_xy[None], axis=2), axis=1)
            coverage["surveyed"].append(distance[side == direction.surveyed_side])
            coverage["unsurveyed"].append(distance[side != direction.surveyed_side])
        seconds = time.perf_counter() - started
        log(f"{floor}: survey {split.describe(direction.surveyed_side)} ({len(survey)} walks), {len(test)} test "
            f"walks: {seconds:.0f} s")
        directions.append({"surveyed": split.describe(direction.surveyed_side), "survey_walks": len(survey),
                           "test_walks": len(test), "failed": failed, "s": seconds,
                           "rows": _rows(floor, mine)})
        for key, value in mine.items():
            errors.setdefault(key, []).extend(value)
    return {"floor": floor, "walks": len(walks), "cut": split.describe(), "axis": "xy"[split.axis],
            "not_tracked": [f["trace"] for d in directions for f in d["failed"]],
            "cut_m": split.cut_m, "rows": _rows(floor, errors), "directions": directions,
            "coverage_m": {h: _stats(np.concatenate(c) if c else np.zeros(0)) for h, c in coverage.items()}}


def progress(what: str):
    """A progress callback for ``evaluate``: one line on standard error per walk done."""
    started = time.perf_counter()

    def tick(done: int, total: int, walk: str) -> None:
        print(f"{what}: {done} of {total} walks ({walk}), {time.perf_counter() - started:.0f} s", file=sys.stderr,
              flush=True)

    return tick


def _stats(errors: np.ndarray) -> dict:
    if errors.size == 0:
        return {"mean": float("nan"), "p75": float("nan"), "n": 0}
    return {"mean": float(errors.mean()), "p75": float(np.percentile(errors, 75)), "n": int(errors.size)}


def _rows(floor: str, errors: dict[tuple[str, str], list[np.ndarray]]) -> list[dict]:
    rows = []
    for method in dict.fromkeys(m for m, _ in errors):
        halves = {h: _stats(np.concatenate(errors.get((method, h), [np.zeros(0)]))) for h in HALVES}
        s, u = halves["surveyed"], halves["unsurveyed"]
        rows.append({"floor": floor, "method": method, "surveyed mean": s["mean"], "surveyed p75": s["p75"],
                     "surveyed n": s["n"], "unsurveyed mean": u["mean"], "unsurveyed p75": u["p75"],
                     "unsurveyed n": u["n"], "ratio mean": u["mean"] / s["mean"], "ratio p75": u["p75"] / s["p75"]})
    return rows


def describe(result: dict) -> str:
    """One line: the floor, the cut, the coverage of each half and the walks the WiFi could not track."""
    not_tracked = result["not_tracked"]
    return (f"{result['floor']}: cut at {result['cut']}; coverage (distance to the nearest survey point, mean) "
            f"{result['coverage_m']['surveyed']['mean']:.1f} m in the surveyed half, "
            f"{result['coverage_m']['unsurveyed']['mean']:.1f} m in the unsurveyed half"
            + (f"; not tracked with the survey's WiFi (pf and kwnn unscored there, reasons in split.json): "
               f"{', '.join(not_tracked)}" if not_tracked else ""))


COLUMNS = ("floor", "method", "surveyed mean", "surveyed p75", "surveyed n", "unsurveyed mean", "unsurveyed p75",
           "unsurveyed n", "ratio mean", "ratio p75")


def tracking_config(seed: int, particles: int, settings: list[str]) -> TrackingConfig:
    """The default config with the offline track, ``particles`` and the ``--set`` overrides."""
    return TrackingConfig(seed=seed, smooth=True).override(
        {"filter.n_particles": particles, **{k: yaml.safe_load(v) for k, v in (s.split("=", 1) for s in settings)}})


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    parser.add_argument("--floors", nargs="+", choices=list(FLOORS), default=list(FLOORS))
    parser.add_argument("--seeds", type=int, nargs="+", default=[1])
    parser.add_argument("--particles", type=int, default=10_000)
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--every", type=int, default=1, help="score every n-th test walk only (a quick look)")
    parser.add_argument("--set", dest="settings", nargs="+", default=[], metavar="SECTION.FIELD=VALUE",
                        help="config overrides (YAML values), e.g. wifi.fingerprint_model=fix")
    parser.add_argument("--start", choices=("truth",), default=None,
                        help="truth: the pf methods start at each walk's first waypoint (evaluate --start truth)")
    parser.add_argument("--transductive", action="store_true",
                        help="the test walks grow the survey's radio map too (evaluate --transductive)")
    parser.add_argument("--out", type=Path, default=REPO / "results" / "split")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    results = []
    for seed in args.seeds:
        for floor in args.floors:
            result = run_split(floor, tracking_config(seed, args.particles, args.settings), args.jobs, args.out,
                               args.every, start=args.start, transductive=args.transductive)
            results.append({"seed": seed, **result})
            print(f"\n{describe(result)} (seed {seed})\n{format_table(result['rows'], COLUMNS)}", flush=True)
    (args.out / "split.json").write_text(json.dumps(results, indent=1))
    print(f"\nwrote {args.out / 'split.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
