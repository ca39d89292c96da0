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

from .attitude import AttitudeConfig
from .pdr_odometry import attitude_track, resolve_heading
from .quaternions import quat_to_matrix
from .steps import StepDetectorConfig

__all__ = ["VelocityModel", "world_frame_imu", "session_frame_imu", "lio_odometry"]


class VelocityModel(Protocol):
    grid: InertialGrid
    key: str  # identifies the model's weights (a cache key part: the same key, the same velocities)
    frame: str  # blenav.features.inertial.FRAMES: heading (turn each window, turn the velocity back) or world

    def predict(self, windows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(K, n_window, 15) float32 -> (velocity (K, 2) m/s, log variance (K, 2))."""


def _attitude_at(q_t: np.ndarray, q: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(len(t), 4): the attitude sample at or before each time (the first one before the track starts)."""
    i = np.clip(np.searchsorted(q_t, t, side="right") - 1, 0, len(q_t) - 1)
    return q[i]


def world_frame_imu(imu_t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, q_t: np.ndarray, q: np.ndarray,
                    rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """The IMU rotated into the attitude's gravity-aligned frame and resampled (module doc).

    ``imu_t`` (T,) s increasing; ``acc`` (T, 3) m/s^2 incl. gravity, ``gyr`` (T, 3) rad/s, device frame; ``q_t``
    (Q,) s, ``q`` (Q, 4) device -> world (w, x, y, z). Returns (t (N,) s on the grid from imu_t[0], X (N, 15) float32
    in :data:`CHANNELS` order)."""
    imu_t = np.asarray(imu_t, float)
    if len(imu_t) < 2:
        raise ValueError("inertial odometry: fewer than two IMU samples")
    if not len(q_t):
        raise ValueError("inertial odometry: the attitude track is empty")
    R = quat_to_matrix(_attitude_at(np.asarray(q_t, float), np.asarray(q, float), imu_t))
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
                      steps: StepDetectorConfig | None = None, cache: dict | None = None, keep: bool = True
                      ) -> tuple[np.ndarray, np.ndarray, str]:
    """The session's IMU in the attitude's gravity-aligned frame on ``grid``'s rate: (t (N,) s, X (N, 15) float32,
    the attitude source used). :class:`MissingStream` without IMU data or the attitude source. ``cache``: the
    attitude (an AHRS run) is kept there, and the result too unless ``keep`` is false."""
    imu = session.imu
    if len(imu) < 2:
        raise MissingStream(f"session {session.id} has no IMU data, which the inertial odometry needs")
    source = resolve_heading(session, attitude)
    key = ("lio-frame", session.id, source, grid.rate_hz, repr(att), repr(steps))
    if cache is not None and key in cache:
        return cache[key]
    q_t, q = attitude_track(session, source, att, steps, cache)
    t, X = world_frame_imu(imu["t"].to_numpy(float), imu[["ax", "ay", "az"]].to_numpy(float),
                           imu[["gx", "gy", "gz"]].to_numpy(float), q_t, q, grid.rate_hz)
    out = (t, X, source)
    if cache is not None and keep:
        cache[key] = out
    return out


def lio_odometry(session, model: VelocityModel, attitude: str = "auto", att: AttitudeConfig | None = None,
                 steps: StepDetectorConfig | None = None, cache: dict | None = None, batch: int = 512) -> pd.DataFrame:
    """The learned odometry track of ``session`` (DataFrame t, x, y, var: s, m from 0, m^2), ``model`` run on every
    window (``batch`` at a time). :class:`MissingStream` without IMU data, the attitude, or a full stride of IMU."""
    key = ("lio-odometry", session.id, model.key, attitude, repr(att), repr(steps))
    if cache is not None and key in cache:
        return cache[key]
    # the attitude (an AHRS run) through the cache; the rotated IMU itself is not kept once the track is
    t, X, _ = session_frame_imu(session, model.grid, attitude, att, steps, cache, keep=False)
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
