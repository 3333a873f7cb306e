"""Visual debugging with rerun: map, particles, wall kills, collapses, tracks and plots.

This is the only package of mapfilter that imports rerun, and it imports it lazily (inside the
logger), so ``import mapfilter.viz`` costs nothing when visualisation is off. The filter never
calls rerun: it returns a :class:`~mapfilter.filter.events.StepReport` per step and the caller
hands it to :meth:`RerunLogger.log_step`.

Coordinates
-----------
rerun's 2D views draw y pointing down (image convention); our world frame has y up. The map
view's origin is the entity ``map``; its child ``map/world`` carries one static
``Transform3D(scale=[1, -1, 1])`` and everything under ``map/world`` is logged in plain world
metres (x right, y up), so hovering a point in the viewer shows its true world coordinates.
Each image (the floor-plan picture, the wall mask) sits under its own parent entity whose
static transform maps pixel (u, v) (origin top-left, v down) to world metres:
``x = x0 + u * res``, ``y = y_top - v * res`` (translation ``(x0, y_top)``, scale
``(res, -res)``); composed with the flip above the image appears upright.

Timelines
---------
``trace_time``: the walk's own clock, a timestamp when the times look like Unix seconds
(>= 1e9, e.g. ILC traces), otherwise a duration (synthetic walks starting at 0); decided once,
by the first time seen. ``step``: the filter's step index (only on data logged by
:meth:`RerunLogger.log_step`). rerun's own ``log_time`` timeline (the wall clock at logging)
is switched off: it would only say how fast the filter ran, and its name is taken.

Entities (all under ``map/world`` are in world metres)
------------------------------------------------------
- ``map/world/floorplan/image`` source picture; ``map/world/walls/mask`` wall-mask overlay
  (semi-transparent; toggle its visibility in the viewer)
- ``map/world/ground_truth/{waypoints,path}`` (static), ``.../now`` (interpolated at each step)
- ``map/world/particles`` (weight-coloured, capped), ``map/world/killed`` (red old->new segments)
- ``map/world/estimate/{position,spread,error}``, ``map/world/estimate/trail/...``
- ``map/world/measurement/{fix,aps}``
- ``map/world/events/{collapses,recoveries,jumps}``
- ``map/world/tracks/<name>/{path,position}``
- ``plots/particles/{ess,alive,resampled}``, ``plots/kills``, ``plots/error_m/<name>``,
  ``plots/pdr/step_length_m``, ``plots/pdr/heading_deg/{filter,ground_truth}``
- ``events`` (text log: collapses and recoveries as WARN, resampling as DEBUG)

A building seen whole (``view_map`` with a building: finished tracks, no filter) draws no
``map``: each floor has its own root and 2D view, ``floors/<floor>/world/...`` with the same
children as ``map/world`` (``floorplan``, ``walls``, ``ground_truth``, ``tracks/<name>``), each
row of a track and each waypoint under the floor it is on (``viz.building.FloorPlansLayer``).
"""

from mapfilter.viz.recorder import NullLogger, RerunLogger, make_logger, view_map, viewer_problem
from mapfilter.viz.style import interpolate_ground_truth, weight_colours, weight_faithful_subsample

__all__ = ["NullLogger", "RerunLogger", "interpolate_ground_truth", "make_logger", "view_map", "viewer_problem",
           "weight_colours", "weight_faithful_subsample"]
