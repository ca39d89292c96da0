"""A floor on the Map Prior Network's grid (Roy, section 3.2.2), without PyTorch: what training
(:mod:`blenav.learn.mapprior.data`) and the runtime (:class:`blenav.runtime.map_prior.MapPrior`) both need.

The network works at one metric resolution (``resolution_m``). A floor at another resolution is resampled
to it (:func:`resample_free`) on a grid with the same lower-left origin (:class:`NetGrid`, built by
:func:`net_grid`); a world point maps to the net pixel that contains it (:meth:`NetGrid.world_to_pixel`).
:func:`floor_key` is the key of a floor's Deep Map Tensor in a cache (mask, resolutions, weights), and
:func:`pad_to_multiple` pads a mask to the U-Net's size multiple (zero = obstacle), as the exported map
encoder expects. Numpy only.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np


def _free_ranges(n_out: int, res_in: float, res_out: float, n_in: int):
    """For each output cell i (counted from the lower-left origin) the input index range [lo, hi) it covers."""
    i = np.arange(n_out)
    lo = np.floor(i * res_out / res_in + 1e-9).astype(np.int64)
    hi = np.ceil((i + 1) * res_out / res_in - 1e-9).astype(np.int64)
    return np.clip(lo, 0, n_in), np.clip(np.maximum(hi, lo + 1), 0, n_in + 1)


def resample_free(free: np.ndarray, res_in: float, res_out: float) -> np.ndarray:
    """Free mask (H, W) bool at ``res_in`` m/px -> (H2, W2) bool at ``res_out`` m/px, same lower-left origin.

    H2 = max(1, round(H * res_in / res_out)) (W2 alike). Coarser output (res_out > res_in): a cell is free
    only if *every* input pixel it touches is free (any obstacle wins, so 0.2 m walls survive at 0.25 or
    0.5 m/px; doors narrow by at most one output pixel per side); finer or equal output: nearest input pixel
    (pixel centre). Input beyond the image counts as obstacle. Image row 0 is the top row (largest y).
    """
    free = np.asarray(free, dtype=bool)
    if free.ndim != 2:
        raise ValueError(f"free mask must be (H, W), got shape {free.shape}")
    res_in, res_out = float(res_in), float(res_out)
    H, W = free.shape
    H2 = max(1, int(round(H * res_in / res_out)))
    W2 = max(1, int(round(W * res_in / res_out)))
    if H2 == H and W2 == W and abs(res_in - res_out) <= 1e-9 * res_out:
        return free.copy()
    up = free[::-1]  # row 0 = bottom row, so output cells align with the lower-left origin
    if res_out <= res_in:  # finer: nearest by centre
        r = np.floor((np.arange(H2) + 0.5) * res_out / res_in).astype(np.int64)
        c = np.floor((np.arange(W2) + 0.5) * res_out / res_in).astype(np.int64)
        ok_r, ok_c = r < H, c < W
        out = up[np.minimum(r, H - 1)][:, np.minimum(c, W - 1)] & ok_r[:, None] & ok_c[None, :]
        return np.ascontiguousarray(out[::-1])
    occ = np.zeros((H + 2, W + 2), dtype=np.int64)  # summed-area table of obstacles, one row/col beyond as obstacle
    occ[1:H + 1, 1:W + 1] = ~up
    occ[H + 1, :] = 1
    occ[:, W + 1] = 1
    sat = np.zeros((H + 3, W + 3), dtype=np.int64)
    sat[1:, 1:] = occ.cumsum(0).cumsum(1)
    r0, r1 = _free_ranges(H2, res_in, res_out, H)
    c0, c1 = _free_ranges(W2, res_in, res_out, W)
    r0, r1 = r0 + 1, r1 + 1  # into the padded table
    c0, c1 = c0 + 1, c1 + 1
    n_occ = sat[r1][:, c1] - sat[r0][:, c1] - sat[r1][:, c0] + sat[r0][:, c0]
    return np.ascontiguousarray((n_occ == 0)[::-1])


@dataclass(frozen=True)
class NetGrid:
    """A floor's grid at the network's resolution: ``shape`` (H, W), ``resolution`` m/px, ``origin`` (x, y) m of
    the lower-left corner (the floor's), row 0 on top (ROS map_server convention, as :class:`blenav.data.Floor`)."""

    shape: tuple[int, int]
    resolution: float
    origin: tuple[float, float]

    def world_to_pixel(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World (..., 2) m -> int64 (row, col) of the containing pixel (may be out of range)."""
        xy = np.asarray(xy, dtype=float)
        h = self.shape[0]
        col = np.floor((xy[..., 0] - self.origin[0]) / self.resolution).astype(np.int64)
        row = (h - 1) - np.floor((xy[..., 1] - self.origin[1]) / self.resolution).astype(np.int64)
        return row, col

    def inside(self, row: np.ndarray, col: np.ndarray) -> np.ndarray:
        return (row >= 0) & (row < self.shape[0]) & (col >= 0) & (col < self.shape[1])


def net_grid(floor, resolution_m: float) -> tuple[NetGrid, np.ndarray]:
    """(grid, free mask (H, W) bool) of a :class:`blenav.data.Floor` resampled to ``resolution_m``.

    Raises ValueError naming the building and floor when the floor (or its resampled mask) has no free pixel.
    """
    free = np.asarray(floor.free_mask, dtype=bool)
    where = _floor_name(floor)
    if not free.any():
        raise ValueError(f"{where} has no free space (no FREE pixel in {floor.image_path}); the map prior needs "
                         "a floor plan with walkable pixels")
    m = resample_free(free, float(floor.resolution), float(resolution_m))
    if not m.any():
        raise ValueError(f"{where} has no free space at the map prior's resolution {resolution_m:g} m/px "
                         f"(floor resolution {floor.resolution:g} m/px; every free area is narrower than a pixel)")
    grid = NetGrid((int(m.shape[0]), int(m.shape[1])), float(resolution_m),
                   (float(floor.origin[0]), float(floor.origin[1])))
    return grid, m


def _floor_name(floor) -> str:
    path = Path(floor.image_path)  # a Floor has no back reference: its building is the folder with building.yaml
    b = next((p.name for p in path.parents if (p / "building.yaml").is_file()), path.parent.name)
    return f"building '{b}' floor {floor.id!r}"


def floor_key(floor, resolution_m: float, weights_hash: str) -> str:
    """sha256 hex of (FREE mask bits, shape, floor resolution, network resolution, weights hash)."""
    free = np.asarray(floor.free_mask, dtype=bool)
    h = hashlib.sha256()
    h.update(str(free.shape).encode())
    h.update(np.packbits(free).tobytes())
    h.update(f"{float(floor.resolution):.9g}|{float(resolution_m):.9g}|{weights_hash}".encode())
    return h.hexdigest()


def pad_to_multiple(mask: np.ndarray, k: int) -> np.ndarray:
    """(H, W) float32 -> (H', W') zero-padded at the bottom/right to multiples of ``k`` (zero = obstacle)."""
    h, w = mask.shape
    return np.pad(mask, ((0, (-h) % k), (0, (-w) % k)))
