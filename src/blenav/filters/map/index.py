"""Spatial indexes for conditioning (Patel et al. Sec. VI.C): the room containing a point and the nearest
navigation edge within ``max_edge_dist``. Two interchangeable implementations (``index=``):

* ``'grid'`` -- the paper's index: a 1 m grid over the map; each cell stores, as padded integer arrays,
  the edges whose distance to the cell is <= ``max_edge_dist`` and the rooms intersecting the cell, plus
  whether the cell lies wholly inside one (shrunk) room. A particle only looks at its cell's lists, so
  the nearest-edge projection is plain numpy over (P, K) candidates.
* ``'strtree'`` -- shapely 2 ``STRtree``: ``query_nearest`` for edges, ``query(predicate='within')`` for
  rooms, ``shortest_line`` for projections.

Both return the same projections (tests check 1e-9; the benchmark finds at most 9e-16 m apart).
Measured with ``benchmarks/map_index.py`` on the simulated office_45x55 building (38 rooms, 124 edge
segments), conditioning 100 runs x 300 particles with the defaults (max_edge_dist 3 m, shrink 1 m),
median of 30 calls on a 2-core machine: **grid 12.4 ms, STRtree 142 ms per call (11.5x)**; on the
same building's derived map (42 rooms, 298 segments) 17.8 ms vs 191 ms (10.8x). So
:data:`DEFAULT_INDEX` is ``'grid'``. The grid is built lazily, once per (max_edge_dist, shrink), in about
15 ms (3 456 cells; 2.3 candidate edges and 0.73 rooms per cell on average, at most 13 and 4). Most of
the STRtree time goes to building shapely Point objects and the GEOS queries.
"""

from __future__ import annotations

import numpy as np
import shapely

from . import kernels as K
from .shapes import ShrunkRooms, project_segments

DEFAULT_INDEX = "grid"
INDEX_KINDS = ("grid", "strtree")


def _pad_lists(pairs_row: np.ndarray, pairs_col: np.ndarray, n_rows: int) -> np.ndarray:
    """Group ``pairs_col`` by ``pairs_row`` into a (n_rows, K) int array padded with -1, each row sorted."""
    order = np.lexsort((pairs_col, pairs_row))
    r, c = pairs_row[order], pairs_col[order]
    counts = np.bincount(r, minlength=n_rows)
    k = max(int(counts.max(initial=0)), 1)
    out = np.full((n_rows, k), -1, dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    pos = np.arange(len(r)) - starts[r]
    out[r, pos] = c
    return out


class SpatialIndex:
    """What conditioning asks of an index; built by :meth:`MapGeometry.get_index`."""

    kind = ""

    def __init__(self, segs: np.ndarray, rooms: np.ndarray, shrunk: ShrunkRooms, max_edge_dist: float):
        self.segs = segs
        self.rooms = rooms
        self.shrunk = shrunk
        self.max_edge_dist = float(max_edge_dist)

    def nearest_edge(self, xy):  # -> proj (P,2), dist (P,), idx (P,) (-1: none within max_edge_dist)
        raise NotImplementedError

    def room_of(self, xy):  # -> (P,) int, -1 outside every room
        raise NotImplementedError

    def in_shrunk(self, xy, k):  # k >= 0 for every point
        return shapely.contains_xy(self.shrunk.geoms[k], xy[:, 0], xy[:, 1])

    def project_shrunk(self, xy, k):  # nearest point of shrunk room k's boundary
        raise NotImplementedError


class GridIndex(SpatialIndex):
    """The paper's 1 m grid (Sec. VI.C): per cell, padded lists of candidate edges and rooms."""

    kind = "grid"

    def __init__(self, segs, rooms, shrunk, max_edge_dist, bounds, cell: float = 1.0):
        super().__init__(segs, rooms, shrunk, max_edge_dist)
        self.cell = float(cell)
        m = self.max_edge_dist
        x0, y0, x1, y1 = bounds
        self.x0, self.y0 = x0 - m - self.cell, y0 - m - self.cell
        self.nx = int(np.ceil((x1 + m + self.cell - self.x0) / self.cell)) + 1
        self.ny = int(np.ceil((y1 + m + self.cell - self.y0) / self.cell)) + 1
        ix, iy = np.meshgrid(np.arange(self.nx), np.arange(self.ny), indexing="xy")
        ix, iy = ix.ravel(), iy.ravel()  # cell id = iy * nx + ix
        bx0 = self.x0 + ix * self.cell
        by0 = self.y0 + iy * self.cell
        boxes = shapely.box(bx0, by0, bx0 + self.cell, by0 + self.cell)
        n_cells = boxes.size
        if len(segs):
            lines = shapely.linestrings(segs)
            ci, ei = shapely.STRtree(lines).query(boxes, predicate="dwithin", distance=m)
        else:
            ci = ei = np.zeros(0, dtype=np.int64)
        self.cell_edges = _pad_lists(ci, ei, n_cells)
        if len(rooms):
            ci, ri = shapely.STRtree(rooms).query(boxes, predicate="intersects")
        else:
            ci = ri = np.zeros(0, dtype=np.int64)
        self.cell_rooms = _pad_lists(ci, ri, n_cells)
        # fast paths: a cell with exactly one candidate room that holds the whole cell in its interior
        n_cand = (self.cell_rooms >= 0).sum(axis=1)
        single = np.flatnonzero(n_cand == 1)
        k = self.cell_rooms[single, 0]
        full = shapely.contains_properly(rooms[k], boxes[single]) if len(single) else np.zeros(0, bool)
        self.cell_full_room = np.full(n_cells, -1, dtype=np.int64)
        self.cell_full_room[single[full]] = k[full]
        fk = self.cell_full_room >= 0
        self.cell_in_shrunk = np.zeros(n_cells, dtype=bool)
        if fk.any():
            self.cell_in_shrunk[fk] = shapely.contains_properly(shrunk.geoms[self.cell_full_room[fk]], boxes[fk])
        self.stats = {"cells": n_cells, "edges_per_cell_mean": float((self.cell_edges >= 0).sum(1).mean()),
                      "edges_per_cell_max": int((self.cell_edges >= 0).sum(1).max()),
                      "rooms_per_cell_mean": float(n_cand.mean()), "rooms_per_cell_max": int(n_cand.max())}

    def _cells(self, xy):
        # compiled (kernels.grid_cells): the ids of _cells_numpy
        return K.grid_cells(np.ascontiguousarray(xy, dtype=float), float(self.x0), float(self.y0), float(self.cell),
                            int(self.nx), int(self.ny))

    def _cells_numpy(self, xy):
        ix = np.floor((xy[:, 0] - self.x0) / self.cell).astype(np.int64)
        iy = np.floor((xy[:, 1] - self.y0) / self.cell).astype(np.int64)
        ok = (ix >= 0) & (ix < self.nx) & (iy >= 0) & (iy < self.ny)
        cid = np.where(ok, iy * self.nx + ix, -1)
        return cid

    def nearest_edge(self, xy):
        # compiled: one loop over the points and their cell's candidates (kernels.grid_nearest_edge), the numbers
        # of nearest_edge_numpy
        return K.grid_nearest_edge(np.ascontiguousarray(xy, dtype=float), float(self.x0), float(self.y0),
                                   float(self.cell), int(self.nx), int(self.ny), self.cell_edges,
                                   np.ascontiguousarray(self.segs, dtype=float).reshape(-1, 2, 2),
                                   float(self.max_edge_dist**2))

    def nearest_edge_numpy(self, xy):
        """:meth:`nearest_edge` in numpy over (P, K) candidates (the reference)."""
        P = len(xy)
        proj = xy.copy()
        dist = np.full(P, np.inf)
        idx = np.full(P, -1, dtype=np.int64)
        cid = self._cells(xy)
        sel = np.flatnonzero(cid >= 0)
        sel = sel[self.cell_edges[cid[sel], 0] >= 0]  # cells with at least one candidate
        if not len(sel) or not len(self.segs):
            return proj, dist, idx
        cand = self.cell_edges[cid[sel]]  # (P', K)
        valid = cand >= 0
        s = self.segs[np.where(valid, cand, 0)]  # (P', K, 2, 2)
        q, d2 = project_segments(xy[sel, None, :], s[:, :, 0], s[:, :, 1])
        d2 = np.where(valid & (d2 <= self.max_edge_dist**2), d2, np.inf)
        j = np.argmin(d2, axis=1)  # candidates are sorted by edge index: ties go to the lowest index
        best = d2[np.arange(len(sel)), j]
        hit = np.isfinite(best)
        rows = sel[hit]
        proj[rows] = q[hit, j[hit]]
        dist[rows] = np.sqrt(best[hit])
        idx[rows] = cand[hit, j[hit]]
        return proj, dist, idx

    def room_of(self, xy):
        # compiled grid part (kernels.grid_room_pairs / lowest_inside), shapely for the point-in-polygon
        # tests: the rooms of room_of_numpy
        xy = np.ascontiguousarray(xy, dtype=float)
        out, pi, rid = K.grid_room_pairs(self._cells(xy), self.cell_full_room, self.cell_rooms)
        if len(pi) and len(self.rooms):
            inside = shapely.contains_xy(self.rooms[rid], xy[pi, 0], xy[pi, 1])
            K.lowest_inside(out, pi, rid, inside)
        return out

    def room_of_numpy(self, xy):
        P = len(xy)
        out = np.full(P, -1, dtype=np.int64)
        cid = self._cells(xy)
        ok = cid >= 0
        full = np.full(P, -1, dtype=np.int64)
        full[ok] = self.cell_full_room[cid[ok]]
        out[full >= 0] = full[full >= 0]
        rest = np.flatnonzero(ok & (full < 0))
        if len(rest) and len(self.rooms):
            cand = self.cell_rooms[cid[rest]]  # (P', K)
            pi, kk = np.nonzero(cand >= 0)
            rid = cand[pi, kk]
            inside = shapely.contains_xy(self.rooms[rid], xy[rest[pi], 0], xy[rest[pi], 1])
            big = np.iinfo(np.int64).max
            m = np.full(cand.shape, big, dtype=np.int64)
            m[pi[inside], kk[inside]] = rid[inside]
            best = m.min(axis=1)
            out[rest] = np.where(best == big, -1, best)
        return out

    def in_shrunk(self, xy, k):
        cid = self._cells(xy)
        res = np.zeros(len(xy), dtype=bool)
        ok = cid >= 0
        fast = np.zeros(len(xy), dtype=bool)
        fast[ok] = self.cell_in_shrunk[cid[ok]] & (self.cell_full_room[cid[ok]] == k[ok])
        res[fast] = True
        slow = np.flatnonzero(~fast)
        if len(slow):
            res[slow] = shapely.contains_xy(self.shrunk.geoms[k[slow]], xy[slow, 0], xy[slow, 1])
        return res

    def project_shrunk(self, xy, k):
        # compiled (kernels.project_rings): the points of project_shrunk_numpy
        return K.project_rings(np.ascontiguousarray(xy, dtype=float), np.ascontiguousarray(k, dtype=np.int64),
                               np.ascontiguousarray(self.shrunk.segs, dtype=float))

    def project_shrunk_numpy(self, xy, k):
        s = self.shrunk.segs[k]  # (P, S, 2, 2), NaN padded
        q, d2 = project_segments(xy[:, None, :], s[:, :, 0], s[:, :, 1])
        d2 = np.where(np.isnan(d2), np.inf, d2)
        j = np.argmin(d2, axis=1)
        return q[np.arange(len(xy)), j]


class STRtreeIndex(SpatialIndex):
    """shapely 2 STRtree queries over all edges and rooms."""

    kind = "strtree"

    def __init__(self, segs, rooms, shrunk, max_edge_dist):
        super().__init__(segs, rooms, shrunk, max_edge_dist)
        self.lines = shapely.linestrings(segs) if len(segs) else np.empty(0, dtype=object)
        self.edge_tree = shapely.STRtree(self.lines)
        self.room_tree = shapely.STRtree(rooms)
        self.stats = {}

    def nearest_edge(self, xy):
        P = len(xy)
        proj = xy.copy()
        dist = np.full(P, np.inf)
        idx = np.full(P, -1, dtype=np.int64)
        if not len(self.segs) or not P:
            return proj, dist, idx
        pts = shapely.points(xy)
        pi, ei = self.edge_tree.query_nearest(pts, max_distance=self.max_edge_dist, all_matches=True)
        if not len(pi):
            return proj, dist, idx
        # among equidistant matches keep the lowest edge index (as the grid does)
        order = np.lexsort((ei, pi))
        pi, ei = pi[order], ei[order]
        first = np.concatenate([[True], pi[1:] != pi[:-1]])
        pi, ei = pi[first], ei[first]
        line = shapely.shortest_line(self.lines[ei], pts[pi])
        q = shapely.get_coordinates(line).reshape(-1, 2, 2)[:, 0]
        d = np.hypot(*(xy[pi] - q).T)
        ok = d <= self.max_edge_dist
        proj[pi[ok]] = q[ok]
        dist[pi[ok]] = d[ok]
        idx[pi[ok]] = ei[ok]
        return proj, dist, idx

    def room_of(self, xy):
        out = np.full(len(xy), -1, dtype=np.int64)
        if not len(self.rooms) or not len(xy):
            return out
        pi, ri = self.room_tree.query(shapely.points(xy), predicate="within")
        if len(pi):
            best = np.full(len(xy), np.iinfo(np.int64).max)
            np.minimum.at(best, pi, ri)
            out = np.where(best == np.iinfo(np.int64).max, -1, best)
        return out

    def project_shrunk(self, xy, k):
        line = shapely.shortest_line(self.shrunk.boundaries[k], shapely.points(xy))
        return shapely.get_coordinates(line).reshape(-1, 2, 2)[:, 0]
