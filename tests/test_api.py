"""The Python API: docs/api.md runs as written, equals the CLI, and the config round-trips."""

import re
import subprocess
import sys

import numpy as np
from conftest import REPO

from mapfilter.cli import main
from mapfilter.trackio import read_track

MAPS = REPO / "maps"
ARGS = [str(MAPS / "office.yaml"), str(MAPS / "office_walk.txt.gz"), "--radiomap", str(MAPS / "office_radiomap.npz")]


def _api_page_code() -> str:
    return "\n".join(re.findall(r"```python\n(.*?)```", (REPO / "docs" / "api.md").read_text(), flags=re.S))


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
