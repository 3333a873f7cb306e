"""Ranges to known anchors (UWB, WiFi RTT) as a measurement source: its registration, config
section and stream adapter.

The anchor table and the range log are ``sensors.anchors``; the likelihood is
``filter.models.ranges``. Written against the registry alone (docs/models.md walks through it).

Measurements. The ranges stamped at one time (a tag's ranging round) are one measurement, at
that time: it depends on nothing later, and a range weighs the particles where they are when it
was measured (a window of ranges, as BLE's readings are grouped, would lag a walker by half a
window). The range log is a table beside the log (``filter.measurement.TimedTableSource``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from mapfilter.errors import MapfilterError
from mapfilter.filter.measurement import TimedTableSource
from mapfilter.filter.sources import SourceOption, SourcePlugin


@dataclasses.dataclass(frozen=True)
class RangesConfig:
    """Ranges to known anchors: how they weigh the particles."""

    # UWB ranges scatter by 0.1-0.3 m in line of sight, more through walls and bodies
    range_sigma_m: float = 0.3  # spread of a measured range around the true 3-D distance

    def __post_init__(self) -> None:
        if not (math.isfinite(self.range_sigma_m) and self.range_sigma_m > 0):
            raise MapfilterError(f"ranges range_sigma_m must be a positive number of metres, got {self.range_sigma_m}")


@dataclasses.dataclass(frozen=True)
class Ranges:
    """The ``ranges`` source's input: the anchors and the ranges measured to them."""

    table: Any  # sensors.anchors.AnchorTable
    log: Any  # sensors.anchors.RangeLog


class RangesPlugin(SourcePlugin):
    """Ranges to known anchors: an anchor table and a range log are the input."""

    name = "ranges"
    title = "ranges to anchors"
    options = (SourceOption("--anchors", "ANCHORS.csv", "anchor table (anchor_id,x,y[,floor][,height]) for --ranges"),
               SourceOption("--ranges", "RANGES.csv", "ranges to the anchors (t_s,anchor_id,range_m on the log's "
                                                      "clock: UWB, WiFi RTT): weighed too, or alone without WiFi"))
    config = RangesConfig
    counts = "range sets"
    help = ("Ranges to anchors (UWB, WiFi RTT): --anchors ANCHORS.csv --ranges RANGES.csv weighs the ranges "
            "measured to known anchors too (config section sources.ranges), or alone without WiFi; the range log "
            "is t_s,anchor_id,range_m rows on the log's clock, and each walk takes the ranges of its own time "
            "span (docs/formats.md).")

    def load(self, files: Mapping[str, Path], building) -> Ranges:
        from mapfilter.sensors.anchors import AnchorTable, read_ranges

        table = AnchorTable.read_csv(files["anchors"], building)
        table.check_on(building, building.path)
        return Ranges(table, read_ranges(files["ranges"], table))

    def check(self, given: Any) -> Ranges:
        if not isinstance(given, Ranges):
            raise TypeError(f"sources['ranges']: expected filter.sources.ranges.Ranges(table, log) or the files "
                            f"{{'anchors': ..., 'ranges': ...}}, got {type(given).__name__}")
        return given

    def source(self, given: Ranges, frame, config: RangesConfig) -> RangeSource:
        return RangeSource(given, frame, config)

    def example(self, log: Path, building, folder: Path, rng) -> tuple[dict[str, Path], Path]:
        """An anchor 1.5 m above the phone in each corner of the first floor's free space, each
        ranged twice a second with 0.1 m of noise along the walk's waypoints."""
        import numpy as np

        from mapfilter.sensors.anchors import AnchorTable, simulate_ranges
        from mapfilter.sensors.logs import read_log

        plan = building.floors[0].plan
        free = plan.sample_free(20_000, rng)
        low, high = np.percentile(free, 2, axis=0), np.percentile(free, 98, axis=0)
        corners = [(low[0], low[1]), (high[0], low[1]), (low[0], high[1]), (high[0], high[1])]
        floor = "" if building.is_single_floor else building.floor_names[0]
        anchors = folder / "anchors.csv"
        anchors.write_text("anchor_id,x,y,floor,height\n" + "".join(
            f"A{i},{x:.2f},{y:.2f},{floor},1.5\n" for i, (x, y) in enumerate(corners)))
        table = AnchorTable.read_csv(anchors, building)
        walk = read_log(log)
        simulate_ranges(table, building, walk.waypoint_t_s, walk.waypoint_xy_m, 0, rng).write_csv(
            folder / "ranges.csv", table)
        return {"anchors": anchors, "ranges": folder / "ranges.csv"}, log


class RangeSource(TimedTableSource):
    """The ranges of a range log as measurements (module docstring)."""

    stream = "ranges"

    def __init__(self, ranges: Ranges, frame, config: RangesConfig) -> None:
        super().__init__(ranges.log)
        self.ranges, self.config = ranges, config
        self.model = self.model_on(frame)

    def model_on(self, frame):
        from mapfilter.filter.models.ranges import RangeLikelihood

        return RangeLikelihood(self.ranges.table, frame, self.config.range_sigma_m)

    def from_rows(self, t_s: float, rows: dict[str, Any]):
        from mapfilter.filter.models.ranges import RangeSet

        return RangeSet(t_s, rows["anchor_id"], rows["range_m"])


SOURCE = RangesPlugin()
