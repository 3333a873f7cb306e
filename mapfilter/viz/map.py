"""The map layer: the floor-plan picture and the wall mask, placed in world metres (static)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mapfilter.errors import MapfilterError, not_a_file
from mapfilter.viz.canvas import Canvas
from mapfilter.viz.style import BACKGROUND, Z_IMAGE, Z_MASK

if TYPE_CHECKING:  # pragma: no cover
    from mapfilter.maps.floorplan import FloorPlan


class MapLayer:
    """Draws ``<root>/world/floorplan/image`` (the source picture, if any) and ``<root>/world/walls/mask``
    (``root``: ``map``, or ``floors/<floor>`` for one floor of a building seen whole, ``viz.building``)."""

    def __init__(self, canvas: Canvas, floorplan: FloorPlan, root: str = "map") -> None:
        self.canvas = canvas
        self.floorplan = floorplan
        self.root = root
        self._picture: np.ndarray | None = None

    def extent_m(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) covering the wall mask and the source picture."""
        x_min, x_max, y_min, y_max = self.floorplan.extent_m
        if self.floorplan.source_image is not None:
            sx_min, sx_max, sy_min, sy_max = self._source_extent_m()
            x_min, x_max = min(x_min, sx_min), max(x_max, sx_max)
            y_min, y_max = min(y_min, sy_min), max(y_max, sy_max)
        return x_min, x_max, y_min, y_max

    def _source_extent_m(self) -> tuple[float, float, float, float]:
        source = self.floorplan.source_image
        height, width = self._source_picture().shape[:2]
        x0, y0 = source.origin_m
        return x0, x0 + width * source.resolution_m, y0, y0 + height * source.resolution_m

    def _source_picture(self) -> np.ndarray:
        """The floor-plan picture as OpenCV reads it (read once)."""
        import cv2

        if self._picture is None:
            source = self.floorplan.source_image
            if not Path(source.path).is_file():
                raise not_a_file(source.path)
            self._picture = cv2.imread(str(source.path), cv2.IMREAD_UNCHANGED)
            if self._picture is None:
                raise MapfilterError("not a readable image", source.path)
        return self._picture

    def _image_transform(self, height_px: int, resolution_m: float, origin_m: tuple[float, float]) -> Any:
        # pixel (u, v) -> world (x0 + u res, y_top - v res): rows grow downwards, world y upwards
        y_top = origin_m[1] + height_px * resolution_m
        return self.canvas.rr.Transform3D(
            translation=[origin_m[0], y_top, 0.0], scale=[resolution_m, -resolution_m, 1.0]
        )

    def draw(self, static: bool = True) -> None:
        """Log the floor-plan picture (if any) and the wall mask overlay, static or (for the
        current floor of a building, which changes) at the current time."""
        import cv2

        rr = self.canvas.rr
        log = self.canvas.log
        fp = self.floorplan
        world = f"{self.root}/world"
        source = fp.source_image
        if source is not None:
            image = self._source_picture()
            log(f"{world}/floorplan", self._image_transform(image.shape[0], source.resolution_m, source.origin_m),
                static=static)
            # rerun 0.41 draws transparent image pixels with their RGB (black in ILC plans), so
            # flatten onto the view's background colour; PNG-encode to keep the recording small
            ok, png = cv2.imencode(".png", flatten_bgr(image, BACKGROUND))
            if not ok:
                raise MapfilterError("could not re-encode the floor-plan picture", source.path)
            log(f"{world}/floorplan/image",
                rr.EncodedImage(contents=png.tobytes(), media_type="image/png", draw_order=Z_IMAGE), static=static)
        log(f"{world}/walls", self._image_transform(fp.shape_px[0], fp.resolution_m, fp.origin_m), static=static)
        log(
            f"{world}/walls",
            rr.AnnotationContext([
                rr.AnnotationInfo(id=0, label="free", color=(0, 0, 0, 0)),
                rr.AnnotationInfo(id=1, label="wall", color=(200, 30, 30, 255)),
            ]),
            static=static,
        )
        # with a picture underneath the mask is a light overlay; alone it is the map itself
        opacity = 0.35 if source is not None else 0.8
        log(f"{world}/walls/mask", rr.SegmentationImage(fp.wall_mask.astype(np.uint8), opacity=opacity,
                                                         draw_order=Z_MASK), static=static)


def flatten_bgr(image: np.ndarray, background_rgb: tuple[int, int, int]) -> np.ndarray:
    """An OpenCV image (grey, BGR or BGRA, any depth) as 8-bit BGR, alpha blended onto a colour."""
    import cv2

    if image.dtype != np.uint8:
        image = cv2.convertScaleAbs(image, alpha=255.0 / max(float(image.max()), 1.0))
    if image.ndim == 2:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    if image.shape[2] == 4:
        alpha = image[..., 3:4].astype(np.float32) / 255.0
        background = np.array(background_rgb[::-1], dtype=np.float32)
        return np.round(image[..., :3] * alpha + background * (1.0 - alpha)).astype(np.uint8)
    return image[..., :3]
