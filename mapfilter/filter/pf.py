"""The map-aware regularised particle filter: the step loop, collapse detection and recovery.

One step (Evennou & Marx, with the Regularised Particle Filter of Musso, Oudjane & Le Gland),
each stage a method of ``ParticleFilter``:

  move (``_move``) -> wall kill (``_kill_wall_crossers``) -> floor changes
  (``FloorModel.change_floors``) -> measurement update and collapse check (``_weigh``) ->
  recovery from a collapse (``_recover_from_collapse``) | normalise, ESS, resample +
  regularise (``_normalise_and_resample``) -> estimate -> lineage (``_record_lineage``) ->
  report (``_report``)

The filter calls its models only through the interfaces of ``filter/models.py``; it reports
what happened as a ``StepReport`` and draws every random number from the generator it is given.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
from numba import njit

from mapfilter.errors import MapfilterError
from mapfilter.filter import fused
from mapfilter.filter.ancestry import Ancestry
from mapfilter.filter.estimate import circular_mean
from mapfilter.filter.events import CollapseEvent, StepReport
from mapfilter.filter.floors import OneFloor
from mapfilter.filter.models import FloorModel, MeasurementModel, MotionModel
from mapfilter.filter.particles import Particles
from mapfilter.filter.regularise import KERNELS, bandwidth_and_root, regularise
from mapfilter.filter.resample import get_resampler
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import clearance_px, crosses_wall
from mapfilter.threads import for_slices

__all__ = ["FilterConfig", "ParticleFilter"]

# exp(x) of a float64 underflows to 0 below about -745: the linear weights are gone
_LOG_UNDERFLOW = -745.0


@njit(cache=True, nogil=True, error_model="numpy")
def _gather_rows(lo, hi, a, index, out):
    # out[i] = a[index[i]] for (N, 2) arrays: numpy's fancy indexing of 2-D rows is ~5x slower
    for i in range(lo, hi):
        j = index[i]
        out[i, 0] = a[j, 0]
        out[i, 1] = a[j, 1]


def _rows(a: np.ndarray, index: np.ndarray) -> np.ndarray:
    out = np.empty((index.shape[0], 2), dtype=np.float64)
    for_slices(_gather_rows, index.shape[0], np.ascontiguousarray(a, dtype=np.float64), index, out)
    return out


def _take(particles: Particles, index: np.ndarray) -> Particles:
    """``particles.take(index)`` with the fast row gather."""
    return Particles(xy_m=_rows(particles.xy_m, index), log_weight=particles.log_weight[index],
                     velocity_mps=_rows(particles.velocity_mps, index), heading_rad=particles.heading_rad[index],
                     step_length_m=particles.step_length_m[index])


def _logsumexp(log_w: np.ndarray) -> float:
    """log(sum(exp(log_w))) for an array with at least one finite entry (-inf entries allowed)."""
    m = float(np.max(log_w))
    return m + math.log(float(np.sum(np.exp(log_w - m))))


@dataclasses.dataclass(frozen=True)
class FilterConfig:
    """Settings of :class:`ParticleFilter` (defaults follow Evennou & Marx where they say)."""

    n_particles: int = 10_000  # Evennou & Marx use 10,000
    resample_ess_fraction: float = 0.5  # resample when ESS = 1/sum(w^2) < fraction * N
    resampler: str = "systematic"  # systematic | stratified | residual | multinomial
    regularise: bool = True  # jitter after resampling (Regularised Particle Filter)
    kernel: str = "gaussian"  # gaussian | epanechnikov
    bandwidth_scale: float = 1.0  # times the optimal bandwidth; < 1 for multimodal clouds
    regularise_tries: int = 3  # redraws of a jitter that crosses a wall, then stay at the parent
    init_samples: int = 50_000  # free-space candidates weighed when initialising from a measurement
    initial_step_length_m: float = 0.7  # PDR state at initialisation
    min_log_likelihood: float | None = None  # best particle's log-likelihood below this = collapse; None = off
    recovery_radius_m: float = 3.0  # first radius around the last estimate when no measurement is at hand
    recovery_radius_growth: float = 2.0  # the radius multiplies by this after each further collapse
    recovery_reset_steps: int = 10  # healthy steps after which the radius starts small again
    recovery_measurement_max_age_s: float = 10.0  # an older measurement is not used to recover
    recovery_heading_keep_fraction: float = 0.5  # PDR: share of recovered particles keeping an old heading
    # for motion models that give its terms (random walk, constant velocity, PDR; any measurement
    # model, a Gaussian fix and trilateration inside the pass) with the systematic resampler and
    # the Gaussian kernel; its draws differ from the named stages' (the same distributions). Its
    # kernels add about 2 s to the first run after install (numba compiles them once), and below
    # 20,000 particles a walk's time goes elsewhere (docs/benchmarks.md)
    fused_from_particles: int | None = 20_000  # the fused step (filter/fused.py) from this many on; None: never

    def __post_init__(self) -> None:
        if int(self.n_particles) < 1:
            raise MapfilterError(f"n_particles must be at least 1, got {self.n_particles}")
        if not 0.0 <= self.resample_ess_fraction <= 1.0:
            raise MapfilterError(f"resample_ess_fraction must be in [0, 1], got {self.resample_ess_fraction}")
        get_resampler(self.resampler)
        if self.kernel not in KERNELS:
            raise MapfilterError(f"kernel must be one of {KERNELS}, got {self.kernel!r}")
        if self.init_samples < 1 or self.recovery_radius_m <= 0 or self.recovery_radius_growth < 1.0:
            raise MapfilterError("init_samples, recovery_radius_m must be positive and recovery_radius_growth >= 1")


class ParticleFilter:
    """A particle filter over one floor plan.

    Parameters
    ----------
    floorplan : the map; particles live on its free pixels.
    motion : a ``MotionModel``.
    config : ``FilterConfig``.
    rng : the only source of randomness (same seed, same result).
    floors : the floor in the state (``filter.models.FloorModel``): a building's
        ``filter.floors.FloorChanges``, whose stack plan ``floorplan`` must then be; particles
        change floor after the wall check, the estimate is taken on the floor with most weight
        and the jitter's spread in the building frame. None: one floor (``OneFloor``, not a
        single extra random draw).
    keep_ancestry : record every step's parents for ``smoothed_track`` (N * 20 bytes per step).
    """

    def __init__(self, floorplan: FloorPlan, motion: MotionModel, config: FilterConfig | None = None,
                 rng: np.random.Generator | None = None, floors: FloorModel | None = None,
                 keep_ancestry: bool = False) -> None:
        if rng is None:
            raise ValueError("pass an explicit numpy.random.Generator (same seed, same result)")
        if floors is not None and floors.plan is not floorplan:
            raise ValueError("a FloorModel's particles live on its own plan: pass floors.plan as the floorplan")
        self.floorplan = floorplan
        self.floors: FloorModel = floors if floors is not None else OneFloor(floorplan)
        self.motion = motion
        self.config = config or FilterConfig()
        self.rng = rng
        self._resample = get_resampler(self.config.resampler)
        self.particles: Particles | None = None
        self.estimate_xy_m: np.ndarray | None = None
        self.estimate_std_m: float = math.inf
        self.collapses: list[CollapseEvent] = []
        self.ancestry: Ancestry | None = Ancestry() if keep_ancestry else None
        self._step_index = 0
        self._lineage_broken = True
        self._last_measurement: tuple[float, Any, Any] | None = None  # (t_s, model, measurement)
        self._recovery_level = 0
        self._healthy_steps = 0
        # the fused step applies with these settings (and models that offer its terms)
        cfg = self.config
        self._one_floor = floors is None  # no floor changes: move, wall check and weighing in one pass
        self._fusable = (cfg.fused_from_particles is not None and self.n >= cfg.fused_from_particles
                         and cfg.resampler == "systematic" and cfg.kernel == "gaussian"
                         and int(cfg.regularise_tries) <= fused.SLOTS)

    @property
    def n(self) -> int:
        return int(self.config.n_particles)

    # ---- initialisation --------------------------------------------------------------------
    def _new_particles(self, xy_m: np.ndarray, heading_rad: float | None) -> Particles:
        n = xy_m.shape[0]
        heading = (self.rng.uniform(-math.pi, math.pi, n) if heading_rad is None
                   else np.full(n, float(heading_rad)))
        return Particles.at(xy_m, heading_rad=heading, step_length_m=self.config.initial_step_length_m)

    def _set(self, particles: Particles) -> None:
        self.particles = particles
        self.estimate_xy_m, self.estimate_std_m, _ = self.floors.estimate(particles.xy_m, particles.weight)
        self._lineage_broken = True

    def initialise_uniform(self, heading_rad: float | None = None) -> None:
        """N particles uniformly over the free space of the map."""
        self._set(self._new_particles(self.floorplan.sample_free(self.n, self.rng), heading_rad))

    def initialise_around(self, xy_m, radius_m: float, heading_rad: float | None = None) -> None:
        """N particles uniformly over the free space within ``radius_m`` of ``xy_m``.

        If no free pixel lies that close, the free pixels nearest to ``xy_m`` are used.
        """
        self._set(self._new_particles(self._sample_free_near(np.asarray(xy_m, dtype=np.float64), radius_m),
                                      heading_rad))

    def initialise_from_measurement(self, t_s: float, model: MeasurementModel, measurement: Any,
                                    heading_rad: float | None = None) -> None:
        """Draw ``init_samples`` free points, weigh them by the measurement, sample N of them.

        Works with any measurement model. Raises ``MapfilterError`` if the measurement has
        zero likelihood everywhere on the map.
        """
        xy = self._sample_from_likelihood(model, measurement)
        if xy is None:
            raise MapfilterError("the measurement has zero likelihood everywhere on the free space of the map")
        self._last_measurement = (float(t_s), model, measurement)
        self._set(self._new_particles(xy, heading_rad))

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

    def _sample_from_likelihood(self, model: MeasurementModel, measurement: Any) -> np.ndarray | None:
        candidates = self.floorplan.sample_free(int(self.config.init_samples), self.rng)
        ll = self._checked_log_likelihood(model, Particles.at(candidates), measurement)
        if not np.isfinite(ll).any():
            return None
        if self._fusable:
            return self._fused_sample(candidates, ll)
        w = np.exp(ll - ll.max())
        picked = self._resample(w, self.n, self.rng)
        xy = candidates[picked]
        # the candidates repeat: spread the copies like after any resampling (wall-safe jitter)
        if self.config.regularise:
            cov = self.floors.covariance(candidates, w)
            xy, _ = regularise(self.floorplan, xy, cov, self.rng, self.config.kernel,
                               self.config.bandwidth_scale, self.config.regularise_tries)
        return xy

    def _fused_sample(self, candidates: np.ndarray, ll: np.ndarray) -> np.ndarray:
        """N of the weighed candidates, drawn and spread as by the fused step's second pass."""
        cfg = self.config
        state = fused.weigh(candidates, np.zeros(len(candidates)), fused.given_values(ll))
        totals = fused.totals(state, (0.0, 0.0))
        cov = totals.covariance_m2 if self._one_floor else self.floors.covariance(
            candidates, np.exp(state.log_weight - totals.log_normaliser))
        u = float(self.rng.random())
        key = self._draw_key()
        tries = max(int(cfg.regularise_tries), 1) if cfg.regularise else 0
        h, root = bandwidth_and_root(self.floorplan, cov, self.n, cfg.kernel, cfg.bandwidth_scale) if cfg.regularise \
            else (0.0, np.eye(2))
        # the candidates stand still: the jitter's second wall check (from the position before a
        # step) is the first one again
        out = fused.resample_regularise(state, totals, state.xy_m, u=u, key=key, tries=tries, h=h, root=root,
                                        floorplan=self.floorplan, clearance=clearance_px(self.floorplan),
                                        shift_xy_m=(0.0, 0.0), n_out=self.n)
        return out.xy_m

    def _checked_log_likelihood(self, model: MeasurementModel, particles: Particles, measurement: Any) -> np.ndarray:
        ll = np.asarray(model.log_likelihood(particles, measurement), dtype=np.float64)
        if ll.shape != (len(particles),):
            raise ValueError(f"log_likelihood returned shape {ll.shape}, expected ({len(particles)},)")
        # NaN or +inf is a model defect: such a particle gets no weight instead of poisoning the sum
        return np.where(np.isfinite(ll), ll, -np.inf)

    # ---- the step ----------------------------------------------------------------------------
    def step(self, t_s: float, dt_s: float, motion_input: Any = None, model: MeasurementModel | None = None,
             measurement: Any = None) -> StepReport:
        """Advance the filter by ``dt_s`` seconds to time ``t_s`` and report what happened.

        The stages, in the module docstring's order: move, kill the moves through walls, change
        floors, weigh by the measurement, then either recover from a collapse or normalise (and
        resample and regularise when the ESS is low), and estimate.
        """
        if self.particles is None:
            raise RuntimeError("initialise the filter before stepping it")
        move = self.motion.kernel_move(motion_input, dt_s) if self._fusable else None
        if move is not None:
            return self._fused_step(t_s, dt_s, motion_input, model, measurement, move)
        step_index = self._step_index
        self._step_index += 1
        prev = self.particles
        moved = self._move(prev, motion_input, dt_s)
        log_w, killed = self._kill_wall_crossers(prev, moved)
        # floor changes after the wall check: the jump between floors is not a wall crossing
        log_w = self.floors.change_floors(moved, log_w, dt_s, self.rng, measurement)
        cause = None if np.isfinite(log_w).any() else "all_killed_by_walls"
        log_w, cause = self._weigh(t_s, moved, log_w, cause, model, measurement)
        n_alive = int(np.count_nonzero(np.isfinite(log_w))) if cause is None else 0
        before_xy, recovery = None, None  # the estimate before a collapse, and how it recovered
        if cause is not None:
            before_xy = self.estimate_xy_m
            new, parent, ess, recovery = self._recover_from_collapse(t_s, prev)
            resampled, w = False, None
        else:
            new, parent, ess, resampled, w = self._normalise_and_resample(prev, moved, log_w)
        self.particles = new
        weights = new.weight
        self.estimate_xy_m, self.estimate_std_m, _ = self.floors.estimate(new.xy_m, weights)
        collapse = self._record_collapse(t_s, step_index, before_xy, cause, prev, recovery)
        self._record_lineage(t_s, parent, new, weights, w if resampled else None, broken=cause is not None)
        return self._report(t_s, step_index, prev, moved, new, weights, killed, ess, n_alive, resampled, collapse,
                            model, measurement)

    def _fused_step(self, t_s: float, dt_s: float, motion_input: Any, model: MeasurementModel | None,
                    measurement: Any, move: fused.Move) -> StepReport:
        """The step of ``step`` in the two passes of ``filter/fused.py`` (same stages, same
        collapse rules, same report; the draws come from a per-step key of ``self.rng``)."""
        step_index = self._step_index
        self._step_index += 1
        prev = self.particles
        plan = self.floorplan
        clearance = clearance_px(plan)
        shift = self.estimate_xy_m if self.estimate_xy_m is not None and np.isfinite(self.estimate_xy_m).all() \
            else np.zeros(2)
        state_args = (np.ascontiguousarray(prev.xy_m, dtype=np.float64),
                      np.ascontiguousarray(prev.velocity_mps, dtype=np.float64),
                      np.ascontiguousarray(prev.heading_rad, dtype=np.float64),
                      np.ascontiguousarray(prev.step_length_m, dtype=np.float64),
                      np.ascontiguousarray(prev.log_weight, dtype=np.float64))
        key = self._draw_key()
        measured = model is not None and measurement is not None
        terms = model.kernel_likelihood(measurement) if measured else None
        if measured and model.locates(measurement):
            self._last_measurement = (float(t_s), model, measurement)

        def moved_particles(state: fused.Advanced, log_weight: np.ndarray) -> Particles:
            return Particles(xy_m=state.xy_m, log_weight=log_weight, velocity_mps=state.velocity_mps,
                             heading_rad=state.heading_rad, step_length_m=state.step_length_m)

        if self._one_floor and (terms is not None or not measured):
            # stages 1-3 in one pass
            state = fused.advance(*state_args, move=move, key=key, floorplan=plan, clearance=clearance,
                                  likelihood=terms if terms is not None else fused.flat(), shift_xy_m=shift)
            moved = moved_particles(state, prev.log_weight)
        else:
            if self._one_floor:
                state = fused.advance(*state_args, move=move, key=key, floorplan=plan, clearance=clearance)
                moved = moved_particles(state, prev.log_weight)
            else:
                state = fused.advance(*state_args, move=move, key=key)
                if self.motion.walks_in_steps and motion_input is not None:
                    state.xy_m = np.ascontiguousarray(self.floors.step_on_stairs(prev.xy_m, state.xy_m, self.rng))
                fused.advance(*state_args, move=None, key=key, floorplan=plan, clearance=clearance, state=state)
                moved = moved_particles(state, prev.log_weight.copy())
                # floor changes after the wall check: the jump between floors is not a wall crossing
                state.log_weight = np.ascontiguousarray(
                    self.floors.change_floors(moved, state.log_weight, dt_s, self.rng, measurement), dtype=np.float64)
            if terms is None and measured:
                terms = fused.given_values(self._checked_log_likelihood(model, moved, measurement))
            fused.advance(*state_args, move=None, key=key, likelihood=terms if terms is not None else fused.flat(),
                          shift_xy_m=shift, state=state)
        totals = fused.totals(state, shift)
        killed = np.flatnonzero(state.killed)
        cause = None if totals.n_alive_after_kill > 0 else "all_killed_by_walls"
        if cause is None and measured:
            gate = self.config.min_log_likelihood
            if gate is not None and totals.best_log_likelihood < gate:
                cause = "measurement_inconsistent"
            else:
                peak = model.log_likelihood_peak
                if totals.n_finite == 0 or (peak is not None and totals.max_log_weight - peak < _LOG_UNDERFLOW):
                    cause = "weights_underflow"
        means = None
        before_xy, recovery = None, None  # the estimate before a collapse, and how it recovered
        if cause is not None:
            before_xy = self.estimate_xy_m
            new, parent, ess, recovery = self._recover_from_collapse(t_s, prev)
            resampled, w, n_alive = False, None, 0
            weights = new.weight
            self.estimate_xy_m, self.estimate_std_m, _ = self.floors.estimate(new.xy_m, weights)
        else:
            new, parent, ess, resampled, w, weights, means = self._fused_normalise_and_resample(
                prev, state, totals, shift, clearance)
            n_alive = totals.n_finite
        self.particles = new
        collapse = self._record_collapse(t_s, step_index, before_xy, cause, prev, recovery)
        if self.ancestry is not None and resampled and w is None:
            w = np.exp(state.log_weight - totals.log_normaliser)
        self._record_lineage(t_s, parent, new, weights, w if resampled else None, broken=cause is not None)
        return self._report(t_s, step_index, prev, moved, new, weights, killed, ess, n_alive, resampled, collapse,
                            model, measurement, means)

    def _draw_key(self) -> int:
        # one draw of the filter's generator keys every counter-based draw of a fused pass
        return int(self.rng.integers(0, 2 ** 63, dtype=np.int64))

    def _fused_normalise_and_resample(self, prev: Particles, state: fused.Advanced, totals: fused.Totals,
                                      shift: np.ndarray, clearance: np.ndarray):
        """Stage 4b and the estimate from the passes' sums: (particles, parents, ESS, resampled,
        the normalised weights before resampling or None, the weights after, (heading, step length) means or None)."""
        cfg = self.config
        n = self.n
        self._healthy_steps += 1
        if self._healthy_steps >= cfg.recovery_reset_steps:
            self._recovery_level = 0
        ess = float(totals.ess)
        walks = self.motion.walks_in_steps
        if ess >= cfg.resample_ess_fraction * n:
            log_w = state.log_weight - totals.log_normaliser
            weights = np.exp(log_w)
            new = Particles(xy_m=state.xy_m, log_weight=log_w, velocity_mps=state.velocity_mps,
                            heading_rad=state.heading_rad, step_length_m=state.step_length_m)
            mean, cov = totals.mean_xy_m, totals.covariance_m2
            self._fused_estimate(new, weights, mean, cov)
            means = (circular_mean(new.heading_rad, weights), float(weights @ new.step_length_m)) if walks else None
            return new, np.arange(n), ess, False, weights, weights, means
        if self._one_floor:
            cov = totals.covariance_m2
            w = None
        else:
            w = np.exp(state.log_weight - totals.log_normaliser)
            cov = self.floors.covariance(state.xy_m, w)
        u = float(self.rng.random())
        key = self._draw_key()
        tries = max(int(cfg.regularise_tries), 1) if cfg.regularise else 0
        h, root = bandwidth_and_root(self.floorplan, cov, n, cfg.kernel, cfg.bandwidth_scale) if cfg.regularise \
            else (0.0, np.eye(2))
        out = fused.resample_regularise(state, totals, prev.xy_m, u=u, key=key, tries=tries, h=h, root=root,
                                        floorplan=self.floorplan, clearance=clearance, shift_xy_m=shift,
                                        walks=walks)
        new = Particles(xy_m=out.xy_m, log_weight=np.full(n, -math.log(n)), velocity_mps=out.velocity_mps,
                        heading_rad=out.heading_rad, step_length_m=out.step_length_m)
        weights = np.full(n, math.exp(-math.log(n)))  # = new.weight, without a pass of exp
        s = out.sums.sum(axis=0)
        ex, ey = s[fused.R_X] / n, s[fused.R_Y] / n
        cov = np.array([[s[fused.R_XX] / n - ex * ex, s[fused.R_XY] / n - ex * ey],
                        [s[fused.R_XY] / n - ex * ey, s[fused.R_YY] / n - ey * ey]])
        self._fused_estimate(new, weights, shift + np.array([ex, ey]), cov)
        means = (math.atan2(s[fused.R_SIN], s[fused.R_COS]), float(s[fused.R_STEP] / n)) if walks else None
        return new, out.parent, ess, True, w, weights, means

    def _fused_estimate(self, new: Particles, weights: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> None:
        """The estimate from the weighted moments when they are a free point of one floor (as
        ``estimate.weighted_estimate``), else from the floor model."""
        if self._one_floor and np.isfinite(mean).all() and self.floorplan.is_free(mean[None, :])[0]:
            self.estimate_xy_m = mean
            self.estimate_std_m = float(math.sqrt(max(0.5 * (cov[0, 0] + cov[1, 1]), 0.0)))
        else:
            self.estimate_xy_m, self.estimate_std_m, _ = self.floors.estimate(new.xy_m, weights)

    def _move(self, prev: Particles, motion_input: Any, dt_s: float) -> Particles:
        """Stage 1: the motion model moves every particle; on stairs a step advances one tread."""
        moved = self.motion.propagate(prev, motion_input, dt_s, self.rng)
        if self.motion.walks_in_steps and motion_input is not None:
            moved.xy_m = self.floors.step_on_stairs(prev.xy_m, moved.xy_m, self.rng)
        return moved

    def _kill_wall_crossers(self, prev: Particles, moved: Particles) -> tuple[np.ndarray, np.ndarray]:
        """Stage 2: a move through a wall kills its particle (Evennou & Marx: P_m = 0 -> weight 0).
        Returns (log weights, indices of the particles killed this step)."""
        killed = crosses_wall(self.floorplan, prev.xy_m, moved.xy_m) & np.isfinite(prev.log_weight)
        log_w = prev.log_weight.copy()
        log_w[killed] = -np.inf
        return log_w, np.flatnonzero(killed)

    def _weigh(self, t_s: float, moved: Particles, log_w: np.ndarray, cause: str | None,
               model: MeasurementModel | None, measurement: Any) -> tuple[np.ndarray, str | None]:
        """Stage 3: the measurement update, and the collapse checks: (log weights, collapse cause)."""
        if model is None or measurement is None:
            return log_w, cause
        if model.locates(measurement):
            # a collapse re-draws from the latest measurement that says where, not only which floor
            self._last_measurement = (float(t_s), model, measurement)
        ll = self._checked_log_likelihood(model, moved, measurement)
        if cause is not None:
            return log_w, cause
        live = np.isfinite(log_w)
        updated = log_w + ll
        best_ll = ll[live].max() if live.any() else -np.inf
        if self.config.min_log_likelihood is not None and best_ll < self.config.min_log_likelihood:
            return updated, "measurement_inconsistent"
        peak = model.log_likelihood_peak
        # every weight underflows relative to the model's best possible value (only a model that
        # knows its peak can say: otherwise a large negative value may be a constant offset)
        if not np.isfinite(updated).any() or (peak is not None and float(updated.max()) - peak < _LOG_UNDERFLOW):
            return updated, "weights_underflow"
        return updated, None

    def _recover_from_collapse(self, t_s: float, prev: Particles) -> tuple[Particles, np.ndarray, float, str]:
        """Stage 4a, a collapse: re-initialise (the lineage breaks here). Returns (particles,
        parents (all -1), ESS, how it recovered)."""
        recovery, new = self._recover(t_s)
        # PDR state: the walker's stride survives a collapse; the heading may be what failed,
        # so a share keeps an old particle's heading and the rest start with a random one
        donors = self.rng.integers(0, len(prev), self.n)
        keep = self.rng.random(self.n) < self.config.recovery_heading_keep_fraction
        new.heading_rad = np.where(keep, prev.heading_rad[donors], new.heading_rad)
        new.step_length_m = prev.step_length_m[donors].copy()
        self._recovery_level += 1
        self._healthy_steps = 0
        return new, np.full(self.n, -1, dtype=np.int64), float(self.n), recovery

    def _normalise_and_resample(self, prev: Particles, moved: Particles, log_w: np.ndarray
                                ) -> tuple[Particles, np.ndarray, float, bool, np.ndarray]:
        """Stage 4b: normalise; when the ESS 1 / sum(w^2) is low, resample and regularise (the
        jitter never crosses a wall). Returns (particles, parents, ESS, resampled, the normalised
        weights before resampling)."""
        cfg = self.config
        self._healthy_steps += 1
        if self._healthy_steps >= cfg.recovery_reset_steps:
            self._recovery_level = 0
        log_w = log_w - _logsumexp(log_w)
        w = np.exp(log_w)
        ess = float(1.0 / np.dot(w, w))
        if ess >= cfg.resample_ess_fraction * self.n:
            return dataclasses.replace(moved, log_weight=log_w), np.arange(self.n), ess, False, w
        parent = self._resample(w, self.n, self.rng)
        new = _take(moved, parent)
        if cfg.regularise:
            cov = self.floors.covariance(moved.xy_m, w)
            new.xy_m, _ = regularise(self.floorplan, new.xy_m, cov, self.rng, cfg.kernel, cfg.bandwidth_scale,
                                     cfg.regularise_tries, origin_xy_m=_rows(prev.xy_m, parent))
        new.log_weight = np.full(self.n, -math.log(self.n))
        return new, parent, ess, True, w

    def _record_collapse(self, t_s: float, step_index: int, before_xy: np.ndarray | None, cause: str | None,
                         prev: Particles, recovery: str | None) -> CollapseEvent | None:
        """The step's collapse (appended to ``collapses``), or None when it had none; called once
        the recovered cloud's estimate is set."""
        if cause is None:
            return None
        collapse = CollapseEvent(
            t_s=float(t_s), step_index=step_index,
            xy_m=(float(before_xy[0]), float(before_xy[1])) if before_xy is not None else (math.nan, math.nan),
            cause=cause, particles_lost=int(np.count_nonzero(np.isfinite(prev.log_weight))), recovery=recovery,
            recovered_xy_m=(float(self.estimate_xy_m[0]), float(self.estimate_xy_m[1])))
        self.collapses.append(collapse)
        return collapse

    def _record_lineage(self, t_s: float, parent: np.ndarray, new: Particles, weights: np.ndarray,
                        weights_before_resampling: np.ndarray | None, broken: bool) -> None:
        """Stage 5 (with ``keep_ancestry``): who descends from whom, for the lineage track."""
        if self.ancestry is not None:
            # the lineage's "best" particle: by the weights that chose the survivors (after a
            # resampling every new weight is equal and would say nothing)
            best = weights
            if weights_before_resampling is not None:
                best = np.where(parent >= 0, weights_before_resampling[np.maximum(parent, 0)], 0.0)
            self.ancestry.record(t_s, np.full(self.n, -1) if self._lineage_broken or broken else parent,
                                 new.xy_m, best)
        self._lineage_broken = False

    def _report(self, t_s: float, step_index: int, prev: Particles, moved: Particles, new: Particles,
                weights: np.ndarray, killed: np.ndarray, ess: float, n_alive: int, resampled: bool,
                collapse: CollapseEvent | None, model: MeasurementModel | None, measurement: Any,
                means: tuple[float, float] | None = None) -> StepReport:
        """What happened this step, for the viewer and the tracks (``means``: the weighted
        heading and step length if known, else computed here)."""
        steps = self.motion.walks_in_steps
        if steps and means is None:
            means = (circular_mean(new.heading_rad, weights), float(weights @ new.step_length_m))
        measured = model is not None and measurement is not None
        fix_xy = model.fix_xy_m(measurement) if measured else None
        return StepReport(
            t_s=float(t_s), step_index=step_index, estimate_xy_m=self.estimate_xy_m.copy(),
            estimate_std_m=float(self.estimate_std_m), ess=ess, n_particles=self.n, n_alive=n_alive,
            n_killed=int(killed.size), resampled=resampled, particles_xy_m=new.xy_m,
            particles_weight=weights, killed_from_xy_m=prev.xy_m[killed], killed_to_xy_m=moved.xy_m[killed],
            collapse=collapse,
            heading_rad=means[0] if steps else None,
            step_length_m=means[1] if steps else None,
            measurement_kind=model.kind if measured else None,
            fix_xy_m=None if fix_xy is None else np.asarray(fix_xy, dtype=np.float64).ravel()[:2].copy(),
            heard_ap_xy_m=model.heard_ap_xy_m(measurement) if measured else None,
            path_loss=model.viewer_state() if measured else None,
            **self.floors.report(new.xy_m, weights, self.estimate_xy_m),
        )

    # ---- collapse recovery -------------------------------------------------------------------
    def _recover(self, t_s: float) -> tuple[str, Particles]:
        """Re-initialise after a collapse: from the latest measurement's likelihood over the map,
        else uniformly around the last estimate with a radius growing with repeated collapses."""
        cfg = self.config
        last = self._last_measurement
        if last is not None and float(t_s) - last[0] <= cfg.recovery_measurement_max_age_s:
            xy = self._sample_from_likelihood(last[1], last[2])
            if xy is not None:
                return "likelihood_over_map", self._new_particles(xy, None)
        x_min, x_max, y_min, y_max = self.floorplan.extent_m
        centre = self.estimate_xy_m if self.estimate_xy_m is not None else ((x_min + x_max) / 2, (y_min + y_max) / 2)
        radius = cfg.recovery_radius_m * cfg.recovery_radius_growth ** self._recovery_level
        width_m, height_m = self.floorplan.size_m
        if radius >= math.hypot(width_m, height_m):
            return "uniform", self._new_particles(self.floorplan.sample_free(self.n, self.rng), None)
        xy = self._sample_free_near(np.asarray(centre, dtype=np.float64), radius)
        return f"around_estimate_r{radius:.1f}m", self._new_particles(xy, None)

    # ---- outputs -----------------------------------------------------------------------------
    def smoothed_track(self) -> tuple[np.ndarray, np.ndarray]:
        """(t_s (T,), xy_m (T, 2)): the lineage of the final best particle (needs keep_ancestry)."""
        if self.ancestry is None:
            raise RuntimeError("smoothed_track needs ParticleFilter(..., keep_ancestry=True)")
        return self.ancestry.smoothed_track()
