"""The prepared floor -1 of the IPIN 2023 venue for docs/formats.md: the wall mask (red) over
the plan turned to north, the nine surveyed reference points (blue crosses, from
plans/references.csv, placed by their latitude/longitude) and every training log's ground-truth
points (green: floor 0, orange: floor -2; drawn here for orientation, they are not on floor -1).

    .venv/bin/python tools/experiments/ipin_venue_picture.py ../shared/data/ipin2023 --out docs/img/ipin2023_floor-1.png
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from mapfilter.cli import main  # noqa: E402
from mapfilter.maps.building import Building  # noqa: E402
from mapfilter.maps.prepare import preview_image  # noqa: E402
from mapfilter.sensors.logs import read_log  # noqa: E402


def main_(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path, help="the ipin2023 data folder")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--side", type=int, default=1400, help="longer side of the picture in pixels")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        venue = Path(tmp) / "venue.yaml"
        assert main(["map", "import-ipin", str(args.data / "plans" / "calib_mapa_Nuremberg.cal"), "--out",
                     str(venue)]) == 0
        building = Building.load(venue)
        plan = building.floor("-1").plan
        picture = preview_image(plan, max_side_px=args.side)
    x_min, x_max, y_min, y_max = plan.extent_m
    res = (x_max - x_min) / picture.shape[1]

    def pixel(xy: np.ndarray) -> np.ndarray:
        return np.round(np.column_stack([(xy[:, 0] - x_min) / res, (y_max - xy[:, 1]) / res])).astype(int)

    for path in sorted((args.data / "logs").glob("*.txt.gz")):
        rec = read_log(path, building=building, warn=lambda message: None)
        xy = building.georeference.to_xy_m(rec.waypoint_latlon_deg)
        for (u, v), floor in zip(pixel(xy), rec.waypoint_floor):
            cv2.circle(picture, (int(u), int(v)), 5, (60, 160, 40) if floor == "0" else (0, 140, 255), -1,
                       cv2.LINE_AA)
    rows = [line.split(",") for line in (args.data / "plans" / "references.csv").read_text().split()[1:]]
    refs = building.georeference.to_xy_m(np.array([[float(r[1]), float(r[2])] for r in rows]))
    for u, v in pixel(refs):
        cv2.drawMarker(picture, (int(u), int(v)), (200, 60, 0), cv2.MARKER_CROSS, 22, 2, cv2.LINE_AA)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), picture, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    print(f"wrote {args.out}: {picture.shape[1]}x{picture.shape[0]} px")
    return 0


if __name__ == "__main__":
    sys.exit(main_())
