"""Wall crossing on an occupancy grid: does a motion step touch an obstacle?

The particle-filter engine's ``walls`` component (``crossed``: the wall-crossing penalty and Roy's
re-initialisation rule) and an obstacle test (``in_obstacle``), vectorised over any leading shape of
particle arrays (the step test is a compiled loop, :func:`blenav.filters.map.kernels.walls_crossed`).
"""

from __future__ import annotations

import numpy as np

from blenav.data.floor import FREE, OCCUPIED, Floor

from . import kernels as K


class WallCrossing:
    """Wall tests on an occupancy grid (int8 (H, W), row 0 on top, FREE 0 / OCCUPIED 1 / UNKNOWN -1).

    ``crossed(x_prev, x_new)`` samples each straight step at t = 1/n, 2/n, ..., 1 (the start point is
    not tested, the end point is) with ``n = ceil(longest step / (resolution / 2))`` samples shared by the
    whole batch, so consecutive samples are at most half a pixel apart (a wall at least one pixel thick is
    never skipped). ``n`` is capped at ``max_samples`` (64: half-pixel spacing for steps up to 3.2 m at
    0.1 m/pixel); longer steps are sampled more sparsely. Off-image points and UNKNOWN pixels block only
    when ``unknown_blocks`` is true.
    """

    def __init__(self, occupancy: np.ndarray, resolution: float, origin=(0.0, 0.0), unknown_blocks: bool = False,
                 max_samples: int = 64):
        self.occupancy = np.asarray(occupancy, dtype=np.int8)
        if self.occupancy.ndim != 2:
            raise ValueError(f"occupancy must be a 2-D grid, got shape {self.occupancy.shape}")
        self.resolution = float(resolution)
        self.origin = (float(origin[0]), float(origin[1]))
        self.unknown_blocks = bool(unknown_blocks)
        self.max_samples = int(max_samples)
        self._blocked = (self.occupancy != FREE) if unknown_blocks else (self.occupancy == OCCUPIED)
        # the same, padded by one pixel of "off-image" on every side and flattened: crossed() clips indices
        # into the padding instead of testing bounds
        self._blocked_pad = np.pad(self._blocked, 1, constant_values=self.unknown_blocks).ravel()

    @classmethod
    def from_floor(cls, floor: Floor, **kw) -> "WallCrossing":
        return cls(floor.occupancy, floor.resolution, floor.origin, **kw)

    def _blocked_at(self, xy: np.ndarray) -> np.ndarray:
        h, w = self._blocked.shape
        col = np.floor((xy[..., 0] - self.origin[0]) / self.resolution).astype(np.int64)
        row = (h - 1) - np.floor((xy[..., 1] - self.origin[1]) / self.resolution).astype(np.int64)
        inside = (row >= 0) & (row < h) & (col >= 0) & (col < w)
        out = np.full(row.shape, self.unknown_blocks, dtype=bool)
        out[inside] = self._blocked[row[inside], col[inside]]
        return out

    def in_obstacle(self, xy: np.ndarray) -> np.ndarray:
        """Bool (...) whether each world point (..., >=2) lies in an occupied (or, if so configured,
        unknown/off-image) pixel."""
        return self._blocked_at(np.asarray(xy, dtype=float)[..., :2])

    def crossed(self, x_prev_xy: np.ndarray, x_new_xy: np.ndarray) -> np.ndarray:
        """Bool (...) whether the straight step from ``x_prev_xy`` to ``x_new_xy`` (..., >=2) touches an
        occupied pixel (see the class docstring for the sampling)."""
        p0 = np.asarray(x_prev_xy, dtype=float)[..., :2]
        p1 = np.asarray(x_new_xy, dtype=float)[..., :2]
        d = p1 - p0
        longest = float(np.max(np.hypot(d[..., 0], d[..., 1]), initial=0.0))
        n = int(np.clip(np.ceil(longest / (0.5 * self.resolution)), 1, self.max_samples))
        # one compiled pass over the steps (kernels.walls_crossed): the same points and pixel arithmetic as
        # _blocked_at at t = k / n, without the (..., n, 2) temporaries; a NaN position lands in the padding
        h, w = self._blocked.shape
        flat = [np.ascontiguousarray(a, dtype=float).ravel() for a in (p0[..., 0], p0[..., 1], d[..., 0], d[..., 1])]
        out = K.walls_crossed(*flat, n, self._blocked_pad, h, w, self.origin[0], self.origin[1], self.resolution)
        return out.reshape(p0.shape[:-1])
