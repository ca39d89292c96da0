"""Rooms derived from the occupancy grid, for maps without ``rooms.geojson`` (most real buildings).

Free space eroded by half a door width (0.6 m: openings up to 1.2 m wide separate rooms), connected
components (>= 0.25 m^2) as seeds, grown back over free space by a watershed on the clearance map (so
boundaries fall in doorways), each label polygonised as the union of its pixel runs, simplified by one
pixel. Corridors become rooms too.
"""

from __future__ import annotations

import numpy as np
import shapely
from scipy import ndimage
from shapely.geometry import Polygon

from blenav.data.floor import Floor

from .raster import clearance, free_grid
from .shapes import polygons_of

ROOM_OPTIONS = {"door_width", "min_seed_area", "min_room_area", "derive_resolution"}


def derive_rooms(floor: Floor, door_width: float = 1.2, min_seed_area: float = 0.25, min_room_area: float = 0.5,
                 derive_resolution: float = 0.1) -> list[Polygon]:
    """Rooms as connected free regions separated at doorways (see :mod:`blenav.filters.map.rooms`)."""
    from skimage.segmentation import watershed

    free, res, origin = free_grid(floor, derive_resolution)
    if not free.any():
        return []
    clear = clearance(free, res)
    # strictly wider than a door, in whole pixels (0.6 / 0.1 is not exactly 6 in floating point)
    seeds, n = ndimage.label(clear / res > door_width / 2 / res + 1e-6)  # 4-connected
    if n:
        sizes = ndimage.sum_labels(np.ones_like(seeds), seeds, index=np.arange(1, n + 1)) * res**2
        small = np.flatnonzero(sizes < min_seed_area) + 1
        seeds[np.isin(seeds, small)] = 0
    if not seeds.any():  # no room wider than a door: every free component is one room
        seeds, n = ndimage.label(free)
    labels = watershed(-clear, markers=seeds, mask=free)
    return _labels_to_polygons(labels, res, origin, min_room_area)


def _labels_to_polygons(lab: np.ndarray, res: float, origin, min_area: float) -> list[Polygon]:
    """One polygon per label > 0: union of its horizontal pixel runs, simplified by one pixel."""
    h, w = lab.shape
    z = np.zeros((h, 1), dtype=lab.dtype)
    prev = np.concatenate([z, lab[:, :-1]], axis=1)
    nxt = np.concatenate([lab[:, 1:], z], axis=1)
    rs, cs = np.nonzero((lab != prev) & (lab > 0))
    _, ce = np.nonzero((lab != nxt) & (lab > 0))
    xe = origin[0] + np.arange(w + 1) * res
    ye = origin[1] + np.arange(h + 1) * res
    boxes = shapely.box(xe[cs], ye[h - 1 - rs], xe[ce + 1], ye[h - rs])
    lbl = lab[rs, cs]
    out = []
    for k in np.unique(lbl):
        g = shapely.union_all(boxes[lbl == k])
        g = shapely.make_valid(g.simplify(res, preserve_topology=True))
        out += [p for p in polygons_of(g) if p.area >= min_area]
    return out
