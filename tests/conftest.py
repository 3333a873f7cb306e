"""Shared test fixtures: where the real ILC data lives (../shared beside the checkout)."""

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def pytest_collection_modifyitems(config, items):
    """Tests that read the real walks in ../shared/data are marked ``real_data`` (and skip,
    with the reason, when the data is absent): ``-m "not real_data"`` is the quick run."""
    for item in items:
        if {"ilc_site1", "ilc_f1_plan", "ipin2023"} & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.real_data)


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
