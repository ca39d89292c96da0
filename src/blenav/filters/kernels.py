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
    """:class:`~blenav.filters.motion.RandomWalk` on (P, D) states with the (P, 4) draws (nu, eps)."""
    P, D = x.shape
    out = x.copy()
    vmax2 = vmax * vmax
    clip = False
    for p in range(P):
        vx = x[p, 2] + sigma_v * e[p, 0]
        vy = x[p, 3] + sigma_v * e[p, 1]
        out[p, 2] = vx
        out[p, 3] = vy
        if vx * vx + vy * vy > vmax2:
            clip = True
    for p in range(P):
        vx, vy = out[p, 2], out[p, 3]
        if clip:  # _clip_speed2: all particles are scaled (by exactly 1.0 below the limit) when one exceeds it
            f = _clip_factor(vx * vx + vy * vy, vmax2, vmax)
            vx = vx * f
            vy = vy * f
            out[p, 2] = vx
            out[p, 3] = vy
        out[p, 0] = x[p, 0] + dt * vx + sigma_p * e[p, 2]
        out[p, 1] = x[p, 1] + dt * vy + sigma_p * e[p, 3]
    return out


@njit(cache=True)
def imu_proposal(x, z, n, ax, ay, dt, sigma_a, sigma_v, vmax):
    """:class:`~blenav.filters.motion.ImuProposal` on (P, D) states: z (P,) standard normal draws of zeta,
    n (P, 2) of nu, (ax, ay) the unit acceleration direction a_hat (or zeros)."""
    P, D = x.shape
    out = x.copy()
    h = 0.5 * dt * dt
    vmax2 = vmax * vmax
    clip = False
    for p in range(P):
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
    """float32 sum of r[0..M)^2 in the order of numpy's einsum 'rnm,rnm->rn' (baseline SSE: 4 lanes)."""
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
def distances_pm(x, l, device_z, d_min):
    """(P, M) float32 3-D distances from the particles (rows of x (P, >= 2) float64) to the anchors l (M, 3),
    particle-major, floored at ``d_min`` (float32; 0 for none): the numbers of ``_PathLoss._distances``."""
    P = x.shape[0]
    M = l.shape[0]
    lx, ly, dz2 = _anchor_terms(l, device_z)
    fmin = np.float32(d_min)
    out = np.empty((P, M), np.float32)
    for p in range(P):
        px = np.float32(x[p, 0])
        py = np.float32(x[p, 1])
        for m in range(M):
            dx = px - lx[m]
            dy = py - ly[m]
            d = np.sqrt(dx * dx + dy * dy + dz2[m])
            out[p, m] = d if not d < fmin else fmin  # np.maximum(d, d_min): NaN stays NaN
    return out


@njit(cache=True)
def rssi_sum_squares(logd, gain, base, inv_sigma):
    """-0.5 sum_m ((log10 d * gain + base_m) * inv_sigma)^2 per particle, float32 residuals summed as numpy's
    einsum, returned as float64 (P,): RssiDomain's likelihood from logd = log10(distances) (P, M)."""
    P, M = logd.shape
    g = np.float32(gain)
    s = np.float32(inv_sigma)
    out = np.empty(P)
    r = np.empty(M, np.float32)
    for p in range(P):
        for m in range(M):
            r[m] = (logd[p, m] * g + base[m]) * s
        out[p] = -0.5 * np.float64(_sum_squares_sse(r, M))
    return out


@njit(cache=True)
def range_loglik(x, l, device_z, ranges, inv_sigma):
    """PathLossRange's likelihood (P,) float64: -0.5 sum_m ((d_pm - r_m) * inv_sigma)^2 in float32, summed as
    numpy's einsum, with d the distances of :func:`distances_pm` (no floor)."""
    P = x.shape[0]
    M = l.shape[0]
    lx, ly, dz2 = _anchor_terms(l, device_z)
    s = np.float32(inv_sigma)
    out = np.empty(P)
    r = np.empty(M, np.float32)
    for p in range(P):
        px = np.float32(x[p, 0])
        py = np.float32(x[p, 1])
        for m in range(M):
            dx = px - lx[m]
            dy = py - ly[m]
            r[m] = (np.sqrt(dx * dx + dy * dy + dz2[m]) - ranges[m]) * s
        out[p] = -0.5 * np.float64(_sum_squares_sse(r, M))
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
