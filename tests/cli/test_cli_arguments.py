"""The command line's arguments as a newcomer types them: no prefix matching, arguments in the
wrong order, a directory where a log was meant, a track without --out."""

import gzip
import shutil

import pytest
from conftest import REPO

from mapfilter.cli import build_parser, main

MAPS = REPO / "maps"
OFFICE = MAPS / "office.yaml"
WALK = MAPS / "office_walk.txt.gz"
RADIOMAP = MAPS / "office_radiomap.npz"


def _one_line_error(capsys, args, *needles):
    assert main([str(a) for a in args]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    for needle in needles:
        assert needle in err, err
    return err


def test_every_parser_refuses_prefixes_of_options():
    from mapfilter.cli import _all_parsers

    parsers = _all_parsers(build_parser())
    assert len(parsers) > 10  # the top level, every command and every subcommand
    assert all(parser.allow_abbrev is False for parser in parsers)


@pytest.mark.parametrize("args, meant", [
    (["track", OFFICE, WALK, "--radiomap", RADIOMAP, "--particle", "500"], "--particles"),
    (["radiomap", "build", OFFICE, WALK, "--out", "x.npz", "--step"], "--steps"),
    (["map", "prepare", "plan.png", "--out", "x.yaml", "--resolut", "0.05"], "--resolution"),
])
def test_a_prefix_of_an_option_is_refused_with_the_option_meant(args, meant, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_info:
        main([str(a) for a in args])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "unrecognized arguments" in err and f"did you mean {meant}?" in err
    assert not list(tmp_path.iterdir())  # nothing ran


@pytest.fixture
def plain_walk(tmp_path):
    """The bundled walk uncompressed: a text file whose first lines are not YAML."""
    path = tmp_path / "walk.txt"
    path.write_bytes(gzip.decompress(WALK.read_bytes()))
    return path


@pytest.mark.parametrize("command", [
    ["track", "{log}", OFFICE, "--radiomap", RADIOMAP],
    ["radiomap", "build", "{log}", OFFICE, "--out", "{tmp}/rm.npz"],
    ["radiomap", "fit-aps", "{log}", OFFICE, "--out", "{tmp}/aps.csv"],
    ["radiomap", "grow", "{log}", OFFICE, "--radiomap", RADIOMAP, "--out", "{tmp}/grown.npz"],
    ["evaluate", "{log}", OFFICE, "--radiomap", RADIOMAP, "--out", "{tmp}/results"],
    ["view", "{log}", "--rerun", "{tmp}/v.rrd"],
    ["simulate", "{log}", "--out", "{tmp}/sim.txt"],
])
@pytest.mark.parametrize("log", ["plain", "gzip"])
def test_a_log_given_as_the_map_says_the_map_comes_first(command, log, plain_walk, tmp_path, capsys):
    log_path = plain_walk if log == "plain" else WALK
    args = [str(a).format(log=log_path, tmp=tmp_path) for a in command]
    _one_line_error(capsys, args, str(log_path), "is a phone log (ILC 2.0)", "the map comes first")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["walk.txt"]  # nothing written


def test_a_getsensordata_log_given_as_the_map_is_named_so(tmp_path, capsys):
    log = tmp_path / "ipin.txt"
    log.write_text("% LogFile version: 2.0\nACCE;0.01;1.0;0.1;0.2;9.8;3\nWIFI;0.5;1.0;net;aa:bb:cc:dd:ee:ff;2412;-60\n")
    _one_line_error(capsys, ["track", log, OFFICE, "--radiomap", RADIOMAP], "GetSensorData", "the map comes first")


@pytest.mark.parametrize("command", [
    ["track", WALK, OFFICE],  # both the wrong way round: the map (a log) is named first
    ["radiomap", "build", OFFICE, WALK, OFFICE, "--out", "{tmp}/rm.npz"],
    ["evaluate", OFFICE, WALK, "--survey", OFFICE, "--out", "{tmp}/r"],
    ["view", OFFICE, "--log", OFFICE, "--rerun", "{tmp}/v.rrd"],
])
def test_a_map_given_as_a_log_says_the_map_comes_first(command, tmp_path, capsys):
    args = [str(a).format(tmp=tmp_path) for a in command]
    err = _one_line_error(capsys, args, "the map comes first")
    assert "is a phone log" in err or f"{OFFICE}: is a map YAML, not a phone log" in err
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("command", [
    ["track", OFFICE, "{dir}", "--radiomap", RADIOMAP],
    ["track", OFFICE, "{dir}", WALK, "--radiomap", RADIOMAP, "--out-dir", "{tmp}/tracks"],
    ["radiomap", "build", OFFICE, "{dir}", "--out", "{tmp}/rm.npz"],
    ["evaluate", OFFICE, "{dir}", "--radiomap", RADIOMAP, "--out", "{tmp}/r"],
])
def test_a_directory_given_as_a_log_says_is_a_directory(command, tmp_path, capsys):
    logs = tmp_path / "walks"
    logs.mkdir()
    shutil.copy(WALK, logs)
    args = [str(a).format(dir=logs, tmp=tmp_path) for a in command]
    _one_line_error(capsys, args, f"{logs}: is a directory", f"{logs}/*.txt.gz")
    assert [p.name for p in tmp_path.iterdir()] == ["walks"]


def test_check_says_is_a_directory(tmp_path, capsys):
    assert main(["check", str(tmp_path)]) == 1
    assert f"{tmp_path}: is a directory" in capsys.readouterr().out


def test_track_without_out_says_no_file_was_written(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["track", str(OFFICE), str(WALK), "--radiomap", str(RADIOMAP), "--particles", "300"]) == 0
    out = capsys.readouterr().out
    assert "no track file written: give --out track.csv" in out
    assert not list(tmp_path.iterdir())
