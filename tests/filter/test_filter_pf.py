"""The particle filter: invariants after every step, collapse and recovery, determinism, tracking."""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mapfilter.errors import MapfilterError
from mapfilter.filter.models.position_fix import GaussianFixLikelihood, PositionFix
from mapfilter.filter.models.interface import MeasurementModel
from mapfilter.filter.models.motion import ConstantVelocityMotion, PDRMotion, RandomWalkMotion, StepInput
from mapfilter.filter.particle_filter import FilterConfig, ParticleFilter
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import count_wall_crossings, crosses_wall
from mapfilter.maps.paths import detour_wall_crossings
from mapfilter.offline.smoother import ParticleHistory, smooth


def _rooms_map(resolution_m=0.1):
    """20 m x 10 m: outer walls, a corridor along y in [4, 6], rooms above/below with doors."""
    h, w = int(10 / resolution_m), int(20 / resolution_m)
    wall = np.zeros((h, w), dtype=bool)
    wall[[0, -1], :] = True
    wall[:, [0, -1]] = True
    r_top, r_bot = int(4 / resolution_m), int(6 / resolution_m)  # rows of the corridor walls (row 0 = top)
    wall[r_top, :] = True
    wall[r_bot, :] = True
    for c in range(int(5 / resolution_m), w, int(5 / resolution_m)):
        wall[:, c] = True
        wall[r_top:r_bot + 1, c] = False  # corridor stays open
    for c0 in range(0, w - 10, int(5 / resolution_m)):
        wall[r_top, c0 + 10:c0 + 18] = False  # doors to the upper rooms
    # the lower-right room (x in [15, 20], y in [0, 4]) has no door: closed
    for c0 in range(0, int(15 / resolution_m), int(5 / resolution_m)):
        wall[r_bot, c0 + 10:c0 + 18] = False
    return FloorPlan(wall, resolution_m)


ROOMS = _rooms_map()


def _record(history, pf, t_s, report=None, step_input=None, dt_s=0.0):
    """What the tracker records of a step for the smoother (``filter.causal.CausalFilter``)."""
    if report is None:  # the start
        history.record(t_s, pf.particles.state, pf.particles.weight, None, 0.0, 0.0, True)
    else:
        history.record(t_s, pf.particles.state, report.particles_weight, step_input, dt_s, pf.last_jitter_m2,
                       report.collapse is not None)


def _check_invariants(pf, report, prev_xy):
    p = pf.particles
    live = np.isfinite(p.log_weight)
    assert live.any()
    assert np.all(np.isfinite(p.xy_m))
    # weights normalised
    assert np.logaddexp.reduce(p.log_weight[live]) == pytest.approx(0.0, abs=1e-9)
    assert report.particles_weight.sum() == pytest.approx(1.0, abs=1e-9)
    # no live particle inside a wall
    assert pf.floorplan.is_free(p.xy_m[live]).all()
    assert pf.floorplan.is_free(report.estimate_xy_m[None])[0]
    # no surviving move crossed one: parent's position before the step -> position after it
    parents = pf.last_parents
    linked = live & (parents >= 0)
    assert not crosses_wall(pf.floorplan, prev_xy[parents[linked]], p.xy_m[linked]).any()
    assert math.isfinite(report.ess) and math.isfinite(report.estimate_std_m)
    assert report.n_particles == len(p) == pf.config.n_particles


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2 ** 31 - 1), motion_kind=st.sampled_from(["rw", "cv", "pdr"]),
       fix_every=st.integers(1, 3), ess_fraction=st.sampled_from([0.3, 0.7, 1.0]))
def test_invariants_after_every_step(seed, motion_kind, fix_every, ess_fraction):
    rng = np.random.default_rng(seed)
    motion = {"rw": RandomWalkMotion(), "cv": ConstantVelocityMotion(accel_sigma_mps2=2.0),
              "pdr": PDRMotion()}[motion_kind]
    cfg = FilterConfig(n_particles=500, resample_ess_fraction=ess_fraction)
    pf = ParticleFilter(ROOMS, motion, cfg, rng)
    pf.initialise_uniform()
    model = GaussianFixLikelihood(sigma_m=2.0)
    for k in range(12):
        prev_xy = pf.particles.xy_m.copy()
        fix = PositionFix(tuple(ROOMS.sample_free(1, rng)[0])) if k % fix_every == 0 else None
        step_input = StepInput(int(rng.integers(0, 3)), float(rng.normal(0, 1.0))) if motion_kind == "pdr" else None
        report = pf.step(k * 1.0, 1.0, step_input, model if fix else None, fix)
        _check_invariants(pf, report, prev_xy)


def test_closed_room_pull_collapses_and_recovers():
    """Particles in the corridor, fixes inside the closed room: every particle is pressed against
    the room's wall, the measurement makes them all implausible -> collapse -> recovery inside."""
    rng = np.random.default_rng(10)
    cfg = FilterConfig(n_particles=2000, min_log_likelihood=-8.0)
    pf = ParticleFilter(ROOMS, RandomWalkMotion(), cfg, rng)
    pf.initialise_around((12.0, 5.0), 1.0)
    model = GaussianFixLikelihood(sigma_m=1.0)
    room_xy = (17.5, 1.5)  # inside the closed lower-right room
    events = []
    for k in range(15):
        prev_xy = pf.particles.xy_m.copy()
        report = pf.step(float(k), 0.5, None, model, PositionFix(room_xy))
        _check_invariants(pf, report, prev_xy)
        if report.collapse:
            events.append(report.collapse)
    assert events, "no collapse although no particle can reach the fix"
    first = events[0]
    assert first.cause in ("measurement_inconsistent", "weights_underflow")
    assert first.recovery == "likelihood_over_map"
    assert first.particles_lost == 2000
    assert math.dist(first.recovered_xy_m, room_xy) < 1.5
    assert math.dist(first.xy_m, room_xy) > 3.0
    # after the recovery the filter stays in the room: no more collapses, estimate at the fix
    assert len(events) == 1
    assert math.dist(tuple(pf.estimate_xy_m), room_xy) < 1.0
    assert pf.collapses == events


def test_underflow_collapse_without_a_gate():
    rng = np.random.default_rng(11)
    pf = ParticleFilter(ROOMS, RandomWalkMotion(), FilterConfig(n_particles=1000), rng)
    pf.initialise_around((2.0, 5.0), 0.5)
    # sigma 0.2 m, 15 m away: log-likelihood about -2800, every weight underflows
    report = pf.step(0.0, 0.1, None, GaussianFixLikelihood(0.2), PositionFix((17.0, 5.0)))
    assert report.collapse is not None and report.collapse.cause == "weights_underflow"
    assert math.dist(tuple(report.estimate_xy_m), (17.0, 5.0)) < 0.5
    assert np.isfinite(report.particles_weight).all()


def test_all_killed_by_walls_recovers_around_estimate_with_growing_radius():
    rng = np.random.default_rng(12)
    pf = ParticleFilter(ROOMS, PDRMotion(heading_sigma_rad=0.01), FilterConfig(n_particles=1000), rng)
    pf.initialise_around((10.0, 2.0), 0.3, heading_rad=-math.pi / 2)  # lower middle room, facing the outer wall
    radii = []
    for k in range(3):
        pf.particles.heading_rad = -math.pi / 2  # every particle walks 14 m into the outer wall
        report = pf.step(float(k), 1.0, StepInput(n_steps=20, heading_change_rad=0.0))
        assert report.collapse is not None
        assert report.collapse.cause == "all_killed_by_walls"
        assert report.n_killed > 0
        radii.append(float(report.collapse.recovery.split("_r")[1].rstrip("m")))
        assert ROOMS.is_free(pf.particles.xy_m).all()
    assert radii[0] < radii[1] < radii[2]


def test_same_seed_same_result():
    def run(seed):
        rng = np.random.default_rng(seed)
        pf = ParticleFilter(ROOMS, PDRMotion(), FilterConfig(n_particles=800),
                            rng)
        pf.initialise_from_measurement(0.0, GaussianFixLikelihood(3.0), PositionFix((3.0, 5.0)))
        history = ParticleHistory()
        _record(history, pf, 0.0)
        out = []
        for k in range(20):
            step_input = StepInput(1, 0.05 * k)
            r = pf.step(k + 1.0, 1.0, step_input, GaussianFixLikelihood(3.0), PositionFix((3.0 + 0.7 * k, 5.0)))
            _record(history, pf, k + 1.0, r, step_input, 1.0)
            out.append(r.estimate_xy_m)
        return np.array(out), smooth(history, ROOMS, pf.motion, None).xy_m

    a, ta = run(5)
    b, tb = run(5)
    c, _ = run(6)
    assert np.array_equal(a, b) and np.array_equal(ta, tb)
    assert not np.array_equal(a, c)


def test_tracks_a_corridor_walk_and_smoothed_track_never_crosses_walls():
    rng = np.random.default_rng(13)
    # along the corridor to x = 19, back to the door at x = 11.4 and into the upper room
    truth = np.column_stack([np.linspace(1.0, 19.0, 37), np.full(37, 5.0)])
    back = np.column_stack([np.linspace(18.5, 11.4, 15), np.full(15, 5.0)])
    truth = np.vstack([truth, back, np.column_stack([np.full(8, 11.4), np.linspace(5.5, 9.0, 8)])])
    pf = ParticleFilter(ROOMS, RandomWalkMotion(), FilterConfig(n_particles=3000), rng)
    model = GaussianFixLikelihood(2.0)
    fixes = truth + rng.normal(0, 2.0, truth.shape)
    pf.initialise_from_measurement(0.0, model, PositionFix(tuple(fixes[0])))
    history = ParticleHistory()
    _record(history, pf, 0.0)
    estimates = []
    for k in range(1, len(truth)):
        r = pf.step(k * 0.5, 0.5, None, model, PositionFix(tuple(fixes[k])))
        _record(history, pf, k * 0.5, r, None, 0.5)
        estimates.append(r.estimate_xy_m)
    err = np.linalg.norm(np.array(estimates) - truth[1:], axis=1)
    raw = np.linalg.norm(fixes[1:] - truth[1:], axis=1)
    print("filter", err.mean(), "raw fixes", raw.mean())
    assert err.mean() < 0.75 * raw.mean()
    smoothed = smooth(history, ROOMS, pf.motion, None)
    t, track = smoothed.t_s[1:], smoothed.xy_m[1:]  # the first row: the start
    assert track.shape == (len(truth) - 1, 2) and np.all(np.diff(t) > 0)
    assert np.linalg.norm(track - truth[1:], axis=1).mean() < err.mean()  # the future helps
    # a mean between two modes may cut a corner: the offline track walks round (as the tracker does)
    assert count_wall_crossings(ROOMS, detour_wall_crossings(ROOMS, smoothed.t_s, smoothed.xy_m)[1]) == 0


def test_initialisation():
    rng = np.random.default_rng(14)
    pf = ParticleFilter(ROOMS, RandomWalkMotion(), FilterConfig(n_particles=2000), rng)
    pf.initialise_from_measurement(0.0, GaussianFixLikelihood(1.0), PositionFix((12.0, 8.0)))
    assert ROOMS.is_free(pf.particles.xy_m).all()
    assert np.linalg.norm(pf.particles.xy_m.mean(axis=0) - [12.0, 8.0]) < 0.5
    pf.initialise_around((2.5, 2.0), 1.0)
    assert ROOMS.is_free(pf.particles.xy_m).all()
    assert np.linalg.norm(pf.particles.xy_m - [2.5, 2.0], axis=1).max() <= 1.0 + 0.15
    pf.initialise_around((-50.0, -50.0), 1.0)  # no free space that close: nearest free pixels
    assert ROOMS.is_free(pf.particles.xy_m).all()
    pf.initialise_uniform()
    assert ROOMS.is_free(pf.particles.xy_m).all()

    class Nowhere(MeasurementModel):
        def log_likelihood(self, particles, measurement):
            return np.full(len(particles), -np.inf)

    with pytest.raises(MapfilterError, match="zero likelihood"):
        pf.initialise_from_measurement(0.0, Nowhere(), None)
    with pytest.raises(RuntimeError):
        ParticleFilter(ROOMS, RandomWalkMotion(), FilterConfig(n_particles=10), rng).step(0.0, 1.0)


def test_bad_model_output_never_poisons_the_filter():
    rng = np.random.default_rng(15)

    class Broken(MeasurementModel):
        def log_likelihood(self, particles, measurement):
            ll = np.zeros(len(particles))
            ll[::3] = np.nan
            ll[1::3] = np.inf
            return ll

    pf = ParticleFilter(ROOMS, RandomWalkMotion(), FilterConfig(n_particles=300), rng)
    pf.initialise_uniform()
    report = pf.step(0.0, 1.0, None, Broken(), object())
    assert np.isfinite(report.particles_weight).all() and report.particles_weight.sum() == pytest.approx(1.0)

    class WrongShape(MeasurementModel):
        def log_likelihood(self, particles, measurement):
            return np.zeros(3)

    with pytest.raises(ValueError, match="shape"):
        pf.step(1.0, 1.0, None, WrongShape(), object())


@pytest.mark.parametrize("bad", [dict(n_particles=0), dict(n_particles=2.5), dict(resample_ess_fraction=2.0),
                                 dict(bandwidth_scale=float("nan")), dict(init_samples=0)])
def test_bad_config_is_a_user_error(bad):
    with pytest.raises((MapfilterError, ValueError)):
        FilterConfig(**bad)


def test_the_jitter_redraws_fit_the_steps_counter_slots():
    """A jitter that crosses a wall is drawn again from the particle's counter-based slots: the
    tries must fit in them."""
    from mapfilter.filter.kernels.draws import SLOTS
    from mapfilter.filter.particle_filter import REGULARISE_TRIES

    assert 1 <= REGULARISE_TRIES <= SLOTS


def test_real_ilc_floor_and_waypoints(ilc_site1):
    """ILC site1/F1 map and a real trace's waypoints; fixes = interpolated truth + 4 m noise."""
    from mapfilter.maps.prepare import import_ilc
    from mapfilter.sensors.ilc import read_ilc

    floor = ilc_site1 / "F1"
    fp = import_ilc(floor)
    rec = read_ilc(sorted((floor / "path_data_files").glob("*.txt.gz"))[0])
    t_wp = rec.waypoint_t_s - rec.waypoint_t_s[0]
    t = np.arange(0.0, t_wp[-1], 1.0)
    truth = np.column_stack([np.interp(t, t_wp, rec.waypoint_xy_m[:, 0]), np.interp(t, t_wp, rec.waypoint_xy_m[:, 1])])
    rng = np.random.default_rng(20)
    fixes = truth + rng.normal(0.0, 4.0, truth.shape)
    model = GaussianFixLikelihood(4.0)
    pf = ParticleFilter(fp, RandomWalkMotion(), FilterConfig(n_particles=5000), rng)
    pf.initialise_from_measurement(0.0, model, PositionFix(tuple(fixes[0])))
    history = ParticleHistory()
    _record(history, pf, 0.0)
    est = []
    for k in range(1, len(t)):
        r = pf.step(t[k], 1.0, None, model, PositionFix(tuple(fixes[k])))
        _record(history, pf, t[k], r, None, 1.0)
        assert fp.is_free(r.estimate_xy_m[None])[0]
        est.append(r.estimate_xy_m)
    err = np.linalg.norm(np.array(est) - truth[1:], axis=1)
    raw = np.linalg.norm(fixes[1:] - truth[1:], axis=1)
    assert err.mean() < 0.8 * raw.mean(), (err.mean(), raw.mean())
    smoothed = smooth(history, fp, pf.motion, None)
    assert count_wall_crossings(fp, detour_wall_crossings(fp, smoothed.t_s, smoothed.xy_m)[1]) == 0
    assert np.linalg.norm(smoothed.xy_m[1:] - truth[1:], axis=1).mean() < err.mean()
    assert not pf.collapses


def test_report_carries_heard_access_points_from_the_model():
    rng = np.random.default_rng(21)

    class Aps(MeasurementModel):
        def log_likelihood(self, particles, measurement):
            return -0.5 * ((particles.xy_m - measurement) ** 2).sum(axis=1)

        def heard_ap_xy_m(self, measurement):
            return np.array([[1.0, 2.0]])

    pf = ParticleFilter(ROOMS, RandomWalkMotion(), FilterConfig(n_particles=200), rng)
    pf.initialise_uniform()
    report = pf.step(0.0, 1.0, None, Aps(), np.array([5.0, 5.0]))
    assert report.heard_ap_xy_m.tolist() == [[1.0, 2.0]]
    assert pf.step(1.0, 1.0).heard_ap_xy_m is None
