"""A radio map on the walkable grid (issue 30): what a scan heard at each cell looks like, from the train walks'
fingerprints, as a likelihood over the cells instead of one KNN point.

A KNN fix collapses a scan that resembles two places into one point between them, and answers only with places
the survey visited. The radio map keeps every cell: the fingerprint expected at cell c is the kernel-weighted mean
of the train walks' fingerprints (Nadaraya-Watson, Gaussian kernel of ``bandwidth_m`` on their labelled positions),
shrunk towards the floor's mean fingerprint where few train fingerprints are near (``shrink``: the weight of that
mean, in kernel units), so an unsurveyed cell is *uninformative* rather than confidently wrong:

    m(c) = (sum_j K(c - x_j) s_j + shrink * s_mean) / (sum_j K(c - x_j) + shrink)
    log p(scan | c) = -|s - m(c)|^2 / tau   (normalised over the cells)

with s the scan's fingerprint in the KNN's representation (:func:`blenav.localizers.knn.represent`: ``metric``
powed / cosine, the BLE part weighted by ``ble_weight``), tau a temperature (the scale of the squared unit-norm
distances, 0..4). Fingerprints as :mod:`blenav.features.fingerprints` reads them (WiFi scans read as heard with the BLE
advertisements of the last 3 s, ``features: both``; ``ble`` on a floor whose train walks have no WiFi). numpy; the
map of a floor is (N cells, F features) float32, built in chunks of cells.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from blenav.features import fingerprints as FP
from blenav.limits import check_memory

from . import knn as KNN

__all__ = ["RadioMap", "RadioMapConfig", "build_radio_map"]


@dataclass(frozen=True)
class RadioMapConfig:
    """Settings of :func:`build_radio_map` (module doc); m, unit-norm distance units."""

    bandwidth_m: float = 4.0
    shrink: float = 1.0
    tau: float = 0.03
    metric: str = "powed"
    ble_weight: float = 0.25
    min_count: int = 2  # a feature heard in fewer train readings is dropped

    def __post_init__(self):
        if not (self.bandwidth_m > 0 and self.shrink >= 0 and self.tau > 0):
            raise ValueError(f"radio_map: need bandwidth_m > 0, shrink >= 0, tau > 0 (got {self.bandwidth_m}, "
                             f"{self.shrink}, {self.tau})")
        if self.metric not in ("powed", "cosine"):
            raise ValueError(f"radio_map: metric must be powed or cosine, got {self.metric!r}")


@dataclass
class RadioMap:
    """The expected fingerprint ``m`` (N, D) float32 per grid cell, the reading config and feature columns it was built
    with, and ``support`` (N,): the kernel weight of the train fingerprints at each cell (how surveyed it is)."""

    cfg: RadioMapConfig
    fp: FP.FingerprintConfig
    columns: dict
    is_ble: np.ndarray
    m: np.ndarray
    support: np.ndarray
    n_train: int
    mm: np.ndarray | None = None  # (N,) the squared norms of m (computed on first use)

    def scans(self, session) -> tuple[np.ndarray, np.ndarray]:
        """(t (F,) s, Q (F, D)): the session's scans heard in the map's features, in its representation."""
        w = FP.session_windows(session, self.columns, self.fp)
        keep = w.heard
        Q = KNN.represent(w.S[keep], self.cfg.metric, self.is_ble, self.cfg.ble_weight, self.fp.fill_dbm)
        return w.t[keep], Q.astype(np.float32)

    def log_likelihood(self, Q: np.ndarray) -> np.ndarray:
        """(F, N) log p(scan | cell) of scans Q (F, D), normalised over the cells (each row's logsumexp is 0)."""
        if self.mm is None:  # the map's squared norms, once
            self.mm = np.einsum("nd,nd->n", self.m, self.m)
        L = -KNN._sqdist(Q, self.m, self.mm).astype(np.float64) / self.cfg.tau
        return L - np.logaddexp.reduce(L, axis=1)[:, None]


def _fingerprints(walks: list, fp: FP.FingerprintConfig, min_count: int):
    tables, used = FP.readable(walks, fp)
    if not used:
        return None
    names = FP.vocabulary(tables, min_count)
    columns = {n: i for i, n in enumerate(names)}
    S, xy = [], []
    for s, rd in zip(used, tables):
        w, _ = FP.label_windows(s, FP.session_windows(s, columns, fp, rd))
        ok = np.isfinite(w.xy).all(axis=1) & w.heard
        S.append(w.S[ok])
        xy.append(w.xy[ok])
    S, xy = np.concatenate(S), np.concatenate(xy)
    return (columns, names, S, xy) if len(S) >= 2 else None


def build_radio_map(grid, walks: list, cfg: RadioMapConfig | None = None) -> RadioMap | None:
    """The radio map of ``grid`` (:class:`blenav.crf.grid.CrfGrid`) from the labelled ``walks`` of its floor (their
    fingerprints labelled by the waypoint interpolation at the scan times); WiFi + BLE when the walks have WiFi scans,
    else BLE; None when they have neither."""
    cfg = cfg or RadioMapConfig()
    got, fp = None, None
    for features in ("both", "ble"):
        fp = FP.FingerprintConfig(features=features, wifi_age_ref="scan", wifi_time="heard")
        got = _fingerprints(walks, fp, cfg.min_count)
        if got is not None:
            break
    if got is None:
        return None
    columns, names, S, xy = got
    is_ble = np.array([n.startswith("ble:") for n in names])
    X = KNN.represent(S, cfg.metric, is_ble, cfg.ble_weight, fp.fill_dbm).astype(np.float32)
    N, D = grid.n_cells, X.shape[1]
    check_memory(4.0 * (N * D + len(X) * D + 1024 * len(X)), f"a radio map of {N:,} cells x {D:,} features from "
                 f"{len(X):,} fingerprints", "radio_map (grid cell_m, the floor's vocabulary)")
    m = np.empty((N, D), np.float32)
    support = np.empty(N)
    mean = X.mean(axis=0)
    xy32, inv = xy.astype(np.float32), np.float32(1.0 / (2.0 * cfg.bandwidth_m**2))
    for a in range(0, N, 1024):  # bounded memory: 1024 cells x the fingerprints at a time
        c = grid.xy[a:a + 1024].astype(np.float32)
        K = np.exp(-((c[:, None, :] - xy32[None]) ** 2).sum(axis=2) * inv)
        w = K.sum(axis=1)
        m[a:a + 1024] = (K @ X + cfg.shrink * mean[None]) / (w + cfg.shrink)[:, None]
        support[a:a + 1024] = w
    return RadioMap(cfg, fp, columns, is_ble, m, support, len(X))
