"""The CRF's state space: a regular grid over a floor's free space and its sparse transitions (004 sec. IV).

"We uniformly discretize the ... domain" (004 sec. IV) at ``cell_m`` (0.5 m in 004 sec. VI-D), one layer at
the device height. A cell is a state when its centre lies on a FREE pixel of the floor's occupancy grid
and at least ``min_free_fraction`` of its pixels are FREE (a cell mostly made of wall or unknown space is no
place to be). Transitions connect a cell to every cell whose centre is within ``max_step_m`` and reachable
along the straight segment between the two centres without touching a pixel that is not FREE (walls,
furniture, unknown space); every cell has a self transition. The segment is sampled every half pixel, so
a wall one pixel thick cannot be jumped.

Edges are stored twice in CSR form (numpy arrays, no Python objects per cell):

* by source: ``src_ptr`` (N+1,), ``dst`` (E,): the edges leaving cell k are ``src_ptr[k]:src_ptr[k+1]``,
  with ``dist`` (E,) m and ``angle`` (E,) rad (direction from source to target, CCW from +x; 0 for self
  edges);
* by target: ``tgt_ptr`` (N+1,), ``tsrc`` (E,) the source of each incoming edge, ``tedge`` (E,) its row in
  the by-source arrays;
* the D offsets of a full neighbourhood, ``off_dist`` (D,), ``off_angle`` (D,): a cell with D edges has
  exactly these (the Viterbi kernel computes their normaliser once per step).

World frame: x east, y north (m); cell (cy, cx) has centre origin + ((cx + 0.5) cell_m, (cy + 0.5) cell_m).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from blenav.data.floor import FREE
from blenav.limits import check_memory

__all__ = ["CrfGrid", "build_grid", "grid_from_occupancy"]


@dataclass
class CrfGrid:
    """Cells (N) of one floor and their transitions (E edges); see the module docstring for the layout."""

    cell_m: float
    origin: tuple[float, float]
    shape: tuple[int, int]  # (ny, nx) cells over the floor's extent
    index: np.ndarray  # (ny, nx) int32 cell id, -1 where not a state
    cy: np.ndarray  # (N,) int32
    cx: np.ndarray  # (N,) int32
    xy: np.ndarray  # (N, 2) m, cell centres
    max_step_m: float
    src_ptr: np.ndarray  # (N+1,) int64
    dst: np.ndarray  # (E,) int32
    dist: np.ndarray  # (E,) float64 m
    angle: np.ndarray  # (E,) float64 rad
    tgt_ptr: np.ndarray  # (N+1,) int64
    tsrc: np.ndarray  # (E,) int32
    tedge: np.ndarray  # (E,) int64
    off_dist: np.ndarray  # (D,) m: the offsets of a full neighbourhood (a cell far from walls has all D edges)
    off_angle: np.ndarray  # (D,) rad

    @property
    def n_cells(self) -> int:
        return int(len(self.xy))

    @property
    def n_edges(self) -> int:
        return int(len(self.dst))

    @property
    def area_m2(self) -> float:
        return self.n_cells * self.cell_m**2

    def cell_of(self, xy: np.ndarray) -> np.ndarray:
        """Cell id (...) of world points (..., 2): the state containing the point, else the nearest state."""
        xy = np.atleast_2d(np.asarray(xy, float))
        cx = np.floor((xy[:, 0] - self.origin[0]) / self.cell_m).astype(np.int64)
        cy = np.floor((xy[:, 1] - self.origin[1]) / self.cell_m).astype(np.int64)
        ny, nx = self.shape
        inside = (cx >= 0) & (cx < nx) & (cy >= 0) & (cy < ny)
        out = np.full(len(xy), -1, np.int64)
        out[inside] = self.index[cy[inside], cx[inside]]
        miss = np.flatnonzero(out < 0)
        for i in miss:  # rare: off the states; nearest centre
            out[i] = int(np.argmin(((self.xy - xy[i]) ** 2).sum(1)))
        return out

    def nbytes(self) -> int:
        return sum(getattr(self, k).nbytes for k in ("index", "cy", "cx", "xy", "src_ptr", "dst", "dist", "angle",
                                                      "tgt_ptr", "tsrc", "tedge"))


def build_grid(floor, cell_m: float = 0.5, max_step_m: float = 2.0, min_free_fraction: float = 0.5) -> CrfGrid:
    """The grid of a :class:`blenav.data.floor.Floor` (its occupancy, resolution and origin)."""
    return grid_from_occupancy(floor.occupancy, floor.resolution, tuple(floor.origin), cell_m, max_step_m,
                               min_free_fraction)


def grid_from_occupancy(occ: np.ndarray, resolution: float, origin: tuple[float, float], cell_m: float = 0.5,
                        max_step_m: float = 2.0, min_free_fraction: float = 0.5) -> CrfGrid:
    """The grid over an occupancy image (H, W) (row 0 at the top, ROS map_server semantics: FREE = 0) of
    ``resolution`` m/pixel whose lower-left corner is at world ``origin``."""
    if not cell_m > 0 or not max_step_m >= 0:
        raise ValueError(f"grid: need cell_m > 0 and max_step_m >= 0 (got {cell_m}, {max_step_m})")
    occ = np.asarray(occ)
    H, W = occ.shape
    free = occ == FREE
    x0, y0 = float(origin[0]), float(origin[1])
    nx = max(1, int(np.ceil(W * resolution / cell_m - 1e-9)))
    ny = max(1, int(np.ceil(H * resolution / cell_m - 1e-9)))
    check_memory(grid_bytes(nx * ny, cell_m, max_step_m, H * W), f"a grid of {ny:,} x {nx:,} cells of {cell_m:g} m "
                 f"with steps up to {max_step_m:g} m", "crf grid (cell_m, max_step_m)")
    frac = _free_fraction(free, resolution, cell_m, nx, ny)
    gcy, gcx = np.mgrid[0:ny, 0:nx]
    cxw = x0 + (gcx + 0.5) * cell_m
    cyw = y0 + (gcy + 0.5) * cell_m
    state = _is_free(free, resolution, x0, y0, cxw, cyw) & (frac >= min_free_fraction)
    index = np.full((ny, nx), -1, np.int32)
    cy, cx = np.nonzero(state)
    N = len(cy)
    if N == 0:
        raise ValueError("grid: the floor has no free cell of "
                         f"{cell_m} m (min_free_fraction {min_free_fraction})")
    index[cy, cx] = np.arange(N, dtype=np.int32)
    xy = np.column_stack([x0 + (cx + 0.5) * cell_m, y0 + (cy + 0.5) * cell_m])
    odx, ody = _offsets(cell_m, max_step_m)
    src, dst, dist, ang = _edges(free, resolution, (x0, y0), cell_m, index, cy, cx, xy, odx, ody)
    order = np.lexsort((dst, src))
    src, dst, dist, ang = src[order], dst[order], dist[order], ang[order]
    src_ptr = np.concatenate([[0], np.cumsum(np.bincount(src, minlength=N))]).astype(np.int64)
    torder = np.lexsort((src, dst))
    tgt_ptr = np.concatenate([[0], np.cumsum(np.bincount(dst, minlength=N))]).astype(np.int64)
    return CrfGrid(float(cell_m), (x0, y0), (ny, nx), index, cy.astype(np.int32), cx.astype(np.int32), xy,
                   float(max_step_m), src_ptr, dst.astype(np.int32), dist, ang, tgt_ptr,
                   src[torder].astype(np.int32), torder.astype(np.int64), np.hypot(odx, ody) * cell_m,
                   np.where((odx != 0) | (ody != 0), np.arctan2(ody, odx), 0.0).astype(float))


def grid_bytes(n_cells: int, cell_m: float, max_step_m: float, n_pixels: int = 0) -> float:
    """Estimated peak bytes of :func:`grid_from_occupancy`: about 64 bytes per cell (index, centres, free
    fraction and the mgrids behind them), 64 per possible edge (one per cell and neighbourhood offset: source,
    target, length, angle and the sorted copies) and 48 per pixel (the free-fraction pass), all upper bounds:
    a floor's free cells are fewer than its bounding box's."""
    k = float(max_step_m) / float(cell_m)
    offsets = math.pi * (k + 1.0) ** 2
    return 64.0 * n_cells * (1.0 + offsets) + 48.0 * n_pixels


def _free_fraction(free: np.ndarray, resolution: float, cell_m: float, nx: int, ny: int) -> np.ndarray:
    """Share of FREE pixels per cell, (ny, nx) in [0, 1] (0 for a cell without pixels).

    ``free`` (H, W) bool, row 0 at the top, ``resolution`` m/pixel; cell (cy, cx) of ``cell_m`` m counts the
    pixels whose centre falls in it (pixels past the last cell go to the last row/column)."""
    H, W = free.shape
    rows, cols = np.mgrid[0:H, 0:W]
    px = (cols + 0.5) * resolution
    py = (H - 1 - rows + 0.5) * resolution
    pcx = np.minimum((px / cell_m).astype(np.int64), nx - 1)
    pcy = np.minimum((py / cell_m).astype(np.int64), ny - 1)
    flat = (pcy * nx + pcx).ravel()
    total = np.bincount(flat, minlength=nx * ny)
    nfree = np.bincount(flat, weights=free.ravel().astype(float), minlength=nx * ny)
    return np.where(total > 0, nfree / np.maximum(total, 1), 0.0).reshape(ny, nx)


def _is_free(free: np.ndarray, resolution: float, x0: float, y0: float, xw: np.ndarray,
             yw: np.ndarray) -> np.ndarray:
    """Whether world points (xw, yw) (any equal shapes, m) lie on a FREE pixel of ``free`` (H, W) bool
    (``resolution`` m/pixel, lower-left corner at (x0, y0)); False off the image. Same shape as ``xw``."""
    H, W = free.shape
    c = np.floor((xw - x0) / resolution).astype(np.int64)
    r = (H - 1) - np.floor((yw - y0) / resolution).astype(np.int64)
    ok = (r >= 0) & (r < H) & (c >= 0) & (c < W)
    out = np.zeros(np.shape(xw), bool)
    out[ok] = free[r[ok], c[ok]]
    return out


def _offsets(cell_m: float, max_step_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The D cell offsets (odx, ody), each (D,) int, whose length (cells x ``cell_m``) is within ``max_step_m``
    m, the zero offset included, in row-major order of (dy, dx)."""
    k = int(np.floor(max_step_m / cell_m + 1e-9))
    ody, odx = np.mgrid[-k:k + 1, -k:k + 1]
    keep = np.hypot(ody, odx) * cell_m <= max_step_m + 1e-9
    return odx[keep], ody[keep]


def _edges(free: np.ndarray, resolution: float, origin: tuple[float, float], cell_m: float, index: np.ndarray,
           cy: np.ndarray, cx: np.ndarray, xy: np.ndarray, odx: np.ndarray, ody: np.ndarray):
    """Unsorted transitions (src (E,) int64, dst (E,) int64, dist (E,) m, angle (E,) rad) between the N states
    (cell rows ``cy``, columns ``cx``, centres ``xy`` (N, 2) m, ids in ``index`` (ny, nx)), one per offset in
    (``odx``, ``ody``) whose target is a state and whose straight segment stays on FREE pixels (sampled every
    half pixel or half cell, whichever is smaller)."""
    ny, nx = index.shape
    x0, y0 = origin
    step = 0.5 * min(resolution, cell_m)
    srcs, dsts, dists, angs = [], [], [], []
    for dy, dx in zip(ody.tolist(), odx.tolist()):  # one vectorised pass per offset (<= ~50), not per cell
        ty, tx = cy + dy, cx + dx
        ok = (ty >= 0) & (ty < ny) & (tx >= 0) & (tx < nx)
        s = np.flatnonzero(ok)
        t = index[ty[ok], tx[ok]]
        good = t >= 0
        s, t = s[good], t[good].astype(np.int64)
        L = float(np.hypot(dx, dy) * cell_m)
        if L > 0 and len(s):
            n_samp = int(np.ceil(L / step)) + 1
            f = np.linspace(0.0, 1.0, n_samp)
            sx = xy[s, 0][:, None] + f[None, :] * dx * cell_m
            sy = xy[s, 1][:, None] + f[None, :] * dy * cell_m
            clear = _is_free(free, resolution, x0, y0, sx, sy).all(axis=1)
            s, t = s[clear], t[clear]
        srcs.append(s)
        dsts.append(t)
        dists.append(np.full(len(s), L))
        angs.append(np.full(len(s), float(np.arctan2(dy, dx)) if L > 0 else 0.0))
    return np.concatenate(srcs), np.concatenate(dsts), np.concatenate(dists), np.concatenate(angs)
