"""Initialisation on the map (Patel et al. eq. 3) and free-space sampling.

``round(beta * N)`` particles per run on navigation edges (edge chosen with probability proportional to
its length, uniform along it) plus N(0, sigma_nav^2 I), the other ``N - round(beta * N)`` in rooms (room
chosen proportional to its area, uniform inside) plus N(0, sigma_rm^2 I). Table I: beta 0.8, sigma_nav
2 m, sigma_rm 1 m. :func:`sample_uniform_free` is the map-free alternative (uniform over free pixels),
:func:`sample_free_within` Roy's re-initialisation around a point.

Obstacles. The paper's equations ignore walls and furniture: a Gaussian around an edge or a room leaves
free space, and a room box contains desks. With ``obstacle='resample'`` (default) a sample that is not in
a FREE pixel is redrawn from its own component (edge or room, position and noise) until it is, so the
initial cloud is eq. 3 restricted to free space (``'project'`` moves it to the nearest free pixel instead,
``'keep'`` leaves eq. 3 untouched; after 100 rounds the few left are projected).

These functions are methods of :class:`~blenav.filters.map.geometry.MapGeometry` (``m.sample_initial(...)``);
``m`` is the map.
"""

from __future__ import annotations

import numpy as np
import shapely

from .protocol import FloorMap

OBSTACLE_INIT = ("resample", "project", "keep")


def sample_uniform_free(m: FloorMap, rng: np.random.Generator, R: int, N: int) -> np.ndarray:
    """(R, N, 2) uniform over the free pixels of the floor (global localisation without a map prior)."""
    r, c = np.nonzero(m.floor.free_mask)
    k = rng.integers(0, len(r), size=(R, N))
    centre = m.floor.pixel_to_world(r[k], c[k])
    return centre + (rng.random((R, N, 2)) - 0.5) * m.floor.resolution


def sample_free_within(m: FloorMap, rng: np.random.Generator, centres: np.ndarray, N: int, radius: float,
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
        bad = ~m.floor.is_free(xy)
        if not bad.any():
            return xy
        m_idx = np.nonzero(bad)[0]
        xy[bad] = draw(len(m_idx), c[m_idx])
    bad = ~m.floor.is_free(xy)
    if bad.any():
        pts = m.floor.free_points()
        res = m.floor.resolution
        for j in np.unique(np.nonzero(bad)[0]):  # rare: a loop over runs, never over particles
            row = bad[j]
            inside = pts[np.sum((pts - c[j]) ** 2, axis=1) <= r * r]
            if len(inside):
                k = rng.integers(0, len(inside), int(row.sum()))
                xy[j, row] = inside[k] + (rng.random((len(k), 2)) - 0.5) * res
            else:
                xy[j, row] = m.snap_free(xy[j, row])
    return xy


def _draw_edges(m: FloorMap, rng, shape, sigma):
    """``shape`` points around the edges (edge ~ length, uniform along it) + N(0, sigma^2 I)."""
    L = m.edge_lengths
    e = rng.choice(m.n_edges, size=shape, p=L / L.sum())
    t = rng.random(shape)[..., None]
    a, b = m.segments[e, 0], m.segments[e, 1]
    return a + t * (b - a) + sigma * rng.standard_normal(shape + (2,))


def _draw_rooms(m: FloorMap, rng, shape, sigma):
    """``shape`` points in rooms (room ~ area, uniform inside) + N(0, sigma^2 I)."""
    A = m.room_areas
    k = rng.choice(m.n_rooms, size=shape, p=A / A.sum()).ravel()
    bounds = shapely.bounds(m._rooms_arr)  # (n_rooms, 4)
    out = np.empty((k.size, 2))
    todo = np.arange(k.size)
    for _ in range(10_000):  # vectorised rejection from each room's bounding box
        if not len(todo):
            break
        b = bounds[k[todo]]
        u = rng.random((len(todo), 2))
        x = b[:, 0] + u[:, 0] * (b[:, 2] - b[:, 0])
        y = b[:, 1] + u[:, 1] * (b[:, 3] - b[:, 1])
        ok = shapely.contains_xy(m._rooms_arr[k[todo]], x, y)
        out[todo[ok], 0], out[todo[ok], 1] = x[ok], y[ok]
        todo = todo[~ok]
    if len(todo):
        raise RuntimeError("rejection sampling inside rooms did not converge (degenerate room polygons?)")
    return out.reshape(shape + (2,)) + sigma * rng.standard_normal(shape + (2,))


def sample_initial(m: FloorMap, rng: np.random.Generator, R: int, N: int, beta: float = 0.8,
                   sigma_nav: float = 2.0, sigma_rm: float = 1.0, obstacle: str = "resample", max_rounds: int = 100,
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
    if not m.n_edges and not m.n_rooms:
        xy = m.sample_uniform_free(rng, R, N)
        return (xy, np.zeros((R, N), bool)) if return_source else xy
    n_nav = int(round(beta * N)) if m.n_edges else 0
    if not m.n_rooms:
        n_nav = N
    n_rm = N - n_nav
    xy = np.empty((R, N, 2))
    if n_nav:
        xy[:, :n_nav] = _draw_edges(m, rng, (R, n_nav), sigma_nav)
    if n_rm:
        xy[:, n_nav:] = _draw_rooms(m, rng, (R, n_rm), sigma_rm)
    if obstacle == "resample":
        for _ in range(max_rounds):
            bad = ~m.floor.is_free(xy)
            if not bad.any():
                break
            bn, br = bad[:, :n_nav], bad[:, n_nav:]
            if bn.any():
                xy[:, :n_nav][bn] = _draw_edges(m, rng, (int(bn.sum()),), sigma_nav)
            if br.any():
                xy[:, n_nav:][br] = _draw_rooms(m, rng, (int(br.sum()),), sigma_rm)
    if obstacle in ("resample", "project"):
        xy = m.snap_free(xy)
    if return_source:
        src = np.zeros((R, N), dtype=bool)
        src[:, :n_nav] = True
        return xy, src
    return xy
