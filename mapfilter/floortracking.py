"""Tracking in a building: one walk through the filter with the floor in its state.

``track_building`` is ``tracking.track_recording`` for a ``maps.building.Building``: with one
floor, or with the floor given, it is exactly that on the floor's plan (the same track for the
same seed); with several floors and the floor not given, the filter runs on the building's
stack plan (``filter.floors.FloorStack``): particles carry their floor, change floor only in
connectors (or anywhere at a small rate without any), and every scan weighs floors by the WiFi
floor vote and positions by the fix made from each floor's own fingerprints. Tracks come back
in each floor's own frame with the floor's name per row.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.filter.events import StepReport
from mapfilter.filter.floors import FloorChangeConfig, FloorChanges, FloorFix, FloorFixLikelihood, FloorStack
from mapfilter.maps.building import Building
from mapfilter.sensors.floors import floor_vote_log_likelihood
from mapfilter.sensors.radiomap import RadioMap
from mapfilter.sensors.recording import Recording
from mapfilter.sensors.wifi import WifiScan, scans_of
from mapfilter.tracking import TrackingConfig, TrackingResult, WifiMeasurements, track_recording
from mapfilter.trackio import Track


class BuildingWifi:
    """A walk's scans as the multi-floor filter weighs them (``FloorFix`` per scan).

    Per floor, the fix of ``tracking.WifiMeasurements`` made from that floor's fingerprints only
    (so ``blend``, ``fix`` and the fix-sigma calibration work as on one floor), moved into the
    stack frame; per scan, the floor vote of ``sensors.floors.floor_vote_log_likelihood`` over
    the whole building's fingerprints.
    """

    def __init__(self, scans: list[WifiScan], radio_map: RadioMap, stack: FloorStack, config: TrackingConfig,
                 fix_sigma_per_floor_m: dict[str, float] | None = None, log_name: str = "the log"):
        if not radio_map.has_floors:
            raise MapfilterError("tracking across floors needs a building's radio map (floor labels): "
                                 "mapfilter radiomap build BUILDING.yaml LOGS...")
        names = stack.building.floor_names
        if list(radio_map.floor_names) != names:
            raise MapfilterError(f"the radio map's floors ({', '.join(radio_map.floor_names)}) are not the "
                                 f"building's ({', '.join(names)})")
        self.scans = scans
        n_scans, n_floors = len(scans), len(names)
        self.fix_xy_m = np.full((n_scans, n_floors, 2), np.nan)
        sigma = np.full(n_floors, 5.0)
        for f, floor in enumerate(stack.building.floors):
            sub = radio_map.floor_map(f)
            if len(sub) == 0:
                continue
            floor_config = config
            if fix_sigma_per_floor_m and floor.name in fix_sigma_per_floor_m:
                floor_config = dataclasses.replace(config, fix_sigma_m=fix_sigma_per_floor_m[floor.name])
            try:
                wifi = WifiMeasurements(scans, sub, None, floor.plan, floor_config, log_name)
            except MapfilterError:
                continue  # this floor's fingerprints share nothing with the walk: no fix there
            if wifi.fix_xy_m is None:
                raise MapfilterError("tracking across floors weighs fingerprint fixes: use the fingerprint "
                                     "model fix or blend")
            self.fix_xy_m[:, f] = stack.to_stack(wifi.fix_xy_m, f)
            sigma[f] = wifi.model.sigma_m
        self.floor_log_likelihood = floor_vote_log_likelihood(radio_map, radio_map.scan_matrix(scans),
                                                              k=config.kwnn_k)
        self.usable = np.isfinite(self.fix_xy_m).all(axis=2).any(axis=1)
        if not self.usable.any():
            raise MapfilterError(f"no WiFi scan of {log_name} gives a fingerprint fix with this radio map")
        self.model = FloorFixLikelihood(stack, sigma)

    def measurement(self, index: int) -> FloorFix | None:
        """The scan ``index`` as a ``FloorFix`` (None when no floor gives it a fix)."""
        if not self.usable[index]:
            return None
        return FloorFix(self.fix_xy_m[index], self.floor_log_likelihood[index])


def track_building(
    building: Building,
    recording: Recording,
    radio_map: RadioMap,
    config: TrackingConfig = TrackingConfig(),
    rng: np.random.Generator | None = None,
    on_step: Callable[[StepReport], None] | None = None,
    floor: str | None = None,
    fix_sigma_per_floor_m: dict[str, float] | None = None,
    floor_changes: FloorChangeConfig = FloorChangeConfig(),
) -> TrackingResult:
    """Track one walk in a building; tracks in each floor's own frame with a floor per row.

    Parameters
    ----------
    building : the floors (a one-floor building is a single map).
    recording : the walk.
    radio_map : a building's radio map (floor labels), or any radio map for one floor.
    config, rng, on_step : as for ``tracking.track_recording``.
    floor : track on this floor only (the floor given) instead of finding it.
    fix_sigma_per_floor_m : the fix Gaussian of each floor by name, instead of calibrating it
        from each floor's fingerprints.
    floor_changes : how particles change floor.
    """
    rng = rng if rng is not None else np.random.default_rng(0)
    if building.is_single_floor or floor is not None:
        index = 0 if building.is_single_floor else building.floor_index(floor)
        plan = building.floors[index].plan
        floor_map = radio_map.floor_map(index) if radio_map.has_floors else radio_map
        if radio_map.has_floors and radio_map.floor_names[index] != building.floors[index].name:
            raise MapfilterError(f"the radio map's floor {radio_map.floor_names[index]!r} is not the building's "
                                 f"{building.floors[index].name!r}")
        if fix_sigma_per_floor_m and building.floors[index].name in fix_sigma_per_floor_m:
            config = dataclasses.replace(config, fix_sigma_m=fix_sigma_per_floor_m[building.floors[index].name])
        result = track_recording(plan, recording, floor_map, None, config, rng, on_step=on_step)
        name = building.floors[index].name
        result.track.floor = [name] * len(result.track)
        if result.smoothed is not None:
            result.smoothed.floor = [name] * len(result.smoothed)
        return result
    if not config.use_map:
        raise MapfilterError("tracking across floors needs the walls (the floors are kept apart by them): "
                             "drop --no-map or give the floor")
    stack = FloorStack(building)
    log_name = str(recording.path) if recording.path is not None else "the log"
    wifi = BuildingWifi(scans_of(recording), radio_map, stack, config, fix_sigma_per_floor_m, log_name)
    changes = FloorChanges(stack, floor_changes)
    result = track_recording(stack.plan, recording, None, None, config, rng, on_step=on_step, wifi=wifi,
                             floors=changes)
    result.track = _to_floors(stack, result.track)
    if result.smoothed is not None:
        result.smoothed = _to_floors(stack, result.smoothed)
    return result


def _to_floors(stack: FloorStack, track: Track) -> Track:
    """A stack-frame track -> each row in its floor's own frame, with the floor's name."""
    xy, floor = stack.to_floor(track.xy_m)
    names = stack.building.floor_names
    return dataclasses.replace(track, xy_m=xy, floor=[names[f] for f in floor])

