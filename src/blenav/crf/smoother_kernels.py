"""The numba kernels of the walk smoother (:mod:`blenav.crf.smoother`, whose docstring states the model): the forward
pass (max-product for Viterbi, log domain; sum-product, linear domain), the backward pass, the fixed-lag smoother and
the cell marginals. Arrays in, arrays out; the grid as CSR arrays (``src_ptr``, ``dst``) and edge vectors."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

@njit(cache=True, nogil=True, inline="always")
def _lae(a, b):
    if a == -np.inf:
        return b
    if b == -np.inf:
        return a
    if a > b:
        return a + math.log1p(math.exp(b - a))
    return b + math.log1p(math.exp(a - b))


@njit(cache=True, nogil=True, inline="always")
def _predicted(d, c, s):
    """The displacement d (2,) under a layer's rotation-scale (c, s) = s_l (cos, sin) theta_l."""
    return c * d[0] - s * d[1], s * d[0] + c * d[1]


@njit(cache=True, nogil=True)
def _source_logw(i, src_ptr, dst, vx, vy, px, py, inv2s2, log_prior, out):
    """Normalised log kernel of the edges leaving cell i into out[:deg]; returns deg."""
    a, b = src_ptr[i], src_ptr[i + 1]
    m = -np.inf
    for e in range(a, b):
        dx = vx[e] - px
        dy = vy[e] - py
        w = -(dx * dx + dy * dy) * inv2s2 + log_prior[dst[e]]
        out[e - a] = w
        if w > m:
            m = w
    if m == -np.inf:  # every target ruled out by the prior: the cell is no source
        return b - a
    s = 0.0
    for e in range(b - a):
        s += math.exp(out[e] - m)
    z = m + math.log(s)
    for e in range(b - a):
        out[e] -= z
    return b - a


@njit(cache=True, nogil=True)
def _first_node(log_init, unary, has_unary, alpha, cur):
    """Node 0 of the forward pass: cur (L, N) and alpha[0] <- init + unary, normalised; returns its log mass."""
    L, N = cur.shape
    tot = -np.inf
    for l in range(L):
        for j in range(N):
            v = log_init[j] - math.log(L)
            if has_unary[0]:
                v += unary[0, j]
            cur[l, j] = v
            tot = _lae(tot, v)
    for l in range(L):
        for j in range(N):
            cur[l, j] -= tot
            alpha[0, l, j] = cur[l, j]
    return tot


@njit(cache=True, nogil=True)
def _close_node(k, tot, nxt, log_init, unary, has_unary, alpha):
    """Node k of the forward pass: nxt (L, N) (unnormalised log messages of log mass tot) normalised into alpha[k];
    where every active state was ruled out (cannot happen with finite unaries) it restarts flat. Returns the log
    mass."""
    L, N = nxt.shape
    if tot == -np.inf:
        for l in range(L):
            for j in range(N):
                nxt[l, j] = log_init[j] - math.log(L) + (unary[k, j] if has_unary[k] else 0.0)
                tot = _lae(tot, nxt[l, j])
    for l in range(L):
        for j in range(N):
            nxt[l, j] -= tot
            alpha[k, l, j] = nxt[l, j]
    return tot


@njit(cache=True, nogil=True)
def _forward_max(src_ptr, dst, vx, vy, disp, sigma, ca, sa, log_prior, unary, has_unary, log_init, prune_log, alpha,
                 back, w):
    """alpha (K, L, N) normalised log max-product forward messages (Viterbi's; the sum-product is
    :func:`_forward_sum`), back (K, L, N) int32 the argmax source; w: scratch of the largest out-degree; returns the
    log mass of the normalisations."""
    K, L, N = alpha.shape
    cur = np.empty((L, N))
    logev = _first_node(log_init, unary, has_unary, alpha, cur)
    nxt = np.empty((L, N))
    for k in range(K - 1):
        nxt[:] = -np.inf
        inv2s2 = 0.5 / (sigma[k] * sigma[k])
        for l in range(L):
            px, py = _predicted(disp[k], ca[l], sa[l])
            for i in range(N):
                a = cur[l, i]
                if a < prune_log:
                    continue
                deg = _source_logw(i, src_ptr, dst, vx, vy, px, py, inv2s2, log_prior, w)
                base = src_ptr[i]
                for e in range(deg):
                    j = dst[base + e]
                    v = a + w[e]
                    if v > nxt[l, j]:
                        nxt[l, j] = v
                        back[k + 1, l, j] = i
        tot = -np.inf
        for l in range(L):
            for j in range(N):
                if nxt[l, j] > -np.inf and has_unary[k + 1]:
                    nxt[l, j] += unary[k + 1, j]
                tot = _lae(tot, nxt[l, j])
        logev += _close_node(k + 1, tot, nxt, log_init, unary, has_unary, alpha)
        cur, nxt = nxt, cur
    return logev


# The sum-product passes in the linear domain: an edge's kernel weight is the product of a per-offset Gaussian (the
# grid's D distinct edge vectors: D exponentials per node and layer instead of one per edge) and the target's prior
# weight exp(log_prior) (once per walk), each scaled so its largest value is 1; a source's row is normalised by its own
# sum, and the messages are scaled by their maximum. While every factor of a term (the source's forward probability,
# the kernel and prior weights, the future's weight in the backward pass) is at least exp(-_DEEP), no product of three
# underflows (exp(-690) > 1e-300), so the sums are the log-domain recursion's. A (node, layer) with a deeper factor
# is done in the log domain (:func:`_source_logw`): a forward source below exp(-_DEEP) (only without pruning), an
# odometry step ~10 m beyond the grid's edges, a prior ~230 nats deep; in the backward pass, a source whose sum comes
# out small (< _SAFE) or zero while a factor was deep. tests/crf/test_smoother.py: equal to enumeration with such
# weights. On real walks (pruning 1e-6, steps of a few metres) every node stays linear.
_DEEP = 230.0
_SAFE = 1e-200


@njit(cache=True, nogil=True)
def _offset_kernel(ovx, ovy, px, py, inv2s2, kd):
    """kd (D,) <- exp(-|v_o - p|^2 / (2 sigma^2)) over the grid's edge offsets, scaled so the largest is 1; returns
    whether one of them is below exp(-_DEEP)."""
    D = len(ovx)
    m = np.inf
    for o in range(D):
        dx = ovx[o] - px
        dy = ovy[o] - py
        q = dx * dx + dy * dy
        kd[o] = q
        if q < m:
            m = q
    under = False
    for o in range(D):
        d = (kd[o] - m) * inv2s2
        kd[o] = math.exp(-d)
        under = under or d > _DEEP
    return under


@njit(cache=True, nogil=True)
def _forward_sum(src_ptr, dst, eoff, ovx, ovy, vx, vy, disp, sigma, ca, sa, log_prior, elp, elp_under, unary, has_unary,
                 log_init, prune_log, alpha, w):
    """alpha (K, L, N) normalised log sum-product forward messages, in the linear domain (the comment above); returns
    the log evidence. eoff (E,) each edge's offset index into ovx, ovy (D,); elp (N,) exp(log_prior - its max);
    elp_under: a finite log_prior more than _DEEP below its max (every node then in the log domain); w: scratch."""
    K, L, N = alpha.shape
    cur = np.empty((L, N))
    logev = _first_node(log_init, unary, has_unary, alpha, cur)
    acc = np.empty((L, N))
    nxt = np.empty((L, N))
    kd = np.empty(len(ovx))
    logrow = np.zeros(L, np.bool_)  # the layers of this node done in the log domain (acc holds log values there)
    for k in range(K - 1):
        inv2s2 = 0.5 / (sigma[k] * sigma[k])
        for l in range(L):
            px, py = _predicted(disp[k], ca[l], sa[l])
            logrow[l] = _offset_kernel(ovx, ovy, px, py, inv2s2, kd) or elp_under
            for i in range(N):  # a source deeper than exp(-_DEEP) (pruning off): the log domain
                if logrow[l]:
                    break
                a = cur[l, i]
                logrow[l] = a > -np.inf and a >= prune_log and a < -_DEEP
            if logrow[l]:  # a weight may underflow: this layer's step in the log domain
                acc[l] = -np.inf
                for i in range(N):
                    a = cur[l, i]
                    if a < prune_log or a == -np.inf:
                        continue
                    deg = _source_logw(i, src_ptr, dst, vx, vy, px, py, inv2s2, log_prior, w)
                    b0 = src_ptr[i]
                    for e in range(deg):
                        acc[l, dst[b0 + e]] = _lae(acc[l, dst[b0 + e]], a + w[e])
                continue
            acc[l] = 0.0
            for i in range(N):
                a = cur[l, i]
                if a < prune_log or a == -np.inf:
                    continue
                b0, b1 = src_ptr[i], src_ptr[i + 1]
                z = 0.0
                for e in range(b0, b1):
                    z += kd[eoff[e]] * elp[dst[e]]
                if z == 0.0:  # every target ruled out by the prior: the cell is no source
                    continue
                f = math.exp(a) / z
                for e in range(b0, b1):
                    acc[l, dst[e]] += f * kd[eoff[e]] * elp[dst[e]]
        tot = -np.inf
        for l in range(L):
            for j in range(N):
                if logrow[l]:
                    v = acc[l, j]
                else:
                    v = math.log(acc[l, j]) if acc[l, j] > 0.0 else -np.inf
                if v > -np.inf and has_unary[k + 1]:
                    v += unary[k + 1, j]
                nxt[l, j] = v
                tot = _lae(tot, v)
        logev += _close_node(k + 1, tot, nxt, log_init, unary, has_unary, alpha)
        cur, nxt = nxt, cur
    return logev


@njit(cache=True, nogil=True)
def _back_step(k, beta, prev, src_ptr, dst, eoff, ovx, ovy, vx, vy, disp, sigma, ca, sa, log_prior, elp, unary,
               has_unary, alpha, prune_log, w, kd, g, elp_under):
    """prev (L, N) <- the backward message of node k from beta (L, N) of node k + 1: for every cell-layer active in
    the forward pass at k, logsumexp over its edges of kernel + node k + 1's unary + beta; -inf elsewhere. In the
    linear domain as :func:`_forward_sum` (beta + unary scaled by its maximum per layer; a source whose sums
    underflow in the log domain); kd (D,), g (N,): scratch."""
    L, N = beta.shape
    prev[:] = -np.inf
    inv2s2 = 0.5 / (sigma[k] * sigma[k])
    hu = has_unary[k + 1]
    for l in range(L):
        M = -np.inf
        for j in range(N):
            v = beta[l, j]
            if v == -np.inf:  # no path to the future from this cell: weight 0, no exponential
                g[j] = v
                continue
            v += unary[k + 1, j] if hu else 0.0
            g[j] = v
            if v > M:
                M = v
        if M == -np.inf:
            continue
        under = False  # a finite beta + unary whose weight is below exp(-_DEEP)
        for j in range(N):
            if g[j] > -np.inf:
                d = g[j] - M
                g[j] = math.exp(d)
                under = under or d < -_DEEP
            else:
                g[j] = 0.0
        px, py = _predicted(disp[k], ca[l], sa[l])
        logrow = _offset_kernel(ovx, ovy, px, py, inv2s2, kd) or elp_under  # this layer in the log domain
        for i in range(N):
            if alpha[k, l, i] < prune_log:
                continue
            b0, b1 = src_ptr[i], src_ptr[i + 1]
            if not logrow:
                z = 0.0
                acc = 0.0
                for e in range(b0, b1):
                    q = kd[eoff[e]] * elp[dst[e]]
                    z += q
                    acc += q * g[dst[e]]
                if acc > _SAFE and z > _SAFE:
                    prev[l, i] = math.log(acc / z) + M
                    continue
                if acc == 0.0 and not under:  # every target without a path to the future: exactly -inf
                    continue
            deg = _source_logw(i, src_ptr, dst, vx, vy, px, py, inv2s2, log_prior, w)  # underflow: the log domain
            acc = -np.inf
            for e in range(deg):
                j = dst[b0 + e]
                b = beta[l, j]
                if b == -np.inf:
                    continue
                acc = _lae(acc, w[e] + b + (unary[k + 1, j] if hu else 0.0))
            prev[l, i] = acc


@njit(cache=True, nogil=True)
def _backward(src_ptr, dst, eoff, ovx, ovy, vx, vy, disp, sigma, ca, sa, log_prior, elp, elp_under, unary, has_unary,
              alpha, prune_log, post, w):
    """post (K, L, N) <- normalised log smoothed marginals log p(x_k, l | all observations); w: scratch."""
    K, L, N = alpha.shape
    beta = np.zeros((L, N))  # node K-1
    for l in range(L):
        for j in range(N):
            post[K - 1, l, j] = alpha[K - 1, l, j]
    prev = np.empty((L, N))
    kd, g = np.empty(len(ovx)), np.empty(N)
    for k in range(K - 2, -1, -1):
        _back_step(k, beta, prev, src_ptr, dst, eoff, ovx, ovy, vx, vy, disp, sigma, ca, sa, log_prior, elp, unary,
                   has_unary, alpha, prune_log, w, kd, g, elp_under)
        # normalise the smoothed marginal alpha + beta of node k; keep beta scaled to avoid underflow
        tot = -np.inf
        m = -np.inf
        for l in range(L):
            for i in range(N):
                p = prev[l, i]
                if p == -np.inf:  # inactive (pruned) or no path: no mass, no exponential
                    continue
                if p > m:
                    m = p
                tot = _lae(tot, alpha[k, l, i] + p)
        if tot == -np.inf:  # pruning cut every path to the future: this node keeps its filtered marginal (restart)
            for l in range(L):
                for i in range(N):
                    post[k, l, i] = alpha[k, l, i]
                    beta[l, i] = 0.0
            continue
        for l in range(L):
            for i in range(N):
                post[k, l, i] = alpha[k, l, i] + prev[l, i] - tot
                beta[l, i] = prev[l, i] - m
    return 0


@njit(cache=True, nogil=True)
def _lagged(src_ptr, dst, eoff, ovx, ovy, vx, vy, disp, sigma, ca, sa, log_prior, elp, elp_under, unary, has_unary,
            alpha, prune_log, lag, out, w):
    """out (K, L, N) <- normalised log p(x_k, l | observations of nodes 0 .. min(k + lag, K - 1)): the fixed-lag
    smoother, a backward recursion of ``lag`` steps from each node (the filtered marginal where it cuts every path)."""
    K, L, N = alpha.shape
    beta = np.empty((L, N))
    prev = np.empty((L, N))
    kd, g = np.empty(len(ovx)), np.empty(N)
    for k in range(K):
        end = min(k + lag, K - 1)
        beta[:] = 0.0
        ok = True
        for j in range(end - 1, k - 1, -1):
            _back_step(j, beta, prev, src_ptr, dst, eoff, ovx, ovy, vx, vy, disp, sigma, ca, sa, log_prior, elp,
                       unary, has_unary, alpha, prune_log, w, kd, g, elp_under)
            m = -np.inf
            for l in range(L):
                for i in range(N):
                    if prev[l, i] > m:
                        m = prev[l, i]
            if m == -np.inf:
                ok = False
                break
            for l in range(L):
                for i in range(N):
                    beta[l, i] = prev[l, i] - m
        tot = -np.inf
        if ok:
            for l in range(L):
                for i in range(N):
                    tot = _lae(tot, alpha[k, l, i] + beta[l, i])
        for l in range(L):
            for i in range(N):
                out[k, l, i] = alpha[k, l, i] + beta[l, i] - tot if tot > -np.inf else alpha[k, l, i]
    return 0


@njit(cache=True, nogil=True)
def _cell_marginals(logp):
    """(K, N) sum over the layers of exp(logp (K, L, N)), each row normalised to 1; a state at -inf (pruned, never
    reached) costs no exponential."""
    K, L, N = logp.shape
    out = np.zeros((K, N))
    for k in range(K):
        tot = 0.0
        for l in range(L):
            for j in range(N):
                v = logp[k, l, j]
                if v > -np.inf:
                    e = math.exp(v)
                    out[k, j] += e
                    tot += e
        if tot > 0.0:
            for j in range(N):
                out[k, j] /= tot
    return out
