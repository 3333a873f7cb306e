"""Floor detection on ILC site 1 as one building (issue 10's must-show numbers).

The five floors of ``--data`` (default ../shared/data/ilc20/site1: B1, F1-F4) are imported as
one building (``mapfilter map import-ilc SITE``: GeoJSON route, 0.25 m, placed by longitude and
latitude) and one building radio map is built from all 191 logs, each labelled with the floor
its header names. Every walk is then judged with that radio map *without its own points*
(leave-one-walk-out), and without its floor label:

- every walk with IMU (F1: 76, F2: the 12 of ``full_set.txt``) is tracked by the particle
  filter with the floor in its state (``pipeline.tracker.track``); the score is the
  share of waypoints at which the causal track is on the header's floor (waypoints before the
  first estimate are left out, as for the errors). The same run also gives the offline track
  (``--smooth``: the smoother's floor at every row; a walk the smoother keeps on one floor
  throughout gets that floor's one-floor offline track), judged at the row nearest each waypoint in time, as
  ``mapfilter evaluate --smooth`` judges ``pf-smooth``. The same walk is also tracked with the
  floor given, to compare the horizontal error (causal, at the waypoints);
- every WiFi-only walk (B1 25, F2's other 28, F3 25, F4 25) gets the floor the WiFi floor
  HMM puts it on (``sensors.floor_vote``: the KWNN floor vote per scan, Viterbi path over the walk,
  the floor of most of its scans); the score is the share of walks on the right floor, and,
  for information, the share of scans whose causal (forward) floor is right.

The fix Gaussian of each floor is calibrated once from that floor's whole radio map (as
``tools/experiments/sweep_ilc.py --fix-sigma per-floor`` does; the walk under test lends only its share in
that one number). 10,000 particles, seed 0. Example (the README's numbers):

    .venv/bin/python tools/experiments/floor_ilc.py --out results/floor_ilc.json
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from mapfilter.io.atomic import atomic_paths  # noqa: E402
from mapfilter.errors import MapfilterError  # noqa: E402
from mapfilter.evaluation.metrics import errors_at_waypoints, floor_at_waypoints, summarise_errors  # noqa: E402
from mapfilter.maps import prepare  # noqa: E402
from mapfilter.maps.building import import_ilc_site  # noqa: E402
from mapfilter.sensors.floor_vote import build_building_radio_map, floor_hmm, floor_vote_log_likelihood, walk_floor  # noqa: E402
from mapfilter.sensors.ilc import read_ilc  # noqa: E402
from mapfilter.sensors.wifi import scans_of  # noqa: E402
from mapfilter.config import TrackingConfig  # noqa: E402
from mapfilter.filter.evidence import calibrated_fix_sigma_m  # noqa: E402
from mapfilter.pipeline.tracker import track  # noqa: E402

ILC = REPO.parent / "shared" / "data" / "ilc20" / "site1"


def main() -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=ILC)
    parser.add_argument("--particles", type=int, default=10_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--limit", type=int, default=0, help="track only the first N walks with IMU (0: all)")
    parser.add_argument("--traces", default="", metavar="ID1,ID2", help="track only these walks with IMU")
    parser.add_argument("--thin", default="", metavar="FLOOR:N",
                        help="that floor's survey thinned: only its first N logs join the radio map (the "
                             "ambiguous-floor reproduction; its walks are still all judged)")
    parser.add_argument("--floors", default="", metavar="F1,F2", help="track only the walks with IMU of these floors")
    parser.add_argument("--out", type=Path, help="write the numbers (JSON)")
    args = parser.parse_args()

    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        building = import_ilc_site(args.data)
        for floor in building.floors:
            floor.map_path = Path(tmp) / f"{floor.name}.yaml"
            prepare.write_map(floor.plan, floor.map_path, preview=False)
    names = building.floor_names
    recordings, floors = [], []
    for name in names:
        for path in sorted((args.data / name / "path_data_files").glob("*.txt.gz")):
            rec = read_ilc(path)
            recordings.append(rec)
            floors.append(building.floor_of_log(rec.floor_name, path))
    radio_map = build_building_radio_map(recordings, floors, names)
    if args.thin:
        thin_floor, _, thin_n = args.thin.partition(":")
        of_floor = [r.name for r, f in zip(recordings, floors) if names[f] == thin_floor]
        radio_map = radio_map.without_traces(of_floor[int(thin_n):])
        print(f"floor {thin_floor}: {min(int(thin_n), len(of_floor))} of its {len(of_floor)} logs in the radio map")
    sigma = {name: calibrated_fix_sigma_m(radio_map.floor_map(i)) for i, name in enumerate(names)}
    print(f"{len(recordings)} logs, {len(radio_map)} reference points; fix sigma per floor: "
          + ", ".join(f"{n} {s:.1f} m" for n, s in sigma.items()), flush=True)
    config = TrackingConfig().with_particles(args.particles)
    # the floor found also gives the offline track (--smooth), its floor the smoother's; keeping
    # the particle history for the smoother leaves the causal track as it is
    smooth_config = TrackingConfig(smooth=True).with_particles(args.particles)

    imu_rows, wifi_rows = [], []
    with_imu = [(r, f) for r, f in zip(recordings, floors) if r.acc_t_s.shape[0] >= 100]
    if args.traces:
        with_imu = [(r, f) for r, f in with_imu if r.name in args.traces.split(",")]
    if args.floors:
        with_imu = [(r, f) for r, f in with_imu if names[f] in args.floors.split(",")]
    if args.limit:
        with_imu = with_imu[:args.limit]
    for i, (rec, f) in enumerate(with_imu):
        loo = radio_map.without_traces([rec.name])
        found = track(building, rec, loo, config=smooth_config, rng=np.random.default_rng(args.seed),
                      fix_sigma_by_floor_m=sigma)
        try:
            given = track(building, rec, loo, config=config, rng=np.random.default_rng(args.seed), floor=names[f],
                          fix_sigma_by_floor_m=sigma)
        except MapfilterError:  # a thinned floor (--thin) may give this walk no fix on its own floor
            given = None
        score = floor_at_waypoints(found.causal.t_s, found.causal.floor, rec.waypoint_t_s, names[f])
        err_found = errors_at_waypoints(found.causal.t_s, found.causal.xy_m, rec.waypoint_t_s, rec.waypoint_xy_m)
        err_given = errors_at_waypoints(given.causal.t_s, given.causal.xy_m, rec.waypoint_t_s, rec.waypoint_xy_m) \
            if given is not None else errors_at_waypoints(np.zeros(0), np.zeros((0, 2)), np.zeros(0), np.zeros((0, 2)))
        # the offline track: the nearest row in time, as mapfilter evaluate judges pf-smooth
        smoothed = found.offline
        score_smoothed = floor_at_waypoints(smoothed.t_s, smoothed.floor, rec.waypoint_t_s, names[f], causal=False)
        err_smoothed = errors_at_waypoints(smoothed.t_s, smoothed.xy_m, rec.waypoint_t_s, rec.waypoint_xy_m,
                                           causal=False)
        imu_rows.append({"trace": rec.name, "floor": names[f], "right": score.n_right, "judged": score.n_judged,
                         "missed": score.missed, "floors_visited": sorted(set(found.causal.floor)),
                         "errors_found_m": err_found.errors_m.tolist(), "errors_given_m": err_given.errors_m.tolist(),
                         "smoothed_right": score_smoothed.n_right, "smoothed_judged": score_smoothed.n_judged,
                         "smoothed_floors_visited": sorted(set(smoothed.floor)),
                         "errors_smoothed_m": err_smoothed.errors_m.tolist()})
        print(f"[{i + 1}/{len(with_imu)}] {rec.name} {names[f]}: floor right at {score.n_right}/{score.n_judged} "
              f"waypoints (whole walk {score_smoothed.n_right}/{score_smoothed.n_judged}); mean error {np.mean(err_found.errors_m):.2f} m (floor given "
              f"{np.mean(err_given.errors_m) if err_given.errors_m.size else float('nan'):.2f} m)", flush=True)

    for rec, f in zip(recordings, floors):
        if rec.acc_t_s.shape[0] >= 100:
            continue
        loo = radio_map.without_traces([rec.name])
        scans = scans_of(rec)
        path = floor_hmm(floor_vote_log_likelihood(loo, loo.scan_matrix(scans)), np.array([s.t_s for s in scans]))
        wifi_rows.append({"trace": rec.name, "floor": names[f], "found": names[walk_floor(path)],
                          "scans": len(scans), "scans_causal_right": int(np.sum(path.causal_floor() == f))})

    report = summarise(imu_rows, wifi_rows, names)
    report.update({"fix_sigma_m": sigma, "particles": args.particles, "seed": args.seed,
                   "runtime_s": time.perf_counter() - started, "imu_walks": imu_rows, "wifi_only_walks": wifi_rows})
    print_report(report, names)
    if args.out is not None:
        with atomic_paths(args.out) as (tmp_out,):
            tmp_out.write_text(json.dumps(report, indent=1))
        print(f"wrote {args.out}")
    return 0


def summarise(imu_rows: list[dict], wifi_rows: list[dict], names: list[str]) -> dict:
    out: dict = {"imu": {}, "wifi_only": {}}
    for floor in [*names, "all"]:
        rows = [r for r in imu_rows if floor in ("all", r["floor"])]
        if rows:
            found = np.concatenate([r["errors_found_m"] for r in rows])
            given = np.concatenate([r["errors_given_m"] for r in rows])
            out["imu"][floor] = {
                "walks": len(rows), "waypoints": int(sum(r["judged"] for r in rows)),
                "floor_accuracy": sum(r["right"] for r in rows) / max(sum(r["judged"] for r in rows), 1),
                "walks_all_right": sum(r["right"] == r["judged"] for r in rows),
                "error_found_m": summarise_errors(found), "error_given_m": summarise_errors(given),
                "smoothed_waypoints": int(sum(r["smoothed_judged"] for r in rows)),
                "smoothed_floor_accuracy": sum(r["smoothed_right"] for r in rows)
                / max(sum(r["smoothed_judged"] for r in rows), 1),
                "smoothed_walks_all_right": sum(r["smoothed_right"] == r["smoothed_judged"] for r in rows),
                "error_smoothed_m": summarise_errors(np.concatenate([r["errors_smoothed_m"] for r in rows]))}
        rows = [r for r in wifi_rows if floor in ("all", r["floor"])]
        if rows:
            out["wifi_only"][floor] = {
                "walks": len(rows), "walks_right": sum(r["found"] == r["floor"] for r in rows),
                "walk_accuracy": sum(r["found"] == r["floor"] for r in rows) / len(rows),
                "scan_causal_accuracy": sum(r["scans_causal_right"] for r in rows) / max(sum(r["scans"] for r in rows), 1),
                "wrong": [f"{r['trace']} ({r['floor']} -> {r['found']})" for r in rows if r["found"] != r["floor"]]}
    return out


def print_report(report: dict, names: list[str]) -> None:
    print("\nWalks with IMU, floor found by the filter (leave-one-walk-out building radio map):")
    print("| floor | walks | waypoints | floor right | mean error, floor found | mean error, floor given "
          "| p75 found | p75 given |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for floor, s in report["imu"].items():
        print(f"| {floor} | {s['walks']} | {s['waypoints']} | {100 * s['floor_accuracy']:.1f} % "
              f"| {s['error_found_m']['mean']:.2f} m | {s['error_given_m']['mean']:.2f} m "
              f"| {s['error_found_m']['p75']:.2f} m | {s['error_given_m']['p75']:.2f} m |")
    print("\nThe same walks, offline (--smooth): the smoother's floor at every row; on one floor "
          "throughout, that floor's one-floor offline track:")
    print("| floor | waypoints | floor right, causal | floor right, offline | walks all right (offline) "
          "| mean error, smoothed | p75 smoothed |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for floor, s in report["imu"].items():
        print(f"| {floor} | {s['smoothed_waypoints']} | {100 * s['floor_accuracy']:.1f} % "
              f"| {100 * s['smoothed_floor_accuracy']:.1f} % | {s['smoothed_walks_all_right']} of {s['walks']} "
              f"| {s['error_smoothed_m']['mean']:.2f} m | {s['error_smoothed_m']['p75']:.2f} m |")
    print("\nWiFi-only walks, floor of the walk from the WiFi floor HMM:")
    print("| floor | walks | walks right | scans right (causal) | wrong |")
    print("| --- | ---: | ---: | ---: | --- |")
    for floor, s in report["wifi_only"].items():
        print(f"| {floor} | {s['walks']} | {s['walks_right']} ({100 * s['walk_accuracy']:.1f} %) "
              f"| {100 * s['scan_causal_accuracy']:.1f} % | {', '.join(s['wrong']) or '-'} |")
    print(f"\n{report['runtime_s']:.0f} s")


if __name__ == "__main__":
    sys.exit(main())
