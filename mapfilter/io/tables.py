"""The small CSV tables a user writes (access-point tables, measurement sources' tables) and the track files read
back: the text of a table read whole within a bound, and the csv module's own refusals (a field
longer than its limit, a NUL byte) as one line naming the file and line."""

from __future__ import annotations

import csv
import os
from collections.abc import Iterator
from pathlib import Path

from mapfilter.errors import MapfilterError

MAX_TABLE_BYTES = 16 << 20  # 16 MiB: a table of 100 000 transmitters is about 6 MB


def read_table_text(path: str | os.PathLike, what: str) -> str:
    """The text of a table: missing, not a file, over ``MAX_TABLE_BYTES`` or not UTF-8 text is one
    line naming the file, before more than the bound is read."""
    from mapfilter.io.yamlio import read_yaml_text  # the same bounded, decoded read as a YAML's

    return read_yaml_text(path, what, MAX_TABLE_BYTES)


class CheckedReader:
    """A ``csv.reader`` whose ``csv.Error`` is a ``MapfilterError`` naming the file and line."""

    def __init__(self, reader, path: str | os.PathLike) -> None:
        self._reader = reader
        self._path = Path(path)

    def __iter__(self) -> Iterator[list[str]]:
        return self

    def __next__(self) -> list[str]:
        try:
            return next(self._reader)
        except csv.Error as exc:
            message = str(exc)
            if "field limit" in message:
                message = (f"a field longer than {csv.field_size_limit()} characters (the csv module's limit): not "
                           "a value of this table")
            raise MapfilterError(f"not a CSV line this reads ({message})", self._path,
                                 max(self._reader.line_num, 1)) from None

    @property
    def line_num(self) -> int:
        return self._reader.line_num

    @property
    def dialect(self):
        return self._reader.dialect


def table_reader(handle, path: str | os.PathLike) -> CheckedReader:
    """``csv.reader(handle)``, its errors named by ``path`` and line."""
    return CheckedReader(csv.reader(handle), path)


def table_dict_reader(handle, path: str | os.PathLike) -> csv.DictReader:
    """``csv.DictReader(handle)``, its errors (the header's too) named by ``path`` and line."""
    reader = csv.DictReader(handle)
    reader.reader = CheckedReader(reader.reader, path)
    return reader
