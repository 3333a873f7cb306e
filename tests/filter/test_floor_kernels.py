"""Oracle tests of a building's numba kernels (``filter.models.building``): each against the plain
numpy it replaced, on random clouds over a three-floor stack (floors rotated and shifted in the
building frame), and a filter run with the kernels against one with the numpy measurement model,
draw for draw from one seed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mapfilter.filter.estimate import weighted_moments
from mapfilter.filter.models.building import FloorChangeConfig, FloorChanges, FloorFix, FloorFixLikelihood, FloorStack
from mapfilter.filter.models.motion import RandomWalkMotion
from mapfilter.filter.models.survey_reach import distance_grid, mixture_log_likelihood
from mapfilter.filter.particle_filter import FilterConfig, ParticleFilter
from mapfilter.filter.particles import Particles
from mapfilter.maps.building import Building, Floor
from mapfilter.maps.floorplan import FloorPlan


def _stack() -> FloorStack:
    """Three 20 m x 15 m floors (0.25 m/px), a different wall box on each, the upper two rotated
    and shifted in the building frame."""
    floors = []
    for i in range(3):
        mask = np.zeros((60, 80), dtype=bool)
        mask[0, :] = mask[-1, :] = mask[:, 0] = mask[:, -1] = True
        mask[20:35, 25 + 6 * i:40 + 6 * i] = True
        floors.append(Floor(f"L{i}", FloorPlan(mask, 0.25, (0.5 * i, -0.3 * i)), elevation_m=4.0 * i,
                            offset_m=(1.5 * i, -2.0 * i), rotation_rad=0.2 * i))
    return FloorStack(Building(floors))


def _cloud(stack: FloorStack, rng: np.random.Generator, n: int = 3000) -> Particles:
    """Particles on every floor (their own free space), a tenth of them dead, random weights."""
    floor = rng.integers(0, stack.n_floors, n)
    local = np.empty((n, 2))
    for f, fl in enumerate(stack.building.floors):
        local[floor == f] = fl.plan.sample_free(int(np.count_nonzero(floor == f)), rng)
    particles = Particles.at(stack.to_stack(local, floor))
    log_weight = rng.normal(-math.log(n), 2.0, n)
    log_weight[rng.random(n) < 0.1] = -np.inf
    particles.log_weight = log_weight
    return particles


def _numpy_log_likelihood(model: FloorFixLikelihood, particles: Particles, measurement: FloorFix) -> np.ndarray:
    """FloorFixLikelihood.log_likelihood as plain numpy (the oracle: what the kernel replaced)."""
    stack = model.stack
    floor = np.clip(np.searchsorted(stack.tile_x_min_m, particles.xy_m[:, 0], side="right") - 1, 0,
                    stack.n_floors - 1)
    fix = measurement.xy_m[floor]
    sigma = np.asarray(model.sigma_m, dtype=np.float64)[floor]
    r2 = ((particles.xy_m - fix) ** 2).sum(axis=1)
    if model.grids is not None and measurement.in_survey is not None:
        floor_xy = particles.xy_m - stack.shift_m[floor]
        d2 = np.zeros(len(floor))
        for f, grid in enumerate(model.grids):
            on = floor == f
            if grid is not None and on.any():
                d2[on] = grid.at(floor_xy[on]) ** 2
        with np.errstate(invalid="ignore"):
            position = np.where(np.isfinite(r2), mixture_log_likelihood(r2, d2, sigma * sigma,
                                                                        float(measurement.in_survey)), -4.5)
    else:
        position = np.where(np.isfinite(r2), -0.5 * r2 / (sigma * sigma), -4.5)
    prior = particles.log_weight
    live = np.isfinite(prior)
    floor_ll = np.asarray(measurement.floor_log_likelihood, dtype=np.float64)
    if measurement.evidence_only:
        return floor_ll[floor]
    if live.any() and floor_ll[floor[live]].max() < floor_ll.max() - model.floor_collapse_nats:
        return np.full(len(particles), -np.inf)
    out = floor_ll[floor] + position
    for f in np.unique(floor[live]):
        on = live & (floor == f)
        a, b = prior[on] + position[on], prior[on]
        out[on] -= (a.max() + math.log(np.exp(a - a.max()).sum())) - (b.max() + math.log(np.exp(b - b.max()).sum()))
    return out


class _NumpyFloorFixLikelihood(FloorFixLikelihood):
    def log_likelihood(self, particles, measurement):
        return _numpy_log_likelihood(self, particles, measurement)


def _grids(stack: FloorStack, rng: np.random.Generator, with_none: bool) -> list:
    """Each floor's distance-to-survey grid from a few random reference points (the middle floor none)."""
    grids = []
    for f, floor in enumerate(stack.building.floors):
        refs = np.column_stack([rng.uniform(*floor.plan.extent_m[:2], 12), rng.uniform(*floor.plan.extent_m[2:], 12)])
        grids.append(None if with_none and f == 1 else distance_grid(refs, floor.plan.extent_m))
    return grids


@pytest.mark.parametrize("in_survey", [None, 0.0, 0.35, 1.0])
@pytest.mark.parametrize("with_none", [False, True])
def test_the_floor_fix_kernel_gives_the_numpy_likelihood(in_survey, with_none):
    """Every particle's value to float rounding: Gaussian fixes, the survey-reach mixture at any
    in-survey probability, a floor without a fix (NaN) or a grid, dead particles (no normaliser)."""
    stack = _stack()
    rng = np.random.default_rng(11)
    model = FloorFixLikelihood(stack, np.array([2.0, 3.5, 5.0]), _grids(stack, rng, with_none))
    particles = _cloud(stack, rng)
    fix = stack.to_stack(np.array([[5.0, 4.0], [12.0, 9.0], [np.nan, np.nan]]), np.arange(3))
    measurement = FloorFix(fix, np.log([0.5, 0.3, 0.2]), in_survey=in_survey)
    got = model.log_likelihood(particles, measurement)
    want = _numpy_log_likelihood(model, particles, measurement)
    assert np.isfinite(want).all() and len(np.unique(np.round(want, 6))) > 100  # a value that says something
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    # without grids: the Gaussian fix whatever the in-survey probability
    plain = FloorFixLikelihood(stack, np.array([2.0, 3.5, 5.0]))
    np.testing.assert_allclose(plain.log_likelihood(particles, measurement),
                               _numpy_log_likelihood(plain, particles, measurement), rtol=1e-12, atol=1e-12)


def test_the_floor_fix_kernel_collapses_and_weighs_floors_alone_as_numpy_does():
    stack = _stack()
    rng = np.random.default_rng(12)
    model = FloorFixLikelihood(stack, np.full(3, 3.0))
    particles = _cloud(stack, rng)
    on_floor_0 = stack.floor_of(particles.xy_m) == 0
    particles.log_weight[~on_floor_0] = -np.inf  # every live particle on L0
    fix = stack.to_stack(np.array([[5.0, 4.0]] * 3), np.arange(3))
    far_below = FloorFix(fix, np.array([-10.0, 0.0, -1.0]))  # L0 10 nats below the best floor: a collapse
    assert np.isneginf(model.log_likelihood(particles, far_below)).all()
    assert np.isneginf(_numpy_log_likelihood(model, particles, far_below)).all()
    near = FloorFix(fix, np.array([-2.0, 0.0, -1.0]))  # 2 nats below: no collapse
    np.testing.assert_allclose(model.log_likelihood(particles, near), _numpy_log_likelihood(model, particles, near),
                               rtol=1e-12, atol=1e-12)
    floors_only = FloorFix(np.full((3, 2), np.nan), np.array([-3.0, 0.0, -1.0]))
    np.testing.assert_array_equal(model.log_likelihood(particles, floors_only),
                                  _numpy_log_likelihood(model, particles, floors_only))


def test_the_stacks_floor_kernels_give_numpys_numbers_to_the_last_bit():
    """floor_of (NaN and points off every tile too), floor_shares (np.bincount), to_building (each
    floor's Floor.to_building) and main_floor_moments (weighted_moments of the main floor's weights,
    and the floor shares it gives the step's report)."""
    stack = _stack()
    rng = np.random.default_rng(13)
    particles = _cloud(stack, rng)
    xy = particles.xy_m
    odd = np.array([[np.nan, 1.0], [-5.0, 1.0], [1e9, 1.0], [stack.tile_x_min_m[1], 2.0], [np.inf, 0.0]])
    for points in (xy, odd, xy[:1], np.zeros((0, 2))):
        want = np.clip(np.searchsorted(stack.tile_x_min_m, points[:, 0], side="right") - 1, 0, stack.n_floors - 1)
        np.testing.assert_array_equal(stack.floor_of(points), want)
    assert stack.floor_of(xy[0]).shape == ()  # one point (2,): a 0-d index, as numpy's
    floor = stack.floor_of(xy)
    weights = np.exp(particles.log_weight)
    np.testing.assert_array_equal(stack.floor_shares(xy, weights), np.bincount(floor, weights, stack.n_floors))
    local = xy - stack.shift_m[floor]
    want = np.empty_like(local)
    for f, fl in enumerate(stack.building.floors):
        want[floor == f] = fl.to_building(local[floor == f])
    np.testing.assert_array_equal(stack.to_building(xy), want)
    main = int(np.argmax(np.bincount(floor, weights, stack.n_floors)))
    w_main = np.where(floor == main, weights, 0.0)
    shares = np.full(stack.n_floors, np.nan)
    w, mean, cov = stack.main_floor_moments(xy, weights, shares)
    want_mean, want_cov = weighted_moments(xy, w_main)
    np.testing.assert_array_equal(w, w_main)
    np.testing.assert_array_equal(mean, want_mean)
    np.testing.assert_array_equal(cov, want_cov)
    np.testing.assert_array_equal(shares, np.bincount(floor, weights, stack.n_floors))  # the report's floor shares


def test_a_filter_run_with_the_kernel_follows_the_numpy_model_draw_for_draw():
    """The same seed, the same steps (moves, floor changes, weighing, resampling): the clouds of a
    run with the kernel and one with the numpy likelihood agree to float rounding, every step."""
    stack = _stack()
    grids = _grids(stack, np.random.default_rng(14), False)
    runs = []
    for model_type in (FloorFixLikelihood, _NumpyFloorFixLikelihood):
        model = model_type(stack, np.array([2.0, 3.0, 4.0]), grids)
        changes = FloorChanges(stack, FloorChangeConfig(0.0, 0.2))
        pf = ParticleFilter(stack.plan, RandomWalkMotion(), FilterConfig(n_particles=2000, init_samples=4000),
                            np.random.default_rng(7), floors=changes)
        fix = FloorFix(stack.to_stack(np.array([[6.0, 5.0], [7.0, 5.0], [6.0, 6.0]]), np.arange(3)),
                       np.log([0.2, 0.6, 0.2]), in_survey=0.7)
        pf.initialise_from_measurement(0.0, model, fix)
        clouds = []
        for k in range(1, 25):
            report = pf.step(float(k), 1.0, None, model, fix if k % 2 == 0 else None)
            clouds.append((pf.particles.xy_m.copy(), pf.particles.log_weight.copy(), report.resampled,
                           pf.estimate_xy_m.copy()))
        runs.append(clouds)
    assert sum(c[2] for c in runs[0]) >= 3  # the run resampled: the draws had a chance to part
    for (xy_a, lw_a, resampled_a, est_a), (xy_b, lw_b, resampled_b, est_b) in zip(*runs):
        assert resampled_a == resampled_b
        np.testing.assert_allclose(xy_a, xy_b, rtol=0, atol=1e-9)
        np.testing.assert_allclose(lw_a, lw_b, rtol=0, atol=1e-9)
        np.testing.assert_allclose(est_a, est_b, rtol=0, atol=1e-9)


def _numpy_change_floors(stack: FloorStack, particles: Particles, log_weight: np.ndarray, p: float,
                         rng: np.random.Generator) -> tuple[np.ndarray, int]:
    """FloorChanges.change_floors without connectors as plain numpy (the oracle: what the kernel
    replaced), moving ``particles`` in place; (the log weights, how many landed)."""
    xy = particles.xy_m
    movers = np.flatnonzero(np.isfinite(log_weight) & (rng.random(len(particles)) < p))
    moving = xy[movers]
    dest = (stack.floor_of(moving) + rng.integers(1, stack.n_floors, movers.size)) % stack.n_floors
    building_xy = stack.to_building(moving)
    out = log_weight.copy()
    for d in np.unique(dest):
        sel = dest == d
        point = stack.building.floors[d].from_building(building_xy[sel])
        idx = movers[sel]
        free = stack.building.floors[d].plan.is_free(point)
        xy[idx[free]] = stack.to_stack(point[free], d)
        out[idx[~free]] = -np.inf
    return out, int(np.count_nonzero(np.isfinite(out[movers])))


@pytest.mark.parametrize("seed", [3, 4])
def test_the_floor_change_kernel_moves_and_kills_as_numpy_did(seed):
    """FloorChanges.change_floors without connectors (``_change_anywhere``) against the numpy it
    replaced, from one seed: the same particles moved to the same stack positions to the bit, the
    same ones killed (their point no free space on the floor drawn), the same count landed."""
    stack = _stack()
    rng = np.random.default_rng(seed)
    particles = _cloud(stack, rng)
    changes = FloorChanges(stack, FloorChangeConfig(0.0, 0.3))
    dt_s = 1.0
    p = -math.expm1(-0.3 * dt_s)
    oracle = Particles(particles.state.copy(), particles.log_weight.copy())
    before = particles.xy_m.copy()
    out = changes.change_floors(particles, particles.log_weight.copy(), dt_s, np.random.default_rng(seed + 10))
    want, landed = _numpy_change_floors(stack, oracle, oracle.log_weight.copy(), p, np.random.default_rng(seed + 10))
    np.testing.assert_array_equal(particles.state, oracle.state)
    np.testing.assert_array_equal(out, want)
    assert changes.changed_last_step == landed
    moved = np.any(particles.xy_m != before, axis=1)
    killed = np.isfinite(oracle.log_weight) & ~np.isfinite(out)
    assert moved.sum() == landed > 50 and killed.sum() > 10  # some land, some find a wall
    assert np.all(stack.floor_of(particles.xy_m[moved]) != stack.floor_of(before[moved]))
