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
