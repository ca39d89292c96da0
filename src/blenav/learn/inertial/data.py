"""Training data of the inertial odometry (issue 31): IMU windows of labelled walks and the segments that supervise
them.

Walks. Every labelled session with an IMU of ``data.path`` and ``data.extra_paths`` (only ``data.sessions`` when
given): its IMU in the gravity-aligned frame of its attitude (``data.attitude``, its yaw per ``data.yaw``;
``data.dense_attitude`` for walks with a dense ground-truth orientation, e.g. simulated ones), resampled and cut into windows
(:mod:`blenav.features.inertial`; :func:`blenav.filters.inertial_odometry.session_frame_imu`).

Segments (no invented positions). A segment is a stretch [a, b] of a walk whose displacement is known: between two
consecutive surveyed waypoints (``groundtruth_kind: waypoints``, the ILC walks; gaps longer than
``waypoint_max_gap_s`` are left out), or ``dense_segment_s`` long on a dense ground-truth trajectory (interpolated,
no gap over 1 s inside). The network's velocities integrate over it (:func:`blenav.features.inertial.segment_weights`:
the seconds of each window's output interval inside [a, b]); the loss compares that integral with the displacement
(:mod:`blenav.learn.inertial.module`).

Validation: ``val_fraction`` of the walks, whole, seeded. Augmentation (training segments only, one draw per segment
for all its windows): a uniform yaw turning inputs and target together, gyro / accelerometer biases and scales; and
dropped samples, drawn per window, each replaced by the sample before it (``data.augment``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset as TorchDataset

from blenav.errors import MissingStream
from blenav.features.inertial import (CHANNELS, FRAMES, InertialGrid, cut, heading_frame, n_windows, padded,
                                      segment_weights, turn_pairs)
from blenav.filters.inertial_odometry import session_frame_imu
from blenav.filters.yaw_hold import check_yaw

from ..common.sessions import labelled_sessions
from .data_config import InertialDataConfig

log = logging.getLogger("blenav.learn")

DENSE_MAX_GAP_S = 1.0


@dataclass
class Walk:
    """One walk's resampled IMU, padded for cutting its K windows (:func:`blenav.features.inertial.padded`; windows are
    cut per item, n_window / n_stride times less memory than keeping them), the grid's first time ``t0`` s, and
    whether its ground truth is waypoints."""

    session: str
    Xp: np.ndarray
    K: int
    t0: float
    sparse: bool


@dataclass
class Segments:
    """Segments of the walks: walk index (S,), target displacement (S, 2) m, [a, b] (S, 2) s, and per segment its
    windows (indices into the walk's windows) with their weights (s)."""

    walk: np.ndarray
    target: np.ndarray
    span: np.ndarray
    win: list[np.ndarray]
    weight: list[np.ndarray]

    def __len__(self) -> int:
        return len(self.walk)


def walk_segments(session, grid: InertialGrid, t0: float, K: int, cfg: InertialDataConfig):
    """(a (S,), b (S,), target (S, 2)) of one session (module doc), inside the windows' span [t0, t0 + K stride]."""
    gt = session.groundtruth
    t = gt["t"].to_numpy(float)
    xy = gt[["x", "y"]].to_numpy(float)
    t_end = t0 + K * grid.stride_s
    if session.groundtruth_sparse:
        a, b = t[:-1], t[1:]
        ok = (b - a > 0) & (b - a <= cfg.waypoint_max_gap_s) & (a >= t0) & (b <= t_end + 1e-9)
        return a[ok], b[ok], (xy[1:] - xy[:-1])[ok]
    L_s = float(cfg.dense_segment_s)
    lo, hi = max(t[0], t0), min(t[-1], t_end)
    if hi - lo < L_s:
        return np.zeros(0), np.zeros(0), np.zeros((0, 2))
    a = lo + L_s * np.arange(int(np.floor((hi - lo) / L_s + 1e-9)))
    b = a + L_s
    # no ground-truth gap over DENSE_MAX_GAP_S inside a segment
    gaps = np.flatnonzero(np.diff(t) > DENSE_MAX_GAP_S)
    ok = np.ones(len(a), bool)
    for g in gaps:
        ok &= ~((a < t[g + 1]) & (b > t[g]))
    a, b = a[ok], b[ok]
    pa = np.stack([np.interp(a, t, xy[:, j]) for j in (0, 1)], axis=1)
    pb = np.stack([np.interp(b, t, xy[:, j]) for j in (0, 1)], axis=1)
    return a, b, pb - pa


def make_segments(walks: list[Walk], per_walk: list[tuple], grid: InertialGrid) -> Segments:
    """:class:`Segments` of ``walks`` from each walk's (a, b, target)."""
    walk, target, span, win, weight = [], [], [], [], []
    for i, (w, (a, b, d)) in enumerate(zip(walks, per_walk)):
        seg, k, wt = segment_weights(w.t0, grid, w.K, a, b)  # sorted by segment
        cuts = np.flatnonzero(np.diff(seg)) + 1
        for j, kj, wj in zip(seg[np.r_[0, cuts]] if len(seg) else [], np.split(k, cuts), np.split(wt, cuts)):
            walk.append(i)
            target.append(d[j])
            span.append((a[j], b[j]))
            win.append(kj)
            weight.append(wj)
    return Segments(np.asarray(walk, np.int64), np.asarray(target, float).reshape(-1, 2),
                    np.asarray(span, float).reshape(-1, 2), win, weight)


def window_batch(walk: Walk, grid: InertialGrid, frame: str, index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(windows ``index`` of ``walk`` (n, n_window, 15) float32 as the network sees them, their headings psi (n,)):
    turned into their heading frames for ``frame: heading``, psi 0 for ``world``."""
    W = cut(walk.Xp, grid, index)
    return heading_frame(W) if frame == "heading" else (W, np.zeros(len(W)))


class SegmentSet(TorchDataset):
    """Items: one segment's windows (n, n_window, 15), their headings psi (n,), weights (n,), target (2,); augmented when
    ``augment``."""

    def __init__(self, walks: list[Walk], segs: Segments, cfg: InertialDataConfig, grid: InertialGrid, augment: bool,
                 seed: int):
        self.walks, self.segs, self.cfg, self.grid, self.augment = walks, segs, cfg, grid, augment
        self.seed, self.epoch = int(seed), 0

    def __len__(self) -> int:
        return len(self.segs)

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __getitem__(self, i: int) -> dict:
        s = self.segs
        W = window_batch(self.walks[s.walk[i]], self.grid, self.cfg.frame, s.win[i])
        psi, W = W[1].astype(np.float32), W[0]
        d = s.target[i].copy()
        if self.augment:
            W, d = self._augment(W, d, np.random.default_rng([self.seed, self.epoch, int(i)]))
        return {"windows": torch.from_numpy(W), "psi": torch.from_numpy(psi),
                "weight": torch.from_numpy(s.weight[i].astype(np.float32)), "target": torch.from_numpy(d.astype(np.float32))}

    def _augment(self, W: np.ndarray, d: np.ndarray, rng: np.random.Generator):
        a = self.cfg.augment
        if a.yaw and self.cfg.frame == "world":  # in the heading frame a yaw changes nothing (exactly equivariant)
            th = rng.uniform(-np.pi, np.pi)
            c, s = np.cos(th), np.sin(th)
            W = turn_pairs(W, np.full(len(W), c), np.full(len(W), s))
            d = np.array([c * d[0] - s * d[1], s * d[0] + c * d[1]])
        W[..., 0:3] = W[..., 0:3] * (1.0 + a.scale_std * rng.standard_normal()) + a.acc_bias_std * rng.standard_normal(3)
        W[..., 3:6] = W[..., 3:6] * (1.0 + a.scale_std * rng.standard_normal()) + a.gyro_bias_std * rng.standard_normal(3)
        if a.drop_prob > 0:
            drop = rng.random(W.shape[:2]) < a.drop_prob
            drop[:, 0] = False
            n, t = np.nonzero(drop)
            W[n, t] = W[n, t - 1]  # the dropped sample holds the previous one
        return W.astype(np.float32), d


def collate(rows: list[dict]) -> dict[str, torch.Tensor]:
    """Concatenated windows (N, n_window, 15), their headings (N,), segment index (N,) and weights (N,), targets (B, 2)."""
    return {"windows": torch.cat([r["windows"] for r in rows]), "psi": torch.cat([r["psi"] for r in rows]),
            "segment": torch.cat([torch.full((len(r["weight"]),), i, dtype=torch.long) for i, r in enumerate(rows)]),
            "weight": torch.cat([r["weight"] for r in rows]),
            "target": torch.stack([r["target"] for r in rows])}


class InertialDataModule(L.LightningDataModule):
    """Walks and segments of the datasets: loaders ``train`` and ``val`` (module doc)."""

    def __init__(self, cfg: InertialDataConfig):
        super().__init__()
        self.cfg = cfg
        self.grid = InertialGrid(cfg.rate_hz, cfg.window_s, cfg.stride_s)
        if cfg.frame not in FRAMES:
            raise ValueError(f"data.frame must be one of {FRAMES}, got {cfg.frame!r}")
        check_yaw(cfg.yaw, "data.yaw")
        self.walks: dict[str, list[Walk]] = {}
        self.segments: dict[str, Segments] = {}
        self.sets: dict[str, SegmentSet] = {}
        self.sessions: dict[str, list] = {}
        self.skipped: dict[str, str] = {}

    def _walk(self, s) -> tuple[Walk, tuple] | None:
        c = self.cfg
        dense = not s.groundtruth_sparse
        source = c.dense_attitude if (dense and c.dense_attitude) else c.attitude
        try:  # a ground-truth orientation is exact: its yaw is kept
            t, X, used = session_frame_imu(s, self.grid, source, yaw=c.yaw if source == c.attitude else "attitude")
        except MissingStream as exc:
            if source == c.attitude:
                raise
            log.info("session %s: %s; its frame from data.attitude=%s", s.id, exc, c.attitude)
            t, X, used = session_frame_imu(s, self.grid, c.attitude, yaw=c.yaw)
        K = n_windows(len(X), self.grid)
        seg = walk_segments(s, self.grid, float(t[0]), K, c)
        if not K or not len(seg[0]):
            return None
        return Walk(s.id, padded(X, self.grid), K, float(t[0]), bool(s.groundtruth_sparse)), seg

    def setup(self, stage: str | None = None) -> None:
        if self.sets:
            return
        c = self.cfg
        where = ", ".join(c.paths)
        sessions = [s for s in labelled_sessions(c.paths, c.sessions) if (s.root / "imu.csv").is_file()]
        if not sessions:
            raise ValueError(f"{where} has no labelled session with an IMU and ground truth"
                             f"{' among data.sessions' if c.sessions is not None else ''}: the inertial odometry "
                             "trains on imu.csv with groundtruth.csv (a trajectory or surveyed waypoints)")
        rng = np.random.default_rng([int(c.seed), 31])
        order = rng.permutation(len(sessions))
        n_val = int(round(c.val_fraction * len(sessions))) if len(sessions) > 1 else 0
        val = {sessions[i].id for i in order[:n_val]}
        built: dict[str, list] = {"train": [], "val": []}
        for s in sessions:
            try:
                got = self._walk(s)
            except MissingStream as exc:
                self.skipped[s.id] = str(exc)
                continue
            if got is None:
                self.skipped[s.id] = "no supervised segment (ground truth outside the IMU's span, or gaps)"
                continue
            built["val" if s.id in val else "train"].append((s, *got))
        if not built["train"]:
            raise ValueError(f"no training segment in {where} ({len(sessions)} labelled walks with an IMU; skipped: "
                             f"{dict(list(self.skipped.items())[:3])}); record walks with ground truth inside the IMU's "
                             "span, or allow longer waypoint gaps (data.waypoint_max_gap_s)")
        for split, rows in built.items():
            if not rows:
                continue
            self.sessions[split] = [r[0] for r in rows]
            self.walks[split] = [r[1] for r in rows]
            self.segments[split] = make_segments(self.walks[split], [r[2] for r in rows], self.grid)
            self.sets[split] = SegmentSet(self.walks[split], self.segments[split], c, self.grid,
                                          augment=(split == "train"), seed=c.seed)

    def normalisation(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-channel mean and std (15,) of the training walks' windows' last strides (each sample once), as the network
        sees them (in their heading frames for ``frame: heading``)."""
        n_s = self.grid.n_stride
        X = np.concatenate([window_batch(w, self.grid, self.cfg.frame, np.arange(w.K))[0][:, -n_s:].reshape(-1, len(CHANNELS))
                            for w in self.walks["train"]])
        return X.mean(axis=0), X.std(axis=0)

    def counts(self) -> dict:
        """Walks, segments and windows per split, the waypoint walks among them, the skipped walks."""
        out = {}
        for split, ws in self.walks.items():
            seg = self.segments[split]
            out[split] = {"walks": len(ws), "waypoint_walks": int(sum(w.sparse for w in ws)),
                          "segments": len(seg), "windows": int(sum(w.K for w in ws)),
                          "segment_s": float((seg.span[:, 1] - seg.span[:, 0]).sum())}
        out["skipped"] = dict(self.skipped)
        return out

    def train_dataloader(self) -> DataLoader:
        g = torch.Generator().manual_seed(int(self.cfg.seed))  # the augmentation's epoch: the module sets it
        return DataLoader(self.sets["train"], batch_size=self.cfg.batch_segments, shuffle=True, generator=g,
                          collate_fn=collate, num_workers=self.cfg.num_workers)

    def val_dataloader(self):
        if "val" not in self.sets:
            return []
        return DataLoader(self.sets["val"], batch_size=self.cfg.batch_segments, shuffle=False, collate_fn=collate,
                          num_workers=self.cfg.num_workers)
