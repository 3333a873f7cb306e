"""ILC site 1, the half-floor split: a radio model of the whole plan as a per-scan predictor (issue 49).

Beside KWNN, where the survey never was: every test walk's scans are labelled with their true
positions (interpolated between waypoints) and placed by
- ``kwnn``: the filter's KWNN fix from the survey's radio map (k = 4);
- ``path loss``: each AP's position, power C and exponent n fitted to the survey (the heard
  readings with a robust loss, the survey points that did not hear it as "below the phone's
  floor", a prior on C and n, the AP anywhere on the plan), each scan then placed at the free
  1 m cell of greatest likelihood: a Gaussian per heard AP, P(below the floor) per fitted AP
  not heard;
- ``nearest survey point``: the survey point nearest the truth, the best any fingerprint can do.
Errors by the scan's distance from the survey (its true position to the nearest survey point).

    .venv/bin/python tools/experiments/radio_region.py --floors F1 F2
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from scipy.special import log_ndtr
from scipy.spatial import cKDTree

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from mapfilter.evaluation.area_split import half_split, split_directions  # noqa: E402
from mapfilter.evaluation.comparison import read_walk  # noqa: E402
from mapfilter.evaluation.metrics import format_table  # noqa: E402
from mapfilter.maps.building import Building  # noqa: E402
from mapfilter.maps.prepare import import_ilc  # noqa: E402
from mapfilter.sensors.radiomap import build_radio_map, kwnn_fix_many  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from split_ilc import floor_walks  # noqa: E402

FLOOR_DBM = -90.0  # a reading below this is taken as not heard (-95 and -85 placed F1 worse)
SIGMA_DB = 6.0  # spread of a heard reading about the model (the fits' median residual is 4-5 dB)
PRIOR_C_DBM, PRIOR_C_SIGMA_DB = -40.0, 10.0
PRIOR_N, PRIOR_N_SIGMA = 2.5, 0.75
MIN_HEARD = 8  # survey scans that heard an AP; fewer: not fitted
NOT_HEARD_SAMPLE = 400  # survey points that did not hear an AP, sampled for its fit
GRID_M = 1.0
DISTANCE_BINS_M = (0.0, 5.0, 15.0, 30.0, np.inf)


def predicted_rssi_dbm(d_m: np.ndarray, c_dbm, n) -> np.ndarray:
    """Log-distance path loss, R = C - 10 n log10(max(d, 1 m))."""
    return c_dbm - 10.0 * n * np.log10(np.maximum(d_m, 1.0))


def fit_access_points(survey_xy_m: np.ndarray, survey_rssi_dbm: np.ndarray, extent_m, rng) -> tuple[np.ndarray, np.ndarray]:
    """(fitted AP columns, (A, 4) x, y, C, n) of every AP heard in >= MIN_HEARD survey scans."""
    x0, x1, y0, y1 = extent_m
    heard = ~np.isnan(survey_rssi_dbm) & (survey_rssi_dbm >= FLOOR_DBM)
    columns, params = [], []
    for k in range(survey_rssi_dbm.shape[1]):
        seen = np.nonzero(heard[:, k])[0]
        if seen.size < MIN_HEARD:
            continue
        unseen = np.nonzero(~heard[:, k])[0]
        if unseen.size > NOT_HEARD_SAMPLE:
            unseen = rng.choice(unseen, NOT_HEARD_SAMPLE, replace=False)
        z = survey_rssi_dbm[seen, k].astype(np.float64)
        xy_seen, xy_unseen = survey_xy_m[seen], survey_xy_m[unseen]
        top = np.argsort(-z)[:3]
        start = np.array([*xy_seen[top].mean(axis=0), PRIOR_C_DBM, PRIOR_N])
        weight_unseen = np.sqrt(seen.size / max(unseen.size, 1))  # the unheard count as much as the heard together

        def residual(p):
            r_seen = (predicted_rssi_dbm(np.hypot(*(xy_seen - p[:2]).T), p[2], p[3]) - z) / SIGMA_DB
            above = predicted_rssi_dbm(np.hypot(*(xy_unseen - p[:2]).T), p[2], p[3]) - FLOOR_DBM
            r_unseen = weight_unseen * np.maximum(above, 0.0) / SIGMA_DB
            prior = [(p[2] - PRIOR_C_DBM) / PRIOR_C_SIGMA_DB, (p[3] - PRIOR_N) / PRIOR_N_SIGMA]
            return np.concatenate([r_seen, r_unseen, prior])

        lo = [x0 - 10.0, y0 - 10.0, -80.0, 1.2]
        hi = [x1 + 10.0, y1 + 10.0, 0.0, 6.0]
        fit = least_squares(residual, np.clip(start, np.array(lo) + 1e-6, np.array(hi) - 1e-6), bounds=(lo, hi),
                            loss="soft_l1", f_scale=1.0, max_nfev=200)
        columns.append(k)
        params.append(fit.x)
    return np.array(columns, dtype=np.int64), np.array(params)


def free_cells(plan) -> np.ndarray:
    """The centres of the free GRID_M cells of the plan (a cell is free where its centre is)."""
    x0, x1, y0, y1 = plan.extent_m
    xs = np.arange(x0 + GRID_M / 2, x1, GRID_M)
    ys = np.arange(y0 + GRID_M / 2, y1, GRID_M)
    xy = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    return xy[plan.is_free(xy)]


def path_loss_fixes(cells_xy_m: np.ndarray, ap_params: np.ndarray, scans_dbm: np.ndarray) -> np.ndarray:
    """Each scan's most likely cell: (S, 2). ``scans_dbm`` over the fitted APs, NaN not heard."""
    expected = np.empty((ap_params.shape[0], cells_xy_m.shape[0]), dtype=np.float32)
    for a, (x, y, c, n) in enumerate(ap_params):
        expected[a] = predicted_rssi_dbm(np.hypot(cells_xy_m[:, 0] - x, cells_xy_m[:, 1] - y), c, n)
    log_unheard = log_ndtr((FLOOR_DBM - expected) / SIGMA_DB).astype(np.float32)  # P(below the floor)
    all_unheard = log_unheard.sum(axis=0)
    fixes = np.empty((scans_dbm.shape[0], 2))
    for s, scan in enumerate(scans_dbm):
        heard = np.nonzero(~np.isnan(scan) & (scan >= FLOOR_DBM))[0]
        r = (scan[heard, None] - expected[heard]) / SIGMA_DB
        loglik = all_unheard - log_unheard[heard].sum(axis=0) - 0.5 * np.minimum(r * r, 16.0).sum(axis=0)
        fixes[s] = cells_xy_m[np.argmax(loglik)]
    return fixes


def run_floor(floor: str, work: Path, seed: int, log) -> dict[str, list]:
    plan = import_ilc(REPO.parent / "shared" / "data" / "ilc20" / "site1" / floor, route="geojson")
    map_path = work / f"{floor}.yaml"
    plan.save(map_path)
    building = Building.from_plan(plan, map_path)
    walks = [read_walk(p, building) for p in floor_walks(floor)]
    split = half_split([w.waypoint_xy_m for w in walks])
    cells = free_cells(plan)
    rng = np.random.default_rng(seed)
    rows: dict[str, list] = {"distance": [], "half": [], "kwnn": [], "path loss": [], "nearest survey point": []}
    for direction in split_directions(split, [w.waypoint_xy_m for w in walks]):
        started = time.perf_counter()
        radio_map = build_radio_map([walks[i] for i in direction.survey], plan)
        columns, params = fit_access_points(radio_map.xy_m, radio_map.rssi_dbm, plan.extent_m, rng)
        survey_tree = cKDTree(radio_map.xy_m)
        index = radio_map.key_index
        for i in direction.test:
            own = build_radio_map([walks[i]], plan)  # the walk's scans, labelled with their true positions
            scans = np.full((len(own), len(radio_map.ap_keys)), np.nan, dtype=np.float32)
            shared = [(j, index[key]) for j, key in enumerate(own.ap_keys) if key in index]
            if shared:
                own_cols, map_cols = map(list, zip(*shared))
                scans[:, map_cols] = own.rssi_dbm[:, own_cols]
            usable = np.count_nonzero(~np.isnan(scans), axis=1) >= 3
            truth, scans = own.xy_m[usable], scans[usable]
            if not len(truth):
                continue
            kwnn = kwnn_fix_many(radio_map, scans).xy_m
            path_loss = path_loss_fixes(cells, params, scans[:, columns])
            distance, nearest = survey_tree.query(truth)
            side = split.side(truth)
            rows["distance"].extend(distance)
            rows["half"].extend(np.where(side == direction.surveyed_side, "surveyed", "unsurveyed"))
            rows["kwnn"].extend(np.linalg.norm(kwnn - truth, axis=1))
            rows["path loss"].extend(np.linalg.norm(path_loss - truth, axis=1))
            rows["nearest survey point"].extend(distance)
        log(f"{floor} {split.describe(direction.surveyed_side)} surveyed: {len(columns)} APs fitted, "
            f"{len(direction.test)} test walks, {time.perf_counter() - started:.0f} s")
    return rows


def table(floor: str, rows: dict[str, list]) -> list[dict]:
    """Mean / median / p75 per method, per distance bin and per half."""
    distance = np.array(rows["distance"])
    half = np.array(rows["half"])
    groups = [("unsurveyed half", half == "unsurveyed"), ("surveyed half", half == "surveyed")]
    groups += [(f"{lo:.0f}-{hi:.0f} m from the survey" if np.isfinite(hi) else f"over {lo:.0f} m from the survey",
                (distance >= lo) & (distance < hi)) for lo, hi in zip(DISTANCE_BINS_M[:-1], DISTANCE_BINS_M[1:])]
    out = []
    for name, keep in groups:
        row = {"floor": floor, "scans": name, "n": int(np.count_nonzero(keep))}
        for method in ("kwnn", "path loss", "nearest survey point"):
            e = np.asarray(rows[method])[keep]
            e = e[np.isfinite(e)]
            row[method] = (f"{e.mean():.1f} / {np.median(e):.1f} / {np.percentile(e, 75):.1f}" if e.size else "")
        out.append(row)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    parser.add_argument("--floors", nargs="+", choices=("F1", "F2"), default=["F1", "F2"])
    parser.add_argument("--seed", type=int, default=1, help="the sample of unheard survey points per AP's fit")
    parser.add_argument("--out", type=Path, default=REPO / "results" / "radio_region")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    results = {}
    for floor in args.floors:
        rows = run_floor(floor, args.out, args.seed, lambda m: print(m, file=sys.stderr, flush=True))
        results[floor] = {k: [float(v) if k != "half" else v for v in values] for k, values in rows.items()}
        print(f"\nper scan error, mean / median / p75 (m)\n"
              f"{format_table(table(floor, rows), ('floor', 'scans', 'n', 'kwnn', 'path loss', 'nearest survey point'))}",
              flush=True)
    (args.out / "radio_region.json").write_text(json.dumps(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
