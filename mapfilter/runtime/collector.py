"""Python's cyclic garbage collector while a command runs: rarely.

A command allocates arrays and short-lived containers (a log's split lines, its rows) and few
reference cycles; reference counting frees nearly everything. At Python's default threshold (a
young-generation collection every 700 net container allocations) a one-walk ``mapfilter track``
runs about 250 collections, a full one among them, most while it imports numpy, numba and the
kernels and while it reads the log: 5-10 % of the command's CPU (docs/benchmarks.md). A
collection every ``COMMAND_GEN0_THRESHOLD`` allocations still collects every cycle, a few
megabytes later.
"""

from __future__ import annotations

import contextlib
import gc
from collections.abc import Iterator

__all__ = ["COMMAND_GEN0_THRESHOLD", "rare_collections"]

COMMAND_GEN0_THRESHOLD = 50_000  # net container allocations between two young-generation collections


@contextlib.contextmanager
def rare_collections() -> Iterator[None]:
    """Collect cyclic garbage every ``COMMAND_GEN0_THRESHOLD`` allocations while the block runs
    (never more often than the process already does; a collector switched off by a threshold of 0
    stays off); the process's thresholds come back after it (tests run many commands in one)."""
    before = gc.get_threshold()
    if before[0] != 0:
        gc.set_threshold(max(before[0], COMMAND_GEN0_THRESHOLD), *before[1:])
    try:
        yield
    finally:
        gc.set_threshold(*before)
