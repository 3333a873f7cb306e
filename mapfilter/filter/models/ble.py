"""BLE beacons as a measurement model: windows of beacon readings weighed by path loss.

The likelihood of the ``ble`` source (registered with its stream adapter, which groups the
stream's BLE readings into ``BeaconWindow`` measurements, in ``filter.sources.ble``).

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

import numpy as np
from numba import njit

from mapfilter.errors import MapfilterError
from mapfilter.filter.kernels.passes import BLOCK, LIKELIHOOD_SIGNATURE, X
from mapfilter.filter.models.frame import StateFrame, floor_block, particle_floor
from mapfilter.filter.models.interface import LikelihoodKernel, MeasurementModel
from mapfilter.filter.models.path_loss import path_loss_kernel
from mapfilter.sensors.beacons import BeaconTable

__all__ = ["BeaconLikelihood", "BeaconWindow"]


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
