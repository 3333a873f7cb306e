"""Where nobody surveyed: a path-loss model of the whole plan as a per-scan predictor (issue 49).

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
The IPIN 2023 logs too (``ipin``): the first repetition of each route, every log of the other
routes the survey, each scan placed on its true floor from that floor's points.

    .venv/bin/python tools/experiments/radio_region.py --parts F1 F2 ipin
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial import cKDTree
from scipy.special import log_ndtr

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from mapfilter.evaluation.area_split import half_split, split_directions
from mapfilter.evaluation.comparison import read_walk
from mapfilter.evaluation.metrics import format_table
from mapfilter.maps.building import Building
from mapfilter.maps.prepare import import_ilc
from mapfilter.sensors.pathloss import path_loss_rssi_dbm
from mapfilter.sensors.radiomap import build_radio_map, kwnn_fix_many

sys.path.insert(0, str(Path(__file__).resolve().parent))
from split_ilc import floor_walks

FLOOR_DBM = -90.0  # a reading below this is taken as not heard (-95 and -85 placed F1 worse)
SIGMA_DB = 6.0  # spread of a heard reading about the model (the fits' median residual is 4-5 dB)
PRIOR_C_DBM, PRIOR_C_SIGMA_DB = -40.0, 10.0
PRIOR_N, PRIOR_N_SIGMA = 2.5, 0.75
MIN_HEARD = 8  # survey scans that heard an AP; fewer: not fitted
NOT_HEARD_SAMPLE = 400  # survey points that did not hear an AP, sampled for its fit
GRID_M = 1.0
DISTANCE_BINS_M = (0.0, 5.0, 15.0, 30.0, np.inf)


def predicted_rssi_dbm(d_m: np.ndarray, c_dbm, n) -> np.ndarray:
    """Log-distance path loss, R = C - 10 n log10(max(d, 1 m)): the Lund model without its wall term."""
    return path_loss_rssi_dbm(d_m, c_dbm, n, 0.0, 0.0)


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

        def residual(p, xy_seen=xy_seen, xy_unseen=xy_unseen, z=z, weight_unseen=weight_unseen):
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
        for i in direction.test:
            own = build_radio_map([walks[i]], plan)  # the walk's scans, labelled with their true positions
            truth, scored = _score(own, radio_map, cells, columns, params)
            for key, values in scored.items():
                rows[key].extend(values)
            rows["half"].extend(np.where(split.side(truth) == direction.surveyed_side, "surveyed", "unsurveyed"))
        log(f"{floor} {split.describe(direction.surveyed_side)} surveyed: {len(columns)} APs fitted, "
            f"{len(direction.test)} test walks, {time.perf_counter() - started:.0f} s")
    return rows


def run_ipin(work: Path, seed: int, log) -> dict[str, list]:
    """IPIN 2023, the first repetition of each route, its floor's survey every log of the other
    routes (leave-one-route-out): each scan placed on its true floor from that floor's points."""
    from beyond_survey import IPIN, ipin_venue

    from mapfilter.sensors.floor_vote import build_building_radio_map

    building = Building.load(ipin_venue(work, beacons=False)[0])
    logs = sorted((IPIN / "logs").glob("*.txt.gz"))
    walks = {p: read_walk(p, building) for p in logs}
    names = building.floor_names
    rng = np.random.default_rng(seed)
    rows: dict[str, list] = {"distance": [], "half": [], "kwnn": [], "path loss": [], "nearest survey point": []}
    for test in (p for p in logs if p.name.endswith("repetition01.txt.gz")):
        route = test.name.split("Trial")[1][:2]
        survey = [walks[p] for p in logs if f"Trial{route}_" not in p.name]
        radio_map = build_building_radio_map(survey, [None] * len(survey), names)
        own = build_building_radio_map([walks[test]], [None], names)  # labelled with their true positions
        for f, floor in enumerate(building.floors):
            floor_map, mine = radio_map.floor_map(f), own.floor == f
            if len(floor_map) == 0 or not mine.any():
                continue
            columns, params = fit_access_points(floor_map.xy_m, floor_map.rssi_dbm, floor.plan.extent_m, rng)
            _, scored = _score(own.select(mine), floor_map, free_cells(floor.plan), columns, params)
            for key, values in scored.items():
                rows[key].extend(values)
            # no halves here: "surveyed" within 15 m of the floor's survey, "unsurveyed" beyond
            rows["half"].extend(np.where(scored["distance"] < 15.0, "surveyed", "unsurveyed"))
        log(f"IPIN route {route} left out: {len(survey)} survey walks")
    return rows


def _score(own, radio_map, cells, columns, params) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(true positions, errors): KWNN, path-loss and nearest-survey-point errors of a walk's
    labelled scans (``own``, a radio map of the walk alone) against a survey's radio map; scans
    sharing under 3 APs with it skipped."""
    index = radio_map.key_index
    scans = np.full((len(own), len(radio_map.ap_keys)), np.nan, dtype=np.float32)
    shared = [(j, index[key]) for j, key in enumerate(own.ap_keys) if key in index]
    if shared:
        own_cols, map_cols = map(list, zip(*shared))
        scans[:, map_cols] = own.rssi_dbm[:, own_cols]
    usable = np.count_nonzero(~np.isnan(scans), axis=1) >= 3
    truth, scans = own.xy_m[usable], scans[usable]
    if not len(truth):
        return truth, {"distance": np.zeros(0), "kwnn": np.zeros(0), "path loss": np.zeros(0),
                       "nearest survey point": np.zeros(0)}
    distance = cKDTree(radio_map.xy_m).query(truth)[0]
    return truth, {"distance": distance,
            "kwnn": np.linalg.norm(kwnn_fix_many(radio_map, scans).xy_m - truth, axis=1),
            "path loss": np.linalg.norm(path_loss_fixes(cells, params, scans[:, columns]) - truth, axis=1),
            "nearest survey point": distance}


def table(floor: str, rows: dict[str, list]) -> list[dict]:
    """Mean / median / p75 per method, per distance bin and per half."""
    distance = np.array(rows["distance"])
    half = np.array(rows["half"])
    far, near = (("15 m or more from the survey", "within 15 m of the survey") if floor == "ipin"
                 else ("unsurveyed half", "surveyed half"))
    groups = [(far, half == "unsurveyed"), (near, half == "surveyed")]
    groups += [(f"{lo:.0f}-{hi:.0f} m from the survey" if np.isfinite(hi) else f"over {lo:.0f} m from the survey",
                (distance >= lo) & (distance < hi)) for lo, hi in itertools.pairwise(DISTANCE_BINS_M)]
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
    parser.add_argument("--parts", nargs="+", choices=("F1", "F2", "ipin"), default=["F1", "F2", "ipin"],
                        help="ILC site 1 floors (the half-floor split) and the IPIN 2023 logs (route left out)")
    parser.add_argument("--seed", type=int, default=1, help="the sample of unheard survey points per AP's fit")
    parser.add_argument("--out", type=Path, default=REPO / "results" / "radio_region")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    results = {}
    log = lambda message: print(message, file=sys.stderr, flush=True)
    for floor in args.parts:
        rows = run_ipin(args.out, args.seed, log) if floor == "ipin" else run_floor(floor, args.out, args.seed, log)
        results[floor] = {k: [float(v) if k != "half" else v for v in values] for k, values in rows.items()}
        print(f"\nper scan error, mean / median / p75 (m)\n"
              f"{format_table(table(floor, rows), ('floor', 'scans', 'n', 'kwnn', 'path loss', 'nearest survey point'))}",
              flush=True)
    (args.out / "radio_region.json").write_text(json.dumps(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
