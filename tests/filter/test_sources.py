"""Measurement sources (filter/sources, filter.measurement.MeasurementSource): the registry, and the
adapters' contract that a chunked feed gives the whole file's track.

The BLE walk is test_ble's simulated office walk with beacon readings; every registered source
with a simulated input has its own chunk test beside its plug-in's tests."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mapfilter.config import TrackingConfig
from mapfilter.errors import MapfilterError
from mapfilter.filter.causal import CausalFilter, RunSettings
from mapfilter.filter.measurement import MeasurementSource, ReplayedMeasurements
from mapfilter.filter.evidence import NoWifiEvidence
from mapfilter.filter.sources import SourceOption, SourcePlugin, evaluation_methods, plugin, registered
from mapfilter.io.tracks import write_track
from mapfilter.pipeline.tracker import Tracker, TrackingInputs, track
from mapfilter.sensors.logs import LogStream, read_log
from mapfilter.sensors.pdr import OnlinePDR
from mapfilter.sensors.recording import Recording
from tests.filter.test_ble import OFFICE, _office_table, office_walk  # noqa: F401 - the fixture
from tests.sensors.test_logs_stream import random_pieces


def _csv_bytes(track_, tmp_path, name: str) -> bytes:
    path = tmp_path / f"{name}.csv"
    write_track(track_, path, "csv")
    return path.read_bytes()


def _in_time_order(path, tmp_path):
    """The walk's log with its records in time order, as a phone streams them (test_ble's
    fixture appends the beacon rows at the end)."""
    lines = path.read_text().splitlines(keepends=True)
    records = sorted((line for line in lines if not line.startswith("#")), key=lambda line: int(line.split("\t")[0]))
    ordered = tmp_path / "ordered.txt"
    ordered.write_text("".join([*(line for line in lines if line.startswith("#")), *records]))
    return ordered


def _fed_in_pieces(tracker, data: bytes, rng: np.random.Generator) -> None:
    stream = LogStream("walk")
    for piece in random_pieces(data, rng):
        tracker.feed(stream.feed_bytes(piece))
    tracker.feed(stream.close())
    tracker.close()


# ---- the registry ---------------------------------------------------------------------------------
def test_the_registry_lists_ble_with_its_options_config_and_methods():
    names = [p.name for p in registered()]
    assert "ble" in names and names == sorted(names)
    ble = plugin("ble")
    assert [o.flag for o in ble.options] == ["--beacons"] and ble.options[0].key == "beacons"
    assert TrackingConfig().sources.ble == ble.config()
    assert evaluation_methods(True)["pf+ble"] == ("ble", "pf")
    assert evaluation_methods(False)["pf-floor+ble"] == ("ble", "pf-floor")
    with pytest.raises(MapfilterError, match="no measurement source named 'radar'"):
        plugin("radar")
    with pytest.raises(MapfilterError, match="no measurement source named 'radar'"):
        TrackingInputs(sources={"radar": object()})


class _Complete(SourcePlugin):
    """A plug-in that writes every hook (what each refusal below takes away one at a time)."""

    name = "zz_dummy"  # no source of the package would take this name or option
    title = "a dummy source"
    options = (SourceOption("--zz-dummy", "DUMMY.csv", "dummy"),)
    config = TrackingConfig

    def load(self, files, building):
        return files

    def source(self, given, frame, config):
        raise AssertionError("not run")

    def check(self, given):
        return given


# the package's own sources, in name order (a new source file adds itself here without any edit)
IN_PACKAGE = [p.name for p in registered()]


@pytest.fixture
def installed(monkeypatch):
    """Installs plug-ins as a package's entry points would (``installed(plugin, ...)``; an
    exception: a package that fails to load), with the registry read afresh before and after."""
    import importlib.metadata

    from mapfilter.filter import sources

    def install(*plugins):
        points = [importlib.metadata.EntryPoint(f"p{i}", f"pkg{i}:SOURCE", sources.ENTRY_POINT_GROUP)
                  for i in range(len(plugins))]
        by_value = {p.value: plugin_ for p, plugin_ in zip(points, plugins)}
        def load(point):
            if isinstance(by_value[point.value], Exception):
                raise by_value[point.value]
            return by_value[point.value]

        monkeypatch.setattr(importlib.metadata.EntryPoint, "load", load)
        monkeypatch.setattr(importlib.metadata, "entry_points",
                            lambda group=None: points if group == sources.ENTRY_POINT_GROUP else [])
        sources._discovered.cache_clear()
        sources._refused_by_caller.clear()

    yield install
    monkeypatch.undo()
    sources._discovered.cache_clear()
    sources._refused_by_caller.clear()


@pytest.mark.parametrize("change, problem", [
    ({"name": "Bad Name"}, "lower-case letters"),
    ({"name": "ble"}, "the name 'ble' is already the source of module mapfilter.filter.sources.ble"),
    ({"config": None}, "needs a config section"),
    ({"options": (SourceOption("--beacons", "T", "h"),)},
     "takes --beacons, which source 'ble' of module mapfilter.filter.sources.ble takes already"),
    ({"options": (SourceOption("-t", "T", "h"),)}, "an option is --name"),
    ({"check": SourcePlugin.check}, "does not write check"),
    ({"load": SourcePlugin.load, "source": SourcePlugin.source}, "does not write load, source"),
])
def test_a_plugin_that_breaks_the_rules_is_left_out_in_one_line_naming_both(installed, change, problem):
    bad = type("Bad", (_Complete,), change)()
    installed(bad)
    assert [p.name for p in registered()] == IN_PACKAGE  # the others still work
    from mapfilter.filter.sources import refusals

    lines = refusals()
    assert len(lines) == 1 and lines[0].startswith("entry point p0 (pkg0:SOURCE): left out") and problem in lines[0]


def test_a_plugin_that_is_not_a_plugin_or_does_not_load_is_left_out(installed):
    from mapfilter.filter.sources import refusals

    installed(object(), ImportError("No module named 'numpyy'"))
    assert refusals() == ["entry point p0 (pkg0:SOURCE): left out: SOURCE must be a SourcePlugin, got object",
                          "entry point p1 (pkg1:SOURCE): left out, it does not load: ImportError: No module named "
                          "'numpyy'"]
    installed(_Complete())
    assert [p.name for p in registered()] == [*IN_PACKAGE, "zz_dummy"] and refusals() == []
    assert SourceOption("--ranges-log", "R", "h").key == "ranges_log"


def test_a_plugin_taking_a_commands_own_option_is_left_out_and_every_command_still_runs(installed, capsys):
    """A plug-in using --seed once broke every command, `config show` included, with argparse's
    traceback: now it is left out with one warning line naming it and the command."""
    from mapfilter.cli import main

    installed(type("Seeded", (_Complete,), {"options": (SourceOption("--seed", "S", "h"),)})())
    assert main(["config", "show"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["mapfilter: warning: source 'zz_dummy': left out: its option --seed is `mapfilter track`'s own"]
    assert [p.name for p in registered()] == IN_PACKAGE


def test_a_source_alone_is_tracked_and_nothing_at_all_is_refused(office_walk):
    plan, recording, _, _ = office_walk
    config = TrackingConfig(seed=1).with_particles(1000)
    result = track(plan, recording, config=config, sources={"ble": _office_table()})
    assert result.n_scans_used == 0 and result.n_measurements["ble"] > 30
    with pytest.raises(MapfilterError, match=r"nothing to weigh the particles by: .* BLE beacons \(--beacons\)"):
        track(plan, recording, config=config)


# ---- the adapters' contract ----------------------------------------------------------------------
def _replay_filter(plan, source: MeasurementSource, config: TrackingConfig) -> CausalFilter:
    """The causal filter on the beacons' measurements replayed, no WiFi (as the Tracker builds it)."""
    settings = RunSettings(config.motion, config.filter, config.steps.abs_heading_offset_rad)
    return CausalFilter(plan, NoWifiEvidence("walk"), settings, np.random.default_rng(config.seed),
                        steps=OnlinePDR(config.steps), sources=(ReplayedMeasurements(source, source.model),))


def test_replayed_measurements_fed_in_random_pieces_give_the_original_track(office_walk, tmp_path):
    """ReplayedMeasurements hands over no measurement before a chunk reaches its time: fed 4 KiB
    pieces, or random ones, it gives the track of the source it replays, to the byte, and drops
    no record as late (handing every time over at once gave a fraction of the rows)."""
    plan, _, _, path = office_walk
    path = _in_time_order(path, tmp_path)
    config = TrackingConfig(seed=4).with_particles(1000)
    original = Tracker(plan, TrackingInputs(sources={"ble": _office_table()}), config)
    original.feed(read_log(path))
    original.close()
    source = original.sources[0]
    assert source.n_measurements > 30
    data = path.read_bytes()
    expected = _csv_bytes(original.stream.track(), tmp_path, "original")
    for pieces in ([data[k:k + 4096] for k in range(0, len(data), 4096)], random_pieces(data, np.random.default_rng(3))):
        replay = _replay_filter(plan, source, config)
        stream = LogStream("walk")
        for piece in pieces:
            replay.feed(stream.feed_bytes(piece))
        replay.feed(stream.close())
        replay.close()
        assert replay.late_records == 0
        assert _csv_bytes(replay.track(), tmp_path, "replay") == expected


def test_the_base_class_holds_back_what_runs_ahead_of_the_chunk():
    class Ahead(MeasurementSource):
        stream = "ahead"

        def records_of(self, records):
            return (np.array([1.0, 2.0, 5.0, 9.0]), np.arange(4)) if not self.measurements and self._held is None \
                else (np.zeros(0), np.zeros(0, dtype=np.int64))

        def measure(self, records, final):
            return [(float(t), int(i)) for t, i in zip(*records)]

    def chunk(t_s: float) -> Recording:
        return dataclasses.replace(Recording.empty(), acc_t_s=np.array([t_s]), acc_mps2=np.zeros((1, 3)))

    source = Ahead()
    taken = source.take(chunk(2.0))
    assert taken[0].tolist() == [1.0, 2.0]  # at or before the chunk's newest record
    assert source.take(chunk(3.0)) is None
    assert source.take(chunk(6.0))[0].tolist() == [5.0]
    assert source.take(None)[0].tolist() == [9.0]  # the end of the walk: the rest
    assert source.add(taken, final=False) == [1.0, 2.0] and source.measurement(1) == 1


def test_nothing_but_a_sources_own_files_imports_them():
    """What keeps a source a plug-in (docs/models.md): the filter, the offline track, the pipeline,
    evaluation, batch, evaal, config and the rest reach a source through the registry only, so a
    new source is new files and nothing else changes. A source's own files are its plug-in
    module, its model (``filter/models/NAME.py``) and the sensor tables its plug-in module reads;
    only the API (which re-exports a source's tables: ``mf.load_beacons``) and a command for the
    source's own files (``radiomap fit-beacons``) may import them too."""
    from tests.test_architecture import _imports

    graph = _imports()
    allowed = {"mapfilter.api", "mapfilter.cli.radiomap_cmd", "mapfilter"}
    # the log readers are every stage's (a source's example reads the walk's truth with them)
    readers = {f"mapfilter.sensors.{m}" for m in ("logs", "recording", "logread", "ilc", "ipin", "wifi")}
    for entry in registered():
        module = f"mapfilter.filter.sources.{entry.name}"
        own = {module, f"mapfilter.filter.models.{entry.name}"} | {
            m for m in graph[module] if m.startswith("mapfilter.sensors.")} - readers
        importers = {a for a, targets in graph.items() if targets & own} - own - allowed
        assert importers == set(), (entry.name, sorted(importers))
