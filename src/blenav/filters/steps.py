"""From sensor streams to filter steps: controls and observations per step window, batch and streaming.

The filter steps at ``rate_hz`` (000 samples its motion model at the BLE rate). Step k closes the
window (t_{k-1}, t_k], t_k = t_start + k / rate_hz. Per window (all causal, so that the streaming
:class:`StepStream` and the batch :func:`session_steps` compute the very same numbers):

* ``acc_w`` (2,): horizontal gravity-compensated world acceleration R_t a_t + g (000 eq. 6) at the
  window's last IMU sample t, with a_t the median of the last ``median_window`` accelerometer samples
  (000's median prefilter) and R_t from the AHRS (m/s^2). Eq. 6 uses the current sample, not an
  average: averaging over the window leaves mostly the gravity leak of small tilt errors, a constant
  direction, and the proposal then only moves particles along it;
* ``heading`` (rad): AHRS heading of the device's forward axis at the window's last IMU sample;
* ``steps``: PDR steps detected in the window (:class:`StepDetector`, causal);
* ``odo`` (2,): inertial-odometry displacement between the last odometry samples at or before
  t_{k-1} and t_k (odometry frame, m);
* ``odo_var`` (float, m^2): the growth of the odometry's own position variance (per axis) over the same interval,
  where the track states one (the learned inertial odometry's column ``var``, issue 31); 0 otherwise;
* ``rssi_idx`` (M,), ``rssi`` (M,): the window's BLE packets (anchor row in the model's
  :class:`~blenav.filters.measurement.AnchorTable`, dBm); packets of anchors that are not BLE anchors
  of the building are left out (the reader already dropped unknown ids and reported them);
* ``fix_xy`` (F, 2), ``fix_std`` (F,), ``fix_source`` (F,): the window's position fixes (``fixes.csv``,
  or :meth:`StepStream.push_fix`): world x, y (m), reported std (m, NaN when unknown) and source
  (str, '' when empty), in time order. All sources are packed; each
  :class:`~blenav.filters.measurement.FixLikelihood` selects its own;
* ``t`` (float, s): the step's time t_k, and ``odo_xy`` (2,): the inertial-odometry position at t_k (the last
  odometry sample at or before t_k, odometry frame, m; zeros without odometry). Models that need a history
  of the odometry (the map prior's window, :mod:`blenav.filters.map_prior`) keep it from these.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from .attitude import (
    AttitudeConfig,
    StreamingAttitude,
    estimate_attitude,
    gravity_compensated_acc,
    yaw_of_device_forward,
)
from .measurement import AnchorTable
from .median import median_of


@dataclass
class StepDetectorConfig:
    threshold: float = 1.2  # m/s^2 above gravity of the smoothed acceleration norm
    min_interval_s: float = 0.3
    smooth_s: float = 0.1


class StepDetector:
    """Causal step detector: upward crossings of (smoothed |a| - g) above ``threshold``, at least
    ``min_interval_s`` apart. Smoothing is a trailing mean over ``smooth_s``."""

    def __init__(self, cfg: StepDetectorConfig, rate_hz: float):
        self.cfg = cfg
        self.w = max(1, int(round(cfg.smooth_s * rate_hz)))
        self.buf: deque[float] = deque(maxlen=self.w)  # the last w norms: O(1) per sample
        self.prev_above = False
        self.last_step = -np.inf

    def update(self, t: float, acc: np.ndarray) -> bool:
        self.buf.append(float(np.sqrt(acc[0] ** 2 + acc[1] ** 2 + acc[2] ** 2)))
        above = (sum(self.buf) / len(self.buf) - 9.80665) > self.cfg.threshold
        step = above and not self.prev_above and t - self.last_step >= self.cfg.min_interval_s
        self.prev_above = above
        if step:
            self.last_step = t
        return step


# The same rule as one compiled pass: the Euclidean norm of each accelerometer sample, the trailing mean of the
# last w = max(1, round(smooth_s rate_hz)) norms (fewer at the start) summed oldest first as the deque of
# StepDetector, a step at each upward crossing of mean - 9.80665 above threshold at least min_interval_s after
# the previous step; tests/crf/test_crf.py checks the flags equal StepDetector's. An hour at 200 Hz takes
# milliseconds instead of seconds.
@njit(cache=True, nogil=True)
def _flags(t, acc, w, threshold, min_interval):
    n = t.shape[0]
    norms = np.empty(n)
    for i in range(n):
        norms[i] = np.sqrt(acc[i, 0] ** 2 + acc[i, 1] ** 2 + acc[i, 2] ** 2)
    out = np.zeros(n, np.bool_)
    prev_above = False
    last = -np.inf
    for i in range(n):
        lo = i - w + 1 if i - w + 1 > 0 else 0
        s = 0
        for j in range(lo, i + 1):  # Python's sum() over the deque: start 0, oldest first
            s = s + norms[j]
        above = (s / (i + 1 - lo) - 9.80665) > threshold
        step = above and (not prev_above) and (t[i] - last >= min_interval)
        prev_above = above
        if step:
            last = t[i]
        out[i] = step
    return out


def step_flags(t: np.ndarray, acc: np.ndarray, cfg: StepDetectorConfig, rate_hz: float) -> np.ndarray:
    """(T,) bool: the samples at which :class:`~blenav.filters.steps.StepDetector` (``cfg``, ``rate_hz``)
    reports a step, for IMU times t (T,) s and accelerations acc (T, 3) m/s^2."""
    w = max(1, int(round(cfg.smooth_s * rate_hz)))
    return _flags(np.ascontiguousarray(t, dtype=np.float64), np.ascontiguousarray(acc, dtype=np.float64), w,
                  float(cfg.threshold), float(cfg.min_interval_s))


def detect_steps(t: np.ndarray, acc: np.ndarray, cfg: StepDetectorConfig | None = None) -> np.ndarray:
    """(T,) bool: :func:`step_flags` at the IMU rate of ``t`` (1 / the median positive interval; 100 Hz without
    one: repeated times, allowed, would make the median 0), the rule of the filters' PDR motion model."""
    t = np.asarray(t, dtype=np.float64)
    dt = np.diff(t)
    dt = dt[dt > 0]
    return step_flags(t, acc, cfg or StepDetectorConfig(), 1.0 / np.median(dt) if len(dt) else 100.0)


@dataclass
class Window:
    """Raw samples of one step window, collected by either path."""

    acc: list = field(default_factory=list)
    q: list = field(default_factory=list)
    steps: int = 0
    rssi_idx: list = field(default_factory=list)
    rssi: list = field(default_factory=list)
    fix_xy: list = field(default_factory=list)
    fix_std: list = field(default_factory=list)
    fix_source: list = field(default_factory=list)


def pack_fixes(xy, std, source) -> dict:
    """The fix observations of one window: fix_xy (F, 2) float64 m, fix_std (F,) m, fix_source (F,) str."""
    return {"fix_xy": np.asarray(xy, dtype=float).reshape(-1, 2), "fix_std": np.asarray(std, dtype=float).reshape(-1),
            "fix_source": np.asarray(source, dtype=str).reshape(-1)}




def _window_controls(win_acc: np.ndarray, win_q: np.ndarray, median_window: int) -> tuple[np.ndarray, float]:
    """The window's control inputs: acc_w (2,), the horizontal gravity-compensated world acceleration of the
    median of the last ``median_window`` accelerometer samples rotated by the last quaternion, and the heading
    (rad) of the device's forward axis. With Python floats, the numbers of :func:`_window_controls_numpy`
    (np.median, gravity_compensated_acc, yaw_of_device_forward) bit for bit: the median as np.median takes
    it, the norm of q summed in order, R's entries as quat_to_matrix writes them, each row of R a summed as
    einsum does (p0 + p2) + p1, and np.arctan2 itself; a tenth of their time per streaming step."""
    tail = win_acc[-median_window:].tolist()
    a0, a1, a2 = (median_of([r[j] for r in tail]) for j in range(3))
    w, x, y, z = (float(v) for v in win_q[-1])
    n = math.sqrt(((w * w + x * x) + y * y) + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    r00, r01, r02 = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    r10, r11, r12 = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    acc_w = np.array([(r00 * a0 + r02 * a2) + r01 * a1 + 0.0, (r10 * a0 + r12 * a2) + r11 * a1 + 0.0])
    heading = float(np.arctan2(np.array([r11]), np.array([r01]))[0])
    return acc_w, heading


def _window_controls_numpy(win_acc: np.ndarray, win_q: np.ndarray, median_window: int) -> tuple[np.ndarray, float]:
    """:func:`_window_controls` with numpy (the reference)."""
    a_t = np.median(win_acc[-median_window:], axis=0)
    acc_w = gravity_compensated_acc(win_q[-1:], a_t[None, :])[0, :2]
    return acc_w, float(yaw_of_device_forward(win_q[-1:])[0])


def window_step(win_acc: np.ndarray, win_q: np.ndarray, steps: int, odo_prev: np.ndarray, odo_now: np.ndarray,
                rssi_idx: np.ndarray, rssi: np.ndarray, last_heading: float, median_window: int = 5,
                fixes: dict | None = None, t: float = float("nan"), odo_var: float = 0.0) -> tuple[dict, dict, float]:
    """Controls and observations of one window (both paths call this).

    ``fixes``: the window's fixes as :func:`pack_fixes` returns them (None: no fixes); ``t``: the step time (s);
    ``odo_var``: the odometry's variance growth over the window (m^2 per axis, 0 when the track states none)."""
    if len(win_acc):
        acc_w, heading = _window_controls(win_acc, win_q, median_window)
    else:
        acc_w, heading = np.zeros(2), last_heading
    ctrl = {"acc_w": acc_w, "heading": heading, "steps": steps, "odo": odo_now - odo_prev, "odo_var": float(odo_var)}
    obs = {"rssi_idx": rssi_idx, "rssi": rssi, **(fixes if fixes is not None else pack_fixes([], [], [])),
           "t": float(t), "odo_xy": np.array(odo_now, dtype=float)}
    return ctrl, obs, heading


@dataclass
class SessionArrays:
    """A session's streams as arrays (times in s).

    Fixes: ``fix_t`` (F,) s, ``fix_xy`` (F, 2) world m, ``fix_std`` (F,) m (NaN when unknown),
    ``fix_source`` (F,) str ('' when empty); all rows of ``fixes.csv``, every source.
    ``t_start``/``t_end`` span the IMU, RSSI, odometry and fixes.

    ``extra_fixes`` (:meth:`from_session`): a DataFrame (t, x, y, std, source) of fixes to add to the
    session's own, in memory (e.g. fixes computed from ``rssi.csv`` by the evaluation; the dataset is not
    touched); rows are merged in time order (stable: the session's rows first at equal t).
    """

    imu_t: np.ndarray
    acc: np.ndarray
    gyr: np.ndarray
    mag_t: np.ndarray | None
    mag: np.ndarray | None
    rssi_t: np.ndarray
    rssi_idx: np.ndarray
    rssi: np.ndarray
    odo_t: np.ndarray
    odo: np.ndarray
    t_start: float
    t_end: float
    fix_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    fix_xy: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    fix_std: np.ndarray = field(default_factory=lambda: np.zeros(0))
    fix_source: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=str))
    odo_var: np.ndarray | None = None  # (n,) m^2 per axis: the odometry's cumulative position variance (column var)

    @classmethod
    def from_session(cls, session, anchors: AnchorTable, extra_fixes=None, odometry=None) -> "SessionArrays":
        """The session's streams as arrays. ``extra_fixes`` (DataFrame t, x, y, std, source): fixes added in memory
        to fixes.csv's rows; ``odometry`` (DataFrame t, x, y): odometry used in place of odometry.csv (e.g. PDR
        odometry computed from the IMU); the session itself is not changed."""
        imu = session.imu
        mag = session.mag
        r = session.rssi
        if len(r) and len(anchors.ids):
            idx = anchors.index_of(r["anchor_id"].astype(str).to_numpy())
        else:  # no BLE anchor in the building: no packet is usable
            idx = np.full(len(r), -1, dtype=int)
        keep = idx >= 0
        odo = session.odometry if odometry is None else odometry
        fx = session.fixes
        if extra_fixes is not None and len(extra_fixes):
            import pandas as pd

            cols = ["t", "x", "y", "std", "source"]
            fx = pd.concat([fx[cols], extra_fixes[cols]], ignore_index=True) if len(fx) else extra_fixes[cols]
            fx = fx.sort_values("t", kind="stable").reset_index(drop=True)
        ts = [s["t"].to_numpy() for s in (imu, r, odo, fx) if len(s)]
        if not ts:
            raise ValueError(f"session {session.id} has no IMU, RSSI, odometry or fixes to filter")
        c = np.ascontiguousarray  # row-major like the streaming path's stacked samples: same float results
        return cls(
            c(imu["t"].to_numpy(float)), c(imu[["ax", "ay", "az"]].to_numpy(float)),
            c(imu[["gx", "gy", "gz"]].to_numpy(float)),
            c(mag["t"].to_numpy(float)) if len(mag) else None, c(mag[["mx", "my", "mz"]].to_numpy(float)) if len(mag) else None,
            c(r["t"].to_numpy(float)[keep]), idx[keep], c(r["rssi"].to_numpy(float)[keep]),
            c(odo["t"].to_numpy(float)), c(odo[["x", "y"]].to_numpy(float)),
            float(min(t[0] for t in ts)), float(max(t[-1] for t in ts)),
            c(fx["t"].to_numpy(float)), c(fx[["x", "y"]].to_numpy(float)), c(fx["std"].to_numpy(float)),
            fx["source"].fillna("").astype(str).str.strip().to_numpy(dtype=str),
            c(odo["var"].to_numpy(float)) if "var" in odo and len(odo) else None)


def step_times(t_start: float, t_end: float, rate_hz: float) -> np.ndarray:
    n = int(np.floor((t_end - t_start) * rate_hz + 1e-9))
    return t_start + np.arange(1, n + 1) / rate_hz


def _odo_at(odo_t: np.ndarray, odo: np.ndarray, t: float) -> np.ndarray:
    i = np.searchsorted(odo_t, t, side="right") - 1
    return odo[i] if i >= 0 else (odo[0] if len(odo) else np.zeros(2))


def _var_growth(odo_t: np.ndarray, var: np.ndarray | None, t0: float, t1: float) -> float:
    """The odometry's variance growth (m^2) between its last samples at or before t0 and t1 (0 without ``var``)."""
    if var is None or not len(var):
        return 0.0
    i0, i1 = np.searchsorted(odo_t, [t0, t1], side="right") - 1
    return float(var[max(i1, 0)] - var[max(i0, 0)])


class OdometryTrack:
    """A stream's odometry samples so far: times (n,) s, positions (n, 2) and cumulative position variances (n,) m^2
    per axis in arrays grown by doubling (amortised O(1) per sample, no list turned into an array per step);
    :meth:`at` is :func:`_odo_at` on them (O(log n)), so a streaming step costs the same after an hour as after a
    second; :meth:`var_growth` is :func:`_var_growth` (the batch path's ``odo_var`` control, issue 31), with a
    variance only while every sample has stated one (a track without the column ``var`` states none)."""

    def __init__(self, capacity: int = 256):
        self._t = np.empty(capacity)
        self._xy = np.empty((capacity, 2))
        self._var = np.empty(capacity)
        self.n = 0
        self.has_var = True

    def append(self, t: float, xy: np.ndarray, var: float | None = None) -> None:
        if self.n == len(self._t):
            self._t = np.concatenate([self._t, np.empty_like(self._t)])
            self._xy = np.concatenate([self._xy, np.empty_like(self._xy)])
            self._var = np.concatenate([self._var, np.empty_like(self._var)])
        self._t[self.n] = t
        self._xy[self.n] = xy
        self._var[self.n] = np.nan if var is None else float(var)
        self.has_var = self.has_var and var is not None
        self.n += 1

    def var_growth(self, t0: float, t1: float) -> float:
        """The variance growth (m^2) between the last samples at or before t0 and t1 (0 without variances)."""
        return _var_growth(self._t[: self.n], self._var[: self.n] if self.has_var else None, t0, t1)

    def at(self, t: float) -> np.ndarray:
        """The last sample at or before ``t`` (the first when none is; zeros without samples)."""
        return _odo_at(self._t[: self.n], self._xy[: self.n], t)


def imu_features(a: SessionArrays, att_cfg: AttitudeConfig, det_cfg: StepDetectorConfig,
                 mag_offset: np.ndarray | None = None) -> tuple[np.ndarray | None, np.ndarray]:
    """AHRS quaternions (T, 4) and PDR step flags (T,) at the IMU times of a session (batch path).

    They depend only on the session and the attitude/step settings, so callers running several
    methods on one session compute them once (see :func:`blenav.filters.runner.run_session`).
    """
    if not len(a.imu_t):
        return None, np.zeros(0, bool)
    q = estimate_attitude(a.imu_t, a.acc, a.gyr, a.mag_t, a.mag, att_cfg, mag_offset=mag_offset)
    return q, detect_steps(a.imu_t, a.acc, det_cfg)


def session_steps(a: SessionArrays, rate_hz: float, att_cfg: AttitudeConfig, det_cfg: StepDetectorConfig,
                  need_imu: bool = True, mag_offset: np.ndarray | None = None,
                  imu: tuple[np.ndarray | None, np.ndarray] | None = None, start: int = 0, stop: int | None = None,
                  heading: float = 0.0):
    """Yield (t_k, ctrl, obs) for every step of a session (batch path). Also returns AHRS quaternions.

    Returns ``(steps, q)`` with ``steps`` a list and ``q`` (T, 4) the AHRS orientation at IMU times
    (``None`` without IMU or when the motion model does not need it). ``start``, ``stop``: only the steps
    ``start`` to ``stop - 1`` (``heading``: the heading of the step before ``start``, its ``ctrl["heading"]``, which a
    window without IMU keeps), the same as those of the full list.
    """
    ts = step_times(a.t_start, a.t_end, rate_hz)
    q = None
    step_flags = np.zeros(len(a.imu_t), bool)
    if need_imu and len(a.imu_t):
        q, step_flags = imu if imu is not None else imu_features(a, att_cfg, det_cfg, mag_offset)
    stop = len(ts) if stop is None else min(stop, len(ts))
    # the window edges of the steps asked for only (edge i - start is step i's left edge)
    edges = np.concatenate([[a.t_start - 1e-9], ts])[start:stop + 1]
    bounds_imu = np.searchsorted(a.imu_t, edges, side="right") if need_imu else None
    bounds_rssi = np.searchsorted(a.rssi_t, edges, side="right")
    bounds_fix = np.searchsorted(a.fix_t, edges, side="right")
    out = []
    prev_t = a.t_start if start == 0 else ts[start - 1]
    for k in range(start, stop):
        t = ts[k]
        i = k - start
        if need_imu and q is not None:
            s = slice(bounds_imu[i], bounds_imu[i + 1])
            wa, wq, n_steps = a.acc[s], q[s], int(step_flags[s].sum())
        else:
            wa, wq, n_steps = np.zeros((0, 3)), np.zeros((0, 4)), 0
        r = slice(bounds_rssi[i], bounds_rssi[i + 1])
        f = slice(bounds_fix[i], bounds_fix[i + 1])
        fixes = pack_fixes(a.fix_xy[f], a.fix_std[f], a.fix_source[f]) if f.stop > f.start else None
        ctrl, obs, heading = window_step(wa, wq, n_steps, _odo_at(a.odo_t, a.odo, prev_t), _odo_at(a.odo_t, a.odo, t),
                                         a.rssi_idx[r], a.rssi[r], heading, att_cfg.median_window, fixes, float(t),
                                         _var_growth(a.odo_t, a.odo_var, prev_t, t))
        out.append((float(t), ctrl, obs))
        prev_t = t
    return out, q


class StepStream:
    """Streaming counterpart of :func:`session_steps`: push samples in time order, get steps when due.

    ``push_*`` return the list of (t_k, ctrl, obs) of the windows that the new sample closed. A sample at
    exactly t_k belongs to window k. Call :meth:`close` at the end of the data.
    """

    def __init__(self, anchors: AnchorTable, rate_hz: float, att_cfg: AttitudeConfig, det_cfg: StepDetectorConfig,
                 t_start: float = 0.0, imu_rate_hz: float = 200.0, need_imu: bool = True,
                 mag_offset: np.ndarray | None = None):
        self.anchors, self.rate = anchors, rate_hz
        self.t_start = t_start
        self.k = 1
        self.att = StreamingAttitude(att_cfg, mag_offset=mag_offset) if need_imu else None
        self.median_window = att_cfg.median_window
        self.det = StepDetector(det_cfg, imu_rate_hz)
        self.win = Window()
        self.heading = 0.0
        self.odo = OdometryTrack()
        self.prev_t = t_start

    def _due(self, t: float) -> list:
        out = []
        while t > self.t_start + self.k / self.rate:
            out.append(self._close())
        return out

    def _close(self):
        t = self.t_start + self.k / self.rate
        w = self.win
        ctrl, obs, self.heading = window_step(
            np.asarray(w.acc).reshape(-1, 3), np.asarray(w.q).reshape(-1, 4), w.steps, self.odo.at(self.prev_t),
            self.odo.at(t), np.asarray(w.rssi_idx, dtype=int), np.asarray(w.rssi, dtype=float), self.heading,
            self.median_window, pack_fixes(w.fix_xy, w.fix_std, w.fix_source) if w.fix_xy else None, float(t),
            self.odo.var_growth(self.prev_t, t))
        self.win = Window()
        self.prev_t = t
        self.k += 1
        return (float(t), ctrl, obs)

    def push_imu(self, t: float, acc: np.ndarray, gyr: np.ndarray) -> list:
        out = self._due(t)
        if self.att is not None:
            q = self.att.update(t, np.asarray(acc, float), np.asarray(gyr, float))
            self.win.acc.append(np.asarray(acc, float))
            self.win.q.append(q)
            self.win.steps += int(self.det.update(t, np.asarray(acc, float)))
        return out

    def push_mag(self, t: float, mag: np.ndarray) -> list:
        out = self._due(t)
        if self.att is not None:
            self.att.update_mag(t, np.asarray(mag, float))
        return out

    def push_rssi(self, t: float, anchor_id: str, rssi: float) -> list:
        out = self._due(t)
        i = int(self.anchors.index_of(np.array([str(anchor_id)]))[0])
        if i >= 0:
            self.win.rssi_idx.append(i)
            self.win.rssi.append(float(rssi))
        return out

    def push_fix(self, t: float, x: float, y: float, std: float | None = None, source: str | None = None) -> list:
        """A position fix (world m) with its std (m, None when unknown) and source ('' when None)."""
        out = self._due(t)
        self.win.fix_xy.append((float(x), float(y)))
        self.win.fix_std.append(np.nan if std is None else float(std))
        self.win.fix_source.append("" if source is None else str(source).strip())
        return out

    def push_odometry(self, t: float, xy: np.ndarray, var: float | None = None) -> list:
        """An odometry position (m, its own frame) and, where the track states one, its cumulative position variance
        (m^2 per axis: the column ``var`` of the learned inertial odometry)."""
        out = self._due(t)
        self.odo.append(t, np.asarray(xy, float), var)
        return out

    def close(self, t_end: float) -> list:
        """Close every window that ends at or before t_end (the last, partial window is dropped, as in batch)."""
        out = []
        while self.t_start + self.k / self.rate <= t_end + 1e-9:
            out.append(self._close())
        return out
