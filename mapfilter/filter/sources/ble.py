"""BLE beacons as a measurement source: the log's beacon readings weighed against a beacon table.

Its registration, config section and stream adapter; the likelihood is ``filter.models.ble``;
the table, the survey readings and the fit are ``sensors.beacons`` (``mapfilter radiomap
fit-beacons``).

Measurements. A measurement is made at the time of a reading that comes at least ``window_s``
after the previous measurement (the first a full window after the first reading), from the
readings of the trailing ``window_s`` up to and including it: per beacon heard, the median RSSI
(a median, because a fade now and then takes 10-20 dB off one reading). So a measurement
depends only on readings stamped at or before its time, each reading counts in one measurement
at most, and a stream that goes quiet leaves no measurement waiting for a later reading (the
tracker never has to hold its other events for one). Beacons not heard in a window say nothing
(as an access point not in a WiFi scan): their readings are few and far between.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from mapfilter.errors import MapfilterError
from mapfilter.filter.measurement import MeasurementSource
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

    def source(self, given: Any, frame, config: BleConfig) -> BeaconSource:
        return BeaconSource(given, frame, config)

    def example(self, log: Path, building, folder: Path, rng) -> tuple[dict[str, Path], Path]:
        """Eight beacons on the first floor's free space (C -62 dBm, n 2.1), each read about
        once a second along the walk's waypoints with 4 dB of noise, unheard below -100 dBm:
        the table, and the log (an ILC trace) with the readings as TYPE_BEACON rows."""
        import gzip

        import numpy as np

        from mapfilter.sensors.beacons import beacon_rssi_dbm
        from mapfilter.sensors.logs import read_log, read_log_header

        if read_log_header(log).get("format") != "ILC 2.0":
            raise MapfilterError("the BLE example writes TYPE_BEACON rows: it needs an ILC 2.0 trace", log)
        xy = building.floors[0].plan.sample_free(8, rng)
        floor = "" if building.is_single_floor else building.floor_names[0]
        macs = [f"00:AB:CD:EF:01:{i:02X}" for i in range(len(xy))]
        table = folder / "beacons.csv"
        table.write_text("beacon_id,x,y,floor,C,n\n" + "".join(
            f"{mac},{x:.2f},{y:.2f},{floor},-62,2.1\n" for mac, (x, y) in zip(macs, xy)))
        walk = read_log(log)
        t0, t1 = walk.waypoint_t_s[0], walk.waypoint_t_s[-1]
        rows = []
        for mac, beacon_xy in zip(macs, xy):
            t = np.sort(rng.uniform(t0, t1, int(t1 - t0)))
            truth = np.column_stack([np.interp(t, walk.waypoint_t_s, walk.waypoint_xy_m[:, k]) for k in (0, 1)])
            rssi = np.round(beacon_rssi_dbm(np.linalg.norm(truth - beacon_xy, axis=1), -62.0, 2.1)
                            + 4.0 * rng.standard_normal(t.size))
            # an ILC trace's TYPE_BEACON row: uuid, major, minor, tx power, RSSI, distance, MAC, time
            rows += [(ms, f"{ms}\tTYPE_BEACON\tfda50693-a4e2-4fb1-afcf-c6eb07647825\t1\t1\t-59\t{int(r)}\t1.0\t"
                          f"{mac}\t{ms}\n") for ms, r in zip(np.round(t * 1000).astype(np.int64).tolist(), rssi)
                     if r >= -100]
        data = Path(log).read_bytes()
        lines = (gzip.decompress(data) if data[:2] == b"\x1f\x8b" else data).decode().splitlines(keepends=True)
        records = sorted([(int(line.split("\t", 1)[0]), line) for line in lines if not line.startswith("#")]
                         + rows, key=lambda row: row[0])
        out = folder / "walk_with_beacons.txt"
        out.write_text("".join([*(line for line in lines if line.startswith("#") and "endTime" not in line),
                                *(line for _, line in records),
                                *(line for line in lines if line.startswith("#") and "endTime" in line)]))
        return {"beacons": table}, out

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


class BeaconSource(MeasurementSource):
    """The BLE readings of a stream as measurements (module docstring); readings of beacons the
    table does not have are left out. The RSSI offset is the table's for the log's phone model
    (the first chunk that names one: ``offset_db:MODEL``), else the config's."""

    stream = "ble"
    # readings come 0.1-2 times a second per beacon: the merge must not wait for the next one.
    # GetSensorData logs its BLE4 rows in time order with the others; the ILC logger writes its
    # TYPE_BEACON rows up to 1.0 s behind the newest record (IPIN 2023, ILC site 1 F1)
    WRITTEN_BEHIND_S = {"GetSensorData": 0.1}
    WRITTEN_BEHIND_OTHER_S = 1.5

    def __init__(self, table, frame, config: BleConfig) -> None:
        super().__init__()
        self.table, self.config = table, config
        self.window_s = float(config.window_s)
        self.offset_db = config.rssi_offset_db
        self._phone_known = False
        self.model = self.model_on(frame)
        self._index = table.index
        self._t: list[float] = []  # readings of the current window (and before, until dropped)
        self._beacon: list[int] = []
        self._rssi: list[float] = []
        self._next_t: float | None = None  # a measurement comes at the first reading at or after this

    def model_on(self, frame):
        from mapfilter.filter.models.ble import BeaconLikelihood

        return BeaconLikelihood(self.table, frame, self.config.rssi_variance_db2, self.offset_db)

    def records_of(self, records) -> tuple:
        """(t_s, table row, RSSI) of the chunk's readings of the table's beacons, in time order."""
        import numpy as np

        from mapfilter.sensors.beacons import beacon_key

        report = records.read_report
        if self.written_behind_s is None and report is not None and report.format:
            self.written_behind_s = self.WRITTEN_BEHIND_S.get(report.format, self.WRITTEN_BEHIND_OTHER_S)
        if not self._phone_known and records.phone_model:
            self._phone_known = True
            offset = self.table.phone_offsets_db.get(records.phone_model)
            if offset is not None:
                self.offset_db = offset
                self.model = self.model_on(self.model.frame)
        beacons = records.beacons
        if len(beacons.t_s) == 0:
            return np.zeros(0), np.zeros(0, dtype=np.int64), np.zeros(0)
        row = np.array([self._index.get(beacon_key(b), -1) for b in beacons.beacon_id], dtype=np.int64)
        rssi = np.asarray(beacons.rssi_dbm, dtype=np.float64)
        keep = (row >= 0) & np.isfinite(rssi)
        t = np.asarray(beacons.t_s, dtype=np.float64)[keep]
        order = np.argsort(t, kind="stable")
        return t[order], row[keep][order], rssi[keep][order]

    def measure(self, records: tuple, final: bool) -> list[tuple[float, Any]]:
        """Released readings in; the measurements they completed."""
        t_s, rows, rssi = records
        made = []
        n = len(t_s)
        for i in range(n):
            t = float(t_s[i])
            self._t.append(t)
            self._beacon.append(int(rows[i]))
            self._rssi.append(float(rssi[i]))
            if self._next_t is None:
                self._next_t = t + self.window_s
            # a reading at the window's end, after every reading stamped at its time
            if t >= self._next_t and (i + 1 == n or float(t_s[i + 1]) > t):
                made.append((t, self._window(t)))
                self._next_t = t + self.window_s
        return made

    def _window(self, t_s: float):
        """The measurement at ``t_s``: readings in (t_s - window_s, t_s]; older ones are dropped."""
        import numpy as np

        from mapfilter.filter.models.ble import BeaconWindow

        t = np.array(self._t)
        keep = t > t_s - self.window_s
        beacon = np.array(self._beacon)[keep]
        rssi = np.array(self._rssi)[keep]
        self._t, self._beacon, self._rssi = [], [], []  # the next window starts after this reading
        heard = np.unique(beacon)
        return BeaconWindow(t_s, heard, np.array([np.median(rssi[beacon == b]) for b in heard]))


SOURCE = BlePlugin()
