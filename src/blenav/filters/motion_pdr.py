"""Pedestrian dead reckoning as an odometry track: detected steps along a heading, world frame.

Roy's map-prior filter (eq. 3.7, :class:`blenav.filters.motion.OdometryIncrement`) and its learned map prior
(:mod:`blenav.filters.map_prior`) read an odometry position track (``odometry.csv``: t, x, y). A phone walk
has none, but it has steps and a heading: this module turns them into that track, so that every
odometry-based row runs on a phone walk (the ILC 2.0 recordings, issue 17).

Track: every step detected at IMU time t_i (:func:`blenav.filters.steps.detect_steps`, the detector of
the filters' PDR motion model) moves the walker ``step_length`` metres along the heading psi(t_i); the
track is sampled at the first IMU sample, at every step and at the last IMU sample (constant position between
steps: the odometry readers hold the last sample, so denser samples would change nothing):

    p(t_i) = p(t_{i-1}) + L [cos psi(t_i), sin psi(t_i)],   p(t_0) = 0.

Heading psi (rad, CCW from world +x) is the heading of the device's +y axis (top edge, the walking
direction of a phone held in front) of a device->world quaternion track, either

* ``orientation``: the phone's own rotation vector (``orientation.csv``, frame ``enu-magnetic``: x east,
  y magnetic north). Floor frames aligned east/north (the ILC floor plans) make the track world-aligned
  up to the magnetic declination and the phone's heading error, so no oracle rotation is needed
  (OdometryIncrement ``theta0: 0``), or
* ``ahrs``: blenav's own AHRS (Madgwick with magnetometer, :func:`blenav.filters.attitude.estimate_attitude`),
  likewise magnetic-north referenced.
"""

from __future__ import annotations

import numpy as np

from .attitude import yaw_of_device_forward
from .steps import StepDetectorConfig, detect_steps

__all__ = ["pdr_track", "heading_at"]


def heading_at(t: np.ndarray, q_t: np.ndarray, q: np.ndarray, offset_rad: float = 0.0) -> np.ndarray:
    """(len(t),) rad: the heading of the device's +y axis of the quaternion track (q_t (Q,) s, q (Q, 4) w, x,
    y, z device->world) at times ``t`` (the last sample at or before each t; the first before it), plus
    ``offset_rad`` (e.g. a declination)."""
    if not len(q_t):
        raise ValueError("heading_at: the orientation track is empty")
    i = np.clip(np.searchsorted(q_t, t, side="right") - 1, 0, len(q_t) - 1)
    return yaw_of_device_forward(np.asarray(q, float)[i]) + float(offset_rad)


def pdr_track(imu_t: np.ndarray, acc: np.ndarray, q_t: np.ndarray, q: np.ndarray, step_length: float = 0.7,
              cfg: StepDetectorConfig | None = None, flags: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The PDR odometry track (t (M,) s, xy (M, 2) m, world-aligned as the heading's frame, starting at 0).

    ``imu_t`` (T,) s, ``acc`` (T, 3) m/s^2; ``q_t`` (Q,) s, ``q`` (Q, 4) the device->world orientation;
    ``step_length`` m per detected step; samples at the IMU span's ends and at every step. ``flags`` (T,) bool:
    the steps already detected in ``acc`` with ``cfg`` (:func:`detect_steps`), not detected again."""
    imu_t = np.asarray(imu_t, float)
    if len(imu_t) < 2:
        raise ValueError("pdr_track: fewer than two IMU samples")
    if not (np.isfinite(step_length) and step_length > 0):
        raise ValueError(f"pdr_track: step_length must be a positive number of metres, got {step_length!r}")
    if flags is None:
        flags = detect_steps(imu_t, np.asarray(acc, float), cfg)
    elif len(flags) != len(imu_t):
        raise ValueError(f"pdr_track: {len(flags)} step flags for {len(imu_t)} IMU samples")
    ts = imu_t[np.asarray(flags, bool)]
    psi = heading_at(ts, np.asarray(q_t, float), q)
    steps = step_length * np.stack([np.cos(psi), np.sin(psi)], axis=-1)
    t = np.union1d([imu_t[0], imu_t[-1]], ts)
    n_before = np.searchsorted(ts, t, side="right")  # steps at or before each sample time
    cum = np.vstack([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    return t, cum[n_before]
