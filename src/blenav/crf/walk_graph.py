"""A walk's track as a factor graph, refined from the grid smoother's marginals (issue 30's second smoother:
``fused-offline`` with ``estimate: graph``, :class:`blenav.localizers.fusedwalk.FusedWalk`).

Variables: the position x_k (m, the building's world frame) of each of the K nodes of a walk. Factors (GTSAM's
``PriorFactorPoint2`` / ``BetweenFactorPoint2`` with the same noise models give the same optimum:
tests/crf/test_walk_graph.py):

* odometry: x_{k+1} - x_k = d_k + N(0, sigma_k^2 I), d_k the odometry's displacement over the interval already turned
  and scaled by the walk's heading offset and step scale (the grid's most probable layer);
* fixes: x_{n_j} = f_j + N(0, s_j^2 I) under a robust kernel rho (Cauchy by default: a fix 20 m off costs a bounded
  amount, as the grid's heavy tail);
* the grid's smoothed marginal at every node as a prior, N(m_k, ``prior_scale`` (P_k + c^2/12 I)) (c the cell size,
  the spread of a marginal on one cell): it holds the graph in the mode the grid found (a uniform start has no other
  anchor) and near the walkable cells the grid weighed (the graph knows no walls).

Every factor is linear in x but for the kernel: iteratively reweighted least squares (IRLS; the M-estimator weights
of Huber 1964 and Zhang 1997, as GTSAM's ``noiseModel.Robust`` applies them to the whitened residual's norm), each
pass the exact solution of the block-tridiagonal normal equations for the current weights w_j = rho'(e_j) / e_j (e_j
the fix's whitened residual; Cauchy k^2 / (k^2 + e^2), Huber min(1, k / e)) by block elimination along the walk, and
the marginal covariances from the same factorisation (the backward recursion of Rauch, Tung and Striebel 1965 in
information form). A factor graph in the sense of Dellaert and Kaess, "Factor Graphs for Robot Perception" (2017);
this one is a chain, so its normal equations need no sparse solver. numba; O(K) per pass.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

log = logging.getLogger("blenav.crf.walk_graph")

__all__ = ["refine_walk", "GraphSettings", "KERNELS"]

KERNELS = ("cauchy", "huber", "none")


@dataclass(frozen=True)
class GraphSettings:
    """The graph's settings (a method's ``graph:`` block; a key not here is refused by the constructor):
    ``prior_scale`` the marginals' covariance factor (0: no prior), ``kernel`` / ``kernel_k`` the fixes' robust kernel
    (k in fix stds), ``odo_sigma_scale`` the odometry's std factor, ``window_s`` the span of an online graph (s)."""

    prior_scale: float = 64.0
    kernel: str = "cauchy"
    kernel_k: float = 1.0
    odo_sigma_scale: float = 1.0
    window_s: float = 60.0

    def __post_init__(self):
        if self.kernel not in KERNELS:
            raise ValueError(f"kernel must be one of {KERNELS}, got {self.kernel!r}")
        for key in ("kernel_k", "odo_sigma_scale", "window_s"):
            if not float(getattr(self, key)) > 0:
                raise ValueError(f"{key} must be > 0, got {getattr(self, key)}")
        if not (math.isfinite(self.prior_scale) and self.prior_scale >= 0):
            raise ValueError(f"prior_scale must be finite and >= 0, got {self.prior_scale}")

    def refine(self, init, prior_cov, disp, sigma, fix_node, fix_xy, fix_std, cell_m: float):
        """:func:`refine_walk` with these settings (the odometry's std times ``odo_sigma_scale``): (positions,
        covariances)."""
        return refine_walk(init, prior_cov, disp, self.odo_sigma_scale * np.asarray(sigma, float), fix_node, fix_xy,
                           fix_std, prior_scale=self.prior_scale, cell_m=cell_m, kernel=self.kernel,
                           kernel_k=self.kernel_k)[:2]


@njit(cache=True, nogil=True)
def _inv2(a):
    det = a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]
    if not det > 0.0:  # a positive-definite block has det > 0; anything else: no anchor reaches this node
        raise ValueError("refine_walk: singular normal equations (a stretch of the walk with no prior and no fix)")
    out = np.empty((2, 2))
    out[0, 0], out[1, 1] = a[1, 1] / det, a[0, 0] / det
    out[0, 1], out[1, 0] = -a[0, 1] / det, -a[1, 0] / det
    return out


@njit(cache=True, nogil=True)
def _solve(Hd, g, q, with_cov):
    """Block-tridiagonal H (diagonal blocks Hd (K, 2, 2), off-diagonal -q_k I between k and k+1, q (K-1,)) x = g (K, 2):
    x (K, 2) and, with ``with_cov``, the diagonal blocks of H^-1 (K, 2, 2)."""
    K = Hd.shape[0]
    Dinv = np.empty((K, 2, 2))
    z = np.empty((K, 2))
    Dinv[0] = _inv2(Hd[0])
    z[0] = g[0]
    for k in range(1, K):
        qq = q[k - 1]
        Dinv[k] = _inv2(Hd[k] - qq * qq * Dinv[k - 1])
        z[k] = g[k] + qq * (Dinv[k - 1] @ z[k - 1])
    x = np.empty((K, 2))
    x[K - 1] = Dinv[K - 1] @ z[K - 1]
    for k in range(K - 2, -1, -1):
        x[k] = Dinv[k] @ (z[k] + q[k] * x[k + 1])
    cov = np.empty((K, 2, 2))
    if with_cov:
        cov[K - 1] = Dinv[K - 1]
        for k in range(K - 2, -1, -1):
            G = q[k] * Dinv[k]
            cov[k] = Dinv[k] + G @ cov[k + 1] @ G.T
    return x, cov


def _weights(e: np.ndarray, kernel: str, k: float) -> np.ndarray:
    if kernel == "cauchy":
        return k * k / (k * k + e * e)
    if kernel == "huber":
        return np.minimum(1.0, k / np.maximum(e, 1e-300))
    return np.ones_like(e)


def refine_walk(init: np.ndarray, prior_cov: np.ndarray, disp: np.ndarray, sigma: np.ndarray, fix_node: np.ndarray,
                fix_xy: np.ndarray, fix_std: np.ndarray, prior_scale: float = 64.0, cell_m: float = 1.0,
                kernel: str = "cauchy", kernel_k: float = 1.0, tol_m: float = 1e-7,
                max_iterations: int = 200) -> tuple[np.ndarray, np.ndarray, int]:
    """The walk's refined track (module doc).

    ``init`` (K, 2) m the grid's smoothed means (the start of IRLS, and the priors' means), ``prior_cov`` (K, 2, 2) m^2
    their covariances (``prior_scale`` <= 0: no prior), ``disp`` (K-1, 2) m the odometry displacement per interval
    (turned by the walk's layer), ``sigma`` (K-1,) m its std; ``fix_node`` (F,) node of each fix, ``fix_xy`` (F, 2)
    m, ``fix_std`` (F,) m; ``kernel`` the fixes' robust kernel, ``kernel_k`` in units of the fix's std. Returns
    (positions (K, 2) m, marginal covariances (K, 2, 2) m^2 at the solution's weights, IRLS passes)."""
    if kernel not in KERNELS:
        raise ValueError(f"kernel must be one of {KERNELS}, got {kernel!r}")
    init = np.ascontiguousarray(init, float)
    K = len(init)
    disp, sigma = np.asarray(disp, float).reshape(-1, 2), np.asarray(sigma, float).ravel()
    if K < 1 or disp.shape != (K - 1, 2) or sigma.shape != (K - 1,) or not (np.isfinite(sigma) & (sigma > 0)).all():
        raise ValueError(f"refine_walk: {K} nodes need disp (K-1, 2) and sigma (K-1,) finite and > 0, got "
                         f"{disp.shape}, {sigma.shape}")
    node = np.asarray(fix_node, np.int64).ravel()
    fxy, fsd = np.asarray(fix_xy, float).reshape(-1, 2), np.asarray(fix_std, float).ravel()
    if len(node) != len(fxy) or len(node) != len(fsd) or (len(node) and (node.min() < 0 or node.max() >= K)) \
            or not (np.isfinite(fsd) & (fsd > 0)).all() or not np.isfinite(fxy).all():
        raise ValueError("refine_walk: fix_node, fix_xy and fix_std must have one row per fix, nodes in [0, K), "
                         "finite positions and finite stds > 0")
    if not np.isfinite(prior_scale) or not np.isfinite(init).all():
        raise ValueError(f"refine_walk: prior_scale ({prior_scale}) and init must be finite")
    if prior_scale <= 0 and not len(node):
        raise ValueError("refine_walk: no prior and no fix: the track has no anchor")
    q = 1.0 / sigma ** 2
    H0 = np.zeros((K, 2, 2))
    g0 = np.zeros((K, 2))
    if prior_scale > 0:  # the grid's marginals
        lam = np.linalg.inv(prior_scale * (np.asarray(prior_cov, float) + (cell_m ** 2 / 12.0) * np.eye(2)))
        H0 += lam
        g0 += np.einsum("kij,kj->ki", lam, init)
    H0[:-1, 0, 0] += q
    H0[:-1, 1, 1] += q
    H0[1:, 0, 0] += q
    H0[1:, 1, 1] += q
    g0[:-1] -= q[:, None] * disp
    g0[1:] += q[:, None] * disp
    def system(x):  # the normal equations with the fixes' weights at x
        w = _weights(np.hypot(*(x[node] - fxy).T) / fsd, kernel, kernel_k) / fsd ** 2
        H, g = H0.copy(), g0.copy()
        np.add.at(H[:, 0, 0], node, w)
        np.add.at(H[:, 1, 1], node, w)
        np.add.at(g, node, w[:, None] * fxy)
        return H, g

    x, it = init, 0
    for it in range(1, max_iterations + 1):
        x_new, _ = _solve(*system(x), q, False)
        step = float(np.abs(x_new - x).max())
        x = x_new
        if step < tol_m or kernel == "none":
            break
    else:
        log.warning("refine_walk: %d IRLS passes without converging (last step %.2g m > %.2g m)", max_iterations,
                    step, tol_m)
    _, cov = _solve(*system(x), q, True)  # the covariances at the solution's own weights
    return x, cov, it
