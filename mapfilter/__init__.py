"""mapfilter: a map-aware particle filter for indoor pedestrian positioning."""

__version__ = "0.1.0"
