"""Radio map (WiFi fingerprint database): building, saving, KWNN fixes and their typical error.

A radio map is a set of reference points, each a WiFi scan labelled with the position where
it was taken. Survey logs with waypoints give the labels: a scan's position is interpolated
between the waypoints around it (the walker went roughly straight between consecutive
waypoints), linearly in time or, optionally, in proportion to the detected steps; scans
before the first or after the last waypoint are dropped.

File format (``.npz``, numpy's zip of arrays, written compressed)
------------------------------------------------------------------
========================  =========================  ================================================
key                       dtype, shape               meaning
========================  =========================  ================================================
``format``                str scalar                 ``"mapfilter-radiomap"``
``version``               int64 scalar               ``2`` (``1`` still loads)
``xy_m``                  float64 (P, 2)             reference-point positions, world metres
``t_s``                   float64 (P,)               scan times, Unix seconds
``trace``                 int64 (P,)                 index into ``source_traces`` of each point
``ap_keys``               str (K,)                   ``"bssid@2.4"`` / ``"bssid@5"``
``rssi_dbm``              float32 (P, K)             RSSI; NaN = the AP was not heard in that scan
``source_traces``         str (T,)                   names of the survey logs (trace ids)
``floor_name``            str scalar                 floor label, ``""`` if unknown
``cv_fix_errors_m``       float64 (E,)               version 2: ``cross_validated_fix_errors`` of
                                                     the map (what calibrates the fix sigma)
``cv_fix_errors_params``  float64 (3,)               version 2: the k, max_groups and
                                                     min_separation_m they were computed with
========================  =========================  ================================================

Version 1 files (without the last two keys) still load; their errors are computed when first
needed. Nothing in the file is pickled (``allow_pickle=False`` on load).

A radio map of a building (several floors, ``mapfilter radiomap build BUILDING.yaml``) is
version 3: every point also carries its floor, and positions are in that floor's own frame.

========================  =========================  ================================================
``floor``                 int64 (P,)                 index into ``floor_names`` of each point
``floor_names``           str (F,)                   the building's floors, bottom to top
``cv_fix_errors_floor``   int64 (E,)                 the floor of each ``cv_fix_errors_m`` entry
                                                     (cross-validated within each floor)
========================  =========================  ================================================

Single-floor maps are still written as version 2, so older readers keep reading them.

A radio map that grew from tracked walks (``mapfilter.pipeline.selftrain``, ``mapfilter radiomap grow``)
is version 4: every point also carries where its position came from and how well it is known.
It may have floors (the three keys above) or not.

========================  =========================  ================================================
``source``                int8 (P,)                  ``0`` surveyed (a waypoint-labelled scan),
                                                     ``1`` grown (placed by a walk's offline track)
``xy_sigma_m``            float64 (P,)               position uncertainty: the standard deviation
                                                     per axis of the point's position, metres;
                                                     ``0`` for surveyed points
========================  =========================  ================================================

A map of surveyed points only is written as version 2 or 3 (as before), and older files load
with every point surveyed.

A one-floor radio map written by ``mapfilter radiomap build`` or ``grow`` also keeps the
radio-map likelihood's grid on the floor plan it was built for (``likelihood_*`` arrays, their
layout versioned by ``likelihood_version``; ``filter.models.radio_map``): a walk tracked with it on
that plan starts from them. They are checked when used, and a file without them, or with
them for another plan, configuration or version, is tracked as before (the grid built for the run).
Every file written now also keeps the survey's own match distances (``survey_*_match_db``, with
the numbers they depend on in ``survey_match_params``; ``filter.models.survey_reach``), made once
here rather than for every walk; a file without them, or with other parameters, makes them when used.
"""

from __future__ import annotations

import dataclasses
import os
import zipfile
import zlib
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np
from numba import njit

from mapfilter.io.atomic import atomic_paths
from mapfilter.errors import MapfilterError, not_a_file
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.sensors.pdr import Steps, detect_steps
from mapfilter.sensors.recording import Recording
from mapfilter.sensors.wifi import WifiScan

FORMAT_NAME = "mapfilter-radiomap"
FORMAT_VERSION = 2
FLOORS_FORMAT_VERSION = 3  # a building's radio map (floor labels)
GROWN_FORMAT_VERSION = 4  # per-point source and position sigma (a map grown from tracked walks)
READABLE_VERSIONS = (1, 2, 3, 4)
# per-point source codes (``RadioMap.source``)
SURVEYED = 0  # labelled from a survey walk's waypoints
GROWN = 1  # placed by the offline track of a walk without waypoints (``mapfilter.pipeline.selftrain``)
# the cross-validation stored in every file: what the tracker's calibration asks for by default
_STORED_CV_PARAMS = (4, 200, 1.0)
# A point of position sigma s counts POSITION_SIGMA_REF_M^2 / (POSITION_SIGMA_REF_M^2 + s^2) of a
# surveyed one (``RadioMap.position_weights``): the scale of how far a KWNN neighbour lies from
# where the scan was taken (on a thinly surveyed floor: metres to tens of metres); weighing grown
# points harder cost more coverage than their errors cost (docs/accuracy.md)
POSITION_SIGMA_REF_M = 10.0
# The most a radio map file may declare, read from the array headers in the zip before numpy
# allocates anything: 1 GiB (a map of 100 000 reference points x 2 500 access points; the ILC
# site 1 radio map of every floor is under 10 MB).
MAX_RADIOMAP_BYTES = 1 << 30
MAX_POSITION_M = 1e7  # any projected frame on Earth (floorplan.MAX_ORIGIN_M)
# RSSI a phone can report, dBm: readings outside are not WiFi (ILC logs: -100 to -20 dBm)
RSSI_RANGE_DBM = (-150.0, 30.0)
_NOT_A_RADIO_MAP = "not a mapfilter radio map (make one with: mapfilter radiomap build MAP LOG... --out RADIOMAP.npz)"


@dataclasses.dataclass(eq=False)
class RadioMap:
    """Reference points (labelled WiFi scans) of one floor.

    Attributes
    ----------
    xy_m : (P, 2) float64 reference positions.
    ap_keys : K access-point keys ("bssid@band").
    rssi_dbm : (P, K) float32, NaN where the AP was not heard.
    t_s : (P,) scan times.
    trace : (P,) index into ``source_traces``.
    source_traces : names of the survey logs the points came from.
    floor_name : floor label or None.
    floor : (P,) int64 index into ``floor_names`` of each point (a building's radio map; each
        point's position is in its floor's frame), or None for one floor.
    floor_names : the building's floors, or None.
    source : (P,) int8 where each point's position came from: ``SURVEYED`` (0) or ``GROWN`` (1);
        None: every point surveyed.
    xy_sigma_m : (P,) float64 position uncertainty of each point (standard deviation per axis,
        m; 0 for surveyed points); None: all 0. KWNN, the radio-map likelihood and the fix-sigma
        calibration weigh a point by it (``position_weights``).
    """

    xy_m: np.ndarray
    ap_keys: list[str]
    rssi_dbm: np.ndarray
    t_s: np.ndarray
    trace: np.ndarray
    source_traces: list[str]
    floor_name: str | None = None
    floor: np.ndarray | None = None
    floor_names: list[str] | None = None
    source: np.ndarray | None = None
    xy_sigma_m: np.ndarray | None = None
    # what the radio-map likelihood keeps of this map for its file (filter.models.radio_map.keep_tables);
    # {} for none. A map made from this one (select, merge, ...) has none: they would not apply
    likelihood_tables: dict[str, np.ndarray] = dataclasses.field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        self.xy_m = np.asarray(self.xy_m, dtype=np.float64).reshape(-1, 2)
        n = self.xy_m.shape[0]
        self.rssi_dbm = np.asarray(self.rssi_dbm, dtype=np.float32).reshape(n, len(self.ap_keys))
        self.t_s = np.asarray(self.t_s, dtype=np.float64)
        self.trace = np.asarray(self.trace, dtype=np.int64)
        self.ap_keys = list(self.ap_keys)
        self.source_traces = list(self.source_traces)
        if self.floor is not None:
            self.floor = np.asarray(self.floor, dtype=np.int64).reshape(n)
            self.floor_names = list(self.floor_names or [])
        self.source = (np.full(n, SURVEYED, dtype=np.int8) if self.source is None
                       else np.asarray(self.source, dtype=np.int8).reshape(n))
        self.xy_sigma_m = (np.zeros(n) if self.xy_sigma_m is None
                           else np.asarray(self.xy_sigma_m, dtype=np.float64).reshape(n))

    @property
    def is_grown(self) -> bool:
        """True when some point is not surveyed or has a position uncertainty (a version 4 file)."""
        return bool(np.any(self.source != SURVEYED) or np.any(self.xy_sigma_m > 0))

    def position_weights(self) -> np.ndarray:
        """(P,) how much each point counts beside a surveyed one, in (0, 1]: the share of a
        neighbour's position variance that is the match's, s^2 / (s^2 + sigma^2), with
        s = ``POSITION_SIGMA_REF_M`` (the typical distance from a surveyed neighbour to where
        the scan was taken) and sigma the point's ``xy_sigma_m``: inverse-variance weighing of
        neighbour positions whose uncertainty adds to the match's. 1 for surveyed points."""
        return POSITION_SIGMA_REF_M ** 2 / (POSITION_SIGMA_REF_M ** 2 + self.xy_sigma_m ** 2)

    @property
    def has_floors(self) -> bool:
        """True for a building's radio map (every point labelled with its floor)."""
        return self.floor is not None

    def floor_map(self, index: int) -> RadioMap:
        """The points of floor ``index`` as a one-floor radio map (all APs kept).

        It carries the floor's stored cross-validated fix errors when this map came whole from
        ``build`` or a file (not from ``select``)."""
        if self.floor is None:
            raise ValueError("not a building's radio map (no floor labels)")
        sub = self.select(self.floor == index)
        sub.floor, sub.floor_names, sub.floor_name = None, None, self.floor_names[index]
        stored = getattr(self, "_floor_cv_errors", None)
        if stored is not None and index in stored:
            _cv_memo(sub)[_STORED_CV_PARAMS] = stored[index].copy()
        return sub

    def __len__(self) -> int:
        return self.xy_m.shape[0]

    @property
    def key_index(self) -> dict[str, int]:
        """Column of each AP key."""
        index = getattr(self, "_key_index", None)
        if index is None or len(index) != len(self.ap_keys):
            index = {key: j for j, key in enumerate(self.ap_keys)}
            self._key_index = index
        return index

    def scan_vector(self, scan: WifiScan) -> np.ndarray:
        """The scan as a (K,) float32 row over this map's APs (NaN = not heard); other APs dropped."""
        row = np.full(len(self.ap_keys), np.nan, dtype=np.float32)
        index = self.key_index
        for key, value in zip(scan.ap_keys, scan.rssi_dbm):
            j = index.get(key)
            if j is not None:
                row[j] = max(value, row[j]) if not np.isnan(row[j]) else value
        return row

    def scan_matrix(self, scans: Sequence[WifiScan]) -> np.ndarray:
        """(S, K) float32 matrix of scans over this map's APs (NaN = not heard)."""
        return np.stack([self.scan_vector(s) for s in scans]) if scans else np.empty((0, len(self.ap_keys)), np.float32)

    def select(self, keep: np.ndarray) -> RadioMap:
        """A new radio map with the reference points where ``keep`` is True (all APs kept)."""
        keep = np.asarray(keep)
        return RadioMap(self.xy_m[keep], self.ap_keys, self.rssi_dbm[keep], self.t_s[keep], self.trace[keep],
                        self.source_traces, self.floor_name, None if self.floor is None else self.floor[keep],
                        self.floor_names, self.source[keep], self.xy_sigma_m[keep])

    def select_aps(self, keep: np.ndarray) -> RadioMap:
        """A new radio map with the access points (columns) where ``keep`` is True, every point kept."""
        keep = np.asarray(keep, dtype=bool)
        return RadioMap(self.xy_m, [k for k, use in zip(self.ap_keys, keep) if use], self.rssi_dbm[:, keep],
                        self.t_s, self.trace, self.source_traces, self.floor_name, self.floor, self.floor_names,
                        self.source, self.xy_sigma_m)

    def without_traces(self, names: Sequence[str]) -> RadioMap:
        """A new radio map without the points of the named source traces (leave-one-trace-out)."""
        drop = [i for i, t in enumerate(self.source_traces) if t in set(names)]
        return self.select(~np.isin(self.trace, drop))

    # ---- files ----------------------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> None:
        """Write the radio map as a compressed ``.npz`` (format in the module docstring), atomically.

        The file carries the map's cross-validated fix errors (computed here if not known yet),
        so that every walk tracked with it skips that (points)^2 work.
        """
        k, max_groups, min_separation_m = _STORED_CV_PARAMS
        floors: dict[str, np.ndarray] = {}
        version = FORMAT_VERSION
        grown: dict[str, np.ndarray] = {}
        if self.is_grown:
            grown = {"source": self.source, "xy_sigma_m": self.xy_sigma_m}
        if self.floor is not None:
            # positions of different floors are in different frames: cross-validate per floor
            per_floor = [cross_validated_fix_errors(self.floor_map(i), k, max_groups, min_separation_m)
                         for i in range(len(self.floor_names))]
            cv_errors = np.concatenate(per_floor) if per_floor else np.zeros(0)
            floors = {"floor": self.floor, "floor_names": np.array(self.floor_names, dtype=str),
                      "cv_fix_errors_floor": np.concatenate(
                          [np.full(e.size, i, dtype=np.int64) for i, e in enumerate(per_floor)] or [np.zeros(0, np.int64)])}
            version = FLOORS_FORMAT_VERSION
        else:
            cv_errors = cross_validated_fix_errors(self, k, max_groups, min_separation_m)
        if grown:
            version = GROWN_FORMAT_VERSION
        with atomic_paths(path) as (tmp,):
            with tmp.open("wb") as handle:
                np.savez_compressed(
                    handle, format=np.array(FORMAT_NAME), version=np.array(version, dtype=np.int64),
                    xy_m=self.xy_m, t_s=self.t_s, trace=self.trace, ap_keys=np.array(self.ap_keys, dtype=str),
                    rssi_dbm=self.rssi_dbm, source_traces=np.array(self.source_traces, dtype=str),
                    floor_name=np.array(self.floor_name or ""), cv_fix_errors_m=cv_errors,
                    cv_fix_errors_params=np.array(_STORED_CV_PARAMS, dtype=np.float64), **floors, **grown,
                    **dict(zip(("survey_inside_match_db", "survey_outside_match_db"), survey_match_distances_db(self))),
                    survey_match_params=_survey_match_params(),
                    **{f"likelihood_{name}": array for name, array in self.likelihood_tables.items()},
                )

    @classmethod
    def load(cls, path: str | os.PathLike) -> RadioMap:
        """Read a radio map written by ``save``; ``MapfilterError`` on anything else."""
        path = Path(path)
        arrays, version = _read_radio_map_arrays(path)
        p = _check_points(arrays, path)
        point_floor, floor_names = _floor_labels(arrays, version, p, path)
        source, xy_sigma = _grown_labels(arrays, version, p, path)
        floor = str(arrays.get("floor_name", ""))
        radio_map = cls(arrays["xy_m"], [str(k) for k in arrays["ap_keys"]], arrays["rssi_dbm"], arrays["t_s"],
                        arrays["trace"], [str(t) for t in arrays["source_traces"]], floor or None,
                        point_floor, floor_names, source, xy_sigma,
                        {key[len("likelihood_"):]: array for key, array in arrays.items() if key.startswith("likelihood_")})
        _restore_match_distances(radio_map, arrays, path)
        _restore_cv_errors(radio_map, arrays, version, point_floor, floor_names, path)
        return radio_map


def _read_radio_map_arrays(path: Path) -> tuple[dict[str, np.ndarray], int]:
    """The arrays of a radio map file and its format version; refused when it is not one (or not
    a version this reads)."""
    if not path.is_file():
        raise not_a_file(path)
    _check_npz_headers(path)  # before numpy allocates what a header declares
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError, zlib.error) as exc:
        raise MapfilterError(f"{_NOT_A_RADIO_MAP}: {exc}", path) from None
    if str(arrays.get("format", "")) != FORMAT_NAME:
        raise MapfilterError(f"{_NOT_A_RADIO_MAP}: no format key {FORMAT_NAME!r}", path)
    version = int(arrays.get("version", -1))
    if version not in READABLE_VERSIONS:
        raise MapfilterError(f"radio map format version {version} is not supported (this reads "
                             f"{', '.join(map(str, READABLE_VERSIONS))})", path)
    return arrays, version


def _check_points(arrays: dict[str, np.ndarray], path: Path) -> int:
    """The number of reference points, their arrays checked: present, of one length, positions
    finite and on a floor, times finite, RSSI as a phone reports it, traces in range."""
    missing = {"xy_m", "t_s", "trace", "ap_keys", "rssi_dbm", "source_traces"} - set(arrays)
    if missing:
        raise MapfilterError(f"radio map lacks the arrays {sorted(missing)}", path)
    xy, rssi, keys = arrays["xy_m"], arrays["rssi_dbm"], arrays["ap_keys"]
    p = xy.shape[0] if xy.ndim == 2 else -1
    if (xy.ndim != 2 or xy.shape[1] != 2 or rssi.shape != (p, keys.shape[0]) or arrays["t_s"].shape != (p,)
            or arrays["trace"].shape != (p,)):
        raise MapfilterError(f"radio map arrays disagree in shape: xy_m {xy.shape}, rssi_dbm {rssi.shape}, "
                             f"ap_keys {keys.shape}", path)
    if not np.all(np.isfinite(xy)):
        raise MapfilterError("radio map has non-finite reference positions", path)
    if xy.size and np.abs(xy).max() > MAX_POSITION_M:
        i = int(np.argmax(np.abs(xy).max(axis=1)))
        raise MapfilterError(f"reference point {i} at {tuple(float(v) for v in xy[i])} m is more than "
                             f"{MAX_POSITION_M:g} m from the origin: not a position on a floor", path)
    if not np.all(np.isfinite(arrays["t_s"])):
        raise MapfilterError("radio map has non-finite scan times", path)
    low, high = (np.nanmin(rssi), np.nanmax(rssi)) if rssi.size and not np.isnan(rssi).all() else (0.0, 0.0)
    if np.isinf(low) or np.isinf(high) or not (RSSI_RANGE_DBM[0] <= low and high <= RSSI_RANGE_DBM[1]):
        raise MapfilterError(f"radio map has RSSI from {low:g} to {high:g} dBm, outside the "
                             f"{RSSI_RANGE_DBM[0]:g} to {RSSI_RANGE_DBM[1]:g} dBm a phone reports", path)
    if p and (arrays["trace"].min() < 0 or arrays["trace"].max() >= len(arrays["source_traces"])):
        raise MapfilterError("radio map trace indices out of range", path)
    return p


def _floor_labels(arrays: dict[str, np.ndarray], version: int, p: int,
                  path: Path) -> tuple[np.ndarray | None, list[str] | None]:
    """(each point's floor index, the floor names) of a radio map with floors, else (None, None)."""
    if not (version == 3 or (version >= GROWN_FORMAT_VERSION and ("floor" in arrays or "floor_names" in arrays))):
        return None, None
    if "floor" not in arrays or "floor_names" not in arrays:
        raise MapfilterError(f"a version {version} radio map with floors needs the arrays floor and "
                             "floor_names", path)
    point_floor, floor_names = arrays["floor"], [str(n) for n in arrays["floor_names"]]
    if point_floor.shape != (p,) or (p and (point_floor.min() < 0 or point_floor.max() >= len(floor_names))):
        raise MapfilterError("radio map floor labels out of range", path)
    return point_floor, floor_names


def _grown_labels(arrays: dict[str, np.ndarray], version: int, p: int,
                  path: Path) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(each point's source, SURVEYED or GROWN, and position sigma) of a grown radio map's
    format, else (None, None)."""
    if version < GROWN_FORMAT_VERSION:
        return None, None
    if "source" not in arrays or "xy_sigma_m" not in arrays:
        raise MapfilterError(f"a version {version} radio map needs the arrays source and xy_sigma_m", path)
    source, xy_sigma = arrays["source"], arrays["xy_sigma_m"]
    if source.shape != (p,) or xy_sigma.shape != (p,):
        raise MapfilterError(f"radio map source {source.shape} / xy_sigma_m {xy_sigma.shape} do not have "
                             f"one entry per point ({p})", path)
    if not np.all(np.isin(source, (SURVEYED, GROWN))):
        raise MapfilterError(f"radio map source codes must be {SURVEYED} (surveyed) or {GROWN} (grown)", path)
    if not (np.all(np.isfinite(xy_sigma)) and np.all(xy_sigma >= 0)):
        raise MapfilterError("radio map xy_sigma_m must be finite and >= 0", path)
    return source, xy_sigma


def _restore_match_distances(radio_map: RadioMap, arrays: dict[str, np.ndarray], path: Path) -> None:
    """The survey's match distances the file stored, when they were made with this release's
    parameters (else they are computed again when asked for)."""
    inside, outside = arrays.get("survey_inside_match_db"), arrays.get("survey_outside_match_db")
    match_params = arrays.get("survey_match_params")
    if inside is not None and outside is not None and match_params is not None \
            and np.array_equal(match_params, _survey_match_params()):
        if not (np.all(np.isfinite(inside)) and np.all(np.isfinite(outside))):
            raise MapfilterError("radio map has malformed survey_inside_match_db / survey_outside_match_db", path)
        memo_of(radio_map)["match distances"] = (np.sort(inside.astype(np.float64)),
                                                 np.sort(outside.astype(np.float64)))


def _restore_cv_errors(radio_map: RadioMap, arrays: dict[str, np.ndarray], version: int,
                       point_floor: np.ndarray | None, floor_names: list[str] | None, path: Path) -> None:
    """The cross-validated fix errors the file stored (per floor in a radio map with floors)."""
    cv_errors, cv_params = arrays.get("cv_fix_errors_m"), arrays.get("cv_fix_errors_params")
    if not (version >= 2 and cv_errors is not None and cv_params is not None):
        return
    if (cv_errors.ndim != 1 or cv_params.shape != (3,) or not np.all(np.isfinite(cv_errors))
            or not np.all(np.isfinite(cv_params))):
        raise MapfilterError("radio map has malformed cv_fix_errors_m / cv_fix_errors_params", path)
    params = (int(cv_params[0]), int(cv_params[1]), float(cv_params[2]))
    if point_floor is None:
        _cv_memo(radio_map)[params] = cv_errors.astype(np.float64)
    elif params == _STORED_CV_PARAMS:
        of_floor = arrays.get("cv_fix_errors_floor")
        if of_floor is None or of_floor.shape != cv_errors.shape:
            raise MapfilterError("radio map has malformed cv_fix_errors_floor", path)
        radio_map._floor_cv_errors = {i: cv_errors[of_floor == i].astype(np.float64)
                                      for i in range(len(floor_names))}


# ---- where a radio map meets a map -------------------------------------------------------------
# Reference points are scans labelled by waypoints on the floor (ILC site 1: none outside its
# floor maps); further off the map than this, the radio map belongs to another map or frame.
MAX_REFERENCE_OFF_MAP_M = 50.0


def map_extents_m(plan) -> list[tuple[float, float, float, float]]:
    """(x_min, x_max, y_min, y_max) of a ``FloorPlan``, or of each floor of a ``Building`` (each
    in its own frame)."""
    if hasattr(plan, "floors"):
        return [floor.plan.extent_m for floor in plan.floors]
    return [plan.extent_m]


def metres_outside(xy_m: np.ndarray, extent_m: tuple[float, float, float, float]) -> np.ndarray:
    """Distance in metres from each point to the rectangle ``extent_m`` (0 inside)."""
    x_min, x_max, y_min, y_max = extent_m
    xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
    dx = np.maximum(0.0, np.maximum(x_min - xy[:, 0], xy[:, 0] - x_max))
    dy = np.maximum(0.0, np.maximum(y_min - xy[:, 1], xy[:, 1] - y_max))
    return np.hypot(dx, dy)


def check_radio_map_on_map(radio_map: RadioMap, plan, radio_map_path: str | os.PathLike | None = None,
                           map_path: str | os.PathLike | None = None) -> None:
    """Refuse a radio map that cannot belong to ``plan`` (a ``FloorPlan`` or a ``Building``):
    a reference point more than ``MAX_REFERENCE_OFF_MAP_M`` outside the map (in a building, its
    own floor's map when the floor names match). ``MapfilterError`` naming the radio map's file,
    the point (its index and source trace) and the map."""
    if len(radio_map) == 0:
        return
    extents = map_extents_m(plan)
    off_m = np.min([metres_outside(radio_map.xy_m, e) for e in extents], axis=0)
    if radio_map.floor is not None and hasattr(plan, "floors"):
        by_name = {floor.name: floor.plan.extent_m for floor in plan.floors}
        for index, name in enumerate(radio_map.floor_names or []):
            on_floor = radio_map.floor == index
            if name in by_name and on_floor.any():
                off_m[on_floor] = metres_outside(radio_map.xy_m[on_floor], by_name[name])
    far = np.nonzero(off_m > MAX_REFERENCE_OFF_MAP_M)[0]
    if far.size == 0:
        return
    i = int(far[0])
    x, y = radio_map.xy_m[i]
    trace = radio_map.source_traces[radio_map.trace[i]] if radio_map.source_traces else "?"
    on = f" {map_path}" if map_path is not None else ""
    raise MapfilterError(f"reference point {i} (trace {trace}) at ({x:.6g}, {y:.6g}) m lies {off_m[i] / 1000:.3g} km "
                         f"outside the map{on} (at most {MAX_REFERENCE_OFF_MAP_M:g} m): was it built on this map?"
                         + (f" ({far.size} such points)" if far.size > 1 else ""), radio_map_path)


def _check_npz_headers(path: Path, max_bytes: int = MAX_RADIOMAP_BYTES) -> None:
    """Refuse a file that is not a zip of plain ``.npy`` arrays, or that declares more than
    ``max_bytes`` of arrays (or object arrays, which only pickle could load), reading only the
    zip directory and each array's header."""
    from numpy.lib import format as npy

    if not zipfile.is_zipfile(path):
        raise MapfilterError(_NOT_A_RADIO_MAP, path)
    total = 0
    headers: dict[str, tuple[tuple[int, ...], np.dtype]] = {}
    try:
        with zipfile.ZipFile(path) as archive:
            names = archive.namelist()
            if "format.npy" not in names:
                raise MapfilterError(f"{_NOT_A_RADIO_MAP}: no format key {FORMAT_NAME!r}", path)
            for info in archive.infolist():
                if not info.filename.endswith(".npy"):
                    raise MapfilterError(f"{_NOT_A_RADIO_MAP}: {info.filename!r} is not an array", path)
                with archive.open(info) as member:
                    version = npy.read_magic(member)
                    if version == (1, 0):
                        shape, _, dtype = npy.read_array_header_1_0(member)
                    elif version == (2, 0):
                        shape, _, dtype = npy.read_array_header_2_0(member)
                    else:
                        raise MapfilterError(f"{_NOT_A_RADIO_MAP}: array {info.filename!r} has .npy format "
                                             f"version {version}", path)
                if dtype.hasobject:
                    raise MapfilterError(f"{_NOT_A_RADIO_MAP}: array {info.filename!r} holds Python objects", path)
                size = int(np.prod(shape, dtype=object)) * dtype.itemsize  # Python ints: no overflow
                headers[info.filename[:-4]] = (tuple(shape), dtype)
                total += size
                if total > max_bytes:
                    raise MapfilterError(f"array {info.filename[:-4]!r} declares shape {tuple(shape)} "
                                         f"({size / 2**30:.3g} GiB): more than the {max_bytes / 2**30:g} GiB a "
                                         "radio map may hold", path)
                if size > info.file_size:  # the data cannot be shorter than the header says: a cut or forged file
                    raise MapfilterError(f"{_NOT_A_RADIO_MAP}: array {info.filename!r} declares {size} bytes but "
                                         f"holds {info.file_size}", path)
    except MapfilterError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile, EOFError, zlib.error, NotImplementedError) as exc:
        raise MapfilterError(f"{_NOT_A_RADIO_MAP}: {exc}", path) from None
    _check_array_kinds(headers, path)
    from mapfilter.runtime.memory import check_fits

    # loading holds each array once, and the checks a NaN mask and a copy of the largest
    check_fits(3 * total, f"the radio map's arrays ({total / 2**20:.0f} MiB when decompressed)")


# what each array of a radio map must be: (number of dimensions, dtype kinds); checked from the
# headers, before anything is decompressed
_ARRAY_KINDS = {"format": (0, "U"), "version": (0, "iu"), "xy_m": (2, "fiu"), "t_s": (1, "fiu"),
                "trace": (1, "iu"), "ap_keys": (1, "US"), "rssi_dbm": (2, "f"), "source_traces": (1, "US"),
                "floor_name": (0, "US"), "floor": (1, "iu"), "floor_names": (1, "US"), "source": (1, "iu"),
                "xy_sigma_m": (1, "fiu"), "cv_fix_errors_m": (1, "fiu"), "cv_fix_errors_params": (1, "fiu"),
                "cv_fix_errors_floor": (1, "iu"), "survey_inside_match_db": (1, "fiu"),
                "survey_outside_match_db": (1, "fiu"), "survey_match_params": (1, "fiu")}


def _check_array_kinds(headers: dict[str, tuple[tuple[int, ...], np.dtype]], path: Path) -> None:
    for name, (shape, dtype) in headers.items():
        if name.startswith("likelihood_"):  # numbers, checked in full where they are used
            ndim, kinds = len(shape), "fiub"
        elif name not in _ARRAY_KINDS:
            continue  # a later version's array: its version number decides
        else:
            ndim, kinds = _ARRAY_KINDS[name]
        if len(shape) != ndim or dtype.kind not in kinds:
            what = {"f": "floats", "i": "integers", "u": "integers", "b": "booleans", "U": "text", "S": "text"}
            raise MapfilterError(f"{_NOT_A_RADIO_MAP}: array {name!r} is {len(shape)}-d {dtype} (shape {shape}); "
                                 f"it must be {ndim}-d {' or '.join(dict.fromkeys(what[k] for k in kinds))}", path)
    xy, rssi, keys = headers.get("xy_m"), headers.get("rssi_dbm"), headers.get("ap_keys")
    if xy and rssi and keys and (xy[0][1:] != (2,) or rssi[0] != (xy[0][0], keys[0][0])):
        raise MapfilterError(f"radio map arrays disagree in shape: xy_m {xy[0]}, rssi_dbm {rssi[0]}, "
                             f"ap_keys {keys[0]}", path)


# ---- building ---------------------------------------------------------------------------------
def label_scans(recording: Recording, steps: Steps | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Positions of a recording's scans interpolated between waypoints.

    Without ``steps``: linear in time. With detected steps (``mapfilter.sensors.pdr.detect_steps``):
    along each waypoint segment, progress is proportional to the step lengths walked so far
    (linear in time between steps), so stops and speed changes between two waypoints move
    the labels the right way, in the spirit of the smoothing in Seitz et al.; segments with
    fewer than two steps fall back to linear in time.

    Returns ``(xy_m, inside)``: (S, 2) positions and (S,) True for scans within the
    waypoint time span (the others get NaN and must be dropped).
    ``MapfilterError`` if the log has fewer than two waypoints.
    """
    if recording.waypoint_t_s.shape[0] < 2:
        raise MapfilterError("the log has fewer than two waypoints: its scans cannot be labelled with positions",
                             recording.path)
    t = recording.wifi.t_s
    wp_t, wp_xy = recording.waypoint_t_s, recording.waypoint_xy_m
    inside = (t >= wp_t[0]) & (t <= wp_t[-1])
    xy = np.full((t.shape[0], 2), np.nan)
    xy[inside, 0] = np.interp(t[inside], wp_t, wp_xy[:, 0])
    xy[inside, 1] = np.interp(t[inside], wp_t, wp_xy[:, 1])
    if steps is None:
        return xy, inside
    for a in range(wp_t.shape[0] - 1):
        t0, t1 = wp_t[a], wp_t[a + 1]
        in_segment = inside & (t >= t0) & (t <= t1)
        sel = (steps.t_s > t0) & (steps.t_s < t1)
        if not in_segment.any() or np.count_nonzero(sel) < 2 or t1 <= t0:
            continue
        # walked distance as a function of time: 0 until one step period before the first
        # step (standing still before it), +length at each step, all of it at t1
        step_t = steps.t_s[sel]
        walk_start = max(t0, step_t[0] - float(np.median(np.diff(step_t))))
        knots_t = np.concatenate([[t0, walk_start], step_t, [t1]])
        walked = np.concatenate([[0.0, 0.0], np.cumsum(steps.step_length_m[sel])])
        walked = np.append(walked, walked[-1] + np.mean(steps.step_length_m[sel]))  # the step into the waypoint
        fraction = np.interp(t[in_segment], knots_t, walked) / walked[-1]
        xy[in_segment] = wp_xy[a] + fraction[:, None] * (wp_xy[a + 1] - wp_xy[a])
    return xy, inside


def build_radio_map(recordings: Sequence[Recording], floorplan: FloorPlan | None = None,
                    min_aps_per_scan: int = 1, use_steps: bool = False) -> RadioMap:
    """Radio map from survey logs with waypoints (module docstring: labelling).

    Parameters
    ----------
    recordings : survey logs of one floor; each needs waypoints and WiFi scans.
    floorplan : optional; gives the floor name if the logs do not.
    min_aps_per_scan : scans hearing fewer APs are dropped.
    use_steps : label with detected steps between waypoints (``label_scans``) instead of
        linearly in time; logs without IMU data fall back to time.

    ``MapfilterError`` naming the log if one has no waypoints or no WiFi, or if no scan
    falls in a waypoint span.
    """
    if not recordings:
        raise MapfilterError("no survey logs given for the radio map")
    keys: dict[str, int] = {}
    blocks = []  # (xy, t, trace, rows, cols, rssi)
    for trace, rec in enumerate(recordings):
        if len(rec.wifi) == 0:
            raise MapfilterError("the log has no usable WiFi scans", rec.path)
        steps = _steps_or_none(rec) if use_steps else None
        xy, inside = label_scans(rec, steps)
        heard_count = np.bincount(rec.wifi.row_scan, minlength=len(rec.wifi))
        keep = inside & (heard_count >= min_aps_per_scan)
        scan_ids = np.nonzero(keep)[0]
        new_row = np.full(len(rec.wifi), -1, dtype=np.int64)
        new_row[scan_ids] = np.arange(scan_ids.size)
        col_of = np.array([keys.setdefault(k, len(keys)) for k in rec.wifi.ap_keys], dtype=np.int64)
        r = new_row[rec.wifi.row_scan]
        use = r >= 0
        blocks.append((xy[scan_ids], rec.wifi.t_s[scan_ids], np.full(scan_ids.size, trace), r[use],
                       col_of[rec.wifi.row_ap[use]], rec.wifi.rssi_dbm[use]))
    total = sum(b[0].shape[0] for b in blocks)
    if total == 0:
        raise MapfilterError("no WiFi scan of the survey logs falls between two waypoints: empty radio map")
    rssi = np.full((total, len(keys)), np.nan, dtype=np.float32)
    offset = 0
    for xy, _, _, r, c, v in blocks:
        rssi[offset + r, c] = v
        offset += xy.shape[0]
    floor = next((rec.floor_name for rec in recordings if rec.floor_name), None)
    if floor is None and floorplan is not None:
        floor = floorplan.floor_name
    return RadioMap(
        xy_m=np.concatenate([b[0] for b in blocks]), ap_keys=list(keys), rssi_dbm=rssi,
        t_s=np.concatenate([b[1] for b in blocks]), trace=np.concatenate([b[2] for b in blocks]),
        source_traces=[rec.name for rec in recordings], floor_name=floor,
    )


def merge_radio_maps(radio_maps: Sequence[RadioMap]) -> RadioMap:
    """One radio map with the points of all ``radio_maps`` (their access points united, in order
    of first appearance; an AP a map never heard is NaN in its rows). Source traces are
    concatenated (a trace name in two maps stays two traces of one name, so ``without_traces``
    drops both); per-point source and sigma are kept. Building maps merge only with building
    maps of the same floors."""
    if not radio_maps:
        raise ValueError("no radio maps to merge")
    with_floors = [m.floor is not None for m in radio_maps]
    if any(with_floors) and not all(with_floors):
        raise MapfilterError("cannot merge a building's radio map with a one-floor radio map")
    floor_names = radio_maps[0].floor_names
    if any(with_floors) and any(list(m.floor_names) != list(floor_names) for m in radio_maps):
        raise MapfilterError("cannot merge building radio maps of different floors")
    keys: dict[str, int] = {}
    for radio_map in radio_maps:
        for key in radio_map.ap_keys:
            keys.setdefault(key, len(keys))
    total = sum(len(m) for m in radio_maps)
    rssi = np.full((total, len(keys)), np.nan, dtype=np.float32)
    offset = 0
    traces: list[str] = []
    trace_index = []
    for radio_map in radio_maps:
        cols = np.array([keys[k] for k in radio_map.ap_keys], dtype=np.int64)
        rssi[offset:offset + len(radio_map), cols] = radio_map.rssi_dbm
        offset += len(radio_map)
        trace_index.append(radio_map.trace + len(traces))
        traces.extend(radio_map.source_traces)
    floor_name = next((m.floor_name for m in radio_maps if m.floor_name), None)
    return RadioMap(np.concatenate([m.xy_m for m in radio_maps]), list(keys), rssi,
                    np.concatenate([m.t_s for m in radio_maps]), np.concatenate(trace_index), traces, floor_name,
                    np.concatenate([m.floor for m in radio_maps]) if all(with_floors) else None,
                    floor_names if all(with_floors) else None,
                    np.concatenate([m.source for m in radio_maps]), np.concatenate([m.xy_sigma_m for m in radio_maps]))


def _steps_or_none(recording: Recording) -> Steps | None:
    if recording.acc_t_s.shape[0] < 100:  # no IMU to speak of (2 s at 50 Hz)
        return None
    return detect_steps(recording)


# ---- KWNN (Chang et al.) -------------------------------------------------------------------------
class KwnnFix(NamedTuple):
    """A KWNN position fix and how it was made."""

    xy_m: np.ndarray  # (2,) or (S, 2); NaN where no fix could be made
    neighbours: np.ndarray  # (k,) or (S, k) reference-point indices, -1 = none
    distance_db: np.ndarray  # signal-space distances of those neighbours
    n_shared_aps: np.ndarray  # APs the scan shares with the radio map (scalar or (S,))


class _SparseRows(NamedTuple):
    """Rows of an RSSI matrix as lists of the heard APs (CSR): row i is ``col``/``val`` in
    ``ptr[i]:ptr[i + 1]``, columns ascending; ``val`` in float64 as the distances use it."""

    ptr: np.ndarray  # (R + 1,) int64
    col: np.ndarray  # (nnz,) int64
    val: np.ndarray  # (nnz,) float64


def _sparse_rows(rssi_dbm: np.ndarray) -> _SparseRows:
    heard = ~np.isnan(rssi_dbm)
    rows, cols = np.nonzero(heard)  # row-major: columns ascending within each row
    ptr = np.zeros(rssi_dbm.shape[0] + 1, dtype=np.int64)
    np.cumsum(np.count_nonzero(heard, axis=1), out=ptr[1:])
    return _SparseRows(ptr, cols.astype(np.int64), rssi_dbm[rows, cols].astype(np.float64))


def _reference_rows(radio_map: RadioMap, min_rssi_dbm: float | None = None) -> _SparseRows:
    """The radio map's reference points as sparse rows (readings below ``min_rssi_dbm`` left
    out), computed once per RSSI array and floor."""
    cached = getattr(radio_map, "_sparse_refs", None)
    if cached is None or cached[0] is not radio_map.rssi_dbm:
        cached = (radio_map.rssi_dbm, {})
        radio_map._sparse_refs = cached
    if min_rssi_dbm not in cached[1]:
        cached[1][min_rssi_dbm] = _sparse_rows(_below_floor_unheard(radio_map.rssi_dbm, min_rssi_dbm))
    return cached[1][min_rssi_dbm]


def _below_floor_unheard(rssi_dbm: np.ndarray, min_rssi_dbm: float | None) -> np.ndarray:
    """``rssi_dbm`` with readings below ``min_rssi_dbm`` set to NaN (not heard); as is for None."""
    if min_rssi_dbm is None:
        return rssi_dbm
    with np.errstate(invalid="ignore"):
        return np.where(rssi_dbm < min_rssi_dbm, np.nan, rssi_dbm).astype(rssi_dbm.dtype)


@njit(cache=True)
def _signal_distances(s_ptr, s_col, s_val, r_ptr, r_col, r_val, p, missing_dbm, per_ap, out_dist, out_shared):
    """Minkowski-p signal distance between every scan and reference point, over sparse rows.

    Walks the two sorted lists of heard APs together, so that a pair costs the APs heard by
    either side, not every AP of the map (a well-surveyed floor has thousands, a scan hears
    tens). The terms are added in ascending AP order, as a loop over every AP that skips the
    ones heard by neither side would add them: the same sums to the last bit (for p = 2 the
    square is a product, which equals libm's pow to the last bit on integer dBm, what phones
    and the ILC logs give). ``per_ap``: the sum is divided by the number of APs heard by either
    side before the root (``kwnn_fix_many``).
    """
    n_scans = s_ptr.shape[0] - 1
    n_refs = r_ptr.shape[0] - 1
    past_end = np.iinfo(np.int64).max
    square = p == 2.0
    for s in range(n_scans):
        i0 = s_ptr[s]
        i1 = s_ptr[s + 1]
        for r in range(n_refs):
            i = i0
            j = r_ptr[r]
            j1 = r_ptr[r + 1]
            acc = 0.0
            shared = 0
            terms = 0
            while i < i1 or j < j1:
                ka = s_col[i] if i < i1 else past_end
                kb = r_col[j] if j < j1 else past_end
                if ka == kb:
                    a = s_val[i]
                    b = r_val[j]
                    shared += 1
                    i += 1
                    j += 1
                elif ka < kb:  # heard by the scan only: the reference gets missing_dbm explicitly
                    a = s_val[i]
                    b = missing_dbm
                    i += 1
                else:  # heard by the reference only
                    a = missing_dbm
                    b = r_val[j]
                    j += 1
                terms += 1
                d = abs(a - b)
                # d * d is what pow(d, 2) returns for integer dBm (exact squares), 20x cheaper
                acc += d * d if square else d ** p
            if per_ap and terms > 0:
                acc /= terms
            out_dist[s, r] = acc ** (1.0 / p)
            out_shared[s, r] = shared


def _distances_to_references(radio_map: RadioMap, scans: np.ndarray, p: float, missing_dbm: float,
                             min_rssi_dbm: float | None = None, per_ap: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(S, P) signal distances and (S, P) numbers of shared APs of the scans (S, K) to every
    reference point; readings below ``min_rssi_dbm`` count as not heard on both sides;
    ``per_ap``: the p-th power mean over the APs heard by either side instead of the sum."""
    refs = _reference_rows(radio_map, min_rssi_dbm)
    rows = _sparse_rows(_below_floor_unheard(scans, min_rssi_dbm))
    if p == 2.0 and _integral(rows.val, missing_dbm) and _integral_references(radio_map, min_rssi_dbm, missing_dbm):
        return _squared_distances_by_products(rows, refs, len(radio_map.ap_keys), float(missing_dbm), per_ap)
    dist = np.empty((scans.shape[0], len(radio_map)))
    shared = np.empty((scans.shape[0], len(radio_map)), dtype=np.int64)
    _signal_distances(rows.ptr, rows.col, rows.val, refs.ptr, refs.col, refs.val, float(p), float(missing_dbm),
                      bool(per_ap), dist, shared)
    return dist, shared


def _integral(values: np.ndarray, missing_dbm: float) -> bool:
    """Whole dBm (what phones and the ILC logs report) small enough that every sum below is exact."""
    return (float(missing_dbm).is_integer() and bool(np.all(np.abs(values) < 1e4))
            and bool(np.all(values == np.round(values))))


def _integral_references(radio_map: RadioMap, min_rssi_dbm: float | None, missing_dbm: float) -> bool:
    """``_integral`` of the radio map's sparse rows (``_reference_rows``), kept with them."""
    refs = _reference_rows(radio_map, min_rssi_dbm)
    kept = radio_map._sparse_refs[1]
    if ("integral", min_rssi_dbm) not in kept:
        kept[("integral", min_rssi_dbm)] = _integral(refs.val, 0.0)
    return float(missing_dbm).is_integer() and kept[("integral", min_rssi_dbm)]


def _squared_distances_by_products(rows: _SparseRows, refs: _SparseRows, n_aps: int,
                                   missing_dbm: float, per_ap: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """``_signal_distances`` for p = 2 as products: with every reading shifted by -missing_dbm an
    AP heard on one side only is the other side's 0, and one heard by neither adds 0, so D^2 =
    |a|^2 + |b|^2 - 2 a.b over all APs, where a.b needs only the APs the scans heard. On whole dBm
    every term and partial sum is an integer far below 2^53: the same D^2 to the last bit as the
    pairwise merge (whatever order the sums take), and the same root; 10-20x faster on a mall's
    radio map (a point hears 200 of 2,000 APs). The products run over each point's readings of
    the scans' APs (``_sparse_products``: a point hears a few of them), not over dense matrices.
    ``per_ap``: D^2 divided by the APs either side heard (each side's count less the shared
    ones), as the merge divides it."""
    a_val = rows.val - missing_dbm
    heard = np.unique(rows.col)  # the APs any scan heard: the only columns of a.b
    column = np.full(n_aps, -1, dtype=np.int64)
    column[heard] = np.arange(heard.size)
    n_scans = rows.ptr.size - 1
    # the scans' shifted readings and 0/1 heard, AP by scan (a point's reading meets every scan at once)
    row = np.repeat(np.arange(n_scans), np.diff(rows.ptr))
    a, a_heard = np.zeros((heard.size, n_scans)), np.zeros((heard.size, n_scans), dtype=np.int64)
    a[column[rows.col], row] = a_val
    a_heard[column[rows.col], row] = 1
    squared = np.empty((n_scans, refs.ptr.size - 1))
    shared = np.empty((n_scans, refs.ptr.size - 1), dtype=np.int64)
    _sparse_products(a, a_heard, refs.ptr, refs.col, refs.val, column, float(missing_dbm),
                     _row_sums(rows, a_val * a_val), np.diff(rows.ptr), bool(per_ap), squared, shared)
    _root_in_place(squared, 2.0)
    return squared, shared


@njit(cache=True, nogil=True)
def _sparse_products(a, a_heard, r_ptr, r_col, r_val, column, missing_dbm, na, row_count, per_ap, squared, shared):
    """Per reference point p (its readings ``r_*``, CSR): b = its readings shifted by
    -``missing_dbm``, |b|^2 over all of them, a.b and the shared count over those of the scans'
    APs (``column``: an AP's row of ``a``, the scans' shifted readings AP by scan, -1 for one no
    scan heard); D^2 = |a|^2 + |b|^2 - 2 a.b (``na``: the scans' |a|^2) into ``squared[:, p]``,
    divided with ``per_ap`` by the APs either side heard where any."""
    n_scans = a.shape[1]
    cross = np.empty(n_scans)
    count = np.empty(n_scans, dtype=np.int64)
    for p in range(r_ptr.shape[0] - 1):
        cross[:] = 0.0
        count[:] = 0
        nb = 0.0
        for e in range(r_ptr[p], r_ptr[p + 1]):
            b = r_val[e] - missing_dbm
            nb += b * b
            j = column[r_col[e]]
            if j < 0:
                continue
            for s in range(n_scans):
                cross[s] += a[j, s] * b
                count[s] += a_heard[j, s]
        n_ref = r_ptr[p + 1] - r_ptr[p]
        for s in range(n_scans):
            value = na[s] + nb - 2.0 * cross[s]
            if per_ap:  # a pair with no AP heard by either side keeps its 0, as in the merge
                either = row_count[s] + n_ref - count[s]
                if either > 0:
                    value = value / either
            squared[s, p] = value
            shared[s, p] = count[s]


def _row_sums(r: _SparseRows, values: np.ndarray) -> np.ndarray:
    """The sum of each sparse row's ``values`` (0 for an empty row)."""
    out = np.zeros(r.ptr.size - 1)
    np.add.at(out, np.repeat(np.arange(r.ptr.size - 1), np.diff(r.ptr)), values)
    return out


@njit(cache=True)
def _root_in_place(acc, p):
    """acc ** (1 / p) element-wise as ``_signal_distances`` takes it (libm's pow: np.sqrt rounds
    some values the other way)."""
    flat = acc.reshape(-1)
    for i in range(flat.shape[0]):
        flat[i] = max(flat[i], 0.0) ** (1.0 / p)


def _kwnn_from_distances(ref_xy_m: np.ndarray, dist: np.ndarray, shared: np.ndarray, n_shared_aps: np.ndarray,
                         k: int, q: float, min_shared_aps: int, ref_weight: np.ndarray | None = None) -> KwnnFix:
    """KWNN fixes from the (S, P) distances and shared-AP counts (``dist`` is overwritten);
    ``ref_weight`` (P,) multiplies each reference point's weight (``RadioMap.position_weights``)."""
    n_scans, n_refs = dist.shape
    dist[shared < max(min_shared_aps, 1)] = np.inf
    kk = min(k, n_refs)
    order = _k_smallest(np.ascontiguousarray(dist), kk)
    d_nn = np.take_along_axis(dist, order, axis=1)
    valid = np.isfinite(d_nn)
    # an exact match (D = 0) takes all the weight instead of dividing by zero
    weight = np.where(valid, 1.0 / np.maximum(d_nn, 1e-9) ** q, 0.0)
    if ref_weight is not None:
        weight *= ref_weight[order]
    total = weight.sum(axis=1)
    xy = np.full((n_scans, 2), np.nan)
    ok = total > 0
    xy[ok] = (weight[ok, :, None] * ref_xy_m[order[ok]]).sum(axis=1) / total[ok, None]
    return KwnnFix(xy, np.where(valid, order, -1), np.where(valid, d_nn, np.nan), n_shared_aps)


@njit(cache=True, nogil=True)
def _k_smallest(values, k):
    """(R, k) ``np.argsort(values, axis=1, kind="stable")[:, :k]`` without sorting whole rows: each
    row's k smallest in order, equal values by index and NaN after everything (numpy's order),
    kept by insertion in one pass (k is a handful, a row thousands of points)."""
    rows, n = values.shape
    out = np.empty((rows, k), dtype=np.int64)
    for r in range(rows):
        row = values[r]
        kept = 0
        for i in range(n):
            v = row[i]
            if kept == k:  # only a value before the last kept one gets in
                last = row[out[r, k - 1]]
                if not (v < last or (last != last and v == v)):
                    continue
                kept -= 1
            j = kept  # after every kept value not above it (stable; NaN sorts last)
            while j > 0:
                w = row[out[r, j - 1]]
                if v < w or (w != w and v == v):
                    out[r, j] = out[r, j - 1]
                    j -= 1
                else:
                    break
            out[r, j] = i
            kept += 1
    return out


def kwnn_fix_many(radio_map: RadioMap, scan_rssi_dbm: np.ndarray, k: int = 4, p: float = 2.0, q: float = 2.0,
                  missing_dbm: float = -100.0, min_shared_aps: int = 3, min_rssi_dbm: float | None = None,
                  per_ap: bool = False) -> KwnnFix:
    """KWNN fixes for many scans given as an (S, K) matrix over the radio map's APs (NaN = not heard).

    Signal distance (Chang et al.): D = (sum_k |r_k - f_k|^p)^(1/p) over the APs heard by the
    scan or the reference point, an AP missing on one side taking ``missing_dbm``. Only
    reference points sharing at least ``min_shared_aps`` heard APs with the scan are
    candidates; the fix is sum_i w_i x_i / sum_i w_i over the k nearest, w_i = 1 / D_i^q, times
    the point's position weight in a grown map (``RadioMap.position_weights``: a grown point
    whose position is uncertain counts less). Scans without any candidate get a NaN fix.
    ``min_rssi_dbm``: readings below it count as not heard, in the scans and in the radio map
    (``strong_kwnn_fixes``). ``per_ap``: D is the
    p-th power *mean* over the n APs heard by either side, (sum_k |r_k - f_k|^p / n)^(1/p), a
    distance in dB per AP that does not grow with how many APs a reference point heard (the
    walk diagnostic ``signal_distance_db``).
    """
    # per_ap gives better fixes but not better tracks: not the default (docs/accuracy.md)
    if k < 1 or p <= 0 or q < 0:
        raise MapfilterError(f"KWNN needs k >= 1, p > 0, q >= 0; got k={k}, p={p}, q={q}")
    scans = np.ascontiguousarray(scan_rssi_dbm, dtype=np.float64)
    if scans.ndim != 2 or scans.shape[1] != len(radio_map.ap_keys):
        raise MapfilterError(f"scan matrix has shape {scans.shape}, expected (S, {len(radio_map.ap_keys)})")
    dist, shared = _distances_to_references(radio_map, scans, p, missing_dbm, min_rssi_dbm, per_ap)
    n_shared_aps = np.count_nonzero(~np.isnan(_below_floor_unheard(scans, min_rssi_dbm)), axis=1)
    return _kwnn_from_distances(radio_map.xy_m, dist, shared, n_shared_aps, k, q, min_shared_aps,
                                _ref_weights(radio_map))


def _ref_weights(radio_map: RadioMap) -> np.ndarray | None:
    """The points' position weights, or None when every point is surveyed (weights all 1: the
    fixes stay those of plain KWNN to the last bit)."""
    return radio_map.position_weights() if radio_map.is_grown else None


# Strong-reading KWNN: readings below this count as not heard, and an AP heard on one side only
# counts as STRONG_MISSING_DBM on the other (5 dB under the floor: just not heard). Phones differ
# by 10-20 dB in what they report for weak APs and in how many they hear at all (an ILC F1 walk
# reports 20 dB less than the survey walk beside it and hears 40-110 APs where the survey heard
# 300), and with -100 dBm for every AP heard on one side the plain distance is decided by those
# (the floor's fixes: docs/accuracy.md).
STRONG_MIN_RSSI_DBM = -85.0
STRONG_MISSING_DBM = -90.0


def strong_kwnn_fixes(radio_map: RadioMap, scan_rssi_dbm: np.ndarray, k: int = 4,
                      min_rssi_dbm: float = STRONG_MIN_RSSI_DBM, missing_dbm: float = STRONG_MISSING_DBM) -> np.ndarray:
    """(S, 2) KWNN fixes from the strong readings only (``kwnn_fix_many`` with ``min_rssi_dbm``);
    a scan with too few strong APs for a fix takes its plain KWNN fix (NaN if it has none either)."""
    fixes = kwnn_fix_many(radio_map, scan_rssi_dbm, k=k, missing_dbm=missing_dbm, min_rssi_dbm=min_rssi_dbm).xy_m
    none = ~np.all(np.isfinite(fixes), axis=1)
    if none.any():
        fixes[none] = kwnn_fix_many(radio_map, np.asarray(scan_rssi_dbm)[none], k=k).xy_m
    return fixes


def plain_signal_distances(radio_map: RadioMap, scan_rssi_dbm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(S, P) the plain KWNN signal distances of the scans to every point (p = 2, an AP heard on
    one side only at -100 dBm) and (S, P) their shared APs: what ``kwnn_fix_many``'s defaults
    and the floor vote use, for a caller that needs both."""
    return _distances_to_references(radio_map, np.ascontiguousarray(scan_rssi_dbm, dtype=np.float64), 2.0, -100.0)


def kwnn_fixes_by_floor(radio_map: RadioMap, scan_rssi_dbm: np.ndarray, point_xy_m: np.ndarray, k: int = 4,
                        min_rssi_dbm: float | None = STRONG_MIN_RSSI_DBM,
                        plain: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A building's KWNN fixes from one matrix of signal distances: ((S, 2) the fix from every
    floor's points, placed at ``point_xy_m`` (P, 2), e.g. each point in the building's frame;
    (S, F, 2) each floor's fix from its own points, in its own frame). The same fixes as
    ``strong_kwnn_fixes`` (``min_rssi_dbm`` None: ``kwnn_fix_many``) of the whole map and of each
    ``floor_map``, without computing the distances once per floor; ``plain``: the scans'
    ``plain_signal_distances`` if the caller has them already."""
    scans = np.ascontiguousarray(scan_rssi_dbm, dtype=np.float64)
    n_floors = len(radio_map.floor_names)
    every = np.full((scans.shape[0], 2), np.nan)
    own = np.full((scans.shape[0], n_floors, 2), np.nan)
    if scans.shape[0] == 0 or len(radio_map) == 0:
        return every, own
    weights = _ref_weights(radio_map)
    floor = np.asarray(radio_map.floor)

    def fixes(rows: np.ndarray, missing_dbm: float, floor_rssi_dbm: float | None) -> None:
        if floor_rssi_dbm is None and plain is not None:
            dist, shared = plain[0][rows], plain[1][rows]
        else:
            dist, shared = _distances_to_references(radio_map, scans[rows], 2.0, missing_dbm, floor_rssi_dbm)
        heard = np.count_nonzero(~np.isnan(_below_floor_unheard(scans[rows], floor_rssi_dbm)), axis=1)
        every[rows] = _kwnn_from_distances(point_xy_m, dist.copy(), shared, heard, k, 2.0, 3, weights).xy_m
        for f in range(n_floors):
            on = floor == f
            if on.any():
                own[rows, f] = _kwnn_from_distances(radio_map.xy_m[on], dist[:, on], shared[:, on], heard, k, 2.0, 3,
                                                    None if weights is None else weights[on]).xy_m

    all_rows = np.arange(scans.shape[0])
    if min_rssi_dbm is None:
        fixes(all_rows, -100.0, None)
        return every, own
    fixes(all_rows, STRONG_MISSING_DBM, min_rssi_dbm)
    # a scan (or a floor) with too few strong APs for a fix takes its plain KWNN fix, as strong_kwnn_fixes
    strong_every, strong_own = every.copy(), own.copy()
    missing = ~np.isfinite(every).all(axis=1) | ~np.isfinite(own).all(axis=2).all(axis=1)
    if missing.any():
        fixes(np.flatnonzero(missing), -100.0, None)
        keep_every = np.isfinite(strong_every).all(axis=1)
        every[keep_every] = strong_every[keep_every]
        keep_own = np.isfinite(strong_own).all(axis=2)
        own[keep_own] = strong_own[keep_own]
    return every, own


def cross_validated_fix_errors(radio_map: RadioMap, k: int = 4, max_groups: int = 200,
                               min_separation_m: float = 1.0) -> np.ndarray:
    """KWNN fix errors (m) of the radio map's own reference points, each fixed without its group.

    A group is a source trace when the map comes from several survey walks (leave one walk
    out, as a new walk would be fixed), else the points within ``min_separation_m`` of one
    location (leave one surveyed spot out). At most ``max_groups`` groups, evenly picked.
    What it measures is how far off a fix from this radio map typically is: the spread that
    a filter should give fixes from it.

    In a grown map (``RadioMap.is_grown``) grown points are references only, weighed by their
    position uncertainty as in ``kwnn_fix_many``: the errors are those of the surveyed points
    (whose labels are the truth), each trace left out with every point of its name (a walk
    that is also grown leaves with its grown points); only a map with fewer than two surveyed
    traces tests its grown points too.

    It depends on the radio map only, and costs (points)^2 signal distances: the result is
    kept with the map (and written to its file by ``RadioMap.save``), so it is computed once
    per map, not once per tracked walk. A map whose arrays are replaced is computed afresh.
    """
    params = (int(k), int(max_groups), float(min_separation_m))
    memo = _cv_memo(radio_map)
    if params not in memo:
        memo[params] = _cross_validated_fix_errors(radio_map, *params)
    return memo[params].copy()


# ---- where the survey reaches: how well a scan matches it (filter.models.survey_reach) ----------
MATCH_MIN_RSSI_DBM = -85.0  # readings below count as unheard in a match distance (weak APs differ most by phone)
MATCH_MIN_SHARED_APS = 3  # a reference point sharing fewer APs with the scan does not match it
INSIDE_WITHIN_M = 3.0  # a survey point this near another walk's point stands for a scan taken inside the survey
OUTSIDE_BEYOND_M = 10.0  # one this far from every other walk's point, for a scan taken outside it
MAX_MATCHED_POINTS = 1200  # survey points matched against the other walks' (spread over the survey): the cost is theirs times the map's


def _survey_match_params() -> np.ndarray:
    """Every number the stored survey match distances depend on besides the radio map."""
    return np.array([MATCH_MIN_RSSI_DBM, MATCH_MIN_SHARED_APS, INSIDE_WITHIN_M, OUTSIDE_BEYOND_M, MAX_MATCHED_POINTS],
                    dtype=np.float64)


def match_distance_db(radio_map: RadioMap, scan_rssi_dbm: np.ndarray) -> np.ndarray:
    """(S,) each scan's signal distance (dB) to its best-matching reference point (inf: none
    shares ``MATCH_MIN_SHARED_APS`` APs heard at ``MATCH_MIN_RSSI_DBM`` or more)."""
    return _match_distances(radio_map, scan_rssi_dbm).min(axis=1, initial=np.inf)


def match_distance_by_floor_db(radio_map: RadioMap, scan_rssi_dbm: np.ndarray) -> np.ndarray:
    """(S, F) each scan's match distance (``match_distance_db``) to each floor's points of a
    building's radio map, from one matrix of signal distances."""
    dist = _match_distances(radio_map, scan_rssi_dbm)
    floor = np.asarray(radio_map.floor)
    return np.stack([dist[:, floor == f].min(axis=1, initial=np.inf) for f in range(len(radio_map.floor_names))],
                    axis=1).reshape(dist.shape[0], len(radio_map.floor_names))


def _match_distances(radio_map: RadioMap, scan_rssi_dbm: np.ndarray) -> np.ndarray:
    """(S, P) the match distance of each scan to each point (inf where they share too few APs)."""
    scans = np.ascontiguousarray(scan_rssi_dbm, dtype=np.float64).reshape(-1, len(radio_map.ap_keys))
    if scans.shape[0] == 0 or len(radio_map) == 0:
        return np.full((scans.shape[0], len(radio_map)), np.inf)
    dist, shared = _distances_to_references(radio_map, scans, 2.0, -100.0, min_rssi_dbm=MATCH_MIN_RSSI_DBM,
                                            per_ap=True)
    return np.where(shared >= MATCH_MIN_SHARED_APS, dist, np.inf)


def memo_of(radio_map: RadioMap) -> dict:
    """What was made from this radio map (kept on it, so it goes with it), emptied when its arrays
    were replaced."""
    arrays = (radio_map.xy_m, radio_map.rssi_dbm, radio_map.trace, radio_map.floor)
    cached = getattr(radio_map, "_survey_reach_memo", None)
    if cached is None or any(a is not b for a, b in zip(cached[0], arrays)):
        cached = (arrays, {})
        radio_map._survey_reach_memo = cached
    return cached[1]


def survey_match_distances_db(radio_map: RadioMap) -> tuple[np.ndarray, np.ndarray]:
    """The match distances (sorted, dB) of scans taken inside the survey and of scans taken
    outside it, as the survey itself shows them: each survey walk's points matched against the
    other walks' points (``MAX_MATCHED_POINTS`` of them at most, spread over the map); inside, the points
    within ``INSIDE_WITHIN_M`` of another walk's point on their floor, outside those farther than
    ``OUTSIDE_BEYOND_M`` from all of them. Kept on the radio map (an evaluation's walks share it)."""
    memo = memo_of(radio_map)
    if "match distances" in memo:
        return memo["match distances"]
    from scipy.spatial import cKDTree  # here: a radio map file keeps them, and a track need not import scipy.spatial
    walk = np.asarray(radio_map.trace)
    floor = np.zeros(len(radio_map), dtype=np.int64) if radio_map.floor is None else np.asarray(radio_map.floor)
    walks = np.unique(walk)
    found, away = [], []  # the survey's own matches, inside and outside
    if walks.size >= 2:
        matched = np.zeros(len(radio_map), dtype=bool)
        matched[np.linspace(0, len(radio_map) - 1, min(MAX_MATCHED_POINTS, len(radio_map))).round().astype(int)] = True
        for w in np.unique(walk[matched]):
            inside = walk == w
            points = inside & matched
            dist, shared = _distances_to_references(radio_map, radio_map.rssi_dbm[points].astype(np.float64), 2.0,
                                                    -100.0, min_rssi_dbm=MATCH_MIN_RSSI_DBM, per_ap=True)
            dist = np.where(shared >= MATCH_MIN_SHARED_APS, dist, np.inf)
            dist[:, inside] = np.inf
            best = dist.min(axis=1)
            gap = np.full(int(points.sum()), np.inf)  # to the nearest point of another walk on the floor
            for f in np.unique(floor[points]):
                others = ~inside & (floor == f)
                mine = floor[points] == f
                if others.any():
                    gap[mine] = cKDTree(radio_map.xy_m[others]).query(radio_map.xy_m[points][mine])[0]
            found.append(best[(gap <= INSIDE_WITHIN_M) & np.isfinite(best)])
            away.append(best[(gap > OUTSIDE_BEYOND_M) & np.isfinite(best)])
    result = tuple(np.sort(np.concatenate(part)) if part else np.zeros(0) for part in (found, away))
    memo["match distances"] = result
    return result


def _cv_memo(radio_map: RadioMap) -> dict:
    """The map's memo of cross-validated errors, emptied when its arrays were replaced."""
    arrays = (radio_map.xy_m, radio_map.rssi_dbm, radio_map.trace, radio_map.source, radio_map.xy_sigma_m)
    cached = getattr(radio_map, "_cv_errors", None)
    if cached is None or any(a is not b for a, b in zip(cached[0], arrays)):
        cached = (arrays, {})
        radio_map._cv_errors = cached
    return cached[1]


def _cross_validated_fix_errors(radio_map: RadioMap, k: int, max_groups: int, min_separation_m: float) -> np.ndarray:
    if len(radio_map) < 2:
        return np.zeros(0)
    grown = radio_map.is_grown
    if len(radio_map.source_traces) > 1:
        group = radio_map.trace
        if grown:  # by name: a walk surveyed and also grown is one group
            _, of_name = np.unique(np.array(radio_map.source_traces, dtype=str), return_inverse=True)
            group = of_name.ravel()[radio_map.trace]
    else:
        cell = np.floor(radio_map.xy_m / min_separation_m).astype(np.int64)
        _, group = np.unique(cell, axis=0, return_inverse=True)
        group = group.ravel()
    tested = np.ones(len(radio_map), dtype=bool)
    if grown and np.unique(group[radio_map.source == SURVEYED]).size >= 2:
        tested = radio_map.source == SURVEYED
    groups = np.unique(group[tested])
    if np.unique(group).size < 2 or groups.size < 1:
        return np.zeros(0)
    picked = groups[np.linspace(0, groups.size - 1, min(max_groups, groups.size)).round().astype(int)]
    ref_weight = _ref_weights(radio_map)
    errors = []
    for g in np.unique(picked):
        inside = group == g
        test = inside & tested
        scans = radio_map.rssi_dbm[test].astype(np.float64)
        # distances to every reference point, the group's own taken out of the candidates:
        # the same fixes as kwnn_fix_many on radio_map.select(~inside), without copying the map
        dist, shared = _distances_to_references(radio_map, scans, 2.0, -100.0)
        dist[:, inside] = np.inf
        fixes = _kwnn_from_distances(radio_map.xy_m, dist, shared, np.count_nonzero(~np.isnan(scans), axis=1),
                                     k, 2.0, 3, ref_weight).xy_m
        ok = np.all(np.isfinite(fixes), axis=1)
        errors.append(np.linalg.norm(fixes[ok] - radio_map.xy_m[test][ok], axis=1))
    return np.concatenate(errors)
