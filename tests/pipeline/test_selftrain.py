"""Self-training: a radio map grown from simulated walks without waypoints, the library and the CLI."""

from __future__ import annotations

import numpy as np
import pytest

from mapfilter.cli import main
from mapfilter.errors import MapfilterError
from mapfilter.evaluation.metrics import errors_at_waypoints
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.pipeline.selftrain import GrowConfig, OfflineWalk, grow_radio_map, grown_points, point_sigma_m
from mapfilter.sensors.ilc import read_ilc
from mapfilter.sensors.pathloss import AccessPointTable
from mapfilter.sensors.radiomap import GROWN, SURVEYED, RadioMap, build_radio_map
from mapfilter.simulate.ilc_writer import write_ilc
from mapfilter.simulate.walk import SimConfig, simulate_walk
from mapfilter.config import TrackingConfig
from mapfilter.pipeline.tracker import track

from pathlib import Path

MAPS = Path(__file__).resolve().parents[2] / "maps"
PARTICLES = 2000


@pytest.fixture(scope="module")
def office(tmp_path_factory):
    """The bundled office, one short surveyed walk (the base map), three walks to grow from and
    two held-out walks, all written as ILC logs and read back (as the CLI would)."""
    plan = FloorPlan.load(MAPS / "office.yaml")
    aps = AccessPointTable.read_csv(MAPS / "office_aps.csv")
    folder = tmp_path_factory.mktemp("office")

    def walk(seed: int, duration_s: float):
        path = folder / f"walk{seed}.txt"
        write_ilc(simulate_walk(plan, aps, SimConfig(duration_s=duration_s), np.random.default_rng(seed)), path)
        return path

    return {"plan": plan, "folder": folder, "survey": walk(1, 40.0),
            "unlabelled": [walk(s, 90.0) for s in (11, 12, 13)], "held_out": [walk(s, 60.0) for s in (21, 22)]}


def _mean_error(plan, radio_map, paths) -> float:
    errors = []
    for i, path in enumerate(paths):
        rec = read_ilc(path)
        out = track(plan, rec, radio_map=radio_map, config=TrackingConfig().with_particles(PARTICLES),
                    rng=np.random.default_rng(i))
        errors.append(errors_at_waypoints(out.causal.t_s, out.causal.xy_m, rec.waypoint_t_s, rec.waypoint_xy_m,
                                          True).errors_m)
    return float(np.concatenate(errors).mean())


@pytest.mark.slow
def test_growing_from_unlabelled_walks_lowers_a_held_out_walks_error(office):
    """One 40 s survey walk covers a corner of the office: held-out walks err about 10 m with
    its map alone. Three walks without waypoints grow it; the held-out walks' causal error must
    at least halve and the grown points lie where their scans were taken."""
    import dataclasses

    plan = office["plan"]
    base = build_radio_map([read_ilc(office["survey"])], plan)
    walks = [read_ilc(p) for p in office["unlabelled"]]
    tracking = TrackingConfig().with_particles(PARTICLES)
    grown, report = grow_radio_map(plan, base, walks, GrowConfig(tracking=tracking, max_iterations=2))
    assert len(grown) > 3 * len(base) and report.grown_walks == 3 and report.points == len(grown) - len(base)
    assert np.all(grown.source[:len(base)] == SURVEYED) and np.all(grown.source[len(base):] == GROWN)
    # the grown points lie where their scans were taken (the walks' truth, read only here)
    truth = {rec.name: rec for rec in walks}
    err = []
    for i in range(len(base), len(grown)):
        rec = truth[grown.source_traces[grown.trace[i]]]
        at = np.array([np.interp(grown.t_s[i], rec.waypoint_t_s, rec.waypoint_xy_m[:, k]) for k in (0, 1)])
        err.append(np.linalg.norm(grown.xy_m[i] - at))
    assert np.median(err) < 1.5
    before, after = _mean_error(plan, base, office["held_out"]), _mean_error(plan, grown, office["held_out"])
    assert after < 0.5 * before


def test_growing_never_reads_the_walks_waypoints(office):
    """The same walks with their waypoints moved 50 m away grow the same map."""
    import dataclasses

    plan = office["plan"]
    base = build_radio_map([read_ilc(office["survey"])], plan)
    config = GrowConfig(tracking=TrackingConfig().with_particles(300), max_iterations=1)
    walk = read_ilc(office["unlabelled"][0])
    moved = dataclasses.replace(walk, waypoint_xy_m=walk.waypoint_xy_m + 50.0)
    a, _ = grow_radio_map(plan, base, [walk], config)
    b, _ = grow_radio_map(plan, base, [moved], config)
    np.testing.assert_array_equal(a.xy_m, b.xy_m)


def test_point_sigma_grows_with_the_filters_spread():
    walk = OfflineWalk("w", np.arange(4.0), np.zeros((4, 2)), None, np.array([1.0, 1.5, 2.5, np.nan]))
    sigma = point_sigma_m(walk, GrowConfig(sigma_per_spread=4.0, spread_floor_m=1.5))
    np.testing.assert_allclose(sigma, [0.0, 0.0, 4.0, 10.0])  # no spread: the largest seen (4 m)


def test_grown_points_carry_the_offline_positions_and_sigma(office):
    rec = read_ilc(office["unlabelled"][0])
    t = rec.wifi.t_s
    walk = OfflineWalk(rec.name, t, np.column_stack([t - t[0], np.zeros(t.size)]), None, np.zeros(t.size))
    points = grown_points(rec, walk, np.arange(t.size, dtype=float))
    assert len(points) == t.size
    np.testing.assert_allclose(points.xy_m[:, 0], points.t_s - t[0])
    np.testing.assert_allclose(points.xy_sigma_m, np.searchsorted(t, points.t_s))
    assert np.all(points.source == GROWN) and points.source_traces == [rec.name]
    # a walk with one scan grows one point
    one = OfflineWalk(rec.name, t[:1], np.array([[3.0, 4.0]]), None, np.zeros(1))
    single = grown_points(rec, one, np.array([2.0]))
    assert len(single) == 1 and single.xy_m.tolist() == [[3.0, 4.0]] and single.xy_sigma_m.tolist() == [2.0]


def test_walks_without_imu_are_skipped_unless_asked(office):
    import dataclasses

    plan = office["plan"]
    base = build_radio_map([read_ilc(office["survey"])], plan)
    rec = read_ilc(office["unlabelled"][1])
    wifi_only = dataclasses.replace(rec, acc_t_s=np.zeros(0), acc_mps2=np.zeros((0, 3)), gyro_t_s=np.zeros(0),
                                    gyro_radps=np.zeros((0, 3)), rotvec_t_s=np.zeros(0), rotvec_xyz=np.zeros((0, 3)))
    grown, report = grow_radio_map(plan, base, [wifi_only], GrowConfig(tracking=TrackingConfig().with_particles(300),
                                                                       max_iterations=1))
    assert len(grown) == len(base) and "no IMU" in report.walks[0].skipped
    grown, report = grow_radio_map(plan, base, [wifi_only], GrowConfig(tracking=TrackingConfig().with_particles(300),
                                                                       max_iterations=1, wifi_only=True))
    assert report.walks[0].points > 0 and not report.walks[0].skipped


def test_growing_a_building_map_needs_the_buildings_radio_map(office):
    from mapfilter.maps.building import Building

    building = Building.load(MAPS / "office.yaml")
    base = build_radio_map([read_ilc(office["survey"])], office["plan"])
    two_floor_like = RadioMap(base.xy_m, base.ap_keys, base.rssi_dbm, base.t_s, base.trace, base.source_traces,
                              None, np.zeros(len(base), int), ["other"])
    with pytest.raises(MapfilterError, match="floors"):
        grow_radio_map(building, two_floor_like, [], GrowConfig())


def test_bad_grow_config_is_refused():
    with pytest.raises(MapfilterError):
        GrowConfig(max_iterations=0)
    with pytest.raises(MapfilterError):
        GrowConfig(sigma_per_spread=-1.0)


def test_cli_grow_end_to_end(office, tmp_path, capsys):
    plan_yaml = MAPS / "office.yaml"
    assert main(["radiomap", "build", str(plan_yaml), str(office["survey"]), "--out", str(tmp_path / "base.npz")]) == 0
    capsys.readouterr()
    logs = [str(p) for p in office["unlabelled"][:2]]
    code = main(["radiomap", "grow", str(plan_yaml), *logs, "--radiomap", str(tmp_path / "base.npz"),
                 "--ignore-waypoints", "--iterations", "1", "--particles", "300", "--out", str(tmp_path / "grown.npz")])
    out = capsys.readouterr().out
    assert code == 0
    grown, base = RadioMap.load(tmp_path / "grown.npz"), RadioMap.load(tmp_path / "base.npz")
    assert np.count_nonzero(grown.source == GROWN) == len(grown) - len(base) > 0
    assert f"grown: {len(grown) - len(base)} points from 2 of 2 walks" in out
    # the grown map tracks a walk through the CLI like any radio map
    assert main(["track", str(plan_yaml), str(office["held_out"][0]), "--radiomap", str(tmp_path / "grown.npz"),
                 "--particles", "300", "--out", str(tmp_path / "track.csv")]) == 0
    # logs with waypoints (no --ignore-waypoints) are added as surveyed points, not grown, and
    # the printout says so and how to grow from them anyway
    capsys.readouterr()
    assert main(["radiomap", "grow", str(plan_yaml), logs[0], "--radiomap", str(tmp_path / "base.npz"),
                 "--iterations", "1", "--particles", "300", "--out", str(tmp_path / "plus.npz")]) == 0
    plus = RadioMap.load(tmp_path / "plus.npz")
    assert len(plus) > len(base) and not plus.is_grown
    out = capsys.readouterr().out
    assert "grown: nothing: the walk has waypoints, so it was added as surveyed points" in out
    assert "--ignore-waypoints grows from walks with waypoints" in out and "0 of 0 walks" not in out


def test_cli_grow_errors_are_one_line_and_write_nothing(office, tmp_path, capsys):
    plan_yaml = MAPS / "office.yaml"
    code = main(["radiomap", "grow", str(plan_yaml), str(office["survey"]), "--radiomap", str(tmp_path / "none.npz"),
                 "--out", str(tmp_path / "out.npz")])
    err = capsys.readouterr().err
    assert code == 1 and err.startswith("mapfilter: error:") and "none.npz" in err and err.count("\n") == 1
    assert not (tmp_path / "out.npz").exists()
    code = main(["radiomap", "grow", str(plan_yaml), str(office["survey"]), "--radiomap", str(tmp_path / "none.npz"),
                 "--iterations", "0", "--out", str(tmp_path / "out.npz")])
    assert code == 1 and "--iterations" in capsys.readouterr().err


def test_cli_default_iterations_match_the_library():
    from mapfilter.cli import radiomap_cmd

    assert radiomap_cmd._MAX_ITERATIONS == GrowConfig().max_iterations


def test_grown_by_fold_never_uses_the_labels_of_the_folds_walks(office, tmp_path):
    """Fold f's points grow over the labelled walks of the other folds only: moving the
    waypoints of fold 0's walk changes the points grown for fold 1, never those of fold 0."""
    import dataclasses

    from mapfilter.pipeline.selftrain import grown_by_fold

    plan = office["plan"]
    labelled = [read_ilc(office["survey"]), read_ilc(office["held_out"][0])]
    unlabelled = [read_ilc(office["unlabelled"][0])]
    config = GrowConfig(tracking=TrackingConfig().with_particles(300), max_iterations=1)
    grown, reports, fold = grown_by_fold(plan, labelled, unlabelled, config, folds=2)
    assert fold.tolist() == [0, 1] and len(grown) == len(reports) == 2
    assert all(np.all(g.source == GROWN) and len(g) > 0 for g in grown)
    moved = [dataclasses.replace(labelled[0], waypoint_xy_m=labelled[0].waypoint_xy_m[::-1].copy()), labelled[1]]
    again, _, _ = grown_by_fold(plan, moved, unlabelled, config, folds=2)
    np.testing.assert_array_equal(again[0].xy_m, grown[0].xy_m)
    assert not np.array_equal(again[1].xy_m, grown[1].xy_m)


def test_grown_by_fold_keeps_given_folds_and_grows_each_folds_own_walks_there(office):
    """Folds given per walk (a route's walks together): each fold's base holds every labelled walk
    but its own fold's, and a fold's own walks (a transductive evaluation's) grow only its points."""
    from mapfilter.pipeline.selftrain import grown_by_fold

    plan = office["plan"]
    labelled = [read_ilc(office["survey"]), read_ilc(office["held_out"][0]), read_ilc(office["held_out"][1])]
    own = [read_ilc(office["unlabelled"][0])]
    bases = []

    def base_of(recordings):
        bases.append([r.name for r in recordings])
        return build_radio_map(recordings, plan)

    config = GrowConfig(tracking=TrackingConfig().with_particles(300), max_iterations=1)
    grown, _, fold = grown_by_fold(plan, labelled, [], config, folds=2, base_of=base_of, fold=[1, 0, 1],
                                   fold_walks=[own, []])
    assert fold.tolist() == [1, 0, 1]
    assert bases == [[labelled[0].name, labelled[2].name], [labelled[1].name]]
    assert set(np.array(grown[0].source_traces)[np.unique(grown[0].trace)]) == {own[0].name}
    assert len(grown[1]) == 0
    with pytest.raises(ValueError, match="fold"):
        grown_by_fold(plan, labelled, [], config, folds=2, fold=[0, 2, 1])


def test_cli_grow_in_a_building_puts_each_point_on_the_offline_tracks_floor(tmp_path, capsys):
    """Three simulated office floors, a coarse survey per floor; two walks that change floor
    grow the building's radio map: their points carry floors, mostly the true ones."""
    import sys

    sys.path.insert(0, str(MAPS.parent / "tools"))
    from floor_sim import FLOORS, make_office_building_with_ap_files

    from mapfilter.sensors.floor_vote import load_building_radio_map

    building = make_office_building_with_ap_files(tmp_path)
    surveys = [tmp_path / f"survey_{name}.txt" for name in FLOORS]
    for name, survey in zip(FLOORS, surveys):
        assert main(["simulate", str(building), "--out", str(survey), "--survey", "--floor", name,
                     "--survey-spacing", "8", "--scans-per-point", "1"]) == 0
    assert main(["radiomap", "build", str(building), *map(str, surveys), "--out", str(tmp_path / "rm.npz")]) == 0
    walks = [tmp_path / f"walk{seed}.txt" for seed in (1, 2)]
    for seed, walk in zip((1, 2), walks):
        assert main(["simulate", str(building), "--out", str(walk), "--seed", str(seed), "--floor-changes", "1",
                     "--segment-s", "4", "6"]) == 0
    capsys.readouterr()
    assert main(["radiomap", "grow", str(building), *map(str, walks), "--radiomap", str(tmp_path / "rm.npz"),
                 "--ignore-waypoints", "--iterations", "1", "--particles", "300",
                 "--out", str(tmp_path / "grown.npz")]) == 0
    assert "grown:" in capsys.readouterr().out
    base = load_building_radio_map(tmp_path / "rm.npz", FLOORS)
    grown = load_building_radio_map(tmp_path / "grown.npz", FLOORS)
    new = np.flatnonzero(grown.source == GROWN)
    assert new.size > 20 and len(grown) == len(base) + new.size
    right = []
    for walk in walks:
        rec = read_ilc(walk)
        mine = new[np.array(grown.source_traces)[grown.trace[new]] == rec.name]
        at = np.clip(np.searchsorted(rec.waypoint_t_s, grown.t_s[mine]), 0, rec.waypoint_t_s.size - 1)
        right.extend(FLOORS[f] == rec.waypoint_floor[j] for f, j in zip(grown.floor[mine], at))
    assert np.mean(right) > 0.8


def test_cli_grow_takes_a_labelled_walk_over_several_floors_as_survey(office3, office3_radio_map, tmp_path, capsys):
    """A walk whose waypoints name their floors and whose header names none (an IPIN log over two
    floors) joins the building's map as surveyed points, each scan on its waypoints' floor."""
    import dataclasses

    from mapfilter.simulate.building import BuildingSimConfig, FloorChange, simulate_building_walk
    from mapfilter.simulate.ilc_writer import write_ilc
    from mapfilter.simulate.walk import SimConfig

    building, tables = office3
    config = BuildingSimConfig(walk=SimConfig(duration_s=40.0), segment_s=(10.0, 15.0))
    walk, _ = simulate_building_walk(building, tables, "F0", [FloorChange("stairs", "F1")], config,
                                     np.random.default_rng(3))
    write_ilc(dataclasses.replace(walk, floor_name=None), tmp_path / "two_floors.txt")
    office3_radio_map.save(tmp_path / "base.npz")
    assert main(["radiomap", "grow", str(building.path), str(tmp_path / "two_floors.txt"), "--radiomap",
                 str(tmp_path / "base.npz"), "--iterations", "1", "--particles", "300",
                 "--out", str(tmp_path / "grown.npz")]) == 0, capsys.readouterr().err
    out = capsys.readouterr().out
    assert "grown: nothing: the walk has waypoints" in out and "surveyed:" in out
    grown = RadioMap.load(tmp_path / "grown.npz")
    assert len(grown) > len(office3_radio_map) and set(np.unique(grown.floor)) >= {0, 1}
