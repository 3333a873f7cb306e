"""The fast step (``ParticleFilter.step``: two numba passes over blocks, the models' kernels) held
to the reference step in numpy (``filter.reference``), draw for draw, on the bundled office map
and an ILC floor: the moves, the wall kills, the weights, the parents and the jitter."""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest

from mapfilter.filter.models.motion import PDRMotion, RandomWalkMotion, StepInput
from mapfilter.filter.models.position_fix import GaussianFixLikelihood, PositionFix
from mapfilter.filter.particle_filter import FilterConfig, ParticleFilter
from mapfilter.filter.reference import reference_step
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import touches_wall_reference
from tests.conftest import REPO

N = 3000


def _office() -> FloorPlan:
    return FloorPlan.load(REPO / "maps" / "office.yaml")


@pytest.fixture(scope="module", params=["office", "ilc"])
def plan(request):
    if request.param == "office":
        return _office()
    return request.getfixturevalue("ilc_f1_plan")


def _filter(plan: FloorPlan, motion, ess_fraction: float, seed: int) -> ParticleFilter:
    pf = ParticleFilter(plan, motion, FilterConfig(n_particles=N, resample_ess_fraction=ess_fraction),
                        np.random.default_rng(seed))
    pf.initialise_uniform()
    rng = np.random.default_rng(seed + 1)
    pf.particles.step_length_m = rng.uniform(0.5, 0.9, N)
    pf.particles.heading_rad = rng.uniform(-np.pi, np.pi, N)
    return pf


def _both(plan: FloorPlan, motion, step_input, ess_fraction: float, seed: int):
    """(the cloud before, the fast filter after its step, the reference step, the reference step
    without the jitter) from the same cloud and draws."""
    pf = _filter(plan, motion, ess_fraction, seed)
    pf.step(0.0, 0.1, step_input)  # a step's parents are known from the second step after a start
    before, rng = pf.particles.copy(), copy.deepcopy(pf.rng)
    centre = before.xy_m[np.argmax(before.xy_m[:, 0])] - [3.0, 0.0]  # a fix inside the map's extent
    model, fix = GaussianFixLikelihood(8.0), PositionFix(centre)
    report = pf.step(1.0, 1.0, step_input, model, fix)
    plain = reference_step(plan, before, motion, step_input, 1.0, [(model, fix)],
                           dataclasses.replace(pf.config, regularise=False), copy.deepcopy(rng))
    expected = reference_step(plan, before, motion, step_input, 1.0, [(model, fix)], pf.config, rng)
    assert report.resampled == expected.resampled
    return before, pf, expected, plain


@pytest.mark.parametrize("motion, step_input", [(RandomWalkMotion(radius_mps=2.0), None),
                                                (PDRMotion(), StepInput(3, 0.6))])
def test_the_fast_moves_kills_and_weights_are_the_references(plan, motion, step_input):
    before, pf, expected, _ = _both(plan, motion, step_input, ess_fraction=0.0, seed=5)
    killed = ~np.isfinite(expected.particles.log_weight)
    assert 0.01 < killed.mean() < 0.9  # the step meets walls on this map
    np.testing.assert_allclose(pf.particles.state, expected.particles.state, atol=2e-6)
    np.testing.assert_array_equal(~np.isfinite(pf.particles.log_weight), killed)
    alive = ~killed
    np.testing.assert_allclose(pf.particles.log_weight[alive], expected.particles.log_weight[alive], atol=1e-9)


@pytest.mark.parametrize("motion, step_input", [(RandomWalkMotion(radius_mps=2.0), None),
                                                (PDRMotion(), StepInput(2, 0.0))])
def test_the_fast_resampling_and_jitter_are_the_references(plan, motion, step_input):
    before, pf, expected, plain = _both(plan, motion, step_input, ess_fraction=1.0, seed=8)
    assert expected.resampled
    same = pf.last_parents == expected.parents
    assert same.mean() > 0.995  # a bin edge within round-off may differ
    close = np.all(np.abs(pf.particles.state - expected.particles.state) < 1e-5, axis=0)
    assert close[same].mean() > 0.995
    assert np.exp(pf.particles.log_weight).sum() == pytest.approx(1.0)
    # the jitter moved most copies off their parents, and none into a wall
    np.testing.assert_array_equal(plain.parents, expected.parents)
    assert np.mean(np.any(expected.particles.xy_m != plain.particles.xy_m, axis=1)) > 0.5
    assert not touches_wall_reference(plan, expected.particles.xy_m, expected.particles.xy_m).any()
