"""Measurement sources besides WiFi, as plug-ins: each one registered once, in one module.

A source is a measurement model (``filter.models.interface.MeasurementModel``) with its stream
adapter (``filter.measurement.MeasurementSource``: a walk's records in, measurements out) and what
the rest of mapfilter needs to reach it, all said by one ``SourcePlugin``:

- ``name``: its config section (``TrackingConfig.sources.<name>``), the key of its input in
  ``mf.track(..., sources={name: ...})`` and of its count in ``TrackResult.n_measurements``,
  and the suffix of its ``evaluate`` methods (``pf+<name>``, ``pf-<name>``, ``pf-floor+<name>``,
  and ``pf-smooth+<name>`` for the offline track);
- ``options``: its files on the command line (``track``, ``evaluate``, ``evaal``);
- ``config``: its config section, a dataclass with a one-line comment per setting;
- ``load``: its files -> its input (a table, ...), checked against the building;
- ``source``: its input -> a walk's ``MeasurementSource`` on the filter's frame
  (``filter.models.frame.StateFrame``);
- ``check``: whether an object is its input (the API takes inputs and files alike);
- ``example``: its files for a walk with ground truth, as its sensor would have measured them:
  the contract tests (``tests/filter/test_source_contract.py``) run every registered source on
  it, so a new source gets them without a line of test code;
- ``survey`` and ``for_walk`` (optional): what an evaluation fits on labelled walks, and the
  input a walk is evaluated with (never fitted on that walk).

From there it reaches ``mf.track``, ``mf.Tracker``, ``mapfilter track`` (a file, many files,
a live stream), ``evaluate``, the offline track's second pass and ``evaal``; nothing else names
it. Every module of this package that sets ``SOURCE`` is one (in name order); a package
installed beside mapfilter adds its own through the entry-point group ``mapfilter.sources``.
The registry protects itself: a plug-in that does not write ``load``, ``source`` and ``check``,
whose name or option another plug-in has, or whose option is a command's own, is left out with
one line saying why (``refusals``), and every other command and source still works.
A plug-in module imports nothing numerical at its top, so that ``--help`` lists its options
without numpy: its hooks import the model and the tables when a run calls them.
docs/models.md writes one.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import pkgutil
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mapfilter.errors import MapfilterError

if TYPE_CHECKING:
    from mapfilter.filter.measurement import MeasurementSource
    from mapfilter.filter.models.frame import StateFrame
    from mapfilter.maps.building import Building
    from mapfilter.sensors.recording import Recording

__all__ = ["ENTRY_POINT_GROUP", "SourceOption", "SourcePlugin", "evaluation_methods", "plugin", "refusals", "refuse",
           "registered"]

ENTRY_POINT_GROUP = "mapfilter.sources"


@dataclasses.dataclass(frozen=True)
class SourceOption:
    """One file of a source on the command line: ``flag`` (``--anchors``) takes a path."""

    flag: str
    metavar: str
    help: str

    @property
    def key(self) -> str:
        """The file's name in ``SourcePlugin.load``'s ``files`` (and argparse's): ``--ranges-log`` -> ``ranges_log``."""
        return self.flag.lstrip("-").replace("-", "_")


class SourcePlugin:
    """A measurement source, registered once (module docstring). Subclass it, set the class
    attributes, write ``load`` and ``source``, and set ``SOURCE = YourPlugin()`` in a module of
    this package (or point the entry point ``mapfilter.sources`` at it)."""

    name: str = ""  # lower case, letters, digits and _: the config section and the methods' suffix
    title: str = ""  # what it is, for help texts and the config's comment ("ranges to anchors")
    options: tuple[SourceOption, ...] = ()  # its files; all of them are given together
    config: type | None = None  # its config section: a frozen dataclass with defaults
    counts: str = "measurements"  # what a run's summary calls its measurements ("range sets")
    alone: bool = True  # it can place the walker without WiFi (evaluate's pf-<name>)
    help: str = ""  # a paragraph for `mapfilter track --help`

    def load(self, files: Mapping[str, Path], building: Building) -> Any:
        """Its input from its files (``{option.key: path}``), checked against ``building``; every
        problem a ``MapfilterError`` naming the file (and line)."""
        raise NotImplementedError

    def source(self, given: Any, frame: StateFrame, config: Any) -> MeasurementSource:
        """A walk's measurement source on ``frame`` from its input, with its config section."""
        raise NotImplementedError

    def check(self, given: Any) -> Any:
        """``given`` if it is this source's input (what ``load`` returns), else a ``TypeError``
        naming what was expected: ``mf.track(..., sources={name: given})`` takes an input or its
        files, and a wrong object must fail here, in one line, not deep inside a run. Every
        source writes it (a source that does not is refused)."""
        raise NotImplementedError

    def example(self, log: Path, building: Building, folder: Path, rng: Any) -> tuple[dict[str, Path], Path]:
        """Its files for the walk of ``log`` (a log with ground truth: waypoints every few
        metres), written into ``folder`` as its sensor would have measured them along the truth
        (``rng``: a ``numpy.random.Generator``), and the log to track with them (``log``, or a
        copy with the source's rows added). The contract tests run every source on it."""
        raise NotImplementedError(f"source {self.name!r} writes no example (docs/models.md)")

    def survey(self, given: Any, building: Building, recordings: Sequence[Recording]) -> Any:
        """What an evaluation takes from labelled walks once for all its walks (None: nothing)."""
        return None

    def for_walk(self, given: Any, survey: Any, left_out: Sequence[str]) -> Any:
        """The input a walk is evaluated with, from ``survey`` (the labelled walks') less the walks
        ``left_out`` (by trace name: the walk itself, or its group). By default the input as given."""
        return given

    def __repr__(self) -> str:
        return f"<source {self.name}: {self.title}>"


@functools.cache
def _discovered() -> tuple[tuple[SourcePlugin, ...], tuple[str, ...]]:
    """(the sources found and accepted, a line for each one refused): this package's modules'
    in name order, then installed packages' entry points; each checked against those before it."""
    found: dict[str, tuple[SourcePlugin, str]] = {}
    refused: list[str] = []
    candidates = []
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if not info.name.startswith("_"):
            candidates.append((f"module {__name__}.{info.name}",
                               lambda name=info.name: getattr(importlib.import_module(f"{__name__}.{name}"), "SOURCE",
                                                              None)))
    from importlib.metadata import entry_points

    for point in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda p: p.name):
        candidates.append((f"entry point {point.name} ({point.value})", point.load))
    for where, load in candidates:
        try:
            entry = load()
        except Exception as exc:  # a broken installed package must not stop every command
            refused.append(f"{where}: left out, it does not load: {type(exc).__name__}: {exc}")
            continue
        if entry is None:
            continue
        problem = _problem(entry, where, found)
        if problem:
            refused.append(f"{where}: left out: {problem}")
        else:
            found[entry.name] = (entry, where)
    return tuple(entry for entry, _ in found.values()), tuple(refused)


def _problem(entry: Any, where: str, found: dict[str, tuple[SourcePlugin, str]]) -> str | None:
    """Why ``entry`` cannot be registered beside ``found`` (None: it can)."""
    if not isinstance(entry, SourcePlugin):
        return f"SOURCE must be a SourcePlugin, got {type(entry).__name__}"
    name = entry.name
    if not name or not name.replace("_", "").isalnum() or name != name.lower():
        return f"a source's name is lower-case letters, digits and _, got {name!r}"
    if name in found:
        return f"the name {name!r} is already the source of {found[name][1]}"
    if entry.config is None or not dataclasses.is_dataclass(entry.config):
        return f"source {name!r} needs a config section (a dataclass)"
    missing = [hook for hook in ("load", "source", "check") if getattr(type(entry), hook) is getattr(SourcePlugin, hook)]
    if missing:
        return f"source {name!r} does not write {', '.join(missing)} (docs/models.md)"
    taken = {option.flag: (other, other_where) for other, other_where in found.values() for option in other.options}
    keys = {option.key: (other, other_where) for other, other_where in found.values() for option in other.options}
    for option in entry.options:
        if not option.flag.startswith("--") or len(option.flag) < 4:
            return f"source {name!r}: an option is --name, got {option.flag!r}"
        clash = taken.get(option.flag) or keys.get(option.key)
        if clash:
            return (f"source {name!r} takes {option.flag}, which source {clash[0].name!r} of {clash[1]} takes "
                    f"already")
    return None


_refused_by_caller: dict[str, str] = {}  # source name -> why a caller refused it (``refuse``)


def registered() -> tuple[SourcePlugin, ...]:
    """Every registered source: this package's modules', then installed packages' (entry points);
    a source that clashes with one before it, or that a caller refused, is left out
    (``refusals``)."""
    return tuple(entry for entry in _discovered()[0] if entry.name not in _refused_by_caller)


def refusals() -> list[str]:
    """One line per source left out, and why."""
    return [*_discovered()[1], *_refused_by_caller.values()]


def refuse(entry: SourcePlugin, reason: str) -> None:
    """Leave a registered source out from now on (the command line refuses a source whose option
    is one of a command's own)."""
    _refused_by_caller[entry.name] = f"source {entry.name!r}: left out: {reason}"


def plugin(name: str) -> SourcePlugin:
    """The registered source ``name``; a ``MapfilterError`` naming the known ones otherwise."""
    for entry in registered():
        if entry.name == name:
            return entry
    known = ", ".join(p.name for p in registered()) or "none"
    raise MapfilterError(f"no measurement source named {name!r} (registered: {known})")


def evaluation_methods(single_floor: bool) -> dict[str, tuple[str, str]]:
    """{method: (source name, what it runs)} of every registered source: ``pf+<name>`` (pf with
    the source too), ``pf-floor+<name>`` in a building (pf-floor with it), ``pf-<name>`` (the
    source alone, no WiFi) where it can place the walker alone."""
    methods: dict[str, tuple[str, str]] = {}
    for entry in registered():
        methods[f"pf+{entry.name}"] = (entry.name, "pf")
        if not single_floor:
            methods[f"pf-floor+{entry.name}"] = (entry.name, "pf-floor")
        if entry.alone:
            methods[f"pf-{entry.name}"] = (entry.name, "alone")
    return methods
