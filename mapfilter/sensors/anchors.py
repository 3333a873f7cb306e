"""Ranges to known anchors (UWB, WiFi RTT): the anchor table and the range log.

An ``AnchorTable`` holds each anchor's id, position (in its floor's frame, or latitude and
longitude placed by a georeferenced building), floor and height above the phone. A
``RangeLog`` holds the measured ranges, ``t_s,anchor_id,range_m`` rows on the walk's own clock
(the log's: Unix seconds in an ILC trace, the AppTimestamp in a GetSensorData log): what a UWB
tag or an Android ``WifiRttManager`` app writes beside the phone's log. Both are CSV files with
a header (docs/formats.md); every problem is one line naming the file and line.
``simulate_ranges`` draws the ranges a walk would have measured (the tests, docs/models.md).
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.io.atomic import write_csv_atomically
from mapfilter.io.tables import Column, TimedTable, read_csv_table, read_timed_table
from mapfilter.maps.building import Building
from mapfilter.sensors.table_positions import PlacedTable, placed_xy_m, position_columns, row_floor, row_position

__all__ = ["AnchorTable", "RangeLog", "read_ranges", "simulate_ranges"]

# what a row's columns can be (a row outside is refused, naming its line)
COLUMN_RANGES = {"x": (-1e7, 1e7), "y": (-1e7, 1e7), "latitude": (-90.0, 90.0), "longitude": (-180.0, 180.0),
                 "height": (-100.0, 100.0), "range_m": (0.0, 1000.0)}
# UWB reaches 50-100 m indoors: an anchor further off its floor's map belongs to another frame
MAX_ANCHOR_OFF_MAP_M = 100.0


@dataclasses.dataclass
class AnchorTable(PlacedTable):
    """Anchors with positions (arrays of length K)."""

    anchor_id: list[str]  # as the range log names them (trimmed)
    xy_m: np.ndarray  # (K, 2) in the frame of the anchor's floor
    floor: list[str | None]  # the floor each is on (None: the one floor of a single map)
    height_m: np.ndarray  # (K,) height above the phone (an anchor on the ceiling: about 1.5 m)
    source_path: Path | None = None  # the CSV it was read from (for messages), or None
    source_lines: list[int] | None = None  # the CSV line of each row, or None

    COLUMNS = ("anchor_id", "x", "y", "floor", "height")
    THING = "anchor"

    def __len__(self) -> int:
        return len(self.anchor_id)

    @property
    def index(self) -> dict[str, int]:
        """Row of each anchor id."""
        return {key: i for i, key in enumerate(self.anchor_id)}

    @property
    def ids(self) -> list[str]:
        return self.anchor_id

    @classmethod
    def read_csv(cls, path: str | os.PathLike, building: Building | None = None) -> AnchorTable:
        """Read an anchor table: ``anchor_id``, the position as ``x,y`` (metres in its floor's
        frame) or ``latitude,longitude`` (placed by ``building``'s georeference), optional
        ``floor`` (needed in a building with several floors) and ``height`` (m above the phone,
        default 0)."""
        table = read_csv_table(path, "the anchor table")
        if "anchor_id" not in table.column:
            raise MapfilterError("an anchor table needs an anchor_id column (the id the range log names it by)",
                                 table.path, 1)
        position = position_columns(table, building, "an anchor table", "anchors")
        ids, ab, floors, heights, lines, first = [], [], [], [], [], {}
        for line_no, fields in table.rows:
            name = fields[table.column["anchor_id"]].strip()
            if not name:
                raise MapfilterError("empty anchor id", table.path, line_no)
            if name in first:
                raise MapfilterError(f"anchor {name} is listed twice (lines {first[name]} and {line_no}): keep one",
                                     table.path, line_no)
            first[name] = line_no
            ab.append(row_position(table, fields, line_no, position, COLUMN_RANGES))
            text = fields[table.column["height"]].strip() if "height" in table.column else ""
            heights.append(table.number(fields, "height", line_no, *COLUMN_RANGES["height"]) if text else 0.0)
            floors.append(row_floor(table, fields, line_no, building, "anchor"))
            ids.append(name)
            lines.append(line_no)
        xy = placed_xy_m(ab, floors, position, building, table.path)
        return cls(ids, xy, floors, np.array(heights), table.path, lines)

    def write_csv(self, path: str | os.PathLike) -> None:
        """The table as CSV (``COLUMNS``), written atomically."""
        write_csv_atomically(path, self.COLUMNS, (
            [self.anchor_id[i], f"{self.xy_m[i, 0]:.3f}", f"{self.xy_m[i, 1]:.3f}",
             "" if self.floor[i] is None else self.floor[i], f"{self.height_m[i]:.2f}"] for i in range(len(self))))

    def check_on(self, building: Building, map_path: str | os.PathLike | None = None) -> None:
        """Refuse a table that cannot belong to ``building``: an anchor on a floor it does not
        have, or more than ``MAX_ANCHOR_OFF_MAP_M`` outside its floor's map."""
        self.check_within(building, MAX_ANCHOR_OFF_MAP_M, map_path)


@dataclasses.dataclass(frozen=True)
class RangeLog(TimedTable):
    """Measured ranges, in time order: ``t_s`` (R,) on the walk's clock and the columns
    ``anchor_id`` (each range's anchor, a row of the table) and ``range_m``."""

    @property
    def anchor(self) -> np.ndarray:
        """(R,) the row of each range's anchor in the table."""
        return self.columns["anchor_id"]

    @property
    def range_m(self) -> np.ndarray:
        """(R,) the measured ranges."""
        return self.columns["range_m"]

    def write_csv(self, path: str | os.PathLike, table: AnchorTable) -> None:
        """The log as CSV ``t_s,anchor_id,range_m``, written atomically."""
        write_csv_atomically(path, ("t_s", "anchor_id", "range_m"), (
            [f"{self.t_s[i]:.3f}", table.anchor_id[int(self.anchor[i])], f"{self.range_m[i]:.3f}"]
            for i in range(len(self))))


def read_ranges(path: str | os.PathLike, table: AnchorTable) -> RangeLog:
    """A range log: ``t_s,anchor_id,range_m`` (seconds on the walk's clock, an anchor of
    ``table``, metres), in any order (sorted by time, stably)."""
    log = read_timed_table(path, "the range log", (
        Column("anchor_id", names=table.index, names_in=f"the anchor table {table.source_path or ''}",
               called="anchor"),
        Column("range_m", *COLUMN_RANGES["range_m"])))
    return RangeLog(log.t_s, log.columns, log.path, log.lines)


def simulate_ranges(table: AnchorTable, building: Building, t_s: np.ndarray, xy_m: np.ndarray,
                    floor: np.ndarray | int, rng: np.random.Generator, *, rate_hz: float = 2.0,
                    sigma_m: float = 0.1, max_range_m: float = 30.0) -> RangeLog:
    """The ranges a walk at ``xy_m`` (floor frames; ``floor``: building floor index per point, or
    one) at times ``t_s`` would have measured: each anchor ranged ``rate_hz`` times a second at
    random times within the walk, the true 3-D distance (the anchor's height, the floors'
    elevations) plus Gaussian noise ``sigma_m``, anchors beyond ``max_range_m`` unheard."""
    t_s, xy_m = np.asarray(t_s, dtype=np.float64), np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
    floor = np.broadcast_to(np.asarray(floor, dtype=np.int64), t_s.shape)
    anchor_xy, anchor_floor = table.building_xy_m(building)
    elevation = np.array([f.elevation_m for f in building.floors])
    parts = []
    for k in range(len(table)):
        n = rng.poisson(rate_hz * (t_s[-1] - t_s[0]))
        when = np.sort(rng.uniform(t_s[0], t_s[-1], n))
        i = np.clip(np.searchsorted(t_s, when), 1, t_s.size - 1)
        a = ((when - t_s[i - 1]) / np.maximum(t_s[i] - t_s[i - 1], 1e-9))[:, None]
        local = xy_m[i - 1] + a * (xy_m[i] - xy_m[i - 1])
        on = floor[i - 1]
        walker = np.array([building.floors[int(f)].to_building(p) for f, p in zip(on, local)]).reshape(-1, 2)
        dz = table.height_m[k] + elevation[anchor_floor[k]] - elevation[on]
        d = np.sqrt(np.sum((walker - anchor_xy[k]) ** 2, axis=1) + dz ** 2)
        measured = np.maximum(d + sigma_m * rng.standard_normal(d.size), 0.0)
        heard = d <= max_range_m
        parts.append((when[heard], np.full(int(heard.sum()), k), measured[heard]))
    t = np.concatenate([p[0] for p in parts])
    order = np.argsort(t, kind="stable")
    return RangeLog(t[order], {"anchor_id": np.concatenate([p[1] for p in parts]).astype(np.int64)[order],
                               "range_m": np.concatenate([p[2] for p in parts])[order]})
