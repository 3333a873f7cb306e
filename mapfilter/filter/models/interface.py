"""The interfaces the filter calls. A new model implements one; the filter never changes.

A motion model gives each step's move as a compiled kernel and its parameters
(:class:`MoveKernel`); a measurement model gives its log-likelihood either as a compiled
per-particle kernel (:class:`LikelihoodKernel`: the fast path, evaluated inside the filter's
pass over the particles) or, when a value depends on more than the particle's own state (a
normalisation over a floor's particles), as numpy over all particles (``log_likelihood``). A
model writes its likelihood once: the filter runs the kernel wherever it needs values
(``filter.particle_filter.evaluate_log_likelihood``). The kernels' signatures are
``filter.kernels.passes.MOVE_SIGNATURE`` and ``LIKELIHOOD_SIGNATURE``; compile a model's kernel
with ``@njit(MOVE_SIGNATURE, cache=True, nogil=True)`` (or the likelihood's) and read the state
rows named in ``filter.particles`` (X, Y, VX, VY, HEADING, STEP).

The floor in the filter's state sits behind :class:`FloorModel` (``filter.models.building``).
Every hook the filter may call is declared here, with the default a model inherits by
subclassing the protocol; the filter never asks a model for its type.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Protocol

import numpy as np

from mapfilter.filter.kernels.passes import run_likelihood, run_move
from mapfilter.filter.particles import Particles
from mapfilter.maps.floorplan import FloorPlan

__all__ = ["FloorModel", "LikelihoodKernel", "MeasurementModel", "MotionModel", "MoveKernel"]


@dataclasses.dataclass(frozen=True)
class MoveKernel:
    """One step's move: ``function`` (compiled with ``MOVE_SIGNATURE``) with ``params`` (float64),
    given ``normal_pairs`` (0-3) pairs of standard normals per particle."""

    function: Any
    params: np.ndarray
    normal_pairs: int


@dataclasses.dataclass(frozen=True)
class LikelihoodKernel:
    """One measurement's log-likelihood: ``function`` (compiled with ``LIKELIHOOD_SIGNATURE``) with
    ``params`` (float64)."""

    function: Any
    params: np.ndarray


class MotionModel(Protocol):
    """Moves particles over one filter step."""

    # True for a model that moves by detected steps (PDR): its particles carry a heading and a
    # step length (the filter reports their means), and on stairs a step advances one tread
    walks_in_steps: bool = False

    def kernel(self, inputs: Any, dt_s: float) -> MoveKernel:
        """This step's move over ``dt_s`` seconds; ``inputs`` is model specific (None for the random
        walk and constant velocity, a ``StepInput`` for PDR)."""
        ...

    def move(self, state: np.ndarray, normals: np.ndarray, inputs: Any, dt_s: float) -> np.ndarray:
        """The same move in numpy over every particle (the reference step's, ``filter.reference``):
        ``state`` (STATE_ROWS, N) before, ``normals`` (2 x the kernel's pairs, N), the state after.
        A model with only a kernel inherits this (its kernel over the particles)."""
        kernel = self.kernel(inputs, dt_s)
        return run_move(kernel.function, kernel.params, state, normals[:2 * kernel.normal_pairs])

    def predict(self, state: np.ndarray, inputs: Any, dt_s: float) -> tuple[np.ndarray, np.ndarray, float]:
        """The move's density, for the smoother (``offline.smoother``): (means (K, M, 2) of the
        position after the move of each of the M particles of ``state``, a mixture of K with
        weights (K,), and the isotropic spread in metres around each mean)."""
        ...


class MeasurementModel(Protocol):
    """Weighs particles by a measurement."""

    # the largest value the log-likelihood can take, if the model knows it (0 for a Gaussian fix
    # without its constant): the filter then treats a step whose every particle falls ~745
    # (float64 underflow) below it as a collapse. None: unknown
    log_likelihood_peak: float | None = None

    def kernel(self, measurement: Any) -> LikelihoodKernel | None:
        """The log-likelihood of ``measurement`` as a per-particle kernel, or None: the filter calls
        ``log_likelihood`` instead."""
        return None

    def log_likelihood(self, particles: Particles, measurement: Any) -> np.ndarray:
        """log p(measurement | particle) for each particle, (N,), finite or -inf. Constant offsets
        do not matter (the filter normalises). A model with a kernel inherits this (its kernel over
        the particles); a model without one writes it instead."""
        kernel = self.kernel(measurement)
        if kernel is None:
            raise NotImplementedError(f"{type(self).__name__} gives neither a kernel nor log_likelihood")
        return run_likelihood(kernel.function, kernel.params, particles.state)

    def locates(self, measurement: Any) -> bool:
        """Whether the measurement says where the walker is (not only which floor): a collapse
        re-draws the particles from the latest measurement that does."""
        return True

    def fix_xy_m(self, measurement: Any) -> np.ndarray | None:
        """The position fix the measurement is, for the viewer (None: not a fix)."""
        return None

    def heard_ap_xy_m(self, measurement: Any) -> np.ndarray | None:
        """(M, 2) positions of the transmitters the measurement heard, for the viewer."""
        return None

    def viewer_state(self) -> Any:
        """The model's own state after its latest update, for the viewer (adaptive path loss)."""
        return None


class FloorModel(Protocol):
    """The floor in the filter's state: the plan particles live on, and what happens between
    floors. ``filter.models.building.OneFloor`` (a single map: nothing happens, no random draw)
    and ``FloorChanges`` (a building's floors side by side in one stack plan)."""

    plan: FloorPlan  # the state space: particles live on its free pixels
    changes_floors: bool = False  # False: the filter skips the hooks below that change nothing
    has_stairs: bool = False  # False: ``step_on_stairs`` gives every step as it is (the filter skips it)

    def step_on_stairs(self, from_xy_m: np.ndarray, to_xy_m: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """One step's end points with the steps that start on stairs shortened to a tread."""
        ...

    def change_floors(self, particles: Particles, log_weight: np.ndarray, dt_s: float, rng: np.random.Generator,
                      measurement: Any) -> np.ndarray:
        """After the wall check: move some live particles to another floor (``particles.xy_m`` in
        place); returns the log weights, with particles that landed on no floor killed."""
        ...

    def estimate(self, xy_m: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, float, bool]:
        """(position, spread in m, whether the position fell back from the mean) of the cloud."""
        ...

    def covariance(self, xy_m: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """(2, 2) the cloud's weighted covariance, for the regularisation's jitter."""
        ...

    def report(self, xy_m: np.ndarray, weights: np.ndarray, estimate_xy_m: np.ndarray,
               floor_shares: np.ndarray | None = None) -> dict:
        """The floor fields of a ``StepReport`` (none on one floor); ``floor_shares``: the cloud's
        share on each floor when the caller has it already (of these positions and weights)."""
        ...

    def change_probability(self, xy_m: np.ndarray, dt_s: float) -> np.ndarray:
        """(M, F) the probability that a particle at each position moves to each floor over
        ``dt_s`` (for the smoother; its own floor's entry is not used)."""
        ...
