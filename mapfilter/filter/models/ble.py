"""BLE beacons as a measurement model: windows of beacon readings weighed by path loss.

The model and stream adapter of the ``ble`` source (registered in ``filter.sources.ble``):
``BeaconSource`` (a ``filter.causal.MeasurementSource``) groups the stream's BLE readings into
measurements and ``BeaconLikelihood`` weighs the particles by them.

Measurements. A measurement is made at the time of a reading that comes at least ``window_s``
after the previous measurement (the first a full window after the first reading), from the
readings of the trailing ``window_s`` up to and including it: per beacon heard, the median RSSI
(a median, because a fade now and then takes 10-20 dB off one reading). So a measurement
depends only on readings stamped at or before its time, each reading counts in one measurement
at most, and a stream that goes quiet leaves no measurement waiting for a later reading (the
tracker never has to hold its other events for one). Beacons not heard in a window say nothing
(as an access point not in a WiFi scan): their readings are few and far between.

Likelihood. The Lund thesis path-loss model of ``filter.models.path_loss.path_loss_kernel``
(alpha 0) with each beacon's C and n, the phone's RSSI offset (the table's for the log's phone
model, else ``BleConfig.rssi_offset_db``), and a loss L per floor between the beacon and the
phone (``sensors.beacons``): a particle on floor f weighs beacon b at the horizontal distance
from the point of floor f above or below the beacon, with C_b - L |f - f_b| as its RSSI at 1 m. A
reading thus says which floor too: a strong one puts the phone on the beacon's floor near it, a
weak one is as likely a floor away as far on the same floor. On one floor (a single map, or a
building's floor given) that is one path-loss kernel over the beacons heard; in a building's
stack plan (``FloorStack``: each floor in its own tile) it is one such kernel per floor, each
particle taking its own floor's value (a few beacons, a few floors: a few times a small kernel;
the per-floor parameters packed by ``filter.models.frame.StateFrame``).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np
from numba import njit

from mapfilter.errors import MapfilterError
from mapfilter.filter.causal import MeasurementSource
from mapfilter.filter.kernels.passes import BLOCK, LIKELIHOOD_SIGNATURE, X
from mapfilter.filter.models.frame import StateFrame, floor_block, particle_floor
from mapfilter.filter.models.interface import LikelihoodKernel, MeasurementModel
from mapfilter.filter.models.path_loss import path_loss_kernel
from mapfilter.sensors.beacons import BeaconTable, beacon_key
from mapfilter.sensors.recording import Recording

if TYPE_CHECKING:  # the config section is the registration's (filter.sources.ble)
    from mapfilter.filter.sources.ble import BleConfig

__all__ = ["BeaconLikelihood", "BeaconSource", "BeaconWindow"]


@dataclasses.dataclass(frozen=True)
class BeaconWindow:
    """One measurement: the beacons heard in a window and each one's median RSSI."""

    t_s: float  # the time of the window's last reading
    beacon: np.ndarray  # (M,) rows of the table, ascending
    rssi_dbm: np.ndarray  # (M,) the median RSSI of each


# the compiled path-loss kernel ``path_loss_kernel`` hands out, called per floor by ``_by_floor``
_PATH_LOSS = path_loss_kernel(np.zeros((0, 2)), [], [], [], [], [], 1.0).function


@njit(LIKELIHOOD_SIGNATURE, cache=True, nogil=True, error_model="numpy")
def _by_floor(params, state, lo, m, out):
    """params: a ``StateFrame.pack`` of each floor's ``path_loss_kernel`` params. Each particle
    takes its own floor's path-loss value (its tile by x, as ``FloorStack.floor_of``)."""
    n_floors = int(params[0])
    floor = np.zeros(BLOCK, dtype=np.int64)
    for j in range(m):
        floor[j] = particle_floor(params, state[X, lo + j])
    values = np.empty(BLOCK)
    for f in range(n_floors):
        start, stop = floor_block(params, f)
        _PATH_LOSS(params[start:stop], state, lo, m, values)
        for j in range(m):
            if floor[j] == f:
                out[j] = values[j]


class BeaconLikelihood(MeasurementModel):
    """Particles weighed by a window of beacon readings (module docstring): ``table`` seen from
    each floor of ``frame``; ``rssi_offset_db``: the phone's RSSI minus the table's (one value, or
    one per beacon), added to every beacon's C."""

    kind = "beacons"
    log_likelihood_peak = 0.0  # -sum (z - R)^2 / (2 var), without its constant

    def __init__(self, table: BeaconTable, frame: StateFrame, variance_db2: float,
                 rssi_offset_db: float | np.ndarray = 0.0) -> None:
        if not (np.isfinite(variance_db2) and variance_db2 > 0):
            raise MapfilterError(f"RSSI variance must be positive, got {variance_db2}")
        self.table = table
        self.frame = frame
        self.variance_db2 = float(variance_db2)
        self.rssi_offset_db = np.broadcast_to(np.asarray(rssi_offset_db, dtype=np.float64), (len(table),))
        beacon_xy, beacon_floor = table.building_xy_m(frame.building)
        # per floor of the state: each beacon seen from it (the point above or below it, in the
        # state's frame) and its RSSI at 1 m there
        self._xy_m = frame.place(beacon_xy)
        self._c_dbm = [table.c_dbm + rssi_offset_db - table.floor_loss_db * apart
                       for apart in frame.floors_apart(beacon_floor)]
        state_floor = {index: f for f, index in enumerate(frame.floors)}
        own = np.array([self._xy_m[state_floor.get(int(b), 0)][i] for i, b in enumerate(beacon_floor)])
        self._own_xy_m = own.reshape(-1, 2)  # each beacon on its own floor, for the viewer

    def heard_ap_xy_m(self, measurement: BeaconWindow) -> np.ndarray:
        """(M, 2) positions of the beacons heard (on their own floors), for the viewer."""
        return self._own_xy_m[measurement.beacon]

    def _floor_params(self, f: int, measurement: BeaconWindow) -> LikelihoodKernel:
        rows = measurement.beacon
        t = self.table
        return path_loss_kernel(self._xy_m[f][rows], self._c_dbm[f][rows], t.n[rows], 0.0, 0.0, measurement.rssi_dbm,
                                self.variance_db2)

    def kernel(self, measurement: BeaconWindow) -> LikelihoodKernel:
        if self.frame.n_floors == 1:
            return self._floor_params(0, measurement)
        per_floor = [self._floor_params(f, measurement).params for f in range(self.frame.n_floors)]
        return LikelihoodKernel(_by_floor, self.frame.pack(per_floor))


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

    def __init__(self, table: BeaconTable, frame: StateFrame, config: BleConfig) -> None:
        super().__init__()
        self.table, self.config = table, config
        self.window_s = float(config.window_s)
        self.offset_db = config.rssi_offset_db
        self._phone_known = False
        self.model = BeaconLikelihood(table, frame, config.rssi_variance_db2, self.offset_db)
        self._index = table.index
        self._t: list[float] = []  # readings of the current window (and before, until dropped)
        self._beacon: list[int] = []
        self._rssi: list[float] = []
        self._next_t: float | None = None  # a measurement comes at the first reading at or after this

    def model_on(self, frame: StateFrame) -> BeaconLikelihood:
        return BeaconLikelihood(self.table, frame, self.config.rssi_variance_db2, self.offset_db)

    def records_of(self, records: Recording) -> tuple:
        """(t_s, table row, RSSI) of the chunk's readings of the table's beacons, in time order."""
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

    def measure(self, records: tuple, final: bool) -> list[tuple[float, BeaconWindow]]:
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

    def _window(self, t_s: float) -> BeaconWindow:
        """The measurement at ``t_s``: readings in (t_s - window_s, t_s]; older ones are dropped."""
        t = np.array(self._t)
        keep = t > t_s - self.window_s
        beacon = np.array(self._beacon)[keep]
        rssi = np.array(self._rssi)[keep]
        self._t, self._beacon, self._rssi = [], [], []  # the next window starts after this reading
        heard = np.unique(beacon)
        return BeaconWindow(t_s, heard, np.array([np.median(rssi[beacon == b]) for b in heard]))
