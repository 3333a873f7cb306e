#!/usr/bin/env python3
"""Get the real data the tests, docs/results.md and docs/ipin.md use, laid out as ../shared/data.

Two public sources (docs/data.md):

- the ILC 2.0 sample: GitHub repository location-competition/indoor-location-competition-20 at
  commit 8ab177cd7be2700442714b7d13fa452bedc685f5, folder data/site1 (MIT licence, XYZ10);
- the IPIN 2023 competition package, Track 3: Zenodo record 8362205 (Torres-Sospedra et al.,
  doi:10.5281/zenodo.8362205; cite it when you use the data).

Three steps, each its own function: **get** the source files (downloaded, or taken from local
copies with --ilc-from / --ipin-from / --from-dir, where they may lie in any folder layout),
**lay out** the files the manifest names (`tools/data/manifest.csv`: ILC traces keep the
record types the project uses and are gzip-compressed, IPIN logs are gzip-compressed whole,
plans and floor files are copied, and the project's own notes come from `tools/data/`), and
**verify** every file's SHA-256 against the manifest. A file already there with the right
checksum is kept; one with another checksum is refused, never overwritten. Every file is checked
before it is laid out (a damaged or wrong source is refused, nothing written); a download must
hold every byte its Content-Length and the record announce, and its MD5 where the record gives
one (a cached download is checked again before use, and a bad one removed); a file name that
would leave its folder (absolute, or with ``..``) is refused; a failed write leaves no temporary.

    python3 tools/get_data.py                                  # download into ../shared/data
    python3 tools/get_data.py --out data --from-dir ~/downloads # from local copies, no network
    python3 tools/get_data.py --verify ../shared/data          # checksums only

Standard library only: it runs before the package is installed.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import fnmatch
import gzip
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import urllib.request
import zipfile
import zlib
from collections.abc import Iterable, Iterator
from pathlib import Path, PurePosixPath

REPO = Path(__file__).resolve().parents[1]
MANIFEST = REPO / "tools" / "data" / "manifest.csv"
PROJECT_FILES = REPO / "tools" / "data"
DEFAULT_OUT = REPO.parent / "shared" / "data"

ILC_REPOSITORY = "location-competition/indoor-location-competition-20"
ILC_COMMIT = "8ab177cd7be2700442714b7d13fa452bedc685f5"
ILC_RAW_URL = f"https://raw.githubusercontent.com/{ILC_REPOSITORY}/{ILC_COMMIT}/{{path}}"
ZENODO_RECORD = "8362205"
ZENODO_API_URL = f"https://zenodo.org/api/records/{ZENODO_RECORD}"

# The ILC record types each kind of trace keeps (the rest of a trace is dropped; '#' header
# lines are always kept): "full" for the walks with IMU, "wifi" for the WiFi-only ones.
ILC_KEEP = {
    "full": {b"TYPE_WAYPOINT", b"TYPE_ACCELEROMETER", b"TYPE_GYROSCOPE", b"TYPE_ROTATION_VECTOR",
             b"TYPE_MAGNETIC_FIELD", b"TYPE_WIFI", b"TYPE_BEACON"},
    "wifi": {b"TYPE_WAYPOINT", b"TYPE_WIFI"},
}
MANIFEST_COLUMNS = ("path", "sha256", "content_sha256", "source", "source_path", "transform")


class DataError(Exception):
    """What went wrong, in one line (the script prints it and exits 1)."""


# ---- the manifest -----------------------------------------------------------------------------
def read_manifest(path: Path = MANIFEST) -> list[dict[str, str]]:
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def sha256_of(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def inside(name: str, what: str) -> str:
    """``name`` when it is a relative path that stays in its folder (no ``..``, not absolute, no
    drive or backslash); ``DataError`` naming ``what`` otherwise."""
    parts = PurePosixPath(name).parts
    if (not name or "\0" in name or "\\" in name or name.startswith("/") or ".." in parts
            or (parts and ":" in parts[0])):
        raise DataError(f"{what} {name!r} would leave its folder (an absolute path, or one with ..): refused")
    return name


def write_new(path: Path, blocks: Iterable[bytes]) -> None:
    """``blocks`` to ``path`` through a temporary beside it, moved into place at the end; on any
    failure (a full disk, Ctrl-C) the temporary is removed and ``path`` is untouched."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(fd, "wb") as handle:
            for block in blocks:
                handle.write(block)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


# ---- step 1: get the source files ----------------------------------------------------------------
def find_source(roots: list[Path], source_path: str) -> Path:
    """The local copy of a source file: ``source_path`` under one of ``roots``, or (the layout
    of a local copy is free) the one file under them whose path ends with the source path's
    last parts (ILC: ``site1/F1/path_data_files/<id>.txt``; IPIN: the file name)."""
    parts = Path(source_path).parts
    for root in roots:
        if (root / source_path).is_file():
            return root / source_path
    tail = parts[-4:] if parts[0] == "data" else parts[-1:]
    found = [p for root in roots for p in _files_named(root, tail[-1]) if p.parts[-len(tail):] == tail]
    if len(found) == 1:
        return found[0]
    if not found:
        raise DataError(f"{source_path}: not found under {', '.join(map(str, roots))}")
    raise DataError(f"{source_path}: {len(found)} copies under {', '.join(map(str, roots))}: keep one")


_NAME_INDEX: dict[Path, dict[str, list[Path]]] = {}


def _files_named(root: Path, name: str) -> list[Path]:
    if root not in _NAME_INDEX:
        index: dict[str, list[Path]] = {}
        for path in root.rglob("*"):
            if path.is_file():
                index.setdefault(path.name, []).append(path)
        _NAME_INDEX[root] = index
    return _NAME_INDEX[root].get(name, [])


def download(url: str, path: Path, md5: str | None = None, size: int | None = None) -> None:
    """``url`` to ``path`` (atomically), refused when it holds fewer or more bytes than its
    Content-Length (or ``size``), or another MD5 than ``md5`` (when the source publishes them)."""
    digest = hashlib.md5()
    received = 0
    declared: list[int] = []

    def blocks() -> Iterator[bytes]:
        nonlocal received
        with urllib.request.urlopen(url, timeout=120) as response:
            length = (response.headers.get("Content-Length") or "").strip()
            if length.isdigit():
                declared.append(int(length))
            for block in iter(lambda: response.read(1 << 20), b""):
                digest.update(block)
                received += len(block)
                yield block
        for expected in declared + ([] if size is None else [size]):
            if received != expected:
                raise DataError(f"{url}: {received} bytes received, {expected} announced: the download was cut short "
                                "(run again)")
        if md5 is not None and digest.hexdigest() != md5:
            raise DataError(f"{url}: MD5 {digest.hexdigest()}, the source publishes {md5}")

    write_new(path, blocks())


def _cached_ok(path: Path, md5: str | None, size: int | None) -> bool:
    """A download kept from an earlier run is whole: its size and MD5 (where the record gives them)."""
    if size is not None and path.stat().st_size != size:
        return False
    if md5 is not None:
        digest = hashlib.md5()
        with path.open("rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
        return digest.hexdigest() == md5
    return True


def download_ilc(rows: list[dict[str, str]], into: Path) -> Path:
    """The ILC files of ``rows`` from the repository at its commit, one file each, into ``into``."""
    for row in rows:
        target = into / inside(row["source_path"], "the manifest's source path")
        if not target.is_file():
            print(f"download {row['source_path']}", file=sys.stderr)
            download(ILC_RAW_URL.format(path=row["source_path"]), target)
    return into


def download_ipin(into: Path) -> Path:
    """Every file of the Zenodo record (MD5 and size checked) into ``into``, zip archives unpacked."""
    with urllib.request.urlopen(ZENODO_API_URL, timeout=60) as response:
        try:
            record = json.loads(response.read(16 << 20))
        except ValueError:
            raise DataError(f"{ZENODO_API_URL}: the record's listing is not JSON") from None
    files = record.get("files") if isinstance(record, dict) else None
    if not isinstance(files, list):
        raise DataError(f"{ZENODO_API_URL}: the record's listing has no list of files")
    for item in files:
        try:
            name, url = str(item["key"]), str(item["links"]["self"])
            size = int(item["size"]) if item.get("size") is not None else None
            checksum = str(item.get("checksum") or "")
        except (KeyError, TypeError, ValueError, AttributeError):
            raise DataError(f"{ZENODO_API_URL}: a file of the record's listing lacks its key, link or size") from None
        target = into / inside(name, "the record's file")
        md5 = checksum.removeprefix("md5:") if checksum.startswith("md5:") else None
        if target.is_file() and not _cached_ok(target, md5, size):
            print(f"{target}: a download kept from an earlier run is not whole: downloading it again", file=sys.stderr)
            target.unlink()
        if not target.is_file():
            print(f"download {name} ({(size or 0) / 1e6:.0f} MB)", file=sys.stderr)
            download(url, target, md5, size)
        if name.lower().endswith(".zip"):
            unpack(target, into / Path(name).parent / Path(name).stem)
    return into


def unpack(archive: Path, folder: Path) -> None:
    """A zip archive unpacked into ``folder``, whole or not at all (a marker beside it says it is
    done); an archive that is not a whole zip is refused and removed, to be downloaded again."""
    marker = folder.parent / f".{archive.name}.unpacked"
    if marker.exists():
        return
    staging = Path(tempfile.mkdtemp(dir=folder.parent, prefix=f".{folder.name}."))
    try:
        try:
            with zipfile.ZipFile(archive) as package:
                package.extractall(staging)
        except (zipfile.BadZipFile, EOFError, zlib.error, NotImplementedError) as exc:
            archive.unlink()
            raise DataError(f"{archive}: not a whole zip archive ({exc}): removed; run again to download it") from None
        if folder.exists():
            shutil.rmtree(folder)  # an unpacking of ours cut short before its marker
        os.replace(staging, folder)
        marker.touch()
    finally:
        shutil.rmtree(staging, ignore_errors=True)


# ---- step 2: lay the files out -------------------------------------------------------------------
def transformed(source: Path, transform: str) -> tuple[bytes, bytes]:
    """(the bytes as laid out, their content before compression) of one source file.

    ``transform``: ``copy``; ``gzip`` (zlib's deflate, level 9, no name, time 0: Python's
    gzip module) or ``gnu-gzip`` (``gzip -9 -n``, whose deflate makes other bytes of the same
    content), each with ``:full`` or ``:wifi`` for an ILC trace cut to those record types."""
    data = source.read_bytes()
    if transform == "copy":
        return data, data
    kind, _, keep = transform.partition(":")
    if kind not in COMPRESSORS:
        raise DataError(f"unknown transform {transform!r} in {MANIFEST}")
    if keep:
        data = ilc_records(data, ILC_KEEP[keep])
    return COMPRESSORS[kind](data), data


def gnu_gzip(data: bytes) -> bytes:
    """``gzip -9 -n`` (GNU gzip); zlib's level 9 where no gzip program is found (the same
    content, other bytes: verify says so)."""
    if shutil.which("gzip") is None:
        return gzip.compress(data, compresslevel=9, mtime=0)
    return subprocess.run(["gzip", "-9", "-n", "-c"], input=data, capture_output=True, check=True).stdout


COMPRESSORS = {"gzip": lambda data: gzip.compress(data, compresslevel=9, mtime=0), "gnu-gzip": gnu_gzip}


def ilc_records(data: bytes, keep: set[bytes]) -> bytes:
    """An ILC trace with only the '#' header lines and the records of the types in ``keep``."""
    lines = data.splitlines(keepends=True)
    return b"".join(line for line in lines if line.startswith(b"#") or line.split(b"\t", 2)[1:2] and
                    line.split(b"\t", 2)[1] in keep)


def lay_out(rows: list[dict[str, str]], out: Path, sources: dict[str, list[Path]]) -> Iterator[tuple[str, str]]:
    """Write every file of ``rows`` under ``out`` from its source, each checked against the
    manifest before it is written (a gzip of the right content by another zlib is written, and
    ``verify`` names it); yields (path, what happened)."""
    for row in rows:
        target = out / inside(row["path"], "the manifest's path")
        if target.is_symlink() or (target.exists() and not target.is_file()):
            raise DataError(f"{target}: exists and is not a plain file: not overwritten")
        if target.is_file():
            if sha256_file(target) == row["sha256"]:
                yield row["path"], "kept (checksum right)"
                continue
            raise DataError(f"{target}: exists with another checksum: not overwritten (move it away, or lay out "
                            "elsewhere with --out)")
        if row["source"] == "project":
            source = PROJECT_FILES / inside(row["source_path"], "the manifest's source path")
        else:
            if not sources.get(row["source"]):
                raise DataError(f"{row['path']}: no {row['source']} source given")
            source = find_source(sources[row["source"]], row["source_path"])
        data, content = transformed(source, row["transform"])
        if sha256_of(data) != row["sha256"] and not (row["content_sha256"]
                                                     and sha256_of(content) == row["content_sha256"]):
            raise DataError(f"{source}: is not the source of {row['path']} (laid out, its SHA-256 would be "
                            f"{sha256_of(data)[:16]}..., the manifest says {row['sha256'][:16]}...): a damaged or "
                            "another file; nothing written")
        write_new(target, [data])
        yield row["path"], f"written from {source}"


# ---- step 3: verify ------------------------------------------------------------------------------
def verify(rows: list[dict[str, str]], out: Path) -> list[str]:
    """One line per file that is missing or whose checksum is not the manifest's (empty: all right).
    A .gz file with other bytes but the right content (another zlib) is named as such."""
    problems = []
    for row in rows:
        path = out / row["path"]
        if not path.is_file():
            problems.append(f"{path}: missing")
            continue
        if sha256_file(path) == row["sha256"]:
            continue
        if row["content_sha256"] and path.suffix == ".gz":
            with contextlib.suppress(OSError, EOFError):
                if sha256_of(gzip.decompress(path.read_bytes())) == row["content_sha256"]:
                    problems.append(f"{path}: the content is right but compressed otherwise (another zlib?)")
                    continue
        problems.append(f"{path}: SHA-256 {sha256_file(path)}, the manifest says {row['sha256']}")
    return problems


# ---- the manifest, for maintainers ---------------------------------------------------------------
def manifest_rows(data_dir: Path) -> list[dict[str, str]]:
    """The manifest of a laid-out data folder (what ``--write-manifest`` writes)."""
    rows = []
    for path in sorted(p for p in data_dir.rglob("*") if p.is_file()):
        rel = path.relative_to(data_dir).as_posix()
        content = gzip.decompress(path.read_bytes()) if path.suffix == ".gz" else None
        source, source_path, transform = _source_of(rel, content)
        if content is not None:
            transform = transform.replace("gzip", _compressor_of(path, content), 1)
        rows.append({"path": rel, "sha256": sha256_file(path),
                     "content_sha256": "" if content is None else sha256_of(content), "source": source,
                     "source_path": source_path, "transform": transform})
    return rows


def _compressor_of(path: Path, content: bytes) -> str:
    """The transform name of the compressor that makes ``path`` from ``content``."""
    data = path.read_bytes()
    for name, compress in COMPRESSORS.items():
        if compress(content) == data:
            return name
    raise DataError(f"{path}: made by a compressor this script does not know (neither zlib nor GNU gzip at -9)")


def _source_of(rel: str, content: bytes | None) -> tuple[str, str, str]:
    parts = rel.split("/")
    name = parts[-1]
    if name in ("README.md", "sparse_set.txt", "full_set.txt"):
        return "project", rel, "copy"
    if parts[0] == "ilc20":
        if name == "LICENSE":
            return "ilc", "LICENSE", "copy"
        source = "data/" + "/".join(parts[1:])
        if name.endswith(".txt.gz"):
            types = {line.split(b"\t")[1] for line in content.splitlines() if line and not line.startswith(b"#")}
            keep = "wifi" if types <= ILC_KEEP["wifi"] else "full"
            return "ilc", source.removesuffix(".gz"), f"gzip:{keep}"
        return "ilc", source, "copy"
    if parts[0] == "ipin2023":
        if name.endswith(".txt.gz"):
            return "ipin", name.removesuffix(".gz"), "gzip"
        return "ipin", name, "copy"
    raise DataError(f"{rel}: no source known")


def write_manifest(data_dir: Path, path: Path = MANIFEST) -> None:
    rows = manifest_rows(data_dir)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, MANIFEST_COLUMNS, lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
    for row in rows:
        if row["source"] == "project":
            target = PROJECT_FILES / row["source_path"]
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(data_dir / row["path"], target)
    print(f"wrote {path}: {len(rows)} files")


# ---- the command ---------------------------------------------------------------------------------
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="Sources and layout: docs/data.md.")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"where to lay the data out (default: {DEFAULT_OUT})")
    parser.add_argument("--from-dir", type=Path, action="append", default=[], metavar="DIR",
                        help="local copies of both sources (any layout; repeatable): nothing is downloaded")
    parser.add_argument("--ilc-from", type=Path, action="append", default=[], metavar="DIR",
                        help="a checkout (or copy) of the ILC 2.0 repository instead of downloading it")
    parser.add_argument("--ipin-from", type=Path, action="append", default=[], metavar="DIR",
                        help="the unpacked IPIN 2023 package instead of downloading it")
    parser.add_argument("--downloads", type=Path, default=None, metavar="DIR",
                        help="where downloads go (default: OUT/.downloads; kept, so a second run downloads nothing)")
    parser.add_argument("--only", action="append", default=[], metavar="PATTERN",
                        help="only the files whose laid-out path matches (e.g. 'ilc20/site1/F2/*'; repeatable)")
    parser.add_argument("--verify", type=Path, metavar="DIR", help="only check the checksums of a laid-out folder")
    parser.add_argument("--write-manifest", type=Path, metavar="DATA_DIR", help=argparse.SUPPRESS)  # maintainers
    args = parser.parse_args(argv)
    try:
        if args.write_manifest is not None:
            write_manifest(args.write_manifest)
            return 0
        rows = read_manifest()
        if args.only:
            rows = [r for r in rows if any(fnmatch.fnmatch(r["path"], p) for p in args.only)]
            if not rows:
                raise DataError(f"--only {' '.join(args.only)}: matches no file of the manifest")
        if args.verify is not None:
            return _report(rows, args.verify)
        sources = {"ilc": [*args.ilc_from, *args.from_dir], "ipin": [*args.ipin_from, *args.from_dir]}
        for root in {p for paths in sources.values() for p in paths}:
            if not root.is_dir():
                raise DataError(f"{root}: not a directory")
        downloads = args.downloads or args.out / ".downloads"
        if not sources["ilc"] and any(r["source"] == "ilc" for r in rows):
            sources["ilc"] = [download_ilc([r for r in rows if r["source"] == "ilc"], downloads / "ilc")]
        if not sources["ipin"] and any(r["source"] == "ipin" for r in rows):
            sources["ipin"] = [download_ipin(downloads / "ipin")]
        written = sum(1 for _, what in lay_out(rows, args.out, sources) if what.startswith("written"))
        print(f"laid out {written} files ({len(rows) - written} already there) in {args.out}")
        return _report(rows, args.out)
    except DataError as exc:
        print(f"get_data: error: {exc}", file=sys.stderr)
        return 1
    except (OSError, EOFError, zlib.error, subprocess.CalledProcessError) as exc:  # the network, a full disk
        print(f"get_data: error: {exc}", file=sys.stderr)
        return 1


def _report(rows: list[dict[str, str]], out: Path) -> int:
    problems = verify(rows, out)
    for line in problems:
        print(line, file=sys.stderr)
    print(f"verified {len(rows) - len(problems)} of {len(rows)} files against {MANIFEST.name}"
          + ("" if not problems else f": {len(problems)} wrong or missing"))
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
