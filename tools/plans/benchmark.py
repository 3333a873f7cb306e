#!/usr/bin/env python3
"""Score `mapfilter map prepare` (defaults only) on generated floor-plan drawings with exact truth.

Each plan of the set (tools/plans/plangen.py; plan i of a seed is the same whatever the count)
is written as an image, prepared by the command line (`map prepare IMAGE --resolution R --out
MAP.yaml`, in this process), and its mask scored against the truth:

- wall IoU: walls found / (found + missed + spurious), each within 2 px of the other mask,
  inside the building (its walls and its free space; the outside is wall in both);
- connectivity: the share of the free space in the largest 4-connected region, the mask's
  against the truth's;
- rooms reached: of the rooms the truth's largest region reaches (most of a room's pixels in
  it), those whose pixels lie mostly in the mask's largest free region;
- runtime: the command's wall-clock time, and that time scaled to a 1,500 x 1,500 px plan.

Prints a table per wall style, paper, outline shape, feature (bays, window runs, terraces, JPEG)
and image size, writes plans.csv and summary.md to --out.

    nice -n 10 .venv/bin/python tools/plans/benchmark.py --seed 2 --count 300 --jobs 2 --out /tmp/bench
"""

from __future__ import annotations

import argparse
import csv
import json
import multiprocessing
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import plangen  # noqa: E402

TOLERANCE_PX = 2
TARGETS = {"wall_iou": 0.95, "connectivity": 0.03, "rooms": 0.95, "runtime_s": 2.0}
REFERENCE_PX = 1500 * 1500


def tolerant_iou(pred: np.ndarray, true: np.ndarray, region: np.ndarray, tol_px: int = TOLERANCE_PX) -> float:
    """Walls found / (found + missed + spurious), each counted within ``tol_px`` of the other mask
    (true walls near a predicted one are found, predicted walls far from any true one spurious)."""
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * tol_px + 1, 2 * tol_px + 1))
    near_pred = cv2.dilate(pred.astype(np.uint8), disc).astype(bool)
    near_true = cv2.dilate(true.astype(np.uint8), disc).astype(bool)
    found = int((true & region & near_pred).sum())
    missed = int((true & region & ~near_pred).sum())
    spurious = int((pred & region & ~near_true).sum())
    total = found + missed + spurious
    return found / total if total else 1.0


def _largest(free: np.ndarray) -> tuple[float, np.ndarray]:
    """(share of the free space in the largest 4-connected region, that region)."""
    count, labels, stats, _ = cv2.connectedComponentsWithStats(free.astype(np.uint8), connectivity=4)
    if count <= 1:
        return 0.0, np.zeros_like(free)
    areas = stats[1:, cv2.CC_STAT_AREA]
    return float(areas.max() / areas.sum()), labels == 1 + int(np.argmax(areas))


def score(wall: np.ndarray, truth_walls: np.ndarray, truth_free: np.ndarray, rooms: np.ndarray,
          room_labels: list[int]) -> dict:
    """The scores of a prepared mask against a plan's truth (see the module docstring)."""
    building = truth_walls | truth_free
    share, region = _largest(~wall)
    truth_share, truth_region = _largest(truth_free)
    reachable = reached = 0
    for label in room_labels:
        room = rooms == label
        if not room.any() or truth_region[room].mean() <= 0.5:
            continue
        reachable += 1
        reached += int(region[room].mean() > 0.5)
    return {"wall_iou": tolerant_iou(wall, truth_walls, building), "connectivity": share,
            "truth_connectivity": truth_share, "rooms_reachable": reachable, "rooms_reached": reached,
            "outside_walled": float(wall[~building].mean()) if (~building).any() else 1.0}


def run_plan(task: tuple[int, int, str]) -> dict:
    """Generate plan ``index`` of ``seed``, prepare it with the command line, score it."""
    seed, index, folder = task
    from mapfilter.cli import main as cli_main
    from mapfilter.maps.floorplan import FloorPlan

    plan = plangen.generate_plan(plangen.plan_seeds(seed, index + 1)[index], plangen.style_of(index))
    work = Path(folder)
    image = plangen.write_plan(plan, work, f"{index:03d}")
    out = work / f"{index:03d}_map.yaml"
    started = time.perf_counter()
    code = cli_main(["map", "prepare", str(image), "--resolution", repr(plan.resolution_m), "--out", str(out)])
    runtime_s = time.perf_counter() - started
    rows, cols = plan.walls.shape
    wall = FloorPlan.load(out).wall_mask if code == 0 else np.ones((rows, cols), bool)
    result = score(wall, plan.walls, plan.free, plan.rooms, [r["label"] for r in plan.room_info])
    for path in work.glob(f"{index:03d}*"):  # the set stays small on disk
        path.unlink()
    result.update(index=index, wall=plan.style.wall, paper=plan.style.paper, outline=plan.features["outline"],
                  bay=plan.features["bay"], window_run=plan.features["window_run"], terrace=plan.features["terrace"],
                  jpeg=bool(plan.style.jpeg_quality), size=size_class(rows * cols), cols=cols, rows=rows,
                  resolution_m=plan.resolution_m, exit_code=code, runtime_s=runtime_s,
                  runtime_1500_s=runtime_s * REFERENCE_PX / (rows * cols))
    return result


SIZES = ((1e6, "under 1 Mpx"), (4e6, "1-4 Mpx"), (float("inf"), "4-9 Mpx"))
FEATURES = ("bay", "window_run", "terrace", "jpeg")


def size_class(pixels: int) -> str:
    return next(name for limit, name in SIZES if pixels < limit)


def summarise(rows: list[dict], key: str) -> list[dict]:
    """One row per value of ``key`` (and one for all): the means, worst cases and targets.
    ``key="feature"``: one row per feature a plan has (bays, window runs, terraces, JPEG)."""
    groups = {"all": rows}
    for row in rows:
        if key == "feature":
            for feature in FEATURES:
                if row[feature]:
                    groups.setdefault(feature.replace("_", " "), []).append(row)
        else:
            groups.setdefault(row[key], []).append(row)
    table = []
    for name, group in groups.items():
        iou = np.array([r["wall_iou"] for r in group])
        error = np.array([abs(r["connectivity"] - r["truth_connectivity"]) for r in group])
        reachable = sum(r["rooms_reachable"] for r in group)
        table.append({"group": name, "plans": len(group), "wall_iou": float(iou.mean()),
                      "wall_iou_p10": float(np.percentile(iou, 10)), "connectivity_error": float(error.mean()),
                      "within_0.03": float((error <= TARGETS["connectivity"]).mean()),
                      "rooms": sum(r["rooms_reached"] for r in group) / max(reachable, 1),
                      "runtime_max_s": max(r["runtime_s"] for r in group),
                      "runtime_1500_max_s": max(r["runtime_1500_s"] for r in group),
                      "failed": sum(r["exit_code"] != 0 for r in group)})
    order = {"all": -1, **{s: i for i, s in enumerate(plangen.WALL_STYLES + plangen.PAPER_STYLES + plangen.OUTLINES
                                                       + tuple(f.replace("_", " ") for f in FEATURES)
                                                       + tuple(name for _, name in SIZES))}}
    return sorted(table, key=lambda t: order.get(t["group"], 99))


def markdown(table: list[dict], title: str) -> str:
    lines = [f"| {title} | plans | wall IoU (mean) | wall IoU (10th pct) | connectivity error (mean) | "
             "plans within 0.03 | rooms reached | runtime max | runtime max at 1,500 px | refused |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for t in table:
        lines.append(f"| {t['group']} | {t['plans']} | {t['wall_iou']:.3f} | {t['wall_iou_p10']:.3f} | "
                     f"{t['connectivity_error']:.3f} | {t['within_0.03']:.0%} | {t['rooms']:.1%} | "
                     f"{t['runtime_max_s']:.2f} s | {t['runtime_1500_max_s']:.2f} s | {t['failed']} |")
    return "\n".join(lines)


def plan_indices(seed: int, count: int, outline: str | None = None) -> list[int]:
    """The indices of the set's plans to score: the first ``count``, or the first ``count`` whose
    outline is ``outline``."""
    if outline is None:
        return list(range(count))
    found: list[int] = []
    batch = 0
    while len(found) < count:
        batch += 1
        seeds = plangen.plan_seeds(seed, 50 * count * batch)
        start = 50 * count * (batch - 1)
        found += [i for i in range(start, len(seeds)) if plangen.outline_of(seeds[i]) == outline]
    return found[:count]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=plangen.HELD_OUT_SEED,
                        help=f"the set's seed (default: {plangen.HELD_OUT_SEED}, held out: the reader is tuned on others)")
    parser.add_argument("--count", type=int, default=300, help="how many plans (default: 300)")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes, at most 2 here (default: 1)")
    parser.add_argument("--outline", choices=plangen.OUTLINES,
                        help="only the plans of this outline's shape: the first COUNT of them in the set")
    parser.add_argument("--out", type=Path, required=True, help="folder for plans.csv and summary.md")
    args = parser.parse_args(argv)
    if args.count < 1 or not 1 <= args.jobs <= 2:
        parser.error("--count must be at least 1 and --jobs 1 or 2")
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as folder:
        tasks = [(args.seed, i, folder) for i in plan_indices(args.seed, args.count, args.outline)]
        rows = []
        with multiprocessing.get_context("spawn").Pool(args.jobs) as pool:
            for done, row in enumerate(pool.imap(run_plan, tasks), 1):
                rows.append(row)
                print(f"[{done}/{args.count}] plan {row['index']:03d} {row['wall']:7s} {row['paper']:6s} {row['outline']:9s} {row['cols']}x{row['rows']} "
                      f"IoU {row['wall_iou']:.3f} connectivity {row['connectivity']:.3f}/"
                      f"{row['truth_connectivity']:.3f} rooms {row['rooms_reached']}/{row['rooms_reachable']} "
                      f"{row['runtime_s']:.2f} s", flush=True)
    with (args.out / "plans.csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    tables = {key: summarise(rows, key) for key in ("wall", "paper", "outline", "feature", "size")}
    command = f"tools/plans/benchmark.py --seed {args.seed} --count {args.count} --jobs {args.jobs}" + \
        (f" --outline {args.outline}" if args.outline else "")
    titles = {"wall": "wall style", "paper": "paper", "outline": "outline", "feature": "plans with", "size": "size"}
    text = "\n\n".join([f"`{command}`"] + [markdown(tables[key], titles[key]) for key in tables])
    (args.out / "summary.md").write_text(text + "\n")
    (args.out / "summary.json").write_text(json.dumps(tables, indent=1))
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
