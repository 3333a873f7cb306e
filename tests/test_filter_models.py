"""Motion models, measurement models, the RSSI kernel, regularisation bandwidth and estimate."""

import math

import numpy as np
import pytest

from mapfilter.filter.estimate import circular_mean, weighted_estimate
from mapfilter.filter.measurement import GaussianFixLikelihood, PositionFix, rssi_log_likelihood
from mapfilter.filter.models.motion import ConstantVelocityMotion, PDRMotion, RandomWalkMotion, StepInput
from mapfilter.filter.particles import Particles
from mapfilter.filter.regularise import optimal_bandwidth, regularise, sample_kernel
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import crosses_wall
from mapfilter.sensors.pathloss import path_loss_rssi_dbm


def _particles(n, xy=(0.0, 0.0), heading=0.0):
    return Particles.at(np.tile(np.asarray(xy, float), (n, 1)), heading_rad=heading, step_length_m=0.7)


def test_random_walk_on_a_circle_matches_thesis_moments():
    rng = np.random.default_rng(0)
    p = _particles(200_000)
    before = p.copy()
    moved = RandomWalkMotion().propagate(p, None, 2.0, rng)
    np.testing.assert_array_equal(p.xy_m, before.xy_m)  # never mutates its input
    d = np.linalg.norm(moved.xy_m, axis=1)
    # r = 1.5 dt = 3 m, sigma = 0.5 dt = 1 m: E|x|^2 = r^2 + 2 sigma^2 = 11
    assert np.mean(d ** 2) == pytest.approx(11.0, rel=0.02)
    assert np.abs(moved.xy_m.mean(axis=0)).max() < 0.02


def test_constant_velocity_moves_along_velocity():
    rng = np.random.default_rng(1)
    p = _particles(50_000)
    p.velocity_mps[:] = [1.0, 0.0]
    moved = ConstantVelocityMotion(accel_sigma_mps2=0.2).propagate(p, None, 1.0, rng)
    assert moved.xy_m.mean(axis=0) == pytest.approx([1.0, 0.0], abs=0.01)
    assert moved.xy_m[:, 1].std() == pytest.approx(0.1, rel=0.05)  # a dt^2 / 2
    assert moved.velocity_mps[:, 1].std() == pytest.approx(0.2, rel=0.05)
    fast = p.copy()
    fast.velocity_mps[:] = [10.0, 0.0]
    out = ConstantVelocityMotion(max_speed_mps=2.0).propagate(fast, None, 1.0, rng)
    assert np.hypot(*out.velocity_mps.T).max() <= 2.0 + 1e-9


def test_pdr_steps_along_heading_with_false_turns():
    rng = np.random.default_rng(2)
    n = 100_000
    p = _particles(n, heading=0.0)
    motion = PDRMotion(heading_sigma_rad=0.0, step_length_walk_sigma_m=0.0, position_sigma_m=0.0)
    moved = motion.propagate(p, StepInput(n_steps=2, heading_change_rad=math.pi / 2), 1.0, rng)
    turned = np.isclose(moved.heading_rad, math.pi / 2)
    ignored = np.isclose(moved.heading_rad, 0.0)
    assert np.all(turned | ignored)
    assert ignored.mean() == pytest.approx(0.15, abs=0.01)  # thesis: 15 % false turns
    np.testing.assert_allclose(moved.xy_m[turned], np.tile([0.0, 1.4], (turned.sum(), 1)), atol=1e-9)
    np.testing.assert_allclose(moved.xy_m[ignored], np.tile([1.4, 0.0], (ignored.sum(), 1)), atol=1e-9)
    # small changes are applied to every particle
    small = motion.propagate(p, StepInput(1, 0.1), 1.0, rng)
    np.testing.assert_allclose(small.heading_rad, 0.1)


def test_pdr_step_length_state_given_and_absolute_heading():
    rng = np.random.default_rng(3)
    p = _particles(10_000)
    motion = PDRMotion(step_length_walk_sigma_m=0.05)
    walked = motion.propagate(p, StepInput(1, 0.0), 1.0, rng)
    assert walked.step_length_m.std() > 0.03  # the state random-walks (eq. 8.23)
    assert walked.step_length_m.min() >= motion.step_length_min_m
    given = PDRMotion(heading_sigma_rad=0.0, position_sigma_m=0.0, step_length_input_sigma_m=0.0).propagate(
        p, StepInput(1, 0.0, heading_abs_rad=-math.pi / 2, step_length_m=0.5), 1.0, rng)
    np.testing.assert_allclose(given.xy_m, np.tile([0.0, -0.5], (10_000, 1)), atol=1e-9)
    standing = motion.propagate(p, StepInput(0, 0.0), 1.0, rng)
    np.testing.assert_array_equal(standing.xy_m, p.xy_m)
    with pytest.raises(ValueError):
        motion.propagate(p, StepInput(-1, 0.0), 1.0, rng)


def test_gaussian_fix_likelihood():
    p = Particles.at(np.array([[0.0, 0.0], [3.0, 4.0]]))
    ll = GaussianFixLikelihood(5.0).log_likelihood(p, PositionFix((0.0, 0.0)))
    np.testing.assert_allclose(ll, [0.0, -0.5])
    ll2 = GaussianFixLikelihood(5.0).log_likelihood(p, PositionFix((0.0, 0.0), sigma_m=1.0))
    np.testing.assert_allclose(ll2, [0.0, -12.5])
    with pytest.raises(ValueError):
        GaussianFixLikelihood(0.0).log_likelihood(p, PositionFix((0.0, 0.0)))


def test_rssi_kernel_matches_the_path_loss_model():
    rng = np.random.default_rng(4)
    xy = rng.uniform(-5, 60, (5000, 2))
    ap = rng.uniform(0, 50, (20, 2))
    ap[0] = xy[0]  # distance 0: clamped at 1 m
    c, n = rng.uniform(-45, -30, 20), rng.uniform(1.5, 3.0, 20)
    alpha, d_max = rng.uniform(0.2, 0.6, 20), rng.uniform(10, 40, 20)
    observed = rng.uniform(-90, -40, 20)
    observed[3] = np.nan  # not heard: left out
    got = rssi_log_likelihood(xy, ap, c, n, alpha, d_max, observed, 25.0)
    d = np.linalg.norm(xy[:, None] - ap[None], axis=-1)
    r = observed - path_loss_rssi_dbm(d, c, n, alpha, d_max)
    expected = -np.nansum(r ** 2, axis=1) / 50.0
    np.testing.assert_allclose(got, expected, rtol=2e-5, atol=1e-3)
    assert got.dtype == np.float64 and got.shape == (5000,)


def test_bandwidth_constants():
    # Gaussian: A = (4/(d+2))^(1/(d+4)) = 1 for d = 2
    assert optimal_bandwidth(1, "gaussian") == pytest.approx(1.0)
    assert optimal_bandwidth(10_000, "gaussian") == pytest.approx(10_000 ** (-1 / 6))
    # Epanechnikov, d = 2: A = (8 * 6 * (2 sqrt(pi))^2 / pi)^(1/6) = 192^(1/6)
    assert optimal_bandwidth(1, "epanechnikov") == pytest.approx(192 ** (1 / 6))
    eps = sample_kernel("epanechnikov", 100_000, np.random.default_rng(5))
    r2 = (eps ** 2).sum(axis=1)
    assert r2.max() <= 1.0 and r2.mean() == pytest.approx(1 / 3, rel=0.02)  # Beta(1, 2) mean
    with pytest.raises(ValueError):
        optimal_bandwidth(10, "box")


def test_regularise_never_crosses_walls():
    rng = np.random.default_rng(6)
    mask = np.zeros((40, 40), dtype=bool)
    mask[:, 20] = True
    fp = FloorPlan(mask, 0.1)
    xy = np.column_stack([rng.uniform(1.85, 1.99, 5000), rng.uniform(0.5, 3.5, 5000)])  # hugging the wall
    origin = xy + np.array([-0.2, 0.0])
    new, moved = regularise(fp, xy, np.diag([0.5, 0.5]), rng, tries=3, origin_xy_m=origin)
    assert not crosses_wall(fp, xy, new).any()
    assert not crosses_wall(fp, origin, new).any()
    assert 0.1 < moved.mean() < 1.0  # some jitter rejected, most accepted
    assert np.array_equal(new[~moved], xy[~moved])


def test_estimate_never_in_a_wall():
    mask = np.zeros((20, 20), dtype=bool)
    mask[:, 9:11] = True  # wall between two halves
    fp = FloorPlan(mask, 1.0)
    xy = np.array([[5.0, 10.0], [15.0, 10.0], [5.5, 10.0]])
    est, std, fell_back = weighted_estimate(fp, xy, np.array([0.45, 0.45, 0.1]))
    assert fell_back and fp.is_free(est[None])[0]
    assert est.tolist() in ([5.5, 10.0], [5.0, 10.0], [15.0, 10.0])
    est2, _, fb2 = weighted_estimate(fp, xy[:1], np.ones(1))
    assert not fb2 and est2.tolist() == [5.0, 10.0]
    assert circular_mean(np.array([math.pi - 0.1, -math.pi + 0.1]), np.ones(2)) == pytest.approx(math.pi)


def test_circle_walk_directions_match_cos_sin():
    from mapfilter.filter.models.motion import _circle_walk

    phi = np.linspace(0.0, 2.0 * math.pi, 20001)[:-1]
    out = np.empty((phi.size, 2))
    _circle_walk(0, phi.size, np.zeros((phi.size, 2)), phi, np.zeros((phi.size, 2)), 1.0, 0.0, out)
    np.testing.assert_allclose(out, np.column_stack([np.cos(phi), np.sin(phi)]), atol=1e-7)


def test_fast_standard_normal_is_box_muller_on_the_generators_uniforms():
    from scipy import stats

    from mapfilter.filter.gaussian import standard_normal

    z = standard_normal(np.random.default_rng(8), (7,))  # odd size
    u = np.random.default_rng(8).random(8)
    r = np.sqrt(-2.0 * np.log(1.0 - u[0::2]))
    exact = np.empty(8)
    exact[0::2] = r * np.cos(2 * np.pi * u[1::2])
    exact[1::2] = r * np.sin(2 * np.pi * u[1::2])
    np.testing.assert_allclose(z, exact[:7], atol=1e-7)
    big = standard_normal(np.random.default_rng(9), (200_000, 2))
    assert big.shape == (200_000, 2)
    assert abs(big.mean()) < 0.01 and abs(big.std() - 1.0) < 0.01
    assert stats.kstest(big.ravel(), "norm").pvalue > 1e-3
    assert np.isfinite(big).all()
