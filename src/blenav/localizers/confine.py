"""Keep every method's estimates on the floor: a documented step applied to every :class:`Estimate`.

Two rules, in this order, per run and step:

1. **Bounding box.** An estimate outside the floor image's extent (xmin..xmax, ymin..ymax, world m) is
   clamped onto it (half a pixel inside). No method may report a position outside the building's plan.
2. **Free space** (methods that use the floor plan, :attr:`Localizer.uses_floor_plan`). An estimate whose
   distance to the nearest free pixel exceeds what its own uncertainty allows -- ``n_sigma`` times its
   standard deviation (sqrt of the covariance trace / 2), and at least one pixel (``resolution``) -- is
   moved to the centre of that nearest free pixel. A method without a covariance is allowed one pixel. An
   estimate inside a wall by less than its uncertainty stays (a particle cloud straddling a wall has its
   mean in the wall). Map-free methods (inertial odometry or PDR from a known start, BLE fix tracks, the
   weighted centroid) are not moved -- that would hand them the map they are compared without -- but
   their violations are counted all the same.

The harness applies it to every method and reports per method how many estimates the bounding box
clamped (``bbox``), how many lay off free space beyond their uncertainty (``off_free``) and how many of
those were moved (``free``), out of ``estimates`` (``confined`` in results.json): a method that wanders
off the plan is visible rather than silently repaired. Positions only: the covariance is kept.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .base import Estimate


def nearest_free(floor, cache: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(distance (H, W) m from each pixel to the nearest free pixel, indices (2, H, W) of that pixel), once
    per floor (``cache``: a dict shared by calls)."""
    key = ("nearest_free", str(floor.image_path), float(floor.resolution), tuple(floor.origin))
    if cache is not None and key in cache:
        return cache[key]
    from scipy.ndimage import distance_transform_edt

    free = floor.free_mask
    if not free.any():
        raise ValueError(f"floor {floor.id} ({floor.image_path}) has no free space")
    dist, idx = distance_transform_edt(~free, return_indices=True)
    out = (dist * float(floor.resolution), idx)
    if cache is not None:
        cache[key] = out
    return out


def confine(est: Estimate, floor, snap_free: bool = True, n_sigma: float = 2.0,
            cache: dict | None = None) -> tuple[Estimate, dict]:
    """``est`` with its positions kept on ``floor`` (rules in the module docstring; ``snap_free``: apply the
    free-space rule), and the counts ``{"bbox", "off_free", "free", "estimates"}``."""
    pos = est.position
    x0, x1, y0, y1 = floor.extent
    eps = 0.5 * float(floor.resolution)
    clamped = np.stack([np.clip(pos[..., 0], x0 + eps, x1 - eps), np.clip(pos[..., 1], y0 + eps, y1 - eps)], -1)
    n_bbox = int(np.count_nonzero(np.any(clamped != pos, axis=-1)))
    dist, idx = nearest_free(floor, cache)
    row, col = floor.world_to_pixel(clamped)
    h, w = floor.shape
    row, col = np.clip(row, 0, h - 1), np.clip(col, 0, w - 1)
    d = dist[row, col]
    std = est.std
    allowed = np.maximum(n_sigma * (std if std is not None else 0.0), float(floor.resolution))
    off = d > allowed
    move = off if snap_free else np.zeros_like(off)
    out = clamped
    if move.any():
        out = clamped.copy()
        out[move] = floor.pixel_to_world(idx[0][row[move], col[move]], idx[1][row[move], col[move]])
    info = {"bbox": n_bbox, "off_free": int(np.count_nonzero(off)), "free": int(np.count_nonzero(move)),
            "estimates": int(pos.shape[0] * pos.shape[1])}
    if n_bbox == 0 and not move.any():
        return est, info
    return replace(est, position=out), info
