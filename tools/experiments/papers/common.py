"""Shared helpers of the paper-reproduction scripts (``tools/experiments/papers/*.py``).

Everything here works on the bundled office map (``maps/office.yaml``) and on walks made by
``mapfilter.simulate``: a walk is simulated, written in the ILC format to a temporary file
and read back with ``read_ilc``, so the methods see exactly what ``mapfilter track`` would.
Fingerprint databases are built at chosen reference points from the simulator's own
multi-wall path-loss model (``simulate.model_rssi_dbm``) plus its shadowing noise.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

import numpy as np

from mapfilter.evaluation.metrics import errors_at_waypoints, format_table  # noqa: F401 (the paper scripts use common.format_table)
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.sensors.ilc import read_ilc
from mapfilter.sensors.pathloss import AccessPointTable
from mapfilter.sensors.radiomap import RadioMap
from mapfilter.sensors.recording import Recording
from mapfilter.simulate.ilc_writer import write_ilc
from mapfilter.simulate.walk import SimConfig, SimulatedWalk, model_rssi_dbm, simulate_walk
from mapfilter.io.tracks import Track

REPO = Path(__file__).resolve().parents[3]
OFFICE_YAML = REPO / "maps" / "office.yaml"
OFFICE_APS = REPO / "maps" / "office_aps.csv"
DOCS = REPO / "docs" / "papers"


def load_office() -> tuple[FloorPlan, AccessPointTable]:
    """The bundled 35 m x 35 m office and its 14 dual-band access points (28 rows)."""
    return FloorPlan.load(OFFICE_YAML), AccessPointTable.read_csv(OFFICE_APS)


def subset_aps(table: AccessPointTable, bssids: Sequence[str], bands: Sequence[str] = ("2.4", "5")) -> AccessPointTable:
    """The rows of ``table`` whose bssid is in ``bssids`` and band in ``bands``, in table order."""
    keep = np.isin(np.array(table.bssid), [b.lower() for b in bssids]) & np.isin(np.array(table.band), list(bands))
    rows = np.flatnonzero(keep)
    return AccessPointTable([table.bssid[i] for i in rows], [table.band[i] for i in rows], table.xy_m[rows],
                            table.c_dbm[rows], table.n[rows], table.alpha_db_per_m[rows], table.d_max_m[rows])


def office_bssid(k: int) -> str:
    """bssid of the k-th (1-based) AP of ``tools/draw_office.py``: 1-4 corners, 5-8 corridor mid-sides."""
    return f"02:00:00:00:00:{k:02x}"


def office_reference_points(corridor_spacing_m: float = 2.0) -> tuple[np.ndarray, int]:
    """Evennou & Marx's database layout on the bundled office: one reference point in the
    middle of every room (the room labels of ``tools/draw_office.py``: 24 offices and 4 labs)
    and one every ``corridor_spacing_m`` along the centre line of the corridor loop.

    Returns (reference_xy_m (P, 2), number of room points): the rooms come first."""
    sys.path.insert(0, str(REPO / "tools"))
    try:
        import draw_office
    finally:
        sys.path.pop(0)
    _, _, labels = draw_office.office_walls_m()
    rooms = [(x, y) for text, x, y in labels if text.startswith(("R", "LAB"))]
    b0 = draw_office.MARGIN_M
    b1 = b0 + draw_office.BUILDING_M
    lo = b0 + 0.5 * (draw_office.RING_OUT_M + draw_office.RING_IN_M)  # corridor centre line
    hi = b0 + b1 - lo
    side = hi - lo
    n_per_side = int(round(side / corridor_spacing_m))
    along = np.arange(4 * n_per_side) * (side / n_per_side)  # arc length around the loop
    corners = np.array([[lo, lo], [hi, lo], [hi, hi], [lo, hi], [lo, lo]])
    leg = (along // side).astype(int)
    frac = (along - leg * side) / side
    corridor = corners[leg] + frac[:, None] * (corners[leg + 1] - corners[leg])
    return np.vstack([np.array(rooms, dtype=np.float64), corridor]), len(rooms)


def office_in_corridor(xy_m: np.ndarray) -> np.ndarray:
    """True for points inside the corridor loop of the bundled office (between its walls)."""
    sys.path.insert(0, str(REPO / "tools"))
    try:
        import draw_office
    finally:
        sys.path.pop(0)
    xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
    b0, b1 = draw_office.MARGIN_M, draw_office.MARGIN_M + draw_office.BUILDING_M

    def inside(offset_m: float) -> np.ndarray:
        lo, hi = b0 + offset_m, b1 - offset_m
        return np.all((xy > lo) & (xy < hi), axis=1)

    return inside(draw_office.RING_OUT_M) & ~inside(draw_office.RING_IN_M)


def simulate_recording(floorplan: FloorPlan, aps: AccessPointTable, config: SimConfig,
                       seed: int) -> tuple[SimulatedWalk, Recording]:
    """Simulate one walk and read it back through the ILC reader (the path every real log takes)."""
    walk = simulate_walk(floorplan, aps, config, np.random.default_rng(seed))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"walk_{seed}.txt"
        write_ilc(walk, path)
        recording = read_ilc(path)
    return walk, recording


def survey_radio_map(floorplan: FloorPlan, aps: AccessPointTable, reference_xy_m: np.ndarray, scans_per_point: int,
                     rng: np.random.Generator, config: SimConfig = SimConfig()) -> RadioMap:
    """A fingerprint database at ``reference_xy_m``: the mean of ``scans_per_point`` simulated
    scans per point (same multi-wall model, shadowing, rounding and sensitivity as the walks).

    An AP heard in none of a point's scans is NaN there (not heard), as in a real survey.
    """
    ref = np.asarray(reference_xy_m, dtype=np.float64).reshape(-1, 2)
    k_ap = len(aps)
    ap_index = np.tile(np.arange(k_ap), ref.shape[0])
    xy = np.repeat(ref, k_ap, axis=0)
    mean_dbm, _ = model_rssi_dbm(floorplan, aps, ap_index, xy, config)
    mean_dbm = mean_dbm.reshape(ref.shape[0], k_ap)
    noise_db = config.shadowing_sigma_db * rng.standard_normal((scans_per_point, *mean_dbm.shape))
    draws = np.round(mean_dbm[None] + noise_db)
    draws = np.where(draws >= config.sensitivity_dbm, draws, np.nan)
    with np.errstate(invalid="ignore"), _quiet_nanmean():
        rssi = np.nanmean(draws, axis=0)
    return RadioMap(ref, aps.keys, rssi.astype(np.float32), np.zeros(ref.shape[0]), np.zeros(ref.shape[0], np.int64),
                    ["simulated-survey"], floorplan.floor_name)


class _quiet_nanmean:
    """Silence numpy's 'Mean of empty slice' for points where an AP is never heard (NaN is right)."""

    def __enter__(self):
        import warnings
        self._ctx = warnings.catch_warnings()
        self._ctx.__enter__()
        warnings.simplefilter("ignore", RuntimeWarning)

    def __exit__(self, *exc):
        return self._ctx.__exit__(*exc)


def track_errors(track: Track, walk: SimulatedWalk) -> np.ndarray:
    """Causal errors of a track at the walk's ground-truth waypoints (metres)."""
    return errors_at_waypoints(track.t_s, track.xy_m, walk.waypoint_t_s, walk.waypoint_xy_m).errors_m


def run_parallel(func: Callable, items: Iterable, jobs: int, setup: Callable | None = None,
                 setup_args: tuple = ()) -> list:
    """``[func(x) for x in items]``, in ``jobs`` fresh processes when jobs > 1 (order kept).

    Fresh (spawned) processes, never forked ones: a process forked after numba's parallel
    kernels have started their thread pool hangs. Each worker calls ``setup(*setup_args)``
    first (build its own state from seeds) and runs numba single-threaded, so ``jobs``
    workers use ``jobs`` cores. With jobs <= 1 everything runs here, after one ``setup`` call.
    """
    items = list(items)
    if jobs <= 1 or len(items) <= 1:
        if setup is not None:
            setup(*setup_args)
        return [func(x) for x in items]
    ctx = multiprocessing.get_context("spawn")
    with ctx.Pool(jobs, _worker_init, (setup, setup_args)) as pool:
        return pool.map(func, items, chunksize=1)



def _worker_init(setup: Callable | None, setup_args: tuple) -> None:
    # one kernel thread per worker process: the processes already fill the cores
    os.environ["MAPFILTER_THREADS"] = "1"
    if setup is not None:
        setup(*setup_args)


def machine_note(started_s: float, jobs: int) -> str:
    """One line: wall-clock time, processes, CPU count, git commit (for the generated page)."""
    try:
        commit = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True,
                                text=True, check=False).stdout.strip() or "?"
    except OSError:
        commit = "?"
    return (f"Wall-clock {time.perf_counter() - started_s:.0f} s with {jobs} process(es) on {os.cpu_count()} cores "
            f"(shared machine), at commit {commit}.")


def write_page(path: Path | None, text: str) -> None:
    """Print ``text`` and write it to ``path`` (atomically) unless path is None."""
    print(text)
    if path is None:
        return
    from mapfilter.io.atomic import atomic_paths

    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_paths(path) as (tmp,):
        tmp.write_text(text)


def summary_row(name: str, errors_m: np.ndarray, paper: float | str = "", **extra) -> dict:
    """A table row: mean / median / p75 / p90 / max of errors, with the paper's figure beside."""
    e = np.asarray(errors_m, dtype=np.float64)
    row = {"method": name, "paper mean (m)": paper if isinstance(paper, str) else f"{paper:.2f}",
           "mean (m)": float(e.mean()) if e.size else math.nan,
           "median (m)": float(np.median(e)) if e.size else math.nan,
           "p75 (m)": float(np.percentile(e, 75)) if e.size else math.nan,
           "p90 (m)": float(np.percentile(e, 90)) if e.size else math.nan}
    row.update(extra)
    return row


def command_line(script: str, argv: Sequence[str]) -> str:
    """The command that regenerated a page, as typed from the repository root."""
    return " ".join([".venv/bin/python", f"tools/experiments/papers/{script}", *argv])
