"""Motion models (the ``MotionModel`` interface): random walk, constant velocity, PDR.

Each gives the filter a compiled move kernel and its parameters per step; the kernel reads the
state before the step and writes the state after it (heading 0 = +x, counter-clockwise,
radians), with standard normals drawn by the filter (``normals[k, j]`` for particle lo + j).
``move`` is the same move in numpy over every particle, the kernel's twin: the reference step
(``filter.reference``) calls it, and the tests hold each kernel to it.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
from typing import ClassVar

import numpy as np
from numba import njit

from mapfilter.errors import MapfilterError
from mapfilter.filter.kernels.draws import cos_sin
from mapfilter.filter.kernels.passes import HEADING, MOVE_SIGNATURE, STEP, VX, VY, X, Y, stay
from mapfilter.filter.models.interface import MotionModel, MoveKernel

__all__ = ["ConstantVelocityMotion", "PDRMotion", "RandomWalkMotion", "StepInput"]

# PDR (thesis eq. 8.23): the model's shape, not a user's choice
TURN_THRESHOLD_RAD = 0.35  # a heading change at least this large (~20 deg) is a turn some particles ignore
STEP_LENGTH_WALK_SIGMA_M = 0.02  # per step, the random walk of the state's step length (eq. 8.23)
POSITION_SIGMA_M = 0.05  # per step, lateral/longitudinal slack: the step's end is not a point


def _check_non_negative(owner: str, **values: float) -> None:
    for name, value in values.items():
        if not (math.isfinite(value) and value >= 0):
            raise MapfilterError(f"{owner} setting {name} must be a number >= 0, got {value}")


@njit(MOVE_SIGNATURE, cache=True, nogil=True, fastmath=True, error_model="numpy")
def _circle_walk(params, src, dst, normals, lo, m):
    # eq. 6.6: x_k = x_{k-1} + r (cos phi, sin phi) + sigma e; (cos phi, sin phi) is the direction of
    # the second normal pair, uniform on the circle
    radius_m = params[0]
    sigma_m = params[1]
    for j in range(m):
        i = lo + j
        r = math.sqrt(normals[2, j] * normals[2, j] + normals[3, j] * normals[3, j])
        dst[X, i] = src[X, i] + radius_m * normals[2, j] / r + sigma_m * normals[0, j]
        dst[Y, i] = src[Y, i] + radius_m * normals[3, j] / r + sigma_m * normals[1, j]
        dst[VX, i] = src[VX, i]
        dst[VY, i] = src[VY, i]
        dst[HEADING, i] = src[HEADING, i]
        dst[STEP, i] = src[STEP, i]


@dataclasses.dataclass(frozen=True)
class RandomWalkMotion(MotionModel):
    """Random walk on a circle (Lund thesis eq. 6.6): each particle jumps to a uniformly random
    point of the circle of radius ``radius_mps * dt`` around it, blurred by isotropic Gaussian
    noise of standard deviation ``sigma_mps * dt``. Thesis values: r = 1.5 dt, sigma = 0.5 dt."""

    radius_mps: float = 1.5  # the circle's radius per second (thesis: 1.5 m/s)
    sigma_mps: float = 0.5  # Gaussian blur per second (thesis: 0.5 m/s)

    def __post_init__(self) -> None:
        _check_non_negative("random walk", radius_mps=self.radius_mps, sigma_mps=self.sigma_mps)

    def kernel(self, inputs: object, dt_s: float) -> MoveKernel:
        dt = max(float(dt_s), 0.0)
        return MoveKernel(_circle_walk, np.array([self.radius_mps * dt, self.sigma_mps * dt]), 2)

    def move(self, state: np.ndarray, normals: np.ndarray, inputs: object, dt_s: float) -> np.ndarray:
        dt = max(float(dt_s), 0.0)
        phi = np.arctan2(normals[3], normals[2])  # the second normal pair's direction: uniform
        out = state.copy()
        out[X] += self.radius_mps * dt * np.cos(phi) + self.sigma_mps * dt * normals[0]
        out[Y] += self.radius_mps * dt * np.sin(phi) + self.sigma_mps * dt * normals[1]
        return out

    def predict(self, state: np.ndarray, inputs: object, dt_s: float) -> tuple[np.ndarray, np.ndarray, float]:
        # the ring as an isotropic Gaussian of the same second moment: r^2 / 2 + sigma^2 per axis
        dt = max(float(dt_s), 0.0)
        spread = math.sqrt(0.5 * (self.radius_mps * dt) ** 2 + (self.sigma_mps * dt) ** 2)
        return state[X:Y + 1].T[None].copy(), np.ones(1), spread


@njit(MOVE_SIGNATURE, cache=True, nogil=True, fastmath=True, error_model="numpy")
def _constant_velocity(params, src, dst, normals, lo, m):
    dt = params[0]
    sigma = params[1]
    max_speed = params[2]
    for j in range(m):
        i = lo + j
        ax = sigma * normals[0, j]
        ay = sigma * normals[1, j]
        vx = src[VX, i]
        vy = src[VY, i]
        dst[X, i] = src[X, i] + vx * dt + 0.5 * dt * dt * ax
        dst[Y, i] = src[Y, i] + vy * dt + 0.5 * dt * dt * ay
        vx += ax * dt
        vy += ay * dt
        speed = math.sqrt(vx * vx + vy * vy)
        scale = max_speed / speed if speed > max_speed else 1.0
        dst[VX, i] = vx * scale
        dst[VY, i] = vy * scale
        dst[HEADING, i] = src[HEADING, i]
        dst[STEP, i] = src[STEP, i]


@dataclasses.dataclass(frozen=True)
class ConstantVelocityMotion(MotionModel):
    """Constant velocity with random acceleration (Evennou & Marx's prediction equation):
    x_k = x_{k-1} + v_{k-1} dt + a dt^2 / 2,  v_k = v_{k-1} + a dt,  a ~ N(0, accel_sigma^2 I);
    speeds above ``max_speed_mps`` (a walking person) are scaled back to it."""

    accel_sigma_mps2: float = 0.5  # random acceleration (per axis)
    max_speed_mps: float = 2.0  # speeds above this (a walking person) are scaled back

    def __post_init__(self) -> None:
        _check_non_negative("constant velocity", accel_sigma_mps2=self.accel_sigma_mps2,
                            max_speed_mps=self.max_speed_mps)

    def kernel(self, inputs: object, dt_s: float) -> MoveKernel:
        params = np.array([max(float(dt_s), 0.0), self.accel_sigma_mps2, self.max_speed_mps])
        return MoveKernel(_constant_velocity, params, 1)

    def move(self, state: np.ndarray, normals: np.ndarray, inputs: object, dt_s: float) -> np.ndarray:
        dt = max(float(dt_s), 0.0)
        accel = self.accel_sigma_mps2 * normals[:2]
        out = state.copy()
        out[X:Y + 1] += state[VX:VY + 1] * dt + 0.5 * dt ** 2 * accel
        velocity = state[VX:VY + 1] + accel * dt
        speed = np.hypot(velocity[0], velocity[1])
        out[VX:VY + 1] = velocity * np.where(speed > self.max_speed_mps, self.max_speed_mps / np.maximum(speed, 1e-300),
                                             1.0)
        return out

    def predict(self, state: np.ndarray, inputs: object, dt_s: float) -> tuple[np.ndarray, np.ndarray, float]:
        dt = max(float(dt_s), 0.0)
        means = state[X:Y + 1].T + dt * state[VX:VY + 1].T
        return means[None], np.ones(1), 0.5 * self.accel_sigma_mps2 * dt * dt


@dataclasses.dataclass(frozen=True)
class StepInput:
    """What pedestrian dead reckoning tells the motion model for one filter step.

    n_steps : steps detected since the last filter step (0 = standing).
    heading_change_rad : heading change over the interval (gyro about gravity), CCW positive.
    """

    n_steps: int
    heading_change_rad: float


# PDR kernel parameters, in this order
(_P_STEPS, _P_CHANGE, _P_HEADING_SIGMA, _P_FALSE_TURN, _P_LENGTH_SIGMA, _P_LENGTH_MIN, _P_LENGTH_MAX,
 _P_POSITION_SIGMA) = range(8)


@njit(MOVE_SIGNATURE, cache=True, nogil=True, fastmath=True, error_model="numpy")
def _pdr_step(params, src, dst, normals, lo, m):
    # normals 0: heading noise, 1: step-length walk, 2 and 3: position, 5: false turns (a particle
    # ignores the change when its normal falls below the false-turn share's quantile)
    two_pi = 2.0 * math.pi
    n_steps = params[_P_STEPS]
    for j in range(m):
        i = lo + j
        change = params[_P_CHANGE]
        if normals[5, j] < params[_P_FALSE_TURN]:
            change = 0.0
        h = src[HEADING, i] + change + params[_P_HEADING_SIGMA] * normals[0, j]
        if not -math.pi <= h < math.pi:
            h = ((h + math.pi) % two_pi) - math.pi
        length = src[STEP, i]
        if n_steps > 0.0:
            length = min(max(length + params[_P_LENGTH_SIGMA] * normals[1, j], params[_P_LENGTH_MIN]),
                         params[_P_LENGTH_MAX])
        c, s = cos_sin(h)
        distance = n_steps * length
        dst[X, i] = src[X, i] + distance * c + params[_P_POSITION_SIGMA] * normals[2, j]
        dst[Y, i] = src[Y, i] + distance * s + params[_P_POSITION_SIGMA] * normals[3, j]
        dst[VX, i] = src[VX, i]
        dst[VY, i] = src[VY, i]
        dst[HEADING, i] = h
        dst[STEP, i] = length


@dataclasses.dataclass(frozen=True)
class PDRMotion(MotionModel):
    """Pedestrian dead reckoning with the state [x, y, heading, step length] (Lund thesis eq. 8.23).

    Per particle: heading += change + N(0, heading_sigma^2), where a share ``false_turn_fraction``
    of the particles ignores a change of at least ``TURN_THRESHOLD_RAD`` ("false turns"); step
    length L += N(0, STEP_LENGTH_WALK_SIGMA_M^2 n) clipped to [min, max] (a random walk the filter
    adapts through resampling); then xy += n L (cos h, sin h) + N(0, POSITION_SIGMA_M^2 n I).
    """

    walks_in_steps: ClassVar[bool] = True

    # the gyro is good over a step: more lets the clouds fan out (docs/accuracy.md)
    heading_sigma_rad: float = 0.02  # per filter step
    false_turn_fraction: float = 0.15  # thesis: 15 % of particles ignore a detected turn
    step_length_min_m: float = 0.4  # the state's step length stays within [min, max]
    step_length_max_m: float = 1.0  # (see step_length_min_m)

    def __post_init__(self) -> None:
        _check_non_negative("PDR", heading_sigma_rad=self.heading_sigma_rad)
        if not 0.0 <= self.false_turn_fraction <= 1.0:
            raise MapfilterError(f"PDR setting false_turn_fraction must be in [0, 1], got {self.false_turn_fraction}")
        if not 0.0 < self.step_length_min_m <= self.step_length_max_m < math.inf:
            raise MapfilterError("PDR settings need 0 < step_length_min_m <= step_length_max_m, got "
                                 f"{self.step_length_min_m} and {self.step_length_max_m}")

    def kernel(self, inputs: StepInput | None, dt_s: float) -> MoveKernel:
        if inputs is None:
            return MoveKernel(stay, np.zeros(1), 0)
        n_steps = int(inputs.n_steps)
        if n_steps < 0:
            raise ValueError(f"n_steps must be >= 0, got {n_steps}")
        change = float(inputs.heading_change_rad)
        share = self.false_turn_fraction if abs(change) >= TURN_THRESHOLD_RAD else 0.0
        params = np.zeros(8)
        params[_P_STEPS] = n_steps
        params[_P_CHANGE] = change
        params[_P_HEADING_SIGMA] = self.heading_sigma_rad
        params[_P_FALSE_TURN] = (-math.inf if share <= 0.0 else math.inf if share >= 1.0
                                 else statistics.NormalDist().inv_cdf(share))
        params[_P_LENGTH_SIGMA] = STEP_LENGTH_WALK_SIGMA_M * math.sqrt(n_steps)
        params[_P_LENGTH_MIN] = self.step_length_min_m
        params[_P_LENGTH_MAX] = self.step_length_max_m
        params[_P_POSITION_SIGMA] = POSITION_SIGMA_M * math.sqrt(n_steps)
        return MoveKernel(_pdr_step, params, 3)

    def move(self, state: np.ndarray, normals: np.ndarray, inputs: StepInput | None, dt_s: float) -> np.ndarray:
        out = state.copy()
        if inputs is None:
            return out
        n = int(inputs.n_steps)
        change = float(inputs.heading_change_rad)
        share = self.false_turn_fraction if abs(change) >= TURN_THRESHOLD_RAD else 0.0
        ignores = normals[5] < (-math.inf if share <= 0 else math.inf if share >= 1
                                else statistics.NormalDist().inv_cdf(share))  # false turns
        heading = state[HEADING] + np.where(ignores, 0.0, change) + self.heading_sigma_rad * normals[0]
        heading = np.mod(heading + math.pi, 2 * math.pi) - math.pi
        length = state[STEP]
        if n > 0:
            length = np.clip(length + STEP_LENGTH_WALK_SIGMA_M * math.sqrt(n) * normals[1], self.step_length_min_m,
                             self.step_length_max_m)
        out[X] += n * length * np.cos(heading) + POSITION_SIGMA_M * math.sqrt(n) * normals[2]
        out[Y] += n * length * np.sin(heading) + POSITION_SIGMA_M * math.sqrt(n) * normals[3]
        out[HEADING] = heading
        out[STEP] = length
        return out

    def predict(self, state: np.ndarray, inputs: StepInput | None, dt_s: float) -> tuple[np.ndarray, np.ndarray, float]:
        xy = state[X:Y + 1].T
        if inputs is None or int(inputs.n_steps) == 0:
            return xy[None].copy(), np.ones(1), 0.0
        n = int(inputs.n_steps)
        change = float(inputs.heading_change_rad)
        distance = n * state[STEP]
        turned = xy + distance[:, None] * np.column_stack([np.cos(state[HEADING] + change),
                                                             np.sin(state[HEADING] + change)])
        # across the track the heading noise, along it the step length's walk, both the slack
        length = float(np.mean(state[STEP]))
        spread = math.sqrt(n * POSITION_SIGMA_M ** 2 + (n * length * self.heading_sigma_rad) ** 2
                           + n ** 3 * STEP_LENGTH_WALK_SIGMA_M ** 2)
        share = self.false_turn_fraction if abs(change) >= TURN_THRESHOLD_RAD else 0.0
        if share <= 0.0:
            return turned[None], np.ones(1), spread
        straight = xy + distance[:, None] * np.column_stack([np.cos(state[HEADING]), np.sin(state[HEADING])])
        return np.stack([turned, straight]), np.array([1.0 - share, share]), spread
