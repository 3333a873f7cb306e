"""BLE beacons: the beacon table, survey readings labelled with the walker's position, and
fitting each beacon's path-loss parameters from them.

A beacon b at horizontal distance d from the phone, ``s`` floors away, is heard at

    R(d, s) = C_b - 10 n_b log10(max(d, 1 m)) - L s   (dBm)

the Lund thesis' path-loss model with alpha 0 (``sensors.pathloss``), plus a loss L per floor
between the beacon and the phone (Seidel & Rappaport's floor attenuation factor). The distance
is horizontal, in the building frame: directly above or below a beacon the model counts the
floors, not the height. A ``BeaconTable`` holds each beacon's id (as the logs name it), position
(in its floor's frame), floor, C, n and L (CSV on disk, like the access-point table);
``fit_beacons`` fits C and n per beacon, and one L, from survey walks with ground truth.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.io.atomic import write_csv_atomically
from mapfilter.io.tables import CsvTable, read_csv_table
from mapfilter.maps.building import Building
from mapfilter.sensors.pathloss import MIN_DISTANCE_M
from mapfilter.sensors.recording import Recording
from mapfilter.sensors.table_positions import PlacedTable, placed_xy_m, position_columns, row_floor, row_position

__all__ = ["BeaconFit", "BeaconFitConfig", "BeaconReadings", "BeaconTable", "beacon_key", "beacon_rssi_dbm",
           "check_beacons_on_map", "fit_beacons", "labelled_readings", "parse_beacon_ids"]

# Defaults of a table without the columns C, n, floor_loss: an iBeacon's "measured power" (its
# RSSI at 1 m) is conventionally about -59 dBm, n = 2 is free space, and a concrete slab takes
# 10-20 dB off 2.4 GHz; fitting them from survey walks (``fit_beacons``) does better.
DEFAULT_C_DBM = -59.0
DEFAULT_PATH_LOSS_EXPONENT = 2.0
DEFAULT_FLOOR_LOSS_DB = 10.0
# what a row's columns can be (a row outside is refused, naming its line)
COLUMN_RANGES = {"x": (-1e7, 1e7), "y": (-1e7, 1e7), "latitude": (-90.0, 90.0), "longitude": (-180.0, 180.0),
                 "C": (-120.0, 20.0), "n": (0.5, 10.0), "floor_loss": (0.0, 100.0), "offset_db": (-40.0, 40.0)}
# BLE reaches about 50 m indoors: a beacon further off its floor's map cannot be heard on it
MAX_BEACON_OFF_MAP_M = 100.0
# the columns a table may name each thing by (case and surrounding spaces ignored); ``bleID`` is
# the IPIN venues' file (BLE_Locations.csv: bleID, Lat, Lon, floor), whose names need ``ids``
_ID_COLUMNS = ("beacon_id", "bleid")
_LAT_COLUMNS = ("latitude", "lat")
_LON_COLUMNS = ("longitude", "lon")
# the optional path-loss columns and their defaults
_PARAMETERS = {"C": DEFAULT_C_DBM, "n": DEFAULT_PATH_LOSS_EXPONENT, "floor_loss": DEFAULT_FLOOR_LOSS_DB}


def beacon_key(beacon_id: str) -> str:
    """The form ids are matched in: trimmed, upper case (a MAC or a UUID written either way)."""
    return beacon_id.strip().upper()


def beacon_rssi_dbm(distance_m, c_dbm, n, floor_loss_db=0.0, floors_apart=0):
    """Expected RSSI (dBm) at horizontal ``distance_m`` and ``floors_apart`` floors:
    C - 10 n log10(max(d, 1 m)) - L s (module docstring); broadcasts over numpy arrays."""
    d = np.maximum(distance_m, MIN_DISTANCE_M)
    return c_dbm - 10.0 * n * np.log10(d) - floor_loss_db * floors_apart


def parse_beacon_ids(text: str) -> dict[str, str]:
    """``NAME=ID,NAME=ID,...`` (e.g. ``BLE1=BE:AC:20:23:00:01``) as {name: id}; ``ValueError``
    naming the first item that is not a pair, or a name given twice."""
    pairs: dict[str, str] = {}
    for item in text.split(","):
        if not item.strip():
            continue
        name, sep, beacon_id = item.partition("=")
        if not sep or not name.strip() or not beacon_id.strip():
            raise ValueError(f"expected NAME=ID pairs separated by commas (BLE1=BE:AC:20:23:00:01,...), got {item!r}")
        if name.strip() in pairs:
            raise ValueError(f"{name.strip()} is given twice")
        pairs[name.strip()] = beacon_id.strip()
    if not pairs:
        raise ValueError("no NAME=ID pair given")
    return pairs


@dataclasses.dataclass
class BeaconTable(PlacedTable):
    """Beacons with positions and path-loss parameters (arrays of length K)."""

    beacon_id: list[str]  # as the logs name them (GetSensorData: the MAC), upper case
    xy_m: np.ndarray  # (K, 2) in the frame of the beacon's floor
    floor: list[str | None]  # the floor each is on (None: the one floor of a single map)
    c_dbm: np.ndarray  # (K,) RSSI at 1 m
    n: np.ndarray  # (K,) path-loss exponent
    floor_loss_db: np.ndarray  # (K,) dB off per floor between the beacon and the phone
    source_path: Path | None = None  # the CSV it was read from (for messages), or None
    source_lines: list[int] | None = None  # the CSV line of each row, or None
    # {phone model: (K,) its RSSI minus the table's, per beacon}: phones report one signal
    # several dB apart (columns offset_db:MODEL)
    phone_offsets_db: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)

    COLUMNS = ("beacon_id", "x", "y", "floor", "C", "n", "floor_loss")
    THING = "beacon"
    OFFSET_PREFIX = "offset_db:"  # a column per phone model: its RSSI minus the table's, per beacon

    def __len__(self) -> int:
        return len(self.beacon_id)

    @property
    def index(self) -> dict[str, int]:
        """Row of each beacon id (``beacon_key`` form)."""
        return {key: i for i, key in enumerate(self.beacon_id)}

    def with_parameters(self, c_dbm: np.ndarray, n: np.ndarray, floor_loss_db: np.ndarray) -> BeaconTable:
        """The same beacons with other path-loss parameters."""
        k = len(self)
        return dataclasses.replace(self, c_dbm=np.broadcast_to(np.asarray(c_dbm, dtype=np.float64), (k,)).copy(),
                                   n=np.broadcast_to(np.asarray(n, dtype=np.float64), (k,)).copy(),
                                   floor_loss_db=np.broadcast_to(np.asarray(floor_loss_db, dtype=np.float64),
                                                                 (k,)).copy())

    @property
    def ids(self) -> list[str]:
        return self.beacon_id

    @classmethod
    def read_csv(cls, path: str | os.PathLike, building: Building | None = None,
                 ids: Mapping[str, str] | None = None) -> BeaconTable:
        """Read a beacon table: a header, then one line per beacon.

        Columns (names in any case): ``beacon_id`` (or ``bleID`` with ``ids``); the position as
        ``x,y`` (metres in the floor's frame) or ``latitude,longitude`` (also ``Lat,Lon``:
        converted with ``building``'s georeference, ``mapfilter map import-ipin``); optional
        ``floor`` (the building's floor name; ``00`` reads as ``0``), ``C``, ``n``,
        ``floor_loss`` (defaults above), and ``offset_db:MODEL`` columns, each phone model's RSSI
        minus the table's (``fit_beacons``' per-phone offsets). ``ids`` maps the file's names to
        the logs' ids (the IPIN venues' ``BLE_Locations.csv`` names its beacons BLE1, BLE2, ...).
        Every problem is a ``MapfilterError`` naming the file and line.
        """
        table = read_csv_table(path, "the beacon table")  # bounded: a table is kilobytes
        id_key = _id_column(table, ids)
        position = position_columns(table, building, "a beacon table", "beacons", _LAT_COLUMNS, _LON_COLUMNS,
                                    " (mapfilter map import-ipin) to convert them")
        phone_keys = _phone_columns(table, cls.OFFSET_PREFIX)
        keys, named, ab, floors, parameters, lines, first_line = [], [], [], [], [], [], {}
        offsets: dict[str, list[float]] = {phone: [] for phone in phone_keys}
        for line_no, fields in table.rows:
            name = fields[table.column[id_key]].strip().strip('"')
            key = _beacon_key_of(name, ids, first_line, table.path, line_no)
            named.append(name)
            first_line[key] = line_no
            ab.append(row_position(table, fields, line_no, position, COLUMN_RANGES))
            parameters.append([_optional_number(table, fields, line_no, label, default)
                               for label, default in _PARAMETERS.items()])
            floors.append(row_floor(table, fields, line_no, building, "beacon", _floor_name))
            keys.append(key)
            for phone, column in phone_keys.items():
                offsets[phone].append(_optional_number(table, fields, line_no, "offset_db", 0.0, column))
            lines.append(line_no)
        if ids is not None:
            unused = sorted(set(ids) - set(named))
            if unused:
                raise MapfilterError(f"the ids name {unused[0]}, which the table does not have", table.path)
        c_dbm, n, floor_loss = (np.array(p, dtype=np.float64).reshape(len(keys)) for p in zip(*parameters))
        return cls(beacon_id=keys, xy_m=placed_xy_m(ab, floors, position, building, table.path), floor=floors,
                   c_dbm=c_dbm, n=n, floor_loss_db=floor_loss, source_path=table.path, source_lines=lines,
                   phone_offsets_db={p: np.array(v) for p, v in offsets.items()})

    def write_csv(self, path: str | os.PathLike) -> None:
        """The table as CSV (``COLUMNS``, then an ``offset_db:MODEL`` column per phone model), written
        atomically."""
        phones = sorted(self.phone_offsets_db)
        write_csv_atomically(path, (*self.COLUMNS, *(self.OFFSET_PREFIX + p for p in phones)), (
            [self.beacon_id[i], f"{self.xy_m[i, 0]:.3f}", f"{self.xy_m[i, 1]:.3f}",
             "" if self.floor[i] is None else self.floor[i], f"{self.c_dbm[i]:.2f}", f"{self.n[i]:.3f}",
             f"{self.floor_loss_db[i]:.2f}", *(f"{self.phone_offsets_db[p][i]:.2f}" for p in phones)]
            for i in range(len(self))))


def _id_column(table: CsvTable, ids: Mapping[str, str] | None) -> str:
    """The key of the id column: ``beacon_id``, or ``bleID`` (the IPIN venues' names, which need
    ``ids``)."""
    id_key = next((c for c in _ID_COLUMNS if c in table.column), None)
    if id_key is None:
        raise MapfilterError("a beacon table needs a beacon_id column (the id the logs name each beacon by)",
                             table.path, 1)
    if table.header[table.column[id_key]].strip().lower() == "bleid" and ids is None:
        raise MapfilterError("the table names its beacons by bleID (BLE1, ...), not as the logs do: give "
                             "the logs' id of each (--ids BLE1=BE:AC:20:23:00:01,...)", table.path, 1)
    return id_key


def _phone_columns(table: CsvTable, prefix: str) -> dict[str, str]:
    """{phone model: key of its ``offset_db:MODEL`` column}."""
    phones = {name.strip()[len(prefix):].strip(): name.strip().lower() for name in table.header
              if name.strip().lower().startswith(prefix)}
    if "" in phones:
        raise MapfilterError(f"a column {prefix} names no phone model ({prefix}MODEL)", table.path, 1)
    return phones


def _beacon_key_of(name: str, ids: Mapping[str, str] | None, first_line: dict[str, int], path: Path,
                   line_no: int) -> str:
    """The ``beacon_key`` of a row's id as the file writes it (through ``ids``); refused when
    empty, not among ``ids``, or listed before."""
    if not name:
        raise MapfilterError("empty beacon id", path, line_no)
    if ids is not None:
        if name not in ids:
            raise MapfilterError(f"beacon {name} has no id among the ids given ({', '.join(ids)})", path, line_no)
        name = ids[name]
    key = beacon_key(name)
    if key in first_line:
        raise MapfilterError(f"beacon {key} is listed twice (lines {first_line[key]} and {line_no}): keep one",
                             path, line_no)
    return key


def _optional_number(table: CsvTable, fields: list[str], line_no: int, label: str, default: float,
                     key: str | None = None) -> float:
    """An optional column's value (``label``: its name in ``COLUMN_RANGES`` and messages; ``key``:
    its key, by default ``label`` in lower case), ``default`` where the table has no such column or
    the row leaves it empty."""
    key = label.lower() if key is None else key
    if key not in table.column or not fields[table.column[key]].strip():
        return default
    return table.number(fields, key, line_no, *COLUMN_RANGES[label], label=label)


def _floor_name(text: str) -> str:
    """A floor as the building names it: integers normalised ("00" -> "0", "-01" -> "-1"), as
    ``mapfilter map import-ipin`` names an IPIN venue's floors."""
    text = text.strip().strip('"')
    try:
        return str(int(text))
    except ValueError:
        return text


def check_beacons_on_map(table: BeaconTable, building: Building, map_path: str | os.PathLike | None = None) -> None:
    """Refuse a table that cannot belong to ``building``: a floor it does not have, or a beacon
    more than ``MAX_BEACON_OFF_MAP_M`` outside its floor's map (a table in another frame).
    ``MapfilterError`` naming the table's file and line."""
    table.check_within(building, MAX_BEACON_OFF_MAP_M, map_path)


# ---- survey readings ----------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class BeaconReadings:
    """Beacon readings of survey walks, each labelled with where the walker was: their position
    interpolated in time between the two waypoints around the reading, both on one floor."""

    beacon: np.ndarray  # (R,) row of the beacon in the table
    rssi_dbm: np.ndarray  # (R,)
    distance_m: np.ndarray  # (R,) horizontal distance walker - beacon (building frame)
    floors_apart: np.ndarray  # (R,) floors between the walker and the beacon
    trace: np.ndarray  # (R,) index into ``traces``
    traces: tuple[str, ...]
    phones: tuple[str | None, ...]  # the phone model each trace names (None: none)
    building_xy_m: np.ndarray  # (R, 2) the walker's position in the building frame
    floor: np.ndarray  # (R,) the walker's floor index
    beacon_xy_m: np.ndarray  # (K, 2) the table's beacons in the building frame
    beacon_floor: np.ndarray  # (K,) their floor indices

    def __len__(self) -> int:
        return int(self.beacon.size)

    def without_traces(self, names: Sequence[str]) -> BeaconReadings:
        """The readings of every walk but ``names`` (a leave-one-out fold)."""
        drop = np.array([t in set(names) for t in self.traces], dtype=bool)
        keep = ~drop[self.trace] if self.trace.size else np.zeros(0, dtype=bool)
        return dataclasses.replace(self, **{f: getattr(self, f)[keep] for f in
                                            ("beacon", "rssi_dbm", "distance_m", "floors_apart", "trace",
                                             "building_xy_m", "floor")})


def labelled_readings(table: BeaconTable, building: Building, recordings: Sequence[Recording]) -> BeaconReadings:
    """The readings of the table's beacons in survey walks, labelled with the walker's position
    (``BeaconReadings``). The walks' ground truth must be in the building's metres
    (``sensors.logs.read_log(..., building=)``); readings of beacons the table does not have,
    before the first or after the last waypoint, or between waypoints of two floors (stairs, a
    lift) are left out."""
    beacon_xy, beacon_floor = table.building_xy_m(building)
    index = table.index
    parts = []
    for trace, rec in enumerate(recordings):
        if rec.waypoint_t_s.size < 2 or len(rec.beacons.t_s) == 0:
            continue
        part = _labelled_part(rec, trace, _waypoint_floors(rec, building), building, index, beacon_xy, beacon_floor)
        if part is not None:
            parts.append(part)
    traces = tuple(r.name for r in recordings)
    phones = tuple(r.phone_model for r in recordings)
    if not parts:
        empty = np.zeros(0)
        return BeaconReadings(empty.astype(np.int64), empty, empty, empty.astype(np.int64), empty.astype(np.int64),
                              traces, phones, np.zeros((0, 2)), empty.astype(np.int64), beacon_xy, beacon_floor)
    cat = [np.concatenate([p[j] for p in parts]) for j in range(7)]
    return BeaconReadings(cat[0], cat[1], cat[2], cat[3], cat[4], traces, phones, cat[5], cat[6], beacon_xy,
                          beacon_floor)


def _waypoint_floors(rec: Recording, building: Building) -> np.ndarray:
    """The floor index of each of the walk's waypoints: as the log labels them, else the one floor
    of a single map or the floor the log's header names; refused when none of these is the
    building's, or when its waypoints are not in the building's metres."""
    names, size = building.floor_names, rec.waypoint_t_s.size
    if rec.waypoint_floor is not None and len(rec.waypoint_floor) == size:
        wp_floor_names = list(rec.waypoint_floor)
    elif building.is_single_floor:
        wp_floor_names = [names[0]] * size
    elif rec.floor_name in names:
        wp_floor_names = [rec.floor_name] * size
    else:
        raise MapfilterError("the log names no floor of the building for its waypoints: its beacon readings "
                             "cannot be placed", rec.path)
    if building.is_single_floor:
        wp_floor = np.zeros(size, dtype=np.int64)
    else:
        unknown = sorted({f for f in wp_floor_names if f not in names})
        if unknown:
            raise MapfilterError(f"the log's waypoints are on floor {unknown[0]!r}, which the building does not "
                                 f"have (floors: {', '.join(names)})", rec.path)
        wp_floor = np.array([names.index(f) for f in wp_floor_names], dtype=np.int64)
    if not np.isfinite(rec.waypoint_xy_m).all():
        raise MapfilterError("the log's waypoints are not in the building's metres (latitude/longitude ground "
                             "truth needs a georeferenced building)", rec.path)
    return wp_floor


def _labelled_part(rec: Recording, trace: int, wp_floor: np.ndarray, building: Building, index: dict[str, int],
                   beacon_xy: np.ndarray, beacon_floor: np.ndarray) -> tuple | None:
    """One walk's readings of the table's beacons between two waypoints of one floor, each placed
    between them by its time: (beacon row, RSSI, distance, floors apart, trace, walker's building
    position, floor), or None when it has none."""
    wp_t, wp_xy = rec.waypoint_t_s, rec.waypoint_xy_m
    t = rec.beacons.t_s
    row = np.array([index.get(beacon_key(b), -1) for b in rec.beacons.beacon_id], dtype=np.int64)
    rssi = np.asarray(rec.beacons.rssi_dbm, dtype=np.float64)
    k = np.searchsorted(wp_t, t, side="right") - 1
    inside = (row >= 0) & (t >= wp_t[0]) & (t <= wp_t[-1]) & np.isfinite(rssi)
    k = np.clip(k, 0, wp_t.size - 2)
    same_floor = wp_floor[k] == wp_floor[k + 1]
    keep = inside & same_floor
    if not keep.any():
        return None
    k, t, row, rssi = k[keep], t[keep], row[keep], rssi[keep]
    span = wp_t[k + 1] - wp_t[k]
    a = np.where(span > 0, (t - wp_t[k]) / np.where(span > 0, span, 1.0), 0.0)[:, None]
    floor = wp_floor[k]
    local = wp_xy[k] + a * (wp_xy[k + 1] - wp_xy[k])
    walker = np.empty_like(local)
    for f in np.unique(floor):
        on = floor == f
        walker[on] = building.floors[int(f)].to_building(local[on])
    return (row, rssi, np.linalg.norm(walker - beacon_xy[row], axis=1), np.abs(floor - beacon_floor[row]),
            np.full(row.size, trace), walker, floor)


# ---- fitting -----------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class BeaconFitConfig:
    """How ``fit_beacons`` fits the path-loss parameters."""

    min_readings: int = 30  # labelled readings a beacon needs for its own C and n; fewer: the shared values
    n_bounds: tuple[float, float] = (1.0, 5.0)  # path-loss exponents a fit may take
    c_bounds_dbm: tuple[float, float] = (-110.0, -20.0)  # RSSI at 1 m a fit may take
    floor_loss_bounds_db: tuple[float, float] = (0.0, 40.0)  # loss per floor a fit may take
    f_scale_db: float = 5.0  # soft-L1 scale: residuals beyond it count linearly (robust to fades)


@dataclasses.dataclass(frozen=True)
class BeaconFitRow:
    """How one beacon was fitted."""

    beacon_id: str
    readings: int  # labelled readings
    on_its_floor: int  # of them, with the walker on the beacon's floor
    own_fit: bool  # its own C and n (else the shared values)
    rmse_db: float  # RMS residual of its readings under the fitted model (NaN: no reading)
    # the check of the table's positions: the beacon whose position (and floor) fits this
    # beacon's readings best, with the RMS residual there (C and n fitted there too)
    best_position: str
    best_position_rmse_db: float


@dataclasses.dataclass(frozen=True)
class BeaconFit:
    """The fitted table and how each beacon was fitted."""

    table: BeaconTable
    rows: tuple[BeaconFitRow, ...]
    shared_c_dbm: float
    shared_n: float
    floor_loss_db: float
    floor_loss_fitted: bool  # False: too few readings across floors, the table's value kept
    n_readings: int
    # each phone model's RSSI minus the table's (the survey walks' phones on average), as the
    # fitted table carries them
    phone_offsets_db: dict[str, float] = dataclasses.field(default_factory=dict)
    phone_readings: dict[str, int] = dataclasses.field(default_factory=dict)


# rounds of fitting the path-loss parameters and the phones' offsets in turn (the offsets move
# by under 0.1 dB after the third on the IPIN 2023 logs)
_OFFSET_ROUNDS = 3


def fit_beacons(table: BeaconTable, readings: BeaconReadings, config: BeaconFitConfig = BeaconFitConfig()) -> BeaconFit:
    """Fit the path-loss parameters of the table's beacons (their positions and floors as given)
    to labelled readings (``labelled_readings``), by robust least squares (soft L1):

    1. shared C, n and the floor loss L over every reading of every beacon (L only when at least
       ``min_readings`` readings are from another floor than their beacon's; else the table's
       median L is kept);
    2. each beacon with at least ``min_readings`` readings: its own C and n, L fixed at the shared
       value; the others keep the shared C and n;
    3. each phone model with at least ``min_readings`` readings: its RSSI offset, the median of its
       readings' residuals, the offsets weighted by readings averaging 0 (phones report the same
       signal several dB apart); 1-3 again on the readings less their phone's offset, three
       times in all.

    ``MapfilterError`` when fewer than ``min_readings`` readings in all are labelled.
    """
    if readings.beacon_xy_m.shape[0] != len(table):
        raise ValueError("the readings were labelled with another table")
    if len(readings) < config.min_readings:
        raise MapfilterError(f"{len(readings)} labelled readings of the table's beacons in the survey walks (at least "
                             f"{config.min_readings} needed): nothing to fit")
    log_d = np.log10(np.maximum(readings.distance_m, MIN_DISTANCE_M))
    apart, beacon = readings.floors_apart.astype(np.float64), readings.beacon
    fit_loss = int(np.count_nonzero(apart > 0)) >= config.min_readings
    kept_loss = float(np.median(table.floor_loss_db))
    phone = np.array([p or "" for p in readings.phones], dtype=object)[readings.trace] if len(readings) else \
        np.zeros(0, dtype=object)
    names, counts = np.unique(phone.astype(str), return_counts=True)
    phones = [str(p) for p, k in zip(names, counts) if p and k >= config.min_readings]
    offset = np.zeros(len(readings))  # each reading's phone offset
    for _ in range(_OFFSET_ROUNDS if phones else 1):
        z = readings.rssi_dbm - offset
        shared, loss = _fit_shared(log_d, apart, z, fit_loss, kept_loss, config)
        c, n, own = _fit_each_beacon(len(table), beacon, log_d, apart, z, loss, shared, config)
        if phones:
            residual = readings.rssi_dbm - (c[beacon] - 10.0 * n[beacon] * log_d - loss * apart)
            offset = _phone_offsets(residual, phone, phones)
    rows = _position_check(table, readings, c, n, own, loss, shared, log_d, z, config)
    phone_offsets = {p: float(offset[phone == p][0]) for p in phones}
    fitted = dataclasses.replace(table.with_parameters(c, n, loss),
                                 phone_offsets_db={p: np.full(len(table), v) for p, v in phone_offsets.items()})
    return BeaconFit(fitted, tuple(rows), float(shared[0]), float(shared[1]), loss,
                     fit_loss, len(readings), phone_offsets,
                     {p: int(np.count_nonzero(phone == p)) for p in phones})


def _solve(residual, start, lo, hi, config: BeaconFitConfig) -> np.ndarray:
    """The parameters within [lo, hi] that minimise the soft-L1 cost of ``residual``, from ``start``."""
    from scipy.optimize import least_squares

    start = np.clip(np.array(start, dtype=np.float64), np.array(lo) + 1e-6, np.array(hi) - 1e-6)
    return least_squares(residual, start, bounds=(lo, hi), loss="soft_l1", f_scale=config.f_scale_db).x


def _fit_shared(log_d: np.ndarray, apart: np.ndarray, z: np.ndarray, fit_loss: bool, kept_loss: float,
                config: BeaconFitConfig) -> tuple[np.ndarray, float]:
    """(C, n[, L]) shared by every beacon over every reading, and the floor loss L (``kept_loss``
    when it is not fitted)."""
    (c_lo, c_hi), (n_lo, n_hi) = config.c_bounds_dbm, config.n_bounds
    if fit_loss:
        shared = _solve(lambda p: p[0] - 10.0 * p[1] * log_d - p[2] * apart - z,
                        [-60.0, 2.0, DEFAULT_FLOOR_LOSS_DB], [c_lo, n_lo, config.floor_loss_bounds_db[0]],
                        [c_hi, n_hi, config.floor_loss_bounds_db[1]], config)
        return shared, float(shared[2])
    shared = _solve(lambda p: p[0] - 10.0 * p[1] * log_d - kept_loss * apart - z, [-60.0, 2.0],
                    [c_lo, n_lo], [c_hi, n_hi], config)
    return shared, kept_loss


def _fit_path_loss(log_dist: np.ndarray, floors_apart: np.ndarray, rssi: np.ndarray, loss: float,
                   start: np.ndarray, config: BeaconFitConfig) -> np.ndarray:
    """(C, n) of one beacon's readings, the floor loss fixed, from ``start``."""
    (c_lo, c_hi), (n_lo, n_hi) = config.c_bounds_dbm, config.n_bounds
    return _solve(lambda p: p[0] - 10.0 * p[1] * log_dist - loss * floors_apart - rssi, start,
                  [c_lo, n_lo], [c_hi, n_hi], config)


def _fit_each_beacon(k: int, beacon: np.ndarray, log_d: np.ndarray, apart: np.ndarray, z: np.ndarray, loss: float,
                     shared: np.ndarray, config: BeaconFitConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(C, n, own) of each of the ``k`` beacons: its own fit where it has ``min_readings``
    readings (``own``), else the shared values."""
    c = np.full(k, shared[0])
    n = np.full(k, shared[1])
    own = np.zeros(k, dtype=bool)
    for b in range(k):
        mine = beacon == b
        if np.count_nonzero(mine) >= config.min_readings:
            c[b], n[b] = _fit_path_loss(log_d[mine], apart[mine], z[mine], loss, shared[:2], config)
            own[b] = True
    return c, n, own


def _phone_offsets(residual: np.ndarray, phone: np.ndarray, phones: list[str]) -> np.ndarray:
    """Each reading's phone offset: the median residual of its phone's readings, the offsets
    weighted by readings averaging 0 (0 for a phone not fitted)."""
    by_phone = {p: float(np.median(residual[phone == p])) for p in phones}
    counts = {p: int(np.count_nonzero(phone == p)) for p in phones}
    mean = sum(by_phone[p] * counts[p] for p in phones) / sum(counts.values())
    by_phone = {p: v - mean for p, v in by_phone.items()}
    return np.array([by_phone.get(p, 0.0) for p in phone])


def _rmse(params, log_dist: np.ndarray, floors_apart: np.ndarray, rssi: np.ndarray, loss: float) -> float:
    residual = params[0] - 10.0 * params[1] * log_dist - loss * floors_apart - rssi
    return float(np.sqrt(np.mean(residual ** 2))) if residual.size else math.nan


def _position_check(table: BeaconTable, readings: BeaconReadings, c: np.ndarray, n: np.ndarray, own: np.ndarray,
                    loss: float, shared: np.ndarray, log_d: np.ndarray, z: np.ndarray,
                    config: BeaconFitConfig) -> list[BeaconFitRow]:
    """How each beacon was fitted, and the check of the table's positions: each beacon's readings
    (with its own fit) fitted at every beacon's position, the best one named."""
    beacon, apart = readings.beacon, readings.floors_apart.astype(np.float64)
    beacon_xy, beacon_floor = readings.beacon_xy_m, readings.beacon_floor
    rows = []
    for b in range(len(table)):
        mine = beacon == b
        here = _rmse((c[b], n[b]), log_d[mine], apart[mine], z[mine], loss)
        best, best_rmse = table.beacon_id[b], here
        if own[b]:
            for other in range(len(table)):
                if other == b:
                    continue
                d = np.linalg.norm(readings.building_xy_m[mine] - beacon_xy[other], axis=1)
                log_other = np.log10(np.maximum(d, MIN_DISTANCE_M))
                apart_other = np.abs(readings.floor[mine] - beacon_floor[other]).astype(np.float64)
                there = _rmse(_fit_path_loss(log_other, apart_other, z[mine], loss, shared[:2], config), log_other,
                              apart_other, z[mine], loss)
                if there < best_rmse:
                    best, best_rmse = table.beacon_id[other], there
        rows.append(BeaconFitRow(table.beacon_id[b], int(np.count_nonzero(mine)),
                                 int(np.count_nonzero(mine & (apart == 0))), bool(own[b]), here, best, best_rmse))
    return rows
