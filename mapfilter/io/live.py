"""Files that grow while a live run goes on: the track written row by row, the rerun recording.

A live run has no end to wait for (``tail -f`` never closes its output; a phone streams until it
is stopped), so its files cannot appear whole at the end as the others do (``io.atomic``).
Instead each is made under a temporary name beside its path and put in place once it has
something worth keeping (a track file: its header and first rows), replacing a file of that name;
from then on the run adds to it, one whole chunk of rows at a time, so that a reader following
the file (``tail -f``) never sees part of a line, and a run stopped at any moment (Ctrl-C,
SIGTERM, a full disk) leaves every row it printed in it. A run that ends before its first row
leaves nothing, and an earlier file of that name as it was.
"""

from __future__ import annotations

import contextlib
import csv
import errno
import io
import os
import secrets
from pathlib import Path

from mapfilter.errors import MapfilterError
from mapfilter.io.atomic import DISK_ERRNOS, check_not_special
from mapfilter.io.tracks import Georeferenced, Track, csv_header, csv_rows, tum_lines, with_latlon

_NAME_MAX = 255  # bytes in a file name


class GrowingFile:
    """A file a run writes as it goes: made as ``.STEM.RANDOM.SUFFIX`` beside ``path`` (the name
    ``io.outputs`` knows as a temporary of ours), moved into place by :meth:`publish`, where the
    run goes on writing it (a rename keeps the open file); :meth:`discard` removes it when it was
    never published. Missing parent directories are made, and removed again with the temporary."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self.temporary: Path | None = None
        self.published = False
        self._made: list[Path] = []  # directories made for it, outermost first

    def create(self) -> Path:
        """Make the (empty, private) temporary file and return its path."""
        if self.path.is_dir():
            raise MapfilterError("is a directory; give a file name", self.path)
        check_not_special(self.path, "output")
        directory = self.path.parent
        missing = []
        while not directory.exists() and directory != directory.parent:
            missing.append(directory)
            directory = directory.parent
        stem = self.path.stem
        while len(os.fsencode(f".{stem}.12345678{self.path.suffix}")) > _NAME_MAX and stem:
            stem = stem[:-1]
        try:
            for folder in reversed(missing):
                folder.mkdir()
                self._made.append(folder)
            for _ in range(100):
                name = self.path.parent / f".{stem}.{secrets.token_hex(4)}{self.path.suffix}"
                self.temporary = name  # named before it exists: an interrupt now still removes it
                try:
                    os.close(os.open(name, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
                    return name
                except FileExistsError:
                    self.temporary = None  # someone else's: never ours to remove
            raise FileExistsError(errno.EEXIST, "no free temporary name", str(self.path.parent))
        except OSError as exc:
            self.discard()
            raise MapfilterError(f"cannot write here ({exc.strerror or exc})", self.path) from None

    def publish(self) -> None:
        """Put the file in place (replacing a file of that name), with the usual mode."""
        if self.published or self.temporary is None:
            return
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(self.temporary, 0o666 & ~umask)
        os.replace(self.temporary, self.path)
        self.published = True
        self._made = []

    def discard(self) -> None:
        """Remove the temporary (and the directories made for it) unless it was published."""
        if self.published:
            return
        if self.temporary is not None:
            with contextlib.suppress(FileNotFoundError):
                self.temporary.unlink()
            self.temporary = None
        for folder in reversed(self._made):
            with contextlib.suppress(OSError):  # something else was put there: keep it
                folder.rmdir()
        self._made = []


class LiveTrackFile:
    """A track file (CSV or TUM, the bytes ``io.tracks.write_track`` writes) written chunk by
    chunk as a live run's rows come (see the module docstring).

    ``append(rows)`` adds the rows of a ``Track`` (the first call, with at least one row, puts the
    file in place with its header); each call's rows reach the file whole, flushed, before it
    returns. Used as a context manager: on leaving, a chunk cut short by an interrupt is taken
    back to its last whole line; a file that never got a row is not made.
    """

    def __init__(self, path: str | os.PathLike, track_format: str = "csv", building: Georeferenced | None = None) -> None:
        if track_format not in ("csv", "tum"):
            raise MapfilterError(f"unknown track format {track_format!r}: csv or tum", path)
        self.path = Path(path)
        self.track_format = track_format
        self.building = building
        self.n_rows = 0
        self._file = GrowingFile(self.path)
        self._fd: int | None = None
        self._size = 0  # bytes of whole chunks written
        self._columns: list[str] | None = None

    def append(self, rows: Track) -> None:
        """Add ``rows`` (each in its floor's frame); nothing happens for an empty track."""
        if not len(rows):
            return
        text = self._text(rows)
        if self._fd is None:
            self._fd = os.open(self._file.create(), os.O_WRONLY)
        self._write(text.encode())
        self._file.publish()  # after its first rows are in it: a reader never sees an empty file
        self.n_rows += len(rows)

    def _text(self, rows: Track) -> str:
        if self.track_format == "tum":
            return "".join(tum_lines(rows))
        if rows.latlon_deg is None and self.building is not None and self.building.georeference is not None:
            rows = with_latlon(rows, self.building)
        out = io.StringIO(newline="")
        writer = csv.writer(out)  # the dialect write_track_csv uses: the same bytes
        columns = csv_header(rows)
        if self._columns is None:
            self._columns = columns
            writer.writerow(columns)
        elif columns != self._columns:
            raise ValueError(f"rows with the columns {columns} after the header {self._columns}")
        writer.writerows(csv_rows(rows))
        return out.getvalue()

    def _write(self, data: bytes) -> None:
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(self._fd, view):]
        except OSError as exc:
            os.ftruncate(self._fd, self._size)  # no part of a chunk: the rows before it stay whole
            if exc.errno in DISK_ERRNOS:
                raise MapfilterError(f"could not write: {exc.strerror or exc}", self.path) from exc
            raise
        self._size += len(data)

    def close(self) -> None:
        """Finish: the file keeps its whole chunks; without any row, nothing is left."""
        if self._fd is not None:
            with contextlib.suppress(OSError):
                if os.fstat(self._fd).st_size != self._size:  # an interrupt inside a chunk's write
                    os.ftruncate(self._fd, self._size)
            os.close(self._fd)
            self._fd = None
        self._file.discard()  # only when it was never published

    def __enter__(self) -> LiveTrackFile:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close()
