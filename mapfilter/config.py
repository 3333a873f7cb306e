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
from mapfilter.settings import (replace_setting, retired_setting_message, settings_from_yaml, settings_to_dict,
                                settings_to_yaml)

__all__ = ["RETIRED_SETTINGS", "FloorsConfig", "SourcesConfig", "TrackingConfig"]

# Settings that were folded into their model's constants: the model's shape, not a user's choice
# (the reason beside each constant, the measurements in docs/accuracy.md)
_FOLDED = {
    "mapfilter.filter.models.motion": ("motion.pdr.turn_threshold_rad", "motion.pdr.step_length_walk_sigma_m",
                                       "motion.pdr.position_sigma_m"),
    "mapfilter.filter.causal": ("motion.idle_tick_s", "motion.initial_heading_sigma_rad"),
    "mapfilter.sensors.pdr": tuple(f"steps.{name}" for name in (
        "sample_rate_hz", "lowpass_hz", "lowpass_order", "step_threshold_rms_fraction", "step_threshold_window_s",
        "min_step_threshold_mps3", "gravity_lowpass_hz", "max_step_window_s", "imu_gap_s", "max_gap_s")),
    "mapfilter.filter.models.radio_map": tuple(f"wifi.radio_map_likelihood.{name}" for name in (
        "support_sigmas", "sigma_floor_db", "prior_sigma_db", "prior_weight", "prior_heard", "prior_rssi_dbm",
        "heard_clip", "min_observations", "min_weight")),
    "mapfilter.filter.models.adaptive_path_loss": tuple(
        [f"trilateration.adaptation.{name}" for name in (
            "vertical_distance_m", "c_gain", "alpha_gain", "alpha_min_distance_m", "alpha_min_aps",
            "alpha_bounds_db_per_m", "share_c_correction")]
        + [f"trilateration.blocking.{name}" for name in (
            "top_k", "recover_db", "reference_gain", "max_blocked_s", "h_source")]),
    "mapfilter.filter.particle_filter": ("filter.regularise_tries",),
    "mapfilter.filter.models.building": ("floors.changes.height_decides_in_connector", "floors.changes.stairs_tread_m"),
    "mapfilter.filter.models.barometer": tuple(f"floors.barometer.{name}" for name in (
        "anchor_share", "steady_m", "steady_window_s", "drift_m_per_s", "smoothing_window_s")),
}
# {dotted name in an old config file: what became of it}; such a file is refused naming the line
RETIRED_SETTINGS: dict[str, str] = {
    **{name: f"a constant of {module}" for module, names in _FOLDED.items() for name in names},
    "trilateration.adaptation.rssi_limit_dbm": "now trilateration.adapt_rssi_limit_dbm",
    "trilateration.blocking.drop_db": "now trilateration.blocking_drop_db",
    # off by default and measured worse (docs/accuracy.md): the code is gone
    "trilateration.blocking.min_fraction_dropped": "removed: the per-AP drop check missed real onsets",
    "trilateration.blocking.max_ambiguous_scans": "removed with the per-AP drop check",
    "steps.step_length_m": "removed: never read (the step length is Weinberg's)",
    "steps.step_length_std_m": "removed: never read (the filter's step length walks by itself)",
    "offline.restart_from_placement": "removed: the offline track always smooths a second forward pass on one floor",
    "offline.restart_radius_m": "now a constant of mapfilter.pipeline.offline (RESTART_RADIUS_M)",
    # the one filter step (filter/kernels/passes.py) has one resampler and one kernel
    "filter.fused_from_particles": "removed: every particle count takes the one step (filter/kernels/passes.py)",
    "filter.resampler": "removed: the step resamples systematically",
    "filter.kernel": "removed: the step's regularisation kernel is Gaussian",
    **{f"filter.{name}": "a constant of mapfilter.filter.particle_filter" for name in (
        "recovery_radius_m", "recovery_radius_growth", "recovery_reset_steps", "recovery_measurement_max_age_s",
        "recovery_heading_keep_fraction")},
    "motion.pdr.fixed_step_length_m": "removed: the step length is always the state's, a random walk "
                                      "within motion.pdr.step_length_min_m..max_m",
    "motion.pdr.step_length_input_sigma_m": "removed with motion.pdr.fixed_step_length_m (the state's random "
                                            "walk: STEP_LENGTH_WALK_SIGMA_M in mapfilter.filter.models.motion)",
    # the BLE section became a measurement source's (filter/sources/ble.py)
    **{f"ble.{name}": f"now sources.ble.{name}" for name in ("window_s", "rssi_variance_db2", "rssi_offset_db")},
}


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
                raise MapfilterError(retired_setting_message(dotted, RETIRED_SETTINGS)
                                     or f"unknown setting {dotted!r}") from None
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
        the defaults). Unknown settings and wrong values are one line naming the file and line; a
        setting of an older mapfilter (``RETIRED_SETTINGS``) says it is no longer a setting."""
        return settings_from_yaml(cls, text_or_path, base, RETIRED_SETTINGS)


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
