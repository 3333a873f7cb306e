"""A building at a floor's cost: one ILC site 1 walk (5dda5247, F2, 201 filter steps) tracked on
the five-floor building with the building's radio map, and on its own floor with the floor's
radio map (both without the walk), in one process, causal and offline.

    .venv/bin/python tools/bench_building.py [--repeats 3]     # about a minute

The maps and radio maps are made here (``map import-ilc``, ``radiomap build``). Each track is
timed after one warm-up (the radio-map likelihood's tables and the kernels loaded: what every
walk after the first pays; the warm-up's own CPU time is the first walk's); the best of the
repeats, in CPU seconds and wall seconds; and for the causal tracks one more run with timers
round the parts that differ between a building and a floor (``PARTS``). Prints one JSON with the
building's time over the floor's (docs/benchmarks.md).
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import mapfilter as mf  # noqa: E402
from mapfilter.cli import main as cli  # noqa: E402
from mapfilter.config import TrackingConfig  # noqa: E402

SITE1 = REPO.parent / "shared" / "data" / "ilc20" / "site1"
WALK = "5dda5247c5b77e0006b176fb"


def _best(function, repeats: int) -> tuple[float, float, float]:
    """(best CPU s, best wall s, the warm-up's CPU s: a first walk's, radio-map likelihoods built)."""
    c0 = time.process_time()
    function()  # warm-up: tables and kernels
    first = time.process_time() - c0
    cpu, wall = [], []
    for _ in range(repeats):
        c0, t0 = time.process_time(), time.perf_counter()
        function()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - t0)
    return min(cpu), min(wall), first


# where a causal track's time goes: (module, attribute path, label); a part inside another's call
# counts in both (the step holds the estimate's walk round walls), a part inside itself once
PARTS = (("mapfilter.filter.evidence", "BuildingEvidence.add_scans", "evidence"),
         ("mapfilter.filter.evidence", "WifiEvidence.add_scans", "evidence"),
         ("mapfilter.filter.particle_filter", "ParticleFilter.step", "filter step"),
         ("mapfilter.filter.particle_filter", "toward", "of it: the estimate's walk round walls"),
         ("mapfilter.filter.models.building", "FloorChanges.change_floors", "of it: floor changes"),
         ("mapfilter.filter.models.building", "FloorFixLikelihood.log_likelihood", "of it: the floor fix likelihood"))


def _parts(function) -> dict[str, float]:
    """CPU seconds of each of ``PARTS`` in one more run of ``function`` (timers around them)."""
    import importlib

    spent: dict[str, float] = {}
    depth: dict[str, int] = {}
    undo = []
    for module_name, path, label in PARTS:
        owner = importlib.import_module(module_name)
        *outer, name = path.split(".")
        for attribute in outer:
            owner = getattr(owner, attribute)
        original = owner.__dict__[name]

        def timed(*args, _original=original, _label=label, **kwargs):
            depth[_label] = depth.get(_label, 0) + 1
            c0 = time.process_time()
            try:
                return _original(*args, **kwargs)
            finally:
                depth[_label] -= 1
                if depth[_label] == 0:
                    spent[_label] = spent.get(_label, 0.0) + time.process_time() - c0

        setattr(owner, name, functools.wraps(original)(timed))
        undo.append((owner, name, original))
    c0 = time.process_time()
    try:
        function()
    finally:
        for owner, name, original in reversed(undo):
            setattr(owner, name, original)
    spent["whole track (timers on)"] = time.process_time() - c0
    return {label: round(value, 3) for label, value in spent.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore")  # the logs' skipped-row warnings
    walk = SITE1 / "F2" / "path_data_files" / f"{WALK}.txt.gz"
    if not walk.is_file():
        print(f"bench_building: the ILC data is not at {SITE1} (tools/get_data.py, docs/data.md)", file=sys.stderr)
        return 1
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        every = [str(p) for p in sorted(SITE1.glob("*/path_data_files/*.txt.gz")) if p.name != walk.name]
        own = [p for p in every if "/F2/" in p]
        assert cli(["map", "import-ilc", str(SITE1), "--out", str(work / "site1.yaml")]) == 0
        assert cli(["radiomap", "build", str(work / "site1.yaml"), *every, "--out", str(work / "site1.npz")]) == 0
        assert cli(["radiomap", "build", str(work / "site1_F2.yaml"), *own, "--out", str(work / "F2.npz")]) == 0
        building, floor = mf.load_map(work / "site1.yaml"), mf.load_map(work / "site1_F2.yaml")
        building_map, floor_map = mf.load_radio_map(work / "site1.npz"), mf.load_radio_map(work / "F2.npz")
        on_building, on_floor = mf.read_log(walk, building=building), mf.read_log(walk, building=floor)
        rows = {}
        for smooth in (False, True):
            config = TrackingConfig(seed=1, smooth=smooth)
            for name, where, radio_map, recording in (("floor", floor, floor_map, on_floor),
                                                      ("building", building, building_map, on_building)):
                run = functools.partial(mf.track, where, recording, radio_map=radio_map, config=config)
                cpu, wall, first = _best(run, args.repeats)
                row = {"cpu_s": round(cpu, 3), "wall_s": round(wall, 3), "first_walk_cpu_s": round(first, 3)}
                if not smooth:
                    row["parts_cpu_s"] = _parts(run)
                rows[f"{name}, {'offline' if smooth else 'causal'}"] = row
                print(f"{name} {'offline' if smooth else 'causal'}: {cpu:.2f} s CPU, {wall:.2f} s", file=sys.stderr)
    ratio = {"building over floor, causal (CPU)": round(rows["building, causal"]["cpu_s"] / rows["floor, causal"]["cpu_s"], 2),
             "building, offline over causal (CPU)": round(rows["building, offline"]["cpu_s"]
                                                          / rows["building, causal"]["cpu_s"], 2)}
    print(json.dumps({"walk": WALK, "load_before": load_before, "load_after": os.getloadavg()[0], "tracks": rows,
                      "ratios": ratio}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
