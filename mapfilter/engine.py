"""Many independent walks, one task each: in this process, on local Dask worker processes, or
on an existing Dask cluster.

Every walk is its own task and draws its random numbers from a generator seeded by the walk
itself (never from a stream shared across walks), so where a task runs does not change its
numbers: a serial run, ``--jobs N`` and a cluster give the same results.

Dask (``distributed``) is an optional dependency (``pip install 'mapfilter[distributed]'``),
imported only when a run asks for more than one process or for a scheduler. Starting a
cluster by hand (see the README)::

    dask scheduler --host 127.0.0.1 --port 8786
    dask worker tcp://127.0.0.1:8786 --nworkers 2 --nthreads 1

Workers need mapfilter installed and the logs at the same paths (a shared file system);
the map and the other inputs common to all walks are sent to every worker once.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from mapfilter.errors import MapfilterError

DASK_HINT = "pip install 'mapfilter[distributed]'"


@dataclasses.dataclass(frozen=True)
class Engine:
    """Where the walks run."""

    jobs: int = 1  # local worker processes; 1 runs every walk in this process (no Dask)
    scheduler: str | None = None  # tcp://HOST:PORT of a running Dask scheduler (jobs is then ignored)

    def __post_init__(self) -> None:
        if self.jobs < 1:
            raise MapfilterError(f"--jobs must be at least 1, got {self.jobs}")
        if self.scheduler is not None and "://" not in self.scheduler:
            raise MapfilterError(f"--scheduler must look like tcp://HOST:PORT, got {self.scheduler!r}")

    @property
    def uses_dask(self) -> bool:
        return self.scheduler is not None or self.jobs > 1

    def describe(self) -> str:
        if self.scheduler is not None:
            return f"Dask cluster at {self.scheduler}"
        return f"{self.jobs} local Dask worker processes" if self.jobs > 1 else "serial"


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
    # one walk on local processes gains nothing from starting a cluster; a named scheduler is always used
    if not engine.uses_dask or total == 0 or (engine.scheduler is None and total == 1):
        for i, item in enumerate(items):
            result = function(*common, item)
            if progress:
                progress(i + 1, total, label(item))
            yield i, result
        return
    with _DaskClient(engine) as client:
        from distributed import as_completed

        # broadcast: every worker gets its own copy up front, instead of fetching it from the
        # first worker that needs it while the others wait
        shared = client.scatter(list(common), broadcast=True) if common else []
        futures = {client.submit(function, *shared, item, pure=False): i for i, item in enumerate(items)}
        try:
            for done, future in enumerate(as_completed(futures), start=1):
                i = futures[future]
                result = future.result()
                if progress:
                    progress(done, total, label(items[i]))
                yield i, result
        finally:
            client.cancel(list(futures))


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
            try:
                self.client = Client(self.engine.scheduler, timeout="10s")
            except (OSError, TimeoutError) as exc:
                raise MapfilterError(f"cannot reach the Dask scheduler at {self.engine.scheduler}: {exc}") from None
        else:
            # one thread per worker: the filter's numba kernels already use the cores, and a
            # walk per process keeps the GIL out of the way. Workers log a failed task with its
            # traceback at ERROR level; the failure reaches the user as our own one line instead.
            self.cluster = LocalCluster(n_workers=self.engine.jobs, threads_per_worker=1, processes=True,
                                        dashboard_address=None, silence_logs=logging.CRITICAL,
                                        # the scheduler's HTTP (health) server on any free loopback port:
                                        # its default, 8787, is often taken by another run (a warning)
                                        scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})
            self.client = Client(self.cluster)
        return self.client

    def __exit__(self, *exc_info) -> None:
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()
