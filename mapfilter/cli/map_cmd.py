"""``mapfilter map prepare|import-ilc|import-ipin``: floor plans -> wall-mask maps (YAML + mask + preview)."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from mapfilter.cli.common import bounded_float, bounded_int, check_output_path, input_paths, warn
from mapfilter.errors import MapfilterError, not_a_file
from mapfilter.io.outputs import check_output_files

# option values, finite and within what a floor plan can use
_PIXELS = bounded_int(0, 1000)  # a morphology radius or kernel: wall gaps and outlines are a few pixels
_AREA = bounded_int(0, 10**9)  # a blob's size in pixels
_METRES_PER_PIXEL = bounded_float(0.001, 10.0)  # as a map YAML's resolution (maps.floorplan)
_METRES = bounded_float(0.0, 1e5, low_open=True)
_STOREY = bounded_float(0.0, 100.0, low_open=True)

_PREPARE_EPILOG = """\
kinds (chosen from the image unless given: a filled-region plan's filled areas are metres
across, a drawing's walls and lines are not; .json/.geojson files are GeoJSON):
  lines    a drawing, dark walls on light paper (scans, CAD exports, real-estate plans): the
           paper evened (grey, yellowed, unevenly lit), ink darker than --threshold, strokes
           thinner than a wall dropped (text, furniture, door arcs, dimension, axis and hatch
           lines), double-line and hatched walls filled, door leaves removed, the building's
           outline found with its windows and entrances closed; outside it is wall
  regions  filled-region plans (e.g. ILC floor_image.png): --walkable colours are free (default:
           transparent, or the paper), everything else wall; small blobs in free space dropped,
           the outlines drawn round filled regions opened by their own width; outside is wall
  geojson  vector floor: first 'floor' feature (else the first) = outline, the other
           polygons = obstacles; outside the outline is wall (--resolution = output m/px,
           default 0.1)

The report: what the reader did, the free share, how much of the free space is one connected
region, and the rooms cut off from it (their pixel box in the mask). Warnings (one line each;
the map is written all the same): almost no free space, almost no walls, free space reaching
the map's edge, small wall blobs in free space, rooms cut off, and with --check-logs LOG...
the waypoints of those logs that fall in walls (a wrong scale, a plan of another floor).
A plan that comes out with no free space at all is refused.

scale (give one or more; they must agree within 2 %):
  --resolution M                 metres per plan pixel
  --size W H                     real width and height of the whole plan in metres
  --scale-points U1 V1 U2 V2 --scale-distance M
                                 two image points (column, row) and their real distance

edits file (metres, world frame: x right, y up, origin at the plan's lower-left corner):
  free:                          # forced free, e.g. doors drawn closed
    - [[10.0, 5.0], [11.0, 5.0], [11.0, 5.3], [10.0, 5.3]]
  wall:                          # forced wall (applied after 'free')
    - [[0, 0], [2, 0], [2, 2], [0, 2]]
  or GeoJSON in metres whose features have properties {"set": "free"|"wall"}.

writes NAME.yaml (ROS map_server), NAME.png (mask: 0 = wall, 254 = free) and
NAME_preview.png (walls in red over the plan, what was taken for the outside shaded grey, rooms
cut off in orange boxes); nothing is written on error. The report says what share of the
drawing was taken for the outside; --outside none keeps all of it walkable.

examples:
  mapfilter map prepare plan.jpg --resolution 0.02 --out floor.yaml
  mapfilter map prepare ../shared/data/ilc20/site1/F1/floor_image.png --size 239.8 176.4 --out F1.yaml
"""

_IMPORT_EPILOG = """\
FLOOR_DIR holds floor_image.png, floor_info.json ({"map_info": {"width": .., "height": ..}})
and geojson_map.json (ILC 2.0 layout). Both routes use the ILC metre frame (origin at the
floor's lower-left corner) and record floor_image.png for display under the mask.
  geojson  outline minus shops (shrunk by 0.6 m) rasterised at --resolution (default 0.25 m);
           outside the building is wall (the default)
  image    transparent pixels walkable, shop outlines opened by 2 px, scale from floor_info.json;
           outside the outline of geojson_map.json is wall as on the other route
The floor is named by its logs' headers (FloorName in path_data_files), else by the folder.

A SITE_DIR (a folder of floor folders, e.g. site1 with B1, F1, ..., F4) becomes one building:
every floor is imported and written beside
--out as NAME_<floor>.yaml (+ mask and preview), and --out is the building YAML that lists
them, placed in one frame by the GeoJSON longitudes/latitudes (the ground floor's frame;
docs/building.md). ILC gives no elevations: storeys come from the names (B1 = -1, F1 = 0,
F2 = 1, ...) times --storey-height (default 5 m).

--check-logs LOG... says in one line how many waypoints of those logs lie on the map's free
space, and warns about each log with waypoints in walls (a log of another floor, a wrong frame).

example:
  mapfilter map import-ilc ../shared/data/ilc20/site1/F1 --out F1.yaml --check-logs walk.txt.gz
  mapfilter map import-ilc ../shared/data/ilc20/site1 --out site1.yaml
"""


_IPIN_EPILOG = """\
CAL is an IPIN competition calibration file: for each floor its plan image (looked for next
to CAL), floor number, building, the image centre's latitude and longitude, the rotation of
the image to north (degrees) and the scale (m/px). The building it writes (--out, with
NAME_<floor>.yaml maps, masks, previews and NAME_<floor>_plan.png, the plan turned to north)
is georeferenced: its frame is east/north metres at the first floor's image centre, so logs
with latitude/longitude ground truth (GetSensorData POSI rows) and tracks in latitude and
longitude work with it. Each plan is decoded reduced (a 54-megapixel plan takes about 100 MB),
its dark strokes become walls (labels shorter than 1.5 m dropped), and the map is walled
beyond the image's edges. A floor whose image is missing becomes an open floor over the
same extent, with a warning. Floors are named by the venue's floor numbers (0, -1, -2) and
stand --storey-height apart (the calibration gives no heights; docs/formats.md shows how the
IPIN 2023 venue's was measured from a walk's barometer).

example:
  mapfilter map import-ipin ../shared/data/ipin2023/plans/calib_mapa_Nuremberg.cal \\
      --out nuremberg.yaml --storey-height 2.8
"""


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("map", help="prepare wall-mask maps from floor plans",
                                   description="Prepare wall-mask maps from floor plans.")
    commands = parser.add_subparsers(dest="map_command", metavar="SUBCOMMAND")
    parser.set_defaults(func=lambda args: _missing_subcommand(parser))

    prepare_parser = commands.add_parser(
        "prepare", help="a floor plan (line drawing, filled regions or GeoJSON) -> map YAML + mask",
        description="Turn a floor plan into a wall mask (ROS map_server YAML + PNG) and a preview.",
        epilog=_PREPARE_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    prepare_parser.add_argument("plan", type=Path, metavar="PLAN", help="plan image (PNG, JPEG, PGM, ...) or GeoJSON file")
    prepare_parser.add_argument("--out", type=Path, required=True, metavar="NAME.yaml", help="output map YAML")
    prepare_parser.add_argument("--kind", choices=("lines", "regions", "geojson"), default=None,
                                help="kind of plan (default: geojson for .json/.geojson, else chosen from the image)")
    scale = prepare_parser.add_argument_group("scale")
    scale.add_argument("--resolution", type=_METRES_PER_PIXEL, metavar="M", help="metres per plan pixel (geojson: per output pixel, default 0.1)")
    scale.add_argument("--size", type=_METRES, nargs=2, metavar=("W", "H"), help="real width and height of the plan in metres")
    scale.add_argument("--scale-points", type=bounded_float(-1e6, 1e6), nargs=4, metavar=("U1", "V1", "U2", "V2"),
                       help="two image points (column, row) ...")
    scale.add_argument("--scale-distance", type=_METRES, metavar="M", help="... and their real distance in metres")
    scale.add_argument("--map-resolution", type=_METRES_PER_PIXEL, metavar="M",
                       help="metres per pixel of the output mask (default: the plan's own; coarser keeps walls closed)")
    lines = prepare_parser.add_argument_group("drawings (--kind lines)")
    lines.add_argument("--threshold", type=_threshold, default="auto", metavar="auto|adaptive|N",
                       help="ink: darker than Otsu's level of the evened paper (auto), than the neighbourhood "
                            "(adaptive), or than grey level N (1-254, paper = 255) (default: auto)")
    lines.add_argument("--thin-lines", type=_PIXELS, default=None, metavar="PX",
                       help="strokes up to PX plan pixels wide are annotation, not walls (0: every stroke is a wall; "
                            "default: 4 cm at the plan's scale)")
    lines.add_argument("--outline-gap", type=bounded_float(0.0, 50.0, low_open=True), default=3.0, metavar="M",
                       help="openings in the outer wall (entrances, windows) up to M metres are closed when the "
                            "building's outline is found (default: 3)")
    lines.add_argument("--close-gaps", type=_PIXELS, default=0, metavar="PX",
                       help="close breaks in the ink narrower than PX plan pixels first (scans; default: 0)")
    lines.add_argument("--remove-text", type=_AREA, default=None, metavar="PX",
                       help="drop wall blobs whose bounding box is shorter than PX (default: under 1 m and not a "
                            "solid column)")
    lines.add_argument("--thicken", type=_PIXELS, default=0, metavar="PX", help="dilate walls by PX pixels (default: 0)")
    prepare_parser.add_argument("--outside", choices=("auto", "none"), default="auto",
                                help="lines and regions: auto finds the building's outline and walls what lies "
                                     "outside it (shaded in the preview); none keeps everything on the sheet "
                                     "walkable (default: auto)")
    # the option's old spelling, for saved workflows: the same as --outside none
    prepare_parser.add_argument("--keep-outside", dest="outside", action="store_const", const="none",
                                help=argparse.SUPPRESS)
    regions = prepare_parser.add_argument_group("filled-region plans (--kind regions)")
    regions.add_argument("--walkable", action="append", metavar="COLOUR",
                         help="a walkable colour: transparent, #rrggbb or r,g,b; repeat for more "
                              "(default: transparent, or the paper of an opaque plan)")
    regions.add_argument("--tolerance", type=bounded_int(0, 255), default=24, metavar="N",
                         help="max per-channel difference to a walkable colour (default: 24)")
    regions.add_argument("--open-outlines", type=_PIXELS, default=None, metavar="PX",
                         help="erode walls by PX pixels along free space (default: the drawn outlines' own width)")
    regions.add_argument("--remove-below", type=_AREA, default=None, metavar="PX",
                         help="wall blobs of fewer than PX pixels become free (default: blobs under 0.5 m2)")
    regions.add_argument("--outside-wall", action="store_true", help=argparse.SUPPRESS)  # now the default
    vector = prepare_parser.add_argument_group("GeoJSON floors (--kind geojson)")
    vector.add_argument("--units", choices=("lonlat", "m"), default="lonlat",
                        help="coordinates: lon/lat (Web Mercator, ILC convention) or metres (default: lonlat)")
    vector.add_argument("--inset", type=bounded_float(0.0, 100.0), default=0.0, metavar="M",
                        help="shrink obstacle polygons by M metres (default: 0)")
    prepare_parser.add_argument("--edits", type=Path, metavar="FILE", help="YAML/GeoJSON polygons forced free or wall (see below)")
    prepare_parser.add_argument("--floor", metavar="NAME", help="floor name stored in the YAML")
    prepare_parser.add_argument("--access-points", type=Path, metavar="CSV",
                                help="access-point table (bssid,x,y,band,C,n,alpha,d_max) referenced from the YAML")
    prepare_parser.add_argument("--check-logs", type=Path, nargs="+", default=[], metavar="LOG",
                                help="warn about waypoints of these logs (with waypoints in the map's metres) that "
                                     "fall in walls")
    prepare_parser.set_defaults(func=run_prepare)

    ilc = commands.add_parser(
        "import-ilc", help="an ILC 2.0 floor directory -> map YAML + mask in one step",
        description="Make a map of an ILC (Indoor Location Competition 2.0) floor directory.",
        epilog=_IMPORT_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    ilc.add_argument("floor_dir", type=Path, metavar="FLOOR_DIR|SITE_DIR",
                     help="e.g. ../shared/data/ilc20/site1/F1, or site1 for every floor as one building")
    ilc.add_argument("--out", type=Path, required=True, metavar="NAME.yaml", help="output map YAML")
    ilc.add_argument("--route", choices=("image", "geojson"), default="geojson",
                     help="from the GeoJSON polygons (the floor's outline minus its shops) or the floor image "
                          "(transparent pixels walkable); either way outside the floor's outline is wall (default: "
                          "geojson)")
    ilc.add_argument("--resolution", type=_METRES_PER_PIXEL, metavar="M",
                     help="metres per output pixel (default: the image's ~0.3 m, or 0.25 m for geojson)")
    ilc.add_argument("--edits", type=Path, metavar="FILE", help="YAML/GeoJSON polygons forced free or wall")
    ilc.add_argument("--storey-height", type=_STOREY, default=5.0, metavar="M",
                     help="a site: metres between storeys for the elevations (default: 5)")
    ilc.add_argument("--check-logs", type=Path, nargs="+", default=[], metavar="LOG",
                     help="say how many waypoints of these logs lie on free space, and warn about those in walls")
    ilc.set_defaults(func=run_import_ilc)

    ipin = commands.add_parser(
        "import-ipin", help="an IPIN calibration file and its plans -> a georeferenced building",
        description="Make a georeferenced building of an IPIN venue's calibration file (.cal) and plan images.",
        epilog=_IPIN_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    ipin.add_argument("cal", type=Path, metavar="CAL", help="the calibration file, e.g. calib_mapa_Nuremberg.cal")
    ipin.add_argument("--out", type=Path, required=True, metavar="NAME.yaml", help="output building YAML")
    ipin.add_argument("--resolution", type=_METRES_PER_PIXEL, default=None, metavar="M",
                      help="metres per map cell (default: 0.1)")
    ipin.add_argument("--storey-height", type=_STOREY, default=None, metavar="M",
                      help="metres between storeys for the elevations (default: 4)")
    ipin.set_defaults(func=run_import_ipin)


def _missing_subcommand(parser: argparse.ArgumentParser) -> int:
    parser.print_help()
    return 2


def _threshold(text: str):
    """argparse type of --threshold: auto (otsu is the same), adaptive, or a grey level 1-254."""
    if text in ("auto", "otsu"):
        return "auto"
    if text == "adaptive":
        return text
    try:
        level = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be auto, adaptive or a grey level 1-254, got {text!r}") from None
    if not 1 <= level <= 254:
        raise argparse.ArgumentTypeError(f"a grey level must be 1-254, got {text}")
    return level


def run_prepare(args: argparse.Namespace) -> int:
    from mapfilter.maps import prepare, walkable
    from mapfilter.maps.drawing import DrawingOptions
    from mapfilter.sensors.logs import log_format

    _check_map_outputs(args.out, input_paths(args.plan, args.edits, args.access_points, args.check_logs))
    kind = args.kind or ("geojson" if args.plan.suffix.lower() in (".json", ".geojson") else None)
    edits = prepare.read_edits(args.edits) if args.edits else None
    if args.access_points is not None and not args.access_points.is_file():
        raise not_a_file(args.access_points)
    for path in args.check_logs:
        log_format(path)  # a missing or unreadable log is refused before the work
    notes = []
    if kind == "geojson":
        if args.size or args.scale_points or args.scale_distance:
            raise MapfilterError("a GeoJSON floor is already in real units: give only --resolution (m per pixel)",
                                 args.plan)
        if args.outside == "none":
            raise MapfilterError("--outside none is for image plans: outside a GeoJSON floor's outline is wall")
        plan = prepare.prepare_geojson(args.plan, args.resolution or args.map_resolution, args.units, args.inset,
                                       0.0, args.floor)
        outside_mask = None  # the floor's outline walls the outside
    else:
        points = None
        if args.scale_points is not None:
            u1, v1, u2, v2 = args.scale_points
            points = ((u1, v1), (u2, v2))
        scale = prepare.PlanScale(args.resolution, tuple(args.size) if args.size else None, points,
                                  args.scale_distance)
        drawing = DrawingOptions(args.threshold, close_gaps_px=args.close_gaps, thin_lines_px=args.thin_lines,
                                 remove_text_px=args.remove_text, outline_gap_m=args.outline_gap,
                                 thicken_px=args.thicken, outside_is_wall=args.outside == "auto")
        regions = prepare.RegionOptions(tuple(args.walkable or ()), args.tolerance, remove_below_px=args.remove_below,
                                        open_outlines_px=args.open_outlines, outside_is_wall=args.outside == "auto")
        prepared = prepare.prepare_plan(args.plan, scale, kind, drawing, regions, args.map_resolution, args.floor)
        plan, kind, notes, outside_mask = prepared.plan, prepared.kind, prepared.notes, prepared.outside
        notes.append(f"{outside_mask.mean():.0%} of the drawing taken for the outside of the building and walled "
                     "(shaded in the preview; --outside none keeps it walkable)" if outside_mask is not None else
                     "nothing taken for the outside (--outside none): all the sheet's free space is walkable")
    if edits is not None:
        plan = prepare.apply_edits(plan, edits)
    if args.access_points is not None:
        plan.access_points_csv = args.access_points.resolve()
    outside = ("you gave --outside none" if args.outside == "none" else
               "an opening in the outer wall wider than --outline-gap let it in, or an edit freed it: close it with "
               "--edits")
    hints = {"lines": (outside, "--remove-text PX drops wall blobs shorter than PX plan pixels"),
             "regions": (outside, "--remove-below PX frees wall blobs of fewer than PX plan pixels"),
             "geojson": (None, None)}[kind]
    found = [f"{args.out}: {message}" for message in prepare.mask_warnings(plan, *hints)]
    walk = walkable.assess(plan.wall_mask, plan.resolution_m)
    cut_off = walkable.cut_off_message(walk, "open their doors with --edits (free polygons), or look at the preview")
    if cut_off:
        found.append(f"{args.out}: {cut_off}")
    in_walls, checked = _check_logs(plan, args.check_logs)
    found += in_walls
    _write(plan, args.out, outside_mask, walkable.cut_off_mask(plan.wall_mask, plan.resolution_m))
    for note in notes:
        print(f"  {note}")
    print(f"  {walkable.summary(walk)}")
    if checked is not None:
        print(f"  {checked}")
    for message in found:
        warn(message)
    return 0


def _check_logs(plan_or_building, log_paths: list[Path]) -> tuple[list[str], str | None]:
    """--check-logs: (a warning per log whose waypoints fall in walls, the check's summary line;
    None without logs)."""
    from mapfilter.cli.common import check_logs_on_map
    from mapfilter.maps.building import Building

    if not log_paths:
        return [], None
    building = plan_or_building if isinstance(plan_or_building, Building) else Building.from_plan(plan_or_building)
    return check_logs_on_map(building, log_paths)


def run_import_ilc(args: argparse.Namespace) -> int:
    from mapfilter.maps import prepare
    from mapfilter.maps.building import is_ilc_site_dir

    from mapfilter.sensors.logs import log_format

    inputs = input_paths(args.floor_dir, args.edits, args.check_logs)
    check_output_path(args.out, inputs=inputs)
    for path in args.check_logs:
        log_format(path)  # a missing or unreadable log is refused before the work
    if is_ilc_site_dir(args.floor_dir):
        return _import_ilc_site(args, inputs)
    _check_map_outputs(args.out, inputs)
    edits = prepare.read_edits(args.edits) if args.edits else None
    plan = prepare.import_ilc(args.floor_dir, args.route, args.resolution)
    named = _ilc_floor_name(args.floor_dir)
    if named is not None and named != plan.floor_name:
        plan = dataclasses.replace(plan, floor_name=named)
    if edits is not None:
        plan = prepare.apply_edits(plan, edits)
    found = [f"{args.out}: {message}"  # the outline walls the outside
             for message in prepare.mask_warnings(plan, None, "" if args.route == "image" else None)]
    in_walls, checked = _check_logs(plan, args.check_logs)
    _write(plan, args.out)
    if checked is not None:
        print(f"  {checked}")
    for message in found + in_walls:
        warn(message)
    return 0


def _ilc_floor_name(floor_dir: Path) -> str | None:
    """The floor name the floor's own logs give (their header's FloorName), if they agree on one:
    the map then accepts those logs and refuses another floor's."""
    from mapfilter.sensors.logs import read_log_header

    names = set()
    for path in sorted((floor_dir / "path_data_files").glob("*.txt*"))[:5]:
        try:
            names.add(read_log_header(path).get("FloorName") or None)
        except MapfilterError:
            continue
    names.discard(None)
    return names.pop() if len(names) == 1 else None


def _check_map_outputs(out: Path, inputs: list[Path]) -> None:
    """The three files a map is written as (NAME.yaml, NAME.png, NAME_preview.png), checked
    against the run's inputs before any work."""
    from mapfilter.maps.prepare import preview_path_for

    check_output_path(out, inputs=inputs)  # the path itself first: a directory, a parent that is a file
    if out.suffix not in (".yaml", ".yml"):
        raise MapfilterError("the output map must be a .yaml file", out)
    check_output_files([out, out.with_name(out.stem + ".png"), preview_path_for(out)], "--out", inputs)


def _import_ilc_site(args: argparse.Namespace, inputs: list[Path]) -> int:
    from mapfilter.maps import prepare
    from mapfilter.maps.building import import_ilc_site

    if args.edits is not None:
        raise MapfilterError("--edits names one floor's polygons: import that floor alone, or edit the floor maps "
                             "of the building afterwards", args.edits)
    if args.out.suffix not in (".yaml", ".yml"):
        raise MapfilterError("the output building must be a .yaml file", args.out)
    if not (args.storey_height > 0):
        raise MapfilterError(f"--storey-height must be positive, got {args.storey_height}")
    # everything is imported and checked before the first file is written
    building = import_ilc_site(args.floor_dir, args.route, args.resolution, args.storey_height)
    for floor in building.floors:
        floor.map_path = args.out.with_name(f"{args.out.stem}_{floor.name}.yaml").resolve()
        _check_map_outputs(floor.map_path, inputs)
        prepare.preview_image(floor.plan)  # fails here, before anything is written, if it fails at all
    in_walls, checked = _check_logs(building, args.check_logs)
    for floor in building.floors:
        _write(floor.plan, floor.map_path)
    building.save(args.out)
    print(f"wrote {args.out}: {len(building.floors)} floors ({', '.join(building.floor_names)}), "
          f"storey height {args.storey_height:g} m")
    if checked is not None:
        print(f"  {checked}")
    for message in in_walls:
        warn(message)
    return 0


def run_import_ipin(args: argparse.Namespace) -> int:
    import cv2

    from mapfilter.io.atomic import atomic_paths
    from mapfilter.maps import ipin_venue, prepare

    if args.out.suffix not in (".yaml", ".yml"):
        raise MapfilterError("the output building must be a .yaml file", args.out)
    inputs = input_paths(args.cal, args.cal.parent)  # the plans lie beside the calibration file
    check_output_path(args.out, inputs=inputs)
    resolution = ipin_venue.DEFAULT_RESOLUTION_M if args.resolution is None else args.resolution
    storey = ipin_venue.DEFAULT_STOREY_HEIGHT_M if args.storey_height is None else args.storey_height
    # everything is imported and checked before the first file is written
    building, floors = ipin_venue.import_ipin_venue(args.cal, resolution, storey, warn=warn)
    for floor in building.floors:
        map_path = args.out.with_name(f"{args.out.stem}_{floor.name}.yaml")
        _check_map_outputs(map_path, inputs)
        check_output_path(map_path.with_name(f"{map_path.stem}_plan.png"), inputs=inputs)
    for floor, venue_floor in zip(building.floors, floors):
        floor.map_path = args.out.with_name(f"{args.out.stem}_{floor.name}.yaml").resolve()
        if venue_floor.display is not None:
            shown = floor.map_path.with_name(f"{floor.map_path.stem}_plan.png")
            if venue_floor.image_path is not None and shown.resolve() == venue_floor.image_path.resolve():
                raise MapfilterError(f"writing the maps would overwrite the plan {shown.name}: choose another --out "
                                     "name", args.out)
            with atomic_paths(shown) as (tmp,):
                if not cv2.imwrite(str(tmp), venue_floor.display):
                    raise MapfilterError("could not write the plan image", shown)
            floor.plan = venue_floor.with_display_file(shown)
        _write(floor.plan, floor.map_path)
        if venue_floor.display is not None:  # a floor without its plan was reported as such
            for message in prepare.mask_warnings(floor.plan, None):  # walled beyond the image
                warn(f"{floor.map_path.name} (floor {floor.name}): {message}")
    building.save(args.out)
    geo = building.georeference
    print(f"wrote {args.out}: {len(building.floors)} floors ({', '.join(building.floor_names)}), storey height "
          f"{storey:g} m, georeferenced at {geo.origin_lat_deg:.8f}, {geo.origin_lon_deg:.8f}")
    return 0


def _write(plan, out: Path, outside=None, cut_off=None) -> None:
    from mapfilter.maps import prepare

    written = prepare.write_map(plan, out, outside=outside, cut_off=cut_off)
    rows, cols = plan.shape_px
    print(f"wrote {', '.join(str(p) for p in written)}: {cols}x{rows} px at {plan.resolution_m:.4g} m/px, "
          f"{plan.free_fraction:.1%} free")
