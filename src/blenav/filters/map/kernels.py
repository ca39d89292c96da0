"""Compiled (numba) map queries of :mod:`blenav.filters.map`: the grid index's cells, nearest edges, rooms and
shrunk-boundary projections (:mod:`~blenav.filters.map.index`), the obstacle snap of the conditioning
(:mod:`~blenav.filters.map.conditioning`) and the wall-crossing test of a step (:mod:`~blenav.filters.map.walls`).
Each does the arithmetic of the numpy / shapely code it replaced in the same order, under the bit-identity rules
of :mod:`blenav.filters.kernels` (single-threaded, cached on disk); tests/filters/test_kernels.py and the map tests
compare them.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# ------------------------------------------------------------------------------------ map queries


@njit(cache=True, inline="always")
def _closest_on_segment(x, y, ax, ay, bx, by):
    """The closest point (qx, qy) of segment a-b to (x, y) and its squared distance (shapes.project_segments'
    arithmetic: t clamped to [0, 1], a zero-length segment projects to a)."""
    dx = bx - ax
    dy = by - ay
    px = x - ax
    py = y - ay
    dd = dx * dx + dy * dy
    t = (px * dx + py * dy) / (dd if dd > 0 else 1.0)
    if t < 0.0:
        t = 0.0
    elif t > 1.0:
        t = 1.0
    qx = ax + t * dx
    qy = ay + t * dy
    rx = x - qx
    ry = y - qy
    return qx, qy, rx * rx + ry * ry


@njit(cache=True)
def grid_nearest_edge(xy, x0, y0, cell, nx, ny, cell_edges, segs, max_d2):
    """GridIndex.nearest_edge: per point, the closest point on the nearest candidate edge of its 1 m cell
    within sqrt(max_d2) (ties: the lowest edge index); proj (P, 2) (the point itself without one), dist (P,)
    (inf), idx (P,) (-1). The arithmetic of shapes.project_segments."""
    P = xy.shape[0]
    K = cell_edges.shape[1]
    proj = np.empty((P, 2))
    dist = np.full(P, np.inf)
    idx = np.full(P, -1, np.int64)
    for p in range(P):
        x = xy[p, 0]
        y = xy[p, 1]
        proj[p, 0] = x
        proj[p, 1] = y
        fx = np.floor((x - x0) / cell)
        fy = np.floor((y - y0) / cell)
        if not (fx >= 0 and fx < nx and fy >= 0 and fy < ny):
            continue
        c = int(fy) * nx + int(fx)
        best = np.inf
        bx = 0.0
        by = 0.0
        be = -1
        for k in range(K):
            e = cell_edges[c, k]
            if e < 0:
                continue
            qx, qy, d2 = _closest_on_segment(x, y, segs[e, 0, 0], segs[e, 0, 1], segs[e, 1, 0], segs[e, 1, 1])
            if d2 <= max_d2 and d2 < best:
                best = d2
                bx = qx
                by = qy
                be = e
        if be >= 0:
            proj[p, 0] = bx
            proj[p, 1] = by
            dist[p] = np.sqrt(best)
            idx[p] = be
    return proj, dist, idx


@njit(cache=True)
def grid_cells(xy, x0, y0, cell, nx, ny):
    """GridIndex._cells: cell id iy nx + ix of each point (P, 2), -1 off the grid (and for NaN)."""
    P = xy.shape[0]
    out = np.empty(P, np.int64)
    for p in range(P):
        fx = np.floor((xy[p, 0] - x0) / cell)
        fy = np.floor((xy[p, 1] - y0) / cell)
        if fx >= 0 and fx < nx and fy >= 0 and fy < ny:
            out[p] = int(fy) * nx + int(fx)
        else:
            out[p] = -1
    return out


@njit(cache=True)
def project_rings(xy, k, segs):
    """GridIndex.project_shrunk: the closest point of room k[p]'s shrunk boundary segments segs[k[p]] (S, 2, 2,
    NaN padded) to each point (project_segments' arithmetic; argmin's first minimum, NaN distances as inf)."""
    P = xy.shape[0]
    S = segs.shape[1]
    out = np.empty((P, 2))
    for p in range(P):
        x = xy[p, 0]
        y = xy[p, 1]
        kk = k[p]
        best = np.inf
        bx = 0.0
        by = 0.0
        for j in range(S):
            qx, qy, d2 = _closest_on_segment(x, y, segs[kk, j, 0, 0], segs[kk, j, 0, 1], segs[kk, j, 1, 0],
                                             segs[kk, j, 1, 1])
            if d2 != d2:
                d2 = np.inf
            if j == 0 or d2 < best:
                best = d2
                bx = qx
                by = qy
        out[p, 0] = bx
        out[p, 1] = by
    return out


_INT64_MIN = -9223372036854775808


@njit(cache=True, inline="always")
def _np_int(f):
    """float -> int64 as numpy's astype(np.int64) gives it on x86-64: INT64_MIN for NaN and out of range."""
    if f >= -9.223372036854775808e18 and f < 9.223372036854775808e18:
        return np.int64(f)
    return np.int64(_INT64_MIN)


@njit(cache=True, inline="always")
def _pixel(x, y, ox, oy, res, h):
    """Floor.world_to_pixel for one point: (row, col), possibly off the image (a negative row where numpy's
    (h - 1) - INT64_MIN wraps around)."""
    col = _np_int(np.floor((x - ox) / res))
    iy = _np_int(np.floor((y - oy) / res))
    row = np.int64(-1) if iy == _INT64_MIN else (h - 1) - iy
    return row, col


@njit(cache=True)
def obstacle_candidates(xy, case, occupancy, ox, oy, res, free, occupied):
    """MapGeometry.condition's step 5 selection: (P,) bool, the points snap_free would move: not in a FREE
    pixel (off the image counts as not free) and (conditioned (case > 0) or in an OCCUPIED pixel)."""
    h, w = occupancy.shape
    P = xy.shape[0]
    out = np.zeros(P, np.bool_)
    for p in range(P):
        row, col = _pixel(xy[p, 0], xy[p, 1], ox, oy, res, h)
        if row >= 0 and row < h and col >= 0 and col < w:
            v = occupancy[row, col]
            out[p] = v != free and (case[p] > 0 or v == occupied)
        else:  # off the image: not free (snap_free), not occupied (lookup(outside=FREE))
            out[p] = case[p] > 0
    return out


@njit(cache=True)
def snap_to_free(xy, bad, ox, oy, res, h, w, nearest_free):
    """MapGeometry.snap_free for the points ``bad``: moved (in place) into the nearest free pixel (nearest_free
    (2, H, W): its row and column per pixel), clipped 1e-3 pixel inside it; off-image points use the
    nearest image pixel."""
    eps = 1e-3 * res
    for p in range(xy.shape[0]):
        if not bad[p]:
            continue
        x = xy[p, 0]
        y = xy[p, 1]
        r, c = _pixel(x, y, ox, oy, res, h)
        r = 0 if r < 0 else (h - 1 if r > h - 1 else r)
        c = 0 if c < 0 else (w - 1 if c > w - 1 else c)
        fr = nearest_free[0, r, c]
        fc = nearest_free[1, r, c]
        cx0 = ox + fc * res
        cy0 = oy + (h - 1 - fr) * res
        lo = cx0 + eps
        hi = cx0 + res - eps
        if x == x:
            xy[p, 0] = hi if (x if x > lo else lo) > hi else (x if x > lo else lo)
        lo = cy0 + eps
        hi = cy0 + res - eps
        if y == y:
            xy[p, 1] = hi if (y if y > lo else lo) > hi else (y if y > lo else lo)


@njit(cache=True)
def grid_room_pairs(cid, cell_full_room, cell_rooms):
    """GridIndex.room_of, the grid part: (out (P,) the room of points in a cell wholly inside one room, -1
    otherwise; pi, rid: the (point, candidate room) pairs left to a point-in-polygon test, by point, rooms
    ascending)."""
    P = cid.shape[0]
    K = cell_rooms.shape[1]
    out = np.full(P, -1, np.int64)
    n = 0
    for p in range(P):
        c = cid[p]
        if c >= 0:
            f = cell_full_room[c]
            if f >= 0:
                out[p] = f
            else:
                for k in range(K):
                    if cell_rooms[c, k] >= 0:
                        n += 1
    pi = np.empty(n, np.int64)
    rid = np.empty(n, np.int64)
    n = 0
    for p in range(P):
        c = cid[p]
        if c >= 0 and cell_full_room[c] < 0:
            for k in range(K):
                r = cell_rooms[c, k]
                if r >= 0:
                    pi[n] = p
                    rid[n] = r
                    n += 1
    return out, pi, rid


@njit(cache=True)
def lowest_inside(out, pi, rid, inside):
    """out[p] = the lowest room id r of the pairs (p, r) with inside, for the points that have pairs (-1 if
    none is inside)."""
    for j in range(pi.shape[0]):
        out[pi[j]] = -1
    for j in range(pi.shape[0] - 1, -1, -1):
        if inside[j]:
            out[pi[j]] = rid[j]


# ------------------------------------------------------------------------------------------ walls
@njit(cache=True, inline="always")
def _pad_index(v, lo, hi):
    """``fmin(fmax(floor(v), lo), hi)`` as an int (NaN -> lo, as numpy's fmax ignores a NaN)."""
    f = np.floor(v)
    if not f >= lo:  # also NaN
        f = lo
    if f > hi:
        f = hi
    return np.int64(f)


@njit(cache=True)
def walls_crossed(x0, y0, dx, dy, n, blocked_pad, h, w, ox, oy, res):
    """Whether each straight step (x0, y0) -> (x0 + dx, y0 + dy) (flat float64 (N,)) touches a blocked pixel at
    the samples t = 1/n, ..., 1; ``blocked_pad`` the flattened grid padded by one pixel of off-image.
    :meth:`blenav.filters.map.walls.WallCrossing.crossed` with the same arithmetic per sample (``k / n``,
    ``((x0 + t dx) - ox) / res``), stopping at a step's first blocked sample."""
    out = np.zeros(x0.shape[0], dtype=np.bool_)
    stride = w + 2
    for i in range(x0.shape[0]):
        for k in range(1, n + 1):
            tk = np.float64(k) / n
            col = _pad_index(((x0[i] + tk * dx[i]) - ox) / res, -1.0, np.float64(w))
            rb = _pad_index(((y0[i] + tk * dy[i]) - oy) / res, -1.0, np.float64(h))
            if blocked_pad[(h - rb) * stride + (col + 1)]:
                out[i] = True
                break
    return out
