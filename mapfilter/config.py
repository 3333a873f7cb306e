"""Every setting of a tracking run in one ``TrackingConfig``, which a user can save and reload.

``mapfilter config show`` prints the defaults as YAML, a one-line comment per setting; commands
take ``--config FILE`` (flags override the file) and write the config that ran beside their
results, so a run can be repeated from its outputs::

    config = TrackingConfig.from_yaml("my.yaml")           # or YAML text
    print(config.to_yaml())
"""

from __future__ import annotations

import dataclasses
import functools
import os
from collections.abc import Mapping
from typing import Any

from mapfilter.errors import MapfilterError
from mapfilter.filter.models.barometer import BarometerConfig
from mapfilter.filter.evidence import TrilaterationConfig, WifiConfig
from mapfilter.filter.models.building import FloorChangeConfig
from mapfilter.filter.particle_filter import FilterConfig
from mapfilter.filter.causal import MotionConfig
from mapfilter.filter.sources import registered
from mapfilter.offline.whole_walk import OfflineConfig
from mapfilter.sensors.pdr import PDRConfig
from mapfilter.settings import REMOVED_SETTINGS_NOTE, replace_setting, settings_from_yaml, settings_to_dict, settings_to_yaml

__all__ = ["FloorsConfig", "SourcesConfig", "TrackingConfig"]

@dataclasses.dataclass(frozen=True)
class FloorsConfig:
    """A building with several floors: how the floor is found."""

    changes: FloorChangeConfig = dataclasses.field(default_factory=FloorChangeConfig)  # how particles change floor
    use_barometer: bool = True  # weigh floors by the log's barometer when it has one
    barometer: BarometerConfig = dataclasses.field(default_factory=BarometerConfig)  # how the barometer weighs floors


# one section per registered measurement source (filter.sources), each the source's own config
SourcesConfig = dataclasses.make_dataclass(
    "SourcesConfig", [(p.name, p.config, dataclasses.field(
        default_factory=p.config, metadata={"doc": f"{p.title} ({', '.join(o.flag for o in p.options)})"}))
        for p in registered()], frozen=True)
SourcesConfig.__module__ = __name__  # pickled by name (to Dask workers)
SourcesConfig.__doc__ = "The measurement sources besides WiFi (``filter.sources``): a section each."


@dataclasses.dataclass(frozen=True)
class TrackingConfig:
    """Every setting of tracking one walk (``mapfilter.track``). ``mapfilter config show`` lists them."""

    seed: int = 0  # the only source of randomness: same seed, same track
    smooth: bool = False  # also make the offline track (the whole walk for every point; not causal)
    use_map: bool = True  # false: walls ignored (what the map buys: the pf-nomap comparison)
    motion: MotionConfig = dataclasses.field(default_factory=MotionConfig)  # how particles move
    steps: PDRConfig = dataclasses.field(default_factory=PDRConfig)  # step detection, heading and step length from the IMU
    wifi: WifiConfig = dataclasses.field(default_factory=WifiConfig)  # fingerprinting (a radio map)
    trilateration: TrilaterationConfig = dataclasses.field(default_factory=TrilaterationConfig)  # an access-point table
    filter: FilterConfig = dataclasses.field(default_factory=FilterConfig)  # the particle filter
    floors: FloorsConfig = dataclasses.field(default_factory=FloorsConfig)  # a building's floors
    offline: OfflineConfig = dataclasses.field(default_factory=OfflineConfig)  # the offline track (smooth)
    sources: SourcesConfig = dataclasses.field(default_factory=SourcesConfig)  # measurement sources besides WiFi, weighed when given

    def __post_init__(self) -> None:
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise MapfilterError(f"the seed must be a whole number >= 0, got {self.seed!r}")

    def with_particles(self, n_particles: int) -> TrackingConfig:
        """The same config with ``n_particles`` particles."""
        return dataclasses.replace(self, filter=dataclasses.replace(self.filter, n_particles=n_particles))

    def override(self, settings: Mapping[str, Any]) -> TrackingConfig:
        """The same config with the settings named by dotted keys replaced, e.g.
        ``config.override({"motion.model": "cv", "filter.n_particles": 2000})``."""
        config = self
        for dotted, value in settings.items():
            try:
                config = replace_setting(config, dotted, value)
            except (AttributeError, TypeError):
                raise MapfilterError(f"unknown setting {dotted!r} ({REMOVED_SETTINGS_NOTE})") from None
        return config

    def to_yaml(self) -> str:
        """Every setting as YAML, with a one-line comment each; ``from_yaml`` reads it back."""
        return settings_to_yaml(self, header="mapfilter tracking config: every setting, with its default unless "
                                             "changed.\nLoad it with --config FILE (flags override it) or "
                                             "TrackingConfig.from_yaml(path).")

    def to_dict(self) -> dict:
        """Every setting as plain data (nested dicts), e.g. for a JSON summary."""
        return settings_to_dict(self)

    @classmethod
    def from_yaml(cls, text_or_path: str | os.PathLike, base: TrackingConfig | None = None) -> TrackingConfig:
        """A config from YAML text or a file: the settings given, the rest from ``base`` (default:
        the defaults). Unknown settings and wrong values are one line naming the file and line."""
        return settings_from_yaml(cls, text_or_path, base)


def _setting_names(section: type, prefix: str = "") -> list[str]:
    """Every setting below a config dataclass, by its dotted name (``filter.n_particles``)."""
    names = []
    for field in dataclasses.fields(section):
        kind = field.type if isinstance(field.type, type) else globals().get(str(field.type))
        default = field.default_factory() if field.default_factory is not dataclasses.MISSING else field.default
        if dataclasses.is_dataclass(kind) or dataclasses.is_dataclass(default):
            names += _setting_names(type(default) if dataclasses.is_dataclass(default) else kind,
                                    f"{prefix}{field.name}.")
        else:
            names.append(prefix + field.name)
    return names


def flat_setting_message(name: str, value: Any) -> str:
    """Why ``TrackingConfig(name=value)`` is refused, and what to write instead: a setting of a
    section is named with its section (``override``), the particle count has ``with_particles``."""
    import difflib

    dotted = [n for n in _setting_names(TrackingConfig) if n.rsplit(".", 1)[-1] == name and "." in n]
    if not dotted:
        near = difflib.get_close_matches(name, {n.rsplit(".", 1)[-1] for n in _setting_names(TrackingConfig)}, n=1)
        hint = f"; did you mean {near[0]!r}?" if near else ""
        return f"TrackingConfig has no setting {name!r}{hint} (mapfilter config show lists every setting)"
    instead = f"TrackingConfig().override({{{dotted[0]!r}: {value!r}}})"
    if dotted == ["filter.n_particles"]:
        instead = f"TrackingConfig().with_particles({value!r}) or {instead}"
    where = f"the setting {dotted[0]}" if len(dotted) == 1 else f"a setting of several sections ({', '.join(dotted)})"
    return f"TrackingConfig takes no {name!r} of its own: it is {where}; give {instead}"


def _own_settings_only(init):
    """``TrackingConfig(...)`` takes its own fields; a section's setting given flat
    (``TrackingConfig(n_particles=2000)``) is a ``TypeError`` saying where it lives."""
    own = {field.name for field in dataclasses.fields(TrackingConfig)}

    @functools.wraps(init)
    def checked(self, *args, **settings) -> None:
        for name, value in settings.items():
            if name not in own:
                raise TypeError(flat_setting_message(name, value))
        init(self, *args, **settings)

    return checked


TrackingConfig.__init__ = _own_settings_only(TrackingConfig.__init__)
