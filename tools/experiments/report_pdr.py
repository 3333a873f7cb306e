"""PDR check on real walks: step distance vs waypoint polyline, gyro turns vs waypoint turns.

For every log given, ILC trace or IPIN GetSensorData log (default: all of
../shared/data/ilc20/site1/F*/path_data_files; ``--ipin``: the 29 IPIN 2023 logs, their POSI
ground truth in metres on the tangent plane at its first point):

- steps: the steps detected between the first and the last waypoint time, per second, and how
  late each was known (``Steps.available_s - t_s``);
- distance: those steps times a fixed step length (0.7 m, the filter's initial per-particle
  step length), the Weinberg lengths (default K), the Weinberg lengths
  with K fitted leave-one-trace-out (K_i = sum of the other traces' polyline lengths over the sum
  of their (a_max - a_min)^(1/4)), and a fixed length fitted leave-one-trace-out the same way;
  each divided by the waypoint polyline length over that span;
- turns: for each pair of consecutive waypoint legs, the angle between the legs vs the gyro
  heading change between the legs' middle times (error wrapped to [-180, 180) degrees);
- absolute heading: the rotation-vector heading (pi/2 - azimuth) minus each leg's direction,
  averaged over the steps of the leg's middle half: its circular mean is the offset between
  magnetic north and the floor plan's y axis.

Prints a markdown table per trace, a summary, and (with --json) writes the numbers as JSON.

    .venv/bin/python tools/experiments/report_pdr.py [--json out.json] [--ipin | TRACE ...]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.maps.georef import LocalFrame
from mapfilter.sensors.logs import read_log
from mapfilter.sensors.pdr import PDRConfig, Steps, dead_reckon, detect_steps, imu_trace, wrap_angle
from mapfilter.sensors.recording import Recording

SHARED = Path(__file__).resolve().parents[2].parent / "shared" / "data"
DATA = SHARED / "ilc20" / "site1"
IPIN_LOGS = SHARED / "ipin2023" / "logs"
FIXED_STEP_M = 0.7  # the filter's initial per-particle step length (FilterConfig.initial_step_length_m)
TURN_MIN_DEG = 30.0  # a leg pair whose directions differ by more is a "turn"
TOLERANCE_DEG = 20.0
TOLERANCE_DIST = 0.10
LONG_LEG_M = 5.0  # turns between two legs at least this long: the legs' directions are a fair reference


def pdr_signals(recording: Recording, config: PDRConfig) -> tuple[Steps, np.ndarray, np.ndarray, np.ndarray]:
    """The steps, and the grid times, gyro heading and rotation-vector heading (NaN where none
    yet) the detector saw."""
    trace = imu_trace(recording, config)
    return detect_steps(recording, config), trace.t_s, trace.heading_rad, trace.abs_heading_rad


def waypoints_m(recording: Recording) -> np.ndarray:
    """The ground truth in metres: as the log has it, or (IPIN) on the tangent plane at its first point."""
    if recording.waypoint_latlon_deg is not None and np.isnan(recording.waypoint_xy_m).all():
        return LocalFrame(*recording.waypoint_latlon_deg[0]).to_xy_m(recording.waypoint_latlon_deg)
    return recording.waypoint_xy_m


def trace_numbers(path: Path, config: PDRConfig) -> dict | str:
    """The numbers of one log, or why it has none (too few waypoints, no usable IMU)."""
    recording = read_log(path)
    if recording.waypoint_t_s.shape[0] < 2:
        return f"{path}: fewer than 2 waypoints"
    try:
        steps, grid_t_s, heading, abs_heading = pdr_signals(recording, config)
    except MapfilterError as exc:
        return str(exc)
    wp_t, wp_xy = recording.waypoint_t_s, waypoints_m(recording)
    legs = np.diff(wp_xy, axis=0)
    polyline_m = float(np.sum(np.linalg.norm(legs, axis=1)))
    in_span = (steps.t_s > wp_t[0]) & (steps.t_s <= wp_t[-1])

    # turns: leg direction change vs gyro heading change between leg middles
    leg_dir = np.arctan2(legs[:, 1], legs[:, 0])
    leg_mid_t = 0.5 * (wp_t[:-1] + wp_t[1:])
    gyro_at_mid = np.interp(leg_mid_t, grid_t_s, heading)
    turn_true = np.degrees(wrap_angle(np.diff(leg_dir)))
    turn_gyro = np.degrees(np.diff(gyro_at_mid))
    turn_err = np.degrees(wrap_angle(np.radians(turn_gyro - turn_true)))
    leg_m = np.linalg.norm(legs, axis=1)
    # the rotation vector's turn at the same times: an independent check of the gyro (it fuses
    # the magnetometer too) that does not assume the walker went straight between waypoints
    known = np.isfinite(abs_heading)
    turn_rotvec_err = np.full(turn_true.shape, np.nan)
    if known.sum() >= 2:
        turn_rotvec = np.degrees(np.diff(np.interp(leg_mid_t, grid_t_s[known], np.unwrap(abs_heading[known]))))
        turn_rotvec_err = np.degrees(wrap_angle(np.radians(turn_gyro - turn_rotvec)))

    # absolute heading offset per leg (steps in the middle half of each leg; legs >= 3 m)
    offsets = []
    if steps.abs_heading_rad is not None:
        for i in range(legs.shape[0]):
            if np.linalg.norm(legs[i]) < 3.0:
                continue
            span = wp_t[i + 1] - wp_t[i]
            sel = (steps.t_s > wp_t[i] + 0.25 * span) & (steps.t_s < wp_t[i + 1] - 0.25 * span)
            sel &= np.isfinite(steps.abs_heading_rad)
            if np.any(sel):
                d = steps.abs_heading_rad[sel] - leg_dir[i]
                offsets.append(float(np.angle(np.mean(np.exp(1j * d)))))
    # PDR only from the first waypoint (Weinberg lengths, default K): no ground truth after the start
    pdr_err = {}
    first = steps.between(wp_t[0], wp_t[-1])
    if steps.abs_heading_rad is not None and len(first) and np.isfinite(first.abs_heading_rad).all():
        for name, use_abs in (("gyro", False), ("rotvec", True)):
            t_track, xy_track = dead_reckon(steps, wp_xy[0], float(first.abs_heading_rad[0]),
                                            start_t_s=float(wp_t[0]), use_abs_heading=use_abs)
            at = np.column_stack([np.interp(wp_t, t_track, xy_track[:, j]) for j in range(2)])
            pdr_err[name] = np.linalg.norm(at - wp_xy, axis=1)[1:].tolist()
    group = "IPIN2023" if recording.waypoint_latlon_deg is not None else path.parent.parent.name
    return {
        "trace": f"{group}/{recording.name}",
        "pdr_only_err_m": pdr_err,
        "polyline_m": polyline_m,
        "duration_s": float(wp_t[-1] - wp_t[0]),
        "n_steps": int(np.sum(in_span)),
        "steps_per_s": float(np.sum(in_span) / (wp_t[-1] - wp_t[0])),
        "delay_s": (steps.available_s - steps.t_s).tolist(),
        "weinberg_m": float(np.sum(steps.step_length_m[in_span])),
        "weinberg_unit_sum": float(np.sum(steps.weinberg_unit[in_span])),
        "turn_true_deg": turn_true.tolist(),
        "turn_gyro_deg": turn_gyro.tolist(),
        "turn_err_deg": turn_err.tolist(),
        "turn_shorter_leg_m": np.minimum(leg_m[:-1], leg_m[1:]).tolist(),
        "turn_gyro_minus_rotvec_deg": turn_rotvec_err.tolist(),
        "abs_offset_rad": offsets,
    }


def summarise(rows: list[dict], config: PDRConfig) -> dict:
    poly = np.array([r["polyline_m"] for r in rows])
    n = np.array([r["n_steps"] for r in rows], dtype=float)
    unit = np.array([r["weinberg_unit_sum"] for r in rows])
    # leave-one-trace-out calibration: the trace under test never informs its own K / length
    k_loo = (poly.sum() - poly) / (unit.sum() - unit)
    len_loo = (poly.sum() - poly) / (n.sum() - n)
    ratios = {
        "fixed": n * FIXED_STEP_M / poly,
        "weinberg": np.array([r["weinberg_m"] for r in rows]) / poly,
        "weinberg_loo": k_loo * unit / poly,
        "fixed_loo": len_loo * n / poly,
    }
    for r, i in zip(rows, range(len(rows))):
        for name, values in ratios.items():
            r[f"ratio_{name}"] = float(values[i])
    dist = {name: {"median_ratio": float(np.median(v)),
                   "p10_ratio": float(np.percentile(v, 10)), "p90_ratio": float(np.percentile(v, 90)),
                   "share_within_10pct": float(np.mean(np.abs(v - 1) <= TOLERANCE_DIST))}
            for name, v in ratios.items()}
    true = np.concatenate([r["turn_true_deg"] for r in rows])
    err = np.concatenate([r["turn_err_deg"] for r in rows])
    turn = np.abs(true) >= TURN_MIN_DEG
    long_legs = turn & (np.concatenate([r["turn_shorter_leg_m"] for r in rows]) >= LONG_LEG_M)
    vs_rotvec = np.concatenate([r["turn_gyro_minus_rotvec_deg"] for r in rows])[turn]
    vs_rotvec = vs_rotvec[np.isfinite(vs_rotvec)]
    offsets = np.concatenate([r["abs_offset_rad"] for r in rows])
    offset_mean = np.angle(np.mean(np.exp(1j * offsets)))
    offset_dev = np.degrees(np.abs(wrap_angle(offsets - offset_mean)))
    pdr_only = {}
    for name in ("gyro", "rotvec"):
        e = np.concatenate([r["pdr_only_err_m"].get(name, []) for r in rows])
        if e.size:
            pdr_only[name] = {"n_waypoints": int(e.size), "mean_m": float(e.mean()), "median_m": float(np.median(e)),
                              "p75_m": float(np.percentile(e, 75)), "p90_m": float(np.percentile(e, 90))}
    per_floor = {}
    for floor in sorted({r["trace"].split("/")[0] for r in rows}):
        of = [r for r in rows if r["trace"].startswith(floor + "/")]
        f_true = np.concatenate([r["turn_true_deg"] for r in of])
        f_err = np.concatenate([r["turn_err_deg"] for r in of])
        f_turn = np.abs(f_true) >= TURN_MIN_DEG
        per_floor[floor] = {
            "n_traces": len(of),
            **{f"share_within_10pct_{name}": float(np.mean([abs(r[f"ratio_{name}"] - 1) <= TOLERANCE_DIST for r in of]))
               for name in ratios},
            "n_turns": int(np.sum(f_turn)),
            "share_turns_within_20deg": float(np.mean(np.abs(f_err[f_turn]) <= TOLERANCE_DEG)),
        }
    delay = np.concatenate([r["delay_s"] for r in rows])
    rate = np.array([r["steps_per_s"] for r in rows])
    return {
        "n_traces": len(rows),
        "steps_per_s": {"median": float(np.median(rate)), "min": float(rate.min()), "max": float(rate.max())},
        "available_after_step_s": {"median": float(np.median(delay)), "p90": float(np.percentile(delay, 90)),
                                   "max": float(delay.max())},
        "per_floor": per_floor,
        "pdr_only": pdr_only,
        "config": dataclasses.asdict(config),
        "weinberg_k_all": float(poly.sum() / unit.sum()),
        "weinberg_k_loo_range": [float(k_loo.min()), float(k_loo.max())],
        "fixed_length_all_m": float(poly.sum() / n.sum()),
        "distance": dist,
        "turns": {
            "n_leg_pairs": int(true.size),
            "n_turns": int(np.sum(turn)),
            "turn_min_deg": TURN_MIN_DEG,
            "share_turns_within_20deg": float(np.mean(np.abs(err[turn]) <= TOLERANCE_DEG)),
            "share_all_pairs_within_20deg": float(np.mean(np.abs(err) <= TOLERANCE_DEG)),
            "median_abs_err_turns_deg": float(np.median(np.abs(err[turn]))),
            "long_leg_m": LONG_LEG_M,
            "n_turns_long_legs": int(np.sum(long_legs)),
            "share_turns_long_legs_within_20deg": float(np.mean(np.abs(err[long_legs]) <= TOLERANCE_DEG)),
            "share_turns_gyro_vs_rotvec_within_20deg": float(np.mean(np.abs(vs_rotvec) <= TOLERANCE_DEG)),
            "median_abs_gyro_vs_rotvec_deg": float(np.median(np.abs(vs_rotvec))),
        },
        "abs_heading": {
            "n_legs": int(offsets.size),
            "offset_deg": float(np.degrees(offset_mean)),
            "median_abs_dev_deg": float(np.median(offset_dev)),
            "share_legs_within_20deg": float(np.mean(offset_dev <= TOLERANCE_DEG)),
        },
    }


def markdown(rows: list[dict], summary: dict) -> str:
    out = ["| trace | polyline m | s | steps | steps/s | fixed | Weinberg | Weinberg LOO | fixed LOO | turns ok |",
           "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in rows:
        err = np.abs(np.array(r["turn_err_deg"]))
        turn = np.abs(np.array(r["turn_true_deg"])) >= TURN_MIN_DEG
        out.append(f"| {r['trace']} | {r['polyline_m']:.1f} | {r['duration_s']:.0f} | {r['n_steps']} "
                   f"| {r['steps_per_s']:.2f} "
                   f"| {r['ratio_fixed']:.2f} | {r['ratio_weinberg']:.2f} | {r['ratio_weinberg_loo']:.2f} "
                   f"| {r['ratio_fixed_loo']:.2f} | {int(np.sum(err[turn] <= TOLERANCE_DEG))}/{int(np.sum(turn))} |")
    out += ["", "| step length | median ratio | 10th pct | 90th pct | traces within +/-10 % |",
            "| --- | ---: | ---: | ---: | ---: |"]
    for name, d in summary["distance"].items():
        out.append(f"| {name} | {d['median_ratio']:.3f} | {d['p10_ratio']:.3f} | {d['p90_ratio']:.3f} "
                   f"| {100 * d['share_within_10pct']:.0f} % |")
    out += ["", "| floor | traces | within +/-10 %: fixed / Weinberg / Weinberg LOO / fixed LOO | turns | turns within 20 deg |",
            "| --- | ---: | --- | ---: | ---: |"]
    for floor, f in summary["per_floor"].items():
        shares = " / ".join(f"{100 * f[f'share_within_10pct_{n}']:.0f} %" for n in summary["distance"])
        out.append(f"| {floor} | {f['n_traces']} | {shares} | {f['n_turns']} | {100 * f['share_turns_within_20deg']:.0f} % |")
    t, a = summary["turns"], summary["abs_heading"]
    rate, late = summary["steps_per_s"], summary["available_after_step_s"]
    out += ["",
            f"Steps per second between the first and last waypoint: median {rate['median']:.2f} "
            f"({rate['min']:.2f}-{rate['max']:.2f}); a step was known {1000 * late['median']:.0f} ms after it "
            f"(median; 90th pct {1000 * late['p90']:.0f} ms, max {1000 * late['max']:.0f} ms).",
            f"Turns (leg pairs turning >= {t['turn_min_deg']:.0f} deg): {t['n_turns']}, within 20 deg: "
            f"{100 * t['share_turns_within_20deg']:.0f} % (median |error| {t['median_abs_err_turns_deg']:.1f} deg); "
            f"all {t['n_leg_pairs']} leg pairs within 20 deg: {100 * t['share_all_pairs_within_20deg']:.0f} %; "
            f"turns between legs >= {t['long_leg_m']:.0f} m: {t['n_turns_long_legs']}, within 20 deg: "
            f"{100 * t['share_turns_long_legs_within_20deg']:.0f} %.",
            f"Gyro turn vs rotation-vector turn at the same times: median |difference| "
            f"{t['median_abs_gyro_vs_rotvec_deg']:.1f} deg, within 20 deg on "
            f"{100 * t['share_turns_gyro_vs_rotvec_within_20deg']:.0f} % of the turns.",
            f"Rotation-vector heading minus leg direction over {a['n_legs']} legs: offset "
            f"{a['offset_deg']:.1f} deg, median |deviation| {a['median_abs_dev_deg']:.1f} deg, "
            f"{100 * a['share_legs_within_20deg']:.0f} % of legs within 20 deg of the offset.",
            *[f"PDR only from the first waypoint, heading from {name} (start: rotation vector), "
              f"Weinberg lengths: error at the other {d['n_waypoints']} waypoints mean {d['mean_m']:.2f} m, "
              f"median {d['median_m']:.2f} m, 75th pct {d['p75_m']:.2f} m, 90th pct {d['p90_m']:.2f} m."
              for name, d in summary["pdr_only"].items()],
            f"Weinberg K over all traces {summary['weinberg_k_all']:.3f} (LOO range "
            f"{summary['weinberg_k_loo_range'][0]:.3f}-{summary['weinberg_k_loo_range'][1]:.3f}); "
            f"fitted fixed length {summary['fixed_length_all_m']:.3f} m."]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.splitlines()[0])
    parser.add_argument("traces", nargs="*", type=Path,
                        help="ILC traces or IPIN logs (default: all of ILC site1 F1 and F2)")
    parser.add_argument("--ipin", action="store_true", help=f"the IPIN 2023 logs in {IPIN_LOGS} instead")
    parser.add_argument("--json", type=Path, help="write per-trace numbers and the summary here")
    parser.add_argument("--threshold", type=float, default=PDRConfig.step_threshold_mps3,
                        help="step threshold on the filtered d|a|/dt, m/s^3 (sensitivity checks)")
    parser.add_argument("--min-interval", type=float, default=PDRConfig.min_step_interval_s,
                        help="minimum step interval, s (sensitivity checks)")
    args = parser.parse_args(argv)
    where = IPIN_LOGS if args.ipin else DATA
    found = IPIN_LOGS.glob("*.txt.gz") if args.ipin else DATA.glob("F*/path_data_files/*.txt.gz")
    traces = args.traces or sorted(found)
    if not traces:
        print(f"no traces found under {where}", file=sys.stderr)
        return 1
    try:
        config = PDRConfig(step_threshold_mps3=args.threshold, min_step_interval_s=args.min_interval)
        rows, skipped = [], []
        for path in traces:
            numbers = trace_numbers(path, config)
            (skipped if isinstance(numbers, str) else rows).append(numbers)
    except (MapfilterError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    if skipped:
        print(f"skipped {len(skipped)} log{'s' if len(skipped) > 1 else ''} (first: {skipped[0]})", file=sys.stderr)
    if not rows:
        print("error: no log with waypoints and a usable IMU", file=sys.stderr)
        return 1
    summary = summarise(rows, config)
    print(markdown(rows, summary))
    print()
    print(json.dumps(summary, indent=1))
    if args.json:
        from mapfilter.io.atomic import atomic_paths
        with atomic_paths(args.json) as (tmp,):
            Path(tmp).write_text(json.dumps({"summary": summary, "traces": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
