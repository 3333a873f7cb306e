"""What the filter reports after each step. The viewer (``mapfilter.viz``) and the CLI draw/print these;
the filter itself never imports rerun."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np


@dataclasses.dataclass
class CollapseEvent:
    """Every particle was killed, every weight underflowed, or (with a gate) the measurement
    disagreed with the whole cloud; the filter re-initialised."""

    t_s: float
    step_index: int
    xy_m: tuple[float, float]  # last estimate before the collapse
    cause: str  # "all_killed_by_walls" | "weights_underflow" | "measurement_inconsistent"
    particles_lost: int
    recovery: str  # "likelihood_over_map" | "around_estimate_r<radius>m" | "uniform"
    recovered_xy_m: tuple[float, float]  # estimate right after the re-initialisation


@dataclasses.dataclass
class StepReport:
    """One filter step, for the viewer and for diagnostics.

    ``particles_xy_m``/``particles_weight`` are the state after the step (after resampling
    and regularisation if they happened), valid until the filter's next step (it reuses its
    arrays): copy them to keep them. ``killed_from_xy_m``/``killed_to_xy_m`` are the
    moves the wall check rejected this step.
    """

    t_s: float
    step_index: int
    estimate_xy_m: np.ndarray  # (2,)
    estimate_std_m: float  # sqrt of the mean of the two position variances
    ess: float  # effective sample size 1 / sum(w^2) before resampling
    n_particles: int
    n_alive: int  # particles with non-zero weight after the wall check and measurement
    n_killed: int  # particles killed by walls this step
    resampled: bool
    particles_xy_m: np.ndarray  # (N, 2)
    particles_weight: np.ndarray  # (N,) normalised
    killed_from_xy_m: np.ndarray  # (K, 2)
    killed_to_xy_m: np.ndarray  # (K, 2)
    collapse: CollapseEvent | None = None
    heading_rad: float | None = None  # PDR: weighted circular mean heading
    step_length_m: float | None = None  # PDR: weighted mean step length
    fix_xy_m: np.ndarray | None = None  # fingerprint fix used this step, if any
    heard_ap_xy_m: np.ndarray | None = None  # trilateration: positions of the APs heard this step
    # adaptive trilateration (``filter.adaptive_pathloss.PathLossState``): H, the nearest AP's C
    path_loss: Any = None
    # a building (``filter.floors``): the share of the weight on each floor after the step, the
    # estimate's floor, and how many particles changed floor this step
    floor_shares: np.ndarray | None = None
    floor_index: int | None = None
    floor_changes: int = 0
