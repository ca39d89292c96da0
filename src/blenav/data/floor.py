"""Floors as occupancy grids, and the rooms and routes on them.

Frames and units (docs/dataset-format.md): world frame x east, y north, z up, metres, one origin per
building. A floor image follows ROS map_server: ``resolution`` m/pixel, ``origin`` the world (x, y) of
the lower-left corner of the lower-left pixel. Image row 0 is the *top* row (largest y).

Occupancy values (:attr:`Floor.occupancy`, int8, shape (H, W), image row order):
``FREE = 0``, ``OCCUPIED = 1``, ``UNKNOWN = -1``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
from PIL import Image
from shapely.geometry import LineString, MultiLineString, MultiPolygon, Polygon

from .schema import DEFAULT_FREE_THRESH, DEFAULT_OCCUPIED_THRESH

__all__ = ["FREE", "OCCUPIED", "UNKNOWN", "Floor", "Region", "floor_key"]

FREE, OCCUPIED, UNKNOWN = 0, 1, -1


@dataclass
class Floor:
    """One floor: an occupancy grid with world<->pixel transforms.

    ``origin`` is (x, y) in metres of the lower-left image corner; ``z`` the floor height in metres.
    """

    id: int | str
    image_path: Path
    resolution: float
    origin: tuple[float, float]
    z: float = 0.0
    occupied_thresh: float = DEFAULT_OCCUPIED_THRESH
    free_thresh: float = DEFAULT_FREE_THRESH
    negate: bool = False

    @cached_property
    def image(self) -> np.ndarray:
        """8-bit grayscale pixels, shape (H, W), row 0 at the top."""
        with Image.open(self.image_path) as im:
            if im.mode != "L":
                im = im.convert("L")
            return np.asarray(im, dtype=np.uint8)

    @cached_property
    def occupancy(self) -> np.ndarray:
        """int8 (H, W): FREE 0, OCCUPIED 1, UNKNOWN -1 by ROS map_server thresholds."""
        v = self.image.astype(np.float32) / 255.0
        dark = v if self.negate else 1.0 - v
        occ = np.full(dark.shape, UNKNOWN, dtype=np.int8)
        occ[dark > self.occupied_thresh] = OCCUPIED
        occ[dark < self.free_thresh] = FREE
        return occ

    @property
    def shape(self) -> tuple[int, int]:
        return self.occupancy.shape

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) of the image in world metres."""
        h, w = self.shape
        x0, y0 = self.origin
        return x0, x0 + w * self.resolution, y0, y0 + h * self.resolution

    @property
    def free_mask(self) -> np.ndarray:
        return self.occupancy == FREE

    def world_to_pixel(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World (..., 2) metres -> integer (row, col) of the containing pixel (may be out of range)."""
        xy = np.asarray(xy, dtype=float)
        h, _ = self.shape
        col = np.floor((xy[..., 0] - self.origin[0]) / self.resolution).astype(np.int64)
        row = (h - 1) - np.floor((xy[..., 1] - self.origin[1]) / self.resolution).astype(np.int64)
        return row, col

    def pixel_to_world(self, row: np.ndarray, col: np.ndarray) -> np.ndarray:
        """Pixel centres -> world (..., 2) metres."""
        h, _ = self.shape
        x = self.origin[0] + (np.asarray(col, dtype=float) + 0.5) * self.resolution
        y = self.origin[1] + (h - 1 - np.asarray(row, dtype=float) + 0.5) * self.resolution
        return np.stack([x, y], axis=-1)

    def lookup(self, xy: np.ndarray, outside: int = UNKNOWN) -> np.ndarray:
        """Occupancy value at world points (...,2); ``outside`` for points off the image."""
        row, col = self.world_to_pixel(xy)
        h, w = self.shape
        inside = (row >= 0) & (row < h) & (col >= 0) & (col < w)
        out = np.full(row.shape, outside, dtype=np.int8)
        out[inside] = self.occupancy[row[inside], col[inside]]
        return out

    def is_free(self, xy: np.ndarray) -> np.ndarray:
        """Boolean (...) whether each world point lies in a free pixel."""
        return self.lookup(xy) == FREE

    def free_points(self) -> np.ndarray:
        """World coordinates (N, 2) of the centres of all free pixels."""
        r, c = np.nonzero(self.free_mask)
        return self.pixel_to_world(r, c)


@dataclass
class Region:
    """A room polygon or a navigation route, with its ``id`` and ``floor`` (GeoJSON properties)."""

    id: str
    floor: int | str
    geometry: Polygon | MultiPolygon | LineString | MultiLineString
    properties: dict = field(default_factory=dict)


def floor_key(floor_id, floors: dict):
    """The key of ``floors`` that names ``floor_id`` (compared as text: 0 and '0' are one floor), or None."""
    for k in floors:
        if str(k) == str(floor_id):
            return k
    return None
