"""Shared test fixtures, and the two tiers of the suite.

The tiers (the README's "Tests" section):

- the fast tier, ``pytest -q -m "not slow" -n auto``: what a developer runs after a change, in
  minutes;
- the slow tier, ``pytest -q -m slow -n auto``: the long end-to-end runs. ``.ci/run`` runs both.

A test is marked ``@pytest.mark.slow`` (a module of them: ``pytestmark = pytest.mark.slow``) when
it takes more than about 5 s by itself on a quiet 2-core machine (``--durations=20`` shows it), or
when it runs a pipeline on real data a second time: the fast tier keeps one real-data run per
pipeline, those named in ``FAST_REAL_DATA_RUNS`` below (tests/test_tiers.py checks that they exist
and are not slow). Nothing else changes between the tiers: a slow test asserts what it would in
the fast one. ``real_data`` is added here to every test that reads ../shared/data (through the
fixtures below), which skip, with the reason, when it is absent.

Under ``-n`` (pytest-xdist, ``--dist loadscope`` from pyproject.toml) the tests of a module run in
one worker, so a module-scoped fixture is built once (the documents of tests/test_docs_commands.py
are units of their own: ``pytest_xdist_make_scheduler`` below); a session-scoped one here is built
once per worker that uses it. Fixtures here are shared: a test reads them and writes only under its
own ``tmp_path``.
"""

import signal
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def ctrl_c_as_a_terminal_gives_it() -> None:
    """``preexec_fn`` of a command the test interrupts: in the child, SIGINT handled as a
    terminal's process gets it, even when the tests run where it is ignored (a shell's background
    job ignores SIGINT, and its children inherit that)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


# the fast tier's one real-data run of each pipeline (the slow tier holds the others)
FAST_REAL_DATA_RUNS = {
    "a real ILC walk tracked (import-ilc, radiomap build, track: the CLI)":
        "tests/sensors/test_radiomap_tables.py::test_radiomap_build_keeps_the_grid_and_track_starts_from_it",
    "an ILC building: walks of two floors evaluated in it":
        "tests/sensors/test_floors.py::test_evaluate_in_a_building_reports_floor_accuracy_per_method",
    "an IPIN log tracked in its venue (the EvaalAPI replay)":
        "tests/evaal/test_evaal.py::test_evaal_out_on_a_log_without_posi_names_evaal_start",
    "the live path: a real ILC walk cut and fed in chunks":
        "tests/pipeline/test_tracker_stream.py::test_real_ilc_walks_are_causal_and_stream",
    "the real logs streamed in random pieces":
        "tests/sensors/test_logs_stream.py::test_a_real_ipin_log_streamed_in_random_pieces_is_the_log_read_whole",
}


def pytest_collection_modifyitems(config, items):
    """Tests that read the real walks in ../shared/data are marked ``real_data`` (and skip,
    with the reason, when the data is absent): ``-m "not real_data"`` leaves them out."""
    for item in items:
        if {"ilc_site1", "ilc_f1_plan", "ipin2023"} & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.real_data)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """``--dist loadscope`` (pyproject.toml) with one change: each document's commands in
    tests/test_docs_commands.py are a unit of their own (a document's commands run in order in
    one workspace; two documents need not wait for each other), not the whole module."""
    if config.getvalue("dist") != "loadscope":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class DocumentScopes(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            scope = super()._split_scope(nodeid)
            if scope.endswith("test_docs_commands.py") and "[" in nodeid:
                return f"{scope}::{nodeid.split('[', 1)[1].split(':', 1)[0]}"  # its document
            return scope

    return DocumentScopes(config, log)


ILC_SITE1 = REPO.parent / "shared" / "data" / "ilc20" / "site1"


@pytest.fixture(scope="session")
def ilc_site1() -> Path:
    if not ILC_SITE1.is_dir():
        pytest.skip(f"ILC 2.0 data absent: {ILC_SITE1} (get it with `python3 tools/get_data.py`, docs/data.md)")
    return ILC_SITE1


@pytest.fixture(scope="session")
def ilc_f1_plan(ilc_site1):
    """ILC site 1 F1 as `map import-ilc` makes it (read-only: shared by every test of the run)."""
    from mapfilter.maps.prepare import import_ilc

    return import_ilc(ilc_site1 / "F1")


IPIN2023 = REPO.parent / "shared" / "data" / "ipin2023"


@pytest.fixture(scope="session")
def ipin2023() -> Path:
    if not (IPIN2023 / "logs").is_dir():
        pytest.skip(f"IPIN 2023 data absent: {IPIN2023} (get it with `python3 tools/get_data.py`, docs/data.md)")
    return IPIN2023


@pytest.fixture(scope="session")
def ipin_venue(ipin2023, tmp_path_factory) -> Path:
    """The IPIN 2023 venue's building YAML as ``mapfilter map import-ipin CAL --storey-height 2.8``
    writes it (with a map per floor beside it; read-only: shared by every test of the run)."""
    from mapfilter.cli import main

    venue = tmp_path_factory.mktemp("ipin_venue") / "venue.yaml"
    assert main(["map", "import-ipin", str(ipin2023 / "plans" / "calib_mapa_Nuremberg.cal"), "--out", str(venue),
                 "--storey-height", "2.8"]) == 0
    return venue


@pytest.fixture(scope="session")
def ilc_site1_building(ilc_site1, tmp_path_factory) -> Path:
    """ILC site 1 as one building, as ``mapfilter map import-ilc SITE`` writes it (read-only)."""
    from mapfilter.cli import main

    out = tmp_path_factory.mktemp("site1") / "site1.yaml"
    assert main(["map", "import-ilc", str(ilc_site1), "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="session")
def office3(tmp_path_factory):
    """(building, AP tables per floor): the bundled office stacked three times with stairs and a
    lift (``tools/floor_sim.make_office_building``); tests read it, never write into it."""
    import sys

    sys.path.insert(0, str(REPO / "tools"))
    from floor_sim import make_office_building

    return make_office_building(tmp_path_factory.mktemp("office3"))


@pytest.fixture(scope="session")
def office3_radio_map(office3, tmp_path_factory):
    """The three-floor office's radio map: one coarse simulated survey per floor (a reference
    point every 4 m, one scan each: coarse keeps the tests fast), labelled with its floor."""
    import numpy as np

    from mapfilter.sensors.floor_vote import build_building_radio_map
    from mapfilter.sensors.ilc import read_ilc
    from mapfilter.simulate.building import BuildingSimConfig, simulate_building_survey
    from mapfilter.simulate.ilc_writer import write_ilc
    from mapfilter.simulate.walk import SimConfig

    building, tables = office3
    survey_config = BuildingSimConfig(walk=SimConfig(survey_spacing_m=4.0, survey_scans_per_point=1))
    folder = tmp_path_factory.mktemp("office3_surveys")
    surveys = []
    for i, name in enumerate(building.floor_names):
        write_ilc(simulate_building_survey(building, tables, name, survey_config, np.random.default_rng([9, i])),
                  folder / f"survey_{name}.txt")
        surveys.append(read_ilc(folder / f"survey_{name}.txt"))
    return build_building_radio_map(surveys, list(range(len(surveys))), building.floor_names)


def tracking_config(**settings):
    """A ``TrackingConfig`` from flat keywords, for tests: motion, n_particles, smooth, seed,
    use_map, fingerprint_model, kwnn_min_rssi_dbm, fix_sigma_m, adapt_path_loss, adapt_rssi_limit_dbm,
    blocking_compensation."""
    import dataclasses

    from mapfilter.config import TrackingConfig

    config = TrackingConfig()
    sections = {"motion": ("motion", "model"), "fingerprint_model": ("wifi", None), "kwnn_min_rssi_dbm": ("wifi", None),
                "fix_sigma_m": ("wifi", None), "adapt_path_loss": ("trilateration", None),
                "adapt_rssi_limit_dbm": ("trilateration", None), "blocking_compensation": ("trilateration", None)}
    for name, value in settings.items():
        if name == "n_particles":
            config = config.with_particles(value)
        elif name in sections:
            section, field = sections[name]
            config = dataclasses.replace(config, **{section: dataclasses.replace(getattr(config, section),
                                                                                 **{field or name: value})})
        else:
            config = dataclasses.replace(config, **{name: value})
    return config
