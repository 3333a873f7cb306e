"""BLE beacons as a measurement source: the log's beacon readings weighed against a beacon table.

The model and its stream adapter are ``filter.models.ble``; the table, the survey readings and
the fit are ``sensors.beacons`` (``mapfilter radiomap fit-beacons``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from mapfilter.errors import MapfilterError
from mapfilter.filter.sources import SourceOption, SourcePlugin

MAX_RSSI_OFFSET_DB = 40.0  # a phone further off than this from the table reads another signal


@dataclasses.dataclass(frozen=True)
class BleConfig:
    """BLE beacons (a beacon table): how their readings weigh the particles."""

    # the IPIN 2023 phones report a beacon 0.1-2.2 times a second (median 0.6): 2 s holds up to four readings
    window_s: float = 2.0  # a measurement every window_s at most: each beacon's median RSSI over the trailing window_s
    # a beacon's error along a route (its shadowing) lasts for many windows, which the filter
    # weighs as if independent: a variance above the readings' own 4-6 dB spread (docs/ipin.md)
    rssi_variance_db2: float = 100.0  # RSSI noise variance of a window's median under the path-loss model
    # phones report one signal several dB apart (9 dB between the two IPIN 2023 phones)
    rssi_offset_db: float = 0.0  # the phone's RSSI minus the table's, for a phone model the table gives no offset for

    def __post_init__(self) -> None:
        if not (math.isfinite(self.window_s) and self.window_s > 0):
            raise MapfilterError(f"ble window_s must be a positive number of seconds, got {self.window_s}")
        if not (math.isfinite(self.rssi_variance_db2) and self.rssi_variance_db2 > 0):
            raise MapfilterError(f"ble rssi_variance_db2 must be positive, got {self.rssi_variance_db2}")
        if not (math.isfinite(self.rssi_offset_db) and abs(self.rssi_offset_db) <= MAX_RSSI_OFFSET_DB):
            raise MapfilterError(f"ble rssi_offset_db must be within +-{MAX_RSSI_OFFSET_DB:g} dB, got "
                                 f"{self.rssi_offset_db}")


class BlePlugin(SourcePlugin):
    """BLE beacons: a beacon table (``sensors.beacons.BeaconTable``) is the input."""

    name = "ble"
    title = "BLE beacons"
    options = (SourceOption("--beacons", "TABLE.csv",
                            "BLE beacon table (mapfilter radiomap fit-beacons): weigh the log's beacon readings too, "
                            "or alone without WiFi"),)
    config = BleConfig
    counts = "beacon windows"
    help = ("BLE beacons: --beacons TABLE.csv (fit one with `mapfilter radiomap fit-beacons`) weighs the log's "
            "beacon readings too (config section sources.ble), each phone model with the RSSI offset the table "
            "gives it; with --beacons and no WiFi source, the beacons alone (and, in a building, the barometer) "
            "place the walker. In `evaluate` with --survey or --leave-one-out, each walk's table takes the given "
            "positions with C, n, the floor loss and the phones' offsets fitted on the labelled walks (never the "
            "walk itself); with --radiomap, the table as given.")

    def load(self, files: Mapping[str, Path], building) -> Any:
        from mapfilter.sensors.beacons import BeaconTable, check_beacons_on_map

        table = BeaconTable.read_csv(files["beacons"], building)
        check_beacons_on_map(table, building, building.path)
        return table

    def check(self, given: Any) -> Any:
        from mapfilter.sensors.beacons import BeaconTable

        if not isinstance(given, BeaconTable):
            raise TypeError(f"sources['ble']: expected a BeaconTable (mf.load_beacons) or the path of its CSV, got "
                            f"{type(given).__name__}")
        return given

    def source(self, given: Any, frame, config: BleConfig):
        from mapfilter.filter.models.ble import BeaconSource

        return BeaconSource(given, frame, config)

    def survey(self, given: Any, building, recordings: Sequence) -> Any:
        from mapfilter.sensors.beacons import labelled_readings

        return labelled_readings(given, building, recordings)

    def for_walk(self, given: Any, survey: Any, left_out: Sequence[str]) -> Any:
        """The table's positions with C, n, the floor loss and the phones' offsets fitted on the
        labelled walks' readings less those of ``left_out``."""
        from mapfilter.sensors.beacons import fit_beacons

        if survey is None:
            return given
        return fit_beacons(given, survey.without_traces(left_out)).table


SOURCE = BlePlugin()
