"""The engine: walks as tasks, serially or on local worker processes (forked from this one); errors
reach the user as one line."""

import json

import pytest
from conftest import REPO

from mapfilter.cli import main
from mapfilter.runtime.dispatch import Engine, run_each
from mapfilter.errors import MapfilterError

MAPS = REPO / "maps"


def _scaled(factor, offset, x):
    return factor * x + offset


def test_serial_runs_in_order_with_progress_and_shared_inputs():
    seen = []
    out = list(run_each(_scaled, [1, 2, 3], Engine(), common=(10, 1),
                        progress=lambda done, total, name: seen.append((done, total, name))))
    assert out == [(0, 11), (1, 21), (2, 31)]
    assert seen == [(1, 3, "1"), (2, 3, "2"), (3, 3, "3")]


def test_bad_engine_options_are_user_errors():
    with pytest.raises(MapfilterError, match="--jobs must be at least 1"):
        Engine(jobs=0)
    with pytest.raises(MapfilterError, match="tcp://HOST:PORT"):
        Engine(scheduler="127.0.0.1:8786")


class _Unpicklable:
    """Shared input that cannot be pickled: a forked worker must inherit it, never receive it."""

    def __init__(self, value):
        self.value = value

    def __reduce__(self):
        raise TypeError("the shared inputs must not be pickled to a forked worker")


def _pid_and_value(shared, x):
    import os

    return os.getpid(), shared.value * x


def _fails_on_three(x):
    if x == 3:
        raise ValueError("task three")
    return x


@pytest.mark.skipif(not __import__("mapfilter.runtime.dispatch", fromlist=["can_fork"]).can_fork(),
                    reason="this platform cannot fork worker processes")
def test_jobs_fork_workers_that_inherit_the_shared_inputs_and_raise_a_tasks_error(monkeypatch):
    import os
    import sys

    monkeypatch.setitem(sys.modules, "distributed", None)  # no Dask: --jobs needs none where it can fork
    results = dict(run_each(_pid_and_value, list(range(8)), Engine(jobs=2), common=(_Unpicklable(5),)))
    assert {i: value for i, (_, value) in results.items()} == {i: 5 * i for i in range(8)}
    pids = {pid for pid, _ in results.values()}
    assert os.getpid() not in pids and 1 <= len(pids) <= 2
    assert Engine(jobs=2).describe() == "2 local worker processes" and not Engine(jobs=2).uses_dask
    with pytest.raises(ValueError, match="task three"):
        list(run_each(_fails_on_three, [1, 2, 3, 4], Engine(jobs=2)))


def _signal_handlers(x):
    import signal

    return signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)


@pytest.mark.skipif(not __import__("mapfilter.runtime.dispatch", fromlist=["can_fork"]).can_fork(),
                    reason="this platform cannot fork worker processes")
def test_workers_forked_while_sigterm_is_ignored_still_die_of_it(monkeypatch):
    # the command ignores a second SIGTERM while it cleans up after the first; a pool forked then
    # must not inherit that, or the parent's terminate() leaves its workers behind
    import signal
    import sys

    monkeypatch.setitem(sys.modules, "distributed", None)
    previous = signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        results = dict(run_each(_signal_handlers, [1, 2, 3], Engine(jobs=2)))
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert set(results.values()) == {(signal.SIG_IGN, signal.SIG_DFL)}


def test_local_workers_give_every_result_and_a_failing_walk_is_one_line(tmp_path, capsys):
    results = dict(run_each(_scaled, list(range(6)), Engine(jobs=2), common=(3, 0)))
    assert results == {i: 3 * i for i in range(6)}
    # a walk without waypoints, evaluated on two local workers: the worker's error is our one line,
    # and the other walk's results are kept
    import gzip

    no_waypoints = tmp_path / "nowp.txt"
    with gzip.open(MAPS / "office_walk.txt.gz", "rt") as handle:
        no_waypoints.write_text("".join(line for line in handle if "TYPE_WAYPOINT" not in line))
    assert main(["evaluate", str(MAPS / "office.yaml"), str(MAPS / "office_walk.txt.gz"), str(no_waypoints),
                 "--radiomap", str(MAPS / "office_radiomap.npz"), "--methods", "kwnn", "--jobs", "2",
                 "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    # one line for the failed walk (a loaded machine may add progress lines around it)
    failed = [line for line in err if "failed" in line]
    assert failed == [f"mapfilter: failed: {no_waypoints}: the log has no waypoints to evaluate against"]
    assert not any("Traceback" in line for line in err)
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert [f["trace"] for f in summary["failed"]] == ["nowp"] and summary["complete"]
    assert [row["method"] for row in summary["summary"]] == ["kwnn"] and summary["traces"][0]["trace"] == "office_walk"


@pytest.mark.parametrize("address", ["tcp://", "tcp://host", "foo://x:1", "tcp://host:99999", "tcp://host:port",
                                     "tcp://:8786", "tcp://host:0", "tcp://host:8786/path", "host:8786"])
def test_a_malformed_scheduler_address_is_one_line_before_dask(address, tmp_path, capsys):
    with pytest.raises(MapfilterError, match="--scheduler must look like tcp://HOST:PORT"):
        Engine(scheduler=address)
    assert main(["evaluate", str(MAPS / "office.yaml"), str(MAPS / "office_walk.txt.gz"), "--radiomap",
                 str(MAPS / "office_radiomap.npz"), "--methods", "kwnn", "--scheduler", address,
                 "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith("mapfilter: error: --scheduler must look like")


@pytest.mark.parametrize("address", ["tcp://127.0.0.1:8786", "tls://scheduler.example:8786", "tcp://[::1]:8786"])
def test_well_formed_scheduler_addresses_pass(address):
    assert Engine(scheduler=address).uses_dask


def test_a_tls_scheduler_without_tls_settings_is_one_line(tmp_path, capsys, monkeypatch):
    pytest.importorskip("distributed")
    for name in ("CA_FILE", "CLIENT__CERT", "CLIENT__KEY"):
        monkeypatch.delenv(f"DASK_DISTRIBUTED__COMM__TLS__{name}", raising=False)
    assert main(["evaluate", str(MAPS / "office.yaml"), str(MAPS / "office_walk.txt.gz"), "--radiomap",
                 str(MAPS / "office_radiomap.npz"), "--methods", "kwnn", "--scheduler", "tls://127.0.0.1:1",
                 "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "needs TLS credentials in Dask's configuration" in err
