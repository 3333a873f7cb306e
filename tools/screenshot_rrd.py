"""Render an .rrd headless (no display) with the rerun viewer and save a PNG screenshot.

    python tools/screenshot_rrd.py RUN.rrd OUT.png [--timeline trace_time] [--fraction 1.0]

Needs a Vulkan driver; on a machine without a GPU, Mesa's software one (Debian:
``apt-get install -y mesa-vulkan-drivers``) with ``WGPU_BACKEND=vulkan`` (set here: the GL
backend fails headless). Uses rerun's experimental ``ViewerClient`` API (rerun-sdk 0.41): spawn
a headless viewer (1920x1080), open the file, pause the time cursor at ``--fraction`` of the
timeline's span (read from the file with ``rerun.chunk.RrdReader``), take a screenshot, quit;
the PNG is quantised to a 256-colour palette (``--palette 0`` keeps it as the viewer sent it).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from pathlib import Path


def timeline_range(rrd: Path, timeline: str) -> tuple[str, int, int] | None:
    """(kind, first, last) of a timeline in the file's recording, in its native integer unit
    (ns for timestamps and durations), or None when no chunk has that timeline."""
    import pyarrow as pa
    import pyarrow.compute as pc
    from rerun.chunk import RrdReader

    kind, lo, hi = None, None, None
    for chunk in RrdReader(rrd).stream().to_chunks():
        if timeline not in chunk.timeline_names:
            continue
        column = chunk.to_record_batch().column(timeline)
        if pa.types.is_timestamp(column.type):
            kind = "timestamp"
        elif pa.types.is_duration(column.type):
            kind = "duration"
        else:
            kind = "sequence"
        values = pc.cast(column, pa.int64())
        lo = pc.min(values).as_py() if lo is None else min(lo, pc.min(values).as_py())
        hi = pc.max(values).as_py() if hi is None else max(hi, pc.max(values).as_py())
    return None if kind is None else (kind, lo, hi)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n")[0])
    parser.add_argument("rrd", type=Path)
    parser.add_argument("png", type=Path)
    parser.add_argument("--timeline", default="trace_time", help="timeline to put the cursor on (default trace_time)")
    parser.add_argument("--fraction", type=float, default=1.0,
                        help="where to put the time cursor, as a fraction of the timeline's span (default 1 = end)")
    parser.add_argument("--settle-s", type=float, default=4.0, help="seconds to let the viewer load and lay out")
    parser.add_argument("--max-size", type=int, default=None, help="scale the PNG so its longest side fits")
    parser.add_argument("--palette", type=int, default=256,
                        help="quantise to this many colours to keep the PNG small (the UI has few); 0 = off")
    parser.add_argument("--port", type=int, default=9877)
    args = parser.parse_args(argv)
    if not args.rrd.is_file():
        print(f"screenshot_rrd: error: {args.rrd}: file not found", file=sys.stderr)
        return 1
    if not 0.0 <= args.fraction <= 1.0:
        print("screenshot_rrd: error: --fraction must be within [0, 1]", file=sys.stderr)
        return 1
    os.environ.setdefault("WGPU_BACKEND", "vulkan")  # the GL backend fails headless

    from rerun.experimental import ViewerClient

    span = timeline_range(args.rrd, args.timeline)
    executable = shutil.which("rerun", path=str(Path(sys.executable).parent)) or shutil.which("rerun")
    viewer = ViewerClient.spawn(headless=True, port=args.port, hide_welcome_screen=True,
                                executable_path=executable)
    try:
        viewer.open(str(args.rrd.resolve()))
        time.sleep(args.settle_s)
        if span is not None:
            kind, lo, hi = span
            at = int(round(lo + args.fraction * (hi - lo)))
            if kind == "sequence":
                viewer.set_time(args.timeline, sequence=at, play_state="paused")
            else:  # integers are nanoseconds, as the viewer client takes them
                import numpy as np

                value = np.datetime64(at, "ns") if kind == "timestamp" else np.timedelta64(at, "ns")
                viewer.set_time(args.timeline, **{kind: value}, play_state="paused")
            time.sleep(1.0)
        png = viewer.take_screenshot(max_size=args.max_size)
    finally:
        viewer.quit()
    if not png:
        print("screenshot_rrd: error: the viewer returned no image", file=sys.stderr)
        return 1
    args.png.parent.mkdir(parents=True, exist_ok=True)
    if args.palette:
        import io

        from PIL import Image  # Pillow comes with matplotlib

        image = Image.open(io.BytesIO(png)).convert("RGB")
        image = image.quantize(colors=args.palette, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
        buffer = io.BytesIO()
        image.save(buffer, format="PNG", optimize=True)
        png = buffer.getvalue()
    args.png.write_bytes(png)
    print(f"wrote {args.png} ({len(png) / 1e3:.0f} kB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
