"""The Python API: docs/api.md runs as written, equals the CLI, and the config round-trips."""

import re
import subprocess
import sys

import numpy as np
import pytest
from conftest import REPO

from mapfilter.cli import main
from mapfilter.io.tracks import read_track

MAPS = REPO / "maps"
ARGS = [str(MAPS / "office.yaml"), str(MAPS / "office_walk.txt.gz"), "--radiomap", str(MAPS / "office_radiomap.npz")]


def _api_page_code() -> str:
    return "\n".join(re.findall(r"```python\n(.*?)```", (REPO / "docs" / "api.md").read_text(), flags=re.S))


@pytest.mark.slow
def test_the_api_page_runs_and_its_causal_track_is_the_clis(tmp_path, monkeypatch):
    monkeypatch.chdir(REPO)
    namespace: dict = {}
    code = _api_page_code().replace('"office_offline.csv"', repr(str(tmp_path / "offline.csv")))
    exec(compile(code.replace('"office_beacons.csv"', repr(str(tmp_path / "beacons.csv"))), "docs/api.md", "exec"),
         namespace)
    result = namespace["result"]
    assert main(["track", *ARGS, "--seed", "3", "--smooth", "--out", str(tmp_path / "cli.csv")]) == 0
    causal = read_track(tmp_path / "cli.causal.csv")
    offline = read_track(tmp_path / "cli.csv")
    np.testing.assert_allclose(causal.xy_m, result.causal.xy_m, atol=5e-4)  # CSV keeps millimetres
    np.testing.assert_allclose(offline.xy_m, result.offline.xy_m, atol=5e-4)
    assert read_track(tmp_path / "offline.csv").xy_m.shape == result.offline.xy_m.shape
    assert namespace["evaluation"].summary_rows()[0]["method"] == "pf"
    assert namespace["beacons"].beacon_id == ["AA:BB:CC:00:00:01", "AA:BB:CC:00:00:02"]
    np.testing.assert_array_equal(namespace["both"].causal.xy_m, result.causal.xy_m)  # no readings: the same track


def test_import_mapfilter_is_cheap_and_names_the_api():
    code = ("import sys, mapfilter as mf\nheavy = [m for m in ('numpy', 'numba', 'scipy') if m in sys.modules]\n"
            "print(heavy, 'track' in dir(mf), mf.__version__)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split("]")[0] == "[" and "True" in out


def test_config_show_read_back_with_config_gives_the_identical_track(tmp_path, capsys):
    assert main(["config", "show"]) == 0
    (tmp_path / "defaults.yaml").write_text(capsys.readouterr().out)
    paths = [tmp_path / "plain.csv", tmp_path / "from_file.csv"]
    assert main(["track", *ARGS, "--particles", "2000", "--out", str(paths[0])]) == 0
    assert main(["track", *ARGS, "--config", str(tmp_path / "defaults.yaml"), "--particles", "2000",
                 "--out", str(paths[1])]) == 0
    assert paths[0].read_bytes() == paths[1].read_bytes()


def test_flags_override_the_config_file(tmp_path, capsys):
    import mapfilter as mf

    (tmp_path / "c.yaml").write_text("seed: 5\nfilter:\n  n_particles: 1500\nmotion:\n  model: cv\n")
    namespace = __import__("argparse").Namespace
    from mapfilter.cli.tracking_options import tracking_config_from

    args = namespace(config=tmp_path / "c.yaml", motion=None, particles=1000, seed=None, smooth=None, no_map=None,
                     fingerprint_model=None, adapt=None, adapt_rssi_limit=None, no_blocking_compensation=None)
    config = tracking_config_from(args)
    assert (config.seed, config.filter.n_particles, config.motion.model) == (5, 1000, "cv")
    assert config == mf.TrackingConfig.from_yaml(config.to_yaml())


# ---- an even API: each function takes the others' results and paths; other types are a TypeError
OFFICE, WALK, RADIOMAP = MAPS / "office.yaml", MAPS / "office_walk.txt.gz", MAPS / "office_radiomap.npz"


def _summary(evaluation):
    return [(row["method"], round(row["mean"], 6), row["n"]) for row in evaluation.summary_rows()]


def test_evaluate_takes_a_radio_map_and_recordings_as_well_as_paths():
    import mapfilter as mf

    config = mf.TrackingConfig(seed=2).with_particles(500)
    by_path = mf.evaluate(str(OFFICE), [WALK], radio_map=str(RADIOMAP), methods=["pf", "kwnn"], config=config)
    by_object = mf.evaluate(mf.load_map(OFFICE), [mf.read_log(WALK)], radio_map=mf.load_radio_map(RADIOMAP),
                            methods=["pf", "kwnn"], config=config)
    assert [m for m, _, _ in _summary(by_object)] == ["pf", "kwnn"]
    assert _summary(by_object) == _summary(by_path)
    assert not by_object.failed


def test_evaluate_takes_recordings_as_survey_walks(tmp_path):
    import shutil

    import mapfilter as mf

    survey_path = tmp_path / "survey_walk.txt.gz"  # the same walk under another name: a survey
    shutil.copy(WALK, survey_path)
    by_path = mf.evaluate(OFFICE, [WALK], survey=[survey_path], methods=["kwnn", "kf"])
    by_object = mf.evaluate(OFFICE, [mf.read_log(WALK)], survey=[mf.read_log(survey_path)], methods=["kwnn", "kf"])
    assert _summary(by_object) == _summary(by_path) and by_object.summary_rows()[0]["n"] > 100


def test_track_takes_paths_as_well_as_objects():
    import mapfilter as mf

    config = mf.TrackingConfig(seed=4).with_particles(500)
    by_path = mf.track(str(OFFICE), WALK, radio_map=RADIOMAP, config=config)
    by_object = mf.track(mf.load_map(OFFICE), mf.read_log(WALK), radio_map=mf.load_radio_map(RADIOMAP), config=config)
    np.testing.assert_array_equal(by_path.causal.xy_m, by_object.causal.xy_m)
    grown, report = mf.grow_radio_map(OFFICE, RADIOMAP, [WALK], config=config, grow=mf.GrowConfig(max_iterations=1))
    assert report.points > 0 and len(grown) > len(mf.load_radio_map(RADIOMAP))
    assert len(mf.build_radio_map(str(OFFICE), [WALK])) > 0


def _walk():
    import mapfilter as mf

    return mf.read_log(WALK)


@pytest.mark.parametrize("call, argument, got", [
    (lambda mf: mf.track(OFFICE, None, radio_map=RADIOMAP), "recording", "None"),
    (lambda mf: mf.track({"map": "office"}, WALK, radio_map=RADIOMAP), "building", "dict"),
    (lambda mf: mf.track(OFFICE, _walk(), radio_map=RADIOMAP, config={"seed": 3}), "config", "dict"),
    (lambda mf: mf.track(OFFICE, _walk(), radio_map=3), "radio_map", "int"),
    (lambda mf: mf.track(OFFICE, _walk(), access_points=["ap"]), "access_points", "list"),
    (lambda mf: mf.track(OFFICE, _walk(), radio_map=RADIOMAP, rng=3), "rng", "int"),
    (lambda mf: mf.evaluate(OFFICE, [WALK], radio_map=mf.load_map(OFFICE)), "radio_map", "Building"),
    (lambda mf: mf.evaluate(OFFICE, str(WALK), radio_map=RADIOMAP), "logs", "str"),
    (lambda mf: mf.evaluate(OFFICE, [WALK, None], radio_map=RADIOMAP), "logs[1]", "None"),
    (lambda mf: mf.evaluate(OFFICE, [WALK], survey=[1.5]), "survey[0]", "float"),
    (lambda mf: mf.evaluate(OFFICE, [WALK], radio_map=RADIOMAP, config="seed: 3"), "config", "str"),
    (lambda mf: mf.evaluate(OFFICE, [WALK], radio_map=RADIOMAP, jobs="2"), "jobs", "str"),
    (lambda mf: mf.build_radio_map(OFFICE, _walk()), "recordings", "Recording"),
    (lambda mf: mf.build_radio_map(None, [WALK]), "building", "None"),
    (lambda mf: mf.grow_radio_map(OFFICE, None, [WALK]), "radio_map", "None"),
    (lambda mf: mf.grow_radio_map(OFFICE, RADIOMAP, [WALK], config=mf.GrowConfig()), "config", "GrowConfig"),
    (lambda mf: mf.read_log(None), "path", "None"),
    (lambda mf: mf.read_log(WALK, building=42), "building", "int"),
    (lambda mf: mf.load_map(mf.load_map(OFFICE)), "path", "Building"),
    (lambda mf: mf.load_radio_map({"points": []}), "path", "dict"),
    (lambda mf: mf.enter_trial("http://127.0.0.1:9/evaalapi/", "t", None, radio_map=RADIOMAP), "building", "None"),
    (lambda mf: mf.enter_trial("http://127.0.0.1:9/evaalapi/", "t", OFFICE, radio_map=3), "radio_map", "int"),
])
def test_a_wrong_type_is_a_one_line_type_error_naming_the_argument(call, argument, got):
    import mapfilter as mf

    with pytest.raises(TypeError) as info:
        call(mf)
    message = str(info.value)
    assert message.startswith(f"{argument}: expected ") and message.endswith(f"got {got}"), message
    assert "\n" not in message


def test_a_log_loaded_as_a_map_and_a_map_read_as_a_log_say_so():
    import mapfilter as mf
    from mapfilter.errors import MapfilterError

    with pytest.raises(MapfilterError, match="is a phone log .* not a map: load it with mf.read_log"):
        mf.load_map(WALK)
    with pytest.raises(MapfilterError, match="is a map YAML, not a phone log: load it with mf.load_map"):
        mf.read_log(OFFICE)


def test_a_sections_setting_given_flat_to_tracking_config_says_where_it_lives():
    """`mf.TrackingConfig(n_particles=2000)` was a bare "unexpected keyword argument"."""
    import mapfilter as mf

    with pytest.raises(TypeError, match=r"it is the setting filter\.n_particles; give "
                                        r"TrackingConfig\(\)\.with_particles\(2000\)"):
        mf.TrackingConfig(n_particles=2000)
    with pytest.raises(TypeError, match=r"override\(\{'motion\.model': 'cv'\}\)"):
        mf.TrackingConfig(seed=2, model="cv")
    with pytest.raises(TypeError, match="did you mean 'n_particles'"):
        mf.TrackingConfig(n_partcles=5)
    config = mf.TrackingConfig(smooth=True, seed=3)  # its own settings, as before
    assert config.smooth and config.seed == 3 and config.with_particles(2000).filter.n_particles == 2000


def test_score_gives_one_tracks_errors_as_evaluate_scores_it():
    """`mf.score(track, recording, building)`: the numbers of evaluate's per-walk table for the
    same track, each method scored at its own waypoints, causal (latest row at each waypoint) and
    offline (interpolated)."""
    import mapfilter as mf

    building, walk = mf.load_map(MAPS / "office.yaml"), mf.read_log(MAPS / "office_walk.txt.gz")
    evaluation = mf.evaluate(building, [walk], radio_map=MAPS / "office_radiomap.npz", methods=["pf", "kwnn"],
                             config=mf.TrackingConfig(smooth=True).with_particles(500), waypoints="own")
    rows = {row["method"]: row for row in evaluation.trace_rows()}
    checked = set()
    for result in evaluation.results:
        scores = mf.score(result.track, walk, building, causal=result.causal)
        for key in ("mean", "median", "p75", "p90", "ce95", "max", "rmse", "n", "missed", "availability",
                    "wall_crossings"):
            assert scores[key] == rows[result.method][key], (result.method, key)
        np.testing.assert_array_equal(scores["errors_m"], result.errors_m)
        checked.add(result.method)
    assert {"pf", "pf-smooth", "kwnn"} <= checked
    assert mf.score(evaluation.results[0].track, MAPS / "office_walk.txt.gz", MAPS / "office.yaml")["n"] > 100


def test_python_in_the_folder_holding_a_clone_named_mapfilter_imports_the_package(tmp_path):
    """`python` started beside a clone folder named mapfilter (no __init__.py at its top) took
    that folder for a namespace package: the install puts its own finder first."""
    clone = tmp_path / "mapfilter"
    (clone / "docs").mkdir(parents=True)
    (clone / "README.md").write_text("a clone\n")
    done = subprocess.run([sys.executable, "-c", "import mapfilter; print(mapfilter.__file__); mapfilter.load_map"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().endswith("__init__.py")
