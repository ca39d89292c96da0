"""Occupancy-grid rasters shared by room and route derivation: the free mask at the derivation resolution,
the clearance (distance to the nearest obstacle) and pixel centres in world coordinates."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from blenav.data.floor import Floor


def free_grid(floor: Floor, derive_resolution: float):
    """Free mask, possibly coarsened to ~derive_resolution (a coarse pixel is free iff all its pixels are),
    with its resolution and origin. Cropping keeps the lower-left corner (the origin) fixed."""
    free = floor.free_mask
    res = floor.resolution
    f = int(np.floor(derive_resolution / res + 1e-9))
    if f >= 2:
        h, w = free.shape
        hh, ww = (h // f) * f, (w // f) * f
        free = free[h - hh:, :ww].reshape(hh // f, f, ww // f, f).all(axis=(1, 3))
        res = res * f
    return free, res, floor.origin


def clearance(free: np.ndarray, res: float) -> np.ndarray:
    """Distance (m) from each free pixel centre to the nearest non-free pixel centre (image border blocks)."""
    pad = np.pad(free, 1, constant_values=False)
    return ndimage.distance_transform_edt(pad)[1:-1, 1:-1] * res


def px_to_world(rows, cols, h, res, origin):
    x = origin[0] + (np.asarray(cols, float) + 0.5) * res
    y = origin[1] + (h - 1 - np.asarray(rows, float) + 0.5) * res
    return np.stack([x, y], axis=-1)
