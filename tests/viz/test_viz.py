"""rerun visualisation: recordings are read back with rerun's own reader and checked."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pyarrow as pa
import pytest

from mapfilter.cli import main as cli_main
from mapfilter.errors import MapfilterError
from mapfilter.filter.events import CollapseEvent, StepReport
from mapfilter.maps.floorplan import FloorPlan, SourceImage
from mapfilter.io.tracks import Track, write_track_csv
from mapfilter.viz import (
    NullLogger,
    RerunLogger,
    interpolate_ground_truth,
    make_logger,
    weight_colours,
    weight_faithful_subsample,
)

RERUN_CLI = Path(sys.executable).parent / "rerun"
ILC_TRACE = "5dd9e7b29191710006b5705b.txt.gz"


# ---- helpers ----------------------------------------------------------------------------------
def read_rrd(path: Path) -> dict[str, list[pa.RecordBatch]]:
    """Record batches of the file's recording, grouped by entity path."""
    from rerun.chunk import RrdReader

    entities: dict[str, list[pa.RecordBatch]] = {}
    for chunk in RrdReader(path).stream().to_chunks():
        entities.setdefault(chunk.entity_path, []).append(chunk.to_record_batch())
    return entities


def rows(batches: list[pa.RecordBatch], column: str) -> list:
    """All values of a column over an entity's chunks, ordered by the ``step`` timeline if any."""
    out = []
    for batch in batches:
        if column not in batch.schema.names:
            continue
        values = batch.column(column).to_pylist()
        order = batch.column("step").to_pylist() if "step" in batch.schema.names else range(len(values))
        out.extend(zip(order, values))
    return [v for _, v in sorted(out, key=lambda item: item[0])]


def mono_rows(batches: list[pa.RecordBatch], column: str) -> list:
    """Like ``rows`` for a component with one value per row (rerun stores each row as a list)."""
    return [v[0] for v in rows(batches, column)]


def verify(path: Path) -> None:
    result = subprocess.run([str(RERUN_CLI), "rrd", "verify", str(path)], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 0, result.stderr
    assert "verified without error" in result.stdout + result.stderr


def small_floor(tmp_path: Path, with_picture: bool = True) -> FloorPlan:
    """20 m x 10 m at 0.1 m/px, walls around, a wall across x = 10 m with a door; a picture."""
    mask = np.zeros((100, 200), dtype=bool)
    mask[:2, :] = mask[-2:, :] = mask[:, :2] = mask[:, -2:] = True
    mask[:, 99:101] = True
    mask[40:60, 99:101] = False
    source = None
    if with_picture:
        picture = np.full((50, 100, 4), 255, dtype=np.uint8)  # a 0.2 m/px RGBA plan, half transparent
        picture[:, 50:, 3] = 0
        cv2.imwrite(str(tmp_path / "plan.png"), picture)
        source = SourceImage(tmp_path / "plan.png", 0.2, (0.0, 0.0))
    return FloorPlan(mask, 0.1, (1.0, 2.0), floor_name="F1", source_image=source)


def synthetic_steps(floor: FloorPlan, n_steps: int, n_particles: int, rng: np.random.Generator,
                    collapse_steps=(), resample_every: int = 3, t0_s: float = 1.6e9):
    """StepReports of a walk left to right; particle weights Gaussian around the truth."""
    for i in range(n_steps):
        truth = floor.pixel_to_world(np.array([20.0 + 160.0 * i / max(n_steps - 1, 1), 50.0]))
        start = truth + rng.normal(0.0, 1.0, size=(n_particles, 2))
        moved = start + rng.normal(0.0, 0.5, size=(n_particles, 2))
        killed = ~floor.is_free(moved)
        logw = -0.5 * np.sum((moved - truth) ** 2, axis=1)
        logw[killed] = -np.inf
        w = np.exp(logw - logw.max())
        w /= w.sum()
        estimate = w @ moved
        collapse = None
        if i in collapse_steps:
            collapse = CollapseEvent(t_s=t0_s + i, step_index=i, xy_m=(float(estimate[0]), float(estimate[1])),
                                     cause="all_killed_by_walls", particles_lost=n_particles, recovery="around_fix",
                                     recovered_xy_m=(float(truth[0]), float(truth[1])))
        yield StepReport(
            t_s=t0_s + i, step_index=i, estimate_xy_m=estimate, estimate_std_m=0.8, ess=float(1 / np.sum(w**2)),
            n_particles=n_particles, n_alive=int(np.count_nonzero(w)), n_killed=int(killed.sum()),
            resampled=(i % resample_every == 0), particles_xy_m=moved, particles_weight=w,
            killed_from_xy_m=start[killed], killed_to_xy_m=moved[killed], collapse=collapse,
            heading_rad=0.1 * i, step_length_m=0.7,
            # even steps: a fingerprint fix; steps 1 and 3 mod 6: three heard APs; others nothing
            fix_xy_m=truth.copy() if i % 2 == 0 else None,
            heard_ap_xy_m=(truth + np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0]])).astype(np.float32)
            if i % 6 in (1, 3) else None,
        )


# ---- pure helpers -----------------------------------------------------------------------------
def test_subsample_keeps_every_live_particle_under_the_cap():
    w = np.array([0.0, 0.5, 0.0, 0.25, 0.25])
    assert weight_faithful_subsample(w, 10).tolist() == [1, 3, 4]


def test_subsample_follows_the_weights():
    # two clusters holding 80 % and 20 % of the weight: the shown points split the same way
    w = np.concatenate([np.full(5000, 0.8 / 5000), np.full(5000, 0.2 / 5000)])
    keep = weight_faithful_subsample(w, 1000)
    assert len(keep) <= 1000
    assert len(np.unique(keep)) == len(keep)
    assert abs(np.count_nonzero(keep < 5000) - 800) <= 1
    assert abs(np.count_nonzero(keep >= 5000) - 200) <= 1


@pytest.mark.parametrize("seed", range(5))
def test_subsample_property_random_weights(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 20000))
    w = rng.random(n) ** 8
    w[rng.random(n) < 0.3] = 0.0  # dead particles
    cap = int(rng.integers(1, 3000))
    keep = weight_faithful_subsample(w, cap)
    assert len(keep) <= cap
    assert np.all(np.diff(keep) > 0)
    if keep.size:
        assert np.all(w[keep] > 0)
    # the heaviest particle is always shown (its weight covers a systematic position or it is alone)
    if np.count_nonzero(w) and w.max() / w.sum() >= 1.0 / cap:
        assert int(np.argmax(w)) in keep


def test_subsample_rejects_a_zero_cap():
    with pytest.raises(ValueError):
        weight_faithful_subsample(np.ones(3), 0)


def test_weight_colours_run_from_dark_to_yellow():
    colours = weight_colours(np.array([1.0, 1e-3, 0.0, 0.5]))
    assert colours.dtype == np.uint8 and colours.shape == (4, 3)
    assert colours[0].tolist() == [253, 231, 37]  # the heaviest: top of the ramp
    assert colours[1].tolist() == [68, 1, 84]  # three decades below: bottom
    assert colours[2].tolist() == [68, 1, 84]
    assert colours[3].sum() < colours[0].sum() and colours[3].sum() > colours[1].sum()


def test_interpolate_ground_truth_between_waypoints_only():
    t = np.array([0.0, 10.0])
    xy = np.array([[0.0, 0.0], [10.0, 20.0]])
    out = interpolate_ground_truth(t, xy, np.array([-1.0, 0.0, 5.0, 10.0, 11.0]))
    assert np.all(np.isnan(out[[0, 4]]))
    np.testing.assert_allclose(out[1:4], [[0, 0], [5, 10], [10, 20]])


# ---- recordings -------------------------------------------------------------------------------
def test_visualisation_off_costs_nothing():
    code = ("import sys, mapfilter.viz as v; "
            "assert isinstance(v.make_logger(None), v.NullLogger); print('rerun' in sys.modules)")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "False"


def test_null_logger_has_every_public_method_of_the_rerun_logger():
    public = {name for name in dir(RerunLogger) if not name.startswith("_") and callable(getattr(RerunLogger, name))}
    public -= {"blueprint"}  # layout of the live logger only
    assert public <= set(dir(NullLogger))


@pytest.fixture(scope="module")
def filter_recording(tmp_path_factory):
    """A 40-step synthetic run, 3000 particles drawn at most 500 at a time, two collapses."""
    tmp_path = tmp_path_factory.mktemp("viz")
    floor = small_floor(tmp_path)
    rng = np.random.default_rng(7)
    reports = list(synthetic_steps(floor, 40, 3000, rng, collapse_steps=(12, 30)))
    out = tmp_path / "run.rrd"
    logger = make_logger(floor, rrd_path=out, max_particles=500, recording_name="synthetic")
    assert isinstance(logger, RerunLogger)
    truth_t = np.array([r.t_s for r in reports])
    truth_xy = floor.pixel_to_world(np.column_stack([20.0 + 160.0 * np.arange(40) / 39, np.full(40, 50.0)]))
    waypoints = np.r_[0:40:5, 39]  # 9 waypoints covering the whole walk
    logger.log_ground_truth(truth_t[waypoints], truth_xy[waypoints])
    assert not out.exists()  # written atomically: appears on close()
    for report in reports:
        logger.log_step(report)
    logger.log_track("smoothed track", truth_t, truth_xy + 0.5)
    logger.close()
    return out, floor, reports


def test_recording_passes_rerun_verify(filter_recording):
    verify(filter_recording[0])


def test_recording_has_one_row_per_step(filter_recording):
    path, _, reports = filter_recording
    entities = read_rrd(path)
    for entity in ("/map/world/particles", "/map/world/estimate/position", "/plots/particles/ess",
                   "/plots/particles/alive", "/plots/kills", "/plots/pdr/heading_deg/filter", "/plots/pdr/step_length_m",
                   "/plots/error_m/filter"):
        batches = [b for b in entities[entity] if "step" in b.schema.names]  # not the static style
        steps = sorted(s for b in batches for s in b.column("step").to_pylist())
        assert steps == list(range(len(reports))), entity
        assert all("trace_time" in b.schema.names for b in batches)
    # resampling steps: one marker each on the ESS plot
    n_resampled = sum(r.resampled for r in reports)
    assert len(rows(entities["/plots/particles/resampled"], "Scalars:scalars")) == n_resampled
    kills = mono_rows(entities["/plots/kills"], "Scalars:scalars")
    assert kills == [r.n_killed for r in reports]


def test_ground_truth_walking_direction_is_plotted(filter_recording):
    path, _, reports = filter_recording
    # the synthetic walk goes left to right (+x): heading 0 deg wherever the waypoints cover it
    headings = np.array(mono_rows(read_rrd(path)["/plots/pdr/heading_deg/ground_truth"], "Scalars:scalars"))
    assert headings.size >= len(reports) - 2  # the first and last step lack a full window
    np.testing.assert_allclose(headings, 0.0, atol=1e-3)


def test_particles_are_capped_and_weight_coloured(filter_recording):
    path, _, reports = filter_recording
    positions = rows(read_rrd(path)["/map/world/particles"], "Points2D:positions")
    counts = [len(p) for p in positions]
    assert max(counts) <= 500
    assert min(counts) > 100  # a weight-faithful subsample of a broad cloud is not a handful
    batches = read_rrd(path)["/map/world/particles"]
    colours = rows(batches, "Points2D:colors")
    assert [len(c) for c in colours] == counts
    # the shown points are particles of that step
    for step in (0, 20):
        shown = np.array(positions[step])
        nearest = np.min(np.linalg.norm(shown[:, None, :] - reports[step].particles_xy_m[None], axis=2), axis=1)
        assert np.all(nearest < 1e-5)


def test_killed_moves_are_red_segments(filter_recording):
    path, _, reports = filter_recording
    strips = rows(read_rrd(path)["/map/world/killed"], "LineStrips2D:strips")
    with_kills = [r for r in reports if r.n_killed]
    assert with_kills, "the synthetic walk must hit a wall"
    assert sum(len(s) for s in strips if s) == sum(min(r.n_killed, 500) for r in with_kills)
    segment = np.array(next(s for s in strips if s)[0])
    assert segment.shape == (2, 2)


def test_measurements_show_only_on_their_steps(filter_recording):
    path, _, reports = filter_recording
    entities = read_rrd(path)

    def shown_steps(entity):
        out = []
        for batch in entities[entity]:
            if "Points2D:positions" in batch.schema.names:
                out += [s for s, p in zip(batch.column("step").to_pylist(),
                                          batch.column("Points2D:positions").to_pylist()) if p]
        return sorted(out)

    assert shown_steps("/map/world/measurement/fix") == [r.step_index for r in reports if r.fix_xy_m is not None]
    assert shown_steps("/map/world/measurement/aps") == [r.step_index for r in reports
                                                         if r.heard_ap_xy_m is not None]
    aps = rows(entities["/map/world/measurement/aps"], "Points2D:positions")
    assert all(len(a) == 3 for a in aps if a)
    # a step without a fix clears the previous one rather than leaving it on screen
    clears = sorted(s for b in entities["/map/world/measurement/fix"] if "Clear:is_recursive" in b.schema.names
                    for s, c in zip(b.column("step").to_pylist(), b.column("Clear:is_recursive").to_pylist())
                    if c is not None)
    assert clears == [r.step_index for r in reports if r.fix_xy_m is None]


def test_collapses_are_warnings_and_markers(filter_recording):
    path, _, _ = filter_recording
    entities = read_rrd(path)
    levels = mono_rows(entities["/events"], "TextLog:level")
    texts = mono_rows(entities["/events"], "TextLog:text")
    warnings = [t for t, level in zip(texts, levels) if level == "WARN"]
    assert len(warnings) == 4  # a collapse and a recovery each, twice
    assert sum("collapse" in t for t in warnings) == 2 and sum("recovery" in t for t in warnings) == 2
    assert sum(level == "DEBUG" for level in levels) == 14  # resampling: steps 0, 3, ..., 39
    markers = rows(entities["/map/world/events/collapses"], "Points2D:positions")
    assert [len(m) for m in markers] == [1, 2]  # each collapse re-logs every marker so far
    steps = sorted(s for b in entities["/map/world/events/collapses"] for s in b.column("step").to_pylist())
    assert steps == [12, 30]


def test_map_is_placed_in_metres(filter_recording):
    """Compose the logged transforms and check that pixel corners land on FloorPlan.pixel_to_world."""
    path, floor, _ = filter_recording
    entities = read_rrd(path)

    def transform(entity):
        batch = next(b for b in entities[entity] if "Transform3D:scale" in b.schema.names)
        translation = np.zeros(3)
        if "Transform3D:translation" in batch.schema.names:
            translation = np.array(batch.column("Transform3D:translation").to_pylist()[0][0])
        scale = np.array(batch.column("Transform3D:scale").to_pylist()[0][0])
        return translation, scale

    flip_t, flip_s = transform("/map/world")
    np.testing.assert_allclose(flip_s, [1, -1, 1])
    t, s = transform("/map/world/walls")
    uv = np.array([[0.0, 0.0], [200.0, 100.0], [37.5, 81.25]])
    world = t[:2] + s[:2] * uv
    np.testing.assert_allclose(world, floor.pixel_to_world(uv), atol=1e-5)
    # the picture (0.2 m/px, 50 rows) shares the map's frame: its lower-left corner is (0, 0)
    t, s = transform("/map/world/floorplan")
    np.testing.assert_allclose(t[:2] + s[:2] * np.array([0.0, 50.0]), [0.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(t[:2] + s[:2] * np.array([100.0, 0.0]), [20.0, 10.0], atol=1e-6)
    mask = entities["/map/world/walls/mask"][0]
    assert "SegmentationImage:buffer" in mask.schema.names
    assert "EncodedImage:blob" in entities["/map/world/floorplan/image"][0].schema.names


def test_tracks_and_ground_truth(filter_recording):
    path, _, _ = filter_recording
    entities = read_rrd(path)
    assert len(rows(entities["/map/world/ground_truth/waypoints"], "Points2D:positions")[0]) == 9
    assert "/map/world/tracks/smoothed_track/path" in entities
    errors = np.array(mono_rows(entities["/plots/error_m/smoothed_track"], "Scalars:scalars"))
    # the track is the truth shifted by (0.5, 0.5): error sqrt(0.5) at each of its 40 samples
    assert errors.size == 40
    np.testing.assert_allclose(errors, np.sqrt(0.5), atol=1e-6)


def test_blueprint_is_stored(filter_recording):
    from rerun.chunk import RrdReader

    assert len(RrdReader(filter_recording[0]).blueprints()) == 1


def test_small_runs_show_every_live_particle(tmp_path):
    floor = small_floor(tmp_path, with_picture=False)
    reports = list(synthetic_steps(floor, 3, 200, np.random.default_rng(1), t0_s=0.0))
    out = tmp_path / "small.rrd"
    with make_logger(floor, rrd_path=out, max_particles=5000) as logger:
        for report in reports:
            logger.log_step(report)
    entities = read_rrd(out)
    counts = [len(p) for p in rows(entities["/map/world/particles"], "Points2D:positions")]
    assert counts == [r.n_alive for r in reports]
    assert "/map/world/floorplan/image" not in entities
    # times from 0: a duration timeline rather than 1970 timestamps
    column = entities["/map/world/particles"][0].column("trace_time")
    assert pa.types.is_duration(column.type)
    verify(out)


def test_failed_run_leaves_no_file(tmp_path):
    floor = small_floor(tmp_path, with_picture=False)
    out = tmp_path / "failed.rrd"
    with pytest.raises(RuntimeError):
        with make_logger(floor, rrd_path=out):
            raise RuntimeError("the filter crashed")
    assert not out.exists()
    assert list(tmp_path.glob("*.rrd")) == []


def test_logger_refuses_two_sinks_and_a_zero_cap(tmp_path):
    floor = small_floor(tmp_path, with_picture=False)
    with pytest.raises(MapfilterError):
        make_logger(floor, rrd_path=tmp_path / "a.rrd", spawn=True)
    with pytest.raises(MapfilterError):
        make_logger(floor, rrd_path=tmp_path / "a.rrd", max_particles=0)
    assert not (tmp_path / "a.rrd").exists()


def test_missing_floor_plan_picture_is_one_error(tmp_path):
    floor = small_floor(tmp_path)
    (tmp_path / "plan.png").unlink()
    with pytest.raises(MapfilterError, match="plan.png"):
        make_logger(floor, rrd_path=tmp_path / "a.rrd")
    assert not (tmp_path / "a.rrd").exists()


# ---- mapfilter view ---------------------------------------------------------------------------
@pytest.fixture
def ilc_map(ilc_site1, tmp_path):
    """The ILC F1 floor as a map: transparent pixels walkable, the picture underneath."""
    floor_dir = ilc_site1 / "F1"
    info = json.loads((floor_dir / "floor_info.json").read_text())["map_info"]
    picture = cv2.imread(str(floor_dir / "floor_image.png"), cv2.IMREAD_UNCHANGED)
    resolution_m = info["width"] / picture.shape[1]
    plan = FloorPlan(picture[..., 3] > 0, resolution_m, (0.0, 0.0), floor_name="F1",
                     source_image=SourceImage(floor_dir / "floor_image.png", resolution_m, (0.0, 0.0)))
    plan.save(tmp_path / "F1.yaml")
    return tmp_path / "F1.yaml"


def test_view_cli_writes_tracks_and_ground_truth(ilc_map, ilc_site1, tmp_path, capsys):
    from mapfilter.sensors.ilc import read_ilc

    log = ilc_site1 / "F1" / "path_data_files" / ILC_TRACE
    recording = read_ilc(log)
    t = np.linspace(recording.waypoint_t_s[0], recording.waypoint_t_s[-1], 200)
    truth = interpolate_ground_truth(recording.waypoint_t_s, recording.waypoint_xy_m, t)
    write_track_csv(Track(t, truth + [0.0, 1.0]), tmp_path / "walk.csv")
    write_track_csv(Track(t, truth + [2.0, 0.0]), tmp_path / "other" / "walk.csv")
    out = tmp_path / "view.rrd"
    code = cli_main(["view", str(ilc_map), str(tmp_path / "walk.csv"), str(tmp_path / "other" / "walk.csv"),
                     "--log", str(log), "--rerun", str(out)])
    assert code == 0
    assert "wrote" in capsys.readouterr().out
    verify(out)
    entities = read_rrd(out)
    for entity in ("/map/world/floorplan/image", "/map/world/walls/mask", "/map/world/ground_truth/waypoints",
                   "/map/world/ground_truth/path", "/map/world/tracks/walk/path", "/map/world/tracks/walk_2/path"):
        assert entity in entities, entity
    waypoints = np.array(rows(entities["/map/world/ground_truth/waypoints"], "Points2D:positions")[0])
    np.testing.assert_allclose(waypoints, recording.waypoint_xy_m, atol=1e-4)
    # each track's error against the interpolated waypoints
    for name, expected in (("walk", 1.0), ("walk_2", 2.0)):
        errors = np.array(mono_rows(entities[f"/plots/error_m/{name}"], "Scalars:scalars"))
        assert errors.size == 200
        np.testing.assert_allclose(errors, expected, atol=5e-3)  # CSV keeps mm
    # the moving position marker: one row per track sample on the trace_time timeline
    positions = entities["/map/world/tracks/walk/position"]
    assert sum(b.num_rows for b in positions if "trace_time" in b.schema.names) == 200


def test_view_cli_without_ground_truth_or_tracks(ilc_map, tmp_path):
    out = tmp_path / "map_only.rrd"
    assert cli_main(["view", str(ilc_map), "--rerun", str(out)]) == 0
    verify(out)
    entities = read_rrd(out)
    assert "/map/world/walls/mask" in entities
    assert not any(e.startswith("/map/world/tracks") for e in entities)


@pytest.mark.parametrize("problem", ["missing_track", "bad_track", "missing_map", "missing_log", "not_rrd"])
def test_view_cli_bad_inputs_are_one_line(problem, ilc_map, tmp_path, capsys):
    track = tmp_path / "walk.csv"
    track.write_text("t_s,x_m,y_m\n1.0,2.0,3.0\n")
    out = tmp_path / "out.rrd"
    args = ["view", str(ilc_map), str(track), "--rerun", str(out)]
    if problem == "missing_track":
        args[2] = str(tmp_path / "nope.csv")
    elif problem == "bad_track":
        track.write_text("t_s,x_m,y_m\n1.0,abc,3.0\n")
    elif problem == "missing_map":
        args[1] = str(tmp_path / "nope.yaml")
    elif problem == "missing_log":
        args += ["--log", str(tmp_path / "nope.txt.gz")]
    elif problem == "not_rrd":
        args[-1] = str(tmp_path / "out.png")
    assert cli_main(args) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("mapfilter: error:")
    assert "nope" in err or "abc" in err or ".rrd" in err
    assert not out.exists()


def test_view_cli_needs_a_sink(ilc_map, capsys):
    with pytest.raises(SystemExit) as exc:
        cli_main(["view", str(ilc_map)])
    assert exc.value.code == 2


def test_view_cli_subprocess_exit_code(tmp_path):
    result = subprocess.run([sys.executable, "-m", "mapfilter", "view", str(tmp_path / "nope.yaml"),
                             "--rerun", str(tmp_path / "x.rrd")], capture_output=True, text=True, timeout=60)
    assert result.returncode == 1
    assert len(result.stderr.strip().splitlines()) == 1
    assert "Traceback" not in result.stderr


def test_a_step_without_estimate_or_live_particles_is_drawn_empty(tmp_path):
    floor = small_floor(tmp_path, with_picture=False)
    report = next(synthetic_steps(floor, 1, 50, np.random.default_rng(2)))
    report.estimate_xy_m = np.array([np.nan, np.nan])
    report.estimate_std_m = float("inf")
    report.particles_weight = np.zeros(50)
    out = tmp_path / "empty.rrd"
    with make_logger(floor, rrd_path=out) as logger:
        logger.log_ground_truth(np.array([report.t_s - 1, report.t_s + 1]), np.array([[1.0, 3.0], [5.0, 3.0]]))
        logger.log_step(report)
    entities = read_rrd(out)
    assert rows(entities["/map/world/particles"], "Points2D:positions") == [[]]
    assert "/map/world/estimate/position" not in entities
    assert rows(entities["/plots/error_m/filter"], "Scalars:scalars") == []  # only its static style
    assert len(rows(entities["/map/world/ground_truth/now"], "Points2D:positions")) == 1  # the truth still shows
    verify(out)


def test_track_smooth_records_the_restarted_run_and_the_smoothed_track(tmp_path):
    """`track --smooth --rerun`: besides the causal steps, the offline track, the second forward
    pass (half its particles from the placed start), a path of as many points as the filter has
    steps, and the smoother's cloud at every step of the filter's run, beside its own cloud."""
    maps = Path(__file__).resolve().parents[2] / "maps"
    out = tmp_path / "office.rrd"
    assert cli_main(["track", str(maps / "office.yaml"), str(maps / "office_walk.txt.gz"), "--radiomap",
                     str(maps / "office_radiomap.npz"), "--smooth", "--particles", "500",
                     "--rerun", str(out)]) == 0
    entities = read_rrd(out)
    assert "/map/world/tracks/smoothed/path" in entities
    restarted = np.array(rows(entities["/map/world/tracks/restarted/path"], "LineStrips2D:strips")[0][0])
    steps = sum(b.num_rows for b in entities["/map/world/particles"] if "step" in b.schema.names)
    assert restarted.shape == (steps + 1, 2)
    # one smoothed cloud per step and one for the start (logged at the first step's time)
    clouds = rows(entities["/map/world/smoothed_particles"], "Points2D:positions")
    assert len(clouds) == steps + 1 and all(0 < len(cloud) <= 256 for cloud in clouds)
