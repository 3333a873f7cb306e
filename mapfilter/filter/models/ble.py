"""BLE beacons as a measurement model: windows of beacon readings weighed by path loss.

A plug-in through the filter's interfaces alone (``filter.models.interface``,
``filter.causal.MeasurementSource``): ``BeaconSource`` groups the stream's BLE readings into
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
(alpha 0) with each beacon's C and n, the phone's RSSI offset (``BleConfig.rssi_offset_db``),
and a loss L per floor between the beacon and the phone (``sensors.beacons``): a particle on floor f weighs beacon b at the horizontal distance from
the point of floor f above or below the beacon, with C_b - L |f - f_b| as its RSSI at 1 m. A
reading thus says which floor too: a strong one puts the phone on the beacon's floor near it, a
weak one is as likely a floor away as far on the same floor. On one floor (a single map, or a
building's floor given) that is one path-loss kernel over the beacons heard; in a building's
stack plan (``FloorStack``: each floor in its own tile) it is one such kernel per floor, each
particle taking its own floor's value (a few beacons, a few floors: a few times a small kernel).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numba import njit

from mapfilter.errors import MapfilterError
from mapfilter.filter.kernels.passes import BLOCK, LIKELIHOOD_SIGNATURE, X
from mapfilter.filter.models.building import FloorStack
from mapfilter.filter.models.interface import LikelihoodKernel, MeasurementModel
from mapfilter.filter.models.path_loss import path_loss_kernel
from mapfilter.maps.building import Building
from mapfilter.sensors.beacons import BeaconTable, beacon_key
from mapfilter.sensors.recording import Recording

__all__ = ["BeaconLikelihood", "BeaconSource", "BeaconWindow", "BleConfig", "beacon_source"]

MAX_RSSI_OFFSET_DB = 40.0  # a phone further off than this from the table reads another signal


@dataclasses.dataclass(frozen=True)
class BleConfig:
    """BLE beacons (a beacon table): how their readings weigh the particles."""

    # the IPIN 2023 phones report a beacon 0.1-2.2 times a second (median 0.6): 2 s holds up to four readings
    window_s: float = 2.0  # a measurement every window_s at most: each beacon's median RSSI over the trailing window_s
    # (10 dB)^2, where the IPIN 2023 venue's fitted beacons leave 4-6 dB RMS per reading: a
    # beacon's error on a route (its shadowing, -7 dB along one walked there) lasts for many
    # windows, which the filter weighs as if independent. On 8 of the 29 IPIN 2023 walks, pf with
    # the beacons had mean error 3.52 m at 36 dB^2, 2.92 m at 100 and 2.97 m at 225 (WiFi alone 3.50)
    rssi_variance_db2: float = 100.0  # RSSI noise variance of a window's median under the path-loss model
    # phones report one signal several dB apart: 9 dB between the two IPIN 2023 phones
    rssi_offset_db: float = 0.0  # the phone's RSSI minus the beacon table's (radiomap fit-beacons prints it per phone model)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.window_s) and self.window_s > 0):
            raise MapfilterError(f"ble window_s must be a positive number of seconds, got {self.window_s}")
        if not (math.isfinite(self.rssi_variance_db2) and self.rssi_variance_db2 > 0):
            raise MapfilterError(f"ble rssi_variance_db2 must be positive, got {self.rssi_variance_db2}")
        if not (math.isfinite(self.rssi_offset_db) and abs(self.rssi_offset_db) <= MAX_RSSI_OFFSET_DB):
            raise MapfilterError(f"ble rssi_offset_db must be within +-{MAX_RSSI_OFFSET_DB:g} dB, got "
                                 f"{self.rssi_offset_db}")


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
    """params: F, then the x where each floor's tile starts (F), then where each floor's
    ``path_loss_kernel`` params start and stop in ``params`` (2 F), then those params. Each
    particle takes its own floor's path-loss value (its tile by x, as ``FloorStack.floor_of``)."""
    n_floors = int(params[0])
    floor = np.zeros(BLOCK, dtype=np.int64)
    for j in range(m):
        x = state[X, lo + j]
        for f in range(1, n_floors):
            if x >= params[1 + f]:
                floor[j] = f
    values = np.empty(BLOCK)
    for f in range(n_floors):
        start = int(params[1 + n_floors + 2 * f])
        stop = int(params[2 + n_floors + 2 * f])
        _PATH_LOSS(params[start:stop], state, lo, m, values)
        for j in range(m):
            if floor[j] == f:
                out[j] = values[j]



class BeaconLikelihood(MeasurementModel):
    """Particles weighed by a window of beacon readings (module docstring).

    ``table`` placed in ``building``; the state is one floor (``floor``: its index, the plan
    frame that floor's) or, with ``stack``, every floor of the building side by side.
    ``rssi_offset_db``: the phone's RSSI minus the table's, added to every beacon's C.
    """

    kind = "beacons"
    log_likelihood_peak = 0.0  # -sum (z - R)^2 / (2 var), without its constant

    def __init__(self, table: BeaconTable, building: Building, variance_db2: float, *, floor: int = 0,
                 stack: FloorStack | None = None, rssi_offset_db: float = 0.0) -> None:
        if not (math.isfinite(variance_db2) and variance_db2 > 0):
            raise MapfilterError(f"RSSI variance must be positive, got {variance_db2}")
        self.table = table
        self.variance_db2 = float(variance_db2)
        self.stack = stack
        beacon_xy, beacon_floor = table.building_xy_m(building)
        floors = range(len(building.floors) if stack is not None else 1)
        # per floor of the state: each beacon seen from it (the point above or below it, in the
        # state's frame) and its RSSI at 1 m there
        self._xy_m, self._c_dbm = [], []
        for f in floors:
            index = f if stack is not None else floor
            xy = building.floors[index].from_building(beacon_xy)
            self._xy_m.append(stack.to_stack(xy, index) if stack is not None else xy)
            self._c_dbm.append(table.c_dbm + rssi_offset_db - table.floor_loss_db * np.abs(index - beacon_floor))
        own = np.array([self._xy_m[int(f) if stack is not None else 0][i] for i, f in enumerate(beacon_floor)])
        self._own_xy_m = own.reshape(-1, 2)  # each beacon on its own floor, for the viewer
        self._tile_x_min_m = stack.tile_x_min_m if stack is not None else None

    def heard_ap_xy_m(self, measurement: BeaconWindow) -> np.ndarray:
        """(M, 2) positions of the beacons heard (on their own floors), for the viewer."""
        return self._own_xy_m[measurement.beacon]

    def _floor_params(self, f: int, measurement: BeaconWindow) -> LikelihoodKernel:
        rows = measurement.beacon
        t = self.table
        return path_loss_kernel(self._xy_m[f][rows], self._c_dbm[f][rows], t.n[rows], 0.0, 0.0, measurement.rssi_dbm,
                                self.variance_db2)

    def kernel(self, measurement: BeaconWindow) -> LikelihoodKernel:
        if self.stack is None:
            return self._floor_params(0, measurement)
        per_floor = [self._floor_params(f, measurement).params for f in range(len(self._xy_m))]
        n_floors = len(per_floor)
        head = 1 + 3 * n_floors
        bounds, start = [], head
        for p in per_floor:
            bounds += [start, start + p.size]
            start += p.size
        params = np.concatenate([[float(n_floors)], self._tile_x_min_m, bounds, *per_floor])
        return LikelihoodKernel(_by_floor, np.ascontiguousarray(params, dtype=np.float64))


class BeaconSource:
    """The BLE readings of a stream as measurements (``filter.causal.MeasurementSource``;
    module docstring). Readings of beacons the table does not have are left out."""

    stream = "ble"

    def __init__(self, model: BeaconLikelihood, window_s: float) -> None:
        self.model = model
        self.window_s = float(window_s)
        self._index = model.table.index
        self._t: list[float] = []  # readings of the current window (and before, until dropped)
        self._beacon: list[int] = []
        self._rssi: list[float] = []
        self._next_t: float | None = None  # a measurement comes at the first reading at or after this
        self.measurements: list[BeaconWindow] = []

    def records_of(self, records: Recording) -> tuple:
        """(t_s, table row, RSSI) of the chunk's readings of the table's beacons, in time order."""
        beacons = records.beacons
        if len(beacons.t_s) == 0:
            return np.zeros(0), np.zeros(0, dtype=np.int64), np.zeros(0)
        row = np.array([self._index.get(beacon_key(b), -1) for b in beacons.beacon_id], dtype=np.int64)
        rssi = np.asarray(beacons.rssi_dbm, dtype=np.float64)
        keep = (row >= 0) & np.isfinite(rssi)
        t = np.asarray(beacons.t_s, dtype=np.float64)[keep]
        order = np.argsort(t, kind="stable")
        return t[order], row[keep][order], rssi[keep][order]

    def add_records(self, records: tuple, final: bool) -> list[float]:
        """Released readings in; the times of the measurements they completed."""
        if len(records) < 3:  # nothing of this stream was released
            return []
        t_s, rows, rssi = records
        times = []
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
                times.append(t)
                self.measurements.append(self._window(t))
                self._next_t = t + self.window_s
        return times

    def _window(self, t_s: float) -> BeaconWindow:
        """The measurement at ``t_s``: readings in (t_s - window_s, t_s]; older ones are dropped."""
        t = np.array(self._t)
        keep = t > t_s - self.window_s
        beacon = np.array(self._beacon)[keep]
        rssi = np.array(self._rssi)[keep]
        self._t, self._beacon, self._rssi = [], [], []  # the next window starts after this reading
        heard = np.unique(beacon)
        return BeaconWindow(t_s, heard, np.array([np.median(rssi[beacon == b]) for b in heard]))

    def measurement(self, index: int) -> BeaconWindow:
        return self.measurements[index]


def beacon_source(table: BeaconTable, building: Building, config: BleConfig, *, floor: int = 0,
                  stack: FloorStack | None = None) -> BeaconSource:
    """The beacons' measurement source for a filter on ``building``'s floor ``floor``, or on its
    stack plan with ``stack``."""
    return BeaconSource(BeaconLikelihood(table, building, config.rssi_variance_db2, floor=floor, stack=stack,
                                         rssi_offset_db=config.rssi_offset_db), config.window_s)
