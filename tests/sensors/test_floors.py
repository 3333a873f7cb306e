"""The floor in the filter's state: the stack of floors, floor changes, the floor vote and HMM,
floor-labelled radio maps, and tracking across the floors of ILC site 1."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from mapfilter.cli import main
from mapfilter.evaluation.metrics import floor_at_waypoints
from mapfilter.filter.models.building import (STAIRS_TREAD_M, FloorChangeConfig, FloorChanges, FloorFix,
                                              FloorFixLikelihood, FloorStack)
from mapfilter.filter.models.motion import RandomWalkMotion
from mapfilter.filter.particle_filter import FilterConfig, ParticleFilter
from mapfilter.filter.causal import IDLE_TICK_S
from mapfilter.maps.building import Building
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import crosses_wall
from mapfilter.sensors.floor_vote import floor_hmm, floor_vote_log_likelihood
from mapfilter.sensors.radiomap import RadioMap

STAIRS = [[2.0, 2.0], [5.0, 2.0], [5.0, 5.0], [2.0, 5.0]]


def _building(tmp_path: Path, connectors: bool = True, n_floors: int = 3) -> Building:
    """Floors of 20 m x 20 m (0.25 m/px) with a wall border and a different wall box each; the
    upper floors sit 1 m east in the building frame; stairs in the south-west corner."""
    floors = []
    for i in range(n_floors):
        mask = np.zeros((80, 80), dtype=bool)
        mask[0, :] = mask[-1, :] = mask[:, 0] = mask[:, -1] = True
        mask[30:50, 30 + 5 * i:45 + 5 * i] = True
        FloorPlan(mask, 0.25, (0.0, 0.0)).save(tmp_path / f"f{i}.yaml")
        floors.append({"name": f"L{i}", "map": f"f{i}.yaml", "elevation_m": 4.0 * i,
                       "offset_m": [0.0 if i == 0 else 1.0, 0.0]})
    meta = {"floors": floors}
    if connectors:
        # the stairs lie at the same building-frame place: 1 m further west in the upper floors' frames
        meta["connectors"] = [{"name": "stairs", "kind": "stairs",
                               "floors": {f"L{i}": [[x - (0.0 if i == 0 else 1.0), y] for x, y in STAIRS]
                                          for i in range(n_floors)}}]
    (tmp_path / "b.yaml").write_text(yaml.safe_dump(meta))
    return Building.load(tmp_path / "b.yaml")


def test_stack_frames_round_trip_and_tiles_are_walled_apart(tmp_path):
    stack = FloorStack(_building(tmp_path))
    rng = np.random.default_rng(1)
    local = rng.uniform(1, 19, (200, 2))
    floor = rng.integers(0, 3, 200)
    back, back_floor = stack.to_floor(stack.to_stack(local, floor))
    assert np.allclose(back, local) and np.array_equal(back_floor, floor)
    # each floor's own mask is its tile of the stack
    for f, fl in enumerate(stack.building.floors):
        pts = rng.uniform(0, 20, (500, 2))
        assert np.array_equal(stack.plan.is_free(stack.to_stack(pts, f)), fl.plan.is_free(pts))
    # any move from one floor's tile to another's crosses a wall
    a = stack.to_stack(rng.uniform(1, 19, (300, 2)), 0)
    b = stack.to_stack(rng.uniform(1, 19, (300, 2)), 1)
    assert crosses_wall(stack.plan, a, b).all()


def _filter(building: Building, connectors_rate: float, anywhere_rate: float, seed: int = 0):
    stack = FloorStack(building)
    changes = FloorChanges(stack, FloorChangeConfig(connectors_rate, anywhere_rate))
    pf = ParticleFilter(stack.plan, RandomWalkMotion(), FilterConfig(n_particles=3000, init_samples=5000),
                        np.random.default_rng(seed), floors=changes)
    return stack, changes, pf


def test_no_particle_lives_in_a_wall_of_its_floor_and_weights_stay_normalised(tmp_path):
    stack, _, pf = _filter(_building(tmp_path, connectors=False), 0.0, 0.05)
    model = FloorFixLikelihood(stack, np.full(3, 3.0))
    fix = FloorFix(stack.to_stack(np.array([[10.0, 5.0]] * 3), np.arange(3)), np.log([0.2, 0.6, 0.2]))
    pf.initialise_from_measurement(0.0, model, fix)
    for k in range(1, 40):
        report = pf.step(float(k), 1.0, None, model, fix if k % 3 == 0 else None)
        local, floor = stack.to_floor(pf.particles.xy_m)
        alive = np.isfinite(pf.particles.log_weight)
        for f, fl in enumerate(stack.building.floors):
            on = alive & (floor == f)
            assert fl.plan.is_free(local[on]).all()
        assert math.isclose(float(np.exp(pf.particles.log_weight).sum()), 1.0, rel_tol=1e-9)
        assert math.isclose(float(report.floor_shares.sum()), 1.0, rel_tol=1e-9)
    # the evidence says L1: most of the weight ends there
    assert report.floor_index == 1 and report.floor_shares[1] > 0.8


def test_floor_changes_happen_only_inside_connectors(tmp_path):
    building = _building(tmp_path)
    stack, changes, _ = _filter(building, 5.0, 0.0)
    rng = np.random.default_rng(3)
    from mapfilter.filter.particles import Particles

    # half the particles inside the stairs, half anywhere
    local = np.concatenate([rng.uniform(2.2, 4.8, (500, 2)), rng.uniform(1, 19, (500, 2))])
    floor = rng.integers(0, 3, 1000)
    local[:500, 0] -= np.where(floor[:500] == 0, 0.0, 1.0)  # into each floor's own frame
    keep = np.array([building.floors[f].plan.is_free(local[i:i + 1])[0] for i, f in enumerate(floor)])
    particles = Particles.at(stack.to_stack(local[keep], floor[keep]))
    before_xy, before_floor = particles.xy_m.copy(), stack.floor_of(particles.xy_m)
    polygons = [__import__("shapely").Polygon(p) for p in building.connectors[0].polygons.values()]
    in_stairs = np.array([
        polygons[f].buffer(1e-9).contains(__import__("shapely").Point(*stack.to_floor(before_xy[i:i + 1])[0][0]))
        for i, f in enumerate(before_floor)])
    log_w = changes.change_floors(particles, particles.log_weight.copy(), 1.0, rng)
    after_local, after_floor = stack.to_floor(particles.xy_m)
    changed = after_floor != before_floor
    assert changed.sum() > 100  # rate 5 / s over 1 s: most particles in the stairs changed floor
    assert not (changed & ~in_stairs).any()  # ... and nobody else did
    for i in np.flatnonzero(changed):  # they land inside the stairs of their new floor, on free space
        assert polygons[after_floor[i]].buffer(0.3).contains(__import__("shapely").Point(*after_local[i]))
        assert building.floors[after_floor[i]].plan.is_free(after_local[i:i + 1])[0]
    assert np.isfinite(log_w).all()
    assert np.array_equal(particles.xy_m[~changed], before_xy[~changed])


def test_without_connectors_a_change_keeps_the_building_position_or_dies(tmp_path):
    building = _building(tmp_path, connectors=False)
    stack, changes, _ = _filter(building, 0.0, 2.0)
    rng = np.random.default_rng(4)
    from mapfilter.filter.particles import Particles

    local = building.floors[0].plan.sample_free(2000, rng)
    particles = Particles.at(stack.to_stack(local, 0))
    log_w = changes.change_floors(particles, particles.log_weight.copy(), 1.0, rng)
    after_local, after_floor = stack.to_floor(particles.xy_m)
    changed = after_floor != 0
    dead = ~np.isfinite(log_w)
    assert (changed | dead).mean() > 0.7  # 1 - exp(-2) took a floor change
    assert changed.sum() > 500 and dead.sum() > 10  # the wall boxes differ: some land in a wall
    assert np.allclose(particles.xy_m[dead], stack.to_stack(local[dead], 0))  # dead where they stood
    for f in (1, 2):
        on = after_floor == f
        assert np.isfinite(log_w[on]).all() and building.floors[f].plan.is_free(after_local[on]).all()
        same_place = building.floors[f].to_building(after_local[on])
        assert np.allclose(same_place, building.floors[0].to_building(local[on]))
    assert changes.changed_last_step == int(changed.sum())


def test_same_seed_same_multi_floor_run(tmp_path):
    building = _building(tmp_path)
    runs = []
    for _ in range(2):
        stack, _, pf = _filter(building, 0.5, 0.0, seed=7)
        model = FloorFixLikelihood(stack, np.full(3, 3.0))
        fix = FloorFix(stack.to_stack(np.array([[3.0, 3.0]] * 3), np.arange(3)), np.log([0.3, 0.4, 0.3]))
        pf.initialise_from_measurement(0.0, model, fix)
        for k in range(1, 15):
            pf.step(float(k), 1.0, None, model, fix)
        runs.append(pf.particles.xy_m.copy())
    assert np.array_equal(runs[0], runs[1])


def test_floor_hmm_finds_a_change_and_ignores_one_odd_scan():
    rng = np.random.default_rng(0)
    truth = np.array([0] * 30 + [2] * 30)
    ll = np.full((60, 3), math.log(0.2))
    ll[np.arange(60), truth] = math.log(0.6)
    ll[10] = np.log([0.2, 0.6, 0.2])  # one scan votes for the wrong floor
    t = np.arange(60) * 2.0 + rng.uniform(0, 0.1, 60)
    path = floor_hmm(ll, t, change_rate_per_s=1 / 600)
    assert np.array_equal(path.path, truth)
    causal = path.causal_floor()
    assert causal[10] == 0 and np.array_equal(causal[40:], truth[40:])
    assert np.allclose(path.forward.sum(axis=1), 1.0)


def _labelled_map() -> RadioMap:
    """Two floors: floor 0 hears AP a strongly, floor 1 hears AP b strongly."""
    rng = np.random.default_rng(0)
    n = 40
    rssi = np.full((2 * n, 3), np.nan, dtype=np.float32)
    rssi[:n, 0], rssi[:n, 1] = -45 + rng.normal(0, 2, n), -80 + rng.normal(0, 2, n)
    rssi[n:, 0], rssi[n:, 1] = -80 + rng.normal(0, 2, n), -45 + rng.normal(0, 2, n)
    rssi[:, 2] = -60 + rng.normal(0, 2, 2 * n)
    xy = rng.uniform(0, 10, (2 * n, 2))
    return RadioMap(xy, ["a@2.4", "b@2.4", "c@2.4"], rssi, np.arange(2 * n, dtype=float),
                    np.repeat(np.arange(8), 10), [f"t{i}" for i in range(8)], None,
                    np.repeat([0, 1], n), ["G", "U"])


def test_floor_vote_picks_the_floor_whose_fingerprints_match():
    radio_map = _labelled_map()
    scans = np.array([[-46, -79, -61], [-79, -44, -59], [np.nan, np.nan, np.nan]], dtype=np.float32)
    ll = floor_vote_log_likelihood(radio_map, scans, k=4, pseudo_count=1.0)
    assert np.allclose(np.exp(ll).sum(axis=1), 1.0)
    assert ll[0].argmax() == 0 and ll[1].argmax() == 1
    assert np.allclose(ll[0], np.log([5 / 6, 1 / 6])) and np.allclose(ll[2], np.log([0.5, 0.5]))


def test_floor_labelled_radio_map_round_trips_with_per_floor_cross_validation(tmp_path, monkeypatch):
    import mapfilter.sensors.radiomap as radiomap_module

    radio_map = _labelled_map()
    radio_map.save(tmp_path / "rm.npz")
    with np.load(tmp_path / "rm.npz") as data:
        assert int(data["version"]) == 3
    loaded = RadioMap.load(tmp_path / "rm.npz")
    assert loaded.floor_names == ["G", "U"] and np.array_equal(loaded.floor, radio_map.floor)
    expected = radiomap_module.cross_validated_fix_errors(radio_map.floor_map(1))
    monkeypatch.setattr(radiomap_module, "_cross_validated_fix_errors",
                        lambda *a: pytest.fail("cross-validated again despite the stored errors"))
    upper = loaded.floor_map(1)
    assert len(upper) == 40 and upper.floor_name == "U" and upper.floor is None
    assert np.array_equal(radiomap_module.cross_validated_fix_errors(upper), expected)
    # leave-one-out keeps the labels
    assert np.array_equal(loaded.without_traces(["t0"]).floor, radio_map.floor[10:])


def test_floor_at_waypoints_counts_causally():
    score = floor_at_waypoints(np.array([1.0, 2.0, 3.0]), ["A", "B", "B"], np.array([0.5, 1.5, 2.5, 3.5]), "B")
    assert (score.n_right, score.n_judged, score.missed) == (2, 3, 1)
    assert math.isclose(score.accuracy, 2 / 3)


# ---- the command line and real data --------------------------------------------------------
def _site_subset(ilc_site1: Path, every: int) -> list[Path]:
    """Every ``every``-th log of every floor."""
    logs = []
    for floor in ("B1", "F1", "F2", "F3", "F4"):
        logs += sorted((ilc_site1 / floor / "path_data_files").glob("*.txt.gz"))[::every]
    return logs


def test_a_log_whose_floor_is_not_in_the_building_is_one_line_and_writes_nothing(ilc_site1_building, ilc_site1,
                                                                                 tmp_path, capsys):
    import gzip

    log = sorted((ilc_site1 / "F1" / "path_data_files").glob("*.txt.gz"))[0]
    text = gzip.decompress(log.read_bytes()).decode().replace("FloorName:F1", "FloorName:F9")
    bad = tmp_path / "walk_f9.txt"
    bad.write_text(text)
    for argv in (["radiomap", "build", str(ilc_site1_building), str(bad), "--out", str(tmp_path / "rm.npz")],
                 ["track", str(ilc_site1_building), str(bad), "--radiomap", str(tmp_path / "none.npz"),
                  "--out", str(tmp_path / "t.csv")]):
        assert main(argv) == 1
        # track may warn first about the building (B1's free space is mostly cut off): one error line
        lines = [line for line in capsys.readouterr().err.strip().splitlines() if "warning:" not in line]
        assert len(lines) == 1 and "'F9' is not in the building" in lines[0] and str(bad) in lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["walk_f9.txt"]


def test_a_building_whose_floors_overlap_nothing_is_one_line_for_track(ilc_site1_building, ilc_site1, tmp_path, capsys):
    meta = yaml.safe_load(ilc_site1_building.read_text())
    meta["floors"][2]["offset_m"] = [5000.0, 0.0]
    for floor in meta["floors"]:
        floor["map"] = str(ilc_site1_building.parent / floor["map"])
    bad = tmp_path / "apart.yaml"
    bad.write_text(yaml.safe_dump(meta))
    log = sorted((ilc_site1 / "F1" / "path_data_files").glob("*.txt.gz"))[0]
    assert main(["track", str(bad), str(log), "--radiomap", str(tmp_path / "rm.npz"), "--out",
                 str(tmp_path / "t.csv")]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "overlaps no other floor" in err and str(bad) in err
    assert not (tmp_path / "t.csv").exists()


@pytest.mark.slow
def test_real_walks_are_tracked_on_their_floor_without_its_label(ilc_site1_building, ilc_site1, tmp_path, capsys):
    """ILC site 1 as one building: a radio map from every other walk of every floor, and walks with IMU
    of F1 and F2 (not in it) tracked without their floor: every waypoint on the right floor."""
    from mapfilter.sensors.ilc import read_ilc
    from mapfilter.io.tracks import read_track

    survey = _site_subset(ilc_site1, 2)
    full_f2 = (ilc_site1 / "F2" / "full_set.txt").read_text().split()
    # the longest F1 walk and the longest F2 walk with IMU (most waypoints) not in the survey
    f1 = [p for p in sorted((ilc_site1 / "F1" / "path_data_files").glob("*.txt.gz")) if p not in survey][:20]
    f2 = [p for p in (ilc_site1 / "F2" / "path_data_files" / f"{n}.txt.gz" for n in full_f2) if p not in survey]
    walks = [max(group, key=lambda p: len(read_ilc(p).waypoint_t_s)) for group in (f1, f2)]
    rm = tmp_path / "rm.npz"
    assert main(["radiomap", "build", str(ilc_site1_building), *map(str, survey), "--out", str(rm)]) == 0
    for walk in walks:
        out = tmp_path / f"{walk.name}.csv"
        assert main(["track", str(ilc_site1_building), str(walk), "--radiomap", str(rm), "--particles", "3000",
                     "--out", str(out)]) == 0
        printed = capsys.readouterr().out
        header_floor = walk.parent.parent.name
        track = read_track(out)
        recording = read_ilc(walk)
        score = floor_at_waypoints(track.t_s, track.floor, recording.waypoint_t_s, header_floor)
        assert score.n_judged >= 5 and score.accuracy == 1.0, printed
        assert f"on {header_floor} at {score.n_right} of {score.n_judged} waypoints" in printed


def test_evaluate_in_a_building_reports_floor_accuracy_per_method(ilc_site1_building, ilc_site1, tmp_path, capsys):
    import json

    f1 = sorted((ilc_site1 / "F1" / "path_data_files").glob("*.txt.gz"))[:2]
    wifi_only = sorted((ilc_site1 / "B1" / "path_data_files").glob("*.txt.gz"))[:2]
    out = tmp_path / "ev"
    assert main(["evaluate", str(ilc_site1_building), *map(str, f1 + wifi_only), "--leave-one-out",
                 "--particles", "500", "--smooth", "--out", str(out)]) == 0
    table = capsys.readouterr().out
    assert "floor_accuracy" in table
    summary = {row["method"]: row for row in json.loads((out / "summary.json").read_text())["summary"]}
    assert set(summary) == {"pf", "pf-floor", "kwnn", "kf", "pdr", "pf-smooth", "pdr-start"}
    assert summary["pf-smooth"]["traces"] == 2 and (out / "tracks" / f1[0].name.split(".")[0] / "pf-smooth.csv").exists()
    assert summary["pf-floor"]["floor_accuracy"] == 1.0  # the floor given
    assert all(0.0 <= row["floor_accuracy"] <= 1.0 for row in summary.values())
    assert summary["pf"]["traces"] == 2 and summary["kwnn"]["traces"] == 4  # no PDR on WiFi-only walks
    assert summary["kf"]["traces"] == 4 and summary["pdr"]["traces"] == 2
    # one floor per walk: the IPIN score is the p75 plus 15 m per storey off, at least the p75
    assert all(row["ipin_score"] >= row["p75"] - 1e-9 for row in summary.values())
    assert "floor_accuracy" in (out / "traces.csv").read_text().splitlines()[0]


def test_rerun_shows_the_current_floor_the_share_per_floor_and_floor_changes(tmp_path):
    """A filter run across three floors whose evidence moves from L0 to L2: the viewer logs the
    share of weight per floor every step, the plan again when the estimate's floor changes, and
    the change in the event log; particles are drawn in the current floor's frame."""
    import sys

    sys.path.insert(0, str(Path(__file__).parents[1] / "viz"))
    from test_viz import mono_rows, read_rrd, rows, verify

    from mapfilter.viz import make_logger

    building = _building(tmp_path, connectors=False)
    stack, _, pf = _filter(building, 0.0, 0.2)
    model = FloorFixLikelihood(stack, np.full(3, 3.0))

    def fix(floor: int) -> FloorFix:
        votes = np.full(3, 0.05)
        votes[floor] = 0.9
        return FloorFix(stack.to_stack(np.array([[10.0, 5.0]] * 3), np.arange(3)), np.log(votes))

    rrd = tmp_path / "floors.rrd"
    pf.initialise_from_measurement(0.0, model, fix(0))
    floors_seen = []
    with make_logger(building.floors[0].plan, rrd_path=rrd, stack=stack) as logger:
        for k in range(1, 41):
            report = pf.step(float(k), 1.0, None, model, fix(0 if k <= 15 else 2))
            floors_seen.append(report.floor_index)
            logger.log_step(report)
    assert floors_seen[0] == 0 and floors_seen[-1] == 2
    verify(rrd)
    entities = read_rrd(rrd)
    texts = mono_rows(entities["/events"], "TextLog:text")
    changes = [t for t in texts if "floor change" in t]
    assert len(changes) == sum(a != b for a, b in zip(floors_seen, floors_seen[1:])) and "L0 -> " in changes[0]
    shares = {name: mono_rows(entities[f"/plots/floors/{name}"], "Scalars:scalars") for name in ("L0", "L1", "L2")}
    assert all(len(v) == 40 for v in shares.values())
    assert np.allclose(np.sum([shares[n] for n in shares], axis=0), 1.0)
    # the mask is logged once per floor that became current, not as static data
    masks = rows(entities["/map/world/walls/mask"], "SegmentationImage:buffer")
    assert len(masks) == len(changes) + 1
    # particles drawn in the floor's own frame: inside the 20 m floor
    last = np.array(rows(entities["/map/world/particles"], "Points2D:positions")[-1])
    assert (last >= 0).all() and (last <= 20).all()


def test_the_fix_weighs_positions_within_a_floor_and_only_the_vote_weighs_floors(tmp_path):
    """A floor whose particles sit right on its (wrong-floor) fix must not gain weight from
    that: each floor's total weight changes by its vote alone."""
    from mapfilter.filter.particles import Particles

    stack = FloorStack(_building(tmp_path, connectors=False))
    rng = np.random.default_rng(0)
    local = np.concatenate([rng.normal([10.0, 5.0], 0.2, (300, 2)),
                            np.clip(rng.normal([15.0, 15.0], 3.0, (300, 2)), 1.0, 19.0)])
    floor = np.repeat([0, 1], 300)
    particles = Particles.at(stack.to_stack(local, floor))
    particles.log_weight = np.log(rng.uniform(0.5, 1.5, 600))
    particles.log_weight -= np.log(np.exp(particles.log_weight).sum())
    fixes = stack.to_stack(np.array([[10.0, 5.0], [2.0, 2.0], [10.0, 10.0]]), np.arange(3))
    vote = np.log([0.2, 0.7, 0.1])
    ll = FloorFixLikelihood(stack, np.full(3, 3.0)).log_likelihood(particles, FloorFix(fixes, vote))
    prior = np.exp(particles.log_weight)
    posterior = prior * np.exp(ll)
    for f in (0, 1):
        assert math.isclose(posterior[floor == f].sum() / prior[floor == f].sum(), math.exp(vote[f]), rel_tol=1e-9)
    # within floor 1, particles nearer its fix gain
    on1 = np.flatnonzero(floor == 1)
    d = np.linalg.norm(local[on1] - [2.0, 2.0], axis=1)
    assert ll[on1[np.argmin(d)]] > ll[on1[np.argmax(d)]]


def test_barometer_between_scans_weighs_floors_only_and_never_collapses_or_becomes_the_redraw_source(tmp_path):
    """The height alone (no fix on any floor) moves weight between floors, keeps positions, and a
    later collapse still re-draws from the last measurement that said where."""
    stack, _, pf = _filter(_building(tmp_path, connectors=False), 0.0, 0.0)
    model = FloorFixLikelihood(stack, np.full(3, 3.0))
    fix = FloorFix(stack.to_stack(np.array([[10.0, 5.0]] * 3), np.arange(3)), np.log([0.1, 0.8, 0.1]))
    pf.initialise_from_measurement(0.0, model, fix)
    pf.step(1.0, 1.0, None, model, fix)
    from mapfilter.filter.particles import Particles

    height = FloorFix(np.full((3, 2), np.nan), np.array([-8.0, -8.0, 0.0]))  # the barometer says floor 2
    assert height.evidence_only and not fix.evidence_only
    on_floor_0 = Particles.at(stack.to_stack(np.array([[10.0, 5.0], [12.0, 6.0]]), np.array([0, 0])))
    on_floor_0.log_weight = np.log([0.5, 0.5])
    # every particle off floor 2: a fix-carrying measurement would collapse (-inf); the height
    # alone gives a per-floor constant (positions keep their relative weights)
    assert np.isneginf(model.log_likelihood(on_floor_0, FloorFix(fix.xy_m, height.floor_log_likelihood))).all()
    np.testing.assert_array_equal(model.log_likelihood(on_floor_0, height), [-8.0, -8.0])
    floor = stack.floor_of(pf.particles.xy_m)
    np.testing.assert_array_equal(model.log_likelihood(pf.particles, height), height.floor_log_likelihood[floor])
    pf.step(2.0, 1.0, None, model, height)
    assert pf._last_measurement[2] is fix


def test_pdr_steps_on_the_barometer_alone_wherever_a_second_passes_without_a_step_or_scan():
    from mapfilter.filter.models.position_fix import GaussianFixLikelihood, PositionFix
    from mapfilter.filter.particle_filter import FilterConfig
    from mapfilter.filter.causal import CausalFilter, MotionConfig, RunSettings
    from mapfilter.maps.floorplan import FloorPlan
    from mapfilter.sensors.pdr import Steps
    from mapfilter.sensors.wifi import WifiScan, scans_recording

    class Evidence:
        """Scans that fix the walker at (5, 5), and evidence between them when ``between``."""

        def __init__(self, scans, between):
            self.scans, self._between = scans, between
            self.usable = np.ones(len(scans), dtype=bool)
            self.model = GaussianFixLikelihood(1000.0)

        def add_scans(self, scans):
            self.scans.extend(scans)

        def measurement(self, index):
            return PositionFix((5.0, 5.0))

        def between_scans(self, t_s):
            return PositionFix((5.0, 5.0)) if self._between else None

        def has_evidence_between_scans(self):
            return self._between

        def observe(self, report):
            pass

    scans = [WifiScan(t, ("a@2.4",), np.array([-50.0], np.float32)) for t in (0.0, 3.0, 12.0)]
    t_steps = np.array([0.5, 1.0, 1.5, 2.0, 2.5, 9.0, 9.5])  # then standing 2.5 s -> 9 s (a lift)
    zeros = np.zeros(t_steps.size)
    steps = Steps(t_steps, zeros, zeros, None, zeros + 0.7, zeros + 1.0, 0.0)
    plan = FloorPlan(np.pad(np.zeros((98, 98), dtype=bool), 1, constant_values=True), 0.1)

    def row_times(model, between):
        settings = RunSettings(MotionConfig(model=model, tick_s=1.0), FilterConfig(n_particles=100))
        stream = CausalFilter(plan, Evidence([], between), settings, np.random.default_rng(0),
                              steps=steps if model == "pdr" else None)
        stream.feed(scans_recording(scans))
        stream.close()
        return np.array([row.t_s for row in stream.rows])

    times = row_times("pdr", True)
    assert np.all(np.diff(times) >= 0) and np.diff(times).max() <= IDLE_TICK_S + 1e-9
    idle = sorted(set(times) - set(t_steps) - {0.0, 3.0, 12.0})
    # only in the gaps (after the scan at 3 s and the step at 9.5 s), never among steps
    gaps = [(3.0, 9.0), (9.5, 12.0)]
    assert idle == [t for t0, t1 in gaps for t in t0 + IDLE_TICK_S * np.arange(1, round((t1 - t0) / IDLE_TICK_S))]
    # without steps (cv / rw): prediction ticks every second from the start, no idle ticks
    assert row_times("cv", True).tolist() == [float(t) for t in range(13)]
    # one floor (nothing weighs the particles between scans): no idle ticks at all
    assert sorted(row_times("pdr", False)) == sorted([0.0, 3.0, 12.0, *t_steps])


def test_barometer_reference_follows_the_weather_not_a_pausing_climber():
    """Without WiFi the reference is the filter's floor when it is sure, moved no faster than the weather."""
    from mapfilter.filter.models.barometer import DRIFT_M_PER_S as drift_m_per_s
    from mapfilter.filter.models.barometer import BarometerReference

    ref = BarometerReference(np.array([0.0, 4.0, 8.0]))
    sure_0 = np.array([0.99, 0.01, 0.0])
    assert ref.floor_log_likelihood(0.0) is None  # no reference yet
    ref.update(0.0, 0.0, True, sure_0)
    # a climber pauses 1 m up the stairs (steady for a few seconds, the filter still on floor 0)
    ref.update(10.0, 1.0, True, sure_0)
    assert 0.0 < ref.drift_m <= 10.0 * drift_m_per_s + 1e-12
    # 2.2 m up: floor 1 already weighs more, as it would have without the pause
    ll = ref.floor_log_likelihood(2.2)
    assert ll[1] > ll[0]
    # the weather moves the barometer 0.3 m in 5 minutes on floor 0: the reference follows it
    ref = BarometerReference(np.array([0.0, 4.0, 8.0]))
    for t in np.arange(0.0, 301.0, 1.0):
        ref.update(float(t), 0.001 * t, True, sure_0)
    assert abs(ref.drift_m - 0.3) < 1e-9 and np.argmax(ref.floor_log_likelihood(0.3)) == 0
    # unsure or not steady: no move; a floor the barometer disagrees with (4 m expected, 0.3 m seen): no move
    before = ref.drift_m, ref.log_p.copy()
    ref.update(301.0, 0.3, False, sure_0)
    ref.update(302.0, 0.3, True, np.array([0.6, 0.4, 0.0]))
    ref.update(303.0, 0.3, True, np.array([0.0, 1.0, 0.0]))
    assert ref.drift_m == before[0] and np.array_equal(ref.log_p, before[1])
    # after a real change (4 m up, the filter sure of floor 1), floor 1 is the barometer's
    ref.update(330.0, 4.3, True, np.array([0.0, 1.0, 0.0]))
    assert np.argmax(ref.floor_log_likelihood(4.3)) == 1


def test_the_scans_not_the_filter_decide_which_floor_the_barometer_started_on():
    """With WiFi, which floor the barometer's zero is on is weighed by every scan's match to each
    floor, never by the filter's floor: a walk that matches the floor below 1 dB better for its
    first scans and its own floor 6 dB better later ends on its own floor (IPIN trial 01), a climb
    the barometer sees rules out a start on the top floor, and a known start is never moved."""
    from mapfilter.filter.models.barometer import BarometerReference

    elevations = np.array([-5.6, -2.8, 0.0])
    ref = BarometerReference(elevations)
    below_a_little = np.array([15.0, np.inf, 16.0])  # floor -2 matches 1 dB better; nobody surveyed -1
    own_much = np.array([14.0, np.inf, 8.0])
    for _ in range(15):
        ref.observe_scan(0.0, below_a_little)
        ref.update(0.0, 0.0, True, np.array([0.0, 0.0, 1.0]))  # the filter's floor is never read
    assert np.argmax(ref.floor_log_likelihood(0.0)) == 0
    for _ in range(10):
        ref.observe_scan(0.1, own_much)
    ll = ref.floor_log_likelihood(0.1)
    assert np.argmax(ll) == 2 and np.exp(ref.log_p[2]) > 0.999
    assert np.isclose(np.exp(ref.log_p).sum(), 1.0)

    # a walk 5.6 m up from where it started: it cannot have started on the top floor
    ref = BarometerReference(elevations)
    ref.observe_scan(0.0, np.array([10.0, np.inf, 10.0]))
    ref.observe_scan(5.6, np.array([10.0, np.inf, 10.0]))
    assert np.argmax(ref.log_p) == 0 and np.argmax(ref.floor_log_likelihood(5.6)) == 2

    # the filter's floor, taken before the first scan (another source started it), is not kept
    ref = BarometerReference(elevations)
    ref.update(0.0, 0.0, True, np.array([0.99, 0.0, 0.01]))
    assert np.argmax(ref.floor_log_likelihood(0.0)) == 0
    for _ in range(5):
        ref.observe_scan(0.0, own_much)
    assert np.argmax(ref.floor_log_likelihood(0.0)) == 2

    # scans that tell the floors apart no better than chance (one floor surveyed) leave every
    # hypothesis as likely as before, however many: the middle floor's gains nothing from its two
    # neighbours (it drifted to 0.52 in 38 scans, and IPIN trial 21 to the wrong floor)
    ref = BarometerReference(elevations)
    for h in np.tile([0.3, -0.2, 0.1], 20):
        ref.observe_scan(h, np.array([8.0, np.inf, np.inf]))
    assert np.allclose(np.exp(ref.log_p), 1.0 / 3.0)

    # a known start: the scans never move it
    ref = BarometerReference(elevations)
    ref.start_on(2, 0.0)
    for _ in range(30):
        ref.observe_scan(0.0, np.array([5.0, np.inf, 15.0]))
    assert np.argmax(ref.floor_log_likelihood(0.0)) == 2


def test_in_a_connector_the_barometers_floor_decides_and_elsewhere_nothing_moves(tmp_path):
    """A step whose height is nearest floor 1: every live particle inside the stairs (which link
    floor 1) lands there, inside the stairs; nobody outside them changes floor; without a
    barometer (no ``height_floor``) only the rate moves particles."""
    import shapely

    from mapfilter.filter.particles import Particles

    building = _building(tmp_path)
    rng = np.random.default_rng(5)
    local = np.concatenate([rng.uniform(2.2, 4.8, (300, 2)), rng.uniform(8.0, 19.0, (300, 2))])
    keep = building.floors[0].plan.is_free(local)
    local = local[keep]
    in_stairs = np.arange(len(local)) < np.count_nonzero(keep[:300])
    stack = FloorStack(building)

    def run(config: FloorChangeConfig, height_floor):
        changes = FloorChanges(stack, config)
        particles = Particles.at(stack.to_stack(local, 0))
        particles.log_weight[-1] = -np.inf  # a dead particle stays where it is
        measurement = FloorFix(np.full((3, 2), np.nan), np.array([-2.0, 0.0, -8.0]), height_floor)
        changes.change_floors(particles, particles.log_weight.copy(), 0.6, rng, measurement)
        return stack.to_floor(particles.xy_m)

    after_local, after_floor = run(FloorChangeConfig(0.0, 0.0), 1)
    assert (after_floor[in_stairs] == 1).all() and (after_floor[~in_stairs] == 0).all()
    stairs_1 = shapely.Polygon(building.connectors[0].polygons["L1"]).buffer(0.3)
    assert shapely.contains_xy(stairs_1, after_local[in_stairs, 0], after_local[in_stairs, 1]).all()
    assert (run(FloorChangeConfig(0.0, 0.0), None)[1] == 0).all()


def test_a_pdr_step_that_starts_on_stairs_advances_a_tread_not_a_stride(tmp_path):
    from mapfilter.filter.models.motion import PDRMotion, StepInput
    from mapfilter.filter.particles import Particles

    building = _building(tmp_path)
    stack = FloorStack(building)
    changes = FloorChanges(stack, FloorChangeConfig(0.0, 0.0))
    lo, hi = STAIRS_TREAD_M
    rng = np.random.default_rng(6)
    on = np.column_stack([rng.uniform(2.3, 3.0, 200), rng.uniform(2.3, 4.7, 200)])  # west end of the stairs
    off = np.column_stack([rng.uniform(8.0, 12.0, 200), rng.uniform(2.3, 4.7, 200)])
    start = stack.to_stack(np.concatenate([on, off]), 0)
    end = start + [0.7, 0.0]  # a 0.7 m stride east
    out = changes.step_on_stairs(start, end, rng)
    step_m = np.linalg.norm(out - start, axis=1)
    assert ((step_m[:200] >= lo - 1e-9) & (step_m[:200] <= hi + 1e-9)).all()
    assert np.allclose(out[:200, 1], start[:200, 1])  # along the step's own direction
    np.testing.assert_array_equal(out[200:], end[200:])
    # in the filter: PDR particles on the stairs keep to treads, the rest stride on
    pf = ParticleFilter(stack.plan, PDRMotion(heading_sigma_rad=0.0),
                        FilterConfig(n_particles=400, regularise=False), rng, floors=changes)
    pf.particles = Particles.at(start)
    pf.particles.heading_rad[:] = 0.0
    pf.particles.step_length_m[:] = 0.7
    pf.step(1.0, 0.6, StepInput(1, 0.0))
    moved_m = np.linalg.norm(pf.particles.xy_m - start, axis=1)
    # a tread on the stairs; off them the 0.7 m stride with its slack (5 sigma below it is still no tread)
    assert (moved_m[:200] <= hi + 1e-9).all() and (moved_m[200:] >= hi + 0.1).all()


def test_barometric_height_is_causal_and_follows_a_climb_without_lag():
    from mapfilter.filter.models.barometer import barometric_height
    from mapfilter.simulate.building import pressure_hpa

    t = 1.6e9 + np.arange(0.0, 60.0, 0.5)
    height = np.clip((t - t[0] - 20.0) * 0.3, 0.0, 6.0)  # 0.3 m/s up from 20 s to 40 s
    noise = 0.03 * np.random.default_rng(0).standard_normal(t.size)
    _, h = barometric_height(t, pressure_hpa(height) + noise)
    # the value at a reading never depends on later readings
    for i in (10, 50, 70):
        _, h_cut = barometric_height(t[:i + 1], (pressure_hpa(height) + noise)[:i + 1])
        assert h_cut[i] == pytest.approx(h[i], abs=1e-9)
    # mid-climb it is on the true height (a trailing mean lags it by 0.3 m/s x 1 s = 0.3 m)
    mid = (t - t[0] > 25.0) & (t - t[0] < 38.0)
    assert abs(np.mean(h[mid] - height[mid])) < 0.1
    assert np.sqrt(np.mean((h[mid] - height[mid]) ** 2)) < 0.35


def test_centred_barometric_height_has_no_lag_and_less_noise_than_the_causal_one():
    from mapfilter.filter.models.barometer import barometric_height
    from mapfilter.simulate.building import pressure_hpa

    t = 1.6e9 + np.arange(0.0, 60.0, 0.5)
    height = np.clip((t - t[0] - 20.0) * 0.3, 0.0, 6.0)
    noise = 0.03 * np.random.default_rng(0).standard_normal(t.size)
    tc, hc = barometric_height(t, pressure_hpa(height) + noise, centred=True)
    _, h = barometric_height(t, pressure_hpa(height) + noise)
    truth_c = np.clip((tc - t[0] - 20.0) * 0.3, 0.0, 6.0)
    flat = (t - t[0] > 3.0) & (t - t[0] < 19.0)
    # the spread (the zero is the first reading's, alike in both): about half, as a line's middle against its end
    assert np.std(hc[flat] - truth_c[flat]) < 0.7 * np.std(h[flat] - height[flat])
    mid = (tc - t[0] > 25.0) & (tc - t[0] < 38.0)
    assert abs(np.mean(hc[mid] - truth_c[mid])) < 0.1




@pytest.mark.slow
def test_a_walk_whose_start_matches_the_floor_below_ends_on_its_own_floor_and_is_there_offline(ipin2023, ipin_venue):
    """IPIN trial 01 (floor 0) against every other trial's survey: its first and last minutes match
    floor -2's fingerprints a little better, its middle floor 0's much better. The barometer's zero
    is weighed by the scans, not by the filter's floor: the causal track ends on floor 0, and the
    offline track, run from the floor the whole walk says, is on floor 0 at every POSI point (the
    filter's floor as the zero kept both on floor -2 throughout)."""
    from mapfilter.api import build_radio_map
    from mapfilter.config import TrackingConfig
    from mapfilter.maps.building import Building
    from mapfilter.pipeline.tracker import track
    from mapfilter.sensors.logs import read_log

    building = Building.load(ipin_venue)
    logs = sorted((ipin2023 / "logs").glob("*.txt.gz"))
    radio_map = build_radio_map(building, [read_log(p, building=building) for p in logs if "Trial01" not in p.name])
    rec = read_log(next(p for p in logs if "Trial01_repetition01" in p.name), building=building)
    config = TrackingConfig(smooth=True, seed=0).override({"filter.n_particles": 2000})
    result = track(building, rec, radio_map, config=config)

    def floors_at_points(tr):
        row = np.clip(np.searchsorted(tr.t_s, rec.waypoint_t_s, side="right") - 1, 0, len(tr) - 1)
        return np.array(tr.floor)[row]

    assert set(rec.waypoint_floor) == {"0"}
    assert result.causal.floor[-1] == "0" and np.mean(floors_at_points(result.causal) == "0") >= 0.5
    assert np.all(floors_at_points(result.offline) == "0")
