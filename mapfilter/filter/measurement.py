"""A measurement source: the adapter between a measurement model and a walk's log.

``MeasurementSource`` is the base class of every source besides the WiFi scans (the registered
plug-ins of ``filter.sources``): a walk's records in, measurements out, merged by time with the
other sensors' records by the causal loop (``filter.causal``). ``TimedTableSource`` is the base
of a source whose measurements come from a table beside the log (``io.tables.TimedTable``: rows
stamped on the log's clock): a new one writes only how a time's rows become a measurement.
``ReplayedMeasurements`` gives one run's measurements to another run over the same walk.

numpy is imported inside the methods: a plug-in module subclasses these at its top, and the
registry imports every plug-in module for ``--help``, which imports no numerical library.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from mapfilter.filter.models.frame import StateFrame
    from mapfilter.filter.models.interface import MeasurementModel
    from mapfilter.io.tables import TimedTable
    from mapfilter.sensors.recording import Recording

__all__ = ["MeasurementSource", "ReplayedMeasurements", "TimedTableSource"]


class MeasurementSource:
    """A stream of measurements besides the WiFi scans, merged by time with the other sensors'
    records: the adapter between a measurement model and the log (a registered source's,
    ``filter.sources``). Subclasses write ``records_of``, ``measure`` and ``model_on``; the
    causal loop calls the rest.

    The contract, which keeps the causal track the same however the log is chunked:

    1. ``records_of(chunk)`` gives the source's records of a chunk, (t_s, values...) in time
       order. It may give records stamped after the chunk's newest record (a table read ahead, a
       replay): the base class holds those back until a chunk reaches their time, or the end
       (``take``). A source never runs ahead of its chunk: a record handed to the merge before
       the other sensors reach its time would make theirs late.
    2. ``measure(records, final)`` gets its records released in time order (every record of every
       sensor before them already released; ``final``: the walk's last) and returns the
       measurements they complete, ``(t_s, measurement)`` in time order, each stamped at or after
       the latest record it uses: a measurement depends only on records stamped at or before its
       time.
    3. ``model_on(frame)`` is its model on another frame (``filter.models.frame.StateFrame``),
       with what the source learnt of the walk (the offline track's second pass on one floor
       weighs the same measurements there: ``ReplayedMeasurements``).

    ``times_s`` and ``measurements`` keep every measurement made, in order.
    """

    stream: str = ""  # the sensor it reads: its records are merged under this name
    model: MeasurementModel
    # how far behind the log's newest record its records can be written (None: unknown; the merge
    # then waits for its next record, as for a dense sensor, which holds the rows of a sparse one)
    written_behind_s: float | None = None

    def __init__(self) -> None:
        self.times_s: list[float] = []
        self.measurements: list = []
        self._held: tuple | None = None  # records stamped after the newest chunk so far

    def records_of(self, records: Recording) -> tuple:
        """(t_s, values...) of its records in a chunk (module docstring of the class: 1)."""
        raise NotImplementedError

    def measure(self, records: tuple, final: bool) -> list[tuple[float, Any]]:
        """The measurements its released records complete (the class docstring: 2)."""
        raise NotImplementedError

    def model_on(self, frame: StateFrame) -> MeasurementModel:
        """Its model on another frame (the class docstring: 3)."""
        raise NotImplementedError

    # ---- what the causal loop calls ---------------------------------------------------------
    def take(self, records: Recording | None) -> tuple | None:
        """Its records of a chunk up to the chunk's newest record (``None``: the end of the walk,
        every record held back), or None when there are none."""
        import numpy as np

        new = self.records_of(records) if records is not None else None
        parts = [p for p in (self._held, new) if p is not None and len(p[0])]
        if not parts:
            self._held = None
            return None
        merged = parts[0] if len(parts) == 1 else _concatenate_records(parts)
        if records is None:
            self._held = None
            return merged
        n = int(np.searchsorted(merged[0], records.newest_t_s, side="right"))
        self._held = tuple(p[n:] for p in merged) if n < len(merged[0]) else None
        return tuple(p[:n] for p in merged) if n else None

    def add(self, records: tuple, final: bool) -> list[float]:
        """Its released records in; the times of the measurements they completed (numbered on)."""
        made = self.measure(records, final)
        for t_s, measurement in made:
            self.times_s.append(float(t_s))
            self.measurements.append(measurement)
        return [float(t_s) for t_s, _ in made]

    def measurement(self, index: int) -> Any:
        """Measurement ``index`` (None when it says nothing)."""
        return self.measurements[index]

    @property
    def n_measurements(self) -> int:
        return len(self.measurements)


def _concatenate_records(parts: list[tuple]) -> tuple:
    import numpy as np

    return tuple(np.concatenate([p[k] for p in parts]) if isinstance(parts[0][k], np.ndarray)
                 else [x for p in parts for x in p[k]] for k in range(len(parts[0])))


class ReplayedMeasurements(MeasurementSource):
    """The measurements another source made of a walk, given again to another run over it,
    weighed by ``model`` (e.g. on one floor's map: ``original.model_on``). Its
    records are the measurements' times, handed over as the run's chunks reach them."""

    def __init__(self, original: MeasurementSource, model: MeasurementModel) -> None:
        super().__init__()
        self.stream, self.model = original.stream, model
        self.written_behind_s = 0.0  # every measurement up to the chunk's newest record is handed over
        self._original = original
        import numpy as np

        self._replayed_t = np.asarray(original.times_s, dtype=np.float64)
        self._replayed = list(original.measurements)
        self._given = 0

    def records_of(self, records: Recording) -> tuple:
        """Every measurement not handed over yet (the base class holds back those ahead of the chunk)."""
        import numpy as np

        start, self._given = self._given, len(self._replayed)
        return self._replayed_t[start:], np.arange(start, len(self._replayed))

    def measure(self, records: tuple, final: bool) -> list[tuple[float, Any]]:
        return [(float(t), self._replayed[int(i)]) for t, i in zip(*records)]

    def model_on(self, frame) -> MeasurementModel:
        return self._original.model_on(frame)


class TimedTableSource(MeasurementSource):
    """A source whose records are the rows of a table beside the log (``io.tables.TimedTable``:
    ``t_s`` on the log's clock and the table's columns), handed over as the log's chunks reach
    their times, and only the walk's own: from its log's start (the header's, where it gives one)
    to its newest record. The rows stamped at one time are one measurement, at that time: it
    depends on nothing later. A subclass sets ``stream`` and ``model`` and writes ``model_on`` and
    ``from_rows``."""

    written_behind_s = 0.0  # every row up to the chunk's newest record is handed over

    def __init__(self, table: TimedTable) -> None:
        super().__init__()
        self.table = table
        self._given = 0  # rows of the table handed over (or passed over, before the walk)
        self._start_s: float | None = None  # the walk's start by its log's header, if it gives one

    def from_rows(self, t_s: float, rows: dict[str, Any]) -> Any:
        """The measurement of the rows stamped ``t_s`` (``rows``: column -> the rows' values)."""
        raise NotImplementedError

    def records_of(self, records: Recording) -> tuple:
        """(t_s, row index) of the table's rows the chunk's records reached."""
        import numpy as np

        t_s = self.table.t_s
        if self._start_s is None and records.start_t_s is not None:
            self._start_s = float(records.start_t_s)
            self._given = max(self._given, int(np.searchsorted(t_s, self._start_s, side="left")))
        stop = int(np.searchsorted(t_s, records.newest_t_s, side="right"))
        start, self._given = self._given, max(self._given, stop)
        return t_s[start:stop], np.arange(start, max(start, stop))

    def measure(self, records: tuple, final: bool) -> list[tuple[float, Any]]:
        """The rows stamped at one time, a measurement each (all of one time come in one chunk)."""
        import numpy as np

        t_s, row = records
        cuts = np.flatnonzero(np.diff(t_s)) + 1
        return [(float(t_s[a]), self.from_rows(float(t_s[a]), self.table.rows(row[a:b])))
                for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(t_s)])]
