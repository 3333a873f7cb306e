"""The rerun stream every layer draws on: timelines, and entities that show or clear per step."""

from __future__ import annotations

from typing import Any

import numpy as np

from mapfilter.viz.style import UNIX_TIME_MIN_S


class Canvas:
    """One rerun recording stream (``rec``), the rerun module (``rr``) and the ``trace_time`` clock.

    ``trace_time`` is a timestamp when the first time seen looks like Unix seconds, else a
    duration (see the package docstring); the choice is made once.
    """

    def __init__(self, rr: Any, rec: Any) -> None:
        self.rr = rr
        self.rec = rec
        self._time_is_unix: bool | None = None
        self._shown: set[str] = set()  # temporal entities currently showing something

    def log(self, path: str, *args: Any, **kwargs: Any) -> None:
        self.rec.log(path, *args, **kwargs)

    def set_time(self, t_s: float, step: int | None = None) -> None:
        if self._time_is_unix is None:
            self._time_is_unix = t_s >= UNIX_TIME_MIN_S
        if self._time_is_unix:
            self.rec.set_time("trace_time", timestamp=float(t_s))
        else:
            self.rec.set_time("trace_time", duration=float(t_s))
        if step is not None:
            self.rec.set_time("step", sequence=int(step))

    def time_column(self, t_s: np.ndarray) -> Any:
        if self._time_is_unix is None:
            self._time_is_unix = bool(t_s.size) and float(t_s[0]) >= UNIX_TIME_MIN_S
        kind = "timestamp" if self._time_is_unix else "duration"
        return self.rr.TimeColumn("trace_time", **{kind: np.asarray(t_s, dtype=np.float64)})

    def show(self, path: str, archetype: Any | None) -> None:
        """Log ``archetype`` at ``path``, or clear ``path`` if it showed something before."""
        if archetype is not None:
            self.rec.log(path, archetype)
            self._shown.add(path)
        elif path in self._shown:
            self.rec.log(path, self.rr.Clear(recursive=False))
            self._shown.discard(path)
