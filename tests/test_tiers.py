"""The fast tier keeps one real-data run per pipeline: each test that tests/conftest.py names in
``FAST_REAL_DATA_RUNS`` exists, takes a real-data fixture, and is not marked slow (at least one
of its parameters is not)."""

from __future__ import annotations

import importlib.util
import inspect

import pytest
from conftest import FAST_REAL_DATA_RUNS, REPO

REAL_DATA_FIXTURES = {"ilc_site1", "ilc_f1_plan", "ipin2023", "ipin_venue", "ilc_site1_building"}


def _marks(thing) -> list:
    marks = getattr(thing, "pytestmark", [])
    return marks if isinstance(marks, list) else [marks]


def _load(path):
    spec = importlib.util.spec_from_file_location(f"_tiers_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("pipeline", sorted(FAST_REAL_DATA_RUNS))
def test_each_pipeline_keeps_a_real_data_run_in_the_fast_tier(pipeline):
    file, name = FAST_REAL_DATA_RUNS[pipeline].split("::")
    module = _load(REPO / file)
    test = getattr(module, name, None)
    assert callable(test), f"{file} has no {name} (tests/conftest.py FAST_REAL_DATA_RUNS)"
    marks = _marks(module) + _marks(test)
    assert not [m for m in marks if m.name == "slow"], f"{name}: the fast tier's real-data run is marked slow"
    for mark in (m for m in marks if m.name == "parametrize"):
        values = mark.args[1]
        fast = [v for v in values if not any(m.name == "slow" for m in getattr(v, "marks", ()))]
        assert fast, f"{name}: every parameter is marked slow"
    # it reads the real data, through a fixture that skips when ../shared/data is absent
    assert set(inspect.signature(test).parameters) & REAL_DATA_FIXTURES, \
        f"{name} takes none of {sorted(REAL_DATA_FIXTURES)}: it reads no real data"
