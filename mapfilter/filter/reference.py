"""The filter's step in plain numpy: read this one first.

``reference_step`` is one step of the regularised particle filter (Evennou & Marx; the
regularisation of Musso, Oudjane & Le Gland), stage by stage: move every particle, kill the moves
that touch a wall, weigh the survivors by every measurement, normalise, and, when the effective
sample size is low, resample and jitter. Each stage is a few lines of numpy over all particles.

``ParticleFilter.step`` (``filter/particle_filter.py``) computes the same step fast: two numba
passes over blocks of particles (``filter/kernels/passes.py``) that call each model's compiled
kernel, with the same draws, so that ``tests/filter/test_reference_step.py`` holds it to this
function particle for particle on the bundled office map and an ILC floor. The fast step adds
what a long run needs and this leaves out: a collapse (every particle killed, or every weight
underflowing) and its recovery, floor changes in a building, the estimate and the step's report.
docs/architecture.md walks from here to the kernels, hop by hop.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from mapfilter.filter.kernels.draws import counter_normals
from mapfilter.filter.models.interface import MeasurementModel, MotionModel
from mapfilter.filter.particle_filter import REGULARISE_TRIES, FilterConfig, bandwidth_and_root
from mapfilter.filter.particles import X, Y, Particles
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import touches_wall_reference

__all__ = ["ReferenceStep", "reference_step"]

# normal pairs a move may use (PDR: heading, step length, position, false turns); a draw is a
# function of (key, pair, particle), so a model that uses fewer ignores the rest
MOVE_NORMAL_PAIRS = 3


@dataclasses.dataclass(frozen=True)
class ReferenceStep:
    """What one step made: the particles after it, each one's parent before it, the ESS of the
    weights before resampling, and whether it resampled."""

    particles: Particles
    parents: np.ndarray
    ess: float
    resampled: bool


def reference_step(plan: FloorPlan, particles: Particles, motion: MotionModel, motion_input: Any, dt_s: float,
                   measurements: Sequence[tuple[MeasurementModel, Any]], config: FilterConfig,
                   rng: np.random.Generator) -> ReferenceStep:
    """One filter step over ``dt_s`` seconds (module docstring): ``measurements`` are this step's
    (model, measurement) pairs; ``rng`` gives the step's draws in the order the fast step draws them."""
    n = len(particles)
    # 1. predict: every particle moves by the motion model, with standard normals of its own
    key = int(rng.integers(0, 2 ** 63, dtype=np.int64))
    normals = np.vstack([np.vstack(counter_normals(key, pair, n)) for pair in range(MOVE_NORMAL_PAIRS)])
    state = motion.move(particles.state, normals, motion_input, dt_s)
    # 2. kill: a move that touches a wall pixel has probability zero (Evennou & Marx's P_m = 0)
    log_weight = np.where(touches_wall_reference(plan, particles.xy_m, state[X:Y + 1].T), -np.inf,
                          particles.log_weight)
    # 3. weigh: log w += log p(z | x) for every measurement of this step
    for model, measurement in measurements:
        log_weight = log_weight + model.log_likelihood(Particles(state, log_weight), measurement)
    # 4. normalise: w = exp(log w) / sum exp(log w), and the effective sample size 1 / sum w^2
    log_weight = log_weight - np.logaddexp.reduce(log_weight)
    weights = np.exp(log_weight)
    ess = float(1.0 / np.sum(weights ** 2))
    if ess >= config.resample_ess_fraction * n:
        return ReferenceStep(Particles(state, log_weight), np.arange(n), ess, resampled=False)
    # 5. resample systematically: copy j is of the particle whose cumulative-weight bin holds (j + u) / N
    u = float(rng.random())
    cumulative = np.cumsum(weights)
    cumulative[np.flatnonzero(weights > 0)[-1]:] = 1.0  # round-off: the last positive weight closes the last bin
    parents = np.searchsorted(cumulative, (np.arange(n) + u) / n, side="right")
    copies = state[:, parents]
    # 6. regularise: each copy jumps by h D eps, D D^T the weighted covariance of the cloud, h the
    #    optimal bandwidth (Musso et al.); a jump that touches a wall, from the copy or from its
    #    parent's position before the move, is drawn again, and after REGULARISE_TRIES the copy stays
    if config.regularise:
        offset = state[X:Y + 1].T - weights @ state[X:Y + 1].T
        h, root = bandwidth_and_root(plan.resolution_m, (weights[:, None] * offset).T @ offset, n,
                                     config.bandwidth_scale)
        jitter_key = int(rng.integers(0, 2 ** 63, dtype=np.int64))
        pending = np.arange(n)
        for attempt in range(REGULARISE_TRIES):
            eps = np.vstack(counter_normals(jitter_key, attempt, n))[:, pending]
            jumped = copies[X:Y + 1, pending].T + h * (root @ eps).T
            blocked = (touches_wall_reference(plan, copies[X:Y + 1, pending].T, jumped)
                       | touches_wall_reference(plan, particles.xy_m[parents[pending]], jumped))
            copies[X:Y + 1, pending[~blocked]] = jumped[~blocked].T
            pending = pending[blocked]
    return ReferenceStep(Particles(copies, np.full(n, -np.log(n))), parents, ess, resampled=True)
