"""The tracking config: every setting documented, YAML out and back, and bad files refused in one line."""

import dataclasses

import pytest

from mapfilter.cli import main
from mapfilter.config import TrackingConfig
from mapfilter.errors import MapfilterError
from mapfilter.settings import field_docs


def _sections(config, prefix=""):
    for field in dataclasses.fields(config):
        value = getattr(config, field.name)
        yield prefix + field.name, type(config), field.name
        if dataclasses.is_dataclass(value):
            yield from _sections(value, prefix + field.name + ".")


def test_every_setting_has_a_one_line_comment():
    undocumented = [name for name, cls, field in _sections(TrackingConfig()) if not field_docs(cls).get(field)]
    assert undocumented == []


def test_yaml_round_trip_of_a_changed_config():
    config = TrackingConfig.from_yaml("seed: 7\nsmooth: true\nmotion:\n  model: rw\n  tick_s: 0.5\n"
                                      "floors:\n  changes:\n    stairs_tread_m: [0.2, 0.3]\nwifi:\n"
                                      "  kwnn_min_rssi_dbm: null\n")
    assert (config.seed, config.smooth, config.motion.model, config.motion.tick_s) == (7, True, "rw", 0.5)
    assert config.floors.changes.stairs_tread_m == (0.2, 0.3) and config.wifi.kwnn_min_rssi_dbm is None
    assert TrackingConfig.from_yaml(config.to_yaml()) == config
    assert config.to_dict()["motion"]["model"] == "rw"
    assert TrackingConfig.from_yaml("") == TrackingConfig()


@pytest.mark.parametrize("text, needle", [
    ("seed: 1\nfilter:\n  n_partcles: 10\n", "line 3: unknown setting 'filter.n_partcles'"),
    ("smooth: yes please\n", "line 1: smooth: expected true or false"),
    ("filter:\n  n_particles: 0\n", "n_particles must be a whole number >= 1"),
    ("motion:\n  model: fly\n", "unknown motion model 'fly'"),
    ("seed: -1\n", "seed must be a whole number >= 0"),
    ("wifi: 3\n", "line 1: wifi must be a mapping"),
    ("filter: [\n", "not valid YAML"),
    ("motion:\n  tick_s: .nan\n", "expected a finite number"),
])
def test_bad_config_files_are_one_line_naming_file_and_line(tmp_path, text, needle):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(MapfilterError) as error:
        TrackingConfig.from_yaml(path)
    message = str(error.value)
    assert needle in message and str(path) in message and "\n" not in message


def test_config_show_prints_every_setting_and_a_file_back(tmp_path, capsys):
    assert main(["config", "show"]) == 0
    text = capsys.readouterr().out
    assert "n_particles: 10000  #" in text and "restart_radius_m: 5.0  #" in text
    assert TrackingConfig.from_yaml(text) == TrackingConfig()
    (tmp_path / "mine.yaml").write_text("seed: 4\n")
    assert main(["config", "show", "--config", str(tmp_path / "mine.yaml")]) == 0
    assert "seed: 4  #" in capsys.readouterr().out
    assert main(["config", "show", "--config", str(tmp_path / "missing.yaml")]) == 1
    assert "missing.yaml: file not found" in capsys.readouterr().err
