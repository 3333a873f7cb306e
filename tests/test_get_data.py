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


# ---- hostile sources (issue 45) -------------------------------------------------------------------
LOG_ROW = "ipin2023/logs/IPIN2023_T3_TrainingTrial01_repetition01.txt.gz"


@pytest.fixture
def one_log(ipin2023, tmp_path):
    """(the manifest row of one IPIN log, a folder holding its source: the log uncompressed)."""
    row = next(r for r in get_data.read_manifest() if r["path"] == LOG_ROW)
    source = tmp_path / "sources"
    source.mkdir()
    (source / row["source_path"]).write_bytes(gzip.decompress((DATA / LOG_ROW).read_bytes()))
    return row, source


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.rglob(".*") if p.is_file())


@pytest.mark.parametrize("damage", ["corrupted", "linked"])
def test_a_bad_source_is_refused_before_it_is_laid_out(one_log, tmp_path, capsys, damage):
    """A source with one byte changed, or a link to another file, is refused in one line and
    nothing is written, so that a run with the right source then lays it out."""
    row, source = one_log
    log = source / row["source_path"]
    good = log.read_bytes()
    if damage == "corrupted":
        log.write_bytes(good[:1000] + b"X" + good[1001:])
    else:
        log.unlink()
        (tmp_path / "other.txt").write_bytes(good[:-10])
        log.symlink_to(tmp_path / "other.txt")
    out = tmp_path / "data"
    assert get_data.main(["--out", str(out), "--from-dir", str(source), "--only", LOG_ROW]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "is not the source of " + LOG_ROW in err and "nothing written" in err
    assert not (out / LOG_ROW).exists() and _leftovers(tmp_path) == []
    log.unlink()
    log.write_bytes(good)
    assert get_data.main(["--out", str(out), "--from-dir", str(source), "--only", LOG_ROW]) == 0
    assert _sha(out / LOG_ROW) == row["sha256"]


def test_a_full_disk_leaves_no_temporary(one_log, tmp_path):
    """A file-size limit makes the write fail (EFBIG, as a full disk): one line, no temporary."""
    import resource
    import subprocess

    row, source = one_log
    out = tmp_path / "data"

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (100_000, 100_000))

    done = subprocess.run([sys.executable, str(REPO / "tools" / "get_data.py"), "--out", str(out), "--from-dir",
                           str(source), "--only", LOG_ROW], preexec_fn=limit, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 1 and done.stderr.startswith("get_data: error: [Errno 27] File too large")
    assert len(done.stderr.strip().splitlines()) == 1 and "Traceback" not in done.stderr
    assert not (out / LOG_ROW).exists() and _leftovers(tmp_path) == []


class _Zenodo:
    """A Zenodo record on 127.0.0.1: ``files`` maps a URL path to (bytes sent, Content-Length
    announced); ``/record`` is the listing ``listing`` (a list of the record's file entries)."""

    def __init__(self, files: dict[str, tuple[bytes, int]], listing: list[dict]) -> None:
        import http.server
        import threading

        zenodo = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self):  # noqa: N802 - the http.server name
                if self.path == "/record":
                    body = json.dumps({"files": zenodo.listing}).encode()
                    length = len(body)
                else:
                    body, length = zenodo.files[self.path]
                self.send_response(200)
                self.send_header("Content-Length", str(length))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *args):
                pass

        self.files, self.listing = files, listing
        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


def _package(row, source: Path) -> bytes:
    import io

    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.write(source / row["source_path"], f"logs/{row['source_path']}")
    return buffer.getvalue()


@pytest.mark.parametrize("name", ["../../victim.txt", "/tmp/mapfilter-get-data-victim.txt", "a/../../b.zip"])
def test_a_record_file_name_that_leaves_the_folder_is_refused(one_log, tmp_path, monkeypatch, capsys, name):
    row, source = one_log
    victim = tmp_path / "victim.txt"
    victim.write_text("the user's own file")
    zenodo = _Zenodo({"/f": (b"overwritten", 11)}, [{"key": name, "size": 11, "links": {"self": "URL/f"}}])
    zenodo.listing[0]["links"]["self"] = zenodo.url + "/f"
    monkeypatch.setattr(get_data, "ZENODO_API_URL", zenodo.url + "/record")
    try:
        out = tmp_path / "deep" / "data"
        assert get_data.main(["--out", str(out), "--only", LOG_ROW]) == 1
    finally:
        zenodo.close()
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"the record's file {name!r} would leave its folder" in err, err
    assert victim.read_text() == "the user's own file" and not Path("/tmp/mapfilter-get-data-victim.txt").exists()


def test_a_download_shorter_than_announced_is_refused_and_not_kept(one_log, tmp_path, monkeypatch, capsys):
    row, source = one_log
    package = _package(row, source)
    zenodo = _Zenodo({"/p.zip": (package[:len(package) // 2], len(package))}, [])
    zenodo.listing.append({"key": "p.zip", "size": len(package), "links": {"self": zenodo.url + "/p.zip"}})
    monkeypatch.setattr(get_data, "ZENODO_API_URL", zenodo.url + "/record")
    out = tmp_path / "data"
    try:
        assert get_data.main(["--out", str(out), "--only", LOG_ROW]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert err[-1].startswith("get_data: error: ") and "bytes received" in err[-1] and "cut short" in err[-1]
        assert not (out / ".downloads" / "ipin" / "p.zip").exists() and _leftovers(tmp_path) == []
        zenodo.files["/p.zip"] = (package, len(package))  # the next run downloads it whole
        assert get_data.main(["--out", str(out), "--only", LOG_ROW]) == 0
    finally:
        zenodo.close()
    assert _sha(out / LOG_ROW) == row["sha256"]


def test_a_half_downloaded_package_is_one_line_and_removed(one_log, tmp_path, monkeypatch, capsys):
    """A record that gives neither size nor MD5, and a package cut in half: the unpacking fails in
    one line and the bad file is removed, so that the next run downloads it again."""
    row, source = one_log
    package = _package(row, source)
    half = package[:len(package) // 2]
    zenodo = _Zenodo({"/p.zip": (half, len(half))}, [])
    zenodo.listing.append({"key": "p.zip", "links": {"self": zenodo.url + "/p.zip"}})
    monkeypatch.setattr(get_data, "ZENODO_API_URL", zenodo.url + "/record")
    out = tmp_path / "data"
    try:
        assert get_data.main(["--out", str(out), "--only", LOG_ROW]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert "p.zip: not a whole zip archive" in err[-1] and "Traceback" not in "".join(err)
        assert not (out / ".downloads" / "ipin" / "p.zip").exists() and _leftovers(tmp_path) == []
        zenodo.files["/p.zip"] = (package, len(package))
        assert get_data.main(["--out", str(out), "--only", LOG_ROW]) == 0
    finally:
        zenodo.close()
