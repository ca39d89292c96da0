"""Compiled (numba) proposals of :mod:`blenav.filters.motion`: :class:`~blenav.filters.motion.RandomWalk` and
:class:`~blenav.filters.motion.ImuProposal`, one pass over the particles each, with the speed cap's
all-or-nothing scaling. Written under the bit-identity rules of :mod:`blenav.filters.kernels` (single-threaded,
cached on disk); tests/filters/test_kernels.py compares them with the numpy expressions they replaced.
"""

from __future__ import annotations

import numpy as np
from numba import njit


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
