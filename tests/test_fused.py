"""The fused step (filter/fused.py) held to the named stages of filter/pf.py.

Oracles: each pass fed to the stage functions with the same random numbers (a stand-in
Generator that hands out the fused kernels' counter-based draws in the order a stage asks for
them) gives the same particles; where the draws cannot be lined up (whole filter runs), the
two paths give the same distribution. Properties (no particle in a wall, weights normalised)
are checked on both paths in tests/test_filter_pf.py.
"""

import math

import numpy as np
import pytest
from scipy import stats

from mapfilter.filter import fused
from mapfilter.filter.measurement import GaussianFixLikelihood, PositionFix, TrilaterationLikelihood
from mapfilter.filter.motion import ConstantVelocityMotion, PDRMotion, RandomWalkMotion, StepInput
from mapfilter.filter.particles import Particles
from mapfilter.filter.pf import FilterConfig, ParticleFilter
from mapfilter.filter.regularise import bandwidth_and_root, regularise
from mapfilter.filter.resample import systematic
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import clearance_px, crosses_wall
from mapfilter.sensors.pathloss import AccessPointTable
from mapfilter.sensors.wifi import WifiScan
from tests.test_filter_pf import ROOMS

KEY = 0x5DEECE66D1234567


class DrawsInOrder:
    """A stand-in for ``numpy.random.Generator`` that returns given arrays in the order asked."""

    def __init__(self, *arrays):
        self.queue = [np.asarray(a, dtype=np.float64) for a in arrays]

    def _next(self, size):
        value = self.queue.pop(0)
        if size is not None:
            assert value.size == int(np.prod(size)), (value.shape, size)
            return value.reshape(size)
        return float(value)

    def random(self, size=None):
        return self._next(size)

    def standard_normal(self, size=None):
        return self._next(size)

    def uniform(self, low=0.0, high=1.0, size=None):
        return low + (high - low) * self._next(size)


def _interleaved(a, b):
    return np.column_stack([a, b]).ravel()


def _cloud(n, seed=0, heading=None):
    rng = np.random.default_rng(seed)
    p = Particles.at(ROOMS.sample_free(n, rng), heading_rad=rng.uniform(-math.pi, math.pi, n) if heading is None
                     else heading, step_length_m=rng.uniform(0.5, 0.9, n))
    p.velocity_mps = rng.normal(0, 0.8, (n, 2))
    p.log_weight = np.log(rng.uniform(0.1, 1.0, n))
    p.log_weight[rng.random(n) < 0.1] = -np.inf  # some dead
    p.log_weight -= np.logaddexp.reduce(p.log_weight)
    return p


def _advance(p, move, **kw):
    return fused.advance(p.xy_m, p.velocity_mps, p.heading_rad, p.step_length_m, p.log_weight, move=move, key=KEY,
                         **kw)


N = 3000  # several blocks and a partial one


@pytest.mark.parametrize("motion", ["rw", "cv"])
def test_move_is_the_motion_model_fed_the_same_draws(motion):
    p = _cloud(N)
    u_a, u_b = fused.counter_uniforms(KEY, fused.SLOT_MOVE_A, N)  # the Box-Muller uniforms of the noise
    if motion == "rw":
        model = RandomWalkMotion()
        # the kernel's circle direction is that of a second normal pair: its angle is phi
        b0, b1 = fused.counter_normals(KEY, fused.SLOT_MOVE_B, N)
        phi_u = np.mod(np.arctan2(b1, b0) / (2 * np.pi), 1.0)
        expected = model.propagate(p, None, 0.7, DrawsInOrder(phi_u, _interleaved(u_a, u_b)))
    else:
        model = ConstantVelocityMotion(accel_sigma_mps2=1.5, max_speed_mps=1.2)
        expected = model.propagate(p, None, 0.7, DrawsInOrder(_interleaved(u_a, u_b)))
    got = _advance(p, model.kernel_move(None, 0.7))
    # the kernels' cos and sin are series (|error| < 1e-7), the named stages' exact
    np.testing.assert_allclose(got.xy_m, expected.xy_m, atol=1e-6, rtol=0)
    np.testing.assert_allclose(got.velocity_mps, expected.velocity_mps, atol=1e-12, rtol=0)
    assert np.array_equal(got.heading_rad, expected.heading_rad)
    assert np.array_equal(got.step_length_m, expected.step_length_m)


@pytest.mark.parametrize("step_input", [
    StepInput(2, 0.6),  # a turn: false turns drawn
    StepInput(1, 0.1),  # no turn
    StepInput(0, 0.2),  # standing: step length kept, no position noise
    StepInput(1, 0.0, heading_abs_rad=2.5),
    StepInput(3, -0.8, step_length_m=0.65),
])
def test_pdr_move_is_the_motion_model_fed_the_same_draws(step_input):
    p = _cloud(N)
    model = PDRMotion(false_turn_fraction=0.3)
    (h_noise, length_walk), (pos_x, pos_y), (given_noise, turn) = (
        fused.counter_normals(KEY, slot, N) for slot in (fused.SLOT_MOVE_A, fused.SLOT_MOVE_B, fused.SLOT_MOVE_C))
    u_turn = stats.norm.cdf(turn)  # the kernel compares the normal with the share's quantile
    # the order PDRMotion.propagate draws in, for this input
    draws = [h_noise]
    if step_input.heading_abs_rad is None and abs(step_input.heading_change_rad) >= model.turn_threshold_rad:
        draws.append(u_turn)
    if step_input.n_steps > 0:
        draws.append(length_walk)
    if step_input.step_length_m is not None:
        draws.append(given_noise)
    if step_input.n_steps > 0:
        draws.append(np.column_stack([pos_x, pos_y]))
    expected = model.propagate(p, step_input, 1.0, DrawsInOrder(*draws))
    got = _advance(p, model.kernel_move(step_input, 1.0))
    np.testing.assert_allclose(got.heading_rad, expected.heading_rad, atol=1e-12, rtol=0)
    np.testing.assert_allclose(got.step_length_m, expected.step_length_m, atol=1e-12, rtol=0)
    np.testing.assert_allclose(got.xy_m, expected.xy_m, atol=3e-6, rtol=0)


def test_pdr_without_a_step_input_stays():
    p = _cloud(N)
    got = _advance(p, PDRMotion().kernel_move(None, 1.0))
    assert np.array_equal(got.xy_m, p.xy_m) and np.array_equal(got.heading_rad, p.heading_rad)


def test_wall_kill_is_crosses_wall_of_the_live_particles():
    p = _cloud(N)
    got = _advance(p, RandomWalkMotion(radius_mps=2.0).kernel_move(None, 1.0), floorplan=ROOMS,
                   clearance=clearance_px(ROOMS))
    live = np.isfinite(p.log_weight)
    expected = crosses_wall(ROOMS, p.xy_m, got.xy_m) & live
    assert 0.05 < expected.mean() < 0.9  # the test moves through walls
    assert np.array_equal(got.killed, expected)
    assert np.array_equal(got.log_weight, np.where(expected, -np.inf, p.log_weight))


def _table(rng, k=12):
    return AccessPointTable(bssid=[f"ap{i}" for i in range(k)], band=["2.4"] * k, xy_m=ROOMS.sample_free(k, rng),
                            c_dbm=rng.uniform(-45, -35, k), n=rng.uniform(1.8, 2.6, k),
                            alpha_db_per_m=rng.uniform(0.2, 0.5, k), d_max_m=np.full(k, 30.0))


@pytest.mark.parametrize("kind", ["fix", "rssi", "given", "flat"])
def test_weights_and_sums_are_the_models_and_numpys(kind):
    rng = np.random.default_rng(3)
    p = _cloud(N)
    if kind == "fix":
        model, measurement = GaussianFixLikelihood(2.0), PositionFix((7.0, 5.0))
    elif kind in ("rssi", "given"):  # trilateration in the pass, or its own kernel's values passed in
        table = _table(rng)
        model = TrilaterationLikelihood(table)
        measurement = WifiScan(0.0, tuple(f"ap{i}@2.4" for i in range(0, 12, 2)), rng.uniform(-90, -40, 6))
    if kind == "flat":
        terms, ll = fused.flat(), np.zeros(N)
    else:
        ll = model.log_likelihood(p, measurement)
        terms = fused.given_values(ll) if kind == "given" else model.kernel_likelihood(measurement)
    shift = np.array([9.0, 4.0])
    got = _advance(p, fused.no_move(), floorplan=ROOMS, clearance=clearance_px(ROOMS), likelihood=terms,
                   shift_xy_m=shift)
    expected_lw = p.log_weight + ll
    np.testing.assert_allclose(got.log_weight, expected_lw, rtol=1e-12, atol=1e-9)
    t = fused.totals(got, shift)
    lse = np.logaddexp.reduce(expected_lw)
    w = np.exp(expected_lw - lse)
    assert t.log_normaliser == pytest.approx(lse, abs=1e-9)
    assert t.ess == pytest.approx(1.0 / np.dot(w, w), rel=1e-9)
    np.testing.assert_allclose(t.mean_xy_m, w @ p.xy_m, atol=1e-9)
    centred = p.xy_m - w @ p.xy_m
    np.testing.assert_allclose(t.covariance_m2, (centred * w[:, None]).T @ centred, atol=1e-9)
    live = np.isfinite(p.log_weight)
    assert t.n_alive_after_kill == live.sum() and t.n_finite == np.isfinite(expected_lw).sum()
    assert t.best_log_likelihood == pytest.approx(ll[live].max())
    np.testing.assert_allclose(got.e * t.block_scale[np.arange(N) // fused.BLOCK], w, rtol=1e-12, atol=1e-300)


def test_bad_likelihood_values_weigh_nothing():
    p = _cloud(N)
    ll = np.zeros(N)
    ll[:5] = [np.nan, np.inf, -np.inf, 1.0, np.nan]
    got = _advance(p, fused.no_move(), likelihood=fused.given_values(ll))
    assert np.isneginf(got.log_weight[[0, 1, 2, 4]]).all() and np.isfinite(got.log_weight[3]) == np.isfinite(
        p.log_weight[3])


@pytest.mark.parametrize("regularised", [False, True])
def test_resampling_and_jitter_are_the_stages_fed_the_same_draws(regularised):
    prev = _cloud(N)
    state = _advance(prev, RandomWalkMotion().kernel_move(None, 0.5), floorplan=ROOMS, clearance=clearance_px(ROOMS),
                     likelihood=GaussianFixLikelihood(3.0).kernel_likelihood(PositionFix((8.0, 5.0))))
    t = fused.totals(state, (0.0, 0.0))
    w = np.exp(state.log_weight - t.log_normaliser)
    u = 0.37
    h, root = bandwidth_and_root(ROOMS, t.covariance_m2, N)
    # one try: every particle's draw is the same on both paths (a redraw goes to the pending ones only)
    got = fused.resample_regularise(state, t, prev.xy_m, u=u, key=KEY, tries=1 if regularised else 0, h=h, root=root,
                                    floorplan=ROOMS, clearance=clearance_px(ROOMS), shift_xy_m=(0.0, 0.0))
    parent = systematic(w, N, DrawsInOrder(u))
    assert np.array_equal(got.parent, parent)
    assert np.array_equal(got.heading_rad, state.heading_rad[parent])
    assert np.array_equal(got.velocity_mps, state.velocity_mps[parent])
    if not regularised:
        assert np.array_equal(got.xy_m, state.xy_m[parent])
        return
    eps_a, eps_b = fused.counter_uniforms(KEY, 0, N)
    expected, moved = regularise(ROOMS, state.xy_m[parent], t.covariance_m2, DrawsInOrder(_interleaved(eps_a, eps_b)),
                                 tries=1, origin_xy_m=prev.xy_m[parent])
    assert 0.3 < moved.mean()
    np.testing.assert_allclose(got.xy_m, expected, atol=1e-12, rtol=0)
    # PDR's sums of headings and step lengths change nothing else
    walking = fused.resample_regularise(state, t, prev.xy_m, u=u, key=KEY, tries=3, h=h, root=root, floorplan=ROOMS,
                                        clearance=clearance_px(ROOMS), shift_xy_m=(0.0, 0.0), walks=True)
    standing = fused.resample_regularise(state, t, prev.xy_m, u=u, key=KEY, tries=3, h=h, root=root, floorplan=ROOMS,
                                         clearance=clearance_px(ROOMS), shift_xy_m=(0.0, 0.0))
    assert np.array_equal(walking.xy_m, standing.xy_m)
    sums = walking.sums.sum(axis=0)
    assert math.atan2(sums[fused.R_SIN], sums[fused.R_COS]) == pytest.approx(
        math.atan2(np.sin(walking.heading_rad).sum(), np.cos(walking.heading_rad).sum()), abs=1e-6)
    assert sums[fused.R_STEP] == pytest.approx(walking.step_length_m.sum())


def test_resampling_never_picks_a_dead_particle():
    prev = _cloud(5000)
    prev.log_weight[:] = -np.inf
    prev.log_weight[[17, 2500, 4999]] = [0.0, -1.0, -50.0]
    state = _advance(prev, fused.no_move(), likelihood=fused.flat())
    t = fused.totals(state, (0.0, 0.0))
    for u in (0.0, 0.5, 1.0 - 1e-12):
        got = fused.resample_regularise(state, t, prev.xy_m, u=u, key=KEY, tries=0, h=0.0, root=np.eye(2),
                                        floorplan=ROOMS, clearance=clearance_px(ROOMS), shift_xy_m=(0.0, 0.0))
        assert set(np.unique(got.parent)) <= {17, 2500, 4999}
        assert np.all(np.diff(got.parent) >= 0)


def test_counter_draws_are_standard():
    z0, z1 = fused.counter_normals(KEY, 2, 200_000)
    for z in (z0, z1):
        assert stats.kstest(z, "norm").pvalue > 1e-3
    assert abs(np.corrcoef(z0, z1)[0, 1]) < 0.01
    a, b = fused.counter_uniforms(KEY, 2, 200_000)
    assert stats.kstest(a, "uniform").pvalue > 1e-3 and stats.kstest(b, "uniform").pvalue > 1e-3
    # neighbouring particles, slots and keys are independent
    c, _ = fused.counter_uniforms(KEY, 3, 200_000)
    d, _ = fused.counter_uniforms(KEY + 1, 2, 200_000)
    assert max(abs(np.corrcoef(a[:-1], a[1:])[0, 1]), abs(np.corrcoef(a, c)[0, 1]), abs(np.corrcoef(a, d)[0, 1])) < 0.01


def _run(fused_path, seed, n, motion, steps=8, threads=None, monkeypatch=None, ess_fraction=0.6):
    if threads is not None:
        monkeypatch.setenv("MAPFILTER_THREADS", str(threads))
    rng = np.random.default_rng(seed)
    cfg = FilterConfig(n_particles=n, fused_from_particles=0 if fused_path else None,
                       resample_ess_fraction=ess_fraction)
    pf = ParticleFilter(ROOMS, motion, cfg, rng)
    pf.initialise_around((3.0, 5.0), 1.0, heading_rad=0.0)
    model = GaussianFixLikelihood(0.8)
    reports = []
    for k in range(steps):
        step_input = StepInput(1, 0.0) if motion.walks_in_steps else None
        reports.append(pf.step(k + 1.0, 1.0, step_input, model, PositionFix((3.0 + 0.8 * (k + 1), 4.6))))
    return pf, reports


def test_same_seed_same_particles_whatever_the_threads(monkeypatch):
    n = 3 * 16_384 + 123  # enough for two threads
    one, _ = _run(True, 4, n, RandomWalkMotion(), steps=3, threads=1, monkeypatch=monkeypatch)
    two, _ = _run(True, 4, n, RandomWalkMotion(), steps=3, threads=2, monkeypatch=monkeypatch)
    assert np.array_equal(one.particles.xy_m, two.particles.xy_m)
    assert np.array_equal(one.particles.log_weight, two.particles.log_weight)
    assert np.array_equal(one.estimate_xy_m, two.estimate_xy_m)


@pytest.mark.parametrize("ess_fraction", [0.6, 1.0])  # 1: resampled and jittered every step
@pytest.mark.parametrize("motion", [RandomWalkMotion(radius_mps=0.7, sigma_mps=0.3), PDRMotion()])
def test_fused_and_named_steps_give_the_same_distribution(motion, ess_fraction):
    n = 20_000
    # a resampled cloud is not an independent sample (its particles share ancestors): the runs
    # are compared by what a step reports, with margins a few times the spread between seeds
    named, named_reports = _run(False, 7, n, motion, ess_fraction=ess_fraction)
    fast, fast_reports = _run(True, 8, n, motion, ess_fraction=ess_fraction)
    # (seeds 7-9 of each path: estimates within 0.03 m, spreads 2 %, kills 8 %, ESS 2 % of each other)
    assert sum(r.resampled for r in fast_reports) >= 2 and sum(r.n_killed for r in fast_reports) > 1000
    for r_named, r_fast in zip(named_reports, fast_reports):
        assert math.dist(r_named.estimate_xy_m, r_fast.estimate_xy_m) < 0.06
        assert r_fast.estimate_std_m == pytest.approx(r_named.estimate_std_m, rel=0.04)
        assert r_fast.n_killed == pytest.approx(r_named.n_killed, rel=0.15, abs=60)
        assert r_fast.ess == pytest.approx(r_named.ess, rel=0.04)


def test_the_fused_step_from_a_number_of_particles_on():
    def stepped(n, **config):
        pf = ParticleFilter(ROOMS, RandomWalkMotion(), FilterConfig(n_particles=n, **config), np.random.default_rng(1))
        pf.initialise_around((3.0, 5.0), 1.0)
        return pf._fusable  # noqa: SLF001

    assert stepped(100, fused_from_particles=50) and not stepped(100, fused_from_particles=101)
    assert not stepped(100, fused_from_particles=None) and stepped(100, fused_from_particles=0)
    assert not stepped(100, fused_from_particles=0, resampler="residual")  # the named stages' resamplers
    assert stepped(FilterConfig.fused_from_particles) and not stepped(FilterConfig.fused_from_particles - 1)


@pytest.mark.parametrize("motion, step_input", [(PDRMotion(heading_sigma_rad=0.02), StepInput(1, 0.0)),
                                                (RandomWalkMotion(), None)])
def test_one_regularised_step_spreads_the_cloud_alike(motion, step_input):
    """From the same cloud, one step with resampling and jitter: the cloud's spread on the two
    paths (a jitter too small or too large moves it by ten times the difference allowed)."""
    open_plan = FloorPlan(np.pad(np.zeros((398, 398), dtype=bool), 1, constant_values=True), 0.1)
    start = np.random.default_rng(99).normal((20.0, 20.0), 0.5, (10_000, 2))

    def spread(fused_path, seed):
        config = FilterConfig(n_particles=10_000, fused_from_particles=0 if fused_path else None,
                              resample_ess_fraction=1.0)
        pf = ParticleFilter(open_plan, motion, config, np.random.default_rng(seed))
        pf.initialise_around((20.0, 20.0), 1.0, heading_rad=0.0)
        pf.particles.xy_m = start.copy()
        pf.step(0.0, 0.5, step_input, GaussianFixLikelihood(1.0), PositionFix((20.7, 20.0)))
        return pf.particles.xy_m.std(axis=0)

    named = np.mean([spread(False, seed) for seed in range(12)], axis=0)
    fast = np.mean([spread(True, seed) for seed in range(12)], axis=0)
    # the mean of 12 seeds errs by about 0.0005 m (PDR) to 0.001 m (random walk); the jitter adds 0.01-0.015 m
    np.testing.assert_allclose(fast, named, atol=0.004)


# ---- a building's floors: the pass runs in three calls around the floor changes ------------------
def _stack_filter(tmp_path, motion, n=3000, seed=0, connectors=False, rates=(0.0, 0.05)):
    from mapfilter.filter.floors import FloorChangeConfig, FloorChanges, FloorStack
    from tests.test_floors import _building

    stack = FloorStack(_building(tmp_path, connectors=connectors))
    changes = FloorChanges(stack, FloorChangeConfig(*rates))
    pf = ParticleFilter(stack.plan, motion, FilterConfig(n_particles=n, init_samples=5000, fused_from_particles=0),
                        np.random.default_rng(seed), floors=changes)
    assert pf._fusable  # noqa: SLF001
    return stack, changes, pf


def test_on_a_buildings_floors_no_particle_lives_in_a_wall_and_the_evidence_finds_the_floor(tmp_path):
    from mapfilter.filter.floors import FloorFix, FloorFixLikelihood

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
    from mapfilter.filter.particles import Particles

    stack, changes, pf = _stack_filter(tmp_path, PDRMotion(heading_sigma_rad=0.0, position_sigma_m=0.0), n=400,
                                       connectors=True, rates=(0.0, 0.0))
    lo, hi = changes.config.stairs_tread_m
    rng = np.random.default_rng(6)
    on = np.column_stack([rng.uniform(2.3, 3.0, 200), rng.uniform(2.3, 4.7, 200)])  # west end of the stairs
    off = np.column_stack([rng.uniform(8.0, 12.0, 200), rng.uniform(2.3, 4.7, 200)])
    start = stack.to_stack(np.concatenate([on, off]), 0)
    pf.particles = Particles.at(start, heading_rad=0.0, step_length_m=0.7)
    pf.step(1.0, 0.6, StepInput(1, 0.0))
    moved_m = np.linalg.norm(pf.particles.xy_m - start, axis=1)
    assert (moved_m[:200] <= hi + 0.05).all() and (moved_m[200:] >= 0.6).all()
