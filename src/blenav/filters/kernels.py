"""Compiled (numba) inner loops of the particle filter's engine (:mod:`blenav.filters.engine`,
:mod:`blenav.filters.resampling`): the weighted mean and covariance, the resampling indices and row gathers, and
the log-weight updates, one pass over the particles each instead of numpy's dozen temporaries. The kernels of the
models live next to their models under the same rules: :mod:`blenav.filters.motion_kernels` (the proposals),
:mod:`blenav.filters.measurement_kernels` (the path-loss likelihoods), :mod:`blenav.filters.map.kernels` (map
queries, wall crossings).

Every kernel does the operations of the numpy code it replaces in the same order, so the numbers are
the same bit for bit (tests/filters/test_kernels.py compares them with the numpy expressions):

* elementwise arithmetic is written as numpy evaluates it (left to right, no fused multiply-add: numba
  does not contract a * b + c unless asked), with the same float32/float64 conversions;
* ``np.einsum('rnm,rnm->rn')`` over float32 residuals (the path-loss likelihoods) sums each particle's
  packets in numpy's baseline-SIMD order: four lanes (lane l takes packets l, l + 4, ...; blocks of 16
  are folded last-to-first), each ``lane + a * a`` rounded twice, then ``(l0 + l1) + (l2 + l3)``
  (:func:`blenav.filters.measurement_kernels._sum_squares_sse`); measured identical for 1-200 packets;
* the float64 einsums of the estimate (``'rn,rnk->rk'``, ``'rn,rni,rnj->rij'``) are sequential sums over
  the particles, ``(w * d_i) * d_j`` for the covariance; ``np.sum`` along a row is numpy's pairwise sum
  (:func:`_pairwise`);
* transcendental functions whose numpy loops are vectorised differently from libm (log10 of float32 is
  numpy's SIMD routine) stay in numpy, between two kernels.

All kernels run single-threaded (``parallel=False``: the machine's cores are shared by the runs of an
experiment and other processes) and are cached on disk (``cache=True``): compiled once per machine
(about 10 s), loaded in well under a second afterwards.
"""

from __future__ import annotations

import numpy as np
from numba import njit

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
    """(R, N) bool: True for every copy of an ancestor index after its first, row by row (the map conditioning
    of :meth:`blenav.filters.engine.ParticleFilter._resample` moves only those)."""
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
