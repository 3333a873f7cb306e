"""The output policy of every command: what a run may write, checked before any work is done.

A command never writes over one of its own inputs, never replaces something that is not a
plain file (a device, a FIFO, a socket, a symbolic link), and only ever deletes or overwrites
in a directory what mapfilter itself wrote there. Each refusal is one line naming the path and
the option, raised before anything is read.

- ``check_output_file``: a file to write (``--out FILE``); ``-`` is standard output where the
  command allows it (``atomic_paths`` then writes the finished file to stdout).
- ``OutputDirectory``: a directory a run fills with many files (``track --out-dir``,
  ``evaluate --out``). Every file written there is first recorded in the directory's manifest
  (``.mapfilter-manifest.json``); an existing directory may only hold files listed there, and a
  new run removes only those. The run's files are staged and committed together: a run that
  fails leaves an earlier run's files whole.
- ``input_paths``: the files a run reads, with what a map or building YAML names (its image,
  its floors' maps, an access-point table), so that none of them is an output.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
from collections.abc import Iterable, Sequence
from pathlib import Path

from mapfilter.io.atomic import STDOUT, StagedFiles, atomic_paths, check_not_special, is_stdout
from mapfilter.errors import MapfilterError

MANIFEST = ".mapfilter-manifest.json"
# the temporaries of mapfilter.io.atomic: ".STEM.8HEX.SUFFIX" (left behind only by a killed run)
_TEMPORARY = re.compile(r"^\..*\.[0-9a-f]{8}(\.[^.]*)?$")
_MAX_LISTED = 100_000  # files looked at in an existing output directory before giving up
_MAX_REFERENCE_DEPTH = 3  # building YAML -> floor map YAML -> image



# ---- what a run reads --------------------------------------------------------------------------
def input_paths(*paths: str | os.PathLike | Iterable[str | os.PathLike] | None) -> list[Path]:
    """Every input of a run: the paths given (None skipped, lists flattened) and, for a YAML or
    JSON file, the files it names (a map's image and access-point table, a building's floor
    maps, recursively). A file that cannot be read is still listed; what it names is not."""
    out: list[Path] = []
    for item in paths:
        if item is None:
            continue
        if isinstance(item, (str, os.PathLike)):
            _add_input(Path(item), out, 0)
        else:
            for path in item:
                if path is not None:
                    _add_input(Path(path), out, 0)
    return out


def _add_input(path: Path, out: list[Path], depth: int) -> None:
    if is_stdout(path) or path in out:
        return
    out.append(path)
    if depth >= _MAX_REFERENCE_DEPTH or path.suffix.lower() not in (".yaml", ".yml"):
        return
    from mapfilter.io.yamlio import load_yaml  # noqa: PLC0415 - yaml only when a YAML is an input

    try:
        data = load_yaml(path, "a YAML file")
    except (MapfilterError, OSError):
        return  # the command's own reader reports it
    for text in _strings(data):
        candidate = Path(text) if os.path.isabs(text) else path.parent / text
        with contextlib.suppress(OSError, ValueError):
            if candidate.is_file():
                _add_input(candidate, out, depth + 1)


def _strings(data, budget: list[int] | None = None) -> Iterable[str]:
    """The strings in a loaded YAML (at most a few thousand: a map names a handful of files)."""
    budget = [5000] if budget is None else budget
    stack = [data]
    while stack and budget[0] > 0:
        item = stack.pop()
        budget[0] -= 1
        if isinstance(item, str):
            if 0 < len(item) < 4096 and "\n" not in item:
                yield item
        elif isinstance(item, dict):
            stack.extend(item.values())
        elif isinstance(item, list):
            stack.extend(item)


# ---- one output file ---------------------------------------------------------------------------
def check_output_file(path: str | os.PathLike | None, option: str = "--out", inputs: Sequence[Path] = (),
                      allow_stdout: bool = False) -> None:
    """Refuse, in one line naming ``path`` and ``option``, an output file that would destroy
    something: one of ``inputs`` (the same path, a link to it, the same inode), a directory, a
    device, a FIFO, a socket or a symbolic link (replacing one writes nothing where the user
    meant), a name longer than the file system takes, a parent that is a file, a directory that
    cannot be written in. ``-`` is standard output when ``allow_stdout`` (else refused). Missing
    parents are fine: writing makes them. ``None`` passes (the option was not given)."""
    if path is None:
        return
    if is_stdout(path):
        if not allow_stdout:
            raise MapfilterError(f"{option} -: this output cannot go to standard output; give a file name")
        return
    path = Path(path)
    if str(path) in ("", "."):
        raise MapfilterError(f"{option} needs a file name")
    _check_name_length(path, option)
    check_not_special(path, option)
    if path.is_dir():
        raise MapfilterError(f"{option}: is a directory; give a file name", path)
    for source in inputs:
        if _same_file(path, source):
            raise MapfilterError(f"{option}: is an input of this run ({source}): writing would destroy it; "
                                 "give another output name", path)
        if _inside(path, source) and path.exists():
            raise MapfilterError(f"{option}: is a file of the input folder {source}; give another output name", path)
    _check_parent(path, option)


def check_output_files(paths: Sequence[Path], option: str, inputs: Sequence[Path] = ()) -> None:
    """``check_output_file`` for every file one output makes (a map's YAML, mask and preview),
    which must also be distinct."""
    for i, path in enumerate(paths):
        check_output_file(path, option, inputs)
        for other in paths[:i]:
            if _same_file(path, other):
                raise MapfilterError(f"{option}: two outputs of this run would be the same file ({other})", path)



def _check_name_length(path: Path, option: str) -> None:
    name_max = 255
    with contextlib.suppress(OSError, ValueError, AttributeError):
        name_max = os.pathconf(_nearest_existing(path.parent), "PC_NAME_MAX")
    if len(os.fsencode(path.name)) > name_max:
        raise MapfilterError(f"{option}: the name is {len(os.fsencode(path.name))} bytes, more than the "
                             f"{name_max} this file system takes", path)


def _check_parent(path: Path, option: str, directory: bool = False) -> None:
    existing = _nearest_existing(path if directory else path.parent)
    if not existing.is_dir():
        raise MapfilterError(f"{option}: cannot be made, {existing} is not a directory", path)
    _check_writable_directory(existing, path, option)


def _nearest_existing(directory: Path) -> Path:
    # the missing directories below it are made when writing
    while not directory.exists() and directory != directory.parent:
        directory = directory.parent
    return directory


def _check_writable_directory(directory: Path, path: Path, option: str) -> None:
    import tempfile

    # os.access says yes to root and knows nothing of read-only mounts or ACLs: try it
    try:
        fd, probe = tempfile.mkstemp(prefix=".mapfilter-probe.", dir=directory)
    except OSError as exc:
        raise MapfilterError(f"{option}: cannot write in {directory} ({exc.strerror or exc})", path) from None
    os.close(fd)
    with contextlib.suppress(OSError):
        os.unlink(probe)


def _resolved(path: Path) -> Path:
    try:
        return path.resolve()
    except (OSError, RuntimeError):  # a symlink loop
        return path.absolute()


def _same_file(a: Path, b: Path) -> bool:
    with contextlib.suppress(OSError, ValueError):
        if os.path.samefile(a, b):  # a hard link, or another name of the same file
            return True
    return _resolved(a) == _resolved(b)


def _inside(path: Path, directory: Path) -> bool:
    """``path`` lies inside the existing directory ``directory``."""
    with contextlib.suppress(OSError):
        if directory.is_dir():
            return _resolved(directory) in _resolved(path).parents
    return False


# ---- a directory of outputs --------------------------------------------------------------------
class OutputDirectory:
    """A directory that a run fills with files, where only mapfilter's own files are ever touched.

    Every file is recorded in the directory's manifest (``MANIFEST``) before it is written, so
    that a later run (or a resumed one) knows what it may remove or overwrite. An existing
    directory that holds any file not listed there, or any input of the run, is refused before
    the work.

    A run writes its files through ``writing`` (staged beside their final names) and ``commit``
    moves them into place together (``io.atomic.StagedFiles``): all of them, or, when the commit
    fails, none, with the earlier run's files whole. ``replace_earlier_run`` makes the commit also
    remove the files an earlier run recorded that this one did not write (and nothing else);
    ``clear`` removes them at once.
    """

    def __init__(self, path: str | os.PathLike, option: str = "--out", inputs: Sequence[Path] = ()) -> None:
        self.path = Path(path)
        self.option = option
        if str(path) in ("", STDOUT):
            raise MapfilterError(f"{option} needs a directory name")
        check_not_special_directory(self.path, option)
        if self.path.exists() and not self.path.is_dir():
            raise MapfilterError(f"{option}: exists and is not a directory", self.path)
        _check_parent(self.path, option, directory=True)
        for source in inputs:
            if _same_file(self.path, source) or _inside(source, self.path):
                raise MapfilterError(f"{option}: holds {source}, an input of this run: give an output directory "
                                     "that holds no input", self.path)
        self.files: set[str] = self._read_manifest()
        self._staged = StagedFiles()
        self._earlier: set[str] = set()  # an earlier run's files that go with the next commit
        self._committed = set(self.files)  # the manifest as the files on disk stand
        foreign = self._foreign_files()
        if foreign:
            first, more = foreign[0], len(foreign) - 1
            raise MapfilterError(f"{option}: holds files that mapfilter did not write ({first}"
                                 + (f" and {more} more" if more else "") + "): give a new or empty directory, "
                                 "so that nothing of yours is removed or overwritten", self.path)

    @property
    def manifest_path(self) -> Path:
        return self.path / MANIFEST

    def _read_manifest(self) -> set[str]:
        if not self.manifest_path.exists():
            return set()
        try:
            data = json.loads(self.manifest_path.read_text())
            files = data["files"]
            if not (isinstance(files, list) and all(isinstance(f, str) for f in files)):
                raise TypeError
        except (OSError, ValueError, KeyError, TypeError):
            raise MapfilterError(f"{self.option}: its {MANIFEST} (the list of files mapfilter wrote there) is not "
                                 "readable: give a new or empty directory", self.path) from None
        return {f for f in files if _is_relative_name(f)}

    def _foreign_files(self) -> list[str]:
        if not self.path.is_dir():
            return []
        foreign = []
        for count, (root, dirs, names) in enumerate(os.walk(self.path)):
            dirs.sort()
            for name in sorted(names):
                relative = Path(root, name).relative_to(self.path).as_posix()
                if relative == MANIFEST or relative in self.files or _TEMPORARY.match(name):
                    continue
                foreign.append(relative)
            if count > _MAX_LISTED or len(foreign) > 20:
                break
        return foreign

    def claim(self, relative: str | os.PathLike) -> Path:
        """The path of ``relative`` in the directory, recorded in the manifest before it is written."""
        name = Path(relative).as_posix()
        if not _is_relative_name(name):
            raise MapfilterError(f"{self.option}: {name!r} is not a file name inside the directory", self.path)
        path = self.path / name
        check_not_special(path, self.option)
        if name not in self.files:
            self.files.add(name)
            self._write_manifest()
        return path

    @contextlib.contextmanager
    def writing(self, *relatives: str | os.PathLike):
        """Temporaries for the files ``relatives`` (claimed: recorded in the manifest first),
        moved into place by :meth:`commit`; a block that raises leaves them out."""
        finals = [self.claim(relative) for relative in relatives]
        with self._staged.writing(*finals) as temps:
            yield temps

    def replace_earlier_run(self) -> None:
        """The next :meth:`commit` removes the files an earlier run recorded that this run does not
        write (until then they stay whole)."""
        self._earlier = set(self.files)

    def commit(self) -> None:
        """The staged files into place together, and an earlier run's files removed (after
        :meth:`replace_earlier_run`); on failure nothing changes and the error is raised."""
        written = {final.relative_to(self.path).as_posix() for final in self._staged.written_paths}
        gone = self._earlier - written
        for name in sorted(gone):
            path = self.path / name
            if path.is_file() and not path.is_symlink():
                self._staged.remove_at_commit(path)
        self._staged.commit()
        self._earlier = set()
        if gone:
            self._remove_empty_folders(gone)
            self.files -= gone
            self._write_manifest()
        self._committed = set(self.files)

    def discard(self) -> None:
        """Drop what was staged and not committed: the directory as the last commit left it (the
        manifest too, where it can be written)."""
        self._staged.discard()
        self._earlier = set()
        if self.files != self._committed and self.manifest_path.exists():
            self.files = set(self._committed)
            with contextlib.suppress(MapfilterError, OSError):  # a manifest listing more is harmless
                if self.files:
                    self._write_manifest()
                else:
                    self.manifest_path.unlink()

    def _remove_empty_folders(self, names: set[str]) -> None:
        folders = {p for name in names for p in Path(name).parents if str(p) != "."}
        for folder in sorted(folders, key=lambda p: len(p.parts), reverse=True):
            with contextlib.suppress(OSError):  # not empty: keep it
                (self.path / folder).rmdir()

    def clear(self) -> None:
        """Remove the files an earlier run recorded (and the folders that this leaves empty)."""
        for name in sorted(self.files):
            path = self.path / name
            with contextlib.suppress(FileNotFoundError, IsADirectoryError):
                if not path.is_symlink() and path.is_file():
                    path.unlink()
        self._remove_empty_folders(self.files)
        self.files = set()
        self._committed = set()
        if self.manifest_path.exists():
            self._write_manifest()

    def _write_manifest(self) -> None:
        with atomic_paths(self.manifest_path) as (tmp,):
            tmp.write_text(json.dumps({"written_by": "mapfilter", "files": sorted(self.files)}, indent=0) + "\n")


def check_not_special_directory(path: Path, option: str) -> None:
    """An output directory may be a link to a directory (written through, never replaced), not a
    device, a FIFO or a socket."""
    if path.is_symlink() and path.is_dir():
        return
    if path.is_symlink():
        raise MapfilterError(f"{option}: is a symbolic link to {os.readlink(path)}, not a directory", path)
    check_not_special(path, option)


def _is_relative_name(name: str) -> bool:
    parts = Path(name).parts
    return bool(parts) and not Path(name).is_absolute() and ".." not in parts
