"""The project's exception: errors a user can cause, reported as one line."""

from __future__ import annotations

import os


class MapfilterError(Exception):
    """An error caused by the user's input (file, value, option).

    The CLI catches it and prints ``str(error)`` as one line with a non-zero exit
    code; anything else is a bug and is allowed to crash loudly.
    """

    def __init__(self, message: str, path: str | os.PathLike | None = None, line: int | None = None):
        self.path = None if path is None else os.fspath(path)
        self.line = line
        self.reason = message
        where = ""
        if self.path is not None:
            where = self.path + (f":{line}" if line is not None else "") + ": "
        super().__init__(where + message)


def not_a_file(path: str | os.PathLike, hint: str = "") -> MapfilterError:
    """The error for a path that should be a file but is not: a directory says so (with ``hint``,
    e.g. which files in it were meant), anything else is not found."""
    if os.path.isdir(path):
        return MapfilterError("is a directory, not a file" + (f" ({hint})" if hint else ""), path)
    return MapfilterError("file not found", path)
