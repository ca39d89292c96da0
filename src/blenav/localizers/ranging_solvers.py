"""The solvers of the distance-based baselines (:mod:`blenav.localizers.ranging`): squared-range least squares,
exact (Beck, Stoica and Li 2008; :func:`srls`, with the collinear-anchor case), and range least squares by grid
search over a floor's free cells (:func:`grid_costs`, L2 or L1 residuals; :func:`free_cells`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["srls", "collinear_anchors", "grid_costs", "free_cells"]


def srls(anchors_xy: np.ndarray, r2: np.ndarray, mask: np.ndarray | None = None, iters: int = 200) -> np.ndarray:
    """Squared-range least squares (Beck, Stoica and Li 2008, sec. III, "SR-LS"), exact, batched.

    ``anchors_xy`` (A, n) or (K, A, n) m, ``r2`` (K, A) squared ranges m^2, ``mask`` (K, A) bool (which ranges
    each problem uses; default all finite). Returns (K, n): ``argmin_x sum_m (||x - a_m||^2 - r2_m)^2``; NaN for
    a problem with fewer than n + 1 ranges.

    With y = (x, ||x||^2) the problem is ``min ||A y - b||^2 s.t. y^T D y + 2 f^T y = 0``, A_m = (-2 a_m^T, 1),
    b_m = r2_m - ||a_m||^2, D = diag(I_n, 0), f = (0, -1/2) (Beck et al. eq. 11), a generalized trust region
    subproblem. Its solution is y(lambda) = (A^T A + lambda D)^{-1} (A^T b - lambda f) with lambda the root of
    phi(lambda) = y^T D y + 2 f^T y, strictly decreasing on I = (-1 / lambda_1, inf), lambda_1 the largest
    eigenvalue of (A^T A)^{-1/2} D (A^T A)^{-1/2} (their Theorem 3.2 / eq. 13); found by bisection, all K
    problems at once. In the "hard case" (no root in I, which needs a special geometry) the bisection ends
    at the interval's left end: the estimate is then the limit y(-1/lambda_1) (approximate, not exact).
    Collinear anchors in 2-D (A^T A singular; a corridor's APs): with s the position along their line and h the
    distance from it, the cost depends on (s, s^2 + h^2) only, so the problem is a least-squares fit of
    (s, w = s^2 + h^2) subject to w >= s^2 (convex): the unconstrained fit when it has w >= s^2 (then
    h = sqrt(w - s^2), on the side of the line's left normal -- the mirror image is as good:
    :func:`collinear_anchors` gives the line, :class:`SrlsLocalizer` picks the mirror on free space), else
    h = 0 and s the one-dimensional SR-LS on the line. Coincident anchors (no line) give NaN."""
    r2 = np.asarray(r2, float)
    K, A = r2.shape
    a = np.asarray(anchors_xy, float)
    if a.ndim == 2:
        a = np.broadcast_to(a, (K,) + a.shape)
    n = a.shape[-1]
    m = np.isfinite(r2) if mask is None else (np.asarray(mask, bool) & np.isfinite(r2))
    ok = m.sum(1) >= n + 1
    if not ok.all():  # too few ranges: NaN; the others solved alone
        x = np.full((K, n), np.nan)
        if ok.any():
            x[ok] = srls(a[ok], r2[ok], m[ok], iters)
        return x
    if n == 2:
        col, centre_c, u = collinear_anchors(a, m)
        if col.any():
            x = np.full((K, n), np.nan)
            if (~col).any():
                x[~col] = srls(a[~col], r2[~col], m[~col], iters)
            x[col] = _srls_on_line(a[col], r2[col], m[col], centre_c[col], u[col], iters)
            return x
    return _srls_general(a, r2, m, iters)


def _srls_general(a: np.ndarray, r2: np.ndarray, m: np.ndarray, iters: int) -> np.ndarray:
    """SR-LS of :func:`srls` for K problems with at least n + 1 used ranges and a non-singular A^T A: ``a``
    (K, A, n) anchors m, ``r2`` (K, A) squared ranges m^2, ``m`` (K, A) bool used ranges. Returns (K, n) m.

    y(lambda) = (A^T A + lambda D)^{-1} (A^T b - lambda f) and phi(lambda) = y^T D y + 2 f^T y (Beck et al.
    eq. 11-13); lambda is phi's root on I = (-1 / lambda_1, inf), by :func:`_srls_bisect`."""
    n = a.shape[-1]
    centre, mu, back, u, v, lo = _srls_spectral(a, r2, m)

    def y_of(lam):
        den = np.maximum(1.0 + lam[:, None] * mu, 1e-15)
        return np.einsum("kij,kj->ki", back, (u - lam[:, None] * v) / den)

    def phi(lam):
        y = y_of(lam)
        return (y[:, :n] ** 2).sum(1) - y[:, n]

    lam = _srls_bisect(phi, lo, iters)
    return y_of(lam)[:, :n] + centre


def _srls_spectral(a: np.ndarray, r2: np.ndarray, m: np.ndarray):
    """One factorisation of the K generalized trust region subproblems (Beck et al. eq. 11) for y(lambda).

    ``a`` (K, A, n) m, ``r2`` (K, A) m^2, ``m`` (K, A) bool. Returns (centre (K, n) m the used anchors' mean the
    problems are solved about, mu (K, n+1) the eigenvalues of L^-1 D L^-T ascending, back (K, n+1, n+1) L^-T Q,
    u (K, n+1) Q^T L^-1 A^T b, v (K, n+1) Q^T L^-1 f, lo (K,) -1 / lambda_1 the left end of I), with
    A^T A = L L^T (Cholesky, slightly regularised) and L^-1 D L^-T = Q diag(mu) Q^T."""
    K, A = r2.shape
    n = a.shape[-1]
    w = m.astype(float)
    # the cost is translation invariant: solve about the used anchors' mean (conditioning), shift back at the end
    centre = np.einsum("ka,kan->kn", w, a) / np.maximum(w.sum(1), 1.0)[:, None]
    a = a - centre[:, None, :]
    Am = np.concatenate([-2.0 * a, np.ones((K, A, 1))], axis=2) * w[..., None]  # (K, A, n+1), unused rows zero
    b = np.where(m, r2 - (a * a).sum(-1), 0.0)
    AtA = np.einsum("kai,kaj->kij", Am, Am)
    Atb = np.einsum("kai,ka->ki", Am, b)
    eye = np.eye(n + 1)
    AtA = AtA + (1e-9 * np.trace(AtA, axis1=1, axis2=2)[:, None, None] + 1e-300) * eye
    D = np.diag(np.r_[np.ones(n), 0.0])
    f = np.r_[np.zeros(n), -0.5]
    # A^T A = L L^T and L^-1 D L^-T = Q diag(mu) Q^T, so (A^T A + lambda D)^-1 = L^-T Q diag(1 / (1 + lambda mu))
    # Q^T L^-1: y(lambda) for every lambda from one factorisation, without a solve that fails near the singular
    # end of I (lambda -> -1 / lambda_1, where 1 + lambda mu_max -> 0); lambda_1 = mu_max.
    L = np.linalg.cholesky(AtA)
    Li = np.linalg.inv(L)
    mu, Q = np.linalg.eigh(Li @ D @ np.swapaxes(Li, 1, 2))
    lam1 = mu[:, -1]
    lo = -1.0 / np.maximum(lam1, 1e-300)
    back = np.swapaxes(Li, 1, 2) @ Q  # (K, n+1, n+1): L^-T Q
    QtLi = np.swapaxes(Q, 1, 2) @ Li
    u = np.einsum("kij,kj->ki", QtLi, Atb)
    v = np.einsum("kij,j->ki", QtLi, f)
    return centre, mu, back, u, v, lo


def _srls_bisect(phi, lo: np.ndarray, iters: int) -> np.ndarray:
    """The root (K,) of the K strictly decreasing functions ``phi`` ((K,) -> (K,)) on (``lo``, inf), ``lo`` (K,):
    grow an upper end until phi < 0 there, then ``iters`` bisection steps; in the hard case (no root) the
    result is just right of ``lo``."""
    scale = np.maximum(np.abs(lo), 1.0)
    hi = scale.copy()
    for _ in range(200):  # phi(hi) < 0: phi -> -||x||^2 ... decreasing; grow hi until the sign changes
        p = phi(hi)
        grow = p > 0
        if not grow.any():
            break
        hi = np.where(grow, hi * 4.0 + scale, hi)
    lo_b = lo.copy()
    for _ in range(iters):
        mid = 0.5 * (lo_b + hi)
        mid = np.where(mid <= lo, 0.5 * (lo + hi), mid)
        p = phi(mid)
        lo_b = np.where(p > 0, mid, lo_b)
        hi = np.where(p > 0, hi, mid)
    return np.where(hi > lo, hi, lo + np.abs(lo) * 1e-12 + 1e-12)


def collinear_anchors(a: np.ndarray, m: np.ndarray, rtol: float = 1e-9):
    """Which problems' used anchors lie on one line: ``a`` (K, A, 2) m, ``m`` (K, A) bool. Returns (flag (K,),
    centre (K, 2) the used anchors' mean, u (K, 2) the line's unit direction). Collinear: the smaller
    eigenvalue of the anchors' scatter is at most ``rtol`` times the larger (coincident anchors count too)."""
    w = m.astype(float)
    centre = np.einsum("ka,kan->kn", w, a) / np.maximum(w.sum(1), 1.0)[:, None]
    c = (a - centre[:, None, :]) * w[..., None]
    ev, vec = np.linalg.eigh(np.einsum("kai,kaj->kij", c, c))
    return ev[:, 0] <= rtol * np.maximum(ev[:, 1], 1e-300), centre, vec[:, :, 1]


def _srls_on_line(a, r2, m, centre, u, iters):
    """SR-LS for collinear anchors (see :func:`srls`): (K, 2) positions, the solution left of the line."""
    K = len(r2)
    w = m.astype(float)
    s_m = np.einsum("kan,kn->ka", a - centre[:, None, :], u)  # positions along the line
    nrm = np.stack([-u[:, 1], u[:, 0]], axis=1)
    Am = np.stack([-2.0 * s_m, np.ones_like(s_m)], axis=2) * w[..., None]
    b = np.where(m, r2 - s_m ** 2, 0.0)
    AtA = np.einsum("kai,kaj->kij", Am, Am)
    Atb = np.einsum("kai,ka->ki", Am, b)
    distinct = np.linalg.det(AtA) > 1e-12 * np.maximum(np.trace(AtA, axis1=1, axis2=2), 1e-300) ** 2
    y = np.zeros((K, 2))
    if distinct.any():
        y[distinct] = np.linalg.solve(AtA[distinct], Atb[distinct][..., None])[..., 0]
    sv, wv = y[:, 0], y[:, 1]
    h2 = wv - sv ** 2
    x = centre + sv[:, None] * u + np.sqrt(np.maximum(h2, 0.0))[:, None] * nrm
    on_line = distinct & (h2 < 0)
    if on_line.any():  # the constraint is active: h = 0, one-dimensional SR-LS along the line
        s1 = srls(s_m[on_line][..., None], np.where(m[on_line], r2[on_line], np.nan), None, iters)[:, 0]
        x[on_line] = centre[on_line] + s1[:, None] * u[on_line]
    x[~distinct] = np.nan
    return x


def grid_costs(cells: np.ndarray, anchor_xyz: np.ndarray, d: np.ndarray, device_z: float, loss: str = "l2",
               chunk_elems: int = 4_000_000) -> np.ndarray:
    """Best cell per window: ``argmin_c sum_m cost(d[w, m] - ||cell_c - a_m||)`` over ranges ``d`` (W, A) m (NaN =
    absent), cells (N, 2) m at height ``device_z``, anchors (A, 3) m; ``loss`` 'l2' (squared residuals) or 'l1'
    (absolute). Returns (W,) cell index (-1 for a window without any range).

    Vectorised over windows and cells: l2 expands the square into three matrix products, (W, N) per chunk of
    windows; l1 forms |residuals| (chunk, N, A) in chunks of at most ``chunk_elems`` elements."""
    D = np.sqrt(((cells[:, None, :] - anchor_xyz[None, :, :2]) ** 2).sum(-1) + (anchor_xyz[None, :, 2] - device_z) ** 2)
    m = np.isfinite(d)
    dz = np.where(m, d, 0.0)
    W, N, A = len(d), len(cells), len(anchor_xyz)
    out = np.full(W, -1, np.int64)
    if N == 0 or A == 0:
        return out
    if loss == "l2":
        step = max(1, chunk_elems // max(N, 1))
        wm = m.astype(float)
        D2 = D * D
        for s in range(0, W, step):
            e = slice(s, s + step)
            c = (wm[e] @ D2.T) - 2.0 * (dz[e] @ D.T) + (dz[e] ** 2).sum(1)[:, None]
            out[e] = np.argmin(c, axis=1)
    elif loss == "l1":  # float32 (centimetre residuals are plenty for a 0.5 m grid): half the time of float64
        step = max(1, chunk_elems // max(N * A, 1))
        D32, d32, m32 = D.astype(np.float32), dz.astype(np.float32), m.astype(np.float32)
        for s in range(0, W, step):
            e = slice(s, s + step)
            c = np.einsum("wna,wa->wn", np.abs(d32[e][:, None, :] - D32[None]), m32[e])
            out[e] = np.argmin(c, axis=1)
    else:
        raise ValueError(f"loss must be 'l2' or 'l1', got {loss!r}")
    out[~m.any(axis=1)] = -1
    return out


def free_cells(floor, grid_m: float, cache: dict | None = None) -> np.ndarray:
    """World (N, 2) m of the centres of the floor's free cells at ``grid_m`` (a cell is free when every floor
    pixel it covers is: :func:`blenav.features.mapgrid.net_grid`); cached per floor and resolution."""
    key = ("ranging-free-cells", str(floor.image_path), float(floor.resolution), tuple(floor.origin), float(grid_m))
    if cache is not None and key in cache:
        return cache[key]
    from blenav.features.mapgrid import net_grid

    g, free = net_grid(floor, grid_m)
    r, c = np.nonzero(free)
    h = g.shape[0]
    xy = np.stack([g.origin[0] + (c + 0.5) * g.resolution, g.origin[1] + (h - 1 - r + 0.5) * g.resolution], axis=1)
    if cache is not None:
        cache[key] = xy
    return xy
