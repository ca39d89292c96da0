"""Distance-based baselines of Duembgen et al. (004, sec. VI-E): range least squares by grid search
(grid-L2), its absolute-residual variant (grid-L1), and squared-range least squares (SRLS, closed form).

"We compare to the two algorithms proposed by [5]: the grid-search implementation of Range Least Squares
(RLS, denoted by grid-L2) and the Squared Range Least Squares (SRLS) solution. We also introduce a variation
of RLS using the median rather than mean distance error (denoted by grid-L1) [...] For fairness, we always use
the Pixlive measurements as position estimate if it is available." (004 sec. VI-E; [5] = Beck, Stoica and Li,
"Exact and approximate solutions of source localization problems", IEEE Trans. Signal Process. 56(5), 2008.)

Per window of ``window_s`` seconds (004 sec. III: every measurement is the median over a one-second window):

* **Ranges.** WiFi RTT: the median ``range_m`` per access point, readings whose WiFi RSSI (the optional
  ``rssi`` column of rtt.csv) is below ``min_wifi_rssi_dbm`` = -65 dBm dropped (004 sec. V-A; rows without an
  RSSI are kept). BLE: the median RSSI per beacon, readings below ``min_ble_rssi_dbm`` = -90 dBm dropped
  (sec. V-A), turned into a distance by the path-loss model ``d = d0 10^((a_X - rssi) / (10 gamma))`` as the
  weighted centroid does (a_X and gamma fitted on labelled data by the evaluation: :class:`PathLossCalibrated`).
  ``sources`` selects the modalities (default both, as the paper's "distance-based" comparison). A dataset
  without RTT uses its BLE ranges; one with neither usable raises :class:`MissingStream` with the reason.
* **Calibration** (``calibration``; 004 sec. V-B and VI-C): ``none``; ``offline`` -- a range offset per AP
  (median of measured minus true range) and a 1 m level a_X per beacon (median of ``rssi + 10 gamma
  log10(d / d0)``), from the labelled static sessions of the same building (``calibration_sessions``);
  ``online`` -- the same medians over the ``calib_window_s`` = 1 s after each visual fix, with the fix as the
  true position, used from then on (before the first fix: uncalibrated); ``calibration_modalities`` names the
  modalities corrected (default both, as 004; on simulated walks the 1 s BLE medians make online a_X noisy
  enough to hurt, which 004 Fig. 9 reports for some beacons too). Functions: :func:`rtt_offsets`,
  :func:`ble_levels`, :func:`online_corrections`.
* **Solver** (the class): grid-L2 ``argmin_y sum_m (d_m - ||y - a_m||)^2`` and grid-L1 ``argmin_y sum_m
  |d_m - ||y - a_m|||`` over the centres of the floor's free cells at ``grid_m`` = 0.5 m (the CRF's grid,
  004 sec. VI-D; 3-D distances with the device at ``device_z``); SRLS ``argmin_x sum_m (||x - a_m||^2 -
  d_m^2)^2`` exactly, by the generalized trust region subproblem of Beck et al. (:func:`srls`), in the
  horizontal plane with ``d_m^2 - (z_m - device_z)^2`` as the squared horizontal range (the same cost as the
  3-D one with the device's height fixed). A window needs ``min_ranges`` = 3 ranges (an estimate from fewer
  is a circle or two points, not a position).
* **Visual fixes**: a window with a fix in ``visual.csv`` takes the (last) fix as its estimate (``visual``;
  online calibration uses the fixes either way).

Estimates: one per window from the first with ranges or a fix to the last, stamped at the window's end
(``stamp: end``, as the centroid and the CRF) or at the time of its last reading (``stamp: last``: the estimate
is ready then, and a static survey scan is scored at its own time, not interpolated towards the next point);
a window without an estimate repeats the previous one, stamped at the window's end (``hold: false``: it has
no estimate; the evaluation then scores only the windows a method could localize -- used for static surveys,
where the previous window may be another point). Deterministic: every run
gets the same trajectory. Positions in world metres (the anchors' frame); no covariance.

"grid-L1": the paper describes it as "the median rather than mean distance error"; we read the name: the sum
of absolute residuals (an L1 cost, whose one-dimensional analogue is the median), which, unlike the median
of three to five residuals, uses every anchor.

Configs: ``conf/localizer/grid_l2.yaml``, ``grid_l1.yaml``, ``srls.yaml``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from blenav.crf.calibration import CALIBRATIONS, offline_calibration
from blenav.crf.preprocess import BLE_MIN_RSSI_DBM, WIFI_MIN_RSSI_DBM, ble_keep_mask, rtt_keep_mask
from blenav.filters.calibration import apply_fit
from blenav.filters.measurement import AnchorTable, PathLossRange
from blenav.filters.runner import MissingStream

from .base import Estimate, Localizer, PathLossCalibrated, RunContext
from .centroid import _window_medians

__all__ = ["GridL2Localizer", "GridL1Localizer", "SrlsLocalizer", "RangeBaseline", "WindowRanges", "srls",
           "collinear_anchors",
           "grid_costs", "free_cells", "wifi_rssi", "rtt_readings", "ble_readings", "rtt_offsets", "ble_levels",
           "online_corrections", "window_ranges", "WIFI_MIN_RSSI_DBM", "BLE_MIN_RSSI_DBM"]

# WIFI_MIN_RSSI_DBM (-65), BLE_MIN_RSSI_DBM (-90): the rules of 004 sec. V-A, defined in blenav.crf.preprocess
SOURCES = ("rtt", "ble")
_NO_ANCHORS = AnchorTable.empty()


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


def _dist3(xy: np.ndarray, z: float | np.ndarray, anchor_xyz: np.ndarray) -> np.ndarray:
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
    cal = offline_calibration(sessions, anchors, _NO_ANCHORS, 0.0, None, min_wifi_rssi_dbm, device_z=device_z)
    return cal.rtt_offset


def ble_levels(sessions, anchors: AnchorTable, gamma: float, d0: float = 1.0, device_z: float = 1.2,
               min_ble_rssi_dbm: float | None = BLE_MIN_RSSI_DBM) -> np.ndarray:
    """Offline BLE calibration: the 1 m level a_X (A,) dBm of each beacon (004 sec. V-B: "transmit powers for
    each Bluetooth beacon"), the median over labelled ``sessions`` of ``rssi + 10 gamma log10(d / d0)`` with d the
    true 3-D distance (at least 0.1 m). NaN for a beacon without a reading.
    (:func:`blenav.crf.calibration.offline_calibration` at the fixed height ``device_z``.)"""
    return offline_calibration(sessions, _NO_ANCHORS, anchors, gamma, min_ble_rssi_dbm, None, device_z=device_z,
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
        corr = _window_medians(fi.astype(np.int64), idx[ri], v, F, n_anchors)
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


def _correction_at(t_query: np.ndarray, base: np.ndarray, t_avail: np.ndarray, corr: np.ndarray) -> np.ndarray:
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
    med = _window_medians(win - w_lo, idx, d, W, A) if len(t) else np.full((W, A), np.nan)
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


# ------------------------------------------------------------------------------------------ solvers
def srls(anchors_xy: np.ndarray, r2: np.ndarray, mask: np.ndarray | None = None, iters: int = 200) -> np.ndarray:
    """Squared-range least squares (Beck, Stoica and Li 2008, sec. III, "SR-LS"), exact, batched.

    ``anchors_xy`` (A, n) or (K, A, n) m, ``r2`` (K, A) squared ranges m^2, ``mask`` (K, A) bool (which ranges
    each problem uses; default all finite). Returns (K, n): ``argmin_x sum_m (||x - a_m||^2 - r2_m)^2``; NaN for
    a problem with fewer than n + 1 ranges.

    With y = (x, ||x||^2) the problem is ``min ||A y - b||^2 s.t. y^T D y + 2 f^T y = 0``, A_m = (-2 a_m^T, 1),
    b_m = r2_m - ||a_m||^2, D = diag(I_n, 0), f = (0, -1/2) (Beck et al. eq. 11), a generalized trust region
    subproblem. Its solution is y(lambda) = (A^T A + lambda D)^{-1} (A^T b - lambda f) with lambda the root of
    phi(lambda) = y^T D y + 2 f^T y, strictly decreasing on I = (-1 / lambda_1, inf), lambda_1 the largest
    eigenvalue of (A^T A)^{-1/2} D (A^T A)^{-1/2} (their Theorem 3.2 / eq. 13); found by bisection, all K
    problems at once. In the "hard case" (no root in I, which needs a special geometry) the bisection ends
    at the interval's left end: the estimate is then the limit y(-1/lambda_1) (approximate, not exact).
    Collinear anchors in 2-D (A^T A singular; a corridor's APs): with s the position along their line and h the
    distance from it, the cost depends on (s, s^2 + h^2) only, so the problem is a least-squares fit of
    (s, w = s^2 + h^2) subject to w >= s^2 (convex): the unconstrained fit when it has w >= s^2 (then
    h = sqrt(w - s^2), on the side of the line's left normal -- the mirror image is as good:
    :func:`collinear_anchors` gives the line, :class:`SrlsLocalizer` picks the mirror on free space), else
    h = 0 and s the one-dimensional SR-LS on the line. Coincident anchors (no line) give NaN."""
    r2 = np.asarray(r2, float)
    K, A = r2.shape
    a = np.asarray(anchors_xy, float)
    if a.ndim == 2:
        a = np.broadcast_to(a, (K,) + a.shape)
    n = a.shape[-1]
    m = np.isfinite(r2) if mask is None else (np.asarray(mask, bool) & np.isfinite(r2))
    ok = m.sum(1) >= n + 1
    if not ok.all():  # too few ranges: NaN; the others solved alone
        x = np.full((K, n), np.nan)
        if ok.any():
            x[ok] = srls(a[ok], r2[ok], m[ok], iters)
        return x
    if n == 2:
        col, centre_c, u = collinear_anchors(a, m)
        if col.any():
            x = np.full((K, n), np.nan)
            if (~col).any():
                x[~col] = srls(a[~col], r2[~col], m[~col], iters)
            x[col] = _srls_on_line(a[col], r2[col], m[col], centre_c[col], u[col], iters)
            return x
    return _srls_general(a, r2, m, iters)


def _srls_general(a: np.ndarray, r2: np.ndarray, m: np.ndarray, iters: int) -> np.ndarray:
    """SR-LS of :func:`srls` for K problems with at least n + 1 used ranges and a non-singular A^T A: ``a``
    (K, A, n) anchors m, ``r2`` (K, A) squared ranges m^2, ``m`` (K, A) bool used ranges. Returns (K, n) m.

    y(lambda) = (A^T A + lambda D)^{-1} (A^T b - lambda f) and phi(lambda) = y^T D y + 2 f^T y (Beck et al.
    eq. 11-13); lambda is phi's root on I = (-1 / lambda_1, inf), by :func:`_srls_bisect`."""
    n = a.shape[-1]
    centre, mu, back, u, v, lo = _srls_spectral(a, r2, m)

    def y_of(lam):
        den = np.maximum(1.0 + lam[:, None] * mu, 1e-15)
        return np.einsum("kij,kj->ki", back, (u - lam[:, None] * v) / den)

    def phi(lam):
        y = y_of(lam)
        return (y[:, :n] ** 2).sum(1) - y[:, n]

    lam = _srls_bisect(phi, lo, iters)
    return y_of(lam)[:, :n] + centre


def _srls_spectral(a: np.ndarray, r2: np.ndarray, m: np.ndarray):
    """One factorisation of the K generalized trust region subproblems (Beck et al. eq. 11) for y(lambda).

    ``a`` (K, A, n) m, ``r2`` (K, A) m^2, ``m`` (K, A) bool. Returns (centre (K, n) m the used anchors' mean the
    problems are solved about, mu (K, n+1) the eigenvalues of L^-1 D L^-T ascending, back (K, n+1, n+1) L^-T Q,
    u (K, n+1) Q^T L^-1 A^T b, v (K, n+1) Q^T L^-1 f, lo (K,) -1 / lambda_1 the left end of I), with
    A^T A = L L^T (Cholesky, slightly regularised) and L^-1 D L^-T = Q diag(mu) Q^T."""
    K, A = r2.shape
    n = a.shape[-1]
    w = m.astype(float)
    # the cost is translation invariant: solve about the used anchors' mean (conditioning), shift back at the end
    centre = np.einsum("ka,kan->kn", w, a) / np.maximum(w.sum(1), 1.0)[:, None]
    a = a - centre[:, None, :]
    Am = np.concatenate([-2.0 * a, np.ones((K, A, 1))], axis=2) * w[..., None]  # (K, A, n+1), unused rows zero
    b = np.where(m, r2 - (a * a).sum(-1), 0.0)
    AtA = np.einsum("kai,kaj->kij", Am, Am)
    Atb = np.einsum("kai,ka->ki", Am, b)
    eye = np.eye(n + 1)
    AtA = AtA + (1e-9 * np.trace(AtA, axis1=1, axis2=2)[:, None, None] + 1e-300) * eye
    D = np.diag(np.r_[np.ones(n), 0.0])
    f = np.r_[np.zeros(n), -0.5]
    # A^T A = L L^T and L^-1 D L^-T = Q diag(mu) Q^T, so (A^T A + lambda D)^-1 = L^-T Q diag(1 / (1 + lambda mu))
    # Q^T L^-1: y(lambda) for every lambda from one factorisation, without a solve that fails near the singular
    # end of I (lambda -> -1 / lambda_1, where 1 + lambda mu_max -> 0); lambda_1 = mu_max.
    L = np.linalg.cholesky(AtA)
    Li = np.linalg.inv(L)
    mu, Q = np.linalg.eigh(Li @ D @ np.swapaxes(Li, 1, 2))
    lam1 = mu[:, -1]
    lo = -1.0 / np.maximum(lam1, 1e-300)
    back = np.swapaxes(Li, 1, 2) @ Q  # (K, n+1, n+1): L^-T Q
    QtLi = np.swapaxes(Q, 1, 2) @ Li
    u = np.einsum("kij,kj->ki", QtLi, Atb)
    v = np.einsum("kij,j->ki", QtLi, f)
    return centre, mu, back, u, v, lo


def _srls_bisect(phi, lo: np.ndarray, iters: int) -> np.ndarray:
    """The root (K,) of the K strictly decreasing functions ``phi`` ((K,) -> (K,)) on (``lo``, inf), ``lo`` (K,):
    grow an upper end until phi < 0 there, then ``iters`` bisection steps; in the hard case (no root) the
    result is just right of ``lo``."""
    scale = np.maximum(np.abs(lo), 1.0)
    hi = scale.copy()
    for _ in range(200):  # phi(hi) < 0: phi -> -||x||^2 ... decreasing; grow hi until the sign changes
        p = phi(hi)
        grow = p > 0
        if not grow.any():
            break
        hi = np.where(grow, hi * 4.0 + scale, hi)
    lo_b = lo.copy()
    for _ in range(iters):
        mid = 0.5 * (lo_b + hi)
        mid = np.where(mid <= lo, 0.5 * (lo + hi), mid)
        p = phi(mid)
        lo_b = np.where(p > 0, mid, lo_b)
        hi = np.where(p > 0, hi, mid)
    return np.where(hi > lo, hi, lo + np.abs(lo) * 1e-12 + 1e-12)


def collinear_anchors(a: np.ndarray, m: np.ndarray, rtol: float = 1e-9):
    """Which problems' used anchors lie on one line: ``a`` (K, A, 2) m, ``m`` (K, A) bool. Returns (flag (K,),
    centre (K, 2) the used anchors' mean, u (K, 2) the line's unit direction). Collinear: the smaller
    eigenvalue of the anchors' scatter is at most ``rtol`` times the larger (coincident anchors count too)."""
    w = m.astype(float)
    centre = np.einsum("ka,kan->kn", w, a) / np.maximum(w.sum(1), 1.0)[:, None]
    c = (a - centre[:, None, :]) * w[..., None]
    ev, vec = np.linalg.eigh(np.einsum("kai,kaj->kij", c, c))
    return ev[:, 0] <= rtol * np.maximum(ev[:, 1], 1e-300), centre, vec[:, :, 1]


def _srls_on_line(a, r2, m, centre, u, iters):
    """SR-LS for collinear anchors (see :func:`srls`): (K, 2) positions, the solution left of the line."""
    K = len(r2)
    w = m.astype(float)
    s_m = np.einsum("kan,kn->ka", a - centre[:, None, :], u)  # positions along the line
    nrm = np.stack([-u[:, 1], u[:, 0]], axis=1)
    Am = np.stack([-2.0 * s_m, np.ones_like(s_m)], axis=2) * w[..., None]
    b = np.where(m, r2 - s_m ** 2, 0.0)
    AtA = np.einsum("kai,kaj->kij", Am, Am)
    Atb = np.einsum("kai,ka->ki", Am, b)
    distinct = np.linalg.det(AtA) > 1e-12 * np.maximum(np.trace(AtA, axis1=1, axis2=2), 1e-300) ** 2
    y = np.zeros((K, 2))
    if distinct.any():
        y[distinct] = np.linalg.solve(AtA[distinct], Atb[distinct][..., None])[..., 0]
    sv, wv = y[:, 0], y[:, 1]
    h2 = wv - sv ** 2
    x = centre + sv[:, None] * u + np.sqrt(np.maximum(h2, 0.0))[:, None] * nrm
    on_line = distinct & (h2 < 0)
    if on_line.any():  # the constraint is active: h = 0, one-dimensional SR-LS along the line
        s1 = srls(s_m[on_line][..., None], np.where(m[on_line], r2[on_line], np.nan), None, iters)[:, 0]
        x[on_line] = centre[on_line] + s1[:, None] * u[on_line]
    x[~distinct] = np.nan
    return x


def grid_costs(cells: np.ndarray, anchor_xyz: np.ndarray, d: np.ndarray, device_z: float, loss: str = "l2",
               chunk_elems: int = 4_000_000) -> np.ndarray:
    """Best cell per window: ``argmin_c sum_m cost(d[w, m] - ||cell_c - a_m||)`` over ranges ``d`` (W, A) m (NaN =
    absent), cells (N, 2) m at height ``device_z``, anchors (A, 3) m; ``loss`` 'l2' (squared residuals) or 'l1'
    (absolute). Returns (W,) cell index (-1 for a window without any range).

    Vectorised over windows and cells: l2 expands the square into three matrix products, (W, N) per chunk of
    windows; l1 forms |residuals| (chunk, N, A) in chunks of at most ``chunk_elems`` elements."""
    D = np.sqrt(((cells[:, None, :] - anchor_xyz[None, :, :2]) ** 2).sum(-1) + (anchor_xyz[None, :, 2] - device_z) ** 2)
    m = np.isfinite(d)
    dz = np.where(m, d, 0.0)
    W, N, A = len(d), len(cells), len(anchor_xyz)
    out = np.full(W, -1, np.int64)
    if N == 0 or A == 0:
        return out
    if loss == "l2":
        step = max(1, chunk_elems // max(N, 1))
        wm = m.astype(float)
        D2 = D * D
        for s in range(0, W, step):
            e = slice(s, s + step)
            c = (wm[e] @ D2.T) - 2.0 * (dz[e] @ D.T) + (dz[e] ** 2).sum(1)[:, None]
            out[e] = np.argmin(c, axis=1)
    elif loss == "l1":  # float32 (centimetre residuals are plenty for a 0.5 m grid): half the time of float64
        step = max(1, chunk_elems // max(N * A, 1))
        D32, d32, m32 = D.astype(np.float32), dz.astype(np.float32), m.astype(np.float32)
        for s in range(0, W, step):
            e = slice(s, s + step)
            c = np.einsum("wna,wa->wn", np.abs(d32[e][:, None, :] - D32[None]), m32[e])
            out[e] = np.argmin(c, axis=1)
    else:
        raise ValueError(f"loss must be 'l2' or 'l1', got {loss!r}")
    out[~m.any(axis=1)] = -1
    return out


def free_cells(floor, grid_m: float, cache: dict | None = None) -> np.ndarray:
    """World (N, 2) m of the centres of the floor's free cells at ``grid_m`` (a cell is free when every floor
    pixel it covers is: :func:`blenav.features.mapgrid.net_grid`); cached per floor and resolution."""
    key = ("ranging-free-cells", str(floor.image_path), float(floor.resolution), tuple(floor.origin), float(grid_m))
    if cache is not None and key in cache:
        return cache[key]
    from blenav.features.mapgrid import net_grid

    g, free = net_grid(floor, grid_m)
    r, c = np.nonzero(free)
    h = g.shape[0]
    xy = np.stack([g.origin[0] + (c + 0.5) * g.resolution, g.origin[1] + (h - 1 - r + 0.5) * g.resolution], axis=1)
    if cache is not None:
        cache[key] = xy
    return xy


# ------------------------------------------------------------------------------------------ localizer
class RangeBaseline(Localizer, PathLossCalibrated):
    """Shared part of the range baselines (module docstring): readings -> calibrated window ranges -> one
    solver per window (:meth:`solve`) -> visual override -> hold. Subclasses set ``solver``."""

    solver = "grid_l2"

    def __init__(self, name: str, shared=None, sources=("rtt", "ble"), window_s: float = 1.0, grid_m: float = 0.5,
                 min_ranges: int = 3, min_wifi_rssi_dbm: float | None = WIFI_MIN_RSSI_DBM,
                 min_ble_rssi_dbm: float | None = BLE_MIN_RSSI_DBM, calibration: str = "online",
                 calibration_sessions="auto", calib_window_s: float = 1.0, visual: bool = True,
                 a_x: float = -60.0, gamma: float = 2.25, d0: float = 1.0, use_anchor_tx_power: bool = True,
                 calibrated: bool = True, device_z: float = 1.2, stamp: str = "end", hold: bool = True,
                 calibration_modalities=("rtt", "ble")):
        super().__init__(name, shared)
        src = [sources] if isinstance(sources, str) else list(sources)
        bad = [s for s in src if s not in SOURCES]
        if bad or not src:
            raise ValueError(f"method {name!r}: sources must be a non-empty subset of {list(SOURCES)}, got {src}")
        if calibration not in CALIBRATIONS:
            raise ValueError(f"method {name!r}: calibration must be one of {CALIBRATIONS}, got {calibration!r}")
        if not window_s > 0 or not grid_m > 0 or not calib_window_s > 0:
            raise ValueError(f"method {name!r}: window_s, grid_m and calib_window_s must be > 0 "
                             f"(got {window_s}, {grid_m}, {calib_window_s})")
        if stamp not in ("end", "last"):
            raise ValueError(f"method {name!r}: stamp must be 'end' or 'last', got {stamp!r}")
        self.stamp, self.hold = stamp, bool(hold)
        cal_mod = ([calibration_modalities] if isinstance(calibration_modalities, str)
                   else list(calibration_modalities or []))
        if [c for c in cal_mod if c not in SOURCES]:
            raise ValueError(f"method {name!r}: calibration_modalities must be a subset of {list(SOURCES)}, got {cal_mod}")
        self.calibration_modalities = cal_mod
        if int(min_ranges) < 1:
            raise ValueError(f"method {name!r}: min_ranges must be >= 1, got {min_ranges}")
        self.sources, self.window_s, self.grid_m, self.min_ranges = src, float(window_s), float(grid_m), int(min_ranges)
        self.min_wifi_rssi_dbm = None if min_wifi_rssi_dbm is None else float(min_wifi_rssi_dbm)
        self.min_ble_rssi_dbm = None if min_ble_rssi_dbm is None else float(min_ble_rssi_dbm)
        self.calibration, self.calibration_sessions = calibration, calibration_sessions
        self.calib_window_s, self.visual, self.device_z = float(calib_window_s), bool(visual), float(device_z)
        self.path_loss = PathLossRange(a_x=a_x, gamma=gamma, d0=d0, device_z=device_z, max_range_m=np.inf,
                                       use_anchor_tx_power=use_anchor_tx_power, calibrated=calibrated)
        self.uses_floor_plan = self.solver != "srls"

    # PathLossCalibrated: BLE ranges use the fitted a_X, gamma (as the weighted centroid)
    def wants_path_loss_fit(self) -> bool:
        return "ble" in self.sources and self.path_loss.calibrated

    def apply_path_loss_fit(self, fit) -> None:
        apply_fit([self.path_loss], fit)

    # -------------------------------------------------------------------------------------- calibration data
    def _offline_sessions(self, session, ctx: RunContext | None) -> list:
        """Labelled static sessions of ``session``'s building (``calibration_sessions``: 'auto' or ids), never
        ``session`` itself."""
        from blenav.data import Dataset

        root = session.root.parent.parent
        cache = ctx.cache if ctx is not None else {}
        key = ("ranging-dataset", str(root))
        if key not in cache:
            cache[key] = Dataset.open(root)
        ds = cache[key]
        spec = self.calibration_sessions
        if spec in (None, "auto"):
            cand = [s for s in ds.sessions(labelled=True) if s.carrier == "static"
                    and s.building.id == session.building.id and s.id != session.id]
        else:
            ids = [spec] if isinstance(spec, str) else [str(i) for i in spec]
            cand = [s for s in ds.sessions(ids) if s.id != session.id] if ids else []
        return cand

    def _corrections(self, session, ctx, wr: WindowRanges, rtt, ble, notes: list):
        """(W, A_rtt) RTT offsets (m) and (W, A_ble) BLE 1 m levels (dBm) in force at each window."""
        (tr, ir, rr, ar), (tb, ib, sb, ab) = rtt, ble
        W = len(wr.t_stamp)
        off_base = np.zeros(len(ar.ids))
        ax_base = self.path_loss._ax() if len(ab.ids) else np.zeros(0)
        gamma, d0 = self.path_loss.gamma, self.path_loss.d0
        do_rtt, do_ble = "rtt" in self.calibration_modalities, "ble" in self.calibration_modalities
        if self.calibration == "offline" and (do_rtt or do_ble):
            cal = self._offline_sessions(session, ctx)
            if not cal:
                raise MissingStream(f"offline calibration needs labelled static sessions of building "
                                    f"{session.building.id} besides {session.id} (calibration_sessions="
                                    f"{self.calibration_sessions!r}); none found")
            c = offline_calibration(cal, ar if do_rtt else _NO_ANCHORS, ab if do_ble else _NO_ANCHORS, gamma,
                                    self.min_ble_rssi_dbm, self.min_wifi_rssi_dbm, device_z=self.device_z, d0=d0)
            if len(ar.ids) and do_rtt:
                off_base = np.where(np.isfinite(c.rtt_offset), c.rtt_offset, 0.0)
            if len(ab.ids) and do_ble:
                ax_base = np.where(np.isfinite(c.ble_tx), c.ble_tx, ax_base)
            notes.append(f"offline calibration on {', '.join(s.id for s in cal)}")
        off = np.broadcast_to(off_base, (W, len(off_base))).copy()
        axw = np.broadcast_to(ax_base, (W, len(ax_base))).copy()
        if self.calibration == "online":
            vis = session.visual
            ft, fxy = vis["t"].to_numpy(float), vis[["x", "y"]].to_numpy(float)
            z = self.device_z
            if len(ar.ids) and do_rtt:
                ta, c = online_corrections(ft, fxy, tr, ir, rr,
                                           lambda v, i, xy: v - _dist3(xy, z, ar.xyz[i]), len(ar.ids), self.calib_window_s)
                off = _correction_at(wr.t_stamp, off_base, ta, c)
            if len(ab.ids) and do_ble:
                ta, c = online_corrections(
                    ft, fxy, tb, ib, sb,
                    lambda v, i, xy: v + 10.0 * gamma * np.log10(np.maximum(_dist3(xy, z, ab.xyz[i]), 0.1) / d0),
                    len(ab.ids), self.calib_window_s)
                axw = _correction_at(wr.t_stamp, ax_base, ta, c)  # before a beacon's first: the configured / fitted a_X
            notes.append(f"online calibration at {len(ft)} visual fix(es)" if len(ft) else
                         f"{session.id}: no visual fix, so no online calibration (ranges uncalibrated)")
        return off, axw

    # -------------------------------------------------------------------------------------- run
    def run(self, session, n_runs: int, seed: int, ctx: RunContext | None = None) -> Estimate:
        t_start = time.perf_counter()
        notes: list[str] = []
        empty_rtt = (np.zeros(0), np.zeros(0, int), np.zeros(0),
                     AnchorTable(np.zeros(0, str), np.zeros((0, 3)), np.zeros(0)))
        empty_ble = empty_rtt
        n_weak = 0
        rtt = empty_rtt
        if "rtt" in self.sources:
            tr, ir, rr, ar, n_weak = rtt_readings(session, self.min_wifi_rssi_dbm)
            rtt = (tr, ir, rr, ar)
        ble = empty_ble
        if "ble" in self.sources:
            ble = ble_readings(session, self.min_ble_rssi_dbm)
            self.path_loss.bind(ble[3])
        why = []
        if "rtt" in self.sources and not len(rtt[0]):
            why.append("no RTT range of an AP with a known position" + (
                f" at or above {self.min_wifi_rssi_dbm:g} dBm" if n_weak else ""))
        if "ble" in self.sources and not len(ble[0]):
            why.append("no BLE reading of a beacon with a known position"
                       + (f" at or above {self.min_ble_rssi_dbm:g} dBm" if self.min_ble_rssi_dbm is not None else ""))
        if not len(rtt[0]) and not len(ble[0]):
            raise MissingStream(f"session {session.id}: " + "; ".join(why))
        if why:
            notes.append(f"{session.id}: " + "; ".join(why) + " (ranges from the other modality only)")
        if n_weak:
            notes.append(f"{session.id}: {n_weak} RTT ranges below {self.min_wifi_rssi_dbm:g} dBm dropped (004 V-A)")
        vis = session.visual if self.visual else None
        vt = vis["t"].to_numpy(float) if vis is not None else np.zeros(0)
        vxy = vis[["x", "y"]].to_numpy(float) if vis is not None else np.zeros((0, 2))
        (tr, ir, rr, ar), (tb, ib, sb, ab) = rtt, ble
        # windows over the raw readings (RSSI medians for BLE: the distance is monotone in the RSSI)
        wr = window_ranges([tr, tb], [ir, ib], [rr, sb], [ar.xyz, ab.xyz], ["rtt", "ble"], vt, vxy, self.window_s)
        off, axw = self._corrections(session, ctx, wr, rtt, ble, notes)
        nr = len(ar.ids)
        d = wr.d.copy()
        d[:, :nr] -= off
        if len(ab.ids):
            d[:, nr:] = self.path_loss.d0 * 10.0 ** ((axw - d[:, nr:]) / (10.0 * self.path_loss.gamma))
        xy = self.solve(session, ctx, wr.anchors, d)
        enough = np.isfinite(d).sum(axis=1) >= self.min_ranges
        xy[~enough] = np.nan
        if self.visual:
            hv = np.isfinite(wr.visual[:, 0])
            xy[hv] = wr.visual[hv]
        good = np.isfinite(xy).all(axis=1)
        if not good.any():
            raise MissingStream(f"session {session.id}: no window with {self.min_ranges} or more ranges or a visual fix")
        first = int(np.argmax(good))
        last = np.maximum.accumulate(np.where(good, np.arange(len(good)), -1))[first:]
        xy = xy[first:][last - first]
        stamp = wr.t_stamp[first:]
        held = ~good[first:]
        ends = wr.t0 + (wr.window[first:] + 1) * self.window_s
        stamp = np.where(held | (self.stamp == "end"), ends, stamp)
        stamp = np.maximum.accumulate(stamp)  # a held window's end can pass the next window's first reading only by 0
        if not self.hold:
            xy, stamp = xy[~held], stamp[~held]
        notes.append(f"{session.id}: {int((~held).sum())} of {len(held)} windows localized "
                     f"({'the others hold the previous estimate' if self.hold else 'the others have no estimate'})")
        pos = np.broadcast_to(xy, (n_runs,) + xy.shape).copy()
        return Estimate(self.name, session.id, stamp, pos, None, [], {}, n_runs * (time.perf_counter() - t_start), notes)

    def solve(self, session, ctx, anchors: np.ndarray, d: np.ndarray) -> np.ndarray:
        """(W, 2) estimates from ranges ``d`` (W, A) m (NaN = none) to ``anchors`` (A, 3) m."""
        raise NotImplementedError


class _GridBaseline(RangeBaseline):
    loss = "l2"

    def solve(self, session, ctx, anchors, d):
        cells = free_cells(session.floor, self.grid_m, ctx.cache if ctx is not None else None)
        if not len(cells):
            raise MissingStream(f"floor {session.floor.id} of {session.building.id} has no free cell at {self.grid_m:g} m")
        best = grid_costs(cells, anchors, d, self.device_z, self.loss)
        xy = np.full((len(d), 2), np.nan)
        ok = best >= 0
        xy[ok] = cells[best[ok]]
        return xy


class GridL2Localizer(_GridBaseline):
    """grid-L2 (004 sec. VI-E; Beck et al.'s range least squares, RLS, by grid search): the free cell that
    minimises the sum of squared range residuals. Config ``conf/localizer/grid_l2.yaml``."""

    solver, loss = "grid_l2", "l2"


class GridL1Localizer(_GridBaseline):
    """grid-L1 (004 sec. VI-E): the free cell that minimises the sum of absolute range residuals (the paper's
    "median rather than mean distance error"; see the module docstring). Config ``conf/localizer/grid_l1.yaml``."""

    solver, loss = "grid_l1", "l1"


class SrlsLocalizer(RangeBaseline):
    """SRLS (004 sec. VI-E; Beck, Stoica and Li 2008): the exact squared-range least-squares position
    (:func:`srls`), in the horizontal plane at height ``device_z``; not confined to the floor plan. Config
    ``conf/localizer/srls.yaml``."""

    solver = "srls"

    def solve(self, session, ctx, anchors, d):
        r2 = d * d - (anchors[None, :, 2] - self.device_z) ** 2
        # a negative range (Android reports some) squared would pretend a distance: such ranges count as 0
        r2 = np.where(np.isfinite(d) & (d < 0), 0.0, r2)
        x = srls(anchors[:, :2], r2)
        # collinear anchors: the mirror image across their line is as good; take the one on free space
        a = np.broadcast_to(anchors[:, :2], (len(d),) + anchors[:, :2].shape)
        col, c, u = collinear_anchors(a, np.isfinite(r2))
        col &= np.isfinite(x).all(axis=1)
        if col.any():
            rel = x[col] - c[col]
            mirror = c[col] + 2.0 * (rel * u[col]).sum(1, keepdims=True) * u[col] - rel
            floor = session.floor
            swap = ~floor.is_free(x[col]) & floor.is_free(mirror)
            idx = np.flatnonzero(col)[swap]
            x[idx] = mirror[swap]
        return x
