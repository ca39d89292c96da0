"""Pre-processing of the radio streams for the CRF (Duembgen et al., 004, sec. V-A).

"Each measurement is given by the median over a one-second time window" (004 sec. III); BLE readings below
-90 dBm and WiFi RTT ranges whose access point was received below -65 dBm are rejected (004 sec. V-A,
Fig. 5: below these levels the ranging error grows).

Windows: ``K`` consecutive windows of ``window_s`` seconds from ``t_start``; window ``k`` holds the
readings with ``t_start + k window_s <= t < t_start + (k + 1) window_s`` and its estimate is reported at
the window's end ``t_start + (k + 1) window_s`` (s, session clock). Readings before ``t_start`` or after the
last window are left out.

The WiFi RSSI rule needs the optional ``rssi`` column of ``rtt.csv`` (dBm of the access point's frames, as
Android's ``RangingResult.getRssi``); without the column (or where a row's cell is empty) the rule cannot
be applied and the range is kept -- :attr:`RadioWindows.notes` says so.

Everything here is numpy + pandas (no torch, no hydra); the functions on arrays are what other
range-based localizers (grid-L2, grid-L1, SRLS) reuse.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from blenav.filters.measurement import AnchorTable

__all__ = ["window_medians", "keyed_medians", "window_count", "rtt_keep_mask", "ble_keep_mask", "RadioWindows",
           "preprocess", "anchor_tables", "session_span", "anchor_rows", "WIFI_MIN_RSSI_DBM", "BLE_MIN_RSSI_DBM"]

#: 004 sec. V-A (Fig. 5): WiFi RTT ranges whose access point is received below this are dropped (dBm); the one
#: definition the CRF, its offline calibration and the range baselines (blenav.localizers.ranging) use
WIFI_MIN_RSSI_DBM = -65.0
#: 004 sec. V-A: BLE readings below this are dropped (dBm)
BLE_MIN_RSSI_DBM = -90.0


def window_count(t_start: float, t_end: float, window_s: float) -> int:
    """Number of windows of ``window_s`` s from ``t_start`` that cover ``t_end`` (>= 1)."""
    return max(1, int(np.floor((t_end - t_start) / window_s + 1e-9)) + 1)


def window_medians(t: np.ndarray, idx: np.ndarray, values: np.ndarray, n_anchors: int, t_start: float,
                   n_windows: int, window_s: float = 1.0) -> np.ndarray:
    """(K, A) median of ``values`` per (window, anchor), NaN where an anchor has no reading in a window.

    t (M,) s, idx (M,) anchor rows in [0, A) (negative rows are ignored), values (M,). The median of an
    even count is the mean of the two middle values. Vectorised: one lexsort, no loop."""
    t = np.asarray(t, float)
    idx = np.asarray(idx, np.int64)
    values = np.asarray(values, float)
    win = np.floor((t - t_start) / window_s).astype(np.int64)
    ok = (idx >= 0) & (idx < n_anchors) & (win >= 0) & (win < n_windows) & np.isfinite(values)
    return keyed_medians(win[ok] * n_anchors + idx[ok], values[ok], n_windows * n_anchors).reshape(n_windows, n_anchors)


def keyed_medians(key: np.ndarray, values: np.ndarray, size: int) -> np.ndarray:
    """(size,) median of ``values`` (M,) per integer ``key`` (M,) in [0, size), NaN for keys without a value.
    The median of an even count is the mean of the two middle values. One lexsort, no loop."""
    out = np.full(size, np.nan)
    order = np.lexsort((values, key))
    key, v = key[order], values[order]
    if len(key) == 0:
        return out
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    counts = np.diff(np.r_[starts, len(key)])
    lo = starts + (counts - 1) // 2
    hi = starts + counts // 2
    out[key[starts]] = 0.5 * (v[lo] + v[hi])
    return out


def rtt_keep_mask(range_m: np.ndarray, wifi_rssi: np.ndarray | None,
                  min_wifi_rssi_dbm: float | None = WIFI_MIN_RSSI_DBM) -> np.ndarray:
    """(M,) bool: RTT rows kept by 004 sec. V-A: finite range and, where the AP's RSSI is known (finite),
    RSSI >= ``min_wifi_rssi_dbm`` (None: no RSSI rule). ``wifi_rssi`` None: the column is absent."""
    keep = np.isfinite(np.asarray(range_m, float))
    if wifi_rssi is not None and min_wifi_rssi_dbm is not None:
        r = np.asarray(wifi_rssi, float)
        keep &= ~(np.isfinite(r) & (r < min_wifi_rssi_dbm))
    return keep


def ble_keep_mask(rssi: np.ndarray, min_rssi_dbm: float | None = BLE_MIN_RSSI_DBM) -> np.ndarray:
    """(M,) bool: BLE rows kept by 004 sec. V-A: finite and >= ``min_rssi_dbm`` (None: all finite)."""
    r = np.asarray(rssi, float)
    keep = np.isfinite(r)
    if min_rssi_dbm is not None:
        keep &= r >= min_rssi_dbm
    return keep


def anchor_tables(building, floor=None) -> tuple[AnchorTable, AnchorTable]:
    """(WiFi RTT anchors, BLE anchors) of ``building`` with a known position (x, y, z finite; z NaN -> dropped)."""
    frame = building.anchors
    if floor is not None and "floor" in frame.columns and len(frame):
        on = frame["floor"].astype(str) == str(floor)
        frame = frame[on | frame["floor"].isna()]
    out = []
    for kind in ("wifi_rtt", "ble"):
        a = AnchorTable.from_frame(frame, kind) if len(frame) else AnchorTable(np.zeros(0, str), np.zeros((0, 3)),
                                                                             np.zeros(0))
        known = np.isfinite(a.xyz).all(axis=1)
        out.append(AnchorTable(a.ids[known], a.xyz[known], a.tx_power_dbm[known]))
    return out[0], out[1]


def anchor_rows(ids, anchors: AnchorTable) -> np.ndarray:
    """(M,) row of each anchor id in ``anchors`` (-1 when unknown); a hash lookup (``AnchorTable.index_of``
    sorts strings: seconds for the hundreds of thousands of BLE packets of an hour)."""
    import pandas as pd

    if not len(anchors.ids):
        return np.full(len(ids), -1, np.int64)
    return pd.Index(anchors.ids.astype(str)).get_indexer(pd.Series(ids).astype(str)).astype(np.int64)


def session_span(session, streams=("imu", "rssi", "rtt", "visual")) -> tuple[float, float]:
    """(first, last) time stamp (s) over the session's present, non-empty ``streams``."""
    lo, hi = [], []
    for name in streams:
        if (session.root / f"{name}.csv").is_file():
            df = session.stream(name)
            if len(df):
                lo.append(float(df["t"].iloc[0]))
                hi.append(float(df["t"].iloc[-1]))
    if not lo:
        raise ValueError(f"session {session.id} has none of the streams {', '.join(streams)}")
    return min(lo), max(hi)


@dataclass
class RadioWindows:
    """The radio streams of one session as 1 s medians (004 sec. V-A).

    t (K,) s: window ends; rtt (K, Aw) m median range per WiFi AP (NaN: none kept); rtt_std (K, Aw) m median
    reported std (NaN: none); ble (K, Ab) dBm median RSSI per beacon (NaN: none kept); wifi, ble_anchors: the
    anchor tables the columns refer to; dropped: rows rejected per rule; notes: remarks for the report;
    rtt_raw, ble_raw: the readings that passed the rules, (t (M,) s, anchor row (M,), range m | RSSI dBm (M,))."""

    t: np.ndarray
    t_start: float
    window_s: float
    rtt: np.ndarray
    rtt_std: np.ndarray
    ble: np.ndarray
    wifi: AnchorTable
    ble_anchors: AnchorTable
    dropped: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    rtt_raw: tuple = (np.zeros(0), np.zeros(0, np.int64), np.zeros(0))
    ble_raw: tuple = (np.zeros(0), np.zeros(0, np.int64), np.zeros(0))


def preprocess(session, t_start: float | None = None, n_windows: int | None = None, window_s: float = 1.0,
               min_ble_rssi_dbm: float | None = BLE_MIN_RSSI_DBM, min_wifi_rssi_dbm: float | None = WIFI_MIN_RSSI_DBM,
               wifi: AnchorTable | None = None, ble_anchors: AnchorTable | None = None) -> RadioWindows:
    """1 s medians of ``session``'s rtt.csv and rssi.csv after the rejection rules of 004 sec. V-A.

    ``t_start`` / ``n_windows`` default to the session's span (:func:`session_span`); ``wifi`` /
    ``ble_anchors`` to the building's anchors with known positions. Absent streams give all-NaN columns."""
    if wifi is None or ble_anchors is None:
        w, b = anchor_tables(session.building, session.meta.get("floor"))
        wifi = w if wifi is None else wifi
        ble_anchors = b if ble_anchors is None else ble_anchors
    if t_start is None or n_windows is None:
        lo, hi = session_span(session)
        t_start = lo if t_start is None else t_start
        n_windows = window_count(t_start, hi, window_s) if n_windows is None else n_windows
    K, Aw, Ab = int(n_windows), len(wifi.ids), len(ble_anchors.ids)
    dropped, notes = {}, []
    rtt_raw = ble_raw = (np.zeros(0), np.zeros(0, np.int64), np.zeros(0))
    rtt = np.full((K, Aw), np.nan)
    rtt_std = np.full((K, Aw), np.nan)
    if Aw and (session.root / "rtt.csv").is_file() and len(session.rtt):
        df = session.rtt
        idx = anchor_rows(df["anchor_id"], wifi)
        rng = df["range_m"].to_numpy(float)
        wr = df["rssi"].to_numpy(float) if "rssi" in df.columns else None
        if wr is None and min_wifi_rssi_dbm is not None:
            notes.append("rtt.csv has no rssi column: the -65 dBm rule of 004 sec. V-A was not applied")
        keep = rtt_keep_mask(rng, wr, min_wifi_rssi_dbm) & (idx >= 0)
        n_weak = int((~rtt_keep_mask(rng, wr, min_wifi_rssi_dbm) & np.isfinite(rng)).sum())
        if n_weak:
            dropped["rtt_weak_wifi_rssi"] = n_weak
        t = df["t"].to_numpy(float)[keep]
        rtt_raw = (t, idx[keep], rng[keep])
        rtt = window_medians(t, idx[keep], rng[keep], Aw, t_start, K, window_s)
        std = df["range_std_m"].to_numpy(float)[keep] if "range_std_m" in df.columns else np.full(keep.sum(), np.nan)
        rtt_std = window_medians(t, idx[keep], std, Aw, t_start, K, window_s)
    ble = np.full((K, Ab), np.nan)
    if Ab and (session.root / "rssi.csv").is_file() and len(session.rssi):
        df = session.rssi
        idx = anchor_rows(df["anchor_id"], ble_anchors)
        r = df["rssi"].to_numpy(float)
        keep = ble_keep_mask(r, min_ble_rssi_dbm) & (idx >= 0)
        n_weak = int((~ble_keep_mask(r, min_ble_rssi_dbm) & np.isfinite(r)).sum())
        if n_weak:
            dropped["ble_below_min_rssi"] = n_weak
        ble_raw = (df["t"].to_numpy(float)[keep], idx[keep], r[keep])
        ble = window_medians(*ble_raw, Ab, t_start, K, window_s)
    t_end = t_start + (np.arange(K) + 1) * window_s
    return RadioWindows(t_end, float(t_start), float(window_s), rtt, rtt_std, ble, wifi, ble_anchors, dropped, notes,
                        rtt_raw, ble_raw)
