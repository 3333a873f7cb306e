"""Compare particle-filter settings on the real ILC walks (leave-one-trace-out), several seeds.

How the tracking defaults were chosen. Each setting is a JSON object of dotted ``TrackingConfig``
settings (``mapfilter config show`` lists them; a constant that used to be a setting is refused,
docs/accuracy.md); the KWNN fixes of the same walks are the reference. Example:

    .venv/bin/python tools/experiments/tune_ilc.py --floor F1 --seeds 1 2 3 \\
        '{"wifi.fix_sigma_m": 5}' '{"wifi.fix_sigma_m": 15}' '{"motion.pdr.heading_sigma_rad": 0.05}'
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from mapfilter.evaluation.comparison import AllWalks, EvaluationSetup, evaluate_trace  # noqa: E402
from mapfilter.evaluation.metrics import format_table, summarise_errors  # noqa: E402
from mapfilter.maps.prepare import import_ilc  # noqa: E402
from mapfilter.sensors.ilc import read_ilc  # noqa: E402
from mapfilter.sensors.radiomap import build_radio_map  # noqa: E402
from mapfilter.config import TrackingConfig  # noqa: E402
from mapfilter.maps.building import Building  # noqa: E402

ILC = REPO.parent / "shared" / "data" / "ilc20" / "site1"


def config_from_json(text: str) -> TrackingConfig:
    """A JSON object of dotted settings, e.g. ``{"motion.pdr.heading_sigma_rad": 0.03}``."""
    return TrackingConfig().override(json.loads(text))


def main() -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("settings", nargs="*", default=["{}"], help="JSON object of dotted TrackingConfig settings ({} = defaults)")
    parser.add_argument("--floor", default="F1")
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--every", type=int, default=1, help="use every k-th walk (1 = all)")
    args = parser.parse_args()

    floor_dir = ILC / args.floor
    building = Building.from_plan(import_ilc(floor_dir, route="geojson"))
    paths = sorted((floor_dir / "path_data_files").glob("*.txt.gz"))[:: args.every]
    all_walks = AllWalks(build_radio_map([read_ilc(p) for p in sorted((floor_dir / "path_data_files").glob("*.txt.gz"))]), None)
    rows = []
    for text in args.settings:
        config = config_from_json(text)
        for seed in args.seeds:
            started = time.perf_counter()
            errors: dict[str, list[float]] = {"pf": [], "kwnn": []}
            for i in range(len(paths)):
                setup = EvaluationSetup(methods=("pf", "kwnn"), leave_one_out=True,
                                        tracking=dataclasses.replace(config, seed=seed))
                for result in evaluate_trace(building, paths, i, setup, all_walks):
                    errors[result.method] += list(result.errors_m)
            pf, kwnn = summarise_errors(errors["pf"]), summarise_errors(errors["kwnn"])
            rows.append({"setting": text, "seed": seed, "pf mean": pf["mean"], "pf p75": pf["p75"],
                         "kwnn mean": kwnn["mean"], "kwnn p75": kwnn["p75"],
                         "mean ratio": pf["mean"] / kwnn["mean"], "p75 ratio": pf["p75"] / kwnn["p75"],
                         "s": time.perf_counter() - started})
            print(json.dumps({k: (round(v, 3) if isinstance(v, float) else v) for k, v in rows[-1].items()}),
                  file=sys.stderr, flush=True)
    print(format_table(rows, list(rows[0])))
    for text in args.settings:
        mine = np.array([r["mean ratio"] for r in rows if r["setting"] == text])
        print(f"{text}: mean ratio {mine.mean():.3f} (seeds {mine.min():.3f}-{mine.max():.3f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
