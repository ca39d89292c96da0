"""Calibration of the CRF's radio and heading parameters (Duembgen et al., 004, sec. V-B and VI-C).

Three schemes, selected per method (``none`` / ``offline`` / ``online``):

* ``none``: RTT ranges as reported (offset 0), each beacon's RSSI at 1 m from anchors.csv
  (``tx_power_dbm``) or the configured default, the AHRS heading as it is;
* ``offline``: from labelled static points recorded before the walk ("measurements at 5 static positions
  (ca. 60 seconds each)", 004 sec. VI-C): per WiFi AP the median of (range - true distance), per beacon the
  median of (RSSI + 10 n log10 true distance) (eq. 7 solved for T_m); the heading is left alone (an AHRS
  heading offset belongs to one recording, not to the infrastructure);
* ``online``: at every visual fix (x, y, z, yaw), the medians of the readings of the following
  ``window_s`` second(s) ("we record measurements for the following second, assuming the user is standing
  still during this time, and use the median", 004 sec. V-B): RTT offset per AP heard, transmit power per
  beacon heard, and the heading offset (visual yaw minus the AHRS yaw); parameters of anchors not heard keep
  their previous values. They apply from the end of that window on (causal).

The result is a :class:`CalibrationTrack`: piecewise-constant parameters over time. Ranges are corrected as
range - offset, the BLE distance uses T_m (eq. 8), headings are corrected as AHRS yaw + offset (rad).

Pure numpy; the array functions (:func:`rtt_offsets`, :func:`ble_tx_powers`, :func:`offline_calibration`)
are what other range-based localizers reuse: the offline calibration of the range baselines
(:func:`blenav.localizers.ranging_windows.rtt_offsets` / ``ble_levels``) is :func:`offline_calibration` at a
fixed device height.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np

from blenav.filters.measurement import AnchorTable

from .features import wrap_angle
from .preprocess import BLE_MIN_RSSI_DBM, WIFI_MIN_RSSI_DBM, ble_keep_mask, keyed_medians, rtt_keep_mask

__all__ = ["Calibration", "CalibrationTrack", "rtt_offsets", "ble_tx_powers", "heading_offset",
           "offline_calibration", "online_track", "static_sessions", "CALIBRATIONS"]

CALIBRATIONS = ("none", "offline", "online")


@dataclass
class Calibration:
    """One set of parameters: rtt_offset (Aw,) m (NaN: unknown, use 0), ble_tx (Ab,) dBm (NaN: unknown, use
    the prior), heading_offset rad."""

    rtt_offset: np.ndarray
    ble_tx: np.ndarray
    heading_offset: float = 0.0

    @classmethod
    def empty(cls, n_wifi: int, n_ble: int) -> "Calibration":
        return cls(np.full(n_wifi, np.nan), np.full(n_ble, np.nan), 0.0)


@dataclass
class CalibrationTrack:
    """Parameters over time: row 0 holds from the start, row c + 1 from ``t_avail[c]`` on (s).

    rtt_offset (C+1, Aw) m, ble_tx (C+1, Ab) dBm (NaN: the prior), heading_offset (C+1,) rad; every row is
    complete (NaN RTT offsets already 0, NaN powers already the prior)."""

    t_avail: np.ndarray
    rtt_offset: np.ndarray
    ble_tx: np.ndarray
    heading_offset: np.ndarray

    def rows(self, t: np.ndarray) -> np.ndarray:
        """Row index valid at each time t (...)."""
        return np.searchsorted(self.t_avail, np.asarray(t, float), side="right")

    @classmethod
    def constant(cls, cal: Calibration, ble_prior: np.ndarray) -> "CalibrationTrack":
        off = np.where(np.isfinite(cal.rtt_offset), cal.rtt_offset, 0.0)
        tx = np.where(np.isfinite(cal.ble_tx), cal.ble_tx, ble_prior)
        return cls(np.zeros(0), off[None, :], tx[None, :], np.array([float(cal.heading_offset)]))


def _medians_by_anchor(idx: np.ndarray, values: np.ndarray, n_anchors: int) -> np.ndarray:
    ok = (idx >= 0) & np.isfinite(values)
    return keyed_medians(idx[ok].astype(np.int64), values[ok], n_anchors)


def rtt_offsets(idx: np.ndarray, range_m: np.ndarray, true_dist: np.ndarray, n_anchors: int) -> np.ndarray:
    """(A,) m: per AP the median of range - true distance over its readings (NaN for APs without any).

    idx (M,) AP rows (-1: ignored), range_m (M,) m reported ranges, true_dist (M,) m 3-D distances."""
    return _medians_by_anchor(np.asarray(idx), np.asarray(range_m, float) - np.asarray(true_dist, float), n_anchors)


def ble_tx_powers(idx: np.ndarray, rssi: np.ndarray, true_dist: np.ndarray, n: float, n_anchors: int,
                  d0: float = 1.0) -> np.ndarray:
    """(A,) dBm: per beacon the median of RSSI + 10 n log10(true distance / d0) (T_m of eq. 7; the level at d0 m,
    the range baselines' a_X), NaN without readings. Distances below 0.1 m count as 0.1 m."""
    d = np.maximum(np.asarray(true_dist, float), 0.1)
    return _medians_by_anchor(np.asarray(idx), np.asarray(rssi, float) + 10.0 * n * np.log10(d / d0), n_anchors)


def heading_offset(yaw_ref: float, yaw_imu: np.ndarray) -> float:
    """Median of wrap(yaw_ref - yaw_imu) (rad), taken around their circular mean; NaN without samples."""
    d = wrap_angle(float(yaw_ref) - np.asarray(yaw_imu, float))
    if d.size == 0:
        return float("nan")
    c = float(np.angle(np.mean(np.exp(1j * d))))
    return float(wrap_angle(c + np.median(wrap_angle(d - c))))


def static_sessions(session, cache: dict | None = None) -> list:
    """Labelled static survey sessions (``carrier: static``) of ``session``'s dataset in its building, other
    than ``session`` itself: the labelled static points of offline calibration. ``cache`` (e.g. the run
    context's): the sessions of a building and floor are opened once, so their streams are read once."""
    from blenav.data import Dataset

    root = session.root.parent.parent
    if not (root / "dataset.yaml").is_file():
        return []
    b, f = session.meta.get("building"), str(session.meta.get("floor"))
    key = ("crf-static-sessions", str(root), b, f)
    cache = cache if cache is not None else {}
    if key not in cache:
        cache[key] = [s for s in Dataset.open(root).sessions(labelled=True)
                      if s.carrier == "static" and s.meta.get("building") == b and str(s.meta.get("floor")) == f]
    return [s for s in cache[key] if s.id != session.id]


def offline_calibration(sessions: list, wifi: AnchorTable, ble: AnchorTable, n: float,
                        min_ble_rssi_dbm: float | None = BLE_MIN_RSSI_DBM,
                        min_wifi_rssi_dbm: float | None = WIFI_MIN_RSSI_DBM, device_z: float | None = None,
                        d0: float = 1.0) -> Calibration:
    """Offline calibration from labelled static sessions (ground truth gives the surveyed point at each time).

    Readings pass the rules of 004 sec. V-A first. Positions are the ground truth interpolated at the reading
    times, with its z (device height; 0 when it has none), or at the fixed height ``device_z`` (m) when given; ``n`` and ``d0``: the
    path-loss exponent and reference distance of the BLE levels (:func:`ble_tx_powers`). Returns NaN for anchors
    without readings (an empty ``wifi`` / ``ble`` table: that modality is not calibrated)."""
    cal = Calibration.empty(len(wifi.ids), len(ble.ids))
    ri, rr, rd, bi, br, bd = [], [], [], [], [], []
    for s in sessions:
        if not len(s.groundtruth):
            continue
        at = partial(s.positions_at, with_z=True, device_z=device_z)
        if len(wifi.ids) and s.has("rtt"):
            df = s.rtt
            idx = wifi.index_of(df["anchor_id"].astype(str).to_numpy())
            r = df["range_m"].to_numpy(float)
            keep = rtt_keep_mask(r, df["rssi"].to_numpy(float) if "rssi" in df.columns else None, min_wifi_rssi_dbm)
            keep &= idx >= 0
            p = at(df["t"].to_numpy(float)[keep])
            ri.append(idx[keep])
            rr.append(r[keep])
            rd.append(np.linalg.norm(wifi.xyz[idx[keep]] - p, axis=1))
        if len(ble.ids) and s.has("rssi"):
            df = s.rssi
            idx = ble.index_of(df["anchor_id"].astype(str).to_numpy())
            r = df["rssi"].to_numpy(float)
            keep = ble_keep_mask(r, min_ble_rssi_dbm) & (idx >= 0)
            p = at(df["t"].to_numpy(float)[keep])
            bi.append(idx[keep])
            br.append(r[keep])
            bd.append(np.linalg.norm(ble.xyz[idx[keep]] - p, axis=1))
    if ri:
        cal.rtt_offset = rtt_offsets(np.concatenate(ri), np.concatenate(rr), np.concatenate(rd), len(wifi.ids))
    if bi:
        cal.ble_tx = ble_tx_powers(np.concatenate(bi), np.concatenate(br), np.concatenate(bd), n, len(ble.ids), d0)
    return cal


def _fix_window(readings: tuple[np.ndarray, np.ndarray, np.ndarray], anchor_xyz: np.ndarray, v: np.ndarray,
                t0: float, t1: float, pooled: list | None):
    """(anchor rows, values, true distances m) of the time-ordered ``readings`` (t, row, value) in [t0, t1)
    with the fix at ``v`` (3,) m; None when the window is empty. ``pooled`` (three lists): the window is
    appended and every window so far is returned."""
    tt, ii, rr = readings
    w = slice(*np.searchsorted(tt, [t0, t1]))  # readings are in time order
    if w.stop <= w.start:
        return None
    args = [ii[w], rr[w], np.linalg.norm(anchor_xyz[ii[w]] - v, axis=1)]
    if pooled is None:
        return args
    for lst, a in zip(pooled, args):
        lst.append(a)
    return [np.concatenate(lst) for lst in pooled]


def online_track(base: CalibrationTrack, fixes: np.ndarray, wifi: AnchorTable, ble: AnchorTable, n: float,
                 rtt: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
                 rssi: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
                 yaw: tuple[np.ndarray, np.ndarray] | None, window_s: float = 1.0, calibrate_rtt: bool = True,
                 calibrate_ble: bool = True, calibrate_heading: bool = True, pool: bool = False) -> CalibrationTrack:
    """Online calibration at visual fixes (004 sec. V-B), on top of ``base`` (a one-row track: the prior).

    fixes (F, 5): t, x, y, z, yaw of visual.csv (yaw NaN: no heading calibration at that fix);
    rtt / rssi: (t (M,), anchor row (M,), range m | RSSI dBm (M,)) readings that passed 004 sec. V-A, in time
    order, or None;
    yaw: (t (T,), AHRS yaw (T,) rad) of the device's forward axis, or None. Each fix gives a row valid from
    t + window_s, computed from the readings in [t, t + window_s). ``pool``: the RTT offsets and beacon powers
    are the medians over the readings of every calibration window so far (not only the latest; the heading
    offset is always the latest's, an AHRS heading drifts)."""
    F = len(fixes)
    off = np.repeat(base.rtt_offset[:1], F + 1, axis=0)
    tx = np.repeat(base.ble_tx[:1], F + 1, axis=0)
    hd = np.repeat(base.heading_offset[:1], F + 1)
    t_av = np.empty(F)
    acc_rtt: list = [[], [], []]  # pooled (anchor, reading, true distance) over the windows so far
    acc_ble: list = [[], [], []]
    for c in range(F):  # loop over visual fixes (a handful per session)
        t0, x, y, z, yv = fixes[c]
        v = np.array([x, y, z])
        t1 = t0 + window_s
        t_av[c] = t1
        off[c + 1], tx[c + 1], hd[c + 1] = off[c], tx[c], hd[c]
        if calibrate_rtt and rtt is not None and len(wifi.ids):
            args = _fix_window(rtt, wifi.xyz, v, t0, t1, acc_rtt if pool else None)
            if args is not None:
                new = rtt_offsets(*args, len(wifi.ids))
                off[c + 1] = np.where(np.isfinite(new), new, off[c])
        if calibrate_ble and rssi is not None and len(ble.ids):
            args = _fix_window(rssi, ble.xyz, v, t0, t1, acc_ble if pool else None)
            if args is not None:
                new = ble_tx_powers(*args, n, len(ble.ids))
                tx[c + 1] = np.where(np.isfinite(new), new, tx[c])
        if calibrate_heading and yaw is not None and np.isfinite(yv):
            tt, yy = yaw
            w = slice(*np.searchsorted(tt, [t0, t1]))
            h = heading_offset(yv, yy[w])
            if np.isfinite(h):
                hd[c + 1] = h
    return CalibrationTrack(t_av, off, tx, hd)
