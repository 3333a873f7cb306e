#!/usr/bin/env python3
"""WiFi position fixes on ILC site1 F1, leave-one-trace-out: KWNN, radio-map likelihood, LS.

For each of the floor's traces, the radio map and the estimated access-point table are
built from the OTHER traces only; every scan of the trace under test that falls in its
waypoint span is then located three ways and compared with the position interpolated
between its waypoints (linear in time, the same labelling the radio map uses):

- KWNN fix (Chang et al.; k=4, p=q=2, missing APs at -100 dBm, >= 3 shared APs),
- the argmax of the radio-map likelihood used alone (``RadioMapLikelihood`` over the free
  cells of the floor map from ``mapfilter map import-ilc``),
- least-squares trilateration (``least_squares_position``) with the AP table fitted by
  ``estimate_access_points`` (scans with fewer than 3 known APs count as failures).

A last row, not a method, gives the distance from each true position to the nearest
reference point of the other traces: where no other trace walked, no fingerprint can help.

Prints a markdown table, then JSON (also written with ``--json PATH``).

    .venv/bin/python tools/experiments/report_wifi.py [--floor DIR] [--jobs 2] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from mapfilter.errors import MapfilterError
from mapfilter.filter.models.radio_map import RadioMapLikelihood
from mapfilter.maps.prepare import import_ilc
from mapfilter.sensors.ilc import read_ilc
from mapfilter.sensors.pathloss import estimate_access_points, least_squares_position
from mapfilter.sensors.radiomap import build_radio_map, kwnn_fix_many, label_scans
from mapfilter.sensors.wifi import iter_scans

DEFAULT_FLOOR = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "ilc20" / "site1" / "F1"
METHODS = ("kwnn", "radiomap_likelihood", "ls_trilateration")
# not a method: the distance from each truth to the nearest reference point of the other
# traces, a floor under what any fingerprint method can reach where the survey is thin
COVERAGE = "coverage_nearest_reference"

_STATE: dict = {}  # per worker process: the recordings, the full radio map, the floor plan


def _init(floor_dir: str, max_wifi_age_s: float) -> None:
    paths = sorted((Path(floor_dir) / "path_data_files").glob("*.txt*"))
    recordings = [read_ilc(p, max_wifi_age_s=max_wifi_age_s) for p in paths]
    _STATE["recordings"] = recordings
    _STATE["radio_map"] = build_radio_map(recordings)
    _STATE["floorplan"] = import_ilc(floor_dir)


def _fold(index: int) -> dict:
    """Errors of the three methods on trace ``index`` with everything built from the others."""
    test = _STATE["recordings"][index]
    others = _STATE["radio_map"].without_traces([test.name])
    truth, inside = label_scans(test)
    truth = truth[inside]
    scans = [s for s, ok in zip(iter_scans(test), inside) if ok]
    timings = {}
    t0 = time.perf_counter()
    fix = kwnn_fix_many(others, others.scan_matrix(scans)).xy_m
    t1 = time.perf_counter()
    likelihood = RadioMapLikelihood(others, _STATE["floorplan"])
    best = np.array([likelihood.best_position(s) for s in scans]).reshape(-1, 2)
    t2 = time.perf_counter()
    aps = estimate_access_points(others)
    ls = np.full((len(scans), 2), np.nan)
    for i, scan in enumerate(scans):
        try:
            ls[i] = least_squares_position(aps, scan)
        except MapfilterError:
            pass  # fewer than 3 known APs in this scan: a failure, counted below
    t3 = time.perf_counter()
    timings = {"kwnn_s": t1 - t0, "radiomap_likelihood_s": t2 - t1, "ap_fit_and_ls_s": t3 - t2}
    errors = {m: np.linalg.norm(xy - truth, axis=1).tolist() for m, xy in zip(METHODS, (fix, best, ls))}
    errors[COVERAGE] = cKDTree(others.xy_m).query(truth)[0].tolist()
    return {"trace": test.name, "scans": len(scans), "reference_points": len(others), "aps_fitted": len(aps),
            "errors_m": errors, "timings": timings}


def summarise(errors: list[float]) -> dict:
    e = np.asarray(errors, dtype=float)
    ok = e[np.isfinite(e)]
    if ok.size == 0:
        return {"scans": int(e.size), "fixes": 0}
    return {"scans": int(e.size), "fixes": int(ok.size), "mean_m": float(ok.mean()), "median_m": float(np.median(ok)),
            "p75_m": float(np.percentile(ok, 75)), "p90_m": float(np.percentile(ok, 90)), "max_m": float(ok.max())}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    parser.add_argument("--floor", type=Path, default=DEFAULT_FLOOR, help="ILC floor directory (default site1/F1)")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes (the machine is shared: <= 2)")
    parser.add_argument("--max-wifi-age", type=float, default=5.0, help="stale-row filter, seconds")
    parser.add_argument("--traces", type=int, default=0, help="only the first N folds (0 = all), for a quick look")
    parser.add_argument("--json", type=Path, help="also write the JSON here")
    args = parser.parse_args(argv)

    start = time.perf_counter()
    n_traces = len(sorted((args.floor / "path_data_files").glob("*.txt*")))
    folds = list(range(n_traces if args.traces <= 0 else min(args.traces, n_traces)))
    init_args = (str(args.floor), args.max_wifi_age)
    if args.jobs > 1:
        with multiprocessing.get_context("fork").Pool(args.jobs, _init, init_args) as pool:
            results = pool.map(_fold, folds, chunksize=1)
    else:
        _init(*init_args)
        results = [_fold(i) for i in folds]

    summary = {m: summarise([e for r in results for e in r["errors_m"][m]]) for m in (*METHODS, COVERAGE)}
    report = {
        "floor": str(args.floor), "folds": len(results), "max_wifi_age_s": args.max_wifi_age,
        "summary": summary,
        "per_trace": [{"trace": r["trace"], "scans": r["scans"], "aps_fitted": r["aps_fitted"],
                       **{f"{m}_median_m": summarise(r["errors_m"][m]).get("median_m") for m in METHODS}}
                      for r in results],
        "seconds": {"total": time.perf_counter() - start,
                    **{k: sum(r["timings"][k] for r in results) for k in results[0]["timings"]}},
    }
    print(f"WiFi fixes, leave-one-trace-out over {len(results)} traces of {args.floor}")
    print()
    print("| method | scans | fixes | mean (m) | median (m) | p75 (m) | p90 (m) |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for m, s in summary.items():
        if s["fixes"]:
            print(f"| {m} | {s['scans']} | {s['fixes']} | {s['mean_m']:.2f} | {s['median_m']:.2f} | "
                  f"{s['p75_m']:.2f} | {s['p90_m']:.2f} |")
        else:
            print(f"| {m} | {s['scans']} | 0 | - | - | - | - |")
    print()
    text = json.dumps(report, indent=1)
    print(text)
    if args.json:
        args.json.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
