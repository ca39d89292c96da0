"""Compiled (numba) path-loss likelihoods of :mod:`blenav.filters.measurement`: the particles' distances to the
anchors, and per particle the sum of its squared float32 residuals in the order numpy's
``einsum('rnm,rnm->rn')`` sums them (four SIMD lanes, :func:`_sum_squares_sse`). Written under the bit-identity
rules of :mod:`blenav.filters.kernels` (single-threaded, cached on disk); log10 of float32 stays in numpy,
between two kernels. tests/filters/test_kernels.py compares them with the numpy expressions they replaced.
"""

from __future__ import annotations

import numpy as np
from numba import njit


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
