"""Navigation routes derived from the occupancy grid, for maps without ``navgraph.geojson``.

Skeleton (``skimage.morphology.skeletonize``) of the walkable free space (clearance > 0.25 m), traced into
a pixel graph, junction pixel clusters merged, terminal spurs shorter than ``1.5 x clearance at their
junction + 0.5 m`` pruned (room-corner branches, furniture nubs), degree-2 nodes contracted, each polyline
Douglas-Peucker simplified (1 pixel) and split into segments.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage
from shapely.geometry import LineString

from blenav.data.floor import Floor

from .raster import clearance, free_grid, px_to_world

ROUTE_OPTIONS = {"min_clearance", "spur_min", "spur_factor", "derive_resolution"}
_OFFS = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]


def derive_routes(floor: Floor, min_clearance: float = 0.25, spur_min: float = 0.5, spur_factor: float = 1.5,
                  derive_resolution: float = 0.1) -> list[LineString]:
    """Routes as the pruned skeleton of walkable free space (see :mod:`blenav.filters.map.routes`)."""
    from skimage.morphology import skeletonize

    free, res, origin = free_grid(floor, derive_resolution)
    clear = clearance(free, res)
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
        xy = px_to_world(rr[path], cc[path], h, res, origin)
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
    clu, rep, ncl = _junctions(rr, cc, is_node, (h, w))
    nbl = [[q for q in row if q >= 0] for row in nb.tolist()]
    visited = [False] * n
    edges = _trace_from_nodes(np.flatnonzero(is_node).tolist(), clu, rep, nbl, visited)
    edges += _trace_cycles(n, clu, rep, nbl, visited, ncl)
    return edges, rep


def _junctions(rr: np.ndarray, cc: np.ndarray, is_node: np.ndarray, shape):
    """Node clusters: per skeleton pixel its cluster (-1: not a node), per cluster its representative
    pixel (the member nearest to the centroid), and the number of clusters."""
    nodemask = np.zeros(shape, dtype=bool)
    nodemask[rr[is_node], cc[is_node]] = True
    lab, ncl = ndimage.label(nodemask, structure=np.ones((3, 3)))
    clu = (lab[rr, cc] - 1).tolist()
    ids = np.flatnonzero(is_node)
    cl = lab[rr[ids], cc[ids]] - 1
    cnt = np.bincount(cl, minlength=ncl)
    cy = np.bincount(cl, rr[ids], minlength=ncl) / np.maximum(cnt, 1)
    cx = np.bincount(cl, cc[ids], minlength=ncl) / np.maximum(cnt, 1)
    d = (rr[ids] - cy[cl]) ** 2 + (cc[ids] - cx[cl]) ** 2
    order = np.lexsort((d, cl))
    first = np.concatenate([[True], cl[order][1:] != cl[order][:-1]])
    rep = {int(c): int(p) for c, p in zip(cl[order][first], ids[order][first])}
    return clu, rep, ncl


def _trace_from_nodes(node_ids: list, clu: list, rep: dict, nbl: list, visited: list) -> list:
    """Walk from every node pixel along each unvisited chain of degree-2 pixels to the next node cluster."""
    edges = []
    for p in node_ids:
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
    return edges


def _trace_cycles(n: int, clu: list, rep: dict, nbl: list, visited: list, next_node: int) -> list:
    """Pure cycles (no node pixel): each becomes a self-loop on a new node (added to ``rep``)."""
    edges = []
    for s in range(n):
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
    return edges


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
