"""Every YAML mapfilter reads goes through mapfilter.io.yamlio: bounded in size and aliases,
duplicate keys refused, encodings named."""

import time

import pytest

from mapfilter.config import TrackingConfig
from mapfilter.errors import MapfilterError
from mapfilter.maps.building import Building
from mapfilter.io.yamlio import MAX_YAML_BYTES, load_yaml

BOMB = "".join(f"{b}: &{b} [{', '.join([f'*{a}'] * 9)}]\n" for a, b in zip("abcdefgh", "bcdefghi"))
BOMB = "a: &a [x, x, x, x, x, x, x, x, x]\n" + BOMB  # i: 9^9 strings


@pytest.mark.parametrize("where", ["image: *i\nresolution: 0.1\norigin: [0, 0, 0]\n",
                                   "image: m.png\nresolution: 0.1\norigin: *i\n",
                                   "floors:\n  - name: *i\n    map: m.yaml\n    elevation_m: 0\n"])
def test_an_alias_bomb_in_a_map_or_building_is_refused_at_once(tmp_path, where):
    path = tmp_path / "bomb.yaml"
    path.write_text(BOMB + where)
    started = time.monotonic()
    with pytest.raises(MapfilterError, match="aliases stand for more than") as info:
        Building.load(path)
    assert time.monotonic() - started < 5  # composing 90 nodes; expanding would take minutes
    assert str(path) in str(info.value)


def test_an_alias_bomb_in_a_config_is_refused(tmp_path):
    path = tmp_path / "config.yaml"
    path.write_text(BOMB + "seed: *i\n")
    with pytest.raises(MapfilterError, match="aliases"):
        TrackingConfig.from_yaml(path)


def test_a_few_aliases_are_fine(tmp_path):
    path = tmp_path / "ok.yaml"
    path.write_text("a: &a [1, 2]\nb: *a\nc: {<<: {x: 1}, y: 2}\n")
    assert load_yaml(path) == {"a": [1, 2], "b": [1, 2], "c": {"x": 1, "y": 2}}


def test_a_recursive_alias_is_refused(tmp_path):
    path = tmp_path / "loop.yaml"
    path.write_text("a: &a [*a]\n")
    with pytest.raises(MapfilterError, match="contains it"):
        load_yaml(path)


def test_a_duplicate_key_names_the_file_and_both_lines(tmp_path):
    path = tmp_path / "map.yaml"
    path.write_text("image: m.png\nresolution: 0.1\norigin: [0, 0, 0]\nresolution: 0.05\n")
    with pytest.raises(MapfilterError) as info:
        Building.load(path)
    assert str(info.value) == (f"{path}:4: key 'resolution' given twice (lines 2 and 4): remove one")


def test_a_file_larger_than_the_limit_is_refused_before_it_is_parsed(tmp_path):
    path = tmp_path / "big.yaml"
    path.write_bytes(b"image: m.png\nnotes: '" + b"x" * MAX_YAML_BYTES + b"'\n")
    with pytest.raises(MapfilterError, match="larger than 4 MiB"):
        load_yaml(path)


def test_encodings(tmp_path):
    latin1 = tmp_path / "latin1.yaml"
    latin1.write_bytes("# b\xe2timent\nimage: m.png\n".encode("latin-1"))
    with pytest.raises(MapfilterError) as info:
        load_yaml(latin1)
    assert str(info.value).startswith(f"{latin1}:1: byte 0xe2 is not UTF-8") and "binary" not in str(info.value)
    utf16 = tmp_path / "utf16.yaml"
    utf16.write_bytes("image: m.png\nresolution: 0.1\n".encode("utf-16"))
    assert load_yaml(utf16) == {"image": "m.png", "resolution": 0.1}
    bom = tmp_path / "bom.yaml"
    bom.write_bytes(b"\xef\xbb\xbfimage: m.png\n")
    assert load_yaml(bom) == {"image": "m.png"}
    png = tmp_path / "plan.yaml"
    png.write_bytes(b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR")
    with pytest.raises(MapfilterError, match="an image"):
        load_yaml(png)


def test_a_400_digit_resolution_is_one_line(tmp_path):
    path = tmp_path / "map.yaml"
    path.write_text(f"image: m.png\nresolution: 1{'0' * 400}\norigin: [0, 0, 0]\n")
    with pytest.raises(MapfilterError, match="'resolution' must be a positive number"):
        Building.load(path)
