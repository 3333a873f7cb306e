"""Lineage of the particles, for a smoothed track that never crosses a wall.

Every filter step records, per particle, the index of its parent in the previous step's set
(``-1`` when the lineage was broken: a collapse recovery, a random injection) and its final
position. Within a step a particle moves from its parent's position by propagation (wall
checked), is copied by resampling and jittered by regularisation, and the jitter is
accepted only if the straight line from the parent's position to the jittered one is wall
free too (``regularise(origin_xy_m=...)``). So with hard walls (P_m = 0) every segment
parent -> child of a lineage is wall free.

:meth:`Ancestry.smoothed_track` follows the final best particle back to the first step: a
fixed-lag-free "smoother" that returns the one particle history consistent with all
measurements. Where the lineage breaks, it continues from the best particle of the step
before the break (the track jumps there; that jump is the only move not wall checked).
"""

from __future__ import annotations

import numpy as np

__all__ = ["Ancestry"]


class Ancestry:
    """Per-step parent indices, positions and best particle (memory: N * 20 bytes per step)."""

    def __init__(self) -> None:
        self._t_s: list[float] = []
        self._parent: list[np.ndarray] = []
        self._xy_m: list[np.ndarray] = []
        self._best: list[int] = []

    def __len__(self) -> int:
        return len(self._t_s)

    def record(self, t_s: float, parent: np.ndarray, xy_m: np.ndarray, weights: np.ndarray) -> None:
        """Store one step: ``parent`` (N,) indices into the previous record (-1 = none)."""
        self._t_s.append(float(t_s))
        self._parent.append(np.asarray(parent, dtype=np.int32).copy())
        self._xy_m.append(np.asarray(xy_m, dtype=np.float64).copy())
        self._best.append(int(np.argmax(weights)))

    def parents(self, k: int) -> np.ndarray:
        """(N,) parent indices of record ``k`` into record ``k - 1`` (-1 = broken lineage)."""
        return self._parent[k]

    def smoothed_track(self) -> tuple[np.ndarray, np.ndarray]:
        """(t_s (T,), xy_m (T, 2)): the lineage of the final best particle, stitched at breaks."""
        n_steps = len(self._t_s)
        xy = np.empty((n_steps, 2), dtype=np.float64)
        if n_steps == 0:
            return np.empty(0), xy
        i = self._best[-1]
        for k in range(n_steps - 1, -1, -1):
            xy[k] = self._xy_m[k][i]
            if k == 0:
                break
            parent = int(self._parent[k][i])
            i = parent if parent >= 0 else self._best[k - 1]
        return np.asarray(self._t_s, dtype=np.float64), xy
