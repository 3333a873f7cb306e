"""The fingerprint fix that knows where its survey reaches (filter/models/survey_reach.py): the
kernel against its numpy twin, the Gaussian inside the survey, a flatter likelihood away from it,
the in-survey probability of scans, and the distance grid against brute force."""

import numpy as np
import pytest

from mapfilter.filter.models.survey_reach import (ReachFix, ReachFixLikelihood, distance_grid,
                                                  mixture_log_likelihood, survey_reach)
from mapfilter.filter.particle_filter import evaluate_log_likelihood
from mapfilter.filter.particles import Particles
from mapfilter.sensors.radiomap import RadioMap

EXTENT = (0.0, 60.0, 0.0, 30.0)  # a 60 m x 30 m floor; the survey covers x < 20 m only


def _survey(n_walks: int = 6, seed: int = 0) -> tuple[RadioMap, np.ndarray]:
    """Walks along y at x < 20 m, 3 m apart, and (with more than one) a last one alone at x = 32 m
    (its points stand for scans from outside the others); 12 APs along the floor, a log-distance
    model with 2 dB noise."""
    rng = np.random.default_rng(seed)
    aps = np.column_stack([np.linspace(2, 58, 12), np.tile([5.0, 25.0], 6)])
    x_m = [2.0 + 3.0 * w for w in range(n_walks)] + ([32.0] if n_walks > 1 else [])
    n_walks = len(x_m)
    xy = np.concatenate([np.column_stack([np.full(30, x), np.linspace(1, 29, 30)]) for x in x_m])
    return RadioMap(xy, [f"ap{i}@2.4" for i in range(12)], _rssi(xy, aps, rng), np.arange(len(xy), dtype=float),
                    np.repeat(np.arange(n_walks), 30), [f"walk{w}" for w in range(n_walks)]), aps


def _rssi(xy: np.ndarray, aps: np.ndarray, rng) -> np.ndarray:
    d = np.maximum(np.linalg.norm(xy[:, None] - aps[None], axis=2), 1.0)
    rssi = -40.0 - 25.0 * np.log10(d) + rng.normal(0, 2.0, d.shape)
    return np.where(rssi >= -95, np.round(rssi), np.nan).astype(np.float32)


def test_the_kernel_is_its_numpy_twin():
    radio_map, _ = _survey()
    grid = distance_grid(radio_map.xy_m, EXTENT)
    model = ReachFixLikelihood(3.0, grid)
    rng = np.random.default_rng(1)
    xy = rng.uniform([-5, -5], [65, 35], (4000, 2))  # beyond the grid too: its edge value
    for w in (0.0, 0.3, 1.0):
        fix = ReachFix(np.array([10.0, 12.0]), w)
        ll = evaluate_log_likelihood(model, fix, Particles.at(xy))
        r2 = ((xy - fix.xy_m) ** 2).sum(axis=1)
        np.testing.assert_allclose(ll, mixture_log_likelihood(r2, grid.at(xy) ** 2, 9.0, w), rtol=1e-9, atol=1e-9)


def test_a_scan_inside_the_survey_weighs_as_the_gaussian_fix():
    radio_map, _ = _survey()
    model = ReachFixLikelihood(4.0, distance_grid(radio_map.xy_m, EXTENT))
    xy = np.array([[10.0, 10.0], [14.0, 13.0], [40.0, 10.0], [400.0, 10.0]])  # the last 97 sigma off: no floor
    ll = evaluate_log_likelihood(model, ReachFix(np.array([10.0, 10.0]), 1.0), Particles.at(xy))
    np.testing.assert_allclose(ll, -((xy - [10.0, 10.0]) ** 2).sum(axis=1) / 32.0, atol=1e-9)


def test_a_scan_from_outside_the_survey_pulls_far_particles_less():
    radio_map, _ = _survey()
    model = ReachFixLikelihood(3.0, distance_grid(radio_map.xy_m, EXTENT))
    fix_at_the_edge = np.array([17.0, 15.0])
    inside, far = np.array([[17.0, 15.0]]), np.array([[45.0, 15.0]])  # far: 28 m off the fix, 28 m off the survey

    def gap(w: float) -> float:  # how much more the particle at the fix weighs than the far one (nats)
        ll = evaluate_log_likelihood(model, ReachFix(fix_at_the_edge, w), Particles.at(np.vstack([inside, far])))
        return float(ll[0] - ll[1])

    assert gap(1.0) == pytest.approx(28.0 ** 2 / 18.0, rel=1e-6)  # the Gaussian: 43.6 nats
    assert gap(0.0) < 5.0  # out of the survey the far particle is nearly as likely
    assert gap(0.0) < gap(0.5) < gap(1.0)


def test_in_survey_probability_ranks_scans_by_how_well_they_match():
    radio_map, aps = _survey()
    reach = survey_reach(radio_map)
    assert reach.in_survey_match_db.size >= 100  # every walk's points have a neighbour walk 3 m away
    assert reach.outside_match_db.size == 30  # the lone walk's: 15 m from the others
    rng = np.random.default_rng(7)
    inside_xy = np.column_stack([np.full(40, 9.5), np.linspace(2, 28, 40)])
    outside_xy = np.column_stack([np.full(40, 55.0), np.linspace(2, 28, 40)])
    w_in = reach.in_survey_probability(_rssi(inside_xy, aps, rng))
    w_out = reach.in_survey_probability(_rssi(outside_xy, aps, rng))
    assert np.all((w_in >= 0) & (w_in <= 1)) and np.all((w_out >= 0) & (w_out <= 1))
    assert np.median(w_in) > 0.3 and np.median(w_out) < 0.05
    deaf = np.full((1, len(radio_map.ap_keys)), np.nan, dtype=np.float32)
    assert reach.in_survey_probability(deaf)[0] == 0.0  # a scan that matches nothing


def test_a_survey_that_shows_no_scan_from_outside_counts_every_matching_scan_as_inside():
    radio_map, aps = _survey()
    overlapping = radio_map.without_traces([radio_map.source_traces[-1]])  # no lone walk: no outside matches
    reach = survey_reach(overlapping)
    assert reach.outside_match_db.size == 0 and reach.in_survey_match_db.size >= 100
    w = reach.in_survey_probability(_rssi(np.array([[9.5, 10.0], [55.0, 10.0]]), aps, np.random.default_rng(0)))
    assert np.all(w == 1.0)  # it cannot tell: the plain Gaussian fix, as before


def test_a_survey_of_one_walk_counts_every_matching_scan_as_inside():
    radio_map, aps = _survey(n_walks=1)
    reach = survey_reach(radio_map)
    assert reach.in_survey_match_db.size == 0
    w = reach.in_survey_probability(_rssi(np.array([[50.0, 10.0]]), aps, np.random.default_rng(0)))
    assert w[0] == 1.0  # nothing to compare with: the plain Gaussian fix, as before


def test_the_distance_grid_is_the_nearest_reference_point():
    rng = np.random.default_rng(3)
    refs = rng.uniform([0, 0], [60, 30], (50, 2))
    grid = distance_grid(refs, EXTENT)
    centres = rng.integers([0, 0], [60, 30], (500, 2)) + 0.5
    brute = np.linalg.norm(centres[:, None] - refs[None], axis=2).min(axis=1)
    np.testing.assert_allclose(grid.at(centres), brute, atol=1e-9)
    refs_3d = np.column_stack([refs, np.where(np.arange(50) < 25, 0.0, 4.0)])
    upstairs = distance_grid(refs_3d, EXTENT, height_m=4.0)
    brute_3d = np.linalg.norm(np.column_stack([centres, np.full(500, 4.0)])[:, None] - refs_3d[None], axis=2).min(axis=1)
    np.testing.assert_allclose(upstairs.at(centres), brute_3d, atol=1e-9)


@pytest.mark.parametrize("dims", [2, 3])
def test_the_distance_grids_sweep_gives_ckdtrees_distances_to_the_last_bit(dims):
    """Oracle: the sweep (no scipy.spatial on a walk's path) against cKDTree.query, which the grid
    was made with before: the same numbers exactly, on points with ties (rounded coordinates),
    points beyond the extent, one point, and none."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(5)
    x0, x1, y0, y1 = -5.0, 62.0, -3.0, 33.0
    for n in (1, 7, 60, 400):
        refs = rng.uniform([-20, -20, 0][:dims], [80, 50, 8][:dims], (n, dims)).round(int(rng.integers(0, 3)))
        grid = distance_grid(refs, (x0, x1, y0, y1), height_m=4.0, cell_m=0.7)
        rows, cols = grid.distance_m.shape
        yy, xx = np.mgrid[0:rows, 0:cols]
        centres = np.column_stack([x0 + (xx.ravel() + 0.5) * 0.7, y0 + (yy.ravel() + 0.5) * 0.7])
        if dims == 3:
            centres = np.column_stack([centres, np.full(len(centres), 4.0)])
        np.testing.assert_array_equal(grid.distance_m.ravel(), cKDTree(refs).query(centres)[0])
    assert np.isinf(distance_grid(np.zeros((0, dims)), (x0, x1, y0, y1)).distance_m).all()


def test_a_building_floor_fix_inside_the_survey_is_the_gaussian_and_flatter_outside():
    """FloorFixLikelihood with each floor's distance grid: a scan taken inside the survey weighs
    positions as the plain Gaussian fix; one taken outside spares the particles far from the survey."""
    from mapfilter.filter.models.building import FloorFix, FloorFixLikelihood, FloorStack
    from mapfilter.maps.building import Building
    from mapfilter.maps.floorplan import FloorPlan

    plan = FloorPlan(np.pad(np.zeros((298, 598), dtype=bool), 1, constant_values=True), 0.1)  # 60 m x 30 m
    stack = FloorStack(Building.from_plan(plan))
    radio_map, _ = _survey()
    grid = distance_grid(radio_map.xy_m, plan.extent_m)
    gaussian, reach = FloorFixLikelihood(stack, np.array([3.0])), FloorFixLikelihood(stack, np.array([3.0]), [grid])
    particles = Particles.at(stack.to_stack(np.array([[10.0, 10.0], [12.0, 14.0], [45.0, 15.0]]), 0))
    fix = stack.to_stack(np.array([[10.0, 10.0]]), 0)
    plain = gaussian.log_likelihood(particles, FloorFix(fix, np.zeros(1)))
    inside = reach.log_likelihood(particles, FloorFix(fix, np.zeros(1), in_survey=1.0))
    np.testing.assert_allclose(inside, plain, atol=1e-9)
    outside = reach.log_likelihood(particles, FloorFix(fix, np.zeros(1), in_survey=0.0))
    assert outside[2] - outside[0] > plain[2] - plain[0] + 50.0  # the far particle: 35 m off, in unsurveyed space


def test_outside_the_survey_the_rotation_vector_weighs_headings_and_inside_nothing_changes():
    """The heading term of the module docstring, in both fix models: (1 - w) (cos(h_i - h_rv) - 1)
    / sigma_h^2 added to the position's log-likelihood (one floor: exactly; a building: within
    each floor, so that no floor's weight moves); nothing at w = 1 or without a heading."""
    from mapfilter.filter.models.building import FloorFix, FloorFixLikelihood, FloorStack
    from mapfilter.filter.particles import HEADING
    from mapfilter.maps.building import Building, Floor
    from mapfilter.maps.floorplan import FloorPlan

    radio_map, _ = _survey()
    grid = distance_grid(radio_map.xy_m, EXTENT)
    model = ReachFixLikelihood(3.0, grid)
    rng = np.random.default_rng(4)
    particles = Particles.at(np.column_stack([rng.uniform(0, 60, 400), rng.uniform(0, 30, 400)]))
    particles.state[HEADING] = rng.uniform(-np.pi, np.pi, 400)
    h_rv, sigma = 0.7, np.radians(25.0)
    fix = np.array([15.0, 12.0])
    for w in (0.0, 0.3, 1.0):
        plain = evaluate_log_likelihood(model, ReachFix(fix, w), particles)
        turned = evaluate_log_likelihood(model, ReachFix(fix, w, heading_rad=h_rv, heading_sigma_rad=sigma), particles)
        expected = (1.0 - w) * (np.cos(particles.state[HEADING] - h_rv) - 1.0) / sigma ** 2
        np.testing.assert_allclose(turned - plain, expected, atol=1e-9)
    assert np.ptp(expected) == 0.0 and np.ptp(turned - plain) < 1e-9  # at w = 1 nothing
    nan_heading = evaluate_log_likelihood(model, ReachFix(fix, 0.3, heading_rad=np.nan, heading_sigma_rad=sigma),
                                          particles)
    np.testing.assert_array_equal(nan_heading, evaluate_log_likelihood(model, ReachFix(fix, 0.3), particles))

    # a building of two floors: the term reweighs within each floor, never between them
    plan = FloorPlan(np.pad(np.zeros((298, 598), dtype=bool), 1, constant_values=True), 0.1)  # 60 m x 30 m
    stack = FloorStack(Building([Floor("0", plan), Floor("1", plan, elevation_m=4.0)]))
    floor_of = rng.integers(0, 2, 400)
    cloud = Particles.at(stack.to_stack(particles.xy_m, floor_of))
    cloud.state[HEADING] = particles.state[HEADING]
    cloud.log_weight = np.log(rng.uniform(0.5, 1.0, 400))
    reach = FloorFixLikelihood(stack, np.array([3.0, 3.0]), [grid, grid])
    fixes = stack.to_stack(np.array([[15.0, 12.0], [40.0, 20.0]]), np.arange(2))
    votes = np.log([0.3, 0.7])
    plain = reach.log_likelihood(cloud, FloorFix(fixes, votes, in_survey=0.2))
    turned = reach.log_likelihood(cloud, FloorFix(fixes, votes, in_survey=0.2, heading_rad=h_rv,
                                                  heading_sigma_rad=sigma))
    for f in range(2):
        on = floor_of == f
        share = [np.logaddexp.reduce(cloud.log_weight[on] + ll[on]) for ll in (plain, turned)]
        assert share[0] == pytest.approx(share[1], abs=1e-9)  # the floor's weight as before
        gain = turned[on] - plain[on]
        expected = 0.8 * (np.cos(cloud.state[HEADING][on] - h_rv) - 1.0) / sigma ** 2
        np.testing.assert_allclose(gain - gain.mean(), expected - expected.mean(), atol=1e-9)


def test_a_track_with_a_radio_map_imports_no_scipy_spatial():
    """The distance grid's sweep and the match distances the radio map file keeps: tracking the
    bundled office walk never imports scipy.spatial (a tenth of a second of every command)."""
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[2]
    code = ("import sys, io, contextlib\nfrom mapfilter.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            "    code = main(['track', 'maps/office.yaml', 'maps/office_walk.txt.gz', '--radiomap',"
            " 'maps/office_radiomap.npz', '--particles', '1000'])\n"
            "print(code, 'scipy.spatial' in sys.modules, 'mapfilter.filter.models.survey_reach' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", code], cwd=repo, capture_output=True, text=True, check=True)
    assert done.stdout.split() == ["0", "False", "True"]  # tracked, with the survey-reach model, no scipy.spatial
