"""The contract every registered measurement source keeps (docs/models.md, "The tests it
needs"), run over each one on the files its plug-in's ``example`` draws for the bundled walk: a
new source gets these tests by writing ``example``, without a line of test code.

Its files load and its input is checked; a bad file is one line naming it; it is tracked by
``mf.track`` beside the WiFi (and alone where it can place the walker); ``mapfilter track``
writes the API's track; a live run (``track MAP -``), a log fed in random pieces and a log cut at
half its time span give the whole file's rows; the offline track replays its measurements;
``evaluate`` runs its methods; its config section is saved and reloaded."""

from __future__ import annotations

import csv
import dataclasses
import gzip
import io
import sys

import numpy as np
import pytest

import mapfilter as mf
from mapfilter.cli import main
from mapfilter.config import TrackingConfig
from mapfilter.errors import MapfilterError
from mapfilter.filter.sources import SourcePlugin, evaluation_methods, registered
from mapfilter.pipeline.tracker import Tracker, TrackingInputs
from mapfilter.sensors.logs import LogStream, read_log
from tests.conftest import REPO
from tests.sensors.test_logs_stream import random_pieces

OFFICE = REPO / "maps" / "office.yaml"
WALK = REPO / "maps" / "office_walk.txt.gz"
RADIO_MAP = REPO / "maps" / "office_radiomap.npz"
PARTICLES = 1500


@pytest.fixture(scope="module", params=[p.name for p in registered()])
def source(request, tmp_path_factory):
    """(plug-in, its files for the bundled walk, the log to track with them)."""
    from mapfilter.filter.sources import plugin

    entry = plugin(request.param)
    folder = tmp_path_factory.mktemp(f"source_{entry.name}")
    files, log = entry.example(WALK, mf.load_map(OFFICE), folder, np.random.default_rng(7))
    assert set(files) == {o.key for o in entry.options}
    return entry, files, log


def _config(**settings) -> TrackingConfig:
    return TrackingConfig(seed=1).override({"filter.n_particles": PARTICLES, **settings})


def _flags(entry: SourcePlugin, files: dict) -> list[str]:
    return [arg for o in entry.options for arg in (o.flag, str(files[o.key]))]


@pytest.mark.parametrize("name", [p.name for p in registered()])
def test_every_registered_source_writes_an_example(name):
    from mapfilter.filter.sources import plugin

    assert type(plugin(name)).example is not SourcePlugin.example, f"source {name!r} writes no example"


def test_its_files_load_and_its_input_is_checked(source):
    entry, files, _ = source
    given = entry.load(files, mf.load_map(OFFICE))
    assert entry.check(given) is given
    with pytest.raises(TypeError, match=entry.name):
        entry.check(object())


@pytest.mark.parametrize("bad", [b"", b"\x00\x01\x02 not a table \xff"])
def test_a_bad_file_is_one_line_naming_it(source, tmp_path, capsys, bad):
    entry, files, log = source
    for option in entry.options:
        broken = tmp_path / f"broken_{option.key}.csv"
        broken.write_bytes(bad)
        given = {**files, option.key: broken}
        assert main(["track", str(OFFICE), str(log), *_flags(entry, given), "--out", str(tmp_path / "t.csv")]) == 1
        err = capsys.readouterr().err.strip()
        assert err.startswith(f"mapfilter: error: {broken}") and "\n" not in err, err
        assert not (tmp_path / "t.csv").exists()


def test_it_is_tracked_beside_the_wifi_and_alone_where_it_can_be(source):
    entry, files, log = source
    walk = read_log(log)
    both = mf.track(OFFICE, walk, radio_map=RADIO_MAP, config=_config(), sources={entry.name: files})
    assert both.n_measurements[entry.name] > 10
    assert np.isfinite(both.causal.xy_m).all()
    if entry.alone:
        alone = mf.track(OFFICE, walk, config=_config(), sources={entry.name: files})
        assert alone.n_scans_used == 0 and alone.n_measurements[entry.name] == both.n_measurements[entry.name]
    # its loaded input is taken as well as its files
    loaded = mf.load_sources({entry.name: files}, OFFICE)
    again = mf.track(OFFICE, walk, radio_map=RADIO_MAP, config=_config(), sources=loaded)
    np.testing.assert_array_equal(again.causal.xy_m, both.causal.xy_m)


def test_mapfilter_track_writes_the_apis_track(source, tmp_path):
    entry, files, log = source
    out = tmp_path / "track.csv"
    assert main(["track", str(OFFICE), str(log), "--radiomap", str(RADIO_MAP), *_flags(entry, files),
                 "--particles", str(PARTICLES), "--seed", "1", "--out", str(out)]) == 0
    api = mf.track(OFFICE, log, radio_map=RADIO_MAP, config=_config(), sources={entry.name: files})
    mf.write_track(api.causal, tmp_path / "api.csv")
    assert out.read_bytes() == (tmp_path / "api.csv").read_bytes()


def _log_bytes(log) -> bytes:
    data = log.read_bytes()
    return gzip.decompress(data) if data[:2] == b"\x1f\x8b" else data


def test_a_live_run_is_the_file_runs_track(source, tmp_path, monkeypatch):
    entry, files, log = source
    options = [*_flags(entry, files), "--radiomap", str(RADIO_MAP), "--particles", str(PARTICLES), "--seed", "3"]
    whole = tmp_path / "file.csv"
    assert main(["track", str(OFFICE), str(log), *options, "--out", str(whole)]) == 0
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BufferedReader(io.BytesIO(_log_bytes(log)))))
    live = tmp_path / "live.csv"
    assert main(["track", str(OFFICE), "-", *options, "--out", str(live)]) == 0
    assert live.read_bytes() == whole.read_bytes()


def _rows(tracker: Tracker) -> tuple:
    return tracker.causal.t_s, tracker.causal.xy_m, tracker.causal.std_m


def test_fed_in_random_pieces_or_cut_at_half_it_gives_the_whole_files_rows(source):
    entry, files, log = source
    inputs = TrackingInputs(mf.load_radio_map(RADIO_MAP), sources=mf.load_sources({entry.name: files}, OFFICE))
    building, config = mf.load_map(OFFICE), _config(seed=5)
    whole = Tracker(building, inputs, config)
    walk = read_log(log)
    whole.feed(walk)
    whole.close()
    data = _log_bytes(log)
    for seed in (1, 2):
        tracker = Tracker(building, inputs, config)
        stream = LogStream("walk")
        for piece in random_pieces(data, np.random.default_rng(seed)):
            tracker.feed(stream.feed_bytes(piece))
        tracker.feed(stream.close())
        tracker.close()
        assert tracker.stream.late_records == 0
        for a, b in zip(_rows(whole), _rows(tracker)):
            np.testing.assert_array_equal(a, b)
        assert tracker.sources[0].n_measurements == whole.sources[0].n_measurements
    # cut at half its time span: every causal row up to the cut is the whole log's
    cut_t = 0.5 * (whole.causal.t_s[0] + walk.newest_t_s)
    half = Tracker(building, inputs, config)
    half.feed(walk.until(cut_t))
    half.close()
    n = int(np.searchsorted(whole.causal.t_s, cut_t, side="right"))
    assert 5 < len(half.causal.t_s) <= n
    for a, b in zip(_rows(whole), _rows(half)):
        np.testing.assert_array_equal(a[:len(half.causal.t_s)], b)


def test_the_offline_track_replays_its_measurements(source):
    entry, files, log = source
    result = mf.track(OFFICE, log, radio_map=RADIO_MAP, config=_config(smooth=True), sources={entry.name: files})
    assert result.offline is not None and np.isfinite(result.offline.xy_m).all()
    assert result.restarted is not None and len(result.restarted.t_s) > len(result.causal.t_s) * 0.5


def test_evaluate_runs_its_methods(source, tmp_path):
    entry, files, log = source
    methods = [m for m, (name, _) in evaluation_methods(True).items() if name == entry.name]
    assert f"pf+{entry.name}" in methods and (f"pf-{entry.name}" in methods) == entry.alone
    out = tmp_path / "eval"
    assert main(["evaluate", str(OFFICE), str(log), "--radiomap", str(RADIO_MAP), *_flags(entry, files),
                 "--methods", ",".join(["pf", *methods]), "--particles", str(PARTICLES), "--out", str(out)]) == 0
    with (out / "summary.csv").open() as handle:
        summary = {row["method"]: row for row in csv.DictReader(handle)}
    assert {"pf", *methods} <= set(summary)
    assert all(np.isfinite(float(summary[m]["mean"])) for m in methods)


def test_its_settings_are_saved_and_reloaded(source):
    entry, _, _ = source
    section = entry.config()
    assert getattr(TrackingConfig().sources, entry.name) == section
    from mapfilter.settings import field_docs

    docs = field_docs(entry.config)
    assert all(docs.get(f.name) for f in dataclasses.fields(entry.config)), "a one-line comment per setting"
    number = next((f for f in dataclasses.fields(entry.config) if isinstance(getattr(section, f.name), float)), None)
    if number is not None:
        changed = TrackingConfig().override({f"sources.{entry.name}.{number.name}": getattr(section, number.name) * 2})
        assert TrackingConfig.from_yaml(changed.to_yaml()) == changed
        with pytest.raises(MapfilterError):
            TrackingConfig.from_yaml(f"sources: {{{entry.name}: {{{number.name}: not-a-number}}}}")
