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
- ``survey`` and ``for_walk`` (optional): what an evaluation fits on labelled walks, and the
  input a walk is evaluated with (never fitted on that walk).

From there it reaches ``mf.track``, ``mf.Tracker``, ``mapfilter track`` (a file, many files,
a live stream), ``evaluate``, the offline track's second pass and ``evaal``; nothing else names
it. Every module of this package that sets ``SOURCE`` is one (in name order); a package
installed beside mapfilter adds its own through the entry-point group ``mapfilter.sources``.
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

__all__ = ["ENTRY_POINT_GROUP", "SourceOption", "SourcePlugin", "evaluation_methods", "plugin", "registered"]

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
        naming what was expected (the Python API takes inputs and files alike)."""
        return given

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
def registered() -> tuple[SourcePlugin, ...]:
    """Every registered source: this package's modules', then installed packages' (entry points)."""
    found: dict[str, SourcePlugin] = {}
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        _add(found, getattr(importlib.import_module(f"{__name__}.{info.name}"), "SOURCE", None), info.name)
    from importlib.metadata import entry_points

    for point in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda p: p.name):
        _add(found, point.load(), f"entry point {point.name} ({point.value})")
    return tuple(found.values())


def _add(found: dict[str, SourcePlugin], plugin: Any, where: str) -> None:
    if plugin is None:
        return
    if not isinstance(plugin, SourcePlugin):
        raise TypeError(f"{where}: SOURCE must be a SourcePlugin, got {type(plugin).__name__}")
    name = plugin.name
    if not name or not name.replace("_", "").isalnum() or name != name.lower():
        raise TypeError(f"{where}: a source's name is lower-case letters, digits and _, got {name!r}")
    if name in found:
        raise TypeError(f"{where}: a source named {name!r} is registered twice")
    if plugin.config is None or not dataclasses.is_dataclass(plugin.config):
        raise TypeError(f"{where}: source {name!r} needs a config section (a dataclass)")
    found[name] = plugin


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
