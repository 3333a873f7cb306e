"""The causal estimate (issue 53, friction 7): the mean of the cloud's main mode, on free space, and
a track that walks round walls from row to row (``filter/estimate.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from mapfilter.filter.estimate import mode_estimate, toward, weighted_moments
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import crosses_wall, wall_crossing_mask

RES_M = 0.1


def _two_rooms(door: bool = True) -> FloorPlan:
    """Two 10 m x 10 m rooms side by side, a 0.3 m wall between them at x = 10 m, a 1 m door at
    its bottom (y 1-2 m) unless ``door`` is False; walled round."""
    wall = np.zeros((100, 203), dtype=bool)
    wall[:, :1] = wall[:, -1:] = wall[:1, :] = wall[-1:, :] = True
    wall[:, 100:103] = True
    if door:
        wall[100 - 20:100 - 10, 100:103] = False  # rows count down from the top: y 1-2 m
    return FloorPlan(wall, RES_M)


def _cloud(rng, centre, spread, n):
    return np.asarray(centre, dtype=float) + spread * rng.standard_normal((n, 2))


def test_a_cloud_split_by_a_wall_is_estimated_in_its_heavier_part():
    plan = _two_rooms()
    rng = np.random.default_rng(1)
    xy = np.concatenate([_cloud(rng, (9.4, 6.0), 0.25, 550), _cloud(rng, (10.9, 6.0), 0.25, 450)])
    xy = xy[plan.is_free(xy)]
    w = np.full(len(xy), 1.0 / len(xy))
    mean = weighted_moments(xy, w)[0]
    assert not plan.is_free(mean[None, :])[0]  # the mean falls in the wall between the rooms
    estimate = mode_estimate(plan, xy, w)
    assert plan.is_free(estimate[None, :])[0] and estimate[0] < 10.0  # the heavier side, left of the wall
    left = xy[:, 0] < 10.0
    np.testing.assert_allclose(estimate, np.average(xy[left], axis=0, weights=w[left]), atol=0.15)
    # weights decide, not counts: the right part carries more weight
    w = np.where(left, 0.2, 1.0)
    assert mode_estimate(plan, xy, w / w.sum())[0] > 10.3


def test_a_unimodal_cloud_is_estimated_at_its_mean():
    plan = _two_rooms()
    rng = np.random.default_rng(2)
    xy = _cloud(rng, (5.0, 5.0), 1.0, 3000)
    w = rng.random(3000)
    np.testing.assert_allclose(mode_estimate(plan, xy, w), np.average(xy, axis=0, weights=w), atol=0.1)


def test_a_large_cloud_is_read_every_kth_particle_and_gives_the_same_mode():
    plan = _two_rooms()
    rng = np.random.default_rng(3)
    xy = np.concatenate([_cloud(rng, (4.0, 7.0), 0.6, 60_000), _cloud(rng, (15.0, 3.0), 0.6, 40_000)])
    xy = xy[plan.is_free(xy)]
    estimate = mode_estimate(plan, xy, np.ones(len(xy)))
    assert np.linalg.norm(estimate - (4.0, 7.0)) < 0.2


def test_the_track_walks_round_a_wall_and_never_crosses_it():
    """From the left room to a target in the right one: each row is seen from the row before (no
    wall between), and the rows reach the target through the door in a few steps."""
    plan = _two_rooms()
    row, target = np.array([8.0, 8.0]), np.array([12.0, 8.0])
    assert crosses_wall(plan, row[None, :], target[None, :])[0]
    rows = [row]
    for _ in range(20):
        row = toward(plan, row, target)
        rows.append(row)
        if np.array_equal(row, target):
            break
    rows = np.array(rows)
    assert np.array_equal(rows[-1], target) and len(rows) <= 6
    assert not wall_crossing_mask(plan, rows).any()
    assert rows[:, 1].min() < 2.0  # through the door at y 1-2 m
    # a move that touches no wall is the target itself; no previous row: the target
    np.testing.assert_array_equal(toward(plan, np.array([2.0, 2.0]), np.array([3.0, 3.0])), [3.0, 3.0])
    np.testing.assert_array_equal(toward(plan, None, target), target)


def test_places_free_space_does_not_join_are_a_jump():
    plan = _two_rooms(door=False)
    np.testing.assert_array_equal(toward(plan, np.array([8.0, 8.0]), np.array([12.0, 8.0])), [12.0, 8.0])


@pytest.mark.parametrize("floor, walks", [("F1", 12), ("F2", 12)])
def test_the_causal_track_never_crosses_a_wall_on_real_walks(ilc_site1, tmp_path, floor, walks):
    """Consecutive causal estimates cross no wall, on real walks (leave-one-out radio maps, 2,000
    particles, seed 0); the weighted mean's track crossed walls 5 times on F1's first 12 walks and
    74 times on F2's 12. Where free space does not join two rows (a filter started afresh in a
    part of the map the walker cannot reach), the row jumps: none here."""
    import mapfilter as mf
    from mapfilter.evaluation.comparison import EvaluationSetup, evaluate
    from mapfilter.maps.building import Building
    from mapfilter.maps.paths import free_path
    from mapfilter.maps.prepare import import_ilc

    plan = import_ilc(ilc_site1 / floor, route="geojson")
    plan.save(tmp_path / f"{floor}.yaml")
    building = Building.load(tmp_path / f"{floor}.yaml")
    logs = sorted((ilc_site1 / floor / "path_data_files").glob("*.txt.gz"))
    setup = EvaluationSetup(methods=("pf",), leave_one_out=True,
                            tracking=mf.TrackingConfig(seed=0).with_particles(2000))
    evaluation = evaluate(building, logs[:walks] if floor == "F1" else logs, setup)
    tracks = [r.track for r in evaluation.results]
    assert len(tracks) >= 10
    plan = building.floors[0].plan
    for track in tracks:
        crossing = np.flatnonzero(wall_crossing_mask(plan, track.xy_m))
        for k in crossing:  # only between places free space does not join
            assert free_path(plan, track.xy_m[k], track.xy_m[k + 1]) is None, (track.name, k)
        assert crossing.size == 0, track.name
