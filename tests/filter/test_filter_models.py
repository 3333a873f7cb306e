"""Motion and measurement models through the filter's kernels: their distributions and values
against the thesis' formulas; the regularisation bandwidth; the estimate."""

import math

import numpy as np
import pytest

from mapfilter.filter.estimate import circular_mean, weighted_estimate
from mapfilter.filter.kernels.draws import cos_sin
from mapfilter.filter.models.motion import ConstantVelocityMotion, PDRMotion, RandomWalkMotion, StepInput
from mapfilter.filter.models.path_loss import TrilaterationLikelihood
from mapfilter.filter.models.position_fix import GaussianFixLikelihood, PositionFix
from mapfilter.filter.particle_filter import FilterConfig, ParticleFilter, evaluate_log_likelihood, optimal_bandwidth
from mapfilter.filter.particles import Particles
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.sensors.pathloss import AccessPointTable, path_loss_rssi_dbm
from mapfilter.sensors.wifi import WifiScan

OPEN = FloorPlan(np.pad(np.zeros((998, 998), dtype=bool), 1, constant_values=True), 0.1)  # 100 m square
CENTRE = (50.0, 50.0)


def _moved(motion, n, inputs, dt_s, heading=0.0, velocity=(0.0, 0.0), seed=0):
    """One step of ``motion`` from n particles at the centre (no weighing, no resampling)."""
    pf = ParticleFilter(OPEN, motion, FilterConfig(n_particles=n, resample_ess_fraction=0.0), np.random.default_rng(seed))
    pf.particles = Particles.at(np.tile(CENTRE, (n, 1)), heading_rad=heading, step_length_m=0.7)
    pf.particles.state[2], pf.particles.state[3] = velocity
    pf.estimate_xy_m = np.array(CENTRE)
    pf.step(1.0, dt_s, inputs)
    return pf.particles


def test_random_walk_on_a_circle_matches_thesis_moments():
    moved = _moved(RandomWalkMotion(), 200_000, None, 2.0)
    d = moved.xy_m - CENTRE
    # r = 1.5 dt = 3 m, sigma = 0.5 dt = 1 m: E|x|^2 = r^2 + 2 sigma^2 = 11
    assert np.mean((d ** 2).sum(axis=1)) == pytest.approx(11.0, rel=0.02)
    assert np.abs(d.mean(axis=0)).max() < 0.02
    angle = np.arctan2(d[:, 1], d[:, 0])
    assert np.histogram(angle, bins=8)[0].min() > 0.95 * len(angle) / 8  # every direction alike


def test_constant_velocity_moves_along_velocity():
    moved = _moved(ConstantVelocityMotion(accel_sigma_mps2=0.2), 50_000, None, 1.0, velocity=(1.0, 0.0))
    d = moved.xy_m - CENTRE
    assert d.mean(axis=0) == pytest.approx([1.0, 0.0], abs=0.01)
    assert d[:, 1].std() == pytest.approx(0.1, rel=0.05)  # a dt^2 / 2
    assert moved.velocity_mps[:, 1].std() == pytest.approx(0.2, rel=0.05)
    fast = _moved(ConstantVelocityMotion(max_speed_mps=2.0), 5_000, None, 1.0, velocity=(10.0, 0.0))
    assert np.hypot(*fast.velocity_mps.T).max() <= 2.0 + 1e-9


def test_pdr_steps_along_heading_with_false_turns():
    from mapfilter.filter.models.motion import POSITION_SIGMA_M, STEP_LENGTH_WALK_SIGMA_M

    moved = _moved(PDRMotion(heading_sigma_rad=0.0), 100_000, StepInput(n_steps=2, heading_change_rad=math.pi / 2),
                   1.0)
    turned = np.isclose(moved.heading_rad, math.pi / 2)
    ignored = np.isclose(moved.heading_rad, 0.0)
    assert np.all(turned | ignored)
    assert ignored.mean() == pytest.approx(0.15, abs=0.01)  # thesis: 15 % false turns
    # two steps of the state's length (0.7 m) along the heading, with the per-step slack across it
    for sel, along in ((turned, 1), (ignored, 0)):
        d = moved.xy_m[sel] - CENTRE
        assert d[:, along].mean() == pytest.approx(1.4, abs=0.01)
        assert d[:, 1 - along].mean() == pytest.approx(0.0, abs=0.01)
        assert d[:, 1 - along].std() == pytest.approx(POSITION_SIGMA_M * math.sqrt(2), rel=0.05)
    small = _moved(PDRMotion(heading_sigma_rad=0.0), 1000, StepInput(1, 0.1), 1.0)
    np.testing.assert_allclose(small.heading_rad, 0.1)  # below the turn threshold: every particle turns
    standing = _moved(PDRMotion(), 1000, StepInput(0, 0.0), 1.0)
    np.testing.assert_allclose(standing.xy_m, np.tile(CENTRE, (1000, 1)))
    np.testing.assert_allclose(standing.step_length_m, 0.7)
    walked = _moved(PDRMotion(), 20_000, StepInput(1, 0.0), 1.0)
    assert walked.step_length_m.std() == pytest.approx(STEP_LENGTH_WALK_SIGMA_M, rel=0.05)
    narrow = _moved(PDRMotion(step_length_min_m=0.69, step_length_max_m=0.71), 20_000, StepInput(1, 0.0), 1.0)
    assert narrow.step_length_m.min() >= 0.69 and narrow.step_length_m.max() <= 0.71  # clipped to the bounds
    with pytest.raises(ValueError):
        PDRMotion().kernel(StepInput(-1, 0.0), 1.0)


def test_gaussian_fix_likelihood():
    p = Particles.at(np.array([[0.0, 0.0], [3.0, 4.0]]))
    ll = evaluate_log_likelihood(GaussianFixLikelihood(5.0), PositionFix((0.0, 0.0)), p)
    np.testing.assert_allclose(ll, [0.0, -0.5])
    ll2 = evaluate_log_likelihood(GaussianFixLikelihood(5.0), PositionFix((0.0, 0.0), sigma_m=1.0), p)
    np.testing.assert_allclose(ll2, [0.0, -12.5])
    with pytest.raises(ValueError):
        evaluate_log_likelihood(GaussianFixLikelihood(0.0), PositionFix((0.0, 0.0)), p)


def test_path_loss_kernel_matches_the_model():
    rng = np.random.default_rng(4)
    xy = rng.uniform(-5, 60, (5000, 2))
    k = 20
    ap = rng.uniform(0, 50, (k, 2))
    ap[0] = xy[0]  # distance 0: clamped at 1 m
    c, n = rng.uniform(-45, -30, k), rng.uniform(1.5, 3.0, k)
    alpha, d_max = rng.uniform(0.2, 0.6, k), rng.uniform(10, 40, k)
    bssids = [f"aa:bb:cc:00:00:{i:02x}" for i in range(k)]
    table = AccessPointTable(bssid=bssids, band=["2.4"] * k, xy_m=ap, c_dbm=c, n=n, alpha_db_per_m=alpha, d_max_m=d_max)
    keys = table.keys
    heard = np.ones(k, dtype=bool)
    heard[3] = False  # not heard: left out
    observed = rng.uniform(-90, -40, k)
    scan = WifiScan(t_s=0.0, ap_keys=tuple(keys[i] for i in np.flatnonzero(heard)), rssi_dbm=observed[heard])
    got = evaluate_log_likelihood(TrilaterationLikelihood(table, 25.0), scan, Particles.at(xy))
    d = np.linalg.norm(xy[:, None] - ap[None], axis=-1)
    r = observed - path_loss_rssi_dbm(d, c, n, alpha, d_max)
    expected = -(r[:, heard] ** 2).sum(axis=1) / 50.0
    np.testing.assert_allclose(got, expected, rtol=2e-5, atol=1e-3)
    assert got.dtype == np.float64 and got.shape == (5000,)


def test_bandwidth_constant():
    # Gaussian: A = (4/(d+2))^(1/(d+4)) = 1 for d = 2
    assert optimal_bandwidth(1) == pytest.approx(1.0)
    assert optimal_bandwidth(10_000) == pytest.approx(10_000 ** (-1 / 6))


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


def test_the_kernels_cos_and_sin():
    angle = np.linspace(-math.pi, math.pi, 20001)
    got = np.array([cos_sin(a) for a in angle])
    np.testing.assert_allclose(got, np.column_stack([np.cos(angle), np.sin(angle)]), atol=1e-6)
