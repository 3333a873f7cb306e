"""The interfaces the filter calls. A new model implements one; the filter never changes.

Motion models (random walk, constant velocity, PDR) live in ``filter/motion.py``; measurement
models live in ``filter/measurement.py`` (position fixes, trilateration),
``filter/adaptive_pathloss.py``, ``filter/radiomap_likelihood.py`` and ``filter/floors.py``
(a scan weighing floors). The floor in the filter's state sits behind ``FloorModel``:
``filter/floors.OneFloor`` for a single map, ``filter/floors.FloorChanges`` for a building.

Every hook the filter may call is declared here, with the default a model inherits by
subclassing the protocol; the filter never asks a model for its type.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from mapfilter.filter.particles import Particles
from mapfilter.maps.floorplan import FloorPlan


class MotionModel(Protocol):
    """Moves particles over one filter step."""

    # True for a model that moves by detected steps (PDR): its particles carry a heading and a
    # step length (the filter reports their means), and on stairs a step advances one tread
    walks_in_steps: bool = False

    def propagate(self, particles: Particles, inputs: Any, dt_s: float, rng: np.random.Generator) -> Particles:
        """Return the particles moved over ``dt_s`` seconds; never mutate ``particles``.

        ``inputs`` is model specific: None for the random walk and constant velocity, a
        ``StepInput`` for PDR. The filter keeps the old positions for the wall check.
        """
        ...

    def kernel_move(self, inputs: Any, dt_s: float) -> Any:
        """This step's move as the fused step's terms (a ``filter.fused.Move``, the same
        distribution as ``propagate``), or None: the filter calls ``propagate``."""
        return None


class MeasurementModel(Protocol):
    """Weighs particles by a measurement."""

    # what the viewer calls this kind of measurement ("fix", "trilateration", ...)
    kind: str = "other"
    # the largest value ``log_likelihood`` can return, if the model knows it (0 for a Gaussian
    # fix without its constant): the filter then treats a step whose every particle falls
    # ~745 (float64 underflow) below it as a collapse. None: unknown (a large negative value
    # may be a constant offset, which the interface allows)
    log_likelihood_peak: float | None = None

    def log_likelihood(self, particles: Particles, measurement: Any) -> np.ndarray:
        """log p(measurement | particle state) for each particle, shape (N,), finite or -inf.

        Constant offsets do not matter (the filter normalises), but the values must be
        comparable across particles of one call.
        """
        ...

    def kernel_likelihood(self, measurement: Any) -> Any:
        """The log-likelihood as terms the fused step evaluates itself (a ``filter.fused.Likelihood``,
        the same values as ``log_likelihood``), or None: the filter calls ``log_likelihood``."""
        return None

    def locates(self, measurement: Any) -> bool:
        """Whether the measurement says where the walker is (not only which floor): a collapse
        re-draws the particles from the latest measurement that does."""
        return True

    def fix_xy_m(self, measurement: Any) -> np.ndarray | None:
        """The position fix the measurement is, for the viewer (None: not a fix)."""
        return None

    def heard_ap_xy_m(self, measurement: Any) -> np.ndarray | None:
        """(M, 2) positions of the access points the measurement heard, for the viewer."""
        return None

    def viewer_state(self) -> Any:
        """The model's own state after its latest update, for the viewer (adaptive path loss)."""
        return None


class FloorModel(Protocol):
    """The floor in the filter's state: the plan particles live on, and what happens between
    floors. ``filter.floors.OneFloor`` (a single map: nothing happens, no random draw) and
    ``filter.floors.FloorChanges`` (a building's floors side by side in one stack plan)."""

    plan: FloorPlan  # the state space: particles live on its free pixels

    def step_on_stairs(self, from_xy_m: np.ndarray, to_xy_m: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """One step's end points with the steps that start on stairs shortened to a tread."""
        ...

    def change_floors(self, particles: Particles, log_weight: np.ndarray, dt_s: float, rng: np.random.Generator,
                      measurement: Any) -> np.ndarray:
        """After the wall check: move some live particles to another floor (``particles.xy_m`` in
        place); returns the log weights, with particles that landed on no floor killed."""
        ...

    def estimate(self, xy_m: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, float, bool]:
        """(position, spread in m, whether the position is free space) of the weighted cloud."""
        ...

    def covariance(self, xy_m: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """(2, 2) the cloud's weighted covariance, for the regularisation's jitter."""
        ...

    def report(self, xy_m: np.ndarray, weights: np.ndarray, estimate_xy_m: np.ndarray) -> dict:
        """The floor fields of a ``StepReport`` (none on one floor)."""
        ...
