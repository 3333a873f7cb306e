#!/usr/bin/env python3
"""Write random floor-plan drawings with their exact truth (tools/plans/plangen.py).

Each plan NNN becomes NNN.png or NNN.jpg (the drawing), NNN_walls.png and NNN_free.png (255 =
wall / free: the truth), NNN_rooms.png (16-bit room labels) and NNN.json (metres per pixel,
style, rooms). Plan i of a seed is the same whatever the count; wall styles go solid, double,
hatched in turn.

    .venv/bin/python tools/plans/generate.py --seed 1 --count 12 --out /tmp/plans
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import plangen  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=1, help="the set's seed (default: 1)")
    parser.add_argument("--count", type=int, default=12, help="how many plans (default: 12)")
    parser.add_argument("--first", type=int, default=0, help="index of the first plan (default: 0)")
    parser.add_argument("--out", type=Path, required=True, help="folder to write into (created)")
    parser.add_argument("--wall", choices=plangen.WALL_STYLES, help="one wall style for all (default: in turn)")
    parser.add_argument("--paper", choices=plangen.PAPER_STYLES, help="one paper for all (default: random)")
    args = parser.parse_args(argv)
    if args.count < 1 or args.first < 0:
        parser.error("--count must be at least 1 and --first at least 0")
    seeds = plangen.plan_seeds(args.seed, args.first + args.count)
    for index in range(args.first, args.first + args.count):
        plan = plangen.generate_plan(seeds[index], args.wall or plangen.style_of(index), args.paper)
        path = plangen.write_plan(plan, args.out, f"{index:03d}")
        rows, cols = plan.walls.shape
        print(f"{path}: {cols}x{rows} px at {plan.resolution_m:.4f} m/px, {plan.style.wall} walls, "
              f"{plan.style.paper} paper, {len(plan.room_info)} rooms, {plan.n_doors} doors", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
