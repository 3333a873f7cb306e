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
def signals_held() -> Iterator[None]:
    """SIGINT and SIGTERM held back for the block (delivered as it ends): a temporary made and
    listed for the clean-up, or the files of a commit moved, are never cut in half by Ctrl-C or
    a SIGTERM (the CLI turns both into an interrupt that cleans up)."""
    import signal
    import threading

    if not hasattr(signal, "pthread_sigmask") or threading.current_thread() is not threading.main_thread():
        yield
        return
    before = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, before)


class StagedFiles:
    """Files written to temporaries beside their final paths and moved into place together: all
    of them, or, on any failure, none (every earlier file stays whole).

    ``stage(final)`` reserves a temporary ``.STEM.RANDOM.SUFFIX`` beside ``final`` (making missing
    parent directories); ``written(final)`` says it is complete (``writing`` does both around a
    ``with`` block); ``remove_at_commit(path)`` marks a file to go with the commit. ``commit()``
    keeps a hard link to every file it replaces or removes, moves each written temporary into
    place, and on any failure (or an interrupt) puts every earlier file back; then the links go.
    A temporary never marked written is removed, never moved. ``discard()`` removes every
    temporary and the directories made for them. As a ``with`` block: commit on success,
    discard on an exception.
    """

    def __init__(self) -> None:
        self._temps: dict[Path, Path] = {}  # final -> its temporary, in staging order
        self._written: set[Path] = set()
        self._removals: list[Path] = []
        self._made: list[Path] = []  # directories made for the temporaries, outermost first

    def __enter__(self) -> StagedFiles:
        return self

    def __exit__(self, kind, value, traceback) -> None:
        if kind is None:
            self.commit()
        else:
            self.discard()

    def __len__(self) -> int:
        return len(self._temps)

    def stage(self, final: str | os.PathLike) -> Path:
        """The temporary of ``final`` (made now, private; the same one when staged again)."""
        final = Path(final)
        if final in self._temps:
            self._written.discard(final)  # written again: complete only once marked so again
            return self._temps[final]
        if final.is_dir():
            raise MapfilterError("is a directory; give a file name", final)
        check_not_special(final, "output")  # a link, a device, a FIFO: never replaced
        temps: list[Path] = []
        with signals_held():  # made and listed for the clean-up at once
            try:
                self._made += _make_parents(final.parent)
                _create_temporary(final, temps)
            except OSError as exc:  # a parent that is a file, a directory we may not write in
                raise MapfilterError(f"cannot write here ({exc.strerror or exc})", final) from None
            self._temps[final] = temps[0]
        return temps[0]

    def written(self, final: str | os.PathLike) -> None:
        """The temporary of ``final`` is complete: ``commit`` moves it into place."""
        final = Path(final)
        if final not in self._temps:
            raise KeyError(f"{final} was not staged")
        self._written.add(final)

    @contextlib.contextmanager
    def writing(self, *finals: str | os.PathLike) -> Iterator[list[Path]]:
        """Temporaries for ``finals``, marked written when the block ends without an exception
        (on one, they are removed and the finals will not change). A disk error (``DISK_ERRNOS``)
        is a ``MapfilterError`` naming the final file."""
        paths = [Path(f) for f in finals]
        temps = [self.stage(f) for f in paths]
        try:
            yield temps
        except BaseException as exc:
            for final, tmp in zip(paths, temps):
                self._drop(final)
            if isinstance(exc, OSError) and exc.errno in DISK_ERRNOS:
                raise MapfilterError(f"could not write: {exc.strerror or exc}",
                                     _failed_file(exc, temps, paths)) from exc
            raise
        for final in paths:
            self.written(final)

    @property
    def written_paths(self) -> list[Path]:
        """The final paths whose temporaries are written (what ``commit`` would move)."""
        return [f for f in self._temps if f in self._written]

    def remove_at_commit(self, path: str | os.PathLike) -> None:
        """``path`` goes with the commit (kept if the commit fails)."""
        self._removals.append(Path(path))

    def commit(self) -> None:
        """Every written temporary into place and every marked file removed, together; on any
        failure the earlier files are put back and the error raised. Afterwards the set is empty.
        An interrupt waits for the commit's end."""
        with signals_held():
            self._commit()

    def _commit(self) -> None:
        pending = [(self._temps[f], f) for f in self.written_paths]
        removals = [p for p in self._removals if p not in self._temps and os.path.lexists(p)]
        umask = os.umask(0)  # mkstemp makes files private (0600): give the usual mode (0666 minus the umask)
        os.umask(umask)
        single = len(pending) + len(removals) <= 1  # one rename is atomic by itself: no backup needed
        backups: dict[Path, Path] = {}  # an earlier file -> its backup
        placed: list[Path] = []
        removed: list[Path] = []
        try:
            for tmp, _ in pending:
                os.chmod(tmp, 0o666 & ~umask)
            if not single:
                for path in [f for _, f in pending] + removals:
                    if os.path.lexists(path):
                        backups[path] = _backup(path)
            for tmp, final in pending:
                os.replace(tmp, final)
                placed.append(final)
            for path in removals:
                os.unlink(path)
                removed.append(path)
        except BaseException:
            for path in reversed(placed + removed):  # put back what was there
                with contextlib.suppress(OSError):
                    if path in backups:
                        os.replace(backups.pop(path), path)
                    elif path in placed:
                        os.unlink(path)
            for path, backup in backups.items():  # a backup by renaming, its file not yet replaced
                if not os.path.lexists(path):
                    with contextlib.suppress(OSError):
                        os.replace(backup, path)
            raise
        finally:
            for backup in backups.values():
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(backup)
            self.discard()  # the directories that now hold a file stay (rmdir refuses them)

    def discard(self) -> None:
        """Remove every temporary not moved into place, and the directories made for them."""
        for final in list(self._temps):
            self._drop(final)
        for directory in reversed(self._made):
            with contextlib.suppress(OSError):  # not empty (something else wrote there): keep it
                directory.rmdir()
        self._made = []
        self._removals = []

    def _drop(self, final: Path) -> None:
        with signals_held():  # unlisted and removed at once
            tmp = self._temps.pop(final, None)
            self._written.discard(final)
            if tmp is not None:
                with contextlib.suppress(FileNotFoundError):
                    tmp.unlink()


def _backup(path: Path) -> Path:
    """A second name for ``path``'s file (a hard link; where the file system has none, ``path``
    itself is renamed), to put it back if a commit fails."""
    temps: list[Path] = []
    for _ in range(100):
        backup = path.parent / f".{path.stem[:200]}.{secrets.token_hex(4)}{path.suffix}"
        try:
            os.link(path, backup, follow_symlinks=False)
            return backup
        except FileExistsError:
            continue
        except OSError:
            break
    _create_temporary(path, temps)
    os.replace(path, temps[0])
    return temps[0]


@contextlib.contextmanager
def atomic_paths(*final_paths: str | os.PathLike) -> Iterator[list[Path]]:
    """Yield temporary paths beside ``final_paths``; move them into place only on success.

    All files appear together at the end of the ``with`` block (``StagedFiles.commit``: all or
    none, the earlier files whole if it fails); if the block raises (or is interrupted: Ctrl-C,
    SIGTERM through the CLI), the temporaries are removed, and so are the directories made for
    them, and no final path is touched. Missing parent directories are made. ``-`` is standard
    output: its file is written to a private temporary and copied to stdout at the end. A path
    that is a symbolic link, a device, a FIFO or a socket is refused (``mapfilter.io.outputs``:
    never replaced). A full disk (or another error of the disk: ``DISK_ERRNOS``) while the block
    writes is a ``MapfilterError`` naming the final file, not an ``OSError`` without a file name.
    """
    finals = [Path(p) for p in final_paths]
    staged = StagedFiles()
    stdout_dir = None  # the private directory of a temporary bound for standard output
    try:
        files = [f for f in finals if not is_stdout(f)]
        temps: dict[Path, Path] = {}
        for final in finals:
            if is_stdout(final):
                stdout_dir = Path(tempfile.mkdtemp(prefix="mapfilter-stdout."))
                temps[final] = stdout_dir / "out"
                temps[final].touch(mode=0o600)
        with staged.writing(*files) as written:
            temps.update(zip(files, written))
            yield [temps[f] for f in finals]
        staged.commit()
        for final in finals:
            if is_stdout(final):
                _copy_to_stdout(temps[final])
    finally:
        staged.discard()
        if stdout_dir is not None:
            shutil.rmtree(stdout_dir, ignore_errors=True)


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
