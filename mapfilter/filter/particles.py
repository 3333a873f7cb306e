"""Particle state as a struct of arrays: one (STATE_ROWS, N) array and the log weights."""

from __future__ import annotations

import numpy as np

from mapfilter.filter.kernels.passes import HEADING, STATE_ROWS, STEP, VX, VY, X, Y

__all__ = ["HEADING", "STATE_ROWS", "STEP", "VX", "VY", "X", "Y", "Particles"]


class Particles:
    """N particles: ``state[row, i]`` with rows X, Y (world metres), VX, VY (m/s, constant
    velocity), HEADING (rad, 0 = +x, counter-clockwise; PDR) and STEP (step length, m; PDR state,
    Lund thesis eq. 8.23), and ``log_weight`` (N,) (normalised after every filter step; a particle
    killed by a wall has -inf). Motion models fill the rows they use and carry the others along.

    ``xy_m``, ``velocity_mps``, ``heading_rad`` and ``step_length_m`` are views of ``state``.
    """

    __slots__ = ("state", "log_weight")

    def __init__(self, state: np.ndarray, log_weight: np.ndarray) -> None:
        self.state = np.ascontiguousarray(state, dtype=np.float64)
        self.log_weight = np.ascontiguousarray(log_weight, dtype=np.float64)
        if self.state.ndim != 2 or self.state.shape[0] != STATE_ROWS or self.log_weight.shape != (self.state.shape[1],):
            raise ValueError(f"state must be ({STATE_ROWS}, N) and log_weight (N,), got {self.state.shape} and "
                             f"{self.log_weight.shape}")

    @classmethod
    def at(cls, xy_m: np.ndarray, heading_rad: np.ndarray | float = 0.0,
           step_length_m: np.ndarray | float = 0.7) -> Particles:
        """Equally weighted particles at the given positions, at rest."""
        xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        n = xy.shape[0]
        state = np.zeros((STATE_ROWS, n))
        state[X], state[Y] = xy[:, 0], xy[:, 1]
        state[HEADING] = heading_rad
        state[STEP] = step_length_m
        return cls(state, np.full(n, -np.log(n) if n else 0.0))

    @classmethod
    def empty(cls, n: int) -> Particles:
        return cls(np.empty((STATE_ROWS, n)), np.empty(n))

    def __len__(self) -> int:
        return self.state.shape[1]

    @property
    def xy_m(self) -> np.ndarray:
        """(N, 2) positions (a view of ``state``)."""
        return self.state[X:Y + 1].T

    @xy_m.setter
    def xy_m(self, value: np.ndarray) -> None:
        self.state[X:Y + 1] = np.asarray(value, dtype=np.float64).reshape(-1, 2).T

    @property
    def velocity_mps(self) -> np.ndarray:
        return self.state[VX:VY + 1].T

    @property
    def heading_rad(self) -> np.ndarray:
        return self.state[HEADING]

    @heading_rad.setter
    def heading_rad(self, value) -> None:
        self.state[HEADING] = value

    @property
    def step_length_m(self) -> np.ndarray:
        return self.state[STEP]

    @step_length_m.setter
    def step_length_m(self, value) -> None:
        self.state[STEP] = value

    def copy(self) -> Particles:
        return Particles(self.state.copy(), self.log_weight.copy())

    @property
    def weight(self) -> np.ndarray:
        """Normalised linear weights."""
        return np.exp(self.log_weight)
