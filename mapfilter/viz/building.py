"""The floor layers of a building.

:class:`FloorLayer` (a tracking run): the current floor's plan, the share of particles per
floor, and floor changes in the event log. The filter works on the building's stack plan
(``filter.floors.FloorStack``: every floor in its own tile). This layer draws what a person
looks at: the plan of the floor the estimate is on (re-drawn whenever that floor changes), the
particles on that floor in its own frame, and a plot of how the weight is shared between the
floors.

:class:`FloorPlansLayer` (finished tracks, ``mapfilter view BUILDING.yaml``): every floor's plan
at once, each under its own root ``floors/<floor>`` (in the floor's own frame, with its own 2D
view), and the root each row of a track or each waypoint is drawn under, by its floor.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from mapfilter.viz.canvas import Canvas
from mapfilter.viz.map import MapLayer
from mapfilter.viz.style import BACKGROUND, entity_name

if TYPE_CHECKING:  # pragma: no cover
    from mapfilter.filter.events import StepReport
    from mapfilter.filter.models.building import FloorStack
    from mapfilter.maps.building import Building

# one colour per floor in the share plot (matplotlib's tab10)
_FLOOR_COLOURS = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
                  (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207)]


class FloorLayer:
    """Draws the current floor's map (``map/world/...``, at the time it becomes current),
    ``plots/floors/<name>`` and floor changes in ``events``; converts each step to the
    current floor's frame for the other layers."""

    def __init__(self, canvas: Canvas, stack: FloorStack) -> None:
        self.canvas = canvas
        self.stack = stack
        self.maps = [MapLayer(canvas, floor.plan) for floor in stack.building.floors]
        self.current: int | None = None

    def extent_m(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) covering every floor's map in its own frame."""
        extents = np.array([layer.extent_m() for layer in self.maps])
        return (float(extents[:, 0].min()), float(extents[:, 1].max()), float(extents[:, 2].min()),
                float(extents[:, 3].max()))

    def style(self) -> None:
        rr = self.canvas.rr
        for i, name in enumerate(self.stack.building.floor_names):
            self.canvas.log(f"plots/floors/{name}",
                            rr.SeriesLines(colors=[_FLOOR_COLOURS[i % len(_FLOOR_COLOURS)]], names=[name]),
                            static=True)

    def draw(self, report: StepReport) -> StepReport:
        """Log this step's floor share and any floor change; the report in the current floor's frame."""
        rr = self.canvas.rr
        names = self.stack.building.floor_names
        floor = report.floor_index if report.floor_index is not None else 0
        if floor != self.current:
            if self.current is not None:
                self.canvas.log("events", rr.TextLog(
                    f"step {report.step_index}: floor change {names[self.current]} -> {names[floor]}",
                    level=rr.TextLogLevel.WARN))
            self.maps[floor].draw(static=False)  # this floor's plan from now on
            self.current = floor
        if report.floor_shares is not None:
            for name, share in zip(names, report.floor_shares):
                self.canvas.log(f"plots/floors/{name}", rr.Scalars(float(share)))
        if report.floor_changes:
            self.canvas.log("events", rr.TextLog(
                f"step {report.step_index}: {report.floor_changes} particles changed floor",
                level=rr.TextLogLevel.DEBUG))
        return self.on_current_floor(report, floor)

    def on_current_floor(self, report: StepReport, floor: int) -> StepReport:
        """The step with positions in ``floor``'s frame and only that floor's particles."""
        stack = self.stack
        xy, on = stack.to_floor(report.particles_xy_m)
        keep = on == floor
        weight = np.asarray(report.particles_weight, dtype=np.float64)[keep]
        total = weight.sum()
        killed_from, killed_on = stack.to_floor(report.killed_from_xy_m.reshape(-1, 2))
        killed_to = np.asarray(report.killed_to_xy_m, dtype=np.float64).reshape(-1, 2) - stack.shift_m[killed_on]
        mine = killed_on == floor
        estimate = np.asarray(report.estimate_xy_m, dtype=np.float64) - stack.shift_m[floor]
        return dataclasses.replace(report, estimate_xy_m=estimate, particles_xy_m=xy[keep],
                                   particles_weight=weight / total if total > 0 else weight,
                                   killed_from_xy_m=killed_from[mine], killed_to_xy_m=killed_to[mine], fix_xy_m=None)


class FloorPlansLayer:
    """Every floor of a building, each under ``floors/<floor>/world/...`` in its own frame (static),
    with one 2D view per floor; ``on(floors)`` says under which root each row is drawn."""

    def __init__(self, canvas: Canvas, building: Building) -> None:
        self.canvas = canvas
        self.names = building.floor_names
        self.roots: dict[str, str] = {}
        for i, name in enumerate(self.names):
            root = f"floors/{entity_name(name)}"
            self.roots[name] = root if root not in self.roots.values() else f"{root}_{i}"  # "F 1" and "F_1"
        self.maps = [MapLayer(canvas, floor.plan, root=self.roots[floor.name]) for floor in building.floors]

    def draw(self) -> None:
        """Each floor's y-up flip (as ``map/world``'s, see ``viz``) and its plan, static."""
        for layer in self.maps:
            self.canvas.log(f"{layer.root}/world", self.canvas.rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
            layer.draw(static=True)

    def on(self, floors: list[str]) -> dict[str, np.ndarray]:
        """Root -> which rows are on that floor, for rows on the floors named by ``floors``."""
        floor = np.asarray(floors, dtype=object)
        return {self.roots[name]: floor == name for name in self.names}

    def views(self) -> list:
        """One 2D view per floor, bottom floor first, each framing its floor's plan."""
        import rerun.blueprint as rrb

        views = []
        for name, layer in zip(self.names, self.maps):
            x_min, x_max, y_min, y_max = layer.extent_m()
            views.append(rrb.Spatial2DView(
                name=f"Floor {name}", origin=layer.root,
                # view coordinates are (x, -y): see the viz package docstring
                visual_bounds=rrb.VisualBounds2D(x_range=[x_min, x_max], y_range=[-y_max, -y_min]),
                background=rrb.Background(color=BACKGROUND)))
        return views
