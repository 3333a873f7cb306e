"""The two small interfaces the filter calls. A new model implements one; the filter never changes.

Motion models (random walk, constant velocity, PDR) live in ``filter/motion.py``; measurement
models live in ``filter/measurement.py`` (position fixes, trilateration) and
``filter/radiomap_likelihood.py``.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from mapfilter.filter.particles import Particles


class MotionModel(Protocol):
    def propagate(self, particles: Particles, inputs: Any, dt_s: float, rng: np.random.Generator) -> Particles:
        """Return the particles moved over ``dt_s`` seconds; never mutate ``particles``.

        ``inputs`` is model specific: None for the random walk and constant velocity, a
        ``StepInput`` for PDR. The filter keeps the old positions for the wall check.
        """
        ...


class MeasurementModel(Protocol):
    def log_likelihood(self, particles: Particles, measurement: Any) -> np.ndarray:
        """log p(measurement | particle state) for each particle, shape (N,), finite or -inf.

        Constant offsets do not matter (the filter normalises), but the values must be
        comparable across particles of one call. A model that knows the largest value it can
        return may say so in an attribute ``log_likelihood_peak``; the filter then treats a
        step whose every particle falls ~745 (float64 underflow) below it as a collapse.
        """
        ...
