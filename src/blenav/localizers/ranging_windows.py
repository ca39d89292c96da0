"""The ranges of the distance-based baselines (:mod:`blenav.localizers.ranging`): a session's usable RTT and BLE
readings (the 004 sec. V-A rules), their offline and online calibration (004 sec. V-B, VI-C), and the median
range per anchor and window (004 sec. III).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from blenav.crf.calibration import offline_calibration
from blenav.crf.preprocess import BLE_MIN_RSSI_DBM, WIFI_MIN_RSSI_DBM, ble_keep_mask, rtt_keep_mask
from blenav.filters.measurement import AnchorTable

from .centroid import medians_by_window

__all__ = ["WindowRanges", "wifi_rssi", "rtt_readings", "ble_readings", "dist3", "rtt_offsets", "ble_levels",
           "online_corrections", "correction_at", "window_ranges", "NO_ANCHORS", "WIFI_MIN_RSSI_DBM",
           "BLE_MIN_RSSI_DBM"]

# WIFI_MIN_RSSI_DBM (-65), BLE_MIN_RSSI_DBM (-90): the rules of 004 sec. V-A, defined in blenav.crf.preprocess
NO_ANCHORS = AnchorTable.empty()  # a modality left out of offline_calibration


# ------------------------------------------------------------------------------------------ readings
def wifi_rssi(rtt: pd.DataFrame) -> np.ndarray:
    """(N,) dBm: the optional ``rssi`` column of an rtt.csv frame, NaN where empty or when the column is absent."""
    if "rssi" not in rtt.columns:
        return np.full(len(rtt), np.nan)
    return pd.to_numeric(rtt["rssi"], errors="coerce").to_numpy(float)


def rtt_readings(session, min_wifi_rssi_dbm: float | None = WIFI_MIN_RSSI_DBM):
    """The RTT readings of ``session`` usable for ranging: ``(t (N,) s, anchor row (N,), range (N,) m, anchors,
    n_weak)``; ``anchors`` the building's ``wifi_rtt`` anchors with a known position (:class:`AnchorTable`).

    Readings with a WiFi RSSI below ``min_wifi_rssi_dbm`` are dropped (004 sec. V-A; ``None``: keep all), and
    counted in ``n_weak``; readings without an RSSI (an empty cell, or no ``rssi`` column) are kept."""
    anchors = _known(AnchorTable.from_frame(session.building.anchors, "wifi_rtt"))
    r = session.rtt
    if not len(r) or not len(anchors.ids):
        return np.zeros(0), np.zeros(0, int), np.zeros(0), anchors, 0
    idx = anchors.index_of(r["anchor_id"].astype(str).to_numpy())
    rng = r["range_m"].to_numpy(float)
    usable = (idx >= 0) & rtt_keep_mask(rng, None)  # a known AP and a finite range
    keep = usable & rtt_keep_mask(rng, wifi_rssi(r), min_wifi_rssi_dbm)
    n_weak = int((usable & ~keep).sum())
    return r["t"].to_numpy(float)[keep], idx[keep], rng[keep], anchors, n_weak


def ble_readings(session, min_ble_rssi_dbm: float | None = BLE_MIN_RSSI_DBM):
    """BLE readings of ``session``: ``(t (N,) s, anchor row (N,), rssi (N,) dBm, anchors)``, readings below
    ``min_ble_rssi_dbm`` dropped (004 sec. V-A), beacons without a known position left out."""
    anchors = _known(AnchorTable.from_frame(session.building.anchors, "ble"))
    r = session.rssi
    if not len(r) or not len(anchors.ids):
        return np.zeros(0), np.zeros(0, int), np.zeros(0), anchors
    idx = anchors.index_of(r["anchor_id"].astype(str).to_numpy())
    rssi = r["rssi"].to_numpy(float)
    keep = (idx >= 0) & ble_keep_mask(rssi, min_ble_rssi_dbm)
    return r["t"].to_numpy(float)[keep], idx[keep], rssi[keep], anchors


def _known(a: AnchorTable) -> AnchorTable:
    ok = np.isfinite(a.xyz).all(axis=1)
    return AnchorTable(a.ids[ok], a.xyz[ok], a.tx_power_dbm[ok])


def dist3(xy: np.ndarray, z: float | np.ndarray, anchor_xyz: np.ndarray) -> np.ndarray:
    """3-D distances (N,) m from points xy (N, 2) at height z to anchors anchor_xyz (N, 3)."""
    return np.sqrt(((anchor_xyz[:, :2] - xy) ** 2).sum(axis=1) + (anchor_xyz[:, 2] - z) ** 2)


# ------------------------------------------------------------------------------------------ calibration
def rtt_offsets(sessions, anchors: AnchorTable, device_z: float = 1.2,
                min_wifi_rssi_dbm: float | None = WIFI_MIN_RSSI_DBM) -> np.ndarray:
    """Offline RTT calibration (004 sec. VI-C: "measurements at 5 static positions"): the range offset (A,) m
    of each AP of ``anchors``, the median over every reading of labelled ``sessions`` of ``range_m`` minus the
    3-D distance from the ground-truth position (at the reading's time, height ``device_z``) to the AP's
    stated position. NaN for an AP without a reading. The -65 dBm rule applies as in localization.
    (:func:`blenav.crf.calibration.offline_calibration` at the fixed height ``device_z``.)"""
    cal = offline_calibration(sessions, anchors, NO_ANCHORS, 0.0, None, min_wifi_rssi_dbm, device_z=device_z)
    return cal.rtt_offset


def ble_levels(sessions, anchors: AnchorTable, gamma: float, d0: float = 1.0, device_z: float = 1.2,
               min_ble_rssi_dbm: float | None = BLE_MIN_RSSI_DBM) -> np.ndarray:
    """Offline BLE calibration: the 1 m level a_X (A,) dBm of each beacon (004 sec. V-B: "transmit powers for
    each Bluetooth beacon"), the median over labelled ``sessions`` of ``rssi + 10 gamma log10(d / d0)`` with d the
    true 3-D distance (at least 0.1 m). NaN for a beacon without a reading.
    (:func:`blenav.crf.calibration.offline_calibration` at the fixed height ``device_z``.)"""
    return offline_calibration(sessions, NO_ANCHORS, anchors, gamma, min_ble_rssi_dbm, None, device_z=device_z,
                               d0=d0).ble_tx


def online_corrections(fix_t: np.ndarray, fix_xy: np.ndarray, t: np.ndarray, idx: np.ndarray, vals: np.ndarray,
                       true_value, n_anchors: int, calib_window_s: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Online calibration at visual fixes (004 sec. V-B): for each fix at ``fix_t`` (F,) s, position
    ``fix_xy`` (F, 2) m, the median of ``true_value(vals, rows, fix_xy_of_reading)`` over the readings
    ``t, idx, vals`` in ``[fix_t, fix_t + calib_window_s]`` per anchor ("we record measurements for the following
    second, assuming the user is standing still").

    Returns ``(t_avail (F,) s, corr (F, A))``: the correction available from ``fix_t + calib_window_s`` on, per
    anchor, forward-filled over the fixes (an anchor not heard after a fix keeps its previous value; NaN before
    its first). ``true_value(vals (N,), rows (N,), xy (N, 2)) -> (N,)`` maps readings to the corrected quantity
    (e.g. range minus true distance)."""
    F = len(fix_t)
    corr = np.full((F, n_anchors), np.nan)
    if F == 0 or not len(t):
        return np.asarray(fix_t, float) + calib_window_s, corr
    order = np.argsort(fix_t, kind="stable")
    fix_t, fix_xy = np.asarray(fix_t, float)[order], np.asarray(fix_xy, float)[order]
    # every reading in a fix's window (a reading may fall in two overlapping windows): pairs (fix, reading)
    lo = np.searchsorted(t, fix_t, "left")
    hi = np.searchsorted(t, fix_t + calib_window_s, "right")
    n = hi - lo
    fi = np.repeat(np.arange(F), n)
    ri = np.repeat(lo - np.r_[0, np.cumsum(n)[:-1]], n) + np.arange(n.sum())
    if len(ri):
        v = true_value(vals[ri], idx[ri], fix_xy[fi])
        corr = medians_by_window(fi.astype(np.int64), idx[ri], v, F, n_anchors)
    corr = _ffill_rows(corr)
    return fix_t + calib_window_s, corr


def _ffill_rows(a: np.ndarray) -> np.ndarray:
    """Forward-fill NaN along axis 0 per column (a NaN keeps the last finite value above it)."""
    if a.shape[0] == 0:
        return a
    ok = np.isfinite(a)
    last = np.maximum.accumulate(np.where(ok, np.arange(a.shape[0])[:, None], -1), axis=0)
    out = np.take_along_axis(a, np.maximum(last, 0), axis=0)
    return np.where(last >= 0, out, np.nan)


def correction_at(t_query: np.ndarray, base: np.ndarray, t_avail: np.ndarray, corr: np.ndarray) -> np.ndarray:
    """(W, A) correction in force at each ``t_query`` (W,): the latest online one available (``t_avail`` <= t),
    else ``base`` (A,); NaN entries fall back to ``base``, a NaN base to 0."""
    base = np.where(np.isfinite(base), base, 0.0)
    out = np.broadcast_to(base, (len(t_query), len(base))).copy()
    if len(t_avail):
        k = np.searchsorted(t_avail, t_query, "right") - 1
        have = k >= 0
        c = corr[np.maximum(k, 0)]
        use = have[:, None] & np.isfinite(c)
        out[use] = c[use]
    return out


# ------------------------------------------------------------------------------------------ windows
@dataclass
class WindowRanges:
    """Median ranges per window: ``t_stamp`` (W,) s (the window's last reading, or its end when it has none),
    ``d`` (W, A) m (NaN where the anchor gave no range), ``anchors`` (A, 3) m (RTT APs first, then beacons),
    ``kind`` (A,) 'rtt' | 'ble', ``window`` (W,) window index (window w covers [t0 + w window_s, t0 + (w+1) window_s)),
    ``t0`` s, ``visual`` (W, 2) m the window's last visual fix (NaN where none)."""

    t_stamp: np.ndarray
    d: np.ndarray
    anchors: np.ndarray
    kind: np.ndarray
    window: np.ndarray
    t0: float
    visual: np.ndarray
    notes: list = field(default_factory=list)


def window_ranges(t_lists, idx_lists, d_lists, anchor_xyz, kinds, vis_t, vis_xy, window_s: float,
                  t0: float | None = None) -> WindowRanges:
    """Median ranges per ``window_s`` window over the given per-modality readings (already in metres)."""
    offs = np.cumsum([0] + [len(a) for a in anchor_xyz])
    A = int(offs[-1])
    t = np.concatenate([np.asarray(x, float) for x in t_lists] + [np.zeros(0)])
    idx = np.concatenate([np.asarray(i, np.int64) + o for i, o in zip(idx_lists, offs[:-1])] + [np.zeros(0, np.int64)])
    d = np.concatenate([np.asarray(x, float) for x in d_lists] + [np.zeros(0)])
    vis_t = np.asarray(vis_t, float)
    all_t = np.concatenate([t, vis_t])
    if t0 is None:
        t0 = float(all_t.min())
    # 1e-9: a reading exactly on a boundary (8.2 s with windows from 0.2 s) is in the window it starts, not the
    # one before by a rounding error
    win = np.floor((t - t0) / window_s + 1e-9).astype(np.int64)
    vwin = np.floor((vis_t - t0) / window_s + 1e-9).astype(np.int64)
    w_lo = int(min(win.min(initial=np.iinfo(np.int64).max), vwin.min(initial=np.iinfo(np.int64).max)))
    w_hi = int(max(win.max(initial=-1), vwin.max(initial=-1)))
    W = w_hi - w_lo + 1
    med = medians_by_window(win - w_lo, idx, d, W, A) if len(t) else np.full((W, A), np.nan)
    stamp = t0 + (np.arange(W) + w_lo + 1) * window_s
    last = np.full(W, -np.inf)
    np.maximum.at(last, win - w_lo, t)
    np.maximum.at(last, vwin - w_lo, vis_t)
    stamp = np.where(np.isfinite(last), last, stamp)
    visual = np.full((W, 2), np.nan)
    if len(vis_t):  # the last fix of each window (fixes are sorted by time)
        visual[vwin - w_lo] = np.asarray(vis_xy, float)
    return WindowRanges(stamp, med, np.concatenate(anchor_xyz, axis=0) if A else np.zeros((0, 3)),
                        np.concatenate([np.full(len(a), k) for a, k in zip(anchor_xyz, kinds)] + [np.zeros(0, str)]),
                        np.arange(W) + w_lo, t0, visual)
