"""Forward-backward (sum-product) and Viterbi (max-product) on the grid of :mod:`blenav.crf.grid` with odometry
displacement kernels: the walk smoother of issue 30 (a phone, no known start, fixes + inertial odometry + plan).

A hidden Markov model over the K nodes of a walk (one every ``dt`` seconds) whose state is a cell of the walkable
grid (N cells) and a *layer* l of L (a heading offset theta_l and a step scale s_l of the odometry, constant over a
walk: the walk's unknown heading error and step-length error, estimated instead of trusted; Duembgen et al.'s
IMU features, 004 eqs. 13-14, with the odometry's heading and length error as states):

* transition k -> k+1 along a grid edge e = (i -> j) of vector v_e (length ``dist``, direction ``angle``), for the
  odometry displacement d_k (world frame, m) of that interval and layer l:

      log psi_l(i -> j) = -|v_e - s_l R(theta_l) d_k|^2 / (2 sigma_k^2) + log_prior[j] - log Z_l(i)

  (Z_l(i): the sum over the edges leaving i, so each row is a transition kernel; ``log_prior`` a log position prior
  on the targets, e.g. where train walks went; edges stop at walls, :func:`blenav.crf.grid.build_grid`);
* unary: ``unary[k]`` (N,) log-likelihood of the node's observations (fixes) per cell, 0 where the node has none;
* start: ``log_init`` (N,) over the cells (uniform over the walkable area when nothing is known), uniform over layers.

:func:`forward_backward` returns the filtered (causal, eq. of the forward recursion) and smoothed marginals' per-node
statistics; :func:`viterbi` the most probable joint state sequence. Pruning (as 004 sec. IV-B): a cell-layer whose
normalised forward probability is below ``prune`` is no source at the next node (and gets no backward message), so
the cost follows the active states, not the floor; ``prune = 0`` is exact.

numba (:mod:`blenav.crf.smoother_kernels`); the sum-product passes work in the linear domain with the kernel
factored over the grid's few distinct edge vectors (the comment above its ``_offset_kernel``: no exponential per
edge; the log domain where a weight is too small for it), the max-product in the log domain. :func:`brute_force`
enumerates every state sequence of a tiny model (the tests' reference).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from blenav.limits import check_memory

from .grid import CrfGrid
from .smoother_kernels import _DEEP, _backward, _cell_marginals, _forward_max, _forward_sum, _lagged

__all__ = ["Layers", "SmootherResult", "forward_backward", "viterbi", "brute_force", "edge_log_kernel"]

@dataclass(frozen=True)
class Layers:
    """The L = len(heading_offsets_rad) x len(scales) odometry hypotheses of a walk (heading offset, step scale)."""

    heading_offsets_rad: tuple = (0.0,)
    scales: tuple = (1.0,)

    def __post_init__(self):
        if not len(self.heading_offsets_rad) or not len(self.scales) or not all(float(x) > 0 for x in self.scales):
            raise ValueError(f"layers need at least one heading offset and positive scales, got "
                             f"{tuple(self.heading_offsets_rad)} / {tuple(self.scales)}")

    def at(self, i: int) -> tuple[float, float]:
        """(heading offset rad, scale) of layer ``i`` (the order of :meth:`arrays`)."""
        return float(self.heading_offsets_rad[i // len(self.scales)]), float(self.scales[i % len(self.scales)])

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(cos (L,), sin (L,)) of s_l R(theta_l): the rotation-scale applied to each displacement per layer."""
        th, sc = np.meshgrid(np.asarray(self.heading_offsets_rad, float), np.asarray(self.scales, float),
                             indexing="ij")
        th, sc = th.ravel(), sc.ravel()
        return sc * np.cos(th), sc * np.sin(th)

    def turn(self, i: int, disp: np.ndarray) -> np.ndarray:
        """Displacements ``disp`` (..., 2) m under layer ``i``'s rotation-scale s_l R(theta_l) (the transition
        kernel's :func:`_predicted`, vectorised)."""
        c, s = (a[i] for a in self.arrays())
        d = np.asarray(disp, float)
        return np.stack([c * d[..., 0] - s * d[..., 1], s * d[..., 0] + c * d[..., 1]], axis=-1)

    @property
    def n(self) -> int:
        return len(self.heading_offsets_rad) * len(self.scales)


@dataclass
class SmootherResult:
    """Per node k of K: ``filtered_mean`` / ``smoothed_mean`` (K, 2) m, the marginals' mean position (filtered: given
    the observations up to node k, or k + lag with a lag);
    ``filtered_cov`` / ``smoothed_cov`` (K, 2, 2) m^2; ``filtered_mode`` / ``smoothed_mode`` (K,) cell of the
    marginal's maximum; ``layer_post`` (L,) the posterior of the layers (last node, smoothed); ``log_evidence``:
    log p(observations) of the (pruned) model."""

    filtered_mean: np.ndarray
    filtered_cov: np.ndarray
    filtered_mode: np.ndarray
    smoothed_mean: np.ndarray
    smoothed_cov: np.ndarray
    smoothed_mode: np.ndarray
    layer_post: np.ndarray
    log_evidence: float



def edge_log_kernel(grid: CrfGrid, disp: np.ndarray, sigma: float, log_prior: np.ndarray | None = None) -> np.ndarray:
    """(E,) normalised log transition weights of every edge for one displacement ``disp`` (2,) m (layer 0, no
    offset); numpy, the readable form of the kernel the numba passes use (tests)."""
    vx, vy = _edge_vectors(grid)
    lp = np.zeros(grid.n_cells) if log_prior is None else np.asarray(log_prior, float)
    w = -((vx - disp[0]) ** 2 + (vy - disp[1]) ** 2) / (2 * sigma**2) + lp[grid.dst]
    src = np.repeat(np.arange(grid.n_cells), np.diff(grid.src_ptr))
    m = np.full(grid.n_cells, -np.inf)
    np.maximum.at(m, src, w)
    z = np.zeros(grid.n_cells)
    np.add.at(z, src, np.exp(w - m[src]))
    return w - (m + np.log(z))[src]


def _edge_vectors(grid: CrfGrid) -> tuple[np.ndarray, np.ndarray]:
    """(vx, vy) (E,) m: every edge's vector (its target's centre minus its source's)."""
    return _edge_geometry(grid)[:2]


def _edge_geometry(grid: CrfGrid) -> tuple[np.ndarray, ...]:
    """(vx (E,), vy (E,), eoff (E,) int32, ovx (D,), ovy (D,)): the edge vectors, and each edge's index among the
    grid's distinct edge vectors (ovx, ovy; a whole number of cells each way, so D is the neighbourhood's size),
    computed once per grid (kept on it: a grid's edges are not changed after it is built)."""
    geo = getattr(grid, "_edge_geometry_cache", None)
    if geo is None:
        d = grid.xy[grid.dst] - grid.xy[np.repeat(np.arange(grid.n_cells), np.diff(grid.src_ptr))]
        cells = np.rint(d / grid.cell_m).astype(np.int64)
        r = int(np.abs(cells).max(initial=0))
        key = (cells[:, 0] + r) * (2 * r + 1) + (cells[:, 1] + r)
        uniq, eoff = np.unique(key, return_inverse=True)
        ov = np.column_stack([uniq // (2 * r + 1) - r, uniq % (2 * r + 1) - r]) * grid.cell_m
        geo = (np.ascontiguousarray(d[:, 0]), np.ascontiguousarray(d[:, 1]), eoff.astype(np.int32).ravel(),
               np.ascontiguousarray(ov[:, 0], float), np.ascontiguousarray(ov[:, 1], float))
        grid._edge_geometry_cache = geo
    return geo


def _prepare(grid, disp, sigma, unary, log_init, log_prior, layers):
    K = len(unary)
    N = grid.n_cells
    disp = np.asarray(disp, float).reshape(-1, 2)
    if len(disp) != K - 1:
        raise ValueError(f"smoother: disp must be (K-1, 2) = ({K - 1}, 2), got {disp.shape}")
    sigma = np.broadcast_to(np.asarray(sigma, float), (max(K - 1, 0),)).copy()
    if (sigma <= 0).any():
        raise ValueError("smoother: sigma must be > 0")
    layers = layers or Layers()
    # alpha, post, a lagged copy and the exp temporary (K, L, N); the unaries and the marginals' statistics (K, N)
    check_memory(4.0 * K * layers.n * N * 8 + 3.0 * K * N * 8, f"a walk smoother of {K:,} nodes x {layers.n} layers "
                 f"x {N:,} cells", "smoother (dt_s, layers, cell_m)")
    has = np.array([u is not None for u in unary])
    U = np.zeros((K, N))
    for k, u in enumerate(unary):
        if u is not None:
            u = np.asarray(u, float)
            if u.shape != (N,):
                raise ValueError(f"smoother: unary[{k}] must be ({N},) per cell, got {u.shape}")
            U[k] = u
    for what, v in (("log_init", log_init), ("log_prior", log_prior)):
        if v is not None and np.shape(v) != (N,):
            raise ValueError(f"smoother: {what} must be ({N},) per cell, got {np.shape(v)}")
    li = np.full(N, -math.log(N)) if log_init is None else np.asarray(log_init, float)
    lp = np.zeros(N) if log_prior is None else np.asarray(log_prior, float)
    ca, sa = layers.arrays()
    vx, vy = _edge_vectors(grid)
    return K, N, disp, sigma, has, U, li, lp, ca, sa, vx, vy


def _linear_kernel(grid, lp):
    """(eoff, ovx, ovy, elp, elp_under) of the linear-domain passes: the edges' offsets (:func:`_edge_geometry`), the
    targets' prior weights exp(log_prior - its max) (N,), and whether one of them, finite in the log domain, is below
    exp(-_DEEP) (the passes are then in the log domain)."""
    _, _, eoff, ovx, ovy = _edge_geometry(grid)
    top = lp.max(initial=-np.inf)
    elp = np.exp(lp - top) if np.isfinite(top) else np.zeros_like(lp)
    under = bool(np.any(np.isfinite(lp) & (lp < top - _DEEP)))  # a finite prior weight below exp(-_DEEP)
    return eoff, ovx, ovy, elp, under


def _prune_log(prune: float) -> float:
    if not 0.0 <= float(prune) < 1.0:
        raise ValueError(f"smoother: prune must be in [0, 1), got {prune}")
    return math.log(prune) if prune > 0 else -np.inf


def _stats(P: np.ndarray, xy: np.ndarray):
    """(mean (K, 2), cov (K, 2, 2), mode (K,)) of cell marginals P (K, N) (summing to 1 per row)."""
    mean = P @ xy
    # second moments about a floor-centred origin (no cancellation on large coordinates), minus the mean's outer product
    c = xy.mean(axis=0)
    x, y = xy[:, 0] - c[0], xy[:, 1] - c[1]
    m2 = P @ np.column_stack([x * x, x * y, y * y])
    mx, my = mean[:, 0] - c[0], mean[:, 1] - c[1]
    cxx, cxy, cyy = m2[:, 0] - mx * mx, m2[:, 1] - mx * my, m2[:, 2] - my * my
    cov = np.stack([np.stack([cxx, cxy], -1), np.stack([cxy, cyy], -1)], -2)
    return mean, cov, P.argmax(axis=1)


def forward_backward(grid: CrfGrid, disp: np.ndarray, sigma, unary: list, log_init: np.ndarray | None = None,
                     log_prior: np.ndarray | None = None, layers: Layers | None = None,
                     prune: float = 1e-9, lag: int = 0) -> SmootherResult:
    """Filtered and smoothed marginals of the walk model (module doc).

    grid: the walkable cells (N) and their edges; disp (K-1, 2) m: the odometry displacement between consecutive
    nodes (world frame); sigma: scalar or (K-1,) m, the displacement noise per interval; unary: K entries, each (N,)
    log-likelihood of the node's observations per cell or None (no observation); log_init (N,): log start
    distribution (None: uniform over the cells); log_prior (N,): log weight of a target cell in every transition
    (None: flat); layers: the heading-offset / step-scale hypotheses; prune: the forward pruning threshold; lag > 0:
    the ``filtered_*`` statistics are those of the fixed-lag smoother, p(x_k | observations up to node k + lag)."""
    K, N, disp, sigma, has, U, li, lp, ca, sa, vx, vy = _prepare(grid, disp, sigma, unary, log_init, log_prior,
                                                                 layers)
    L = len(ca)
    pl = _prune_log(prune)
    if int(lag) < 0:
        raise ValueError(f"smoother: lag must be >= 0 nodes, got {lag}")
    alpha = np.empty((K, L, N), np.float64)
    w = np.empty(int(np.diff(grid.src_ptr).max()))
    eoff, ovx, ovy, elp, elp_under = _linear_kernel(grid, lp)
    logev = _forward_sum(grid.src_ptr, grid.dst, eoff, ovx, ovy, vx, vy, disp, sigma, ca, sa, lp, elp, elp_under, U,
                         has, li, pl, alpha, w)
    post = np.empty((K, L, N), np.float64)
    _backward(grid.src_ptr, grid.dst, eoff, ovx, ovy, vx, vy, disp, sigma, ca, sa, lp, elp, elp_under, U, has, alpha,
              pl, post, w)
    if int(lag) > 0:
        lagged = np.empty((K, L, N), np.float64)
        _lagged(grid.src_ptr, grid.dst, eoff, ovx, ovy, vx, vy, disp, sigma, ca, sa, lp, elp, elp_under, U, has, alpha,
                pl, int(lag), lagged, w)
        Pf = _cell_marginals(lagged)
    else:
        Pf = _cell_marginals(alpha)
    fm, fc, fo = _stats(Pf, grid.xy)
    sm, sc, so = _stats(_cell_marginals(post), grid.xy)
    lay = np.exp(post[K - 1]).sum(axis=1)
    return SmootherResult(fm, fc, fo, sm, sc, so, lay / lay.sum(), float(logev))


def viterbi(grid: CrfGrid, disp: np.ndarray, sigma, unary: list, log_init: np.ndarray | None = None,
            log_prior: np.ndarray | None = None, layers: Layers | None = None, prune: float = 1e-9
            ) -> tuple[np.ndarray, int]:
    """The most probable (cell (K,), layer) sequence of the walk model (same arguments as
    :func:`forward_backward`); pruning on the max-product messages normalised to sum to one."""
    K, N, disp, sigma, has, U, li, lp, ca, sa, vx, vy = _prepare(grid, disp, sigma, unary, log_init, log_prior,
                                                                 layers)
    L = len(ca)
    pl = _prune_log(prune)
    delta = np.empty((K, L, N), np.float64)
    back = np.full((K, L, N), -1, np.int32)
    _forward_max(grid.src_ptr, grid.dst, vx, vy, disp, sigma, ca, sa, lp, U, has, li, pl, delta, back,
                 np.empty(int(np.diff(grid.src_ptr).max())))
    l, j = np.unravel_index(int(np.argmax(delta[K - 1])), (L, N))
    path = np.empty(K, np.int64)
    path[K - 1] = j
    for k in range(K - 1, 0, -1):
        j = int(back[k, l, j])
        if j < 0:  # node k restarted (every path ruled out): the path before it ends at node k-1's best cell
            j = int(np.argmax(delta[k - 1, l]))
        path[k - 1] = j
    return path, int(l)


def brute_force(grid: CrfGrid, disp, sigma, unary: list, log_init=None, log_prior=None, layers: Layers | None = None):
    """Exact (marginals (K, N), best path (K,), best layer) of a tiny model by enumerating all L x N^K sequences
    over the grid's edges (the reference of the tests; exponential)."""
    K, N, disp, sigma, has, U, li, lp, ca, sa, vx, vy = _prepare(grid, disp, sigma, unary, log_init, log_prior,
                                                                 layers)
    L = len(ca)
    logw = {}
    for k in range(K - 1):
        for l in range(L):
            p = np.array([ca[l] * disp[k, 0] - sa[l] * disp[k, 1], sa[l] * disp[k, 0] + ca[l] * disp[k, 1]])
            e_lw = -((vx - p[0]) ** 2 + (vy - p[1]) ** 2) / (2 * sigma[k] ** 2) + lp[grid.dst]
            for i in range(N):
                a, b = grid.src_ptr[i], grid.src_ptr[i + 1]
                z = np.logaddexp.reduce(e_lw[a:b])
                for e in range(a, b):
                    logw[(k, l, i, int(grid.dst[e]))] = e_lw[e] - z
    M = np.zeros((K, N))
    best, best_path, best_l = -np.inf, None, 0
    paths = []  # (log weight, sequence) of every possible path; normalised by their logsumexp (weights far below 1)
    for l in range(L):
        for seq in itertools.product(range(N), repeat=K):
            v = li[seq[0]] - math.log(L) + U[0, seq[0]]
            for k in range(K - 1):
                key = (k, l, seq[k], seq[k + 1])
                if key not in logw:
                    v = -np.inf
                    break
                v += logw[key] + U[k + 1, seq[k + 1]]
            if v == -np.inf:
                continue
            paths.append((v, seq))
            if v > best:
                best, best_path, best_l = v, np.array(seq), l
    tot = np.logaddexp.reduce([v for v, _ in paths])
    for v, seq in paths:
        for k in range(K):
            M[k, seq[k]] += math.exp(v - tot)
    return M, best_path, best_l
