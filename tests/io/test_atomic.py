import os

import pytest

from mapfilter.io.atomic import atomic_paths


def test_files_appear_together_with_normal_permissions(tmp_path):
    a, b = tmp_path / "a.txt", tmp_path / "sub" / "b.txt"
    with atomic_paths(a, b) as (ta, tb):
        ta.write_text("A")
        tb.write_text("B")
        assert not a.exists() and not b.exists()
    assert a.read_text() == "A" and b.read_text() == "B"
    umask = os.umask(0)
    os.umask(umask)
    assert (a.stat().st_mode & 0o777) == (0o666 & ~umask)


def test_a_failure_leaves_nothing(tmp_path):
    a = tmp_path / "a.txt"
    with pytest.raises(RuntimeError):
        with atomic_paths(a) as (ta,):
            ta.write_text("half")
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_a_directory_or_a_parent_that_is_a_file_is_one_error_naming_the_final_path(tmp_path):
    from mapfilter.errors import MapfilterError

    (tmp_path / "dir").mkdir()
    (tmp_path / "file").write_text("x")
    with pytest.raises(MapfilterError, match="is a directory") as info:
        with atomic_paths(tmp_path / "dir"):
            pass
    assert info.value.path == str(tmp_path / "dir")
    with pytest.raises(MapfilterError, match="cannot write here") as info:
        with atomic_paths(tmp_path / "new" / "a.csv", tmp_path / "file" / "b.csv"):
            pass
    assert info.value.path == str(tmp_path / "file" / "b.csv")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dir", "file"]  # "new", made for a.csv, is gone


def _earlier(tmp_path):
    """An earlier run's three files."""
    files = {name: tmp_path / name for name in ("a.csv", "b.csv", "old.png")}
    for name, path in files.items():
        path.write_text(f"earlier {name}")
    return files


def test_a_multi_file_output_replaces_all_or_nothing_when_a_move_fails(tmp_path, monkeypatch):
    """The second move of a commit fails (as on a full disk): the first file is put back, the
    file marked for removal stays, and no temporary or backup is left."""
    from mapfilter.io import atomic
    from mapfilter.io.atomic import StagedFiles

    files = _earlier(tmp_path)
    staged = StagedFiles()
    with staged.writing(files["a.csv"], files["b.csv"]) as (ta, tb):
        ta.write_text("new a")
        tb.write_text("new b")
    staged.remove_at_commit(files["old.png"])
    real_replace, calls = os.replace, []

    def failing_replace(src, dst):
        calls.append(dst)
        if len(calls) == 2:
            raise OSError(28, "No space left on device")
        real_replace(src, dst)

    monkeypatch.setattr(atomic.os, "replace", failing_replace)
    with pytest.raises(OSError):
        staged.commit()
    monkeypatch.setattr(atomic.os, "replace", real_replace)
    assert {name: path.read_text() for name, path in files.items()} == {
        name: f"earlier {name}" for name in files}
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(files)


def test_a_commit_interrupted_while_removing_puts_everything_back(tmp_path, monkeypatch):
    from mapfilter.io import atomic
    from mapfilter.io.atomic import StagedFiles

    files = _earlier(tmp_path)
    staged = StagedFiles()
    with staged.writing(files["a.csv"]) as (ta,):
        ta.write_text("new a")
    staged.remove_at_commit(files["old.png"])

    def interrupted(path):
        raise KeyboardInterrupt

    monkeypatch.setattr(atomic.os, "unlink", interrupted)
    with pytest.raises(KeyboardInterrupt):
        staged.commit()
    monkeypatch.undo()
    assert files["a.csv"].read_text() == "earlier a.csv" and files["old.png"].read_text() == "earlier old.png"
    # the backups could not be unlinked here (unlink itself was what failed): only they may remain
    assert {p.name for p in tmp_path.iterdir() if not p.name.startswith(".")} == set(files)


def test_a_commit_replaces_writes_and_removes_together(tmp_path):
    from mapfilter.io.atomic import StagedFiles

    files = _earlier(tmp_path)
    with StagedFiles() as staged:
        with staged.writing(files["a.csv"], tmp_path / "new" / "c.csv") as (ta, tc):
            ta.write_text("new a")
            tc.write_text("c")
        staged.remove_at_commit(files["old.png"])
        assert files["a.csv"].read_text() == "earlier a.csv"  # nothing moves before the commit
    assert files["a.csv"].read_text() == "new a" and (tmp_path / "new" / "c.csv").read_text() == "c"
    assert not files["old.png"].exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "b.csv", "new"]


def test_a_temporary_never_marked_written_is_not_committed(tmp_path):
    """A write cut short (its block raised) is dropped; the files written before it still commit."""
    from mapfilter.io.atomic import StagedFiles

    files = _earlier(tmp_path)
    staged = StagedFiles()
    with staged.writing(files["a.csv"]) as (ta,):
        ta.write_text("new a")
    with pytest.raises(RuntimeError):
        with staged.writing(files["b.csv"]) as (tb,):
            tb.write_text("half")
            raise RuntimeError("cut")
    tmp_c = staged.stage(tmp_path / "c.csv")  # reserved, never marked written
    tmp_c.write_text("half")
    staged.commit()
    assert files["a.csv"].read_text() == "new a" and files["b.csv"].read_text() == "earlier b.csv"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(files)
