"""mapfilter: track a walking person on an indoor floor plan with a map-aware particle filter.

The Python API (``mapfilter.api``; docs/api.md)::

    import mapfilter as mf
    building = mf.load_map("maps/office.yaml")
    walk = mf.read_log("maps/office_walk.txt.gz")
    radio_map = mf.load_radio_map("maps/office_radiomap.npz")
    result = mf.track(building, walk, radio_map=radio_map, config=mf.TrackingConfig(smooth=True, seed=3))

The names are loaded on first use: ``import mapfilter`` alone imports no numerical library.
"""

__version__ = "0.2.0"

_API = ("Building", "Evaluation", "GrowConfig", "GrowReport", "RadioMap", "Recording", "Track", "TrackResult",
        "TrackingConfig", "build_radio_map", "evaluate", "grow_radio_map", "load_access_points", "load_map",
        "load_radio_map", "read_log", "read_track", "track", "write_track")

__all__ = ["__version__", *_API]


def __getattr__(name: str):
    if name in _API:
        from mapfilter import api

        return getattr(api, name)
    raise AttributeError(f"module 'mapfilter' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(__all__)
