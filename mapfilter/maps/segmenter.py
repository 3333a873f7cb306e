"""The learned wall segmenter of the drawing reader: a small U-Net trained only on generated plans
(tools/plans/train_segmenter.py), its ONNX weights shipped with the package and run by OpenCV's
``cv2.dnn`` (no other dependency). It sees the paper-evened drawing at ``WORK_M`` metres per pixel
as darkness (0 paper, 1 black) and gives each pixel the logit of its being wall (walls, windows,
columns); :func:`network_walls` returns the mask at the drawing's own pixels.
"""

from __future__ import annotations

import functools
from importlib import resources

import cv2
import numpy as np

WORK_M = 0.025  # the network's metres per pixel (train_segmenter.WORK_M)
MAX_PIXELS = 16e6  # larger at WORK_M is no drawing of a floor (a filled-region plan of a mall at 0.3 m/px is)


@functools.lru_cache(maxsize=1)
def _network():
    with resources.as_file(resources.files("mapfilter.maps") / "data" / "segmenter.onnx") as path:
        return cv2.dnn.readNetFromONNX(str(path))


def network_walls(evened: np.ndarray, resolution_m: float) -> np.ndarray | None:
    """The segmenter's wall mask of a paper-evened drawing (``evened``: 8-bit, paper 255) at its
    own pixels; None when the drawing at ``WORK_M`` per pixel would exceed ``MAX_PIXELS``."""
    rows, cols = evened.shape
    factor = resolution_m / WORK_M
    if rows * cols * factor ** 2 > MAX_PIXELS:
        return None
    size = (max(8, round(cols * factor)), max(8, round(rows * factor)))
    darkness = cv2.resize((255.0 - evened.astype(np.float32)) / 255.0, size,
                          interpolation=cv2.INTER_AREA if factor < 1 else cv2.INTER_LINEAR)
    # three poolings: the input is padded to a multiple of 8 (paper beyond the edge)
    padded = np.zeros(((size[1] + 7) // 8 * 8, (size[0] + 7) // 8 * 8), np.float32)
    padded[:size[1], :size[0]] = darkness
    net = _network()
    net.setInput(padded[None, None])
    logit = net.forward()[0, 0, :size[1], :size[0]]
    return cv2.resize(logit, (cols, rows), interpolation=cv2.INTER_LINEAR) > 0.0
