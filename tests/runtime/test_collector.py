"""The garbage collector while a command runs: rare collections inside, the process's thresholds after."""

import gc

import pytest

import mapfilter.cli.config_cmd as config_cmd
from mapfilter.cli import main
from mapfilter.runtime.collector import COMMAND_GEN0_THRESHOLD, rare_collections


@pytest.fixture
def thresholds():
    before = gc.get_threshold()
    yield
    gc.set_threshold(*before)


def test_rare_inside_and_as_before_after(thresholds):
    gc.set_threshold(700, 10, 10)
    with rare_collections():
        assert gc.get_threshold() == (COMMAND_GEN0_THRESHOLD, 10, 10)
    assert gc.get_threshold() == (700, 10, 10)


def test_never_more_often_and_off_stays_off(thresholds):
    gc.set_threshold(10 * COMMAND_GEN0_THRESHOLD, 5, 5)
    with rare_collections():
        assert gc.get_threshold() == (10 * COMMAND_GEN0_THRESHOLD, 5, 5)
    gc.set_threshold(0)
    with rare_collections():
        assert gc.get_threshold()[0] == 0
    assert gc.get_threshold()[0] == 0


def test_restored_after_an_exception(thresholds):
    gc.set_threshold(700, 10, 10)
    with pytest.raises(RuntimeError), rare_collections():
        raise RuntimeError("boom")
    assert gc.get_threshold() == (700, 10, 10)


def test_a_command_runs_with_rare_collections(thresholds, monkeypatch, capsys):
    gc.set_threshold(700, 10, 10)
    seen = []

    def show(args):
        seen.append(gc.get_threshold())
        return 0

    monkeypatch.setattr(config_cmd, "run_show", show)
    assert main(["config", "show"]) == 0
    assert seen == [(COMMAND_GEN0_THRESHOLD, 10, 10)]
    assert gc.get_threshold() == (700, 10, 10)
