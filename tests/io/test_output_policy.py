"""The output policy (mapfilter.io.outputs): no command overwrites an input, replaces a device, a
FIFO or a link, or touches a file in an output folder that mapfilter did not write."""

import hashlib
import os
import shutil
from pathlib import Path

import pytest

from mapfilter.io.atomic import atomic_paths
from mapfilter.cli import main
from mapfilter.errors import MapfilterError
from mapfilter.io.outputs import MANIFEST, OutputDirectory, check_output_file

MAPS = Path(__file__).resolve().parents[2] / "maps"


@pytest.fixture
def user(tmp_path):
    """Copies of the bundled map, walk and radio map: a user's files."""
    for name in ("office.yaml", "office.png", "office_radiomap.npz", "office_walk.txt.gz"):
        shutil.copy(MAPS / name, tmp_path / name)
    return tmp_path


def _digests(folder: Path) -> dict:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in folder.iterdir() if p.is_file()}


@pytest.mark.parametrize("out", ["office.yaml", "office.png", "office_walk.txt.gz", "office_radiomap.npz"])
def test_track_refuses_an_output_that_is_one_of_its_inputs(user, out, capsys):
    before = _digests(user)
    code = main(["track", str(user / "office.yaml"), str(user / "office_walk.txt.gz"), "--radiomap",
                 str(user / "office_radiomap.npz"), "--out", str(user / out)])
    err = capsys.readouterr().err
    assert code == 1 and "is an input of this run" in err and err.count("\n") == 1
    assert _digests(user) == before


def test_a_hard_link_to_an_input_is_the_input(user):
    os.link(user / "office_walk.txt.gz", user / "alias.csv")
    with pytest.raises(MapfilterError, match="is an input"):
        check_output_file(user / "alias.csv", inputs=[user / "office_walk.txt.gz"])


def test_simulate_and_fit_aps_refuse_their_inputs(user, capsys):
    before = _digests(user)
    assert main(["simulate", str(user / "office.yaml"), "--out", str(user / "office.yaml")]) == 1
    assert main(["radiomap", "fit-aps", str(user / "office.yaml"), str(user / "office_walk.txt.gz"), "--out",
                 str(user / "office_walk.txt.gz")]) == 1
    assert _digests(user) == before


def test_a_fifo_a_symlink_and_a_device_are_refused_not_replaced(tmp_path):
    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "target.csv").write_text("mine")
    os.symlink(tmp_path / "target.csv", tmp_path / "link.csv")
    for name, words in (("fifo", "FIFO"), ("link.csv", "symbolic link")):
        with pytest.raises(MapfilterError, match=words):
            check_output_file(tmp_path / name)
        with pytest.raises(MapfilterError, match=words):  # the library's own writer refuses too
            with atomic_paths(tmp_path / name) as (tmp,):
                tmp.write_text("x")
    assert (tmp_path / "fifo").is_fifo() and (tmp_path / "link.csv").is_symlink()
    assert (tmp_path / "target.csv").read_text() == "mine"
    with pytest.raises(MapfilterError, match="is a device"):
        check_output_file(Path("/dev/null"))


def test_out_dash_writes_the_track_to_standard_output(capsys):
    code = main(["track", str(MAPS / "office.yaml"), str(MAPS / "office_walk.txt.gz"), "--radiomap",
                 str(MAPS / "office_radiomap.npz"), "--particles", "500", "--out", "-"])
    out, err = capsys.readouterr()
    assert code == 0
    assert out.splitlines()[0] == "t_s,x_m,y_m,std_m,heading_rad" and len(out.splitlines()) > 100
    assert "wrote standard output" in err  # the summary goes out of the track's way


def test_a_name_of_250_characters_is_written(tmp_path):
    final = tmp_path / ("t" * 246 + ".csv")
    with atomic_paths(final) as (tmp,):
        tmp.write_text("x")
    assert final.read_text() == "x"
    with pytest.raises(MapfilterError, match="more than the 255"):
        check_output_file(tmp_path / ("t" * 252 + ".csv"))


def test_an_output_directory_holding_a_users_file_is_refused_untouched(tmp_path, capsys):
    res = tmp_path / "res"
    (res / "tracks").mkdir(parents=True)
    (res / "tracks" / "my_track.csv").write_text("mine")
    code = main(["evaluate", str(MAPS / "office.yaml"), str(MAPS / "office_walk.txt.gz"), "--radiomap",
                 str(MAPS / "office_radiomap.npz"), "--methods", "kwnn", "--out", str(res)])
    assert code == 1 and "did not write (tracks/my_track.csv)" in capsys.readouterr().err
    assert (res / "tracks" / "my_track.csv").read_text() == "mine" and not (res / MANIFEST).exists()


def test_evaluate_out_dot_in_the_folder_of_its_logs_is_refused(tmp_path, monkeypatch):
    (tmp_path / "walks").mkdir()
    shutil.copy(MAPS / "office_walk.txt.gz", tmp_path / "walks" / "office_walk.txt.gz")
    monkeypatch.chdir(tmp_path)
    assert main(["evaluate", str(MAPS / "office.yaml"), "walks/office_walk.txt.gz", "--radiomap",
                 str(MAPS / "office_radiomap.npz"), "--methods", "kwnn", "--out", "."]) == 1
    assert (tmp_path / "walks" / "office_walk.txt.gz").read_bytes() == (MAPS / "office_walk.txt.gz").read_bytes()


def test_an_output_directory_clears_only_what_its_manifest_lists(tmp_path):
    out = OutputDirectory(tmp_path / "out")
    out.claim("walks/a.json").parent.mkdir(parents=True)
    (tmp_path / "out" / "walks" / "a.json").write_text("{}")
    again = OutputDirectory(tmp_path / "out")  # an earlier run's own files: accepted
    assert again.files == {"walks/a.json"}
    again.clear()
    assert not (tmp_path / "out" / "walks").exists()
    (tmp_path / "out" / "notes.txt").write_text("mine")
    with pytest.raises(MapfilterError, match=r"did not write \(notes.txt\)"):
        OutputDirectory(tmp_path / "out")


def test_a_log_named_summary_gets_its_own_track_file():
    from mapfilter.cli.track_cmd import batch_track_names

    names = batch_track_names(["summary", "walk", "config"], "csv", smooth=True)
    assert names == {"summary": "summary.track.csv", "walk": "walk.csv", "config": "config.csv"}
    assert batch_track_names(["a", "a.causal"], "csv", smooth=True)["a.causal"] == "a.causal.track.csv"


def test_an_output_directory_commits_a_run_all_or_nothing(tmp_path):
    """A second run's files are staged: nothing changes until its commit, which replaces the
    earlier run's files and removes those it did not write; a run discarded (it failed) leaves
    the earlier files and manifest byte-identical."""
    first = OutputDirectory(tmp_path / "out")
    with first.writing("walks/a.json", "summary.csv") as (a, summary):
        a.write_text("a1")
        summary.write_text("s1")
    first.commit()
    before = {p.name: p.read_bytes() for p in (tmp_path / "out").rglob("*") if p.is_file()}
    assert set(before) == {"a.json", "summary.csv", MANIFEST}

    failed = OutputDirectory(tmp_path / "out")
    failed.replace_earlier_run()
    with failed.writing("walks/b.json") as (b,):
        b.write_text("b2")
    with pytest.raises(MapfilterError, match="summary.csv: could not write: Input/output error"):
        with failed.writing("summary.csv") as (summary,):
            raise OSError(5, "Input/output error")
    failed.discard()
    assert {p.name: p.read_bytes() for p in (tmp_path / "out").rglob("*") if p.is_file()} == before

    second = OutputDirectory(tmp_path / "out")
    second.replace_earlier_run()
    with second.writing("walks/b.json", "summary.csv") as (b, summary):
        b.write_text("b2")
        summary.write_text("s2")
    assert (tmp_path / "out" / "walks" / "a.json").read_text() == "a1"  # until the commit
    second.commit()
    assert sorted(p.name for p in (tmp_path / "out").rglob("*") if p.is_file()) == [MANIFEST, "b.json", "summary.csv"]
    assert OutputDirectory(tmp_path / "out").files == {"walks/b.json", "summary.csv"}
