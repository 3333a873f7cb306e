"""Self-training on ILC site 1: does a radio map grown from unlabelled walks close the gap to labels?

F1: labelled = the 36 walks of ``sparse_set.txt``, unlabelled = the other 40 F1 walks (their
waypoints never read by the growing), scored = the 36 leave-one-out. Three radio maps per scored
walk, each without the walk itself:

- (a) ``labelled``: the 35 other labelled walks;
- (b) ``true``: (a) plus the 40 unlabelled walks with their true waypoints;
- (c) ``grown``: (a) plus the points grown from the 40 (``mapfilter.pipeline.selftrain.grow_radio_map``).

The growing never sees a scored walk's labels: the labelled walks are split into ``--folds``
folds, the 40 walks are grown once per fold over the labelled walks of the other folds, and a
scored walk's map is its 35 labelled neighbours plus the points grown without its fold
(``--folds 1`` grows once over all 36: the scored walk's labels then helped place the grown
points, which flatters (c)).

F2: labelled = the 12 walks with IMU (``full_set.txt``), scored leave-one-out, unlabelled = the
28 WiFi-only walks (no IMU: placed by ``selftrain``'s WiFi-only path).

F2's WiFi-only walks grow only with ``--grow '{"wifi_only": true}'`` (``GrowConfig.wifi_only``).

Example (the numbers of docs/self-training.md; the grown points of seed 0 cached under
``--out``, then scored with every seed):

    .venv/bin/python tools/experiments/selftrain_ilc.py --sets f1 --seeds 0 --tag final
    .venv/bin/python tools/experiments/selftrain_ilc.py --sets f1 --seeds 1 2 3 4 --tag final --grown-seed 0 --label=-g0
    .venv/bin/python tools/experiments/selftrain_ilc.py --sets f2 --seeds 0 --tag final --grow '{"wifi_only": true}'

``--sigma-override``, ``--resigma`` and ``--sigma-ref`` re-weigh cached grown points (the
variants of docs/accuracy.md).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pickle
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from mapfilter.runtime.dispatch import Engine, run_each  # noqa: E402
from mapfilter.evaluation.comparison import AllWalks, EvaluationSetup, evaluate_trace  # noqa: E402
from mapfilter.evaluation.metrics import format_table, summarise_errors  # noqa: E402
from mapfilter.maps.prepare import import_ilc  # noqa: E402
from mapfilter.pipeline.selftrain import GrowConfig, grown_by_fold  # noqa: E402
from mapfilter.sensors.ilc import read_ilc  # noqa: E402
from mapfilter.sensors.radiomap import build_radio_map, label_scans, merge_radio_maps  # noqa: E402
from mapfilter.config import TrackingConfig  # noqa: E402
from mapfilter.maps.building import Building  # noqa: E402

SITE1 = REPO.parent / "shared" / "data" / "ilc20" / "site1"
METHODS = ("pf", "kwnn")


def set_paths(name: str) -> tuple[str, list[Path], list[Path]]:
    """(floor, labelled = scored walks, unlabelled walks)."""
    floor, listing = {"f1": ("F1", "sparse_set.txt"), "f2": ("F2", "full_set.txt")}[name]
    folder = SITE1 / floor / "path_data_files"
    chosen = (SITE1 / floor / listing).read_text().split()
    labelled = [folder / f"{trace}.txt.gz" for trace in chosen]
    unlabelled = [p for p in sorted(folder.glob("*.txt.gz")) if p.name.removesuffix(".txt.gz") not in set(chosen)]
    return floor, labelled, unlabelled


def _score(building, setup, paths, all_walks_of, index):
    return evaluate_trace(building, paths, index, setup, AllWalks(all_walks_of[index], None))


def score(floorplan, paths, maps_by_walk, seed, particles, engine) -> tuple[dict[str, np.ndarray], dict]:
    """Errors per method over every scored walk, each with its own all-walks map (the walk's
    own points are dropped by evaluate_trace); and each walk's mean error per method."""
    setup = EvaluationSetup(methods=METHODS, leave_one_out=True,
                            tracking=dataclasses.replace(TrackingConfig(seed=seed), smooth=True)
                            .with_particles(particles))
    errors: dict[str, list[np.ndarray]] = {}
    per_walk: dict[str, dict[str, float]] = {}
    for _, results in run_each(_score, list(range(len(paths))), engine,
                               common=(Building.from_plan(floorplan), setup, paths, maps_by_walk)):
        for r in results:
            errors.setdefault(r.method, []).append(r.errors_m)
            per_walk.setdefault(r.trace, {})[r.method] = float(r.errors_m.mean()) if r.errors_m.size else None
    return {m: np.concatenate(e) for m, e in errors.items()}, per_walk


def resigma(grown, report, per_spread: float, floor_m: float):
    """Research: the cached grown points with sigma = per_spread x (spread - floor_m)."""
    names = np.array(grown.source_traces)[grown.trace]
    for w in report.offline if hasattr(report, "offline") else report.walks:
        w = w if isinstance(w, dict) else dataclasses.asdict(w)
        spread = w.get("spread_m", w.get("causal_std_m"))
        mine = np.flatnonzero(names == w["name"])
        j = np.searchsorted(w["scan_t_s"], grown.t_s[mine])
        grown.xy_sigma_m[mine] = per_spread * np.maximum(np.nan_to_num(spread, nan=4.0)[j] - floor_m, 0.0)
    return grown


def grown_point_errors(grown, unlabelled) -> dict[str, float]:
    """How far the grown points lie from where their scans were taken (the unlabelled walks'
    true waypoints, read here only to measure)."""
    truth = {}
    for rec in unlabelled:
        xy, inside = label_scans(rec)
        truth[rec.name] = (rec.wifi.t_s[inside], xy[inside])
    errors, sigma = [], []
    for i in range(len(grown)):
        t, xy = truth[grown.source_traces[grown.trace[i]]]
        j = np.flatnonzero(t == grown.t_s[i])
        if j.size:
            errors.append(float(np.linalg.norm(grown.xy_m[i] - xy[j[0]])))
            sigma.append(grown.xy_sigma_m[i])
    e = np.array(errors)
    return {"points": len(grown), "scored": e.size, "err_mean": float(e.mean()), "err_p75": float(np.percentile(e, 75)),
            "err_over_8m": float((e > 8).mean()), "sigma_median": float(np.median(sigma)),
            "spearman_sigma_err": float(_spearman(np.array(sigma), e))}


def _spearman(a, b) -> float:
    if np.ptp(a) == 0:
        return float("nan")
    ra, rb = np.argsort(np.argsort(a)), np.argsort(np.argsort(b))
    return float(np.corrcoef(ra, rb)[0, 1])


def grown_for_folds(floorplan, labelled, unlabelled, folds, grow: GrowConfig, engine, cache: Path | None):
    """The grown points (a radio map of grown points only) for each fold of the labelled walks
    (``selftrain.grown_by_fold``, one fold at a time so that each is cached)."""
    out, reports = [], []
    for f in range(folds):
        path = None if cache is None else cache / f"fold{f}of{folds}.pkl"
        if path is not None and path.exists():
            grown, report = pickle.loads(path.read_bytes())
        else:
            started = time.perf_counter()
            keep = [r for i, r in enumerate(labelled) if i % folds != f or folds == 1]
            grown, report = (x[0] for x in grown_by_fold(floorplan, keep, unlabelled, grow, folds=1, engine=engine)[:2])
            report.iterations.append({"wall_s": time.perf_counter() - started})
            if path is not None:
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_bytes(pickle.dumps((grown, report)))
        print(f"  fold {f}: {len(grown)} grown points; {report.iterations}", file=sys.stderr, flush=True)
        out.append(grown)
        reports.append(report)
    return out, reports


def main() -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sets", nargs="+", choices=("f1", "f2"), default=["f1"])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--maps", nargs="+", choices=("labelled", "true", "grown"),
                        default=["labelled", "true", "grown"])
    parser.add_argument("--folds", type=int, default=4)
    parser.add_argument("--particles", type=int, default=10_000)
    parser.add_argument("--grow", default="{}", help="GrowConfig fields as JSON (research)")
    parser.add_argument("--tag", default="default", help="names the cache of grown maps")
    parser.add_argument("--resigma", type=float, nargs=2, default=None, metavar=("PER_SPREAD", "FLOOR_M"),
                        help="research: the cached points' sigma replaced by PER_SPREAD x (spread - FLOOR_M)")
    parser.add_argument("--sigma-ref", type=float, default=None, metavar="M",
                        help="research: sensors.radiomap.POSITION_SIGMA_REF_M")
    parser.add_argument("--grown-seed", type=int, default=None, metavar="SEED",
                        help="score with the points grown with this seed (cached), not each scoring seed's own")
    parser.add_argument("--label", default="", help="appended to the tag in the rows")
    parser.add_argument("--sigma-override", type=float, default=None, metavar="M",
                        help="research: every grown point's position sigma set to M (the cached positions kept)")
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--out", type=Path, default=REPO / "results" / "selftrain")
    args = parser.parse_args()

    engine = Engine(jobs=args.jobs)
    if args.sigma_ref is not None:
        import mapfilter.sensors.radiomap as radiomap_module

        radiomap_module.POSITION_SIGMA_REF_M = args.sigma_ref
    args.out.mkdir(parents=True, exist_ok=True)
    rows, walks = [], []
    for name in args.sets:
        floor, lab_paths, unl_paths = set_paths(name)
        floorplan = import_ilc(SITE1 / floor, route="geojson")
        labelled = [read_ilc(p) for p in lab_paths]
        unlabelled = [read_ilc(p) for p in unl_paths]
        base_all = build_radio_map(labelled, floorplan)
        for seed in args.seeds:
            grow = GrowConfig(**{**json.loads(args.grow), "seed": seed})
            for which in args.maps:
                started = time.perf_counter()
                if which == "labelled":
                    maps = [base_all] * len(lab_paths)
                elif which == "true":
                    maps = [build_radio_map(labelled + unlabelled, floorplan)] * len(lab_paths)
                else:
                    grown_seed = seed if args.grown_seed is None else args.grown_seed
                    cache = args.out / "grown" / name / args.tag / f"seed{grown_seed}"
                    grown, reports = grown_for_folds(floorplan, labelled, unlabelled, args.folds, grow, engine, cache)
                    if args.sigma_override is not None:
                        for g in grown:
                            g.xy_sigma_m = np.full(len(g), args.sigma_override)
                    if args.resigma is not None:
                        grown = [resigma(g, r, *args.resigma) for g, r in zip(grown, reports)]
                    for f, g in enumerate(grown):
                        print(f"  fold {f} grown points: {json.dumps(grown_point_errors(g, unlabelled))}",
                              file=sys.stderr, flush=True)
                    merged = [merge_radio_maps([base_all, g]) for g in grown]
                    maps = [merged[i % args.folds] for i in range(len(lab_paths))]
                errors, per_walk = score(floorplan, lab_paths, maps, seed, args.particles, engine)
                label = args.tag + ("" if args.sigma_override is None else f"-s{args.sigma_override:g}") + args.label
                walks.append({"set": name, "seed": seed, "map": which, "tag": label, "walks": per_walk})
                for method, e in errors.items():
                    stats = summarise_errors(e)
                    rows.append({"set": name, "seed": seed, "map": which, "tag": label if which == "grown" else "",
                                 "method": method, "mean": stats["mean"], "p75": stats["p75"], "n": stats["n"],
                                 "s": round(time.perf_counter() - started)})
                    print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    print(format_table(rows, list(rows[0])))
    variant = args.tag + ("" if args.sigma_override is None else f"-s{args.sigma_override:g}") + args.label
    out = args.out / f"rows_{variant}_{'_'.join(args.sets)}_{'_'.join(map(str, args.seeds))}.json"
    out.write_text(json.dumps({"rows": rows, "walks": walks}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
