"""Which walks leave the survey together: the protocols of ``mapfilter evaluate``.

Leave-one-walk-out drops one walk from the radio map it is scored with; the other repetitions
of its route stay in, so the walk is scored where the survey walked. Leave-one-group-out drops
every walk of the walk's group: every repetition of an IPIN trial (``by_ipin_trial``, the route
a competition's scoring trial walks unsurveyed), or any grouping a user gives by a regular
expression over the log file names (``by_regex``) or a CSV file of ``log,group`` rows
(``from_csv``). A ``Grouping`` maps every walk's trace name (``sensors.recording.trace_name``)
to its group and names the protocol for the tables.
"""

from __future__ import annotations

import csv
import dataclasses
import os
import re
from collections.abc import Iterable, Mapping
from pathlib import Path

from mapfilter.errors import MapfilterError
from mapfilter.sensors.recording import Recording, trace_name

__all__ = ["IPIN_TRIAL", "Grouping", "by_ipin_trial", "by_regex", "each_walk", "from_csv", "walk_file_name"]

# a GetSensorData training log of the IPIN competitions: IPIN2023_T3_TrainingTrial03_repetition02
IPIN_TRIAL = re.compile(r"TrainingTrial(\d+)_repetition\d+", re.IGNORECASE)


@dataclasses.dataclass(frozen=True)
class Grouping:
    """Every walk's group: a walk is scored with a survey that holds no walk of its group."""

    protocol: str  # what the tables say ran, e.g. "leave-one-route-out (IPIN trials)"
    group_of: Mapping[str, str]  # trace name -> group
    unit: str = "group"  # what a group is, for the per-group table ("route", "walk", "group")

    def group(self, trace: str) -> str:
        """The walk's group (``MapfilterError`` for a walk the grouping does not know)."""
        try:
            return self.group_of[trace]
        except KeyError:
            raise MapfilterError(f"the grouping ({self.protocol}) names no group for walk {trace}") from None

    def members(self, trace: str) -> list[str]:
        """Every walk of ``trace``'s group, ``trace`` among them."""
        group = self.group(trace)
        return [t for t, g in self.group_of.items() if g == group]

    def groups(self) -> list[str]:
        """The groups in order of first appearance."""
        return list(dict.fromkeys(self.group_of.values()))

    def describe(self) -> str:
        """One line: the protocol and the sizes of its groups."""
        sizes = [list(self.group_of.values()).count(g) for g in self.groups()]
        span = f"{min(sizes)}" if min(sizes) == max(sizes) else f"{min(sizes)}-{max(sizes)}"
        return (f"{self.protocol}: {len(sizes)} {self.unit}{'s' if len(sizes) != 1 else ''} of {span} "
                f"walk{'s' if max(sizes) != 1 else ''}")

    def checked(self, traces: Iterable[str]) -> Grouping:
        """This grouping, restricted to ``traces``, each of which it must name."""
        traces = list(traces)
        for trace in traces:
            self.group(trace)
        return dataclasses.replace(self, group_of={t: self.group_of[t] for t in traces})


def walk_file_name(walk: str | os.PathLike | Recording) -> str:
    """The name a grouping reads: a log's file name, or a ``Recording``'s (its file's, else its own)."""
    if isinstance(walk, Recording):
        return walk.path.name if walk.path is not None else walk.name
    return Path(walk).name


def _trace(walk: str | os.PathLike | Recording) -> str:
    return walk.name if isinstance(walk, Recording) else trace_name(walk)


def each_walk(walks: Iterable[str | os.PathLike | Recording]) -> Grouping:
    """Leave-one-walk-out: every walk its own group."""
    return Grouping("leave-one-walk-out", {_trace(w): _trace(w) for w in walks}, "walk")


def by_ipin_trial(walks: Iterable[str | os.PathLike | Recording]) -> Grouping:
    """Leave-one-route-out over IPIN training logs: a walk's group is its trial number
    (``IPIN2023_T3_TrainingTrial03_repetition02`` -> ``T03``), every repetition of a trial one
    route. Refuses, in one line, a walk whose name is not such a log's."""
    groups = {}
    for walk in walks:
        name = walk_file_name(walk)
        match = IPIN_TRIAL.search(name)
        if match is None:
            raise MapfilterError(f"--leave-out route cannot tell the route of {name}: it knows IPIN training logs "
                                 f"(..._TrainingTrialNN_repetitionR); group other walks with --leave-out-group REGEX "
                                 f"or --groups FILE")
        groups[_trace(walk)] = f"T{match.group(1)}"
    return Grouping("leave-one-route-out (IPIN trials)", groups, "route")


def by_regex(walks: Iterable[str | os.PathLike | Recording], pattern: str) -> Grouping:
    """Leave-one-group-out by a regular expression searched in each log's file name: its first
    group (or the whole match, without groups) is the walk's group. Refuses, in one line, a bad
    expression and a file name it does not match."""
    try:
        regex = re.compile(pattern)
    except re.error as exc:
        raise MapfilterError(f"--leave-out-group {pattern!r} is not a regular expression: {exc}") from None
    groups = {}
    for walk in walks:
        name = walk_file_name(walk)
        match = regex.search(name)
        if match is None:
            raise MapfilterError(f"--leave-out-group {pattern!r} does not match the log {name}: every walk needs a "
                                 f"group")
        group = match.group(1) if regex.groups else match.group(0)
        if not group:
            raise MapfilterError(f"--leave-out-group {pattern!r} gives the log {name} an empty group")
        groups[_trace(walk)] = group
    return Grouping(f"leave-one-group-out (groups by {pattern!r})", groups)


def from_csv(path: str | os.PathLike, walks: Iterable[str | os.PathLike | Recording]) -> Grouping:
    """Leave-one-group-out by a CSV file with a header ``log,group`` and one row per log: the
    log by its file name or trace name (a path's folder is ignored). Refuses, in one line naming
    the file (and line), another header, an empty group, a log given two groups, and a walk the
    file does not name."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise MapfilterError(f"cannot read the groups file: {getattr(exc, 'strerror', None) or exc}", path) from None
    rows = list(csv.reader(text.splitlines()))
    if not rows or [c.strip().lower() for c in rows[0]] != ["log", "group"]:
        raise MapfilterError("the groups file needs the header 'log,group' on its first line", path, 1)
    given: dict[str, str] = {}
    for number, row in enumerate(rows[1:], start=2):
        if not row or not "".join(row).strip():
            continue
        if len(row) != 2 or not row[0].strip() or not row[1].strip():
            raise MapfilterError(f"expected 'log,group', got {','.join(row)!r}", path, number)
        log, group = trace_name(Path(row[0].strip()).name), row[1].strip()
        if given.setdefault(log, group) != group:
            raise MapfilterError(f"log {log} is given two groups ({given[log]}, {group})", path, number)
    groups = {}
    for walk in walks:
        trace = _trace(walk)
        if trace not in given:
            raise MapfilterError(f"names no group for the log {walk_file_name(walk)}", path)
        groups[trace] = given[trace]
    return Grouping(f"leave-one-group-out (groups from {path.name})", groups)
