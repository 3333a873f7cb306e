"""The map-aware regularised particle filter: one step, collapse detection and recovery.

One step (Evennou & Marx, with the Regularised Particle Filter of Musso, Oudjane & Le Gland):

  move -> kill the moves through walls -> floor changes (a building) -> weigh by the
  measurement -> collapse check -> recover | normalise (and, when the ESS is low, resample
  and jitter without crossing a wall) -> estimate

in the two passes of ``filter.kernels.passes``, which call the models' own compiled kernels
(``filter.models.interface``). Every random number comes from the generator the filter is
given: the passes draw counter-based numbers under one key per step drawn from it, so the same
seed gives the same track whatever the number of threads.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.filter.estimate import circular_mean, mode_estimate, toward, weighted_moments
from mapfilter.filter.events import CollapseEvent, StepReport
from mapfilter.filter.kernels import passes
from mapfilter.filter.models.building import OneFloor
from mapfilter.filter.models.interface import FloorModel, LikelihoodKernel, MeasurementModel, MotionModel, MoveKernel
from mapfilter.filter.particles import HEADING, STEP, X, Y, Particles
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import wall_grid

__all__ = ["FilterConfig", "ParticleFilter", "evaluate_log_likelihood"]

# exp(x) of a float64 underflows to 0 below about -745: the linear weights are gone
_LOG_UNDERFLOW = -745.0
# After a collapse without a recent measurement, particles are re-drawn around the last estimate
# within a radius that starts at 3 m and doubles with each further collapse, back to 3 m after
# 10 healthy steps; a measurement older than 10 s is not used to re-draw. Half of the re-drawn
# PDR particles keep an old heading (the heading may be what failed, or not).
_RECOVERY_RADIUS_M = 3.0
_RECOVERY_RADIUS_GROWTH = 2.0
_RECOVERY_RESET_STEPS = 10
_RECOVERY_MEASUREMENT_MAX_AGE_S = 10.0
_RECOVERY_HEADING_KEEP_FRACTION = 0.5
_NO_PARAMS = np.zeros(1)
# a jitter that crosses a wall is drawn again this often, then the particle stays at its parent:
# the draws come from the step's counter-based slots (at most ``kernels.draws.SLOTS``)
REGULARISE_TRIES = 3


@dataclasses.dataclass(frozen=True)
class FilterConfig:
    """Settings of :class:`ParticleFilter` (defaults follow Evennou & Marx where they say)."""

    n_particles: int = 10_000  # Evennou & Marx use 10,000
    resample_ess_fraction: float = 0.5  # resample when ESS = 1/sum(w^2) < fraction * N
    regularise: bool = True  # jitter after resampling (Regularised Particle Filter)
    bandwidth_scale: float = 1.0  # times the optimal bandwidth; < 1 for multimodal clouds
    init_samples: int = 50_000  # free-space candidates weighed when initialising from a measurement
    initial_step_length_m: float = 0.7  # PDR state at initialisation
    # Evennou & Marx's collapse rule: no particle agrees with the measurement (for a Gaussian fix
    # the value is minus half the squared distance in sigmas: -8 is 4 sigmas)
    min_log_likelihood: float | None = None  # best particle's log-likelihood below this = collapse; null: off

    def __post_init__(self) -> None:
        if not (isinstance(self.n_particles, int) and self.n_particles >= 1):
            raise MapfilterError(f"n_particles must be a whole number >= 1, got {self.n_particles!r}")
        if not 0.0 <= self.resample_ess_fraction <= 1.0:
            raise MapfilterError(f"resample_ess_fraction must be in [0, 1], got {self.resample_ess_fraction}")
        if not (math.isfinite(self.bandwidth_scale) and self.bandwidth_scale > 0):
            raise MapfilterError(f"bandwidth_scale must be a positive number, got {self.bandwidth_scale}")
        if not (isinstance(self.init_samples, int) and self.init_samples >= 1):
            raise MapfilterError(f"init_samples must be a whole number >= 1, got {self.init_samples!r}")
        if not (math.isfinite(self.initial_step_length_m) and self.initial_step_length_m > 0):
            raise MapfilterError(f"initial_step_length_m must be positive, got {self.initial_step_length_m}")


def optimal_bandwidth(n: int, d: int = 2) -> float:
    """Musso, Oudjane & Le Gland's optimal h = A N^(-1/(d+4)) of a Gaussian kernel, A = (4/(d+2))^(1/(d+4))."""
    return (4.0 / (d + 2.0)) ** (1.0 / (d + 4.0)) * max(int(n), 1) ** (-1.0 / (d + 4.0))


def bandwidth_and_root(resolution_m: float, covariance_m2: np.ndarray, n: int,
                       bandwidth_scale: float = 1.0) -> tuple[float, np.ndarray]:
    """(h, D): the jitter is h D eps with D D^T the covariance plus a pixel's variance on the
    diagonal (a cloud on one pixel still spreads), h the optimal bandwidth times ``bandwidth_scale``."""
    h = optimal_bandwidth(n) * bandwidth_scale
    cov = np.asarray(covariance_m2, dtype=np.float64) + resolution_m ** 2 * np.eye(2)
    try:
        root = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:  # NaN or not positive definite (a degenerate cloud)
        root = np.diag(np.sqrt(np.maximum(np.nan_to_num(np.diag(cov), nan=0.0), resolution_m ** 2)))
    return h, root


def _kernel_of(model: MeasurementModel | None, measurement: Any) -> LikelihoodKernel | None:
    if model is None or measurement is None:
        return LikelihoodKernel(passes.flat_log_likelihood, _NO_PARAMS)
    return model.kernel(measurement)


def evaluate_log_likelihood(model: MeasurementModel, measurement: Any, particles: Particles) -> np.ndarray:
    """(N,) the model's log-likelihood of ``measurement`` at every particle (its kernel run over them,
    or its ``log_likelihood``); NaN and +inf become -inf."""
    kernel = model.kernel(measurement)
    n = len(particles)
    if kernel is None:
        values = np.asarray(model.log_likelihood(particles, measurement), dtype=np.float64)
        if values.shape != (n,):
            raise ValueError(f"log_likelihood returned shape {values.shape}, expected ({n},)")
    else:
        values = passes.run_likelihood(kernel.function, kernel.params, particles.state)
    return np.where(np.isfinite(values), values, -np.inf)


class ParticleFilter:
    """A particle filter over one floor plan (a building's floors side by side in one).

    Parameters
    ----------
    floorplan : the map; particles live on its free pixels.
    motion : a ``MotionModel``.
    config : ``FilterConfig``.
    rng : the only source of randomness (same seed, same result).
    floors : the floor in the state (``filter.models.building.FloorChanges``, whose stack plan
        ``floorplan`` must be); None: one floor (``OneFloor``, not a single extra random draw).
    """

    def __init__(self, floorplan: FloorPlan, motion: MotionModel, config: FilterConfig | None = None,
                 rng: np.random.Generator | None = None, floors: FloorModel | None = None) -> None:
        if rng is None:
            raise ValueError("pass an explicit numpy.random.Generator (same seed, same result)")
        if floors is not None and floors.plan is not floorplan:
            raise ValueError("a FloorModel's particles live on its own plan: pass floors.plan as the floorplan")
        self.floorplan = floorplan
        self.floors: FloorModel = floors if floors is not None else OneFloor(floorplan)
        self.motion = motion
        self.config = config or FilterConfig()
        self.rng = rng
        self.walls = wall_grid(floorplan)
        self.particles: Particles | None = None
        self.estimate_xy_m: np.ndarray | None = None
        self.estimate_std_m: float = math.inf
        self.collapses: list[CollapseEvent] = []
        self.last_parents: np.ndarray | None = None  # (N,) each particle's parent in the step before (-1: none)
        self._step_index = 0
        self._estimate_floor_shares: np.ndarray | None = None  # the latest estimate's cloud's floor shares (a building)
        self._parents_unknown = True
        self._last_measurement: tuple[float, Any, Any] | None = None  # (t_s, model, measurement)
        self._recovery_level = 0
        self._healthy_steps = 0
        self.last_jitter_m2 = 0.0
        n = self.n
        self._spare: list[Particles] = []
        self._scratch = (np.empty(n, dtype=np.bool_), np.empty(n), passes.advance_sums(n))
        self._uniform_weights = np.full(n, 1.0 / n)  # a resampled cloud's weights (the reports share it)
        self._uniform_weights.flags.writeable = False

    @property
    def n(self) -> int:
        return int(self.config.n_particles)

    def _buffer(self) -> Particles:
        """Particles to write a step into: arrays of an earlier step when one is free. Reusing them
        spares the page faults of fresh memory, which the kernel serves one thread at a time."""
        while self._spare:
            buffer = self._spare.pop()
            if len(buffer) == self.n:
                return buffer
        return Particles.empty(self.n)

    # ---- initialisation --------------------------------------------------------------------
    def _new_particles(self, xy_m: np.ndarray, heading_rad: float | None) -> Particles:
        n = xy_m.shape[0]
        heading = (self.rng.uniform(-math.pi, math.pi, n) if heading_rad is None
                   else np.full(n, float(heading_rad)))
        return Particles.at(xy_m, heading_rad=heading, step_length_m=self.config.initial_step_length_m)

    def _set(self, particles: Particles) -> None:
        self.particles = particles
        self._set_estimate(particles.xy_m, particles.weight)
        self._parents_unknown = True

    def _set_estimate(self, xy_m: np.ndarray, weights: np.ndarray, std_m: float | None = None,
                      mean: np.ndarray | None = None) -> None:
        """The reported estimate: the cloud's weighted mean where it is free space, else the mean of
        its main mode (of its main floor in a building), reached from the previous estimate without
        crossing a wall (``filter.estimate``); the spread is the cloud's (``std_m`` when the caller
        has it). The mean of a split cloud falls in a wall and the track would cut through it; the
        mode everywhere costs IPIN 9 % (docs/accuracy.md, "The reported estimate")."""
        stack = getattr(self.floors, "stack", None)
        w = weights
        self._estimate_floor_shares = None
        if stack is not None:  # the floor holding most of the weight: a mode between floors' tiles is no place
            self._estimate_floor_shares = np.empty(stack.n_floors)  # the step's report takes them from here
            # its weights and their moments
            w, w_mean, cov = stack.main_floor_moments(xy_m, weights, self._estimate_floor_shares)
        if std_m is None or mean is None or stack is not None:  # the moments of the weight w, in one pass
            if stack is None:
                w_mean, cov = weighted_moments(xy_m, w)
            if std_m is None:  # the spread of the cloud (in a building: of its main floor's part)
                std_m = float(math.sqrt(max(0.5 * (cov[0, 0] + cov[1, 1]), 0.0)))
            if mean is None or stack is not None:
                mean = w_mean
        if np.isfinite(mean).all() and self.floorplan.is_free(mean[None, :])[0]:
            target = np.asarray(mean, dtype=np.float64)
        else:
            target = mode_estimate(self.floorplan, xy_m, w)
        previous = self.estimate_xy_m
        if previous is not None and (
                stack is None or stack.floor_of(previous[None, :])[0] == stack.floor_of(target[None, :])[0]):
            target = toward(self.floorplan, previous, target)  # a change of floor is a jump, not a move
        self.estimate_xy_m, self.estimate_std_m = target, float(std_m)

    def initialise_uniform(self, heading_rad: float | None = None) -> None:
        """N particles uniformly over the free space of the map."""
        self._set(self._new_particles(self.floorplan.sample_free(self.n, self.rng), heading_rad))

    def initialise_around(self, xy_m, radius_m: float, heading_rad: float | None = None) -> None:
        """N particles uniformly over the free space within ``radius_m`` of ``xy_m`` (the free
        pixels nearest to it if none is that close)."""
        self._set(self._new_particles(self._sample_free_near(np.asarray(xy_m, dtype=np.float64), radius_m),
                                      heading_rad))

    def initialise_from_measurement(self, t_s: float, model: MeasurementModel, measurement: Any,
                                    heading_rad: float | None = None) -> None:
        """Draw ``init_samples`` free points, weigh them by the measurement, draw N of them and
        spread the copies like after any resampling. Raises ``MapfilterError`` if the measurement
        has zero likelihood everywhere on the map."""
        xy = self._sample_from_likelihood(model, measurement)
        if xy is None:
            raise MapfilterError("the measurement has zero likelihood everywhere on the free space of the map")
        self._last_measurement = (float(t_s), model, measurement)
        self._set(self._new_particles(xy, heading_rad))

    def initialise_from_measurement_and_around(self, t_s: float, model: MeasurementModel, measurement: Any,
                                               xy_m, radius_m: float, share_around: float) -> None:
        """A mixture of two starts: a share of the particles within ``radius_m`` of ``xy_m``, the
        rest drawn from the measurement's likelihood (``initialise_from_measurement``): the data
        that follow decide between the two."""
        n_around = int(round(share_around * self.n))
        near = self._sample_free_near(np.asarray(xy_m, dtype=np.float64), radius_m)[:n_around]
        measured = self._sample_from_likelihood(model, measurement, self.n - n_around)
        if measured is None:
            raise MapfilterError("the measurement has zero likelihood everywhere on the free space of the map")
        self._last_measurement = (float(t_s), model, measurement)
        self._set(self._new_particles(np.concatenate([near, measured]), None))

    def _sample_free_near(self, centre_xy_m: np.ndarray, radius_m: float) -> np.ndarray:
        fp = self.floorplan
        rows, cols = fp.free_pixels
        if rows.size == 0:
            raise MapfilterError("the map has no free space to place particles in")
        centres = fp.pixel_to_world(np.stack([cols + 0.5, rows + 0.5], axis=-1))
        d2 = ((centres - centre_xy_m.reshape(1, 2)) ** 2).sum(axis=1)
        near = np.flatnonzero(d2 <= radius_m * radius_m)
        if near.size == 0:
            near = np.argsort(d2)[:64]
        pick = near[self.rng.integers(0, near.size, self.n)]
        uv = np.stack([cols[pick] + self.rng.random(self.n), rows[pick] + self.rng.random(self.n)], axis=-1)
        return fp.pixel_to_world(uv)

    def _sample_from_likelihood(self, model: MeasurementModel, measurement: Any, n: int | None = None
                                ) -> np.ndarray | None:
        """``n`` (default N) positions drawn from free-space candidates weighed by the measurement
        (None: it rules out every candidate); the candidates stand still, so the jitter's checks
        start there."""
        candidates = Particles.at(self.floorplan.sample_free(int(self.config.init_samples), self.rng))
        m = len(candidates)
        kernel = model.kernel(measurement)
        if kernel is None:
            values = evaluate_log_likelihood(model, measurement, candidates)
            kernel = LikelihoodKernel(passes.given_log_likelihood, values)
        state = candidates.state
        log_weight = np.zeros(m)
        e = np.empty(m)
        sums = passes.advance_sums(m)
        shift = state[X:Y + 1, 0].copy()
        passes.advance_pass(passes.Advance(passes.WEIGH, np.uint64(0), 0, float(shift[0]), float(shift[1])),
                            passes.move_call(passes.stay, _NO_PARAMS),
                            passes.likelihood_call(kernel.function, kernel.params), self.walls,
                            passes.Cloud(state, log_weight),
                            passes.Advanced(state, log_weight, np.zeros(m, dtype=np.bool_), e, sums))
        totals = passes.Totals(sums, shift)
        if totals.n_finite == 0:
            return None
        cov = totals.covariance_m2 if not self.floors.changes_floors else self.floors.covariance(
            candidates.xy_m, np.exp(log_weight - totals.log_normaliser))
        out = Particles.empty(self.n if n is None else n)
        self._resample(totals, e, state, state, shift, cov, out, walks=False)
        return out.xy_m.copy()

    # ---- the step ----------------------------------------------------------------------------
    def step(self, t_s: float, dt_s: float, motion_input: Any = None, model: MeasurementModel | None = None,
             measurement: Any = None) -> StepReport:
        """Advance the filter by ``dt_s`` seconds to time ``t_s`` and report what happened: move,
        kill the moves through walls, change floors, weigh by the measurement, then recover from
        a collapse or normalise (resampling and jittering when the ESS is low), and estimate."""
        if self.particles is None:
            raise RuntimeError("initialise the filter before stepping it")
        step_index = self._step_index
        self._step_index += 1
        self._estimate_floor_shares = None  # set by this step's estimate
        prev = self.particles
        measured = model is not None and measurement is not None
        self.last_jitter_m2 = 0.0  # the variance per axis of this step's jitter (the smoother's transition)
        if measured and model.locates(measurement):
            # a collapse re-draws from the latest measurement that says where, not only which floor
            self._last_measurement = (float(t_s), model, measurement)
        move: MoveKernel = self.motion.kernel(motion_input, dt_s)
        likelihood = _kernel_of(model, measurement)
        shift = self.estimate_xy_m if self.estimate_xy_m is not None and np.isfinite(self.estimate_xy_m).all() \
            else prev.state[X:Y + 1, 0].copy()
        moved = self._buffer()
        killed, e, sums = self._scratch
        key = self._draw_key()

        move_call = passes.move_call(move.function, move.params)

        def run(flags: int, kernel: LikelihoodKernel | None = None, src_log_weight: np.ndarray = prev.log_weight):
            kernel = kernel or likelihood or LikelihoodKernel(passes.flat_log_likelihood, _NO_PARAMS)
            # moved's arrays as they are now: a floor model may have given it new log weights
            passes.advance_pass(passes.Advance(flags, np.uint64(key), int(move.normal_pairs), float(shift[0]),
                                               float(shift[1])), move_call,
                                passes.likelihood_call(kernel.function, kernel.params), self.walls,
                                passes.Cloud(prev.state, src_log_weight),
                                passes.Advanced(moved.state, moved.log_weight, killed, e, sums))

        if not self.floors.changes_floors and likelihood is not None:
            run(passes.MOVE | passes.KILL | passes.WEIGH)  # the common step: one pass
        else:
            if self.floors.changes_floors:
                if self.motion.walks_in_steps and motion_input is not None and self.floors.has_stairs:
                    run(passes.MOVE)
                    moved.xy_m = self.floors.step_on_stairs(prev.xy_m, moved.xy_m, self.rng)
                    run(passes.KILL)
                else:  # no step shortened: the move and the wall check in one pass, block by block
                    run(passes.MOVE | passes.KILL)
                # floor changes after the wall check: the jump between floors is not a wall crossing
                moved.log_weight[:] = self.floors.change_floors(moved, moved.log_weight, dt_s, self.rng,
                                                                measurement)
            else:
                run(passes.MOVE | passes.KILL)
            if likelihood is None:
                values = evaluate_log_likelihood(model, measurement, moved)
                likelihood = LikelihoodKernel(passes.given_log_likelihood, values)
            run(passes.WEIGH, likelihood, moved.log_weight)
        totals = passes.Totals(sums, shift)
        cause = self._collapse_cause(totals, model if measured else None)
        before_xy, recovery, resampled = None, None, False
        if cause is not None:
            before_xy = self.estimate_xy_m
            new, parent, ess, recovery = self._recover_from_collapse(t_s, prev)
            weights = new.weight
            self._set_estimate(new.xy_m, weights)
            n_alive, means = 0, None
        else:
            n_alive = totals.n_finite
            new, parent, ess, resampled, weights, means = self._normalise_and_resample(prev, moved, totals, e, shift)
        self.particles = new
        self._spare.append(prev)  # its arrays are written again from the step after next
        if new is not moved:
            self._spare.append(moved)
        collapse = self._record_collapse(t_s, step_index, before_xy, cause, prev, recovery)
        self.last_parents = np.full(self.n, -1) if self._parents_unknown or cause is not None else parent
        self._parents_unknown = False
        return self._report(t_s, step_index, passes.killed_moves(killed, sums, prev.state, moved.state), new,
                            weights, ess, n_alive,
                            resampled, collapse, model if measured else None, measurement, means)

    def _draw_key(self) -> int:
        # one draw of the filter's generator keys every counter-based draw of a pass
        return int(self.rng.integers(0, 2 ** 63, dtype=np.int64))

    def _collapse_cause(self, totals: passes.Totals, model: MeasurementModel | None) -> str | None:
        if totals.n_alive == 0:
            return "all_killed_by_walls"
        if model is None:
            return None
        gate = self.config.min_log_likelihood
        if gate is not None and totals.best_log_likelihood < gate:
            return "measurement_inconsistent"
        peak = model.log_likelihood_peak
        # every weight underflows relative to the model's best possible value (only a model that
        # knows its peak can say: otherwise a large negative value may be a constant offset)
        if totals.n_finite == 0 or (peak is not None and totals.max_log_weight - peak < _LOG_UNDERFLOW):
            return "weights_underflow"
        return None

    def _normalise_and_resample(self, prev: Particles, moved: Particles, totals: passes.Totals, e: np.ndarray,
                                shift: np.ndarray):
        """Normalise; when the ESS 1 / sum(w^2) is low, resample and jitter (never through a wall).
        Returns (particles, parents, ESS, resampled, weights after, (heading, step length) means or None)."""
        cfg = self.config
        n = self.n
        self._healthy_steps += 1
        if self._healthy_steps >= _RECOVERY_RESET_STEPS:
            self._recovery_level = 0
        walks = self.motion.walks_in_steps
        if totals.ess >= cfg.resample_ess_fraction * n:
            moved.log_weight -= totals.log_normaliser
            weights = np.exp(moved.log_weight)
            self._estimate(moved, weights, totals.mean_xy_m, totals.covariance_m2)
            means = (circular_mean(moved.heading_rad, weights), float(weights @ moved.step_length_m)) if walks else None
            return moved, np.arange(n), float(totals.ess), False, weights, means
        cov = totals.covariance_m2 if not self.floors.changes_floors else self.floors.covariance(
            moved.xy_m, np.exp(moved.log_weight - totals.log_normaliser))
        new = self._buffer()
        parent, s = self._resample(totals, e, prev.state, moved.state, shift, cov, new, walks)
        weights = self._uniform_weights
        ex, ey = s["dx"] / n, s["dy"] / n
        cov_new = np.array([[s["dxx"] / n - ex * ex, s["dxy"] / n - ex * ey],
                            [s["dxy"] / n - ex * ey, s["dyy"] / n - ey * ey]])
        self._estimate(new, weights, shift + np.array([ex, ey]), cov_new)
        means = (math.atan2(s["sin_heading"], s["cos_heading"]), float(s["step_length_m"] / n)) if walks else None
        return new, parent, float(totals.ess), True, weights, means

    def _resample(self, totals: passes.Totals, e: np.ndarray, origin: np.ndarray, src: np.ndarray,
                  shift: np.ndarray, cov: np.ndarray, dst: Particles, walks: bool) -> tuple[np.ndarray, dict]:
        """Systematic resampling of ``src`` into ``dst`` (equal weights) and the jitter; (parents, the
        new cloud's sums by ``passes.RESAMPLE_SUMS`` field)."""
        cfg = self.config
        n_out = len(dst)
        u = float(self.rng.random())
        key = self._draw_key()
        tries = REGULARISE_TRIES if cfg.regularise else 0
        h, root = bandwidth_and_root(self.floorplan.resolution_m, cov, n_out, cfg.bandwidth_scale)
        self.last_jitter_m2 = 0.5 * h * h * float(np.trace(root @ root.T)) if tries else 0.0
        parent = np.empty(n_out, dtype=np.int64)
        sums = passes.resample_sums(n_out)
        passes.resample_pass(totals, e, u, key, tries, walks, h, root, self.walls, origin, src, shift,
                             passes.Resampled(parent, dst.state, dst.log_weight, sums))
        # added in block order, as a (blocks, fields) array (every field is a float64)
        summed = sums.view(np.float64).reshape(len(sums), -1).sum(axis=0)
        return parent, dict(zip(passes.RESAMPLE_SUMS.names, summed.tolist()))

    def _estimate(self, particles: Particles, weights: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> None:
        """The estimate of a normalised cloud (``_set_estimate``); ``mean`` and ``cov`` are its
        moments from the pass' block sums (one floor: the spread without another pass)."""
        std = None if self.floors.changes_floors else float(math.sqrt(max(0.5 * (cov[0, 0] + cov[1, 1]), 0.0)))
        self._set_estimate(particles.xy_m, weights, std, None if self.floors.changes_floors else mean)

    # ---- collapse recovery -------------------------------------------------------------------
    def _recover_from_collapse(self, t_s: float, prev: Particles) -> tuple[Particles, np.ndarray, float, str]:
        """A collapse: re-initialise (no particle has a parent). Returns (particles, parents (all
        -1), ESS, how it recovered)."""
        recovery, new = self._recover(t_s)
        # PDR state: the walker's stride survives a collapse; the heading may be what failed,
        # so a share keeps an old particle's heading and the rest start with a random one
        donors = self.rng.integers(0, len(prev), self.n)
        keep = self.rng.random(self.n) < _RECOVERY_HEADING_KEEP_FRACTION
        new.state[HEADING] = np.where(keep, prev.state[HEADING, donors], new.state[HEADING])
        new.state[STEP] = prev.state[STEP, donors]
        self._recovery_level += 1
        self._healthy_steps = 0
        return new, np.full(self.n, -1, dtype=np.int64), float(self.n), recovery

    def _recover(self, t_s: float) -> tuple[str, Particles]:
        """Re-initialise after a collapse: from the latest measurement's likelihood over the map,
        else uniformly around the last estimate with a radius growing with repeated collapses."""
        last = self._last_measurement
        if last is not None and float(t_s) - last[0] <= _RECOVERY_MEASUREMENT_MAX_AGE_S:
            xy = self._sample_from_likelihood(last[1], last[2])
            if xy is not None:
                return "likelihood_over_map", self._new_particles(xy, None)
        x_min, x_max, y_min, y_max = self.floorplan.extent_m
        centre = self.estimate_xy_m if self.estimate_xy_m is not None else ((x_min + x_max) / 2, (y_min + y_max) / 2)
        radius = _RECOVERY_RADIUS_M * _RECOVERY_RADIUS_GROWTH ** self._recovery_level
        width_m, height_m = self.floorplan.size_m
        if radius >= math.hypot(width_m, height_m):
            return "uniform", self._new_particles(self.floorplan.sample_free(self.n, self.rng), None)
        xy = self._sample_free_near(np.asarray(centre, dtype=np.float64), radius)
        return f"around_estimate_r{radius:.1f}m", self._new_particles(xy, None)

    def _record_collapse(self, t_s: float, step_index: int, before_xy: np.ndarray | None, cause: str | None,
                         prev: Particles, recovery: str | None) -> CollapseEvent | None:
        """The step's collapse (appended to ``collapses``), or None; called once the recovered
        cloud's estimate is set."""
        if cause is None:
            return None
        collapse = CollapseEvent(
            t_s=float(t_s), step_index=step_index,
            xy_m=(float(before_xy[0]), float(before_xy[1])) if before_xy is not None else (math.nan, math.nan),
            cause=cause, particles_lost=int(np.count_nonzero(np.isfinite(prev.log_weight))), recovery=recovery,
            recovered_xy_m=(float(self.estimate_xy_m[0]), float(self.estimate_xy_m[1])))
        self.collapses.append(collapse)
        return collapse

    def _report(self, t_s: float, step_index: int, killed_moves: tuple[np.ndarray, np.ndarray], new: Particles,
                weights: np.ndarray, ess: float, n_alive: int, resampled: bool,
                collapse: CollapseEvent | None, model: MeasurementModel | None, measurement: Any,
                means: tuple[float, float] | None) -> StepReport:
        """What happened this step, for the viewer and the tracks."""
        steps = self.motion.walks_in_steps
        if steps and means is None:
            means = (circular_mean(new.heading_rad, weights), float(weights @ new.step_length_m))
        fix_xy = model.fix_xy_m(measurement) if model is not None else None
        return StepReport(
            t_s=float(t_s), step_index=step_index, estimate_xy_m=self.estimate_xy_m.copy(),
            estimate_std_m=float(self.estimate_std_m), ess=ess, n_particles=self.n, n_alive=n_alive,
            n_killed=len(killed_moves[0]), resampled=resampled, particles_xy_m=new.xy_m,
            particles_weight=weights, killed_from_xy_m=killed_moves[0], killed_to_xy_m=killed_moves[1],
            collapse=collapse,
            heading_rad=means[0] if steps else None,
            step_length_m=means[1] if steps else None,
            fix_xy_m=None if fix_xy is None else np.asarray(fix_xy, dtype=np.float64).ravel()[:2].copy(),
            heard_ap_xy_m=model.heard_ap_xy_m(measurement) if model is not None else None,
            path_loss=model.viewer_state() if model is not None else None,
            # the estimate was made of this cloud (new, weights) this step: its floor shares are the report's
            **self.floors.report(new.xy_m, weights, self.estimate_xy_m, self._estimate_floor_shares),
        )
