"""Many particles over the machine's cores: one serial numba kernel, run on slices by threads.

The hot kernels are plain ``@njit(cache=True, nogil=True)`` loops over a slice ``[lo, hi)``
of their particles. :func:`for_slices` runs a kernel once over everything when the work is
small, and otherwise over a few slices on a small pool of Python threads (numba releases the
GIL inside the kernel, so they run on all cores).

Why not ``@njit(parallel=True)`` with ``prange``: each parallel kernel took about a second
more to compile (a fresh install compiles every kernel once: 22 s of the README's first run
were compile time, 5 with serial kernels); OpenMP's static schedule makes every kernel wait
for its slowest thread, which on a shared machine is the one whose core another process
holds; and its idle threads had to be told not to spin (``OMP_WAIT_POLICY``). Slices taken
from a queue balance themselves: a thread that gets less CPU takes fewer of them. Every
element is computed by the same compiled code whatever the slicing, so results do not
depend on the number of threads.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

__all__ = ["MIN_PER_THREAD", "for_slices", "n_threads"]

# Below this many elements per thread, the thread hand-over (tens of microseconds) costs
# more than it saves: a 10,000-particle step runs each kernel on one thread.
MIN_PER_THREAD = 16_384
SLICES_PER_THREAD = 4  # more slices than threads, so that a descheduled thread does less

_pool: ThreadPoolExecutor | None = None
_pool_threads = 0


def _forget_pool_after_fork() -> None:
    # a forked child (e.g. a ProcessPoolExecutor worker) inherits the pool object but none of
    # its threads: work submitted to it would wait forever, so the child starts its own
    global _pool, _pool_threads, _cpus
    _pool, _pool_threads, _cpus = None, 0, None


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pool_after_fork)


_cpus: int | None = None  # the CPUs this process may use, asked once (a system call)


def n_threads() -> int:
    """Threads for large kernels: ``MAPFILTER_THREADS`` if set, else the CPUs this process may use."""
    value = os.environ.get("MAPFILTER_THREADS")
    if value:
        return max(1, int(value))
    global _cpus
    if _cpus is None:
        try:
            _cpus = max(1, len(os.sched_getaffinity(0)))
        except AttributeError:  # not on Linux
            _cpus = max(1, os.cpu_count() or 1)
    return _cpus


def for_slices(kernel: Callable[..., None], n: int, *args, min_per_thread: int = MIN_PER_THREAD) -> None:
    """Run ``kernel(lo, hi, *args)`` over slices covering ``[0, n)``.

    One call over everything when ``n`` is below two threads' worth of work (or one thread
    is available); otherwise ``SLICES_PER_THREAD`` slices per thread on the shared pool. The
    kernel must write only the elements of its own slice and release the GIL (``nogil=True``).
    """
    threads = min(n_threads(), n // max(int(min_per_thread), 1))
    if threads <= 1:
        kernel(0, n, *args)
        return
    global _pool, _pool_threads
    if _pool is None or _pool_threads < threads:
        _pool = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="mapfilter")
        _pool_threads = threads
    n_slices = threads * SLICES_PER_THREAD
    bounds = [n * s // n_slices for s in range(n_slices + 1)]
    futures = [_pool.submit(kernel, bounds[s], bounds[s + 1], *args) for s in range(n_slices)]
    for future in futures:
        future.result()  # re-raises a kernel's exception here
