"""Simulated walks over several floors: stairs and lifts, WiFi through floors, the barometer,
and the filter following the floor changes."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import shapely

from mapfilter.evaluation.metrics import errors_at_waypoints
from mapfilter.maps.walls import crosses_wall
from mapfilter.sensors.ilc import read_ilc
from mapfilter.simulate.building import (
    BuildingSimConfig,
    FloorChange,
    pressure_hpa,
    simulate_building_walk,
)
from mapfilter.simulate.ilc_writer import format_ilc, write_ilc

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))
from floor_sim import floor_scores  # noqa: E402

CHANGES = [FloorChange("stairs", "F1"), FloorChange("lift", "F2")]
FAST = BuildingSimConfig(segment_s=(12.0, 15.0))


@pytest.fixture(scope="module")
def walk(office3):
    building, tables = office3
    return simulate_building_walk(building, tables, "F0", CHANGES, FAST, np.random.default_rng(5))


def test_floor_changes_follow_the_plan_inside_connectors_and_no_step_crosses_a_wall(office3, walk):
    building, _ = office3
    sim, happened = walk
    assert [(c[3], c[4], c[5]) for c in happened] == [("F0", "F1", "stairs"), ("F1", "F2", "lift")]
    floors = sim.waypoint_floor
    assert floors[0] == "F0" and floors[-1] == "F2" and sim.floor_name == "F0"
    # the ground truth's floor changes only inside the connector, on both floors
    for i in np.flatnonzero(np.array(floors[1:]) != np.array(floors[:-1])) + 1:
        connector = next(c for c in building.connectors if c.kind == ("stairs" if floors[i] == "F1" else "lift"))
        for name, j in ((floors[i - 1], i - 1), (floors[i], i)):
            assert connector.polygons[name].buffer(0.05).contains(shapely.Point(*sim.waypoint_xy_m[j]))
    # every move between waypoints on one floor stays off that floor's walls
    for name in ("F0", "F1", "F2"):
        on = np.array([f == name for f in floors])
        pairs = np.flatnonzero(on[:-1] & on[1:])
        plan = building.floor(name).plan
        assert not crosses_wall(plan, sim.waypoint_xy_m[pairs], sim.waypoint_xy_m[pairs + 1]).any()


def test_barometer_follows_the_elevation(walk):
    sim, happened = walk
    t, p = sim.pressure_t_s, sim.pressure_hpa
    before = p[t < happened[0][0]].mean()
    after = p[t > happened[1][2]].mean()
    # F0 -> F2: 8 m up, about 0.96 hPa less (noise 0.03 hPa per sample averages out)
    assert abs((before - after) - (pressure_hpa(0.0) - pressure_hpa(8.0))) < 0.1


def test_the_log_round_trips_with_floors_and_pressure_and_is_the_same_for_a_seed(office3, walk, tmp_path):
    building, tables = office3
    sim, _ = walk
    write_ilc(sim, tmp_path / "w.txt.gz")
    rec = read_ilc(tmp_path / "w.txt.gz")
    assert rec.waypoint_floor == sim.waypoint_floor
    assert np.allclose(rec.pressure_hpa, sim.pressure_hpa, atol=1e-4) and rec.pressure_t_s.size == sim.pressure_t_s.size
    again, _ = simulate_building_walk(building, tables, "F0", CHANGES, FAST, np.random.default_rng(5))
    assert format_ilc(again) == format_ilc(sim)


def test_wifi_through_floors_is_path_loss_in_3d_minus_a_loss_per_floor(office3):
    from mapfilter.sensors.pathloss import path_loss_rssi_dbm
    from mapfilter.simulate.building import building_access_points, building_rssi_dbm

    building, tables = office3
    table, ap_floor = building_access_points(building, tables)
    config = BuildingSimConfig()
    k_f0 = 0  # the first AP of F0; the same place two floors up is AP k_f0 + len(F0's table)
    k_f2 = k_f0 + 2 * len(tables["F0"])
    assert ap_floor[k_f0] == 0 and ap_floor[k_f2] == 2 and np.allclose(table.xy_m[k_f0], table.xy_m[k_f2])
    phone = table.xy_m[k_f0] + [1.0, 0.5]  # in the same room as the AP: no wall between
    rssi, walls = building_rssi_dbm(building, table, ap_floor, np.array([k_f0, k_f2]), np.array([0, 0]),
                                    np.array([phone, phone]), np.array([0.0, 0.0]), config)
    assert list(walls) == [0, 0]
    d2, d3 = np.hypot(1.0, 0.5), np.sqrt(1.0 + 0.25 + 8.0 ** 2)
    same = path_loss_rssi_dbm(np.array([d2]), table.c_dbm[[k_f0]], table.n[[k_f0]], table.alpha_db_per_m[[k_f0]],
                              table.d_max_m[[k_f0]])[0]
    up = path_loss_rssi_dbm(np.array([d3]), table.c_dbm[[k_f2]], table.n[[k_f2]], table.alpha_db_per_m[[k_f2]],
                            table.d_max_m[[k_f2]])[0]
    assert np.isclose(rssi[0], same) and np.isclose(rssi[1], up - 2 * config.floor_loss_db)


def test_the_filter_follows_stairs_and_a_lift_with_the_barometer(office3, walk, office3_radio_map, tmp_path):
    """A radio map from one survey per floor; the walk tracked without its floors: right most of
    the time, and each change found within a few seconds of the walker's half-way point."""
    from mapfilter.pipeline.tracker import track
    from conftest import tracking_config

    building, tables = office3
    sim, happened = walk
    write_ilc(sim, tmp_path / "walk.txt")
    rec = read_ilc(tmp_path / "walk.txt")
    result = track(building, rec, office3_radio_map, config=tracking_config(n_particles=2000), rng=np.random.default_rng(1))
    scores = floor_scores(result.causal, rec.waypoint_t_s, rec.waypoint_floor, happened)
    assert scores["time_right"] >= 0.9
    assert all(d["delay_s"] is not None and d["delay_s"] <= 8.0 for d in scores["delays"]), scores


def test_a_lift_ride_without_steps_is_followed_by_the_barometer_within_3_s(office3, office3_radio_map, tmp_path):
    """Two storeys up by lift (6 s of ride, no steps): the filter steps on the barometer alone at
    least every ``IDLE_TICK_S`` while the walker stands, finds the new floor within 3 s of the ride's
    half-way point, and no barometer-only step collapses the cloud."""
    from mapfilter.filter.causal import IDLE_TICK_S
    from mapfilter.pipeline.tracker import track
    from conftest import tracking_config

    building, tables = office3
    sim, happened = simulate_building_walk(building, tables, "F0", [FloorChange("lift", "F2")], FAST,
                                           np.random.default_rng(11))
    write_ilc(sim, tmp_path / "lift.txt")
    rec = read_ilc(tmp_path / "lift.txt")
    result = track(building, rec, office3_radio_map, config=tracking_config(n_particles=2000), rng=np.random.default_rng(2))
    t_enter, t_switch, t_leave = happened[0][:3]
    ride = (result.causal.t_s > t_enter + 1.0) & (result.causal.t_s < t_leave)
    assert np.diff(result.causal.t_s[ride]).max() <= IDLE_TICK_S + 1e-6
    scores = floor_scores(result.causal, rec.waypoint_t_s, rec.waypoint_floor, happened)
    assert scores["delays"][0]["delay_s"] is not None and scores["delays"][0]["delay_s"] <= 3.0, scores
    scan_t = np.unique(rec.wifi.t_s)
    assert all(np.isclose(scan_t, c.t_s).any() for c in result.collapses)  # a collapse only ever at a scan


def _changes_inside_connectors(building, track, tolerance_m: float = 0.3) -> bool:
    """Every floor change of a track is at a row inside a connector linking both floors (on both)."""
    floors = np.array(track.floor)
    for k in np.flatnonzero(floors[1:] != floors[:-1]) + 1:
        a, b = floors[k - 1], floors[k]
        point = building.floor(b).to_building(track.xy_m[k])
        if not any(a in c.polygons and b in c.polygons
                   and c.polygons[a].buffer(tolerance_m).contains(shapely.Point(*building.floor(a).from_building(point)))
                   and c.polygons[b].buffer(tolerance_m).contains(shapely.Point(*track.xy_m[k]))
                   for c in building.connectors):
            return False
    return True


def test_the_whole_walk_floor_changes_where_the_walker_does_and_only_in_connectors(office3, walk, office3_radio_map, tmp_path):
    """--smooth in a building: the causal track is the same as without it; the offline track's floor,
    decided from the whole walk (WiFi vote + barometer), changes where the walker's does (within 1 s)
    and only inside a connector."""
    from mapfilter.pipeline.tracker import track
    from conftest import tracking_config

    building, _ = office3
    sim, happened = walk
    write_ilc(sim, tmp_path / "walk.txt")
    rec = read_ilc(tmp_path / "walk.txt")
    plain = track(building, rec, office3_radio_map, config=tracking_config(n_particles=2000), rng=np.random.default_rng(1))
    result = track(building, rec, office3_radio_map, config=tracking_config(n_particles=2000, smooth=True), rng=np.random.default_rng(1))
    assert np.array_equal(plain.causal.xy_m, result.causal.xy_m) and plain.causal.floor == result.causal.floor
    # one change per true change, each within 1 s of the true one (the walker's half-way point)
    floors = np.array(result.offline.floor)
    at = np.flatnonzero(floors[1:] != floors[:-1]) + 1
    true_at = np.flatnonzero(np.array(rec.waypoint_floor[1:]) != np.array(rec.waypoint_floor[:-1])) + 1
    assert [(floors[k - 1], floors[k]) for k in at] == [("F0", "F1"), ("F1", "F2")]
    assert np.all(np.abs(result.offline.t_s[at] - rec.waypoint_t_s[true_at]) < 1.0)
    assert _changes_inside_connectors(building, result.offline)
    # each floor's stretch is placed and map-matched on its floor: closer than the causal track
    causal = errors_at_waypoints(result.causal.t_s, result.causal.xy_m, rec.waypoint_t_s, rec.waypoint_xy_m, True)
    offline = errors_at_waypoints(result.offline.t_s, result.offline.xy_m, rec.waypoint_t_s, rec.waypoint_xy_m,
                                  False)
    assert offline.errors_m.mean() < causal.errors_m.mean()


@pytest.mark.xfail(strict=True, reason="since the online step detector (OnlinePDR) the whole-walk floor keeps the wrong F2 for "
                                      "the first 18-20 s on seeds 0-3 (right 82-84 % of the time), the smoother's too")
def test_a_wrong_start_of_the_floor_evidence_is_outvoted_in_the_whole_walk_floor(office3, walk, tmp_path, office3_radio_map):
    """No barometer; the first five scans vote F2 unanimously, every later one the walker's floor:
    the whole-walk floor is F0 from the start until the walker's first change (the stairs), and
    right at least 95 % of the time. (The whole-walk floor of this offline track depends on the
    run's draws: of seeds 0-3, two pass; the smoother of the filter's own belief replaces it.)"""
    import dataclasses

    from conftest import tracking_config

    from mapfilter.config import FloorsConfig
    from mapfilter.pipeline.tracker import track

    building, _ = office3
    sim, happened = walk
    write_ilc(sim, tmp_path / "walk.txt")
    rec = read_ilc(tmp_path / "walk.txt")
    scan_t = np.unique(rec.wifi.t_s)
    truth = np.array([building.floor_index(f) for f in rec.waypoint_floor])
    true_scan_floor = truth[np.clip(np.searchsorted(rec.waypoint_t_s, scan_t, side="right") - 1, 0, None)]
    vote = np.full((scan_t.size, 3), np.log(1 / 7))  # a unanimous k = 4 vote, one pseudo-vote per floor
    vote[np.arange(scan_t.size), true_scan_floor] = np.log(5 / 7)
    vote[:5] = np.log(np.array([1, 1, 5]) / 7)
    config = dataclasses.replace(tracking_config(n_particles=2000, smooth=True, offline_method="placement"),
                                 floors=FloorsConfig(use_barometer=False))
    result = track(building, rec, office3_radio_map, config=config, rng=np.random.default_rng(2), floor_evidence=vote)
    smoothed = result.offline
    before = smoothed.t_s < happened[0][0]  # before the walker enters the stairs
    assert np.all(np.array(smoothed.floor)[before] == "F0")
    assert floor_scores(smoothed, rec.waypoint_t_s, rec.waypoint_floor, happened)["time_right"] >= 0.95
    assert _changes_inside_connectors(building, smoothed)


def test_a_walk_that_keeps_its_floor_gets_the_one_floor_offline_track(office3, office3_radio_map, tmp_path):
    """--smooth in a building, floor not given: a walk the whole-walk floor keeps on one floor gets
    the placed, map-matched offline track of that floor (not the particle lineage): every row on
    that floor, no wall crossed on its plan, and less than half the causal track's error."""
    from mapfilter.pipeline.tracker import track
    from conftest import tracking_config

    building, tables = office3
    sim, _ = simulate_building_walk(building, tables, "F1", [], BuildingSimConfig(segment_s=(40.0, 50.0)),
                                    np.random.default_rng(7))
    write_ilc(sim, tmp_path / "flat.txt")
    rec = read_ilc(tmp_path / "flat.txt")
    config = tracking_config(n_particles=2000, smooth=True)
    result = track(building, rec, office3_radio_map, config=config, rng=np.random.default_rng(1))
    assert set(result.offline.floor) == {"F1"}
    smoothed = result.offline
    assert not crosses_wall(building.floor("F1").plan, smoothed.xy_m[:-1], smoothed.xy_m[1:]).any()
    causal = errors_at_waypoints(result.causal.t_s, result.causal.xy_m, rec.waypoint_t_s, rec.waypoint_xy_m, True)
    offline = errors_at_waypoints(smoothed.t_s, smoothed.xy_m, rec.waypoint_t_s, rec.waypoint_xy_m, False)
    assert offline.errors_m.mean() < 0.5 * causal.errors_m.mean()  # the lineage: 0.66-2x on three such walks
