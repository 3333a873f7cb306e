"""The memory guard: what a run will allocate, estimated before it allocates, refused when it
cannot fit.

A setting a hundred thousand times too large (``--particles 1e12``, a grid cell of 1e-6 m)
must be one line naming the setting and the figure, not a ``MemoryError`` traceback minutes
later or a machine swapping to a halt. The estimates are deliberately rough (the order of
magnitude is what matters) and are compared with what the process can still get: the
machine's available memory (``MemAvailable``) and the address-space limit (``RLIMIT_AS``),
whichever is smaller.

Call ``check_fits(n_bytes, what)`` with one of the ``*_bytes`` estimates below before the
allocation; ``check_tracking_fits`` does it for a tracking run's settings and map.
"""

from __future__ import annotations

import math
import os
import resource

from mapfilter.errors import MapfilterError

__all__ = ["PARTICLE_BYTES", "available_bytes", "check_fits", "check_tracking_fits", "format_bytes",
           "grid_bytes", "init_samples_bytes", "jobs_bytes", "particle_filter_bytes"]

# A particle's state (x, y, heading, step scale, floor, weight, ...) and the per-step
# temporaries of the filter (proposals, likelihoods, the resampled copy): about 200 bytes per
# particle for each live filter (a first estimate, see docs/robustness.md).
PARTICLE_BYTES = 200
# The causal filter and, with smooth, the offline stage's second filter run at the same time
# as the first's results are kept: two live copies at most.
PARTICLE_COPIES_SMOOTH = 2
INIT_SAMPLE_BYTES = 64  # a candidate drawn from free space at the start: xy, weight, likelihood temporaries
LIKELIHOOD_CELL_BYTES = 100  # a radio-map likelihood grid cell: indices, centre, tree query, masks
MAP_MATCH_CELL_BYTES = 64  # a map-matching grid cell: free mask, counts, forward/backward rows
WORKER_BYTES = 400 << 20  # one local worker process: Python, numpy, numba, the map, a radio map


def format_bytes(n_bytes: float) -> str:
    """``n_bytes`` for a person: 3.1 GiB, 450 MiB, 2.5 EiB."""
    value = float(n_bytes)
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(value) < 1024:
            return f"{value:.3g} {unit}"
        value /= 1024
    return f"{value:.3g} EiB"


def available_bytes() -> int:
    """What this process can still allocate: the machine's available memory, or what the
    address-space limit (``RLIMIT_AS``) leaves above the process's present size, if smaller."""
    available = _meminfo_available()
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        available = min(available, max(soft - _address_space_bytes(), 0))
    return available


def _meminfo_available() -> int:
    try:
        with open("/proc/meminfo") as handle:
            for line in handle:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, AttributeError):
        return 1 << 62  # unknown: no refusal on that account


def _address_space_bytes() -> int:
    try:
        with open("/proc/self/status") as handle:
            for line in handle:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return 0


def check_fits(n_bytes: float, what: str, hint: str = "") -> None:
    """Refuse, in one line with the figures, ``what`` when its estimated ``n_bytes`` do not fit
    in what the process can still allocate (``available_bytes``). ``hint`` says what to do."""
    if not math.isfinite(n_bytes):
        n_bytes = float("inf")
    available = available_bytes()
    if n_bytes > available:
        needed = "an unbounded amount" if math.isinf(n_bytes) else f"about {format_bytes(n_bytes)}"
        raise MapfilterError(f"{what} needs {needed} of memory, more than the {format_bytes(available)} this "
                             f"machine has free" + (f": {hint}" if hint else ""))


def particle_filter_bytes(n_particles: float, copies: int = 1) -> float:
    """The particle filter's memory for ``n_particles`` (``PARTICLE_BYTES`` each, per live copy)."""
    return float(n_particles) * PARTICLE_BYTES * copies


def init_samples_bytes(n_samples: float) -> float:
    """The free-space candidates drawn to start the filter from a measurement."""
    return float(n_samples) * INIT_SAMPLE_BYTES


def grid_bytes(width_m: float, height_m: float, cell_m: float, bytes_per_cell: float) -> float:
    """A grid of ``cell_m`` cells over a ``width_m`` x ``height_m`` area."""
    if not cell_m > 0:
        return float("inf")
    return math.ceil(max(width_m, cell_m) / cell_m) * math.ceil(max(height_m, cell_m) / cell_m) * float(bytes_per_cell)


def jobs_bytes(jobs: int) -> float:
    """``jobs`` local worker processes (``WORKER_BYTES`` each)."""
    return float(jobs) * WORKER_BYTES


def check_tracking_fits(config, extents_m: list[tuple[float, float, float, float]] | None = None,
                        uses_radio_map_likelihood: bool = True) -> None:
    """A tracking run's settings against the memory there is: the particles, the start's
    candidates and, given the floors' extents ``(x0, x1, y0, y1)``, the grids of the radio-map
    likelihood and of map matching. ``config`` is a ``TrackingConfig``."""
    copies = PARTICLE_COPIES_SMOOTH if config.smooth else 1
    n = config.filter.n_particles
    check_fits(particle_filter_bytes(n, copies), f"the particle filter with {n} particles (filter.n_particles, "
               "--particles)", "use fewer particles (10000 track a walk well)")
    samples = config.filter.init_samples
    check_fits(init_samples_bytes(samples), f"filter.init_samples {samples}", "use fewer (the default is 50000)")
    for x0, x1, y0, y1 in extents_m or []:
        width, height = x1 - x0, y1 - y0
        if uses_radio_map_likelihood:
            cell = config.wifi.radio_map_likelihood.cell_m
            check_fits(grid_bytes(width, height, cell, LIKELIHOOD_CELL_BYTES),
                       f"wifi.radio_map_likelihood.cell_m {cell:g} m over a {width:.0f} x {height:.0f} m floor",
                       "use a larger cell (the default is 1 m)")
        if config.smooth:
            cell = config.offline.map_matching.cell_m
            check_fits(grid_bytes(width, height, cell, MAP_MATCH_CELL_BYTES),
                       f"offline.map_matching.cell_m {cell:g} m over a {width:.0f} x {height:.0f} m floor",
                       "use a larger cell (the default is 0.25 m)")


def building_extents_m(building) -> list[tuple[float, float, float, float]]:
    """The extent of every floor plan of a ``Building`` (for ``check_tracking_fits``)."""
    return [tuple(float(v) for v in floor.plan.extent_m) for floor in building.floors]
