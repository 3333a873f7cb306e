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
                                      "floors:\n  changes:\n    anywhere_rate_per_s: 0.01\nwifi:\n"
                                      "  kwnn_min_rssi_dbm: null\n")
    assert (config.seed, config.smooth, config.motion.model, config.motion.tick_s) == (7, True, "rw", 0.5)
    assert config.floors.changes.anywhere_rate_per_s == 0.01 and config.wifi.kwnn_min_rssi_dbm is None
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
    assert "n_particles: 10000  #" in text and "lag_s: 0.0  #" in text
    assert TrackingConfig.from_yaml(text) == TrackingConfig()
    (tmp_path / "mine.yaml").write_text("seed: 4\n")
    assert main(["config", "show", "--config", str(tmp_path / "mine.yaml")]) == 0
    assert "seed: 4  #" in capsys.readouterr().out
    assert main(["config", "show", "--config", str(tmp_path / "missing.yaml")]) == 1
    assert "missing.yaml: file not found" in capsys.readouterr().err


def _removed_settings() -> dict[str, str]:
    """{dotted name: what became of it} of every setting docs/changelog.md says a release removed."""
    import re

    from tests.conftest import REPO

    text = (REPO / "docs" / "changelog.md").read_text()
    return dict(re.findall(r"^\| `([a-z_.]+)` \| (.+) \|$", text, flags=re.M))


def test_an_old_config_naming_a_removed_setting_is_refused_at_its_line_pointing_to_the_changelog(tmp_path, capsys):
    old = tmp_path / "saved.yaml"
    old.write_text("seed: 3\nmotion:\n  model: pdr\n  pdr:\n    heading_sigma_rad: 0.02\n"
                   "    turn_threshold_rad: 0.35\n  tick_s: 1.0\n")
    assert main(["config", "show", "--config", str(old)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"mapfilter: error: {old} line 6: unknown setting 'motion.pdr.turn_threshold_rad' (known "
                          "here: ") and err.endswith("; settings removed by a release: docs/changelog.md)")
    assert "\n" not in err
    with pytest.raises(MapfilterError, match=r"unknown setting 'filter.kernel' \(settings removed by a release"):
        TrackingConfig().override({"filter.kernel": 1})


def test_the_changelog_lists_the_removed_settings_and_none_is_a_setting_again():
    from mapfilter.settings import settings_to_dict

    def leaves(tree, prefix=""):
        for key, value in tree.items():
            yield from leaves(value, f"{prefix}{key}.") if isinstance(value, dict) else [prefix + key]

    removed = _removed_settings()
    assert len(removed) >= 60 and "motion.pdr.turn_threshold_rad" in removed
    assert not set(leaves(settings_to_dict(TrackingConfig()))) & set(removed)
    for fate in removed.values():
        if fate.startswith("now ") and " " not in fate[4:]:  # renamed: the new name is a setting
            TrackingConfig().override({fate[4:]: getattr_dotted(TrackingConfig(), fate[4:])})


def getattr_dotted(config, dotted: str):
    for part in dotted.split("."):
        config = getattr(config, part)
    return config


