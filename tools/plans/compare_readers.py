#!/usr/bin/env python3
"""The classical drawing reader against the learned segmenter (tools/plans/train_segmenter.py),
on generated plans of the held-out seed and on the ILC floor images.

``classical``: `mapfilter.maps.drawing.read_drawing` from the strokes alone (``segmenter=False``).
``default``: what `map prepare` runs: the strokes' walls kept within 3 px of the network's.
``network``: the segmenter's walls (its ONNX weights run through OpenCV's ``cv2.dnn``, the
probability resampled to the plan's pixels, wall above one half), then the classical reader's
later steps on them: a sheet frame and text blobs dropped, the building's outline from every
stroke, the outside walled. Scores as tools/plans/benchmark.py (wall IoU within 2 px inside the
building, connectivity error, rooms reached) and seconds per plan. The ILC floors (filled-region
images) are scored against their GeoJSON as tests/maps/test_drawing.py does, by
`map prepare`'s regions reader and by the network.

    nice -n 10 .venv/bin/python tools/plans/compare_readers.py --count 60
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import benchmark  # noqa: E402
import plangen  # noqa: E402

WORK_M = 0.025  # the segmenter's metres per pixel (train_segmenter.WORK_M)


def network_walls(net, gray: np.ndarray, resolution_m: float) -> np.ndarray:
    """The segmenter's wall mask of a drawing, at the drawing's pixels."""
    from mapfilter.maps.drawing import even_paper

    rows, cols = gray.shape
    evened = even_paper(gray, resolution_m)
    factor = resolution_m / WORK_M
    size = (max(8, round(cols * factor)), max(8, round(rows * factor)))
    darkness = cv2.resize((255.0 - evened.astype(np.float32)) / 255.0, size,
                          interpolation=cv2.INTER_AREA if factor < 1 else cv2.INTER_LINEAR)
    r8, c8 = (darkness.shape[0] + 7) // 8 * 8, (darkness.shape[1] + 7) // 8 * 8
    padded = np.zeros((r8, c8), np.float32)
    padded[:darkness.shape[0], :darkness.shape[1]] = darkness
    net.setInput(padded[None, None])
    logit = net.forward()[0, 0, :darkness.shape[0], :darkness.shape[1]]
    return cv2.resize(logit, (cols, rows), interpolation=cv2.INTER_LINEAR) > 0.0


def network_reading(net, gray: np.ndarray, resolution_m: float) -> np.ndarray:
    """The network's walls finished by the classical reader's later steps (the outline, the outside walled)."""
    from mapfilter.maps import drawing

    wall = network_walls(net, gray, resolution_m)
    wall = drawing._drop_frames(wall, resolution_m)
    wall, _ = drawing._drop_text_blobs(wall, resolution_m, None)
    evened = drawing.even_paper(gray, resolution_m)
    ink = evened <= drawing.ink_threshold(evened)
    inside, outer_gaps = drawing.building_footprint(wall, resolution_m, drawing.DrawingOptions().outline_gap_m, ink)
    return drawing._drop_outer_slivers(wall | outer_gaps | ~inside, inside, resolution_m)


MAX_NETWORK_PIXELS = 16e6  # the network's input at its 2.5 cm pixels: larger is no drawing it was made for


def ilc_scores(net, ilc_site: Path) -> list[dict]:
    """Wall IoU (2 px) against the GeoJSON floor of the ILC F1 and F2 images, per reader."""
    from mapfilter.maps import prepare
    from mapfilter.maps.prepare import PlanScale

    found = []
    for floor in ("F1", "F2"):
        floor_dir = ilc_site / floor
        width_m, height_m = prepare.read_ilc_floor_info(floor_dir)
        prepared = prepare.prepare_plan(floor_dir / "floor_image.png", PlanScale(size_m=(width_m, height_m)))
        plan = prepared.plan
        truth = prepare.prepare_geojson(floor_dir / "geojson_map.json", plan.resolution_m, "lonlat", 0.0)
        rows, cols = np.indices(plan.shape_px)
        xy = plan.pixel_to_world(np.stack([cols + 0.5, rows + 0.5], axis=-1).reshape(-1, 2))
        true_wall = ~truth.is_free(xy).reshape(plan.shape_px)
        everywhere = np.ones_like(true_wall)
        bgra = prepare.read_plan_image(floor_dir / "floor_image.png")
        gray = cv2.cvtColor(prepare._flatten_on_white(bgra), cv2.COLOR_BGR2GRAY)
        scaled = gray.size * (plan.resolution_m / WORK_M) ** 2
        network = (benchmark.tolerant_iou(network_reading(net, gray, plan.resolution_m), true_wall, everywhere)
                   if scaled <= MAX_NETWORK_PIXELS else float("nan"))
        found.append({"floor": floor, "classical": benchmark.tolerant_iou(plan.wall_mask, true_wall, everywhere),
                      "network": network, "network_pixels": scaled})
    return found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    parser.add_argument("--onnx", type=Path, default=Path(__file__).resolve().parents[2] / "mapfilter" / "maps" / "data"
                        / "segmenter.onnx", help="the segmenter's weights (default: the package's)")
    parser.add_argument("--seed", type=int, default=plangen.HELD_OUT_SEED)
    parser.add_argument("--count", type=int, default=60)
    parser.add_argument("--ilc-site", type=Path, default=Path("../shared/data/ilc20/site1"))
    parser.add_argument("--no-ilc", action="store_true", help="the generated plans only")
    args = parser.parse_args(argv)
    from mapfilter.maps import drawing

    cv2.setNumThreads(1)
    net = cv2.dnn.readNetFromONNX(str(args.onnx))
    rows_by_reader: dict[str, list[dict]] = {"classical": [], "network": [], "default": []}
    for index, seed in enumerate(plangen.plan_seeds(args.seed, args.count)):
        plan = plangen.generate_plan(seed, plangen.style_of(index))
        gray = plan.image if plan.image.ndim == 2 else cv2.cvtColor(plan.image, cv2.COLOR_BGR2GRAY)
        if plan.jpeg is not None:
            gray = cv2.imdecode(np.frombuffer(plan.jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
        for reader in rows_by_reader:
            started = time.perf_counter()
            if reader == "classical":
                wall = drawing.read_drawing(gray, plan.resolution_m, drawing.DrawingOptions(segmenter=False)).wall
            elif reader == "network":
                wall = network_reading(net, gray, plan.resolution_m)
            else:
                wall = drawing.read_drawing(gray, plan.resolution_m).wall
            row = benchmark.score(wall, plan.walls, plan.free, plan.rooms, [r["label"] for r in plan.room_info])
            row.update(index=index, wall=plan.style.wall, paper=plan.style.paper, runtime_s=time.perf_counter() - started,
                       runtime_1500_s=0.0, exit_code=0)
            rows_by_reader[reader].append(row)
        print(f"[{index + 1}/{args.count}] " + "  ".join(
            f"{reader} IoU {rows[-1]['wall_iou']:.3f} error {abs(rows[-1]['connectivity'] - rows[-1]['truth_connectivity']):.3f}"
            for reader, rows in rows_by_reader.items()), flush=True)
    for reader, rows in rows_by_reader.items():
        print(f"\n{reader}\n" + benchmark.markdown(benchmark.summarise(rows, "wall"), "wall style"))
    if (args.ilc_site / "F1").is_dir() and not args.no_ilc:
        print("\n| ILC floor | classical (regions reader) | network |\n| --- | --- | --- |")
        for row in ilc_scores(net, args.ilc_site):
            print(f"| {row['floor']} | {row['classical']:.3f} | " + (f"{row['network']:.3f} |" if row["network"] == row["network"]
                  else f"not run: {row['network_pixels'] / 1e6:.0f} M pixels at 2.5 cm |"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
