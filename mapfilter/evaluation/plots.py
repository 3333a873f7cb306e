"""Pictures of an evaluation: the error CDF of every method, and tracks over the floor plan (PNG)."""

from __future__ import annotations

import os

import numpy as np

from mapfilter.io.atomic import atomic_paths


def load_plotting() -> None:
    """Import the plotting library now: a run that draws pictures after long work loads it before
    that work, so that an interrupt (Ctrl-C) cannot land in its import and leave it half loaded
    for the partial results' pictures."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot  # noqa: F401


def plot_error_cdf(errors_by_method: dict[str, np.ndarray], path: str | os.PathLike, title: str = "") -> None:
    """Write a PNG with the empirical CDF of the errors of each method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5), dpi=120)
    for method, errors in errors_by_method.items():
        errors = np.sort(np.asarray(errors, dtype=np.float64))
        if errors.size == 0:
            continue
        share = np.arange(1, errors.size + 1) / errors.size
        ax.step(errors, share, where="post", label=f"{method} (median {np.median(errors):.2f} m)")
    ax.axhline(0.75, color="0.6", lw=0.8, ls=":")
    ax.set_xlabel("horizontal error (m)")
    ax.set_ylabel("share of waypoints")
    ax.set_ylim(0, 1)
    ax.set_xlim(left=0)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    if title:
        ax.set_title(title)
    fig.tight_layout()
    save_figure(fig, path)


def walk_window_m(floorplan, points_xy_m: list[np.ndarray], margin_m: float = 10.0) -> tuple[float, float, float, float]:
    """(x0, x1, y0, y1): the box around the points (the walk and its tracks) plus ``margin_m``,
    within the plan's extent; the whole plan when there are no points."""
    px0, px1, py0, py1 = floorplan.extent_m
    xy = [np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in points_xy_m if len(p)]
    xy = np.vstack(xy) if xy else np.zeros((0, 2))
    xy = xy[np.isfinite(xy).all(axis=1)]
    if xy.shape[0] == 0:
        return px0, px1, py0, py1
    lo, hi = xy.min(axis=0) - margin_m, xy.max(axis=0) + margin_m
    return max(px0, lo[0]), min(px1, hi[0]), max(py0, lo[1]), min(py1, hi[1])


def plot_tracks_on_map(floorplan, tracks: dict[str, np.ndarray], path,
                       ground_truth_xy_m: np.ndarray | None = None, title: str = "") -> None:
    """Write a PNG of tracks (name -> (T, 2) metres) and the ground truth over the floor plan,
    zoomed on the walk (``walk_window_m``), to ``path`` (a file's path, or a binary stream)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x0, x1, y0, y1 = floorplan.extent_m
    wx0, wx1, wy0, wy1 = walk_window_m(floorplan, [*tracks.values()] + ([ground_truth_xy_m]
                                                                         if ground_truth_xy_m is not None else []))
    aspect = (wy1 - wy0) / max(wx1 - wx0, 1e-9)
    fig, ax = plt.subplots(figsize=(8, min(max(3.0, 8 * aspect), 12.0)), dpi=120)
    ax.imshow(np.where(floorplan.wall_mask, 0.35, 1.0), cmap="gray", vmin=0, vmax=1,
              extent=(x0, x1, y0, y1), origin="upper", interpolation="nearest")
    if ground_truth_xy_m is not None and len(ground_truth_xy_m):
        gt = np.asarray(ground_truth_xy_m)
        ax.plot(gt[:, 0], gt[:, 1], "k--", lw=1.2, marker="o", ms=3, label="ground truth")
    for name, xy in tracks.items():
        xy = np.asarray(xy)
        if len(xy):
            ax.plot(xy[:, 0], xy[:, 1], lw=1.0, label=name)
    ax.set_xlim(wx0, wx1)
    ax.set_ylim(wy0, wy1)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal")
    ax.legend(loc="best", fontsize=7)
    if title:
        ax.set_title(title)
    fig.tight_layout()
    save_figure(fig, path)


def save_figure(fig, path, dpi: float | None = None) -> None:
    """Write a matplotlib figure as PNG atomically (``path`` a file's path, or a binary stream
    it is written to) and close it."""
    import matplotlib.pyplot as plt

    if hasattr(path, "write"):
        fig.savefig(path, format="png", dpi=dpi)
    else:
        with atomic_paths(path) as (tmp,):
            fig.savefig(tmp, format="png", dpi=dpi)
    plt.close(fig)
