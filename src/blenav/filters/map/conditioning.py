"""Conditioning of resampled particles on the map (Patel et al. eqs. 4-5): jitter, then keep / project onto
the 1 m-shrunk room / project onto the nearest navigation edge; then (not in the paper) out of obstacles.

Obstacles. A room box (or its 1 m-shrunk version) contains desks and a Gaussian jitter crosses walls. With
``obstacle='project'`` (default) a conditioned particle that ends in a non-free pixel (or any particle that
ends in an OCCUPIED pixel) is moved to the nearest point of the nearest free pixel (Euclidean distance
transform); particles far from the map in UNKNOWN space or off the image are left alone. ``'keep'`` gives
the paper's rule unchanged.

:func:`condition` is the method :meth:`MapGeometry.condition` (``m`` is the map); the spatial queries go
through :mod:`blenav.filters.map.index`.
"""

from __future__ import annotations

import numpy as np

from blenav.data.floor import FREE, OCCUPIED

from . import kernels as K
from .protocol import FloorMap

OBSTACLE_COND = ("project", "keep")

# cases returned by MapGeometry.condition(..., return_case=True)
CASE_FAR, CASE_IN_SHRUNK, CASE_TO_SHRUNK, CASE_TO_EDGE = 0, 1, 2, 3


def condition(m: FloorMap, x_xy: np.ndarray, rng: np.random.Generator, sigma: float | np.ndarray | None = None,
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
    ix = m.get_index(index, max_edge_dist, shrink)
    p = flat[sel]
    # 1. jitter
    if sigma is None:
        parent_room = ix.room_of(p) if m.n_rooms else np.full(len(p), -1)
        s = np.where(parent_room >= 0, sigma_rm, sigma_nav)[:, None]
    else:
        s = np.broadcast_to(np.asarray(sigma, dtype=float), lead).reshape(-1)[sel][:, None]
    p = p + s * rng.standard_normal(p.shape)
    out = p.copy()
    c = np.zeros(len(p), dtype=np.int8)
    # 2. rooms
    k = _condition_rooms(m, ix, p, out, c)
    # 3. edges
    rest = np.flatnonzero(k < 0)
    if len(rest) and m.n_edges:
        proj, _, e = ix.nearest_edge(p[rest])
        hit = e >= 0
        out[rest[hit]] = proj[hit]
        c[rest[hit]] = CASE_TO_EDGE
    # 5. obstacles
    if obstacle == "project":
        _snap_obstacles(m, out, c)
    flat[sel] = out
    case[sel] = c
    x[..., :2] = flat.reshape(lead + (2,))
    return (x, case.reshape(lead)) if return_case else x


def _condition_rooms(m: FloorMap, ix, p: np.ndarray, out: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Step 2 of :func:`condition` (eq. 5, rooms) on the jittered particles ``p`` (n, 2) world m: those inside
    their room's shrunk version keep their place (case ``CASE_IN_SHRUNK``), those on its periphery are projected
    onto the shrunk room's boundary (``CASE_TO_SHRUNK``); ``out`` (n, 2) m and ``c`` (n,) int8 are updated in
    place. ``ix``: the spatial index. Returns the room of each particle (n,) int (-1: in no room)."""
    k = ix.room_of(p) if m.n_rooms else np.full(len(p), -1)
    in_room = np.flatnonzero(k >= 0)
    if len(in_room):
        inside = ix.in_shrunk(p[in_room], k[in_room])
        c[in_room[inside]] = CASE_IN_SHRUNK
        band = in_room[~inside]
        if len(band):
            out[band] = ix.project_shrunk(p[band], k[band])
            c[band] = CASE_TO_SHRUNK
    return k


def _snap_obstacles(m: FloorMap, out: np.ndarray, c: np.ndarray) -> None:
    """Step 5 of :func:`condition` (obstacle='project'), in place on the particles ``out`` (n, 2) world m with
    cases ``c`` (n,) int8: every conditioned one (``c > CASE_FAR``) not in a FREE pixel, and every one in an
    OCCUPIED pixel, moves to the nearest point of the nearest free pixel. Compiled: the points and numbers of
    ``m.snap_free(out, only=(c > CASE_FAR) | occupied)``."""
    fl = m.floor
    ox, oy, res = float(fl.origin[0]), float(fl.origin[1]), float(fl.resolution)
    bad = K.obstacle_candidates(out, c, fl.occupancy, ox, oy, res, FREE, OCCUPIED)
    if bad.any():
        K.snap_to_free(out, bad, ox, oy, res, fl.shape[0], fl.shape[1], m.nearest_free_pixels())
