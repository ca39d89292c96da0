"""Map fusion for the particle filter: rooms, navigation edges, walls (Patel et al., Sec. V and VI.C).

Patel, Girgensohn and Biehl, "Fusing Map Information with a Probabilistic Sensor Model for Indoor
Localization using RF Beacons" (``/work/shared/papers/002_*``). The map enters the filter in three
places, all vectorised over particles (state arrays (R, N, D): R runs, N particles; the first two state
dims are world x, y in metres; randomness only from an explicit ``numpy.random.Generator``):

* **initialisation** (eq. 3, :meth:`MapGeometry.sample_initial`): ``round(beta * N)`` particles per run
  on navigation edges (edge chosen with probability proportional to its length, uniform along it) plus
  N(0, sigma_nav^2 I), the other ``N - round(beta * N)`` in rooms (room chosen proportional to its area,
  uniform inside) plus N(0, sigma_rm^2 I). Table I: beta 0.8, sigma_nav 2 m, sigma_rm 1 m.
  :meth:`MapGeometry.sample_uniform_free` is the map-free alternative (uniform over free pixels).
* **conditioning of resampled particles** (eqs. 4-5, :meth:`MapGeometry.condition`): jitter, then
  keep / project onto the 1 m-shrunk room / project onto the nearest navigation edge.
* **walls** (:class:`WallCrossing`): whether a motion step crosses an occupied pixel.

Spatial index (Sec. VI.C). Conditioning needs, per particle, the room containing it and the nearest
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

Obstacles. The paper's equations ignore walls and furniture: a Gaussian around an edge or a room leaves
free space, and a room box (or its 1 m-shrunk version) contains desks. This module's choice:

* initialisation (``obstacle='resample'``, default): a sample that is not in a FREE pixel is redrawn
  from its own component (edge or room, position and noise) until it is, so the initial cloud is eq. 3
  restricted to free space (``'project'`` moves it to the nearest free pixel instead, ``'keep'`` leaves
  eq. 3 untouched; after 100 rounds the few left are projected);
* conditioning (``obstacle='project'``, default): a conditioned particle that ends in a non-free pixel
  (or any particle that ends in an OCCUPIED pixel) is moved to the nearest point of the nearest free
  pixel (Euclidean distance transform); particles far from the map in UNKNOWN space or off the image
  are left alone. ``'keep'`` gives the paper's rule unchanged.

Maps without rooms or routes (most real buildings): :meth:`MapGeometry.from_building` derives what is
missing from the occupancy grid (``.derived``, ``.notes`` say so):

* routes: skeleton (``skimage.morphology.skeletonize``) of the walkable free space (clearance > 0.25 m),
  traced into a pixel graph, junction pixel clusters merged, terminal spurs shorter than
  ``1.5 x clearance at their junction + 0.5 m`` pruned (room-corner branches, furniture nubs),
  degree-2 nodes contracted, each polyline Douglas-Peucker simplified (1 pixel) and split into segments;
* rooms: free space eroded by half a door width (0.6 m: openings up to 1.2 m wide separate rooms),
  connected components (>= 0.25 m^2) as seeds, grown back over free space by a watershed on the
  clearance map (so boundaries fall in doorways), each label polygonised as the union of its pixel runs,
  simplified by one pixel. Corridors become rooms too.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import shapely
from scipy import ndimage
from shapely.geometry import LineString, MultiLineString, MultiPolygon, Polygon

from blenav.data.building import FREE, OCCUPIED, Building, Floor

DEFAULT_INDEX = "grid"
INDEX_KINDS = ("grid", "strtree")
OBSTACLE_INIT = ("resample", "project", "keep")
OBSTACLE_COND = ("project", "keep")

# cases returned by MapGeometry.condition(..., return_case=True)
CASE_FAR, CASE_IN_SHRUNK, CASE_TO_SHRUNK, CASE_TO_EDGE = 0, 1, 2, 3


# ---------------------------------------------------------------------------------------------- walls
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
        t = np.arange(1, n + 1, dtype=float) / n
        # one pass per sample along the steps (n <= max_samples), vectorised over all steps: the same points
        # and pixel arithmetic as _blocked_at on the (..., n, 2) array, without its large temporaries
        h, w = self._blocked.shape
        ox, oy = self.origin
        res = self.resolution
        x0, y0, dx, dy = p0[..., 0], p0[..., 1], d[..., 0], d[..., 1]
        out = np.zeros(p0.shape[:-1], dtype=bool)
        for tk in t:
            # fmax/fmin: a NaN position lands in the padding (off-image), as in _blocked_at
            col = np.fmin(np.fmax(np.floor(((x0 + tk * dx) - ox) / res), -1), w).astype(np.int64)
            rb = np.fmin(np.fmax(np.floor(((y0 + tk * dy) - oy) / res), -1), h).astype(np.int64)  # from the bottom
            out = out | self._blocked_pad[(h - rb) * (w + 2) + (col + 1)]
        return out


# ------------------------------------------------------------------------------------- geometry helpers
def _segments_of(geoms) -> np.ndarray:
    """2-point segments (E, 2, 2) of LineStrings / MultiLineStrings / polygon rings; zero-length dropped."""
    parts = []
    for g in geoms:
        for line in _lines_of(g):
            c = np.asarray(line.coords, dtype=float)[:, :2]
            if len(c) >= 2:
                parts.append(np.stack([c[:-1], c[1:]], axis=1))
    if not parts:
        return np.zeros((0, 2, 2))
    s = np.concatenate(parts)
    keep = np.hypot(*(s[:, 1] - s[:, 0]).T) > 1e-12
    return s[keep]


def _lines_of(g):
    if g is None or g.is_empty:
        return []
    if isinstance(g, LineString):
        return [g]
    if isinstance(g, (MultiLineString, shapely.GeometryCollection)):
        return [p for q in g.geoms for p in _lines_of(q)]
    if isinstance(g, Polygon):
        return [g.exterior, *g.interiors]
    if isinstance(g, MultiPolygon):
        return [r for p in g.geoms for r in _lines_of(p)]
    return []


def _polygons_of(g) -> list[Polygon]:
    if g is None or g.is_empty:
        return []
    if isinstance(g, Polygon):
        return [g]
    if hasattr(g, "geoms"):
        return [p for q in g.geoms for p in _polygons_of(q)]
    return []


def _project_segments(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest points q on segments [a, b] to points p (broadcast, last dim 2) and squared distances."""
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]  # explicit 2-D arithmetic: 2-3x faster than einsum
    px, py = p[..., 0] - a[..., 0], p[..., 1] - a[..., 1]
    dd = dx * dx + dy * dy
    t = np.clip((px * dx + py * dy) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    qx, qy = a[..., 0] + t * dx, a[..., 1] + t * dy
    rx, ry = p[..., 0] - qx, p[..., 1] - qy
    return np.stack([qx, qy], axis=-1), rx * rx + ry * ry


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


# --------------------------------------------------------------------------------------- shrunk rooms
@dataclass
class _Shrunk:
    """Rooms shrunk by ``shrink`` m (mitred), their boundary segments padded (n_rooms, S, 2, 2)."""

    shrink: float
    geoms: np.ndarray  # object array of (Multi)Polygons, prepared
    boundaries: np.ndarray  # object array of (Multi)LineStrings
    segs: np.ndarray  # (n_rooms, S, 2, 2), NaN padding
    effective: np.ndarray  # (n_rooms,) the shrink actually used per room


def _shrink_rooms(rooms: list[Polygon], shrink: float, notes: list[str]) -> _Shrunk:
    geoms, eff = [], []
    reduced = 0
    for poly in rooms:
        s, g = float(shrink), None
        for _ in range(6):  # halve the shrink while the shrunk room would vanish
            if s <= 1e-9:
                break
            g = poly.buffer(-s, join_style="mitre")
            if not g.is_empty and g.area > 1e-9:
                break
            s, g = s / 2, None
        if g is None:
            g, s = poly, 0.0
        if s < shrink:
            reduced += 1
        geoms.append(g)
        eff.append(s)
    if reduced and shrink > 0:
        notes.append(f"{reduced} of {len(rooms)} rooms are too narrow to shrink by {shrink} m; they are shrunk by "
                     f"less (halved until non-empty)")
    geoms_a = np.empty(len(geoms), dtype=object)
    geoms_a[:] = geoms
    shapely.prepare(geoms_a)
    bnd = shapely.boundary(geoms_a) if len(geoms) else np.empty(0, dtype=object)
    per = [_segments_of([g]) for g in geoms]
    smax = max([len(s) for s in per], default=1)
    segs = np.full((len(geoms), max(smax, 1), 2, 2), np.nan)
    for i, s in enumerate(per):
        segs[i, : len(s)] = s
    return _Shrunk(float(shrink), geoms_a, bnd, segs, np.asarray(eff))


# ---------------------------------------------------------------------------------------------- indexes
class _IndexBase:
    kind = ""

    def __init__(self, segs: np.ndarray, rooms: np.ndarray, shrunk: _Shrunk, max_edge_dist: float):
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


class GridIndex(_IndexBase):
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
        ix = np.floor((xy[:, 0] - self.x0) / self.cell).astype(np.int64)
        iy = np.floor((xy[:, 1] - self.y0) / self.cell).astype(np.int64)
        ok = (ix >= 0) & (ix < self.nx) & (iy >= 0) & (iy < self.ny)
        cid = np.where(ok, iy * self.nx + ix, -1)
        return cid

    def nearest_edge(self, xy):
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
        q, d2 = _project_segments(xy[sel, None, :], s[:, :, 0], s[:, :, 1])
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
        s = self.shrunk.segs[k]  # (P, S, 2, 2), NaN padded
        q, d2 = _project_segments(xy[:, None, :], s[:, :, 0], s[:, :, 1])
        d2 = np.where(np.isnan(d2), np.inf, d2)
        j = np.argmin(d2, axis=1)
        return q[np.arange(len(xy)), j]


class STRtreeIndex(_IndexBase):
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


# ------------------------------------------------------------------------------------------ the map
@dataclass(repr=False, eq=False)
class MapGeometry:
    """Rooms and navigation edges of one floor, with the floor's occupancy grid.

    ``rooms``: list of shapely Polygons (MultiPolygons exploded); ``segments``: (E, 2, 2) array of
    2-point navigation segments (world metres). ``derived`` says which of the two were derived from the
    occupancy grid; ``notes`` records in words what was read, derived, repaired or is missing.

    Use with :class:`blenav.filters.engine.ParticleFilter`: the object is an ``initializer``
    (:meth:`sample`, :meth:`snap_free`), a ``conditioner`` (:meth:`condition`) and ``walls``
    (:attr:`walls`, a :class:`WallCrossing`).
    """

    floor: Floor
    rooms: list
    segments: np.ndarray
    building_id: str = ""
    floor_id: object = None
    room_ids: list = field(default_factory=list)
    derived: dict = field(default_factory=lambda: {"rooms": False, "routes": False})
    notes: list = field(default_factory=list)
    index: str = DEFAULT_INDEX

    def __post_init__(self):
        if self.index not in INDEX_KINDS:
            raise ValueError(f"index must be one of {INDEX_KINDS}, got {self.index!r}")
        self.segments = np.asarray(self.segments, dtype=float).reshape(-1, 2, 2)
        ids = list(self.room_ids) if len(self.room_ids) == len(self.rooms) else [f"room{i}" for i in
                                                                                range(len(self.rooms))]
        rooms, room_ids = [], []
        for rid, g in zip(ids, self.rooms):  # explode MultiPolygons, drop empty parts
            parts = [p for p in _polygons_of(g) if p.area > 0]
            rooms += parts
            room_ids += [rid] if len(parts) == 1 else [f"{rid}#{j}" for j in range(len(parts))]
        self.rooms, self.room_ids = rooms, room_ids
        self._rooms_arr = np.empty(len(self.rooms), dtype=object)
        self._rooms_arr[:] = self.rooms
        shapely.prepare(self._rooms_arr)
        self._indexes: dict = {}
        self._shrunk: dict = {}
        self._nearest_free = None
        self._bbox = None
        self.walls = WallCrossing.from_floor(self.floor)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_building(cls, building: Building | str | Path, floor_id, derive_missing: bool = True,
                      index: str = DEFAULT_INDEX, **derive_kw) -> "MapGeometry":
        """Rooms and routes of ``floor_id`` from ``rooms.geojson`` / ``navgraph.geojson``; what is missing
        is derived from the occupancy grid when ``derive_missing`` (see :func:`derive_routes`,
        :func:`derive_rooms`; ``derive_kw`` are passed on). Raises ``ValueError`` when the floor has no
        free pixel.
        """
        unknown = set(derive_kw) - _ROOM_KW - _ROUTE_KW
        if unknown:
            raise TypeError(f"unknown derivation option(s) {sorted(unknown)}; known: {sorted(_ROOM_KW | _ROUTE_KW)}")
        if not isinstance(building, Building):
            building = Building.load(Path(building))
        floor = building.floor(floor_id)
        where = f"building '{building.id}' floor {floor_id!r}"
        if not floor.free_mask.any():
            raise ValueError(f"{where} has no free space: every pixel of {floor.image_path.name} is occupied or "
                             f"unknown (check the image and its free_thresh/occupied_thresh/negate)")
        notes: list[str] = []
        derived = {"rooms": False, "routes": False}

        rooms, room_ids = [], []
        for reg in building.rooms_on(floor.id):
            g = reg.geometry
            if not g.is_valid:
                g = shapely.make_valid(g)
                notes.append(f"room {reg.id}: invalid polygon repaired with make_valid")
            parts = [p for p in _polygons_of(g) if p.area > 0]
            for j, p in enumerate(parts):
                rooms.append(p)
                room_ids.append(reg.id if len(parts) == 1 else f"{reg.id}#{j}")
        if rooms:
            notes.append(f"rooms: {len(rooms)} polygons from rooms.geojson")
        elif derive_missing:
            rooms = derive_rooms(floor, **{k: v for k, v in derive_kw.items() if k in _ROOM_KW})
            room_ids = [f"derived{i:03d}" for i in range(len(rooms))]
            derived["rooms"] = True
            cover = sum(p.area for p in rooms) / (floor.free_mask.sum() * floor.resolution**2)
            notes.append(f"rooms: none in rooms.geojson for this floor; derived {len(rooms)} from the occupancy grid "
                         f"(free space split at doorways), covering {cover:.0%} of the free area")
        else:
            notes.append("rooms: none for this floor (derive_missing=False)")

        segs = _segments_of([r.geometry for r in building.routes_on(floor.id)])
        if len(segs):
            notes.append(f"routes: {len(segs)} segments from navgraph.geojson")
        elif derive_missing:
            lines = derive_routes(floor, **{k: v for k, v in derive_kw.items() if k in _ROUTE_KW})
            segs = _segments_of(lines)
            derived["routes"] = True
            notes.append(f"routes: none in navgraph.geojson for this floor; derived {len(segs)} segments "
                         f"({sum(ln.length for ln in lines):.0f} m) from the skeleton of free space")
        else:
            notes.append("routes: none for this floor (derive_missing=False)")
        if rooms and not len(segs):
            notes.append("no routes: sample_initial puts every particle in rooms (beta ignored) and condition never "
                         "projects onto a route")
        elif len(segs) and not rooms:
            notes.append("no rooms: sample_initial puts every particle around routes (beta ignored)")
        elif not rooms and not len(segs):
            notes.append("no rooms and no routes: sample_initial falls back to uniform over free space and "
                         "condition only keeps particles out of obstacles")
            warnings.warn(f"{where}: no rooms and no routes; map fusion is reduced to free-space checks",
                          stacklevel=2)
        return cls(floor=floor, rooms=rooms, segments=segs, building_id=building.id, floor_id=floor.id,
                   room_ids=room_ids, derived=derived, notes=notes, index=index)

    # ------------------------------------------------------------------ properties
    @property
    def n_rooms(self) -> int:
        return len(self.rooms)

    @property
    def n_edges(self) -> int:
        return len(self.segments)

    @property
    def room_areas(self) -> np.ndarray:
        return shapely.area(self._rooms_arr) if self.n_rooms else np.zeros(0)

    @property
    def edge_lengths(self) -> np.ndarray:
        return np.hypot(*(self.segments[:, 1] - self.segments[:, 0]).T) if self.n_edges else np.zeros(0)

    def __repr__(self) -> str:
        return (f"MapGeometry(building={self.building_id!r}, floor={self.floor_id!r}, rooms={self.n_rooms}, "
                f"edges={self.n_edges}, derived={self.derived}, index={self.index!r})")

    def describe(self) -> str:
        return (f"MapGeometry(building={self.building_id!r}, floor={self.floor_id!r}: {self.n_rooms} rooms, "
                f"{self.n_edges} edges, derived={self.derived}, index={self.index!r})\n  "
                + "\n  ".join(self.notes))

    def _bounds(self):
        if self._bbox is None:
            xmin, xmax, ymin, ymax = self.floor.extent
            b = [xmin, ymin, xmax, ymax]
            if self.n_edges:
                b = [min(b[0], self.segments[..., 0].min()), min(b[1], self.segments[..., 1].min()),
                     max(b[2], self.segments[..., 0].max()), max(b[3], self.segments[..., 1].max())]
            if self.n_rooms:
                rb = shapely.total_bounds(self._rooms_arr)
                b = [min(b[0], rb[0]), min(b[1], rb[1]), max(b[2], rb[2]), max(b[3], rb[3])]
            self._bbox = tuple(float(v) for v in b)
        return self._bbox

    def shrunk_rooms(self, shrink: float = 1.0) -> _Shrunk:
        key = float(shrink)
        if key not in self._shrunk:
            self._shrunk[key] = _shrink_rooms(self.rooms, key, self.notes)
        return self._shrunk[key]

    def get_index(self, kind: str | None = None, max_edge_dist: float = 3.0, shrink: float = 1.0) -> _IndexBase:
        """The spatial index ``kind`` ('grid' | 'strtree'; default :attr:`index`), built once per
        (kind, max_edge_dist, shrink)."""
        kind = kind or self.index
        if kind not in INDEX_KINDS:
            raise ValueError(f"index must be one of {INDEX_KINDS}, got {kind!r}")
        key = (kind, float(max_edge_dist), float(shrink))
        if key not in self._indexes:
            sh = self.shrunk_rooms(shrink)
            if kind == "grid":
                self._indexes[key] = GridIndex(self.segments, self._rooms_arr, sh, max_edge_dist, self._bounds())
            else:
                self._indexes[key] = STRtreeIndex(self.segments, self._rooms_arr, sh, max_edge_dist)
        return self._indexes[key]

    # ------------------------------------------------------------------ queries
    def nearest_edge(self, xy: np.ndarray, max_edge_dist: float = 3.0, index: str | None = None):
        """For points (..., 2): the perpendicular (closest-point) projection onto the nearest navigation
        segment within ``max_edge_dist``, its distance and the segment index. Points with no segment that
        close keep their position, get distance inf and index -1."""
        xy = np.asarray(xy, dtype=float)
        flat = xy[..., :2].reshape(-1, 2)
        proj, dist, idx = self.get_index(index, max_edge_dist).nearest_edge(flat)
        shp = xy.shape[:-1]
        return proj.reshape(*shp, 2), dist.reshape(shp), idx.reshape(shp)

    def room_of(self, xy: np.ndarray, index: str | None = None, max_edge_dist: float = 3.0) -> np.ndarray:
        """Index of the room containing each point (lowest index if rooms overlap), -1 outside all rooms."""
        xy = np.asarray(xy, dtype=float)
        flat = xy[..., :2].reshape(-1, 2)
        return self.get_index(index, max_edge_dist).room_of(flat).reshape(xy.shape[:-1])

    def snap_free(self, xy: np.ndarray, only: np.ndarray | None = None) -> np.ndarray:
        """Move points whose pixel is not FREE (restricted to ``only`` if given) to the nearest point of the
        nearest free pixel; off-image points are first clipped onto the image. Returns a new array."""
        xy = np.array(xy, dtype=float, copy=True)
        p = xy[..., :2]
        bad = ~self.floor.is_free(p)
        if only is not None:
            bad &= only
        if not bad.any():
            return xy
        fl = self.floor
        if self._nearest_free is None:
            blocked = ~fl.free_mask
            _, ind = ndimage.distance_transform_edt(blocked, return_indices=True)
            self._nearest_free = ind.astype(np.int32)
        h, w = fl.shape
        pts = p[bad]
        row, col = fl.world_to_pixel(pts)
        row, col = np.clip(row, 0, h - 1), np.clip(col, 0, w - 1)
        fr, fc = self._nearest_free[0, row, col], self._nearest_free[1, row, col]
        res, (ox, oy) = fl.resolution, fl.origin
        eps = 1e-3 * res
        cx0 = ox + fc * res
        cy0 = oy + (h - 1 - fr) * res
        pts[:, 0] = np.clip(pts[:, 0], cx0 + eps, cx0 + res - eps)
        pts[:, 1] = np.clip(pts[:, 1], cy0 + eps, cy0 + res - eps)
        p[bad] = pts
        return xy

    # ------------------------------------------------------------------ initialisation
    def sample_uniform_free(self, rng: np.random.Generator, R: int, N: int) -> np.ndarray:
        """(R, N, 2) uniform over the free pixels of the floor (global localisation without a map prior)."""
        r, c = np.nonzero(self.floor.free_mask)
        k = rng.integers(0, len(r), size=(R, N))
        centre = self.floor.pixel_to_world(r[k], c[k])
        return centre + (rng.random((R, N, 2)) - 0.5) * self.floor.resolution

    def sample_free_within(self, rng: np.random.Generator, centres: np.ndarray, N: int, radius: float,
                           max_rounds: int = 30) -> np.ndarray:
        """(M, N, 2) world m: N points per centre (M, 2), uniform over the FREE space within ``radius`` (m).

        Roy's re-initialisation (section 3.2, r_reinit = 5 m). Vectorised rejection from the disc (radius
        ``radius * sqrt(U)``, uniform angle) for ``max_rounds`` rounds; the few points still not free after
        that (a disc that is mostly wall) are drawn uniformly among the free pixels inside that disc (one
        ``nonzero`` per such centre, not per particle), or, when the disc holds no free pixel, moved to
        the nearest free pixel (:meth:`snap_free`).
        """
        c = np.asarray(centres, dtype=float).reshape(-1, 2)
        M = len(c)
        r = float(radius)

        def draw(n_pts, cen):
            rad = r * np.sqrt(rng.random(n_pts))
            ang = rng.uniform(-np.pi, np.pi, n_pts)
            return cen + np.stack([rad * np.cos(ang), rad * np.sin(ang)], axis=-1)

        xy = draw((M, N), c[:, None, :])
        for _ in range(max_rounds):
            bad = ~self.floor.is_free(xy)
            if not bad.any():
                return xy
            m_idx = np.nonzero(bad)[0]
            xy[bad] = draw(len(m_idx), c[m_idx])
        bad = ~self.floor.is_free(xy)
        if bad.any():
            pts = self.floor.free_points()
            res = self.floor.resolution
            for m in np.unique(np.nonzero(bad)[0]):  # rare: a loop over runs, never over particles
                row = bad[m]
                inside = pts[np.sum((pts - c[m]) ** 2, axis=1) <= r * r]
                if len(inside):
                    k = rng.integers(0, len(inside), int(row.sum()))
                    xy[m, row] = inside[k] + (rng.random((len(k), 2)) - 0.5) * res
                else:
                    xy[m, row] = self.snap_free(xy[m, row])
        return xy

    def _draw_edges(self, rng, shape, sigma):
        L = self.edge_lengths
        e = rng.choice(self.n_edges, size=shape, p=L / L.sum())
        t = rng.random(shape)[..., None]
        a, b = self.segments[e, 0], self.segments[e, 1]
        return a + t * (b - a) + sigma * rng.standard_normal(shape + (2,))

    def _draw_rooms(self, rng, shape, sigma):
        A = self.room_areas
        k = rng.choice(self.n_rooms, size=shape, p=A / A.sum()).ravel()
        bounds = shapely.bounds(self._rooms_arr)  # (n_rooms, 4)
        out = np.empty((k.size, 2))
        todo = np.arange(k.size)
        for _ in range(10_000):  # vectorised rejection from each room's bounding box
            if not len(todo):
                break
            b = bounds[k[todo]]
            u = rng.random((len(todo), 2))
            x = b[:, 0] + u[:, 0] * (b[:, 2] - b[:, 0])
            y = b[:, 1] + u[:, 1] * (b[:, 3] - b[:, 1])
            ok = shapely.contains_xy(self._rooms_arr[k[todo]], x, y)
            out[todo[ok], 0], out[todo[ok], 1] = x[ok], y[ok]
            todo = todo[~ok]
        if len(todo):
            raise RuntimeError("rejection sampling inside rooms did not converge (degenerate room polygons?)")
        return out.reshape(shape + (2,)) + sigma * rng.standard_normal(shape + (2,))

    def sample_initial(self, rng: np.random.Generator, R: int, N: int, beta: float = 0.8, sigma_nav: float = 2.0,
                       sigma_rm: float = 1.0, obstacle: str = "resample", max_rounds: int = 100,
                       return_source: bool = False):
        """Eq. 3: (R, N, 2) particles, ``round(beta*N)`` per run around navigation edges, the rest in rooms.

        Edge ~ length, uniform along it, + N(0, sigma_nav^2 I); room ~ area, uniform inside (vectorised
        rejection from its bounding box), + N(0, sigma_rm^2 I). The counts per run are deterministic
        (``beta*N`` rounded): eq. 3 splits the particle set, it does not draw the split. Without edges every
        particle goes to rooms and vice versa; without either, :meth:`sample_uniform_free`.

        ``obstacle``: 'resample' (default) redraws samples outside FREE pixels from their own component
        until they are free (max ``max_rounds`` rounds, then the rest are projected); 'project' moves them to
        the nearest free pixel; 'keep' returns eq. 3 as is. With ``return_source`` also returns a bool
        (R, N) array, True for the particles drawn around edges (they come first in each run).
        """
        if obstacle not in OBSTACLE_INIT:
            raise ValueError(f"obstacle must be one of {OBSTACLE_INIT}, got {obstacle!r}")
        if not 0.0 <= beta <= 1.0:
            raise ValueError(f"beta must be in [0, 1], got {beta}")
        if not self.n_edges and not self.n_rooms:
            xy = self.sample_uniform_free(rng, R, N)
            return (xy, np.zeros((R, N), bool)) if return_source else xy
        n_nav = int(round(beta * N)) if self.n_edges else 0
        if not self.n_rooms:
            n_nav = N
        n_rm = N - n_nav
        xy = np.empty((R, N, 2))
        if n_nav:
            xy[:, :n_nav] = self._draw_edges(rng, (R, n_nav), sigma_nav)
        if n_rm:
            xy[:, n_nav:] = self._draw_rooms(rng, (R, n_rm), sigma_rm)
        if obstacle == "resample":
            for _ in range(max_rounds):
                bad = ~self.floor.is_free(xy)
                if not bad.any():
                    break
                bn, br = bad[:, :n_nav], bad[:, n_nav:]
                if bn.any():
                    xy[:, :n_nav][bn] = self._draw_edges(rng, (int(bn.sum()),), sigma_nav)
                if br.any():
                    xy[:, n_nav:][br] = self._draw_rooms(rng, (int(br.sum()),), sigma_rm)
        if obstacle in ("resample", "project"):
            xy = self.snap_free(xy)
        if return_source:
            src = np.zeros((R, N), dtype=bool)
            src[:, :n_nav] = True
            return xy, src
        return xy

    def sample(self, rng: np.random.Generator, R: int, N: int) -> np.ndarray:
        """The filter engine's initializer hook: :meth:`sample_initial` with Table I's parameters."""
        return self.sample_initial(rng, R, N)

    # ------------------------------------------------------------------ conditioning
    def condition(self, x_xy: np.ndarray, rng: np.random.Generator, sigma: float | np.ndarray | None = None,
                  max_edge_dist: float = 3.0, shrink: float = 1.0, sigma_nav: float = 2.0, sigma_rm: float = 1.0,
                  mask: np.ndarray | None = None, index: str | None = None, obstacle: str = "project",
                  return_case: bool = False):
        """Eqs. 4-5: jitter freshly resampled particles, then condition them on the map.

        ``x_xy`` (..., D >= 2): copies of the strong particles (the first two dims are x, y); a new array of
        the same shape is returned with only x, y changed (only where ``mask``, if given, is true).

        Interpretation of the paper, step by step, per particle:

        1. eq. 4: ``x_new = x_stg + N(0, sigma^2 I)``. The paper only says the new particles are
           conditioned "using the same parameters as used during the initialization": with
           ``sigma=None`` (default) a particle whose parent lies in a room is jittered with ``sigma_rm``
           (1 m), any other with ``sigma_nav`` (2 m). Pass ``sigma`` (scalar or broadcastable array, e.g.
           Table I's 0.1 m motion noise) to override; ``sigma=0`` conditions without jitter.
        2. eq. 5, rooms first: if ``x_new`` is inside a room (the lowest-indexed if rooms overlap) and
           inside that room shrunk by ``shrink`` m (mitred negative buffer; a room too narrow to shrink by
           ``shrink`` is shrunk by the largest of shrink/2, shrink/4, ... that leaves it non-empty) it is
           kept ("not conditioned any further"); inside the room but outside the shrunk room ("on the
           periphery") it is projected onto the nearest point of the shrunk room's boundary. A particle
           in a room is never pulled onto an edge.
        3. otherwise, if a navigation segment is within ``max_edge_dist`` (3 m, Sec. VI.C), it is projected
           perpendicularly onto the nearest segment (closest point: the foot of the perpendicular, or the
           segment's end point when the foot falls outside it).
        4. otherwise it is left where it is.
        5. obstacles (not in the paper): with ``obstacle='project'`` a particle conditioned in steps 2-3
           that is not in a FREE pixel, or any particle in an OCCUPIED pixel, is moved to the nearest point
           of the nearest free pixel (see :meth:`snap_free`). ``'keep'`` skips this.

        ``index``: 'grid' or 'strtree' (default :attr:`index`). ``return_case`` also returns an int8 array
        of the case per particle: 0 far from the map, 1 in a shrunk room, 2 projected onto a shrunk room,
        3 projected onto an edge (-1 where ``mask`` is false).
        """
        if obstacle not in OBSTACLE_COND:
            raise ValueError(f"obstacle must be one of {OBSTACLE_COND}, got {obstacle!r}")
        x = np.array(x_xy, dtype=float, copy=True)
        lead = x.shape[:-1]
        flat = x[..., :2].reshape(-1, 2)
        sel = np.arange(len(flat)) if mask is None else np.flatnonzero(np.broadcast_to(mask, lead).ravel())
        case = np.full(len(flat), -1, dtype=np.int8)
        if not len(sel):
            return (x, case.reshape(lead)) if return_case else x
        ix = self.get_index(index, max_edge_dist, shrink)
        p = flat[sel]
        # 1. jitter
        if sigma is None:
            parent_room = ix.room_of(p) if self.n_rooms else np.full(len(p), -1)
            s = np.where(parent_room >= 0, sigma_rm, sigma_nav)[:, None]
        else:
            s = np.broadcast_to(np.asarray(sigma, dtype=float), lead).reshape(-1)[sel][:, None]
        p = p + s * rng.standard_normal(p.shape)
        out = p.copy()
        c = np.zeros(len(p), dtype=np.int8)
        # 2. rooms
        k = ix.room_of(p) if self.n_rooms else np.full(len(p), -1)
        in_room = np.flatnonzero(k >= 0)
        if len(in_room):
            inside = ix.in_shrunk(p[in_room], k[in_room])
            c[in_room[inside]] = CASE_IN_SHRUNK
            band = in_room[~inside]
            if len(band):
                out[band] = ix.project_shrunk(p[band], k[band])
                c[band] = CASE_TO_SHRUNK
        # 3. edges
        rest = np.flatnonzero(k < 0)
        if len(rest) and self.n_edges:
            proj, _, e = ix.nearest_edge(p[rest])
            hit = e >= 0
            out[rest[hit]] = proj[hit]
            c[rest[hit]] = CASE_TO_EDGE
        # 5. obstacles
        if obstacle == "project":
            occupied = self.floor.lookup(out, outside=FREE) == OCCUPIED
            out = self.snap_free(out, only=(c > CASE_FAR) | occupied)
        flat[sel] = out
        case[sel] = c
        x[..., :2] = flat.reshape(lead + (2,))
        return (x, case.reshape(lead)) if return_case else x

    def uniform_initializer(self) -> "_UniformFree":
        """An engine ``initializer`` that samples uniformly over free space (000's global localisation)."""
        return _UniformFree(self)


class _UniformFree:
    def __init__(self, m: MapGeometry):
        self.map = m

    def sample(self, rng, R, N):
        return self.map.sample_uniform_free(rng, R, N)

    def snap_free(self, xy):
        return self.map.snap_free(xy)


# ------------------------------------------------------------------------------------------ derivation
_ROOM_KW = {"door_width", "min_seed_area", "min_room_area", "derive_resolution"}
_ROUTE_KW = {"min_clearance", "spur_min", "spur_factor", "derive_resolution"}
_OFFS = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]


def _free_grid(floor: Floor, derive_resolution: float):
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


def _clearance(free: np.ndarray, res: float) -> np.ndarray:
    """Distance (m) from each free pixel centre to the nearest non-free pixel centre (image border blocks)."""
    pad = np.pad(free, 1, constant_values=False)
    return ndimage.distance_transform_edt(pad)[1:-1, 1:-1] * res


def _px_to_world(rows, cols, h, res, origin):
    x = origin[0] + (np.asarray(cols, float) + 0.5) * res
    y = origin[1] + (h - 1 - np.asarray(rows, float) + 0.5) * res
    return np.stack([x, y], axis=-1)


def derive_rooms(floor: Floor, door_width: float = 1.2, min_seed_area: float = 0.25, min_room_area: float = 0.5,
                 derive_resolution: float = 0.1) -> list[Polygon]:
    """Rooms as connected free regions separated at doorways (see the module docstring)."""
    from skimage.segmentation import watershed

    free, res, origin = _free_grid(floor, derive_resolution)
    if not free.any():
        return []
    clear = _clearance(free, res)
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
        out += [p for p in _polygons_of(g) if p.area >= min_area]
    return out


def derive_routes(floor: Floor, min_clearance: float = 0.25, spur_min: float = 0.5, spur_factor: float = 1.5,
                  derive_resolution: float = 0.1) -> list[LineString]:
    """Routes as the pruned skeleton of walkable free space (see the module docstring)."""
    from skimage.morphology import skeletonize

    free, res, origin = _free_grid(floor, derive_resolution)
    clear = _clearance(free, res)
    walk = clear > min_clearance
    if not walk.any():
        walk = free
    skel = skeletonize(walk)
    h = skel.shape[0]
    edges, node_px = _skeleton_graph(skel)
    rr, cc = np.nonzero(skel)
    node_clear = {u: clear[rr[p], cc[p]] for u, p in node_px.items()}

    def length(e):
        c = np.stack([rr[e[2]], cc[e[2]]], 1).astype(float)
        return float(np.hypot(*np.diff(c, axis=0).T).sum()) * res

    edges = _contract(edges)
    edges = _prune(edges, length, lambda u: spur_factor * node_clear.get(u, 0.0) + spur_min, spur_min)
    edges = _contract(edges)
    edges = _prune(edges, length, lambda u: spur_min, spur_min)
    edges = _contract(edges)
    lines = []
    for _, _, path in edges:
        if len(path) < 2:
            continue
        xy = _px_to_world(rr[path], cc[path], h, res, origin)
        ln = LineString(xy).simplify(res, preserve_topology=False)
        if ln.length > 0:
            lines.append(ln)
    return lines


def _skeleton_graph(skel: np.ndarray):
    """Trace a one-pixel skeleton into edges (u, v, [pixel ids]) between node clusters.

    Nodes are pixels with a neighbour count other than 2; 8-adjacent node pixels form one cluster (a
    junction), represented by its member nearest to the cluster centroid. Edge pixel lists start and end
    at the representative pixels. Pure cycles get u = v = a new node.
    """
    h, w = skel.shape
    rr, cc = np.nonzero(skel)
    n = rr.size
    if n == 0:
        return [], {}
    pad = np.full((h + 2, w + 2), -1, dtype=np.int64)
    pad[rr + 1, cc + 1] = np.arange(n)
    nb = np.stack([pad[rr + 1 + dr, cc + 1 + dc] for dr, dc in _OFFS], axis=1)
    deg = (nb >= 0).sum(axis=1)
    is_node = deg != 2
    nodemask = np.zeros((h, w), dtype=bool)
    nodemask[rr[is_node], cc[is_node]] = True
    lab, ncl = ndimage.label(nodemask, structure=np.ones((3, 3)))
    clu = (lab[rr, cc] - 1).tolist()
    # representative pixel per cluster
    ids = np.flatnonzero(is_node)
    cl = lab[rr[ids], cc[ids]] - 1
    cnt = np.bincount(cl, minlength=ncl)
    cy = np.bincount(cl, rr[ids], minlength=ncl) / np.maximum(cnt, 1)
    cx = np.bincount(cl, cc[ids], minlength=ncl) / np.maximum(cnt, 1)
    d = (rr[ids] - cy[cl]) ** 2 + (cc[ids] - cx[cl]) ** 2
    order = np.lexsort((d, cl))
    first = np.concatenate([[True], cl[order][1:] != cl[order][:-1]])
    rep = {int(c): int(p) for c, p in zip(cl[order][first], ids[order][first])}

    nbl = [[q for q in row if q >= 0] for row in nb.tolist()]
    visited = [False] * n
    edges = []
    for p in ids.tolist():
        u = clu[p]
        for q in nbl[p]:
            if clu[q] >= 0 or visited[q]:
                continue
            path = [rep[u], p, q] if p != rep[u] else [p, q]
            visited[q] = True
            prev, cur = p, q
            v = None
            while True:
                a = nbl[cur]
                nxt = a[1] if a[0] == prev else a[0]
                if clu[nxt] >= 0:
                    v = clu[nxt]
                    path += [nxt] if nxt == rep[v] else [nxt, rep[v]]
                    break
                if visited[nxt]:  # should not happen on a thin skeleton
                    break
                visited[nxt] = True
                path.append(nxt)
                prev, cur = cur, nxt
            if v is not None:
                edges.append((u, v, path))
    next_node = ncl
    for s in range(n):  # pure cycles (no node pixel)
        if visited[s] or clu[s] >= 0:
            continue
        visited[s] = True
        path = [s]
        prev, cur = nbl[s][1], s
        while True:
            a = nbl[cur]
            nxt = a[1] if a[0] == prev else a[0]
            path.append(nxt)
            if nxt == s or visited[nxt]:
                break
            visited[nxt] = True
            prev, cur = cur, nxt
        rep[next_node] = s
        edges.append((next_node, next_node, path))
        next_node += 1
    return edges, rep


def _degrees(edges):
    deg: dict = {}
    for u, v, _ in edges:
        deg[u] = deg.get(u, 0) + 1
        deg[v] = deg.get(v, 0) + 1
    return deg


def _prune(edges, length, spur_limit, spur_min):
    """Drop terminal edges (one end of degree 1) shorter than ``spur_limit(junction)``, isolated edges
    (both ends of degree 1) shorter than ``2 * spur_min`` and self-loops shorter than ``4 * spur_min``."""
    deg = _degrees(edges)
    out = []
    for e in edges:
        u, v, _ = e
        L = length(e)
        if u == v:
            if L < 4 * spur_min:
                continue
        elif deg[u] == 1 and deg[v] == 1:
            if L < 2 * spur_min:
                continue
        elif deg[u] == 1 or deg[v] == 1:
            j = v if deg[u] == 1 else u
            if L < spur_limit(j):
                continue
        out.append(e)
    return out


def _contract(edges):
    """Merge the two edges meeting at every node of degree 2 (other than a self-loop's node)."""
    edges = {i: e for i, e in enumerate(edges)}
    adj: dict = {}
    for i, (u, v, _) in edges.items():
        adj.setdefault(u, []).append(i)
        adj.setdefault(v, []).append(i)
    nid = len(edges)
    for node in list(adj):
        inc = adj.get(node, [])
        if len(inc) != 2 or inc[0] == inc[1]:
            continue
        i, j = inc
        ui, vi, pi = edges[i]
        uj, vj, pj = edges[j]
        if vi != node:  # orient i to end at node
            ui, vi, pi = vi, ui, pi[::-1]
        if uj != node:  # orient j to start at node
            uj, vj, pj = vj, uj, pj[::-1]
        new = (ui, vj, pi + pj[1:])
        del edges[i], edges[j]
        edges[nid] = new
        for end, old in ((ui, i), (vj, j)):
            lst = adj[end]
            lst[lst.index(old)] = nid
        adj[node] = []
        nid += 1
    return list(edges.values())
