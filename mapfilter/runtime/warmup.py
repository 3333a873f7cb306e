"""Compile the numba kernels once, into numba's cache beside the sources (``cache=True``).

Compiling every kernel takes about 15 s of CPU; loading them from the cache, a fraction of a
second. The editable install runs this module (the in-tree build backend in ``build_backend/``),
so a user's first command loads the kernels instead of compiling them. ``python -m
mapfilter.runtime.warmup`` does it again, e.g. after numba was upgraded (its cache is per numba version
and per CPU; a stale entry is simply compiled again on first use) or after the sources changed. It
first removes the package's numba cache files: numba checks a cached kernel against its own
source file only, so a kernel whose file did not change but which calls a changed kernel of
another module would load stale from its cache (a pulled checkout, an upgraded install).

The work is a small simulated office (two rooms, a door, six access points): a survey and a walk
written as an ILC log and read back, a radio map, then the walk tracked by
each motion and fingerprint model and by trilateration, with the offline track, and a walk in a
building of two such floors, so that every kernel a command can reach gets compiled with the
argument types the commands use.
"""

from __future__ import annotations

import dataclasses
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["clear_kernel_cache", "compile_kernels"]


def _office_plan():
    from mapfilter.maps.floorplan import FloorPlan

    wall = np.zeros((160, 200), dtype=bool)  # 20 m x 16 m at 0.1 m
    wall[:2, :] = wall[-2:, :] = wall[:, :2] = wall[:, -2:] = True
    wall[:, 98:101] = True
    wall[70:90, 98:101] = False  # the door between the two rooms
    return FloorPlan(wall, 0.1)


def _access_points():
    from mapfilter.sensors.pathloss import AccessPointTable

    xy = np.array([[2.0, 2.0], [18.0, 2.0], [2.0, 14.0], [18.0, 14.0], [9.0, 8.0], [11.0, 8.0]])
    k = len(xy)
    return AccessPointTable([f"02:00:00:00:00:{i:02x}" for i in range(k)], ["2.4"] * k, xy,
                            np.full(k, -40.0), np.full(k, 2.5), np.full(k, 0.5), np.full(k, 60.0))


def compile_kernels(verbose: bool = False) -> float:
    """Run every kernel once on a small simulated walk; returns the seconds it took."""
    from mapfilter.api import build_radio_map, track
    from mapfilter.config import TrackingConfig
    from mapfilter.sensors.logs import read_log
    from mapfilter.simulate.ilc_writer import write_ilc
    from mapfilter.simulate.walk import SimConfig, simulate_walk

    started = time.perf_counter()
    plan, aps = _office_plan(), _access_points()
    with tempfile.TemporaryDirectory(prefix="mapfilter-warmup-") as tmp:
        walk_path, survey_path = Path(tmp) / "walk.txt", Path(tmp) / "survey.txt"
        write_ilc(simulate_walk(plan, aps, SimConfig(duration_s=40.0), np.random.default_rng(1)), walk_path)
        write_ilc(simulate_walk(plan, aps, SimConfig(survey=True, duration_s=None, survey_spacing_m=3.0),
                                np.random.default_rng(2)), survey_path)
        walk, survey = read_log(walk_path), read_log(survey_path)
    radio_map = build_radio_map(plan, [survey])
    base = TrackingConfig(smooth=True).with_particles(500)
    runs = [({"wifi.fingerprint_model": model}, radio_map, None) for model in ("fix", "blend", "likelihood")]
    runs += [({"motion.model": "cv"}, radio_map, None), ({"motion.model": "rw"}, radio_map, None),
             ({}, None, aps)]
    for settings, rm, ap_table in runs:
        track(plan, walk, rm, ap_table, base.override(settings))
        if verbose:
            print(f"mapfilter warm-up: {settings or 'trilateration'} done", file=sys.stderr)
    _building_walk(plan, aps, base)
    if verbose:
        print("mapfilter warm-up: a building's walk done", file=sys.stderr)
    return time.perf_counter() - started


def _building_walk(plan, aps, config) -> None:
    """The office twice, one floor above the other, without connectors (as the ILC buildings are):
    a survey of each floor, then a walk tracked across the floors, causal and offline, for the
    kernels only a building reaches (the floors in the filter's state)."""
    from mapfilter.api import track
    from mapfilter.maps.building import Building, Floor
    from mapfilter.sensors.floor_vote import build_building_radio_map
    from mapfilter.sensors.logs import read_log
    from mapfilter.simulate.building import BuildingSimConfig, simulate_building_survey, simulate_building_walk
    from mapfilter.simulate.ilc_writer import write_ilc
    from mapfilter.simulate.walk import SimConfig

    building = Building([Floor("L0", plan), Floor("L1", plan, elevation_m=4.0)])
    upstairs = dataclasses.replace(aps, bssid=[key.replace("02:00:00:00:00:", "02:00:00:00:01:") for key in aps.bssid])
    tables = {"L0": aps, "L1": upstairs}  # each floor its own access points
    surveys = BuildingSimConfig(walk=SimConfig(survey_spacing_m=3.0, survey_scans_per_point=1))
    walk_config = BuildingSimConfig(walk=SimConfig(), segment_s=(20.0, 20.0))
    with tempfile.TemporaryDirectory(prefix="mapfilter-warmup-") as tmp:
        logs = []
        for i, name in enumerate(building.floor_names):
            write_ilc(simulate_building_survey(building, tables, name, surveys, np.random.default_rng([3, i])),
                      Path(tmp) / f"survey_{name}.txt")
            logs.append(read_log(Path(tmp) / f"survey_{name}.txt"))
        walk, _ = simulate_building_walk(building, tables, "L0", [], walk_config, np.random.default_rng(4))
        write_ilc(walk, Path(tmp) / "walk.txt")
        recording = read_log(Path(tmp) / "walk.txt", building=building)
    radio_map = build_building_radio_map(logs, list(range(len(logs))), building.floor_names)
    track(building, recording, radio_map, None, config)


def clear_kernel_cache(package_dir: Path | None = None) -> int:
    """Remove numba's cache files of the package's kernels (``*.nbi``, ``*.nbc`` in the
    ``__pycache__`` folders beside its sources, where ``cache=True`` writes them; nothing else);
    returns how many were removed."""
    root = Path(__file__).resolve().parents[1] if package_dir is None else Path(package_dir)
    removed = 0
    for cache in root.rglob("__pycache__"):
        for path in [*cache.glob("*.nbi"), *cache.glob("*.nbc")]:
            try:
                path.unlink()
                removed += 1
            except OSError:  # removed by another process first, or a read-only install: left as it is
                pass
    return removed


def main() -> int:
    clear_kernel_cache()  # a kernel calling a changed kernel of another module would load stale
    seconds = compile_kernels(verbose="-v" in sys.argv[1:])
    print(f"mapfilter: numba kernels compiled into their cache in {seconds:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
