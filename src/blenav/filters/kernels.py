"""Compiled (numba) inner loops of the particle filter: the proposals, the path-loss likelihoods and the
weighted mean and covariance, one pass over the particles each instead of numpy's dozen temporaries.

Every kernel does the operations of the numpy code it replaces in the same order, so the numbers are
the same bit for bit (tests/test_kernels.py compares them with the numpy expressions):

* elementwise arithmetic is written as numpy evaluates it (left to right, no fused multiply-add: numba
  does not contract a * b + c unless asked), with the same float32/float64 conversions;
* ``np.einsum('rnm,rnm->rn')`` over float32 residuals (the path-loss likelihoods) sums each particle's
  packets in numpy's baseline-SIMD order: four lanes (lane l takes packets l, l + 4, ...; blocks of 16
  are folded last-to-first), each ``lane + a * a`` rounded twice, then ``(l0 + l1) + (l2 + l3)``
  (:func:`_sum_squares_sse`); measured identical for 1-200 packets;
* the float64 einsums of the estimate (``'rn,rnk->rk'``, ``'rn,rni,rnj->rij'``) are sequential sums over
  the particles, ``(w * d_i) * d_j`` for the covariance;
* transcendental functions whose numpy loops are vectorised differently from libm (log10 of float32 is
  numpy's SIMD routine) stay in numpy, between two kernels.

All kernels run single-threaded (``parallel=False``: the machine's cores are shared by the runs of an
experiment and other processes) and are cached on disk (``cache=True``): compiled once per machine
(about 10 s), loaded in well under a second afterwards.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# ------------------------------------------------------------------------------------------ motion


@njit(cache=True, inline="always")
def _clip_factor(s2, vmax2, vmax):
    """np.minimum(1.0, vmax / np.sqrt(np.maximum(s2, 1e-24))) with numpy's NaN propagation."""
    m = s2 if (s2 > 1e-24 or s2 != s2) else 1e-24
    q = vmax / np.sqrt(m)
    if q != q:
        return q
    return 1.0 if 1.0 < q else q


@njit(cache=True)
def random_walk(x, e, dt, sigma_v, sigma_p, vmax):
    """:class:`~blenav.filters.motion.RandomWalk` on (P, D) states with the (P, 4) draws (nu, eps). One pass
    without the speed cap; only when some particle exceeds ``vmax`` a second pass redoes every particle with
    _clip_speed2's all-or-nothing scaling (by exactly 1.0 below the limit)."""
    P, D = x.shape
    out = np.empty((P, D))
    vmax2 = vmax * vmax
    clip = False
    for p in range(P):
        vx = x[p, 2] + sigma_v * e[p, 0]
        vy = x[p, 3] + sigma_v * e[p, 1]
        clip |= vx * vx + vy * vy > vmax2
        out[p, 0] = x[p, 0] + dt * vx + sigma_p * e[p, 2]
        out[p, 1] = x[p, 1] + dt * vy + sigma_p * e[p, 3]
        out[p, 2] = vx
        out[p, 3] = vy
        for k in range(4, D):
            out[p, k] = x[p, k]
    if clip:
        for p in range(P):
            vx = x[p, 2] + sigma_v * e[p, 0]
            vy = x[p, 3] + sigma_v * e[p, 1]
            f = _clip_factor(vx * vx + vy * vy, vmax2, vmax)
            vx = vx * f
            vy = vy * f
            out[p, 0] = x[p, 0] + dt * vx + sigma_p * e[p, 2]
            out[p, 1] = x[p, 1] + dt * vy + sigma_p * e[p, 3]
            out[p, 2] = vx
            out[p, 3] = vy
    return out


@njit(cache=True)
def imu_proposal(x, z, n, ax, ay, dt, sigma_a, sigma_v, vmax):
    """:class:`~blenav.filters.motion.ImuProposal` on (P, D) states: z (P,) standard normal draws of zeta,
    n (P, 2) of nu, (ax, ay) the unit acceleration direction a_hat (or zeros)."""
    P, D = x.shape
    out = np.empty((P, D))
    h = 0.5 * dt * dt
    vmax2 = vmax * vmax
    clip = False
    for p in range(P):
        for k in range(4, D):
            out[p, k] = x[p, k]
        zeta = sigma_a * z[p]
        nu0 = sigma_v * n[p, 0]
        nu1 = sigma_v * n[p, 1]
        u = zeta * ax
        out[p, 0] = x[p, 0] + dt * x[p, 2] + h * u + dt * nu0
        vx = x[p, 2] + dt * u + nu0
        u = zeta * ay
        out[p, 1] = x[p, 1] + dt * x[p, 3] + h * u + dt * nu1
        vy = x[p, 3] + dt * u + nu1
        out[p, 2] = vx
        out[p, 3] = vy
        if vx * vx + vy * vy > vmax2:
            clip = True
    if clip:
        for p in range(P):
            vx, vy = out[p, 2], out[p, 3]
            f = _clip_factor(vx * vx + vy * vy, vmax2, vmax)
            out[p, 2] = vx * f
            out[p, 3] = vy * f
    return out


# ------------------------------------------------------------------------------------ likelihoods


@njit(cache=True, inline="always")
def _sum_squares_sse(r, M):
    """float32 sum of r[0..M)^2 in the order of numpy's einsum 'rnm,rnm->rn' (baseline SSE: 4 lanes, lane l
    takes r[l], r[l + 4], ...; in blocks of 16 the four rows of a lane are added last to first; each
    ``lane + a * a`` rounded twice; then (l0 + l1) + (l2 + l3)). The reference for the lane kernels below."""
    a0 = np.float32(0.0)
    a1 = np.float32(0.0)
    a2 = np.float32(0.0)
    a3 = np.float32(0.0)
    i = 0
    while M - i >= 16:  # the 4x unrolled loop: blocks 3, 2, 1, 0 into the accumulator
        a0 = r[i] * r[i] + (r[i + 4] * r[i + 4] + (r[i + 8] * r[i + 8] + (r[i + 12] * r[i + 12] + a0)))
        a1 = r[i + 1] * r[i + 1] + (r[i + 5] * r[i + 5] + (r[i + 9] * r[i + 9] + (r[i + 13] * r[i + 13] + a1)))
        a2 = r[i + 2] * r[i + 2] + (r[i + 6] * r[i + 6] + (r[i + 10] * r[i + 10] + (r[i + 14] * r[i + 14] + a2)))
        a3 = r[i + 3] * r[i + 3] + (r[i + 7] * r[i + 7] + (r[i + 11] * r[i + 11] + (r[i + 15] * r[i + 15] + a3)))
        i += 16
    while i < M:  # the tail, four at a time, zero-filled
        a0 = r[i] * r[i] + a0
        if i + 1 < M:
            a1 = r[i + 1] * r[i + 1] + a1
        if i + 2 < M:
            a2 = r[i + 2] * r[i + 2] + a2
        if i + 3 < M:
            a3 = r[i + 3] * r[i + 3] + a3
        i += 4
    return (a0 + a1) + (a2 + a3)


@njit(cache=True)
def _anchor_terms(l, device_z):
    """float32 anchor x, y and the squared height difference (M,), as _PathLoss._distances computes them."""
    M = l.shape[0]
    lx = np.empty(M, np.float32)
    ly = np.empty(M, np.float32)
    dz2 = np.empty(M, np.float32)
    for m in range(M):
        lx[m] = np.float32(l[m, 0])
        ly[m] = np.float32(l[m, 1])
        dz = np.float32(device_z) - np.float32(l[m, 2])
        dz2[m] = dz * dz
    return lx, ly, dz2


@njit(cache=True)
def _xy32(x):
    """float32 copies (P,) of the particles' x and y (rows of x (P, >= 2))."""
    P = x.shape[0]
    px = np.empty(P, np.float32)
    py = np.empty(P, np.float32)
    for p in range(P):
        px[p] = np.float32(x[p, 0])
        py[p] = np.float32(x[p, 1])
    return px, py


@njit(cache=True)
def distances_mp(x, l, device_z, d_min):
    """(M, P) float32 3-D distances from the particles (rows of x (P, >= 2) float64) to the anchors l (M, 3),
    anchor-major, floored at ``d_min`` (0: no floor): the numbers of ``_PathLoss._distances`` (and of
    np.maximum(d, d_min), NaN staying NaN). Anchor-major, so the inner loop runs over particles (SIMD)."""
    M = l.shape[0]
    lx, ly, dz2 = _anchor_terms(l, device_z)
    px, py = _xy32(x)
    P = px.shape[0]
    fmin = np.float32(d_min)
    out = np.empty((M, P), np.float32)
    for m in range(M):
        a = lx[m]
        b = ly[m]
        c = dz2[m]
        o = out[m]
        for p in range(P):
            dx = px[p] - a
            dy = py[p] - b
            d = np.sqrt(dx * dx + dy * dy + c)
            o[p] = d if not d < fmin else fmin
    return out


@njit(cache=True)
def rssi_sum_squares(logd, gain, base, inv_sigma):
    """RssiDomain's likelihood (P,) float64 from logd = log10(distances) (M, P) float32: -0.5 sum_m r_m^2,
    r_m = (logd_m * gain + base_m) * inv_sigma in float32, summed per particle in :func:`_sum_squares_sse`'s
    order (four lane accumulators per particle, vectorised over the particles)."""
    M, P = logd.shape
    g = np.float32(gain)
    s = np.float32(inv_sigma)
    acc = np.zeros((4, P), np.float32)
    i = 0
    while M - i >= 16:
        for l in range(4):
            a = acc[l]
            r0, r1, r2, r3 = logd[i + l], logd[i + 4 + l], logd[i + 8 + l], logd[i + 12 + l]
            b0, b1, b2, b3 = base[i + l], base[i + 4 + l], base[i + 8 + l], base[i + 12 + l]
            for p in range(P):
                v0 = (r0[p] * g + b0) * s
                v1 = (r1[p] * g + b1) * s
                v2 = (r2[p] * g + b2) * s
                v3 = (r3[p] * g + b3) * s
                a[p] = v0 * v0 + (v1 * v1 + (v2 * v2 + (v3 * v3 + a[p])))
        i += 16
    while i < M:
        for l in range(4):
            if i + l < M:
                a = acc[l]
                r0 = logd[i + l]
                b0 = base[i + l]
                for p in range(P):
                    v0 = (r0[p] * g + b0) * s
                    a[p] = v0 * v0 + a[p]
        i += 4
    out = np.empty(P)
    for p in range(P):
        out[p] = -0.5 * np.float64((acc[0, p] + acc[1, p]) + (acc[2, p] + acc[3, p]))
    return out


@njit(cache=True, inline="always")
def _range_res(px, py, a, b, c, rng_m, s):
    dx = px - a
    dy = py - b
    return (np.sqrt(dx * dx + dy * dy + c) - rng_m) * s


@njit(cache=True)
def range_loglik(x, l, device_z, ranges, inv_sigma):
    """PathLossRange's likelihood (P,) float64: -0.5 sum_m ((d_pm - r_m) * inv_sigma)^2 in float32, d the
    distances of :func:`distances_mp` (no floor), summed in :func:`_sum_squares_sse`'s order."""
    M = l.shape[0]
    lx, ly, dz2 = _anchor_terms(l, device_z)
    px, py = _xy32(x)
    P = px.shape[0]
    s = np.float32(inv_sigma)
    acc = np.zeros((4, P), np.float32)
    i = 0
    while M - i >= 16:
        for l4 in range(4):
            a = acc[l4]
            m0, m1, m2, m3 = i + l4, i + 4 + l4, i + 8 + l4, i + 12 + l4
            for p in range(P):
                v0 = _range_res(px[p], py[p], lx[m0], ly[m0], dz2[m0], ranges[m0], s)
                v1 = _range_res(px[p], py[p], lx[m1], ly[m1], dz2[m1], ranges[m1], s)
                v2 = _range_res(px[p], py[p], lx[m2], ly[m2], dz2[m2], ranges[m2], s)
                v3 = _range_res(px[p], py[p], lx[m3], ly[m3], dz2[m3], ranges[m3], s)
                a[p] = v0 * v0 + (v1 * v1 + (v2 * v2 + (v3 * v3 + a[p])))
        i += 16
    while i < M:
        for l4 in range(4):
            m0 = i + l4
            if m0 < M:
                a = acc[l4]
                for p in range(P):
                    v0 = _range_res(px[p], py[p], lx[m0], ly[m0], dz2[m0], ranges[m0], s)
                    a[p] = v0 * v0 + a[p]
        i += 4
    out = np.empty(P)
    for p in range(P):
        out[p] = -0.5 * np.float64((acc[0, p] + acc[1, p]) + (acc[2, p] + acc[3, p]))
    return out


# --------------------------------------------------------------------------------------- estimate


@njit(cache=True)
def mean_cov(w, x):
    """Weighted mean (R, 2) and covariance (R, 2, 2) of positions x[..., :2] (R, N, D) with weights (R, N):
    the numbers of einsum('rn,rnk->rk') and einsum('rn,rni,rnj->rij') on the deviations."""
    R, N = w.shape
    mean = np.empty((R, 2))
    cov = np.empty((R, 2, 2))
    for r in range(R):
        mx = 0.0
        my = 0.0
        for n in range(N):
            mx += w[r, n] * x[r, n, 0]
            my += w[r, n] * x[r, n, 1]
        c00 = 0.0
        c01 = 0.0
        c10 = 0.0
        c11 = 0.0
        for n in range(N):
            dx = x[r, n, 0] - mx
            dy = x[r, n, 1] - my
            t = w[r, n] * dx
            c00 += t * dx
            c01 += t * dy
            t = w[r, n] * dy
            c10 += t * dx
            c11 += t * dy
        mean[r, 0] = mx
        mean[r, 1] = my
        cov[r, 0, 0] = c00
        cov[r, 0, 1] = c01
        cov[r, 1, 0] = c10
        cov[r, 1, 1] = c11
    return mean, cov


# -------------------------------------------------------------------------------------- resampling


@njit(cache=True, inline="always")
def _less(a, b):
    """numpy's sort order for floats (NaN last)."""
    return a < b or (b != b and a == a)


@njit(cache=True)
def inverse_cdf(w, u):
    """resampling._inverse_cdf, the same indices: per row r the cumulative weights c (sequential sums as
    np.cumsum, the last set to 1.0) offset by r, all rows concatenated, and the keys u + r searched with numpy's
    own binary search (side='right', its window carried over from the previous key), minus r N, clipped to
    [0, N - 1]."""
    R, N = w.shape
    M = u.shape[1]
    arr = np.empty(R * N)
    for r in range(R):
        off = float(r)
        acc = 0.0
        for j in range(N):
            acc = w[r, j] if j == 0 else acc + w[r, j]
            arr[r * N + j] = acc
        arr[r * N + N - 1] = 1.0
        for j in range(N):
            arr[r * N + j] = arr[r * N + j] + off
    out = np.empty((R, M), np.int64)
    n = R * N
    # sorted (numpy's order): the answer (first index with key < arr[i]) is unique, and ascending keys (the
    # systematic and stratified schemes) are found galloping forward; else numpy's own search path
    monotone = True
    for i in range(n - 1):
        if _less(arr[i + 1], arr[i]):
            monotone = False
            break
    min_idx = 0
    max_idx = n
    last = u[0, 0] + 0.0 if R * M else 0.0
    for r in range(R):
        off = float(r)
        for k in range(M):
            key = u[r, k] + off
            if not _less(key, last):  # cmp(last, key) for side='right': last <= key
                max_idx = n
                if monotone:  # the answer is >= the previous one: gallop forward from it, then bisect
                    b = 1
                    hi = min_idx
                    while hi < n and not _less(key, arr[hi]):  # arr[hi] <= key: the answer is > hi
                        min_idx = hi + 1
                        hi = min_idx + b
                        b *= 2
                    max_idx = hi if hi < n else n
            else:
                min_idx = 0
                max_idx = max_idx + 1 if max_idx < n else n
                if monotone:
                    max_idx = n
            last = key
            while min_idx < max_idx:
                mid = min_idx + ((max_idx - min_idx) >> 1)
                if not _less(key, arr[mid]):  # arr[mid] <= key
                    min_idx = mid + 1
                else:
                    max_idx = mid
            i = min_idx - r * N
            out[r, k] = 0 if i < 0 else (N - 1 if i > N - 1 else i)
    return out


@njit(cache=True)
def gather_rows(x, runs, idx):
    """x[runs] = take_along_axis(x[runs], idx[..., None], axis=1) in place: x (R, N, D), idx (Q, N)."""
    N = x.shape[1]
    D = x.shape[2]
    tmp = np.empty((N, D))
    for q in range(runs.shape[0]):
        r = runs[q]
        tmp[:, :] = x[r]
        for j in range(N):
            a = idx[q, j]
            for k in range(D):
                x[r, j, k] = tmp[a, k]


@njit(cache=True)
def duplicates(idx):
    """(R, N) bool: True for every copy of an ancestor index after its first, row by row (engine._duplicates)."""
    R, N = idx.shape
    out = np.zeros((R, N), np.bool_)
    seen = np.zeros(N, np.bool_)
    for r in range(R):
        seen[:] = False
        for j in range(N):
            a = idx[r, j]
            out[r, j] = seen[a]
            seen[a] = True
    return out


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


# ----------------------------------------------------------------------------------------- weights


@njit(cache=True, inline="always")
def _pairwise_block(a, lo, n):
    """numpy's pairwise sum of a[lo:lo + n] for n <= 128: 8 accumulators, then the rest in order."""
    if n < 8:
        res = -0.0
        for i in range(n):
            res += a[lo + i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    while i < n - (n % 8):
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@njit(cache=True)
def _pairwise(a, lo, n):
    """numpy's pairwise summation of a[lo:lo + n] (what np.sum along a contiguous axis computes): blocks of
    at most 128, halves (rounded down to a multiple of 8) added left + right. Its recursion is run on an
    explicit stack (numba's cache does not support recursive functions)."""
    if n <= 128:
        return _pairwise_block(a, lo, n)
    st_lo = np.empty(64, np.int64)
    st_n = np.empty(64, np.int64)
    st_phase = np.empty(64, np.int64)
    st_left = np.empty(64)
    sp = 0
    st_lo[0], st_n[0], st_phase[0] = lo, n, 0
    ret = 0.0
    while sp >= 0:
        fl, fn, ph = st_lo[sp], st_n[sp], st_phase[sp]
        if fn <= 128:
            ret = _pairwise_block(a, fl, fn)
            sp -= 1
            continue
        n2 = fn // 2
        n2 -= n2 % 8
        if ph == 0:  # evaluate the left half
            st_phase[sp] = 1
            sp += 1
            st_lo[sp], st_n[sp], st_phase[sp] = fl, n2, 0
        elif ph == 1:  # left done (ret): evaluate the right half
            st_left[sp] = ret
            st_phase[sp] = 2
            sp += 1
            st_lo[sp], st_n[sp], st_phase[sp] = fl + n2, fn - n2, 0
        else:  # both done
            ret = st_left[sp] + ret
            sp -= 1
    return ret


@njit(cache=True)
def shift_by_row_max(logw):
    """(logw - m, m): m (R,) the row maxima as np.max gives them (NaN if the row holds one)."""
    R, N = logw.shape
    m = np.empty(R)
    d = np.empty((R, N))
    for r in range(R):
        v = logw[r, 0]
        for j in range(1, N):
            x = logw[r, j]
            if v != v:
                break
            if x != x or x > v:
                v = x
        m[r] = v
        for j in range(N):
            d[r, j] = logw[r, j] - v
    return d, m


@njit(cache=True)
def normalise_rows(e):
    """In place e /= e.sum(axis=1, keepdims=True) (numpy's pairwise sums); returns the sums (R,)."""
    R, N = e.shape
    s = np.empty(R)
    for r in range(R):
        t = _pairwise(e[r], 0, N)
        s[r] = t
        for j in range(N):
            e[r, j] = e[r, j] / t
    return s


@njit(cache=True)
def ess_rows(w):
    """1 / np.sum(w * w, axis=1): the effective sample size per row (numpy's pairwise sums)."""
    R, N = w.shape
    out = np.empty(R)
    sq = np.empty(N)
    for r in range(R):
        for j in range(N):
            sq[j] = w[r, j] * w[r, j]
        out[r] = 1.0 / _pairwise(sq, 0, N)
    return out


@njit(cache=True)
def add_loglik(logw, loglik):
    """logw + loglik with every non-finite sum set to -inf (a new array)."""
    R, N = logw.shape
    out = np.empty((R, N))
    for r in range(R):
        for j in range(N):
            v = logw[r, j] + loglik[r, j]
            out[r, j] = v if (v - v) == 0.0 else -np.inf  # v - v is NaN for inf and NaN
    return out


@njit(cache=True)
def recover_checks(logw, loglik):
    """Per run: dead (no finite log-weight) and the best finite log-likelihood (-inf if none)."""
    R, N = logw.shape
    dead = np.empty(R, np.bool_)
    best = np.empty(R)
    for r in range(R):
        alive = False
        b = -np.inf
        for j in range(N):
            if (logw[r, j] - logw[r, j]) == 0.0:
                alive = True
            v = loglik[r, j]
            if (v - v) == 0.0 and v > b:
                b = v
        dead[r] = not alive
        best[r] = b
    return dead, best


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
