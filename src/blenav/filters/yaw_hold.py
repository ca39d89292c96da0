"""The gyroscope's heading held to the attitude's mean (issue 31): an attitude track whose yaw changes as the
gyroscope turns, not as the magnetometer's local disturbances pull it.

A phone's rotation vector (and blenav's AHRS) takes its heading from the magnetometer, low-passed: indoors, where steel
deflects the field by several degrees from place to place, its yaw wanders with the field as the walker passes. The
gyroscope turns with the phone (a calibrated gyro drifts well under a degree a minute) but has no absolute heading.
The held track keeps the attitude's tilt, takes its yaw increments from the gyroscope, and places that yaw at the
attitude's running mean over the last :data:`WINDOW_S` seconds (causal: the same track live and offline):

    d(t)     = psi_att(t) - psi_gyro(t)                          (the attitude's yaw against the integrated gyro)
    delta(t) = mean_{t - W <= s <= t} d(s) - d(t)                (the turn that puts the gyro yaw at the window's mean)
    q_held(t) = Rz(delta(t)) q_att(t)

``psi_att`` is the cumulative world-z twist of the attitude's increments (continuous, defined in every pose, also with
the phone upright), ``psi_gyro`` the cumulative sum of the world-z rate (the gyro rotated by the attitude) of each
sample times the interval to the next. The window bounds what a gyroscope bias b costs: the held yaw lags the mean by
about b W / 2 (0.001 rad/s: 3.4 deg with W = 120 s), however long the session; the ILC walks (15-114 s) all fit in it.
On the ILC test walks (leave-one-floor-out networks) the learned odometry's segment error goes from 1.47 / 1.33 / 1.33
to 1.37 / 1.25 / 1.32 m, F1 / F2 / B1 (``benchmarks/inertial_heading.py``; docs/inertial.md).

The hold assumes a **calibrated** gyroscope (Android's ``TYPE_GYROSCOPE``, its bias removed by the phone). A raw MEMS
gyroscope's bias (0.01 rad/s is common, the simulator's default) makes the held yaw lag the mean by tens of degrees
within the window, far worse than the attitude's own yaw (the AHRS estimates the bias against the magnetometer). The
source ``auto`` (:func:`resolve_yaw`) therefore holds where the session says its gyroscope is calibrated (session.yaml
``gyro_calibrated``, :attr:`blenav.data.session.Session.gyro_calibrated`) and keeps the attitude's yaw elsewhere.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from .quaternions import qconj, qmul, quat_to_matrix

__all__ = ["YAW_SOURCES", "WINDOW_S", "check_yaw", "resolve_yaw", "hold_yaw", "StreamingYawHold"]

#: where an attitude track's yaw comes from: the attitude itself, the gyroscope held to its running mean, or ``auto``:
#: the gyroscope where it is calibrated, else the attitude (:func:`resolve_yaw`)
YAW_SOURCES = ("attitude", "gyro", "auto")
#: seconds of the attitude's running mean (the bias bound of the module doc)
WINDOW_S = 120.0


def check_yaw(yaw, what: str = "yaw") -> str:
    """``yaw`` when it is one of :data:`YAW_SOURCES` (a config's, a method's, an export's), else ValueError naming
    ``what`` (the key it came from)."""
    if yaw not in YAW_SOURCES:
        raise ValueError(f"{what} must be one of {YAW_SOURCES}, got {yaw!r}")
    return str(yaw)


def resolve_yaw(yaw: str, gyro_calibrated: bool) -> str:
    """The yaw source a track runs with: ``yaw`` itself, or for ``auto`` ``gyro`` when ``gyro_calibrated`` (the
    hold's assumption, module doc) and ``attitude`` otherwise. ValueError for a source not in :data:`YAW_SOURCES`."""
    if check_yaw(yaw) == "auto":
        return "gyro" if gyro_calibrated else "attitude"
    return yaw


def _twist_z(dq: np.ndarray) -> np.ndarray:
    """(N,) rad: the rotation about world z in each world-frame increment quaternion (N, 4) (swing-twist)."""
    w = np.where(dq[:, 0] < 0, -1.0, 1.0)  # q and -q are one rotation: take the short way
    return 2.0 * np.arctan2(w * dq[:, 3], w * dq[:, 0])


def hold_yaw(t: np.ndarray, gyr: np.ndarray, q: np.ndarray, window_s: float = WINDOW_S) -> np.ndarray:
    """The held attitude (T, 4) (module doc) at the IMU times ``t`` (T,) s, from the gyroscope ``gyr`` (T, 3) rad/s
    (device frame) and the attitude ``q`` (T, 4) device -> world (w, x, y, z) at those times; the mean over the last
    ``window_s`` seconds. T >= 1."""
    t, gyr, q = np.asarray(t, float), np.asarray(gyr, float), np.asarray(q, float)
    if len(t) < 2:
        return q.copy()
    wz = np.einsum("tij,tj->ti", quat_to_matrix(q), gyr)[:, 2]
    d_att = _twist_z(qmul(q[1:], qconj(q[:-1])))
    d_gyr = wz[:-1] * np.diff(t)
    d = np.concatenate([[0.0], np.cumsum(d_att - d_gyr)])
    S = np.cumsum(d)
    j = np.searchsorted(t, t - float(window_s), side="left")  # the first sample inside each one's window
    before = np.where(j > 0, S[np.maximum(j - 1, 0)], 0.0)
    delta = (S - before) / (np.arange(len(d)) - j + 1) - d
    turn = np.stack([np.cos(delta / 2), np.zeros_like(delta), np.zeros_like(delta), np.sin(delta / 2)], axis=1)
    return qmul(turn, q)


class StreamingYawHold:
    """:func:`hold_yaw` one IMU sample at a time: ``update(t, gyr, q)`` returns the held attitude (4,) of the sample;
    the same numbers as the batch function over the samples pushed so far (the same operations in the same order).
    Memory: the samples of one window."""

    def __init__(self, window_s: float = WINDOW_S):
        self.window_s = float(window_s)
        self._prev: tuple[float, float, np.ndarray] | None = None  # (t, world-z rate, q) of the previous sample
        self._d = 0.0
        self._sum = 0.0  # the running sum of d over every sample so far
        self._n = 0
        self._win: deque[tuple[float, float, int]] = deque()  # (t, the sum before it, index) of the window's samples

    def update(self, t: float, gyr, q) -> np.ndarray:
        t = float(t)
        q = np.asarray(q, float).reshape(4)
        wz = float(np.einsum("tij,tj->ti", quat_to_matrix(q[None]), np.asarray(gyr, float).reshape(1, 3))[0, 2])
        if self._prev is not None:
            tp, wzp, qp = self._prev
            d_att = float(_twist_z(qmul(q[None], qconj(qp[None])))[0])
            self._d = self._d + (d_att - wzp * (t - tp))
        self._prev = (t, wz, q)
        self._win.append((t, self._sum, self._n))
        self._sum += self._d
        while self._win[0][0] < t - self.window_s:
            self._win.popleft()
        _, before, j = self._win[0]
        delta = (self._sum - before) / (self._n - j + 1) - self._d
        self._n += 1
        turn = np.array([[np.cos(delta / 2), 0.0, 0.0, np.sin(delta / 2)]])
        return qmul(turn, q[None])[0]
