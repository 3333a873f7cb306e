"""The one filter step (two numba passes calling the models' kernels) stage by stage: each motion
kernel against its numpy twin (``MotionModel.move``), the wall kill against the brute-force check,
the weights against the formulas, fed the same counter-based draws (the whole step against the
reference step: test_reference_step.py); determinism across threads; a model plugged in from
outside the package; a building's floors."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from numba import njit
from scipy import stats

from mapfilter.filter.kernels.draws import counter_normals, counter_uniforms, trailing_zeros
from mapfilter.filter.kernels.passes import LIKELIHOOD_SIGNATURE, SPAN, X
from mapfilter.filter.models.interface import LikelihoodKernel, MeasurementModel
from mapfilter.filter.models.motion import ConstantVelocityMotion, PDRMotion, RandomWalkMotion, StepInput
from mapfilter.filter.models.path_loss import path_loss_kernel
from mapfilter.filter.models.position_fix import GaussianFixLikelihood, PositionFix
from mapfilter.filter.particle_filter import FilterConfig, ParticleFilter
from mapfilter.filter.particles import Particles
from mapfilter.filter.reference import reference_step
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import touches_wall_reference
from tests.filter.test_filter_pf import ROOMS

KEY = 0x1234_5678_9ABC


def _normals(key: int, pairs: int, n: int) -> np.ndarray:
    """(2 pairs, n): the standard normals the move kernel gets (pair k in rows 2k, 2k + 1)."""
    return np.vstack([np.vstack(counter_normals(key, pair, n)) for pair in range(pairs)])


def _draws(pf: ParticleFilter, resampled: bool) -> tuple[int, float | None, int | None]:
    """The filter's next step's move key and, when it resamples, its u and jitter key (a copy of its
    generator drawn as the step draws)."""
    rng = copy.deepcopy(pf.rng)
    key = int(rng.integers(0, 2 ** 63, dtype=np.int64))
    if not resampled:
        return key, None, None
    return key, float(rng.random()), int(rng.integers(0, 2 ** 63, dtype=np.int64))


def _filter(plan, motion, n=700, ess_fraction=0.0, seed=3, centre=(3.0, 5.0), radius=2.0, heading=0.3):
    pf = ParticleFilter(plan, motion, FilterConfig(n_particles=n, resample_ess_fraction=ess_fraction),
                        np.random.default_rng(seed))
    pf.initialise_around(centre, radius, heading_rad=heading)
    rng = np.random.default_rng(seed + 1)
    pf.particles.step_length_m = rng.uniform(0.5, 0.9, n)
    pf.particles.state[2:4] = rng.normal(0.0, 0.8, (2, n))  # velocities
    pf.particles.heading_rad = rng.uniform(-math.pi, math.pi, n)
    return pf


OPEN = FloorPlan(np.pad(np.zeros((398, 398), dtype=bool), 1, constant_values=True), 0.1)  # 40 m x 40 m, no walls


@pytest.mark.parametrize("motion, step_input", [
    (RandomWalkMotion(), None),
    (ConstantVelocityMotion(accel_sigma_mps2=1.5, max_speed_mps=1.2), None),  # speeds clipped
    (PDRMotion(), StepInput(2, 0.6)),  # a turn: some particles ignore it
    (PDRMotion(), StepInput(1, 0.1)),  # no turn
    (PDRMotion(), StepInput(0, 0.2)),  # standing: the step length is kept
])
def test_the_move_is_the_oracles(motion, step_input):
    pf = _filter(OPEN, motion, centre=(20.0, 20.0))
    before = pf.particles.state.copy()
    key, _, _ = _draws(pf, resampled=False)
    pf.step(1.0, 0.7, step_input)
    z = _normals(key, 3, before.shape[1])
    expected = motion.move(before, z, step_input, 0.7)
    if isinstance(motion, PDRMotion):
        if step_input.n_steps == 2:
            ignored = np.isclose(np.mod(expected[4] - before[4] + math.pi, 2 * math.pi) - math.pi,
                                 motion.heading_sigma_rad * z[0], atol=1e-9)
            assert 0.1 < ignored.mean() < 0.2  # the thesis' 15 % false turns
    np.testing.assert_allclose(pf.particles.state, expected, atol=2e-6)


@pytest.mark.parametrize("motion, step_input", [(RandomWalkMotion(radius_mps=2.0), None), (PDRMotion(), StepInput(3, 0.0))])
def test_the_wall_kill_is_the_brute_force_check_of_every_live_move(motion, step_input):
    pf = _filter(ROOMS, motion, centre=(5.0, 5.0), radius=3.0)
    pf.particles.log_weight[::17] = -np.inf  # the dead stay dead and are not checked
    before = pf.particles.copy()
    pf.step(1.0, 1.0, step_input)
    after = pf.particles
    moved_dead = ~np.isfinite(after.log_weight)
    live_before = np.isfinite(before.log_weight)
    expected = touches_wall_reference(ROOMS, before.xy_m[live_before], after.xy_m[live_before])
    assert expected.sum() > 50  # the test sees many crossings
    np.testing.assert_array_equal(moved_dead[live_before], expected)
    assert moved_dead[~live_before].all()


@pytest.mark.parametrize("kind", ["fix", "path_loss", "none"])
def test_the_weights_are_the_formulas(kind):
    pf = _filter(OPEN, RandomWalkMotion(), centre=(20.0, 20.0), radius=6.0)
    rng = np.random.default_rng(9)
    before = pf.particles.copy()
    if kind == "fix":
        model, measurement = GaussianFixLikelihood(2.5), PositionFix((21.0, 19.0))
    elif kind == "path_loss":
        ap = rng.uniform(5, 35, (12, 2))

        class Table(MeasurementModel):
            def kernel(self, z):
                return path_loss_kernel(ap, -38.0, 2.2, 0.4, 30.0, z, 25.0)
        model, measurement = Table(), rng.uniform(-90, -40, 12)
        measurement[3] = np.nan  # not heard: left out
    else:
        model, measurement = None, None
    pf.step(1.0, 0.5, None, model, measurement)
    xy = pf.particles.xy_m
    if kind == "fix":
        ll = -((xy - [21.0, 19.0]) ** 2).sum(axis=1) / (2 * 2.5 ** 2)
    elif kind == "path_loss":
        heard = np.isfinite(measurement)
        d = np.maximum(np.linalg.norm(xy[:, None, :] - ap[None, heard], axis=2), 1.0)
        expected_rssi = -38.0 - 22.0 * np.log10(d) - 0.4 * np.minimum(d, 30.0)
        ll = -((measurement[heard] - expected_rssi) ** 2).sum(axis=1) / 50.0
    else:
        ll = np.zeros(len(xy))
    log_w = before.log_weight + ll
    log_w -= np.logaddexp.reduce(log_w)
    np.testing.assert_allclose(pf.particles.log_weight, log_w, atol=1e-4)  # float32 inside the path-loss kernel
    assert np.exp(pf.particles.log_weight).sum() == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("regularise", [False, True])
def test_resampling_with_and_without_the_jitter_is_the_reference_steps(regularise):
    pf = _filter(ROOMS, RandomWalkMotion(radius_mps=0.8), ess_fraction=1.0, centre=(5.0, 5.0), radius=3.0)
    pf.config = FilterConfig(n_particles=pf.n, resample_ess_fraction=1.0, regularise=regularise)
    pf.step(0.5, 0.1)  # parents exist from the first step after the initialisation
    before, rng = pf.particles.copy(), copy.deepcopy(pf.rng)
    model, fix = GaussianFixLikelihood(1.5), PositionFix((6.0, 5.5))
    assert pf.step(1.0, 1.0, None, model, fix).resampled
    expected = reference_step(ROOMS, before, pf.motion, None, 1.0, [(model, fix)], pf.config, rng)
    same = expected.parents == pf.last_parents
    assert same.mean() > 0.995  # a bin edge within round-off may differ
    close = np.all(np.abs(pf.particles.xy_m - expected.particles.xy_m) < 1e-5, axis=1)
    assert close[same].mean() > 0.995


def test_resampling_never_picks_a_dead_particle():
    pf = _filter(OPEN, RandomWalkMotion(radius_mps=0.0, sigma_mps=0.0), ess_fraction=1.0, centre=(20.0, 20.0))
    pf.step(0.5, 1.0)  # parents exist from the first step after the initialisation
    pf.particles.log_weight[:] = -np.inf
    pf.particles.log_weight[[17, 250, 699]] = np.log([0.2, 0.5, 0.3])
    pf.step(1.0, 1.0)
    parents = pf.last_parents
    assert set(np.unique(parents)) == {17, 250, 699} and np.all(np.diff(parents) >= 0)
    assert np.bincount(parents)[[17, 250, 699]] == pytest.approx([140, 350, 210], abs=1)


def test_resampling_across_blocks_of_dead_particles_is_the_search_of_the_cumulative_weights():
    """Each copy's parent is the plain search of its position (j + u) / N in the cumulative weights,
    across a block whose particles are all dead and blocks of few live ones: never a dead parent,
    every particle copied floor or ceil of N w times (a bin edge within round-off may differ)."""
    n = 3 * SPAN + 100
    pf = _filter(OPEN, RandomWalkMotion(radius_mps=0.0, sigma_mps=0.0), n=n, ess_fraction=1.0, centre=(20.0, 20.0))
    pf.config = FilterConfig(n_particles=n, resample_ess_fraction=1.0, regularise=False)
    pf.step(0.5, 1.0)  # parents exist from the first step after the initialisation
    rng = np.random.default_rng(4)
    alive = np.zeros(n, dtype=bool)
    alive[rng.choice(SPAN, 40, replace=False)] = True  # block 1 all dead
    alive[2 * SPAN + rng.choice(SPAN + 100, 60, replace=False)] = True
    log_weight = np.where(alive, rng.normal(0.0, 2.0, n), -np.inf)
    pf.particles.log_weight[:] = log_weight
    _, u, _ = _draws(pf, resampled=True)
    assert pf.step(1.0, 1.0).resampled
    w = np.exp(log_weight - np.logaddexp.reduce(log_weight))
    expected = np.minimum(np.searchsorted(np.cumsum(w), (np.arange(n) + u) / n, side="right"), np.flatnonzero(alive)[-1])
    parents = pf.last_parents
    assert alive[parents].all() and np.all(np.diff(parents) >= 0)
    assert (parents == expected).mean() > 0.998
    copies = np.bincount(parents, minlength=n)
    assert np.all(np.abs(copies - n * w) < 1.0 + 1e-6)


def test_the_lowest_set_bit_is_found():
    @njit
    def lowest(word):
        return trailing_zeros(word)

    rng = np.random.default_rng(6)
    for word in [1, 2, 3, 1 << 63, *rng.integers(1, 2 ** 63, 200)]:
        word = np.uint64(word)
        assert lowest(word) == (int(word) & -int(word)).bit_length() - 1
    assert lowest(np.uint64(0)) == 64


def test_counter_draws_are_standard():
    z0, z1 = counter_normals(KEY, 2, 200_000)
    for z in (z0, z1):
        assert stats.kstest(z, "norm").pvalue > 1e-3
    assert abs(np.corrcoef(z0, z1)[0, 1]) < 0.01
    a, b = counter_uniforms(KEY, 2, 200_000)
    assert stats.kstest(a, "uniform").pvalue > 1e-3 and stats.kstest(b, "uniform").pvalue > 1e-3
    # neighbouring particles, slots and keys are independent
    c, _ = counter_uniforms(KEY, 3, 200_000)
    d, _ = counter_uniforms(KEY + 1, 2, 200_000)
    assert max(abs(np.corrcoef(a[:-1], a[1:])[0, 1]), abs(np.corrcoef(a, c)[0, 1]), abs(np.corrcoef(a, d)[0, 1])) < 0.01


def _run(seed, n, motion, steps, monkeypatch, threads):
    monkeypatch.setenv("MAPFILTER_THREADS", str(threads))
    pf = ParticleFilter(ROOMS, motion, FilterConfig(n_particles=n, resample_ess_fraction=0.6), np.random.default_rng(seed))
    pf.initialise_around((3.0, 5.0), 1.0, heading_rad=0.0)
    model = GaussianFixLikelihood(0.8)
    for k in range(steps):
        step_input = StepInput(1, 0.0) if motion.walks_in_steps else None
        pf.step(k + 1.0, 1.0, step_input, model, PositionFix((3.0 + 0.8 * (k + 1), 4.6)))
    return pf


@pytest.mark.parametrize("n", [9_000, 3 * 16_384 + 123])  # one thread, two threads (from 32,768 particles)
def test_same_seed_same_particles_whatever_the_threads(monkeypatch, n):
    one = _run(4, n, PDRMotion(), 4, monkeypatch, 1)
    two = _run(4, n, PDRMotion(), 4, monkeypatch, 2)
    assert np.array_equal(one.particles.state, two.particles.state)
    assert np.array_equal(one.particles.log_weight, two.particles.log_weight)
    assert np.array_equal(one.estimate_xy_m, two.estimate_xy_m)


# ---- a model from outside the package: one kernel, nothing else touched -----------------------------
@njit(LIKELIHOOD_SIGNATURE, cache=True, nogil=True)
def _beyond_x(params, state, lo, m, out):
    # log-likelihood 0 east of x = params[0], -inf west of it
    for j in range(m):
        out[j] = 0.0 if state[X, lo + j] > params[0] else -np.inf


class EastOf(MeasurementModel):
    def kernel(self, x_m):
        return LikelihoodKernel(_beyond_x, np.array([float(x_m)]))


def test_a_model_written_outside_the_package_plugs_in():
    pf = ParticleFilter(OPEN, RandomWalkMotion(), FilterConfig(n_particles=2000), np.random.default_rng(2))
    pf.initialise_from_measurement(0.0, EastOf(), 30.0)
    # drawn from its likelihood (the jitter, about 0.8 m here, spreads the copies a little)
    assert np.mean(pf.particles.xy_m[:, 0] > 30.0) > 0.9 and (pf.particles.xy_m[:, 0] > 26.0).all()
    report = pf.step(1.0, 1.0, None, EastOf(), 34.0)
    assert report.estimate_xy_m[0] > 34.0
    alive = np.isfinite(pf.particles.log_weight)
    assert not report.resampled and 0.3 < alive.mean() < 0.9 and (pf.particles.xy_m[alive, 0] > 34.0).all()


# ---- a building's floors: the pass runs in calls around the floor changes (three with stairs, two without)
def _stack_filter(tmp_path, motion, n=3000, seed=0, connectors=False, rates=(0.0, 0.05)):
    from mapfilter.filter.models.building import FloorChangeConfig, FloorChanges, FloorStack
    from tests.sensors.test_floors import _building

    stack = FloorStack(_building(tmp_path, connectors=connectors))
    changes = FloorChanges(stack, FloorChangeConfig(*rates))
    pf = ParticleFilter(stack.plan, motion, FilterConfig(n_particles=n, init_samples=5000),
                        np.random.default_rng(seed), floors=changes)
    return stack, changes, pf


def test_on_a_buildings_floors_no_particle_lives_in_a_wall_and_the_evidence_finds_the_floor(tmp_path):
    from mapfilter.filter.models.building import FloorFix, FloorFixLikelihood

    stack, changes, pf = _stack_filter(tmp_path, RandomWalkMotion())
    model = FloorFixLikelihood(stack, np.full(3, 3.0))
    fix = FloorFix(stack.to_stack(np.array([[10.0, 5.0]] * 3), np.arange(3)), np.log([0.2, 0.6, 0.2]))
    pf.initialise_from_measurement(0.0, model, fix)
    changed = 0
    for k in range(1, 40):
        report = pf.step(float(k), 1.0, None, model, fix if k % 3 == 0 else None)
        changed += report.floor_changes
        local, floor = stack.to_floor(pf.particles.xy_m)
        alive = np.isfinite(pf.particles.log_weight)
        for f, fl in enumerate(stack.building.floors):
            assert fl.plan.is_free(local[alive & (floor == f)]).all()
        assert math.isclose(float(np.exp(pf.particles.log_weight).sum()), 1.0, rel_tol=1e-9)
        assert math.isclose(float(report.floor_shares.sum()), 1.0, rel_tol=1e-9)
    assert changed > 100  # particles did change floor (0.05 / s, 3000 particles, 39 s)
    assert report.floor_index == 1 and report.floor_shares[1] > 0.8


def test_on_a_buildings_stairs_a_pdr_step_advances_a_tread(tmp_path):
    from mapfilter.filter.models.building import STAIRS_TREAD_M

    stack, changes, pf = _stack_filter(tmp_path, PDRMotion(heading_sigma_rad=0.0), n=400, connectors=True,
                                       rates=(0.0, 0.0))
    lo, hi = STAIRS_TREAD_M
    rng = np.random.default_rng(6)
    on = np.column_stack([rng.uniform(2.3, 3.0, 200), rng.uniform(2.3, 4.7, 200)])  # west end of the stairs
    off = np.column_stack([rng.uniform(8.0, 12.0, 200), rng.uniform(2.3, 4.7, 200)])
    start = stack.to_stack(np.concatenate([on, off]), 0)
    pf.particles = Particles.at(start, heading_rad=0.0, step_length_m=0.7)
    pf.step(1.0, 0.6, StepInput(1, 0.0))
    moved_m = np.linalg.norm(pf.particles.xy_m - start, axis=1)
    # a tread on the stairs; off them the 0.7 m stride with its slack (5 sigma below it is still no tread)
    assert (moved_m[:200] <= hi + 0.05).all() and (moved_m[200:] >= hi + 0.1).all()


def test_without_stairs_the_move_and_the_wall_check_in_one_call_are_the_two_calls(tmp_path):
    """A building without stairs moves and checks walls in one call of the pass; the two calls a
    building with stairs makes (its steps shortened between them, here none: no stairs) give the
    same clouds to the bit, step by step, floor changes and weighing included."""
    from mapfilter.filter.models.building import FloorChanges, FloorFix, FloorFixLikelihood

    class SaysItHasStairs(FloorChanges):
        has_stairs = True  # the filter takes the two calls; step_on_stairs still shortens nothing

    runs = []
    for split in (False, True):
        stack, changes, pf = _stack_filter(tmp_path, PDRMotion(), seed=5, rates=(0.0, 0.05))
        if split:
            changes.__class__ = SaysItHasStairs
        assert pf.floors.has_stairs == split
        model = FloorFixLikelihood(stack, np.full(3, 3.0))
        fix = FloorFix(stack.to_stack(np.array([[10.0, 5.0]] * 3), np.arange(3)), np.log([0.2, 0.6, 0.2]))
        pf.initialise_from_measurement(0.0, model, fix)
        clouds = []
        for k in range(1, 16):
            report = pf.step(float(k), 0.6, StepInput(1, 0.1), model, fix if k % 3 == 0 else None)
            clouds.append((pf.particles.state.copy(), pf.particles.log_weight.copy(), report.n_killed,
                           report.floor_changes))
        runs.append(clouds)
    assert sum(c[2] for c in runs[0]) > 0 and sum(c[3] for c in runs[0]) > 0  # walls killed, floors changed
    for (state_a, lw_a, killed_a, changed_a), (state_b, lw_b, killed_b, changed_b) in zip(*runs):
        assert np.array_equal(state_a, state_b) and np.array_equal(lw_a, lw_b, equal_nan=True)
        assert killed_a == killed_b and changed_a == changed_b
