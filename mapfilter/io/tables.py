"""The CSV tables a user writes (access-point tables, measurement sources' tables) and the track files read
back: the text of a table read whole within a bound, and the csv module's own refusals (a field
longer than its limit, a NUL byte) as one line naming the file and line.

``read_csv_table`` is a table with a header, its rows checked for their field count;
``CsvTable.number`` a value checked for its range. ``read_timed_table`` is a table of rows
stamped on a log's clock beside the log (a measurement source's: ranges to anchors), its
columns numbers within a range or names looked up in another table, sorted by time."""

from __future__ import annotations

import csv
import dataclasses
import io
import math
import os
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from mapfilter.errors import MapfilterError

MAX_TABLE_BYTES = 16 << 20  # 16 MiB: a table of 100 000 transmitters is about 6 MB
# a timed table beside a log: 64 MiB holds 2 million rows (8 anchors ranged at 10 Hz for 7 hours)
MAX_TIMED_TABLE_BYTES = 64 << 20
# a row's time on a log's clock: Unix seconds, or seconds since the app started
TIME_RANGE_S = (-1e11, 1e11)


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


def finite_number(text: str | None, name: str, path: str | os.PathLike, line_no: int) -> float:
    """A CSV field (``name``'s, None where the row lacks it) as a finite number; else one line naming
    the file, line and column."""
    try:
        value = float(text)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise MapfilterError(f"column {name} is not a number: {text!r}", path, line_no) from None
    if not math.isfinite(value):
        raise MapfilterError(f"column {name} is not finite: {text!r}", path, line_no)
    return value


@dataclasses.dataclass(frozen=True)
class CsvTable:
    """A CSV table with a header: ``column`` maps each lower-case column name to its index,
    ``rows`` holds (line number, fields) of every non-blank row."""

    path: Path
    header: list[str]
    column: dict[str, int]
    rows: list[tuple[int, list[str]]]

    def number(self, fields: list[str], name: str, line_no: int, low: float = -math.inf,
               high: float = math.inf, label: str | None = None) -> float:
        """Column ``name`` of a row as a finite number within [low, high]; else one line naming
        the file and line (and the column as ``label``, by default ``name``)."""
        text = fields[self.column[name]]
        label = name if label is None else label
        try:
            value = float(text)
        except ValueError:
            raise MapfilterError(f"column {label} is not a number: {text.strip()!r}", self.path, line_no) from None
        if not math.isfinite(value):
            raise MapfilterError(f"column {label} is not finite: {text.strip()!r}", self.path, line_no)
        if not low <= value <= high:
            raise MapfilterError(f"column {label} is {value:g}, outside {low:g} to {high:g}", self.path, line_no)
        return value


def read_csv_table(path: str | os.PathLike, what: str, max_bytes: int = MAX_TABLE_BYTES) -> CsvTable:
    """A CSV table with a header, read whole within ``max_bytes``: an empty file, a row with fewer
    fields than the header or no rows at all is one line naming the file (and line)."""
    from mapfilter.io.yamlio import read_yaml_text

    path = Path(path)
    text = read_yaml_text(path, what, max_bytes)
    reader = table_reader(io.StringIO(text, newline=""), path)
    header = next(reader, None)
    if header is None:
        raise MapfilterError(f"{what} is empty: it needs a header line", path, 1)
    rows = []
    for fields in reader:
        if not any(f.strip() for f in fields):
            continue
        if len(fields) < len(header):
            raise MapfilterError(f"{len(fields)} fields, the header has {len(header)}", path, reader.line_num)
        rows.append((reader.line_num, fields))
    if not rows:
        raise MapfilterError(f"{what} has no rows", path)
    return CsvTable(path, header, {name.strip().lower(): j for j, name in enumerate(header)}, rows)


@dataclasses.dataclass(frozen=True)
class Column:
    """A column of a timed table: a number within [``low``, ``high``], or, with ``names``, a name
    that must be one of them (its value is the name's index: a row of another table)."""

    name: str
    low: float = -math.inf
    high: float = math.inf
    names: Mapping[str, int] | None = None
    names_in: str = ""  # where the names come from, for the message ("the anchor table anchors.csv")
    called: str = ""  # what a name names, for the message ("anchor"; default: the column's name)


@dataclasses.dataclass(frozen=True)
class TimedTable:
    """Rows stamped on a log's clock, in time order (stably sorted): ``t_s`` (R,) and each
    column's values (R,) (floats; a name column's indices as int64)."""

    t_s: Any  # numpy (R,) float64
    columns: dict[str, Any]
    path: Path | None = None  # the CSV it was read from (for messages)
    lines: Any = None  # numpy (R,) int64: each row's line in that CSV (a check after reading names it), or None

    def __len__(self) -> int:
        return int(self.t_s.size)

    def rows(self, index) -> dict[str, Any]:
        """Column -> the values of rows ``index`` (a slice or an index array)."""
        return {name: values[index] for name, values in self.columns.items()}


def read_timed_table(path: str | os.PathLike, what: str, columns: Sequence[Column]) -> TimedTable:
    """A table with a ``t_s`` column (seconds on the log's clock) and ``columns``, rows in any
    order; every problem is one line naming the file and line, and a file over
    ``MAX_TIMED_TABLE_BYTES`` is refused before more is read."""
    import numpy as np

    table = read_csv_table(path, what, MAX_TIMED_TABLE_BYTES)
    needed = ["t_s", *(c.name for c in columns)]
    missing = [name for name in needed if name not in table.column]
    if missing:
        raise MapfilterError(f"{what} needs the columns {','.join(needed)} (missing: {', '.join(missing)})",
                             table.path, 1)
    t_s = np.array([table.number(fields, "t_s", line, *TIME_RANGE_S) for line, fields in table.rows])
    values = {}
    for column in columns:
        if column.names is None:
            values[column.name] = np.array([table.number(fields, column.name, line, column.low, column.high)
                                            for line, fields in table.rows])
            continue
        found = []
        for line, fields in table.rows:
            name = fields[table.column[column.name]].strip()
            if name not in column.names:
                raise MapfilterError(f"{column.called or column.name} {name!r} is not in {column.names_in}".rstrip(),
                                     table.path, line)
            found.append(column.names[name])
        values[column.name] = np.array(found, dtype=np.int64)
    order = np.argsort(t_s, kind="stable")
    lines = np.array([line for line, _ in table.rows], dtype=np.int64)
    return TimedTable(t_s[order], {name: v[order] for name, v in values.items()}, table.path, lines[order])
