"""The readings the beacon mapping (:mod:`blenav.backend.mapping`) fits: each (beacon, session) pair's RSSI at
the ground-truth positions of a labelled walk, with the walking direction (the body's shadow), and the walls on
a floor plan between a beacon and those positions (the multi-wall count).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import MappingConfig

__all__ = ["Readings", "collect_readings", "count_walls", "walls_on_cells", "WALL_CELL_M"]


@dataclass
class Readings:
    """The readings of one beacon (row j of the BLE anchors) in one session (index s): P (n, 3) m, rssi (n,) dBm,
    heading (n, 2) unit walking direction (0 when not walking)."""

    j: int
    s: int
    P: np.ndarray
    rssi: np.ndarray
    heading: np.ndarray


def collect_readings(sessions, ids: np.ndarray, cfg: MappingConfig) -> tuple[list[Readings], list[str]]:
    """(beacon, session) pairs of readings at ground-truth positions (linear interpolation; readings outside the
    ground truth's time span are left out), readings below ``min_rssi_dbm`` dropped. Returns (pairs, notes)."""
    pairs, notes = [], []
    index = {str(a): j for j, a in enumerate(ids)}
    for s, sess in enumerate(sessions):
        if not sess.labelled:
            raise ValueError(f"session {sess.id} is not labelled: mapping needs its ground-truth poses")
        gt, r = sess.groundtruth, sess.rssi
        if not len(gt) or not len(r):
            notes.append(f"session {sess.id}: no {'ground truth' if not len(gt) else 'RSSI'}; skipped")
            continue
        tg = gt["t"].to_numpy(float)
        t = r["t"].to_numpy(float)
        j = np.array([index.get(str(a), -1) for a in r["anchor_id"].astype(str)], dtype=int)
        y = r["rssi"].to_numpy(float)
        keep = (t >= tg[0]) & (t <= tg[-1]) & (j >= 0)
        floor_db = None
        if cfg.censor_margin_db is not None and keep.any():  # the receiver's own sensitivity: its weakest readings
            floor_db = float(np.percentile(y[keep], 0.5)) + cfg.censor_margin_db
        threshold = max([v for v in (cfg.min_rssi_dbm, floor_db) if v is not None], default=None)
        if threshold is not None:
            weak = keep & (y < threshold)
            if weak.any():
                notes.append(f"session {sess.id}: {np.count_nonzero(weak)} of {np.count_nonzero(keep)} readings below "
                             f"{threshold:.1f} dBm left out")
            keep &= ~weak
        t, j, y = t[keep], j[keep], y[keep]
        P = sess.positions_at(t, with_z=True, device_z=cfg.device_z)
        hd = _walking_direction(tg, gt["x"].to_numpy(float), gt["y"].to_numpy(float), t)
        order = np.argsort(j, kind="stable")
        j, P, y, hd = j[order], P[order], y[order], hd[order]
        for jj, lo, hi in _runs(j):
            pairs.append(Readings(int(jj), s, P[lo:hi], y[lo:hi], hd[lo:hi]))
    return pairs, notes


def count_walls(floor, src_xy: np.ndarray, targets: np.ndarray, cap: int | None = None) -> np.ndarray:
    """(n,) number of free -> occupied transitions on the floor plan along the segments ``src_xy`` (2,) ->
    ``targets`` (n, 2) (world m), sampled every half pixel (the multi-wall count of Motley-Keenan / COST 231);
    capped at ``cap``."""
    from blenav.data import OCCUPIED

    targets = np.asarray(targets, float)
    out = np.zeros(len(targets))
    if not len(targets):
        return out
    occ = floor.occupancy == OCCUPIED
    step = 0.5 * floor.resolution
    d = np.linalg.norm(targets - src_xy, axis=1)
    s = np.arange(0.0, float(d.max()) + step, step)
    for lo in range(0, len(targets), 2048):  # chunks bound the (n, K) samples to a few MB
        tg, dd = targets[lo:lo + 2048], d[lo:lo + 2048]
        u = (tg - src_xy) / np.maximum(dd, 1e-9)[:, None]
        pts = src_xy + u[:, None, :] * s[None, :, None]  # (m, K, 2)
        row, col = floor.world_to_pixel(pts)
        inside = (row >= 0) & (row < occ.shape[0]) & (col >= 0) & (col < occ.shape[1])
        hit = np.zeros(row.shape, bool)
        hit[inside] = occ[row[inside], col[inside]]
        hit &= s[None, :] <= dd[:, None]
        out[lo:lo + 2048] = np.count_nonzero(hit[:, 1:] & ~hit[:, :-1], axis=1) + hit[:, 0]
    return np.minimum(out, cap) if cap is not None else out


WALL_CELL_M = 0.25  # m: readings' positions snapped to this grid for the wall count (one ray per cell)


def walls_on_cells(floor, src_xy: np.ndarray, P: np.ndarray, cap: int | None) -> np.ndarray:
    """:func:`count_walls` from ``src_xy`` to positions P (n, 2), one ray per ``WALL_CELL_M`` cell they fall in
    (a receiver reports ~20 readings per second from nearly one place: 30x fewer rays on a walk)."""
    cells = np.round(P / WALL_CELL_M).astype(np.int64)
    uniq, inv = np.unique(cells, axis=0, return_inverse=True)
    return count_walls(floor, src_xy, uniq * WALL_CELL_M, cap)[inv.ravel()]


def _walking_direction(tg: np.ndarray, x: np.ndarray, y: np.ndarray, t: np.ndarray, span_s: float = 1.0,
                       min_speed: float = 0.3) -> np.ndarray:
    """(n, 2) unit direction of travel at times t from the ground truth (central differences over ``span_s``);
    zero where slower than ``min_speed`` m/s (standing: the body's facing is unknown)."""
    lo, hi = np.clip(t - span_s / 2, tg[0], tg[-1]), np.clip(t + span_s / 2, tg[0], tg[-1])
    dx, dy = np.interp(hi, tg, x) - np.interp(lo, tg, x), np.interp(hi, tg, y) - np.interp(lo, tg, y)
    dist = np.hypot(dx, dy)
    moving = dist > min_speed * np.maximum(hi - lo, 1e-9)
    out = np.zeros((len(t), 2))
    out[moving] = np.column_stack([dx, dy])[moving] / dist[moving, None]
    return out


def _runs(sorted_ids: np.ndarray):
    """(value, start, stop) of each run of equal values in a sorted array."""
    if not len(sorted_ids):
        return
    cut = np.flatnonzero(np.diff(sorted_ids)) + 1
    starts = np.r_[0, cut]
    stops = np.r_[cut, len(sorted_ids)]
    for a, b in zip(starts, stops):
        yield sorted_ids[a], a, b
