#!/usr/bin/env python3
"""Seconds the drawing reader takes per plan at a given size, on one core: plans of the held-out
seed drawn at each size (2.25 megapixels: a 1,500 x 1,500 px drawing; 8.75: a 3,500 x 2,500 px
scan), each read by `mapfilter map prepare` (defaults, in this process) after one warm-up run;
the median and the largest of the runs are printed. Run it on a quiet machine, single-threaded:

    OMP_NUM_THREADS=1 MAPFILTER_THREADS=1 .venv/bin/python tools/plans/reader_speed.py --count 6
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import plangen  # noqa: E402

SIZES_MPX = (2.25, 8.75)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    parser.add_argument("--count", type=int, default=6, help="plans per size (default: 6)")
    parser.add_argument("--seed", type=int, default=plangen.HELD_OUT_SEED)
    args = parser.parse_args(argv)
    from mapfilter.cli import main as cli_main

    cv2.setNumThreads(1)
    with tempfile.TemporaryDirectory() as folder:
        for megapixels in SIZES_MPX:
            times, shapes = [], []
            for index, seed in enumerate(plangen.plan_seeds(args.seed, args.count)):
                plan = plangen.generate_plan(seed, plangen.style_of(index), megapixels=megapixels)
                image = plangen.write_plan(plan, Path(folder), f"p{index}")
                command = ["map", "prepare", str(image), "--resolution", repr(plan.resolution_m),
                           "--out", str(Path(folder) / f"p{index}_map.yaml")]
                with contextlib.redirect_stdout(io.StringIO()):
                    if not times:
                        cli_main(command)  # warm-up: imports and caches
                    started = time.perf_counter()
                    code = cli_main(command)
                    times.append(time.perf_counter() - started)
                if code != 0:
                    print(f"plan {index} at {megapixels:g} Mpx was refused", flush=True)
                shapes.append(plan.image.shape[:2])
            rows, cols = np.median(np.array(shapes), axis=0)
            print(f"{megapixels:g} Mpx (about {cols:.0f} x {rows:.0f} px): median {np.median(times):.2f} s, "
                  f"largest {max(times):.2f} s over {len(times)} plans", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
