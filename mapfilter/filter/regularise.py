"""Regularisation after resampling (Musso, Oudjane & Le Gland, Regularised Particle Filter).

Resampled particles are jittered with a kernel K of bandwidth h = A * N^(-1/(d+4)) scaled
by the square root of the empirical covariance S (x_i += h D eps_i, D D^T = S). A is the
kernel's optimal constant for a Gaussian density:
  Gaussian kernel:      A = (4 / (d + 2))^(1/(d+4))                       (= 1 for d = 2)
  Epanechnikov kernel:  A = (8 (d + 4) (2 sqrt(pi))^d / c_d)^(1/(d+4))     (c_d = unit-ball volume)
Here d = 2 (the position). A jittered particle whose move from its parent crosses a wall is
redrawn up to ``tries`` times and otherwise stays at its parent; so is one whose straight
line from its position before the step (``origin_xy_m``) would cross a wall, which keeps the
ancestral path of every particle wall-free (see ``filter/ancestry.py``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from mapfilter.filter.estimate import weighted_moments
from mapfilter.filter.gaussian import standard_normal
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import NO_BUFFER, _segment_crosses_world, clearance_px
from mapfilter.threads import for_slices

__all__ = ["KERNELS", "bandwidth_and_root", "optimal_bandwidth", "regularise", "sample_kernel", "weighted_covariance"]

KERNELS = ("gaussian", "epanechnikov")


def optimal_bandwidth(n: int, kernel: str = "gaussian", d: int = 2) -> float:
    """Musso, Oudjane & Le Gland's optimal h = A N^(-1/(d+4)) for unit covariance."""
    if kernel == "gaussian":
        a = (4.0 / (d + 2.0)) ** (1.0 / (d + 4.0))
    elif kernel == "epanechnikov":
        unit_ball = math.pi ** (d / 2.0) / math.gamma(d / 2.0 + 1.0)
        a = (8.0 * (d + 4.0) * (2.0 * math.sqrt(math.pi)) ** d / unit_ball) ** (1.0 / (d + 4.0))
    else:
        raise ValueError(f"unknown kernel {kernel!r}; choose one of {KERNELS}")
    return a * max(int(n), 1) ** (-1.0 / (d + 4.0))


def sample_kernel(kernel: str, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 2) draws from the unit-covariance-shaped kernel (standard normal, or Epanechnikov on the unit disc)."""
    if kernel == "gaussian":
        return standard_normal(rng, (n, 2))
    if kernel == "epanechnikov":
        # density ~ (1 - |e|^2) on the unit disc: |e|^2 ~ Beta(d/2, 2) with d = 2, uniform direction
        r = np.sqrt(rng.beta(1.0, 2.0, n))
        phi = rng.uniform(0.0, 2.0 * math.pi, n)
        return np.stack([r * np.cos(phi), r * np.sin(phi)], axis=1)
    raise ValueError(f"unknown kernel {kernel!r}; choose one of {KERNELS}")


def weighted_covariance(xy_m: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(2, 2) covariance of the positions under normalised weights."""
    return weighted_moments(xy_m, weights)[1]


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)  # no refcounting: see maps/walls.py
def _jitter_kernel(lo, hi, mask, clearance, x0_m, y0_m, resolution_m, parent_xy, origin_xy, index, eps, root, h,
                   new_xy, accepted, no_buffer):
    """Candidates parent + h * root @ eps for the particles ``index``; accept those whose move
    from the parent (and from the origin, the position before the step) touches no wall."""
    inv = 1.0 / resolution_m
    for j in range(lo, hi):
        i = index[j]
        px = parent_xy[i, 0]
        py = parent_xy[i, 1]
        cx = px + h * (root[0, 0] * eps[j, 0] + root[0, 1] * eps[j, 1])
        cy = py + h * (root[1, 0] * eps[j, 0] + root[1, 1] * eps[j, 1])
        ok = not _segment_crosses_world(mask, clearance, x0_m, y0_m, inv, px, py, cx, cy, no_buffer)
        if ok and origin_xy.shape[0] > 0:
            ok = not _segment_crosses_world(mask, clearance, x0_m, y0_m, inv, origin_xy[i, 0], origin_xy[i, 1],
                                            cx, cy, no_buffer)
        if ok:
            new_xy[i, 0] = cx
            new_xy[i, 1] = cy
        accepted[j] = ok


def bandwidth_and_root(floorplan: FloorPlan, covariance_m2: np.ndarray, n: int, kernel: str = "gaussian",
                       bandwidth_scale: float = 1.0, min_std_m: float | None = None) -> tuple[float, np.ndarray]:
    """(h, D): the jitter is h D eps with D D^T the covariance plus ``min_std_m``^2 (default one
    pixel) on the diagonal, h the optimal bandwidth for ``n`` particles times ``bandwidth_scale``."""
    h = optimal_bandwidth(n, kernel) * bandwidth_scale
    floor_std = floorplan.resolution_m if min_std_m is None else min_std_m
    cov = np.asarray(covariance_m2, dtype=np.float64) + (floor_std ** 2) * np.eye(2)
    try:
        root = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        root = np.diag(np.sqrt(np.maximum(np.diag(cov), floor_std ** 2)))
    return h, root


def regularise(floorplan: FloorPlan, xy_m: np.ndarray, covariance_m2: np.ndarray, rng: np.random.Generator,
               kernel: str = "gaussian", bandwidth_scale: float = 1.0, tries: int = 3,
               origin_xy_m: np.ndarray | None = None, min_std_m: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Jitter resampled positions without crossing walls.

    Parameters
    ----------
    floorplan : the map.
    xy_m : (N, 2) resampled positions (the parents of the jitter).
    covariance_m2 : (2, 2) empirical covariance of the cloud (before resampling).
    rng : random generator.
    kernel : "gaussian" or "epanechnikov".
    bandwidth_scale : multiplies the optimal bandwidth (< 1 for multimodal clouds).
    tries : redraws for a jitter that crosses a wall; after that the particle stays.
    origin_xy_m : (N, 2) optional second anchor: the jittered point must also be reachable
        in a straight wall-free line from it (the particle's position before this step).
    min_std_m : floor on the kernel's standard deviation per axis (default: one pixel), so
        that a cloud collapsed onto one point still spreads.

    Returns
    -------
    new_xy_m : (N, 2) jittered positions.
    moved : (N,) bool, False where the particle stayed at its parent.
    """
    xy = np.ascontiguousarray(xy_m, dtype=np.float64).reshape(-1, 2)
    n = xy.shape[0]
    h, root = bandwidth_and_root(floorplan, covariance_m2, n, kernel, bandwidth_scale, min_std_m)
    new_xy = xy.copy()
    moved = np.zeros(n, dtype=bool)
    origin = (np.zeros((0, 2)) if origin_xy_m is None
              else np.ascontiguousarray(origin_xy_m, dtype=np.float64).reshape(-1, 2))
    clearance = clearance_px(floorplan)
    pending = np.arange(n)
    for _ in range(max(int(tries), 1)):
        if pending.size == 0:
            break
        eps = sample_kernel(kernel, pending.size, rng)
        accepted = np.empty(pending.size, dtype=np.bool_)
        for_slices(_jitter_kernel, pending.size, floorplan.wall_mask, clearance, floorplan.origin_m[0],
                   floorplan.origin_m[1], floorplan.resolution_m, xy, origin, pending, eps, root, h, new_xy, accepted,
                   NO_BUFFER)
        moved[pending[accepted]] = True
        pending = pending[~accepted]
    return new_xy, moved
