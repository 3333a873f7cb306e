"""Beyond the survey (issue 41), in one go: the IPIN 2023 logs leave-one-route-out and the ILC
site 1 half-floor split, with one compact summary, so that every candidate is measured the same way.

1. IPIN 2023, the 29 shared logs, leave-one-route-out (``mapfilter evaluate --leave-out route``:
   each walk's radio map, fix calibration and beacon fit without every repetition of its trial),
   default settings, 10,000 particles, seed 1: the IPIN score (p75 + 15 m per storey off) of the
   causal filter (pf), the offline track (pf-smooth) and KWNN over all POSI points, the floor
   accuracy, and per route the causal / offline p75 (``--beacons``: with the BLE beacons too).
2. ILC site 1 F1 and F2, the half-floor split (``split_ilc.py``): the mean and p75 in the surveyed
   and in the unsurveyed half, for pf, pf-smooth, KWNN and dead reckoning from the true start.

``--set SECTION.FIELD=VALUE`` overrides the config for both (a candidate's settings). ``--quick``:
2,000 particles, one repetition of each IPIN route scored (the other 21 logs survey, each walk's
route still left out) and every third ILC test walk; minutes, for iterating, not for the docs.
``--start truth``: the particle filter starts at each walk's first waypoint, and the offline
track passes there (``evaluate --start truth``; docs/accuracy.md).

    .venv/bin/python tools/experiments/beyond_survey.py --jobs 2 [--quick] [--set wifi.fingerprint_model=fix]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from split_ilc import COLUMNS, FLOORS, REPO, describe, progress, run_split, tracking_config  # noqa: E402

from mapfilter.cli import main as cli  # noqa: E402
from mapfilter.evaluation.comparison import EvaluationSetup, evaluate  # noqa: E402
from mapfilter.evaluation.groups import by_ipin_trial  # noqa: E402
from mapfilter.evaluation.metrics import format_table  # noqa: E402
from mapfilter.filter.sources import plugin  # noqa: E402
from mapfilter.maps.building import Building  # noqa: E402
from mapfilter.runtime.dispatch import Engine  # noqa: E402

IPIN = REPO.parent / "shared" / "data" / "ipin2023"
# BLEn is the beacon with minor n, but for BLE2 and BLE3 (docs/ipin.md)
BEACON_IDS = ("BLE1=BE:AC:20:23:00:01,BLE2=BE:AC:20:23:00:03,BLE3=BE:AC:20:23:00:02,BLE4=BE:AC:20:23:00:04,"
              "BLE5=BE:AC:20:23:00:05,BLE6=BE:AC:20:23:00:06")


def ipin_venue(work: Path, beacons: bool) -> tuple[Path, Path | None]:
    """The venue YAML (and the beacon table) as docs/ipin.md makes them, made once in ``work``."""
    venue = work / "venue.yaml"
    if not venue.is_file():
        assert cli(["map", "import-ipin", str(IPIN / "plans" / "calib_mapa_Nuremberg.cal"), "--out", str(venue),
                    "--storey-height", "2.8"]) == 0
    table = work / "beacons.csv" if beacons else None
    if table is not None and not table.is_file():
        assert cli(["radiomap", "fit-beacons", str(venue), *map(str, sorted((IPIN / "logs").glob("*.txt.gz"))),
                    "--positions", str(IPIN / "BLE_Locations.csv"), "--ids", BEACON_IDS, "--out", str(table)]) == 0
    return venue, table


def run_ipin(work: Path, tracking, jobs: int, quick: bool, beacons: bool, start=None) -> dict:
    """The IPIN 2023 logs leave-one-route-out: summary rows and rows per route."""
    venue, table = ipin_venue(work, beacons)
    building = Building.load(venue)
    sources = {"ble": plugin("ble").load({"beacons": table}, building)} if table is not None else {}
    logs = sorted((IPIN / "logs").glob("*.txt.gz"))
    scored = [p for p in logs if p.name.endswith("repetition01.txt.gz")] if quick else logs
    setup = EvaluationSetup(methods=("pf", "kwnn") + (("pf+ble",) if beacons else ()),
                            survey_paths=tuple(p for p in logs if p not in scored), groups=by_ipin_trial(logs),
                            sources=sources, tracking=tracking, start=start)
    evaluation = evaluate(building, scored, setup, Engine(jobs=jobs), progress=progress("IPIN 2023"))
    failed = [f"{o.trace}: {o.reason}" for o in evaluation.failed]
    return {"protocol": evaluation.protocol, "walks": len(scored), "failed": failed,
            "summary": evaluation.summary_rows(), "by_route": evaluation.summary_rows(by_group=True)}


def ipin_tables(result: dict) -> str:
    summary = [{"method": r["method"], "IPIN score": r["ipin_score"], "mean": r["mean"], "p75": r["p75"],
                "floor right %": 100 * r["floor_accuracy"], "n": r["n"]} for r in result["summary"]]
    routes: dict[str, dict] = {}
    for row in result["by_route"]:
        routes.setdefault(row["group"], {"route": row["group"], "walks": row["traces"]})[row["method"]] = (
            f"{row['p75']:.1f} / {100 * row['floor_accuracy']:.0f} %")
    methods = list(dict.fromkeys(r["method"] for r in result["by_route"]))
    return (f"IPIN 2023, {result['walks']} walks scored, {result['protocol']}\n"
            f"{format_table(summary, list(summary[0]))}\n\nper route, p75 (m) / floor right:\n"
            f"{format_table(list(routes.values()), ['route', 'walks', *methods])}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--quick", action="store_true",
                        help="2,000 particles, one repetition per IPIN route, every third ILC test walk")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--particles", type=int, default=None, help="default 10,000 (--quick: 2,000)")
    parser.add_argument("--beacons", action="store_true", help="the IPIN walks with the BLE beacons too (pf+ble)")
    parser.add_argument("--parts", nargs="+", choices=("ipin", "ilc"), default=["ipin", "ilc"])
    parser.add_argument("--floors", nargs="+", choices=list(FLOORS), default=list(FLOORS))
    parser.add_argument("--set", dest="settings", nargs="+", default=[], metavar="SECTION.FIELD=VALUE",
                        help="config overrides (YAML values) for every run")
    parser.add_argument("--start", choices=("truth",), default=None,
                        help="truth: the pf methods start at each walk's first waypoint (evaluate --start truth)")
    parser.add_argument("--out", type=Path, default=REPO / "results" / "beyond_survey")
    args = parser.parse_args(argv)
    particles = args.particles or (2_000 if args.quick else 10_000)
    tracking = tracking_config(args.seed, particles, args.settings)
    args.out.mkdir(parents=True, exist_ok=True)
    report, printed, seconds = {"particles": particles, "seed": args.seed, "set": args.settings,
                                "start": args.start}, [], {}
    if "ipin" in args.parts:
        started = time.perf_counter()
        report["ipin"] = run_ipin(args.out, tracking, args.jobs, args.quick, args.beacons, args.start)
        seconds["ipin"] = time.perf_counter() - started
        printed.append(ipin_tables(report["ipin"]))
        print(printed[-1], flush=True)
    if "ilc" in args.parts:
        started = time.perf_counter()
        report["ilc"] = [run_split(floor, tracking, args.jobs, args.out, every=3 if args.quick else 1, start=args.start)
                         for floor in args.floors]
        seconds["ilc"] = time.perf_counter() - started
        rows = [row for result in report["ilc"] for row in result["rows"]]
        lines = "\n".join(describe(r) for r in report["ilc"])
        printed.append(f"ILC site 1, the half-floor split:\n{lines}\n{format_table(rows, COLUMNS)}")
        print(printed[-1], flush=True)
    report["seconds"] = seconds
    (args.out / "beyond_survey.json").write_text(json.dumps(report, indent=1, default=_plain))
    print(f"\n{particles} particles, seed {args.seed}" + (f", --set {' '.join(args.settings)}" if args.settings else "")
          + (f", --start {args.start}" if args.start else "")
          + "; " + ", ".join(f"{k} {v / 60:.1f} min" for k, v in seconds.items()) + f"; wrote {args.out}")
    return 0


def _plain(value):
    return value.item() if isinstance(value, np.generic) else str(value)


if __name__ == "__main__":
    sys.exit(main())
