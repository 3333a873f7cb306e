"""The learned wall segmenter of the drawing reader: a small U-Net trained only on generated plans
(tools/plans/train_segmenter.py), its ONNX weights shipped with the package and run by OpenCV's
``cv2.dnn`` (no other dependency). It sees the paper-evened drawing at ``WORK_M`` metres per pixel
as darkness (0 paper, 1 black) and gives each pixel the logit of its being wall (walls, windows,
columns); :func:`network_walls` returns the mask at the drawing's own pixels.
"""

from __future__ import annotations

import functools
import math
from importlib import resources

import cv2
import numpy as np

WORK_M = 0.025  # the network's metres per pixel (train_segmenter.WORK_M)
MAX_PIXELS = 16e6  # larger at WORK_M is no drawing of a floor (a filled-region plan of a mall at 0.3 m/px is)


@functools.lru_cache(maxsize=1)
def _network():
    with resources.as_file(resources.files("mapfilter.maps") / "data" / "segmenter.onnx") as path:
        return cv2.dnn.readNetFromONNX(str(path))


def network_walls(evened: np.ndarray, resolution_m: float,
                  region: tuple[slice, slice] | None = None) -> np.ndarray | None:
    """The segmenter's wall mask of a paper-evened drawing (``evened``: 8-bit, paper 255) at its
    own pixels; None when the drawing at ``WORK_M`` per pixel would exceed ``MAX_PIXELS``.

    ``region`` (rows, columns of the drawing): the network is run there only (the time it takes
    goes with the pixels it sees), on the same pixel grid as over the whole drawing; no wall
    beyond it."""
    rows, cols = evened.shape
    factor = resolution_m / WORK_M
    if rows * cols * factor ** 2 > MAX_PIXELS:
        return None
    size = (max(8, round(cols * factor)), max(8, round(rows * factor)))
    darkness = cv2.resize((255.0 - evened.astype(np.float32)) / 255.0, size,
                          interpolation=cv2.INTER_AREA if factor < 1 else cv2.INTER_LINEAR)
    top, left, bottom, right = 0, 0, size[1], size[0]
    if region is not None:
        # (starts on a multiple of 8: the three poolings group the pixels as over the whole drawing)
        top = min(int(region[0].start * factor) // 8 * 8, bottom - 8)
        left = min(int(region[1].start * factor) // 8 * 8, right - 8)
        bottom = min(bottom, max(top + 8, math.ceil(region[0].stop * factor) + 1))
        right = min(right, max(left + 8, math.ceil(region[1].stop * factor) + 1))
    height, width = bottom - top, right - left
    # three poolings: the input is padded to a multiple of 8 (paper beyond the edge)
    padded = np.zeros(((height + 7) // 8 * 8, (width + 7) // 8 * 8), np.float32)
    padded[:height, :width] = darkness[top:bottom, left:right]
    net = _network()
    net.setInput(padded[None, None])
    logit = np.full((size[1], size[0]), -1.0, np.float32)  # (beyond the region: no wall)
    logit[top:bottom, left:right] = net.forward()[0, 0, :height, :width]
    return cv2.resize(logit, (cols, rows), interpolation=cv2.INTER_LINEAR) > 0.0
