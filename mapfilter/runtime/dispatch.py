"""Many independent walks, one task each: in this process, on local worker processes, or on an
existing Dask cluster.

Every walk is its own task and draws its random numbers from a generator seeded by the walk
itself (never from a stream shared across walks), so where a task runs does not change its
numbers: a serial run, ``--jobs N`` and a cluster give the same results.

``--jobs N`` forks N worker processes from this one (where the platform can fork): each starts
with what this process has already loaded (the modules, the compiled kernels, the map, the
radio map and whatever the tasks share), so a worker costs nothing to start and nothing is
sent to it but each task's item; the pool opens no socket. Where processes cannot be forked,
``--jobs`` starts a local Dask cluster instead (below).

Dask (``distributed``) is an optional dependency (``pip install 'mapfilter[distributed]'``),
imported only when a run asks for a scheduler (or for ``--jobs`` where forking is not
available). Starting a cluster by hand (see the README)::

    dask scheduler --host 127.0.0.1 --port 8786
    dask worker tcp://127.0.0.1:8786 --nworkers 2 --nthreads 1

Workers need mapfilter installed and the logs at the same paths (a shared file system);
the map and the other inputs common to all walks are sent to every worker once.

Security. A local Dask cluster (``--jobs`` where processes cannot be forked) listens on 127.0.0.1 only and speaks TLS with
credentials made for this run and held only in memory (``Security.temporary()``): its
scheduler, workers and nannies accept only a peer holding a certificate of this run's own
authority, so no other user (or other run) of the machine can connect and run code as you.
A cluster named with ``--scheduler`` must be one you trust: whoever can submit work to it runs
code as its workers' user, and what it sends back is unpickled here, that is, it can run code
in this process. A ``tls://`` scheduler is reached with the TLS settings of Dask's own
configuration (``distributed.comm.tls.ca-file``, ``.client.cert``, ``.client.key``).
"""

from __future__ import annotations

import dataclasses
import logging
import os
from collections.abc import Callable, Iterator, Sequence
from typing import Any
from urllib.parse import urlsplit

from mapfilter.errors import MapfilterError

DASK_HINT = "pip install 'mapfilter[distributed]'"
LOOPBACK = "127.0.0.1"
SCHEDULER_SCHEMES = ("tcp", "tls")


@dataclasses.dataclass(frozen=True)
class Engine:
    """Where the walks run."""

    jobs: int = 1  # local worker processes; 1 runs every walk in this process (no Dask)
    scheduler: str | None = None  # tcp://HOST:PORT of a running Dask scheduler (jobs is then ignored)

    def __post_init__(self) -> None:
        if self.jobs < 1:
            raise MapfilterError(f"--jobs must be at least 1, got {self.jobs}")
        if self.scheduler is not None:
            check_scheduler_address(self.scheduler)

    @property
    def uses_dask(self) -> bool:
        return self.scheduler is not None or (self.jobs > 1 and not can_fork())

    def describe(self) -> str:
        if self.scheduler is not None:
            return f"Dask cluster at {self.scheduler}"
        if self.jobs == 1:
            return "serial"
        return f"{self.jobs} local worker processes" if can_fork() else f"{self.jobs} local Dask worker processes"


def can_fork() -> bool:
    """Whether worker processes can be forked from this one (Linux, and the BSDs; not Windows,
    and not macOS, where system libraries are not safe to use in a forked child)."""
    import multiprocessing
    import sys

    return sys.platform.startswith(("linux", "freebsd")) and "fork" in multiprocessing.get_all_start_methods()


def check_scheduler_address(address: str) -> tuple[str, str, int]:
    """(scheme, host, port) of a scheduler address ``tcp://HOST:PORT`` or ``tls://HOST:PORT``
    (an IPv6 host in brackets); ``MapfilterError`` in one line for anything else."""
    usage = f"--scheduler must look like tcp://HOST:PORT or tls://HOST:PORT, got {address!r}"
    if "://" not in address:
        raise MapfilterError(usage)
    try:
        parts = urlsplit(address)
        port = parts.port
    except ValueError as exc:  # a port that is not a number, or out of range
        raise MapfilterError(f"{usage}: {exc}") from None
    if parts.scheme not in SCHEDULER_SCHEMES:
        raise MapfilterError(f"{usage}: the protocol {parts.scheme!r} is not one of {', '.join(SCHEDULER_SCHEMES)}")
    if not parts.hostname:
        raise MapfilterError(f"{usage}: no host")
    if port is None or port == 0:
        raise MapfilterError(f"{usage}: no port (1-65535)")
    if parts.path not in ("", "/") or parts.query or parts.fragment or parts.username or parts.password:
        raise MapfilterError(f"{usage}: only a host and a port")
    return parts.scheme, parts.hostname, port


def machine_cores() -> int:
    """The cores this process may run on (its CPU affinity, else the machine's count)."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except (AttributeError, OSError):
        return max(os.cpu_count() or 1, 1)


def check_local_jobs(jobs: int) -> None:
    """``--jobs N``: at most one local worker process per core (more only wait for a core, and
    each holds its own copy of the map and the radio map), and N workers' memory must fit."""
    from mapfilter.runtime import memory

    cores = machine_cores()
    if jobs > cores:
        raise MapfilterError(f"--jobs {jobs}: this machine has {cores} core{'s' if cores != 1 else ''}; give at "
                             f"most --jobs {cores} (more processes than cores only wait for them)")
    if jobs > 1:
        memory.check_fits(memory.jobs_bytes(jobs), f"--jobs {jobs} (local worker processes)", "give fewer")


# What a scheduler must do within seconds: accept, and send the first message of Dask's
# handshake (a few hundred bytes). Anything else (silence, an HTTP server, random bytes whose
# first 8 read as a length of exabytes) is refused before Dask's client trusts it.
SCHEDULER_TIMEOUT_S = 5.0
MAX_HANDSHAKE_BYTES = 1 << 16


def probe_scheduler(address: str, security=None, timeout_s: float = SCHEDULER_TIMEOUT_S) -> None:
    """Connect to the scheduler at ``address`` and read the first message it sends (Dask's
    handshake: an 8-byte length, then that many bytes), with a timeout and a bound on the
    length; ``MapfilterError`` in one line for anything that is not a Dask scheduler."""
    import socket
    import struct
    import time

    scheme, host, port = check_scheduler_address(address)
    deadline = time.monotonic() + timeout_s
    try:
        sock = socket.create_connection((host, port), timeout=timeout_s)
    except OSError as exc:
        raise MapfilterError(f"cannot reach the Dask scheduler at {address}: {exc.strerror or exc}") from None
    try:
        if scheme == "tls":
            context = security.get_connection_args("client")["ssl_context"] if security is not None else None
            if context is None:
                raise MapfilterError(f"--scheduler {address}: no TLS settings to reach it with")
            sock = context.wrap_socket(sock, server_hostname=None if context.check_hostname is False else host)

        def read(n: int) -> bytes:
            data = b""
            while len(data) < n:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError
                sock.settimeout(left)
                chunk = sock.recv(n - len(data))
                if not chunk:
                    raise ConnectionError("closed the connection")
                data += chunk
            return data

        head = read(8)
        if head.startswith((b"HTTP", b"<", b"SSH-", b"220 ")):
            raise MapfilterError(f"--scheduler {address} is not a Dask scheduler (it answered {head[:8]!r}...: an "
                                 "HTTP, SSH or mail server?)")
        (length,) = struct.unpack("<Q", head)
        if not 8 <= length <= MAX_HANDSHAKE_BYTES:
            raise MapfilterError(f"--scheduler {address} is not a Dask scheduler (its first message would be "
                                 f"{length} bytes; Dask's handshake is a few hundred)")
        read(length)
    except TimeoutError:
        raise MapfilterError(f"--scheduler {address} accepted the connection but sent nothing a Dask scheduler "
                             f"sends within {timeout_s:g} s: is it one?") from None
    except (ConnectionError, OSError) as exc:
        raise MapfilterError(f"--scheduler {address}: the connection failed during Dask's handshake "
                             f"({getattr(exc, 'strerror', None) or exc}): is it a Dask scheduler?") from None
    finally:
        sock.close()


def run_each(function: Callable[..., Any], items: Sequence[Any], engine: Engine, common: tuple = (),
             progress: Callable[[int, int, str], None] | None = None,
             label: Callable[[Any], str] = str) -> Iterator[tuple[int, Any]]:
    """Yield ``(i, function(*common, items[i]))`` for every item, in the order they finish.

    ``common`` holds the inputs every task shares (the map, a radio map): with Dask they are
    sent to each worker once rather than with every task. An exception raised by a task is
    raised here (the remaining tasks are cancelled); a task that must not stop the others
    catches its own errors and returns them. ``progress(done, total, label(item))`` is called
    after each task.
    """
    total = len(items)
    # one walk on local processes gains nothing from starting them; a named scheduler is always used
    if engine.jobs == 1 and engine.scheduler is None or total == 0 or (engine.scheduler is None and total == 1):
        for i, item in enumerate(items):
            result = function(*common, item)
            if progress:
                progress(i + 1, total, label(item))
            yield i, result
        return
    if not engine.uses_dask:
        yield from _on_forked_workers(function, items, engine.jobs, common, progress, label)
        return
    with _DaskClient(engine) as client:
        from distributed import as_completed

        # broadcast: every worker gets its own copy up front, instead of fetching it from the
        # first worker that needs it while the others wait
        shared = client.scatter(list(common), broadcast=True) if common else []
        futures = {client.submit(function, *shared, item, pure=False): i for i, item in enumerate(items)}
        try:
            yield from _as_completed(futures, as_completed, items, progress, label)
        finally:
            client.cancel(list(futures))


def _as_completed(futures: dict, as_completed: Callable, items: Sequence[Any],
                  progress: Callable[[int, int, str], None] | None, label: Callable[[Any], str]
                  ) -> Iterator[tuple[int, Any]]:
    """(item index, result) of each future (future -> its item's index) as it completes, with the
    progress told (``as_completed``: Dask's or concurrent.futures')."""
    for done, future in enumerate(as_completed(futures), start=1):
        i = futures[future]
        result = future.result()
        if progress:
            progress(done, len(items), label(items[i]))
        yield i, result


# what every task of a forked pool shares: set before the pool forks, so every worker starts with
# it (nothing pickled); emptied when the pool is done
_COMMON: tuple = ()


def _with_common(function: Callable[..., Any], item: Any) -> Any:
    return function(*_COMMON, item)


def _worker_signals() -> None:
    # Ctrl-C reaches the whole process group: the parent stops the run (and its workers) and
    # keeps what was done; a worker interrupted on its own would only lose its walk. SIGTERM ends
    # a worker at once, whatever the parent's handler was when it forked: a pool forked after a
    # first SIGTERM (which the command's handler answers by ignoring the next) inherited that, and
    # its workers outlived the run, waiting for tasks that never came
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _on_forked_workers(function: Callable[..., Any], items: Sequence[Any], jobs: int, common: tuple,
                       progress: Callable[[int, int, str], None] | None,
                       label: Callable[[Any], str]) -> Iterator[tuple[int, Any]]:
    """``run_each`` on ``jobs`` worker processes forked from this one (module docstring)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    global _COMMON
    _COMMON = tuple(common)
    pool = ProcessPoolExecutor(max_workers=min(jobs, len(items)), mp_context=multiprocessing.get_context("fork"),
                               initializer=_worker_signals)
    finished = False
    try:
        futures = {pool.submit(_with_common, function, item): i for i, item in enumerate(items)}
        yield from _as_completed(futures, as_completed, items, progress, label)
        finished = True
    finally:
        _COMMON = ()
        if finished:
            pool.shutdown(wait=True)
        else:  # an error, an interrupt, or the caller stopped: the workers' walks are not waited for
            workers = list(getattr(pool, "_processes", {}).values())
            pool.shutdown(wait=False, cancel_futures=True)
            for worker in workers:
                worker.terminate()


class _DaskClient:
    """A Dask client on a new local cluster (``jobs`` worker processes) or on ``scheduler``."""

    def __init__(self, engine: Engine) -> None:
        self.engine = engine
        self.cluster = None
        self.client = None

    def __enter__(self):
        try:
            from distributed import Client, LocalCluster
        except ImportError:
            raise MapfilterError(f"--jobs above 1 and --scheduler run on Dask, which is not installed: "
                                 f"{DASK_HINT}") from None
        if self.engine.scheduler is not None:
            address = self.engine.scheduler
            security = _configured_security(address)
            probe_scheduler(address, security)  # silence or a stranger: one line in seconds
            import dask

            try:
                with dask.config.set({"distributed.comm.timeouts.connect": "10s"}):
                    self.client = Client(address, timeout="10s", security=security)
            except (OSError, TimeoutError) as exc:
                raise MapfilterError(f"cannot reach the Dask scheduler at {address}: {exc}") from None
        else:
            security = temporary_security()
            # one thread per worker: the filter's numba kernels already use the cores, and a
            # walk per process keeps the GIL out of the way. Workers log a failed task with its
            # traceback at ERROR level; the failure reaches the user as our own one line instead.
            # TLS with this run's own credentials, on the loopback address only (module docstring).
            self.cluster = LocalCluster(n_workers=self.engine.jobs, threads_per_worker=1, processes=True,
                                        host=LOOPBACK, protocol="tls", security=security,
                                        dashboard_address=None, silence_logs=logging.CRITICAL,
                                        # the scheduler's HTTP (health) server on any free loopback port:
                                        # its default, 8787, is often taken by another run (a warning)
                                        scheduler_kwargs={"dashboard_address": f"{LOOPBACK}:0"})
            self.client = Client(self.cluster, security=security)
        return self.client

    def __exit__(self, *exc_info) -> None:
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def temporary_security():
    """TLS credentials made for one run, held in memory: a certificate authority of its own and
    certificates for the scheduler, the workers and the client (``Security.temporary``)."""
    from distributed.security import Security

    try:
        return Security.temporary()
    except ImportError:  # Security.temporary makes its certificates with the cryptography package
        raise MapfilterError("--jobs secures its local cluster with TLS, which needs the cryptography package: "
                             f"{DASK_HINT}") from None


def _configured_security(address: str):
    """The TLS settings of Dask's configuration for a ``tls://`` scheduler; None for ``tcp://``."""
    if not address.startswith("tls://"):
        return None
    from distributed.security import Security

    security = Security()  # from dask's configuration: distributed.comm.tls.*
    if security.get_connection_args("client").get("ssl_context") is None:
        raise MapfilterError(f"--scheduler {address}: a tls:// scheduler needs TLS credentials in Dask's "
                             "configuration (distributed.comm.tls.ca-file, .client.cert, .client.key; see "
                             "https://distributed.dask.org/en/stable/tls.html)")
    return security
