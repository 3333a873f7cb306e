"""Simulated walks over three stacked floors that change floor by stairs and by lift (issue 10).

The building: three floors (F0, F1, F2; 4 m apart) with the bundled office's plan, a stairwell
in the south corridor and a lift in the east corridor linking all three
(``make_office_building``). Every floor has the office's access points (its own BSSIDs);
WiFi crosses floors with 15 dB per floor (``simulate.building``). The radio map: one survey
per floor (a reference point every 2 m), labelled with its floor. Every walk starts on a
random floor and takes three floor changes, stairs and lift mixed (``simulate_building_walk``),
with a barometer in the log.

Each walk is tracked three ways with the same seed: the floor found (WiFi floor vote and
barometer), the floor found without the barometer, and the floor given (the true floor as
the floor evidence of every scan). Reported: the share of time (1 s grid, from the first
estimate) on the right floor, the delay of every floor change (from the true switch, half-way
up the stairs or the lift ride, to the first causal estimate on the new floor), and the
horizontal error at the waypoints (each row in its own floor's frame). Example:

    .venv/bin/python tools/floor_sim.py --walks 10 --out results/floor_sim.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from mapfilter.io.atomic import atomic_paths  # noqa: E402
from mapfilter.evaluation.metrics import errors_at_waypoints, summarise_errors  # noqa: E402
from mapfilter.maps.building import Building  # noqa: E402
from mapfilter.maps.floorplan import FloorPlan  # noqa: E402
from mapfilter.sensors.floor_vote import build_building_radio_map  # noqa: E402
from mapfilter.sensors.ilc import read_ilc  # noqa: E402
from mapfilter.sensors.pathloss import AccessPointTable  # noqa: E402
from mapfilter.simulate.building import (  # noqa: E402
    BuildingSimConfig,
    FloorChange,
    simulate_building_survey,
    simulate_building_walk,
)
from mapfilter.simulate.ilc_writer import write_ilc  # noqa: E402
from mapfilter.config import FloorsConfig, TrackingConfig  # noqa: E402
from mapfilter.pipeline.tracker import track  # noqa: E402

FLOORS = ("F0", "F1", "F2")
STOREY_M = 4.0
# free corridor strips of maps/office.yaml (38 m x 38 m, 0.1 m/px)
STAIRS = [[12.0, 7.9], [18.0, 7.9], [18.0, 9.1], [12.0, 9.1]]
LIFT = [[28.8, 16.0], [30.2, 16.0], [30.2, 17.5], [28.8, 17.5]]


def make_office_building(out_dir: Path) -> tuple[Building, dict[str, AccessPointTable]]:
    """Three office floors stacked 4 m apart, a stairwell and a lift; an AP table per floor."""
    plan = FloorPlan.load(REPO / "maps" / "office.yaml")
    aps = AccessPointTable.read_csv(REPO / "maps" / "office_aps.csv")
    floors, tables = [], {}
    for i, name in enumerate(FLOORS):
        floor_plan = FloorPlan(plan.wall_mask, plan.resolution_m, plan.origin_m, name, plan.source_image)
        floor_plan.save(out_dir / f"{name}.yaml")
        floors.append({"name": name, "map": f"{name}.yaml", "elevation_m": STOREY_M * i, "offset_m": [0.0, 0.0]})
        # the same places on every floor, their own BSSIDs (02:00:00:0i:..)
        bssid = [b[:9] + f"{i:02x}" + b[11:] for b in aps.bssid]
        tables[name] = AccessPointTable(bssid, list(aps.band), aps.xy_m.copy(), aps.c_dbm.copy(), aps.n.copy(),
                                        aps.alpha_db_per_m.copy(), aps.d_max_m.copy())
    meta = {"building": "office-3", "storey_height_m": STOREY_M, "floors": floors, "connectors": [
        {"name": "stairs", "kind": "stairs", "floors": {n: STAIRS for n in FLOORS}},
        {"name": "lift", "kind": "lift", "floors": {n: LIFT for n in FLOORS}}]}
    (out_dir / "building.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    return Building.load(out_dir / "building.yaml"), tables


def make_office_building_with_ap_files(out_dir: Path) -> Path:
    """``make_office_building``, each floor's map also naming its access-point table (written as
    ``<floor>_aps.csv`` beside it), as ``mapfilter simulate BUILDING.yaml`` needs; the building YAML."""
    _, tables = make_office_building(out_dir)
    for name, table in tables.items():
        table.write_csv(out_dir / f"{name}_aps.csv")
        plan = FloorPlan.load(out_dir / f"{name}.yaml")
        dataclasses.replace(plan, access_points_csv=(out_dir / f"{name}_aps.csv").resolve()).save(out_dir / f"{name}.yaml")
    return out_dir / "building.yaml"


def schedule(rng: np.random.Generator) -> tuple[str, list[FloorChange]]:
    """A start floor and three changes to neighbouring floors (stairs) or any floor (lift)."""
    floor = int(rng.integers(0, len(FLOORS)))
    start = FLOORS[floor]
    changes = []
    kinds = ["stairs", "lift", "stairs"] if rng.random() < 0.5 else ["lift", "stairs", "lift"]
    for kind in kinds:
        if kind == "stairs":
            options = [f for f in (floor - 1, floor + 1) if 0 <= f < len(FLOORS)]
        else:
            options = [f for f in range(len(FLOORS)) if f != floor]
        floor = int(rng.choice(options))
        changes.append(FloorChange(kind, FLOORS[floor]))
    return start, changes


def floor_scores(track, truth_t_s: np.ndarray, truth_floor: list[str], changes: list[tuple]) -> dict:
    """Share of time on the right floor (1 s grid from the first estimate) and change delays."""
    grid = np.arange(track.t_s[0], truth_t_s[-1], 1.0)
    true_at = np.array(truth_floor)[np.clip(np.searchsorted(truth_t_s, grid, side="right") - 1, 0, None)]
    est_at = np.array(track.floor)[np.searchsorted(track.t_s, grid, side="right") - 1]
    delays = []
    for t_enter, t_switch, _, _, to_floor, kind in changes:
        after = np.flatnonzero((track.t_s >= t_enter) & (np.array(track.floor) == to_floor))
        delays.append({"kind": kind, "to": to_floor,
                       "delay_s": float(track.t_s[after[0]] - t_switch) if after.size else None})
    return {"time_right": float(np.mean(true_at == est_at)), "delays": delays}


def main() -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    parser.add_argument("--walks", type=int, default=10)
    parser.add_argument("--particles", type=int, default=5000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    started = time.perf_counter()
    sim = BuildingSimConfig()
    rows = []
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        building, tables = make_office_building(tmp)
        surveys = []
        for i, name in enumerate(FLOORS):
            survey = simulate_building_survey(building, tables, name, sim, np.random.default_rng([args.seed, 99, i]))
            write_ilc(survey, tmp / f"survey_{name}.txt")
            surveys.append(read_ilc(tmp / f"survey_{name}.txt"))
        radio_map = build_building_radio_map(surveys, [building.floor_index(s.floor_name) for s in surveys],
                                             building.floor_names)
        print(f"radio map: {len(radio_map)} points, {len(radio_map.ap_keys)} APs", flush=True)
        # smooth: also the offline track, its floor the smoother's (the causal track is the same
        # with or without it: the particle history is only recorded)
        smooth_config = TrackingConfig(smooth=True).with_particles(args.particles)
        for w in range(args.walks):
            rng = np.random.default_rng([args.seed, w])
            start, changes = schedule(rng)
            walk, happened = simulate_building_walk(building, tables, start, changes, sim, rng)
            path = tmp / f"walk_{w}.txt"
            write_ilc(walk, path)
            rec = read_ilc(path)
            scan_t = np.unique(rec.wifi.t_s)
            truth_idx = np.array([building.floor_index(f) for f in rec.waypoint_floor])
            true_scan_floor = truth_idx[np.clip(np.searchsorted(rec.waypoint_t_s, scan_t, side="right") - 1, 0, None)]
            oracle = np.full((scan_t.size, len(FLOORS)), -30.0)
            oracle[np.arange(scan_t.size), true_scan_floor] = 0.0
            row = {"walk": w, "start": start, "changes": [(c.connector, c.to_floor) for c in changes],
                   "duration_s": float(rec.waypoint_t_s[-1] - rec.waypoint_t_s[0])}
            no_baro = dataclasses.replace(smooth_config, floors=FloorsConfig(use_barometer=False))
            for label, config, kwargs in (("found", smooth_config, {}), ("found_no_baro", no_baro, {}),
                                          ("given", smooth_config, {"floor_evidence": oracle})):
                result = track(building, rec, radio_map, config=config,
                               rng=np.random.default_rng([args.seed, w, 1]), **kwargs)
                err = errors_at_waypoints(result.causal.t_s, result.causal.xy_m, rec.waypoint_t_s, rec.waypoint_xy_m)
                row[label] = {"errors_m": err.errors_m.tolist(),
                              **floor_scores(result.causal, rec.waypoint_t_s, rec.waypoint_floor, happened)}
                if label != "given":
                    smoothed = floor_scores(result.offline, rec.waypoint_t_s, rec.waypoint_floor, happened)
                    row[label]["smoothed_time_right"] = smoothed["time_right"]
                    row[label]["smoothed_errors_m"] = errors_at_waypoints(
                        result.offline.t_s, result.offline.xy_m, rec.waypoint_t_s, rec.waypoint_xy_m, False).errors_m.tolist()
            rows.append(row)
            f, g, n = row["found"], row["given"], row["found_no_baro"]
            print(f"walk {w} ({start} then {', '.join(f'{c}->{t}' for c, t in row['changes'])}, "
                  f"{row['duration_s']:.0f} s): floor right {100 * f['time_right']:.1f} % of the time "
                  f"(no barometer {100 * n['time_right']:.1f} %; whole walk {100 * f['smoothed_time_right']:.1f} %, "
                  f"no barometer {100 * n['smoothed_time_right']:.1f} %), change delays "
                  f"{[d['delay_s'] if d['delay_s'] is None else round(d['delay_s'], 1) for d in f['delays']]} s; "
                  f"mean error {np.mean(f['errors_m']):.2f} m (floor given {np.mean(g['errors_m']):.2f} m)",
                  flush=True)
    report = {"walks": rows, "particles": args.particles, "seed": args.seed,
              "runtime_s": time.perf_counter() - started}
    for label in ("found", "found_no_baro", "given"):
        errors = np.concatenate([r[label]["errors_m"] for r in rows])
        delays = [d["delay_s"] for r in rows for d in r[label]["delays"]]
        report[label] = {"time_right": float(np.mean([r[label]["time_right"] for r in rows])),
                         "changes": len(delays), "changes_missed": sum(d is None for d in delays),
                         "max_delay_s": max((d for d in delays if d is not None), default=None),
                         "changes_within_5s": sum(d is not None and d <= 5.0 for d in delays),
                         "error_m": summarise_errors(errors)}
        if label != "given":
            report[label]["smoothed_time_right"] = float(np.mean([r[label]["smoothed_time_right"] for r in rows]))
            report[label]["smoothed_error_m"] = summarise_errors(
                np.concatenate([r[label]["smoothed_errors_m"] for r in rows]))
    print("\n| tracking | floor right (time) | changes found within 5 s | max delay | mean error | p75 error |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    for label, name in (("found", "floor found (WiFi + barometer)"), ("found_no_baro", "floor found (WiFi only)"),
                        ("given", "floor given")):
        s = report[label]
        max_delay = "-" if s["max_delay_s"] is None else f"{s['max_delay_s']:.1f} s"
        print(f"| {name} | {100 * s['time_right']:.1f} % | {s['changes_within_5s']} of {s['changes']} "
              f"| {max_delay} | {s['error_m']['mean']:.2f} m | {s['error_m']['p75']:.2f} m |")
    print("\nWhole walk (offline, --smooth): floor right "
          f"{100 * report['found']['smoothed_time_right']:.2f} % of the time with the barometer, "
          f"{100 * report['found_no_baro']['smoothed_time_right']:.2f} % without; error at every waypoint "
          f"{report['found']['smoothed_error_m']['mean']:.2f} m mean, {report['found']['smoothed_error_m']['p75']:.2f} m p75 "
          f"(without the barometer {report['found_no_baro']['smoothed_error_m']['mean']:.2f} m)")
    print(f"\n{report['runtime_s']:.0f} s")
    if args.out is not None:
        with atomic_paths(args.out) as (tmp_out,):
            tmp_out.write_text(json.dumps(report, indent=1))
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
