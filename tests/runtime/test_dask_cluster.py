"""`mapfilter evaluate --scheduler`: a real Dask cluster on 127.0.0.1 gives the serial numbers exactly.

A scheduler and two workers are started as separate processes, as a user would start them
(the README's two commands), bound to the loopback address only.
"""

import contextlib
import csv
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

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


@pytest.mark.slow
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


def _uid_of_worker():
    import os

    return os.getuid()


def test_the_jobs_cluster_refuses_a_foreign_client_and_listens_on_loopback_only():
    """The cluster of --jobs speaks TLS with this run's own credentials: a client without them
    (plain TCP, or TLS with another authority's certificates) cannot connect, to the scheduler
    or to a worker, so it cannot run code as the user."""
    distributed = pytest.importorskip("distributed")
    pytest.importorskip("cryptography")
    from distributed.security import Security

    from mapfilter.runtime.dispatch import Engine, _DaskClient

    with _DaskClient(Engine(jobs=2)) as client:
        client.wait_for_workers(2, timeout=120)
        assert client.submit(_uid_of_worker).result() >= 0  # the run's own client works
        info = client.scheduler_info()
        addresses = [info["address"], *info["workers"]]
        assert len(addresses) == 3 and all(a.startswith(f"tls://{LOOPBACK}:") for a in addresses)
        for address in addresses:
            for attempt, security in ((address.replace("tls://", "tcp://"), None), (address, Security.temporary())):
                with pytest.raises((OSError, TimeoutError)):
                    foreign = distributed.Client(attempt, timeout="5s", security=security)
                    foreign.close()  # not reached: connecting fails
        # every socket the run listens on (scheduler, nannies, workers, their HTTP health servers)
        # is bound to the loopback address
        listening = _listening_addresses(os.getpid())
        if listening is not None:
            assert len(listening) >= 3 and all(host == "127.0.0.1" for host in listening), listening


def _listening_addresses(root_pid: int) -> list[str] | None:
    """IPv4 hosts of the TCP sockets in LISTEN state held by ``root_pid`` and its children
    (from /proc; None where there is no /proc)."""
    proc = Path("/proc")
    if not (proc / "net" / "tcp").is_file():
        return None
    pids = {root_pid}
    for task in (proc / str(root_pid) / "task").iterdir():  # worker processes are started from any thread
        with contextlib.suppress(OSError):
            pids |= {int(p) for p in (task / "children").read_text().split()}
    inodes = set()
    for pid in pids:
        with contextlib.suppress(OSError):
            for fd in (proc / str(pid) / "fd").iterdir():
                with contextlib.suppress(OSError):
                    target = os.readlink(fd)
                    if target.startswith("socket:["):
                        inodes.add(target[8:-1])
    hosts = []
    for table in ("tcp", "tcp6"):
        for line in (proc / "net" / table).read_text().splitlines()[1:]:
            fields = line.split()
            if fields[3] == "0A" and fields[9] in inodes:  # 0A: LISTEN
                host_hex = fields[1].split(":")[0]
                if table == "tcp":
                    hosts.append(socket.inet_ntoa(bytes.fromhex(host_hex)[::-1]))
                else:
                    hosts.append("ipv6:" + host_hex)
    return hosts
