"""How work runs: walks dispatched in this process or over Dask, kernel threads, memory bounds,
and the warm-up that fills numba's cache."""
