"""Learned inertial odometry of a session (issue 31): the odometry track (t, x, y, var) a network's per-window
velocities integrate to, in the frame of the session's attitude (world-aligned where that is: the phone's rotation
vector or blenav's AHRS, both magnetic-north referenced).

The network is anything with the :class:`VelocityModel` protocol: ``grid`` (:class:`blenav.features.inertial.InertialGrid`)
and ``predict(windows) -> (velocity (K, 2), log_var (K, 2))``; :class:`blenav.runtime.inertial.InertialModel` runs an
exported one with onnxruntime (no torch). The track is what ``odometry.csv`` holds (plus the column ``var``, the
cumulative position variance in m^2 from the network's covariance head), so every odometry consumer runs on it:
Roy's odometry increment (eq. 3.7), the learned map prior (eq. 3.8), the global-fusion smoother.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
import pandas as pd

from blenav.errors import MissingStream
from blenav.limits import check_memory
from blenav.features.inertial import GRAVITY, InertialGrid, heading_frame, integrate, rotate_velocity, windows

from .attitude import AttitudeConfig, StreamingAttitude
from .pdr_odometry import HEADINGS, attitude_at, attitude_track, resolve_heading
from .quaternions import quat_to_matrix
from .steps import StepDetectorConfig
from .yaw_hold import StreamingYawHold, check_yaw, resolve_yaw

__all__ = ["VelocityModel", "model_yaw", "world_frame_imu", "session_frame_imu", "lio_odometry", "StreamingLio",
           "LIVE_ATTITUDES"]


class VelocityModel(Protocol):
    grid: InertialGrid
    key: str  # identifies the model's weights (a cache key part: the same key, the same velocities)
    frame: str  # blenav.features.inertial.FRAMES: heading (turn each window, turn the velocity back) or world
    # optional: yaw (YAW_SOURCES), the attitude's yaw the network was trained with; "attitude" where absent

    def predict(self, windows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(K, n_window, 15) float32 -> (velocity (K, 2) m/s, log variance (K, 2))."""


def model_yaw(model) -> str:
    """The yaw source (:data:`YAW_SOURCES`) ``model`` was trained with: its ``yaw``, ``attitude`` where it has none."""
    return check_yaw(getattr(model, "yaw", None) or "attitude", "inertial model: yaw")


def world_frame_imu(imu_t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, q_t: np.ndarray, q: np.ndarray,
                    rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """The IMU rotated into the attitude's gravity-aligned frame and resampled (module doc).

    ``imu_t`` (T,) s increasing; ``acc`` (T, 3) m/s^2 incl. gravity, ``gyr`` (T, 3) rad/s, device frame; ``q_t``
    (Q,) s, ``q`` (Q, 4) device -> world (w, x, y, z); an attitude at the IMU's own times (``q_t`` is ``imu_t``: the
    AHRS, the held yaw) gives each sample its own, also where a time repeats. Returns (t (N,) s on the grid from
    imu_t[0], X (N, 15) float32 in :data:`CHANNELS` order)."""
    imu_t = np.asarray(imu_t, float)
    if len(imu_t) < 2:
        raise ValueError("inertial odometry: fewer than two IMU samples")
    if not len(q_t):
        raise ValueError("inertial odometry: the attitude track is empty")
    q_t, q = np.asarray(q_t, float), np.asarray(q, float)
    own = len(q_t) == len(imu_t) and np.array_equal(q_t, imu_t)  # one attitude per sample, as the live path has
    R = quat_to_matrix(q if own else attitude_at(q_t, q, imu_t))
    a_w = np.einsum("tij,tj->ti", R, np.asarray(acc, float))
    g_w = np.einsum("tij,tj->ti", R, np.asarray(gyr, float))
    a_w[:, 2] -= GRAVITY
    n = int(np.floor((imu_t[-1] - imu_t[0]) * rate_hz + 1e-9)) + 1
    # the grid spans the recording's first to last time: a file whose clock jumps (t in ms, a 10^6 s gap) would ask
    # for an enormous grid; refused here, before anything is allocated (BLENAV_MAX_MEMORY_GB)
    check_memory(4.0 * n * (6 + 9) * 8, f"the IMU resampled to {rate_hz:g} Hz over {imu_t[-1] - imu_t[0]:.6g} s "
                 f"({n:,} samples)", "inertial odometry")
    t = imu_t[0] + np.arange(n) / float(rate_hz)
    raw = np.concatenate([a_w, g_w, R[:, :, 0], R[:, :, 1], R[:, :, 2]], axis=1)
    X = np.stack([np.interp(t, imu_t, raw[:, j]) for j in range(raw.shape[1])], axis=1)
    return t, X.astype(np.float32)


def session_frame_imu(session, grid: InertialGrid, attitude: str = "auto", att: AttitudeConfig | None = None,
                      steps: StepDetectorConfig | None = None, cache: dict | None = None, keep: bool = True,
                      yaw: str = "attitude") -> tuple[np.ndarray, np.ndarray, str]:
    """The session's IMU in the attitude's gravity-aligned frame on ``grid``'s rate: (t (N,) s, X (N, 15) float32,
    the attitude source used). :class:`MissingStream` without IMU data or the attitude source. ``cache``: the
    attitude (an AHRS run) is kept there, and the result too unless ``keep`` is false. ``yaw``: the attitude's own
    or the gyroscope's held to it (:func:`blenav.filters.pdr_odometry.attitude_track`)."""
    imu = session.imu
    if len(imu) < 2:
        raise MissingStream(f"session {session.id} has no IMU data, which the inertial odometry needs")
    source = resolve_heading(session, attitude)
    key = ("lio-frame", session.id, source, yaw, grid.rate_hz, repr(att), repr(steps))
    if cache is not None and key in cache:
        return cache[key]
    q_t, q = attitude_track(session, source, att, steps, cache, yaw)
    t, X = world_frame_imu(imu["t"].to_numpy(float), imu[["ax", "ay", "az"]].to_numpy(float),
                           imu[["gx", "gy", "gz"]].to_numpy(float), q_t, q, grid.rate_hz)
    out = (t, X, source)
    if cache is not None and keep:
        cache[key] = out
    return out


def lio_odometry(session, model: VelocityModel, attitude: str = "auto", att: AttitudeConfig | None = None,
                 steps: StepDetectorConfig | None = None, cache: dict | None = None, batch: int = 512) -> pd.DataFrame:
    """The learned odometry track of ``session`` (DataFrame t, x, y, var: s, m from 0, m^2), ``model`` run on every
    window (``batch`` at a time), its yaw as the model was trained (``model.yaw``, :data:`YAW_SOURCES`; ``attitude``
    for a model that does not say). :class:`MissingStream` without IMU data, the attitude, or a full stride of IMU."""
    yaw = model_yaw(model)
    key = ("lio-odometry", session.id, model.key, attitude, yaw, repr(att), repr(steps))
    if cache is not None and key in cache:
        return cache[key]
    # the attitude (an AHRS run) through the cache; the rotated IMU itself is not kept once the track is
    t, X, _ = session_frame_imu(session, model.grid, attitude, att, steps, cache, keep=False, yaw=yaw)
    W = windows(X, model.grid)
    psi = np.zeros(len(W))
    if model.frame == "heading":
        W, psi = heading_frame(W)
    if not len(W):
        raise MissingStream(f"session {session.id}: its IMU spans less than one {model.grid.stride_s:g} s stride")
    vs, lvs = [], []
    for i in range(0, len(W), batch):
        v, lv = model.predict(W[i:i + batch])
        vs.append(np.asarray(v, float))
        lvs.append(np.asarray(lv, float))
    v, lv = np.concatenate(vs), np.concatenate(lvs)
    if model.frame == "heading":
        v, lv = rotate_velocity(v, lv, psi)
    if not (np.isfinite(v).all() and np.isfinite(lv).all()):
        raise ValueError(f"session {session.id}: the inertial model returned a non-finite velocity")
    tt, xy, var = integrate(float(t[0]), model.grid, v, lv)
    df = pd.DataFrame({"t": tt, "x": xy[:, 0], "y": xy[:, 1], "var": var})
    if cache is not None:
        cache[key] = df
    return df


#: the attitude sources a live stream can give the learned odometry: the phone's rotation vector (pushed samples) or
#: blenav's AHRS on the pushed IMU (and magnetometer): the PDR headings
LIVE_ATTITUDES = HEADINGS
#: the largest step of the IMU clock a live stream may take (s), and the longest IMU waits for a rotation vector
MAX_GAP_S = 60.0


class StreamingLio:
    """:func:`lio_odometry` one sample at a time: the track a phone makes live from its IMU (issue 31, the push API).

    ``push_imu(t, acc, gyr)`` (device frame, m/s^2 incl. gravity, rad/s; times increasing) returns the track points
    (t s, xy (2,) m, var m^2) it completed: the origin (t0, 0, 0) at the first sample, then one point per stride when
    the window ending there is full. The attitude: ``orientation``, the latest sample of ``push_orientation(t, q)``
    (device -> world, w x y z) at or before each IMU sample (IMU samples before the first one wait for it, as the
    batch path takes the first sample for them), or ``ahrs``, :class:`StreamingAttitude` on the pushed IMU and
    ``push_mag(t, mag)`` with ``mag_offset`` (uT; the batch path fits it on the whole walk, a phone has its own
    calibration); with a model trained on the gyroscope's yaw (``yaw: gyro``, or ``auto`` with ``gyro_calibrated``:
    whether the pushed gyroscope has its bias removed, as the batch path's ``session.gyro_calibrated``; None: true for
    the ``orientation`` attitude, Android's rotation vector coming with its calibrated gyroscope) that attitude is
    held sample by sample (:class:`blenav.filters.yaw_hold.StreamingYawHold`). With the batch path's attitude the points are
    :func:`lio_odometry`'s (the same resampling to ``model.grid``, windows, frames and integration;
    tests/filters/test_streaming_lio.py; an IMU time stamp repeated on a grid time is the one exception: the batch
    interpolation takes the later sample there). Per sample O(1): one
    network run per stride, on one window; a jump of the IMU clock by more than :data:`MAX_GAP_S` is refused (a gap
    would cost a network run per stride of it), as is an ``orientation`` attitude whose rotation vector has not come
    after :data:`MAX_GAP_S` of IMU."""

    def __init__(self, model: VelocityModel, attitude: str, att: AttitudeConfig | None = None, mag_offset=None,
                 gyro_calibrated: bool | None = None):
        if attitude not in LIVE_ATTITUDES:
            raise ValueError(f"live inertial odometry: attitude must be one of {LIVE_ATTITUDES}, got {attitude!r}")
        self.model, self.attitude, self.grid = model, attitude, model.grid
        self.ahrs = StreamingAttitude(att or AttitudeConfig(), mag_offset=mag_offset) if attitude == "ahrs" else None
        calibrated = attitude == "orientation" if gyro_calibrated is None else bool(gyro_calibrated)
        held = resolve_yaw(model_yaw(model), calibrated) == "gyro"
        self.hold = StreamingYawHold() if held else None  # every IMU sample, in order
        self._q: np.ndarray | None = None
        self._waiting: list[tuple] = []  # IMU samples before the first orientation sample
        self._prev: tuple[float, np.ndarray] | None = None  # the last IMU sample, rotated (t, raw (15,))
        self.t0: float | None = None
        self.n = 0  # grid samples made
        self._buf: np.ndarray | None = None  # (n_window, 15) float32: the last window's samples
        self.xy, self.var, self.k = np.zeros(2), 0.0, 0

    @property
    def horizon(self) -> float | None:
        """The time of the last IMU sample made into odometry (every point up to it is out); None before the first."""
        return None if self._prev is None else self._prev[0]

    def push_orientation(self, t: float, q) -> list[tuple]:
        """A rotation-vector sample (``orientation`` attitude; ignored otherwise)."""
        if self.attitude != "orientation":
            return []
        self._q = np.asarray(q, float).reshape(4)
        out, waiting, self._waiting = [], self._waiting, []
        for t_i, acc, gyr in waiting:
            out += self._sample(t_i, acc, gyr, self._q)
        return out

    def push_mag(self, t: float, mag) -> None:
        if self.ahrs is not None:
            self.ahrs.update_mag(float(t), np.asarray(mag, float))

    def push_imu(self, t: float, acc, gyr) -> list[tuple]:
        if not np.isfinite(t):
            raise ValueError(f"live inertial odometry: an IMU sample at time {t!r}")
        acc, gyr = np.asarray(acc, float).reshape(3), np.asarray(gyr, float).reshape(3)
        if self.ahrs is not None:
            return self._sample(float(t), acc, gyr, self.ahrs.update(float(t), acc, gyr))
        if self._q is None:
            if self._waiting and float(t) - self._waiting[0][0] > MAX_GAP_S:
                raise ValueError(f"live inertial odometry: attitude 'orientation', but no rotation vector came in "
                                 f"{MAX_GAP_S:g} s of IMU: push the rotation vector, or use the AHRS (attitude 'ahrs')")
            self._waiting.append((float(t), acc, gyr))
            return []
        return self._sample(float(t), acc, gyr, self._q)

    def _sample(self, t: float, acc: np.ndarray, gyr: np.ndarray, q: np.ndarray) -> list[tuple]:
        if self._prev is not None:  # refused before anything (the held yaw included) takes the sample in
            tp = self._prev[0]
            if t < tp:
                raise ValueError(f"live inertial odometry: IMU time goes backwards: {t} after {tp}")
            if t - tp > MAX_GAP_S:
                raise ValueError(f"live inertial odometry: the IMU's time jumps from {tp:.3f} s to {t:.3f} s (more "
                                 f"than {MAX_GAP_S:g} s without a sample; times in seconds?): split the recording at "
                                 "the gap")
        if self.hold is not None:
            q = self.hold.update(t, gyr, q)
        R = quat_to_matrix(q[None])  # (1, 3, 3), as world_frame_imu rotates every sample
        a_w = np.einsum("tij,tj->ti", R, acc[None])
        g_w = np.einsum("tij,tj->ti", R, gyr[None])
        a_w[:, 2] -= GRAVITY
        raw = np.concatenate([a_w, g_w, R[:, :, 0], R[:, :, 1], R[:, :, 2]], axis=1)[0]
        rate = float(self.grid.rate_hz)
        out: list[tuple] = []
        if self.t0 is None:
            self.t0, self._prev = t, (t, raw)
            self._buf = np.repeat(raw.astype(np.float32)[None], self.grid.n_window, axis=0)
            self.n = 1
            return [(t, np.zeros(2), 0.0)]
        tp, rp = self._prev
        if not t > tp:  # a repeated time stamp: the later sample, as the batch interpolation takes it
            self._prev = (t, raw)
            return out
        while True:  # the grid samples in (tp, t], interpolated as np.interp over the whole walk does
            g = self.t0 + self.n / rate
            if g > t:
                break
            x = np.array([np.interp(g, (tp, t), (rp[j], raw[j])) for j in range(len(raw))], np.float32)
            out += self._grid_sample(x)
        self._prev = (t, raw)
        return out

    def _grid_sample(self, x: np.ndarray) -> list[tuple]:
        self._buf = np.concatenate([self._buf[1:], x[None]], axis=0)
        j, self.n = self.n, self.n + 1
        if j % self.grid.n_stride:
            return []
        W, psi = self._buf[None], np.zeros(1)
        if self.model.frame == "heading":
            W, psi = heading_frame(W)
        v, lv = (np.asarray(a, float) for a in self.model.predict(W))
        if self.model.frame == "heading":
            v, lv = rotate_velocity(v, lv, psi)
        if not (np.isfinite(v).all() and np.isfinite(lv).all()):
            raise ValueError("live inertial odometry: the inertial model returned a non-finite velocity")
        s = float(self.grid.stride_s)
        self.k += 1
        self.xy = self.xy + v[0] * s  # integrate(): the cumulative sum, one window at a time
        self.var = self.var + float(s * s * np.exp(np.clip(lv[0], -30.0, 30.0)).mean())
        return [(self.t0 + s * self.k, self.xy.copy(), self.var)]
