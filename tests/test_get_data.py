"""tools/get_data.py: the real data laid out as ../shared/data from local copies of the two
public sources (these machines cannot download: the download step is fed file:// URLs), with
the manifest's checksums."""

import gzip
import hashlib
import json
import shutil
import sys
import zipfile
from pathlib import Path

import pytest
from conftest import REPO

sys.path.insert(0, str(REPO / "tools"))
import get_data  # noqa: E402

DATA = REPO.parent / "shared" / "data"
IPIN_LOGS = "01 Logfiles/01 IPIN2023_T3_TrainingTrials (training)"
IPIN_PLANS = "02 Supplementary Materials/01 - Calibration Floormaps"
SUBSET = ["ilc20/LICENSE", "ilc20/README.md", "ilc20/site1/F2/*", "ipin2023/README.md", "ipin2023/plans/*",
          "ipin2023/BLE_Locations.csv", "ipin2023/logs/*Trial01_repetition0[12]*"]


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _original(laid_out: Path, extra: bytes) -> bytes:
    """A trace as the source would have it: the laid-out content with records of types the
    layout drops mixed in (after the header and near the end)."""
    lines = gzip.decompress(laid_out.read_bytes()).splitlines(keepends=True)
    t = next(line.split(b"\t")[0] for line in lines if not line.startswith(b"#"))
    dropped = [t + b"\t" + extra + b"\t0.1\t0.2\t0.3\t3\n", t + b"\tTYPE_GAME_ROTATION_VECTOR\t0.1\t0.2\t0.3\n"]
    return b"".join(lines[:4] + dropped + lines[4:-2] + dropped + lines[-2:])


def _sources(rows, into: Path) -> tuple[Path, Path]:
    """Local copies of the two sources for ``rows``, in their own layouts: the ILC repository's
    (data/site1/...) and the IPIN package's folders, with a trial the layout does not keep."""
    ilc, ipin = into / "indoor-location-competition-20", into / "IPIN2023_T3"
    for row in rows:
        laid_out = DATA / row["path"]
        if row["source"] == "ilc":
            target = ilc / row["source_path"]
            target.parent.mkdir(parents=True, exist_ok=True)
            if row["path"].endswith(".gz"):
                # WiFi-only traces come with the IMU rows the layout drops
                target.write_bytes(_original(laid_out, b"TYPE_ACCELEROMETER" if row["transform"].endswith(":wifi")
                                             else b"TYPE_MAGNETIC_FIELD_UNCALIBRATED"))
            else:
                shutil.copyfile(laid_out, target)
        elif row["source"] == "ipin":
            log = row["path"].endswith(".gz")
            folder = ipin / (IPIN_LOGS if log else IPIN_PLANS)
            folder.mkdir(parents=True, exist_ok=True)
            data = gzip.decompress(laid_out.read_bytes()) if log else laid_out.read_bytes()
            (folder / row["source_path"]).write_bytes(data)
    (ipin / IPIN_LOGS / "IPIN2023_T3_TrainingTrial04_repetition01.txt").write_text("% not kept\n")
    return ilc, ipin


def _subset_rows():
    import fnmatch

    return [r for r in get_data.read_manifest() if any(fnmatch.fnmatch(r["path"], p) for p in SUBSET)]


def _only() -> list[str]:
    return [arg for pattern in SUBSET for arg in ("--only", pattern)]


@pytest.fixture
def local_sources(ilc_site1, ipin2023, tmp_path):
    return _sources(_subset_rows(), tmp_path / "sources")


def test_the_manifest_holds_the_shared_data_with_its_checksums(ilc_site1, ipin2023, capsys):
    rows = get_data.read_manifest()
    shared = sorted(p.relative_to(DATA).as_posix() for p in DATA.rglob("*") if p.is_file())
    assert sorted(r["path"] for r in rows) == shared
    assert get_data.main(["--verify", str(DATA)]) == 0
    assert f"verified {len(rows)} of {len(rows)} files" in capsys.readouterr().out


def test_local_copies_are_laid_out_byte_for_byte(local_sources, tmp_path, capsys):
    ilc, ipin = local_sources
    out = tmp_path / "data"
    assert get_data.main(["--out", str(out), "--ilc-from", str(ilc), "--ipin-from", str(ipin), *_only()]) == 0
    rows = _subset_rows()
    assert len(rows) == 40 + 3 + 2 + 2 + 2 + 3 + 1  # F2's traces, floor files, ...
    laid_out = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file())
    assert laid_out == sorted(r["path"] for r in rows)
    for row in rows:
        assert _sha(out / row["path"]) == row["sha256"] == _sha(DATA / row["path"]), row["path"]
    printed = capsys.readouterr().out
    assert f"laid out {len(rows)} files" in printed and f"verified {len(rows)} of {len(rows)}" in printed
    # a second run keeps what is right and writes nothing
    assert get_data.main(["--out", str(out), "--ilc-from", str(ilc), "--ipin-from", str(ipin), *_only()]) == 0
    assert f"laid out 0 files ({len(rows)} already there)" in capsys.readouterr().out


def test_one_from_dir_holds_both_sources(local_sources, tmp_path, capsys):
    out = tmp_path / "data"
    from_dir = local_sources[0].parent
    assert get_data.main(["--out", str(out), "--from-dir", str(from_dir), *_only()]) == 0


def test_verify_names_a_changed_file_and_a_recompressed_one(local_sources, tmp_path, capsys):
    ilc, ipin = local_sources
    out = tmp_path / "data"
    assert get_data.main(["--out", str(out), "--from-dir", str(ilc.parent), *_only()]) == 0
    capsys.readouterr()
    changed = out / "ipin2023" / "plans" / "references.csv"
    changed.write_bytes(changed.read_bytes() + b"\n")
    trace = next((out / "ilc20" / "site1" / "F2" / "path_data_files").glob("*.txt.gz"))
    trace.write_bytes(gzip.compress(gzip.decompress(trace.read_bytes()), compresslevel=1, mtime=0))
    assert get_data.main(["--verify", str(out), *_only()]) == 1
    err = capsys.readouterr().err.splitlines()
    assert any(line.startswith(f"{changed}: SHA-256 ") for line in err)
    assert f"{trace}: the content is right but compressed otherwise (another zlib?)" in err
    # and a run does not write over a file with another checksum
    before = changed.read_bytes()
    assert get_data.main(["--out", str(out), "--from-dir", str(ilc.parent), *_only()]) == 1
    assert "exists with another checksum: not overwritten" in capsys.readouterr().err
    assert changed.read_bytes() == before


def test_a_missing_source_file_is_one_line(local_sources, tmp_path, capsys):
    ilc, ipin = local_sources
    next((ilc / "data" / "site1" / "F2" / "path_data_files").glob("*.txt")).unlink()
    assert get_data.main(["--out", str(tmp_path / "data"), "--from-dir", str(ilc.parent), *_only()]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("get_data: error: data/site1/F2/path_data_files/")
    assert "not found under" in err


def test_the_download_step_fetches_each_source_file(ilc_site1, ipin2023, local_sources, tmp_path, monkeypatch,
                                                    capsys):
    """The download step fed file:// URLs: the ILC files one by one at the repository's commit,
    the Zenodo record's listing and a zip archive of the package (MD5 checked, unpacked)."""
    ilc, ipin = local_sources
    monkeypatch.setattr(get_data, "ILC_RAW_URL", ilc.as_uri() + "/{path}")
    package = tmp_path / "zenodo" / "IPIN2023_T3.zip"
    package.parent.mkdir()
    with zipfile.ZipFile(package, "w") as archive:
        for path in ipin.rglob("*"):
            if path.is_file():
                archive.write(path, path.relative_to(ipin).as_posix())
    md5 = hashlib.md5(package.read_bytes()).hexdigest()
    listing = tmp_path / "zenodo" / "record.json"
    listing.write_text(json.dumps({"files": [{"key": package.name, "size": package.stat().st_size,
                                              "checksum": f"md5:{md5}", "links": {"self": package.as_uri()}}]}))
    monkeypatch.setattr(get_data, "ZENODO_API_URL", listing.as_uri())
    out = tmp_path / "data"
    assert get_data.main(["--out", str(out), *_only()]) == 0
    assert (out / ".downloads" / "ilc" / "data" / "site1" / "F2" / "floor_info.json").is_file()
    for row in _subset_rows():
        assert _sha(out / row["path"]) == row["sha256"]
    # a download whose MD5 is not the record's is refused
    listing.write_text(listing.read_text().replace(md5, "0" * 32))
    shutil.rmtree(out)
    assert get_data.main(["--out", str(out), *_only()]) == 1
    assert "MD5" in capsys.readouterr().err


@pytest.mark.slow
def test_everything_laid_out_from_local_copies_is_the_shared_data(ilc_site1, ipin2023, tmp_path):
    rows = get_data.read_manifest()
    ilc, ipin = _sources(rows, tmp_path / "sources")
    out = tmp_path / "data"
    assert get_data.main(["--out", str(out), "--ilc-from", str(ilc), "--ipin-from", str(ipin)]) == 0
    for row in rows:
        assert _sha(out / row["path"]) == _sha(DATA / row["path"]), row["path"]
