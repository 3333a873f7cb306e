"""Particle-filter throughput benchmark: particle-steps per second, the filter's step against references.

For N = 1k, 10k, 100k, 1M particles on an ILC floor map (site1/F1 from ../shared) and on
the bundled map maps/office.yaml, it times

- ``wall_check``: ``mapfilter.maps.walls.crosses_wall`` alone on random-walk moves;
- ``step``: ``ParticleFilter.step`` with random-walk motion + wall check + a 20-access-point
  RSSI Gaussian likelihood + resampling (forced every step) + wall-safe regularisation + estimate;
- ``reference_step``: the same step in plain numpy (points sampled every half pixel along each
  segment for the wall check, float32 numpy RSSI likelihood, cumsum + searchsorted resampling);
- with ``--baseline REV``: the same step by the filter of an earlier revision of this repository
  (a temporary git worktree, run in a child process that imports that revision's package, not the
  installed one, and times its own steps; its default path at that N, or the path
  ``--baseline-config`` names), one step of each in turn;
- ``one_thread`` (from 100,000 particles, on a machine with more than one CPU): the same step on
  one thread (``MAPFILTER_THREADS=1``), for what the threads buy;

and the speed-ups over the references, one step of each in turn, in the same run, each rate with the
share of the particles that the step's wall check kills (``killed_per_step_share``: a real map's
outside is wall, and the kills are where the step works hardest).

It also times what a user feels (``--skip-user`` leaves it out):

- ``first_run``: the README's first command (``mapfilter track maps/office.yaml ... --smooth``)
  as after a fresh install (``NUMBA_CACHE_DIR`` pointed at a new folder that ``mapfilter.runtime.warmup``,
  the install's compile, filled; timed too), then again (warm), and once with an empty cache
  (every kernel compiles: the cost the install's compile saves);
- ``help``: ``mapfilter --help`` and ``mapfilter track --help``;
- ``real_walk``: one real ILC site1/F1 walk of about a minute (not one of the sparse set's
  walks), 10,000 particles, with the sparse (36 walks, ``sparse_set.txt``) and the dense
  (all 76 walks) F1 radio maps, built here with ``mapfilter radiomap build`` (timed too): the
  tracker's own time (``mapfilter.track``) for the first walk with a radio map (which builds
  its likelihood) and for a walk after it (which reuses it), and the whole ``mapfilter track``
  command (one walk: builds it), with the ratio of the command's time to the tracking time it
  prints.

Every step time comes with the CPU time the process used for it (``cpu_ms``): on a shared
machine, the wall time moves with the other jobs; the CPU time much less.

Prints one JSON document. ``--quick`` runs fewer repetitions and skips 1M for the reference.
Usage: ``.venv/bin/python tools/bench_filter.py [--quick] [--maps ilc,office] [--skip-user] [--baseline REV]``
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import platform
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from mapfilter.filter.estimate import weighted_moments  # noqa: E402
from mapfilter.filter.models.interface import MeasurementModel  # noqa: E402
from mapfilter.filter.models.motion import RandomWalkMotion  # noqa: E402
from mapfilter.filter.models.path_loss import path_loss_kernel  # noqa: E402
from mapfilter.filter.particle_filter import FilterConfig, ParticleFilter, optimal_bandwidth  # noqa: E402
from mapfilter.maps.floorplan import FloorPlan  # noqa: E402
from mapfilter.maps.walls import crosses_wall  # noqa: E402
from mapfilter.runtime.threads import n_threads  # noqa: E402

ILC_FLOOR = REPO.parent / "shared" / "data" / "ilc20" / "site1" / "F1"
OFFICE_YAML = REPO / "maps" / "office.yaml"
# 58.6 s of WiFi scans, 119 PDR steps; not in sparse_set.txt (so not in the sparse radio map)
REAL_WALK = "5dd9e7d1c5b77e0006b17343"
README_TRACK = ["track", "maps/office.yaml", "maps/office_walk.txt.gz", "--radiomap", "maps/office_radiomap.npz",
                "--smooth"]
N_APS = 20
DT_S = 1.0
VARIANCE_DB2 = 25.0


# ---- maps ------------------------------------------------------------------------------------
def load_ilc_map() -> tuple[FloorPlan, str]:
    try:
        from mapfilter.maps.prepare import import_ilc
        return import_ilc(ILC_FLOOR), "mapfilter.maps.prepare.import_ilc(site1/F1)"
    except ImportError:
        import json as _json

        import cv2
        info = _json.loads((ILC_FLOOR / "floor_info.json").read_text())["map_info"]
        rgba = cv2.imread(str(ILC_FLOOR / "floor_image.png"), cv2.IMREAD_UNCHANGED)
        wall = rgba[..., 3] > 0  # transparent = corridor
        return FloorPlan(wall, info["width"] / wall.shape[1]), "alpha threshold of site1/F1 floor_image.png"


def load_office_map() -> tuple[FloorPlan, str]:
    if OFFICE_YAML.is_file():
        return FloorPlan.load(OFFICE_YAML), "maps/office.yaml"
    wall = np.zeros((200, 300), dtype=bool)
    wall[[0, -1], :] = True
    wall[:, [0, -1]] = True
    wall[100, :] = True
    wall[100, 140:160] = False
    for c in range(50, 300, 50):
        wall[:100, c] = True
        wall[40:50, c] = False
    return FloorPlan(wall, 0.1), "synthetic office stand-in"


# ---- the measurement used by both implementations -------------------------------------------
class RssiModel(MeasurementModel):
    """20 access points with the thesis path-loss model; the numba kernel."""

    def __init__(self, ap_xy_m: np.ndarray) -> None:
        k = ap_xy_m.shape[0]
        self.ap_xy_m = ap_xy_m
        self.c_dbm = np.full(k, -38.0)
        self.n = np.full(k, 2.0)
        self.alpha = np.full(k, 0.4)
        self.d_max = np.full(k, 30.0)

    def expected(self, xy_m: np.ndarray) -> np.ndarray:
        d = np.maximum(np.linalg.norm(xy_m[:, None, :] - self.ap_xy_m[None], axis=-1), 1.0)
        return self.c_dbm - 10 * self.n * np.log10(d) - self.alpha * np.minimum(d, self.d_max)

    def kernel(self, observed_rssi_dbm: np.ndarray):
        return path_loss_kernel(self.ap_xy_m, self.c_dbm, self.n, self.alpha, self.d_max, observed_rssi_dbm,
                                VARIANCE_DB2)


# ---- plain-numpy reference ---------------------------------------------------------------------
def numpy_crosses(fp: FloorPlan, a_xy: np.ndarray, b_xy: np.ndarray) -> np.ndarray:
    """Sample points every half pixel along each segment (misses corner clips)."""
    uv_a = fp.world_to_pixel(a_xy)
    uv_b = fp.world_to_pixel(b_xy)
    length_px = np.abs(uv_b - uv_a).max(axis=1)
    n_samples = int(min(np.ceil(length_px.max() * 2.0) + 1, 2000)) if length_px.size else 1
    h, w = fp.wall_mask.shape
    out = np.zeros(a_xy.shape[0], dtype=bool)
    for s in np.linspace(0.0, 1.0, max(n_samples, 2)):
        uv = uv_a + s * (uv_b - uv_a)
        cols = np.floor(uv[:, 0]).astype(np.int64)
        rows = np.floor(uv[:, 1]).astype(np.int64)
        inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
        hit = ~inside
        hit[inside] = fp.wall_mask[rows[inside], cols[inside]]
        out |= hit
    return out


def numpy_rssi_ll(xy_m: np.ndarray, model: RssiModel, observed: np.ndarray) -> np.ndarray:
    f32 = np.float32
    d = np.linalg.norm(xy_m.astype(f32)[:, None, :] - model.ap_xy_m.astype(f32)[None], axis=-1)
    d = np.maximum(d, f32(1.0))
    pred = model.c_dbm.astype(f32) - f32(10) * model.n.astype(f32) * np.log10(d) \
        - model.alpha.astype(f32) * np.minimum(d, model.d_max.astype(f32))
    r = observed.astype(f32) - pred
    return -(r * r).sum(axis=1).astype(np.float64) / (2 * VARIANCE_DB2)


class NumpyReferenceFilter:
    """The same step as ParticleFilter with the configuration used here, in plain numpy."""

    def __init__(self, fp: FloorPlan, xy_m: np.ndarray, rng: np.random.Generator) -> None:
        self.fp = fp
        self.xy = xy_m.copy()
        self.log_w = np.full(xy_m.shape[0], -math.log(xy_m.shape[0]))
        self.rng = rng

    def step(self, model: RssiModel, observed: np.ndarray) -> None:
        n = self.xy.shape[0]
        rng = self.rng
        phi = rng.uniform(0, 2 * math.pi, n)
        new = self.xy + 1.5 * DT_S * np.stack([np.cos(phi), np.sin(phi)], 1) + 0.5 * DT_S * rng.standard_normal((n, 2))
        log_w = self.log_w.copy()
        log_w[numpy_crosses(self.fp, self.xy, new)] = -np.inf
        log_w = log_w + numpy_rssi_ll(new, model, observed)
        if not np.isfinite(log_w).any():
            log_w = np.zeros(n)
        log_w -= np.logaddexp.reduce(log_w[np.isfinite(log_w)])
        w = np.exp(log_w)
        cumsum = np.cumsum(w)
        cumsum[-1] = 1.0
        parent = np.minimum(np.searchsorted(cumsum, (np.arange(n) + rng.random()) / n, side="right"), n - 1)
        cov = weighted_moments(new, w)[1] + self.fp.resolution_m ** 2 * np.eye(2)
        root = np.linalg.cholesky(cov)
        h = optimal_bandwidth(n)
        base = new[parent]
        origin = self.xy[parent]
        out = base.copy()
        pending = np.arange(n)
        for _ in range(3):
            cand = base[pending] + h * (rng.standard_normal((pending.size, 2)) @ root.T)
            ok = ~numpy_crosses(self.fp, base[pending], cand) & ~numpy_crosses(self.fp, origin[pending], cand)
            out[pending[ok]] = cand[ok]
            pending = pending[~ok]
        self.xy = out
        self.log_w = np.full(n, -math.log(n))
        w = np.exp(self.log_w)
        mean = w @ self.xy
        _ = self.fp.is_free(mean[None])


# ---- timing ----------------------------------------------------------------------------------
def timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def timed_cpu(fn) -> tuple[float, float]:
    """(wall s, CPU s of this process, every thread) of one call."""
    t0, c0 = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - t0, time.process_time() - c0


def per_step_seconds(fn, reps: int) -> float:
    """Median wall time of ``reps`` calls (after one warm-up call)."""
    fn()
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


THREADS_FROM = 100_000  # particle counts from which the step is also timed on one thread


@contextlib.contextmanager
def _threads(count: int):
    """``MAPFILTER_THREADS`` set to ``count`` inside the block (the kernels read it at every call)."""
    before = os.environ.get("MAPFILTER_THREADS")
    os.environ["MAPFILTER_THREADS"] = str(count)
    try:
        yield
    finally:
        if before is None:
            del os.environ["MAPFILTER_THREADS"]
        else:
            os.environ["MAPFILTER_THREADS"] = before


def _pf(fp: FloorPlan, n: int, true_xy: np.ndarray, seed: int) -> ParticleFilter:
    # the filter starts around the truth so that the cloud is realistic (not map-wide)
    pf = ParticleFilter(fp, RandomWalkMotion(), FilterConfig(n_particles=n, resample_ess_fraction=1.0),
                        np.random.default_rng(seed))
    pf.initialise_around(true_xy, 5.0)
    return pf


# The baseline: the same setup and step in an earlier revision's filter, in a child process that
# times its own steps (a step per line asked on stdin, "wall_s cpu_s resampled killed" answered).
# ``BASELINE_CONFIG`` is a dict of FilterConfig settings the revision knows (e.g. its fused path).
_BASELINE_CHILD = r"""
import json, sys, time
# the revision's own package, not the one installed in editable mode (whose finder comes first)
sys.meta_path[:] = [f for f in sys.meta_path if not getattr(f, "__module__", "").startswith("__editable__")]
sys.path.insert(0, sys.argv[1])
sys.path.insert(0, sys.argv[1] + "/tools")
import numpy as np
import mapfilter
if not mapfilter.__file__.startswith(sys.argv[1]):
    raise SystemExit(f"the baseline imported {mapfilter.__file__}, not the revision's package in {sys.argv[1]}")
import bench_filter as b
try:
    from mapfilter.filter.particle_filter import FilterConfig, ParticleFilter
    from mapfilter.filter.models.motion import RandomWalkMotion
except ImportError:  # a revision before the filter's modules were renamed
    from mapfilter.filter.pf import FilterConfig, ParticleFilter
    from mapfilter.filter.motion import RandomWalkMotion
key, n, seed, extra = sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), json.loads(sys.argv[5])
fp, _ = {"ilc": b.load_ilc_map, "office": b.load_office_map}[key]()
rng = np.random.default_rng(seed)
model = b.RssiModel(fp.sample_free(b.N_APS, rng))
true_xy = fp.sample_free(1, rng)
observed = model.expected(true_xy)[0] + rng.normal(0, 5.0, b.N_APS)
pf = ParticleFilter(fp, RandomWalkMotion(), FilterConfig(n_particles=n, resample_ess_fraction=1.0, **extra),
                    np.random.default_rng(seed))
pf.initialise_around(true_xy[0], 5.0)
pf.step(0.0, b.DT_S, None, model, observed)
print("ready", flush=True)
for line in sys.stdin:
    t0, c0 = time.perf_counter(), time.process_time()
    report = pf.step(0.0, b.DT_S, None, model, observed)
    print(time.perf_counter() - t0, time.process_time() - c0, int(report.resampled), report.n_killed, flush=True)
"""


class Baseline:
    """An earlier revision's filter step, timed in a child process (see ``_BASELINE_CHILD``)."""

    def __init__(self, checkout: Path, key: str, n: int, seed: int, config: dict) -> None:
        self.process = subprocess.Popen([sys.executable, "-c", _BASELINE_CHILD, str(checkout), key, str(n), str(seed),
                                         json.dumps(config)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                        text=True, cwd=checkout)
        if self.process.stdout.readline().strip() != "ready":
            raise RuntimeError("the baseline child did not start")
        self.last: tuple[float, float, int, int] | None = None

    def step(self) -> None:
        self.process.stdin.write("step\n")
        self.process.stdin.flush()
        wall, cpu, resampled, killed = self.process.stdout.readline().split()
        self.last = (float(wall), float(cpu), int(resampled), int(killed))

    def close(self) -> None:
        self.process.stdin.close()
        self.process.wait(timeout=60)


def _summary(name: str, row: dict) -> str:
    """One line of a map's row: each step's rate with its kill share, then the ratios."""
    def rate(label: str) -> str:
        return (f"{label} {row[f'{label}_step_per_s'] / 1e6:.3g} M/s ({row[f'{label}_step_ms']:.3g} ms, "
                f"CPU {row[f'{label}_step_cpu_ms']:.3g} ms)")
    parts = [f"{name} N={row['n_particles']}: {rate('step')}, kill share {row['killed_per_step_share']:.3f}"]
    parts += [rate(label) for label in ("one_thread", "reference") if f"{label}_step_per_s" in row]
    if "baseline_step_per_s" in row:
        parts.append(f"{rate('baseline')}, kill share {row['baseline_killed_per_step_share']:.3f}")
    for other in ("reference", "baseline"):
        if f"speedup_vs_{other}" in row:
            parts.append(f"step/{other} {row[f'speedup_vs_{other}']:.3g}x (CPU {row[f'speedup_vs_{other}_cpu']:.3g}x)")
    if "speedup_vs_reference_one_thread_cpu" in row:
        parts.append(f"one thread/reference CPU {row['speedup_vs_reference_one_thread_cpu']:.3g}x")
    return "; ".join(parts)


def bench_map(fp: FloorPlan, name: str, sizes: list[int], reps: int, ref_max_n: int, seed: int,
              baseline: Path | None = None, baseline_config: dict | None = None) -> dict:
    """Per N: the wall check alone; then the step, the numpy reference (and the baseline revision's
    step), one step of each in turn (so that all see the same load), from the same cloud."""
    rng = np.random.default_rng(seed)
    ap_xy = fp.sample_free(N_APS, rng)
    model = RssiModel(ap_xy)
    true_xy = fp.sample_free(1, rng)
    observed = model.expected(true_xy)[0] + rng.normal(0, 5.0, N_APS)
    rows = []
    for n in sizes:
        row: dict = {"n_particles": n}
        a = fp.sample_free(n, rng)
        moved = a + rng.normal(0.0, 1.5 * DT_S / math.sqrt(2.0), a.shape)
        t = per_step_seconds(lambda: crosses_wall(fp, a, moved), reps)
        row["wall_check_per_s"] = n / t
        row["wall_check_crossing_share"] = float(crosses_wall(fp, a, moved).mean())

        pf = _pf(fp, n, true_xy[0], seed)
        stats = {"resampled": 0, "steps": 0, "killed": 0}

        def step(pf=pf, stats=stats):
            report = pf.step(0.0, DT_S, None, model, observed)
            stats["resampled"] += report.resampled
            stats["steps"] += 1
            stats["killed"] += report.n_killed

        step()  # warm-up at this size
        runs: dict = {"step": step}
        if n_threads() > 1 and n >= THREADS_FROM:
            # the same step on one thread (same seed: the same particles whatever the threads)
            single = _pf(fp, n, true_xy[0], seed)

            def one_thread(single=single):
                with _threads(1):
                    single.step(0.0, DT_S, None, model, observed)

            one_thread()
            runs["one_thread"] = one_thread
        if n <= ref_max_n:
            ref = NumpyReferenceFilter(fp, _pf(fp, n, true_xy[0], seed).particles.xy_m, np.random.default_rng(seed))
            runs["reference"] = lambda: ref.step(model, observed)
            runs["reference"]()
        child = Baseline(baseline, name, n, seed, baseline_config or {}) if baseline is not None else None
        n_rounds = reps if n < 1_000_000 else max(3, reps // 3)
        times: dict = {label: ([], []) for label in [*runs, *(["baseline"] if child else [])]}
        baseline_killed = 0
        for _ in range(n_rounds):
            for label, fn in runs.items():
                wall, cpu = timed_cpu(fn)
                times[label][0].append(wall)
                times[label][1].append(cpu)
            if child is not None:
                child.step()
                times["baseline"][0].append(child.last[0])
                times["baseline"][1].append(child.last[1])
                baseline_killed += child.last[3]
        if child is not None:
            child.close()
        for label, (walls, cpus) in times.items():
            t_wall, t_cpu = float(np.median(walls)), float(np.median(cpus))
            row[f"{label}_step_per_s"] = n / t_wall
            row[f"{label}_step_ms"] = 1e3 * t_wall
            row[f"{label}_step_cpu_ms"] = 1e3 * t_cpu
        for other in ("reference", "baseline"):
            if other in times:
                row[f"speedup_vs_{other}"] = row[f"{other}_step_ms"] / row["step_step_ms"]
                row[f"speedup_vs_{other}_cpu"] = row[f"{other}_step_cpu_ms"] / row["step_step_cpu_ms"]
        if "one_thread" in times:
            row["threads"] = n_threads()
            row["speedup_of_threads"] = row["one_thread_step_ms"] / row["step_step_ms"]
            if "reference" in times:
                row["speedup_vs_reference_one_thread_cpu"] = (row["reference_step_cpu_ms"]
                                                              / row["one_thread_step_cpu_ms"])
        row["resampled_share"] = stats["resampled"] / stats["steps"]
        row["killed_per_step_share"] = stats["killed"] / stats["steps"] / n
        if child is not None:
            row["baseline_killed_per_step_share"] = baseline_killed / n_rounds / n
        rows.append(row)
        print(_summary(name, row), file=sys.stderr, flush=True)
    return {"map": name, "shape_px": list(fp.wall_mask.shape), "resolution_m": fp.resolution_m,
            "free_fraction": fp.free_fraction, "results": rows}


# ---- what a user feels: first run, --help, a real walk ------------------------------------------
def _children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _mapfilter(args: list[str], env: dict | None = None, cwd: Path = REPO) -> tuple[float, float, str]:
    """(wall s, CPU s, stdout) of ``python -m mapfilter ARGS`` in a fresh process; raises on failure.

    The CPU time (user + system, all threads) moves much less with the machine's load than
    the wall time; for a process that mostly runs one thread (start-up, numba compiling) it
    is about what the wall time would be on a quiet machine.
    """
    t0, c0 = time.perf_counter(), _children_cpu_s()
    done = subprocess.run([sys.executable, "-m", "mapfilter", *args], cwd=cwd, env={**os.environ, **(env or {})},
                          capture_output=True, text=True)
    wall, cpu = time.perf_counter() - t0, _children_cpu_s() - c0
    if done.returncode != 0:
        raise RuntimeError(f"mapfilter {' '.join(args)} failed: {done.stderr.strip()[-500:]}")
    return wall, cpu, done.stdout


def bench_first_run(tmp: Path) -> dict:
    """The README's first command as a new user runs it: after the editable install compiled the
    numba kernels (``mapfilter.runtime.warmup``, which ``pip install -e .`` runs) into an empty numba
    cache, then again (warm); and, for the compile's cost, once with no kernel compiled."""
    out_csv = tmp / "office_track.csv"
    installed = {"NUMBA_CACHE_DIR": str(tmp / "numba_cache_installed")}
    t0, c0 = time.perf_counter(), _children_cpu_s()
    subprocess.run([sys.executable, "-m", "mapfilter.runtime.warmup"], env={**os.environ, **installed}, check=True,
                   capture_output=True)
    install_s, install_cpu_s = time.perf_counter() - t0, _children_cpu_s() - c0
    first_s, first_cpu_s, stdout = _mapfilter(README_TRACK + ["--out", str(out_csv)], installed)
    warm_s, warm_cpu_s, _ = _mapfilter(README_TRACK + ["--out", str(out_csv)], installed)
    uncompiled_s, uncompiled_cpu_s, _ = _mapfilter(README_TRACK + ["--out", str(out_csv)],
                                                   {"NUMBA_CACHE_DIR": str(tmp / "numba_cache_empty")})
    # "...; causal 9.8 s, offline 6.8 s": the causal filter run and the offline track
    tracker_s = re.search(r"causal ([0-9.]+) s, offline ([0-9.]+) s", stdout)
    return {"command": "mapfilter " + " ".join(README_TRACK) + " --out office_track.csv",
            "install_compile_s": install_s, "install_compile_cpu_s": install_cpu_s,
            "cold_s": first_s, "cold_cpu_s": first_cpu_s, "warm_s": warm_s, "warm_cpu_s": warm_cpu_s,
            "cold_over_warm_cpu": first_cpu_s / warm_cpu_s,
            "without_install_compile_s": uncompiled_s, "without_install_compile_cpu_s": uncompiled_cpu_s,
            "tracker_s_as_printed": (float(tracker_s.group(1)) + float(tracker_s.group(2))) if tracker_s else None,
            "numba_cache_dir": "new empty folders (NUMBA_CACHE_DIR): one the install's compile filled, one not"}


def bench_help(reps: int = 3) -> dict:
    """Median wall and CPU seconds of ``mapfilter --help`` and ``mapfilter track --help``."""
    out = {}
    for args in (["--help"], ["track", "--help"]):
        runs = [_mapfilter(args)[:2] for _ in range(reps)]
        out[" ".join(args)] = {"wall_s": float(np.median([r[0] for r in runs])),
                               "cpu_s": float(np.median([r[1] for r in runs]))}
    return out


def bench_real_walk(tmp: Path) -> dict:
    """One real F1 walk of about a minute with the sparse and the dense radio maps (10,000 particles)."""
    from mapfilter.sensors.ilc import read_ilc
    from mapfilter.sensors.radiomap import RadioMap
    from mapfilter.config import TrackingConfig
    from mapfilter.pipeline.tracker import track

    logs_dir = ILC_FLOOR / "path_data_files"
    sparse = [logs_dir / f"{name}.txt.gz" for name in (ILC_FLOOR / "sparse_set.txt").read_text().split()]
    dense = sorted(logs_dir.glob("*.txt.gz"))
    walk = logs_dir / f"{REAL_WALK}.txt.gz"
    map_yaml = tmp / "F1.yaml"
    _mapfilter(["map", "import-ilc", str(ILC_FLOOR), "--route", "geojson", "--out", str(map_yaml)])
    floorplan = FloorPlan.load(map_yaml)
    recording = read_ilc(walk)
    doc: dict = {"walk": REAL_WALK, "wifi_span_s": float(recording.wifi.t_s[-1] - recording.wifi.t_s[0]),
                 "n_particles": TrackingConfig().filter.n_particles, "radio_maps": {}}
    for name, logs in (("sparse", sparse), ("dense", dense)):
        rm_path = tmp / f"F1_{name}.npz"
        build_s, build_cpu_s, _ = _mapfilter(["radiomap", "build", str(map_yaml), *map(str, logs),
                                              "--out", str(rm_path)])
        radio_map = RadioMap.load(rm_path)
        # the first walk builds the radio-map likelihood (once per radio map); the walks after it reuse it
        c0 = time.process_time()
        first = track(floorplan, recording, radio_map, config=TrackingConfig())
        first_cpu_s = time.process_time() - c0
        c0 = time.process_time()
        result = track(floorplan, recording, radio_map, config=TrackingConfig())
        track_cpu_s = time.process_time() - c0
        command_s, command_cpu_s, stdout = _mapfilter(["track", str(map_yaml), str(walk), "--radiomap", str(rm_path),
                                                       "--out", str(tmp / f"track_{name}.csv")])
        printed = re.search(r"causal ([0-9.]+) s", stdout)
        doc["radio_maps"][name] = {"walks": len(logs), "reference_points": len(radio_map),
                                   "access_points": len(radio_map.ap_keys), "radiomap_build_s": build_s,
                                   "radiomap_build_cpu_s": build_cpu_s,
                                   "track_recording_first_walk_s": first.runtime_s,
                                   "track_recording_first_walk_cpu_s": first_cpu_s,
                                   "track_recording_s": result.runtime_s,
                                   "track_recording_cpu_s": track_cpu_s, "filter_steps": result.n_filter_steps,
                                   "track_command_s": command_s, "track_command_cpu_s": command_cpu_s,
                                   "tracking_s_as_printed": float(printed.group(1)) if printed else None,
                                   "command_over_printed_tracking": command_s / float(printed.group(1))
                                   if printed else None}
        print(f"real walk, {name} map: " + ", ".join(f"{k}={v:.4g}" for k, v in doc["radio_maps"][name].items()),
              file=sys.stderr, flush=True)
    return doc


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="few repetitions, no 1M reference run")
    parser.add_argument("--maps", default="ilc,office", help="comma list of: ilc, office")
    parser.add_argument("--sizes", default="1000,10000,100000,1000000", help="particle counts")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--skip-user", action="store_true", help="leave out the first run, --help and the real walk")
    parser.add_argument("--baseline", metavar="REV", help="also time the step of this git revision (e.g. the commit "
                                                          "before the filter was rebuilt)")
    parser.add_argument("--baseline-config", default="{}", help="FilterConfig settings of the baseline, as JSON")
    args = parser.parse_args(argv)
    sizes = [int(s) for s in args.sizes.split(",")]
    reps = 5 if args.quick else 15
    ref_max_n = 100_000 if args.quick else 1_000_000

    load_before = os.getloadavg()[0]
    # warm up numba (compile or load from cache) before any timing
    t0 = time.perf_counter()
    warm_fp = FloorPlan(np.zeros((8, 8), dtype=bool), 1.0)
    warm = ParticleFilter(warm_fp, RandomWalkMotion(), FilterConfig(n_particles=64, resample_ess_fraction=1.0),
                          np.random.default_rng(0))
    warm.initialise_uniform()
    warm_model = RssiModel(np.array([[1.0, 1.0], [6.0, 6.0]]))
    warm.step(0.0, 1.0, None, warm_model, np.array([-40.0, -50.0]))
    warmup_s = time.perf_counter() - t0

    user: dict = {}
    if not args.skip_user:
        with tempfile.TemporaryDirectory(prefix="bench_filter_") as tmp:
            user["first_run"] = bench_first_run(Path(tmp))
            print(f"first run: {user['first_run']}", file=sys.stderr, flush=True)
            user["help_s"] = bench_help()
            print(f"help: {user['help_s']}", file=sys.stderr, flush=True)
            user["real_walk"] = bench_real_walk(Path(tmp))

    loaders = {"ilc": load_ilc_map, "office": load_office_map}
    maps = []
    with contextlib.ExitStack() as stack:
        checkout = None
        if args.baseline:
            checkout = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="bench_baseline_"))) / "repo"
            subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", str(checkout), args.baseline],
                           check=True, capture_output=True)
            stack.callback(subprocess.run, ["git", "-C", str(REPO), "worktree", "remove", "--force", str(checkout)],
                           capture_output=True)
            (checkout.parent / "shared").symlink_to(REPO.parent / "shared")  # its ../shared
        for key in args.maps.split(","):
            fp, source = loaders[key]()
            maps.append({"source": source, **bench_map(fp, key, sizes, reps, ref_max_n, args.seed, checkout,
                                                       json.loads(args.baseline_config))})
    import numba

    doc = {
        "unit": "particle-steps per second (median step time; full step forces resampling every step); "
                "*_cpu_ms: CPU time of the process (all threads) for one step",
        "machine": {"cpus": os.cpu_count(), "kernel_threads": n_threads(),
                    "python": platform.python_version(), "numpy": np.__version__, "numba": numba.__version__},
        "numba_warmup_s": warmup_s,
        "load_average_1min_before_after": [load_before, os.getloadavg()[0]],
        "quick": args.quick,
        "baseline": {"revision": args.baseline, "config": json.loads(args.baseline_config)} if args.baseline else None,
        **user,
        "maps": maps,
    }
    print(json.dumps(doc, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
