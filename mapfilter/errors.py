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
