"""Motion models (the ``MotionModel`` interface): random walk, constant velocity, PDR.

Each ``propagate(particles, inputs, dt_s, rng)`` returns *new* particles and never mutates
its argument; the filter keeps the old positions for the wall check. Heading 0 = +x,
counter-clockwise, radians.
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import numpy as np
from numba import njit

from mapfilter.filter import fused
from mapfilter.filter.gaussian import standard_normal
from mapfilter.filter.models import MotionModel
from mapfilter.filter.particles import Particles
from mapfilter.threads import for_slices

__all__ = ["ConstantVelocityMotion", "PDRMotion", "RandomWalkMotion", "StepInput"]


def _moved(particles: Particles, **fields: np.ndarray) -> Particles:
    """A new Particles with ``fields`` replaced and every other array copied."""
    out = {f.name: getattr(particles, f.name) for f in dataclasses.fields(particles)}
    for name, value in out.items():
        out[name] = fields[name] if name in fields else value.copy()
    return Particles(**out)


@njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def _circle_walk(lo, hi, xy, phi, noise, radius_m, sigma_m, out):
    # eq. 6.6: x_k = x_{k-1} + r (cos phi, sin phi) + sigma e, phi in [0, 2 pi).
    # cos/sin from Taylor series of b = phi/2 - pi/2 in [-pi/2, pi/2] (|error| < 1e-7) and the
    # double-angle formulas: unlike libm's, they vectorise (3x faster than math.cos/sin).
    for i in range(lo, hi):
        b = 0.5 * phi[i] - 0.5 * math.pi
        b2 = b * b
        sin_b = b * (1.0 - b2 / 6.0 * (1.0 - b2 / 20.0 * (1.0 - b2 / 42.0 * (1.0 - b2 / 72.0 * (1.0 - b2 / 110.0)))))
        cos_b = 1.0 - b2 / 2.0 * (1.0 - b2 / 12.0 * (1.0 - b2 / 30.0 * (1.0 - b2 / 56.0 * (
            1.0 - b2 / 90.0 * (1.0 - b2 / 132.0)))))
        # phi/2 = b + pi/2: sin(phi/2) = cos b, cos(phi/2) = -sin b
        c = 1.0 - 2.0 * cos_b * cos_b
        s = -2.0 * cos_b * sin_b
        out[i, 0] = xy[i, 0] + radius_m * c + sigma_m * noise[i, 0]
        out[i, 1] = xy[i, 1] + radius_m * s + sigma_m * noise[i, 1]


@dataclasses.dataclass(frozen=True)
class RandomWalkMotion(MotionModel):
    """Random walk on a circle (Lund thesis eq. 6.6).

    Each particle jumps to a uniformly random point of the circle of radius
    ``radius_mps * dt`` around it, blurred by isotropic Gaussian noise of standard deviation
    ``sigma_mps * dt``: x_k = x_{k-1} + r (cos phi, sin phi) + e, phi ~ U[0, 2 pi),
    e ~ N(0, sigma^2 I). Thesis values: r = 1.5 dt, sigma = 0.5 dt.
    """

    radius_mps: float = 1.5  # the circle's radius per second (thesis: 1.5 m/s)
    sigma_mps: float = 0.5  # Gaussian blur per second (thesis: 0.5 m/s)

    def propagate(self, particles: Particles, inputs: object, dt_s: float, rng: np.random.Generator) -> Particles:
        n = len(particles)
        dt = max(float(dt_s), 0.0)
        phi = rng.uniform(0.0, 2.0 * math.pi, n)
        noise = standard_normal(rng, (n, 2))
        xy = np.empty((n, 2))
        for_slices(_circle_walk, n, np.ascontiguousarray(particles.xy_m, dtype=np.float64), phi, noise,
                   self.radius_mps * dt, self.sigma_mps * dt, xy)
        return _moved(particles, xy_m=xy)

    def kernel_move(self, inputs: object, dt_s: float) -> fused.Move:
        dt = max(float(dt_s), 0.0)
        return fused.circle_walk(self.radius_mps * dt, self.sigma_mps * dt)


@dataclasses.dataclass(frozen=True)
class ConstantVelocityMotion(MotionModel):
    """Constant velocity with random acceleration (Evennou & Marx prediction equation).

    x_k = x_{k-1} + v_{k-1} dt + a dt^2 / 2,  v_k = v_{k-1} + a dt,  a ~ N(0, accel_sigma^2 I).
    Speeds above ``max_speed_mps`` (a walking person) are scaled back to it.
    """

    accel_sigma_mps2: float = 0.5  # random acceleration (per axis)
    max_speed_mps: float = 2.0  # speeds above this (a walking person) are scaled back

    def propagate(self, particles: Particles, inputs: object, dt_s: float, rng: np.random.Generator) -> Particles:
        n = len(particles)
        dt = max(float(dt_s), 0.0)
        accel = self.accel_sigma_mps2 * standard_normal(rng, (n, 2))
        xy = particles.xy_m + particles.velocity_mps * dt + 0.5 * dt * dt * accel
        velocity = particles.velocity_mps + accel * dt
        speed = np.hypot(velocity[:, 0], velocity[:, 1])
        too_fast = speed > self.max_speed_mps
        if np.any(too_fast):
            velocity[too_fast] *= (self.max_speed_mps / speed[too_fast])[:, None]
        return _moved(particles, xy_m=xy, velocity_mps=velocity)

    def kernel_move(self, inputs: object, dt_s: float) -> fused.Move:
        return fused.constant_velocity(max(float(dt_s), 0.0), self.accel_sigma_mps2, self.max_speed_mps)


@dataclasses.dataclass(frozen=True)
class StepInput:
    """What pedestrian dead reckoning tells the motion model for one filter step.

    n_steps : steps detected since the last filter step (0 = standing).
    heading_change_rad : heading change over the interval (gyro about gravity), CCW positive.
    heading_abs_rad : absolute heading if known (compass / rotation vector); it replaces the
        particles' heading (plus noise) instead of the change.
    step_length_m : step length estimated by the PDR module; None = use the particles' own.
    """

    n_steps: int
    heading_change_rad: float
    heading_abs_rad: float | None = None
    step_length_m: float | None = None


@dataclasses.dataclass(frozen=True)
class PDRMotion(MotionModel):
    """Pedestrian dead reckoning with the state [x, y, heading, step length] (thesis eq. 8.23).

    Per particle: heading += change + N(0, heading_sigma^2) (a share ``false_turn_fraction``
    of particles ignores a change of at least ``turn_threshold_rad``: "false turns"),
    step length L += N(0, step_length_walk_sigma^2) clipped to [min, max] (a random walk the
    filter adapts through resampling), then xy += n_steps * L * (cos h, sin h) + N(0, (
    position_sigma^2 * n_steps)). With ``fixed_step_length_m`` or a step length in the input,
    that length (plus ``step_length_input_sigma_m`` noise) is used instead of the state.
    """

    walks_in_steps: ClassVar[bool] = True

    heading_sigma_rad: float = 0.05  # per filter step
    false_turn_fraction: float = 0.15  # thesis: 15 % of particles ignore a detected turn
    turn_threshold_rad: float = 0.35  # a change at least this large counts as a turn (~20 deg)
    step_length_walk_sigma_m: float = 0.02  # per step, random walk of the state (eq. 8.23)
    step_length_min_m: float = 0.4  # the state's step length stays within [min, max]
    step_length_max_m: float = 1.0  # (see step_length_min_m)
    fixed_step_length_m: float | None = None  # set: ignore the state
    step_length_input_sigma_m: float = 0.05  # noise on a given step length
    position_sigma_m: float = 0.05  # per step, lateral/longitudinal slack

    def propagate(self, particles: Particles, inputs: StepInput | None, dt_s: float,
                  rng: np.random.Generator) -> Particles:
        if inputs is None:
            return particles.copy()
        n = len(particles)
        n_steps = int(inputs.n_steps)
        if n_steps < 0:
            raise ValueError(f"n_steps must be >= 0, got {n_steps}")
        heading_noise = self.heading_sigma_rad * rng.standard_normal(n)
        if inputs.heading_abs_rad is not None:
            heading = float(inputs.heading_abs_rad) + heading_noise
        else:
            change = float(inputs.heading_change_rad)
            per_particle = np.full(n, change)
            if abs(change) >= self.turn_threshold_rad and self.false_turn_fraction > 0:
                per_particle[rng.random(n) < self.false_turn_fraction] = 0.0
            heading = particles.heading_rad + per_particle + heading_noise
        heading = np.mod(heading + math.pi, 2.0 * math.pi) - math.pi

        if n_steps > 0:
            step_length = np.clip(
                particles.step_length_m + self.step_length_walk_sigma_m * math.sqrt(n_steps) * rng.standard_normal(n),
                self.step_length_min_m, self.step_length_max_m)
        else:
            step_length = particles.step_length_m.copy()
        given = self.fixed_step_length_m if self.fixed_step_length_m is not None else inputs.step_length_m
        if given is not None:
            length = float(given) + self.step_length_input_sigma_m * rng.standard_normal(n)
        else:
            length = step_length
        distance = n_steps * length
        xy = particles.xy_m + distance[:, None] * np.stack([np.cos(heading), np.sin(heading)], axis=1)
        if n_steps > 0 and self.position_sigma_m > 0:
            xy += (self.position_sigma_m * math.sqrt(n_steps)) * rng.standard_normal((n, 2))
        return _moved(particles, xy_m=xy, heading_rad=heading, step_length_m=step_length)

    def kernel_move(self, inputs: StepInput | None, dt_s: float) -> fused.Move:
        if inputs is None:
            return fused.no_move()
        n_steps = int(inputs.n_steps)
        if n_steps < 0:
            raise ValueError(f"n_steps must be >= 0, got {n_steps}")
        change = float(inputs.heading_change_rad)
        turn = inputs.heading_abs_rad is None and abs(change) >= self.turn_threshold_rad
        given = self.fixed_step_length_m if self.fixed_step_length_m is not None else inputs.step_length_m
        return fused.pdr_step(
            n_steps, change, None if inputs.heading_abs_rad is None else float(inputs.heading_abs_rad),
            self.heading_sigma_rad, self.false_turn_fraction if turn else 0.0,
            self.step_length_walk_sigma_m * math.sqrt(n_steps), self.step_length_min_m, self.step_length_max_m,
            None if given is None else float(given), self.step_length_input_sigma_m,
            self.position_sigma_m * math.sqrt(n_steps) if n_steps > 0 and self.position_sigma_m > 0 else 0.0)
