"""Viterbi on the CRF's grid (Duembgen et al., 004, sec. IV and IV-B), in log space.

One step of eq. 4, p_j(y_i) = max_k p_{j-1}(y_k) Psi(y_i, y_k, Z_j), with the pairwise part of Psi the IMU
features (eqs. 13-14, normalised over the targets of each source cell: a transition kernel) or, without IMU,
the uniform kernel over the cells reachable in one step; the unary part (RTT, BLE) is added afterwards and
the result normalised to sum to one on the grid. Pruning (004 sec. IV-B): only cells whose normalised
probability at the previous step is at least ``prune`` (1e-10) are sources of the max-product; ``prune`` = 0
keeps every cell.

The max-product runs over the sparse transition structure of :class:`~blenav.crf.grid.CrfGrid` in one
compiled pass over the active sources' edges (:func:`maxprod_step`, numba; a scatter-max with the argmax
kept as backpointer), so its cost is the number of active edges; :func:`maxprod_step_numpy` is the
vectorised numpy reference over the by-target CSR (``np.maximum.reduceat``) used by the tests. Ties go to
the lower source index in both.

Estimates: the argmax cell per step (eq. 16). "CRF recursive" (004 sec. IV-B): the backpointers (the argmax
of eq. 4) are kept for the cells above the pruning threshold and the state sequence is backtracked from the
final argmax (:meth:`ViterbiDecoder.backtrack`): an offline, smoothed track. At a visual reset (eq. 15) the
map is replaced; the reset cell keeps its transition backpointer, and where it has none (the fix lies
outside every cell reachable from the previous map) the backtrack continues from the previous step's
argmax.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .features import normalise_log
from .grid import CrfGrid

__all__ = ["maxprod_step", "maxprod_step_numpy", "ViterbiDecoder", "transition_log_numpy"]


@njit(cache=True, nogil=True)
def _wrap(a):
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@njit(cache=True, nogil=True, inline="always")
def _edge_w(length, heading, use_heading, inv_sl, inv_st, dist, angle):
    r = (length - dist) * inv_sl
    w = -0.5 * r * r
    if use_heading:
        if dist > 0.0:
            d = _wrap(heading - angle)
        else:
            d = math.pi
        w -= 0.5 * (d * inv_st) * (d * inv_st)
    return w


@njit(cache=True, nogil=True)
def _log_norm(length, heading, use_heading, inv_sl, inv_st, dist, angle):
    m = -np.inf
    for e in range(dist.shape[0]):
        w = _edge_w(length, heading, use_heading, inv_sl, inv_st, dist[e], angle[e])
        if w > m:
            m = w
    z = 0.0
    for e in range(dist.shape[0]):
        z += math.exp(_edge_w(length, heading, use_heading, inv_sl, inv_st, dist[e], angle[e]) - m)
    return m + math.log(z)


@njit(cache=True, nogil=True)
def _maxprod(score, thresh, src_ptr, dst, dist, angle, off_dist, off_angle, use_imu, length, heading, use_heading,
             inv_sl, inv_st, normalise, out, back):
    N = score.shape[0]
    for j in range(N):
        out[j] = -np.inf
        back[j] = -1
    n_active = 0
    D = off_dist.shape[0]
    lz_full = 0.0
    if use_imu and normalise:  # every cell with a full neighbourhood has the same normaliser: once per step
        lz_full = _log_norm(length, heading, use_heading, inv_sl, inv_st, off_dist, off_angle)
    for i in range(N):
        s = score[i]
        if not (s >= thresh):
            continue
        n_active += 1
        a = src_ptr[i]
        b = src_ptr[i + 1]
        if use_imu:
            lz = 0.0
            if normalise:
                lz = lz_full if b - a == D else _log_norm(length, heading, use_heading, inv_sl, inv_st, dist[a:b],
                                                          angle[a:b])
            for e in range(a, b):
                v = s + _edge_w(length, heading, use_heading, inv_sl, inv_st, dist[e], angle[e]) - lz
                j = dst[e]
                if v > out[j]:
                    out[j] = v
                    back[j] = i
        else:
            lz = math.log(b - a) if normalise else 0.0
            v = s - lz
            for e in range(a, b):
                j = dst[e]
                if v > out[j]:
                    out[j] = v
                    back[j] = i
    return n_active


def maxprod_step(grid: CrfGrid, score: np.ndarray, prune_log: float = math.log(1e-10), imu=None,
                 sigma_l: float = 2.0, sigma_theta: float = 0.1, normalise: bool = True,
                 out: np.ndarray | None = None, back: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """max_k score[k] + ln Psi_pair(i, k) for every cell i (eq. 4, log space), compiled.

    score (N,) log-probabilities of the previous step (normalised); sources below ``prune_log`` are skipped.
    imu: None (uniform kernel over reachable cells) or (l_IMU m, theta_IMU rad, step_detected bool).
    Returns (out (N,), back (N,) int32 argmax source or -1, number of active sources)."""
    N = grid.n_cells
    out = np.empty(N) if out is None else out
    back = np.empty(N, np.int32) if back is None else back
    if imu is None:
        length, heading, use_heading, use_imu = 0.0, 0.0, False, False
    else:
        length, heading, use_heading = float(imu[0]), float(imu[1]), bool(imu[2])
        use_imu = True
    n = _maxprod(np.ascontiguousarray(score, dtype=np.float64), float(prune_log), grid.src_ptr, grid.dst, grid.dist,
                 grid.angle, grid.off_dist, grid.off_angle, use_imu, length, heading, use_heading, 1.0 / sigma_l,
                 1.0 / sigma_theta, bool(normalise), out, back)
    return out, back, int(n)


def transition_log_numpy(grid: CrfGrid, imu=None, sigma_l: float = 2.0, sigma_theta: float = 0.1,
                         normalise: bool = True) -> np.ndarray:
    """(E,) ln Psi_pair per edge in by-source order (numpy reference of the kernel's weights)."""
    from .features import imu_edge_log

    src = np.repeat(np.arange(grid.n_cells), np.diff(grid.src_ptr))
    if imu is None:
        w = np.zeros(grid.n_edges)
    else:
        w = imu_edge_log(float(imu[0]), float(imu[1]), grid.dist, grid.angle, sigma_l, sigma_theta, bool(imu[2]))
    if normalise:
        m = np.maximum.reduceat(w, grid.src_ptr[:-1])
        z = np.add.reduceat(np.exp(w - m[src]), grid.src_ptr[:-1])
        w = w - (m + np.log(z))[src]
    return w


def maxprod_step_numpy(grid: CrfGrid, score: np.ndarray, prune_log: float = math.log(1e-10), imu=None,
                       sigma_l: float = 2.0, sigma_theta: float = 0.1, normalise: bool = True
                       ) -> tuple[np.ndarray, np.ndarray]:
    """The same step as :func:`maxprod_step`, vectorised in numpy over the by-target CSR (reference)."""
    w = transition_log_numpy(grid, imu, sigma_l, sigma_theta, normalise)[grid.tedge]
    s = score[grid.tsrc]
    cand = np.where(s >= prune_log, s + w, -np.inf)
    best = np.maximum.reduceat(cand, grid.tgt_ptr[:-1])
    tgt = np.repeat(np.arange(grid.n_cells), np.diff(grid.tgt_ptr))
    hit = (cand == best[tgt]) & np.isfinite(cand)
    back = np.full(grid.n_cells, -1, np.int32)
    first = np.flatnonzero(hit)
    # the first hit per target (lowest source: tsrc is sorted within a target)
    first = first[np.r_[True, tgt[first][1:] != tgt[first][:-1]]] if len(first) else first
    back[tgt[first]] = grid.tsrc[first]
    return best, back


class ViterbiDecoder:
    """Step-by-step Viterbi over a :class:`CrfGrid` with pruning, argmax estimates and backtracking.

    ``prune``: probability below which a previous cell is no source (1e-10, 004 sec. IV-B; 0: none).
    ``sigma_l`` (m), ``sigma_theta`` (rad): the IMU features' standard deviations (eqs. 13-14).
    ``keep_backpointers``: store what :meth:`backtrack` needs (the backpointers of the cells above the
    pruning threshold, per step)."""

    def __init__(self, grid: CrfGrid, prune: float = 1e-10, sigma_l: float = 2.0, sigma_theta: float = 0.1,
                 normalise_transitions: bool = True, keep_backpointers: bool = True):
        self.grid = grid
        self.prune_log = math.log(prune) if prune > 0 else -np.inf
        self.sigma_l, self.sigma_theta = float(sigma_l), float(sigma_theta)
        self.normalise = bool(normalise_transitions)
        self.keep = bool(keep_backpointers)
        N = grid.n_cells
        self.score = np.full(N, -math.log(N))  # uniform start
        self._out = np.empty(N)
        self._back = np.empty(N, np.int32)
        self.cells: list[np.ndarray] = []
        self.preds: list[np.ndarray] = []
        self.argmax: list[int] = []
        self.active: list[int] = []

    def step(self, unary=None, imu=None, reset: np.ndarray | None = None) -> int:
        """Advance one step: transitions (``imu`` = (l, theta, step_detected) or None), then the unary log
        features, or -- at a visual fix -- ``reset`` (N,) log map replacing the result (eq. 15).

        ``unary``: None (no unary feature), an (N,) array, or a callable ``unary(cells) -> (len(cells),)``
        evaluated only on the cells the transitions reached (the others have probability 0): the features'
        normalisation constants are the same for every cell, so the normalised result is the same as with the
        features evaluated and normalised on the whole grid. Returns the argmax cell (eq. 16)."""
        out, back, n_act = maxprod_step(self.grid, self.score, self.prune_log, imu, self.sigma_l, self.sigma_theta,
                                        self.normalise, self._out, self._back)
        if reset is not None:
            new = normalise_log(np.asarray(reset, float).copy())
        elif callable(unary):
            cand = np.flatnonzero(out > -np.inf)
            new = np.full_like(out, -np.inf)
            v = out[cand] + unary(cand)
            new[cand] = normalise_log(v)
        else:
            new = out + unary if unary is not None else out.copy()
            new = normalise_log(new)
        best = int(np.argmax(new))
        if self.keep:
            keep = np.flatnonzero(new >= self.prune_log) if np.isfinite(self.prune_log) else np.flatnonzero(np.isfinite(new))
            if reset is not None and best not in set(keep.tolist()):
                keep = np.union1d(keep, [best])
            self.cells.append(keep.astype(np.int32))
            self.preds.append(back[keep].copy())
        self.argmax.append(best)
        self.active.append(n_act)
        self.score = new
        return best

    def backtrack(self) -> np.ndarray:
        """(K,) cells of the most likely sequence ending in the final argmax ("CRF recursive", 004 sec. IV-B)."""
        if not self.keep:
            raise ValueError("backtrack needs keep_backpointers=True")
        K = len(self.argmax)
        path = np.empty(K, np.int64)
        if K == 0:
            return path
        c = self.argmax[-1]
        path[-1] = c
        for k in range(K - 1, 0, -1):
            cells = self.cells[k]
            i = np.searchsorted(cells, c)
            pred = int(self.preds[k][i]) if i < len(cells) and cells[i] == c else -1
            c = pred if pred >= 0 else self.argmax[k - 1]
            path[k - 1] = c
        return path
