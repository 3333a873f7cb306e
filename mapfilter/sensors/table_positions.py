"""Where the rows of a table of placed things are (BLE beacons, ranging anchors): the position as
columns ``x,y`` (metres in the row's floor's frame) or ``latitude,longitude`` (placed by a
georeferenced building), and the row's floor. Every problem is one line naming the file (and
line)."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.io.tables import CsvTable
from mapfilter.maps.building import Building
from mapfilter.sensors.radiomap import map_extents_m, metres_outside

__all__ = ["PlacedTable", "PositionColumns", "placed_xy_m", "position_columns", "row_floor", "row_position"]


@dataclasses.dataclass(frozen=True)
class PositionColumns:
    """A table's two position columns: their keys in ``CsvTable.column``, their names in
    messages and ranges (``x, y`` or ``latitude, longitude``), and whether they are geographic."""

    keys: tuple[str, str]
    names: tuple[str, str]
    geographic: bool


def position_columns(table: CsvTable, building: Building | None, what: str, things: str,
                     latitude: Sequence[str] = ("latitude",), longitude: Sequence[str] = ("longitude",),
                     how: str = "") -> PositionColumns:
    """The position columns of ``table`` (``what``: "an anchor table"; its rows are ``things``):
    ``x,y``, else a latitude and a longitude column (by any of the names given), which need a
    georeferenced ``building`` (``how``: the message's hint to make one)."""
    column = table.column
    if "x" in column and "y" in column:
        return PositionColumns(("x", "y"), ("x", "y"), False)
    lat = next((c for c in latitude if c in column), None)
    lon = next((c for c in longitude if c in column), None)
    if lat is None or lon is None:
        raise MapfilterError(f"{what} needs the position as columns x,y (metres) or latitude,longitude", table.path, 1)
    if building is None or building.georeference is None:
        raise MapfilterError(f"the {things}' positions are latitude/longitude: they need a georeferenced "
                             f"building{how}", table.path, 1)
    return PositionColumns((lat, lon), ("latitude", "longitude"), True)


def row_position(table: CsvTable, fields: list[str], line_no: int, columns: PositionColumns,
                 ranges: Mapping[str, tuple[float, float]]) -> list[float]:
    """A row's two position values, each within its range (``ranges`` by column name)."""
    return [table.number(fields, key, line_no, *ranges[name], label=name)
            for key, name in zip(columns.keys, columns.names)]


def row_floor(table: CsvTable, fields: list[str], line_no: int, building: Building | None, thing: str,
              floor_name: Callable[[str], str] = str) -> str | None:
    """A row's floor (column ``floor`` as ``floor_name`` reads it), None where the table has no
    such column or the row leaves it empty; refused in a building with several floors when the
    row names none (each ``thing`` needs one) or one the building does not have."""
    text = fields[table.column["floor"]].strip() if "floor" in table.column else ""
    floor = floor_name(text) if text else None
    several = building is not None and not building.is_single_floor
    if floor is None and several:
        raise MapfilterError(f"no floor: a building with several floors needs each {thing}'s floor (column floor)",
                             table.path, line_no)
    if floor is not None and several and floor not in building.floor_names:
        raise MapfilterError(f"floor {floor!r} is not in the building (floors: {', '.join(building.floor_names)})",
                             table.path, line_no)
    return floor


def placed_xy_m(positions: list[list[float]], floors: list[str | None], columns: PositionColumns,
                building: Building | None, path: str | os.PathLike) -> np.ndarray:
    """(K, 2) the rows' positions in their floors' frames: latitude/longitude placed by the
    building's georeference (a row without a floor on the building's first floor)."""
    ab = np.array(positions, dtype=np.float64).reshape(-1, 2)
    if not columns.geographic:
        return ab
    return building.latlon_to_floor_xy(ab, [f if f is not None else building.floors[0].name for f in floors], path)


class PlacedTable:
    """What a table of placed things read by these functions shares (a mixin of its dataclass:
    ``ids``, ``xy_m``, ``floor``, ``source_path``, ``source_lines``; ``THING`` names a row)."""

    THING = "row"
    xy_m: np.ndarray
    floor: list[str | None]
    source_path: os.PathLike | None
    source_lines: list[int] | None

    @property
    def ids(self) -> list[str]:
        raise NotImplementedError

    def _line(self, i: int) -> int | None:
        return self.source_lines[i] if self.source_lines is not None else None

    def building_xy_m(self, building: Building) -> tuple[np.ndarray, np.ndarray]:
        """((K, 2) positions in the building frame, (K,) floor indices) of the rows in
        ``building`` (a one-floor building takes every row on its floor); ``MapfilterError``
        naming the table's line for a floor the building does not have, or a row without a
        floor in a building with several."""
        floors = np.zeros(len(self.floor), dtype=np.int64)
        out = np.empty_like(self.xy_m)
        for i, name in enumerate(self.floor):
            if not building.is_single_floor:
                if name is None:
                    raise MapfilterError(f"{self.THING} {self.ids[i]} has no floor: a building with several floors "
                                         "needs the floor column", self.source_path, self._line(i))
                if name not in building.floor_names:
                    raise MapfilterError(f"{self.THING} {self.ids[i]} is on floor {name!r}, which the building "
                                         f"does not have (floors: {', '.join(building.floor_names)})",
                                         self.source_path, self._line(i))
                floors[i] = building.floor_names.index(name)
            out[i] = building.floors[floors[i]].to_building(self.xy_m[i])
        return out, floors

    def check_within(self, building: Building, max_off_m: float, map_path: str | os.PathLike | None = None) -> None:
        """Refuse a table that cannot belong to ``building``: a row on a floor it does not have, or
        more than ``max_off_m`` outside its floor's map (a table in another frame)."""
        _, floors = self.building_xy_m(building)
        for i in range(len(self.floor)):
            extents = map_extents_m(building.floors[int(floors[i])].plan)
            off_m = min(float(metres_outside(self.xy_m[i:i + 1], e)[0]) for e in extents)
            if off_m > max_off_m:
                x, y = self.xy_m[i]
                on = f" {map_path}" if map_path is not None else ""
                raise MapfilterError(f"{self.THING} {self.ids[i]} at ({x:.6g}, {y:.6g}) m lies {off_m:.0f} m outside "
                                     f"the map{on} (at most {max_off_m:g} m): is the table in the map's frame?",
                                     self.source_path, self._line(i))
