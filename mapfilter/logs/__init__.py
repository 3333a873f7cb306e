"""Log readers: phone walks -> ``Recording``."""

from mapfilter.logs.ilc import read_ilc
from mapfilter.logs.recording import Recording, WifiScans

__all__ = ["read_ilc", "Recording", "WifiScans"]
