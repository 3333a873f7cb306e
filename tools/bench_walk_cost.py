"""A walk's cost against the radio map's size: one ILC F1 walk tracked three times in one process
with the sparse (36 walks), the dense (all F1 walks but this one) and a grown radio map (the
sparse one grown from the other 39 walks, their waypoints unread).

    .venv/bin/python tools/bench_walk_cost.py [--jobs 2]     # about 2 minutes with --jobs 2

Prints, per radio map, its size and the tracker's CPU seconds for the first walk (which builds
the radio-map likelihood, once per radio map) and the two after it (docs/benchmarks.md).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import warnings
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import mapfilter as mf  # noqa: E402
from mapfilter.maps.prepare import import_ilc  # noqa: E402

F1 = REPO.parent / "shared" / "data" / "ilc20" / "site1" / "F1"
WALK = "5dd9e7d1c5b77e0006b17343"  # 58.6 s of WiFi, not in sparse_set.txt (as in bench_filter.py)


def main() -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--jobs", type=int, default=1, help="Dask worker processes for the growing")
    args = parser.parse_args()
    warnings.simplefilter("ignore")  # the logs' skipped-row warnings
    logs = F1 / "path_data_files"
    sparse_names = (F1 / "sparse_set.txt").read_text().split()
    with tempfile.TemporaryDirectory() as tmp:
        import_ilc(F1, route="geojson").save(Path(tmp) / "F1.yaml")
        building = mf.load_map(Path(tmp) / "F1.yaml")
        sparse = [mf.read_log(logs / f"{name}.txt.gz") for name in sparse_names]
        others = [mf.read_log(path) for path in sorted(logs.glob("*.txt.gz"))
                  if path.name[:-len(".txt.gz")] not in sparse_names and path.name[:-len(".txt.gz")] != WALK]
        radio_maps = {"sparse": mf.build_radio_map(building, sparse), "dense": mf.build_radio_map(building, sparse + others)}
        started = time.perf_counter()
        radio_maps["grown"], _ = mf.grow_radio_map(building, radio_maps["sparse"], others, jobs=args.jobs)
        print(f"grown from {len(others)} walks: {len(radio_maps['sparse'])} -> {len(radio_maps['grown'])} points "
              f"in {time.perf_counter() - started:.0f} s", flush=True)
        walk = mf.read_log(logs / f"{WALK}.txt.gz")
        for name, radio_map in radio_maps.items():
            cpu_s = []
            for _ in range(3):
                c0 = time.process_time()
                mf.track(building, walk, radio_map=radio_map)
                cpu_s.append(time.process_time() - c0)
            print(f"{name}: {len(radio_map)} points, {len(radio_map.ap_keys)} APs; tracker CPU s, walks 1-3: "
                  + ", ".join(f"{s:.2f}" for s in cpu_s), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
