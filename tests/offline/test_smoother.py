"""The smoother (``offline.smoother``): the backward pass against a numpy FFBSm oracle, the
fixed-lag smoother against the whole-walk one, and the invariants (weights normalised, the walls
respected, a broken chain starts afresh). That it helps a real filter run: test_filter_pf.py's
corridor and ILC walks, and the trackers' end-to-end tests."""

from __future__ import annotations

import numpy as np
import pytest

from mapfilter.filter.models.motion import RandomWalkMotion
from mapfilter.filter.particles import STATE_ROWS, X, Y
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import touches_wall_reference
from mapfilter.offline import smoother
from mapfilter.offline.smoother import FixedLagSmoother, ParticleHistory, smooth



def _rooms() -> FloorPlan:
    """20 m x 10 m, a wall across x = 10 m with a door at y = 4-6 m."""
    wall = np.zeros((100, 200), dtype=bool)
    wall[0, :] = wall[-1, :] = wall[:, 0] = wall[:, -1] = True
    wall[:, 99:101] = True
    wall[40:60, 99:101] = False
    return FloorPlan(wall, 0.1)


def _history(plan: FloorPlan, n_steps: int, m: int, seed: int, broken_at: tuple[int, ...] = ()) -> ParticleHistory:
    """Clouds walking right along y = 5 m through the door, weighed unevenly (at most ``keep``
    particles, so the history keeps them whole)."""
    rng = np.random.default_rng(seed)
    history = ParticleHistory(keep=m)
    for t in range(n_steps):
        state = np.zeros((STATE_ROWS, m))
        centre = np.array([6.0 + 0.8 * t, 5.0])
        xy = centre + rng.normal(0.0, 0.9, (m, 2))
        xy = xy[plan.is_free(xy)]
        while len(xy) < m:
            more = centre + rng.normal(0.0, 0.9, (m, 2))
            xy = np.vstack([xy, more[plan.is_free(more)]])
        state[X], state[Y] = xy[:m, 0], xy[:m, 1]
        w = rng.uniform(0.2, 1.0, m)
        history.record(float(t), state, w / w.sum(), None, 1.0, 0.0, t == 0 or t in broken_at)
    return history


def _oracle_weights(history: ParticleHistory, plan: FloorPlan, variance_m2: float) -> list[np.ndarray]:
    """FFBSm in numpy: W_t^i = w_t^i sum_j W_{t+1}^j f_ij / sum_k w_t^k f_kj, with f a Gaussian
    around the particle's own position (the random walk predicts no move), 0 through a wall."""
    steps = history.steps
    weights = [None] * len(steps)
    weights[-1] = steps[-1].weight
    for t in range(len(steps) - 2, -1, -1):
        now, after = steps[t], steps[t + 1]
        if after.broken:
            weights[t] = now.weight
            continue
        a, b = now.state[X:Y + 1].T, after.state[X:Y + 1].T
        d2 = ((b[None, :, :] - a[:, None, :]) ** 2).sum(axis=2)  # (i, j)
        exponent = d2 / (2 * variance_m2)
        f = np.where(exponent < -np.log(smoother._NEGLIGIBLE), np.exp(-exponent), 0.0)  # the kernel's cut-offs
        ii, jj = np.meshgrid(np.arange(len(a)), np.arange(len(b)), indexing="ij")
        f[touches_wall_reference(plan, a[ii.ravel()], b[jj.ravel()]).reshape(f.shape)] = 0.0
        f[f <= smoother._NEGLIGIBLE * f.max(axis=0, keepdims=True)] = 0.0
        denominator = now.weight @ f
        w = now.weight * (f @ np.where(denominator > 0, weights[t + 1] / np.where(denominator > 0, denominator, 1), 0))
        weights[t] = w / w.sum()
    return weights


def test_the_backward_pass_is_the_ffbsm_oracle():
    plan = _rooms()
    history = _history(plan, 12, 60, seed=1, broken_at=(7,))
    motion = RandomWalkMotion(radius_mps=0.0, sigma_mps=1.0)
    _, _, spread_m = motion.predict(history.steps[0].state, None, 1.0)
    space = smoother._Space(plan, None)
    got = smoother._backward_weights(history, motion, space, len(history) - 1)
    expected = _oracle_weights(history, plan, max(spread_m ** 2, smoother.MIN_SPREAD_M ** 2))
    for t, (g, e) in enumerate(zip(got, expected)):
        np.testing.assert_allclose(g, e, rtol=1e-6, atol=1e-12, err_msg=f"step {t}")
        assert g.sum() == pytest.approx(1.0)
    # the chain breaks at step 7: step 6 keeps its filtered weights; before it, the future counts
    np.testing.assert_array_equal(got[6], history.steps[6].weight)
    assert not np.allclose(got[3], history.steps[3].weight)


def test_a_successor_behind_a_wall_gives_no_weight_through_it():
    """Two kept particles, one each side of the wall (far from the door), and the next step's
    one particle on the right: only the right one keeps weight."""
    plan = _rooms()
    history = ParticleHistory(keep=4)
    before = np.zeros((STATE_ROWS, 2))
    before[X], before[Y] = [9.6, 10.4], [1.5, 1.5]
    after = np.zeros((STATE_ROWS, 1))
    after[X], after[Y] = [10.3], [1.5]
    history.record(0.0, before, np.array([0.5, 0.5]), None, 1.0, 0.0, True)
    history.record(1.0, after, np.array([1.0]), None, 1.0, 0.0, False)
    motion = RandomWalkMotion(radius_mps=0.0, sigma_mps=1.0)
    weights = smoother._backward_weights(history, motion, smoother._Space(plan, None), 1)
    np.testing.assert_allclose(weights[0], [0.0, 1.0])


def test_the_fixed_lag_smoother_is_the_whole_walks_at_a_long_lag_and_waits_its_lag():
    plan = _rooms()
    history = _history(plan, 15, 40, seed=2)
    motion = RandomWalkMotion(radius_mps=0.0, sigma_mps=1.0)
    whole = smooth(history, plan, motion)
    for lag_s, expect_whole in ((100.0, True), (3.0, False)):
        lagged = FixedLagSmoother(plan, motion, None, lag_s, keep=40)
        for step in history.steps:
            lagged.record(step.t_s, step.state, step.weight, step.inputs, step.dt_s, step.jitter_m2, step.broken)
            assert len(lagged.history) <= lag_s + 2  # only the window is kept
        lagged.close()
        t = np.array([r[0] for r in lagged.rows])
        available = np.array([r[1] for r in lagged.rows])
        xy = np.array([r[2] for r in lagged.rows])
        np.testing.assert_array_equal(t, whole.t_s)
        if expect_whole:
            np.testing.assert_allclose(xy, whole.xy_m, atol=1e-9)
        else:
            # each row waited its lag (but those the end of the walk released), and the last
            # lag's rows are the whole walk's
            waited = available - t
            assert np.all((waited >= lag_s) | (available == t[-1]))
            tail = t >= t[-1] - lag_s
            np.testing.assert_allclose(xy[tail], whole.xy_m[tail], atol=1e-9)
            assert not np.allclose(xy[~tail], whole.xy_m[~tail])


def test_an_empty_history_and_a_bad_lag_are_refused():
    plan = _rooms()
    with pytest.raises(ValueError, match="no step"):
        smooth(ParticleHistory(), plan, RandomWalkMotion())
    for lag in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="lag"):
            FixedLagSmoother(plan, RandomWalkMotion(), None, lag)
