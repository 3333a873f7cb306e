"""Write output files so that a failure leaves nothing half-written."""

from __future__ import annotations

import contextlib
import csv
import errno
import os
import secrets
import shutil
import stat
import sys
import tempfile
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path

from mapfilter.errors import MapfilterError

STDOUT = "-"  # an output path that means standard output


def is_stdout(path: str | os.PathLike | None) -> bool:
    return path is not None and str(path) == STDOUT


def check_not_special(path: Path, option: str = "--out") -> None:
    """Refuse a path that exists and is not a plain file or directory: a symbolic link, a device,
    a FIFO, a socket. ``os.replace`` would put a new file in its place (a copy of /dev/null, or
    /dev/null itself when run as root, replaced by a regular file; a link replaced, not written
    through)."""
    try:
        mode = os.lstat(path).st_mode
    except OSError:  # missing, or under a file: writing it reports that
        return
    if stat.S_ISLNK(mode):
        target = os.readlink(path)
        raise MapfilterError(f"{option}: is a symbolic link (to {target}); give the file's own path, or "
                             f"{STDOUT} for standard output", path)
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        raise MapfilterError(f"{option}: is a device, not a file; give a file name, or {STDOUT} for standard "
                             "output", path)
    if stat.S_ISFIFO(mode):
        raise MapfilterError(f"{option}: is a FIFO (named pipe); give {STDOUT} and redirect standard output "
                             "into it", path)
    if stat.S_ISSOCK(mode):
        raise MapfilterError(f"{option}: is a socket, not a file", path)


# errors of the disk rather than of the program: a full disk, a quota, a file size limit,
# an I/O error, a read-only file system
DISK_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO, errno.EROFS})
_NAME_MAX = 255  # bytes in a file name (Linux, macOS, Windows)


@contextlib.contextmanager
def atomic_paths(*final_paths: str | os.PathLike) -> Iterator[list[Path]]:
    """Yield temporary paths beside ``final_paths``; move them into place only on success.

    All files appear together at the end of the ``with`` block; if the block raises (or is
    interrupted: Ctrl-C, SIGTERM through the CLI), the temporaries are removed, and so are the
    directories made for them, and no final path is touched. Missing parent directories are
    made. ``-`` is standard output: its file is written to a private temporary and copied to
    stdout at the end. A path that is a symbolic link, a device, a FIFO or a socket is refused
    (``mapfilter.io.outputs``: never replaced). A full disk (or another error of the disk: ``DISK_ERRNOS``) while the block writes
    is a ``MapfilterError`` naming the final file, not an ``OSError`` without a file name.
    """
    finals = [Path(p) for p in final_paths]
    temps: list[Path] = []
    made: list[Path] = []  # directories made here, deepest last
    stdout_dir = None  # the private directory of a temporary bound for standard output
    try:
        for final in finals:
            if is_stdout(final):
                stdout_dir = Path(tempfile.mkdtemp(prefix="mapfilter-stdout."))
                temps.append(stdout_dir / "out")
                temps[-1].touch(mode=0o600)
                continue
            if final.is_dir():
                raise MapfilterError("is a directory; give a file name", final)
            check_not_special(final, "output")  # a link, a device, a FIFO: never replaced
            try:
                made += _make_parents(final.parent)
                _create_temporary(final, temps)
            except OSError as exc:  # a parent that is a file, a directory we may not write in
                raise MapfilterError(f"cannot write here ({exc.strerror or exc})", final) from None
        try:
            yield temps
        except OSError as exc:
            if exc.errno not in DISK_ERRNOS:
                raise
            raise MapfilterError(f"could not write: {exc.strerror or exc}", _failed_file(exc, temps, finals)) from exc
        # mkstemp makes files private (0600); give them the usual mode (0666 minus the umask)
        umask = os.umask(0)
        os.umask(umask)
        for tmp, final in zip(temps, finals):
            if is_stdout(final):
                _copy_to_stdout(tmp)
                continue
            if tmp.exists():
                os.chmod(tmp, 0o666 & ~umask)
            os.replace(tmp, final)
        temps = []
        made = []
    finally:
        for tmp in temps:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
        if stdout_dir is not None:
            shutil.rmtree(stdout_dir, ignore_errors=True)
        for directory in reversed(made):
            with contextlib.suppress(OSError):  # not empty (something else wrote there): keep it
                directory.rmdir()


def write_csv_atomically(path: str | os.PathLike, header: Sequence[str], rows: Iterable[Sequence[object]]) -> None:
    """A CSV file of ``header`` and ``rows`` (cells as given: numbers formatted by the caller),
    written through ``atomic_paths``."""
    with atomic_paths(path) as (tmp,):
        with tmp.open("w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(header)
            writer.writerows(rows)


def _create_temporary(final: Path, temps: list[Path]) -> None:
    """A new private file ``.STEM.RANDOM.SUFFIX`` beside ``final``, listed in ``temps`` *before* it
    is made, so that an interrupt at any moment (Ctrl-C, SIGTERM) leaves none unlisted for the
    clean-up (``tempfile.mkstemp`` makes the file before it returns its name)."""
    # ".STEM.RANDOM.SUFFIX" is 10 bytes longer than the final name: a stem that would make it
    # longer than a file name may be (255 bytes) is cut (a 250-character --out is valid)
    stem = final.stem
    while len(os.fsencode(f".{stem}.12345678{final.suffix}")) > _NAME_MAX and stem:
        stem = stem[:-1]
    for _ in range(100):
        tmp = final.parent / f".{stem}.{secrets.token_hex(4)}{final.suffix}"
        temps.append(tmp)
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
            return
        except FileExistsError:
            temps.pop()  # someone else's: never remove it
        except OSError:
            temps.pop()  # not made (a parent that is a file, no permission)
            raise
    raise FileExistsError(errno.EEXIST, "no free temporary name", str(final.parent))


def _copy_to_stdout(tmp: Path) -> None:
    """The finished output on standard output (``--out -``), after what was printed before."""
    sys.stdout.flush()
    with tmp.open("rb") as handle:
        shutil.copyfileobj(handle, sys.stdout.buffer)
    sys.stdout.buffer.flush()


def _make_parents(directory: Path) -> list[Path]:
    """Make ``directory`` and its missing parents; the ones made, outermost first."""
    missing = []
    while not directory.exists() and directory != directory.parent:
        missing.append(directory)
        directory = directory.parent
    made = []
    for path in reversed(missing):
        try:
            path.mkdir()
        except FileExistsError:
            continue  # made meanwhile by someone else: not ours to remove
        made.append(path)
    return made


def _failed_file(exc: OSError, temps: list[Path], finals: list[Path]) -> Path | str:
    """The final file whose temporary the error names, else the one file, else all of them."""
    for tmp, final in zip(temps, finals):
        if exc.filename is not None and Path(exc.filename) == tmp:
            return final
    return finals[0] if len(finals) == 1 else ", ".join(str(f) for f in finals)
