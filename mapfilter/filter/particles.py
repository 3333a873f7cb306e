"""Particle state as a struct of arrays."""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass
class Particles:
    """N particles. Every array has length N along its first axis.

    ``log_weight`` is normalised (logsumexp == 0) after every filter step; a particle
    killed by a wall has ``log_weight == -inf``. Motion models fill the fields they use
    and carry the others along unchanged.
    """

    xy_m: np.ndarray  # (N, 2) float64 world position, metres
    log_weight: np.ndarray  # (N,) float64
    velocity_mps: np.ndarray  # (N, 2) float64, constant-velocity model
    heading_rad: np.ndarray  # (N,) float64, PDR model; 0 = +x, counter-clockwise
    step_length_m: np.ndarray  # (N,) float64, PDR model (thesis eq. 8.23 state)

    @classmethod
    def at(cls, xy_m: np.ndarray, heading_rad: np.ndarray | float = 0.0,
           step_length_m: np.ndarray | float = 0.7) -> Particles:
        """Equally weighted particles at the given positions, at rest."""
        xy = np.array(xy_m, dtype=np.float64).reshape(-1, 2)
        n = xy.shape[0]
        return cls(
            xy_m=xy,
            log_weight=np.full(n, -np.log(n) if n else 0.0),
            velocity_mps=np.zeros((n, 2)),
            heading_rad=np.broadcast_to(np.asarray(heading_rad, dtype=np.float64), (n,)).copy(),
            step_length_m=np.broadcast_to(np.asarray(step_length_m, dtype=np.float64), (n,)).copy(),
        )

    def __len__(self) -> int:
        return self.xy_m.shape[0]

    def take(self, index: np.ndarray) -> Particles:
        """New particles that copy the rows ``index`` (e.g. resampling ancestors)."""
        return Particles(**{f.name: getattr(self, f.name)[index] for f in dataclasses.fields(self)})

    def copy(self) -> Particles:
        return Particles(**{f.name: getattr(self, f.name).copy() for f in dataclasses.fields(self)})

    @property
    def weight(self) -> np.ndarray:
        """Normalised linear weights."""
        return np.exp(self.log_weight)
