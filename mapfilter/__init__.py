"""mapfilter: track a walking person on an indoor floor plan with a map-aware particle filter.

The Python API (``mapfilter.api``; docs/api.md)::

    import mapfilter as mf
    building = mf.load_map("maps/office.yaml")
    walk = mf.read_log("maps/office_walk.txt.gz")
    radio_map = mf.load_radio_map("maps/office_radiomap.npz")
    result = mf.track(building, walk, radio_map=radio_map, config=mf.TrackingConfig(smooth=True, seed=3))

The names are loaded on first use: ``import mapfilter`` alone imports no numerical library.
"""

import os as _os

__version__ = "0.3.0"


def _numba_cache_dir() -> None:
    """Point numba's cache (``NUMBA_CACHE_DIR``) at a per-user folder when the package's own
    ``__pycache__`` cannot be written (a system-wide or container install, a read-only file
    system): numba's kernels are compiled with ``cache=True``, and without a writable place
    every command would fail with "cannot cache function ...: no locator available". Runs
    before numba is imported anywhere; a cache folder the user chose is left alone."""
    if _os.environ.get("NUMBA_CACHE_DIR"):
        return
    package = _os.path.dirname(_os.path.abspath(__file__))
    if _writable(_os.path.join(package, "__pycache__"), package):
        return
    base = _os.environ.get("XDG_CACHE_HOME") or _os.path.join(_os.path.expanduser("~"), ".cache")
    for folder in (_os.path.join(base, "mapfilter", "numba"),
                   _os.path.join(__import__("tempfile").gettempdir(), f"mapfilter-numba-{_os.getuid()}")):
        if _writable(folder, None):
            _os.environ["NUMBA_CACHE_DIR"] = folder
            return


def _writable(folder: str, parent: str | None) -> bool:
    """``folder`` can be written in (made if missing), tried for real: ``os.access`` knows nothing
    of read-only mounts."""
    import tempfile

    try:
        if not _os.path.isdir(folder):
            if parent is not None and not _os.access(parent, _os.W_OK):
                return False
            _os.makedirs(folder, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            return True
    except OSError:
        return False


_numba_cache_dir()

# cached kernels load without numba's whole compiler set up (runtime/numba_cache.py); numba is
# not imported here
from mapfilter.runtime import numba_cache as _numba_cache  # noqa: E402

_numba_cache.install()

_API = ("BeaconFit", "BeaconTable", "Building", "Evaluation", "GrowConfig", "GrowReport", "LogStream", "RadioMap",
        "Recording", "Track", "TrackResult", "Tracker", "TrackingConfig", "TrackingInputs", "build_radio_map",
        "enter_trial", "evaluate", "fit_beacons", "grow_radio_map", "load_access_points", "load_beacons", "load_map",
        "load_radio_map", "load_sources", "read_log", "read_track", "score", "track", "write_track")

__all__ = ["__version__", *_API]


def __getattr__(name: str):
    if name in _API:
        from mapfilter import api

        return getattr(api, name)
    raise AttributeError(f"module 'mapfilter' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(__all__)
