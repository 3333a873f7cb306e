"""Building: several floor plans, their elevations, their placement in one frame, and connectors.

A building YAML lists its floors (each a ROS map_server map YAML as ``FloorPlan`` reads it)
and the connectors between them (stairs, escalators, lifts)::

    building: site1                 # optional name
    storey_height_m: 5.0            # optional, only documents how elevations were chosen
    floors:
      - name: F1
        map: F1.yaml                # relative to this file
        elevation_m: 0.0
        offset_m: [0.0, 0.0]        # the floor frame's origin in the building frame
        rotation_deg: 0.0           # optional: the floor frame's x axis, counter-clockwise
      - name: F2
        map: F2.yaml
        elevation_m: 5.0
        offset_m: [0.0, 2.8]
    connectors:                     # optional
      - name: stairs-east
        kind: stairs                # stairs | escalator | lift
        floors:                     # a polygon per linked floor, in that floor's own frame
          F1: [[10, 5], [14, 5], [14, 9], [10, 9]]
          F2: [[10, 5], [14, 5], [14, 9], [10, 9]]
    connectors_geojson: connectors.geojson   # optional, more connectors (see below)
    georeference:                   # optional: the building frame is the east/north tangent
      origin_lat_deg: 49.46115181   # plane (x east, y north, metres) at this WGS-84 point
      origin_lon_deg: 11.11114911

Connectors in GeoJSON: a FeatureCollection of polygons in floor metres whose properties
name the connector, its kind and the floor the polygon is on
(``{"name": "lift-1", "kind": "lift", "floor": "F2"}``); features sharing a name are one
connector.

A point ``p`` of a floor frame is at ``offset_m + R(rotation) p`` in the building frame.
Positions on a floor (tracks, waypoints, connectors) stay in that floor's frame, so ILC
ground truth (each floor in its own frame) compares directly.

:meth:`Building.load` reads either a building YAML or a single map YAML (a one-floor
building), so every command that takes a map also takes a building. A building with a
georeference knows where it is on the Earth (maps/georef.py): positions convert between floor
metres and latitude/longitude (:meth:`Building.floor_xy_to_latlon`, :meth:`Building.latlon_to_floor_xy`).
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from mapfilter.io.atomic import atomic_paths
from mapfilter.errors import MapfilterError
from mapfilter.io.yamlio import path_for_yaml, path_in_yaml
from mapfilter.maps.floorplan import FloorPlan, is_number, read_yaml_mapping
from mapfilter.maps.georef import LocalFrame

if TYPE_CHECKING:
    import shapely

CONNECTOR_KINDS = ("stairs", "escalator", "lift")


@dataclasses.dataclass(eq=False)
class Floor:
    """One floor of a building: its plan and where its frame sits in the building frame."""

    name: str
    plan: FloorPlan
    elevation_m: float = 0.0
    offset_m: tuple[float, float] = (0.0, 0.0)  # floor-frame origin in the building frame
    rotation_rad: float = 0.0  # floor-frame x axis in the building frame, counter-clockwise
    map_path: Path | None = None  # the floor's map YAML, when loaded from a file

    def to_building(self, xy_m: np.ndarray) -> np.ndarray:
        """Floor-frame points -> building-frame points (..., 2)."""
        xy = np.asarray(xy_m, dtype=np.float64)
        c, s = math.cos(self.rotation_rad), math.sin(self.rotation_rad)
        x = self.offset_m[0] + c * xy[..., 0] - s * xy[..., 1]
        y = self.offset_m[1] + s * xy[..., 0] + c * xy[..., 1]
        return np.stack([x, y], axis=-1)

    def from_building(self, xy_m: np.ndarray) -> np.ndarray:
        """Building-frame points -> floor-frame points (..., 2) (inverse of ``to_building``)."""
        xy = np.asarray(xy_m, dtype=np.float64)
        c, s = math.cos(self.rotation_rad), math.sin(self.rotation_rad)
        dx, dy = xy[..., 0] - self.offset_m[0], xy[..., 1] - self.offset_m[1]
        return np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)

    def outline_in_building(self) -> shapely.Polygon:
        """The map's rectangle (its extent) in the building frame."""
        x0, x1, y0, y1 = self.plan.extent_m
        import shapely  # here: a map without connectors never needs it (a tenth of a second to import)

        return shapely.Polygon(self.to_building(np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])))


@dataclasses.dataclass(eq=False)
class Connector:
    """Stairs, an escalator or a lift: a polygon on each floor it links (floor frame, metres)."""

    name: str
    kind: str
    polygons: dict[str, shapely.Polygon]  # floor name -> polygon in that floor's frame

    @property
    def floor_names(self) -> list[str]:
        return list(self.polygons)


@dataclasses.dataclass(eq=False)
class Building:
    """Floors (bottom to top as listed) and the connectors between them.

    ``path`` is the file it came from (a building YAML or, for a one-floor building, the map
    YAML); errors about the building name it.
    """

    floors: list[Floor]
    connectors: list[Connector] = dataclasses.field(default_factory=list)
    name: str | None = None
    path: Path | None = None
    storey_height_m: float | None = None
    georeference: LocalFrame | None = None  # the building frame's place on the Earth, if known

    def __post_init__(self) -> None:
        if not self.floors:
            raise MapfilterError("a building needs at least one floor", self.path)
        names = [f.name for f in self.floors]
        duplicates = sorted({n for n in names if names.count(n) > 1})
        if duplicates:
            raise MapfilterError(f"floor names must be unique: {', '.join(duplicates)} listed twice", self.path)

    # ---- lookup ---------------------------------------------------------------------------
    @property
    def floor_names(self) -> list[str]:
        return [f.name for f in self.floors]

    @property
    def is_single_floor(self) -> bool:
        return len(self.floors) == 1

    def floor_index(self, name: str, where: str | os.PathLike | None = None) -> int:
        """Index of the floor called ``name``; ``MapfilterError`` naming ``where`` if none is."""
        for i, floor in enumerate(self.floors):
            if floor.name == name:
                return i
        raise MapfilterError(f"floor {name!r} is not in the building {self.path or ''} "
                             f"(floors: {', '.join(self.floor_names)})".replace(" ()", ""),
                             where if where is not None else self.path)

    def floor(self, name: str) -> Floor:
        return self.floors[self.floor_index(name)]

    def floor_of_log(self, header_floor: str | None, log_path: str | os.PathLike | None,
                     given: str | None = None) -> int | None:
        """The floor index a log belongs to: ``given`` (the user's ``--floor``) if any, else the
        floor its header names (``FloorName``); None if neither names one.

        A log whose header names a floor the building does not have is refused with one line
        (a walk of another floor tracked here goes wrong by the floors' distance), except on a
        one-floor map that declares no floor name (it takes every log).
        """
        if given is not None:
            return self.floor_index(given, log_path)
        if not header_floor:
            return 0 if self.is_single_floor else None
        for i, floor in enumerate(self.floors):
            if floor.name == header_floor:
                return i
        if self.is_single_floor and self.floors[0].plan.floor_name is None:
            return 0
        raise MapfilterError(f"floor {header_floor!r} is not in the building {self.path or ''} (floors: "
                             f"{', '.join(self.floor_names)}): give the map of the log's floor (track --floor NAME "
                             f"tracks it on one of these anyway)".replace("building  (", "building ("), log_path)

    # ---- georeference ----------------------------------------------------------------------
    def _frame(self, where: str | os.PathLike | None) -> LocalFrame:
        if self.georeference is None:
            raise MapfilterError(f"the building {self.path or ''} has no georeference (latitude/longitude): "
                                 "make it with 'mapfilter map import-ipin' or add a 'georeference' "
                                 "to its YAML".replace("  ", " "), where if where is not None else self.path)
        return self.georeference

    def latlon_to_floor_xy(self, latlon_deg: np.ndarray, floor_names: list[str] | str,
                           where: str | os.PathLike | None = None) -> np.ndarray:
        """(N, 2) latitude/longitude degrees -> (N, 2) metres in each point's floor frame.

        ``floor_names`` names each point's floor (or one floor for all); a one-floor building
        takes every point on its floor. ``MapfilterError`` (naming ``where``) without a
        georeference or for a floor the building does not have.
        """
        frame = self._frame(where)
        building_xy = frame.to_xy_m(np.asarray(latlon_deg, dtype=np.float64).reshape(-1, 2))
        return self._per_floor(building_xy, floor_names, where, to_building=False)

    def floor_xy_to_latlon(self, xy_m: np.ndarray, floor_names: list[str] | str | None,
                           where: str | os.PathLike | None = None) -> np.ndarray:
        """(N, 2) metres in each point's floor frame -> (N, 2) latitude/longitude degrees."""
        frame = self._frame(where)
        xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        if floor_names is None:
            floor_names = self.floors[0].name
        return frame.to_latlon_deg(self._per_floor(xy, floor_names, where, to_building=True))

    def _per_floor(self, xy: np.ndarray, floor_names: list[str] | str, where, to_building: bool) -> np.ndarray:
        names = [floor_names] * xy.shape[0] if isinstance(floor_names, str) else list(floor_names)
        if len(names) != xy.shape[0]:
            raise ValueError(f"{xy.shape[0]} points but {len(names)} floor names")
        out = np.empty_like(xy)
        for name in sorted(set(names)):
            floor = self.floors[0] if self.is_single_floor else self.floors[self.floor_index(name, where)]
            rows = np.array([n == name for n in names])
            out[rows] = floor.to_building(xy[rows]) if to_building else floor.from_building(xy[rows])
        return out

    # ---- validation -----------------------------------------------------------------------
    def validate(self) -> None:
        """Check what the loader cannot see field by field; ``MapfilterError`` naming the file.

        - with several floors, each floor's map must overlap another floor's in the building
          frame (a floor that overlaps nothing is almost always a wrong offset);
        - each connector names known floors, links at least two, and each of its polygons has
          free space of its floor inside.
        """
        where = self.path
        if len(self.floors) > 1:
            outlines = [f.outline_in_building() for f in self.floors]
            for i, floor in enumerate(self.floors):
                overlap = max(outlines[i].intersection(o).area for j, o in enumerate(outlines) if j != i)
                if overlap <= 0.0:
                    raise MapfilterError(f"floor {floor.name!r} overlaps no other floor in the building frame "
                                         f"(check its offset_m / rotation_deg)", where)
        known = set(self.floor_names)
        for connector in self.connectors:
            if connector.kind not in CONNECTOR_KINDS:
                raise MapfilterError(f"connector {connector.name!r}: kind must be one of "
                                     f"{', '.join(CONNECTOR_KINDS)}, got {connector.kind!r}", where)
            unknown = [n for n in connector.polygons if n not in known]
            if unknown:
                raise MapfilterError(f"connector {connector.name!r} names unknown floor(s) {', '.join(unknown)} "
                                     f"(floors: {', '.join(self.floor_names)})", where)
            if len(connector.polygons) < 2:
                raise MapfilterError(f"connector {connector.name!r} links {len(connector.polygons)} floor(s): "
                                     f"it needs a polygon on at least two", where)
            for floor_name, polygon in connector.polygons.items():
                if connector_pixels(self.floor(floor_name).plan, polygon)[0].size == 0:
                    raise MapfilterError(f"connector {connector.name!r} lies outside floor {floor_name!r} "
                                         f"(its polygon covers no free space of that floor's map)", where)

    # ---- files ----------------------------------------------------------------------------
    @classmethod
    def from_plan(cls, plan: FloorPlan, path: str | os.PathLike | None = None) -> Building:
        """A single map as a one-floor building (as ``load`` makes one from a map YAML)."""
        path = None if path is None else Path(path)
        name = plan.floor_name or (path.stem if path is not None else "floor")
        return cls([Floor(name, plan, map_path=path)], path=path)

    @classmethod
    def load(cls, path: str | os.PathLike) -> Building:
        """Read a building YAML, or a map YAML as a one-floor building (see the module docstring)."""
        path = Path(path)
        meta = read_yaml_mapping(path, "a map or building YAML")
        if "floors" not in meta:
            if "image" in meta:  # a ROS map_server map: one floor
                return cls.from_plan(FloorPlan.load(path), path)
            raise MapfilterError("neither a building YAML (no 'floors' list) nor a map YAML (no 'image')", path)
        floors_meta = meta["floors"]
        if not isinstance(floors_meta, list) or not floors_meta:
            raise MapfilterError("'floors' must be a non-empty list", path)
        floors = _in_elevation_order([_read_floor(path, i, f) for i, f in enumerate(floors_meta)], path)
        connectors = [_read_connector(path, i, c) for i, c in enumerate(meta.get("connectors") or [])]
        if not isinstance(meta.get("connectors") or [], list):
            raise MapfilterError("'connectors' must be a list", path)
        if meta.get("connectors_geojson"):
            connectors += read_connectors_geojson(path_in_yaml(path, meta["connectors_geojson"]))
        storey = meta.get("storey_height_m")
        building = cls(floors, connectors, None if meta.get("building") is None else str(meta["building"]), path,
                       float(storey) if is_number(storey) else None, _read_georeference(path, meta))
        building.validate()
        return building

    def save(self, path: str | os.PathLike) -> None:
        """Write the building YAML (floor maps are referenced, not written), atomically."""
        path = Path(path)
        floors = []
        for floor in self.floors:
            if floor.map_path is None:
                raise MapfilterError(f"floor {floor.name!r} has no map file to reference: write it first", path)
            entry: dict[str, Any] = {"name": floor.name, "map": path_for_yaml(floor.map_path, path.parent),
                                     "elevation_m": float(floor.elevation_m),
                                     "offset_m": [float(floor.offset_m[0]), float(floor.offset_m[1])]}
            if floor.rotation_rad:
                entry["rotation_deg"] = math.degrees(floor.rotation_rad)
            floors.append(entry)
        meta: dict[str, Any] = {}
        if self.name:
            meta["building"] = self.name
        if self.storey_height_m is not None:
            meta["storey_height_m"] = float(self.storey_height_m)
        if self.georeference is not None:
            meta["georeference"] = {"origin_lat_deg": float(self.georeference.origin_lat_deg),
                                    "origin_lon_deg": float(self.georeference.origin_lon_deg)}
        meta["floors"] = floors
        if self.connectors:
            meta["connectors"] = [
                {"name": c.name, "kind": c.kind,
                 "floors": {n: [[float(x), float(y)] for x, y in np.asarray(p.exterior.coords)[:-1, :2]]
                            for n, p in c.polygons.items()}}
                for c in self.connectors]
        with atomic_paths(path) as (tmp,):
            tmp.write_text(yaml.safe_dump(meta, sort_keys=False))


def connector_pixels(plan: FloorPlan, polygon: shapely.Geometry) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) of the free pixels of ``plan`` whose centre lies inside ``polygon`` (floor frame)."""
    x_min, y_min, x_max, y_max = polygon.bounds
    rows_a, cols_a, _ = plan.pixel_index(np.array([[x_min, y_max], [x_max, y_min]]))
    h, w = plan.shape_px
    r0, r1 = max(int(rows_a[0]), 0), min(int(rows_a[1]), h - 1)
    c0, c1 = max(int(cols_a[0]), 0), min(int(cols_a[1]), w - 1)
    if r0 > r1 or c0 > c1:
        return np.empty(0, np.int64), np.empty(0, np.int64)
    rr, cc = np.mgrid[r0:r1 + 1, c0:c1 + 1]
    rr, cc = rr.ravel(), cc.ravel()
    centres = plan.pixel_to_world(np.stack([cc + 0.5, rr + 0.5], axis=-1))
    import shapely

    inside = shapely.contains_xy(polygon, centres[:, 0], centres[:, 1]) & ~plan.wall_mask[rr, cc]
    return rr[inside], cc[inside]


def read_connectors_geojson(path: str | os.PathLike) -> list[Connector]:
    """Connectors from a GeoJSON FeatureCollection of floor-metre polygons with properties
    ``name``, ``kind`` and ``floor``; features sharing a name make one connector."""
    path = Path(path)
    meta = read_yaml_mapping(path, "a connector file")  # YAML reads JSON
    features = meta.get("features")
    if not isinstance(features, list):
        raise MapfilterError("connector GeoJSON has no 'features' list", path)
    import shapely.geometry

    by_name: dict[str, Connector] = {}
    for index, feature in enumerate(features):
        props = (feature or {}).get("properties") or {}
        name, kind, floor = props.get("name"), props.get("kind"), props.get("floor")
        if not (name and kind and floor):
            raise MapfilterError(f"feature {index}: properties must give 'name', 'kind' and 'floor'", path)
        try:
            polygon = shapely.make_valid(shapely.geometry.shape(feature["geometry"]))
        except Exception as exc:  # shapely raises several types for bad geometry
            raise MapfilterError(f"feature {index} has no valid geometry ({exc})", path) from None
        if polygon.geom_type not in ("Polygon", "MultiPolygon") or polygon.is_empty:
            raise MapfilterError(f"feature {index}: a connector must be a polygon", path)
        connector = by_name.setdefault(str(name), Connector(str(name), str(kind), {}))
        if connector.kind != str(kind):
            raise MapfilterError(f"feature {index}: connector {name!r} is both {connector.kind!r} and {kind!r}", path)
        connector.polygons[str(floor)] = polygon
    return list(by_name.values())


# ---- reading helpers -------------------------------------------------------------------------
def _read_floor(path: Path, index: int, meta: Any) -> Floor:
    if not isinstance(meta, dict):
        raise MapfilterError(f"floors[{index}] must be a mapping with name, map, elevation_m, offset_m", path)
    for key in ("name", "map"):
        if not meta.get(key):
            raise MapfilterError(f"floors[{index}] lacks '{key}'", path)
    name = str(meta["name"])
    elevation = meta.get("elevation_m", 0.0)
    if not is_number(elevation):
        raise MapfilterError(f"floor {name!r}: elevation_m must be a number, got {elevation!r}", path)
    offset = meta.get("offset_m", [0.0, 0.0])
    if not (isinstance(offset, list) and len(offset) == 2 and all(is_number(v) for v in offset)):
        raise MapfilterError(f"floor {name!r}: offset_m must be [x, y] numbers, got {offset!r}", path)
    rotation = meta.get("rotation_deg", 0.0)
    if not is_number(rotation):
        raise MapfilterError(f"floor {name!r}: rotation_deg must be a number, got {rotation!r}", path)
    map_path = path_in_yaml(path, meta["map"])
    plan = FloorPlan.load(map_path)
    return Floor(name, plan, float(elevation), (float(offset[0]), float(offset[1])), math.radians(float(rotation)),
                 map_path)


def _read_georeference(path: Path, meta: dict) -> LocalFrame | None:
    geo = meta.get("georeference")
    if geo is None:
        return None
    if not (isinstance(geo, dict) and is_number(geo.get("origin_lat_deg")) and is_number(geo.get("origin_lon_deg"))):
        raise MapfilterError("'georeference' must give origin_lat_deg and origin_lon_deg (WGS-84 degrees)", path)
    try:
        return LocalFrame(float(geo["origin_lat_deg"]), float(geo["origin_lon_deg"]))
    except MapfilterError as exc:
        raise MapfilterError(exc.reason, path) from None


def _read_connector(path: Path, index: int, meta: Any) -> Connector:
    if not isinstance(meta, dict) or not meta.get("name") or not meta.get("kind"):
        raise MapfilterError(f"connectors[{index}] must be a mapping with name, kind and floors", path)
    name = str(meta["name"])
    floors = meta.get("floors")
    if not isinstance(floors, dict):
        raise MapfilterError(f"connector {name!r}: 'floors' must map floor names to polygons", path)
    import shapely

    polygons = {}
    for floor_name, ring in floors.items():
        try:
            points = np.asarray(ring, dtype=np.float64)
            if points.ndim != 2 or points.shape[1] != 2 or len(points) < 3 or not np.isfinite(points).all():
                raise ValueError
        except (TypeError, ValueError):
            raise MapfilterError(f"connector {name!r}, floor {floor_name!r}: the polygon must be at least three "
                                 f"[x, y] points", path) from None
        polygons[str(floor_name)] = shapely.make_valid(shapely.Polygon(points))
    return Connector(name, str(meta["kind"]), polygons)


def _in_elevation_order(floors: list[Floor], path: Path) -> list[Floor]:
    """The floors from the lowest up (a building YAML may list them in any order); two floors at
    one elevation are refused: the barometer and the floor changes tell floors by elevation."""
    ordered = sorted(floors, key=lambda f: f.elevation_m)
    for lower, upper in zip(ordered, ordered[1:]):
        if upper.elevation_m == lower.elevation_m:
            raise MapfilterError(f"floors {lower.name!r} and {upper.name!r} are both at elevation_m "
                                 f"{lower.elevation_m:g}: each floor needs its own elevation", path)
    return ordered


# ---- ILC sites -------------------------------------------------------------------------------
# ILC gives no elevations. A storey of a shopping mall (the ILC sites) is typically 4.5-6 m;
# 5 m is stated here and written into the building YAML (``storey_height_m``) so a user can
# see and change it. Storeys come from the floor names: B<n> = -n, F<n> = n - 1 (F1 is the
# ground floor at 0 m), L<n> likewise, G = 0.
ILC_STOREY_HEIGHT_M = 5.0


def storey_of_floor_name(name: str) -> int | None:
    """Storey number from an ILC-style floor name (B2 -> -2, B1 -> -1, F1/L1/G -> 0, F2 -> 1), or None."""
    import re

    text = name.strip().upper()
    if text in ("G", "GF"):
        return 0
    match = re.fullmatch(r"([BFL])(\d+)", text) or re.fullmatch(r"(\d+)(F)", text)
    if match is None:
        return None
    letter, number = (match.group(1), int(match.group(2))) if match.group(1).isalpha() else (match.group(2),
                                                                                             int(match.group(1)))
    return -number if letter == "B" else number - 1


def is_ilc_site_dir(path: str | os.PathLike) -> bool:
    """True for a folder of ILC floor folders (each with floor_info.json) that is not a floor itself."""
    path = Path(path)
    return (path.is_dir() and not (path / "floor_info.json").is_file()
            and any((sub / "floor_info.json").is_file() for sub in path.iterdir() if sub.is_dir()))


def import_ilc_site(site_dir: str | os.PathLike, route: str = "geojson", resolution_m: float | None = None,
                    storey_height_m: float = ILC_STOREY_HEIGHT_M) -> Building:
    """Every floor folder of an ILC site as one building (floor maps not yet written).

    Each ILC floor has its own metre frame (origin at the lower-left corner of its GeoJSON
    outline). The floors are placed by their GeoJSON longitudes and latitudes, projected as
    ``prepare.read_geojson_floor`` does (Web Mercator scaled by the cosine of the mean
    latitude): the building frame is the frame of the ground floor (storey 0, else the lowest),
    so that floor's offset is (0, 0). Elevations: ``storey * storey_height_m`` from the names
    (:func:`storey_of_floor_name`). The floors are listed bottom to top.
    """
    from mapfilter.maps import prepare  # prepare imports this module's neighbours only; no cycle

    site_dir = Path(site_dir)
    if not is_ilc_site_dir(site_dir):
        raise MapfilterError("not an ILC site folder (no floor folders with floor_info.json inside)", site_dir)
    entries = []
    for sub in sorted(p for p in site_dir.iterdir() if (p / "floor_info.json").is_file()):
        storey = storey_of_floor_name(sub.name)
        if storey is None:
            raise MapfilterError(f"cannot tell the storey of floor folder {sub.name!r}: name floors B<n>, F<n>, "
                                 f"L<n> or G", sub)
        vector = prepare.read_geojson_floor(sub / "geojson_map.json", "lonlat")
        entries.append((storey, sub, vector.origin_lonlat))
    entries.sort(key=lambda e: e[0])
    storeys = [e[0] for e in entries]
    if len(set(storeys)) != len(storeys):
        raise MapfilterError("two floor folders name the same storey", site_dir)
    reference = next((e for e in entries if e[0] == 0), entries[0])
    lat_ref_rad = math.radians(reference[2][1])
    k = math.cos(lat_ref_rad)

    def mercator(lonlat: tuple[float, float]) -> np.ndarray:
        lon, lat = math.radians(lonlat[0]), math.radians(lonlat[1])
        return np.array([prepare.EARTH_RADIUS_M * lon * k,
                         prepare.EARTH_RADIUS_M * math.log(math.tan(math.pi / 4 + lat / 2)) * k])

    origin_ref = mercator(reference[2])
    floors = []
    for storey, sub, lonlat in entries:
        plan = prepare.import_ilc(sub, route, resolution_m)
        offset = mercator(lonlat) - origin_ref
        floors.append(Floor(sub.name, plan, storey * storey_height_m, (float(offset[0]), float(offset[1]))))
    building = Building(floors, [], site_dir.name, None, storey_height_m)
    building.validate()
    return building
