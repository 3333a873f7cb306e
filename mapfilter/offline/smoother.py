"""The smoother of the particle filter's own model: forward filtering, backward smoothing (FFBSm).

The forward pass is the causal filter. After each of its steps the ``ParticleHistory`` keeps a
subsample of the weighted cloud (``SUBSAMPLE`` particles by systematic resampling: equal weights)
and the step's motion input. The backward pass (Doucet, Godsill & Andrieu 2000; Godsill, Doucet &
West 2004 for the backward recursion) gives every kept particle at step t its weight given the
whole walk:

    W_t^i = w_t^i sum_j W_{t+1}^j f(x_{t+1}^j | x_t^i) / sum_k w_t^k f(x_{t+1}^j | x_t^k)

where f is the filter's transition: the motion model's predicted position of particle i
(``MotionModel.predict``: its own heading and step length, the step's turn, the false turns),
spread by the motion noise and the regularisation's jitter, zero for a move through a wall, and
between floors the floor model's change probability (``FloorModel.change_probability``). So a
scan late in the walk weighs the particles of its start, walls and floors included, and the
smoothed estimate is never less informed than the causal one. A collapse (the filter re-drew
its particles) or a restart after a gap breaks the chain: the backward pass starts afresh there.

The cost is (kept particles)^2 density evaluations per step, the wall checked only where the
density is not negligible, whatever the filter's own number of particles.

``smooth`` is the whole walk; ``FixedLagSmoother`` the same backward pass over the last few
seconds only, for a live tracker that may answer a little late.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
from numba import njit

from mapfilter.filter.models.interface import FloorModel, MotionModel
from mapfilter.filter.particles import HEADING, X, Y
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import move_crosses, wall_grid

__all__ = ["FixedLagSmoother", "ParticleHistory", "Smoothed", "smooth"]

# Particles kept per step: the backward pass costs their square per step. 256 keeps the spacing
# of a 3 m cloud's particles near 0.2 m, below the transition's spread
SUBSAMPLE = 256
# The transition's spread never below this: between two kept subsamples a particle's own
# successor is rarely kept, so its density must reach the neighbours of that successor
MIN_SPREAD_M = 0.3
# densities below this share of a successor's largest count as 0 (and are not wall checked): a
# predecessor 4.3 spreads off its prediction
_NEGLIGIBLE = 1e-4


@dataclasses.dataclass
class _Step:
    t_s: float
    state: np.ndarray  # (STATE_ROWS, M) the kept particles
    weight: np.ndarray  # (M,) their filtered weights (normalised)
    inputs: object  # the motion input of the step that led here (from the previous step)
    dt_s: float
    jitter_m2: float  # variance of the regularisation's jitter of this step (0: not resampled)
    broken: bool  # the chain breaks here: initialised, recovered from a collapse, or restarted


class ParticleHistory:
    """The steps of a filter run as the smoother needs them (a subsample of each cloud)."""

    def __init__(self, keep: int = SUBSAMPLE) -> None:
        self.keep = int(keep)
        self.steps: list[_Step] = []

    def __len__(self) -> int:
        return len(self.steps)

    def record(self, t_s: float, state: np.ndarray, weight: np.ndarray, inputs: object, dt_s: float,
               jitter_m2: float, broken: bool) -> None:
        """A filter step's cloud (``state`` (STATE_ROWS, N), normalised ``weight``): kept whole when
        small, else ``keep`` particles drawn systematically (the offset fixed: no random draw, so
        the filter's own random numbers are the same with or without a smoother)."""
        w = np.asarray(weight, dtype=np.float64)
        n = w.shape[0]
        if n <= self.keep:
            kept, kept_w = np.array(state, dtype=np.float64, copy=True), w.copy()
        else:
            cumulative = np.cumsum(w)
            cumulative /= cumulative[-1]
            index = np.minimum(np.searchsorted(cumulative, (np.arange(self.keep) + 0.5) / self.keep, side="right"),
                               n - 1)
            kept, kept_w = np.ascontiguousarray(state[:, index]), np.full(self.keep, 1.0 / self.keep)
        self.steps.append(_Step(float(t_s), kept, kept_w, inputs, float(dt_s), float(jitter_m2), bool(broken)))


@dataclasses.dataclass(frozen=True)
class Smoothed:
    """The smoothed marginals of a filter run, one row per recorded step (the plan's frame)."""

    t_s: np.ndarray  # (T,)
    xy_m: np.ndarray  # (T, 2) the smoothed mean (a kept particle when the mean falls in a wall)
    std_m: np.ndarray  # (T,)
    heading_rad: np.ndarray  # (T,)
    floor_shares: np.ndarray | None  # (T, F) a building: the smoothed weight of each floor


@njit(cache=True, nogil=True, error_model="numpy")
def _backward_step(from_xy, means, mix, inv_two_var, from_floor, to_xy, to_floor, change_p, to_building,
                   from_building, w_from, w_next, walls, out):
    """One step of the FFBSm recursion: out[i] = w_from[i] sum_j w_next[j] f_ij / sum_k w_from[k] f_kj.

    means (K, M, 2): the predicted positions of the particles at the earlier step (mixture of K,
    weights mix); between floors the prediction is compared in the building frame and weighed by
    change_p[i, floor of j]. A density below ``_NEGLIGIBLE`` of a successor's largest counts as 0
    (it is not wall checked). Returns whether any successor found a predecessor."""
    m_from = from_xy.shape[0]
    m_to = to_xy.shape[0]
    n_mix = mix.shape[0]
    f = np.zeros(m_from)
    cutoff = -math.log(_NEGLIGIBLE)  # in units of d^2 / (2 var)
    for i in range(m_from):
        out[i] = 0.0
    found = False
    for j in range(m_to):
        if w_next[j] <= 0.0:
            continue
        top = 0.0
        for i in range(m_from):
            value = 0.0
            same = from_floor[i] == to_floor[j]
            for k in range(n_mix):
                if same:
                    dx = to_xy[j, 0] - means[k, i, 0]
                    dy = to_xy[j, 1] - means[k, i, 1]
                else:
                    # the predicted move in the building frame: predicted - from, applied to from's building position
                    dx = to_building[j, 0] - (from_building[i, 0] + means[k, i, 0] - from_xy[i, 0])
                    dy = to_building[j, 1] - (from_building[i, 1] + means[k, i, 1] - from_xy[i, 1])
                exponent = (dx * dx + dy * dy) * inv_two_var
                if exponent < cutoff:  # far beyond the spread: exp would say 0
                    value += mix[k] * math.exp(-exponent)
            if value > 0.0 and not same:
                value *= change_p[i, to_floor[j]]
            f[i] = value
            if value > top:
                top = value
        if top <= 0.0:
            continue
        total = 0.0
        floor_value = top * _NEGLIGIBLE
        for i in range(m_from):
            value = f[i]
            if value <= floor_value:
                f[i] = 0.0
                continue
            if from_floor[i] == to_floor[j]:
                # a move through a wall has density 0
                if move_crosses(walls, from_xy[i, 0], from_xy[i, 1], to_xy[j, 0], to_xy[j, 1]):
                    f[i] = 0.0
                    continue
            total += w_from[i] * value
        if total <= 0.0:
            continue
        found = True
        scale = w_next[j] / total
        for i in range(m_from):
            if f[i] > 0.0:
                out[i] += scale * f[i]
    for i in range(m_from):
        out[i] *= w_from[i]
    return found


class _Space:
    """The plan, its walls and floors as the backward pass needs them."""

    def __init__(self, plan: FloorPlan, floors: FloorModel | None) -> None:
        self.plan = plan
        self.floors = floors if floors is not None and floors.changes_floors else None
        self.walls = wall_grid(plan)

    def frame(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        """(floor index per point, building-frame positions, number of floors)."""
        if self.floors is None:
            return np.zeros(len(xy), dtype=np.int64), xy, 1
        stack = self.floors.stack
        return stack.floor_of(xy).astype(np.int64), stack.to_building(xy), stack.n_floors

    def change_probability(self, xy: np.ndarray, dt_s: float, n_floors: int) -> np.ndarray:
        if self.floors is None:
            return np.zeros((len(xy), n_floors))
        return self.floors.change_probability(xy, dt_s)


def _backward_weights(history: ParticleHistory, motion: MotionModel, space: _Space, last: int,
                      first: int = 0) -> list[np.ndarray]:
    """The smoothed weights of the kept particles of steps ``first`` to ``last`` (the backward pass
    from ``last``, whose weights are its filtered ones)."""
    steps = history.steps
    weights: list[np.ndarray] = [np.zeros(0)] * (last - first + 1)
    weights[-1] = steps[last].weight.copy()
    for t in range(last - 1, first - 1, -1):
        now, after = steps[t], steps[t + 1]
        w_next = weights[t + 1 - first]
        if after.broken:
            weights[t - first] = now.weight.copy()
            continue
        from_xy = np.ascontiguousarray(now.state[X:Y + 1].T)
        to_xy = np.ascontiguousarray(after.state[X:Y + 1].T)
        means, mix, spread_m = motion.predict(now.state, after.inputs, after.dt_s)
        variance = max(spread_m ** 2 + after.jitter_m2, MIN_SPREAD_M ** 2)
        from_floor, from_building, n_floors = space.frame(from_xy)
        to_floor, to_building, _ = space.frame(to_xy)
        out = np.empty(len(from_xy))
        found = _backward_step(from_xy, np.ascontiguousarray(means, dtype=np.float64),
                               np.ascontiguousarray(mix, dtype=np.float64), 0.5 / variance, from_floor, to_xy,
                               to_floor, space.change_probability(from_xy, after.dt_s, n_floors),
                               np.ascontiguousarray(to_building), np.ascontiguousarray(from_building), now.weight,
                               w_next, space.walls, out)
        total = out.sum()
        # no kept particle can reach the next step's (the subsample missed the way): start afresh
        weights[t - first] = out / total if found and total > 0 else now.weight.copy()
    return weights


def _estimate(space: _Space, state: np.ndarray, weight: np.ndarray) -> tuple[np.ndarray, float, float, np.ndarray]:
    """(position, spread, heading, floor shares) of kept particles under smoothed weights."""
    from mapfilter.filter.estimate import circular_mean, weighted_estimate

    xy = np.ascontiguousarray(state[X:Y + 1].T)
    floor, _, n_floors = space.frame(xy)
    shares = np.bincount(floor, weights=weight, minlength=n_floors)
    if space.floors is not None:
        position, spread, _ = space.floors.estimate(xy, weight)
    else:
        position, spread, _ = weighted_estimate(space.plan, xy, weight)
    return position, spread, circular_mean(state[HEADING], weight), shares


def smooth(history: ParticleHistory, plan: FloorPlan, motion: MotionModel, floors: FloorModel | None = None,
           on_row: Callable[[float, np.ndarray, np.ndarray], None] | None = None) -> Smoothed:
    """The smoothed estimate of every recorded step of a filter run (module docstring);
    ``on_row(t_s, xy_m (M, 2), weight (M,))`` sees each step's kept particles under their
    smoothed weights (the smoothed cloud, e.g. for the viewer)."""
    if not len(history):
        raise ValueError("the history holds no step")
    space = _Space(plan, floors)
    weights = _backward_weights(history, motion, space, len(history) - 1)
    if on_row is not None:
        for step, w in zip(history.steps, weights):
            on_row(step.t_s, np.ascontiguousarray(step.state[X:Y + 1].T), w)
    rows = [_estimate(space, step.state, w) for step, w in zip(history.steps, weights)]
    shares = np.array([r[3] for r in rows]) if space.floors is not None else None
    return Smoothed(np.array([s.t_s for s in history.steps]), np.array([r[0] for r in rows]),
                    np.array([r[1] for r in rows]), np.array([r[2] for r in rows]), shares)


class FixedLagSmoother:
    """The smoothed estimate of the step ``lag_s`` seconds behind the latest, as a live tracker can
    give it: after every step, the backward pass over the steps of the last ``lag_s`` seconds. Each
    row is stamped with its step's time and is available ``lag_s`` later (``available_s``)."""

    def __init__(self, plan: FloorPlan, motion: MotionModel, floors: FloorModel | None, lag_s: float,
                 keep: int = SUBSAMPLE) -> None:
        if not (math.isfinite(lag_s) and lag_s > 0):
            raise ValueError(f"the lag must be a positive number of seconds, got {lag_s}")
        self.history = ParticleHistory(keep)
        self.motion = motion
        self.lag_s = float(lag_s)
        self._space = _Space(plan, floors)
        self.rows: list[tuple[float, float, np.ndarray, float, float, np.ndarray]] = []  # (t_s, available_s, ...)

    def record(self, *args, **kwargs) -> None:
        """``ParticleHistory.record`` a step; the rows that became ``lag_s`` old with it join ``rows``."""
        self.history.record(*args, **kwargs)
        self._advance(final=False)

    def close(self) -> None:
        """The rows not yet given, smoothed by everything recorded (the end of the walk)."""
        self._advance(final=True)

    def _advance(self, final: bool) -> None:
        steps = self.history.steps
        last = len(steps) - 1
        latest = steps[last].t_s if steps else -math.inf
        done = 0
        while done <= last and (final or latest - steps[done].t_s >= self.lag_s):
            # smoothed by every step up to the latest known: at least a lag's worth after it
            weights = _backward_weights(self.history, self.motion, self._space, last, done)
            step = steps[done]
            available = latest if not final else max(latest, step.t_s)
            self.rows.append((step.t_s, available, *_estimate(self._space, step.state, weights[0])))
            done += 1
        del steps[:done]  # a live run keeps only the window
