"""`mapfilter evaluate --scheduler`: a real Dask cluster on 127.0.0.1 gives the serial numbers exactly.

A scheduler and two workers are started as separate processes, as a user would start them
(the README's two commands), bound to the loopback address only.
"""

import csv
import socket
import subprocess
import sys
import time

import pytest
from conftest import REPO

from mapfilter.cli import main
from mapfilter.maps.prepare import import_ilc

LOOPBACK = "127.0.0.1"


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind((LOOPBACK, 0))
        return sock.getsockname()[1]


@pytest.fixture
def cluster(tmp_path):
    """tcp://127.0.0.1:PORT of a scheduler with two single-threaded workers; all three stopped after."""
    distributed = pytest.importorskip("distributed")
    address = f"tcp://{LOOPBACK}:{_free_port()}"
    dask = [sys.executable, "-m", "dask"]
    # the HTTP (health) server too: --no-dashboard alone still listens on every interface
    common = ["--host", LOOPBACK, "--no-dashboard", "--dashboard-address", f"{LOOPBACK}:0"]
    logs = tmp_path / "dask-logs"
    logs.mkdir()
    processes = []

    def start(name, args):
        handle = (logs / f"{name}.log").open("w")
        processes.append(subprocess.Popen(dask + args, stdout=handle, stderr=subprocess.STDOUT))

    start("scheduler", ["scheduler", "--port", address.rsplit(":", 1)[1], *common])
    for i in range(2):
        start(f"worker{i}", ["worker", address, "--nthreads", "1", "--name", f"w{i}", *common,
                             "--local-directory", str(tmp_path / f"w{i}")])
    try:
        deadline = time.monotonic() + 120
        while True:  # the scheduler takes a moment to listen
            try:
                with distributed.Client(address, timeout="5s") as client:
                    client.wait_for_workers(2, timeout=max(deadline - time.monotonic(), 1))
                    assert len(client.scheduler_info()["workers"]) == 2
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(1)
        yield address
    finally:
        for process in reversed(processes):
            process.terminate()
        for process in processes:
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                process.kill()


def _numbers(out):
    """Every per-walk, per-method number except the run time (which no two runs share)."""
    with (out / "traces.csv").open() as handle:
        rows = [{k: v for k, v in row.items() if k != "runtime_s"} for row in csv.DictReader(handle)]
    tracks = {p.relative_to(out): p.read_bytes() for p in sorted((out / "tracks").rglob("*.csv"))}
    return rows, tracks


def test_evaluate_on_a_two_worker_cluster_gives_the_serial_numbers_exactly(ilc_site1, tmp_path, cluster):
    floor = ilc_site1 / "F1"
    import_ilc(floor, route="geojson").save(tmp_path / "F1.yaml")
    walks = [str(p) for p in sorted((floor / "path_data_files").glob("*.txt.gz"))[:4]]
    base = ["evaluate", str(tmp_path / "F1.yaml"), *walks, "--leave-one-out", "--methods", "pf,pf-nopdr,kwnn,kf",
            "--particles", "300", "--seed", "7"]
    assert main(base + ["--out", str(tmp_path / "serial")]) == 0
    assert main(base + ["--scheduler", cluster, "--out", str(tmp_path / "cluster")]) == 0
    serial, cluster_numbers = _numbers(tmp_path / "serial"), _numbers(tmp_path / "cluster")
    assert len(serial[0]) == 16 and len(serial[1]) == 16  # 4 walks x 4 methods: the comparison is not empty
    assert cluster_numbers == serial


def test_an_unreachable_scheduler_is_one_line(tmp_path, capsys):
    pytest.importorskip("distributed")
    address = f"tcp://{LOOPBACK}:{_free_port()}"  # nobody listens there
    maps = REPO / "maps"
    assert main(["evaluate", str(maps / "office.yaml"), str(maps / "office_walk.txt.gz"), "--radiomap",
                 str(maps / "office_radiomap.npz"), "--methods", "kwnn", "--scheduler", address, "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"cannot reach the Dask scheduler at {address}" in err
